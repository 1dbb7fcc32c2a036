"""netsim bench: the delay-tolerance benchmark and scenario sweeps (tiny runs)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from helpers import lcsys

from netsim import bench
from netsim.bench import (
    DELAY_SETTINGS,
    FAMILIES,
    PRESETS,
    _verdict,
    add_bench_parser,
    cmd_bench,
    main,
)

TINY = ["--trials", "2", "--steps", "40", "--taus", "0,3", "--workers", "1", "--no-progress"]


@pytest.fixture(scope="module")
def tiny_json(tmp_path_factory):
    """The lcsys2022-fig1 preset, 2 trials x 40 steps, taus 0 and 3, as JSON (+ plot)."""
    out = tmp_path_factory.mktemp("bench")
    results = out / "cells.jsonl"
    plot = out / "bench.png"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["delay-tolerance", "lcsys2022-fig1", *TINY, "--json", "--plot", str(plot),
                     "--resume", str(results)])
    assert code == 0
    return json.loads(buf.getvalue()), results, plot


def test_json_holds_every_cell(tiny_json):
    data, results, plot = tiny_json
    settings = list(PRESETS["lcsys2022-fig1"].delays)
    assert list(data["settings"]) == settings and data["taus"] == [0, 3]
    cells = {(c["setting"], c["tau"], c["family"]) for c in data["cells"]}
    assert cells == {(s, t, f) for s in settings for t in (0, 3) for f in FAMILIES}
    assert len(data["cells"]) == len(settings) * 2 * len(FAMILIES)
    for c in data["cells"]:
        m, a = c["measured"], c["analytics"]
        assert m["verdict"] in ("stable", "diverging", "unbounded", "undecided", "diverged")
        assert c["verdict"] in ("stable", "diverging", "unbounded", "undecided", "diverged",
                                "bound violated", "prediction contradicted",
                                "bound conservative")
        # a steady MSE belongs to stable runs only; every run has its last trusted MSE
        assert ("steady_state_mse" in m) == (m["verdict"] == "stable")
        assert "last_trusted_mse" in m and "decay_factor" in m
        if c["family"] != "centralized-kf":
            assert a["bound_eq26"] > 0 and a["bound_tolerant"] > 0 and a["exact"] is not None
    het = next(c for c in data["cells"] if c["setting"] == "heterogeneous" and c["tau"] == 3
               and c["family"] == "compensated")
    assert set(het["analytics"]["realised_delays"]) == {"0->1", "1->2", "2->3", "3->0"}
    assert data["analysis"]["tau_star"] is not None
    assert {t["family"] for t in data["tolerance"]} == {"compensated", "uncompensated", "block"}
    assert data["claims"] and all(c["status"] for c in data["claims"])
    assert data["run"]["cells_computed"] > 0
    assert plot.exists() and plot.stat().st_size > 10000


def test_text_table_and_resume(tiny_json, capsys):
    data, results, _ = tiny_json
    code = main(["delay-tolerance", "lcsys2022-fig1", *TINY, "--resume", str(results)])
    out = capsys.readouterr().out
    assert code == 0
    assert "delays: homogeneous" in out and "delays: heterogeneous" in out
    assert "largest tolerated delay" in out and "the papers' statements" in out
    assert f"0 cells computed, {data['run']['cells_computed']} reused" in out
    for family in ("compensated", "uncompensated", "block", "kf (reference)"):
        assert family in out
    # the uncompensated estimator diverges on this unstable plant as soon as tau > 0,
    # which the delay-tolerant paper's Theorem 1 says cannot happen: reported as such
    unc = next(c for c in data["cells"] if c["setting"] == "homogeneous" and c["tau"] == 3
               and c["family"] == "uncompensated")
    if unc["measured"]["verdict"] in ("diverging", "diverged"):
        assert unc["verdict"] == "prediction contradicted"
        assert any("uncompensated, homogeneous, tau 3" in d for d in data["disagreements"])


def test_cell_agrees_with_netsim_run(tiny_json):
    """A benchmark cell uses netsim run's trial seeds and definitions."""
    from netsim.models.scenario import DelaySpec

    from netsim.runner import run_monte_carlo, scenario_gains

    data, _, _ = tiny_json
    scenario = lcsys()
    variant = scenario.with_tau(3)
    assert variant.delays == DelaySpec("heterogeneous", 3, {}, 0, scenario.delays.seed)
    result = run_monte_carlo(variant, steps=40, trials=2, seed=scenario.seed,
                             families=["compensated"], gains=scenario_gains(scenario))
    mc = result.estimators["compensated"]
    cell = next(c for c in data["cells"] if c["setting"] == "heterogeneous" and c["tau"] == 3
                and c["family"] == "compensated")
    assert cell["measured"]["steady_state_mse"] == mc.steady_state_mse
    assert cell["measured"]["last_trusted_mse"] == mc.last_trusted_mse
    assert cell["measured"]["verdict"] == mc.verdict
    assert cell["analytics"]["exact"] == pytest.approx(result.analytics["rho_exact_compensated"])


