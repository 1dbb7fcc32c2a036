"""MCAP traces of simulation runs: record (:mod:`netsim.traces.recorder`; format 3 through
:mod:`netsim.traces.stepwriter`), read back and recover (:mod:`netsim.traces.reader`,
formats 1, 2 and 3; format 3 expanded by :mod:`netsim.traces.stepread`), summarise
(:mod:`netsim.traces.inspect`), Foxglove layouts (:mod:`netsim.traces.layout`); message
types and topics of format 3 in :mod:`netsim.traces.schemas3` and
``traces/netsim_trace_v3.proto``, of format 2 in :mod:`netsim.traces.schemas` and
``traces/netsim_trace_v2.proto``. This package imports ``models`` but never
``netsim``/``simpy``.
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
