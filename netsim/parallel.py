"""Independent tasks on the local cores, in order, only when that is worth it.

:func:`ordered_map` runs ``fn(item)`` for every item and returns the results in the
items' order, whatever order they finish in; the results are what a serial loop gives
(each task must be deterministic in its arguments: no shared random state). It runs
in worker processes only when the caller's estimate of the serial work is at least
:data:`PARALLEL_MIN_SECONDS`: starting the workers (``fork`` on Linux, about 10-50 ms;
``spawn`` elsewhere, which re-imports netsim: about 0.5 s each) costs more than it saves
on a sub-second command. ``netsim analyze`` uses it for its tau values; ``netsim
claims`` can use it the same way.

The worker count is ``workers`` if given, else :envvar:`NETSIM_WORKERS`, else the CPUs
this process may run on. Inside a worker process (a sweep's, or this module's) it
always runs serially, so pools never nest.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, TypeVar

__all__ = ["PARALLEL_MIN_SECONDS", "WORKERS_ENV", "available_cpus", "choose_workers",
           "env_workers", "ordered_map"]

T = TypeVar("T")
R = TypeVar("R")

#: Serial work (seconds, the caller's estimate) below which tasks run in-process.
PARALLEL_MIN_SECONDS: float = 1.0

#: Environment variable overriding the worker count (``1``: always serial).
WORKERS_ENV = "NETSIM_WORKERS"


def available_cpus() -> int:
    """Return the number of CPUs this process may run on (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


def choose_workers(n_items: int, estimated_seconds: float | None,
                   workers: int | None = None, max_workers: int | None = None) -> int:
    """Return how many processes :func:`ordered_map` uses (1: serial, in-process).

    Parameters
    ----------
    n_items : int
        Number of tasks.
    estimated_seconds : float or None
        The caller's estimate of the serial run time; ``None`` means unknown (serial
        unless ``workers`` asks for more).
    workers : int, optional
        An explicit count (from ``--workers``); ``None``: :envvar:`NETSIM_WORKERS`,
        else :func:`available_cpus`, and only if the estimate reaches
        :data:`PARALLEL_MIN_SECONDS`.
    max_workers : int, optional
        A cap on the result (e.g. how many tasks fit in memory at once).
    """
    if n_items <= 1 or multiprocessing.parent_process() is not None:
        return 1
    if workers is None:
        workers = env_workers()
    if workers is None:
        if estimated_seconds is None or estimated_seconds < PARALLEL_MIN_SECONDS:
            return 1
        workers = available_cpus()
    if max_workers is not None:
        workers = min(int(workers), int(max_workers))
    return max(1, min(int(workers), n_items))


def env_workers() -> int | None:
    """Return :envvar:`NETSIM_WORKERS` as a positive int (None if unset or empty).

    Raises
    ------
    ValueError
        If it is set to anything but a positive integer (one line naming it).
    """
    from netsim.taskoptions import getenv

    env = (getenv(WORKERS_ENV) or "").strip()  # a sweep's task sets it to 1
    if not env:
        return None
    try:
        value = int(env)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{WORKERS_ENV} must be a positive integer, got {env!r}")
    return value


def _ignore_sigint() -> None:
    """Worker initialiser: Ctrl-C is the parent's to handle (it cancels the pool); one
    BLAS thread (:func:`netsim.threads.limit_worker_threads`)."""
    from netsim.threads import limit_worker_threads

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_worker_threads()


def _context() -> Any:
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else None)


def ordered_map(
    fn: Callable[[T], R],
    items: Iterable[T],
    *,
    estimated_seconds: float | None = None,
    workers: int | None = None,
    max_workers: int | None = None,
    progress: Callable[[int], None] | None = None,
    check: Callable[[], None] | None = None,
) -> list[R]:
    """Return ``[fn(item) for item in items]``, in parallel when worth it.

    Parameters
    ----------
    fn : callable
        A module-level function (picklable), deterministic in its argument.
    items : iterable
        Its arguments (picklable).
    estimated_seconds, workers, max_workers
        See :func:`choose_workers`.
    progress : callable(int), optional
        Called with 1 as each task finishes (in completion order when parallel).
    check : callable, optional
        Called before each task (serial) or while waiting (parallel); an exception it
        raises (e.g. :func:`netsim.interrupt.check`'s KeyboardInterrupt) cancels the
        remaining tasks and propagates.

    Returns
    -------
    list
        ``fn(item)`` per item, in the items' order.
    """
    todo: Sequence[T] = list(items)
    count = choose_workers(len(todo), estimated_seconds, workers, max_workers)
    if count == 1:
        out = []
        for item in todo:
            if check is not None:
                check()
            out.append(fn(item))
            if progress is not None:
                progress(1)
        return out
    results: list[Any] = [None] * len(todo)
    pool = ProcessPoolExecutor(max_workers=count, mp_context=_context(),
                               initializer=_ignore_sigint)
    try:
        pending: dict[Future[R], int] = {pool.submit(fn, item): i
                                         for i, item in enumerate(todo)}
        while pending:
            if check is not None:
                check()
            done, _ = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            for fut in done:
                results[pending.pop(fut)] = fut.result()
                if progress is not None:
                    progress(1)
    except BaseException:
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            proc.terminate()  # a task in flight need not finish
        raise
    pool.shutdown(wait=True)
    return results
