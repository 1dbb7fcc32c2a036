"""MCAP traces of simulation runs: record (:mod:`netsim.traces.recorder`), read back and
recover (:mod:`netsim.traces.reader`, formats 1 and 2), summarise (:mod:`netsim.traces.inspect`),
Foxglove layouts (:mod:`netsim.traces.layout`); message types and topics of format 2 in
:mod:`netsim.traces.schemas` and ``traces/netsim_trace_v2.proto``. This package imports
``models`` but never ``netsim``/``simpy``.
"""

from netsim.traces.inspect import InspectReport, inspect_trace
from netsim.traces.reader import Trace, TraceError, read_trace
from netsim.traces.recorder import TraceRecorder, trace_path

__all__ = [
    "InspectReport",
    "Trace",
    "TraceError",
    "TraceRecorder",
    "inspect_trace",
    "read_trace",
    "trace_path",
]
