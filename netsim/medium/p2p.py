"""Point-to-point links: every link is its own wire with a FIFO transmit queue.

Link (j, i) serialises its packets one after the other at ``bit_rate`` from a finite
FIFO queue at the sender; a packet is received ``propagation`` seconds after its last
bit leaves (``per_link`` entries give a link a rate and a propagation of its own).
With Poisson arrivals and one packet size this is the M/D/1 queue: mean wait
in the queue W = lambda S^2 / (2 (1 - rho)), rho = lambda S (Pollaczek-Khinchine).
A broadcast is one copy per out-link.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import simpy

from netsim.medium.core import Medium, Packet, TransmitQueue
from netsim.medium.registry import register_mac

__all__ = ["PointToPoint"]


@register_mac
class PointToPoint(Medium):
    """Point-to-point links with FIFO transmit queues (one server per link)."""

    name = "point-to-point"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.links: dict[tuple[int, int], TransmitQueue] = {}

    def link_queue(self, sender: int, receiver: int) -> TransmitQueue:
        """The transmit queue of link sender -> receiver (its server starts on first use)."""
        queue = self.links.get((sender, receiver))
        if queue is None:
            queue = self.links[(sender, receiver)] = self.queue()
            rate, prop = (self.params.get("per_link") or {}).get((sender, receiver),
                                                                  (None, None))
            self.env.process(self._serve(queue, self.bit_rate if rate is None else rate,
                                         self.propagation if prop is None else prop))
        return queue

    def submit(self, packet: Packet) -> None:
        if len(packet.destinations) == 1:
            self.link_queue(packet.source, packet.destinations[0]).put(packet)
            return
        for d in packet.destinations:
            self.link_queue(packet.source, d).put(
                Packet(packet.source, (d,), packet.step, packet.created, packet.bits))

    def _serve(self, queue: TransmitQueue, rate: float, propagation: float
               ) -> Generator[simpy.Event, Any, None]:
        env = self.env
        while True:
            packet = yield from queue.get()
            yield env.timeout(packet.bits / rate)
            self.deliver_all(packet, env.now + propagation)
