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
import sys
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["single_threaded_blas", "limit_worker_threads", "mark_process_single_threaded"]

#: Open :func:`single_threaded_blas` blocks in this process (any thread), and the
#: limiter the first one set (restored when the last one closes).
_lock = threading.Lock()
_open = 0
_limiter: Any = None
#: Set by :func:`mark_process_single_threaded`: the BLAS of this whole process was
#: limited to one thread before it loaded (the ``netsim`` command, :mod:`netsim.console`).
_process_single_threaded = False


def mark_process_single_threaded() -> None:
    """Record that this process's BLAS runs one thread for its whole life.

    Called by the ``netsim`` command's entry point (:func:`netsim.console.main`) after it
    set the thread variables to 1 before numpy loaded; :func:`single_threaded_blas` is
    then free (no threadpoolctl, no walk over the loaded libraries).
    """
    global _process_single_threaded
    _process_single_threaded = True


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Limit the process's BLAS thread pools to one thread while the block runs.

    Usable as ``with single_threaded_blas():`` or as a decorator
    (``@single_threaded_blas()``). Nested (or concurrent, from several threads) uses
    cost nothing: the first one to open sets the limit and the last one to close
    restores the pools as they were (setting it takes about a millisecond, so it
    belongs at entry points, never inside a loop).

    Yields
    ------
    None
    """
    global _open, _limiter
    if _process_single_threaded:  # the netsim command: one thread since start-up
        yield
        return
    with _lock:
        if _open == 0:
            from threadpoolctl import threadpool_limits

            _load_blas()
            _limiter = threadpool_limits(limits=1, user_api="blas")
        _open += 1
    try:
        yield
    finally:
        with _lock:
            _open -= 1
            if _open == 0:
                limiter, _limiter = _limiter, None
                limiter.restore_original_limits()


def limit_worker_threads() -> None:
    """Limit BLAS to one thread for the rest of this (worker) process's life.

    The initialiser of the worker processes netsim starts (a worker made by
    ``fork`` inherits its parent's limit; one made by ``forkserver`` or ``spawn`` does
    not).
    """
    from threadpoolctl import threadpool_limits

    _load_blas()
    threadpool_limits(limits=1, user_api="blas")


def _load_blas() -> None:
    """Load the BLAS libraries netsim computes with (numpy's and scipy's own), so that
    the limit reaches them: threadpoolctl limits only libraries already loaded (a fresh
    ``forkserver`` or ``spawn`` worker has loaded none).

    scipy's BLAS is loaded by its file when the wheel bundles it (``scipy.libs``:
    the dynamic linker then gives scipy.linalg that same, limited, library), so that
    a command that never uses scipy.linalg does not import it (0.2-0.3 s of CPU at
    start-up, issue 34); elsewhere scipy.linalg is imported."""
    import numpy  # noqa: F401

    if "scipy.linalg" in sys.modules or _load_bundled_scipy_blas():
        return
    import scipy.linalg  # noqa: F401


def _load_bundled_scipy_blas() -> bool:
    """Load the BLAS libraries a scipy wheel bundles in ``site-packages/scipy.libs``
    with ctypes, without importing scipy.linalg: whether any was found and loaded."""
    import ctypes
    import glob
    import importlib.util
    import os

    spec = importlib.util.find_spec("scipy")
    if spec is None or not spec.submodule_search_locations:
        return False
    folder = os.path.join(os.path.dirname(list(spec.submodule_search_locations)[0]),
                          "scipy.libs")
    libraries = sorted(glob.glob(os.path.join(folder, "lib*blas*.so*")))
    try:
        for path in libraries:
            ctypes.CDLL(path)
    except OSError:
        return False
    return bool(libraries)
