"""The packet/queue core of the network layer: packets, transmit queues, the recorder.

Everything runs in a SimPy environment whose clock is in **seconds** (the medium's
parameters are physical). A MAC model (:class:`Medium` subclass) takes packets with
:meth:`Medium.submit` and reports each destination's fate to a :class:`Recorder`:
delivered at a time, or dropped with a reason. Reasons (:data:`REASONS`):
``collision``, ``queue full (drop-tail)``, ``queue full (drop-oldest)``,
``switch buffer full (drop-tail)`` / ``(drop-oldest)``, ``channel access failure``
(CSMA/CA gave up after ``max_backoffs``) and ``retry limit`` (ALOHA's ``max_attempts``,
CSMA/CA's unicast frame retries).

A transmit queue is finite (``capacity`` packets) with one of the link buffers' drop
policies: ``drop-tail`` drops the arriving packet, ``drop-oldest`` the packet queued
longest; ``keep-latest`` acts as ``drop-oldest`` here (a FIFO queue never reorders, so
there is nothing to supersede).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import simpy

__all__ = [
    "Packet",
    "TransmitQueue",
    "Recorder",
    "Medium",
    "SharedMedium",
    "poisson_source",
    "REASON_COLLISION",
    "REASON_ACCESS_FAILURE",
    "REASON_RETRY_LIMIT",
    "REASONS",
    "queue_reason",
]

REASON_COLLISION = "collision"
REASON_ACCESS_FAILURE = "channel access failure"
REASON_RETRY_LIMIT = "retry limit"


def queue_reason(policy: str, where: str = "queue") -> str:
    """The drop reason of a full queue under ``policy``."""
    return f"{where} full ({'drop-tail' if policy == 'drop-tail' else 'drop-oldest'})"


REASONS = (REASON_COLLISION, REASON_ACCESS_FAILURE, REASON_RETRY_LIMIT,
           queue_reason("drop-tail"), queue_reason("drop-oldest"),
           queue_reason("drop-tail", "switch buffer"),
           queue_reason("drop-oldest", "switch buffer"))


@dataclass(slots=True)
class Packet:
    """One packet on the medium.

    Attributes
    ----------
    source : int
        Sending node (agent).
    destinations : tuple of int
        Receiving nodes (one for unicast, the out-neighbours for a broadcast).
    step : int
        The scenario step whose estimate it carries; -1 for background traffic.
    created : float
        Time it was handed to the sender's transmit queue (s).
    bits : float
        Size on the medium.
    attempts : int
        Transmission attempts so far (CSMA/CA retries, ALOHA).
    remaining : int
        Frames still to send (CAN fragments).
    """

    source: int
    destinations: tuple[int, ...]
    step: int
    created: float
    bits: float
    attempts: int = 0
    remaining: int = 1
    frames: tuple[float, ...] = field(default=())


class TransmitQueue:
    """A finite FIFO transmit queue with a drop policy.

    Parameters
    ----------
    env : simpy.Environment
    capacity : int or None
        Largest number of queued packets (the one being transmitted is not queued).
    policy : str
        ``drop-tail``, ``drop-oldest`` or ``keep-latest`` (as drop-oldest).
    on_drop : callable(Packet, str)
        Called with every dropped packet and its reason.
    where : str
        ``queue`` or ``switch buffer`` (the reason's wording).
    """

    __slots__ = ("env", "capacity", "tail", "on_drop", "items", "_waiter", "reason",
                 "_claimed")

    def __init__(self, env: simpy.Environment, capacity: int | None, policy: str,
                 on_drop: Callable[[Packet, str], None], where: str = "queue") -> None:
        self.env = env
        self.capacity = capacity
        self.tail = policy == "drop-tail"
        self.reason = queue_reason(policy, where)
        self.on_drop = on_drop
        self.items: deque[Packet] = deque()
        self._waiter: simpy.Event | None = None
        # 1 while an idle server has been woken for the head packet but has not taken it
        # yet (same instant): that packet is the one being transmitted, not queued
        self._claimed = 0

    def __len__(self) -> int:
        return len(self.items)

    def put(self, packet: Packet) -> bool:
        """Queue ``packet``; False if it was dropped (drop-tail on a full queue)."""
        items = self.items
        if self.capacity is not None and len(items) >= self.capacity + self._claimed:
            if self.tail:
                self.on_drop(packet, self.reason)
                return False
            oldest = items[self._claimed]  # not the head an idle server is taking
            del items[self._claimed]
            self.on_drop(oldest, self.reason)
        items.append(packet)
        waiter = self._waiter
        if waiter is not None:
            self._waiter = None
            self._claimed = 1
            waiter.succeed()
        return True

    def wait(self) -> simpy.Event:
        """An event that fires at the next :meth:`put` (or now, if not empty)."""
        if self.items:
            event = self.env.event()
            event.succeed()
            return event
        if self._waiter is None:
            self._waiter = self.env.event()
        return self._waiter

    def get(self) -> Generator[simpy.Event, Any, Packet]:
        """Generator (``packet = yield from queue.get()``): the head packet, waiting."""
        while not self.items:
            yield self.wait()
        self._claimed = 0
        return self.items.popleft()


class Recorder:
    """The fate of every packet at every destination.

    Scenario packets (``step >= 0``) are kept by (source, destination, step) in
    :attr:`outcomes` as (done time, reason or None); background packets as rows of
    :attr:`background` (source, destination, created, done, reason).
    """

    def __init__(self) -> None:
        self.outcomes: dict[tuple[int, int, int], tuple[float, float, str | None]] = {}
        self.background: list[tuple[int, int, float, float, str | None]] = []
        self.keep_background = True

    def deliver(self, packet: Packet, destination: int, time: float) -> None:
        self._note(packet, destination, time, None)

    def drop(self, packet: Packet, destination: int, reason: str, time: float) -> None:
        self._note(packet, destination, time, reason)

    def _note(self, packet: Packet, destination: int, time: float, reason: str | None) -> None:
        if packet.step >= 0:
            self.outcomes[(packet.source, destination, packet.step)] = (packet.created, time,
                                                                        reason)
        elif self.keep_background:
            self.background.append((packet.source, destination, packet.created, time, reason))

    def background_arrays(self) -> dict[str, np.ndarray]:
        """The background rows as arrays: ``source``, ``destination``, ``created``,
        ``done`` (s) and ``dropped`` (bool)."""
        rows = self.background
        return {
            "source": np.array([r[0] for r in rows], dtype=np.int64),
            "destination": np.array([r[1] for r in rows], dtype=np.int64),
            "created": np.array([r[2] for r in rows], dtype=float),
            "done": np.array([r[3] for r in rows], dtype=float),
            "dropped": np.array([r[4] is not None for r in rows], dtype=bool),
        }


class Medium:
    """Base class of the MAC models.

    Parameters
    ----------
    env : simpy.Environment
        Clock in seconds.
    params : mapping
        The medium's parameters (:data:`netsim.models.medium.MEDIUM_PARAMETERS`, filled in).
    n_nodes : int
    out_neighbours : list of list of int
        Each node's destinations (links).
    rng : numpy.random.Generator
        The medium's own stream (backoffs, ALOHA attempts).
    recorder : Recorder
    """

    name = ""

    def __init__(self, env: simpy.Environment, params: dict[str, Any], n_nodes: int,
                 out_neighbours: list[list[int]], rng: np.random.Generator,
                 recorder: Recorder) -> None:
        self.env = env
        self.params = params
        self.n_nodes = n_nodes
        self.out_neighbours = out_neighbours
        self.rng = rng
        self.recorder = recorder
        self.bit_rate = float(params["bit_rate"])
        self.propagation = float(params["propagation"])
        self.stats: dict[str, int] = {}

    def queue(self, where: str = "queue", capacity: int | None = None,
              policy: str | None = None) -> TransmitQueue:
        """A transmit queue with the medium's capacity and policy (or the given ones)."""
        return TransmitQueue(self.env, self.params["queue"] if capacity is None else capacity,
                             self.params["policy"] if policy is None else policy,
                             self.drop_all, where)

    def submit(self, packet: Packet) -> None:
        """Hand ``packet`` to its source's MAC at the current time."""
        raise NotImplementedError

    def tx_time(self, packet: Packet) -> float:
        """Seconds to transmit ``packet`` at the bit rate."""
        return packet.bits / self.bit_rate

    def deliver_all(self, packet: Packet, time: float) -> None:
        """Every destination receives ``packet`` at ``time`` (transmission end +
        propagation)."""
        for d in packet.destinations:
            self.recorder.deliver(packet, d, time)

    def drop_all(self, packet: Packet, reason: str) -> None:
        """``packet`` is lost for every destination, now."""
        now = self.env.now
        for d in packet.destinations:
            self.recorder.drop(packet, d, reason, now)

    def count(self, name: str, by: int = 1) -> None:
        self.stats[name] = self.stats.get(name, 0) + by


class SharedMedium(Medium):
    """A medium one channel process serves: a transmit queue per node, a wake-up.

    The channel process (started by the subclass) sleeps on :meth:`idle` while every
    queue is empty; :meth:`submit` queues a packet at its source and wakes it.
    Subclasses with slots of ``slot`` seconds from t = 0 (TDMA, slotted ALOHA) resume at
    :meth:`next_slot`.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.queues = [self.queue() for _ in range(self.n_nodes)]
        self._wake: simpy.Event | None = None

    def submit(self, packet: Packet) -> None:
        self.queues[packet.source].put(packet)
        if self._wake is not None:
            wake, self._wake = self._wake, None
            wake.succeed()

    def idle(self) -> simpy.Event:
        """An event that fires at the next :meth:`submit`."""
        self._wake = self.env.event()
        return self._wake

    def next_slot(self, m: int, slot: float) -> int:
        """The index of the first slot (of ``slot`` seconds) that starts at or after now,
        and not before slot ``m``."""
        return max(m, math.ceil(self.env.now / slot * (1 - 1e-12)))


def poisson_source(env: simpy.Environment, medium: Medium, source: int,
                   destinations: tuple[int, ...], rate: float, bits: float,
                   rng: np.random.Generator, start: float = 0.0
                   ) -> Generator[simpy.Event, Any, None]:
    """SimPy process: Poisson packets (``rate`` per second) from ``source``.

    Background traffic (``step = -1``): exponential gaps drawn from ``rng``.
    """
    if rate <= 0:
        return
    if start > 0:
        yield env.timeout(start)
    while True:
        yield env.timeout(float(rng.exponential(1.0 / rate)))
        medium.submit(Packet(source, destinations, -1, env.now, bits))
