"""Options that travel with a task instead of through the environment (issue 34).

A few settings are read from environment variables where they are used:
``NETSIM_CACHE_DIR`` (the gain cache, ``off`` for ``--no-cache``),
``NETSIM_MEMORY_LIMIT`` and ``NETSIM_TIME_LIMIT`` (:mod:`netsim.budget`) and
``NETSIM_WORKERS`` (:mod:`netsim.parallel`), ``NETSIM_NUMBA`` (the vectorised
engine's compiled step, :func:`netsim.vectorised.choose_kernel`). A worker of a Dask
cluster is a process started long before the sweep, often on another machine: it never
sees the client's environment. So a sweep takes a :func:`snapshot` of the client's
settings and every task runs inside :func:`applied`, and the readers call
:func:`getenv` instead of ``os.environ.get``.

Rules:

* an option the client set (in its environment, or ``--no-cache``) is the task's value,
  whatever the worker's environment says;
* an option the client did not set is left to the worker's own environment (a cache
  folder or a memory limit is a property of the machine);
* a choice of how results are computed (:data:`CHOICES`: ``NETSIM_NUMBA``) is the
  client's, set or not (unset travels as ``""``, the default);
* ``NETSIM_WORKERS`` is always ``1`` in a task: a cell never starts a pool of its own.

The overrides live in a :class:`contextvars.ContextVar`, so tasks that run at the same
time in threads of one worker process (``dask worker --nthreads 2``) each see their own.

Example
-------
>>> from netsim.taskoptions import applied, getenv
>>> with applied({"NETSIM_CACHE_DIR": "off"}):
...     getenv("NETSIM_CACHE_DIR")
'off'
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys
from collections.abc import Iterator, Mapping

__all__ = ["CHOICES", "FORWARDED", "IN_TASK", "applied", "getenv", "snapshot"]

#: The environment variables a sweep forwards from the client to its tasks.
FORWARDED: tuple[str, ...] = ("NETSIM_CACHE_DIR", "NETSIM_MEMORY_LIMIT", "NETSIM_TIME_LIMIT")

#: Forwarded whether the client set them or not (unset: ``""``): they choose how a
#: result is computed, not a property of the worker's machine. ``NETSIM_NUMBA`` picks
#: the vectorised engine's compiled step (:func:`netsim.vectorised.choose_kernel`),
#: whose numbers differ from the numpy step's by round-off, so a cell computes what
#: the client would have computed whatever the worker's environment says.
CHOICES: tuple[str, ...] = ("NETSIM_NUMBA",)

#: Set in every task whatever the client says (a cell never starts a pool).
IN_TASK: dict[str, str] = {"NETSIM_WORKERS": "1"}

_overrides: contextvars.ContextVar[Mapping[str, str] | None] = contextvars.ContextVar(
    "netsim_task_options", default=None)


def snapshot() -> dict[str, str]:
    """Return the options of this (client) process that its tasks must use.

    Returns
    -------
    dict of str to str
        The :data:`FORWARDED` variables set in this process (``NETSIM_CACHE_DIR`` is
        ``"off"`` inside :func:`netsim.gaincache.disabled`, i.e. ``--no-cache``), plus
        :data:`IN_TASK`. Plain strings: it is pickled into every task.
    """
    out = {name: os.environ[name] for name in FORWARDED if name in os.environ}
    out.update({name: os.environ.get(name, "") for name in CHOICES})
    gaincache = sys.modules.get("netsim.gaincache")
    if gaincache is not None and getattr(gaincache, "_OFF", [False])[-1]:
        out["NETSIM_CACHE_DIR"] = "off"
    out.update(IN_TASK)
    return out


@contextlib.contextmanager
def applied(options: Mapping[str, str] | None) -> Iterator[None]:
    """Make :func:`getenv` answer from ``options`` first while the block runs.

    Parameters
    ----------
    options : mapping of str to str, or None
        What :func:`snapshot` returned on the client; None changes nothing.

    Yields
    ------
    None
    """
    if options is None:
        yield
        return
    token = _overrides.set(dict(options))
    try:
        yield
    finally:
        _overrides.reset(token)


def getenv(name: str, default: str | None = None) -> str | None:
    """Return the task's value of ``name``, else the environment's, else ``default``.

    Parameters
    ----------
    name : str
        An environment variable (e.g. ``NETSIM_CACHE_DIR``).
    default : str, optional
        Returned when neither the task nor the environment sets it.

    Returns
    -------
    str or None
    """
    options = _overrides.get()
    if options is not None and name in options:
        return options[name]
    return os.environ.get(name, default)
