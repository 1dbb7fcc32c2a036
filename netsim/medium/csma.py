"""Unslotted CSMA/CA with binary exponential backoff (IEEE 802.15.4 nonbeacon mode).

Per packet (IEEE 802.15.4-2006, 7.5.1.4, unslotted): NB = 0, BE = ``min_be``; wait a
random number of unit backoff periods, uniform on 0..2^BE - 1; perform a clear channel
assessment (``cca`` symbols); if the channel was busy at any time during it, NB += 1,
BE = min(BE + 1, ``max_be``) and back off again, or give up (``channel access
failure``) when NB > ``max_backoffs``; if it was idle, turn the radio around
(``turnaround`` symbols) and transmit. Defaults are the standard's (2.4 GHz O-QPSK,
16 us symbols, 250 kbit/s).

Collisions: one collision domain (every node hears every other, no capture, no hidden
terminals): two transmissions that overlap in time are both lost for every receiver
(``collision``). Broadcast frames are not acknowledged and not retried (as in 802.15.4);
unicast frames that collided are retried after ``ack_wait`` symbols up to
``max_frame_retries`` times (the acknowledgement frames themselves are not put on the
channel).

Closed form checked in the tests: n nodes that each get one frame at the same instant
on an idle channel; the first transmission starts after the smallest backoff, and with
aligned backoff periods it collides exactly when two or more nodes drew that smallest
value: P(collision) = 1 - sum_m n (1/W) ((W - 1 - m) / W)^(n - 1), W = 2^min_be (a
node whose count is one period larger senses the first frame during its CCA, because
CCA + turnaround = one unit backoff period).
"""

from __future__ import annotations

import math
from collections.abc import Generator
from typing import Any

import simpy

from netsim.medium.core import REASON_ACCESS_FAILURE, REASON_COLLISION, Medium, Packet
from netsim.medium.registry import register_mac

__all__ = ["CSMACA"]


@register_mac
class CSMACA(Medium):
    """Unslotted CSMA/CA, one collision domain."""

    name = "csma"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        p = self.params
        symbol = float(p["symbol"])
        self.unit = int(p["unit_backoff"]) * symbol
        self.cca = int(p["cca"]) * symbol
        self.turnaround = int(p["turnaround"]) * symbol
        self.ack_wait = int(p["ack_wait"]) * symbol
        self.min_be, self.max_be = int(p["min_be"]), int(p["max_be"])
        self.max_backoffs = int(p["max_backoffs"])
        self.retries = int(p["max_frame_retries"]) if p["addressing"] == "unicast" else 0
        self.queues = [self.queue() for _ in range(self.n_nodes)]
        #: transmissions on the air: [packet, collided]
        self.active: list[list[Any]] = []
        #: the latest end of any transmission started so far (s)
        self.busy_until = -math.inf
        for i in range(self.n_nodes):
            self.env.process(self._node(i))

    def submit(self, packet: Packet) -> None:
        self.queues[packet.source].put(packet)

    def _node(self, i: int) -> Generator[simpy.Event, Any, None]:
        env, rng = self.env, self.rng
        queue = self.queues[i]
        while True:
            packet = yield from queue.get()
            while True:  # one CSMA/CA procedure per transmission attempt
                nb, be = 0, self.min_be
                entry = None
                while True:
                    yield env.timeout(int(rng.integers(0, 1 << be)) * self.unit)
                    start = env.now
                    yield env.timeout(self.cca)
                    if self.busy_until > start:  # something was on the air during CCA
                        self.count("busy_cca")
                        nb += 1
                        be = min(be + 1, self.max_be)
                        if nb > self.max_backoffs:
                            break
                        continue
                    yield env.timeout(self.turnaround)
                    entry = [packet, False]
                    if self.active:
                        entry[1] = True
                        for other in self.active:
                            other[1] = True
                    self.active.append(entry)
                    tx = packet.bits / self.bit_rate
                    self.busy_until = max(self.busy_until, env.now + tx)
                    self.count("transmissions")
                    yield env.timeout(tx)
                    self.active.remove(entry)
                    break
                if entry is None:
                    self.count("access_failures")
                    self.drop_all(packet, REASON_ACCESS_FAILURE)
                    break
                if not entry[1]:
                    self.deliver_all(packet, env.now + self.propagation)
                    break
                self.count("collisions")
                if packet.attempts < self.retries:
                    packet.attempts += 1
                    yield env.timeout(self.ack_wait)
                    continue
                self.drop_all(packet, REASON_COLLISION)
                break
