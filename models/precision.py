"""The float64 precision horizon of a run on an unstable plant.

The error x_k - x-hat_k is the difference of two numbers of size |x_k|, so its rounding
is about eps |x_k|. On an unstable plant |x_k| grows like rho(A)^k while the error stays
of the size of the noise: from some step on, the recorded error is rounding, not the
estimator's. :func:`precision_horizon` finds that step. It lives in ``models`` so that
both ``netsim`` (run, bench verdicts: :mod:`netsim.verdicts`) and ``traces`` (replay)
use the same rule.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np

__all__ = ["HORIZON_FACTOR", "HORIZON_FRACTION", "precision_horizon"]

#: The rounding of the error is taken as HORIZON_FACTOR * eps * max|x_k|.
HORIZON_FACTOR = 100.0
#: The horizon is where that rounding reaches this fraction of the error scale.
HORIZON_FRACTION = 1.0

_EPS = float(np.finfo(float).eps)


def precision_horizon(states: Sequence[np.ndarray], errors: Sequence[np.ndarray],
                      factor: float = HORIZON_FACTOR,
                      fraction: float = HORIZON_FRACTION) -> int | None:
    """First step whose state rounding reaches the error scale, or None.

    Parameters
    ----------
    states : sequence of array_like, each (K+1, n)
        True states of each trial.
    errors : sequence of array_like, each (K+1,)
        Each trial's MSE (squared error) per step; NaN steps are ignored.
    factor, fraction : float
        The rounding is ``factor * eps * max_t |x_k|``; the horizon is the first k where
        it reaches ``fraction`` times the error scale.

    Returns
    -------
    int or None
        The horizon step, None when the rounding stays below the error scale.

    Notes
    -----
    The error scale is the RMS error over the early steady state: steps K0/2..K0 where
    K0 is the last step before max |x_k| exceeds 1e6 times its value at step 0 (or K if
    it never does). On a stable plant the rounding stays far below and there is no
    horizon.
    """
    if not len(states):
        return None
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN steps after a blow-up
        return _horizon(states, errors, factor, fraction)


def _horizon(states: Sequence[np.ndarray], errors: Sequence[np.ndarray], factor: float,
             fraction: float) -> int | None:
    X = np.stack([np.asarray(s, dtype=float) for s in states])
    length = X.shape[1]
    size = np.nanmax(np.abs(X.reshape(X.shape[0], length, -1)), axis=(0, 2))
    # a step without any state (every trial stopped) is no evidence; an overflowed
    # state (inf) is past the horizon
    size = np.where(np.isnan(size), 0.0, size)
    floor = factor * _EPS * size
    start = max(float(size[0]), 1e-300)
    grown = np.flatnonzero(size > 1e6 * max(start, 1.0))
    k0 = int(grown[0]) if grown.size else length - 1
    E = np.stack([np.asarray(e, dtype=float) for e in errors])
    early = E[:, k0 // 2: k0 + 1]
    scale = math.sqrt(float(np.nanmean(early))) if np.any(np.isfinite(early)) else math.nan
    if not math.isfinite(scale) or scale <= 0:
        return None
    hit = np.flatnonzero(floor >= fraction * scale)
    return int(hit[0]) if hit.size else None
