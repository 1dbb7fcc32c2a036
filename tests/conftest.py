import os
import sys
import tempfile
from pathlib import Path

# Small dense eigenproblems: one BLAS thread (see netsim/__init__.py). Set before numpy.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).parent))
# The suite's own gain cache (netsim.gaincache), shared by its subprocesses: nothing
# is read from or written to the user's ~/.cache.
os.environ.setdefault("NETSIM_CACHE_DIR", tempfile.mkdtemp(prefix="netsim-test-gains-"))
