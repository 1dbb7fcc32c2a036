"""Integers beyond what the engines represent (issue 29): refused in one line naming
the key, and wherever a run is accepted, both engines agree."""

from __future__ import annotations

import os
import resource
import subprocess
import sys

import numpy as np
from netsim.models.scenario import MAX_DELAY_STEPS

from netsim.api import run
from netsim.cli import main

LIMIT = 4 * 1024 ** 3


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


def test_a_tau_beyond_the_largest_delay_is_one_line(capsys, tmp_path):
    assert main(["run", "lcsys2022-heterogeneous", "--tau", str(10 ** 20), "--steps", "5",
                 "--trials", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tau" in err[0] and str(MAX_DELAY_STEPS) in err[0]
    s = tmp_path / "s.toml"
    s.write_text('name = "big"\n[plant]\nA = [[0.5]]\nC = [[[1.0]], [[1.0]]]\nQ = 0.1\n'
                 'R = 0.1\n[network]\ntopology = "cycle"\nagents = 2\n[delays]\n'
                 f'model = "homogeneous"\ntau = {2 ** 63}\n')
    assert main(["run", str(s), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "delays.tau" in err[0] and "Traceback" not in err[0]


def test_analyze_a_huge_tau_max_is_refused_from_the_count():
    proc = subprocess.run([sys.executable, "-m", "netsim.cli", "analyze",
                           "lcsys2022-homogeneous", "--tau-max", str(10 ** 18)],
                          capture_output=True, text=True, timeout=120, preexec_fn=_limit,
                          env={**os.environ}, stdin=subprocess.DEVNULL)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("netsim analyze: error: --tau-max = ")


def test_both_engines_agree_at_the_largest_delay_bound():
    kw = dict(steps=40, trials=2, seed=3, estimators=["compensated", "uncompensated"])
    scenario = "lcsys2022-heterogeneous"
    from netsim.models.scenario import resolve_scenario

    sc = resolve_scenario(scenario).with_tau(MAX_DELAY_STEPS)
    a = run(sc, engine="events", **kw)
    b = run(sc, engine="vectorised", **kw)
    for fam in ("compensated", "uncompensated"):
        ea, eb = a[fam].squared_errors, b[fam].squared_errors
        assert ea.shape == eb.shape
        assert np.allclose(ea, eb, rtol=1e-9, atol=1e-12), fam
