"""Sweeps on a Dask cluster whose workers are set up as on other machines (issue 34).

A ``dask scheduler`` and two ``dask worker`` processes, each worker started in a folder
of its own with its own HOME and NETSIM_CACHE_DIR and without the client's folder (where
the plugin estimator's module file is) on its path. Checked:

* a sweep with a plugin estimator (``module:attribute`` of a file beside the scenario
  in the client's folder) and a built-in one gives exactly the rows of a serial sweep;
* the gains are designed once, on the client: the workers' cache folders stay empty;
* the client's options (``--no-cache``, the memory limit) reach the tasks;
* a worker that runs another netsim version is refused before anything is submitted:
  one line naming it and both versions, exit 2.

Every process runs in its own session and is killed (its process group) whatever
happens. No timing is asserted.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from helpers import kill_process, start_process

import netsim
from netsim.sweep import (
    WorkerVersionMismatch,
    environment_cell,
    grid,
    run_sweep,
    version_mismatches,
)

TIMEOUT = 120
ROOT = Path(__file__).resolve().parents[1]
PLUGIN = "ci_plugin_for_dask_test"  # a module name found nowhere else
FAKE_VERSION_ENV = "NETSIM_TEST_FAKE_VERSION"
PRELOAD = f'''"""Test preload: pretend to be another netsim version."""
import os

import netsim

if os.environ.get("{FAKE_VERSION_ENV}"):
    netsim.__version__ = os.environ["{FAKE_VERSION_ENV}"]
'''


def _start(argv: list[str], log: Path, cwd: Path, env: dict[str, str]
           ) -> subprocess.Popen[bytes]:
    return start_process(argv, log, cwd, env)


def _kill(proc: subprocess.Popen[bytes]) -> None:
    kill_process(proc, TIMEOUT)


def _wait(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + TIMEOUT
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


def _clean_env(home: Path, **extra: str) -> dict[str, str]:
    """An environment as on another machine: no NETSIM_*, XDG or PYTHONPATH of ours."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("NETSIM_", "XDG_")) and k not in ("PYTHONPATH", "HOME")}
    return {**env, "HOME": str(home), **extra}


