"""Summaries of a trace: what is in the file, link delays, drops, reorderings, errors.

:func:`inspect_trace` turns a :class:`netsim.traces.reader.Trace` into an
:class:`InspectReport`; ``report.to_dict()`` is JSON-ready and ``report.format_text()``
(also ``str(report)``) is the human-readable form.

Definitions
-----------
- Link delay statistics are over the *delivered* messages of a link (``delay_steps``
  d: the message is usable at step s + 1 + d).
- A *reordering* is a delivery whose time-stamp (``sent_step``) is smaller than that
  of a message already delivered on the same link.
- ``in_flight``: sent but neither delivered nor dropped when the trace ends.
- Effective delays are the r_ij[k] the receiver's updates used (``/agent_<i>/update``),
  excluding steps where it substituted its own estimate (counted as ``substituted``).
- Per-agent MSE: the mean over recorded steps of ||x-hat^i_k - x_k||^2; ``final`` is
  the value at the last recorded update; ``tail_mse`` the mean over the last quarter.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from netsim.models.jsonsafe import json_number as _num
from netsim.traces.reader import Trace
from netsim.traces.schemas import format_time_origin

__all__ = ["LinkStats", "AgentStats", "InspectReport", "inspect_trace", "delay_statistics"]




def delay_statistics(delays: list[int] | np.ndarray) -> dict[str, Any]:
    """Return count, min, mean, max and histogram {d: count} of step delays."""
    values = [int(d) for d in delays]
    if not values:
        return {"count": 0, "min": None, "mean": None, "max": None, "histogram": {}}
    hist: dict[int, int] = {}
    for d in values:
        hist[d] = hist.get(d, 0) + 1
    return {
        "count": len(values),
        "min": min(values),
        "mean": sum(values) / len(values),
        "max": max(values),
        "histogram": dict(sorted(hist.items())),
    }


@dataclass
class LinkStats:
    """Traffic on one link sender -> receiver."""

    sender: int
    receiver: int
    sent: int = 0
    delivered: int = 0
    dropped: int = 0
    accepted: int = 0
    discarded: int = 0
    reordered: int = 0
    in_flight: int = 0
    delay: dict[str, Any] = field(default_factory=dict)
    effective_delay: dict[str, Any] = field(default_factory=dict)
    substituted: int = 0
    drop_reasons: dict[str, int] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.sender}->{self.receiver}"

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        for key in ("delay", "effective_delay"):
            stats = dict(out[key])
            stats["mean"] = _num(stats.get("mean"))
            stats["histogram"] = {str(k): v for k, v in stats.get("histogram", {}).items()}
            out[key] = stats
        return out


@dataclass
class AgentStats:
    """Estimation error of one agent."""

    agent: int
    updates: int
    mse: float
    tail_mse: float
    final_squared_error: float
    final_error_norm: float
    max_squared_error: float

    def to_dict(self) -> dict[str, Any]:
        return {k: (_num(v) if isinstance(v, float) else v) for k, v in asdict(self).items()}


@dataclass
class InspectReport:
    """Summary of a trace (see module docstring for the definitions)."""

    path: str
    scenario: str
    family: str
    trial: int | None
    seed: str
    status: str
    status_detail: dict[str, str]
    truncated: bool
    recovered_messages: int
    topics: dict[str, int]
    first_step: int | None
    last_step: int | None
    steps_recorded: int
    n_agents: int
    n_states: int
    links: dict[str, LinkStats]
    agents: dict[int, AgentStats]
    totals: dict[str, int]
    network_mse: float
    matrices: list[str]
    #: AoI traces: per agent, [first step all indices triggered, largest index after]
    freshness: dict[int, list[int | None]] | None = None
    #: Damaged chunks the reader skipped (``LostChunk.to_dict``), [] for an intact file.
    lost_chunks: list[dict[str, Any]] = field(default_factory=list)
    #: Messages lost with them (None if some count is unknown).
    lost_messages: int | None = 0
    #: Messages of intact chunks on channels defined only in a lost chunk.
    orphaned_messages: int = 0
    #: How the file was read, when its summary was unusable.
    read_note: str = ""
    #: Trace format (1, 2 or 3) and time origin of log_time (ISO 8601 UTC).
    trace_format: int = 1
    time_origin: str = ""
    #: Messages per topic of the file itself (format 3: its per-step topics, which
    #: ``topics`` gives as the per-agent and per-link view; else equal to ``topics``).
    file_topics: dict[str, int] = field(default_factory=dict)
    #: [time] traces: per agent, its clock as the samples show it (samples, sent,
    #: offset at the first sample, drift in ppm fitted over the run, mean local period)
    clocks: dict[int, dict[str, float]] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            **({"clocks": {str(i): {k: _num(v) for k, v in c.items()}
                           for i, c in self.clocks.items()}} if self.clocks else {}),
            "freshness": None if self.freshness is None else {
                str(i): {"triggered_at": v[0], "max_index_after": v[1]}
                for i, v in self.freshness.items()
            },
            "path": self.path,
            "trace_format": self.trace_format,
            "time_origin": self.time_origin,
            "scenario": self.scenario,
            "family": self.family,
            "trial": self.trial,
            "seed": self.seed,
            "status": self.status,
            "status_detail": dict(self.status_detail),
            "truncated": self.truncated,
            "recovered_messages": self.recovered_messages,
            "damaged": bool(self.lost_chunks) or self.orphaned_messages > 0,
            "lost_chunks": [dict(c) for c in self.lost_chunks],
            "lost_messages": self.lost_messages,
            "orphaned_messages": self.orphaned_messages,
            "read_note": self.read_note,
            "topics": dict(self.topics),
            "file_topics": dict(self.file_topics),
            "steps": {
                "first": self.first_step,
                "last": self.last_step,
                "recorded": self.steps_recorded,
            },
            "n_agents": self.n_agents,
            "n_states": self.n_states,
            "matrices": list(self.matrices),
            "messages": dict(self.totals),
            "links": {name: s.to_dict() for name, s in self.links.items()},
            "agents": {str(i): s.to_dict() for i, s in self.agents.items()},
            "network_mse": _num(self.network_mse),
        }

    def format_text(self) -> str:
        lines = [f"trace {self.path}   (format {self.trace_format}, log_time origin "
                 f"{self.time_origin})"]
        lines.append(
            f"  scenario {self.scenario or '?'}   family {self.family or '?'}   "
            f"trial {self.trial if self.trial is not None else '?'}   seed {self.seed or '?'}"
        )
        if self.truncated:
            state = (f"TRUNCATED (writer never finished): recovered {self.recovered_messages} "
                     "messages from complete chunks")
        else:
            state = f"{self.status}"
            extra = {k: v for k, v in self.status_detail.items() if k != "status"}
            if extra:
                state += " (" + ", ".join(f"{k} {v}" for k, v in extra.items()) + ")"
        lines.append(f"  status {state}")
        if self.lost_chunks or self.orphaned_messages:
            lost = "?" if self.lost_messages is None else str(self.lost_messages)
            lines.append(f"  DAMAGED: {len(self.lost_chunks)} unreadable part(s) skipped, "
                         f"{lost} messages lost; every intact chunk around them was read "
                         f"({self.recovered_messages} messages)")
            for c in self.lost_chunks:
                what = (f"chunk {c['chunk']}" if c["chunk"] is not None
                        else "bytes")
                steps = ("" if c["steps"] is None
                         else f", steps {c['steps'][0]}..{c['steps'][1]}")
                messages = "" if c["messages"] is None else f", {c['messages']} messages"
                lines.append(f"    lost {what} at byte {c['offset']} ({c['length']} bytes"
                             f"{steps}{messages}): {c['reason']}")
            if self.orphaned_messages:
                lines.append(f"    {self.orphaned_messages} messages on channels defined "
                             "only in a lost chunk (not decoded)")
        if self.read_note:
            lines.append(f"  note: {self.read_note}")
        steps = ("none" if self.first_step is None
                 else f"{self.first_step}..{self.last_step} ({self.steps_recorded} recorded)")
        lines.append(f"  steps {steps}   agents {self.n_agents}   states {self.n_states}")
        if self.matrices:
            lines.append(f"  matrices {', '.join(_name_ranges(self.matrices))}")
        t = self.totals
        lines.append(
            f"  messages sent {t['sent']}, delivered {t['delivered']} "
            f"(accepted {t['accepted']}, stale {t['discarded']}), dropped {t['dropped']}, "
            f"reordered {t['reordered']}, in flight at end {t['in_flight']}"
        )
        if self.file_topics and self.file_topics != self.topics:
            lines.append("topics in the file (one message per step)")
            width = max((len(name) for name in self.file_topics), default=10)
            for name, count in self.file_topics.items():
                lines.append(f"  {name:<{width}}  {count:>8}")
            lines.append("topics as read (per agent and per link event, as format 2)")
        else:
            lines.append("topics")
        width = max((len(name) for name in self.topics), default=10)
        for name, count in _first(self.topics.items(), lines, "topics"):
            lines.append(f"  {name:<{width}}  {count:>8}")
        if self.links:
            lines.append("links (delay_steps of delivered messages; r = effective delay used)")
            lines.append(
                f"  {'link':<8}{'sent':>6}{'deliv':>7}{'drop':>6}{'reord':>7}{'fly':>5}"
                f"{'min':>5}{'mean':>7}{'max':>5}  histogram d:count   | r min/mean/max"
            )
            for name, s in _first(self.links.items(), lines, "links"):
                d, r = s.delay, s.effective_delay
                hist = " ".join(f"{k}:{v}" for k, v in d.get("histogram", {}).items()) or "-"
                rtxt = ("-" if not r.get("count")
                        else f"{r['min']}/{r['mean']:.2f}/{r['max']}")
                lines.append(
                    f"  {name:<8}{s.sent:>6}{s.delivered:>7}{s.dropped:>6}{s.reordered:>7}"
                    f"{s.in_flight:>5}{_fmt(d.get('min')):>5}{_fmt(d.get('mean'), 2):>7}"
                    f"{_fmt(d.get('max')):>5}  {hist}   | {rtxt}"
                )
        dropping = {name: s for name, s in self.links.items() if s.drop_reasons}
        if dropping:
            lines.append("drop reasons (messages lost per link and cause)")
            for name, s in _first(dropping.items(), lines, "links"):
                causes = ", ".join(f"{reason} {count}" for reason, count
                                   in sorted(s.drop_reasons.items()))
                lines.append(f"  {name:<8}{causes}")
        if self.agents:
            lines.append("agents (squared error ||x-hat - x||^2)")
            lines.append(f"  {'agent':<6}{'updates':>8}{'mse':>12}{'tail mse':>12}"
                         f"{'final':>12}{'max':>12}")
            for i, a in _first(self.agents.items(), lines, "agents"):
                lines.append(
                    f"  {i:<6}{a.updates:>8}{_fmt(a.mse, 4, True):>12}"
                    f"{_fmt(a.tail_mse, 4, True):>12}{_fmt(a.final_squared_error, 4, True):>12}"
                    f"{_fmt(a.max_squared_error, 4, True):>12}"
                )
            lines.append(f"  network mse {_fmt(self.network_mse, 4, True)}")
        if self.freshness:
            lines.append("age of information (AoI freshness index, largest over substates)")
            for i, (first, worst) in self.freshness.items():
                lines.append(f"  agent {i}: every index triggered from step {first}; "
                             f"largest index after that {worst}")
        if self.clocks:
            lines.append("clocks (samples on each agent's own clock; offset = local - true "
                         "at the first sample, drift fitted, period in local time)")
            lines.append(f"  {'agent':<6}{'samples':>8}{'sent':>7}{'offset':>12}"
                         f"{'drift ppm':>12}{'period':>10}")
            for i, c in self.clocks.items():
                lines.append(f"  {i:<6}{int(c['samples']):>8}{int(c['sent']):>7}"
                             f"{_fmt(c['offset'], 4):>12}{_fmt(c['drift_ppm'], 1):>12}"
                             f"{_fmt(c['period'], 4):>10}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format_text()


def _fmt(value: Any, digits: int = 0, sci: bool = False) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return f"{value:.{digits}e}" if sci else f"{value:.{digits}f}"
    return str(value)


def inspect_trace(trace: Trace) -> InspectReport:
    """Summarise a trace read by :func:`netsim.traces.reader.read_trace`."""
    links: dict[tuple[int, int], LinkStats] = {}

    def link(j: int, i: int) -> LinkStats:
        if (j, i) not in links:
            links[(j, i)] = LinkStats(j, i)
        return links[(j, i)]

    delays: dict[tuple[int, int], list[int]] = {}
    for j, i in trace.links:
        stats = link(j, i)
        newest = -1
        seen_sent: set[int] = set()
        done: set[int] = set()
        for msg in trace.link_events(j, i):
            if msg.event == "sent":
                stats.sent += 1
                seen_sent.add(msg.sequence)
            elif msg.event == "delivered":
                stats.delivered += 1
                done.add(msg.sequence)
                if msg.accepted:
                    stats.accepted += 1
                else:
                    stats.discarded += 1
                if msg.sent_step < newest:
                    stats.reordered += 1
                newest = max(newest, int(msg.sent_step))
                delays.setdefault((j, i), []).append(int(msg.delay_steps))
            elif msg.event == "dropped":
                stats.dropped += 1
                done.add(msg.sequence)
                reason = msg.reason or "unspecified"
                stats.drop_reasons[reason] = stats.drop_reasons.get(reason, 0) + 1
        stats.in_flight = len(seen_sent - done)
        stats.delay = delay_statistics(delays.get((j, i), []))

    effective: dict[tuple[int, int], list[int]] = {}
    agents: dict[int, AgentStats] = {}
    for i in trace.agents:
        for msg in trace.topic(trace.update_topic(i)):
            for j, r in zip(msg.neighbours, msg.effective_delay, strict=True):
                r = int(r)
                if r < 0:
                    link(int(j), i).substituted += 1
                else:
                    effective.setdefault((int(j), i), []).append(int(r))
        estimates = trace.topic(trace.estimate_topic(i))
        sq = np.array([m.squared_error for m in estimates], dtype=float)
        if len(sq):
            tail = sq[-max(1, len(sq) // 4):]
            agents[i] = AgentStats(
                agent=i,
                updates=len(sq),
                mse=float(np.mean(sq)),
                tail_mse=float(np.mean(tail)),
                final_squared_error=float(sq[-1]),
                final_error_norm=float(estimates[-1].error_norm),
                max_squared_error=float(np.max(sq)),
            )
    for key, values in effective.items():
        link(*key).effective_delay = delay_statistics(values)
    for stats in links.values():
        if not stats.effective_delay:
            stats.effective_delay = delay_statistics([])
        if not stats.delay:
            stats.delay = delay_statistics([])

    ordered = {s.name: s for _, s in sorted(links.items())}
    totals = {
        key: sum(getattr(s, key) for s in ordered.values())
        for key in ("sent", "delivered", "accepted", "discarded", "dropped", "reordered",
                    "in_flight")
    }
    steps = trace.steps
    status = trace.status
    if trace.truncated:
        status_name = "truncated"
    elif status is None:
        status_name = "unknown"
    else:
        status_name = status.get("status", "unknown")
    mses = [a.mse for a in agents.values()]
    return InspectReport(
        path=trace.path,
        scenario=trace.scenario.get("name", ""),
        family=trace.family,
        trial=trace.trial,
        seed=trace.seed,
        status=status_name,
        status_detail=dict(status or {}),
        truncated=trace.truncated,
        recovered_messages=trace.recovered_messages,
        topics=dict(sorted(trace.counts.items(), key=lambda kv: _topic_key(kv[0]))),
        file_topics=dict(sorted(getattr(trace, "file_counts", trace.counts).items(),
                                key=lambda kv: _topic_key(kv[0]))),
        first_step=steps[0] if steps else None,
        last_step=steps[-1] if steps else None,
        steps_recorded=len(steps),
        n_agents=trace.n_agents,
        n_states=trace.n_states,
        links=ordered,
        agents=dict(sorted(agents.items())),
        totals=totals,
        network_mse=float(np.mean(mses)) if mses else math.nan,
        matrices=sorted(trace.matrices, key=_topic_key),
        freshness=_freshness_summary(trace),
        clocks=_clock_summary(trace),
        lost_chunks=[c.to_dict(trace.sample_period) for c in trace.lost_chunks],
        lost_messages=trace.lost_messages,
        orphaned_messages=trace.orphaned_messages,
        read_note=trace.note,
        trace_format=trace.format,
        time_origin=format_time_origin(trace.time_origin_ns),
    )


def _clock_summary(trace: Trace) -> dict[int, dict[str, float]] | None:
    """Per agent: samples, sent, offset at the first sample, fitted drift (ppm) and
    mean local period, from ``/agent_<i>/clock`` (None without those topics)."""
    if not any(t.endswith("/clock") for t in trace.counts):
        return None
    out: dict[int, dict[str, float]] = {}
    for i, c in trace.clocks().items():
        true, local = c["true_time"], c["local_time"]
        lead = local - true
        drift = (float(np.polyfit(true, lead, 1)[0]) * 1e6
                 if len(true) > 1 and np.ptp(true) > 0 else math.nan)
        out[i] = {"samples": float(len(true)), "sent": float(c["sent"].sum()),
                  "offset": float(lead[0]) if len(lead) else math.nan,
                  "drift_ppm": drift,
                  "period": float(np.mean(np.diff(local))) if len(local) > 1 else math.nan}
    return out


def _freshness_summary(trace: Trace) -> dict[int, list[int | None]] | None:
    if not any(t.endswith("/freshness") for t in trace.counts):
        return None
    ages = trace.freshness()
    out: dict[int, list[int | None]] = {}
    for i in trace.agents:
        col = ages[:, i]
        recorded = col >= -1
        triggered = np.flatnonzero(recorded & (col >= 0))
        # first step from which every later recorded index is triggered (no omega)
        first = None
        for k in triggered:
            if np.all(col[k:][recorded[k:]] >= 0):
                first = int(k)
                break
        out[i] = [first, None if first is None else int(col[first:][recorded[first:]].max())]
    return out


def _topic_key(name: str) -> tuple:
    """Sort topics/names with embedded numbers numerically."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name))


