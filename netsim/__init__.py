"""netsim: discrete-event simulation of distributed estimation over delayed networks."""

import os as _os

# The analytics take eigenvalues of many small dense matrices (a few hundred rows),
# where a multithreaded BLAS is 10-100x slower than one thread on a busy 2-core
# machine. Only a default: a value set by the user wins. Must run before numpy loads.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__all__: list[str] = []
