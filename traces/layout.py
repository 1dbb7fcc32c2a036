"""Foxglove layouts for netsim traces (formats 2 and 3), and a headless picture of one.

:func:`foxglove_layout` builds a Foxglove layout (the JSON a user imports with *Layouts
> Import from file*) for one trace: a ``Tab`` panel whose tabs hold ``Plot`` panels of
message paths (``/topic.field`` or ``/topic.field[index]``) on the trace's own topics.

Format 2 (:mod:`netsim.traces.schemas`, one message per agent and per link event):

- **Errors**: each agent's error norm ||x-hat^i_k - x_k|| (``/agent_<i>/estimate.error_norm``);
- **State**: per state component s (the first :data:`MAX_STATES`), the true state
  ``/plant/state.state[s]`` against every agent's ``/agent_<i>/estimate.estimate[s]``;
- **Delays**: the effective delay r_ij[k] each receiver i used from each in-neighbour
  j (``/agent_<i>/update.effective_delay[p]``, p = j's position in the update's
  ``neighbours``), and each delivered message's step delay
  (``/link_<j>_<i>/delivered.delay_steps``);
- **Drops** (links that dropped messages): which messages (``.../dropped.sequence``) and
  why (``.../dropped.reason``, codes listed in the panel title);
- **Age of information** (AoI traces): each agent's largest freshness index
  (``/agent_<i>/freshness.max_index``, -1 = omega) and per-substate indices.

Format 3 (:mod:`netsim.traces.schemas3`, one message per step and kind; the arrays are
indexed as the file's last ``trace_layout`` metadata record says): the same tabs, with
indexed paths into the per-step arrays (N agents, n states, link l = ``links[l]``,
update entry e = ``updates[e]``; -3 = :data:`netsim.traces.schemas3.ABSENT`):

- **Errors**: ``/agents/estimate.error_norm[i]`` per agent i;
- **State**: ``/plant/state.state[s]`` against ``/agents/estimate.estimate[i*n + s]``;
- **Delays**: r_ij[k] per update entry e = [j, i] (``/agents/update.effective_delay[e]``;
  -1 own estimate used, -3 not reported: below the y axis, which starts at -1.5), and the
  step delay d of the message sent at k on link l (``/links/sent.delay_steps[l]``, by
  sending step; -3 nothing sent: below the y axis, which starts at -0.5);
- **Drops** (``/links/dropped`` has messages): one series per link l that dropped a
  message, ``/links/dropped.link_reason[l]`` labelled ``link j→i``: at the end of each
  sample period with drops, the reason code of link l's drops (0, none, lies below the
  y axis; the codes are named in the panel title). A trace of an earlier version (no
  ``link_reason``) gets its drops in the order they happened (``.link[q]``,
  ``.reason[q]``), as many entries as a message holds.
- **Age of information** (AoI traces): ``/agents/freshness.max_index[i]`` per AoI agent
  and, for the first :data:`MAX_FRESHNESS_AGENTS`, ``/agents/freshness.index[o_i + s]``
  per substate s (o_i = the sizes of the earlier agents' ``freshness_sizes``); -1 omega,
  -3 no report: below the y axis, which starts at -1.5.

Series whose values may hold the -3 sentinel are points, never joined into lines (a
line would run down to the sentinel below the axis). An entry that never holds a value
to draw gets no series: a format-3 layout reads the file's estimate, update, link and
freshness messages once (:func:`_step_presence`).

Every panel has its title under both ``foxglovePanelTitle`` (Foxglove) and
``lichtblickPanelTitle`` (Lichtblick); series colours are mid tones, readable on the
light and the dark theme. Series are grouped :data:`MAX_SERIES` to a panel. The layout
is built from the file's summary (channels, metadata and, in format 2, the first message
of a few topics for the neighbour order and dimensions), plus in format 3 the one pass
above; a format-2 file
without a summary (its writer was killed) is read in full, a format-3 one is scanned for
its metadata and channels without decoding messages.

:func:`render_layout` draws the same panels from the trace's data with matplotlib (Agg,
no screen), evaluating each panel's message paths: a picture of what Foxglove shows.
Format-2 paths are evaluated against the records :func:`read_trace` read, format-3
paths against the file's own per-step messages (:func:`message_path_series`).

This module imports ``netsim.traces`` modules, ``mcap``, ``mcap_protobuf`` and matplotlib
(lazily), never ``netsim`` or ``simpy``.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Container, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from netsim.traces.reader import Trace, TraceError, read_trace
from netsim.traces.schemas import (
    estimate_topic,
    freshness_topic,
    link_topic,
    parse_topic,
    plant_topic,
    update_topic,
)
from netsim.traces.schemas3 import ABSENT, LAYOUT_METADATA
from netsim.traces.schemas3 import TRACE_FORMAT as _TRACE_FORMAT3

__all__ = [
    "MAX_SERIES",
    "MAX_STATES",
    "MAX_FRESHNESS_AGENTS",
    "LayoutSource",
    "layout_source",
    "source_from_trace",
    "foxglove_layout",
    "layout_paths",
    "layout_path_for",
    "write_layout",
    "parse_message_path",
    "message_path_series",
    "render_layout",
]

#: Most series (message paths) in one Plot panel; more go to further panels.
MAX_SERIES = 12
#: State components given a "state against estimates" panel.
MAX_STATES = 4
#: Agents given a per-substate freshness panel.
MAX_FRESHNESS_AGENTS = 4


@dataclass
class LayoutSource:
    """What a layout needs to know about a trace.

    Attributes
    ----------
    path : str
    format : int
        Trace format (layouts need 2 or 3).
    topics : list of str
        The file's topics (format 3: its per-step topics, ``/agents/estimate`` ...).
    n_states : int
        n, the length of ``/plant/state.state``.
    neighbours : dict int -> list of int
        Format 2: per agent, its update's ``neighbours`` in order (index p of
        ``effective_delay[p]``). Empty in format 3 (see ``step_updates``).
    substates : dict int -> int
        Per AoI agent, the number of freshness indices.
    drop_reasons : dict int -> str
        Drop reason codes (``LinkDropped.reason``, format 3 ``LinkDrops.reason``).
    family, scenario : str
    n_agents : int
        Format 3: N, agents in the per-step arrays (``trace_layout`` ``agents``).
    step_links : list of (int, int)
        Format 3: link l is ``step_links[l]`` = (sender j, receiver i).
    step_updates : list of (int, int)
        Format 3: entry e of ``Updates.effective_delay`` is r_ij of
        ``step_updates[e]`` = (j, i).
    freshness_sizes : list of int
        Format 3: freshness indices per agent (0: no freshness report), the layout of
        ``Freshness.index``.
    counts : dict str -> int
        Messages per topic from the file's statistics (empty when not known).
    time_origin_ns : int
        log_time of simulation time 0 (``run.time_origin_ns``; 0 when not recorded).
    present : dict or None
        Format 3: which array entries ever hold a value to draw, from one pass over the
        file's messages (:func:`_step_presence`): ``agents`` (updated at least once),
        ``updates`` (entries e ever reported), ``sends`` (links l that ever sent),
        ``drops`` (links that dropped), ``link_reason`` (the drops carry
        ``LinkDrops.link_reason``), ``drop_entries`` (most drops in one message),
        ``freshness`` (agents reporting) and ``fresh_index`` (entries ever reported).
        None: not read (every entry is laid out).
    """

    path: str
    format: int
    topics: list[str]
    n_states: int
    neighbours: dict[int, list[int]] = field(default_factory=dict)
    substates: dict[int, int] = field(default_factory=dict)
    drop_reasons: dict[int, str] = field(default_factory=dict)
    family: str = ""
    scenario: str = ""
    n_agents: int = 0
    step_links: list[tuple[int, int]] = field(default_factory=list)
    step_updates: list[tuple[int, int]] = field(default_factory=list)
    freshness_sizes: list[int] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    time_origin_ns: int = 0
    present: dict[str, Any] | None = None

    def has_messages(self, topic: str) -> bool:
        """Whether the file has the topic and, as far as its statistics say, messages on
        it."""
        return topic in self.topics and self.counts.get(topic, 1) > 0

    def agents(self, kind: str = "estimate") -> list[int]:
        """Agents with a topic of ``kind`` (estimate, update, freshness); format 3: the
        agents of the per-step arrays of that kind (every agent, the receivers of
        ``step_updates``, the agents with freshness indices)."""
        if self.format >= 3:
            if not self.has_messages(f"/agents/{kind}"):
                return []
            if kind == "estimate":
                return list(range(self.n_agents))
            if kind == "update":
                return sorted({i for _j, i in self.step_updates})
            if kind == "freshness":
                return [i for i, size in enumerate(self.freshness_sizes) if size > 0]
            return []
        return sorted({info.index for t in self.topics
                       if (info := parse_topic(t)) is not None and info.kind == kind
                       and info.index is not None})

    def links(self, event: str) -> list[tuple[int, int]]:
        """Links (sender, receiver) with a topic of ``event``; format 3: every link of
        ``step_links`` when ``/links/<event>`` has messages (which links had such events
        is in the messages, not the summary)."""
        if self.format >= 3:
            return list(self.step_links) if self.has_messages(f"/links/{event}") else []
        return sorted({(info.index, info.receiver) for t in self.topics
                       if (info := parse_topic(t)) is not None and info.kind == "link"
                       and info.event == event
                       and info.index is not None and info.receiver is not None})


def _format_number(run: dict[str, str], library: str = "") -> int:
    """Trace format from ``run.trace_format`` (``netsim-trace/<n>``), else from the MCAP
    header's library string (``netsim-trace/3 ...``); 1 when neither says."""
    text = run.get("trace_format")
    if text is None and library.startswith("netsim-trace/"):
        text = library.split()[0]
    fmt = (text or "netsim-trace/1").rsplit("/", 1)[-1]
    return int(fmt) if fmt.isdigit() else 1


