"""Delayed links: time-stamped messages delivered by scheduled events.

A link does not run a process per message: :meth:`Link.send` schedules one
:class:`Delivery` event at the arrival time, with URGENT priority so that a message
arriving exactly at a sampling instant is delivered before that instant's updates
(DESIGN.md). The delivery's callback hands the message to the receiver.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import simpy
from simpy.core import URGENT

from models.delays import DelayModel, latency_to_steps

__all__ = ["Message", "Delivery", "Link"]


@dataclass(slots=True)
class Message:
    """A time-stamped message on one link.

    Attributes
    ----------
    sender, receiver : int
        Agents j (sender) and i (receiver) of link (j, i).
    sent_step : int
        The step s the payload refers to (the time-stamp).
    sequence : int
        Per-link sequence number, 0, 1, 2, ...
    payload : numpy.ndarray, shape (n,)
        The sender's estimate x-hat^j_{s|s}.
    send_time : float
        Simulation time of sending, s * Ts.
    arrival_time : float
        Simulation time of delivery.
    delay_steps : int
        Step delay d: the message is usable at step s + 1 + d.
    """

    sender: int
    receiver: int
    sent_step: int
    sequence: int
    payload: np.ndarray
    send_time: float
    arrival_time: float
    delay_steps: int


class Delivery(simpy.events.Event):
    """An already-triggered event processed at ``now + delay`` with URGENT priority."""

    __slots__ = ()

    def __init__(self, env: simpy.Environment, delay: float, message: Message) -> None:
        # Same construction as simpy.Timeout, but URGENT so deliveries precede the
        # updates scheduled for the same instant.
        self.env = env
        self.callbacks: list = []
        self._value = message
        self._ok = True
        env.schedule(self, URGENT, delay)


class Link:
    """Directed link (sender -> receiver) with a delay model.

    Parameters
    ----------
    env : simpy.Environment
    sender, receiver : int
    delay_model : DelayModel
        Step delays or continuous latencies, see :mod:`models.delays`.
    deliver : callable(Message) -> None
        Called at the arrival time.
    sample_period : float
        Ts.
    """

    __slots__ = (
        "env", "sender", "receiver", "delay_model", "_deliver",
        "sample_period", "sent", "delivered", "dropped", "_sequence", "on_send", "on_drop",
        "availability",
    )

    def __init__(
        self,
        env: simpy.Environment,
        sender: int,
        receiver: int,
        delay_model: DelayModel,
        deliver: Callable[[Message], None],
        sample_period: float = 1.0,
    ) -> None:
        self.env = env
        self.sender = sender
        self.receiver = receiver
        self.delay_model = delay_model
        self._deliver = deliver
        self.sample_period = sample_period
        self.sent = 0
        self.delivered = 0
        self.dropped = 0
        self._sequence = 0
        self.on_send: Callable[[Message], None] | None = None
        #: Called as on_drop(message, reason) for every message the link loses.
        self.on_drop: Callable[[Message, str], None] | None = None
        #: availability(sender, receiver, step) -> bool: whether the link is up at the
        #: sending step (time-varying topologies, outages); None: always up.
        self.availability: Callable[[int, int, int], bool] | None = None

    def send(self, step: int, payload: np.ndarray) -> Message:
        """Send the payload time-stamped ``step``; schedule its delivery."""
        raw = self.delay_model.draw(self.sender, self.receiver, step)
        # The environment's clock counts sampling periods (step k at time k exactly),
        # so equal-time comparisons are exact; reported times are scaled by Ts.
        ts = self.sample_period
        if self.delay_model.unit == "steps":
            d = int(raw)
            wait = 1.0 + d
        else:
            d = latency_to_steps(float(raw), ts)
            wait = float(raw) / ts
        now = self.env.now
        message = Message(
            self.sender, self.receiver, step, self._sequence, payload,
            now * ts, (now + wait) * ts, d,
        )
        self._sequence += 1
        self.sent += 1
        if self.on_send is not None:
            self.on_send(message)
        if self.availability is not None and not self.availability(
            self.sender, self.receiver, step
        ):
            self.drop(message, "link down")
            return message
        event = Delivery(self.env, wait, message)
        event.callbacks.append(self._arrive)
        return message

    def drop(self, message: Message, reason: str) -> None:
        """Count a lost message and report it (drops are never silent)."""
        self.dropped += 1
        if self.on_drop is not None:
            self.on_drop(message, reason)

    def _arrive(self, event: simpy.events.Event) -> None:
        self.delivered += 1
        self._deliver(event._value)
