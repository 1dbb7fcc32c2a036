"""Fixed clock patterns of ``netsim bench sweep`` and the LCSYS2022 clock / trigger presets.

A fixed-pattern cell (``offset_pattern`` / ``drift_pattern`` ``fixed``) gives every trial
the same clocks, so ``auto`` runs it on the batched timed engine
(:mod:`netsim.timedlockstep`); the event kernel (:mod:`netsim.timedkernel`, one SimPy run
per trial) is the independent implementation it is held to, with the tolerance of
``tests/test_timed_lockstep.py`` (1e-9 relative; about 1e-15 is measured).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from netsim.bench.scenario_sweep import run_scenario_sweep, scenario_sweep_cell
from netsim.bench.variants import fixed_pattern, scenario_data, sweep_variant
from netsim.runner import run_monte_carlo

RELATIVE = 1e-9
_PRESETS = ("lcsys2022-clock-offset", "lcsys2022-clock-drift", "lcsys2022-trigger")


def _close(a: np.ndarray, b: np.ndarray) -> None:
    """tests/test_timed_lockstep.py's rule: equal NaNs, else within 1e-9 of the scale."""
    assert np.array_equal(np.isnan(a), np.isnan(b))
    scale = max(1.0, float(np.nanmax(np.abs(a)))) if np.any(np.isfinite(a)) else 1.0
    assert np.nanmax(np.abs(a - b), initial=0.0) <= RELATIVE * scale


def _data(steps: int = 30) -> tuple[dict, str]:
    data, source = scenario_data("lcsys2022-heterogeneous")
    data["run"]["steps"] = steps
    data["gains"] = {"method": "local"}  # fast, the same for both engines
    return data, source


def test_fixed_pattern_is_the_harmonic_sequence():
    """p_i = (-1)^(i+1) / (i // 2 + 1): (-1, 1, -1/2, 1/2, -1/3, ...), written out."""
    assert fixed_pattern(5) == [-1.0, 1.0, -0.5, 0.5, -1.0 / 3.0]
    data, source = _data()
    cell = sweep_variant(data, source, {"offset": 0.2, "offset_pattern": "fixed",
                                        "drift_ppm": 50.0, "drift_pattern": "fixed"})
    assert cell.timing.offset.kind == "fixed" and cell.timing.drift_ppm.kind == "fixed"
    assert np.allclose(cell.timing.offset.values, [-0.2, 0.2, -0.1, 0.1], rtol=0, atol=1e-15)
    assert np.allclose(cell.timing.drift_ppm.values, [-50.0, 50.0, -25.0, 25.0], rtol=0,
                       atol=1e-12)
    # the default patterns draw per trial, as before
    drawn = sweep_variant(data, source, {"offset": 0.2, "drift_ppm": 50.0})
    assert (drawn.timing.offset.kind, drawn.timing.drift_ppm.kind) == ("uniform", "normal")


@pytest.mark.parametrize("params", [
    {"offset": 0.3, "offset_pattern": "fixed"},
    {"drift_ppm": 2000.0, "drift_pattern": "fixed"},
])
def test_fixed_cell_runs_batched_and_equals_the_kernel(params):
    """The sweep cell picks the batched timed engine (auto) and says so; the same cell on
    the event kernel gives the same MSE curves, verdicts and message counts."""
    data, source = _data()
    scenario = sweep_variant(data, source, params)
    families = ["compensated", "uncompensated"]
    runs = {engine: run_monte_carlo(scenario, steps=30, trials=2, seed=5, families=families,
                                    engine=engine)
            for engine in ("auto", "events")}
    assert runs["auto"].engine == "vectorised" and runs["events"].engine == "events"
    for family in families:
        a, b = runs["events"].estimators[family], runs["auto"].estimators[family]
        _close(a.mse, b.mse)
        assert a.verdict == b.verdict
        assert (a.messages_sent, a.messages_delivered, a.message_rate) == (
            b.messages_sent, b.messages_delivered, b.message_rate)
    context = {"data": data, "source": source, "families": families, "trials": 2,
               "steps": 30}
    cells = {engine: scenario_sweep_cell({**params, "_engine": engine}, None, context)
             for engine in ("auto", "events")}
    for family in families:
        batched = cells["auto"]["estimators"][family]
        kernel = cells["events"]["estimators"][family]
        assert (batched["engine"], kernel["engine"]) == ("vectorised", "events")
        assert batched["verdict"] == kernel["verdict"]
        assert batched["message_rate"] == kernel["message_rate"]
        got, want = batched["last_trusted_mse"], kernel["last_trusted_mse"]
        assert abs(got - want) <= RELATIVE * max(1.0, abs(want))


def test_drawn_and_triggered_cells_run_on_the_kernel_and_say_so():
    data, source = _data(steps=10)
    context = {"data": data, "source": source, "families": ["compensated"], "trials": 1,
               "steps": 10}
    for params in ({"offset": 0.3}, {"threshold": 1.0}):
        out = scenario_sweep_cell({**params, "_engine": "auto"}, None, context)
        assert out["estimators"]["compensated"]["engine"] == "events"