def _step_source(where: str, metadata: dict[str, dict[str, str]], topics: Iterable[str],
                 counts: dict[str, int], library: str = "",
                 drop_reasons: dict[int, str] | None = None) -> LayoutSource:
    """The :class:`LayoutSource` of a format-3 file from its metadata records (the last
    of each name; ``trace_layout`` says what the arrays are indexed by) and channels."""
    record = metadata.get(LAYOUT_METADATA)
    if record is None:
        raise TraceError(f"{where}: a {_TRACE_FORMAT3} trace without a {LAYOUT_METADATA!r} "
                         "metadata record (what its arrays are indexed by); cannot lay it out")

    def value(key: str, default: Any) -> Any:
        text = record.get(key)
        return default if text is None else json.loads(text)

    try:
        links = [(int(j), int(i)) for j, i in value("links", [])]
        updates = [(int(j), int(i)) for j, i in value("updates", [])]
        sizes = [int(c) for c in value("freshness_sizes", [])]
        n_agents, n_states = int(value("agents", 0)), int(value("n_states", 0))
    except (TypeError, ValueError) as exc:
        raise TraceError(f"{where}: its {LAYOUT_METADATA!r} metadata record is unusable "
                         f"({exc})") from None
    run = metadata.get("run", {})
    if drop_reasons is None:
        drop_reasons = {int(c): r for c, r in metadata.get("drop_reasons", {}).items()
                        if c.isdigit()}
    origin = run.get("time_origin_ns", "0")
    try:
        present: dict[str, Any] | None = _step_presence(where)
    except OSError:
        present = None
    return LayoutSource(
        present=present,
        path=where, format=_format_number(run, library), topics=sorted(set(topics)),
        n_states=n_states, substates={i: c for i, c in enumerate(sizes) if c > 0},
        drop_reasons=dict(drop_reasons), family=run.get("family", ""),
        scenario=metadata.get("scenario", {}).get("name", ""), n_agents=n_agents,
        step_links=links, step_updates=updates, freshness_sizes=sizes, counts=dict(counts),
        time_origin_ns=int(origin) if origin.isdigit() else 0)


