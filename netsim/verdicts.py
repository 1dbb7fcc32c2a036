"""Verdicts on a run's error: stable, diverging, unbounded, undecided, diverged.

One rule, used by ``netsim run`` (:func:`netsim.runner.run_monte_carlo`), the benchmark
cells and sweeps (:mod:`netsim.bench.cells`) and ``netsim replay``; the words are defined
for runs and claims alike in :data:`VERDICT_TABLE`.

The rule
--------
1. **Blow-up.** A trial whose error exceeded the divergence threshold or became
   non-finite is ``diverged`` (printed ``diverged at step k``); nothing else is judged.
2. **Precision horizon** (:func:`precision_horizon`). On an unstable plant the state
   grows like rho(A)^k while the estimation error stays of the size of the noise; the
   error x_k - x-hat_k is a difference of two numbers of size ``|x_k|``, so its rounding
   is about ``eps |x_k|``. The horizon is the first step where
   ``HORIZON_FACTOR * eps * max|x_k|`` (over the trials) reaches ``HORIZON_FRACTION`` of
   the error scale (the RMS error over the early steady state, steps K0/2..K0 of the
   steps before the state grows by 1e6 of its start, or the first half of the run).
   Errors from the horizon on are not trusted: the verdict is decided on the steps
   before it, and the report says "beyond the float64 precision horizon at step k".
3. **Exact analysis** (:mod:`netsim.models.jointsystem`). Where the family's error is
   linear under the run's fixed delays (compensating, uncompensated and block-update
   estimators; no losses, no time-varying topology), the joint linear system of plant
   state and error decides: growth ``geometric`` (rho > 1, from the error recursion or
   from a growing plant mode that forces the error, e.g. the uncompensated estimator's
   (A^(r+1) - A) x term) is ``diverging``; ``polynomial`` (rho = 1: a unit-modulus mode
   driven by noise, or a Jordan block) is ``unbounded``; ``bounded`` is ``stable``. The
   measured growth is still estimated and reported next to it.
4. **Measured growth** (:func:`estimate_growth`), everywhere else. Per trial, a
   least-squares line through log MSE (the trial's network MSE) over the second half of
   the trusted steps gives a slope b_t (log growth per step), and a line through log MSE
   against log k a power p_t. The estimates are the means over trials; a standard error
   is the larger of (a) the spread across trials, s / sqrt(T) (T >= 2), and (b) the
   pooled within-trial standard error of the fits, each from the fit's residuals with the
   effective sample size W (1 - r1) / (1 + r1) (r1: lag-1 autocorrelation of the
   residuals), divided by sqrt(T). Over the W fitted steps the log growth is G = b W with
   uncertainty u = Z * se * W (Z = ``Z_SCORE``):

   * ``diverging`` when G - u > log(GROWTH_TOLERANCE): even at its lower confidence
     bound the MSE trend grows by more than x2 over the window (geometric growth);
   * ``unbounded`` when the power's lower bound p - Z se_p exceeds ``POWER_MIN``: the MSE
     grows at least like k^0.5 (e.g. linearly), and the geometric test did not fire;
   * ``stable`` when G < log(TREND_TOLERANCE) and G + u < log(STABLE_TOLERANCE): the
     fitted trend grows by less than x1.25 over the window (stricter than the diverging
     tolerance: a trend that visibly grows is never stable) and the evidence bounds its
     growth below x1.5;
   * ``undecided`` otherwise, and also when fewer than ``MIN_WINDOW`` steps can be
     fitted (a short run, or a precision horizon early in it).

The growth factor per step is reported as exp(b) with the band exp(b +- Z se). A steady
MSE belongs to stable runs only (:func:`has_steady_state`); other runs report their last
trusted MSE and the growth.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from netsim.models.precision import HORIZON_FACTOR, HORIZON_FRACTION, precision_horizon

__all__ = [
    "GROWTH_TOLERANCE",
    "STABLE_TOLERANCE",
    "TREND_TOLERANCE",
    "POWER_MIN",
    "VERDICT_RULES",
    "VERDICT_TABLE",
    "Z_SCORE",
    "MIN_WINDOW",
    "HORIZON_FACTOR",
    "HORIZON_FRACTION",
    "STABLE",
    "DIVERGING",
    "UNBOUNDED",
    "UNDECIDED",
    "DIVERGED",
    "GrowthEstimate",
    "Verdict",
    "estimate_growth",
    "precision_horizon",
    "judge",
    "horizon_text",
    "steady_slice",
    "BEYOND_HORIZON",
    "beyond_horizon",
    "trusted_values",
    "has_steady_state",
    "analysis_verdict",
]

#: Factor by which the MSE trend may grow over the fitted window (the second half of
#: the trusted steps) and still count as not diverging.
GROWTH_TOLERANCE = 2.0
#: The upper confidence bound of the MSE trend's growth over the window must stay below
#: this factor for a measured ``stable`` (stricter than GROWTH_TOLERANCE) ...
STABLE_TOLERANCE = 1.5
#: ... and the fitted trend's growth itself below this stricter one: a trend that
#: visibly grows is at best ``undecided``.
TREND_TOLERANCE = 1.25
#: Lower confidence bound of the fitted power p (MSE ~ k^p over the window) above which
#: the measured growth is ``unbounded`` (polynomial).
POWER_MIN = 0.5
#: Version of the verdict rule (part of the benchmark cells' keys: a results file
#: written under another rule is not reused).
VERDICT_RULES = 2
#: Standard errors between the estimate and the tolerance before a verdict is given.
Z_SCORE = 3.0
#: Fewest fitted steps (the second half of the trusted steps) for any verdict.
MIN_WINDOW = 8

STABLE = "stable"
DIVERGING = "diverging"
UNBOUNDED = "unbounded"
UNDECIDED = "undecided"
DIVERGED = "diverged"

#: Every verdict word of runs and claims, in one table (``netsim run --help``,
#: ``netsim claims --help``, docs/concepts/verdicts.rst).
VERDICT_TABLE = """\
verdicts of runs (netsim run, bench, replay)
  stable              the MSE stays bounded: by exact analysis (fixed delays: the joint
                      system of plant state and error has rho < 1), else the measured MSE
                      trend over the second half grows by < x1.25, and < x1.5 beyond doubt
  diverging           geometric growth: exact rho > 1 (the MSE grows as rho^2 per step),
                      else the measured trend grows by more than x2, beyond doubt
  unbounded           growth slower than geometric (e.g. linear): a unit-modulus mode
                      driven by noise, else a measured power law k^p with p > 0.5
  undecided           the evidence decides nothing (too few steps or trials, noisy MSE)
  diverged at step k  a trial's error exceeded the divergence threshold or overflowed
  (a steady MSE is printed for stable runs only; the others show their last MSE)
