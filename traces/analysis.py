"""Augmented-matrix analytics recomputed from a trace alone (no scenario file).

:func:`analyze_trace` returns a :class:`TraceAnalysis` (``to_dict()`` JSON-ready,
``format_text()`` human-readable) with, from the trace's matrices (P, A, C_i, L_i) and
the effective delays r_ij[k] its agents recorded:

- rho(A-hat) delay-free, rho((I - blockdiag(L_i C_i))(P kron A)) (LCSYS2022 eq. 12);
- the exact spectral radius of the augmented closed loop of every distinct delay
  pattern seen (k >= 1), with how many steps each occurred: blocks P_r kron A^(r+1)
  (LCSYS2022 eq. 9) for the ``compensated`` family, P_r kron A (delay-tolerant eq. 11)
  for ``uncompensated``; a substitution r_ij = -1 puts p_ij on agent i's own delay-0
  term (as the estimator does);
- the papers' bounds at the observed maximum delay tau_obs: LCSYS2022 eq. (26)
  rho((I-KD)(P kron A^(tau+1)))^(1/(tau+1)) and Theorem 1's tau*, the delay-tolerant
  paper's rho(A-hat)^(1/(tau+1)) (its Lemma 5 / Theorem 1; rate (17));
- the realised growth rate (1/k) log ||A-hat[k] ... A-hat[1]|| of the matrix product
  along the trace (renormalised every step, logs accumulated), and exp of it as a
  per-step factor; also over the second half only;
- the empirical decay rate of the recorded error: a least-squares line through
  log(mean_i ||e^i_k||^2) over the transient (step 0 until the MSE first reaches twice
  its steady-state level, the mean of the last quarter), as a per-step factor of the
  error norm exp(slope/2);

each with a verdict. For the ``block`` family the spectral prediction is the
block estimator's own per-step rate, rho((I-KD)(P kron A^(tau+1)))^(1/(tau+1)) with
its period tau+1 (eq. 26's expression is exact for it); ``centralized-kf`` has no
augmented closed loop (only the error decay is reported).

This module imports ``models`` (``netsim.models.augmented``), never ``netsim`` or ``simpy``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from netsim.estimators.registry import RECURSION_BLOCK
from netsim.models.augmented import (
    DEFAULT_TAU_MAX,
    augmented_closed_loop,
    augmented_spectral_radius,
    delay_bound_lcsys,
    delay_bound_tolerant,
    delay_free_closed_loop,
    spectral_radius,
    tau_star_report,
)
from netsim.models.jsonsafe import json_number as _num
from netsim.traces.reader import NOT_USED, Trace
from netsim.traces.replay import TraceSystem, effective_pattern, trace_system

__all__ = [
    "BOUND_SLACK",
    "DECAY_TOLERANCE",
    "PatternStats",
    "DecayFit",
    "TraceAnalysis",
    "analyze_trace",
    "pattern_rho",
    "decay_fit",
    "growth_rates",
]

#: An exact rho counts as violating a bound when it exceeds it by more than this.
BOUND_SLACK = 1e-9
#: The fitted per-step decay factor of the error norm may exceed the spectral
#: prediction by this much and still count as consistent: one trial's transient is
#: noisy (on lcsys2022-heterogeneous, tau 3, rho 0.923, single-trial fits over seeds
#: 0..7 give 0.90..0.95) and the approach to the noise floor flattens the fit.
DECAY_TOLERANCE = 0.03
#: A transient shorter than this many steps counts as "no transient".
MIN_TRANSIENT = 3
#: Threshold of the transient's end: MSE <= TRANSIENT_LEVEL * steady-state MSE.
TRANSIENT_LEVEL = 2.0
#: Entries of the renormalised product below this are set to 0 (no subnormals).
_TINY = 1e-250
#: How many patterns ``format_text`` lists.
TOP_PATTERNS = 5




def _fmt(value: float | None, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.{digits}f}"


# -- pieces ----------------------------------------------------------------------------


def pattern_rho(system: TraceSystem, delays: np.ndarray, compensated: bool) -> float:
    """Exact spectral radius of A-hat for one step's effective delays (shape (N, N)).

    ``netsim.models.augmented.augmented_spectral_radius`` of (P_eff, r_eff) (see
    :func:`netsim.traces.replay.effective_pattern`) at the pattern's own depth (deeper
    augmentation only adds zero eigenvalues).
    """
    P_eff, r_eff = effective_pattern(system.P, delays)
    with np.errstate(over="ignore", invalid="ignore"):
        return float(augmented_spectral_radius(P_eff, system.A, system.C, system.L, r_eff,
                                               tau=None, compensated=compensated))


def growth_rates(system: TraceSystem, patterns: list[np.ndarray], tau: int,
                 compensated: bool) -> tuple[float, float]:
    """Growth rates of the product A-hat[k] ... A-hat[1] along the given delay patterns.

    Returns ``(full, late)``: full = (1/K) log ||A-hat[K] ... A-hat[1]||_2 and
    late = (log ||Pi_K|| - log ||Pi_h||) / (K - h), h = K // 2, Pi_k = A-hat[k] ... A-hat[1]
    (the rate over the second half; the constant prefactor of ||Pi_k|| ~ c rho^k cancels,
    so for a fixed pattern it converges to log rho much faster than ``full``).

    The product is accumulated with the companion structure (A-hat[k] Pi = [F[k] Pi;
    Pi without its last block row]) and renormalised (Frobenius) every step; the logs
    of the scale factors are summed. (NaN, NaN) for an empty sequence.

    ``netsim.models.augmented.closed_loop_sequence_growth`` computes ``full`` for patterns on a
    fixed P; it is not used here because a start-up step with a substitution (r = -1)
    moves p_ij onto p_ii, i.e. changes P for that step.
    """
    K = len(patterns)
    if K == 0:
        return math.nan, math.nan
    N, n = system.n_agents, system.n_states
    Nn = N * n
    dim = Nn * (tau + 1)
    cache: dict[bytes, np.ndarray] = {}
    Pi = np.eye(dim)
    log_sum = 0.0
    half = K // 2
    log_half = 0.0
    for k, d in enumerate(patterns, start=1):
        key = d.tobytes()
        F = cache.get(key)
        if F is None:
            P_eff, r_eff = effective_pattern(system.P, d)
            F = augmented_closed_loop(P_eff, system.A, system.C, system.L, r_eff, tau,
                                      compensated=compensated)[:Nn]
            cache[key] = F
        top = F @ Pi
        if tau > 0:
            Pi[Nn:] = Pi[:-Nn].copy()
        Pi[:Nn] = top
        scale = float(np.linalg.norm(Pi))
        if not np.isfinite(scale) or scale == 0.0:
            value = -math.inf if scale == 0.0 else math.inf
            return value, value
        log_sum += math.log(scale)
        Pi /= scale
        # flush what the renormalisation pushed towards subnormal numbers (which make
        # every later product orders of magnitude slower)
        Pi[np.abs(Pi) < _TINY] = 0.0
        if k == half:
            log_half = log_sum + math.log(float(np.linalg.norm(Pi, 2)))
    log_full = log_sum + math.log(float(np.linalg.norm(Pi, 2)))
    late = (log_full - log_half) / (K - half) if K > half else math.nan
    return log_full / K, late


@dataclass
class DecayFit:
    """Least-squares fit of log(MSE) over the transient.

    Attributes
    ----------
    transient : bool
        False when the MSE is already within TRANSIENT_LEVEL x steady state before
        MIN_TRANSIENT steps (or never comes down to it: growing error).
    start, end : int
        Fitted steps start..end (inclusive).
    slope : float
        Slope of log(MSE) per step.
    factor : float
        exp(slope / 2): per-step factor of the error norm.
    steady_mse : float
        Mean MSE over the last quarter.
    tail_factor : float
        exp(slope / 2) of a line through log(MSE) over the second half (about 1 at
        steady state, > 1 for a growing error).
    excess_factor : float
        exp(slope / 2) of the same fit of log(MSE - steady_mse) (the noise floor
        subtracted; less biased towards 1 than ``factor``), NaN without transient.
    """

    transient: bool
    start: int
    end: int
    slope: float
    factor: float
    steady_mse: float
    tail_factor: float
    excess_factor: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        return {
            "transient": self.transient,
            "start": self.start,
            "end": self.end,
            "slope": _num(self.slope),
            "factor": _num(self.factor),
            "steady_mse": _num(self.steady_mse),
            "tail_factor": _num(self.tail_factor),
            "excess_factor": _num(self.excess_factor),
        }


def decay_fit(mse: np.ndarray) -> DecayFit:
    """Fit the decay of a network MSE series (index = step); see :class:`DecayFit`."""
    mse = np.asarray(mse, dtype=float)
    good = np.isfinite(mse) & (mse > 0)
    last = int(np.flatnonzero(good)[-1]) if np.any(good) else -1
    series = mse[: last + 1]
    if last < 1:
        return DecayFit(False, 0, max(last, 0), math.nan, math.nan, math.nan, math.nan)
    q = max(1, len(series) // 4)
    steady = float(np.nanmean(series[-q:]))
    below = np.flatnonzero(series <= TRANSIENT_LEVEL * steady)
    end = int(below[0]) if below.size else -1
    half = series[len(series) // 2:]
    tail = math.nan
    ok = np.isfinite(half) & (half > 0)
    if np.sum(ok) >= 2:
        steps = np.arange(len(half))[ok]
        tail = float(np.exp(np.polyfit(steps, np.log(half[ok]), 1)[0] / 2))
    if end < MIN_TRANSIENT:
        return DecayFit(False, 0, max(end, 0), math.nan, math.nan, steady, tail)
    seg = series[: end + 1]
    ok = np.isfinite(seg) & (seg > 0)
    steps = np.arange(end + 1)[ok]
    slope = float(np.polyfit(steps, np.log(seg[ok]), 1)[0])
    excess = seg - steady
    ok = np.isfinite(excess) & (excess > 0)
    excess_factor = math.nan
    if np.sum(ok) >= 2:
        steps = np.arange(end + 1)[ok]
        excess_factor = float(np.exp(np.polyfit(steps, np.log(excess[ok]), 1)[0] / 2))
    return DecayFit(True, 0, end, slope, float(np.exp(slope / 2)), steady, tail,
                    excess_factor)


@dataclass
class PatternStats:
    """One distinct delay pattern r[k] and its augmented closed loop.

    ``delays`` maps link ``"j->i"`` to r_ij (-1: i substituted its own estimate).
    """

    delays: dict[str, int]
    count: int
    first_step: int
    last_step: int
    depth: int
    substituted: bool
    rho: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "delays": dict(self.delays),
            "count": self.count,
            "first_step": self.first_step,
            "last_step": self.last_step,
            "depth": self.depth,
            "substituted": self.substituted,
            "rho": _num(self.rho),
        }

    def describe(self) -> str:
        parts = [f"{link}:{'sub' if r < 0 else r}" for link, r in self.delays.items()]
        return " ".join(parts)


@dataclass
class TraceAnalysis:
    """Result of :func:`analyze_trace` (see the module docstring for the definitions).

    Attributes
    ----------
    path, family : str
    trial : int or None
    steps : int
        Last step recorded.
    n_agents, n_states : int
    compensated : bool or None
        Family's blocks: A^(r+1) (True), A (False), None (no augmented recursion).
    rho_delay_free : float or None
    tau_obs : int or None
        Largest effective delay r_ij[k] >= 0 recorded (None: no delays recorded).
    tau_star : int or None
        LCSYS2022 Theorem 1 (None: fails already at tau = 0).
    tau_star_scan : int
        Largest tau scanned for tau*.
    tau_star_isolated : tuple of int
        Passing tau above tau* + 1 (Theorem 1's condition is not monotone in tau when A
        has negative or complex unstable eigenvalues; ``netsim.models.augmented.TauStar``).
    bound_lcsys_eq26, bound_delay_tolerant : float or None
        At tau_obs.
    patterns : list of PatternStats
        Every distinct pattern, most frequent first (consensus families).
    n_patterns : int
    rho_exact_max : float or None
        Max over the delay patterns, i.e. those without a substitution (the start-up
        patterns, where some agent had nothing from a neighbour yet, are reported
        apart: they are not delay patterns of the papers). Over all patterns if every
        pattern has a substitution.
    rho_startup_max : float or None
        Max over the start-up patterns (with a substitution r = -1).
    startup_steps : int
        Steps whose pattern has a substitution.
    rho_exact_final : float or None
        Of the last step's pattern (for fixed delays: the realised delays' exact rho).
    rho_exact_weighted : float or None
        Step-weighted mean of the patterns' rho.
    growth_rate, growth_factor : float or None
        (1/K) log ||A-hat[K] ... A-hat[1]|| and exp of it.
    tail_growth_rate, tail_growth_factor : float or None
        The rate over the second half, (log ||Pi_K|| - log ||Pi_{K/2}||) / (K - K/2)
        (see :func:`growth_rates`; for fixed delays it converges to log rho fastest).
    block_period : int or None
        ``block`` family: update period tau+1.
    spectral_prediction : float or None
        Per-step factor the spectral analysis predicts for the error norm (max exact rho;
        for ``block`` its eq. (26)-type rate).
    decay : DecayFit or None
    verdicts : dict of str -> str
        ``stability``, ``eq26``, ``theorem1``, ``delay_tolerant``, ``growth``, ``decay``
        (those that apply).
    notes : list of str
    """

    path: str
    family: str
    trial: int | None
    steps: int
    n_agents: int
    n_states: int
    compensated: bool | None = None
    rho_delay_free: float | None = None
    tau_obs: int | None = None
    tau_star: int | None = None
    tau_star_scan: int = 0
    tau_star_isolated: tuple[int, ...] = ()
    bound_lcsys_eq26: float | None = None
    bound_delay_tolerant: float | None = None
    patterns: list[PatternStats] = field(default_factory=list)
    n_patterns: int = 0
    rho_exact_max: float | None = None
    rho_startup_max: float | None = None
    startup_steps: int = 0
    rho_exact_final: float | None = None
    rho_exact_weighted: float | None = None
    growth_rate: float | None = None
    growth_factor: float | None = None
    tail_growth_rate: float | None = None
    tail_growth_factor: float | None = None
    block_period: int | None = None
    spectral_prediction: float | None = None
    decay: DecayFit | None = None
    mse: np.ndarray | None = field(default=None, repr=False)
    verdicts: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def __repr__(self) -> str:
        """One line (``format_text()`` gives the report)."""
        rho = "-" if self.rho_exact_max is None else f"{self.rho_exact_max:.6g}"
        return (f"<TraceAnalysis {self.path}: {self.family}, trial {self.trial}, steps "
                f"0..{self.steps}, tau_obs {self.tau_obs}, rho max {rho}, "
                f"{len(self.patterns)} pattern(s), verdicts on {', '.join(self.verdicts)}>")

    @property
    def max_pattern(self) -> PatternStats | None:
        """The delay pattern (no substitution, if any) with the largest rho."""
        pool = [p for p in self.patterns if not p.substituted] or self.patterns
        if not pool:
            return None
        return max(pool, key=lambda p: (p.rho, p.count))

    def to_dict(self) -> dict[str, Any]:
        worst = self.max_pattern
        return {
            "path": self.path,
            "family": self.family,
            "trial": self.trial,
            "steps": self.steps,
            "n_agents": self.n_agents,
            "n_states": self.n_states,
            "compensated": self.compensated,
            "rho_delay_free": _num(self.rho_delay_free),
            "tau_obs": self.tau_obs,
            "tau_star": self.tau_star,
            "tau_star_scan": self.tau_star_scan,
            "tau_star_isolated": list(self.tau_star_isolated),
            "bound_lcsys_eq26": _num(self.bound_lcsys_eq26),
            "bound_delay_tolerant": _num(self.bound_delay_tolerant),
            "n_patterns": self.n_patterns,
            "patterns": [p.to_dict() for p in self.patterns],
            "max_pattern": None if worst is None else worst.to_dict(),
            "rho_exact_max": _num(self.rho_exact_max),
            "rho_startup_max": _num(self.rho_startup_max),
            "startup_steps": self.startup_steps,
            "rho_exact_final": _num(self.rho_exact_final),
            "rho_exact_weighted": _num(self.rho_exact_weighted),
            "growth_rate": _num(self.growth_rate),
            "growth_factor": _num(self.growth_factor),
            "tail_growth_rate": _num(self.tail_growth_rate),
            "tail_growth_factor": _num(self.tail_growth_factor),
            "block_period": self.block_period,
            "spectral_prediction": _num(self.spectral_prediction),
            "decay": None if self.decay is None else self.decay.to_dict(),
            "verdicts": dict(self.verdicts),
            "notes": list(self.notes),
        }

    def format_text(self) -> str:
        trial = "?" if self.trial is None else self.trial
        lines = [f"analysis {self.path}"]
        lines.append(f"  family {self.family or '?'}   trial {trial}   steps 0..{self.steps}   "
                     f"agents {self.n_agents}   states {self.n_states}")
        lines.append(f"  rho(A-hat) delay-free {_fmt(self.rho_delay_free)}")
        if self.tau_obs is not None:
            ts = "none (fails at tau = 0)" if self.tau_star is None else str(self.tau_star)
            if self.tau_star is not None and self.tau_star >= self.tau_star_scan:
                ts += f" (never fails up to {self.tau_star_scan})"
            lines.append(
                f"  tau_obs {self.tau_obs}   tau* (Theorem 1) {ts}   "
                f"eq. (26) bound {_fmt(self.bound_lcsys_eq26)}   "
                f"delay-tolerant bound {_fmt(self.bound_delay_tolerant)}"
            )
        if self.patterns:
            blocks = "P_r kron A^(r+1)" if self.compensated else "P_r kron A"
            lines.append(
                f"  delay patterns ({blocks}): {self.n_patterns} distinct; exact rho max "
                f"{_fmt(self.rho_exact_max)}, final {_fmt(self.rho_exact_final)}, "
                f"step-weighted mean {_fmt(self.rho_exact_weighted)}"
            )
            if self.startup_steps:
                lines.append(
                    f"  start-up patterns (own estimate substituted, nothing arrived yet): "
                    f"{self.startup_steps} steps, max rho {_fmt(self.rho_startup_max)} "
                    "(excluded from the max and the verdicts)"
                )
            lines.append(f"    {'steps':>6} {'first':>6} {'rho':>8}  pattern (j->i:r, sub = "
                         "own estimate substituted)")
            shown = self.patterns[:TOP_PATTERNS]
            worst = self.max_pattern
            for p in shown:
                lines.append(f"    {p.count:>6} {p.first_step:>6} {_fmt(p.rho):>8}  "
                             f"{p.describe()}")
            if worst is not None and worst not in shown:
                lines.append(f"    {worst.count:>6} {worst.first_step:>6} {_fmt(worst.rho):>8}  "
                             f"{worst.describe()}  (max rho)")
            if len(self.patterns) > len(shown) + (worst not in shown):
                lines.append(f"    ... {len(self.patterns)} patterns in to_dict()['patterns']")
        if self.growth_rate is not None:
            lines.append(
                f"  realised growth (1/k) log||A-hat[k]...A-hat[1]||: {self.growth_rate:.5f} "
                f"(factor {_fmt(self.growth_factor)}/step); second half "
                f"{self.tail_growth_rate:.5f} (factor {_fmt(self.tail_growth_factor)}/step)"
            )
        if self.decay is not None:
            d = self.decay
            # a steady MSE only where the second half does not grow: else the mean MSE of
            # the last quarter is just that
            grows = not math.isnan(d.tail_factor) and d.tail_factor > 1.0 + 1e-3
            level = (f"last-quarter mean MSE {d.steady_mse:.3e} (not steady: the second half "
                     "grows)" if grows else f"steady-state MSE {d.steady_mse:.3e}")
            if d.transient:
                lines.append(
                    f"  error decay: steps {d.start}..{d.end}, ||e|| factor {d.factor:.4f}/step "
                    f"(log-MSE slope {d.slope:.5f}; floor subtracted "
                    f"{_fmt(d.excess_factor)}/step); {level}; "
                    f"second-half trend {_fmt(d.tail_factor)}/step"
                )
            else:
                lines.append(
                    f"  error decay: no transient; {level}; "
                    f"second-half trend {_fmt(d.tail_factor)}/step"
                )
        if self.verdicts:
            lines.append("verdicts")
            for name, text in self.verdicts.items():
                lines.append(f"  {name}: {text}")
        lines.extend(f"  note: {n}" for n in self.notes)
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format_text()


# -- analysis --------------------------------------------------------------------------


def _network_mse(trace: Trace) -> np.ndarray:
    sq = trace.squared_errors()
    if sq.size == 0:
        return np.zeros(0)
    with np.errstate(invalid="ignore"):
        out = np.full(sq.shape[0], np.nan)
        rows = np.any(np.isfinite(sq), axis=1)
        out[rows] = np.nanmean(sq[rows], axis=1)
    return out


def analyze_trace(trace: Trace, *, tau_max: int = DEFAULT_TAU_MAX,
                  decay_tolerance: float = DECAY_TOLERANCE) -> TraceAnalysis:
    """Analyse a trace (see the module docstring); never raises for a readable trace.

    Parameters
    ----------
    trace : Trace
    tau_max : int
        Largest tau scanned for Theorem 1's tau*.
    decay_tolerance : float
        Slack of the decay-vs-spectrum verdict.
    """
    steps = trace.steps
    out = TraceAnalysis(path=trace.path, family=trace.family, trial=trace.trial,
                        steps=steps[-1] if steps else -1, n_agents=trace.n_agents,
                        n_states=trace.n_states, tau_star_scan=int(tau_max))
    family = trace.family
    if trace.truncated:
        out.notes.append("the trace is truncated (writer never finished); analysed the "
                         "recovered steps")
    status = (trace.status or {}).get("status")
    if status and status != "complete":
        out.notes.append(f"run status {status!r}")
    mse = _network_mse(trace)
    out.mse = mse
    out.decay = decay_fit(mse) if mse.size else None

    if trace.error_recursion is None:
        # the gains and bounds in the trace are the consensus estimators'; they say
        # nothing about a family that declares no augmented error recursion
        out.notes.append(f"family {family or '?'!r} declares no augmented error recursion; "
                         "only the error decay is reported")
        _decay_verdict(out, decay_tolerance)
        return out
    system, why = trace_system(trace)
    if system is None:
        out.notes.append(f"no spectral analysis: {why}")
        _decay_verdict(out, decay_tolerance)
        return out
    P, A, C, L = system.P, system.A, system.C, system.L
    out.rho_delay_free = spectral_radius(delay_free_closed_loop(P, A, C, L))
    out.verdicts["delay_free"] = (
        f"rho(A-hat) delay-free {out.rho_delay_free:.4f} "
        + ("< 1: the delay-free design is Schur stable" if out.rho_delay_free < 1
           else ">= 1: the gains do not stabilise even the delay-free estimator")
    )

    N = system.n_agents
    D = trace.effective_delays()
    edge = (P != 0) & ~np.eye(N, dtype=bool)
    if D.shape[1:] != (N, N):
        if trace.error_recursion is not None:
            out.notes.append("the effective delays do not match P's size; delays ignored")
        D = np.full((0, N, N), NOT_USED, dtype=np.int32)
    recorded = D[1:][np.broadcast_to(edge, D[1:].shape)] if D.shape[0] > 1 else np.zeros(0)
    positive = recorded[recorded >= 0]
    if positive.size:
        out.tau_obs = int(positive.max())
    else:
        delivered = [int(m.delay_steps) for (j, i) in trace.links
                     for m in trace.link_events(j, i, "delivered")]
        if delivered:
            out.tau_obs = max(delivered)
            out.notes.append("no effective delays recorded; tau_obs from the links' "
                             "delivered messages")
    if out.tau_obs is not None:
        t = out.tau_obs
        with np.errstate(over="ignore", invalid="ignore"):
            report = tau_star_report(P, A, C, L, tau_max=tau_max)
            out.bound_lcsys_eq26 = float(delay_bound_lcsys(P, A, C, L, t))
        out.tau_star = report.contiguous
        out.tau_star_isolated = tuple(int(v) for v in report.isolated)
        out.bound_delay_tolerant = float(delay_bound_tolerant(P, A, C, L, t))

    if trace.recursion_compensated is not None:
        _consensus(out, system, D, edge, trace.recursion_compensated)
    elif trace.error_recursion == RECURSION_BLOCK:
        _block(out, system, D, edge)
    else:
        out.notes.append(
            f"family {family or '?'!r}: augmented recursion {trace.error_recursion!r} is "
            "not analysed here; only the delay-free rho, the bounds and the error decay "
            "are reported"
        )
    _bound_verdicts(out)
    _decay_verdict(out, decay_tolerance)
    return out


def _consensus(out: TraceAnalysis, system: TraceSystem, D: np.ndarray, edge: np.ndarray,
               compensated: bool) -> None:
    out.compensated = compensated
    N = system.n_agents
    seq: list[np.ndarray] = []
    for k in range(1, D.shape[0]):
        if np.any(edge & (D[k] == NOT_USED)):
            out.notes.append(f"effective delays incomplete from step {k}; patterns and "
                             f"growth use steps 1..{k - 1}")
            break
        seq.append(np.where(edge, D[k], 0).astype(np.int32))
    if not seq:
        out.notes.append("no step with recorded effective delays")
        return
    counts: Counter[bytes] = Counter()
    first: dict[bytes, int] = {}
    last: dict[bytes, int] = {}
    example: dict[bytes, np.ndarray] = {}
    for k, d in enumerate(seq, start=1):
        key = d.tobytes()
        counts[key] += 1
        first.setdefault(key, k)
        last[key] = k
        example.setdefault(key, d)
    links = [(int(j), int(i)) for i, j in zip(*np.nonzero(edge), strict=True)]
    links.sort()
    rho_of: dict[bytes, float] = {}
    for key in counts:
        d = example[key]
        rho_of[key] = pattern_rho(system, d, compensated)
        out.patterns.append(PatternStats(
            delays={f"{j}->{i}": int(d[i, j]) for j, i in links},
            count=counts[key],
            first_step=first[key],
            last_step=last[key],
            depth=int(max(0, d[edge].max())) if np.any(edge) else 0,
            substituted=bool(np.any(d[edge] < 0)),
            rho=rho_of[key],
        ))
    out.patterns.sort(key=lambda p: (-p.count, p.first_step))
    out.n_patterns = len(out.patterns)
    startup = {key for key in counts if np.any(example[key][edge] < 0)}
    delay_keys = [key for key in counts if key not in startup] or list(counts)
    if len(delay_keys) == len(counts) and startup:
        out.notes.append("every pattern has a substitution; the max is over all of them")
    out.rho_exact_max = max(rho_of[k] for k in delay_keys)
    if startup:
        out.rho_startup_max = max(rho_of[k] for k in startup)
        out.startup_steps = sum(counts[k] for k in startup)
    out.rho_exact_final = rho_of[seq[-1].tobytes()]
    out.rho_exact_weighted = float(sum(rho_of[k] * counts[k] for k in delay_keys)
                                   / sum(counts[k] for k in delay_keys))
    out.spectral_prediction = out.rho_exact_max
    tau = max(0, int(max(int(d[edge].max()) for d in seq))) if np.any(edge) else 0
    with np.errstate(over="ignore", invalid="ignore"):
        out.growth_rate, out.tail_growth_rate = growth_rates(system, seq, tau, compensated)
    out.growth_factor = _exp(out.growth_rate)
    out.tail_growth_factor = _exp(out.tail_growth_rate)
    del N
    if not compensated:
        out.notes.append(
            "uncompensated: the patterns' matrices (delay-tolerant eq. 11) are the "
            "homogeneous part of the estimate recursion; the error of a moving state also "
            "contains (A^(r+1) - A) x_{k-1-r} (see traces.replay), so they do not bound it"
        )


def _block(out: TraceAnalysis, system: TraceSystem, D: np.ndarray, edge: np.ndarray) -> None:
    used = [k for k in range(1, D.shape[0]) if np.any(edge & (D[k] != NOT_USED))]
    if len(used) < 2:
        out.notes.append("block family: fewer than two block updates recorded")
        return
    gaps = Counter(b - a for a, b in zip(used, used[1:], strict=False))
    period = gaps.most_common(1)[0][0]
    out.block_period = period
    rate = float(delay_bound_lcsys(system.P, system.A, system.C, system.L, period - 1))
    out.spectral_prediction = rate
    out.notes.append(
        f"block family (LCSYS2022 eqs. 15-16): updates every {period} steps, a delay-free "
        f"estimator with A^{period}; its per-step rate rho((I-KD)(P kron A^{period}))^(1/"
        f"{period}) = {rate:.4f} (the eq. (26) expression at tau = {period - 1})"
    )


def _exp(value: float | None) -> float | None:
    if value is None or math.isnan(value):
        return None
    if value > 700:
        return math.inf
    return math.exp(value)


def _cmp(exact: float, bound: float, what: str) -> str:
    if exact > bound + BOUND_SLACK:
        return f"VIOLATED: exact {exact:.6f} > {what} {bound:.6f}"
    return f"respected: exact {exact:.6f} <= {what} {bound:.6f}"


def _bound_verdicts(out: TraceAnalysis) -> None:
    v = out.verdicts
    if out.rho_exact_max is not None:
        worst = out.max_pattern
        where = "" if worst is None else f" (pattern first at step {worst.first_step})"
        if out.rho_exact_max < 1:
            v["stability"] = (f"exact max rho {out.rho_exact_max:.6f} < 1: stable (every delay "
                              "pattern seen is Schur stable"
                              + (", start-up excluded)" if out.startup_steps else ")"))
        else:
            v["stability"] = (f"exact max rho {out.rho_exact_max:.6f} >= 1{where}: a delay "
                              "pattern seen is not Schur stable")
    if out.tau_obs is None:
        return
    t = out.tau_obs
    own = {True: "eq26", False: "delay_tolerant"}.get(out.compensated)  # type: ignore[arg-type]
    if out.bound_lcsys_eq26 is not None:
        claim = ("the bound LCSYS2022 claims for this estimator" if own == "eq26"
                 else "claimed for the compensating estimator; shown for comparison")
        if out.rho_exact_max is not None:
            text = _cmp(out.rho_exact_max, out.bound_lcsys_eq26,
                        f"eq. (26) bound at tau_obs = {t}")
        else:
            text = f"eq. (26) bound at tau_obs = {t}: {out.bound_lcsys_eq26:.6f}"
        v["eq26"] = f"{text} ({claim})"
    if out.bound_delay_tolerant is not None:
        claim = ("the bound the delay-tolerant paper claims for this estimator"
                 if own == "delay_tolerant"
                 else "claimed for the uncompensated estimator; shown for comparison")
        if out.rho_exact_max is not None:
            text = _cmp(out.rho_exact_max, out.bound_delay_tolerant,
                        f"rho(A-hat)^(1/(tau_obs+1)) at tau_obs = {t}")
        else:
            text = f"rho(A-hat)^(1/(tau_obs+1)) at tau_obs = {t}: {out.bound_delay_tolerant:.6f}"
        v["delay_tolerant"] = f"{text} ({claim})"
        if out.bound_delay_tolerant < 1 and out.rho_delay_free is not None \
                and out.rho_delay_free < 1 and out.bound_lcsys_eq26 is not None \
                and out.bound_lcsys_eq26 >= 1:
            v["delay_tolerant"] += ("; note it is < 1 for every tau while eq. (26) at this "
                                    f"tau is {out.bound_lcsys_eq26:.4f} >= 1")
    if out.tau_star is None:
        v["theorem1"] = ("tau* undefined: rho((I-KD)(P kron A)) >= 1 already at tau = 0; "
                         "Theorem 1 predicts nothing")
    elif t <= out.tau_star:
        pred = f"tau_obs {t} <= tau* {out.tau_star}: Theorem 1 predicts stable tracking"
        if out.compensated is True and out.rho_exact_max is not None:
            pred += ("; exact: stable (consistent)" if out.rho_exact_max < 1
                     else f"; CONTRADICTED: exact max rho {out.rho_exact_max:.6f} >= 1")
        elif out.compensated is False:
            pred += " (the theorem is about the compensating estimator)"
        v["theorem1"] = pred
    else:
        v["theorem1"] = (f"tau_obs {t} > tau* {out.tau_star}: outside Theorem 1's sufficient "
                         "condition (no prediction)")
        if t in out.tau_star_isolated:
            v["theorem1"] += (f"; the condition holds again at the isolated tau = {t} "
                              "(not monotone in tau), which the theorem does not cover")
    if out.growth_rate is not None and out.rho_exact_max is not None:
        g = out.growth_factor if out.growth_factor is not None else math.nan
        gt = out.tail_growth_factor if out.tail_growth_factor is not None else math.nan
        parts = [f"realised growth factor {g:.6f}/step over all steps, {gt:.6f}/step over "
                 "the second half (compared below)"]
        if gt <= out.rho_exact_max + 1e-3:
            parts.append(f"<= max exact rho {out.rho_exact_max:.6f} (+1e-3): consistent")
        else:
            parts.append(f"> max exact rho {out.rho_exact_max:.6f}: the switching between "
                         "patterns makes the product grow faster than any single pattern")
        for name, bound in (("eq. (26) bound", out.bound_lcsys_eq26),
                            ("delay-tolerant bound", out.bound_delay_tolerant)):
            if bound is not None:
                rel = "<=" if gt <= bound + 1e-3 else "EXCEEDS"
                parts.append(f"{rel} {name} {bound:.6f}")
        parts.append("stable product" if g < 1 else "GROWING product")
        v["growth"] = "; ".join(parts)


def _decay_verdict(out: TraceAnalysis, tol: float) -> None:
    d = out.decay
    if d is None:
        return
    pred = out.spectral_prediction
    if not d.transient:
        text = "no transient (the MSE is within 2x its steady level from the start"
        if d.tail_factor is not None and not math.isnan(d.tail_factor) and d.tail_factor > 1:
            text = "no transient (the MSE never comes down to 2x its final level"
        text += f"); second-half trend {_fmt(d.tail_factor)}/step"
        if d.tail_factor > 1.0 + 1e-3 and not math.isnan(d.tail_factor):
            text += ": the ERROR GROWS"
            if pred is not None and pred < 1:
                text += (f" although the spectral prediction is {pred:.4f} < 1 "
                         "(the augmented matrix does not govern this error)")
        out.verdicts["decay"] = text
        return
    text = f"error norm decays by {d.factor:.4f}/step over steps {d.start}..{d.end}"
    if pred is None:
        text += " (no spectral prediction for this family)"
    elif d.factor <= pred + tol:
        text += f" <= spectral prediction {pred:.4f} + {tol:g}: consistent"
    else:
        text += (f" > spectral prediction {pred:.4f} + {tol:g}: INCONSISTENT (slower than "
                 "the spectrum predicts)")
    if not math.isnan(d.tail_factor) and d.tail_factor > 1.0 + 1e-3:
        text += f"; but the second half GROWS ({d.tail_factor:.4f}/step)"
    out.verdicts["decay"] = text
