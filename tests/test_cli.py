"""The netsim command: demo acceptance, JSON output, determinism."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
from helpers import mse_level

from netsim.cli import main


def _run_json(capsys, *args):
    code = main(["run", "lcsys2022-heterogeneous", "--no-progress", "--json", *args])
    out = capsys.readouterr().out
    assert code == 0
    return json.loads(out)


@pytest.mark.parametrize("tau", [0, 3, 8])
def test_compensating_estimator_has_bounded_steady_state_mse(capsys, tau):
    data = _run_json(capsys, "--tau", str(tau), "--trials", "4", "--steps", "250")
    for name, est in data["estimators"].items():
        assert {"verdict", "growth_rate", "last_trusted_mse"} <= set(est), name
        # a steady MSE belongs to stable runs only
        assert ("steady_state_mse" in est) == (est["verdict"] == "stable"), name
    comp = data["estimators"]["compensated"]
    assert comp["verdict"] == "stable"
    assert not comp["diverged_trials"]
    mse = comp["steady_state_mse"]
    assert isinstance(mse, float) and math.isfinite(mse)
    # bounded: far below the error of not estimating at all (the state grows like 1.04^k)
    kf = mse_level(data["estimators"]["centralized-kf"])
    assert kf <= mse < 100 * kf
    assert data["scenario"]["delays"]["bound"] == tau


def test_same_seed_same_json_bit_for_bit():
    cmd = [sys.executable, "-m", "netsim.cli", "run", "lcsys2022-time-varying", "--tau", "4",
           "--trials", "2", "--steps", "60", "--seed", "17", "--json", "--no-progress"]
    a = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    b = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    assert a == b
    c = subprocess.run(cmd[:-3] + ["18", "--json", "--no-progress"], capture_output=True,
                       text=True, check=True).stdout
    assert json.loads(c)["estimators"] != json.loads(a)["estimators"]


def test_divergence_is_a_reported_result_not_a_crash(capsys, tmp_path):
    from netsim.models.scenario import builtin_scenarios

    text = builtin_scenarios()["lcsys2022-heterogeneous"].read_text()
    zero = "K = [" + ", ".join(["[" + ", ".join(["[0,0,0,0,0,0]"] * 6) + "]"] * 4) + "]"
    text = text.replace('method = "lmi"', f'method = "given"\n{zero}')
    text = text.replace("[run]", "[run]\ndivergence_threshold = 100.0")
    path = tmp_path / "zero-gain.toml"
    path.write_text(text)
    code = main(["run", str(path), "--trials", "2", "--steps", "400", "--no-progress",
                 "--estimators", "compensated"])
    out = capsys.readouterr().out
    assert code == 0
    assert "diverged at step" in out
    assert "inf" not in out.split("steady")[1].lower().replace("info", "")


def test_scenarios_lists_the_builtins(capsys):
    assert main(["scenarios", "--json"]) == 0
    names = {s["name"] for s in json.loads(capsys.readouterr().out)["scenarios"]}
    assert {"lcsys2022-heterogeneous", "lcsys2022-homogeneous", "lcsys2022-time-varying"} <= names


def test_help_explains_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for option in ("--steps", "--trials", "--seed", "--tau", "--json"):
        assert option in text
