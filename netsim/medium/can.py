"""CAN bus: priority arbitration, non-preemptive frames.

Each node queues its packets FIFO; a packet of P data bytes is sent as ceil(P /
``frame_payload_bytes``) frames (8 bytes: classic CAN; up to 64: CAN FD data lengths,
counted with the classic frame format), each of
:func:`netsim.models.medium.can_frame_bits` bits (11-bit identifier, worst-case bit
stuffing). Whenever the bus is idle, the pending frames arbitrate and the one with the
lowest identifier (``priorities[node]``, default the agent index) is sent; a frame
being sent is never pre-empted. A packet is received ``propagation`` seconds after the
last bit of its last frame.

Closed form checked in the tests: the worst-case response time of a periodic message
set by the standard response-time analysis (Tindell, Burns and Wellings 1994, as
revised by Davis et al. 2007): R_m = w_m + C_m, w_m = B_m + sum over higher-priority k
of ceil((w_m + tau_bit) / T_k) C_k, B_m the longest lower-priority frame.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import simpy

from netsim.medium.core import Packet, SharedMedium
from netsim.medium.registry import register_mac
from netsim.models.medium import can_frame_bits

__all__ = ["CANBus"]


@register_mac
class CANBus(SharedMedium):
    """CAN arbitration by identifier."""

    name = "can"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.ids = tuple(int(v) for v in self.params["priorities"])
        self.per_frame = int(self.params["frame_payload_bytes"])
        self.current: list[Packet | None] = [None] * self.n_nodes
        self.env.process(self._bus())

    def frames(self, packet: Packet) -> tuple[float, ...]:
        """Frame lengths (bits) of a packet of ``packet.bits / 8`` data bytes."""
        data = int(round(packet.bits / 8))
        full, rest = divmod(data, self.per_frame)
        sizes = [can_frame_bits(self.per_frame)] * full
        if rest or not full:
            sizes.append(can_frame_bits(rest))
        return tuple(float(s) for s in sizes)

    def submit(self, packet: Packet) -> None:
        packet.frames = self.frames(packet)
        packet.remaining = len(packet.frames)
        super().submit(packet)

    def _bus(self) -> Generator[simpy.Event, Any, None]:
        env = self.env
        n = self.n_nodes
        while True:
            best = -1
            for i in range(n):
                if (self.current[i] is not None or self.queues[i].items) and (
                        best < 0 or self.ids[i] < self.ids[best]):
                    best = i
            if best < 0:
                yield self.idle()
                continue
            packet = self.current[best]
            if packet is None:
                packet = self.current[best] = self.queues[best].items.popleft()
            bits = packet.frames[len(packet.frames) - packet.remaining]
            self.count("frames")
            yield env.timeout(bits / self.bit_rate)
            packet.remaining -= 1
            if packet.remaining == 0:
                self.current[best] = None
                self.deliver_all(packet, env.now + self.propagation)
