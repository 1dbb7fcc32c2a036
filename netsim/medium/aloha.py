"""Slotted ALOHA: a backlogged node transmits in each slot with probability p.

Slots of ``slot`` seconds (default: one packet's transmission time) from t = 0. At each
slot boundary every node with a queued packet transmits its head packet with
probability ``p`` (p-persistent; default 1/N). A slot with exactly one transmission
delivers it (``propagation`` after the slot's end); two or more collide, and each
collided packet stays at the head of its queue for another try, or is dropped after
``max_attempts`` attempts (``retry limit``; 0: never).

Closed form checked in the tests: with every node backlogged, the attempts per slot are
Binomial(N, p), so the throughput (successes per slot) is S = N p (1 - p)^(N-1), which
tends to the classic S = G e^(-G) with offered load G = N p as N grows.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import simpy

from netsim.medium.core import REASON_RETRY_LIMIT, SharedMedium
from netsim.medium.registry import register_mac

__all__ = ["SlottedAloha"]


@register_mac
class SlottedAloha(SharedMedium):
    """p-persistent slotted ALOHA, one collision domain."""

    name = "aloha"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.slot = float(self.params["slot"])
        self.p = float(self.params["p"])
        self.max_attempts = int(self.params["max_attempts"])
        self.env.process(self._slots())

    def _slots(self) -> Generator[simpy.Event, Any, None]:
        env, rng = self.env, self.rng
        m = 0
        while True:
            backlogged = [i for i, q in enumerate(self.queues) if q.items]
            if not backlogged:
                yield self.idle()
                m = self.next_slot(m, self.slot)  # a packet waits for the next slot boundary
                continue
            start = m * self.slot
            if start > env.now:
                yield env.timeout(start - env.now)
                backlogged = [i for i, q in enumerate(self.queues) if q.items]
            draws = rng.random(len(backlogged))
            senders = [i for i, u in zip(backlogged, draws.tolist(), strict=True) if u < self.p]
            heads = [self.queues[i].items[0] for i in senders]
            self.count("slots")
            self.count("attempts", len(senders))
            yield env.timeout(self.slot)
            if len(senders) == 1:
                self.count("successes")
                items = self.queues[senders[0]].items
                if items and items[0] is heads[0]:  # (not dropped from the queue meanwhile)
                    items.popleft()
                    self.deliver_all(heads[0], env.now + self.propagation)
            elif senders:
                self.count("collisions")
                for i, packet in zip(senders, heads, strict=True):
                    packet.attempts += 1
                    if self.max_attempts and packet.attempts >= self.max_attempts:
                        q = self.queues[i].items
                        if q and q[0] is packet:
                            q.popleft()
                            self.drop_all(packet, REASON_RETRY_LIMIT)
            m += 1