def _scan_step_file(where: str) -> LayoutSource | None:
    """The source of a format-3 file without a usable summary (e.g. its writer was
    killed): its records streamed up to the first damaged one, messages counted, not
    decoded. None when the file is not a format-3 netsim trace (or not readable)."""
    from mcap.records import Channel, Header, Message, Metadata
    from netsim.traces.reader import stream_records

    library = ""
    metadata: dict[str, dict[str, str]] = {}
    channels: dict[int, str] = {}
    counts: dict[str, int] = {}
    try:
        with open(where, "rb") as f:
            try:
                for record in stream_records(f, where=str(where)):
                    if isinstance(record, Message):
                        topic = channels.get(record.channel_id)
                        if topic is not None:
                            counts[topic] = counts.get(topic, 0) + 1
                    elif isinstance(record, Channel):
                        channels[record.id] = record.topic
                        counts.setdefault(record.topic, 0)
                    elif isinstance(record, Metadata):
                        if record.name == "drop_reasons":
                            metadata.setdefault(record.name, {}).update(record.metadata)
                        else:
                            metadata[record.name] = dict(record.metadata)
                    elif isinstance(record, Header):
                        library = record.library
            except Exception:  # noqa: BLE001 - the records before the damage
                pass
    except OSError:
        return None
    if "scenario" not in metadata or _format_number(metadata.get("run", {}), library) < 3:
        return None
    return _step_source(where, metadata, channels.values(), counts, library)


def source_from_trace(trace: Trace) -> LayoutSource:
    """Return the :class:`LayoutSource` of a trace read by :func:`read_trace` (format 3:
    from its metadata and the file's own topics, :attr:`Trace.file_topics`)."""
    if trace.format >= 3:
        return _step_source(trace.path, trace.metadata, trace.file_topics,
                            trace.file_counts, trace.library, trace.drop_reasons)
    neighbours = {}
    for i in trace.agents:
        updates = trace.topic(trace.update_topic(i))
        if updates:
            neighbours[i] = [int(j) for j in updates[0].neighbours]
    substates = {}
    for i in trace.agents:
        fresh = trace.topic(trace.freshness_topic(i))
        if fresh:
            substates[i] = len(fresh[0].index)
    return LayoutSource(
        path=trace.path, format=trace.format, topics=sorted(trace.topics),
        n_states=trace.n_states, neighbours=neighbours, substates=substates,
        drop_reasons=dict(trace.drop_reasons), family=trace.family,
        scenario=trace.scenario.get("name", ""), time_origin_ns=trace.time_origin_ns)


def _decoded_messages(f: Any, topics: Container[str], where: str, *,
                      until_damage: bool = False) -> Iterator[tuple[str, int, Any]]:
    """``(topic, log_time, decoded message)`` of every message on ``topics`` in file
    order, streamed with the bounded chunk inflation of
    :func:`netsim.traces.reader.stream_records` (the mcap library's own readers inflate a
    chunk without a bound). ``until_damage``: a file cut short or damaged ends the
    messages where it breaks, instead of raising."""
    from mcap.records import Channel, Message, Schema
    from mcap_protobuf.decoder import DecoderFactory
    from netsim.traces.reader import stream_records

    factory = DecoderFactory()
    schemas: dict[int, Schema] = {}
    decoders: dict[int, tuple[str, Any]] = {}
    records = iter(stream_records(f, where=where))
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except Exception:
            if until_damage:
                return
            raise
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            schema = schemas.get(record.schema_id)
            if record.topic in topics and schema is not None:
                decoders[record.id] = (record.topic,
                                       factory.decoder_for(record.message_encoding, schema))
        elif isinstance(record, Message) and record.channel_id in decoders:
            topic, decode = decoders[record.channel_id]
            yield topic, record.log_time, decode(record.data)


def _first_messages(f: Any, topics: set[str], where: str) -> dict[str, Any]:
    """The first decoded message of each of ``topics``, in file order."""
    first: dict[str, Any] = {}
    for topic, _, message in _decoded_messages(f, topics, where):
        first.setdefault(topic, message)
        if len(first) == len(topics):
            break
    return first


