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
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from models.delays import DelayModel

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
    wait : numpy.ndarray, shape (T, L, S), float
        Time from sending to arrival, in sampling periods (arrival at s + wait).
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
    """

    links: list[tuple[int, int]]
    send_steps: np.ndarray
    wait: np.ndarray
    delay_steps: np.ndarray
    latency: np.ndarray
    fate: np.ndarray
    drop_time: np.ndarray
    reasons: list[str]

    @property
    def arrival(self) -> np.ndarray:
        """Arrival times s + wait, shape (T, L, S), in sampling periods."""
        return self.send_steps.astype(float) + self.wait

    def counts(self, trial: int, end: int) -> dict[str, object]:
        """Messages sent, delivered and dropped up to and including time ``end``.

        Returns a dict with ``sent``, ``delivered``, ``dropped`` (ints) and
        ``drop_reasons`` (reason -> count), as the kernel counts them for a run
        that stopped at step ``end``.
        """
        sent_mask = self.send_steps <= end
        fate = self.fate[trial][:, sent_mask]
        arrival = self.arrival[trial][:, sent_mask]
        drop_time = self.drop_time[trial][:, sent_mask]
        delivered = int(np.count_nonzero((fate == DELIVERED) & (arrival <= end)))
        dropped_mask = (fate != DELIVERED) & (drop_time <= end)
        reasons: dict[str, int] = {}
        codes, numbers = np.unique(fate[dropped_mask], return_counts=True)
        for code, number in zip(codes.tolist(), numbers.tolist(), strict=True):
            reasons[self.reasons[code - 1]] = int(number)
        return {
            "sent": int(fate.size),
            "delivered": delivered,
            "dropped": int(np.count_nonzero(dropped_mask)),
            "drop_reasons": reasons,
        }


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
    """

    chosen: np.ndarray
    discarded: np.ndarray
    max_lag: int


def _kernel_link_model(delay_model: DelayModel, sender: int, receiver: int):
    """The (delay model, link model or None) the kernel gives link sender -> receiver."""
    per_link = getattr(delay_model, "link", None)
    model = per_link(sender, receiver) if per_link is not None else None
    delays = model.delay if model is not None and model.delay is not None else delay_model
    if model is not None and model.trivial:
        model = None
    return delays, model


def _draw(delays: DelayModel, sender: int, receiver: int, send_steps: np.ndarray,
          sample_period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw draws, waits (periods) and step delays of one link's messages."""
    many = getattr(delays, "draw_many", None)
    if many is not None:
        raw = np.asarray(many(sender, receiver, send_steps))
    else:
        raw = np.array([delays.draw(sender, receiver, int(s)) for s in send_steps])
    if delays.unit == "steps":
        d = raw.astype(np.int64)
        return raw.astype(float), 1.0 + d, d
    raw = raw.astype(float)
    if raw.size and not (np.all(np.isfinite(raw)) and np.all(raw >= 0)):
        bad = raw[~(np.isfinite(raw) & (raw >= 0))][0]
        raise ValueError(f"latency must be finite and >= 0, got {bad} on link "
                         f"{sender}->{receiver}")
    wait = raw / sample_period
    d = np.maximum(np.ceil(wait) - 1, 0).astype(np.int64)
    return raw, wait, d


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
    wait = np.zeros((T, L, S))
    delay_steps = np.zeros((T, L, S), dtype=np.int64)
    latency = np.zeros((T, L, S))
    fate = np.zeros((T, L, S), dtype=np.int16)
    drop_time = np.full((T, L, S), np.nan)
    reasons: list[str] = []
    index: dict[str, int] = {}

    def code(reason: str) -> int:
        if reason not in index:
            index[reason] = len(reasons) + 1
            reasons.append(reason)
        return index[reason]

    for t, model in enumerate(delay_models):
        for l_, (j, i) in enumerate(links):
            delays, configured = _kernel_link_model(model, j, i)
            raw, w, d = _draw(delays, j, i, send_steps, sample_period)
            latency[t, l_], wait[t, l_], delay_steps[t, l_] = raw, w, d
            if configured is not None:
                _configured_pass(configured, send_steps, w, fate[t, l_], drop_time[t, l_],
                                 code)
    return LinkSchedule(list(links), send_steps, wait, delay_steps, latency, fate, drop_time,
                        reasons)


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
    ok = schedule.fate == DELIVERED
    arrival = np.where(ok, schedule.arrival, np.inf)
    # usable at the first sampling instant at or after arrival, and never before s + 1
    with np.errstate(invalid="ignore"):
        usable = np.maximum(send + 1, np.ceil(np.minimum(arrival, K + 1))).astype(np.int64)
    usable = np.minimum(usable, K + 1)
    order = np.argsort(arrival, axis=-1, kind="stable")  # arrival order, ties by sending
    slots = np.broadcast_to(np.arange(S, dtype=np.int64), (T, L, S))
    if timestamps:
        key = slots
    else:
        key = np.empty((T, L, S), dtype=np.int64)
        np.put_along_axis(key, order, slots, axis=-1)  # rank in arrival order
    latest = np.full((T, L, K + 2), -1, dtype=np.int64)
    flat = (np.arange(T * L, dtype=np.int64).reshape(T, L, 1) * (K + 2) + usable)
    np.maximum.at(latest.reshape(-1), flat[ok], key[ok])
    held = np.maximum.accumulate(latest[:, :, : K + 1], axis=-1)
    if not timestamps:
        held = np.where(held >= 0, np.take_along_axis(order, np.maximum(held, 0), axis=-1), -1)
    # freshest rule: discarded on arrival if a newer time-stamp arrived before it
    discarded = np.zeros((T, L, S), dtype=bool)
    if timestamps and S:
        arrived = np.take_along_axis(np.where(ok, slots, -1), order, axis=-1)
        before = np.maximum.accumulate(arrived, axis=-1)
        before = np.concatenate([np.full((T, L, 1), -1), before[:, :, :-1]], axis=-1)
        np.put_along_axis(discarded, order, (arrived >= 0) & (arrived < before), axis=-1)
    used = held >= 0
    max_lag = 0
    if np.any(used):
        steps_k = np.arange(K + 1, dtype=np.int64)
        lag = np.where(used, steps_k - send[np.maximum(held, 0)], 0)
        max_lag = int(lag.max())
    chosen = np.ascontiguousarray(held.transpose(2, 1, 0)).astype(np.int32)
    return MessageSelection(chosen, discarded, max_lag)
