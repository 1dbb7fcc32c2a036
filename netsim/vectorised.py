"""Vectorised lockstep engine: all trials of a Monte Carlo batch advance together.

The event kernel (:mod:`netsim.kernel`) is the reference; this engine computes the
same runs with numpy arrays of shape (agents, trials, n) instead of one SimPy event
per message, for the estimator families whose sending steps are known in advance
(``compensated``, ``uncompensated``, ``block``) and the centralised Kalman filter.

What is the same as the kernel, by construction:

* the random streams: trial t's plant noise comes from ``stream(seed_t, "plant")``
  drawn in the kernel's order (x_0, then per step the process noise and each
  sensor's measurement noise), and the links consume each trial's delay model
  exactly as the kernel does (:mod:`netsim.linkschedule`);
* the update rules: LCSYS2022 eqs. (4)-(5) with A^(k - s) compensation, the
  delay-tolerant paper's eqs. (6)-(7) with A and the most recently arrived message,
  LCSYS2022 eqs. (15)-(16) for the block update, the Kalman filter of
  :class:`netsim.estimators.kalman.CentralizedKalmanFilter`; substitution of the agent's own
  prediction before anything arrived from a neighbour (DESIGN.md);
* the outputs: one :class:`netsim.kernel.TrialResult` per trial, with the same
  divergence rule and message counts.

Only the order of floating-point additions differs (the neighbour sum is a sparse
matrix product), so estimates agree with the kernel's to round-off; the
differential tests (tests/test_vectorised.py) hold them to 1e-9 relative.

Past estimates are kept in a ring buffer as deep as the largest lag k - s any
receiver uses (known from the schedule), and powers A^r are precomputed once.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from netsim import budget, interrupt
from netsim.estimators.gains import GainDesign
from netsim.kernel import NOT_USED, ROUNDOFF_RELATIVE_ERROR, TrialResult, squared_threshold
from netsim.linkschedule import (
    LinkSchedule,
    MessageSelection,
    build_schedule,
    select_messages,
)
from netsim.models.scenario import Scenario
from netsim.models.seeding import SeedLike, stream

__all__ = [
    "BATCH_ELEMENTS",
    "PlantBatch",
    "VectorisedBatch",
    "simulate_plant",
    "run_batch",
    "run_vectorised",
    "LockstepRule",
    "lockstep_rule",
    "effective_delays_per_link",
]

#: Largest trials x links x (steps + 2) of one lockstep batch. Links with random
#: delays, losses or buffers need about 75 bytes per element at the peak (measured by
#: benchmarks/engine_scaling.py), so a full batch takes about 0.75 GB; constant delays
#: need far less. One trial is never split.
BATCH_ELEMENTS = 10_000_000


@dataclass(frozen=True)
class LockstepRule:
    """The update rule a family's lockstep form runs, from its ``batched_options``.

    Attributes
    ----------
    kind : str
        ``consensus`` (the consensus + innovation estimators, LCSYS2022 eqs. 4-5,
        15-16 and delay-tolerant eqs. 6-7) or ``kalman`` (the centralised filter).
    compensate : bool
        A^(k - s_j) compensation (LCSYS2022 eq. 4); False: A (delay-tolerant eq. 6).
    timestamps : bool
        The freshest time-stamp is used; False: the most recently arrived message.
    block : bool
        Update and communicate every tau+1 steps with A^(tau+1) (LCSYS2022 eq. 15).
    """

    kind: str
    compensate: bool = True
    timestamps: bool = True
    block: bool = False


def lockstep_rule(family: str) -> LockstepRule:
    """The lockstep rule the registry declares for ``family`` (ValueError if none)."""
    from netsim.estimators.registry import get_family

    declared = get_family(family, "family")
    options = dict(declared.batched_options)
    kind = options.pop("rule", None)
    if kind not in ("consensus", "kalman"):
        raise ValueError(f"the vectorised engine has no lockstep form of estimator family "
                         f"{family!r}")
    return LockstepRule(kind, **options)


@dataclass
class PlantBatch:
    """States and measurements of a batch of trials.

    Attributes
    ----------
    states : numpy.ndarray, shape (K+1, T, n)
    measurements : numpy.ndarray, shape (K+1, T, M)
        All sensors' measurements stacked (sensor i in columns ``offsets[i]:offsets[i+1]``).
    offsets : numpy.ndarray, shape (N+1,)
    """

    states: np.ndarray
    measurements: np.ndarray
    offsets: np.ndarray


def simulate_plant(scenario: Scenario, trial_seeds: Sequence[SeedLike], steps: int
                   ) -> PlantBatch:
    """Simulate the plant and sensors of every trial (LCSYS2022 eq. 1).

    Trial t draws from ``stream(trial_seeds[t], "plant")`` exactly the numbers the
    kernel's plant process draws: per step k, n process-noise values (x_0's for
    k = 0), then each sensor's m_i measurement-noise values.
    """
    plant = scenario.plant
    sizes = [C.shape[0] for C in plant.C]
    noise = np.empty((int(steps) + 1, len(trial_seeds), plant.noise_width))
    for t, seed in enumerate(trial_seeds):
        noise[:, t, :] = plant.standard_noise(stream(seed, "plant"), int(steps))
    trajectory = plant.simulate(noise)
    states, measurements = trajectory.states, trajectory.measurements
    return PlantBatch(states, measurements, np.concatenate([[0], np.cumsum(sizes)]))


@dataclass
class VectorisedBatch:
    """What :func:`run_batch` computed.

    Attributes
    ----------
    results : list of TrialResult
        One per trial.
    schedule : LinkSchedule or None
        Every message's delay and fate (None for the centralised filter).
    selection : MessageSelection or None
        The message each receiver held at each step.
    updated : numpy.ndarray, shape (U,)
        Steps at which the estimators updated (every step; block steps for ``block``).
    period : int
        Sending period (tau + 1 for ``block``, else 1).
    """

    results: list[TrialResult]
    schedule: LinkSchedule | None
    selection: MessageSelection | None
    updated: np.ndarray
    period: int


class _Outputs:
    """Per-step recording with the kernel's divergence rule (agent-major arrays)."""

    def __init__(self, K: int, N: int, T: int, n: int, threshold: float,
                 record_estimates: bool) -> None:
        self.K = K
        self.sq = np.full((K + 1, T, N), np.nan)
        self.estimates = np.full((K + 1, T, N, n), np.nan) if record_estimates else None
        self.diverged_at = np.full(T, -1, dtype=np.int64)
        self.alive = np.ones(T, dtype=bool)
        self.all_alive = True
        self.threshold_sq = squared_threshold(threshold)

    def record(self, k: int, estimates: np.ndarray, state: np.ndarray) -> bool:
        """Record step k (estimates (N, T, n), state (T, n)); False when all diverged."""
        err = estimates - state[None]
        sq = np.einsum("itj,itj->ti", err, err)
        alive = self.alive
        if self.all_alive:
            self.sq[k] = sq
            if self.estimates is not None:
                self.estimates[k] = estimates.transpose(1, 0, 2)
            # every error finite and within the threshold (NaN fails the comparisons):
            # no trial diverges at k, whatever the round-off floor
            worst = sq.max(initial=0.0)
            if worst <= self.threshold_sq and worst < np.inf:
                return True
        else:
            self.sq[k, alive] = sq[alive]
            if self.estimates is not None:
                self.estimates[k, alive] = estimates.transpose(1, 0, 2)[alive]
        state_sq = np.einsum("tj,tj->t", state, state)
        floor = np.maximum(self.threshold_sq, ROUNDOFF_RELATIVE_ERROR ** 2 * state_sq)
        bad = ~np.all(np.isfinite(sq), axis=1) | np.any(sq > floor[:, None], axis=1)
        newly = bad & alive
        if np.any(newly):
            self.diverged_at[newly] = k
            self.sq[k, newly] = np.where(np.isfinite(sq[newly]), sq[newly], np.inf)
            self.alive = alive & ~newly
            self.all_alive = False
        return bool(np.any(self.alive))


