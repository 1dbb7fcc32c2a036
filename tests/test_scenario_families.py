"""Every family from one scenario format: AoI and DKFE scenarios as TOML, run by the
common runner, under [links] tables, beside the older code paths they replace."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import mse_level
from netsim.models.scenario import ScenarioError, builtin_scenarios, resolve_scenario

from netsim.cli import main

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "models" / "scenarios"


def run_json(capsys, *args):
    code = main(["run", *args, "--json", "--no-progress"])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


def test_every_builtin_scenario_is_a_toml_file_listed_by_netsim_scenarios(capsys):
    files = {p.stem for p in SCENARIOS.glob("*.toml")}
    assert {"aoi-example", "aoi-random", "dkfe-example1", "dkfe-example2"} <= files
    assert set(builtin_scenarios()) == files
    assert main(["scenarios", "--json"]) == 0
    listed = {s["name"] for s in json.loads(capsys.readouterr().out)["scenarios"]}
    assert listed == files


# -- DKFE ---------------------------------------------------------------------------


def test_dkfe_scenario_reproduces_the_fusion_command(capsys):
    # `netsim fusion run` builds its agents in netsim/fusion.py from models.dkfe's
    # example; `netsim run` builds them from the TOML through the registry: the same
    # trials must give the same numbers
    new = run_json(capsys, "dkfe-example2", "--trials", "4", "--steps", "40")
    assert main(["fusion", "run", "dkfe-example2", "--trials", "4", "--steps", "40",
                 "--json"]) == 0
    old = json.loads(capsys.readouterr().out)
    for family, name in (("dkfe", "DKFE"), ("sdkfe", "SDKFE"), ("odkfe", "ODKFE (d=0)")):
        report = new["estimators"][family]["report"]
        assert report["marks"] == old["marks"]
        assert report["mse"][family] == old["mse"][name]
        assert report["exact_trace"][family] == old["exact_trace"][name]
    assert new["analytics"]["fusion"]["conditions"] == old["conditions"]


def test_dkfe_mse_approaches_the_exact_covariance_trace(capsys):
    # Monte Carlo against the paper's exact covariance recursion (an independent
    # computation): within 4 standard errors at every mark after the start
    data = run_json(capsys, "dkfe-example2", "--trials", "200", "--steps", "30",
                    "--estimators", "dkfe,odkfe")
    for family in ("dkfe", "odkfe"):
        r = data["estimators"][family]["report"]
        for mse, se, exact in zip(r["mse"][family], r["mse_standard_error"][family],
                                  r["exact_trace"][family], strict=True):
            assert abs(mse - exact) <= 4 * se + 1e-9, (family, mse, exact, se)


def _with_links(source: Path, tmp_path: Path, table: str) -> Path:
    path = tmp_path / source.name
    path.write_text(source.read_text() + "\n" + table)
    return path


def test_dkfe_under_random_delays_and_loss(capsys, tmp_path):
    path = _with_links(SCENARIOS / "dkfe-example2.toml", tmp_path, """
[links]
loss = { model = "bernoulli", p = 0.1 }