def _step_presence(where: str) -> dict[str, Any]:
    """Which entries of a format-3 file's per-step arrays hold a value to draw (not NaN,
    not :data:`ABSENT`), over all its messages (:attr:`LayoutSource.present`); a file
    cut short is read up to the damage."""
    import numpy as np

    seen: dict[str, Any] = {}
    drops: set[int] = set()
    link_reason = False
    entries = 0

    def mark(key: str, values: Any) -> None:
        values = np.asarray(values)
        old = seen.get(key)
        if old is None or old.shape[0] < values.shape[0]:
            grown = np.zeros(values.shape[0], dtype=bool)
            if old is not None:
                grown[:old.shape[0]] = old
            seen[key] = old = grown
        old[:values.shape[0]] |= values

    topics = {"/agents/estimate", "/agents/update", "/links/sent", "/links/dropped",
              "/agents/freshness"}
    with open(where, "rb") as f:
        for topic, _, m in _decoded_messages(f, topics, where, until_damage=True):
            if topic == "/agents/estimate":
                mark("agents", np.asarray(m.updated, dtype=bool))
            elif topic == "/agents/update":
                mark("updates", np.asarray(m.effective_delay) != ABSENT)
            elif topic == "/links/sent":
                mark("sends", np.asarray(m.delay_steps) != ABSENT)
            elif topic == "/links/dropped":
                drops.update(int(x) for x in m.link)
                entries = max(entries, len(m.link))
                if "link_reason" in m.DESCRIPTOR.fields_by_name and len(m.link_reason):
                    link_reason = True
            else:
                mark("freshness", np.asarray(m.max_index) != ABSENT)
                mark("fresh_index", np.asarray(m.index) != ABSENT)
    out: dict[str, Any] = {key: {int(q) for q in np.flatnonzero(mask)}
                           for key, mask in seen.items()}
    for key in ("agents", "updates", "sends", "freshness", "fresh_index"):
        out.setdefault(key, set())
    out.update(drops=drops, link_reason=link_reason, drop_entries=entries)
    return out


def layout_source(path: str | os.PathLike[str]) -> LayoutSource:
    """Return what a layout needs from a trace file, reading its summary: metadata,
    channels and statistics and, in format 2, the first message of the plant, update
    and freshness topics. A file without a usable summary (e.g. its writer was killed)
    is read in full (format 2, :func:`read_trace`) or scanned for its metadata and
    channels (format 3).

    Raises
    ------
    TraceError
        The file is not a readable netsim trace (or a format-3 one without its
        ``trace_layout`` metadata).
    """
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    where = str(path)
    step: tuple[Any, ...] | None = None
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            if summary is None or not summary.chunk_indexes:
                raise LookupError("no summary")
            metadata: dict[str, dict[str, str]] = {}
            for record in reader.iter_metadata():
                if record.name == "drop_reasons":
                    metadata.setdefault(record.name, {}).update(record.metadata)
                else:
                    metadata[record.name] = dict(record.metadata)
            if "scenario" not in metadata:
                raise LookupError("not netsim")
            topics = sorted({c.topic for c in summary.channels.values()})
            library = reader.get_header().library
            if _format_number(metadata.get("run", {}), library) >= 3:
                counts: dict[str, int] = {}
                if summary.statistics is not None:
                    for cid, channel in summary.channels.items():
                        counts[channel.topic] = counts.get(channel.topic, 0) + int(
                            summary.statistics.channel_message_counts.get(cid, 0))
                step = (metadata, topics, counts, library)
            wanted = [] if step is not None else [
                t for t in topics if t == plant_topic()
                or ((info := parse_topic(t)) is not None and info.kind in ("update", "freshness"))]
            first: dict[str, Any] = {}
            if wanted:
                f.seek(0)
                first = _first_messages(f, set(wanted), where)
    except OSError as exc:
        raise TraceError(f"{where}: cannot read file ({exc.strerror or exc})") from None
    except Exception:  # noqa: BLE001 - unfinished or damaged: the full reader decides
        scanned = _scan_step_file(where)
        return scanned if scanned is not None else source_from_trace(read_trace(path))
    if step is not None:
        return _step_source(where, *step)
    run = metadata.get("run", {})
    fmt = run.get("trace_format", "netsim-trace/1").rsplit("/", 1)[-1]
    neighbours: dict[int, list[int]] = {}
    substates: dict[int, int] = {}
    for topic, msg in first.items():
        info = parse_topic(topic)
        if info is None or info.index is None:  # (index None: the plant)
            continue
        if info.kind == "update":
            neighbours[info.index] = [int(j) for j in msg.neighbours]
        elif info.kind == "freshness":
            substates[info.index] = len(msg.index)
    plant = first.get(plant_topic())
    reasons = {int(c): r for c, r in metadata.get("drop_reasons", {}).items() if c.isdigit()}
    origin = run.get("time_origin_ns", "0")
    return LayoutSource(
        path=where, format=int(fmt) if fmt.isdigit() else 1, topics=topics,
        n_states=0 if plant is None else len(plant.state), neighbours=neighbours,
        substates=substates, drop_reasons=reasons, family=run.get("family", ""),
        scenario=metadata.get("scenario", {}).get("name", ""),
        time_origin_ns=int(origin) if origin.isdigit() else 0)


# -- the layout ----------------------------------------------------------------------

#: One Plot panel: (panel id, config); a tab: (title, its panels).
_Panel = tuple[str, dict[str, Any]]
_Tabs = list[tuple[str, list[_Panel]]]
_Panels = Callable[..., list[_Panel]]

#: Series colours: mid tones, a contrast ratio of at least 3 against both a white and a
#: near-black background (Foxglove's and Lichtblick's light and dark themes).
_PALETTE = ("#1c7ed6", "#e8590c", "#2f9e44", "#c2255c", "#7048e8", "#0c8599", "#a9770a",
            "#ae3ec9", "#5c940d", "#f03e3e", "#4c6ef5", "#d6336c")
