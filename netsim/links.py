"""Delayed links: time-stamped messages delivered by scheduled events.

A link does not run a process per message: :meth:`Link.send` puts the message on
the simulation's :class:`netsim.deliveries.DeliveryCalendar`, which schedules one
URGENT event per arrival instant, so that a message arriving exactly at a sampling
instant is delivered before that instant's updates (DESIGN.md), in sending order.
The delivery hands the message to the receiver.

:class:`Link` is the plain link (delays only, plus the availability hook): its
per-message path is one delay draw, one :class:`Message` and one calendar entry.
:class:`ConfiguredLink` adds what a :class:`netsim.models.linkmodels.LinkModel` asks for:
outages, losses and a finite buffer of in-flight messages with a drop policy
(definitions in :mod:`netsim.models.linkmodels`). Only links that have such a model pay for
it. A cancelled delivery (drop-oldest, keep-latest) is not removed from the calendar:
the message leaves the link's in-flight table, and the arrival callback ignores
deliveries whose message is no longer in it.

Drop reasons reported to ``on_drop`` (and traced): ``link down`` (availability),
``outage``, the loss model's reason (``loss: bernoulli``, ``loss: gilbert-elliott
(bad state)``, ..., ``trace: <recorded reason>``), ``buffer full (drop-tail)``,
``buffer full (drop-oldest)`` and ``superseded (keep-latest)``.

Lean path: a plain :class:`Link` whose ``receive`` hook is set (the receiver's
``message_arrived``), with no ``on_send`` and no ``availability`` hook and a delay
model in steps, builds no :class:`Message` at all: its calendar entry carries
``(sender, sent_step, payload)`` and its arrival calls ``receive(sender, sent_step, payload)``
directly, counting refusals (stale messages) in :attr:`Link.discarded`. The kernel
uses it when no observer and no message recording need the Message objects; the
delay draw, the arrival time and the delivery order are exactly those of the full
path. :func:`sender_function` sends on all out-links of one agent in one call (the
kernel's per-agent send); lean links then share one entry value.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, cast

import numpy as np
import simpy

from netsim.deliveries import DeliveryCalendar
from netsim.models.delays import DelayModel, latency_to_steps

__all__ = [
    "Message", "Link", "ConfiguredLink", "resolve_link", "sender_function",
    "REASON_LINK_DOWN", "REASON_DROP_TAIL", "REASON_DROP_OLDEST", "REASON_SUPERSEDED",
]

REASON_LINK_DOWN = "link down"
REASON_DROP_TAIL = "buffer full (drop-tail)"
REASON_DROP_OLDEST = "buffer full (drop-oldest)"
REASON_SUPERSEDED = "superseded (keep-latest)"


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


class Link:
    """Directed link (sender -> receiver) with a delay model.

    Parameters
    ----------
    env : simpy.Environment
    sender, receiver : int
    delay_model : DelayModel
        Step delays or continuous latencies, see :mod:`netsim.models.delays`.
    deliver : callable(Message) -> None
        Called at the arrival time.
    sample_period : float
        Ts.
    calendar : DeliveryCalendar, optional
        The environment's delivery calendar, shared by all its links (the delivery
        order across links is the sending order only within one calendar); default:
        a calendar of this link's own.
    """

    __slots__ = (
        "env", "sender", "receiver", "delay_model", "_deliver",
        "sample_period", "sent", "delivered", "dropped", "_sequence", "on_send", "on_drop",
        "availability", "receive", "discarded", "calendar", "_schedule",
    )

    def __init__(
        self,
        env: simpy.Environment,
        sender: int,
        receiver: int,
        delay_model: DelayModel,
        deliver: Callable[[Message], None],
        sample_period: float = 1.0,
        calendar: DeliveryCalendar | None = None,
    ) -> None:
        self.env = env
        self.calendar = calendar if calendar is not None else DeliveryCalendar(env)
        self._schedule = self.calendar.schedule
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
        #: receive(sender, sent_step, payload) -> bool (accepted): when set, a plain
        #: link without on_send / availability hooks takes the lean path and
        #: ``deliver`` is not called (see the module docstring).
        self.receive: Callable[[int, int, np.ndarray], bool] | None = None
        #: Deliveries refused by ``receive`` (lean path only).
        self.discarded = 0

    def _stamp(self, step: int, payload: np.ndarray) -> tuple[Message, float, bool]:
        """Draw the delay, build and count the message, report it sent.

        Returns the message, the wait until its arrival (in sampling periods), and
        whether the link is up at this sending step.
        """
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
        up = self.availability is None or self.availability(self.sender, self.receiver, step)
        if not up:
            self.drop(message, REASON_LINK_DOWN)
        return message, wait, up

    def send(self, step: int, payload: np.ndarray) -> Message | None:
        """Send the payload time-stamped ``step``; schedule its delivery.

        Returns the :class:`Message`, or None on the lean path (no Message is built).
        """
        if self.lean:
            self.send_function()(step, payload)
            return None
        message, wait, up = self._stamp(step, payload)
        if up:
            self._schedule(wait, self._arrive, message)
        return message

    @property
    def lean(self) -> bool:
        """Whether :meth:`send` takes the lean path with the link's current hooks."""
        return (type(self).send is Link.send and self.receive is not None
                and self.on_send is None and self.availability is None
                and self.delay_model.unit == "steps")

    def send_function(self) -> Callable[[int, np.ndarray], Message | None]:
        """Return the send function for the link's current hooks (resolved once).

        The same as :meth:`send`, minus the per-message test of the hooks: call it
        again after changing ``receive``, ``on_send``, ``availability`` or the delay
        model.
        """
        if not self.lean:
            return self.send
        return sender_function([self])

    def _lane(self) -> tuple[Link, Callable[[int], Any] | None, float, Callable[[Any], None]]:
        """(link, delay sampler or None, constant wait, arrival) of the lean path.

        The same draw and arrival time as :meth:`_stamp`, without a Message: a
        time-invariant delay model is drawn once (it promises the same value for every
        message of the link), otherwise each message draws from the link's sampler.
        """
        if self.delay_model.time_invariant:
            wait = 1.0 + int(self.delay_model.draw(self.sender, self.receiver, 0))
            return self, None, wait, self._arrive_lean
        sampler = getattr(self.delay_model, "sampler", None)
        sample = (sampler(self.sender, self.receiver) if sampler is not None
                  else partial(self.delay_model.draw, self.sender, self.receiver))
        return self, sample, 0.0, self._arrive_lean

    def drop(self, message: Message, reason: str) -> None:
        """Count a lost message and report it (drops are never silent)."""
        self.dropped += 1
        if self.on_drop is not None:
            self.on_drop(message, reason)

    def _arrive(self, message: Message) -> None:
        self.delivered += 1
        self._deliver(message)

    def _arrive_lean(self, stamped: tuple[int, int, np.ndarray]) -> None:
        # stamped = (sender, sent_step, payload)
        self.delivered += 1
        receive = cast("Callable[[int, int, np.ndarray], bool]", self.receive)  # lean: set
        if not receive(*stamped):
            self.discarded += 1


