"""netsim run --trace, inspect, replay, analyze TRACE, plot: the command-line path."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from netsim.traces.reader import read_trace

from netsim.cli import main


@pytest.fixture(scope="module")
def traced(tmp_path_factory):
    folder = tmp_path_factory.mktemp("traces")
    base = folder / "run.mcap"
    code = main(["run", "lcsys2022-heterogeneous", "--tau", "3", "--trials", "1", "--steps",
                 "150", "--estimators", "compensated,uncompensated", "--trace", str(base),
                 "--no-progress", "--json"])
    assert code == 0
    return folder


def test_run_writes_one_trace_per_estimator_and_trial(traced, capsys):
    files = sorted(p.name for p in traced.glob("*.mcap"))
    assert files == ["run.compensated.trial0.mcap", "run.uncompensated.trial0.mcap"]
    trace = read_trace(traced / "run.compensated.trial0.mcap")
    assert trace.family == "compensated" and not trace.truncated
    assert trace.status["status"] == "complete"


def test_inspect_replay_analyze_plot(traced, capsys):
    comp = str(traced / "run.compensated.trial0.mcap")
    unc = str(traced / "run.uncompensated.trial0.mcap")
    assert main(["inspect", comp, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info and "links" in json.dumps(info)
    assert main(["replay", comp, "--json"]) == 0
    replay = json.loads(capsys.readouterr().out)
    assert replay["exact"]["reproduces"] is True
    assert replay["exact"]["max_rel_deviation"] < 1e-9
    assert replay["paper"]["reproduces"] is False
    assert main(["replay", unc]) == 0
    text = capsys.readouterr().out
    assert "proportional to the state" in text or "(A^(r+1) - A)" in text
    assert main(["analyze", comp, "--json"]) == 0
    analysis = json.loads(capsys.readouterr().out)
    assert analysis["rho_delay_free"] < 1
    png = traced / "plot.png"
    assert main(["plot", comp, unc, "-o", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("content", [b"not an mcap file at all", b""])
def test_foreign_or_corrupt_file_is_one_line_and_nonzero(tmp_path, capsys, content):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    for command in ("inspect", "replay", "analyze"):
        assert main([command, str(bad)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "bad.mcap" in err[0] and "Traceback" not in err[0]


@pytest.mark.parametrize("trace_format, engine, size", [
    # the vectorised engine writes format 2 in bulk once the batch is done (60,000 steps,
    # about 50 MB, in under a second): interrupted while it writes, once its first
    # chunks are in the file
    ("2", "vectorised", 2_000_000),
    # the event kernel writes format 3 step by step (a chunk every 25 steps) while it runs
    ("3", "events", 100_000),
])
def test_ctrl_c_mid_run_leaves_a_finished_file_and_exits_nonzero(tmp_path, trace_format,
                                                                engine, size):
    trace = tmp_path / "long.mcap"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "netsim.cli", "run", "lcsys2022-time-varying", "--trials", "1",
         "--steps", "60000", "--estimators", "compensated", "--trace", str(trace),
         "--trace-format", trace_format, "--engine", engine, "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    deadline = time.time() + 60
    while not trace.exists() and time.time() < deadline:
        time.sleep(0.05)
    assert trace.exists(), "the run never started writing its trace"
    while (trace.stat().st_size < size and proc.poll() is None
           and time.time() < deadline):
        time.sleep(0.002)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    recorded = read_trace(trace)
    assert not recorded.truncated  # finished and indexed
    assert recorded.status["status"] == "interrupted"
    assert 0 < len(recorded.steps) < 60001