[[links.per_link]]
from = 1
to = 2
delay = { distribution = "uniform", low = 0, high = 1, unit = "steps", mode = "asynchronous" }
""")
    data = run_json(capsys, str(path), "--trials", "6", "--steps", "60")
    sent = data["estimators"]["dkfe"]["messages"]["sent"]
    missing = data["estimators"]["dkfe"]["report"]["missing_selections"]
    # every lost selection is one the centre had to predict (delays stay within d_i - 1)
    dropped = sent - data["estimators"]["dkfe"]["messages"]["delivered"]
    assert 0 < missing
    assert missing <= dropped
    for family in ("dkfe", "sdkfe", "odkfe"):  # 60 steps may not establish "stable"
        assert data["estimators"][family]["verdict"] in ("stable", "undecided")
    # losing selections costs accuracy against the loss-free run of the same trials: the
    # mean MSE over the last quarter (not a "steady MSE": these runs may be undecided)
    from netsim.runner import run_monte_carlo

    lossy, clean = (run_monte_carlo(resolve_scenario(str(name)), trials=6, steps=60,
                                    families=["dkfe"]).estimators["dkfe"]
                    for name in (path, "dkfe-example2"))
    assert lossy.tail_mse > clean.tail_mse


def test_dkfe_fail_policy_refuses_a_lost_selection(capsys, tmp_path):
    text = (SCENARIOS / "dkfe-example2.toml").read_text().replace(
        'on_missing = "predict"', 'on_missing = "fail"')
    path = tmp_path / "fail.toml"
    path.write_text(text + '\n[links]\nloss = { model = "bernoulli", p = 0.3 }\n')
    code = main(["run", str(path), "--trials", "2", "--steps", "30", "--estimators", "dkfe",
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1
    assert "had not arrived" in err


@pytest.mark.parametrize("edit, key", [
    ("delays = [1, 2]", "options.fusion.delays"),
    ("components = [2, 2]", "options.fusion.components"),
])
def test_dkfe_bad_options_name_the_key(capsys, tmp_path, edit, key):
    bad = {"delays = [1, 2]": "delays = [1, 3]",
           "components = [2, 2]": "components = [2, 9]"}[edit]
    text = (SCENARIOS / "dkfe-example2.toml").read_text().replace(edit, bad)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    code = main(["run", str(path), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and key in err and err.count("\n") == 1, err


# -- AoI ----------------------------------------------------------------------------


def test_aoi_under_random_delays_and_loss(capsys, tmp_path):
    path = _with_links(SCENARIOS / "aoi-random.toml", tmp_path, """
[links]
delay = { distribution = "uniform", low = 0, high = 2, unit = "steps", mode = "asynchronous" }
loss = { model = "gilbert-elliott", p = 0.05, r = 0.3 }
""")
    path.write_text(path.read_text().replace('delayed = "discard"', 'delayed = "age"'))
    data = run_json(capsys, str(path), "--trials", "3", "--steps", "100")
    for family in ("aoi", "naive-uniform", "naive-tree"):
        e = data["estimators"][family]
        m = e["report"]["messages"]
        # drops of both kinds, counted apart: the graph sequence's links that are down,
        # and the Gilbert-Elliott losses
        assert set(m["drop_reasons"]) == {"link down", "loss: gilbert-elliott (bad state)"}
        assert sum(m["drop_reasons"].values()) == m["dropped"]
        in_flight = m["sent"] - m["delivered"] - m["dropped"]
        assert 0 <= in_flight <= 3 * 4  # at most the last steps' messages per link
    # the freshness observer with aged messages still becomes exact (finite time)
    assert data["estimators"]["aoi"]["verdict"].startswith("converged at step")
    assert data["estimators"]["naive-uniform"]["verdict"] == "diverging"


def test_aoi_topology_errors_name_the_key(tmp_path):
    text = (SCENARIOS / "aoi-example.toml").read_text().replace("[2, 1]", "[2, 7]")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=r"topology\.graphs\[\d\]\[\d\]"):
        resolve_scenario(str(path))


def test_consensus_estimator_runs_on_a_time_varying_topology(capsys):
    # the papers' consensus estimators on the AoI graph sequence: links that are down
    # drop the messages (counted), the kernel runs it; compare with the same families
    # on the union graph with every link up
    data = run_json(capsys, "aoi-random", "--estimators", "local-kf,centralized-kf",
                    "--noise", "0.01", "--trials", "2")
    assert data["engine"] == "events"
    assert data["estimators"]["centralized-kf"]["verdict"] in ("stable", "undecided")
    # no agent observes the system alone (rho(A) = 1.1): the local filters lose it
    assert (mse_level(data["estimators"]["local-kf"])
            > 10 * mse_level(data["estimators"]["centralized-kf"]))


def test_noise_override_changes_only_the_noise():
    scenario = resolve_scenario("aoi-example").with_noise(0.5, 0.25)
    assert np.array_equal(scenario.plant.Q, 0.5 * np.eye(1))
    assert [R.shape for R in scenario.plant.R] == [(1, 1), (0, 0), (0, 0)]
    assert np.array_equal(scenario.plant.A, resolve_scenario("aoi-example").plant.A)