class ConfiguredLink(Link):
    """A :class:`Link` with outages, losses and a finite buffer (a ``LinkModel``).

    Parameters are those of :class:`Link`; then call :meth:`configure`.

    Attributes
    ----------
    in_flight : dict sequence -> Message
        Messages accepted by the link and not yet delivered, in sending order.
    """

    __slots__ = ("loss", "outages", "capacity", "policy", "in_flight", "_newest_delivered")

    def configure(self, model) -> None:
        """Apply a :class:`netsim.models.linkmodels.LinkModel` (its delay model too, if set)."""
        if model.delay is not None:
            self.delay_model = model.delay
        self.loss = model.loss
        self.outages = model.outages if model.outages is not None and \
            model.outages.intervals else None
        self.capacity = model.buffer_capacity
        self.policy = model.buffer_policy
        self.in_flight: dict[int, Message] = {}
        self._newest_delivered = -1

    def send(self, step: int, payload: np.ndarray) -> Message:
        """Send like :meth:`Link.send`, then apply outages, loss and the buffer policy.

        A configured link always builds Messages (its buffer holds them); it never
        takes the lean path.
        """
        # the delay is drawn first, for every message (trace replay counts on it)
        message, wait, up = self._stamp(step, payload)
        if not up:
            return message
        sequence = message.sequence
        if self.outages is not None and self.outages.down(step):
            self.drop(message, self.outages.reason)
            return message
        if self.loss is not None:
            reason = self.loss.drop_reason(step, sequence)
            if reason is not None:
                self.drop(message, reason)
                return message
        in_flight = self.in_flight
        if self.capacity is not None and len(in_flight) >= self.capacity:
            if self.policy == "drop-tail":
                self.drop(message, REASON_DROP_TAIL)
                return message
            oldest = next(iter(in_flight))
            self.drop(in_flight.pop(oldest), REASON_DROP_OLDEST)
        in_flight[sequence] = message
        self._schedule(wait, self._arrive, message)
        return message

    def _arrive(self, message: Message) -> None:
        if self.in_flight.pop(message.sequence, None) is None:
            return  # cancelled (dropped while in flight)
        if self.policy == "keep-latest":
            if message.sequence < self._newest_delivered:
                self.drop(message, REASON_SUPERSEDED)
                return
            self._newest_delivered = message.sequence
        self.delivered += 1
        self._deliver(message)


