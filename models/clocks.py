"""Agent clocks: offset, drift and read jitter (the TrueTime model of a node clock).

True time t is the clock of the plant and of the network. Agent i reads

    c_i(t) = t + o_i + delta_i t (+ e, a read jitter ~ N(0, sigma_i^2) per reading),

with offset o_i (time units), drift delta_i (given in ppm: delta_i = ppm * 1e-6) and
read-jitter standard deviation sigma_i. An agent samples when its (jitter-free) clock
reads phi_i + m T_i (phase phi_i, period T_i, both local time), i.e. at true times
t_{i,m} = (phi_i + m T_i - o_i) / (1 + delta_i); every reading it makes at such an
instant (the time handed to its estimator, the stamp on what it sends) carries the
jitter. With o = delta = sigma = 0 and T_i = T, phi_i = 0 the samples are at m T and
every reading is m T exactly (the step kernel's times).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Clock", "sample_times"]


@dataclass(frozen=True)
class Clock:
    """One agent's clock and sampling schedule.

    Parameters
    ----------
    offset : float
        o_i, time units (local minus true at t = 0).
    drift_ppm : float
        delta_i in parts per million.
    jitter : float
        Standard deviation sigma_i of each reading's jitter (time units).
    period : float
        T_i, the agent's sampling period in local time.
    phase : float
        phi_i, local time of sample 0 (before the others, see :func:`sample_times`).
    """

    offset: float = 0.0
    drift_ppm: float = 0.0
    jitter: float = 0.0
    period: float = 1.0
    phase: float = 0.0

    @property
    def drift(self) -> float:
        """delta_i = ppm * 1e-6."""
        return self.drift_ppm * 1e-6

    @property
    def neutral(self) -> bool:
        """Whether the clock reads true time exactly (no offset, drift or jitter)."""
        return self.offset == 0 and self.drift_ppm == 0 and self.jitter == 0

    def local(self, t: float) -> float:
        """c_i(t) without jitter: t + o_i + delta_i t."""
        if self.drift_ppm == 0:
            return t + self.offset if self.offset else t
        return t + self.offset + self.drift * t

    def true_time(self, c: float) -> float:
        """The true time at which the (jitter-free) clock reads ``c``."""
        if self.drift_ppm == 0:
            return c - self.offset if self.offset else c
        return (c - self.offset) / (1.0 + self.drift)

    def read(self, t: float, rng: np.random.Generator | None) -> float:
        """A reading at true time t: c_i(t) plus a jitter draw (none if sigma_i = 0)."""
        c = self.local(t)
        if self.jitter and rng is not None:
            c += self.jitter * float(rng.standard_normal())
        return c


def sample_times(clock: Clock, horizon: float) -> tuple[np.ndarray, np.ndarray]:
    """The agent's sampling instants in [0, horizon]: (true times, scheduled local times).

    The samples are at local readings phi + m T for integer m; those whose true time
    falls in [0, horizon] are returned in order (m need not start at 0: a clock ahead
    of true time has already passed phi at t = 0).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray), each shape (M,)
        True times t_{i,m} and the jitter-free local times phi + m T.
    """
    lo = math.ceil((clock.local(0.0) - clock.phase) / clock.period - 1e-12)
    hi = math.floor((clock.local(horizon) - clock.phase) / clock.period + 1e-12)
    m = np.arange(lo, hi + 1, dtype=float)
    local = clock.phase + m * clock.period
    if clock.neutral:
        true = local.copy()
    else:
        true = np.array([clock.true_time(float(c)) for c in local])
    keep = (true >= 0.0) & (true <= horizon)
    return true[keep], local[keep]
