"""The ``netsim`` command's entry point: one BLAS thread for the whole process.

The ``netsim`` command is netsim's own process, like the worker processes it starts
(:func:`netsim.threads.limit_worker_threads`), so the one-BLAS-thread rule of
:mod:`netsim.threads` can hold for its whole life. :func:`main` sets the standard
thread variables (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``,
``BLIS_NUM_THREADS``, ``VECLIB_MAXIMUM_THREADS``, ``NUMEXPR_NUM_THREADS``) to 1
*before numpy loads*, so the BLAS never starts the threads it would not be allowed to
use: numpy's import costs about 50 ms less CPU on the 2-core development machine, and
:func:`netsim.threads.single_threaded_blas` need not load threadpoolctl nor walk the
process's libraries (about 15 ms; issue 34). The worker processes the command starts
inherit the variables.

It changes nothing when the user has set any of these variables (their choice is
kept, and :func:`~netsim.threads.single_threaded_blas` limits the BLAS around the work
as in any other process), nor when numpy is already loaded (the variables would come
too late). ``import netsim`` and ``from netsim.cli import main`` (the Python API, a
notebook, tests) change no environment variable: only this entry point does.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

__all__ = ["THREAD_VARIABLES", "main"]

#: The environment variables the common BLAS and OpenMP runtimes read at load time.
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                    "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def _one_blas_thread() -> bool:
    """Set every thread variable to 1 unless the user set one or numpy is loaded:
    whether it did."""
    if "numpy" in sys.modules or any(name in os.environ for name in THREAD_VARIABLES):
        return False
    for name in THREAD_VARIABLES:
        os.environ[name] = "1"
    return True


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``netsim`` command (:func:`netsim.cli.main`) with one BLAS thread.

    Parameters
    ----------
    argv : sequence of str, optional
        The arguments after ``netsim``; default ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit code.
    """
    if _one_blas_thread():
        from netsim import threads

        threads.mark_process_single_threaded()
    from netsim.cli import main as cli_main

    return cli_main(argv)
