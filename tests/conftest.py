import os
import sys
from pathlib import Path

# Small dense eigenproblems: one BLAS thread (see netsim/__init__.py). Set before numpy.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).parent))