#: The true state (drawn thicker).
_TRUTH = "#868e96"
#: Panel config keys of the panel title: Foxglove's and Lichtblick's.
TITLE_KEYS = ("foxglovePanelTitle", "lichtblickPanelTitle")


def _series(value: str, label: str, colour: str, *, line: bool = True,
            size: float | None = None) -> dict[str, Any]:
    """A Plot series: a line, or (``line=False``) points not joined (for values with
    gaps or off-axis sentinels)."""
    if size is None:
        size = 1.5 if line else 3.0
    return {"value": value, "enabled": True, "timestampMethod": "receiveTime",
            "label": label, "color": colour, "showLine": line, "lineSize": size}


def _arrow(j: int, i: int) -> str:
    return f"{j}\u2192{i}"


def _plot(title: str, paths: list[dict[str, Any]], *, y_min: float | None = None,
          y_max: float | None = None) -> dict[str, Any]:
    config: dict[str, Any] = {
        "title": title, **dict.fromkeys(TITLE_KEYS, title), "paths": paths,
        "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True,
        "legendDisplay": "floating", "showPlotValuesInLegend": False, "isSynced": True,
        "xAxisVal": "timestamp", "sidebarDimension": 240,
    }
    if y_min is not None:
        config["minYValue"] = y_min
    if y_max is not None:
        config["maxYValue"] = y_max
    return config


def _chunks(items: list[Any], size: int) -> list[list[Any]]:
    return [items[q:q + size] for q in range(0, len(items), size)] or []


def _tree(ids: Sequence[str], direction: str = "column") -> Any:
    """A balanced mosaic tree (Foxglove's ``first``/``second``/``direction``)."""
    if len(ids) == 1:
        return ids[0]
    half = (len(ids) + 1) // 2
    other = "row" if direction == "column" else "column"
    return {"first": _tree(ids[:half], other), "second": _tree(ids[half:], other),
            "direction": direction, "splitPercentage": round(100.0 * half / len(ids), 3)}


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")


def foxglove_layout(source: LayoutSource | Trace, *, max_series: int = MAX_SERIES,
                    max_states: int = MAX_STATES) -> dict[str, Any]:
    """Return a Foxglove layout (JSON-ready dict) for a format-2 or format-3 trace.

    Parameters
    ----------
    source : LayoutSource or Trace
        The trace (see :func:`layout_source`). Its format picks the message paths: one
        topic per agent and link event (format 2) or indexed paths into the per-step
        arrays (format 3; see the module docstring).
    max_series : int
        Most message paths per Plot panel.
    max_states : int
        State components given a "state against estimates" panel.

    Raises
    ------
    ValueError
        A format-1 trace (its link events share one topic; re-record it), or a format
        newer than 3.
    """
    if isinstance(source, Trace):
        source = source_from_trace(source)
    if source.format < 2:
        raise ValueError(f"{source.path}: trace format {source.format}; Foxglove layouts "
                         "need format 2 or 3 (record it again with netsim run --trace)")
    if source.format > 3:
        raise ValueError(f"{source.path}: trace format {source.format}; this netsim lays "
                         "out formats 2 and 3")

    def colour(index: int) -> str:
        return _PALETTE[index % len(_PALETTE)]

    def panels(title: str, series: list[dict[str, Any]], **kw: Any) -> list[_Panel]:
        groups = _chunks(series, max_series)
        out = []
        for q, group in enumerate(groups):
            name = title if len(groups) == 1 else f"{title} ({q + 1}/{len(groups)})"
            out.append((f"Plot!{_slug(name)}", _plot(name, group, **kw)))
        return out

    if source.format == 3:
        tabs = _step_tabs(source, panels, colour, max_series=max_series,
                          max_states=max_states)
    else:
        tabs = _record_tabs(source, panels, colour, max_states=max_states)
    return _assemble(tabs)


def _error_and_state_tabs(panels: _Panels, colour: Callable[[int], str], agents: list[int],
                          *, error_path: Callable[[int], str],
                          state_path: Callable[[int], str],
                          estimate_path: Callable[[int, int], str], states: int) -> _Tabs:
    """The Errors tab (each agent's error norm) and the State tab (the first ``states``
    components of the true state against every agent's estimate), either format: the
    paths say where agent i's values and state component s are."""
    tabs: _Tabs = []
    errors = [_series(error_path(i), f"agent {i}", colour(i)) for i in agents]
    if errors:
        tabs.append(("Errors", panels("Error norm ||x-hat^i_k - x_k|| per agent", errors,
                                      y_min=0)))
    state: list[_Panel] = []
    for s in range(states):
        series = [_series(state_path(s), f"x[{s}] (true)", _TRUTH, size=2.5)]
        series += [_series(estimate_path(i, s), f"agent {i}", colour(i), size=1.0)
                   for i in agents]
        state += panels(f"State x[{s}] against the agents' estimates", series)
    if state:
        tabs.append(("State", state))
    return tabs


