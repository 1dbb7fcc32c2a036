"""Statistical verdicts on a run's error: stable, diverging, undecided, diverged.

One rule, used by ``netsim run`` (:func:`netsim.runner.run_monte_carlo`), the benchmark
cells and sweeps (:mod:`netsim.bench.cells`) and ``netsim replay``.

The rule
--------
1. **Blow-up.** A trial whose error exceeded the divergence threshold or became
   non-finite is ``diverged`` (printed ``diverged at step k``); nothing else is judged.
2. **Precision horizon** (:func:`precision_horizon`). On an unstable plant the state
   grows like rho(A)^k while the estimation error stays of the size of the noise; the
   error x_k - x-hat_k is a difference of two numbers of size |x_k|, so its rounding is
   about ``eps |x_k|``. The horizon is the first step where
   ``HORIZON_FACTOR * eps * max|x_k|`` (over the trials) reaches ``HORIZON_FRACTION`` of
   the error scale (the RMS error over the early steady state, steps K0/2..K0 of the
   steps before the state grows by 1e6 of its start, or the first half of the run).
   Errors from the horizon on are not trusted: the verdict is decided on the steps
   before it, and the report says "beyond the float64 precision horizon at step k".
3. **Exact spectral radius.** Where the family's error recursion is exact and its
   spectral radius is known (compensating estimator, time-invariant delays:
   ``rho_exact_compensated``), the verdict is ``diverging`` when rho > 1 and ``stable``
   when rho < 1 (a stable linear recursion driven by stationary noise has a bounded
   MSE); the measured growth is still estimated and reported next to it.
4. **Measured growth** (:func:`estimate_growth`). Per trial, a least-squares line
   through log ||e_k||^2-MSE (the trial's network MSE) over the second half of the
   trusted steps gives a slope b_t (log growth per step). The estimate is the mean b
   over trials; its standard error is the larger of (a) the spread of b_t across trials,
   s / sqrt(T) (T >= 2), and (b) the pooled within-trial standard error of the slopes,
   each from the fit's residuals with the effective sample size W (1 - r1) / (1 + r1)
   (r1: lag-1 autocorrelation of the residuals), divided by sqrt(T). Over the W fitted
   steps the log growth is G = b W with uncertainty u = Z * se * W (Z = ``Z_SCORE``):

   * ``diverging`` when G - u > log(GROWTH_TOLERANCE): even at its lower confidence
     bound the MSE trend grows by more than the tolerance over the window;
   * ``stable`` when G + u < log(GROWTH_TOLERANCE): the evidence bounds the growth
     below the tolerance;
   * ``undecided`` otherwise, and also when fewer than ``MIN_WINDOW`` steps can be
     fitted (a short run, or a precision horizon early in it).

The growth factor per step is reported as exp(b) with the band exp(b +- Z se).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from netsim.models.precision import HORIZON_FACTOR, HORIZON_FRACTION, precision_horizon

__all__ = [
    "GROWTH_TOLERANCE",
    "Z_SCORE",
    "MIN_WINDOW",
    "HORIZON_FACTOR",
    "HORIZON_FRACTION",
    "STABLE",
    "DIVERGING",
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
]

#: Factor by which the MSE trend may grow over the fitted window (the second half of
#: the trusted steps) and still count as not diverging.
GROWTH_TOLERANCE = 2.0
#: Standard errors between the estimate and the tolerance before a verdict is given.
Z_SCORE = 3.0
#: Fewest fitted steps (the second half of the trusted steps) for any verdict.
MIN_WINDOW = 8

STABLE = "stable"
DIVERGING = "diverging"
UNDECIDED = "undecided"
DIVERGED = "diverged"

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
    """

    log_slope: float
    stderr: float
    window: tuple[int, int]
    trials: int

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

    def to_dict(self) -> dict[str, Any]:
        low, high = self.band
        return {"rate": _num(self.rate), "rate_low": _num(low), "rate_high": _num(high),
                "log_slope": _num(self.log_slope), "stderr": _num(self.stderr),
                "window": list(self.window), "trials": self.trials}