def test_presets_are_lcsys2022s():
    from netsim.bench.presets import sweep_presets
    from netsim.papers import get_paper
    from netsim.timedlockstep import lockstep_refusal

    paper = get_paper("LCSYS2022")
    named = {p.name: p for p in paper.sweeps}
    for name in _PRESETS:
        assert name in named and sweep_presets()[name] is named[name]
        assert named[name].scenario == "lcsys2022-heterogeneous"
    offset, drift = named["lcsys2022-clock-offset"], named["lcsys2022-clock-drift"]
    assert set(offset.families) == {"compensated", "uncompensated"}
    assert offset.axes["offset_pattern"] == ("fixed",) and drift.axes["drift_pattern"] == (
        "fixed",)
    assert min(offset.axes["offset"]) == 0.0 and max(offset.axes["offset"]) == 1.0
    assert min(drift.axes["drift_ppm"]) == 0.0
    # the largest drift parts the clocks by more than a period over the run
    assert max(drift.axes["drift_ppm"]) * 1e-6 * drift.steps > 1.0
    assert min(named["lcsys2022-trigger"].axes["threshold"]) == 0.0
    # the fixed cells are ones the batched engine expresses (largest values checked)
    data, source = scenario_data(offset.scenario)
    for preset, axis, pattern in ((offset, "offset", "offset_pattern"),
                                  (drift, "drift_ppm", "drift_pattern")):
        cell = sweep_variant(data, source, {axis: max(preset.axes[axis]),
                                            pattern: preset.axes[pattern][0]})
        assert lockstep_refusal(cell) is None


@pytest.mark.parametrize("name", _PRESETS)
def test_every_family_a_preset_names_runs(name):
    """One cell (the largest value of each axis) of each preset on its scenario (with
    local gains, fast), 1 trial x 5 steps: every family it names gives a row with an
    MSE, a message rate and the engine (batched for the fixed clocks, the kernel for a
    trigger that holds updates back)."""
    from netsim.bench.presets import sweep_presets

    preset = sweep_presets()[name]
    data, source = scenario_data(preset.scenario)
    data["gains"] = {"method": "local"}
    params = {k: max(v) if k in ("offset", "drift_ppm", "threshold") else v[0]
              for k, v in preset.axes.items()}
    context = {"data": data, "source": source, "families": list(preset.families),
               "trials": 1, "steps": 5}
    out = scenario_sweep_cell({**params, "_engine": "auto"}, None, context)
    assert "error" not in out
    assert set(out["estimators"]) == set(preset.families)
    for e in out["estimators"].values():
        assert e["message_rate"] > 0 and np.isfinite(e["last_trusted_mse"])
    expected = "events" if name == "lcsys2022-trigger" else "vectorised"
    assert {e["engine"] for e in out["estimators"].values()} == {expected}


@pytest.mark.parametrize("argv, option", [
    (["--offsets", "0.1", "--offset-pattern", "fixd"], "--offset-pattern"),
    (["--drifts", "10", "--drift-pattern", "uniform"], "--drift-pattern"),
    (["--offset-pattern", "fixed"], "--offset-pattern"),
    (["--drift-pattern", "fixed", "--offsets", "0.1"], "--drift-pattern"),
])
def test_bad_pattern_is_one_line_naming_the_option(tmp_path, capsys, argv, option):
    from netsim.cli import main

    out = tmp_path / "cells.jsonl"
    try:
        code = main(["bench", "sweep", "lcsys2022-heterogeneous", *argv, "--estimators",
                     "compensated", "--trials", "1", "--steps", "5", "--out", str(out),
                     "--workers", "1", "--no-progress"])
    except SystemExit as exc:  # argparse's own (one-line) refusal of a bad choice
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and option in err[0], err
    assert not out.exists() or not out.read_text().strip()


def test_bad_pattern_from_python_names_the_axis():
    with pytest.raises(ValueError, match="offset_pattern"):
        run_scenario_sweep("lcsys2022-heterogeneous",
                           axes={"offset": [0.1], "offset_pattern": ["fixd"]}, trials=1,
                           steps=5, families=["compensated"], seed=0, executor="serial",
                           progress=False)


@pytest.fixture
def local_preset(tmp_path):
    """A sweep preset like lcsys2022-clock-offset on a copy of its scenario with local
    gains (no LMI design: fast), registered under a toy paper."""
    from netsim.models.scenario import builtin_scenarios

    from netsim.bench.presets import SweepPreset
    from netsim.papers import Paper, register_paper, unregister_paper

    text = builtin_scenarios()["lcsys2022-heterogeneous"].read_text()
    assert text.count('method = "lmi"') == 1
    path = tmp_path / "local.toml"
    path.write_text(text.replace('method = "lmi"', 'method = "local"'))
    preset = SweepPreset("toy-clock-offset", str(path),
                         {"offset": (0.0, 0.5), "offset_pattern": ("fixed",)},
                         ("compensated",), 1, 5, "a toy clock-offset sweep")
    register_paper(Paper(key="TOY-TIME", title="toy", text_file="", sweeps=(preset,)))
    yield preset
    unregister_paper("TOY-TIME")


def test_cli_rows_name_the_engine(local_preset, tmp_path, capsys):
    """The text rows of a preset's fixed-pattern sweep name the batched engine;
    --offset-pattern uniform on that preset restores offsets drawn per trial (kernel)."""
    from netsim.cli import main

    args = ["bench", "sweep", local_preset.name, "--offsets", "0.5", "--workers", "1",
            "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "a.jsonl")]) == 0
    text = capsys.readouterr().out
    assert "'offset_pattern': 'fixed'" in text and "[vectorised]" in text
    assert main([*args, "--offset-pattern", "uniform", "--out", str(tmp_path / "b.jsonl"),
                 "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert "offset_pattern" not in row["params"]
    assert row["result"]["estimators"]["compensated"]["engine"] == "events"
