"""Graceful Ctrl-C: stop a run at the next step boundary, never inside a write.

A KeyboardInterrupt raised at an arbitrary bytecode can land inside the MCAP writer and
leave its bookkeeping inconsistent. :func:`graceful_interrupts` replaces the SIGINT and
SIGTERM handlers for the duration of a command: the first Ctrl-C (or ``kill``) only sets
a flag, which the kernel checks at the start of every step (:func:`check`) and turns
into a KeyboardInterrupt there (the command then finishes its traces and exits 130); a
second signal interrupts at once. A signal that comes after the last safe point still
ends the block with a KeyboardInterrupt (raised when the block is left), so a command
never swallows it.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["graceful_interrupts", "check", "requested"]

_requested = False


def requested() -> bool:
    """Whether a graceful stop has been requested."""
    return _requested


def check() -> None:
    """Raise KeyboardInterrupt if a graceful stop was requested (a safe point)."""
    if _requested:
        raise KeyboardInterrupt("interrupted by Ctrl-C")


@contextmanager
def graceful_interrupts() -> Iterator[None]:
    """Within the block, the first SIGINT or SIGTERM requests a stop at the next safe
    point."""
    global _requested
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):  # noqa: ARG001
        global _requested
        if _requested:
            raise KeyboardInterrupt("interrupted twice")
        _requested = True

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    _requested = False
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
        late = _requested
        _requested = False
        # a stop requested after the last safe point (e.g. while the last trace was being
        # finished) is still a stop: the work is complete, but the command ends as
        # interrupted (exit 130), never silently with exit 0
        if late and sys.exc_info()[0] is None:
            raise KeyboardInterrupt("interrupted by Ctrl-C after the last step")
