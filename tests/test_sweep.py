"""Sweeps: keys, streaming, resumption, and identical results on every executor."""

from __future__ import annotations

import json

import pytest
from helpers import lcsys

from netsim.sweep import (
    SweepInterrupted,
    cell_key,
    demo_cell,
    grid,
    read_results,
    run_sweep,
)

CELLS = grid(scale=[1.0, 2.0, 3.0], n=[50, 80], sleep=0.0)


def test_grid_and_keys():
    cells = grid(tau=[0, 3], delays=["homogeneous", "time-varying"], seed=7)
    assert cells[:2] == [{"tau": 0, "delays": "homogeneous", "seed": 7},
                         {"tau": 0, "delays": "time-varying", "seed": 7}]
    assert len(cells) == 4
    a = cell_key({"tau": 3, "delays": "homogeneous"}, 1, "s")
    assert a == cell_key({"delays": "homogeneous", "tau": 3}, 1, "s")  # order-free
    assert len(a) == 16 and int(a, 16) >= 0
    assert a != cell_key({"tau": 3, "delays": "homogeneous"}, 2, "s")  # root seed
    assert a != cell_key({"tau": 3, "delays": "homogeneous"}, 1, "t")  # sweep name
    assert a != cell_key({"tau": 4, "delays": "homogeneous"}, 1, "s")


def test_serial_and_local_pool_give_identical_results(tmp_path):
    serial = run_sweep(demo_cell, CELLS, root_seed=5, executor="serial", progress=False,
                       results=tmp_path / "serial.jsonl")
    pool = run_sweep(demo_cell, reversed(CELLS), root_seed=5, executor="local", workers=2,
                     progress=False, results=tmp_path / "pool.jsonl",
                     csv_path=tmp_path / "pool.csv")
    by_key = {r["key"]: r["result"] for r in pool.rows}
    assert [by_key[r["key"]] for r in serial.rows] == serial.results()
    assert serial.computed == pool.computed == len(CELLS)
    # the JSON-lines file holds every cell; the CSV is one table in cell order
    assert set(read_results(tmp_path / "pool.jsonl")) == set(by_key)
    lines = (tmp_path / "pool.csv").read_text().splitlines()
    assert lines[0].split(",")[:4] == ["key", "n", "scale", "sleep"]  # params sorted
    assert len(lines) == len(CELLS) + 1
    assert [line.split(",")[0] for line in lines[1:]] == [r["key"] for r in pool.rows]
    # different root seed, different numbers
    other = run_sweep(demo_cell, CELLS, root_seed=6, executor="serial", progress=False)
    assert other.results() != serial.results()


def test_interrupted_sweep_resumes_computing_only_the_missing_cells(tmp_path):
    path = tmp_path / "rows.jsonl"
    cells = grid(scale=[1.0, 2.0, 3.0, 4.0], n=[30, 60], sleep=0.05)
    with pytest.raises(SweepInterrupted) as info:
        run_sweep(demo_cell, cells, root_seed=1, executor="local", workers=2,
                  progress=False, results=path, stop_after=3)
    assert info.value.done == 3 and info.value.total == 8
    assert len(read_results(path)) == 3
    resumed = run_sweep(demo_cell, cells, root_seed=1, executor="local", workers=2,
                        progress=False, results=path)
    assert resumed.reused == 3 and resumed.computed == 5
    fresh = run_sweep(demo_cell, cells, root_seed=1, executor="serial", progress=False)
    assert resumed.results() == fresh.results()
    again = run_sweep(demo_cell, cells, root_seed=1, executor="local", workers=2,
                      progress=False, results=path)
    assert again.computed == 0 and again.reused == 8
    assert again.results() == fresh.results()


