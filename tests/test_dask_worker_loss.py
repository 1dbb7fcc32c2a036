"""A sweep on a real Dask cluster survives the loss of a worker (issue 29).

A ``dask scheduler`` and two ``dask worker`` processes (each without a nanny, so a
killed worker stays dead) on the loopback interface; the sweep runs cells that take a
fraction of a second each, one worker is killed once rows have started to arrive, and the
sweep must finish with exactly the rows of a serial sweep. Every process runs in its own
session and is killed, whatever happens, when the test ends.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from helpers import kill_process, start_process

from netsim.sweep import demo_cell, grid, run_sweep

TIMEOUT = 180
CELLS = grid(scale=[1.0, 2.0, 3.0, 4.0], n=[40, 60, 80], sleep=0.4)


def _start(argv: list[str], log: Path) -> subprocess.Popen[bytes]:
    return start_process(argv, log)


def _kill(proc: subprocess.Popen[bytes]) -> None:
    kill_process(proc, TIMEOUT)


def _wait(condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


def test_a_sweep_finishes_with_the_serial_rows_after_a_worker_dies(tmp_path):
    pytest.importorskip("distributed")
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    info = tmp_path / "scheduler.json"
    procs = [_start([*dask, "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                     "--scheduler-file", str(info)], tmp_path / "scheduler.log")]
    try:
        _wait(lambda: info.is_file() and info.stat().st_size > 0, "the scheduler")
        for name in ("w1", "w2"):
            procs.append(_start([sys.executable, "-m", "distributed.cli.dask_worker",
                                 "--scheduler-file", str(info), "--nthreads", "1",
                                 "--no-nanny", "--no-dashboard", "--name", name],
                                tmp_path / f"{name}.log"))
        address = json.loads(info.read_text())["address"]
        from distributed import Client

        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=TIMEOUT)
            results = tmp_path / "dask.jsonl"
            done: dict[str, object] = {}

            def sweep() -> None:
                try:
                    done["sweep"] = run_sweep(demo_cell, CELLS, root_seed=11,
                                              dask_address=client, progress=False,
                                              results=results)
                except BaseException as exc:  # noqa: BLE001 - reported by the test
                    done["error"] = exc

            thread = threading.Thread(target=sweep, daemon=True)
            thread.start()
            _wait(lambda: results.is_file() and results.read_text().count("\n") >= 2
                  or not thread.is_alive(), "the first rows")
            assert thread.is_alive(), "the sweep finished before a worker could be killed"
            _kill(procs[1])  # worker w1 dies mid-sweep
            thread.join(TIMEOUT)
            assert not thread.is_alive(), "the sweep did not finish after the worker died"
        assert "error" not in done, done.get("error")
        serial = run_sweep(demo_cell, CELLS, root_seed=11, executor="serial",
                           progress=False, results=tmp_path / "serial.jsonl")
        finished = done["sweep"]
        assert finished.computed == len(CELLS)
        assert finished.results() == serial.results()
        workers = {r["worker"] for r in finished.rows}
        assert len(workers) >= 1
    finally:
        for proc in reversed(procs):
            _kill(proc)
