"""Replay a trace through the augmented error recursion and compare with the recorded errors.

:func:`replay_trace` rebuilds, from a trace alone, each step's augmented closed-loop
matrix A-hat[k] (LCSYS2022 eq. 10 with the blocks of eq. 9, ``P_r[k] kron A^(r+1)``,
for the compensating estimator; the delay-tolerant paper's eq. 11, ``P_r[k] kron A``,
for the uncompensated one) from the effective delays r_ij[k] the agents recorded, and
reruns

    E_k = A-hat[k] E_{k-1} + b_1 kron eta_k,   E_k = (e_k; e_{k-1}; ...; e_{k-tau}),
    e_k = (x_k - x-hat^1_k; ...; x_k - x-hat^N_k),

from the recorded e_0, with the noise recorded in the trace: process noise
nu_k = x_k - A x_{k-1} (from ``/plant/state``) and measurement noise
zeta^i_k = y^i_k - C_i x_k (from ``/sensor_<i>/measurement``). The augmentation depth
tau is the largest effective delay in the trace. Where agent i substituted its own
estimate for j's (r_ij[k] = -1: nothing had arrived from j yet), the weight p_ij goes
on agent i's own delay-0 term, as the estimator does.

Two versions of eta_k are replayed and both are reported:

``paper``
    LCSYS2022 eq. (11) / delay-tolerant eq. (14): per agent
    eta^i_k = (I - L_i C_i) nu_k - L_i zeta^i_k.
``exact``
    What the estimator's equations give (``netsim.estimators.consensus``): per agent
    eta^i_k = (I - L_i C_i) sum_j p_ij (x_k - A^(r_ij+1) x_{k-1-r_ij}) - L_i zeta^i_k
    (compensated), or the same with ``A`` in place of ``A^(r_ij+1)`` (uncompensated).

With delays, x_k - A^(r+1) x_{k-1-r} = sum_{s=0}^{r} A^s nu_{k-s}: the paper's eta
keeps only the s = 0 term, so its recursion deviates from the run as soon as an
effective delay is non-zero. For the uncompensated estimator
x_k - A x_{k-1-r} = (A^(r+1) - A) x_{k-1-r} + sum_{s=0}^{r} A^s nu_{k-s}: the "noise"
contains a term proportional to the state, so eq. (11)'s recursion (which assumes
x_k = A x_{k-1-r} + noise) does not describe the error of a moving state at all.

Only the consensus families ``compensated`` and ``uncompensated`` have this
recursion; for any other family (``block``, ``centralized-kf``, ...) the report says
replay is not defined (``defined=False``).

This module imports ``models`` (``netsim.models.augmented``), never ``netsim`` or ``simpy``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from netsim.models.augmented import augmented_closed_loop
from netsim.models.jsonsafe import json_number as _num
from netsim.models.precision import precision_horizon
from netsim.traces.reader import NOT_USED, Trace

__all__ = [
    "ROUNDOFF_TOLERANCE",
    "TraceSystem",
    "EtaReplay",
    "ReplayReport",
    "trace_system",
    "effective_pattern",
    "replay_trace",
]

#: Relative deviation (to max |e| of the trace) below which a replay "reproduces" the run.
ROUNDOFF_TOLERANCE = 1e-9
#: The recorded errors x_k - x-hat^i_k are differences of numbers of size |x|: an
#: absolute deviation below ROUNDOFF_STATE_FACTOR * eps * max|x| is round-off too
#: (matters on an unstable plant, where |x| outgrows |e| by many orders of magnitude).
ROUNDOFF_STATE_FACTOR = 100.0
#: Largest augmented dimension N n (tau+1) for which ``method="auto"`` builds A-hat[k]
#: densely with :func:`netsim.models.augmented.augmented_closed_loop`.
DENSE_LIMIT = 1500

_CAUSE_PAPER_COMPENSATED = (
    "the paper's eta_k omits the accumulated process noise sum_{s=1}^{r} A^s nu_{k-s} "
    "of delayed terms: x_k - A^(r+1) x_{k-1-r} = sum_{s=0}^{r} A^s nu_{k-s}, and "
    "eq. (11) keeps only nu_k"
)
_CAUSE_PAPER_UNCOMPENSATED = (
    "eq. (11)'s recursion assumes x_k = A x_{k-1-r} + nu_k for a term delayed by r; "
    "in fact x_k - A x_{k-1-r} = (A^(r+1) - A) x_{k-1-r} + sum_{s=0}^{r} A^s nu_{k-s}, "
    "so the error contains (A^(r+1) - A) x_{k-1-r}, proportional to the state, and the "
    "delay-tolerant paper's error recursion (13)-(14) does not hold for a moving state"
)
_CAUSE_NO_DELAY = (
    "every effective delay is 0, so the paper's eta_k equals the exact one "
    "(sum_j p_ij (x_k - A x_{k-1}) = nu_k)"
)


# -- the system stored in a trace ------------------------------------------------------


@dataclass(frozen=True)
class TraceSystem:
    """The matrices of a consensus run, as stored in the trace's attachments."""

    P: np.ndarray
    A: np.ndarray
    C: list[np.ndarray]
    L: list[np.ndarray]

    @property
    def n_agents(self) -> int:
        return int(self.P.shape[0])

    @property
    def n_states(self) -> int:
        return int(self.A.shape[0])

    @property
    def G(self) -> np.ndarray:
        """I - blockdiag(L_i C_i) = I - K D_C-bar."""
        n = self.n_states
        out = np.eye(self.n_agents * n)
        for i, (Li, Ci) in enumerate(zip(self.L, self.C, strict=True)):
            out[i * n:(i + 1) * n, i * n:(i + 1) * n] -= Li @ Ci
        return out

    def local_gain(self, i: int) -> np.ndarray:
        """I - L_i C_i."""
        return np.eye(self.n_states) - self.L[i] @ self.C[i]


