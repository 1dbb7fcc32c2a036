"""Delay sources: file-backed delay distributions that a higher layer reads for ``models``.

A scenario's ``[links] delay = { distribution = "trace", file = "earlier.mcap" }`` needs
an MCAP trace read back, which is :mod:`netsim.traces`' job; ``models`` must not import
``traces``. So ``models`` only keeps this registry: a *delay source* is a loader
``path -> distribution`` registered under the distribution's name, and
:func:`netsim.models.linkmodels.load_trace_replay` calls the ``"trace"`` source. The
``netsim`` package registers it when it is imported (which happens before any
``netsim.models`` module loads); the loader imports :mod:`netsim.traces` only when called.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["delay_source", "register_delay_source"]

_SOURCES: dict[str, Callable[[str | Path], Any]] = {}


def register_delay_source(name: str, loader: Callable[[str | Path], Any]) -> None:
    """Register (or replace) the loader of the file-backed delay distribution ``name``.

    Parameters
    ----------
    name : str
        The ``distribution`` value of a ``[links] delay`` table, e.g. ``"trace"``.
    loader : callable
        ``loader(path)`` returns the distribution read from ``path``; it raises
        ``ValueError`` (naming the file) when the file cannot be used.
    """
    _SOURCES[str(name)] = loader


def delay_source(name: str) -> Callable[[str | Path], Any]:
    """Return the loader registered for the delay distribution ``name``.

    Raises
    ------
    ValueError
        If no loader is registered under ``name``.
    """
    try:
        return _SOURCES[name]
    except KeyError:
        raise ValueError(f"no reader is registered for {name!r} delays "
                         "(netsim.models.delaysources.register_delay_source)") from None