#: Rows of one table the text report shows (``--json`` has them all).
TEXT_ROWS = 40


def _first(items: Any, lines: list[str], what: str, limit: int | None = None) -> Any:
    """The first ``limit`` (default :data:`TEXT_ROWS`) of ``items``; when there are
    more, a line saying how many were left out is appended to ``lines`` after them."""
    items = list(items)
    limit = TEXT_ROWS if limit is None else limit
    yield from items[:limit]
    if len(items) > limit:
        lines.append(f"  ... and {len(items) - limit} more {what} (all of them: --json)")


def _name_ranges(names: Sequence[str]) -> list[str]:
    """Names with runs of one prefix and consecutive indices folded: ``C_0 .. C_31``."""
    out: list[str] = []
    run: tuple[str, int, int] | None = None
    for name in names:
        prefix, _, index = name.rpartition("_")
        if prefix and index.isdigit():
            i = int(index)
            if run is not None and run[0] == prefix and run[2] == i - 1:
                run = (prefix, run[1], i)
                continue
            if run is not None:
                out.append(_fold(run))
            run = (prefix, i, i)
            continue
        if run is not None:
            out.append(_fold(run))
            run = None
        out.append(name)
    if run is not None:
        out.append(_fold(run))
    return out


def _fold(run: tuple[str, int, int]) -> str:
    prefix, lo, hi = run
    if hi == lo:
        return f"{prefix}_{lo}"
    if hi == lo + 1:
        return f"{prefix}_{lo}, {prefix}_{hi}"
    return f"{prefix}_{lo} .. {prefix}_{hi}"
