"""The delivery calendar: one scheduled SimPy event per arrival instant.

Every message a link carries is delivered at its arrival time, before the updates of
that instant (URGENT priority, DESIGN.md). Rather than one SimPy event per message,
the links of a simulation share a :class:`DeliveryCalendar`: the first message for an
arrival time t schedules one URGENT :class:`Delivery` event at t, and later messages
for t join its list. When the event is processed, the messages are handed over one by
one, in the order they were sent.

That is exactly the order one event per message would give, provided every URGENT
event at a time t > 0 is a delivery: SimPy pops events at equal time and priority in
the order they were scheduled, and a list is taken off the calendar before it is
handed over, so a message scheduled for t after that starts a new event (after the
first, as its own event would be). The kernel keeps that proviso: it starts no
process during a run and stops on a NORMAL event. A process started inside a
delivery, or ``env.run(until=t)`` (an URGENT stop event), would be ordered after all
of t's pending messages rather than between them (tests/test_deliveries.py). The
per-message cost is a dictionary lookup and an append instead of a heap push and pop.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import simpy
from simpy.core import URGENT
from simpy.events import Event

__all__ = ["Delivery", "DeliveryCalendar"]


class Delivery(Event):
    """An already-triggered URGENT event: the deliveries due at one arrival instant.

    Its value is the arrival time (the calendar's key).
    """

    __slots__ = ()


#: Allocates a Delivery without running ``Event.__init__`` (the calendar sets its fields).
_new_delivery = Event.__new__


class DeliveryCalendar:
    """Pending deliveries of one SimPy environment, grouped by arrival time.

    Links that share an environment must share its calendar: the delivery order
    across links is the sending order only within one calendar.

    Parameters
    ----------
    env : simpy.Environment
        The environment whose clock the arrival times refer to.

    Attributes
    ----------
    events : int
        Delivery events scheduled so far (one per distinct arrival instant).
    """

    __slots__ = ("env", "_pending", "events")

    def __init__(self, env: simpy.Environment) -> None:
        self.env = env
        self._pending: dict[float, list[Any]] = {}
        self.events = 0

    def schedule(self, wait: float, arrive: Callable[[Any], None], value: Any) -> None:
        """Call ``arrive(value)`` after ``wait`` (in the environment's time units).

        The arrival time is ``env.now + wait``, the same sum SimPy forms for an
        event's time, so equal arrival times are recognised exactly.
        """
        env = self.env
        at = env._now + wait
        pending = self._pending.get(at)
        if pending is None:
            self._pending[at] = pending = []
            event = _new_delivery(Delivery)
            event.env = env
            event.callbacks = [self._hand_over]
            event._value = at
            event._ok = True
            env.schedule(event, URGENT, wait)
            self.events += 1
        pending.append(arrive)
        pending.append(value)

    def _hand_over(self, event: Event) -> None:
        # taken off the calendar first: a delivery scheduled for this instant from
        # here on starts a new event, after this one
        entries = iter(self._pending.pop(event._value))
        for arrive, value in zip(entries, entries, strict=False):  # (arrive, value) pairs
            arrive(value)

    def __len__(self) -> int:
        """Messages scheduled for instants whose event has not been processed yet.

        The rest of a batch being handed over is not counted.
        """
        return sum(len(pending) for pending in self._pending.values()) // 2
