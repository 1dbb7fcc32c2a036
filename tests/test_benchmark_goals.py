"""benchmarks/goals.py starts and refuses unknown rows (no measurement is run: timings
are never asserted)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "goals.py"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True,
                          text=True, timeout=60)


def test_help_names_every_part_and_option():
    proc = _run("--help")
    assert proc.returncode == 0, proc.stderr
    for word in ("--quick", "--only", "--json", "startup", "engine", "cold", "million",
                 "NETSIM_NUMBA=1"):
        assert word in proc.stdout, word


def test_only_rejects_an_unknown_row_in_one_line():
    proc = _run("--only", "startup,bogus-row")
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--only" in lines[0] and "'bogus-row'" in lines[0], lines
