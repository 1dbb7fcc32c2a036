"""Write trace format 3: per-step messages, from the kernel's events or from arrays.

Two writers share :class:`StepWriter` (schemas, channels, the ``trace_layout``
metadata, encoding through :func:`netsim.traces.stepcodec.encode_steps` and the bulk
MCAP writer's :meth:`~netsim.traces.bulkmcap.BulkMcapWriter.add_records`):

- :class:`StepLog`, the event kernel's path: :class:`netsim.traces.recorder.TraceRecorder`
  (``trace_format=3``) hands it every observer call; it gathers a step's values and,
  when the next step starts, that step's messages; every ``flush_every`` steps the
  gathered steps are encoded at once and written as a chunk (what a killed writer can
  lose);
- the vectorised engine's path (:func:`netsim.vectrace.write_trial`) builds the same
  columns for the whole trial from the batch arrays and calls :meth:`StepWriter.emit`.

Format 3 itself is described in :mod:`netsim.traces.schemas3`. Which step's message
holds an event: a sent message, the step it was sent at; a delivery, the step it is
usable at (``usable_step`` = s + 1 + d: deliveries at k Ts before the updates of k,
zero-latency ones at (k-1) Ts and those between the two), in (link, s) order; a drop,
the step
:func:`drop_bucket` gives (the first k with k Ts >= drop time).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from netsim.traces.schemas3 import (
    ABSENT,
    LAYOUT_METADATA,
    MAX_LINK_REASON_LINKS,
    TOPICS,
    file_descriptor_set,
    schema_name,
)
from netsim.traces.stepcodec import Column, encode_records

__all__ = ["StepWriter", "StepLog", "TraceLayoutError", "drop_bucket", "arrival_column"]

_TOPIC_OF = {type_name: topic for topic, type_name in TOPICS.items()}


class TraceLayoutError(ValueError):
    """An event that format 3 cannot hold (the message says what and why)."""


def drop_bucket(drop_time: float, sample_period: float) -> int:
    """The step whose ``/links/dropped`` message lists a drop at ``drop_time``: the
    first k with k Ts >= drop_time (times within 1e-9 steps of k Ts count as k Ts)."""
    return int(math.ceil(drop_time / sample_period - 1e-9))


def link_reasons(link: Column, reason: Column, rows: int, n_links: int) -> Column:
    """``LinkDrops.link_reason`` of ``rows`` messages: per message and link l, the largest
    reason code of link l's drops in it (0 none); no values beyond
    :data:`netsim.traces.schemas3.MAX_LINK_REASON_LINKS` links."""
    if not 0 < n_links <= MAX_LINK_REASON_LINKS:
        return Column(np.zeros(0, dtype=np.uint32), np.zeros(rows, dtype=np.int64))
    counts = (np.full(rows, link.values.shape[1], dtype=np.int64) if link.counts is None
              else np.asarray(link.counts, dtype=np.int64))
    row = np.repeat(np.arange(rows), counts)
    table = np.zeros((rows, n_links), dtype=np.uint32)
    links = np.asarray(link.values, dtype=np.int64).ravel()
    known = links < n_links
    np.maximum.at(table, (row[known], links[known]),
                  np.asarray(reason.values, dtype=np.uint32).ravel()[known])
    return Column(table)


@functools.cache
def _descriptor_set_bytes() -> bytes:
    return file_descriptor_set().SerializeToString()


class StepWriter:
    """Schemas, channels and layout of a format-3 file written through ``recorder``
    (a type's schema and channel are written when its first message is).

    Parameters
    ----------
    recorder : netsim.traces.recorder.TraceRecorder
        An open recorder (its ``writer``, ``time_origin_ns``, counts).
    """

    def __init__(self, recorder: Any) -> None:
        self.recorder = recorder
        self.writer = recorder.writer
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._layout_written: dict[str, str] | None = None
        self._n_links = 0

    def channel(self, type_name: str) -> int:
        """The channel id of a message type's topic (registered on first use)."""
        found = self._channels.get(type_name)
        if found is None:
            schema = self._schemas[type_name] = self.writer.register_schema(
                name=schema_name(type_name), encoding=SchemaEncoding.Protobuf,
                data=_descriptor_set_bytes())
            found = self._channels[type_name] = self.writer.register_channel(
                topic=_TOPIC_OF[type_name], message_encoding=MessageEncoding.Protobuf,
                schema_id=schema)
        return found

    def layout(self, layout: Mapping[str, Any]) -> None:
        """Write the ``trace_layout`` metadata record (again when it changed: readers
        take the last one; every list in it only grows, so an index never moves)."""
        record = {str(k): json.dumps(v, separators=(",", ":")) for k, v in layout.items()}
        self._n_links = len(layout.get("links", ()))
        if record != self._layout_written:
            self.writer.add_metadata(LAYOUT_METADATA, record)
            self._layout_written = record

    def emit(self, type_name: str, step: np.ndarray, time: np.ndarray,
             columns: Mapping[str, Column]) -> None:
        """Encode and add one message per row (step order) of one type."""
        step = np.asarray(step, dtype=np.int64)
        rows = step.shape[0]
        if not rows:
            return
        recorder = self.recorder
        if type_name == "LinkDrops" and "link_reason" not in columns:
            columns = {**columns, "link_reason": link_reasons(
                columns["link"], columns["reason"], rows, self._n_links)}
        time = np.asarray(time, dtype=float)
        log_time = (np.round(time * 1e9).astype(np.int64)
                    + np.int64(recorder.time_origin_ns)).astype(np.uint64)
        channel = self.channel(type_name)
        records, starts = encode_records(type_name, step, time, columns, channel, log_time)
        self.writer.add_records(records, starts, np.full(rows, channel, dtype=np.uint16),
                                log_time)
        topic = _TOPIC_OF[type_name]
        recorder.counts[topic] = recorder.counts.get(topic, 0) + rows
        recorder.messages_written += rows
        recorder._last_log_time = max(recorder._last_log_time, int(log_time[-1]))


class _Step:
    """What one step gathers (the event kernel's path)."""

    __slots__ = ("k", "time", "state", "measurements", "estimates", "updates", "freshness",
                 "sends")

    def __init__(self, k: int, time: float, state: np.ndarray,
                 measurements: list[np.ndarray]) -> None:
        self.k, self.time = k, time
        self.state = state
        self.measurements = measurements
        self.estimates: dict[int, tuple[np.ndarray, float]] = {}
        self.updates: dict[int, int] = {}  # update entry -> r
        self.freshness: dict[int, tuple[list[int], list[int], list[int], int]] = {}
        self.sends: dict[int, tuple[int, float, np.ndarray | None]] = {}


class StepLog:
    """The event kernel's format-3 path: observer calls in, per-step messages out.

    Parameters
    ----------
    recorder : netsim.traces.recorder.TraceRecorder
        The recorder whose hooks call this object (``on_plant`` ... ``on_dropped``).
    record_payloads : bool
        Keep sent payloads (a payload equal to the sender's estimate of that step is
        not stored: the reader takes the estimate).
    """

    def __init__(self, recorder: Any, record_payloads: bool = True) -> None:
        self.recorder = recorder
        self.out = StepWriter(recorder)
        self.ts = float(recorder.sample_period)
        self.record_payloads = record_payloads
        self.links: list[tuple[int, int]] = []
        self._link: dict[tuple[int, int], int] = {}
        self.entries: list[tuple[int, int]] = []  # update entries (j, i)
        self._entry: dict[tuple[int, int], int] = {}
        self.n_agents = 0
        self.n_states: int | None = None
        self.sensor_widths: list[int] | None = None
        self.freshness_sizes: list[int] = []
        self.payload_width: int | None = None
        self._sent_counts: dict[int, int] = {}
        self.current: _Step | None = None
        self.done: list[_Step] = []
        self.deliveries: dict[int, list[tuple[int, int, int]]] = {}
        self.drops: dict[int, list[tuple[int, int, int, float]]] = {}

    # -- layout ----------------------------------------------------------------------

    def layout(self) -> dict[str, Any]:
        """The ``trace_layout`` record as it stands."""
        return {
            "agents": self.n_agents, "n_states": self.n_states or 0,
            "sensor_widths": self.sensor_widths or [], "links": [list(x) for x in self.links],
            "updates": [list(x) for x in self.entries],
            "freshness_sizes": self.freshness_sizes,
            "payload": "estimate" if self.record_payloads else "none",
            "payload_width": self.payload_width or 0,
        }

    def _link_index(self, sender: int, receiver: int) -> int:
        key = (sender, receiver)
        found = self._link.get(key)
        if found is None:
            found = self._link[key] = len(self.links)
            self.links.append(key)
        return found

    # -- hooks -----------------------------------------------------------------------

    def plant(self, k: int, state: np.ndarray, measurements: Any) -> None:
        if self.current is not None:
            self._finish(self.current)
        step = self.current = _Step(
            k, k * self.ts, np.array(state, dtype=float).ravel(),
            [np.asarray(y, dtype=float).ravel() for y in measurements])
        if self.n_states is None:
            self.n_states = step.state.shape[0]
            self.sensor_widths = [y.shape[0] for y in step.measurements]

    def _step(self, k: int, what: str) -> _Step:
        step = self.current
        if step is None or step.k != k:
            raise TraceLayoutError(
                f"trace format 3: {what} at step {k} outside plant step "
                f"{None if step is None else step.k} (use trace format 2)")
        return step

    def update(self, agent: int, k: int, estimate: np.ndarray, delays: Mapping[int, int],
               error_norm: float) -> None:
        step = self._step(k, f"agent {agent}'s update")
        x_hat = np.array(estimate, dtype=float).ravel()
        step.estimates[agent] = (x_hat, error_norm)
        self.n_agents = max(self.n_agents, agent + 1)
        for j, r in delays.items():
            key = (int(j), agent)
            e = self._entry.get(key)
            if e is None:
                e = self._entry[key] = len(self.entries)
                self.entries.append(key)
            step.updates[e] = int(r)

    def freshness(self, agent: int, k: int, index: list[int], adopted: list[int],
                  dims: list[int], max_index: int) -> None:
        step = self._step(k, f"agent {agent}'s freshness")
        while len(self.freshness_sizes) <= agent:
            self.freshness_sizes.append(0)
        if self.freshness_sizes[agent] == 0:
            self.freshness_sizes[agent] = len(index)
        elif self.freshness_sizes[agent] != len(index):
            raise TraceLayoutError(
                f"trace format 3: agent {agent} reports {len(index)} freshness indices "
                f"after {self.freshness_sizes[agent]} (use trace format 2)")
        step.freshness[agent] = (index, adopted, dims, max_index)

    def sent(self, message: Any) -> None:
        k = int(message.sent_step)
        step = self._step(k, f"message {message.sender}->{message.receiver} sent")
        l_ = self._link_index(int(message.sender), int(message.receiver))
        expected = self._sent_counts.get(l_, 0)
        if int(message.sequence) != expected or float(message.send_time) != step.time:
            raise TraceLayoutError(
                f"trace format 3: message {message.sender}->{message.receiver} of step {k} "
                f"has sequence {message.sequence} (expected {expected}) and send time "
                f"{message.send_time} (expected {step.time}) (use trace format 2)")
        self._sent_counts[l_] = expected + 1
        payload = None
        if self.record_payloads and message.payload is not None:
            own = step.estimates.get(int(message.sender))
            values = np.asarray(message.payload, dtype=float).ravel()
            if own is None or not np.array_equal(values, own[0]):
                if self.payload_width is None:
                    self.payload_width = values.shape[0]
                if values.shape[0] != self.payload_width:
                    raise TraceLayoutError(
                        f"trace format 3: payloads of {values.shape[0]} values after "
                        f"{self.payload_width} (use trace format 2)")
                payload = values
        step.sends[l_] = (int(message.delay_steps), float(message.arrival_time), payload)

    def delivered(self, message: Any, accepted: bool) -> None:
        l_ = self._link_index(int(message.sender), int(message.receiver))
        usable = int(message.sent_step) + 1 + int(message.delay_steps)
        self.deliveries.setdefault(usable, []).append(
            (l_, int(message.sent_step), int(bool(accepted))))

    def dropped(self, message: Any, code: int, drop_time: float) -> None:
        l_ = self._link_index(int(message.sender), int(message.receiver))
        bucket = drop_bucket(drop_time, self.ts)
        self.drops.setdefault(bucket, []).append(
            (l_, int(message.sent_step), int(code), float(drop_time)))

    # -- writing ---------------------------------------------------------------------

    def _finish(self, step: _Step) -> None:
        self.done.append(step)
        self.current = None

    def flush(self) -> None:
        """Encode and write every finished step (and the link events of their steps)."""
        steps, self.done = self.done, []
        if not steps:
            return
        self._write(steps, extra=[])

    def close(self) -> None:
        """Finish the step in progress and write everything left, then the link events
        of steps after the last plant step (deliveries and drops still to come)."""
        if self.current is not None:
            self._finish(self.current)
        steps, self.done = self.done, []
        last = steps[-1].k if steps else -1
        extra = sorted(k for k in set(self.deliveries) | set(self.drops) if k > last)
        self._write(steps, extra)

    def _write(self, steps: list[_Step], extra: list[int]) -> None:
        if not steps and not extra:
            return
        out = self.out
        out.layout(self.layout())
        N, n, L, E = self.n_agents, self.n_states or 0, len(self.links), len(self.entries)
        k = np.array([s.k for s in steps], dtype=np.int64)
        t = k * self.ts
        if steps:
            out.emit("PlantState", k, t, {"state": Column(np.stack([s.state for s in steps]))})
            values = [np.concatenate(s.measurements) if s.measurements else np.zeros(0)
                      for s in steps]
            out.emit("Measurements", k, t, {"values": _ragged(values, np.float64)})
            updated = np.zeros((len(steps), N), dtype=bool)
            est = np.full((len(steps), N, n), np.nan)
            norm = np.full((len(steps), N), np.nan)
            delays = np.full((len(steps), E), ABSENT, dtype=np.int32)
            for r, s in enumerate(steps):
                for i, (x_hat, e) in s.estimates.items():
                    updated[r, i] = True
                    est[r, i] = x_hat
                    norm[r, i] = e
                for e, d in s.updates.items():
                    delays[r, e] = d
            out.emit("Estimates", k, t, {"updated": Column(updated),
                                         "estimate": Column(est.reshape(len(steps), N * n)),
                                         "error_norm": Column(norm)})
            out.emit("Updates", k, t, {"effective_delay": Column(delays)})
            if any(s.freshness for s in steps):
                self._write_freshness(steps, k, t)
            self._write_sends(steps, k, t, L)
        buckets = [int(b) for b in k] + extra
        self._write_link_events(buckets)

    def _write_freshness(self, steps: list[_Step], k: np.ndarray, t: np.ndarray) -> None:
        sizes = self.freshness_sizes + [0] * (self.n_agents - len(self.freshness_sizes))
        start = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        S = int(start[-1])
        index = np.full((len(steps), S), ABSENT, dtype=np.int32)
        adopted = np.full((len(steps), S), ABSENT, dtype=np.int32)
        dims = np.full((len(steps), S), ABSENT, dtype=np.int32)
        top = np.full((len(steps), len(sizes)), ABSENT, dtype=np.int32)
        for r, s in enumerate(steps):
            for i, (idx, adp, dim, m) in s.freshness.items():
                a, b = start[i], start[i + 1]
                index[r, a:b], adopted[r, a:b], dims[r, a:b] = idx, adp, dim
                top[r, i] = m
        self.out.emit("Freshness", k, t, {"index": Column(index), "adopted_from": Column(adopted),
                                          "substate_dim": Column(dims),
                                          "max_index": Column(top)})

    def _write_sends(self, steps: list[_Step], k: np.ndarray, t: np.ndarray, L: int) -> None:
        delay = np.full((len(steps), L), ABSENT, dtype=np.int32)
        arrival = np.full((len(steps), L), np.nan)
        payloads: list[np.ndarray] = []
        for r, s in enumerate(steps):
            stored = None
            for l_, (d, a, p) in s.sends.items():
                delay[r, l_], arrival[r, l_] = d, a
                if p is not None:
                    if stored is None:
                        stored = np.full((L, self.payload_width or 0), np.nan)
                    stored[l_] = p
            if stored is not None:  # some payload was not the sender's estimate
                for l_, (_, _, p) in s.sends.items():
                    if p is None:
                        j = self.links[l_][0]
                        stored[l_] = s.estimates[j][0]
            payloads.append(np.zeros(0) if stored is None else stored.reshape(-1))
        columns = {"delay_steps": Column(delay),
                   "arrival_time": arrival_column(k, delay, arrival, self.ts)}
        if any(p.size for p in payloads):
            columns["payload"] = _ragged(payloads, np.float64)
        self.out.emit("LinkSends", k, t, columns)

    def _write_link_events(self, buckets: list[int]) -> None:
        drops = [self.drops.pop(b, []) for b in buckets]
        if any(drops):
            rows = [b for b, d in zip(buckets, drops, strict=True) if d]
            events = [d for d in drops if d]
            flat = [e for d in events for e in d]
            counts = np.array([len(d) for d in events], dtype=np.int64)
            kk = np.array(rows, dtype=np.int64)
            self.out.emit("LinkDrops", kk, kk * self.ts, {
                "link": Column(np.array([e[0] for e in flat], dtype=np.uint32), counts),
                "sent_step": Column(np.array([e[1] for e in flat], dtype=np.uint32), counts),
                "reason": Column(np.array([e[2] for e in flat], dtype=np.uint32), counts),
                "drop_time": Column(np.array([e[3] for e in flat], dtype=float), counts)})
        deliveries = [self.deliveries.pop(b, []) for b in buckets]
        if any(deliveries):
            rows = [b for b, d in zip(buckets, deliveries, strict=True) if d]
            delivered = [sorted(d) for d in deliveries if d]  # (link, sent step) order
            counts = np.array([len(d) for d in delivered], dtype=np.int64)
            kk = np.array(rows, dtype=np.int64)
            self.out.emit("LinkDeliveries", kk, kk * self.ts, {"accepted": Column(
                np.array([e[2] for d in delivered for e in d], dtype=bool), counts)})


def arrival_column(k: np.ndarray, delay: np.ndarray, arrival: np.ndarray, ts: float
                   ) -> Column:
    """``LinkSends.arrival_time`` of rows ``k``: left out of a row (empty) when every
    message sent at k arrives at (k + 1 + d) Ts (delays in steps), else all L values.

    ``delay`` and ``arrival`` have shape (rows, L) (``ABSENT`` / NaN: nothing sent)."""
    sent = delay != ABSENT
    implied = (k[:, None] + 1 + delay).astype(float) * ts
    same = np.all(~sent | (arrival == implied), axis=1)
    if same.all():
        return Column(np.zeros((len(k), 0)))
    if not same.any():
        return Column(arrival)
    counts = np.where(same, 0, arrival.shape[1])
    return Column(arrival[~same].reshape(-1), counts)


def _ragged(rows: list[np.ndarray], dtype: Any) -> Column:
    counts = np.array([r.shape[0] for r in rows], dtype=np.int64)
    values = np.concatenate(rows).astype(dtype) if rows else np.zeros(0, dtype)
    return Column(values, counts)