@dataclass(frozen=True)
class Verdict:
    """The verdict on one estimator's run.

    Attributes
    ----------
    verdict : str
        ``stable``, ``diverging``, ``undecided`` or ``diverged``.
    basis : str
        ``blow-up``, ``exact rho`` or ``measured growth``.
    reason : str
        One line: why.
    growth : GrowthEstimate
    measured : str
        What the measured growth alone says (``stable``/``diverging``/``undecided``).
    precision_horizon : int or None
        First untrusted step (see :func:`precision_horizon`), None if none in the run.
    diverged_at : int or None
        First blow-up step over the trials (``diverged``).
    """

    verdict: str
    basis: str
    reason: str
    growth: GrowthEstimate
    measured: str
    precision_horizon: int | None = None
    diverged_at: int | None = None

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
                "diverged_at": self.diverged_at}


def _exp(v: float) -> float:
    if v is None or math.isnan(v):
        return math.nan
    return math.inf if v > 700 else math.exp(v)


def _num(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _slope_fit(y: np.ndarray) -> tuple[float, float]:
    """OLS slope of y against 0..W-1 and its standard error with an AR(1)-corrected
    effective sample size (inf if W < 3)."""
    W = len(y)
    t = np.arange(W, dtype=float)
    t -= t.mean()
    sxx = float(t @ t)
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
    """
    M = np.atleast_2d(np.asarray(mse_per_trial, dtype=float))
    T, length = M.shape if M.size else (0, 0)
    end = length if end is None else max(0, min(int(end), length))
    start = end // 2
    window = (start, end)
    if T == 0 or end - start < 2:
        return GrowthEstimate(math.nan, math.inf, window, T)
    slopes, ses = [], []
    for row in M[:, start:end]:
        if not np.all(np.isfinite(row)) or np.any(row <= 0):
            continue
        b, se = _slope_fit(np.log(row))
        slopes.append(b)
        ses.append(se)
    if not slopes:
        return GrowthEstimate(math.nan, math.inf, window, 0)
    n = len(slopes)
    b = float(np.mean(slopes))
    within = math.sqrt(float(np.mean(np.square(ses))) / n)
    across = float(np.std(slopes, ddof=1)) / math.sqrt(n) if n >= 2 else 0.0
    return GrowthEstimate(b, max(within, across), window, n)


def steady_slice(length: int, fraction: float, horizon: int | None = None) -> slice:
    """The steady-state steps: the last ``fraction`` of the trusted steps 0..end-1
    (end = the precision horizon, or ``length``)."""
    end = length if horizon is None else max(1, min(int(horizon), length))
    tail = max(1, int(round(fraction * end)))
    return slice(end - tail, end)


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


def trusted_values(values: dict[str, float | None], horizon: int | None) -> dict[str, float | None]:
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
    if high < GROWTH_TOLERANCE:
        return STABLE, band + f" < x{GROWTH_TOLERANCE:g}"
    return UNDECIDED, band + f" straddles x{GROWTH_TOLERANCE:g}"


def judge(mse_per_trial: Sequence[np.ndarray] | np.ndarray, *,
          states: Sequence[np.ndarray] | None = None,
          diverged_at: Sequence[int | None] | None = None,
          rho_exact: float | None = None) -> Verdict:
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
        Exact spectral radius of the family's error recursion, when it is exact.

    Returns
    -------
    Verdict
    """
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        return _judge(mse_per_trial, states, diverged_at, rho_exact)


def _judge(mse_per_trial: Sequence[np.ndarray] | np.ndarray,
           states: Sequence[np.ndarray] | None, diverged_at: Sequence[int | None] | None,
           rho_exact: float | None) -> Verdict:
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
                       growth, measured, horizon, first)
    if horizon is not None:
        late = [d for d in blowups if d is not None]
        why = (horizon_text(horizon)
               + (f" ({len(late)} trial(s) overflowed after it)" if late else "")
               + "; " + why)
    if rho_exact is not None and math.isfinite(rho_exact) and rho_exact != 1.0:
        verdict = DIVERGING if rho_exact > 1 else STABLE
        reason = f"exact rho {rho_exact:.4f} {'>' if rho_exact > 1 else '<'} 1; measured: {why}"
        return Verdict(verdict, "exact rho", reason, growth, measured, horizon)
    return Verdict(measured, "measured growth", why, growth, measured, horizon)
