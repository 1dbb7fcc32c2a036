"""A switched network: an output-queued, store-and-forward switch.

Every node has an uplink to the switch (FIFO transmit queue, ``bit_rate``); a packet is
in the switch ``propagation`` seconds after its last bit left the node, and is then
copied into the output queue of each destination's port (``switch_buffer`` packets,
``switch_policy``), whose port transmits at ``bit_rate`` and delivers ``propagation``
seconds after the last bit. A broadcast crosses the uplink once and is replicated by
the switch. Deterministic check: N packets sent to one port at the same instant over
idle uplinks leave the port back to back, the k-th one ``k`` transmission times after
the uplink, and all but ``switch_buffer + 1`` are dropped on a full buffer.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any, cast

import simpy

from netsim.medium.core import Medium, Packet, TransmitQueue
from netsim.medium.registry import register_mac

__all__ = ["SwitchedNetwork"]


@register_mac
class SwitchedNetwork(Medium):
    """Output-queued switch with a per-port rate and finite port buffers."""

    name = "switched"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.uplinks = [self.queue() for _ in range(self.n_nodes)]
        for q in self.uplinks:
            self.env.process(self._uplink(q))
        self.ports: dict[int, TransmitQueue] = {}

    def port(self, node: int) -> TransmitQueue:
        """The output queue of ``node``'s switch port (its server starts on first use)."""
        q = self.ports.get(node)
        if q is None:
            q = self.ports[node] = self.queue("switch buffer", self.params["switch_buffer"],
                                              self.params["switch_policy"])
            self.env.process(self._port(q))
        return q

    def submit(self, packet: Packet) -> None:
        self.uplinks[packet.source].put(packet)

    def _forward(self, packet: Packet) -> None:
        for d in packet.destinations:
            self.port(d).put(packet if len(packet.destinations) == 1 else
                             Packet(packet.source, (d,), packet.step, packet.created,
                                    packet.bits))

    def _arrived(self, event: simpy.Event) -> None:
        self._forward(cast(Packet, event.value))

    def _uplink(self, queue: TransmitQueue) -> Generator[simpy.Event, Any, None]:
        env = self.env
        while True:
            packet = yield from queue.get()
            yield env.timeout(packet.bits / self.bit_rate)
            if self.propagation > 0:
                arrive = env.timeout(self.propagation, packet)
                arrive.callbacks.append(self._arrived)
            else:
                self._forward(packet)

    def _port(self, queue: TransmitQueue) -> Generator[simpy.Event, Any, None]:
        env = self.env
        while True:
            packet = yield from queue.get()
            yield env.timeout(packet.bits / self.bit_rate)
            self.deliver_all(packet, env.now + self.propagation)
