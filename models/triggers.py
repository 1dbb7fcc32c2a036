"""Event triggers: whether an agent sends its new estimate (send-on-delta and relatives).

A trigger is consulted once after every update of the agent that owns it; it sees
only that agent's estimates (never the network), so the estimator, not the host,
decides when to send (DESIGN.md, "Time beyond the papers"). The host counts what is
sent and reports the message rate beside the MSE.

Kinds (``[time.trigger]`` ``kind``):

- ``always``: send after every update (the papers' rule; the neutral setting);
- ``send-on-delta``: send when ||x-hat_k - x-hat_last sent||_2 >= threshold (the first
  estimate is always sent);
- ``periodic``: periodic with threshold: at every ``every``-th update (m = 0, every,
  2 every, ...) send if ||x-hat_k - x-hat_last sent||_2 >= threshold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TRIGGER_KINDS", "TriggerSpec", "Trigger"]

TRIGGER_KINDS = ("always", "send-on-delta", "periodic")


@dataclass(frozen=True)
class TriggerSpec:
    """A validated ``[time.trigger]`` table.

    Parameters
    ----------
    kind : str
        One of :data:`TRIGGER_KINDS`.
    threshold : float
        delta >= 0 of the norm test.
    every : int
        Check period (updates) of ``periodic`` (>= 1).
    """

    kind: str = "always"
    threshold: float = 0.0
    every: int = 1

    def make(self) -> Trigger:
        """A fresh trigger (one per agent and run)."""
        return Trigger(self)

    @property
    def neutral(self) -> bool:
        """Whether every update is sent."""
        return self.kind == "always"


class Trigger:
    """One agent's trigger state (the last estimate sent, the update count)."""

    __slots__ = ("spec", "last_sent", "updates", "sent")

    def __init__(self, spec: TriggerSpec) -> None:
        self.spec = spec
        self.last_sent: np.ndarray | None = None
        #: Updates seen and estimates the trigger let through.
        self.updates = 0
        self.sent = 0

    def should_send(self, estimate: np.ndarray) -> bool:
        """Whether to send ``estimate`` (shape (n,)), the agent's newest; counts it."""
        m = self.updates
        self.updates += 1
        spec = self.spec
        if spec.kind == "always":
            send = True
        elif spec.kind == "periodic" and m % spec.every:
            send = False
        elif self.last_sent is None:
            send = True
        else:
            d = estimate - self.last_sent
            distance = math.sqrt(float(d.dot(d)))
            send = not distance < spec.threshold  # NaN sends (the receiver sees it)
        if send:
            self.sent += 1
            if spec.kind != "always":
                self.last_sent = np.array(estimate, dtype=float, copy=True)
        return send
