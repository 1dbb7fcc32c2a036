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

# Property tests draw the same examples on every run (a fixed seed per test, no example
# database), so the default suite and CI cannot fail by luck of the draw;
# HYPOTHESIS_PROFILE=explore draws fresh examples each run for bug hunting.
from hypothesis import settings  # noqa: E402

settings.register_profile("default", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))
