"""Trace-driven link delays: a recorded trace's link events as a delay distribution.

A scenario's ``[links] delay = { distribution = "trace", file = "earlier.mcap" }``
replays, message by message, the per-link delays and losses of an earlier run.
:func:`load_trace_replay` reads them into a :class:`netsim.models.linkmodels.TraceReplay`;
the ``netsim`` package registers it as the ``"trace"`` delay source of
:mod:`netsim.models.delaysources`, which is how the scenario loader in ``models`` reaches
it without importing ``traces``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from netsim.models.linkmodels import LinkRecord, TraceReplay
from netsim.traces.reader import TraceError, read_trace

__all__ = ["load_trace_replay"]


def load_trace_replay(path: str | Path) -> TraceReplay:
    """Read the link events of an MCAP trace written by netsim into a
    :class:`netsim.models.linkmodels.TraceReplay`.

    The ``"trace"`` delay source (:mod:`netsim.models.delaysources`): the ``netsim``
    package registers it, and :func:`netsim.models.linkmodels.load_trace_replay` calls it.

    Parameters
    ----------
    path : str or Path
        The MCAP trace.

    Returns
    -------
    TraceReplay
        The recorded link events, by link and per-link sequence number.

    Raises
    ------
    ValueError
        Naming the file: not readable as a netsim trace, no link topics, or a link
        whose sequence numbers do not start at 0.
    """
    try:
        trace = read_trace(path)
    except TraceError as exc:
        raise ValueError(str(exc)) from None
    ts = trace.sample_period
    records: dict[tuple[int, int], LinkRecord] = {}
    for link in trace.links:
        sent: dict[int, Any] = {}
        dropped: dict[int, str] = {}
        for ev in trace.link_events(*link):
            if ev.event == "sent":
                sent[int(ev.sequence)] = ev
            elif ev.event == "dropped":
                dropped[int(ev.sequence)] = str(ev.reason)
        count = 0
        while count in sent:
            count += 1
        if sent and count == 0:
            raise ValueError(f"trace {path}: link {link[0]}->{link[1]} has no message with "
                             "sequence number 0")
        evs = [sent[q] for q in range(count)]
        steps = np.array([int(e.sent_step) for e in evs], dtype=np.int64)
        lat = np.array([float(e.arrival_time) - float(e.send_time) for e in evs])
        d = np.array([int(e.delay_steps) for e in evs], dtype=np.int64)
        boundary = all(
            float(e.arrival_time) == (float(e.sent_step) + 1.0 + int(e.delay_steps)) * ts
            for e in evs
        )
        records[link] = LinkRecord(steps, lat, d, boundary,
                                   {q: r for q, r in dropped.items() if q < count})
    if not records:
        raise ValueError(f"trace {path} has no link topics (/link_<j>_<i>/...) to replay")
    return TraceReplay(records, ts, str(path))
