"""TDMA: a shared medium with a repeating slot schedule.

Time is cut into slots of ``slot`` seconds from t = 0; slot m belongs to node
``schedule[m mod len(schedule)]`` (default: agents 0..N-1, one slot each), so a frame
lasts F = len(schedule) * slot. In its slot a node transmits the packets at the head of
its FIFO queue that fit before the slot's end minus ``guard``; a packet is received
``propagation`` after its last bit. Nobody else transmits in a slot: no collisions.

Closed form (the deterministic worst case): a node with one slot per frame whose queue
holds at most the packet being sent waits less than one frame for its slot, so every
delay is below F + C + propagation (C = packet bits / bit rate) and comes arbitrarily
close to it for a packet made just after its slot began.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import simpy

from netsim.medium.core import SharedMedium
from netsim.medium.registry import register_mac

__all__ = ["TDMA"]


@register_mac
class TDMA(SharedMedium):
    """Time-division multiple access with a slot schedule."""

    name = "tdma"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.slot = float(self.params["slot"])
        self.guard = float(self.params["guard"])
        self.schedule = tuple(self.params["schedule"])
        self.env.process(self._frames())

    @property
    def frame(self) -> float:
        """F, seconds per frame."""
        return self.slot * len(self.schedule)

    def _frames(self) -> Generator[simpy.Event, Any, None]:
        env = self.env
        slots = len(self.schedule)
        m = 0
        while True:
            if not any(q.items for q in self.queues):
                # idle medium: sleep until a packet comes, then resume at the first slot
                # that starts at or after it
                yield self.idle()
                m = self.next_slot(m, self.slot)
                continue
            start = m * self.slot
            if start > env.now:
                yield env.timeout(start - env.now)
            items = self.queues[self.schedule[m % slots]].items
            end = start + self.slot - self.guard
            while items and env.now + items[0].bits / self.bit_rate <= end * (1 + 1e-12):
                packet = items.popleft()
                yield env.timeout(packet.bits / self.bit_rate)
                self.deliver_all(packet, env.now + self.propagation)
            m += 1