def test_verdict_rules():
    def cell(measured, predicted, exact=None, bound=0.9):
        m = {"verdict": measured}
        a = {"predicted_stable": predicted, "exact": exact, "bound": bound,
             "exact_violates_bound": exact is not None and exact > bound}
        return m, a

    assert _verdict("compensated", *cell("stable", True)) == "stable"
    assert _verdict("compensated", *cell("diverging", False)) == "diverging"
    assert _verdict("compensated", *cell("diverged", True)) == "prediction contradicted"
    assert _verdict("compensated", *cell("diverging", True)) == "prediction contradicted"
    assert _verdict("compensated", *cell("undecided", True)) == "undecided"
    assert _verdict("compensated", *cell("stable", False)) == "bound conservative"
    assert _verdict("compensated", *cell("stable", True, exact=0.95)) == "bound violated"
    assert _verdict("centralized-kf", {"verdict": "stable"}, {}) == "stable"


@pytest.mark.parametrize("argv, message", [
    (["delay-tolerance", "lcsys2022-fig1", "--taus", "0,x"], "--taus"),
    (["delay-tolerance", "lcsys2022-fig1", "--taus", "-1"], "--taus"),
    (["delay-tolerance", "lcsys2022-fig1", "--delays", "sometimes"], "--delays"),
    (["delay-tolerance", "lcsys2022-fig1", "--estimators", "oracle"], "--estimators"),
    (["delay-tolerance", "lcsys2022-fig1", "--trials", "0"], "--trials"),
    (["delay-tolerance", "lcsys2022-fig1", "--plot", "out.pdf"], "--plot"),
    (["delay-tolerance", "no-such-scenario"], "no-such-scenario"),
    (["delay-tolerance", "lcsys2022-fig1", "--workers", "0"], "--workers"),
    (["sweep", "lcsys2022-heterogeneous", "--out", "x.jsonl", "--sizes", "1"], "--sizes"),
])
def test_bad_input_exits_2_with_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_parser_registration():
    from netsim.cli import CommandError

    parser = argparse.ArgumentParser(prog="netsim")
    sub = parser.add_subparsers(dest="command")
    add_bench_parser(sub)
    args = parser.parse_args(["bench", "delay-tolerance", "delay-tolerant-fig2", "--json"])
    assert args.bench_command == "delay-tolerance" and args.json and args.workers == 2
    with pytest.raises(CommandError, match="name a benchmark"):
        cmd_bench(parser.parse_args(["bench"]))
    assert set(PRESETS) == {"lcsys2022-fig1", "lcsys2022-baselines", "delay-tolerant-fig1",
                            "delay-tolerant-fig2"}
    assert PRESETS["lcsys2022-fig1"].trials == 100
    assert PRESETS["lcsys2022-fig1"].taus == (0, 3, 8, 19)
    assert PRESETS["delay-tolerant-fig2"].delays == ("time-varying", "synchronous",
                                                     "asynchronous-fixed")
    assert all(s in DELAY_SETTINGS for p in PRESETS.values() for s in p.delays)


def test_time_varying_cell_reports_the_realised_growth():
    from netsim.runner import scenario_gains

    scenario = lcsys()
    gains = scenario_gains(scenario)
    out = bench.delay_tolerance_cell(
        {"kind": "mc", "setting": "synchronous", "tau": 3, "family": "compensated",
         "trials": 1, "steps": 60, "seed": 1}, None, {"scenario": scenario, "gains": gains})
    a = out["analytics"]
    assert a["exact_kind"].startswith("realised growth")
    assert 0 < a["exact"] < 2 and a["realised_max_delay"] <= 3
    m = out["measured"]
    assert np.isfinite(m["last_trusted_mse"])
    assert ("steady_state_mse" in m) == (m["verdict"] == "stable")
    assert "joint" not in a  # time-varying delays: no exact analysis, measured growth
    assert m["verdict_basis"] == "measured growth"


def test_scenario_sweep_command(tmp_path, capsys):
    out, table = tmp_path / "rows.jsonl", tmp_path / "table.csv"
    argv = ["sweep", "lcsys2022-heterogeneous", "--delays", "homogeneous,time-varying",
            "--taus", "0,2", "--estimators", "compensated", "--trials", "1", "--steps", "30",
            "--workers", "1", "--no-progress", "--out", str(out), "--csv", str(table)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "4 cells (4 computed, 0 reused)" in text
    lines = table.read_text().splitlines()
    assert len(lines) == 5 and "estimators.compensated.steady_state_mse" in lines[0]
    assert main(argv + ["--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["computed"] == 0 and data["reused"] == 4
    assert all(r["result"]["estimators"]["compensated"]["verdict"] for r in data["rows"])