def sender_function(links: Sequence[Link]) -> Callable[[int, np.ndarray], None]:
    """Return one function that sends a payload on each of ``links`` in turn.

    ``send(step, payload)`` is the same as calling every link's
    :meth:`Link.send_function` in order (same draws, same calendar entries, same
    order). When every link takes the lean path -- one sender's out-links, the usual
    case in the kernel -- the loop over the links runs inside one function and the
    links share one ``(sender, step, payload)`` entry value, so a message costs one
    delay draw and one calendar call.
    """
    links = list(links)
    if not all(link.lean for link in links):
        sends = [link.send_function() for link in links]

        def send_each(step: int, payload: np.ndarray) -> None:
            for send in sends:
                send(step, payload)

        return send_each
    senders = {link.sender for link in links}
    if len(senders) > 1:
        raise ValueError(f"lean links of one send function must share a sender, got {senders}")
    calendars = {id(link.calendar): link.calendar for link in links}
    if len(calendars) > 1:
        raise ValueError("links of one send function must share a delivery calendar")
    if not links:
        return lambda step, payload: None
    sender = senders.pop()
    schedule = links[0].calendar.schedule
    lanes = [link._lane() for link in links]

    def send_lean(step: int, payload: np.ndarray) -> None:
        value = (sender, step, payload)
        for link, sample, wait, arrive in lanes:
            link.sent += 1
            schedule(wait if sample is None else 1.0 + int(sample(step)), arrive, value)

    return send_lean


def resolve_link(delay_model: DelayModel, sender: int, receiver: int,
                 link_models: Any = None) -> tuple[DelayModel, Any]:
    """The delays and the link model of link sender -> receiver, as the kernel uses them.

    ``link_models`` (mapping (sender, receiver) -> LinkModel) takes precedence over the
    delay model's own ``link()``. Returns the link's delay model and its
    :class:`netsim.models.linkmodels.LinkModel`, or None when the link needs no loss, outage
    or buffer (a plain :class:`Link`).
    """
    model = link_models.get((sender, receiver)) if link_models is not None else None
    per_link = getattr(delay_model, "link", None)
    if model is None and per_link is not None:
        model = per_link(sender, receiver)
    delays = model.delay if model is not None and model.delay is not None else delay_model
    return delays, (model if model is not None and not model.trivial else None)
