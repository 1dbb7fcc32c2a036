"""MCAP traces of simulation runs: record (:mod:`netsim.traces.recorder`), read back and
recover (:mod:`netsim.traces.reader`), summarise (:mod:`netsim.traces.inspect`); message types in
:mod:`netsim.traces.schemas`. This package imports ``models`` but never ``netsim``/``simpy``.
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
