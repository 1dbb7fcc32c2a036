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

Past estimates are kept in a ring as deep as the largest lag k - s any receiver uses
(known from the schedule), already multiplied by the powers of A they will need (see
:func:`_consensus_run`), so the neighbour sum of LCSYS2022 eq. (4) is one gather and
one sparse product per step, whatever the delays; squared errors and the divergence
test are computed a chunk of steps at a time. With one delay on every link the
estimates are held state-major, (n, N, T), and every operation of a step is one call
over rows of N T (or T) numbers (:func:`_state_major_run`).

That numpy step is the default and the reference (the same seed gives the same
numbers, bit for bit). ``NETSIM_NUMBA=1`` or ``kernel="numba"`` runs the consensus
step compiled instead (:mod:`netsim.lockstep_numba`, the optional extra
``netsim[numba]``; :func:`choose_kernel`): the same recursion with the additions
grouped per lag, equal to the numpy step's to round-off.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from netsim import budget, interrupt
from netsim.estimators.gains import GainDesign
from netsim.linkschedule import (
    DELIVERED,
    LinkSchedule,
    MessageSelection,
    build_schedule,
    select_messages,
)
from netsim.models.scenario import Scenario
from netsim.models.seeding import SeedLike, stream

if TYPE_CHECKING:  # scipy.sparse loads when a run needs it
    import scipy.sparse as sp

    from netsim.trialresult import TrialResult

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
    "KERNEL_ENV",
    "choose_kernel",
    "numba_available",
]

#: Largest trials x links x (steps + 2) of one lockstep batch (the budget's
#: :data:`netsim.budget.BATCH_ELEMENTS`, where it is explained).
BATCH_ELEMENTS = budget.BATCH_ELEMENTS


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
    # trial-major: each trial's draws land in place, read by the plant as (K+1, T, n+M)
    noise = np.empty((len(trial_seeds), int(steps) + 1, plant.noise_width))
    for t, seed in enumerate(trial_seeds):
        plant.standard_noise(stream(seed, "plant"), int(steps), out=noise[t])
    trajectory = plant.simulate(noise.transpose(1, 0, 2))
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
                 record_estimates: bool, filled: bool = True) -> None:
        self.K = K
        # (not filled: the caller writes every step's errors or fills NaN itself)
        self.sq = np.full((K + 1, T, N), np.nan) if filled else np.empty((K + 1, T, N))
        self.estimates = np.full((K + 1, T, N, n), np.nan) if record_estimates else None
        self.diverged_at = np.full(T, -1, dtype=np.int64)
        self.alive = np.ones(T, dtype=bool)
        self.all_alive = True
        from netsim.trialresult import squared_threshold

        self.threshold_sq = squared_threshold(threshold)
        self._scratch: np.ndarray | None = None  # record_many's errors
        self._ones = np.ones(n)

    def record_many(self, k0: int, estimates: np.ndarray, states: np.ndarray) -> bool:
        """Record steps k0, k0 + 1, ... (estimates (c, N, T, n), states (c, T, n)).

        The same as :meth:`record` step by step; False when all trials have diverged
        (the steps after that are not recorded).
        """
        if self.all_alive:
            c = len(estimates)
            if self._scratch is None or len(self._scratch) < c or \
                    self._scratch.shape[1:] != estimates.shape[1:]:
                self._scratch = np.empty_like(estimates)
            # ||x^i_k - x_k||^2: squares summed by one product with a vector of ones,
            # written straight into the (K+1, T, N) record
            err = np.subtract(estimates, states[:, None], out=self._scratch[:c])
            np.square(err, out=err)
            sq = self.sq[k0:k0 + c]
            np.matmul(err, self._ones, out=sq.transpose(0, 2, 1))
            worst = sq.max(initial=0.0)
            if worst <= self.threshold_sq and worst < np.inf:
                # every error of the chunk finite and within the threshold
                if self.estimates is not None:
                    self.estimates[k0:k0 + c] = estimates.transpose(0, 2, 1, 3)
                return True
            sq[...] = np.nan  # recorded again step by step below
        for c in range(len(estimates)):
            if not self.record(k0 + c, estimates[c], states[c]):
                return False
        return True

    def record_chunk(self, k0: int, sums: np.ndarray, estimates: np.ndarray | None,
                     states: np.ndarray) -> bool:
        """Record steps k0, k0 + 1, ... from their squared errors ``sums`` (c, N, T) and
        (when recorded) estimates held state-major, (c, n, N, T); ``states`` (c, n, T).

        The same as :meth:`record_errors` step by step; False when all trials have
        diverged (the steps after that are not recorded).
        """
        c = len(sums)
        if self.all_alive:
            sq = self.sq[k0:k0 + c]
            np.copyto(sq, sums.transpose(0, 2, 1))
            worst = sq.max(initial=0.0)
            if worst <= self.threshold_sq and worst < np.inf:
                if self.estimates is not None and estimates is not None:
                    self.estimates[k0:k0 + c] = estimates.transpose(0, 3, 2, 1)
                return True
            sq[...] = np.nan  # recorded again step by step below
        for q in range(c):
            if not self.record_errors(
                    k0 + q, sums[q].T,
                    None if estimates is None else estimates[q].transpose(2, 1, 0),
                    states[q].T):
                return False
        return True

    def record(self, k: int, estimates: np.ndarray, state: np.ndarray) -> bool:
        """Record step k (estimates (N, T, n), state (T, n)); False when all diverged."""
        err = estimates - state[None]
        sq = np.einsum("itj,itj->ti", err, err)
        return self.record_errors(k, sq, estimates.transpose(1, 0, 2), state)

    def record_errors(self, k: int, sq: np.ndarray, estimates: np.ndarray | None,
                      state: np.ndarray) -> bool:
        """Record step k from its squared errors sq (T, N) and estimates (T, N, n)
        (may be None when they are not recorded); False when all diverged."""
        from netsim.trialresult import ROUNDOFF_RELATIVE_ERROR

        alive = self.alive
        if self.all_alive:
            self.sq[k] = sq
            if self.estimates is not None:
                self.estimates[k] = cast(np.ndarray, estimates)
            # every error finite and within the threshold (NaN fails the comparisons):
            # no trial diverges at k, whatever the round-off floor
            worst = sq.max(initial=0.0)
            if worst <= self.threshold_sq and worst < np.inf:
                return True
        else:
            self.sq[k, alive] = sq[alive]
            if self.estimates is not None:
                self.estimates[k, alive] = cast(np.ndarray, estimates)[alive]
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
    offsets = np.asarray(batch.offsets)
    if m == 1 and np.array_equal(offsets, np.arange(len(offsets))):
        # one output per agent: a view of the stacked measurements
        return batch.measurements.transpose(0, 2, 1)[..., None]
    # column of output r of agent i in the stacked measurements, or a zero column
    column = offsets[:-1, None] + np.arange(m)[None, :]  # (N, m)
    padded = np.arange(m)[None, :] >= np.diff(offsets)[:, None]
    stacked = np.concatenate([batch.measurements, np.zeros((K1, T, 1))], axis=2)
    column = np.where(padded, stacked.shape[2] - 1, column)
    return np.ascontiguousarray(stacked[:, :, column].transpose(0, 2, 1, 3))