def _link_positions(schedule_links: Sequence[tuple[int, int]], scenario: Scenario,
                    src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Index into ``schedule_links`` of each link (src[e], dst[e]), -1 if absent, shape (E,).

    The schedule's links are normally the scenario's (its :attr:`Scenario.link_table`,
    sorted by sender then receiver): then a search on the sorted keys, no dictionary.
    """
    N = scenario.n_agents
    table = scenario.link_table
    if len(schedule_links) == len(table) and (
            schedule_links is scenario.links or list(schedule_links) == scenario.links):
        # link q sits at (dst, src) of a CSR matrix holding q + 1: reading it at the
        # wanted (receiver, sender) pairs is a counting sort, not a search
        L = len(table)
        index = sp.csr_array((np.arange(1, L + 1, dtype=np.int64), (table.dst, table.src)),
                             shape=(N, N))
        index.sum_duplicates()
        rows = np.repeat(np.arange(N, dtype=np.int64), np.diff(index.indptr))
        wanted_dst = np.asarray(dst, dtype=np.int64)
        wanted_src = np.asarray(src, dtype=np.int64)
        if (len(rows) == len(wanted_dst) and np.array_equal(rows, wanted_dst)
                and np.array_equal(index.indices, wanted_src)):
            return index.data - 1  # the terms are exactly the links, in row order
        keys = table.src * N + table.dst
    else:
        arr = np.array(schedule_links, dtype=np.int64).reshape(-1, 2)
        keys = arr[:, 0] * N + arr[:, 1]
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    wanted = np.asarray(src, dtype=np.int64) * N + np.asarray(dst, dtype=np.int64)
    at = np.minimum(np.searchsorted(sorted_keys, wanted), max(len(keys) - 1, 0))
    found = (sorted_keys[at] == wanted) if len(keys) else np.zeros(len(wanted), dtype=bool)
    return np.where(found, order[at] if len(keys) else -1, -1).astype(np.int64)


def _consensus_terms(scenario: Scenario, schedule: LinkSchedule
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The consensus terms from the sparse weights (never an N x N array).

    Returns every (i, j) with p_ij > 0, j != i, in row order (the order of the
    neighbour sums): receivers ``term_i``, senders ``term_j``, weights ``term_w``,
    the schedule link of each term ``term_link`` (-1 if none), all shape (E,), and
    the self weights p_ii, shape (N,).
    """
    W = scenario.weights_sparse
    N = W.shape[0]
    rows = np.repeat(np.arange(N, dtype=np.int64), np.diff(W.indptr))
    cols = W.indices.astype(np.int64)
    vals = W.data
    keep = (rows != cols) & (vals != 0)
    term_i, term_j, term_w = rows[keep], cols[keep], vals[keep]
    term_link = _link_positions(schedule.links, scenario, term_j, term_i)
    return term_i, term_j, term_w, term_link, W.diagonal()


def _pad_outputs(scenario: Scenario, gains: GainDesign) -> tuple[np.ndarray, np.ndarray]:
    """C_i (N, m, n) and L_i (N, n, m), zero-padded to the largest m_i."""
    C = scenario.plant.C
    m = max(Ci.shape[0] for Ci in C)
    n = scenario.plant.n_states
    N = len(C)
    if all(Ci.shape[0] == m for Ci in C):
        return (np.stack(C).astype(float, copy=False).reshape(N, m, n),
                np.stack([np.asarray(Li, dtype=float) for Li in gains.L]).reshape(N, n, m))
    Cp = np.zeros((N, m, n))
    Lp = np.zeros((N, n, m))
    for i, Ci in enumerate(C):
        Cp[i, : Ci.shape[0]] = Ci
        Lp[i, :, : Ci.shape[0]] = np.asarray(gains.L[i])
    return Cp, Lp


def _agent_measurements(batch: PlantBatch, m: int) -> np.ndarray:
    """Measurements per agent, shape (K+1, N, T, m), zero-padded."""
    K1, T, _ = batch.measurements.shape
    N = len(batch.offsets) - 1
    if N and batch.measurements.shape[2] == N * m:  # every agent has m outputs
        return np.ascontiguousarray(
            batch.measurements.reshape(K1, T, N, m).transpose(0, 2, 1, 3))
    out = np.zeros((K1, N, T, m))
    for i in range(N):
        a, b = batch.offsets[i], batch.offsets[i + 1]
        out[:, i, :, : b - a] = batch.measurements[:, :, a:b]
    return out


def _powers(A: np.ndarray, count: int) -> np.ndarray:
    """A^0 .. A^count, shape (count+1, n, n), by the estimators' recursion A @ A^(r-1)."""
    out = [np.eye(A.shape[0]), A]
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is a divergence
        while len(out) <= count:
            out.append(A @ out[-1])
    return np.stack(out[: count + 1])


def _times(x: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Return x @ M over the last axis as one 2-D product (x: (..., n), M: (n, p))."""
    return (x.reshape(-1, x.shape[-1]) @ M).reshape(*x.shape[:-1], M.shape[1])


def _consensus_run(scenario: Scenario, rule: LockstepRule, gains: GainDesign,
                   batch: PlantBatch, schedule: LinkSchedule, selection: MessageSelection,
                   steps: int, record_estimates: bool) -> tuple[_Outputs, np.ndarray]:
    """Run a consensus family; returns the outputs and the steps with an update."""
    plant = scenario.plant
    A = plant.A
    n = plant.n_states
    K = int(steps)
    T = batch.states.shape[1]
    N = scenario.n_agents
    Cp, Lp = _pad_outputs(scenario, gains)
    Y = _agent_measurements(batch, Cp.shape[1])
    term_i, term_j, term_w, term_link, diagonal = _consensus_terms(scenario, schedule)
    E = len(term_i)
    aggregate = sp.csr_matrix((term_w, (term_i, np.arange(E))), shape=(N, E))
    # one constant delay d on every link, a message every step: from step d + 1 on,
    # every term uses the estimate of step k - 1 - d, so the neighbour sum is one
    # sparse product with P minus its diagonal
    uniform = selection.uniform_delay if not np.any(term_link < 0) else None
    neighbour_matrix = sp.csr_matrix((term_w, (term_i, term_j)), shape=(N, N))
    own_weight = diagonal[:, None, None]
    block = rule.block
    period = scenario.delay_bound + 1 if block else 1
    send = schedule.send_steps
    # the delay horizon that can matter: a power A^r with r > K is never applied (a
    # message delayed past the last step never arrives; a block period beyond K only
    # propagates the step-0 estimate, with A^(k - 0), k <= K), so the ring of past
    # estimates and the powers stop there however large the delays are
    horizon = min(max(selection.max_lag, period), K)
    depth = horizon + 1
    powers = _powers(A, horizon)
    powers_T = np.ascontiguousarray(powers.transpose(0, 2, 1))
    A_T = A.T
    history = np.zeros((depth, N, T, n))
    flat_history = history.reshape(-1, n)
    trials = np.arange(T)[None, :]
    no_link = term_link < 0
    term_row = np.maximum(term_link, 0)

    Cp_T = np.ascontiguousarray(Cp.transpose(0, 2, 1))  # (N, n, m)
    Lp_T = np.ascontiguousarray(Lp.transpose(0, 2, 1))  # (N, m, n)

    # one output per agent (m = 1): L_i (y - C_i x) is one product per entry, here
    # against the gain repeated over the trials (the same numbers as the (T, 1) @
    # (1, n) matmul, at half its time)
    gain_rows = (np.ascontiguousarray(np.broadcast_to(Lp_T, (N, T, n)))
                 if Lp_T.shape[1] == 1 else None)

    def innovate(prior: np.ndarray, k: int) -> np.ndarray:
        # eq. (5): x_{k|k} = x_{k|k-1} + L_i (y - C_i x_{k|k-1}), per agent i as a
        # stacked product over the trials: (T, n) @ C_i^T, (T, m) @ L_i^T
        innovation = Y[k] - prior @ Cp_T
        if gain_rows is not None:
            return prior + innovation * gain_rows
        return prior + innovation @ Lp_T

    def uniform_prior(k: int, own: np.ndarray) -> np.ndarray:
        # every term holds the estimate of step s = k - 1 - d: one sparse product on
        # the ring slot, then A^(k - s) (eq. 4) or A (eq. 6)
        sent_step = k - 1 - uniform
        summed = (neighbour_matrix @ history[sent_step % depth].reshape(N, -1)
                  ).reshape(N, T, n)
        power = k - sent_step if rule.compensate else 1
        return own_weight * own + _times(summed, powers_T[power])

    def scheduled_prior(k: int, own: np.ndarray) -> np.ndarray:
        # the message each term holds at step k, from the link schedule
        held = selection.chosen[k][term_row]  # (E, T)
        held[no_link] = -1
        missing = held < 0
        sent = send[np.maximum(held, 0)]
        # x-hat^j_{s|s} of every term, from the ring of past estimates
        slot = ((sent % depth) * N + term_j[:, None]) * T + trials
        payload = flat_history.take(slot, axis=0)  # (E, T, n)
        own_total = own_weight
        if missing.any():
            # nothing from j yet: agent i's own prediction stands in, so j's weight
            # joins p_ii and j's term is zero
            payload = payload * ~missing[:, :, None]
            own_total = own_weight + (aggregate @ missing.astype(float))[:, :, None]
        prior = own_total * own
        # The terms are summed per lag before the power is applied:
        # sum_j p_ij A^r x_j = A^r (sum_j p_ij x_j), one product per distinct lag on
        # (N, T, n) rather than on every (term, trial).
        if not rule.compensate:
            groups = [(1, payload)]  # eq. (6): A, whatever the delay
        else:
            lag = np.where(missing, 0, k - sent)  # eq. (4): A^(k - s_j)
            lags = np.flatnonzero(np.bincount(lag.reshape(-1)))
            lags = lags[lags > 0]
            groups = [(r, payload if len(lags) == 1 else payload * (lag == r)[:, :, None])
                      for r in lags]
        for r, part in groups:
            summed = (aggregate @ part.reshape(E, -1)).reshape(N, T, n)
            prior = prior + _times(summed, powers_T[r])
        return prior

    outputs = _Outputs(K, N, T, n, scenario.divergence_threshold, record_estimates)
    estimate = innovate(np.broadcast_to(plant.x0_mean, (N, T, n)).copy(), 0)
    block_estimate, block_step = estimate, 0
    history[0] = estimate
    updated = [0]
    alive = outputs.record(0, estimate, batch.states[0])
    with np.errstate(all="ignore"):
        for k in range(1, K + 1):
            if not alive:
                break
            interrupt.check()  # a requested Ctrl-C stops here, between steps
            if block and k % period:
                estimate = _times(block_estimate, powers_T[k - block_step])
            else:
                # eq. (15)'s own term A^(tau+1) x-hat^i at the last block step, or A x-hat^i
                own = (_times(block_estimate, powers_T[period]) if block
                       else _times(estimate, A_T))
                if not E:
                    prior = own_weight * own
                elif uniform is not None and k > uniform:
                    prior = uniform_prior(k, own)
                else:
                    prior = scheduled_prior(k, own)
                estimate = innovate(prior, k)
                block_estimate, block_step = estimate, k
                updated.append(k)
            history[k % depth] = estimate
            alive = outputs.record(k, estimate, batch.states[k])
    return outputs, np.asarray(updated)


def _kalman_run(scenario: Scenario, batch: PlantBatch, steps: int,
                record_estimates: bool) -> _Outputs:
    """The centralised Kalman filter on all trials (gains are the same for every trial)."""
    from netsim.estimators.kalman import kalman_gain

    plant = scenario.plant
    M = sum(Ci.shape[0] for Ci in plant.C)
    # the filter's dense M x M innovation covariance (and R, the gain's solve)
    budget.check_memory(4 * 8.0 * M * M, "plant.C", "the centralised Kalman filter of "
                        f"M = {M} stacked outputs", f"{len(plant.C)} sensors",
                        "drop centralized-kf from run.estimators for large networks")
    A, C, Q, R = plant.A, plant.C_stacked, plant.Q, plant.R_stacked
    K = int(steps)
    T = batch.states.shape[1]
    n = plant.n_states
    x = np.broadcast_to(plant.x0_mean, (T, n)).astype(float)
    cov = np.asarray(plant.x0_cov, dtype=float).copy()
    outputs = _Outputs(K, 1, T, n, scenario.divergence_threshold, record_estimates)
    identity = np.eye(n)
    with np.errstate(all="ignore"):
        for k in range(K + 1):
            interrupt.check()
            if k > 0:
                x = x @ A.T
                cov = A @ cov @ A.T + Q
            S = C @ cov @ C.T + R
            G = kalman_gain(S, C @ cov, "plant.R", k)
            x = x + (batch.measurements[k] - x @ C.T) @ G.T
            I_GC = identity - G @ C
            cov = I_GC @ cov @ I_GC.T + G @ R @ G.T
            cov = 0.5 * (cov + cov.T)
            if not outputs.record(k, x[None], batch.states[k]):
                break
    return outputs


def effective_delays_per_link(selection: MessageSelection, schedule: LinkSchedule,
                              term_link: np.ndarray, updated: np.ndarray, trial: int,
                              end: int) -> np.ndarray:
    """r_ij[k] of one trial per consensus term, shape (K+1, E), int32.

    Column e is the term of ``term_link[e]`` (a schedule link, -1: none): the lag
    k - 1 - s of the message the receiver used at update step k (-1: nothing used,
    its own prediction stood in; :data:`netsim.kernel.NOT_USED` at steps without an
    update or after ``end``). The kernel's (K+1, N, N) record holds the same numbers
    at (k, i, j); this form has no N x N array.
    """
    K1 = selection.chosen.shape[0]
    E = len(term_link)
    out = np.full((K1, E), NOT_USED, dtype=np.int32)
    steps = np.asarray(updated[updated <= end])
    if not E or not steps.size:
        return out
    linked = term_link >= 0
    held = np.full((len(steps), E), -1, dtype=np.int64)
    held[:, linked] = selection.chosen[steps][:, term_link[linked], trial]
    sent = schedule.send_steps[np.maximum(held, 0)]
    r = np.where(held >= 0, steps[:, None] - 1 - sent, -1)
    r[steps == 0] = -1
    out[steps] = r
    return out


def _effective_delays(selection: MessageSelection, schedule: LinkSchedule,
                      scenario: Scenario, updated: np.ndarray, trial: int, end: int
                      ) -> np.ndarray:
    """r_ij[k] of one trial as the kernel records it, shape (K+1, N, N) (from the
    per-link record :func:`effective_delays_per_link`)."""
    term_i, term_j, _, term_link, _ = _consensus_terms(scenario, schedule)
    per_link = effective_delays_per_link(selection, schedule, term_link, updated, trial, end)
    N = scenario.n_agents
    out = np.full((per_link.shape[0], N, N), NOT_USED, dtype=np.int32)
    out[:, term_i, term_j] = per_link
    return out


def run_batch(
    scenario: Scenario,
    family: str,
    gains: GainDesign | None,
    trial_seeds: Sequence[SeedLike],
    steps: int | None = None,
    *,
    record_delays: bool | Collection[int] = False,
    record_estimates: bool = True,
    progress: Callable[[int], None] | None = None,
) -> VectorisedBatch:
    """Run a batch of trials of one estimator family in lockstep.

    Parameters
    ----------
    scenario : Scenario
    family : str
        A registered family whose batched form is this engine's lockstep (its
        ``batched_options`` give the rule, :class:`LockstepRule`).
    gains : GainDesign or None
        Innovation gains L_i (unused by the centralised filter).
    trial_seeds : sequence of seed-like, length T
        Trial t's seed, as :func:`netsim.runner.run_trial` takes it.
    steps : int, optional
        Last step K (default: the scenario's).
    record_delays : bool or collection of int
        Fill ``TrialResult.effective_delays`` (K+1, N, N) of every trial (True) or of
        the listed trials.
    record_estimates : bool
        Fill ``TrialResult.estimates`` (K+1, N, n); otherwise it has shape (0, N, n).
    progress : callable(int), optional
        Called with T once the batch is done.

    Returns
    -------
    VectorisedBatch
        ``results``: one TrialResult per trial, as the event kernel returns it
        (``messages`` is empty); and the link schedule and message selection the run
        used (None for the centralised filter).
    """
    rule = lockstep_rule(family)
    K = scenario.steps if steps is None else int(steps)
    T = len(trial_seeds)
    budget.check_memory(
        budget.vectorised_batch_bytes(scenario, K, T, record_estimates=record_estimates),
        "steps", f"a lockstep batch of {T} trial(s)", K)
    plant = scenario.plant
    batch = simulate_plant(scenario, trial_seeds, K)
    schedule = selection = None
    if rule.kind == "kalman":
        outputs = _kalman_run(scenario, batch, K, record_estimates)
        updated = np.arange(K + 1)
        N = 1
    else:
        if gains is None:
            raise ValueError(f"estimator family {family!r} needs gains")
        period = scenario.delay_bound + 1 if rule.block else 1
        schedule = build_schedule([scenario.delay_model(s) for s in trial_seeds],
                                  scenario.links, np.arange(0, K + 1, period),
                                  sample_period=scenario.sample_period)
        selection = select_messages(schedule, K, timestamps=rule.timestamps)
        outputs, updated = _consensus_run(scenario, rule, gains, batch, schedule,
                                          selection, K, record_estimates)
        N = scenario.n_agents
    n = plant.n_states
    wanted = set(range(T)) if record_delays is True else set(record_delays or ())
    ends = np.where(outputs.diverged_at >= 0, outputs.diverged_at, K)
    if schedule is not None:
        all_counts = schedule.counts(ends)
        all_discarded = selection.discarded_by(schedule, ends)
    results = []
    for t in range(T):
        end = int(ends[t])
        states = batch.states[:, t].copy()
        states[end + 1:] = np.nan
        measurements = []
        for i in range(len(batch.offsets) - 1):
            y = batch.measurements[:, t, batch.offsets[i]:batch.offsets[i + 1]].copy()
            y[end + 1:] = np.nan
            measurements.append(y)
        estimates = (outputs.estimates[:, t] if outputs.estimates is not None
                     else np.zeros((0, N, n)))
        counts: dict[str, Any] = {"sent": 0, "delivered": 0, "dropped": 0, "drop_reasons": {}}
        discarded = 0
        delays = None
        if schedule is not None:
            counts = all_counts[t]
            discarded = int(all_discarded[t])
            if t in wanted:
                delays = _effective_delays(selection, schedule, scenario, updated, t, end)
        elif t in wanted:
            delays = np.full((K + 1, N, N), NOT_USED, dtype=np.int32)
        results.append(TrialResult(
            states=states,
            measurements=measurements,
            estimates=estimates,
            squared_errors=outputs.sq[:, t],
            effective_delays=delays,
            diverged_at=end if outputs.diverged_at[t] >= 0 else None,
            messages_sent=counts["sent"],
            messages_delivered=counts["delivered"],
            messages_discarded=discarded,
            messages_dropped=counts["dropped"],
            drop_reasons=counts["drop_reasons"],
        ))
    if progress is not None:
        progress(T)
    return VectorisedBatch(results, schedule, selection, updated,
                           scenario.delay_bound + 1 if rule.block else 1)


def run_vectorised(
    scenario: Scenario,
    family: str,
    gains: GainDesign | None,
    trial_seeds: Sequence[SeedLike],
    steps: int | None = None,
    *,
    record_delays: bool | Collection[int] = False,
    record_estimates: bool = True,
    progress: Callable[[int], None] | None = None,
) -> list[TrialResult]:
    """Run trials in lockstep; one TrialResult per trial (see :func:`run_batch`).

    Trials are run in batches whose link-schedule arrays (trials x links x steps) hold
    at most :data:`BATCH_ELEMENTS` entries, so memory stays bounded however many
    trials are asked for; ``progress`` is called after each batch. The split depends
    only on the number of trials, links and steps, so the same request always gives
    the same numbers.
    """
    K = scenario.steps if steps is None else int(steps)
    per = max(1, BATCH_ELEMENTS // (max(1, len(scenario.links)) * (K + 2)))
    results: list[TrialResult] = []
    for start in range(0, len(trial_seeds), per):
        stop = min(start + per, len(trial_seeds))
        wanted: bool | set[int] = record_delays if isinstance(record_delays, bool) else {
            t - start for t in record_delays if start <= t < stop}
        results += run_batch(scenario, family, gains, trial_seeds[start:stop], K,
                             record_delays=wanted, record_estimates=record_estimates,
                             progress=progress).results
    return results
