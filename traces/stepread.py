"""Read trace format 3 as format 2: per-step messages expanded into format-2 records.

A format-3 file (:mod:`netsim.traces.schemas3`) holds one message per step and kind;
:func:`netsim.traces.reader.read_trace` collects them chunk by chunk as for any trace
(damaged chunks skipped and reported) and then calls :func:`expand_steps`, which
rebuilds from them and the last ``trace_layout`` metadata record the records the
format-2 recorder (:class:`netsim.traces.recorder.TraceRecorder`) writes for the same
event-kernel run: the same topics (``/plant/state``, ``/sensor_<i>/measurement``,
``/agent_<i>/estimate`` ...), messages of the format-2 classes
(:func:`netsim.traces.schemas.message_classes`), ``log_time``, ``publish_time`` and
``sequence``, in log_time order with the kernel's order on ties. So everything that reads
a :class:`netsim.traces.reader.Trace` reads format 3 unchanged.

What is rebuilt, per step k (log_time = origin + ``round(t * 1e9)`` ns of the event's
time t, as the recorder rounds; sequence = k, or the per-link sequence number for link
events):

- ``PlantState``; a ``Measurement`` per sensor (``values`` split by ``sensor_widths``);
- per agent that updated (``Estimates.updated``): ``Estimate`` (``error`` = estimate -
  x_k elementwise, NaN without x_k; ``squared_error`` recomputed from it as the
  recorder computes it; ``error_norm`` as stored) and ``EstimatorUpdate`` (the
  in-neighbours j of its ``Updates`` entries [j, i] that are not ``ABSENT``, sorted;
  ``effective_delay`` r; ``used_timestamp`` k - 1 - r, or -1 when r < 0);
- per AoI agent that reported: ``Freshness`` (its slice of the arrays, by
  ``freshness_sizes``);
- per message sent (``delay_steps`` not ``ABSENT``): ``LinkSent`` (the link's sequence
  number counts the earlier sends on that link in the file; ``payload`` the stored one,
  else the sender's estimate of step k when the layout's ``payload`` is ``estimate``,
  else empty), published at its send time;
- per drop: ``LinkDropped``, joined on (link, sent step) to the message's sent record
  (sequence, times, delay), logged at the drop time;
- per delivery: ``LinkDelivered``. The deliveries of step k are the messages usable
  from k on (sent at s with delay k - 1 - s) that were not dropped, in (link, s) order,
  ``LinkDeliveries.accepted`` saying for each whether the receiver kept it; in a step
  after the last plant step only those that arrived before the run ended (the earliest
  ones). Logged at the arrival time.

Link records are published at the message's send time.

Order on equal log_time (the kernel's, :mod:`netsim.vectrace`): at one instant first the
deliveries scheduled before it and the keep-latest supersessions (by sending step,
sender, link), then the plant and its measurements, then agent by agent its estimate,
update and freshness and, per out-link, the message sent, its drop at sending and the
in-flight message a drop-oldest buffer cancelled for it, then zero-latency deliveries.

What cannot be rebuilt is left out and counted in :attr:`StepView.unexpanded` (and said
in :attr:`StepView.note`), which only happens in a damaged file: a drop whose sent
message was in a lost chunk, the deliveries of a step whose messages do not match its
``accepted`` list (a lost chunk held some of their sends or drops), an agent's update
whose step has no ``Updates`` message, a payload equal to an estimate that was lost, or
entries the last layout does not describe. Sequence numbers count the sends that were
read: after a lost chunk they are smaller than the recorded ones.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from google.protobuf.descriptor_pb2 import FieldDescriptorProto
from netsim.traces.bulkproto import BulkEncoder
from netsim.traces.schemas import MESSAGES as MESSAGES2
from netsim.traces.schemas import (
    TraceRecord,
    estimate_topic,
    freshness_topic,
    link_topic,
    message_classes,
    plant_topic,
    schema_name,
    sensor_topic,
    update_topic,
)
from netsim.traces.schemas3 import ABSENT, LAYOUT_METADATA, TOPICS
from netsim.traces.schemas3 import PACKAGE as PACKAGE3

__all__ = ["StepLayout", "StepView", "read_layout", "expand_steps", "unstack_matrices"]

# phases of the events at one instant (the kernel's order, see netsim.vectrace)
_EARLY, _STEP, _LATE = 0, 1, 2
_REPEATED = FieldDescriptorProto.LABEL_REPEATED
_SEQUENCE_MASK = 0xFFFFFFFF
#: Fields every format-2 link record has (from the message's sent record).
_LINK_COMMON = ("sender", "receiver", "sent_step", "usable_step", "sequence", "send_time",
                "arrival_time", "delay_steps")


@dataclass(frozen=True)
class StepLayout:
    """The ``trace_layout`` metadata record: what format-3 arrays are indexed by.

    Attributes
    ----------
    agents : int
        N.
    n_states : int
        n.
    sensor_widths : tuple of int
        m_i of each sensor (``Measurements.values`` stacks them in sensor order).
    links : tuple of (int, int)
        Link l is ``links[l]`` = (sender j, receiver i).
    updates : tuple of (int, int)
        Entry e of ``Updates.effective_delay`` is r_ij[k] of ``updates[e]`` = (j, i).
    freshness_sizes : tuple of int
        Substates per AoI agent (0: no freshness report).
    payload : str
        ``estimate`` (a payload not stored is the sender's estimate), ``message`` or
        ``none`` (payloads not recorded).
    payload_width : int
        Values per link of ``LinkSends.payload``.
    """

    agents: int = 0
    n_states: int = 0
    sensor_widths: tuple[int, ...] = ()
    links: tuple[tuple[int, int], ...] = ()
    updates: tuple[tuple[int, int], ...] = ()
    freshness_sizes: tuple[int, ...] = ()
    payload: str = "estimate"
    payload_width: int = 0


def read_layout(record: Mapping[str, str]) -> StepLayout:
    """Parse a ``trace_layout`` metadata record (JSON values).

    Parameters
    ----------
    record : mapping str -> str
        The record's entries.

    Returns
    -------
    StepLayout

    Raises
    ------
    ValueError
        An entry that is not the JSON it should be.
    """
    def value(key: str, default: Any) -> Any:
        text = record.get(key)
        if text is None:
            return default
        try:
            return json.loads(text)
        except ValueError:
            raise ValueError(f"trace_layout entry {key!r} is not JSON: {text[:60]!r}") from None

    try:
        pairs = {key: tuple((int(j), int(i)) for j, i in value(key, []))
                 for key in ("links", "updates")}
        return StepLayout(
            agents=int(value("agents", 0)),
            n_states=int(value("n_states", 0)),
            sensor_widths=tuple(int(m) for m in value("sensor_widths", [])),
            links=pairs["links"],
            updates=pairs["updates"],
            freshness_sizes=tuple(int(s) for s in value("freshness_sizes", [])),
            payload=str(value("payload", "estimate")),
            payload_width=int(value("payload_width", 0)),
        )
    except (TypeError, ValueError) as exc:
        raise ValueError(f"trace_layout record unusable ({exc})") from None


@dataclass
class StepView:
    """The format-2 view of a format-3 file (what :class:`netsim.traces.reader.Trace`
    exposes as ``topics``, ``counts``, ``records`` and ``messages``).

    Attributes
    ----------
    topics : dict of str -> str
        Format-2 topic -> format-2 schema name (plus the file's foreign topics), in the
        order the format-2 recorder registers them (first message).
    counts : dict of str -> int
        Records per topic.
    records : dict of str -> list of TraceRecord
        Per topic, in log_time order.
    messages : list of TraceRecord
        All records, in log_time order (the kernel's order on ties).
    unexpanded : dict of str -> int
        What the file holds but could not be expanded, by kind (e.g. ``delivered``: a
        delivery whose sent message was lost); empty for an intact file.
    note : str
        One line on what was left out, "" if nothing.
    """

    topics: dict[str, str]
    counts: dict[str, int]
    records: dict[str, list[TraceRecord]]
    messages: list[TraceRecord]
    unexpanded: dict[str, int] = field(default_factory=dict)
    note: str = ""


# -- reading the format-3 messages ---------------------------------------------------


def _ints(values: Any) -> np.ndarray:
    return np.array(values, dtype=np.int64)


def _floats(values: Any) -> np.ndarray:
    return np.array(values, dtype=np.float64)


def _ns(origin: int, t: np.ndarray) -> np.ndarray:
    """origin + round(t * 1e9) ns (round half to even, as the recorder's ``to_ns``)."""
    return (np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)
            + np.int64(origin)).astype(np.uint64)


class _Block:
    """Format-2 records of one type with equal repeated-field lengths: their columns,
    topics, times, MCAP fields and the keys of the kernel's order."""

    __slots__ = ("type_name", "table", "topic", "columns", "when", "phase", "k1", "k2", "k3",
                 "log_time", "publish_time", "sequence")

    def __init__(self, type_name: str, table: Sequence[str], topic: np.ndarray,
                 columns: dict[str, np.ndarray], when: np.ndarray, phase: Any, k1: Any,
                 k2: Any, k3: Any, log_time: np.ndarray, publish_time: np.ndarray | None = None,
                 sequence: np.ndarray | None = None) -> None:
        rows = topic.shape[0]

        def full(v: Any, dtype: Any) -> np.ndarray:
            return np.broadcast_to(np.asarray(v, dtype=dtype), (rows,))

        self.type_name, self.table, self.topic, self.columns = type_name, table, topic, columns
        self.when = np.asarray(when, dtype=np.float64)
        self.phase, self.k1, self.k2, self.k3 = (full(phase, np.int64), full(k1, np.int64),
                                                 full(k2, np.int64), full(k3, np.int64))
        self.log_time = log_time
        self.publish_time = log_time if publish_time is None else publish_time
        self.sequence = (np.asarray(columns["step"], dtype=np.int64) if sequence is None
                         else sequence) & _SEQUENCE_MASK

    def __len__(self) -> int:
        return int(self.topic.shape[0])


_ENCODERS: dict[tuple[str, tuple[tuple[str, int], ...]], BulkEncoder] = {}


def _decode(block: _Block) -> list[Any]:
    """The block's format-2 messages: encoded at once, then parsed one by one."""
    type_name, rows = block.type_name, len(block)
    lengths = {f.name: (block.columns[f.name].shape[1] if f.name in block.columns else 0)
               for f in MESSAGES2[type_name] if f.label == _REPEATED}
    key = (type_name, tuple(sorted(lengths.items())))
    encoder = _ENCODERS.get(key)
    if encoder is None:
        encoder = _ENCODERS[key] = BulkEncoder(message_classes()[type_name].DESCRIPTOR,
                                               lengths)
    columns = {k: v for k, v in block.columns.items() if lengths.get(k, 1)}
    data = encoder.encode(columns, n=rows).tobytes()
    size = encoder.payload_length
    parse = message_classes()[type_name].FromString
    return [parse(data[o:o + size]) for o in range(0, rows * size, size)]


def _by_length(rows: list[np.ndarray]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Rows (1-D arrays) grouped by length: length -> (row indices, stacked rows)."""
    groups: dict[int, list[int]] = {}
    for r, row in enumerate(rows):
        groups.setdefault(row.shape[0], []).append(r)
    return {m: (np.asarray(idx, dtype=np.int64),
                np.stack([rows[r] for r in idx]) if m else np.zeros((len(idx), 0)))
            for m, idx in groups.items()}


def _padded(rows: list[np.ndarray], fill: Any, dtype: Any) -> np.ndarray:
    """Rows of different lengths as one (len(rows), longest) array padded with ``fill``."""
    width = max((r.shape[0] for r in rows), default=0)
    out = np.full((len(rows), width), fill, dtype=dtype)
    for r, row in enumerate(rows):
        out[r, :row.shape[0]] = row
    return out


def _gather(matrix: np.ndarray, rows: np.ndarray, starts: np.ndarray, count: int
            ) -> np.ndarray:
    """``matrix[rows[g], starts[g]:starts[g] + count]`` for every g: shape (g, count)."""
    return matrix[rows[:, None], starts[:, None] + np.arange(count)[None, :]]


class _Expander:
    """Builds the format-2 blocks of one file (see the module docstring)."""

    def __init__(self, messages: Mapping[str, list[Any]], layout: StepLayout, origin: int,
                 sample_period: float) -> None:
        self.m = messages
        self.layout = layout
        self.origin = origin
        self.ts = sample_period
        self.blocks: list[_Block] = []
        self.unexpanded: dict[str, int] = {}
        links = layout.links
        self.link_sender = np.array([j for j, _ in links], dtype=np.int64)
        self.link_receiver = np.array([i for _, i in links], dtype=np.int64)
        self.link_topics = {e: [link_topic(j, i, e) for j, i in links]
                            for e in ("sent", "delivered", "dropped")}
        # the plant states by step (for the estimates' errors)
        self.state_steps = np.zeros(0, dtype=np.int64)
        self.states = np.zeros((0, 0))
        # the estimates by step (for payloads equal to them)
        self.est_steps = np.zeros(0, dtype=np.int64)
        self.est_updated = np.zeros((0, 0), dtype=bool)
        self.est = np.zeros((0, 0, 0))
        #: the last plant step in the file (-1: none)
        self.last_plant = -1

    def skip(self, kind: str, count: int = 1) -> None:
        if count:
            self.unexpanded[kind] = self.unexpanded.get(kind, 0) + int(count)

    def run(self) -> list[_Block]:
        self.plant()
        self.measurements()
        self.estimates()
        self.freshness()
        sends = self.sends()
        self.link_events(sends)
        return self.blocks

    # -- per step -------------------------------------------------------------------

    def _step_block(self, type_name: str, table: Sequence[str], topic: np.ndarray,
                    columns: dict[str, np.ndarray], k1: Any, k2: Any, k3: Any) -> None:
        time = columns["time"]
        self.blocks.append(_Block(type_name, table, topic, columns, time, _STEP, k1, k2, k3,
                                  _ns(self.origin, time)))

    def plant(self) -> None:
        msgs = self.m.get("PlantState", [])
        if not msgs:
            return
        step = _ints([m.step for m in msgs])
        time = _floats([m.time for m in msgs])
        self.last_plant = int(step.max())
        groups = _by_length([_floats(m.state) for m in msgs])
        for idx, state in groups.values():
            self._step_block("PlantState", [plant_topic()], np.zeros(len(idx), np.int64),
                             {"step": step[idx], "time": time[idx], "state": state},
                             -1, 0, 0)
        # the states of the layout's size give the estimates' errors (NaN for others)
        n = self.layout.n_states or max(groups, key=lambda m: len(groups[m][0]))
        if n in groups:
            idx, state = groups[n]
            self.state_steps, self.states = step[idx], state

    def measurements(self) -> None:
        msgs = self.m.get("Measurements", [])
        widths = np.asarray(self.layout.sensor_widths, dtype=np.int64)
        total = int(widths.sum())
        good = [m for m in msgs if len(m.values) == total]
        self.skip("measurements", len(msgs) - len(good))
        if not good:
            return
        step = _ints([m.step for m in good])
        time = _floats([m.time for m in good])
        values = np.array([list(m.values) for m in good], dtype=np.float64).reshape(
            len(good), total)
        starts = np.concatenate([[0], np.cumsum(widths)])
        rows = len(good)
        for i, m in enumerate(widths.tolist()):
            self._step_block("Measurement", [sensor_topic(i)], np.zeros(rows, np.int64),
                             {"step": step, "time": time, "sensor": np.full(rows, i),
                              "values": values[:, starts[i]:starts[i] + m]}, -1, 1, i)

    def estimates(self) -> None:
        msgs = [m for m in self.m.get("Estimates", []) if len(m.updated)]
        if not msgs:
            return
        n = self.layout.n_states or (len(msgs[0].estimate) // len(msgs[0].updated))
        good = [m for m in msgs if len(m.estimate) == n * len(m.updated)]
        self.skip("estimates", len(msgs) - len(good))
        if not good:
            return
        step = _ints([m.step for m in good])
        time = _floats([m.time for m in good])
        updated = _padded([np.array(m.updated, dtype=bool) for m in good], False, bool)
        R, N = updated.shape
        est = np.full((R, N, n), np.nan)
        norm = np.full((R, N), np.nan)
        for r, m in enumerate(good):
            width = len(m.updated)
            est[r, :width] = _floats(m.estimate).reshape(width, n)
            norm[r, :width] = _floats(m.error_norm)[:width]
        self.est_steps, self.est_updated, self.est = step, updated, est
        rr, ii = np.nonzero(updated)
        x_hat = est[rr, ii]
        # error = x-hat - x_k as the recorder computes it (NaN without x_k)
        where = np.searchsorted(self.state_steps, step[rr])
        found = where < self.state_steps.shape[0]
        found[found] = self.state_steps[where[found]] == step[rr][found]
        if self.states.shape[1] != n:
            found[:] = False
        error = np.full(x_hat.shape, np.nan)
        if found.any():
            error[found] = x_hat[found] - self.states[where[found]]
        squared = np.einsum("ij,ij->i", error, error)  # as the recorder computes it
        squared[~found] = np.nan
        agents = max(N, self.layout.agents)
        self._step_block("Estimate", [estimate_topic(i) for i in range(agents)], ii,
                         {"step": step[rr], "time": time[rr], "agent": ii, "estimate": x_hat,
                          "error": error, "squared_error": squared,
                          "error_norm": norm[rr, ii]}, ii, 0, 0)
        self.updates(step, time, updated, rr, ii, agents)

    def updates(self, step: np.ndarray, time: np.ndarray, updated: np.ndarray,
                rr: np.ndarray, ii: np.ndarray, agents: int) -> None:
        """The EstimatorUpdate of every (row rr, agent ii) that updated."""
        by_step = {int(m.step): m for m in self.m.get("Updates", [])}
        entries = self.layout.updates
        E = len(entries)
        rows = []
        have = np.zeros(step.shape[0], dtype=bool)
        for r, k in enumerate(step.tolist()):
            m = by_step.get(k)
            if m is None:
                rows.append(np.zeros(0, dtype=np.int64))
                continue
            have[r] = True
            values = _ints(m.effective_delay)
            if values.shape[0] > E:
                self.skip("update entries", int((values[E:] != ABSENT).sum()))
                values = values[:E]
            rows.append(values)
        delays = _padded(rows, ABSENT, np.int64)
        ok = have[rr]
        self.skip("updates", int((~ok).sum()))
        rr, ii = rr[ok], ii[ok]
        if not rr.size:
            return
        R, N = updated.shape
        j_of = np.array([j for j, _ in entries], dtype=np.int64)
        i_of = np.array([i for _, i in entries], dtype=np.int64)
        er, ee = np.nonzero(delays != ABSENT)
        ei, ej, ev = i_of[ee], j_of[ee], delays[er, ee]
        keep = ei < N
        keep[keep] = updated[er[keep], ei[keep]]
        er, ei, ej, ev = er[keep], ei[keep], ej[keep], ev[keep]
        ident = er * N + ei
        order = np.lexsort((ej, ident))
        ident, ej, ev = ident[order], ej[order], ev[order]
        per = np.bincount(ident, minlength=R * N)
        first = np.concatenate([[0], np.cumsum(per)])[:-1]
        row_id = rr * N + ii
        count = per[row_id]
        table = [update_topic(i) for i in range(agents)]
        for c in np.unique(count).tolist():
            g = np.flatnonzero(count == c)
            r_g, i_g = rr[g], ii[g]
            k = step[r_g]
            pick = first[row_id[g]][:, None] + np.arange(c)[None, :]
            r = ev[pick].astype(np.float64)
            used = np.where(r >= 0, (k[:, None] - 1) - r, -1.0)
            self._step_block("EstimatorUpdate", table, i_g,
                             {"step": k, "time": time[r_g], "agent": i_g,
                              "neighbours": ej[pick].astype(np.float64),
                              "effective_delay": r, "used_timestamp": used}, i_g, 1, 0)

    def freshness(self) -> None:
        msgs = self.m.get("Freshness", [])
        if not msgs:
            return
        sizes_all = np.asarray(self.layout.freshness_sizes, dtype=np.int64)
        good, tops = [], []
        for m in msgs:
            top = _ints(m.max_index)
            sizes = np.zeros(top.shape[0], dtype=np.int64)
            width = min(top.shape[0], sizes_all.shape[0])
            sizes[:width] = sizes_all[:width]
            if int(sizes.sum()) != len(m.index):
                self.skip("freshness", int((top != ABSENT).sum()))
                continue
            good.append(m)
            tops.append(top)
        if not good:
            return
        step = _ints([m.step for m in good])
        time = _floats([m.time for m in good])
        top = _padded(tops, ABSENT, np.int64)
        N = top.shape[1]
        sizes = np.zeros(N, dtype=np.int64)
        sizes[:min(N, sizes_all.shape[0])] = sizes_all[:N]
        starts = np.concatenate([[0], np.cumsum(sizes)])[:-1]
        arrays = {name: _padded([_ints(getattr(m, name)) for m in good], ABSENT, np.int64)
                  for name in ("index", "adopted_from", "substate_dim")}
        rr, ii = np.nonzero(top != ABSENT)
        table = [freshness_topic(i) for i in range(max(N, self.layout.agents))]
        for c in np.unique(sizes[ii]).tolist():
            g = np.flatnonzero(sizes[ii] == c)
            r_g, i_g = rr[g], ii[g]
            columns = {name: _gather(a, r_g, starts[i_g], c).astype(np.float64)
                       for name, a in arrays.items()}
            self._step_block("Freshness", table, i_g,
                             {"step": step[r_g], "time": time[r_g], "agent": i_g,
                              **columns, "max_index": top[r_g, i_g]}, i_g, 2, 0)

    # -- links ----------------------------------------------------------------------

    def sends(self) -> dict[str, np.ndarray]:
        """The LinkSent blocks; returns the sends as columns for the joins."""
        msgs = self.m.get("LinkSends", [])
        L_known = len(self.layout.links)
        if not msgs:
            none = np.zeros(0, dtype=np.int64)
            return {**{key: none for key in _LINK_COMMON}, "link": none, "key": none,
                    "publish": none.astype(np.uint64), "multiplier": np.array([1]),
                    "arrival_time": none.astype(float)}
        step = _ints([m.step for m in msgs])
        time = _floats([m.time for m in msgs])
        delay = _padded([_ints(m.delay_steps) for m in msgs], ABSENT, np.int64)
        R, L = delay.shape
        arrival = np.full((R, L), np.nan)
        stored: dict[int, list[int]] = {}  # payload width -> rows storing payloads
        payloads: dict[int, np.ndarray] = {}
        for r, m in enumerate(msgs):
            row_len = len(m.delay_steps)
            given = _floats(m.arrival_time)
            if given.shape[0] == row_len:
                arrival[r, :row_len] = given
            elif given.shape[0] == 0:  # every message arrives at (k + 1 + d) Ts
                arrival[r, :row_len] = (step[r] + 1 + delay[r, :row_len]).astype(float) * self.ts
            else:
                arrival[r, :row_len] = np.nan
                self.skip("arrival times", int((delay[r] != ABSENT).sum()))
            if len(m.payload):
                p = _floats(m.payload)
                if row_len and p.shape[0] % row_len == 0:
                    stored.setdefault(p.shape[0] // row_len, []).append(r)
                    payloads[r] = p.reshape(row_len, p.shape[0] // row_len)
                else:
                    self.skip("payloads", int((delay[r] != ABSENT).sum()))
        sent = delay != ABSENT
        if L > L_known:
            self.skip("sent", int(sent[:, L_known:].sum()))
            sent[:, L_known:] = False
        sequence = np.cumsum(sent, axis=0) - 1
        rs, ls = np.nonzero(sent)
        s = step[rs]
        d = delay[rs, ls]
        j, i = self.link_sender[ls], self.link_receiver[ls]
        common = {"sender": j, "receiver": i, "sent_step": s, "usable_step": s + 1 + d,
                  "sequence": sequence[rs, ls], "send_time": time[rs],
                  "arrival_time": arrival[rs, ls], "delay_steps": d}
        publish = _ns(self.origin, time[rs])
        # payloads: stored, else the sender's estimate of that step, else none
        width = np.zeros(rs.shape[0], dtype=np.int64)
        store_width = np.zeros(R, dtype=np.int64)  # 0: that step stores no payloads
        store_row = np.zeros(R, dtype=np.int64)  # its row in the stored array of its width
        stored_values: dict[int, np.ndarray] = {}
        for w, rows in stored.items():
            store_width[rows] = w
            store_row[rows] = np.arange(len(rows))
            stored_values[w] = np.full((len(rows), L, w), np.nan)
            for a, r in enumerate(rows):
                stored_values[w][a, :payloads[r].shape[0]] = payloads[r]
        from_store = store_width[rs] > 0
        width[from_store] = store_width[rs[from_store]]
        from_estimate = ~from_store & (self.layout.payload == "estimate")
        e_row = np.searchsorted(self.est_steps, s)
        ok = from_estimate & (e_row < self.est_steps.shape[0])
        ok[ok] = self.est_steps[e_row[ok]] == s[ok]
        ok[ok] = (j[ok] < self.est_updated.shape[1])
        ok[ok] = self.est_updated[e_row[ok], j[ok]]
        self.skip("payloads", int((from_estimate & ~ok).sum()))
        n = self.est.shape[2] if self.est.ndim == 3 else 0
        width[ok] = n
        for w in np.unique(width).tolist():
            g = np.flatnonzero(width == w)
            columns = {key: v[g] for key, v in common.items()}
            if w:
                values = np.empty((g.shape[0], w))
                est_g, store_g = ok[g], from_store[g]
                if est_g.any():
                    values[est_g] = self.est[e_row[g[est_g]], j[g[est_g]]]
                if store_g.any():
                    q = g[store_g]
                    values[store_g] = stored_values[w][store_row[rs[q]], ls[q]]
                columns["payload"] = values
            self.blocks.append(_Block(
                "LinkSent", self.link_topics["sent"], ls[g], columns, time[rs[g]], _STEP,
                j[g], 3, 3 * ls[g], publish[g], publish[g], common["sequence"][g]))
        common["link"] = ls
        common["publish"] = publish
        common["key"] = s * (L + 1) + ls
        common["multiplier"] = np.array([L + 1])
        return common

    def _join(self, sends: dict[str, np.ndarray], link: np.ndarray, sent_step: np.ndarray,
              kind: str) -> tuple[np.ndarray, np.ndarray]:
        """(found mask, index into the sends) of events on (link, sent_step)."""
        keys = sends["key"]
        if not keys.shape[0]:
            self.skip(kind, link.shape[0])
            return np.zeros(link.shape[0], dtype=bool), np.zeros(link.shape[0], np.int64)
        L1 = int(sends["multiplier"][0])
        order = np.argsort(keys, kind="stable")
        want = sent_step * L1 + link
        pos = np.searchsorted(keys[order], want)
        found = (pos < keys.shape[0]) & (link < L1 - 1)
        found[found] = keys[order][pos[found]] == want[found]
        self.skip(kind, int((~found).sum()))
        index = np.zeros(link.shape[0], dtype=np.int64)
        index[found] = order[pos[found]]
        return found, index

    def link_events(self, sends: dict[str, np.ndarray]) -> None:
        drops = self.m.get("LinkDrops", [])
        dropped_keys = np.zeros(0, dtype=np.int64)
        if drops:
            link = np.concatenate([_ints(m.link) for m in drops])
            sent_step = np.concatenate([_ints(m.sent_step) for m in drops])
            reason = np.concatenate([_ints(m.reason) for m in drops])
            drop_time = np.concatenate([_floats(m.drop_time) for m in drops])
            L1 = int(sends["multiplier"][0])
            known = link < L1 - 1
            dropped_keys = sent_step[known] * L1 + link[known]
            found, q = self._join(sends, link, sent_step, "dropped")
            q = q[found]
            if q.size:
                columns = {key: sends[key][q] for key in _LINK_COMMON}
                columns["reason"] = reason[found]
                when = columns["drop_time"] = drop_time[found]
                j, l_, s = columns["sender"], sends["link"][q], columns["sent_step"]
                # at sending (send time), superseded on arrival (keep-latest), or
                # cancelled in flight by a later send (drop-oldest)
                at_send = when == columns["send_time"]
                superseded = ~at_send & (when == columns["arrival_time"])
                self.blocks.append(_Block(
                    "LinkDropped", self.link_topics["dropped"], l_, columns, when,
                    np.where(superseded, _EARLY, _STEP), np.where(superseded, s, j),
                    np.where(superseded, j, 3),
                    np.where(superseded, l_, 3 * l_ + np.where(at_send, 1, 2)),
                    _ns(self.origin, when), sends["publish"][q], columns["sequence"]))
        deliveries = self.m.get("LinkDeliveries", [])
        if not deliveries:
            return
        q, accepted = self._implied_deliveries(sends, deliveries, dropped_keys)
        if not q.size:
            return
        columns = {key: sends[key][q] for key in _LINK_COMMON}
        columns["accepted"] = accepted
        arrival, send_time = columns["arrival_time"], columns["send_time"]
        late = arrival == send_time  # zero latency: after the sends of that instant
        j, l_, s = columns["sender"], sends["link"][q], columns["sent_step"]
        self.blocks.append(_Block(
            "LinkDelivered", self.link_topics["delivered"], l_, columns, arrival,
            np.where(late, _LATE, _EARLY), np.where(late, j, s), np.where(late, l_, j),
            np.where(late, 0, l_), _ns(self.origin, arrival), sends["publish"][q],
            columns["sequence"]))

    def _implied_deliveries(self, sends: dict[str, np.ndarray], deliveries: list[Any],
                            dropped_keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sends index, accepted) of the deliveries of step k: the messages usable from
        k on that were not dropped, in (link, time-stamp) order; in a step after the
        last plant step, those that arrived before the run ended (the earliest ones)."""
        keys = sends["key"]
        usable = sends["usable_step"]
        candidate = np.flatnonzero(~np.isin(keys, dropped_keys))
        candidate = candidate[np.lexsort((sends["sent_step"][candidate],
                                          sends["link"][candidate], usable[candidate]))]
        by_step = usable[candidate]
        arrival = sends["arrival_time"]
        picked: list[np.ndarray] = []
        accepted: list[np.ndarray] = []
        for m in deliveries:
            k = int(m.step)
            flags = _ints(m.accepted)
            c = flags.shape[0]
            lo, hi = np.searchsorted(by_step, [k, k + 1])
            found = candidate[lo:hi]
            if found.shape[0] > c and k > self.last_plant:  # the run ended meanwhile
                times = np.sort(arrival[found])
                if c == 0 or times[c - 1] < times[c]:
                    found = found[arrival[found] <= times[c - 1]] if c else found[:0]
            if found.shape[0] != c:
                self.skip("delivered", c)
                continue
            picked.append(found)
            accepted.append(flags)
        if not picked:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        return np.concatenate(picked), np.concatenate(accepted)


def unstack_matrices(matrices: Mapping[str, np.ndarray], run: Mapping[str, str]
                     ) -> dict[str, np.ndarray]:
    """The per-agent matrices ``X_0 .. X_{N-1}`` of attachments stacked as one ``X``.

    A format-3 recorder attaches per-agent matrices of one shape as one array of shape
    (N, ...) and lists their names in ``run.stacked_matrices``
    (:func:`netsim.traces.recorder.stack_matrices`); this gives them back as the
    format-2 attachments ``X_i``, in place of ``X`` (the same order).

    Parameters
    ----------
    matrices : mapping str -> numpy.ndarray
        The ``.npy`` attachments by name.
    run : mapping str -> str
        The ``run`` metadata record.

    Returns
    -------
    dict of str -> numpy.ndarray
    """
    stacked = {name for name in str(run.get("stacked_matrices", "")).split(",") if name}
    if not stacked:
        return dict(matrices)
    out: dict[str, np.ndarray] = {}
    for name, matrix in matrices.items():
        if name in stacked and np.ndim(matrix) >= 1:
            out.update({f"{name}_{i}": np.asarray(matrix[i]) for i in range(len(matrix))})
        else:
            out[name] = matrix
    return out


def _describe(unexpanded: Mapping[str, int]) -> str:
    if not unexpanded:
        return ""
    parts = ", ".join(f"{count} {kind}" for kind, count in unexpanded.items())
    return (f"format 3 read as format 2; left out what could not be rebuilt ({parts}): "
            "part of what they need was lost")


def expand_steps(records: Mapping[str, list[TraceRecord]], topics: Mapping[str, str],
                 counts: Mapping[str, int], metadata: Mapping[str, Mapping[str, str]],
                 foreign: Iterable[str] = ()) -> StepView:
    """Expand the format-3 records of a file into the format-2 view.

    Parameters
    ----------
    records : mapping str -> list of TraceRecord
        The decoded messages per topic of the file, in log_time order.
    topics : mapping str -> str
        The file's channels: topic -> schema name.
    counts : mapping str -> int
        Messages read per topic of the file.
    metadata : mapping str -> mapping str -> str
        The file's metadata records (``run`` for the time origin and sample period, the
        last ``trace_layout``).
    foreign : iterable of str
        Topics with schemas not from this project (kept in the view, not expanded).

    Returns
    -------
    StepView
    """
    skip = set(foreign)
    foreign = [t for t in topics if t in skip]
    run = metadata.get("run", {})
    origin_text = str(run.get("time_origin_ns", "0"))
    origin = int(origin_text) if origin_text.isdigit() else 0
    try:
        sample_period = float(run.get("sample_period", "1.0"))
    except ValueError:
        sample_period = 1.0
    messages3: dict[str, list[Any]] = {}
    for topic, type_name in TOPICS.items():
        if topics.get(topic) == f"{PACKAGE3}.{type_name}":
            messages3[type_name] = [r.message for r in records.get(topic, [])]
    unexpanded: dict[str, int] = {}
    blocks: list[_Block] = []
    layout_record = metadata.get(LAYOUT_METADATA)
    total = sum(len(v) for v in messages3.values())
    problem = ""
    if layout_record is None:
        problem = "no trace_layout metadata record"
    else:
        try:
            layout = read_layout(layout_record)
        except ValueError as exc:
            problem = str(exc)
        else:
            expander = _Expander(messages3, layout, origin, sample_period)
            blocks = expander.run()
            unexpanded = expander.unexpanded
    if problem and total:  # nothing says what the arrays are indexed by
        unexpanded["messages"] = total
    view = _merge(blocks)
    # netsim topics of another format in the file: kept as they are
    others = [t for t in topics if t not in foreign and t not in TOPICS]
    if others:
        for t in others:
            view.topics[t] = topics[t]
            view.records[t] = list(records.get(t, []))
            view.counts[t] = len(view.records[t])
            view.messages.extend(view.records[t])
        view.messages.sort(key=lambda r: r.log_time)
    for t in foreign:
        view.topics[t] = topics[t]
        view.counts[t] = counts.get(t, 0)
    view.unexpanded = unexpanded
    if problem and total:
        view.note = f"format 3: {total} messages not read ({problem})"
    else:
        view.note = _describe(unexpanded)
    return view


def _merge(blocks: list[_Block]) -> StepView:
    """All blocks' records in the kernel's order, per topic and overall."""
    blocks = [b for b in blocks if len(b)]
    if not blocks:
        return StepView({}, {}, {}, [])
    log_time = np.concatenate([b.log_time for b in blocks])
    order = np.lexsort((np.concatenate([b.k3 for b in blocks]),
                        np.concatenate([b.k2 for b in blocks]),
                        np.concatenate([b.k1 for b in blocks]),
                        np.concatenate([b.phase for b in blocks]),
                        np.concatenate([b.when for b in blocks]), log_time))
    names: list[str] = []
    decoded: list[Any] = []
    schemas: dict[str, str] = {}
    for b in blocks:
        table = b.table
        topic_names = [table[t] for t in b.topic.tolist()]
        names.extend(topic_names)
        decoded.extend(_decode(b))
        full = schema_name(b.type_name)
        for t in set(topic_names):
            schemas[t] = full
    publish = np.concatenate([b.publish_time for b in blocks])[order].tolist()
    sequence = np.concatenate([b.sequence for b in blocks])[order].tolist()
    idx = order.tolist()
    messages = list(map(TraceRecord, [names[i] for i in idx], log_time[order].tolist(),
                        publish, sequence, [decoded[i] for i in idx]))
    records: dict[str, list[TraceRecord]] = {}
    for record in messages:
        found = records.get(record.topic)
        if found is None:
            records[record.topic] = [record]
        else:
            found.append(record)
    topics = {t: schemas[t] for t in records}
    counts = {t: len(v) for t, v in records.items()}
    return StepView(topics, counts, records, messages)