def _powers(A: np.ndarray, count: int) -> np.ndarray:
    """A^0 .. A^count, shape (count+1, n, n), by the estimators' recursion A @ A^(r-1)."""
    out = [np.eye(A.shape[0]), A]
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is a divergence
        while len(out) <= count:
            out.append(A @ out[-1])
    return np.stack(out[: count + 1])


@dataclass(frozen=True)
class _Terms:
    """The consensus terms of LCSYS2022 eq. (4): every (i, j) with p_ij > 0, j != i.

    Attributes
    ----------
    i, j : numpy.ndarray, shape (E,), int
        Receiver i and sender j, in row order of P.
    weight : numpy.ndarray, shape (E,), float
        p_ij.
    link : numpy.ndarray, shape (E,), int
        Index of link (j, i) in the schedule's links, -1 when there is none.
    diagonal : numpy.ndarray, shape (N,), float
        The self weights p_ii.
    """

    i: np.ndarray
    j: np.ndarray
    weight: np.ndarray
    link: np.ndarray
    diagonal: np.ndarray

    def __iter__(self):
        return iter((self.i, self.j, self.weight, self.link, self.diagonal))


def _link_positions(schedule_links: Sequence[tuple[int, int]], scenario: Scenario,
                    src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Index into ``schedule_links`` of each link (src[e], dst[e]), -1 if absent, shape (E,).

    The schedule's links are normally the scenario's (its :attr:`Scenario.link_table`,
    sorted by sender then receiver): then a counting sort through a CSR matrix, no
    dictionary and no N x N array.
    """
    N = scenario.n_agents
    table = scenario.link_table
    same_links = len(schedule_links) == len(table) and (
        schedule_links is scenario.links or list(schedule_links) == scenario.links)
    if same_links and not _use_scipy(scenario):
        keys = table.src * N + table.dst  # the search below: the same positions
    elif same_links:
        import scipy.sparse as sp

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


def _consensus_terms(scenario: Scenario, schedule: LinkSchedule) -> _Terms:
    """The terms of eq. (4) and their links, from the sparse weights and the schedule.

    Parameters
    ----------
    scenario : Scenario
        Its :attr:`Scenario.weights_sparse` (CSR, never an N x N array).
    schedule : LinkSchedule
        Its links (sender, receiver), length L.

    Returns
    -------
    _Terms
        The one place the engine looks at the network: every (i, j) with p_ij > 0,
        j != i, in row order (the order of the neighbour sums), and the self weights
        p_ii; everything per link after this is an array of shape (E,), (L,) or (N,).
        Unpacks as ``(i, j, weight, link, diagonal)``.
    """
    if not _use_scipy(scenario):
        # the nonzeros of the dense P in row-major order: the entries, and the order, of
        # its canonical CSR form (no scipy.sparse; :func:`_use_scipy`)
        dense = scenario.dense_weights()
        rows, cols = (a.astype(np.int64) for a in np.nonzero(dense))
        vals = dense[rows, cols]
        diagonal = np.diagonal(dense).astype(float)
    else:
        W = scenario.weights_sparse
        N = W.shape[0]
        rows = np.repeat(np.arange(N, dtype=np.int64), np.diff(W.indptr))
        cols = W.indices.astype(np.int64)
        vals = W.data
        diagonal = np.asarray(W.diagonal(), dtype=float)
    keep = (rows != cols) & (vals != 0)
    term_i, term_j, term_w = rows[keep], cols[keep], vals[keep]
    link = _link_positions(schedule.links, scenario, term_j, term_i)
    return _Terms(term_i, term_j, term_w, link, diagonal)


#: Above this many multiply-adds of the consensus products in a run (stored entries x
#: trials x n x steps), the lockstep step uses scipy's CSR kernel; at or below it, the
#: same products by :func:`_csr_product_into` with numpy alone, so that a small run
#: does not import scipy.sparse (about 0.17 s of CPU, as much as numpy and scipy
#: together: start-up, issue 34). Both give the same bits.
NUMPY_PRODUCT_MAX_WORK = 4_000_000


def _use_scipy(scenario: Scenario, trials: int | None = None,
               steps: int | None = None) -> bool:
    """Whether the consensus products go through scipy.sparse (see
    :data:`NUMPY_PRODUCT_MAX_WORK`): sparse weights always; dense ones when the run's
    products are large. A count, not a measurement, so a run always takes the same path."""
    from netsim.models.lazy import issparse

    if issparse(scenario.weights):
        return True
    N = scenario.n_agents
    weights = np.asarray(scenario.weights)
    # the pair/aggregate products hold each nonzero of P once, plus N own entries
    stored = int(np.count_nonzero(weights)) + N
    T = 1 if trials is None else int(trials)
    K = scenario.steps if steps is None else int(steps)
    return stored * T * scenario.plant.n_states * (K + 1) > NUMPY_PRODUCT_MAX_WORK


#: Above this many multiply-adds of the consensus products in a run (the count of
#: :data:`NUMPY_PRODUCT_MAX_WORK`), the step with one delay on every link runs
#: state-major (:func:`_state_major_run`: fewer, wider calls, which pay on large
#: arrays); at or below it, and always for the block rule, agent-major (a few BLAS
#: products on short arrays, faster there: 19 ms against 45 ms at N = 4, 100 x 200).
#: A count of its own, so that the choice of scipy or numpy products never changes the
#: step (``tests/test_startup_numpy_paths.py``).
STATE_MAJOR_MIN_WORK = 4_000_000


def _state_major(scenario: Scenario, trials: int, steps: int) -> bool:
    """Whether a run with one delay on every link takes :func:`_state_major_run` (see
    :data:`STATE_MAJOR_MIN_WORK`).

    Sparse weights (the large networks) never do: on ``examples/geometric-100k.toml``
    (100,000 agents, 1 trial) the state-major step took 17.3-17.5 s wall and 1.68 GB
    against 11.7-13.1 s and 0.81 GB for the agent-major one (``/usr/bin/time netsim
    run``, alternated twice, issue 34)."""
    from netsim.models.lazy import issparse

    if issparse(scenario.weights):
        return False
    stored = int(np.count_nonzero(np.asarray(scenario.weights))) + scenario.n_agents
    return stored * int(trials) * scenario.plant.n_states * (int(steps) + 1) \
        > STATE_MAJOR_MIN_WORK


def _csr_parts(data: np.ndarray, rows: np.ndarray, cols: np.ndarray, n_rows: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(indptr, indices, data)`` of the CSR matrix with these (distinct) entries, rows
    in order and columns sorted within each row: scipy's canonical form, with numpy."""
    order = np.lexsort((cols, rows))
    indptr = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n_rows), out=indptr[1:])
    return indptr, np.asarray(cols, dtype=np.int64)[order], np.asarray(data, float)[order]


