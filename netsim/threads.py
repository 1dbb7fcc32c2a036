"""One BLAS thread around the work that needs it, and nowhere else (issue 30).

netsim's analytics and engines take eigenvalues and products of many small dense
matrices (a few to a few hundred rows: the augmented closed loop, the gain design,
the vectorised engine's batched updates). On such matrices a multithreaded BLAS is
10-100x slower than one thread on a busy machine, because its threads spin and fight
for the cores. So the entry points (:func:`netsim.run`, :func:`netsim.analyze`, the
gain design, sweeps, claims) run inside :func:`single_threaded_blas`, which limits the
BLAS thread pools of this process with :mod:`threadpoolctl` for as long as they run
and restores them afterwards.

``import netsim`` changes nothing in the process (no environment variables): code the
user runs between netsim calls keeps the BLAS threads it had. Worker processes netsim
starts (:mod:`netsim.parallel`, local sweeps, claims searches) call
:func:`limit_worker_threads` as their initialiser: they are netsim's own processes, so
the limit holds for their whole life.

Example
-------
>>> import numpy as np
>>> from threadpoolctl import threadpool_info
>>> from netsim.threads import single_threaded_blas
>>> with single_threaded_blas():
...     inside = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
>>> all(n == 1 for n in inside)
True
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

__all__ = ["single_threaded_blas", "limit_worker_threads"]

_state = threading.local()


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Limit the process's BLAS thread pools to one thread while the block runs.

    Usable as ``with single_threaded_blas():`` or as a decorator
    (``@single_threaded_blas()``). Nested uses cost nothing: only the outermost one
    sets and restores the limit (about a millisecond, so it belongs at entry points,
    never inside a loop).

    Yields
    ------
    None
    """
    if getattr(_state, "depth", 0):
        _state.depth += 1
        try:
            yield
        finally:
            _state.depth -= 1
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        _state.depth = 1
        try:
            yield
        finally:
            _state.depth = 0


def limit_worker_threads() -> None:
    """Limit BLAS to one thread for the rest of this (worker) process's life.

    The initialiser of the worker processes netsim starts (a worker made by
    ``fork`` inherits its parent's limit; one made by ``forkserver`` or ``spawn`` does
    not).
    """
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