verdicts of claims (netsim claims)
  refuted             a counterexample, verified by exact analysis and by simulation
  proved for this instance
                      an exact computation shows the claim holds for this instance
  no counterexample in M instances of <family> (seed s)
                      a seeded search of M drawn instances found none
  undecided           and why: e.g. a search cut short by its budget, a paper's
                      unprinted system"""

_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class GrowthEstimate:
    """Per-step growth of the MSE, estimated over trials and steps.

    Attributes
    ----------
    log_slope : float
        Mean over trials of the fitted slope of log MSE per step (NaN: no fit).
    stderr : float
        Its standard error (see the module docstring), inf when it cannot be estimated.
    window : tuple of int
        First and one-past-last step of the fitted window.
    trials : int
        Trials fitted.
    power : float
        Mean over trials of the fitted slope of log MSE against log k over the same
        window: the p of MSE ~ k^p (NaN: no fit).
    power_stderr : float
        Its standard error (as for ``stderr``).
    """

    log_slope: float
    stderr: float
    window: tuple[int, int]
    trials: int
    power: float = math.nan
    power_stderr: float = math.inf

    @property
    def steps(self) -> int:
        """Number of fitted steps W."""
        return self.window[1] - self.window[0]

    @property
    def rate(self) -> float:
        """exp(log_slope): the fitted per-step MSE growth factor."""
        return _exp(self.log_slope)

    @property
    def band(self) -> tuple[float, float]:
        """(low, high) per-step growth factors exp(b -+ Z se)."""
        if not math.isfinite(self.log_slope):
            return (math.nan, math.nan)
        return (_exp(self.log_slope - Z_SCORE * self.stderr),
                _exp(self.log_slope + Z_SCORE * self.stderr))

    @property
    def window_growth(self) -> tuple[float, float, float]:
        """(low, estimate, high) growth factors of the MSE over the fitted window."""
        W = self.steps
        b, u = self.log_slope, Z_SCORE * self.stderr
        return (_exp((b - u) * W), _exp(b * W), _exp((b + u) * W))

    @property
    def power_band(self) -> tuple[float, float]:
        """(low, high) of the fitted power, p -+ Z se_p."""
        if not math.isfinite(self.power) or not math.isfinite(self.power_stderr):
            return (math.nan, math.nan)
        u = Z_SCORE * self.power_stderr
        return (self.power - u, self.power + u)

    def to_dict(self) -> dict[str, Any]:
        low, high = self.band
        p_low, p_high = self.power_band
        return {"rate": _num(self.rate), "rate_low": _num(low), "rate_high": _num(high),
                "log_slope": _num(self.log_slope), "stderr": _num(self.stderr),
                "power": _num(self.power), "power_low": _num(p_low),
                "power_high": _num(p_high),
                "window": list(self.window), "trials": self.trials}


@dataclass(frozen=True)
class Verdict:
    """The verdict on one estimator's run.

    Attributes
    ----------
    verdict : str
        ``stable``, ``diverging``, ``unbounded``, ``undecided`` or ``diverged``.
    basis : str
        ``blow-up``, ``exact analysis`` (the joint system of plant state and error),
        ``exact rho`` (a spectral radius given by the caller) or ``measured growth``.
    reason : str
        One line: why.
    growth : GrowthEstimate
    measured : str
        What the measured growth alone says (``stable``/``diverging``/``unbounded``/
        ``undecided``).
    precision_horizon : int or None
        First untrusted step (see :func:`precision_horizon`), None if none in the run.
    diverged_at : int or None
        First blow-up step over the trials (``diverged``).
    analysis : netsim.models.jointsystem.JointAnalysis or None
        The exact analysis that decided (basis ``exact analysis``).
    """

    verdict: str
    basis: str
    reason: str
    growth: GrowthEstimate
    measured: str
    precision_horizon: int | None = None
    diverged_at: int | None = None
    analysis: Any = None

    @property
    def label(self) -> str:
        """The verdict as printed: ``diverged at step k`` for a blow-up."""
        if self.verdict == DIVERGED and self.diverged_at is not None:
            return f"diverged at step {self.diverged_at}"
        return self.verdict

    def to_dict(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "basis": self.basis, "reason": self.reason,
                "measured": self.measured, "growth": self.growth.to_dict(),
                "precision_horizon": self.precision_horizon,
                "diverged_at": self.diverged_at,
                **({"analysis": self.analysis.to_dict()} if self.analysis is not None
                   else {})}


def _exp(v: float) -> float:
    if v is None or math.isnan(v):
        return math.nan
    return math.inf if v > 700 else math.exp(v)


def _num(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _line_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """OLS slope of y against x and its standard error with an AR(1)-corrected
    effective sample size (inf if fewer than 3 points)."""
    W = len(y)
    t = np.asarray(x, dtype=float) - float(np.mean(x))
    sxx = float(t @ t)
    if sxx <= 0:
        return math.nan, math.inf
    b = float(t @ (y - y.mean()) / sxx)
    if W < 3:
        return b, math.inf
    resid = y - y.mean() - b * t
    s2 = float(resid @ resid) / (W - 2)
    denom = float(resid @ resid)
    r1 = float(resid[1:] @ resid[:-1]) / denom if denom > 0 else 0.0
    r1 = min(max(r1, 0.0), 0.99)
    inflation = (1 + r1) / (1 - r1)  # variance factor of the slope under AR(1) residuals
    return b, math.sqrt(s2 / sxx * inflation)


def _slope_fit(y: np.ndarray) -> tuple[float, float]:
    """OLS slope of y against 0..W-1 and its standard error (see :func:`_line_fit`)."""
    return _line_fit(np.arange(len(y), dtype=float), y)


def _pooled(slopes: list[float], ses: list[float]) -> tuple[float, float]:
    """Mean of per-trial slopes and its standard error (the larger of the pooled
    within-trial error and the spread across trials)."""
    n = len(slopes)
    b = float(np.mean(slopes))
    within = math.sqrt(float(np.mean(np.square(ses))) / n)
    across = float(np.std(slopes, ddof=1)) / math.sqrt(n) if n >= 2 else 0.0
    return b, max(within, across)


def estimate_growth(mse_per_trial: Sequence[np.ndarray] | np.ndarray,
                    end: int | None = None) -> GrowthEstimate:
    """Estimate the per-step growth of the MSE (see the module docstring).

    Parameters
    ----------
    mse_per_trial : array_like, shape (T, K+1)
        Each trial's MSE per step (non-negative).
    end : int, optional
        One past the last trusted step (the precision horizon); default K+1.

    Returns
    -------
    GrowthEstimate
        The geometric fit (log MSE against k) and the power fit (log MSE against log k,
        steps k >= 1) over the second half of the trusted steps.
    """
    M = np.atleast_2d(np.asarray(mse_per_trial, dtype=float))
    T, length = M.shape if M.size else (0, 0)
    end = length if end is None else max(0, min(int(end), length))
    start = end // 2
    window = (start, end)
    if T == 0 or end - start < 2:
        return GrowthEstimate(math.nan, math.inf, window, T)
    steps = np.arange(start, end, dtype=float)
    positive = steps >= 1
    log_k = np.log(steps[positive])
    slopes, ses, powers, pses = [], [], [], []
    for row in M[:, start:end]:
        if not np.all(np.isfinite(row)) or np.any(row <= 0):
            continue
        y = np.log(row)
        b, se = _slope_fit(y)
        slopes.append(b)
        ses.append(se)
        p, pse = _line_fit(log_k, y[positive]) if positive.sum() >= 2 else (math.nan,
                                                                             math.inf)
        powers.append(p)
        pses.append(pse)
    if not slopes:
        return GrowthEstimate(math.nan, math.inf, window, 0)
    b, se = _pooled(slopes, ses)
    if all(math.isfinite(p) for p in powers):
        p, pse = _pooled(powers, pses)
    else:
        p, pse = math.nan, math.inf
    return GrowthEstimate(b, se, window, len(slopes), p, pse)


def steady_slice(length: int, fraction: float, horizon: int | None = None) -> slice:
    """The steady-state steps: the last ``fraction`` of the trusted steps 0..end-1
    (end = the precision horizon, or ``length``)."""
    end = length if horizon is None else max(1, min(int(horizon), length))
    tail = max(1, int(round(fraction * end)))
    return slice(end - tail, end)


#: Verdict words other than ``stable`` under which a family's own report (e.g. the AoI
#: observer's) says the error settles: such runs have a steady MSE too.
_SETTLED = ("bounded", "converging", "converged")


def has_steady_state(verdict: str) -> bool:
    """Whether a run with this verdict has a steady MSE to report: ``stable`` (or a
    family's own settled words: ``bounded``, ``converging``, ``converged at step k``).
    Diverging, unbounded, undecided and diverged runs report their last trusted MSE and
    the growth instead."""
    return verdict == STABLE or verdict.startswith(_SETTLED)


#: What ``netsim run`` prints in an MSE@ column at or after the precision horizon.
BEYOND_HORIZON = "(beyond)"


def beyond_horizon(marks: Sequence[int | str], horizon: int | None) -> list[str]:
    """The marks (step numbers) at or after the precision horizon ``horizon``, as strings.

    Errors from the horizon step on are rounding of the state, not estimation errors
    (:func:`precision_horizon`); ``netsim run`` does not print them.
    """
    if horizon is None:
        return []
    return [str(m) for m in marks if int(m) >= int(horizon)]


_V = TypeVar("_V")


def trusted_values(values: dict[str, _V], horizon: int | None) -> dict[str, _V | None]:
    """``values`` (keyed by step) with None at every step at or after ``horizon``."""
    bad = set(beyond_horizon(list(values), horizon))
    return {k: (None if k in bad else v) for k, v in values.items()}


def horizon_text(step: int | None) -> str:
    """The report's words for a precision horizon ("" when there is none)."""
    if step is None:
        return ""
    return f"beyond the float64 precision horizon at step {step}"


def _measured(g: GrowthEstimate) -> tuple[str, str]:
    if g.steps < MIN_WINDOW:
        return UNDECIDED, f"too few steps to fit ({g.steps} < {MIN_WINDOW})"
    if not math.isfinite(g.log_slope) or not math.isfinite(g.stderr):
        return UNDECIDED, "no usable growth fit"
    low, est, high = g.window_growth
    band = (f"MSE growth over steps {g.window[0]}..{g.window[1] - 1}: x{est:.3g} "
            f"(band x{low:.3g}..x{high:.3g}, {g.trials} trials)")
    if low > GROWTH_TOLERANCE:
        return DIVERGING, band + f" > x{GROWTH_TOLERANCE:g}"
    p_low, p_high = g.power_band
    if math.isfinite(p_low) and p_low > POWER_MIN:
        return UNBOUNDED, (band + f"; MSE ~ k^p with p = {g.power:.3g} (band "
                           f"{p_low:.3g}..{p_high:.3g}) > {POWER_MIN:g}: polynomial growth")
    if est > TREND_TOLERANCE:
        return UNDECIDED, (band + f": the trend grows (x{est:.3g} > x{TREND_TOLERANCE:g}), "
                           f"but not beyond doubt by more than x{GROWTH_TOLERANCE:g}")
    if high < STABLE_TOLERANCE:
        return STABLE, band + f" < x{STABLE_TOLERANCE:g}"
    return UNDECIDED, band + f" straddles x{STABLE_TOLERANCE:g}"


def analysis_verdict(analysis: Any) -> str:
    """The run verdict of a joint-system analysis
    (:class:`netsim.models.jointsystem.JointAnalysis`): geometric growth ``diverging``,
    polynomial ``unbounded``, bounded ``stable``."""
    return {"geometric": DIVERGING, "polynomial": UNBOUNDED,
            "bounded": STABLE}[analysis.growth]


def judge(mse_per_trial: Sequence[np.ndarray] | np.ndarray, *,
          states: Sequence[np.ndarray] | None = None,
          diverged_at: Sequence[int | None] | None = None,
          rho_exact: float | None = None,
          analysis: Any = None) -> Verdict:
    """The verdict of one estimator's run (the rule in the module docstring).

    Parameters
    ----------
    mse_per_trial : array_like, shape (T, K+1)
        Each trial's MSE per step (NaN after a blow-up).
    states : sequence of array_like, optional
        The trials' true states (K+1, n) (NaN after a blow-up), for the precision horizon.
    diverged_at : sequence of int or None, optional
        Per trial, its blow-up step or None. A blow-up at or after the precision horizon
        is the state outgrowing double precision, not a divergence.
    rho_exact : float, optional
        Exact spectral radius of an error recursion known to be the whole error dynamics
        (basis ``exact rho``); ``analysis`` takes precedence.
    analysis : netsim.models.jointsystem.JointAnalysis, optional
        The exact analysis of the joint system of plant state and error (basis
        ``exact analysis``).

    Returns
    -------
    Verdict
    """
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        return _judge(mse_per_trial, states, diverged_at, rho_exact, analysis)


def _judge(mse_per_trial: Sequence[np.ndarray] | np.ndarray,
           states: Sequence[np.ndarray] | None, diverged_at: Sequence[int | None] | None,
           rho_exact: float | None, analysis: Any) -> Verdict:
    M = np.asarray(mse_per_trial, dtype=float)
    if M.ndim == 1:
        M = M[None, :]
    blowups = [None] * M.shape[0] if diverged_at is None else list(diverged_at)
    horizon = None
    if states is not None and M.size:
        horizon = precision_horizon(states, list(M))
    real = [int(d) for d in blowups if d is not None and (horizon is None or d < horizon)]
    kept = [row for row, d in zip(M, blowups, strict=True)
            if d is None or (horizon is not None and d >= horizon)]
    end = horizon
    if horizon is None and kept and M.shape[1]:
        end = None
    growth = (estimate_growth(np.array(kept), end) if kept
              else GrowthEstimate(math.nan, math.inf, (0, 0), 0))
    measured, why = _measured(growth)
    if real:
        first = min(real)
        return Verdict(DIVERGED, "blow-up",
                       f"{len(real)} trial(s) blew up, first at step {first}",
                       growth, measured, horizon, first, analysis)
    if horizon is not None:
        late = [d for d in blowups if d is not None]
        why = (horizon_text(horizon)
               + (f" ({len(late)} trial(s) overflowed after it)" if late else "")
               + "; " + why)
    if analysis is not None:
        reason = f"{analysis.reason}; measured: {why}"
        return Verdict(analysis_verdict(analysis), "exact analysis", reason, growth,
                       measured, horizon, None, analysis)
    if rho_exact is not None and math.isfinite(rho_exact) and rho_exact != 1.0:
        verdict = DIVERGING if rho_exact > 1 else STABLE
        reason = f"exact rho {rho_exact:.4f} {'>' if rho_exact > 1 else '<'} 1; measured: {why}"
        return Verdict(verdict, "exact rho", reason, growth, measured, horizon)
    return Verdict(measured, "measured growth", why, growth, measured, horizon)
