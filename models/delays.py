"""Link delay models: fixed per link, and time-varying random bounded.

A delay model answers one question for the kernel: a message sent on link
``(sender, receiver)`` at step ``s`` is delayed by how much? Models in *steps*
return an integer d >= 0 (the message is usable by the receiver's update at step
s + 1 + d, DESIGN.md); models in *time* return a continuous latency l >= 0 in the
unit of the sampling period Ts, which maps to d = ceil(l / Ts) - 1 clamped at 0.

Every random model owns its generator(s), derived from one seed by name
(:mod:`netsim.models.seeding`), so two models never share a stream. Per-message draws
of a link set (asynchronous delays) come from one stream per trial for the whole set,
drawn as (messages, links) blocks (:class:`LinkBlockDraws`, seed layout 2,
:data:`netsim.models.seeding.SEED_LAYOUT`), which the event kernel reads one value at
a time and the vectorised engine as whole arrays. Adding or removing a link of the set
changes the draws of the others (the table's rows are the set's width).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from itertools import chain, islice
from operator import length_hint
from typing import Any, Literal, Protocol

import numpy as np
from netsim.models.seeding import SeedLike, stream

__all__ = [
    "BATCH_SIZE",
    "BLOCK_ELEMENTS",
    "BatchedDraws",
    "LinkBlockDraws",
    "DelayModel",
    "FixedDelays",
    "SynchronousRandomDelays",
    "AsynchronousRandomDelays",
    "FixedLatencies",
    "heterogeneous_delays",
    "homogeneous_delays",
    "latency_to_steps",
]

Link = tuple[int, int]

#: Random draws are made this many at a time per stream (same numbers as one at a time).
BATCH_SIZE = 256


class BatchedDraws:
    """Values of ``fn(rng, size)`` handed out in order, drawn BATCH_SIZE at a time.

    :meth:`next` and :attr:`sampler` (one value, for the event kernel) and :meth:`take`
    (many values at once, for the vectorised engine) advance the same sequence, so a
    model gives the same numbers whichever engine asks.

    Parameters
    ----------
    rng : numpy.random.Generator
        The stream (owned by this object from now on).
    fn : callable(rng, size) -> numpy.ndarray
        One batch of draws.
    """

    __slots__ = ("_rng", "_fn", "_values", "_dtype", "_current", "_carry", "sampler")

    def __init__(self, rng: np.random.Generator, fn: Any) -> None:
        self._rng = rng
        self._fn = fn
        self._dtype: Any = float
        #: iterator over the rest of the batch being handed out (None before the first)
        self._current: Iterator[Any] | None = None
        #: the rest of a batch that :meth:`take` drew and cut, to be handed out next
        self._carry: list[Any] | None = None
        # the endless sequence of values (Python scalars), batch after batch
        self._values = chain.from_iterable(self._batches())
        #: The next value as a callable send_step -> value, at the cost of one C call:
        #: ``next(values, send_step)``, whose second argument (a default for an
        #: exhausted iterator) is never used since the sequence never ends.
        self.sampler = partial(next, self._values)

    def _batches(self) -> Iterator[Iterator[Any]]:
        while True:
            if self._carry is not None:
                values, self._carry = self._carry, None
            else:
                batch = self._fn(self._rng, BATCH_SIZE)
                self._dtype = batch.dtype
                values = batch.tolist()
            self._current = iter(values)
            yield self._current

    def next(self, send_step: int | None = None) -> Any:
        """Return the next value (a Python scalar).

        ``send_step`` is ignored: it lets ``next`` serve as a per-link sampler
        send_step -> delay (see ``DelayModel``).
        """
        return next(self._values)

    def take(self, count: int) -> np.ndarray:
        """Return the next ``count`` values as an array, shape (count,).

        The rest of the batch being handed out comes first; whole batches are then
        drawn as arrays (the same ``fn(rng, BATCH_SIZE)`` calls as one at a time), and
        the part of the last one not taken is handed out next.
        """
        left = length_hint(self._current) if self._current is not None else 0
        head = list(islice(self._values, min(left, count)))
        if self._carry is not None and len(head) < count:
            # a cut batch not yet handed out: it comes next
            cut = count - len(head)
            head += self._carry[:cut]
            self._carry = self._carry[cut:] or None
        batches = []
        need = count - len(head)
        while need > 0:
            batch = self._fn(self._rng, BATCH_SIZE)
            self._dtype = batch.dtype
            if need < BATCH_SIZE:
                self._carry = batch[need:].tolist()
                batch = batch[:need]
            batches.append(batch)
            need -= len(batch)
        return np.concatenate([np.array(head, dtype=self._dtype), *batches])


#: A block of :class:`LinkBlockDraws` holds about this many values (at least one row).
BLOCK_ELEMENTS = 1 << 16


class LinkBlockDraws:
    """Per-message draws of a link set from one stream, one (rows, L) block at a time.

    Row q of the (endless) table holds the value of message q (the q-th message sent)
    of every link; column c is link ``links[c]``. Blocks of R = max(1, min(BATCH_SIZE,
    BLOCK_ELEMENTS // L)) rows are drawn in order as ``fn(rng, R * L)`` laid out row
    by row, so the table depends only on the stream, ``fn`` and the link set, never on
    who reads it or in which order: the event kernel reads a link's column one value
    at a time (:meth:`sampler`, :meth:`next`), the vectorised engine many rows of many
    columns at once (:meth:`take`), and both get the same numbers.

    Parameters
    ----------
    rng : numpy.random.Generator
        The stream (owned by this object from now on).
    fn : callable(rng, size) -> numpy.ndarray
        ``size`` draws, shape (size,).
    links : sequence of (int, int)
        The link set, in column order.
    """

    __slots__ = ("_rng", "_fn", "links", "column", "rows", "_blocks", "_start", "_iters")

    def __init__(self, rng: np.random.Generator, fn: Any, links: Iterable[Link]) -> None:
        self._rng = rng
        self._fn = fn
        self.links = [(int(j), int(i)) for j, i in links]
        #: column of each link
        self.column = {link: c for c, link in enumerate(self.links)}
        if len(self.column) != len(self.links):
            raise ValueError("the links of a block stream must be distinct")
        self.rows = max(1, min(BATCH_SIZE, BLOCK_ELEMENTS // max(1, len(self.links))))
        self._blocks: list[np.ndarray] = []
        #: the next row of each column not yet read by a sampler (see ``_iters``)
        self._start = np.zeros(len(self.links), dtype=np.int64)
        #: per-column iterators of the one-at-a-time readers (created on first use)
        self._iters: dict[int, Iterator[Any]] = {}

    def _block(self, b: int) -> np.ndarray:
        while len(self._blocks) <= b:
            L = len(self.links)
            values = np.asarray(self._fn(self._rng, self.rows * L)).reshape(self.rows, L)
            values.flags.writeable = False  # handed out as views (take)
            self._blocks.append(values)
        return self._blocks[b]

    def _values(self, c: int, start: int) -> Iterator[Any]:
        b, r = divmod(int(start), self.rows)
        while True:
            yield from self._block(b)[r:, c].tolist()
            b, r = b + 1, 0

    def _iter(self, link: Link) -> Iterator[Any]:
        c = self.column[link]
        it = self._iters.get(c)
        if it is None:
            it = self._iters[c] = self._values(c, int(self._start[c]))
        return it

    def next(self, link: Link) -> Any:
        """The next value of ``link``'s column (a Python scalar)."""
        return next(self._iter(link))

    def sampler(self, link: Link) -> Any:
        """``link``'s next value as a callable send_step -> value (one C call).

        ``next(values, send_step)``: the default argument of ``next`` is never used,
        the column never ends.
        """
        return partial(next, self._iter(link))

    def take(self, links: Sequence[Link], count: int) -> np.ndarray:
        """The next ``count`` values of each of ``links``, shape (count, len(links)).

        The same numbers, and the same state afterwards, as ``count`` calls of
        :meth:`next` per link. Columns read as a whole from the same row (the
        vectorised engine's case) are sliced from the blocks; others value by value.
        """
        cols = np.array([self.column[(int(j), int(i))] for j, i in links], dtype=np.int64)
        if (len(cols) == len(self.links) and not self._iters and count
                and np.array_equal(cols, np.arange(len(cols)))
                and bool(np.all(self._start == self._start[0]))):
            # the whole set from one row (the vectorised engine): rows of the blocks
            start = int(self._start[0])
            first, last = start // self.rows, (start + count - 1) // self.rows
            r = start - first * self.rows
            self._start += count
            if first == last:
                return self._block(first)[r:r + count]
            return np.concatenate([self._block(b) for b in range(first, last + 1)])[
                r:r + count]
        out = np.empty((count, len(cols)), dtype=self._block(0).dtype)
        fresh = np.array([c not in self._iters for c in cols.tolist()], dtype=bool)
        starts = self._start[cols]
        for start in np.unique(starts[fresh]).tolist():
            which = np.flatnonzero(fresh & (starts == start))
            first, last = start // self.rows, (start + count - 1) // self.rows
            rows = np.concatenate([self._block(b) for b in range(first, last + 1)]) \
                if count else self._block(0)[:0]
            r = start - first * self.rows
            out[:, which] = rows[r:r + count][:, cols[which]]
            self._start[cols[which]] += count
        for w in np.flatnonzero(~fresh).tolist():
            out[:, w] = list(islice(self._iters[int(cols[w])], count))
        return out


def latency_to_steps(latency: float, sample_period: float = 1.0) -> int:
    """Map a continuous latency to a step delay, d = max(ceil(l / Ts) - 1, 0).

    A message that arrives exactly at a sampling instant counts as arrived there.

    Parameters
    ----------
    latency : float
        Latency l >= 0 in the unit of ``sample_period``.
    sample_period : float
        Ts > 0.

    Returns
    -------
    int
    """
    if latency < 0 or not math.isfinite(latency):
        raise ValueError(f"latency must be finite and >= 0, got {latency}")
    return max(math.ceil(latency / sample_period) - 1, 0)


class DelayModel(Protocol):
    """Contract of a delay model used by the kernel."""

    # Read-only properties here, so that frozen dataclasses and computed properties
    # satisfy the contract as well as plain attributes do.
    @property
    def unit(self) -> Literal["steps", "time"]:
        """``"steps"`` (integer step delays) or ``"time"`` (continuous latencies)."""
        ...

    @property
    def max_delay(self) -> int:
        """Upper bound tau-bar on the step delay (the papers' bound)."""
        ...

    @property
    def time_invariant(self) -> bool:
        """Whether the delay of a link is constant over time."""
        ...

    def draw(self, sender: int, receiver: int, send_step: int) -> float:
        """Return the delay of one message (steps or time, see ``unit``)."""
        ...

    # Optional: ``sampler(sender, receiver)`` -> callable(send_step) -> delay, the
    # link's ``draw`` as one call (the kernel's lean links use it when present).
    # Optional: ``draw_many(sender, receiver, send_steps) -> numpy.ndarray``, the
    # delays of the link's next messages, sent at the increasing ``send_steps``; the
    # same numbers, and the same state afterwards, as calling ``draw`` for each in
    # order. The vectorised engine uses it when present (else it calls ``draw``).


@dataclass(frozen=True)
class FixedDelays:
    """Constant, possibly heterogeneous, integer delay per link (LCSYS2022 Assumption 2).

    Parameters
    ----------
    delays : Mapping[(sender, receiver), int]
        Delay tau_ij in steps of each link; links not listed use ``default``.
    default : int
        Delay of unlisted links.
    """

    delays: Mapping[Link, int] = field(default_factory=dict)
    default: int = 0
    unit: Literal["steps", "time"] = "steps"
    time_invariant: bool = True

    def __post_init__(self) -> None:
        checked: list[tuple[Link | str, int]] = [*self.delays.items(), ("default", self.default)]
        for link, d in checked:
            if int(d) != d or d < 0:
                raise ValueError(f"delay of link {link} must be a non-negative integer, got {d}")

    @property
    def max_delay(self) -> int:
        return int(max([self.default, *self.delays.values()]))

    def draw(self, sender: int, receiver: int, send_step: int) -> int:
        return int(self.delays.get((sender, receiver), self.default))

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """Delays of messages sent at ``send_steps``, shape (len(send_steps),)."""
        return np.full(len(send_steps), self.draw(sender, receiver, 0), dtype=np.int64)

    def link_delays(self, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
        """Delay of every link (src[l], dst[l]) at once, shape (L,), int64 (vectorised
        :meth:`draw`: the default, then the listed links by a sorted-key search)."""
        src = np.asarray(src, dtype=np.int64)
        dst = np.asarray(dst, dtype=np.int64)
        out = np.full(len(src), int(self.default), dtype=np.int64)
        if self.delays and len(src):
            listed = np.array(list(self.delays), dtype=np.int64).reshape(-1, 2)
            values = np.array(list(self.delays.values()), dtype=np.int64)
            base = int(max(src.max(), dst.max(), listed.max())) + 1
            keys = src * base + dst
            order = np.argsort(keys, kind="stable")
            wanted = listed[:, 0] * base + listed[:, 1]
            at = np.minimum(np.searchsorted(keys[order], wanted), len(keys) - 1)
            hit = keys[order][at] == wanted
            out[order[at[hit]]] = values[hit]
        return out


def homogeneous_delays(links: Iterable[Link], tau: int) -> FixedDelays:
    """Return fixed delays equal to ``tau`` on every link (the default: no per-link
    table, so this is O(1) at any number of links)."""
    return FixedDelays({}, default=int(tau))


def heterogeneous_delays(links: Iterable[Link], tau: int, seed: SeedLike) -> FixedDelays:
    """Return fixed delays drawn once, uniformly from {0, ..., tau}, per link, with the
    bound attained: the link with the largest draw (the first, in sorted link order) is
    set to tau.

    This is the heterogeneous setting of LCSYS2022 Section IV (delays uniformly
    distributed between 0 and tau-bar for different links). Without the last rule a
    realisation for a bound tau could stay far below it (with the same stream reused
    for every tau, tau = 19 gave a largest delay of 10 on the built-in cycle), so a
    report at "tau" would describe a smaller delay. The other links stay uniform in
    {0, ..., tau}. The realisation uses the stream ``"delays/heterogeneous"`` of ``seed``.
    """
    rng = stream(seed, "delays/heterogeneous")
    links = sorted(links)
    draws = rng.integers(0, int(tau) + 1, size=len(links))
    if len(links):
        draws[int(np.argmax(draws))] = int(tau)
    delays = {link: int(d) for link, d in zip(links, draws, strict=True)}
    return FixedDelays(delays, default=int(tau) if not links else int(max(draws)))


class SynchronousRandomDelays:
    """Time-varying bounded delay, one uniform draw in {0..tau} per step for all links.

    The delay-tolerant paper's "synchronous time-varying" case (Fig. 2): at a given
    step every link has the same delay, which changes from step to step.
    """

    unit: Literal["steps", "time"] = "steps"
    time_invariant = False

    def __init__(self, tau: int, seed: SeedLike) -> None:
        if int(tau) != tau or tau < 0:
            raise ValueError(f"delay bound tau must be a non-negative integer, got {tau}")
        self.max_delay = int(tau)
        high = self.max_delay + 1
        self._source = BatchedDraws(stream(seed, "delays/synchronous"),
                                    lambda g, n: g.integers(0, high, size=n))
        self._draws = np.zeros(0, dtype=np.int64)

    def _extend(self, last_step: int) -> None:
        if len(self._draws) <= last_step:
            more = self._source.take(max(last_step + 1 - len(self._draws), BATCH_SIZE))
            self._draws = np.concatenate([self._draws, more.astype(np.int64)])

    def draw(self, sender: int, receiver: int, send_step: int) -> int:
        self._extend(send_step)
        return int(self._draws[send_step])

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """Delays of messages sent at ``send_steps`` (the draws of those steps)."""
        steps = np.asarray(send_steps, dtype=np.int64)
        if steps.size:
            self._extend(int(steps.max()))
        return self._draws[steps]


class AsynchronousRandomDelays:
    """Time-varying bounded delay, an independent uniform draw per link per message.

    The delay-tolerant paper's "asynchronous time-varying" case: every message of
    every link has its own draw, so messages can be reordered. The draws of the link
    set ``links`` come from the trial's one stream ``"delays/asynchronous"`` as
    (messages, links) blocks (:class:`LinkBlockDraws`; seed layout 2): message q of
    link ``links[c]`` gets entry (q, c). A link outside ``links`` (or every link, when
    ``links`` is not given) draws from a stream of its own,
    ``"delays/link/<sender>-<receiver>"`` (the layout-1 stream of that link).
    """

    unit: Literal["steps", "time"] = "steps"
    time_invariant = False

    def __init__(self, tau: int, seed: SeedLike, links: Iterable[Link] | None = None) -> None:
        if int(tau) != tau or tau < 0:
            raise ValueError(f"delay bound tau must be a non-negative integer, got {tau}")
        self.max_delay = int(tau)
        self._seed = seed
        high = self.max_delay + 1
        # int32 draws (the table is (messages x links) of them: half the memory)
        self._fn = lambda g, n: g.integers(0, high, size=n, dtype=np.int32)
        #: the link set's block stream (None without links)
        self.block = (LinkBlockDraws(stream(seed, "delays/asynchronous"), self._fn, links)
                      if links is not None else None)
        self._sources: dict[Link, BatchedDraws] = {}

    def _source(self, sender: int, receiver: int) -> BatchedDraws:
        source = self._sources.get((sender, receiver))
        if source is None:
            high = self.max_delay + 1
            source = self._sources[(sender, receiver)] = BatchedDraws(
                stream(self._seed, f"delays/link/{sender}-{receiver}"),
                lambda g, n: g.integers(0, high, size=n))
        return source

    def _block_of(self, sender: int, receiver: int) -> LinkBlockDraws | None:
        """The link set's block stream if the link is in it, else None."""
        block = self.block
        return block if block is not None and (sender, receiver) in block.column else None

    def draw(self, sender: int, receiver: int, send_step: int) -> int:
        if (block := self._block_of(sender, receiver)) is not None:
            return int(block.next((sender, receiver)))
        return int(self._source(sender, receiver).next())

    def sampler(self, sender: int, receiver: int) -> Any:
        """The link's draw as one callable send_step -> delay (the same sequence)."""
        if (block := self._block_of(sender, receiver)) is not None:
            return block.sampler((sender, receiver))
        return self._source(sender, receiver).sampler

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """Delays of the link's next len(send_steps) messages."""
        if (block := self._block_of(sender, receiver)) is not None:
            return block.take([(sender, receiver)], len(send_steps))[:, 0].astype(
                np.int64, copy=False)
        return self._source(sender, receiver).take(len(send_steps)).astype(np.int64, copy=False)

    def draw_block(self, links: Sequence[Link], send_steps: np.ndarray) -> np.ndarray:
        """Delays of the next len(send_steps) messages of each of ``links``, shape
        (len(send_steps), len(links)): the same numbers and state as :meth:`draw_many`
        link by link."""
        if self.block is not None and all(link in self.block.column for link in links):
            return self.block.take(links, len(send_steps))
        return np.stack([self.draw_many(j, i, send_steps) for j, i in links], axis=1) \
            if len(links) else np.zeros((len(send_steps), 0), dtype=np.int64)


@dataclass(frozen=True)
class FixedLatencies:
    """Constant continuous latency per link, in the time unit of Ts.

    Parameters
    ----------
    latencies : Mapping[(sender, receiver), float]
        Latency l_ij >= 0 of each link; unlisted links use ``default``.
    default : float
        Latency of unlisted links.
    sample_period : float
        Ts, used to report the equivalent step bound.
    """

    latencies: Mapping[Link, float] = field(default_factory=dict)
    default: float = 0.0
    sample_period: float = 1.0
    unit: Literal["steps", "time"] = "time"
    time_invariant: bool = True

    def __post_init__(self) -> None:
        checked: list[tuple[Link | str, float]] = [*self.latencies.items(),
                                                   ("default", self.default)]
        for link, lat in checked:
            if not math.isfinite(lat) or lat < 0:
                raise ValueError(f"latency of link {link} must be finite and >= 0, got {lat}")

    @property
    def max_delay(self) -> int:
        worst = max([self.default, *self.latencies.values()])
        return latency_to_steps(worst, self.sample_period)

    def draw(self, sender: int, receiver: int, send_step: int) -> float:
        return float(self.latencies.get((sender, receiver), self.default))

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """Latencies of messages sent at ``send_steps``, shape (len(send_steps),)."""
        return np.full(len(send_steps), self.draw(sender, receiver, 0), dtype=float)
