"""MCAP traces of simulation runs: record (:mod:`traces.recorder`), read back and
recover (:mod:`traces.reader`), summarise (:mod:`traces.inspect`); message types in
:mod:`traces.schemas`. This package imports ``models`` but never ``netsim``/``simpy``.
"""

from traces.inspect import InspectReport, inspect_trace
from traces.reader import Trace, TraceError, read_trace
from traces.recorder import TraceRecorder, trace_path

__all__ = [
    "InspectReport",
    "Trace",
    "TraceError",
    "TraceRecorder",
    "inspect_trace",
    "read_trace",
    "trace_path",
]