def _record_tabs(source: LayoutSource, panels: _Panels, colour: Callable[[int], str], *,
                 max_states: int) -> _Tabs:
    """The format-2 tabs: one topic per agent and per link event."""
    topics = set(source.topics)
    agents = [i for i in source.agents("estimate") if estimate_topic(i) in topics]
    tabs = _error_and_state_tabs(
        panels, colour, agents,
        error_path=lambda i: f"{estimate_topic(i)}.error_norm",
        state_path=lambda s: f"{plant_topic()}.state[{s}]",
        estimate_path=lambda i, s: f"{estimate_topic(i)}.estimate[{s}]",
        states=min(source.n_states, max_states) if plant_topic() in topics else 0)

    all_links = sorted(set(source.links("sent")) | set(source.links("delivered"))
                       | set(source.links("dropped"))
                       | {(j, i) for i, js in source.neighbours.items() for j in js})
    link_colour = {link: colour(q) for q, link in enumerate(all_links)}
    delays: list[dict[str, Any]] = []
    for i in source.agents("update"):
        for p, j in enumerate(source.neighbours.get(i, [])):
            if j == i:
                continue
            delays.append(_series(f"{update_topic(i)}.effective_delay[{p}]",
                                  f"r {_arrow(j, i)}", link_colour[(j, i)]))
    delay_panels = panels("Effective delay r_ij[k] (steps; -1 own estimate used)", delays)
    delivered = [_series(f"{link_topic(j, i, 'delivered')}.delay_steps",
                         f"link {_arrow(j, i)}",
                         link_colour[(j, i)], line=False)
                 for j, i in source.links("delivered")]
    delay_panels += panels("Delivered message delay d (steps) per link", delivered, y_min=0)
    if delay_panels:
        tabs.append(("Delays", delay_panels))

    dropped_links = source.links("dropped")
    if dropped_links:
        which = [_series(f"{link_topic(j, i, 'dropped')}.sequence", f"link {_arrow(j, i)}",
                         link_colour[(j, i)], line=False) for j, i in dropped_links]
        why = [_series(f"{link_topic(j, i, 'dropped')}.reason", f"link {_arrow(j, i)}",
                       link_colour[(j, i)], line=False) for j, i in dropped_links]
        codes = ", ".join(f"{c} = {r}" for c, r in sorted(source.drop_reasons.items()))
        reasons = f" ({codes})" if codes else ""
        tabs.append(("Drops", panels("Dropped messages per link: sequence number", which)
                     + panels(f"Drops per link: reason code{reasons}", why, y_min=0.5,
                              y_max=max(source.drop_reasons, default=1) + 0.5)))

    fresh_agents = [i for i in source.agents("freshness") if freshness_topic(i) in topics]
    if fresh_agents:
        aoi = panels("Age of information: largest freshness index (-1 omega)",
                     [_series(f"{freshness_topic(i)}.max_index", f"agent {i}", colour(i))
                      for i in fresh_agents])
        for i in fresh_agents[:MAX_FRESHNESS_AGENTS]:
            aoi += panels(f"Freshness index per substate, agent {i}",
                          [_series(f"{freshness_topic(i)}.index[{s}]", f"substate {s}",
                                   colour(s)) for s in range(source.substates.get(i, 0))])
        tabs.append(("Age of information", aoi))
    return tabs


def _step_tabs(source: LayoutSource, panels: _Panels, colour: Callable[[int], str], *,
               max_series: int, max_states: int) -> _Tabs:
    """The format-3 tabs: indexed paths into the per-step arrays (module docstring); an
    entry that never holds a value to draw (:attr:`LayoutSource.present`) gets no
    series, and series with the :data:`ABSENT` sentinel are points, not lines."""
    n = source.n_states
    present = source.present

    def shown(key: str, entries: Iterable[int]) -> list[int]:
        entries = list(entries)
        return entries if present is None else [q for q in entries if q in present[key]]

    tabs = _error_and_state_tabs(
        panels, colour, shown("agents", source.agents("estimate")),
        error_path=lambda i: f"/agents/estimate.error_norm[{i}]",
        state_path=lambda s: f"/plant/state.state[{s}]",
        estimate_path=lambda i, s: f"/agents/estimate.estimate[{i * n + s}]",
        states=min(n, max_states) if source.has_messages("/plant/state") else 0)

    every_link = sorted(set(source.step_links) | set(source.step_updates))
    link_colour = {link: colour(q) for q, link in enumerate(every_link)}
    delays: list[_Panel] = []
    if source.has_messages("/agents/update"):
        effective = [_series(f"/agents/update.effective_delay[{e}]", f"r {_arrow(j, i)}",
                             link_colour[(j, i)], line=False)
                     for e in shown("updates", range(len(source.step_updates)))
                     if (j := source.step_updates[e][0]) != (i := source.step_updates[e][1])]
        delays += panels("Effective delay r_ij[k] per link (steps; -1 own estimate used)",
                         effective, y_min=-1.5)
    if source.has_messages("/links/sent"):
        sent = [_series(f"/links/sent.delay_steps[{q}]", f"link {_arrow(j, i)}",
                        link_colour[(j, i)], line=False)
                for q in shown("sends", range(len(source.step_links)))
                for j, i in [source.step_links[q]]]
        delays += panels("Delay d (steps) of the message sent at k, per link", sent,
                         y_min=-0.5)
    if delays:
        tabs.append(("Delays", delays))

    if source.has_messages("/links/dropped") and source.step_links:
        codes = ", ".join(f"{c} = {r}" for c, r in sorted(source.drop_reasons.items()))
        reasons = f" ({codes})" if codes else ""
        top = max(source.drop_reasons, default=1) + 0.5
        if present is None or present["link_reason"]:
            dropped = shown("drops", range(len(source.step_links)))
            per_link = [_series(f"/links/dropped.link_reason[{q}]",
                                f"link {_arrow(j, i)}", link_colour[(j, i)], line=False)
                        for q in dropped for j, i in [source.step_links[q]]]
            drop_panels = panels(f"Drops per link: reason code{reasons}, a point per "
                                 "sample period with a drop", per_link, y_min=0.5,
                                 y_max=top)
        else:  # a trace of an earlier version: its drops in the order they happened
            entries = min(present["drop_entries"], max_series)

            def drop_series(name: str) -> list[dict[str, Any]]:
                return [_series(f"/links/dropped.{name}[{q}]", f"drop {q + 1} of the period",
                                colour(q), line=False) for q in range(entries)]

            named = ", ".join(f"{q} = {_arrow(j, i)}"
                              for q, (j, i) in enumerate(source.step_links[:8]))
            if len(source.step_links) > 8:
                named += ", ..."
            drop_panels = (panels(f"Dropped messages: link ({named})", drop_series("link"))
                           + panels(f"Dropped messages: reason code{reasons}",
                                    drop_series("reason"), y_min=0.5, y_max=top))
        if drop_panels:
            tabs.append(("Drops", drop_panels))

    fresh_agents = shown("freshness", source.agents("freshness"))
    if fresh_agents:
        starts = [sum(source.freshness_sizes[:i]) for i in range(len(source.freshness_sizes))]
        aoi = panels("Largest freshness index per agent (-1 omega)",
                     [_series(f"/agents/freshness.max_index[{i}]", f"agent {i}", colour(i),
                              line=False) for i in fresh_agents], y_min=-1.5)
        for i in fresh_agents[:MAX_FRESHNESS_AGENTS]:
            substates = [s for s in range(source.freshness_sizes[i])
                         if present is None or starts[i] + s in present["fresh_index"]]
            aoi += panels(f"Freshness index per substate, agent {i} (-1 omega)",
                          [_series(f"/agents/freshness.index[{starts[i] + s}]",
                                   f"substate {s}", colour(s), line=False)
                           for s in substates], y_min=-1.5)
        tabs.append(("Age of information", aoi))
    return tabs


