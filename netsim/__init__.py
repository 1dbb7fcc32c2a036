"""netsim: discrete-event simulation of distributed estimation over delayed networks."""

import os as _os

# The analytics take eigenvalues of many small dense matrices (a few hundred rows),
# where a multithreaded BLAS is 10-100x slower than one thread on a busy 2-core
# machine. Only a default: a value set by the user wins. Must run before numpy loads.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from netsim.models.delaysources import register_delay_source as _register_delay_source  # noqa: E402

__all__: list[str] = []


def _trace_replay(path):
    """The ``"trace"`` delay source: imports :mod:`netsim.traces` only when a scenario
    names a trace, so ``netsim.models`` never loads ``netsim.traces`` by itself."""
    from netsim.traces.linkdelays import load_trace_replay

    return load_trace_replay(path)


# Before any netsim.models module runs (netsim/__init__ always loads first), give the
# scenario loader its reader of trace-driven delays ([links] delay.distribution = "trace").
_register_delay_source("trace", _trace_replay)