def test_keyboard_interrupt_keeps_finished_cells_and_a_cut_line_is_repaired(tmp_path):
    path = tmp_path / "rows.jsonl"
    seen = []

    def stop(row):
        seen.append(row)
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(SweepInterrupted, match="2 of 6 cells finished"):
        run_sweep(demo_cell, CELLS, executor="serial", progress=False, results=path,
                  on_row=stop)
    # a writer killed mid-line leaves a partial last line: it is cut off on resume
    with open(path, "a") as f:
        f.write('{"key": "abc", "params": {"sc')
    resumed = run_sweep(demo_cell, CELLS, executor="serial", progress=False, results=path)
    assert resumed.reused == 2 and resumed.computed == 4
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert len(rows) == 6 and path.read_text().endswith("\n")


def test_context_is_passed_and_bad_arguments_rejected(tmp_path):
    one = run_sweep(demo_cell, CELLS[:2], executor="serial", progress=False, context=None)
    ten = run_sweep(demo_cell, CELLS[:2], executor="serial", progress=False, context=10.0)
    assert ten.results()[0]["std"] == pytest.approx(10 * one.results()[0]["std"])
    with pytest.raises(ValueError, match="unknown executor"):
        run_sweep(demo_cell, CELLS, executor="threads", progress=False)
    with pytest.raises(ValueError, match="workers"):
        run_sweep(demo_cell, CELLS, workers=0, progress=False)
    bad = tmp_path / "bad.jsonl"
    bad.write_text("not json\n")
    with pytest.raises(ValueError, match="bad.jsonl, line 1"):
        run_sweep(demo_cell, CELLS, executor="serial", progress=False, results=bad)


@pytest.fixture(scope="module")
def dask_cluster():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
    yield cluster
    cluster.close()


def test_the_same_sweep_is_identical_on_the_local_pool_and_dask(tmp_path, dask_cluster):
    """A benchmark sweep (tiny Monte Carlo cells of the delay-tolerance benchmark, with
    random time-varying delays) on 2 local processes and on a 2-worker Dask LocalCluster."""
    from netsim.bench import delay_tolerance_cell
    from netsim.runner import scenario_gains

    scenario = lcsys()
    context = {"scenario": scenario, "gains": scenario_gains(scenario)}
    cells = [{"kind": "mc", "setting": s, "tau": t, "family": f, "trials": 2, "steps": 30,
              "seed": 3}
             for s in ("heterogeneous", "time-varying") for t in (2, 4)
             for f in ("compensated", "uncompensated")]
    local = run_sweep(delay_tolerance_cell, cells, root_seed=3, executor="local", workers=2,
                      context=context, progress=False, results=tmp_path / "local.jsonl")
    dask = run_sweep(delay_tolerance_cell, cells, root_seed=3,
                     dask_address=dask_cluster.scheduler_address, context=context,
                     progress=False, results=tmp_path / "dask.jsonl")
    assert dask.executor == "dask" and dask.computed == len(cells)
    assert local.results() == dask.results()
    assert {r["worker"] for r in dask.rows} and all(r["result"]["measured"]["curve"]
                                                    for r in dask.rows)
    # resuming on the other executor recomputes nothing
    again = run_sweep(delay_tolerance_cell, cells, root_seed=3, executor="local",
                      context=context, progress=False, results=tmp_path / "dask.jsonl")
    assert again.computed == 0 and again.results() == local.results()


def test_a_scenario_sweep_runs_every_requested_family_listed_or_not(tmp_path, capsys):
    """--estimators names what runs: a family the scenario does not list (local-kf) is
    not dropped because another one (compensated) is listed."""
    from netsim.cli import main

    code = main(["bench", "sweep", "lcsys2022-heterogeneous", "--estimators",
                 "compensated,local-kf", "--taus", "0", "--delays", "homogeneous",
                 "--trials", "1", "--steps", "10", "--out", str(tmp_path / "rows.jsonl"),
                 "--json", "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0
    rows = json.loads(out)["rows"]
    assert rows and all(set(r["result"]["estimators"]) == {"compensated", "local-kf"}
                        for r in rows)
