"""Ctrl-C and SIGTERM during a traced run (issue 29): exit 130, one line, and every
trace file written is finished and readable. The run is a subprocess in its own
session; the test always kills that group, so a failure leaves nothing running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from netsim.traces.reader import read_trace

TIMEOUT = 180


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_ends_a_traced_run_with_finished_traces(tmp_path, sig):
    trace = tmp_path / "t.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "netsim.cli", "run", "lcsys2022-heterogeneous", "--steps",
         "20000", "--trials", "400", "--estimators", "compensated", "--trace", str(trace),
         "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True, cwd=tmp_path)
    try:
        deadline = time.monotonic() + TIMEOUT
        while (len(list(tmp_path.glob("t.*.mcap"))) < 2 and proc.poll() is None
               and time.monotonic() < deadline):
            time.sleep(0.05)
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=TIMEOUT)
        assert proc.returncode == 130, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "interrupted" in lines[0] and "Traceback" not in err
        files = sorted(tmp_path.glob("t.*.mcap"), key=lambda p: p.stat().st_mtime)
        assert 2 <= len(files) < 400
        for f in [files[0], *files[-2:]]:  # the first and the last written
            t = read_trace(f)
            assert not t.damaged and not t.truncated and t.status is not None, f
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=TIMEOUT)