def _csr_row_sums(indptr: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Row sums of a CSR matrix, shape (rows,), as scipy's ``csr.sum(axis=1)`` forms them
    (``np.add.reduceat`` over the rows that hold entries; the same bits)."""
    sums = np.zeros(len(indptr) - 1)
    major = np.flatnonzero(np.diff(indptr))
    if len(major):
        sums[major] = np.add.reduceat(data, indptr[major])
    return sums


def _csr_product_into(parts: tuple[np.ndarray, np.ndarray, np.ndarray], out: np.ndarray
                      ) -> Callable[[np.ndarray], np.ndarray]:
    """``product(x)`` writes the CSR matrix ``parts`` times x into ``out`` with numpy.

    The same additions in the same order as scipy's ``csr_matvecs`` (row i: 0, then
    ``+= data * x[col]`` for each of its entries in order), so the same bits, one pass
    per entry position within a row: pass p adds the p-th entry of every row that has
    one (a gather, a product and a sum over ``out``'s rows).
    """
    indptr, indices, data = parts
    counts = np.diff(indptr)
    width = out.shape[1]
    passes = []
    for p in range(int(counts.max()) if len(counts) else 0):
        has = np.flatnonzero(counts > p)
        at = indptr[has] + p
        rows = None if len(has) == len(counts) else has  # every row: no scatter
        passes.append((rows, indices[at], data[at][:, None], np.empty((len(has), width))))

    def product(x: np.ndarray) -> np.ndarray:
        out.fill(0.0)
        for rows, cols, weights, term in passes:
            np.take(x, cols, axis=0, out=term)
            np.multiply(weights, term, out=term)
            if rows is None:
                np.add(out, term, out=out)
            else:
                out[rows] += term
        return out
    return product


def _sparse_product_into(matrix: sp.csr_matrix, out: np.ndarray
                         ) -> Callable[[np.ndarray], np.ndarray]:
    """``product(x)`` writes matrix @ x into ``out`` (2-D, C-contiguous) and returns it.

    scipy's own kernel for CSR times dense (``csr_matvecs``, the one ``matrix @ x``
    runs: the same additions in the same order, bit for bit), called directly into a
    preallocated output, so a step allocates nothing; through ``@`` and a copy when
    that private kernel is not there.
    """
    rows, cols = matrix.shape
    indptr, indices, data = matrix.indptr, matrix.indices, matrix.data
    csr_matvecs: Callable[..., None] | None
    try:
        from scipy.sparse._sparsetools import csr_matvecs
    except ImportError:  # pragma: no cover - other scipy layouts
        csr_matvecs = None
    flat = out.reshape(-1)
    if csr_matvecs is None or not out.flags.c_contiguous \
            or indptr.dtype != indices.dtype or data.dtype != np.float64:
        def product(x: np.ndarray) -> np.ndarray:
            np.copyto(out, matrix @ x)
            return out
        return product
    vectors = out.shape[1]

    def product_direct(x: np.ndarray) -> np.ndarray:
        flat.fill(0.0)  # the kernel adds into its output
        csr_matvecs(rows, cols, vectors, indptr, indices, data, x.reshape(-1), flat)
        return out
    return product_direct


#: Environment variable choosing the lockstep step's implementation when ``run_batch``
#: is not told: ``numba`` (or ``1``) for the compiled step (:mod:`netsim.lockstep_numba`,
#: needs the optional extra ``netsim[numba]``), anything else the numpy step.
KERNEL_ENV = "NETSIM_NUMBA"


def numba_available() -> bool:
    """Whether numba can be imported (``pip install netsim[numba]``), without importing it."""
    import importlib.util

    return importlib.util.find_spec("numba") is not None


def choose_kernel(kernel: str | None = None) -> str:
    """The lockstep step to run: ``"numpy"`` (the reference) or ``"numba"``.

    Parameters
    ----------
    kernel : {"numpy", "numba"} or None
        None: ``numba`` when ``NETSIM_NUMBA`` is ``1`` or ``numba``, else ``numpy``;
        inside a sweep's task, the client's setting, which the task carries
        (:mod:`netsim.taskoptions`), not the worker's environment. The numpy step is
        the default because importing numba costs more CPU than importing numpy and
        scipy together (about 0.25 s here), which a short run would pay for nothing.

    Returns
    -------
    str
        ``"numba"`` only when numba is installed. ``kernel="numba"`` without it raises
        :class:`netsim.models.extras.MissingExtra` (naming ``pip install
        'netsim[numba]'``); ``NETSIM_NUMBA=1`` without it warns (RuntimeWarning) and
        the numpy step runs, the same numbers to round-off.
    """
    from netsim.taskoptions import getenv

    asked = kernel is not None
    if kernel is None:
        # the task's value first (a sweep's task carries the client's choice, set or
        # not: :data:`netsim.taskoptions.CHOICES`), else this process' environment
        kernel = ("numba" if (getenv(KERNEL_ENV) or "").strip().lower()
                  in ("1", "numba", "yes", "on", "true") else "numpy")
    if kernel not in ("numpy", "numba"):
        raise ValueError(f"kernel must be 'numpy' or 'numba', got {kernel!r}")
    if kernel == "numba" and not numba_available():
        from netsim.models.extras import missing

        if asked:
            raise missing("numba", "numba", "the vectorised engine's compiled step")
        import warnings

        warnings.warn(f"{KERNEL_ENV}=1 asks for the compiled step but numba is not "
                      "installed (pip install 'netsim[numba]'); running the numpy step",
                      RuntimeWarning, stacklevel=3)
        return "numpy"
    return kernel


def _consensus_run_numba(scenario: Scenario, rule: LockstepRule, gains: GainDesign,
                         batch: PlantBatch, selection: MessageSelection, send: np.ndarray,
                         terms: _Terms, steps: int, record_estimates: bool
                         ) -> tuple[_Outputs, np.ndarray]:
    """:func:`_consensus_run` by the compiled step (:mod:`netsim.lockstep_numba`).

    The same recursion (LCSYS2022 eqs. 4-5; delay-tolerant eqs. 6-7), the same
    message selection and the same recording and divergence rule; the estimates are
    kept agent-major with the trials innermost, (N, n, T), and the terms of each
    receiver are summed per lag before A^lag is applied, so the numbers agree with
    the numpy step to round-off. Not for the block rule.
    """
    from netsim.lockstep_numba import consensus_chunk

    plant = scenario.plant
    n = plant.n_states
    K = int(steps)
    T = batch.states.shape[1]
    N = scenario.n_agents
    Cp, Lp = _pad_outputs(scenario, gains)
    Cp = np.ascontiguousarray(Cp, dtype=float)
    Lp = np.ascontiguousarray(Lp, dtype=float)
    oldest = max(1, min(selection.max_lag, K))  # the largest k - s of a message used
    R = oldest if rule.compensate else 1  # powers A^r applied (eq. 6: A only)
    powers = np.ascontiguousarray(_powers(plant.A, R), dtype=float)
    depth = oldest + 1  # step k's slot is never one that step k reads
    ring = np.zeros((depth, N, n, T))
    term_ptr = np.zeros(N + 1, dtype=np.int64)
    np.cumsum(np.bincount(terms.i, minlength=N), out=term_ptr[1:])
    uniform = selection.uniform_delay
    chosen = (np.zeros((1, 1, 1), dtype=np.int32) if uniform is not None
              else np.ascontiguousarray(selection.chosen, dtype=np.int32))
    offsets = np.asarray(batch.offsets, dtype=np.int64)
    meas = np.ascontiguousarray(batch.measurements, dtype=float)
    # (K+1, n, T) flat: the trials innermost
    states = np.ascontiguousarray(batch.states.transpose(0, 2, 1), dtype=float).reshape(-1)
    # the errors' record is filled with NaN only from the first chunk with a divergence
    # on, or after the last step run (the chunks before write every entry)
    outputs = _Outputs(K, N, T, n, scenario.divergence_threshold, record_estimates,
                       filled=False)
    filled = False
    chunk_steps = max(1, min(64, 200_000 // max(1, N * T)))
    sq_chunk = np.empty((chunk_steps, T, N))
    est_chunk = np.empty((chunk_steps, T, N, n) if record_estimates else (1, 1, 1, 1))
    acc = np.zeros((R + 1) * n * T)  # per lag, (n, T) flat
    prior = np.empty(n * T)
    res = np.empty((Cp.shape[1] + 1) * T)  # the residuals and the squared errors
    ystep = np.empty(meas.shape[2] * T)  # one step's measurements, trials innermost
    args = (ring, ring.reshape(-1), powers,
            np.ascontiguousarray(terms.diagonal, dtype=float), term_ptr,
            terms.j.astype(np.int64), np.ascontiguousarray(terms.weight, dtype=float),
            terms.link.astype(np.int64), chosen, np.asarray(send, dtype=np.int64),
            -1 if uniform is None else int(uniform), bool(rule.compensate),
            np.ascontiguousarray(plant.x0_mean, dtype=float), meas, offsets[:-1].copy(),
            np.diff(offsets), Cp, Lp, states)
    last = -1
    with np.errstate(all="ignore"):
        for k0 in range(0, K + 1, chunk_steps):
            interrupt.check()  # a requested Ctrl-C stops here, between chunks
            k1 = min(k0 + chunk_steps, K + 1)
            c = k1 - k0
            direct = outputs.all_alive  # written straight into the record
            sq_out = outputs.sq[k0:k1] if direct else sq_chunk
            est_out = (outputs.estimates[k0:k1] if direct and outputs.estimates is not None
                       else est_chunk)
            consensus_chunk(k0, k1, *args, sq_out, est_out, record_estimates, acc, prior, res,
                            ystep)
            last = k1 - 1
            worst = float(sq_out[:c].max(initial=0.0))  # NaN when any error is NaN
            if direct and worst <= outputs.threshold_sq and worst < np.inf:
                continue  # every error of the chunk finite and within the threshold
            if direct:  # recorded again step by step below, with the divergence rule
                sq_chunk[:c] = sq_out
                sq_out[...] = np.nan
                if outputs.estimates is not None:
                    est_chunk[:c] = est_out
                    est_out[...] = np.nan
            if not filled:  # (a chunk not written directly comes after this one)
                outputs.sq[k1:] = np.nan
                filled = True
            alive = True
            for k in range(k0, k1):
                alive = outputs.record_errors(
                    k, sq_chunk[k - k0],
                    est_chunk[k - k0] if record_estimates else None, batch.states[k])
                if not alive:
                    break
            if not alive:
                break
    if not filled:
        outputs.sq[last + 1:] = np.nan
    return outputs, np.arange(last + 1)


def _sparse_into(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, columns: int,
                 out: np.ndarray, use_scipy: bool) -> Callable[[np.ndarray], np.ndarray]:
    """``product(x)`` writes the CSR matrix ``(data, indices, indptr)`` times x into
    ``out`` (2-D), its entries summed in the order given (scipy's kernel, or the same
    sums with numpy: the same bits)."""
    if use_scipy:
        import scipy.sparse as sp

        matrix = sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, columns))
        return _sparse_product_into(matrix, out)
    return _csr_product_into((indptr, indices, data), out)


def _state_major_run(scenario: Scenario, rule: LockstepRule, batch: PlantBatch,
                     terms: _Terms, Cp: np.ndarray, Lp: np.ndarray, d: int, steps: int,
                     record_estimates: bool, use_scipy: bool) -> tuple[_Outputs, np.ndarray]:
    """:func:`_consensus_run` with one constant delay d on every link, a message every
    step (not the block rule), the estimates held state-major, (n, N, T).

    LCSYS2022 eq. (4) with one delay d,

        x^i_{k|k-1} = p_ii A x^i_{k-1} + sum_j p_ij A^(d+1) x^j_{k-1-d}

    (eq. 6: A in place of A^(d+1); before step d + 1 nothing has arrived and agent
    i's own prediction stands in with the whole row's weight, DESIGN.md), then eq. (5),
    x^i_{k|k} = x^i_{k|k-1} + L_i (y^i_k - C_i x^i_{k|k-1}). Every array is a stack of
    rows of N T (or T) numbers, so each operation is one call over all agents and
    trials:

    * each estimate x(s) is multiplied once, when it is stored, by A^(d+1) into ring
      slot s (a dense product, or a sparse one over the nonzero entries when at most
      half of them are nonzero), and by A into the own slot, unless A is at most
      half nonzero: then the own slot holds x(s) itself;
    * the prior is one sparse product over the whole ring, by the matrix of the
      step's ring position: row (a, i) holds p_ij at component a of A^(d+1) x^j in
      slot k-1-d (j in order), then p_ii at component a of A x^i(k-1) (or p_ii A[a, b]
      at component b of x^i(k-1), b in order);
    * C_i x^i_{k|k-1} is one sparse product over the nonzero entries of the C_i;
      the squared errors are whole-array operations a chunk of steps at a time.
    """
    plant = scenario.plant
    A = plant.A
    n = plant.n_states
    K = int(steps)
    T = batch.states.shape[1]
    N = scenario.n_agents
    E = len(terms.i)
    lag = min(d + 1, K) if rule.compensate else 1
    far = _powers(A, lag)[lag] if lag > 1 else A
    depth = min(d, K) + 1  # slot k - 1 - d is slot k: read before step k writes it
    # slots 0 .. depth-1: A^(d+1) x(s) at slot s % depth; slot depth: A x(k-1)
    ring = np.zeros((depth + 1, n, N, T))
    ring_rows = ring.reshape(-1, T)
    m = Cp.shape[1]
    prior = np.empty((n, N, T))
    prior_rows = prior.reshape(n * N, T)
    innovation_rows = np.empty((m * N, T))

    def product_by(matrix: np.ndarray, out: np.ndarray) -> Callable[[np.ndarray], Any]:
        # matrix (n x n) @ x (n x N T) into out: dense, or over the nonzero entries
        # when at most half are nonzero (A's structural zeros)
        nonzero = matrix != 0
        if 2 * int(nonzero.sum()) > matrix.size:
            return lambda x: np.matmul(matrix, x, out=out)
        r_, c_ = np.nonzero(nonzero)
        ptr = np.zeros(len(matrix) + 1, dtype=np.int64)
        np.cumsum(np.bincount(r_, minlength=len(matrix)), out=ptr[1:])
        return _sparse_into(ptr, c_.astype(np.int64), matrix[r_, c_], matrix.shape[1], out,
                            use_scipy)

    far_into = [product_by(far, ring[q].reshape(n, N * T)) for q in range(depth)]
    # the own prediction p_ii A x^i(k-1): with A at most half nonzero, slot depth is
    # x(k-1) itself (the step's estimates are written there) and the prior's rows
    # carry p_ii A[a, b], one product fewer a step; otherwise slot depth holds A x(k-1)
    fold = 2 * int(np.count_nonzero(A)) <= A.size
    x_prev = ring[depth]
    near_into = product_by(A, (prior if fold else x_prev).reshape(n, N * T))

    # the prior: the sparse matrix of each ring position q = k % depth (steps k > d),
    # row (a, i): the terms of receiver i (senders in order), then its own entries
    # (b in order when folded)
    own_a, own_b = np.nonzero(A) if fold else (np.arange(n), np.arange(n))
    own_w = A[own_a, own_b] if fold else np.ones(n)
    P_own = len(own_a)
    ent_a = np.r_[np.repeat(np.arange(n), E), np.repeat(own_a, N)]
    ent_i = np.r_[np.tile(terms.i, n), np.tile(np.arange(N), P_own)]
    ent_own = np.r_[np.zeros(n * E, dtype=bool), np.ones(N * P_own, dtype=bool)]
    ent_pos = np.r_[np.tile(np.arange(E), n), np.repeat(own_b, N)]
    ent_sender = np.r_[np.tile(terms.j, n), np.tile(np.arange(N), P_own)]
    ent_comp = np.r_[np.repeat(np.arange(n), E), np.repeat(own_b, N)]
    ent_w = np.r_[np.tile(terms.weight, n),
                  np.repeat(own_w, N) * np.tile(terms.diagonal, P_own)]
    order = np.lexsort((ent_pos, ent_own, ent_i, ent_a))
    ent_own, data = ent_own[order], ent_w[order]
    local = (ent_comp * N + ent_sender)[order].astype(np.int64)
    indptr = np.zeros(n * N + 1, dtype=np.int64)
    np.cumsum(np.bincount((ent_a * N + ent_i)[order], minlength=n * N), out=indptr[1:])
    prior_at = []
    for q in range(depth if d < K else 0):
        base = np.where(ent_own, depth * n * N, (q - 1 - d) % depth * n * N)
        prior_at.append(_sparse_into(indptr, base + local, data, len(ring_rows),
                                     prior_rows, use_scipy))
    # before anything arrives: the whole row's weight on the own prediction
    if use_scipy:
        row_sum = np.asarray(scenario.weights_sparse.sum(axis=1)).reshape(N, 1)
    else:
        dense = scenario.dense_weights()
        nz_rows, nz_cols = np.nonzero(dense)
        row_sum = _csr_row_sums(_csr_parts(dense[nz_rows, nz_cols], nz_rows, nz_cols, N)[0],
                                dense[nz_rows, nz_cols]).reshape(N, 1)

    # eq. (5): row (o, i) of C x is sum_a C_i[o, a] x^i[a] (the nonzero entries)
    i_, o_, a_ = np.nonzero(Cp)
    c_order = np.lexsort((a_, i_, o_))
    i_, o_, a_ = i_[c_order], o_[c_order], a_[c_order]
    c_ptr = np.zeros(m * N + 1, dtype=np.int64)
    np.cumsum(np.bincount(o_ * N + i_, minlength=m * N), out=c_ptr[1:])
    output_of = _sparse_into(c_ptr, (a_ * N + i_).astype(np.int64), Cp[i_, o_, a_], n * N,
                             innovation_rows, use_scipy)
    innovation = innovation_rows.reshape(m, N, T)
    # L_i[:, o] repeated over the trials, (n, N, T): a product of whole rows (half the
    # time of broadcasting an (n, N, 1) column over rows of T)
    gain = [np.ascontiguousarray(np.broadcast_to(Lp[:, :, o].T[:, :, None], (n, N, T)))
            for o in range(m)]
    correction = np.empty((n, N, T) if m > 1 else (0, 0, 0))  # (several outputs)
    x = x_prev if fold else np.empty((n, N, T))
    errors = np.empty((n, N, T))
    Y = _agent_measurements(batch, m)  # (K+1, N, T, m)
    states = np.ascontiguousarray(batch.states.transpose(0, 2, 1))  # (K+1, n, T)
    x0 = np.broadcast_to(np.asarray(plant.x0_mean, dtype=float)[:, None, None], (n, N, T))
    outputs = _Outputs(K, N, T, n, scenario.divergence_threshold, record_estimates)
    # each step's squared errors are computed while its estimates are in cache, and
    # recorded (with the divergence test) a chunk of steps at a time; the estimates are
    # kept for the chunk only when they are recorded
    chunk_steps = max(1, min(32, 100_000 // max(1, N * T)))
    sums = np.empty((chunk_steps, N, T))
    kept = np.empty((chunk_steps, n, N, T)) if record_estimates else None
    chunk_start = 0
    last = K
    with np.errstate(all="ignore"):
        for k in range(K + 1):
            if k:
                interrupt.check()  # a requested Ctrl-C stops here, between steps
            if k == 0:
                np.copyto(prior, x0)
            elif k <= d:
                if fold:
                    near_into(x_prev.reshape(n, N * T))  # A x(k-1), into the prior
                np.multiply(row_sum, prior if fold else x_prev, out=prior)
            else:
                prior_at[k % depth](ring_rows)
            output_of(prior_rows)  # C_i x^i_{k|k-1}
            for o in range(m):
                # y - C_i x^i_{k|k-1}, then x = prior + sum_o L_i[:, o] (y - C_i prior)
                np.subtract(Y[k, :, :, o], innovation[o], out=innovation[o])
                if o == 0:
                    np.multiply(gain[0], innovation[0], out=x)
                else:
                    np.multiply(gain[o], innovation[o], out=correction)
                    x += correction
            x += prior
            np.subtract(x, states[k][:, None, :], out=errors)
            rows = x.reshape(n, N * T)
            far_into[k % depth](rows)
            if not fold:
                near_into(rows)
            # ||x^i_k - x_k||^2, the components summed in order
            np.square(errors, out=errors)
            np.add.reduce(errors, axis=0, out=sums[k - chunk_start])
            if kept is not None:
                np.copyto(kept[k - chunk_start], x)
            if k + 1 - chunk_start == chunk_steps or k == K:
                c = k + 1 - chunk_start
                if not outputs.record_chunk(chunk_start, sums[:c],
                                            None if kept is None else kept[:c],
                                            states[chunk_start:k + 1]):
                    last = k
                    break
                chunk_start = k + 1
    return outputs, np.arange(last + 1)


def _consensus_run(scenario: Scenario, rule: LockstepRule, gains: GainDesign,
                   batch: PlantBatch, schedule: LinkSchedule, selection: MessageSelection,
                   steps: int, record_estimates: bool, kernel: str = "numpy"
                   ) -> tuple[_Outputs, np.ndarray]:
    """Run a consensus family; returns the outputs and the steps with an update.

    Estimates are (N, T, n) arrays (agent, trial, state). The prior of LCSYS2022
    eq. (4),

        x^i_{k|k-1} = p_ii A x^i_{k-1|k-1} + sum_j p_ij A^(k - s_j) x^j_{s_j|s_j},

    (with agent i's own prediction standing in for a neighbour j from whom nothing
    has arrived yet, DESIGN.md) is one sparse product per step over a ring of past
    estimates that already carry their compensation, so no per-lag work remains:

    * one constant delay d on every link (``uniform``), a large run
      (:func:`_state_major`): :func:`_state_major_run`, the estimates state-major,
      (n, N, T); a small one: ring slot s keeps the pair A^(d+1) x(s), A x(s + d)
      (one product each when an estimate is computed), and the prior is one sparse
      (N x 2N) product [P - diag | diag(p_ii)] with the slot of s = k - 1 - d, i.e.
      p_ij A^(d+1) x^j(k-1-d) and p_ii A x^i(k-1);
    * otherwise: a ring Z of compensated estimates, Z[s] = A^(k - s) x(s), advanced
      by one product per step (Z <- A Z); the message each term holds is gathered
      from it (one ``take``) and summed by one sparse (N x (N + E)) product.

    The delay-tolerant rule (eq. 6, no compensation) applies A once to the sum; the
    block rule (eqs. 15-16) updates every tau+1 steps with A^(tau+1) on the own term
    and propagates with A^(k - block step) in between. Eq. (5),
    x^i_{k|k} = x^i_{k|k-1} + L_i (y^i_k - C_i x^i_{k|k-1}), is a stacked product.
    """
    plant = scenario.plant
    A = plant.A
    n = plant.n_states
    K = int(steps)
    T = batch.states.shape[1]
    N = scenario.n_agents
    use_scipy = _use_scipy(scenario, T, K)
    if use_scipy:
        import scipy.sparse as sp

    def product_into(data: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                     shape: tuple[int, int], out: np.ndarray, sort: bool
                     ) -> Callable[[np.ndarray], np.ndarray]:
        # the CSR matrix with these entries (canonical: rows in order, columns sorted)
        # times a dense block, by scipy's kernel or the same sums with numpy
        if not use_scipy:
            return _csr_product_into(_csr_parts(data, rows, cols, shape[0]), out)
        matrix = sp.csr_matrix((data, (rows, cols)), shape=shape)
        if sort:
            matrix.sort_indices()
        return _sparse_product_into(matrix, out)

    Cp, Lp = _pad_outputs(scenario, gains)
    terms = _consensus_terms(scenario, schedule)
    if kernel == "numba" and not rule.block:
        return _consensus_run_numba(scenario, rule, gains, batch, selection,
                                    schedule.send_steps, terms, steps, record_estimates)
    if (not rule.block and selection.uniform_delay is not None
            and not np.any(terms.link < 0) and _state_major(scenario, T, K)):
        return _state_major_run(scenario, rule, batch, terms, Cp, Lp,
                                selection.uniform_delay, K, record_estimates, use_scipy)
    Y = _agent_measurements(batch, Cp.shape[1])
    E = len(terms.i)
    own_weight = terms.diagonal.copy()
    block = rule.block
    period = scenario.delay_bound + 1 if block else 1
    send = schedule.send_steps
    # one constant delay d on every link, a message every step (see the docstring)
    uniform = (selection.uniform_delay if not block and not np.any(terms.link < 0)
               else None)
    # the delay horizon that can matter: a power A^r with r > K is never applied (a
    # message delayed past the last step never arrives; a block period beyond K only
    # propagates the step-0 estimate, with A^(k - 0), k <= K), so the rings stop
    # there however large the delays are
    horizon = max(1, min(max(selection.max_lag, period), K))
    A_T = np.ascontiguousarray(A.T)
    Cp_T = np.ascontiguousarray(Cp.transpose(0, 2, 1))  # (N, n, m)
    Lp_T = np.ascontiguousarray(Lp.transpose(0, 2, 1))  # (N, m, n)
    m_out = Lp_T.shape[1]
    # one output per agent (m = 1): L_i (y - C_i x) is one product per entry, here
    # against the gain repeated over the trials (the same numbers as the (T, 1) @
    # (1, n) matmul, at half its time). Folding eq. (5) into one stacked product
    # (I - L_i C_i) x + L_i y (fewer calls) measured slower in the run (session 7)
    gain_rows = (np.ascontiguousarray(np.broadcast_to(Lp_T, (N, T, n)))
                 if m_out == 1 else None)
    residual = np.empty((N, T, m_out))  # y - C_i x_{k|k-1} of one step
    # the matmul's output where the outputs are several (unused when m = 1)
    correction = np.empty((N, T, n) if m_out != 1 else (0, 0, 0))

    def innovate(prior: np.ndarray, k: int, out: np.ndarray) -> np.ndarray:
        # eq. (5): x_{k|k} = x_{k|k-1} + L_i (y - C_i x_{k|k-1}), per agent i as a
        # stacked product over the trials: (T, n) @ C_i^T, (T, m) @ L_i^T; into ``out``
        # (preallocated buffers: nothing is allocated)
        innovation = np.matmul(prior, Cp_T, out=residual)
        np.subtract(Y[k], innovation, out=innovation)
        if gain_rows is not None:
            np.multiply(innovation, gain_rows, out=out)
            out += prior
        else:
            np.matmul(innovation, Lp_T, out=correction)
            np.add(prior, correction, out=out)
        return out

    if uniform is not None:
        # eq. (4) with one delay d: prior(k) = p_ii A x^i(k-1) + sum_j p_ij A^(d+1)
        # x^j(k-1-d) (eq. 6: A x^j(k-1-d)). Ring slot s holds the pair
        # [A^(d+1) x(s) ; A x(s+d)] as one (2N, T n) block, so the prior is ONE
        # sparse product of [P minus its diagonal | diag(p_ii)] with slot k-1-d;
        # each x(k) costs two products into the ring when it is stored
        d = uniform
        depth = d + 1
        lag = min(d + 1, K) if rule.compensate else 1
        far_T = np.ascontiguousarray(_powers(A, lag)[lag].T) if lag > 1 else A_T
        ring = np.zeros((depth, 2, N, T, n))
        if use_scipy:
            row_sum3 = np.asarray(scenario.weights_sparse.sum(axis=1)).reshape(N, 1, 1)
        else:
            dense = scenario.dense_weights()
            nz_rows, nz_cols = np.nonzero(dense)
            row_sum3 = _csr_row_sums(
                _csr_parts(dense[nz_rows, nz_cols], nz_rows, nz_cols, N)[0],
                dense[nz_rows, nz_cols]).reshape(N, 1, 1)

        def store(k: int, estimate: np.ndarray) -> None:
            x = estimate.reshape(-1, n)
            np.matmul(x, far_T, out=ring[k % depth, 0].reshape(-1, n))
            np.matmul(x, A_T, out=ring[(k - d) % depth, 1].reshape(-1, n))

        prior_buffer = np.empty((N, T, n))
        # [P minus its diagonal | diag(p_ii)]: p_ij x^j summed in the order of j,
        # then p_ii A x^i
        pair_product = product_into(
            np.concatenate([terms.weight, own_weight]),
            np.concatenate([terms.i, np.arange(N)]),
            np.concatenate([terms.j, N + np.arange(N)]), (N, 2 * N),
            prior_buffer.reshape(N, T * n), sort=True)

        def prior_at(k: int) -> np.ndarray:
            slot = ring[(k - 1 - d) % depth]
            if k <= d:
                # nothing has arrived: the own prediction with the whole row's weight
                return np.multiply(row_sum3, slot[1], out=prior_buffer)
            pair_product(slot.reshape(2 * N, T * n))
            return prior_buffer
    else:
        # ring Z[s % depth]: eq. (4) A^(k - s) x(s) (advanced by A every step), or
        # x(s) itself for eq. (6); gathered per (term, trial), own term first
        depth = horizon
        ring = np.zeros((depth, N, T, n))
        spare = np.empty_like(ring)
        # ring rows fit int32 below 2^31 (halves the index arrays)
        index_type: type[np.signedinteger[Any]] = (
            np.int32 if depth * N * T < 2**31 - 1 else np.int64)
        trials = np.arange(T, dtype=index_type)[None, :]
        no_link = terms.link < 0
        any_no_link = bool(no_link.any())
        term_row = np.maximum(terms.link, 0)
        term_j = terms.j.astype(index_type)[:, None]
        own_agent = np.arange(N, dtype=index_type)[:, None]
        index_steps = max(1, min(64, 2_000_000 // max(1, (N + E) * T)))
        index_chunk: list[np.ndarray] = []
        index_start = [0]

        # the ring row of message q of a link from sender j in trial t is
        # slot_row[q] + base[term, t], with slot_row[q] = (s_q % depth) N T
        slot_row = ((send % depth) * (N * T)).astype(index_type)
        base = (term_j * T + trials).astype(index_type)  # (E, T)
        terms_are_links = (not any_no_link and len(term_row) == selection.chosen.shape[1]
                           and bool(np.array_equal(term_row, np.arange(len(term_row)))))

        def gather_index(k0: int, k1: int) -> np.ndarray:
            # (k1 - k0, N + E, T) rows of the ring: the own term (the slot of step
            # k - period) and the message each term holds (sent at s, slot s), or the
            # own term's row when nothing has arrived from j yet
            c = k1 - k0
            ks = np.arange(k0, k1, dtype=index_type)[:, None, None]
            out = np.empty((c, N + E, T), dtype=index_type)
            own_rows = out[:, :N]
            np.add((((ks - period) % depth) * N + own_agent) * T, trials, out=own_rows)
            held = selection.chosen[k0:k1]
            if not terms_are_links:
                held = held[:, term_row]  # (c, E, T)
                if any_no_link:
                    held[:, no_link] = -1
            rows = out[:, N:]
            np.take(slot_row, held, out=rows, mode="wrap")  # -1: replaced below
            rows += base
            if held.size and int(held.min()) < 0:
                np.copyto(rows, own_rows[:, terms.i], where=held < 0)
            return out

        payload = np.empty(((N + E) * T, n))
        prior_buffer = np.empty((N, T, n))
        uncompensated = np.empty((N, T, n)) if not rule.compensate else None
        # [diag(p_ii) | the terms' weights]: the own term first, then the terms
        agg_product = product_into(
            np.concatenate([own_weight, terms.weight]),
            np.concatenate([np.arange(N), terms.i]), np.arange(N + E), (N, N + E),
            prior_buffer.reshape(N, T * n), sort=False)

        def prior_at(k: int) -> np.ndarray:
            if not index_chunk or k >= index_start[0] + len(index_chunk[0]):
                index_start[0] = k
                index_chunk[:] = [gather_index(k, min(k + index_steps, K + 1))]
            index = index_chunk[0][k - index_start[0]]
            # mode "clip": the rows are valid, and "raise" would buffer the output
            ring.reshape(-1, n).take(index.reshape(-1), axis=0, out=payload, mode="clip")
            agg_product(payload.reshape(N + E, T * n))
            if uncompensated is not None:
                # eq. (6): A on every term
                np.matmul(prior_buffer.reshape(-1, n), A_T, out=uncompensated.reshape(-1, n))
                return uncompensated
            return prior_buffer

        def store(k: int, estimate: np.ndarray) -> None:
            ring[k % depth] = estimate

    outputs = _Outputs(K, N, T, n, scenario.divergence_threshold, record_estimates)
    # estimates are recorded (squared errors, divergence test) a chunk of steps at a
    # time, about 100,000 numbers (the chunk just written is still in cache); a chunk
    # whose trials have all diverged ends the run
    chunk_steps = max(1, min(32, 100_000 // max(1, N * T * n)))
    chunk = np.empty((chunk_steps, N, T, n))
    chunk_start = 0
    estimate = innovate(np.broadcast_to(plant.x0_mean, (N, T, n)).copy(), 0, chunk[0])
    block_step = 0
    store(0, estimate)
    updated = [0]
    alive = True
    with np.errstate(all="ignore"):
        for k in range(1, K + 2):
            if k - chunk_start == chunk_steps or k == K + 1:
                alive = outputs.record_many(chunk_start, chunk[: k - chunk_start],
                                            batch.states[chunk_start:k])
                chunk_start = k
            if not alive or k > K:
                break
            interrupt.check()  # a requested Ctrl-C stops here, between steps
            if uniform is None and rule.compensate:
                # Z <- A Z: every past estimate gains one power of A (eq. 4's A^(k - s))
                np.matmul(ring.reshape(-1, n), A_T, out=spare.reshape(-1, n))
                ring, spare = spare, ring
            estimate = chunk[k - chunk_start]
            if block and k % period:
                # between block steps: A^(k - block step) x(block step), from the ring
                np.copyto(estimate, ring[block_step % depth])
            else:
                innovate(prior_at(k), k, estimate)
                block_step = k
                updated.append(k)
                store(k, estimate)
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
    from netsim.trialresult import NOT_USED

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
    from netsim.trialresult import NOT_USED

    terms = _consensus_terms(scenario, schedule)
    per_link = effective_delays_per_link(selection, schedule, terms.link, updated, trial, end)
    N = scenario.n_agents
    out = np.full((per_link.shape[0], N, N), NOT_USED, dtype=np.int32)
    out[:, terms.i, terms.j] = per_link
    return out


def _drop_records(schedule: LinkSchedule, trial: int, end: int
                  ) -> list[tuple[int, int, int, float, str]]:
    """The messages of one trial dropped by step ``end``, as the kernel records them
    (``TrialResult.drops``: sender, receiver, sent step, drop time in sampling periods,
    reason), ordered by drop time."""
    if schedule.constant_delay is not None or schedule.lossless_steps:
        return []
    lost = (schedule.fate[trial] != DELIVERED) & (schedule.drop_time[trial] <= end)
    link, q = np.nonzero(lost)
    times = schedule.drop_time[trial][link, q]
    codes = schedule.fate[trial][link, q]
    order = np.argsort(times, kind="stable")
    return [(*schedule.links[e], int(schedule.send_steps[s]), float(when),
             schedule.reasons[c - 1])
            for e, s, when, c in zip(link[order].tolist(), q[order].tolist(),
                                     times[order].tolist(), codes[order].tolist(),
                                     strict=True)]


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
    kernel: str | None = None,
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
    kernel : {"numpy", "numba"} or None
        The step of the consensus families (not the block rule, which always runs
        the numpy step): the numpy step (the reference, bit for bit the same numbers
        for the same seeds) or the compiled one (:mod:`netsim.lockstep_numba`, the
        extra ``netsim[numba]``; the same numbers to round-off). None: the
        environment variable ``NETSIM_NUMBA`` decides (:func:`choose_kernel`).

    Returns
    -------
    VectorisedBatch
        ``results``: one TrialResult per trial, as the event kernel returns it
        (``messages`` is empty); and the link schedule and message selection the run
        used (None for the centralised filter).
    """
    from netsim.trialresult import NOT_USED, TrialResult

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
                                          selection, K, record_estimates,
                                          choose_kernel(kernel))
        N = scenario.n_agents
    n = plant.n_states
    wanted = set(range(T)) if record_delays is True else set(record_delays or ())
    ends = np.where(outputs.diverged_at >= 0, outputs.diverged_at, K)
    if schedule is not None and selection is not None:  # (both or neither)
        all_counts = schedule.counts(ends)
        all_discarded = selection.discarded_by(schedule, ends)
    results = []
    # per trial, views of the batch's arrays (owned by this run), NaN after the trial's
    # last step
    for t in np.flatnonzero(ends < K).tolist():
        batch.states[ends[t] + 1:, t] = np.nan
        batch.measurements[ends[t] + 1:, t] = np.nan
    all_states = batch.states.transpose(1, 0, 2)
    all_measurements = batch.measurements.transpose(1, 0, 2)
    sensors = [slice(int(a), int(b)) for a, b in zip(batch.offsets[:-1], batch.offsets[1:],
                                                    strict=True)]
    for t in range(T):
        end = int(ends[t])
        states = all_states[t]
        measurements = [all_measurements[t][:, rows] for rows in sensors]
        estimates = (outputs.estimates[:, t] if outputs.estimates is not None
                     else np.zeros((0, N, n)))
        counts: dict[str, Any] = {"sent": 0, "delivered": 0, "dropped": 0, "drop_reasons": {}}
        discarded = 0
        delays = None
        drops = None
        if schedule is not None and selection is not None:
            counts = all_counts[t]
            discarded = int(all_discarded[t])
            if t in wanted:
                delays = _effective_delays(selection, schedule, scenario, updated, t, end)
                drops = _drop_records(schedule, t, end)
        elif t in wanted:
            delays = np.full((K + 1, N, N), NOT_USED, dtype=np.int32)
            drops = []
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
            drops=drops,
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
    kernel: str | None = None,
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
                             progress=progress, kernel=kernel).results
    return results
