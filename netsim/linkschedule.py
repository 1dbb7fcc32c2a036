"""Every message of every link, computed ahead of time, as the event kernel handles it.

The links' behaviour (delays, losses, outages, buffers) does not depend on what the
messages carry, only on when they are sent. When the sending steps are known in
advance (every step, or every block step), the fate of each message of a trial can
therefore be computed before any estimate exists: its delay, its arrival time, and
whether and when it is dropped. :func:`build_schedule` does this for a batch of
trials with the same random streams and the same rules as :class:`netsim.links.Link`
and :class:`netsim.links.ConfiguredLink` (delay drawn first for every message, then
outage, loss and buffer, in that order; deliveries at equal times in sending order;
a message that arrives exactly at a sampling instant is usable there).
:func:`select_messages` then gives, for every link and step, the message the
receiving estimator uses: the largest time-stamp delivered so far (the freshest rule,
estimators with time-stamps) or the most recently arrived one (no time-stamps).

Links whose model has no loss, outage or buffer are computed with array operations
(the delay model's ``draw_many`` when it has one); the others message by message.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, cast

import numpy as np

from netsim.models.delays import DelayModel, FixedDelays

__all__ = [
    "DELIVERED",
    "LinkSchedule",
    "MessageSelection",
    "build_schedule",
    "select_messages",
]

#: ``LinkSchedule.fate`` of a message that was not dropped (delivered if it arrives
#: before the run ends).
DELIVERED = 0

_REASON_DROP_TAIL = "buffer full (drop-tail)"
_REASON_DROP_OLDEST = "buffer full (drop-oldest)"
_REASON_SUPERSEDED = "superseded (keep-latest)"


@dataclass
class LinkSchedule:
    """The messages of a batch of trials on every link.

    Attributes
    ----------
    links : list of (int, int)
        Links (sender, receiver), in the kernel's order (by sender, then receiver).
    send_steps : numpy.ndarray, shape (S,), int
        Steps at which every link sends; message ``q`` of a link is its ``q``-th
        (sequence number q).
    wait : numpy.ndarray, shape (T, L, S), float, or None
        Time from sending to arrival, in sampling periods (arrival at s + wait); None
        for integer step delays without drops (``lossless_steps``), where it is
        ``delay_steps + 1`` (:meth:`wait_of`).
    delay_steps : numpy.ndarray, shape (T, L, S), int
        Step delay d of each message (usable at s + 1 + d).
    latency : numpy.ndarray, shape (T, L, S), float
        The raw draw of the delay model (steps or time, as the model's ``unit``).
    fate : numpy.ndarray, shape (T, L, S), int
        DELIVERED, or 1 + the index of the drop reason in ``reasons``.
    drop_time : numpy.ndarray, shape (T, L, S), float
        Time of the drop in sampling periods (NaN when not dropped).
    reasons : list of str
        Drop reasons, see :mod:`netsim.links`.
    constant_delay : numpy.ndarray or None, shape (T, L), int
        Set when every link has one constant step delay and drops nothing (the
        per-message arrays are then broadcast views).
    lossless_steps : bool
        Every delay is in steps and no link drops anything (``fate`` and
        ``drop_time`` are broadcast views): a message arrives at the sampling instant
        s + 1 + d.
    """

    links: list[tuple[int, int]]
    send_steps: np.ndarray
    wait: np.ndarray | None
    delay_steps: np.ndarray
    latency: np.ndarray
    fate: np.ndarray
    drop_time: np.ndarray
    reasons: list[str]
    constant_delay: np.ndarray | None = None
    lossless_steps: bool = False

    def wait_of(self, trial: int) -> np.ndarray:
        """``wait`` of one trial, shape (L, S), float."""
        if self.wait is None:
            return self.delay_steps[trial] + 1.0
        return self.wait[trial]

    @cached_property
    def arrival(self) -> np.ndarray:
        """Arrival times s + wait, shape (T, L, S), in sampling periods."""
        if self.wait is None:
            return (self.send_steps + 1.0) + self.delay_steps
        return self.send_steps.astype(float) + self.wait

    @cached_property
    def max_delay_steps(self) -> int:
        """The largest step delay d of any message (0 without messages)."""
        return int(self.delay_steps.max()) if self.delay_steps.size else 0

    def _arrived_counts(self, ends: np.ndarray, among: np.ndarray | None = None
                        ) -> np.ndarray:
        """Per trial, the messages (of ``among``, a (T, L, S) bool array, if given) that
        arrived by step ``ends[t]``: s + 1 + d <= end, lossless step delays only.

        With delays at most D every message sent at s <= end - 1 - D has arrived and
        none sent after end - 1 has, so only the D rows of sending steps in between
        are compared, per group of trials with the same end (the same counts as the
        whole (T, L, S) comparison). The arrays are read as (S, L, T) views.
        """
        send = self.send_steps
        T, L, S = self.delay_steps.shape
        d = self.delay_steps.transpose(2, 1, 0)  # (S, L, T)
        flags = None if among is None else among.transpose(2, 1, 0)
        if flags is not None:
            # messages of ``among`` per trial in the rows before each sending step
            per_row = np.count_nonzero(flags, axis=1)  # (S, T)
            before = np.zeros((S + 1, T), dtype=np.int64)
            np.cumsum(per_row, axis=0, out=before[1:])
        D = self.max_delay_steps
        out = np.zeros(T, dtype=np.int64)
        for end in np.unique(ends).tolist():
            trials = np.flatnonzero(ends == end)
            sure = int(np.searchsorted(send, end - 1 - D, side="right"))
            maybe = max(sure, int(np.searchsorted(send, end - 1, side="right")))
            counted = (sure * L if flags is None else before[sure, trials])
            if maybe > sure:
                limit = (end - 1 - send[sure:maybe])[:, None, None]
                every = len(trials) == T
                rows = d[sure:maybe] if every else d[sure:maybe][:, :, trials]
                hit = rows <= limit
                if flags is not None:
                    hit &= flags[sure:maybe] if every else flags[sure:maybe][:, :, trials]
                counted = counted + np.count_nonzero(hit, axis=(0, 1))
            out[trials] = counted
        return out

    def counts(self, ends: np.ndarray) -> list[dict[str, object]]:
        """Messages sent, delivered and dropped by each trial's end.

        Parameters
        ----------
        ends : numpy.ndarray, shape (T,)
            Last step of each trial (the divergence step, or K).

        Returns
        -------
        list of dict
            Per trial: ``sent``, ``delivered``, ``dropped`` (ints) and
            ``drop_reasons`` (reason -> count), as the kernel counts them for a run that
            stopped at that step (deliveries and drops up to and including its time).
        """
        end = np.asarray(ends, dtype=float)[:, None, None]
        if self.constant_delay is not None:
            # s + 1 + d <= end  <=>  s <= end - 1 - d
            limit = np.asarray(ends)[:, None] - 1 - self.constant_delay
            delivered = np.searchsorted(self.send_steps, limit, side="right").sum(axis=1)
            return [{"sent": int(np.count_nonzero(self.send_steps <= e)) * len(self.links),
                     "delivered": int(n), "dropped": 0, "drop_reasons": {}}
                    for e, n in zip(np.asarray(ends).tolist(), delivered.tolist(), strict=True)]
        if self.lossless_steps:
            # s + 1 + d <= end, in integers
            delivered = self._arrived_counts(np.asarray(ends, dtype=np.int64))
            return [{"sent": int(np.count_nonzero(self.send_steps <= e)) * len(self.links),
                     "delivered": int(n), "dropped": 0, "drop_reasons": {}}
                    for e, n in zip(np.asarray(ends).tolist(), delivered.tolist(), strict=True)]
        delivered = np.count_nonzero((self.fate == DELIVERED) & (self.arrival <= end),
                                     axis=(1, 2))
        dropped = (self.fate != DELIVERED) & (self.drop_time <= end)
        out = []
        for t in range(self.fate.shape[0]):
            reasons: dict[str, int] = {}
            if self.reasons:
                codes = np.bincount(self.fate[t][dropped[t]], minlength=len(self.reasons) + 1)
                reasons = {r: int(c) for r, c in zip(self.reasons, codes[1:].tolist(),
                                                      strict=True) if c}
            out.append({
                "sent": int(np.count_nonzero(self.send_steps <= ends[t])) * len(self.links),
                "delivered": int(delivered[t]),
                "dropped": int(np.count_nonzero(dropped[t])),
                "drop_reasons": reasons,
            })
        return out


@dataclass
class MessageSelection:
    """Which message each link's receiver uses at each step.

    Attributes
    ----------
    chosen : numpy.ndarray, shape (K+1, L, T), int32
        Index q (into ``send_steps``) of the message the receiver of link l holds at
        step k of trial t, or -1 when nothing has arrived yet.
    discarded : numpy.ndarray, shape (T, L, S), bool
        Messages discarded on arrival by the freshest rule (time-stamp not newer than
        the one already held); all False without time-stamps.
    max_lag : int
        Largest k - s over all used messages (0 when none is used).
    uniform_delay : int or None
        d when every link of every trial has the constant step delay d and a message
        is sent every step (so the receiver holds the message sent at k - 1 - d from
        step d + 1 on); None otherwise.
    """

    chosen: np.ndarray
    discarded: np.ndarray
    max_lag: int
    uniform_delay: int | None = None

    def discarded_by(self, schedule: LinkSchedule, ends: np.ndarray) -> np.ndarray:
        """Messages discarded by each trial's end, shape (T,), int.

        Those that arrived (and were sent) by the trial's last step ``ends[t]``, as
        the kernel counts them for a run that stopped there. With constant delays
        every link delivers in sending order and nothing is discarded
        (:func:`_select_constant`), so the (T, L, S) arrival times are not built.
        """
        if schedule.constant_delay is not None:
            return np.zeros(len(ends), dtype=np.int64)
        end = np.asarray(ends)[:, None, None]
        if schedule.lossless_steps:
            return schedule._arrived_counts(np.asarray(ends, dtype=np.int64),
                                            among=self.discarded)
        else:
            arrived = (schedule.arrival <= end) & (schedule.send_steps[None, None, :] <= end)
        return np.count_nonzero(self.discarded & arrived, axis=(1, 2))


def _draws(delays: DelayModel, sender: int, receiver: int, send_steps: np.ndarray
           ) -> np.ndarray | float:
    """The delay model's raw draws for one link's messages (a scalar if constant)."""
    if delays.time_invariant:
        return delays.draw(sender, receiver, int(send_steps[0]) if len(send_steps) else 0)
    many = getattr(delays, "draw_many", None)
    if many is not None:
        return np.asarray(many(sender, receiver, send_steps))
    return np.array([delays.draw(sender, receiver, int(s)) for s in send_steps])


def _configured_pass(model, send_steps: np.ndarray, wait: np.ndarray, fate: np.ndarray,
                     drop_time: np.ndarray, code) -> None:
    """Outages, loss and buffer of one link, message by message (ConfiguredLink rules)."""
    outages = model.outages if model.outages is not None and model.outages.intervals else None
    loss = model.loss
    capacity = model.buffer_capacity
    policy = model.buffer_policy
    keep_latest = policy == "keep-latest"
    in_flight: dict[int, float] = {}
    pending: list[tuple[float, int]] = []
    newest = -1

    def deliver_until(time: float) -> None:
        nonlocal newest
        while pending and pending[0][0] <= time:
            arrival, q = heapq.heappop(pending)
            if in_flight.pop(q, None) is None:
                continue  # cancelled while in flight (drop-oldest)
            if keep_latest:
                if q < newest:
                    fate[q] = code(_REASON_SUPERSEDED)
                    drop_time[q] = arrival
                    continue
                newest = q
    for q, s in enumerate(send_steps.tolist()):
        deliver_until(float(s))
        if outages is not None and outages.down(s):
            fate[q], drop_time[q] = code(outages.reason), s
            continue
        if loss is not None:
            reason = loss.drop_reason(s, q)
            if reason is not None:
                fate[q], drop_time[q] = code(reason), s
                continue
        if capacity is not None and len(in_flight) >= capacity:
            if policy == "drop-tail":
                fate[q], drop_time[q] = code(_REASON_DROP_TAIL), s
                continue
            oldest = next(iter(in_flight))
            del in_flight[oldest]
            fate[oldest], drop_time[oldest] = code(_REASON_DROP_OLDEST), s
        arrival = s + float(wait[q])
        in_flight[q] = arrival
        heapq.heappush(pending, (arrival, q))
    deliver_until(math.inf)


def _same_model(model: DelayModel, first: DelayModel) -> bool:
    """Whether two delay models are equal as values (dataclass equality), not just the
    same object; models without value equality compare as different."""
    try:
        return type(model) is type(first) and bool(model == first)
    except (TypeError, ValueError):  # e.g. == on arrays inside a model
        return False


def _static_schedule(delay_models: Sequence[DelayModel], links: Sequence[tuple[int, int]],
                     send_steps: np.ndarray) -> LinkSchedule | None:
    """The schedule of constant integer step delays on lossless links, or None.

    Every message of a link then has the same delay: the per-message arrays are
    broadcast views of one value per link (no memory per message), and nothing is
    dropped, so the whole schedule costs O(T L).
    """
    T, L, S = len(delay_models), len(links), len(send_steps)
    d = np.zeros((T, L, 1))
    arrays = None
    for t, model in enumerate(delay_models):
        if t and _same_model(model, delay_models[0]):
            d[t] = d[0]  # e.g. homogeneous delays: every trial has the same model
            continue
        if type(model) is FixedDelays:
            # plain fixed delays (homogeneous, heterogeneous, fixed): one vectorised
            # lookup for every link (no per-link Python)
            if arrays is None:
                arr = np.fromiter(itertools.chain.from_iterable(links), dtype=np.int64,
                                  count=2 * L).reshape(-1, 2)
                arrays = arr[:, 0], arr[:, 1]
            d[t, :, 0] = model.link_delays(*arrays)
            continue
        for l_, (j, i) in enumerate(links):
            from netsim.links import resolve_link

            delays, configured = resolve_link(model, j, i)
            if configured is not None or not delays.time_invariant or delays.unit != "steps":
                return None
            d[t, l_, 0] = delays.draw(j, i, int(send_steps[0]) if S else 0)
    if not (np.all(np.isfinite(d)) and np.all(d >= 0)):
        return None  # the general path reports the bad value
    shape = (T, L, S)
    delay_steps = d.astype(np.int64)
    return LinkSchedule(
        list(links), send_steps,
        wait=np.broadcast_to(delay_steps + 1.0, shape),
        delay_steps=np.broadcast_to(delay_steps, shape),
        latency=np.broadcast_to(d, shape),
        fate=np.broadcast_to(np.zeros((1, 1, 1), dtype=np.int16), shape),
        drop_time=np.broadcast_to(np.full((1, 1, 1), np.nan), shape),
        reasons=[],
        constant_delay=delay_steps[:, :, 0],
    )


def build_schedule(
    delay_models: Sequence[DelayModel],
    links: Sequence[tuple[int, int]],
    send_steps: np.ndarray,
    *,
    sample_period: float = 1.0,
) -> LinkSchedule:
    """Compute every message's delay and fate for a batch of trials.

    Parameters
    ----------
    delay_models : sequence of DelayModel, length T
        Each trial's delay model, freshly built (``Scenario.delay_model(trial_seed)``);
        it is consumed exactly as the kernel would consume it.
    links : sequence of (int, int), length L
        Links (sender, receiver).
    send_steps : numpy.ndarray, shape (S,)
        Increasing steps at which every link sends.
    sample_period : float
        Ts.

    Returns
    -------
    LinkSchedule
    """
    send_steps = np.asarray(send_steps, dtype=np.int64)
    T, L, S = len(delay_models), len(links), len(send_steps)
    static = _static_schedule(delay_models, links, send_steps)
    if static is not None:
        return static
    # stored (trial, message, link): each trial's (messages, links) block lands in
    # place, one contiguous write (the selection reads it as (S, L, T) through one
    # transposing copy into bytes, :func:`_select_bounded`); the schedule's arrays
    # are (T, L, S) views of it
    # whole-set integer step draws (asynchronous delays): kept as integers
    integer = all(getattr(m, "link", None) is None and hasattr(m, "draw_block")
                  and not m.time_invariant and m.unit == "steps" for m in delay_models)
    stored = np.zeros((T, S, L), dtype=np.int32 if integer else float)
    latency = stored.transpose(0, 2, 1)
    in_steps = np.zeros(L, dtype=bool)
    reasons: list[str] = []
    index: dict[str, int] = {}

    def code(reason: str) -> int:
        if reason not in index:
            index[reason] = len(reasons) + 1
            reasons.append(reason)
        return index[reason]

    from netsim.links import resolve_link  # (simpy: only when a run builds a schedule)

    configured_links = []
    for t, model in enumerate(delay_models):
        # models that draw a whole link set at once (one stream per trial, seed layout
        # 2): their links' delays as one (S, L') block
        # (a delay model with the optional draw_block, its columns)
        blocks: dict[int, tuple[Any, list[int]]] = {}
        plain = getattr(model, "link", None) is None  # no per-link models to resolve
        if plain and hasattr(model, "draw_block") and not model.time_invariant:
            in_steps[:] = model.unit == "steps"
            stored[t] = model.draw_block(links, send_steps)
            continue
        for l_, (j, i) in enumerate(links):
            delays, configured = (model, None) if plain else resolve_link(model, j, i)
            in_steps[l_] = delays.unit == "steps"
            if hasattr(delays, "draw_block") and not delays.time_invariant:
                blocks.setdefault(id(delays), (delays, []))[1].append(l_)
            else:
                latency[t, l_] = _draws(delays, j, i, send_steps)
            if configured is not None:
                configured_links.append((t, l_, configured))
        for delays, columns in blocks.values():
            stored[t][:, columns] = delays.draw_block([links[c] for c in columns], send_steps)
    # Link._stamp: a step delay d waits 1 + d periods; a latency l waits l / Ts and
    # counts as d = ceil(l / Ts) - 1 (at least 0)
    if integer and (not stored.size or stored.min() >= 0):
        shape = (T, L, S)
        return LinkSchedule(
            list(links), send_steps, None, latency, latency,
            fate=np.broadcast_to(np.zeros((1, 1, 1), dtype=np.int16), shape),
            drop_time=np.broadcast_to(np.full((1, 1, 1), np.nan), shape),
            reasons=[], lossless_steps=True)
    if not np.all(np.isfinite(latency)) or np.any(latency < 0):
        t, l_, q = np.argwhere(~(np.isfinite(latency) & (latency >= 0)))[0]
        j, i = links[l_]
        raise ValueError(f"delay must be finite and >= 0, got {latency[t, l_, q]} on link "
                         f"{j}->{i}")
    if in_steps.all():
        delay_steps = latency.astype(np.int64)
        wait = delay_steps + 1.0
    else:
        scaled = latency / sample_period
        delay_steps = np.maximum(np.ceil(scaled) - 1, 0).astype(np.int64)
        wait = scaled
        if in_steps.any():
            steps_mask = in_steps[None, :, None]
            delay_steps = np.where(steps_mask, latency.astype(np.int64), delay_steps)
            wait = np.where(steps_mask, delay_steps + 1.0, scaled)
    if in_steps.all() and not configured_links:
        # nothing is dropped: the per-message fates are broadcast views
        shape = (T, L, S)
        return LinkSchedule(
            list(links), send_steps, wait, delay_steps, latency,
            fate=np.broadcast_to(np.zeros((1, 1, 1), dtype=np.int16), shape),
            drop_time=np.broadcast_to(np.full((1, 1, 1), np.nan), shape),
            reasons=[], lossless_steps=True)
    fate = np.zeros((T, L, S), dtype=np.int16)
    drop_time = np.full((T, L, S), np.nan)
    for t, l_, configured in configured_links:
        _configured_pass(configured, send_steps, wait[t, l_], fate[t, l_], drop_time[t, l_],
                         code)
    return LinkSchedule(list(links), send_steps, wait, delay_steps, latency, fate, drop_time,
                        reasons)


def _max_lag(chosen: np.ndarray, send: np.ndarray) -> int:
    """Largest k - s over the messages held in ``chosen`` (K+1, L, T)."""
    if chosen.size == 0:
        return 0
    held = chosen >= 0
    # per step k, the oldest message held anywhere (index of its send step), at once
    oldest = np.min(chosen, axis=tuple(range(1, chosen.ndim)), initial=np.iinfo(np.int32).max,
                    where=held)
    steps = np.flatnonzero(held.reshape(chosen.shape[0], -1).any(axis=1))
    if steps.size == 0:
        return 0
    return max(0, int(np.max(steps - send[oldest[steps]])))


def _select_constant(schedule: LinkSchedule, K: int) -> MessageSelection:
    """:func:`select_messages` for constant step delays d and no drops.

    Messages arrive in sending order, so the freshest is also the last arrived and
    none is discarded: at step k the receiver holds the last message sent at a step
    s with s + 1 + d <= k.
    """
    send = schedule.send_steps
    T, L, S = schedule.fate.shape
    discarded = np.broadcast_to(np.zeros((1, 1, 1), dtype=bool), (T, L, S))
    # a delay beyond K + 1 behaves as K + 1 (the message never arrives by step K);
    # capping keeps the int32 step arithmetic below exact for any delay
    constant = cast(np.ndarray, schedule.constant_delay)  # the caller checked: constant
    delay = np.minimum(constant.T, K + 1)  # (L, T)
    steps = np.arange(K + 1, dtype=np.int32)[:, None, None]
    every_step = len(send) == K + 1 and bool(np.array_equal(send, np.arange(K + 1)))
    if every_step and delay.size and bool(np.all(delay == delay.flat[0])):
        # one delay d everywhere, a message every step: the message sent at k - 1 - d
        # (index = step), the same for every link and trial (a broadcast view)
        d = int(delay.flat[0])
        column = np.maximum(steps - 1 - d, -1).astype(np.int32)
        chosen = np.broadcast_to(column, (K + 1, L, T))
        return MessageSelection(chosen, discarded, d + 1 if K >= d + 1 else 0, d)
    limit = steps - 1 - delay[None, :, :].astype(np.int32)  # (K+1, L, T): latest s usable
    if every_step:
        chosen = np.maximum(limit, -1).astype(np.int32)  # index = step
    else:
        chosen = (np.searchsorted(send, limit, side="right") - 1).astype(np.int32)
    return MessageSelection(chosen, discarded, _max_lag(chosen, send))


def _select_bounded(schedule: LinkSchedule, K: int) -> MessageSelection:
    """:func:`select_messages` (freshest rule) for lossless step delays, a message every
    step.

    Message s of a link is usable from step s + 1 + d_s on, so the receiver holds at
    step k the largest s with d_s <= k - 1 - s (LCSYS2022 eq. 4's freshest time-stamp).
    With delays at most D, the message sent at k - 1 - D has always arrived and
    dominates every older one: held[k] = k - 1 - r for the smallest r in 0..D with
    d_{k-1-r} <= r (-1 if none, which happens only at k <= D), D + 1 whole-array passes
    instead of a sort. The passes run on one-byte copies of the delays and lags
    (D < 127; :func:`_select_bounded_wide` otherwise), without masked copies (a
    candidate lag is r, or r + 128 when message k - 1 - r has not arrived, and the
    lag is the minimum of the candidates), a block of steps at a time in cache; the
    int32 indices are written once per block. The same selection as
    :func:`_select_bounded_wide`, element for element.
    """
    T, L, S = schedule.delay_steps.shape
    D = schedule.max_delay_steps
    if D >= 127:
        return _select_bounded_wide(schedule, K)
    # (S, L, T), the delays in one byte: one transposing copy of the schedule's array
    small = schedule.delay_steps.transpose(2, 1, 0).astype(np.uint8, order="C")
    chosen = np.empty((K + 1, L, T), dtype=np.int32)
    chosen[0] = -1  # nothing arrives before step 1
    stale = np.zeros((S, L, T), dtype=bool)
    max_r = -1
    width = max(1, (1 << 18) // max(1, L * T))
    lag = np.empty((width, L, T), dtype=np.uint8)
    mask = np.empty((width, L, T), dtype=bool)
    cand = np.empty((width, L, T), dtype=np.uint8)
    for k0 in range(1, K + 1, width):
        k1 = min(k0 + width, K + 1)
        part = lag[: k1 - k0]
        part.fill(255)  # nothing held
        for r in range(min(D, k1 - 2), -1, -1):
            # step k holds s = k - 1 - r (if s >= 0) when it has arrived: d_s <= r
            lo = max(k0, r + 1)
            m, c = mask[: k1 - lo], cand[: k1 - lo]
            np.greater(small[lo - 1 - r:k1 - 1 - r], r, out=m)
            np.left_shift(m.view(np.uint8), 7, out=c)
            np.bitwise_or(c, r, out=c)
            np.minimum(part[lo - k0:], c, out=part[lo - k0:])
        out = chosen[k0:k1]
        # chosen = k - 1 - lag where a message is held; from step D + 1 on one always is
        np.subtract(np.arange(k0 - 1, k1 - 1, dtype=np.int32)[:, None, None], part,
                    out=out, dtype=np.int32)
        early = min(k1, D + 1) - k0  # steps k <= D of this block
        if early > 0:
            none = part[:early] >= 128
            out[:early][none] = -1
            held = part[:early][~none]
            if held.size:
                max_r = max(max_r, int(held.max()))
            if early < k1 - k0:
                max_r = max(max_r, int(part[early:].max()))
        else:
            max_r = max(max_r, int(part.max()))
    # freshest rule: message s is discarded on arrival if a newer one s' = s + r
    # arrived before it: s' + 1 + d_s' < s + 1 + d_s, i.e. d_(s+r) + r < d_s (r <= D)
    shifted = cand.view(np.uint8)
    for s0 in range(0, S, width):
        s1 = min(s0 + width, S)
        out_s = stale[s0:s1]
        for r in range(1, D + 1):
            if s0 + r >= S:
                break
            top = min(s1, S - r)  # s + r must exist
            c, m = shifted[: top - s0], mask[: top - s0]
            np.add(small[s0 + r:top + r], r, out=c)  # at most 2 D < 254
            np.less(c, small[s0:top], out=m)
            out_s[: top - s0] |= m
    return MessageSelection(chosen, stale.transpose(2, 1, 0), max_r + 1)


def _select_bounded_wide(schedule: LinkSchedule, K: int) -> MessageSelection:
    """:func:`_select_bounded` for delays of 127 steps and more (int32 passes).

    Message s of a link is usable from step s + 1 + d_s on, so the receiver holds at
    step k the largest s with d_s <= k - 1 - s (LCSYS2022 eq. 4's freshest time-stamp).
    With delays at most D, the message sent at k - 1 - D has always arrived and
    dominates every older one: held[k] = k - 1 - r for the smallest r in 0..D with
    d_{k-1-r} <= r (-1 if none), D + 1 whole-array passes instead of a sort.
    """
    T, L, S = schedule.delay_steps.shape
    d = np.ascontiguousarray(schedule.delay_steps.transpose(2, 1, 0))  # (S, L, T)
    D = int(d.max()) if d.size else 0
    chosen = np.full((K + 1, L, T), -1, dtype=np.int32)
    stale = np.zeros((S, L, T), dtype=bool)
    sent = np.arange(K + 1, dtype=np.int32)[:, None, None]
    max_lag = 0
    # a few hundred thousand entries at a time, so that the D + 1 passes stay in cache
    width = max(1, (1 << 18) // max(1, L * T))
    for k0 in range(1, K + 1, width):
        k1 = min(k0 + width, K + 1)
        part = chosen[k0:k1]
        for r in range(min(D, k1 - 2), -1, -1):  # oldest first: newer ones overwrite
            # step k holds s = k - 1 - r (if s >= 0) when it has arrived: d_s <= r
            lo = max(k0, r + 1)
            np.copyto(part[lo - k0:], sent[lo - 1 - r:k1 - 1 - r],
                      where=d[lo - 1 - r:k1 - 1 - r] <= r)
        lag = sent[k0:k1] - part
        max_lag = max(max_lag, int(np.max(lag, where=part >= 0, initial=0)))
    # freshest rule: message s is discarded on arrival if a newer one s' = s + r
    # arrived before it: s' + 1 + d_s' < s + 1 + d_s, i.e. d_(s+r) + r < d_s (r <= D)
    for s0 in range(0, S, width):
        s1 = min(s0 + width, S)
        out = stale[s0:s1]
        for r in range(1, D + 1):
            if s0 + r >= S:
                break
            top = min(s1, S - r)  # s + r must exist
            out[: top - s0] |= d[s0 + r:top + r] + r < d[s0:top]
    return MessageSelection(chosen, stale.transpose(2, 1, 0), max_lag)


def select_messages(schedule: LinkSchedule, steps: int, *, timestamps: bool) -> MessageSelection:
    """For every link and step, the message its receiver holds at that step's update.

    Parameters
    ----------
    schedule : LinkSchedule
    steps : int
        Last step K.
    timestamps : bool
        True: the message with the largest time-stamp delivered so far (freshest
        rule, LCSYS2022 eq. 4); False: the most recently arrived one (delay-tolerant
        eq. 6; at equal arrival times the one sent last, as the kernel delivers them).

    Returns
    -------
    MessageSelection
    """
    K = int(steps)
    T, L, S = schedule.fate.shape
    send = schedule.send_steps
    if schedule.constant_delay is not None and S:
        return _select_constant(schedule, K)
    if (timestamps and schedule.lossless_steps and S == K + 1
            and bool(np.array_equal(send, np.arange(K + 1)))):
        return _select_bounded(schedule, K)
    ok = schedule.fate == DELIVERED
    all_ok = bool(ok.all())
    arrival = schedule.arrival if all_ok else np.where(ok, schedule.arrival, np.inf)
    # usable at the first sampling instant at or after arrival, and never before s + 1
    usable_f = np.minimum(arrival, K + 1)
    np.ceil(usable_f, out=usable_f)
    np.maximum(usable_f, send + 1, out=usable_f)
    usable = usable_f.astype(np.int64)
    del usable_f
    group = np.arange(T * L, dtype=np.int64).reshape(T, L, 1) * (K + 2)

    def held_count(values: np.ndarray) -> np.ndarray:
        # values: (T, L, S) non-decreasing along the last axis; returns, per step k,
        # (number of entries <= k) - 1, shape (T, L, K+1)
        counts = np.bincount((group + values).reshape(-1), minlength=T * L * (K + 2))
        held = np.cumsum(counts.reshape(T, L, K + 2)[:, :, : K + 1], axis=-1, dtype=np.int32)
        held -= 1
        return held

    discarded = np.zeros((T, L, S), dtype=bool)
    if timestamps:
        # held[k] = largest q with usable[q] <= k = (number of q whose suffix minimum
        # of usable is <= k) - 1, since that suffix minimum is non-decreasing in q
        suffix = np.minimum.accumulate(usable[:, :, ::-1], axis=-1)[:, :, ::-1]
        held = held_count(suffix)
        if S > 1:
            # freshest rule: discarded on arrival if a newer message arrived before it
            later = np.minimum.accumulate(arrival[:, :, :0:-1], axis=-1)[:, :, ::-1]
            discarded[:, :, :-1] = later < arrival[:, :, :-1]
            if not all_ok:
                discarded &= ok
    else:
        # arrival order (ties: the one sent first arrives first, as the kernel
        # schedules them); usable steps are non-decreasing in that order
        order = np.argsort(arrival, axis=-1, kind="stable")
        rank_held = held_count(np.take_along_axis(usable, order, axis=-1))
        held = np.where(rank_held >= 0,
                        np.take_along_axis(order, np.maximum(rank_held, 0), axis=-1), -1)
    chosen = np.ascontiguousarray(held.transpose(2, 1, 0), dtype=np.int32)
    del held
    return MessageSelection(chosen, discarded, _max_lag(chosen, send))
