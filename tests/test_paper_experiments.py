"""The experiments LCSYS2022 leaves out (issue 31): their bench side, in tiny runs.

The reproduce items themselves are checked on the quick ``netsim reproduce`` run of
tests/test_reproduce.py (binomial loss rate, the Riccati optimum of the centralised
filter); here: the baselines preset runs every family it names, and ``bench sweep
--losses`` loses messages at the asked rate (a binomial bound on the delivered count).
"""

from __future__ import annotations

import json
import math

import pytest

from netsim.cli import main


def _scalar_scenario(folder):
    """A 2-agent scalar scenario with given gains (no gain design: the tests stay fast)."""
    from netsim.claims.search import ScalarInstance, write_scenario

    small = ScalarInstance(0.9, ((0.5, 0.5), (0.5, 0.5)), (1.0, 1.0), (0.5, 0.5))
    return str(write_scenario(small, 1, folder, "small", "two agents, given gains"))


def test_the_baselines_families_run_in_a_delay_tolerance_bench(tmp_path):
    from netsim.models.scenario import resolve_scenario

    from netsim.bench.delay_tolerance import run_delay_tolerance
    from netsim.bench.presets import presets

    preset = presets()["lcsys2022-baselines"]
    assert {"kcf", "ci", "diffkf", "centralized-kf", "local-kf"} <= set(preset.families)
    data = run_delay_tolerance(resolve_scenario(_scalar_scenario(tmp_path)), taus=(0, 2),
                               delays=("homogeneous", "time-varying"), trials=2, steps=20,
                               seed=0, families=list(preset.families), executor="serial",
                               progress=False)
    assert {c["family"] for c in data["cells"]} == set(preset.families)
    for c in data["cells"]:  # every family ran: an MSE at every step, none blew up
        assert c["measured"]["diverged_trials"] == 0, c["family"]
        assert math.isfinite(c["measured"]["last_trusted_mse"]), c["family"]


@pytest.mark.slow
def test_the_baselines_preset_runs_every_family_it_names(capsys):
    from netsim.bench.presets import presets

    preset = presets()["lcsys2022-baselines"]
    assert {"kcf", "ci", "diffkf", "centralized-kf", "local-kf"} <= set(preset.families)
    code = main(["bench", "delay-tolerance", "lcsys2022-baselines", "--taus", "0",
                 "--delays", "homogeneous", "--trials", "2", "--steps", "20", "--workers",
                 "1", "--no-progress", "--json"])
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    assert data["families"] == list(preset.families)
    assert {c["family"] for c in data["cells"]} == set(preset.families)
    assert data["preset"]["families"] == list(preset.families)
    # every family ran its 2 trials of 20 steps: an MSE at every step but none blew up
    for c in data["cells"]:
        assert c["measured"]["diverged_trials"] == 0, c["family"]
        assert math.isfinite(c["measured"]["last_trusted_mse"]), c["family"]


def test_bench_sweep_losses_lose_messages_at_the_asked_rate(tmp_path, capsys):
    out = tmp_path / "rows.jsonl"
    code = main(["bench", "sweep", _scalar_scenario(tmp_path), "--losses", "0,0.4",
                 "--estimators", "compensated", "--trials", "4", "--steps", "200",
                 "--workers", "1", "--no-progress", "--out", str(out), "--json"])
    assert code == 0
    rows = {r["params"]["loss"]: r["result"]["estimators"]["compensated"]
            for r in json.loads(capsys.readouterr().out)["rows"]}
    base = rows[0.0]["messages_delivered"]
    assert rows[0.4]["messages_sent"] == rows[0.0]["messages_sent"]
    # each message lost independently with p = 0.4: delivered / delivered at p = 0 ~ 0.6
    sd = math.sqrt(0.4 * 0.6 / base)
    assert abs(rows[0.4]["messages_delivered"] / base - 0.6) < 5 * sd


@pytest.mark.parametrize("value", ["1.5", "-0.1", "x"])
def test_bench_sweep_refuses_a_bad_loss_probability(value, capsys, tmp_path):
    code = main(["bench", "sweep", "lcsys2022-heterogeneous", "--losses", value,
                 "--out", str(tmp_path / "x.jsonl")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--losses" in err[0]


def test_a_sweep_preset_gives_the_sweep_its_axes_unless_given(tmp_path, capsys):
    from netsim.bench.presets import SweepPreset, sweep_presets
    from netsim.papers import Paper, register_paper, unregister_paper
    from netsim.papers._lcsys2022_experiments import LOSSES

    assert sweep_presets()["lcsys2022-loss"].axes == {"loss": LOSSES}
    toy = SweepPreset("toy-sweep", _scalar_scenario(tmp_path), {"loss": (0.0, 0.4)},
                      ("compensated", "centralized-kf"), 2, 30, "a toy sweep")
    register_paper(Paper(key="toy-sweeps", title="toy", text_file="toy.txt", sweeps=(toy,)))
    try:
        code = main(["bench", "sweep", "toy-sweep", "--workers", "1", "--no-progress",
                     "--out", str(tmp_path / "a.jsonl"), "--json"])
        assert code == 0
        rows = json.loads(capsys.readouterr().out)["rows"]
        assert sorted(r["params"]["loss"] for r in rows) == [0.0, 0.4]
        assert all(r["params"]["_trials"] == 2 and r["params"]["_steps"] == 30 for r in rows)
        assert all(set(r["result"]["estimators"]) == {"compensated", "centralized-kf"}
                   for r in rows)
        # the command line overrides the preset's axes, estimators and trials
        code = main(["bench", "sweep", "toy-sweep", "--losses", "0.2", "--estimators",
                     "compensated", "--trials", "3", "--workers", "1", "--no-progress",
                     "--out", str(tmp_path / "b.jsonl"), "--json"])
        assert code == 0
        (row,) = json.loads(capsys.readouterr().out)["rows"]
        assert row["params"]["loss"] == 0.2 and row["params"]["_trials"] == 3
        assert set(row["result"]["estimators"]) == {"compensated"}
    finally:
        unregister_paper("toy-sweeps")
