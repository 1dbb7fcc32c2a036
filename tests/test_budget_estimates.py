"""The budget's memory estimates against the measured peak (issue 29).

A run in a fresh process: after a warm-up (imports, gains, lazy caches), the growth of
the peak resident set during one vectorised Monte Carlo run must not exceed the budget's
estimate (the estimate is what refusals rest on: an underestimate lets a run exhaust the
machine), and the estimate must stay within a stated factor of it (not so pessimistic
that it refuses what fits). Measured here: estimate / growth 1.7-2.7.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

#: Largest accepted ratio estimate / measured growth.
PESSIMISM = 8.0

SCRIPT = """
import json, resource, sys
from netsim import budget
from netsim.models.scenario import resolve_scenario
from netsim.runner import run_monte_carlo, scenario_gains
sc = resolve_scenario(sys.argv[1])
steps, trials = int(sys.argv[2]), int(sys.argv[3])
g = scenario_gains(sc)
run_monte_carlo(sc, steps=5, trials=1, families=["compensated"], gains=g,
                engine="vectorised")
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
run_monte_carlo(sc, steps=steps, trials=trials, families=["compensated"], gains=g,
                engine="vectorised")
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"growth": peak - base,
                  "estimate": budget.run_bytes(sc, steps, trials, "vectorised")[0]}))
"""


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> str:
    return str(tmp_path_factory.mktemp("gains"))


@pytest.mark.parametrize("scenario, steps, trials", [
    ("lcsys2022-heterogeneous", 5000, 100),
    ("lcsys2022-time-varying", 4000, 100),
    ("lcsys2022-homogeneous", 20000, 20),
])
def test_the_vectorised_run_estimate_bounds_the_measured_peak(scenario, steps, trials,
                                                              cache):
    proc = subprocess.run([sys.executable, "-c", SCRIPT, scenario, str(steps), str(trials)],
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ, "NETSIM_CACHE_DIR": cache})
    assert proc.returncode == 0, proc.stderr
    m = json.loads(proc.stdout.strip().splitlines()[-1])
    assert m["growth"] > 20e6  # the run is big enough to measure
    assert m["growth"] <= m["estimate"] <= PESSIMISM * m["growth"], m
