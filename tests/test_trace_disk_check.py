"""The trace disk check (issue 29): a traced run that the disk cannot hold is refused
before anything is simulated, and the estimate it rests on bounds the real file size."""

from __future__ import annotations

import json
import os
from collections import namedtuple

from netsim.models.scenario import resolve_scenario

from netsim import budget
from netsim.cli import main

Usage = namedtuple("Usage", "total used free")


def test_a_trace_the_disk_cannot_hold_is_refused_first(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(budget.shutil, "disk_usage", lambda _p: Usage(10 ** 9, 0, 50_000))
    trace = tmp_path / "t.mcap"
    assert main(["run", "lcsys2022-heterogeneous", "--steps", "200", "--trials", "4",
                 "--trace", str(trace), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("netsim run: error: --trace ")
    assert "free on" in err[0]
    assert list(tmp_path.iterdir()) == []  # nothing written, nothing simulated


def test_the_trace_size_estimate_bounds_the_written_files(tmp_path, capsys):
    steps, trials = 150, 2
    trace = tmp_path / "t.mcap"
    assert main(["run", "lcsys2022-heterogeneous", "--steps", str(steps), "--trials",
                 str(trials), "--estimators", "compensated", "--trace", str(trace),
                 "--no-progress", "--json"]) == 0
    files = json.loads(capsys.readouterr().out)["traces"]
    written = sum(os.path.getsize(f) for f in files)
    estimate = budget.trace_bytes(resolve_scenario("lcsys2022-heterogeneous"), steps) * trials
    assert written <= estimate <= 50 * written, (written, estimate)