def trace_system(trace: Trace) -> tuple[TraceSystem | None, str]:
    """Return the trace's (P, A, C_i, L_i), or (None, why not)."""
    m = trace.matrices
    missing = [name for name in ("A", "P") if name not in m]
    if missing:
        return None, f"the trace has no {' and '.join(missing)} attachment"
    P = np.asarray(m["P"], dtype=float)
    A = np.asarray(m["A"], dtype=float)
    if P.ndim != 2 or P.shape[0] != P.shape[1] or A.ndim != 2 or A.shape[0] != A.shape[1]:
        return None, f"P {P.shape} or A {A.shape} is not square"
    N, n = P.shape[0], A.shape[0]
    C, L = [], []
    for i in range(N):
        if f"C_{i}" not in m or f"L_{i}" not in m:
            return None, f"the trace has no C_{i}/L_{i} attachment (gains not recorded)"
        Ci = np.atleast_2d(np.asarray(m[f"C_{i}"], dtype=float))
        Li = np.asarray(m[f"L_{i}"], dtype=float)
        if Li.ndim == 1:
            Li = Li.reshape(-1, 1)
        if Ci.shape[1] != n or Li.shape != (n, Ci.shape[0]):
            return None, f"C_{i} {Ci.shape} / L_{i} {Li.shape} do not fit n = {n}"
        C.append(Ci)
        L.append(Li)
    return TraceSystem(P, A, C, L), ""