def _assemble(tabs: _Tabs) -> dict[str, Any]:
    """The layout JSON: a ``Tab`` panel of the tabs' mosaics of Plot panels."""
    config_by_id: dict[str, Any] = {}
    tab_list = []
    for title, content in tabs:
        ids = []
        for panel_id, config in content:
            while panel_id in config_by_id:
                panel_id += "_"
            config_by_id[panel_id] = config
            ids.append(panel_id)
        tab_list.append({"title": title, "layout": _tree(ids)})
    config_by_id["Tab!netsim"] = {"activeTabIdx": 0, "tabs": tab_list,
                                  **dict.fromkeys(TITLE_KEYS, "netsim trace")}
    return {
        "configById": config_by_id,
        "globalVariables": {},
        "userNodes": {},
        "linkedGlobalVariables": [],
        "playbackConfig": {"speed": 1.0},
        "layout": "Tab!netsim",
    }


def layout_paths(layout: dict[str, Any]) -> list[str]:
    """Every message path the layout's Plot panels reference, in panel order."""
    return [p["value"] for key, config in layout["configById"].items()
            if key.startswith("Plot!") for p in config["paths"]]


_PATH = re.compile(r"^(/[A-Za-z0-9_/]+)\.([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


def parse_message_path(path: str) -> tuple[str, str, int | None]:
    """Split a message path ``/topic.field`` or ``/topic.field[index]`` (the subset the
    layouts use) into (topic, field, index or None); ValueError for anything else."""
    m = _PATH.match(path)
    if m is None:
        raise ValueError(f"unsupported message path {path!r}")
    return m.group(1), m.group(2), None if m.group(3) is None else int(m.group(3))


def layout_path_for(trace_path: str | os.PathLike[str]) -> Path:
    """The layout file written beside a trace: ``run.mcap`` -> ``run.layout.json``."""
    trace_path = Path(trace_path)
    stem = trace_path.stem if trace_path.suffix == ".mcap" else trace_path.name
    return trace_path.with_name(f"{stem}.layout.json")


def write_layout(trace_path: str | os.PathLike[str],
                 output: str | os.PathLike[str] | None = None, **options: Any) -> Path:
    """Write the Foxglove layout of a trace file (default :func:`layout_path_for`)."""
    layout = foxglove_layout(layout_source(trace_path), **options)
    out = layout_path_for(trace_path) if output is None else Path(output)
    out.write_text(json.dumps(layout, indent=2) + "\n")
    return out


# -- a picture of the layout ---------------------------------------------------------


def _series_data(trace: Trace, path: str) -> tuple[list[float], list[float]]:
    topic, name, index = parse_message_path(path)
    xs, ys = [], []
    origin = trace.time_origin_ns
    for record in trace.records.get(topic, []):
        value = getattr(record.message, name)
        if index is not None:
            value = value[index] if index < len(value) else math.nan
        xs.append((record.log_time - origin) / 1e9)
        ys.append(float(value))
    return xs, ys


def message_path_series(trace_path: str | os.PathLike[str], message_paths: Iterable[str],
                        *, origin_ns: int | None = None
                        ) -> dict[str, tuple[list[float], list[float]]]:
    """Evaluate message paths against a trace file's own messages (any format; meant for
    format 3, whose per-step topics :func:`read_trace` expands into format-2 records).

    Parameters
    ----------
    trace_path : str or path
        An MCAP file (read with the plain ``mcap`` stream reader and the protobuf schemas
        stored in it; a file cut short or damaged is read up to the damage).
    message_paths : iterable of str
        ``/topic.field`` (a scalar field) or ``/topic.field[index]`` (an array entry).
    origin_ns : int, optional
        log_time of time 0 (default: the file's ``run.time_origin_ns``).

    Returns
    -------
    dict str -> (list of float, list of float)
        Per path, (time in seconds since ``origin_ns``, value) of each message of its
        topic, in log_time order; NaN where the message's array has no such index (what
        Foxglove does not draw).

    Raises
    ------
    ValueError
        A path :func:`parse_message_path` does not accept, a field the message type does
        not have, or an array field without an index.
    """
    wanted: dict[str, list[tuple[str, str, int | None]]] = {}
    for path in dict.fromkeys(message_paths):
        topic, name, index = parse_message_path(path)
        wanted.setdefault(topic, []).append((path, name, index))
    if origin_ns is None:
        origin_ns = layout_source(trace_path).time_origin_ns
    rows: dict[str, list[tuple[int, float]]] = {
        path: [] for entries in wanted.values() for path, _, _ in entries}
    with open(trace_path, "rb") as f:
        # a file cut short or damaged: what was read
        for topic, log_time, message in _decoded_messages(f, wanted, str(trace_path),
                                                          until_damage=True):
            for path, name, index in wanted[topic]:
                if name not in message.DESCRIPTOR.fields_by_name:
                    raise ValueError(f"{path}: {message.DESCRIPTOR.full_name} has no "
                                     f"field {name!r}")
                value = getattr(message, name)
                if index is not None:
                    value = value[index] if index < len(value) else math.nan
                elif not isinstance(value, (int, float)):
                    raise ValueError(f"{path}: {name!r} is an array; give an index")
                rows[path].append((log_time, float(value)))
    out = {}
    for path, points in rows.items():
        points.sort(key=lambda point: point[0])
        out[path] = ([(t - origin_ns) / 1e9 for t, _ in points], [v for _, v in points])
    return out


def render_layout(trace: Trace | str | os.PathLike[str], layout: dict[str, Any],
                  output: str | os.PathLike[str], *, tabs: Sequence[str] | None = None,
                  columns: int = 2, max_panels: int = 8) -> Path:
    """Draw the layout's Plot panels from the trace's data into a PNG (dark theme, like
    Foxglove): every series evaluated from its message path, x = simulation time in
    seconds (Foxglove's x axis is the same, from the start).

    Parameters
    ----------
    trace : Trace or str or path
        The trace (a :class:`Trace` or its file). Format 2: paths evaluated against the
        records :func:`read_trace` read; format 3: against the file's own per-step
        messages (:func:`message_path_series`, reading ``trace.path``).
    layout : dict
        A layout of :func:`foxglove_layout` for that trace.
    output : str or path
        The PNG to write.
    tabs : sequence of str, optional
        Tabs to draw, by title (default all).
    columns : int
        Panels per row.
    max_panels : int
        Most panels drawn (the first ones, in tab order).

    Returns
    -------
    Path
        ``output``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    config = layout["configById"]
    chosen: list[tuple[str, dict[str, Any]]] = []
    for tab in config[layout["layout"]]["tabs"]:
        if tabs is not None and tab["title"] not in tabs:
            continue
        chosen += [(tab["title"], config[pid]) for pid in _leaves(tab["layout"])]
    chosen = chosen[:max_panels]
    if not chosen:
        raise ValueError("the layout has no panels to draw")
    if isinstance(trace, Trace):
        where, fmt, origin = trace.path, trace.format, trace.time_origin_ns
    else:
        source = layout_source(trace)
        where, fmt, origin = str(trace), source.format, source.time_origin_ns
    values = [series["value"] for _tab, panel in chosen for series in panel["paths"]]
    if fmt >= 3:
        data = message_path_series(where, values, origin_ns=origin)
    else:
        records = trace if isinstance(trace, Trace) else read_trace(where)
        data = {value: _series_data(records, value) for value in values}
    rows = math.ceil(len(chosen) / columns)
    with plt.style.context("dark_background"):
        fig, axes = plt.subplots(rows, columns, figsize=(6.4 * columns, 3.2 * rows),
                                 squeeze=False, facecolor="#15151a")
        for ax in axes.ravel()[len(chosen):]:
            ax.set_visible(False)
        for ax, (tab, panel) in zip(axes.ravel(), chosen, strict=False):
            ax.set_facecolor("#1e1e24")
            for series in panel["paths"]:
                xs, ys = data[series["value"]]
                style = "-" if series.get("showLine", True) else "none"
                ax.plot(xs, ys, linestyle=style, marker=None if style == "-" else ".",
                        color=series.get("color"), linewidth=series.get("lineSize", 1.5),
                        label=series.get("label", series["value"]))
            ax.set_title(f"{tab} | {panel['title']}", fontsize=9, loc="left")
            if "minYValue" in panel:
                ax.set_ylim(bottom=panel["minYValue"])
            ax.grid(color="#33333a", linewidth=0.6)
            ax.tick_params(labelsize=7)
            ax.set_xlabel("simulation time (s)", fontsize=7)
            if len(panel["paths"]) <= 12:
                ax.legend(fontsize=6, loc="upper right", framealpha=0.4, ncol=2)
        fig.suptitle(f"Foxglove layout of {Path(where).name} (netsim layout)",
                     fontsize=10)
        fig.tight_layout()
        out = Path(output)
        fig.savefig(out, format="png", dpi=110, facecolor=fig.get_facecolor())
        plt.close(fig)
    return out


def _leaves(tree: Any) -> list[str]:
    if isinstance(tree, str):
        return [tree]
    return _leaves(tree["first"]) + _leaves(tree["second"])
