"""Foxglove layouts for netsim traces (format 2), and a headless picture of one.

:func:`foxglove_layout` builds a Foxglove layout (the JSON a user imports with *Layouts
> Import from file*) for one trace: a ``Tab`` panel whose tabs hold ``Plot`` panels of
message paths (``/topic.field`` or ``/topic.field[index]``) on the trace's own topics:

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

Series are grouped :data:`MAX_SERIES` to a panel. The layout is built from the file's
summary (channels, metadata) and the first message of a few topics (neighbour order,
dimensions), so it is cheap for a large trace; an unfinished file is read in full.

:func:`render_layout` draws the same panels from the trace's data with matplotlib (Agg,
no screen), evaluating each panel's message paths: a picture of what Foxglove shows.

This module imports ``netsim.traces`` modules, ``mcap`` and matplotlib (lazily), never
``netsim`` or ``simpy``.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Sequence
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

__all__ = [
    "MAX_SERIES",
    "MAX_STATES",
    "LayoutSource",
    "layout_source",
    "source_from_trace",
    "foxglove_layout",
    "layout_paths",
    "layout_path_for",
    "write_layout",
    "parse_message_path",
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
        Trace format (layouts need 2).
    topics : list of str
        The file's topics.
    n_states : int
        n, the length of ``/plant/state.state``.
    neighbours : dict int -> list of int
        Per agent, its update's ``neighbours`` in order (index p of
        ``effective_delay[p]``).
    substates : dict int -> int
        Per AoI agent, the number of freshness indices.
    drop_reasons : dict int -> str
        ``LinkDropped.reason`` codes.
    family, scenario : str
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

    def agents(self, kind: str = "estimate") -> list[int]:
        """Agents with a topic of ``kind`` (estimate, update, freshness)."""
        return sorted({info.index for t in self.topics
                       if (info := parse_topic(t)) is not None and info.kind == kind})

    def links(self, event: str) -> list[tuple[int, int]]:
        """Links (sender, receiver) with a topic of ``event``."""
        return sorted({(info.index, info.receiver) for t in self.topics
                       if (info := parse_topic(t)) is not None and info.kind == "link"
                       and info.event == event})


def source_from_trace(trace: Trace) -> LayoutSource:
    """Return the :class:`LayoutSource` of a trace read by :func:`read_trace`."""
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
        scenario=trace.scenario.get("name", ""))


def layout_source(path: str | os.PathLike[str]) -> LayoutSource:
    """Return what a layout needs from a trace file, reading its summary and the first
    message of the plant, update and freshness topics (the whole file when it has no
    summary, e.g. its writer was killed).

    Raises
    ------
    TraceError
        The file is not a readable netsim trace.
    """
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    where = str(path)
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
            wanted = [t for t in topics if t == plant_topic()
                      or ((info := parse_topic(t)) is not None
                          and info.kind in ("update", "freshness"))]
            first: dict[str, Any] = {}
            if wanted:
                for _schema, channel, _message, decoded in reader.iter_decoded_messages(
                        topics=wanted, log_time_order=False):
                    first.setdefault(channel.topic, decoded)
                    if len(first) == len(wanted):
                        break
    except OSError as exc:
        raise TraceError(f"{where}: cannot read file ({exc.strerror or exc})") from None
    except Exception:  # noqa: BLE001 - unfinished or damaged: the full reader decides
        return source_from_trace(read_trace(path))
    run = metadata.get("run", {})
    fmt = run.get("trace_format", "netsim-trace/1").rsplit("/", 1)[-1]
    neighbours: dict[int, list[int]] = {}
    substates: dict[int, int] = {}
    for topic, msg in first.items():
        info = parse_topic(topic)
        if info is None:
            continue
        if info.kind == "update":
            neighbours[info.index] = [int(j) for j in msg.neighbours]
        elif info.kind == "freshness":
            substates[info.index] = len(msg.index)
    plant = first.get(plant_topic())
    reasons = {int(c): r for c, r in metadata.get("drop_reasons", {}).items() if c.isdigit()}
    return LayoutSource(
        path=where, format=int(fmt) if fmt.isdigit() else 1, topics=topics,
        n_states=0 if plant is None else len(plant.state), neighbours=neighbours,
        substates=substates, drop_reasons=reasons, family=run.get("family", ""),
        scenario=metadata.get("scenario", {}).get("name", ""))


# -- the layout ----------------------------------------------------------------------

_PALETTE = ("#4e98e2", "#f5774d", "#5cd67a", "#f7df71", "#eb8fd0", "#a395e2", "#61e0e0",
            "#e25c5c", "#b6e06e", "#fd9a3a", "#9bd0f5", "#c4c4c4")
_TRUTH = "#ffffff"


def _series(value: str, label: str, colour: str, *, line: bool = True,
            size: float = 1.5) -> dict[str, Any]:
    return {"value": value, "enabled": True, "timestampMethod": "receiveTime",
            "label": label, "color": colour, "showLine": line, "lineSize": size}


def _plot(title: str, paths: list[dict[str, Any]], *, y_min: float | None = None,
          y_max: float | None = None) -> dict[str, Any]:
    config: dict[str, Any] = {
        "title": title, "foxglovePanelTitle": title, "paths": paths,
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
    """Return a Foxglove layout (JSON-ready dict) for a format-2 trace.

    Parameters
    ----------
    source : LayoutSource or Trace
        The trace (see :func:`layout_source`).
    max_series : int
        Most message paths per Plot panel.
    max_states : int
        State components given a "state against estimates" panel.

    Raises
    ------
    ValueError
        A format-1 trace (its link events share one topic; re-record it).
    """
    if isinstance(source, Trace):
        source = source_from_trace(source)
    if source.format < 2:
        raise ValueError(f"{source.path}: trace format {source.format}; Foxglove layouts "
                         "need format 2 (record it again with netsim run --trace)")
    topics = set(source.topics)
    tabs: list[tuple[str, list[tuple[str, dict[str, Any]]]]] = []

    def colour(index: int) -> str:
        return _PALETTE[index % len(_PALETTE)]

    def panels(title: str, series: list[dict[str, Any]], **kw: Any
               ) -> list[tuple[str, dict[str, Any]]]:
        groups = _chunks(series, max_series)
        out = []
        for q, group in enumerate(groups):
            name = title if len(groups) == 1 else f"{title} ({q + 1}/{len(groups)})"
            out.append((f"Plot!{_slug(name)}", _plot(name, group, **kw)))
        return out

    agents = [i for i in source.agents("estimate") if estimate_topic(i) in topics]
    errors = [_series(f"{estimate_topic(i)}.error_norm", f"agent {i}", colour(i))
              for i in agents]
    if errors:
        tabs.append(("Errors", panels("Error norm ||x-hat^i_k - x_k|| per agent", errors,
                                      y_min=0)))

    state: list[tuple[str, dict[str, Any]]] = []
    if plant_topic() in topics:
        for s in range(min(source.n_states, max_states)):
            series = [_series(f"{plant_topic()}.state[{s}]", f"x[{s}] (true)", _TRUTH,
                              size=2.5)]
            series += [_series(f"{estimate_topic(i)}.estimate[{s}]", f"agent {i}",
                               colour(i), size=1.0) for i in agents]
            state += panels(f"State x[{s}] against the agents' estimates", series)
    if state:
        tabs.append(("State", state))

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
                                  f"r {j}->{i}", link_colour[(j, i)]))
    delay_panels = panels("Effective delay r_ij[k] (steps; -1 own estimate used)", delays)
    delivered = [_series(f"{link_topic(j, i, 'delivered')}.delay_steps", f"{j}->{i}",
                         link_colour[(j, i)], line=False)
                 for j, i in source.links("delivered")]
    delay_panels += panels("Delivered message delay d (steps) per link", delivered, y_min=0)
    if delay_panels:
        tabs.append(("Delays", delay_panels))

    dropped_links = source.links("dropped")
    if dropped_links:
        which = [_series(f"{link_topic(j, i, 'dropped')}.sequence", f"{j}->{i}",
                         link_colour[(j, i)], line=False) for j, i in dropped_links]
        why = [_series(f"{link_topic(j, i, 'dropped')}.reason", f"{j}->{i}",
                       link_colour[(j, i)], line=False) for j, i in dropped_links]
        codes = ", ".join(f"{c} {r}" for c, r in sorted(source.drop_reasons.items()))
        tabs.append(("Drops", panels("Dropped messages (sequence number) per link", which)
                     + panels(f"Drop reason code ({codes or 'none'})", why, y_min=0)))

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
    config_by_id["Tab!netsim"] = {"activeTabIdx": 0, "tabs": tab_list}
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


def render_layout(trace: Trace, layout: dict[str, Any], output: str | os.PathLike[str], *,
                  tabs: Sequence[str] | None = None, columns: int = 2,
                  max_panels: int = 8) -> Path:
    """Draw the layout's Plot panels from the trace's data into a PNG (dark theme, like
    Foxglove): every series evaluated from its message path against the trace records,
    x = simulation time in seconds (Foxglove's x axis is the same, from the start).

    ``tabs`` picks tabs by title (default all), ``max_panels`` caps the picture.
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
    rows = math.ceil(len(chosen) / columns)
    with plt.style.context("dark_background"):
        fig, axes = plt.subplots(rows, columns, figsize=(6.4 * columns, 3.2 * rows),
                                 squeeze=False, facecolor="#15151a")
        for ax in axes.ravel()[len(chosen):]:
            ax.set_visible(False)
        for ax, (tab, panel) in zip(axes.ravel(), chosen, strict=False):
            ax.set_facecolor("#1e1e24")
            for series in panel["paths"]:
                xs, ys = _series_data(trace, series["value"])
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
        fig.suptitle(f"Foxglove layout of {Path(trace.path).name} (netsim layout)",
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