class Cluster:
    """A scheduler and its workers; :meth:`worker` starts one in a folder of its own."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.procs: list[subprocess.Popen[bytes]] = []
        self.info = root / "scheduler.json"
        self.preload = root / "preload" / "fake_netsim_version.py"
        self.preload.parent.mkdir(parents=True)
        self.preload.write_text(PRELOAD)
        where = root / "scheduler"
        where.mkdir()
        self.procs.append(_start(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
             "--port", "0", "--no-dashboard", "--scheduler-file", str(self.info)],
            root / "scheduler.log", where, _clean_env(where)))
        _wait(lambda: self.info.is_file() and self.info.stat().st_size > 0, "the scheduler")
        self.address: str = json.loads(self.info.read_text())["address"]

    def worker(self, name: str, **env: str) -> Path:
        """Start worker ``name`` in ``root/name`` (HOME and NETSIM_CACHE_DIR inside);
        return its cache folder."""
        where = self.root / name
        (where / "home").mkdir(parents=True)
        cache = where / "cache"
        self.procs.append(_start(
            [sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file",
             str(self.info), "--nthreads", "1", "--no-nanny", "--no-dashboard", "--name",
             name, "--preload", str(self.preload)],
            self.root / f"{name}.log", where,
            _clean_env(where / "home", NETSIM_CACHE_DIR=str(cache), **env)))
        return cache

    def close(self) -> None:
        for proc in reversed(self.procs):
            _kill(proc)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    pytest.importorskip("distributed")
    made = Cluster(tmp_path / "cluster")
    try:
        yield made
    finally:
        made.close()


def _entries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file()] if folder.exists() else []


def test_a_plugin_sweep_on_foreign_workers_matches_serial_with_gains_designed_once(
        cluster: Cluster, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from distributed import Client

    from netsim import runner
    from netsim.bench.scenario_sweep import run_scenario_sweep

    caches = [cluster.worker(name) for name in ("w1", "w2")]
    client_dir = tmp_path / "client"
    client_dir.mkdir()
    shutil.copy(ROOT / "examples" / "consensus_on_information.py",
                client_dir / f"{PLUGIN}.py")
    toml = (ROOT / "examples" / "consensus-on-information.toml").read_text()
    scenario = client_dir / "ci.toml"
    scenario.write_text(toml.replace('"consensus_on_information:', f'"{PLUGIN}:'))
    monkeypatch.chdir(client_dir)
    monkeypatch.delenv("NETSIM_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "client-xdg"))
    client_cache = tmp_path / "client-xdg" / "netsim" / "gains"
    designs: list[str] = []
    design = runner.scenario_gains

    def counted(scenario):  # noqa: ANN001, ANN202 - a wrapper
        designs.append(scenario.name)
        return design(scenario)

    monkeypatch.setattr(runner, "scenario_gains", counted)
    sweep = dict(axes={"agents": [4, 5], "tau": [0, 2]}, trials=2, steps=30,
                 families=["compensated", f"{PLUGIN}:ConsensusOnInformation"], seed=5,
                 progress=False, engine="events")
    with Client(cluster.address, timeout="60s") as client:
        client.wait_for_workers(2, timeout=TIMEOUT)
        # the plugin is nowhere on the workers' path
        found = client.run(lambda: __import__("importlib.util").util.find_spec(PLUGIN))
        assert set(found.values()) == {None}
        dask = run_scenario_sweep(str(scenario), dask_address=client,
                                  results=tmp_path / "dask.jsonl", **sweep)
    assert dask.executor == "dask" and dask.computed == 4
    assert len(designs) == 2  # one design per network size, on the client
    assert len(_entries(client_cache)) == 2
    for cache in caches:
        assert _entries(cache) == [], f"a worker designed gains: {_entries(cache)}"
    assert {r["worker"].split(":")[-1] for r in dask.rows} != {str(os.getpid())}
    for row in dask.rows:
        estimators = row["result"]["estimators"]
        assert set(estimators) == {"compensated", "ci-filter"}, row["result"]
    serial = run_scenario_sweep(str(scenario), executor="serial",
                                results=tmp_path / "serial.jsonl", **sweep)
    assert [r["key"] for r in serial.rows] == [r["key"] for r in dask.rows]
    assert serial.results() == dask.results()


def test_the_clients_options_reach_the_tasks_and_a_foreign_version_is_refused(
        cluster: Cluster, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from distributed import Client

    from netsim import gaincache
    from netsim.cli import main

    caches = {name: cluster.worker(name) for name in ("w1", "w2")}
    monkeypatch.delenv("NETSIM_CACHE_DIR", raising=False)
    monkeypatch.setenv("NETSIM_MEMORY_LIMIT", "3GiB")
    cells = grid(n=[1, 2, 3, 4])
    with Client(cluster.address, timeout="60s") as client:
        client.wait_for_workers(2, timeout=TIMEOUT)
        mine = run_sweep(environment_cell, cells, dask_address=client, progress=False)
        with gaincache.disabled():
            fresh = run_sweep(environment_cell, cells, dask_address=client, progress=False)
    seen = {r["result"]["cache_dir"] for r in mine.rows}
    assert seen <= {str(c) for c in caches.values()}  # unset here: each worker's own
    for row in mine.rows + fresh.rows:
        assert row["result"]["memory_limit_source"] == "NETSIM_MEMORY_LIMIT"
        assert row["result"]["memory_limit"] == 3 << 30
        assert row["result"]["workers"] == 1
        assert row["result"]["netsim"] == netsim.__version__
    assert {r["result"]["cache_dir"] for r in fresh.rows} == {None}  # --no-cache

    other = "0.0.0+other"
    cluster.worker("w3", **{FAKE_VERSION_ENV: other})
    with Client(cluster.address, timeout="60s") as client:
        client.wait_for_workers(3, timeout=TIMEOUT)
        with pytest.raises(WorkerVersionMismatch) as refused:
            run_sweep(environment_cell, cells, dask_address=client, progress=False)
    assert "worker w3 (tcp://" in str(refused.value)
    assert f"runs netsim {other}, this client netsim {netsim.__version__}" in str(refused.value)
    out = tmp_path / "refused.jsonl"
    code = main(["bench", "sweep", "lcsys2022-heterogeneous", "--sizes", "4", "--trials", "1",
                 "--steps", "5", "--out", str(out), "--no-progress", "--dask",
                 cluster.address])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "w3" in lines[0] and other in lines[0] \
        and netsim.__version__ in lines[0], err
    assert not out.exists() or out.read_text() == ""


def test_version_mismatches_names_the_worker_and_both_versions() -> None:
    found = {"tcp://10.0.0.2:4000": "1.0", "tcp://10.0.0.1:4000": "0.9",
             "tcp://10.0.0.3:4000": ModuleNotFoundError("No module named 'netsim'")}
    names = {"tcp://10.0.0.1:4000": "gpu-1", "tcp://10.0.0.3:4000": "tcp://10.0.0.3:4000"}
    message = version_mismatches(found, "1.0", names)
    assert message == ("worker gpu-1 (tcp://10.0.0.1:4000) runs netsim 0.9, this client "
                       "netsim 1.0 (and 1 more); install the same netsim on every worker")
    only = version_mismatches({"tcp://10.0.0.3:4000": found["tcp://10.0.0.3:4000"]}, "1.0")
    assert only is not None and only.startswith("worker tcp://10.0.0.3:4000 cannot import "
                                                "netsim (ModuleNotFoundError")
    assert version_mismatches({"tcp://10.0.0.2:4000": "1.0"}, "1.0") is None
    assert version_mismatches({}, "1.0") is None