def effective_pattern(P: np.ndarray, delays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (P_eff, r_eff) of one step's effective delays r_ij[k] (shape (N, N)).

    P_eff = P with the weight p_ij of every substitution (r_ij = -1) moved to p_ii;
    r_eff[i, j] = r_ij[k] on the remaining edges j != i, 0 on the diagonal and off the
    graph. ``augmented_closed_loop(P_eff, A, C, L, r_eff, ...)`` is then A-hat[k].
    Entries NOT_USED (-2) on an edge j != i are treated as substitutions too (the caller
    checks that they do not occur in a consensus trace).
    """
    N = P.shape[0]
    P_eff = np.array(P, dtype=float, copy=True)
    r_eff = np.zeros((N, N), dtype=np.int64)
    off = ~np.eye(N, dtype=bool)
    edge = (P != 0) & off
    sub = edge & (delays < 0)
    if np.any(sub):
        moved = np.where(sub, P_eff, 0.0).sum(axis=1)
        P_eff[sub] = 0.0
        P_eff[np.diag_indices(N)] += moved
    keep = edge & ~sub
    r_eff[keep] = delays[keep]
    return P_eff, r_eff


# -- report ----------------------------------------------------------------------------




@dataclass
class EtaReplay:
    """The replay with one version of eta_k.

    Attributes
    ----------
    name : str
        ``exact`` or ``paper``.
    description : str
    errors : numpy.ndarray, shape (K+1, N, n)
        Replayed e_k = x_k - x-hat^i_k (rows past ``steps_replayed`` are NaN).
    deviation_abs : numpy.ndarray, shape (K+1,)
        max over agents and components of |e_replayed - e_recorded| at each step.
    deviation_rel : numpy.ndarray, shape (K+1,)
        ``deviation_abs / error_scale`` (max |e| recorded over the whole trace).
    max_abs, max_rel : float
        Largest deviation over the replayed steps.
    worst_step : int
        Step of the largest deviation.
    first_step_above : int or None
        First step whose relative deviation exceeds the tolerance.
    reproduces : bool
        Every step's relative deviation is within its round-off allowance: the larger
        of ``tolerance`` and ROUNDOFF_STATE_FACTOR eps max_{j<=k} |x_j| / error_scale
        (the state's rounding so far); the recursion reproduces the run to round-off.
    tail_mse_replayed, tail_mse_recorded : float
        Mean over agents and the second half of the steps of ||e^i_k||^2, replayed and
        recorded (how far off the replay is in MSE terms).
    cause : str
        Why it deviates (empty when it reproduces).
    """

    name: str
    description: str
    errors: np.ndarray
    deviation_abs: np.ndarray
    deviation_rel: np.ndarray
    max_abs: float
    max_rel: float
    worst_step: int
    first_step_above: int | None
    reproduces: bool
    tail_mse_replayed: float = math.nan
    tail_mse_recorded: float = math.nan
    cause: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "max_abs_deviation": _num(self.max_abs),
            "max_rel_deviation": _num(self.max_rel),
            "worst_step": self.worst_step,
            "first_step_above_tolerance": self.first_step_above,
            "reproduces": self.reproduces,
            "tail_mse_replayed": _num(self.tail_mse_replayed),
            "tail_mse_recorded": _num(self.tail_mse_recorded),
            "cause": self.cause,
        }


@dataclass
class ReplayReport:
    """Result of :func:`replay_trace` (``to_dict()`` JSON-ready, ``format_text()``).

    Attributes
    ----------
    path, family : str
    trial : int or None
    defined : bool
        False for families without the augmented error recursion (then ``reason``).
    reason : str
    compensated : bool or None
        Blocks ``P_r kron A^(r+1)`` (True) or ``P_r kron A`` (False).
    steps_replayed : int
        Last step replayed (the trace's last complete step).
    n_agents, n_states : int
    tau : int
        Augmentation depth = largest effective delay in the replayed steps.
    distinct_patterns : int
        Distinct delay patterns r[k] (k >= 1), i.e. distinct A-hat[k].
    substitutions : int
        (agent, step) pairs where some neighbour's weight went on the own term (r = -1).
    nonzero_delay_steps : int
        Steps k >= 1 with some effective delay > 0.
    method : str
        ``dense`` (A-hat[k] from ``netsim.models.augmented.augmented_closed_loop``, cached per
        pattern) or ``agents`` (the same recursion agent by agent, no big matrices).
    tolerance : float
        Relative tolerance for "reproduces" as given.
    roundoff_floor : float
        ROUNDOFF_STATE_FACTOR * eps * max |x|: absolute deviations below it are
        round-off of the state's size.
    effective_tolerance : float
        ``max(tolerance, roundoff_floor / error_scale)``, what "reproduces" uses.
    error_scale, state_scale : float
        max |e| recorded and max |x| over the replayed steps.
    eta_gap : float
        max |eta_exact - eta_paper| over the replayed steps.
    state_term : float or None
        Uncompensated only: max |(I - L_i C_i) sum_j p_ij (A^(r+1) - A) x_{k-1-r}|,
        the state-proportional part of the exact eta.
    precision_horizon : int or None
        First step whose recorded error is below the float64 resolution of the state
        (:func:`netsim.models.precision.precision_horizon`); the replay compares only
        the steps before it. None: every step is trusted.
    exact, paper : EtaReplay or None
    notes : list of str
    verdict : str
    """

    path: str
    family: str
    trial: int | None
    defined: bool
    reason: str = ""
    compensated: bool | None = None
    steps_replayed: int = -1
    n_agents: int = 0
    n_states: int = 0
    tau: int = 0
    distinct_patterns: int = 0
    substitutions: int = 0
    nonzero_delay_steps: int = 0
    method: str = ""
    tolerance: float = ROUNDOFF_TOLERANCE
    roundoff_floor: float = math.nan
    effective_tolerance: float = math.nan
    error_scale: float = math.nan
    state_scale: float = math.nan
    eta_gap: float = math.nan
    state_term: float | None = None
    exact: EtaReplay | None = None
    paper: EtaReplay | None = None
    precision_horizon: int | None = None
    recorded: np.ndarray | None = field(default=None, repr=False)
    notes: list[str] = field(default_factory=list)
    verdict: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "family": self.family,
            "trial": self.trial,
            "defined": self.defined,
            "reason": self.reason,
            "compensated": self.compensated,
            "steps_replayed": self.steps_replayed,
            "n_agents": self.n_agents,
            "n_states": self.n_states,
            "tau": self.tau,
            "distinct_patterns": self.distinct_patterns,
            "substitutions": self.substitutions,
            "nonzero_delay_steps": self.nonzero_delay_steps,
            "method": self.method,
            "tolerance": self.tolerance,
            "roundoff_floor": _num(self.roundoff_floor),
            "effective_tolerance": _num(self.effective_tolerance),
            "error_scale": _num(self.error_scale),
            "state_scale": _num(self.state_scale),
            "eta_gap": _num(self.eta_gap),
            "state_term": _num(self.state_term),
            "exact": None if self.exact is None else self.exact.to_dict(),
            "paper": None if self.paper is None else self.paper.to_dict(),
            "precision_horizon": self.precision_horizon,
            "notes": list(self.notes),
            "verdict": self.verdict,
        }

    def format_text(self) -> str:
        lines = [f"replay {self.path}"]
        trial = "?" if self.trial is None else self.trial
        if not self.defined:
            lines.append(f"  family {self.family or '?'}   trial {trial}")
            lines.append(f"  replay not defined: {self.reason}")
            lines.extend(f"  note: {n}" for n in self.notes)
            return "\n".join(lines)
        blocks = "P_r kron A^(r+1) (LCSYS2022 eq. 9)" if self.compensated else (
            "P_r kron A (delay-tolerant eq. 11)")
        lines.append(
            f"  family {self.family}   trial {trial}   steps 0..{self.steps_replayed}   "
            f"agents {self.n_agents}   states {self.n_states}"
        )
        lines.append(
            f"  A-hat[k] blocks {blocks}; depth tau = {self.tau} (max effective delay); "
            f"{self.distinct_patterns} distinct delay patterns; method {self.method}"
        )
        lines.append(
            f"  steps with a non-zero delay {self.nonzero_delay_steps}; own-estimate "
            f"substitutions (r = -1) {self.substitutions} agent-steps"
        )
        lines.append(
            f"  recorded max |e| {self.error_scale:.3e}; max |x| {self.state_scale:.3e}; "
            f"max |eta_exact - eta_paper| {self.eta_gap:.3e}"
            + ("" if self.state_term is None
               else f"; state-proportional part of eta {self.state_term:.3e}")
        )
        if self.precision_horizon is not None:
            lines.append(
                f"  beyond the float64 precision horizon at step {self.precision_horizon}: "
                f"compared steps 0..{self.precision_horizon - 1} only"
            )
        for rep in (self.exact, self.paper):
            if rep is None:
                continue
            state = ("reproduces the recorded errors to round-off" if rep.reproduces
                     else f"DEVIATES (first above its round-off allowance at step "
                          f"{rep.first_step_above})")
            lines.append(
                f"  {rep.name:<5} eta ({rep.description}): max |dev| {rep.max_abs:.3e} "
                f"(relative {rep.max_rel:.3e}) at step {rep.worst_step}: {state}"
            )
            if not rep.reproduces:
                lines.append(
                    f"        tail MSE (second half) replayed {rep.tail_mse_replayed:.3e} vs "
                    f"recorded {rep.tail_mse_recorded:.3e}"
                )
            if rep.cause:
                lines.append(f"        cause: {rep.cause}")
        lines.extend(f"  note: {n}" for n in self.notes)
        lines.append(f"  verdict: {self.verdict}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format_text()


# -- replay ----------------------------------------------------------------------------


@dataclass
class _Recorded:
    """Steps 0..K of a consensus run as its trace recorded them.

    Attributes
    ----------
    system : TraceSystem
    X : numpy.ndarray, shape (K+1, n)
        x_k.
    Ys : list of numpy.ndarray, each (K+1, m_i)
        y^i_k.
    Xhat : numpy.ndarray, shape (K+1, N, n)
        x-hat^i_{k|k}.
    D : numpy.ndarray, shape (K+1, N, N), int
        r_ij[k].
    edge : numpy.ndarray, shape (N, N), bool
        j -> i is a link of the graph (p_ij != 0, j != i).
    errors : numpy.ndarray, shape (K+1, N, n)
        The recorded errors e^i_k = x_k - x-hat^i_k.
    """

    system: TraceSystem
    X: np.ndarray
    Ys: list[np.ndarray]
    Xhat: np.ndarray
    D: np.ndarray
    edge: np.ndarray
    errors: np.ndarray

    @property
    def K(self) -> int:
        return self.X.shape[0] - 1


@dataclass
class _Recursion:
    """What the error recursion of one trace is built from.

    Attributes
    ----------
    compensated : bool
        Blocks ``P_r kron A^(r+1)`` (True) or ``P_r kron A`` (False).
    tau : int
        Augmentation depth.
    powers : list of numpy.ndarray
        A^0 .. A^(tau+1).
    local : list of numpy.ndarray
        I - L_i C_i.
    terms : list (per step k >= 1) of list (per agent i) of list of (j, r, p_ij)
        The terms of each agent's consensus step (see :func:`_consensus_terms`).
    """

    compensated: bool
    tau: int
    powers: list[np.ndarray]
    local: list[np.ndarray]
    terms: list[list[list[tuple[int, int, float]]]]


def _recursion_kind(trace: Trace) -> bool | None:
    """Whether the trace's family compensates with A^(r+1); None: it declares no
    consensus error recursion (:attr:`netsim.traces.reader.Trace.recursion_compensated`,
    what the family declares in the registry, recorded in the trace)."""
    return trace.recursion_compensated


def _no_recursion_reason(trace: Trace) -> str:
    """Why a family without the recursion (see :func:`_recursion_kind`) is not replayed."""
    from netsim.estimators.registry import (
        RECURSION_BLOCK,
        RECURSION_COMPENSATED,
        RECURSION_UNCOMPENSATED,
        families,
    )

    known = ", ".join(f.name for f in families() if f.error_recursion in
                      (RECURSION_COMPENSATED, RECURSION_UNCOMPENSATED))
    if trace.error_recursion == RECURSION_BLOCK:
        return ("the block-update estimator (LCSYS2022 eqs. 15-16) updates every tau+1 "
                "steps and predicts open loop in between; it has no per-step augmented "
                "error recursion (only the consensus families have one: "
                f"{known})")
    if trace.centralised:
        return ("the centralised Kalman filter has no consensus step and no delays; "
                f"the augmented error recursion exists only for {known}")
    return (f"family {trace.family or '?'!r} has no augmented error recursion (only "
            f"{known})")


def _timed_reason(trace: Trace) -> str:
    """Why a trace of a ``[time]`` scenario is not replayed ('' when it can be: every
    sample on the base grid, read exactly, every update sent)."""
    if not any(t.endswith("/clock") for t in trace.counts):
        return ""
    for c in trace.clocks().values():
        steps = c["true_time"] / trace.sample_period
        if (not np.array_equal(c["local_time"], c["true_time"])
                or not np.array_equal(steps, np.rint(steps)) or not c["sent"].all()):
            return ("a [time] trace (agent clocks, asynchronous sampling or a trigger): "
                    "the augmented error recursion (one clock, one grid, every update "
                    "sent) is not defined for it; see docs/time.rst")
    return ""


def _usable_steps(system: TraceSystem, X: np.ndarray, Ys: list[np.ndarray],
                  Xhat: np.ndarray, D: np.ndarray) -> tuple[int, str]:
    """Last step k such that steps 0..k are complete and finite; and why it stops."""
    N = system.n_agents
    edge = (system.P != 0) & ~np.eye(N, dtype=bool)
    K = X.shape[0] - 1
    for k in range(K + 1):
        why = ""
        if not np.all(np.isfinite(X[k])):
            why = "no finite true state"
        elif not all(np.all(np.isfinite(Y[k])) for Y in Ys):
            why = "a measurement is missing"
        elif not np.all(np.isfinite(Xhat[k])):
            why = "an estimate is missing or not finite"
        elif k >= 1 and np.any(edge & (D[k] == NOT_USED)):
            i, j = (int(v) for v in np.argwhere(edge & (D[k] == NOT_USED))[0])
            why = f"agent {i} recorded no effective delay for neighbour {j}"
        if why:
            return k - 1, f"replay stops at step {k - 1}: step {k}: {why}"
    return K, ""


def _read_run(trace: Trace, system: TraceSystem) -> tuple[_Recorded | None, str, str]:
    """The complete steps 0..K of the run in ``trace``.

    Returns (run, reason, stop): run is None when there is nothing to replay (reason
    says why); stop says where and why the replay stops before the trace's last step.
    """
    N = system.n_agents
    if trace.n_agents != N:
        return None, f"the trace has {trace.n_agents} agents but P is {N}x{N}", ""
    X = trace.states()
    if X.shape[0] == 0:
        return None, "the trace has no plant steps", ""
    sensors = trace.sensors
    if sensors != list(range(N)):
        return None, (f"replay needs one sensor per agent (sensor i = agent i), the trace "
                      f"has sensors {sensors}"), ""
    Ys = [trace.measurements(i) for i in range(N)]
    Xhat = trace.estimates()
    D = trace.effective_delays()
    K, stop = _usable_steps(system, X, Ys, Xhat, D)
    if K < 0:
        return None, "no complete step to replay", stop
    X, Xhat, D = X[: K + 1], Xhat[: K + 1], D[: K + 1]
    edge = (system.P != 0) & ~np.eye(N, dtype=bool)
    return _Recorded(system, X, [Y[: K + 1] for Y in Ys], Xhat, D, edge,
                     errors=X[:, None, :] - Xhat), "", stop


def _status_notes(trace: Trace) -> list[str]:
    """Notes on a trace whose writer never finished or whose run did not complete."""
    notes = []
    if trace.truncated:
        notes.append("the trace is truncated (writer never finished); replayed the "
                     "recovered steps")
    status = (trace.status or {}).get("status")
    if status and status != "complete":
        notes.append(f"run status {status!r}")
    return notes


def _scales(run: _Recorded, tolerance: float) -> tuple[float, float, float, float]:
    """(error_scale, state_scale, roundoff_floor, effective_tolerance) of the run."""
    recorded = run.errors
    error_scale = float(np.max(np.abs(recorded))) if recorded.size else 0.0
    state_scale = float(np.max(np.abs(run.X)))
    roundoff_floor = ROUNDOFF_STATE_FACTOR * float(np.finfo(float).eps) * state_scale
    effective_tolerance = max(
        float(tolerance), roundoff_floor / error_scale if error_scale > 0 else 0.0
    )
    return error_scale, state_scale, roundoff_floor, effective_tolerance


def _delay_patterns(run: _Recorded) -> tuple[int, int, int]:
    """(tau, substitutions, nonzero_delay_steps) of the effective delays of steps >= 1.

    tau is the largest effective delay on an edge; substitutions counts the
    (agent, step) pairs with some r_ij[k] = -1; nonzero_delay_steps the steps with
    some r_ij[k] > 0.
    """
    edge, D = run.edge, run.D
    used = np.where(edge[None, :, :], D, -1)  # -1 off the graph
    tau = max(0, int(used[1:].max())) if run.K >= 1 else 0
    substitutions = int(np.sum(np.any(edge[None] & (D[1:] == -1), axis=2)))
    nonzero_delay_steps = int(np.sum(np.any(used[1:] > 0, axis=(1, 2))))
    return tau, substitutions, nonzero_delay_steps


def _choose_method(method: str, dim: int) -> str:
    """``auto``: dense if the augmented dimension N n (tau+1) is at most DENSE_LIMIT."""
    if method == "auto":
        return "dense" if dim <= DENSE_LIMIT else "agents"
    return method


def _consensus_terms(run: _Recorded) -> list[list[list[tuple[int, int, float]]]]:
    """Per step k >= 1 and agent i: the terms (j, r_ij[k], p_ij) of its consensus step.

    The own term is (i, 0, p_ii); a substitution (r_ij[k] = -1) is the term
    (i, 0, p_ij): the weight goes on agent i's own delay-0 term.
    """
    P, D = run.system.P, run.D
    terms: list[list[list[tuple[int, int, float]]]] = [[] for _ in range(run.K + 1)]
    for k in range(1, run.K + 1):
        for i in range(run.system.n_agents):
            row = [(i, 0, float(P[i, i]))]
            for j in np.flatnonzero(run.edge[i]):
                r = int(D[k, i, j])
                w = float(P[i, j])
                row.append((i, 0, w) if r < 0 else (int(j), r, w))
            terms[k].append(row)
    return terms


def _recursion(run: _Recorded, compensated: bool, tau: int) -> _Recursion:
    """The powers of A, the local gains and the consensus terms of the run's recursion."""
    system = run.system
    powers = [np.eye(system.n_states)]
    for _ in range(tau + 1):
        powers.append(system.A @ powers[-1])
    local = [system.local_gain(i) for i in range(system.n_agents)]
    return _Recursion(compensated, tau, powers, local, _consensus_terms(run))


def _etas(run: _Recorded, rec: _Recursion) -> tuple[np.ndarray, np.ndarray]:
    """(eta_exact, eta_paper), each (K+1, N, n), from the noise of the recorded run.

    nu_k = x_k - A x_{k-1}, zeta^i_k = y^i_k - C_i x_k; paper: (I - L_i C_i) nu_k -
    L_i zeta^i_k; exact: (I - L_i C_i) sum_j p_ij (x_k - B_r x_{k-1-r}) - L_i zeta^i_k
    with B_r = A^(r+1) (compensated) or A.
    """
    system, X, K = run.system, run.X, run.K
    nu = np.zeros_like(X)
    nu[1:] = X[1:] - X[:-1] @ system.A.T
    zeta = [Y - X @ Ci.T for Y, Ci in zip(run.Ys, system.C, strict=True)]
    eta_exact = np.zeros((K + 1, system.n_agents, system.n_states))
    eta_paper = np.zeros_like(eta_exact)
    for k in range(1, K + 1):
        for i, row in enumerate(rec.terms[k]):
            meas = system.L[i] @ zeta[i][k]
            eta_paper[k, i] = rec.local[i] @ nu[k] - meas
            gap = np.zeros(system.n_states)
            for _j, r, w in row:
                Ar = rec.powers[r + 1] if rec.compensated else rec.powers[1]
                gap += w * (X[k] - Ar @ X[k - 1 - r])
            eta_exact[k, i] = rec.local[i] @ gap - meas
    return eta_exact, eta_paper


def _state_term(run: _Recorded, rec: _Recursion) -> float:
    """max |(I - L_i C_i) sum_j p_ij (A^(r+1) - A) x_{k-1-r}| over steps and agents."""
    A, X = run.system.A, run.X
    out = 0.0
    for k in range(1, run.K + 1):
        for i, row in enumerate(rec.terms[k]):
            drift = np.zeros(run.system.n_states)
            for _j, r, w in row:
                if r > 0:
                    drift += w * ((rec.powers[r + 1] - A) @ X[k - 1 - r])
            out = max(out, float(np.max(np.abs(rec.local[i] @ drift))))
    return out


def _replay_errors(run: _Recorded, rec: _Recursion, method: str, eta_exact: np.ndarray,
                   eta_paper: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(exact errors, paper errors, distinct delay patterns) of the recursion from e_0."""
    system, D, K, tau, e0 = run.system, run.D, run.K, rec.tau, run.errors[0]
    if method == "dense":
        rows, distinct = _dense_rows(system, D, K, tau, rec.compensated)
        N, n = system.n_agents, system.n_states
        return (_run_dense(rows, e0, eta_exact, N, n, tau),
                _run_dense(rows, e0, eta_paper, N, n, tau), distinct)
    distinct = len({D[k].tobytes() for k in range(1, K + 1)})
    blocks = [rec.powers[r + 1] if rec.compensated else system.A for r in range(tau + 1)]
    return (_run_agents(rec.terms, rec.local, blocks, e0, eta_exact),
            _run_agents(rec.terms, rec.local, blocks, e0, eta_paper), distinct)


def _paper_cause(compensated: bool, delays_seen: bool) -> str:
    """Why the paper's eta deviates from the run (used when it does)."""
    if not delays_seen:
        return _CAUSE_NO_DELAY
    return _CAUSE_PAPER_COMPENSATED if compensated else _CAUSE_PAPER_UNCOMPENSATED


def _exact_description(compensated: bool) -> str:
    """The exact eta_k, as the report describes it."""
    return ("(I - L_i C_i) sum_j p_ij (x_k - A^(r+1) x_{k-1-r}) - L_i zeta^i_k"
            if compensated else
            "(I - L_i C_i) sum_j p_ij (x_k - A x_{k-1-r}) - L_i zeta^i_k")


def _exact_cause(report: ReplayReport) -> str:
    """Why the exact recursion fails to reproduce the run (it is just algebra)."""
    # failing to reproduce means the trace and the matrices disagree (or round-off on a
    # huge state)
    return (
        "the exact eta must reproduce the run up to round-off; a larger deviation means "
        "the recorded matrices/delays do not describe the run, or the state "
        f"(max |x| {report.state_scale:.2e}) is so large that its round-off "
        f"(~{np.finfo(float).eps * report.state_scale:.1e}) is not small against "
        f"max |e| {report.error_scale:.2e}"
    )


def replay_trace(trace: Trace, *, method: str = "auto",
                 tolerance: float = ROUNDOFF_TOLERANCE) -> ReplayReport:
    """Replay the augmented error recursion of a consensus trace (see module docstring).

    Parameters
    ----------
    trace : Trace
        Read by :func:`netsim.traces.reader.read_trace`.
    method : str
        ``dense`` (A-hat[k] built with ``netsim.models.augmented.augmented_closed_loop``,
        cached per delay pattern), ``agents`` (the same recursion agent by agent, for
        large tau) or ``auto`` (dense if N n (tau+1) <= DENSE_LIMIT).
    tolerance : float
        Relative deviation (to max |e| recorded) that still counts as round-off.

    Returns
    -------
    ReplayReport
        ``defined=False`` (with the reason) for families without the recursion or a
        trace that lacks what the replay needs; never raises for those.
    """
    if method not in ("auto", "dense", "agents"):
        raise ValueError(f"method must be auto, dense or agents, got {method!r}")
    report = ReplayReport(path=trace.path, family=trace.family, trial=trace.trial,
                          defined=False, tolerance=float(tolerance))
    # 1. the family's recursion, the system and the recorded run
    compensated = _recursion_kind(trace)
    if compensated is None:
        report.reason = _no_recursion_reason(trace)
        return report
    report.compensated = compensated
    off_grid = _timed_reason(trace)
    if off_grid:
        report.reason = off_grid
        return report
    system, why = trace_system(trace)
    if system is None:
        report.reason = why
        return report
    report.n_agents, report.n_states = system.n_agents, system.n_states
    run, why, stop = _read_run(trace, system)
    if stop:
        report.notes.append(stop)
    if run is None:
        report.reason = why
        return report
    horizon = precision_horizon(
        [run.X], [np.mean(np.sum(run.errors ** 2, axis=2), axis=1)])
    if horizon is not None:
        # errors from the horizon on are rounding of the state: replay the steps before
        report.precision_horizon = horizon
        keep = max(1, horizon)
        run = _Recorded(system, run.X[:keep], [Y[:keep] for Y in run.Ys], run.Xhat[:keep],
                        run.D[:keep], run.edge, run.errors[:keep])
    report.defined = True
    report.steps_replayed = run.K
    report.notes.extend(_status_notes(trace))
    report.recorded = run.errors
    (report.error_scale, report.state_scale, report.roundoff_floor,
     report.effective_tolerance) = _scales(run, tolerance)
    # 2. the effective-delay patterns: the depth tau and how A-hat[k] is built
    tau, report.substitutions, report.nonzero_delay_steps = _delay_patterns(run)
    report.tau = tau
    report.method = _choose_method(method, system.n_agents * system.n_states * (tau + 1))
    # 3. the recursion E_k = A-hat[k] E_{k-1} + b_1 kron eta_k from e_0, both etas
    rec = _recursion(run, compensated, tau)
    eta_exact, eta_paper = _etas(run, rec)
    report.eta_gap = float(np.max(np.abs(eta_exact - eta_paper))) if run.K >= 1 else 0.0
    if not compensated:
        report.state_term = _state_term(run, rec)
    exact_err, paper_err, report.distinct_patterns = _replay_errors(
        run, rec, report.method, eta_exact, eta_paper)
    # 4. compare with the recorded errors
    delays_seen = report.nonzero_delay_steps > 0
    # per step: the round-off of the state so far (ROUNDOFF_STATE_FACTOR eps max_{j<=k}
    # |x_j|), so that a large late state does not excuse early deviations
    tol: float | np.ndarray = report.effective_tolerance
    if report.error_scale > 0:
        running = np.maximum.accumulate(np.max(np.abs(run.X), axis=1))
        floor = ROUNDOFF_STATE_FACTOR * float(np.finfo(float).eps) * running
        tol = np.maximum(float(tolerance), floor / report.error_scale)
    report.exact = _compare("exact", _exact_description(compensated), exact_err, run.errors,
                            report.error_scale, tol, "")
    report.paper = _compare("paper", "LCSYS2022 eq. 11: (I - L_i C_i) nu_k - L_i zeta^i_k",
                            paper_err, run.errors, report.error_scale, tol,
                            _paper_cause(compensated, delays_seen))
    if not report.exact.reproduces:
        report.exact.cause = _exact_cause(report)
    # 5. the verdict
    report.verdict = _verdict(report, compensated, delays_seen)
    return report


def _dense_rows(system: TraceSystem, D: np.ndarray, K: int, tau: int,
                compensated: bool) -> tuple[list[np.ndarray | None], int]:
    """First block rows F[k] of A-hat[k] (k = 1..K), built once per delay pattern."""
    Nn = system.n_agents * system.n_states
    cache: dict[bytes, np.ndarray] = {}
    rows: list[np.ndarray | None] = [None]
    for k in range(1, K + 1):
        key = D[k].tobytes()
        F = cache.get(key)
        if F is None:
            P_eff, r_eff = effective_pattern(system.P, D[k])
            full = augmented_closed_loop(P_eff, system.A, system.C, system.L, r_eff, tau,
                                         compensated=compensated)
            F = np.ascontiguousarray(full[:Nn])
            cache[key] = F
        rows.append(F)
    return rows, len(cache)


def _run_dense(rows: list[np.ndarray | None], e0: np.ndarray, eta: np.ndarray, N: int,
               n: int, tau: int) -> np.ndarray:
    """E_k = A-hat[k] E_{k-1} + b_1 kron eta_k with A-hat[k] = [F[k]; shift]."""
    K = eta.shape[0] - 1
    Nn = N * n
    out = np.zeros((K + 1, N, n))
    out[0] = e0
    E = np.zeros(Nn * (tau + 1))
    E[:Nn] = e0.ravel()
    for k in range(1, K + 1):
        F = rows[k]
        assert F is not None  # rows[0] is the only None
        top = F @ E + eta[k].ravel()
        if tau > 0:
            E[Nn:] = E[:-Nn].copy()
        E[:Nn] = top
        out[k] = top.reshape(N, n)
    return out


def _run_agents(terms: list[list[list[tuple[int, int, float]]]], local: list[np.ndarray],
                blocks: list[np.ndarray], e0: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """The same recursion agent by agent: e^i_k = (I - L_i C_i) sum w B_r e^j_{k-1-r} + eta."""
    K = eta.shape[0] - 1
    out = np.zeros_like(eta)
    out[0] = e0
    for k in range(1, K + 1):
        for i, row in enumerate(terms[k]):
            acc = np.zeros(eta.shape[2])
            for j, r, w in row:
                acc += w * (blocks[r] @ out[k - 1 - r, j])
            out[k, i] = local[i] @ acc + eta[k, i]
    return out


def _compare(name: str, description: str, replayed: np.ndarray, recorded: np.ndarray,
             scale: float, tolerance: float | np.ndarray, cause: str) -> EtaReplay:
    """``tolerance``: relative round-off allowance, one number or one per step."""
    dev = np.abs(replayed - recorded).reshape(replayed.shape[0], -1).max(axis=1)
    rel = dev / scale if scale > 0 else np.where(dev > 0, np.inf, 0.0)
    worst = int(np.argmax(dev)) if dev.size else 0
    above = np.flatnonzero(rel > tolerance)
    max_rel = float(rel.max()) if rel.size else 0.0
    half = replayed.shape[0] // 2
    tail_rep = float(np.mean(np.sum(replayed[half:] ** 2, axis=2)))
    tail_rec = float(np.mean(np.sum(recorded[half:] ** 2, axis=2)))
    return EtaReplay(
        name=name,
        description=description,
        errors=replayed,
        deviation_abs=dev,
        deviation_rel=rel,
        max_abs=float(dev.max()) if dev.size else 0.0,
        max_rel=max_rel,
        worst_step=worst,
        first_step_above=int(above[0]) if above.size else None,
        reproduces=bool(above.size == 0),
        tail_mse_replayed=tail_rep,
        tail_mse_recorded=tail_rec,
        cause=cause if above.size else "",
    )


def _verdict(report: ReplayReport, compensated: bool, delays_seen: bool) -> str:
    exact, paper = report.exact, report.paper
    assert exact is not None and paper is not None
    if not exact.reproduces:
        where = ("" if report.precision_horizon is None else
                 f" before the float64 precision horizon at step {report.precision_horizon}")
        return (f"the exact recursion does NOT reproduce the run{where} (relative deviation "
                f"{exact.max_rel:.2e} > {report.effective_tolerance:.1e}); see the exact "
                "eta's cause")
    head = (f"the augmented recursion with the estimator's exact eta reproduces the recorded "
            f"errors to round-off (relative {exact.max_rel:.1e})")
    if report.precision_horizon is not None:
        head += (f" before the float64 precision horizon at step {report.precision_horizon}"
                 " (later errors are rounding of the state and are not compared)")
    if paper.reproduces:
        why = "no effective delay > 0" if not delays_seen else f"relative {paper.max_rel:.1e}"
        return head + f"; so does the paper's eta ({why})"
    if compensated:
        return (head + f"; with the paper's eta (eq. 11) it deviates by up to "
                f"{paper.max_rel:.2e} of max |e|: eq. (11) is not the error recursion of the "
                "compensating estimator with delays (its noise term is incomplete)")
    return (head + f"; with the paper's eta it deviates by up to {paper.max_rel:.2e} of "
            "max |e|: the delay-tolerant paper's error recursion does not describe the "
            "uncompensated estimator on a moving state (the error has a state-proportional "
            "part)")
