"""Every count goes through the budget (issue 29): a fusion run's trials, a sweep's
sizes and the claims' instances are refused from the counts alone, before anything is
built, in one line naming the option, the estimate and the limit.

Each case runs in a subprocess under a 4 GB address-space limit: a refusal that came
only after building the request would run out of memory or time there instead.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys

import pytest

LIMIT = 4 * 1024 ** 3


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


@pytest.mark.parametrize("argv, option", [
    (["fusion", "run", "dkfe-example1", "--trials", "1000000000"], "--trials"),
    (["fusion", "run", "dkfe-example2", "--trials", "100000", "--steps", "1000000"],
     "--trials"),
    (["bench", "sweep", "lcsys2022-heterogeneous", "--sizes", "1000000000", "--trials",
      "1", "--steps", "10", "--out", "OUT"], "--sizes"),
    (["claims", "L-theorem1", "--instances", "100000000000"], "--instances"),
], ids=["fusion-trials", "fusion-steps", "sweep-sizes", "claims-instances"])
def test_huge_counts_are_refused_in_one_line_before_anything_is_built(argv, option,
                                                                      tmp_path):
    out = tmp_path / "r.jsonl"
    argv = [str(out) if a == "OUT" else a for a in argv]
    proc = subprocess.run([sys.executable, "-m", "netsim.cli", *argv], capture_output=True,
                          text=True, timeout=120, preexec_fn=_limit, cwd=tmp_path,
                          env={**os.environ, "NETSIM_CACHE_DIR": "off"},
                          stdin=subprocess.DEVNULL)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith(f"netsim {argv[0]}: error: {option} = ")
    assert "about" in lines[0] and ("more than" in lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written
