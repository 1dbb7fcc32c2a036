"""What one trial produced, and the constants its records use (no SimPy).

:class:`TrialResult`, :data:`NOT_USED`, the divergence threshold and its round-off
guard live here so that the engines that do not run the event kernel (the vectorised
lockstep, :mod:`netsim.vectorised`) can build results without importing SimPy
(start-up, issue 34). :mod:`netsim.kernel` re-exports all of them, so
``from netsim.kernel import TrialResult`` keeps working and names the same class.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # netsim.links imports simpy
    from netsim.links import Message

__all__ = [
    "DEFAULT_DIVERGENCE_THRESHOLD",
    "NOT_USED",
    "ROUNDOFF_RELATIVE_ERROR",
    "TrialResult",
    "squared_threshold",
]

#: Entry of ``TrialResult.effective_delays`` where no neighbour estimate was used.
NOT_USED = -2
#: An agent's error norm above this (or non-finite) marks the trial as diverged.
DEFAULT_DIVERGENCE_THRESHOLD = 1e8
#: ... provided the error is also above this fraction of the state's norm: on an
#: unstable plant the state outgrows double precision (|x| ~ 1e23 after ~1400 steps at
#: rho(A) = 1.04), and one rounding step of x is then larger than the threshold.
ROUNDOFF_RELATIVE_ERROR = 1e-9


def squared_threshold(threshold: float) -> float:
    """The divergence threshold squared; beyond sqrt(float max) it means no threshold."""
    return threshold * threshold if threshold < 1e150 else math.inf


@dataclass
class TrialResult:
    """Everything one run produced.

    Attributes
    ----------
    states : numpy.ndarray, shape (K+1, n)
        True states x_0..x_K.
    measurements : list of numpy.ndarray, each (K+1, m_i)
        Each sensor's measurements.
    estimates : numpy.ndarray, shape (K+1, N_agents, n)
        Each agent's estimate after its update at each step.
    squared_errors : numpy.ndarray, shape (K+1, N_agents)
        ||x_k - x-hat^i_{k|k}||^2 (NaN after divergence).
    effective_delays : numpy.ndarray or None, shape (K+1, N_agents, N_agents), int
        r_ij[k] = k - 1 - s_j used by agent i's update at step k; -1 when i
        substituted its own estimate (nothing arrived yet), NOT_USED (-2) when j's
        estimate was not used at that step.
    diverged_at : int or None
        First step at which an agent's error exceeded the threshold or was not finite.
    messages_sent, messages_delivered, messages_discarded, messages_dropped : int
        Counts over all links (discarded: stale on arrival, freshest rule; dropped:
        lost by the link).
    messages : list of Message
        Every delivered message, in delivery order (when recorded).
    drop_reasons : dict of str -> int
        Dropped messages by reason (see :mod:`netsim.links`); sums to messages_dropped.
    extras : dict
        What the family's own observer collected (``EstimatorFamily.observer``).
    drops : list of (int, int, int, float, str) or None
        Every dropped message as (sender j, receiver i, sent step s, drop time in
        sampling periods, reason), in the order they were dropped, when effective
        delays are recorded (``record_delays``); else None.
    """

    states: np.ndarray
    measurements: list[np.ndarray]
    estimates: np.ndarray
    squared_errors: np.ndarray
    effective_delays: np.ndarray | None
    diverged_at: int | None
    messages_sent: int
    messages_delivered: int
    messages_discarded: int
    messages: list[Message] = field(default_factory=list)
    messages_dropped: int = 0
    drop_reasons: dict[str, int] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)
    drops: list[tuple[int, int, int, float, str]] | None = None

    def __repr__(self) -> str:
        """A few lines (the arrays' shapes, not their values; issue 30)."""
        fate = ("not diverged" if self.diverged_at is None
                else f"diverged at step {self.diverged_at}")
        return (f"<TrialResult steps 0..{len(self.states) - 1}, {fate}; messages "
                f"{self.messages_sent} sent, {self.messages_delivered} delivered, "
                f"{self.messages_dropped} dropped, {self.messages_discarded} discarded; "
                f"states {self.states.shape}, estimates {self.estimates.shape}, "
                f"squared_errors {self.squared_errors.shape}>")
