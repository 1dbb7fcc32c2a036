"""The timed lockstep (netsim.timedlockstep) against the timed event kernel.

The kernel (netsim.timedkernel) is the independent implementation: one SimPy run per
trial, message by message. The lockstep must give the same runs: estimates, states and
squared errors to round-off (the kernel applies one update operator per agent and
sample, the lockstep sums its blocks term by term, and propagates the plant of all
trials with one matrix product: 1e-9 relative is asserted, about 1e-15 is measured),
everything discrete exactly (divergence steps, message counts, drops and their
reasons, discards, effective delays, the sample record).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from netsim.models.scenario import builtin_scenarios, parse_scenario, read_scenario_data
from netsim.models.seeding import child_sequence

from netsim import timedlockstep
from netsim.runner import engines_for, run_monte_carlo, run_trial, scenario_gains
from netsim.timedlockstep import lockstep_refusal, run_timed_lockstep

RELATIVE = 1e-9


def _scenario(time_table: dict, *, steps: int = 30, delays: dict | None = None,
              links: dict | None = None, run: dict | None = None):
    data = read_scenario_data(builtin_scenarios()["lcsys2022-heterogeneous"])
    data["run"]["steps"] = steps
    data["run"].update(run or {})
    data["gains"] = {"method": "local"}  # fast, the same for both engines
    data["time"] = copy.deepcopy(time_table)
    if delays is not None:
        data["delays"] = delays
    if links is not None:
        data["links"] = links
        if "delay" in links:  # the links' delays replace the [delays] table's
            data["delays"] = {"model": "none"}
    return parse_scenario(data, "test")


def _close(a: np.ndarray, b: np.ndarray) -> None:
    assert np.array_equal(np.isnan(a), np.isnan(b))
    scale = max(1.0, float(np.nanmax(np.abs(a)))) if np.any(np.isfinite(a)) else 1.0
    assert np.nanmax(np.abs(a - b), initial=0.0) <= RELATIVE * scale


def _equal_runs(reference, got) -> None:
    assert len(reference) == len(got)
    for a, b in zip(reference, got, strict=True):
        assert a.diverged_at == b.diverged_at
        _close(a.states, b.states)
        _close(a.estimates, b.estimates)
        _close(a.squared_errors, b.squared_errors)
        for ma, mb in zip(a.measurements, b.measurements, strict=True):
            _close(ma, mb)
        assert (a.messages_sent, a.messages_delivered, a.messages_dropped,
                a.messages_discarded) == (b.messages_sent, b.messages_delivered,
                                          b.messages_dropped, b.messages_discarded)
        assert a.drop_reasons == b.drop_reasons
        assert a.drops == b.drops
        assert np.array_equal(a.effective_delays, b.effective_delays)
        ta, tb = a.extras["timing"], b.extras["timing"]
        for key in ("samples", "broadcasts", "messages_sent", "duration", "clocks"):
            assert ta[key] == tb[key], key
        for key in ("message_rate", "send_fraction"):
            assert ta[key] == tb[key] or (np.isnan(ta[key]) and np.isnan(tb[key])), key
        for field in ("agent", "index", "true_time", "local_time", "sent"):
            assert np.array_equal(getattr(ta["sample_record"], field),
                                  getattr(tb["sample_record"], field)), field


def _both(scenario, family: str, trials: int = 3, seed: int = 3):
    gains = scenario_gains(scenario)
    seeds = [child_sequence(seed, "trial", t) for t in range(trials)]
    reference = [run_trial(scenario, family, gains, s) for s in seeds]
    return reference, run_timed_lockstep(scenario, family, gains, seeds, record_delays=True)


CASES = {
    # clock offsets (not whole periods) and asynchronous random delays (reordering)
    "offsets-async-delays": dict(
        time_table={"offset": [0.0, 0.3, -0.2, 0.5]},
        delays={"model": "asynchronous", "tau": 2, "seed": 5}),
    # two commensurate periods with phases, offsets, Bernoulli losses; a send-on-delta
    # trigger of threshold 0 (it sends every update)
    "two-periods-loss": dict(
        time_table={"periods": [1.0, 0.5, 1.0, 0.5], "phases": [0.0, 0.25, 0.0, 0.1],
                    "offset": [0.0, 0.1, 0.0, 0.7],
                    "trigger": {"kind": "send-on-delta", "threshold": 0.0}},
        links={"loss": {"model": "bernoulli", "p": 0.3}}),
    # fixed drifts, continuous latencies (gamma, in time units) with losses
    "drift-latency-loss": dict(
        time_table={"drift_ppm": [0.0, 100.0, -50.0, 10.0], "offset": [0.1, 0.0, 0.0, 0.0],
                    "periods": [1.0, 1.1, 0.9, 1.2]},
        links={"delay": {"distribution": "gamma", "shape": 2.0, "scale": 0.6,
                         "shift": 0.4, "mode": "asynchronous"},
               "loss": {"model": "bernoulli", "p": 0.2}, "bound": 5},
        steps=20),  # (every lag differs: one matrix exponential per lag on the kernel)
    # constant latencies of half a period on half-period samplers: arrivals meet
    # samples (counted as arrived, within the kernel's rounding tolerance)
    "latencies-meeting-samples": dict(
        time_table={"periods": [0.5, 1.0, 0.5, 1.5], "phases": [0.0, 0.3, 0.2, 0.0],
                    "offset": [0.0, 0.2, 0.0, 0.0]},
        links={"delay": {"distribution": "constant", "value": 0.5, "unit": "time"}}),
    # offsets of whole periods (the plant on the base grid), bursty losses and outages
    "whole-period-offsets-outages": dict(
        time_table={"offset": [0.0, 1.0, 0.0, 2.0]},
        links={"loss": {"model": "gilbert-elliott", "p": 0.2, "r": 0.3},
               "outages": [[5, 9]]}),
}


@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_lockstep_is_the_timed_kernel(case, family):
    scenario = _scenario(**CASES[case])
    assert lockstep_refusal(scenario) is None
    reference, got = _both(scenario, family)
    _equal_runs(reference, got)
    # the cases exercise what they claim
    if "loss" in case:
        assert sum(r.messages_dropped for r in reference) > 0
    if case == "offsets-async-delays" and family == "compensated":
        assert sum(r.messages_discarded for r in reference) > 0  # reordered messages


def test_divergence_steps_and_truncation_match():
    """A low divergence threshold: trials stop at different report steps, and what
    each has counted by then (messages, samples) is the kernel's."""
    scenario = _scenario({"offset": [0.0, 0.3, -0.2, 0.5], "periods": [1.0, 0.5, 1.0, 0.5]},
                         steps=100, delays={"model": "asynchronous", "tau": 3, "seed": 1},
                         run={"divergence_threshold": 3.0})
    reference, got = _both(scenario, "uncompensated", trials=4)
    ends = {r.diverged_at for r in reference}
    assert None not in ends and len(ends) > 1 and min(ends) > 0  # at various steps
    _equal_runs(reference, got)


def test_same_seed_same_results_whatever_the_batch(monkeypatch):
    scenario = _scenario(**CASES["two-periods-loss"])
    gains = scenario_gains(scenario)
    seeds = [child_sequence(9, "trial", t) for t in range(3)]
    a = run_timed_lockstep(scenario, "compensated", gains, seeds)
    b = run_timed_lockstep(scenario, "compensated", gains, seeds)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.estimates, y.estimates, equal_nan=True)
        assert np.array_equal(x.squared_errors, y.squared_errors, equal_nan=True)
    monkeypatch.setattr(timedlockstep, "BATCH_VALUES", 1)  # one trial per batch
    c = run_timed_lockstep(scenario, "compensated", gains, seeds)
    for x, y in zip(a, c, strict=True):
        _close(x.estimates, y.estimates)
        assert x.messages_delivered == y.messages_delivered


@pytest.mark.parametrize(("time_table", "links", "key"), [
    ({"offset": {"distribution": "uniform", "low": -0.2, "high": 0.2}}, None, "time.offset"),
    ({"drift_ppm": {"distribution": "normal", "std": 100.0}}, None, "time.drift_ppm"),
    ({"jitter": 1e-4}, None, "time.jitter"),
    ({"trigger": {"kind": "send-on-delta", "threshold": 0.05}}, None, "time.trigger"),
    ({"trigger": {"kind": "periodic", "threshold": 0.0, "every": 2}}, None, "time.trigger"),
    ({"sync": {"period": 5.0}}, None, "time.sync"),
    ({"offset": [0.0, 0.1, 0.0, 0.0]}, {"buffer": {"capacity": 2, "policy": "drop-tail"}},
     "links"),
])
def test_inexpressible_cases_run_on_the_kernel_and_say_why(time_table, links, key):
    scenario = _scenario(time_table, steps=5, links=links)
    why = lockstep_refusal(scenario)
    assert why is not None and why.startswith(f"{key}:") and "\n" not in why
    assert engines_for("auto", ["compensated"], scenario) == {"compensated": "events"}
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        engines_for("vectorised", ["compensated"], scenario)


def test_engine_selection_of_expressible_cases():
    scenario = _scenario({"offset": [0.0, 0.3, -0.2, 0.5]}, steps=5)
    assert engines_for("auto", ["compensated", "uncompensated", "block"], scenario) == {
        "compensated": "vectorised", "uncompensated": "vectorised", "block": "events"}
    assert engines_for("events", ["compensated"], scenario) == {"compensated": "events"}
    # traces of [time] runs are the kernel's
    assert engines_for("auto", ["compensated"], scenario, traced=True) == {
        "compensated": "events"}
    with pytest.raises(ValueError, match="traced"):
        engines_for("vectorised", ["compensated"], scenario, traced=True)
    with pytest.raises(ValueError, match="'block'"):
        engines_for("vectorised", ["block"], scenario)


def test_monte_carlo_on_both_engines():
    scenario = _scenario(CASES["two-periods-loss"]["time_table"],
                         links=CASES["two-periods-loss"]["links"])
    gains = scenario_gains(scenario)
    runs = {engine: run_monte_carlo(scenario, trials=3, seed=4, gains=gains, engine=engine,
                                    families=["compensated", "uncompensated"])
            for engine in ("auto", "events")}
    assert runs["auto"].engine == "vectorised" and runs["events"].engine == "events"
    for family in ("compensated", "uncompensated"):
        a, b = runs["events"].estimators[family], runs["auto"].estimators[family]
        _close(a.mse, b.mse)
        assert a.verdict == b.verdict
        assert (a.message_rate, a.send_fraction) == (b.message_rate, b.send_fraction)
        assert (a.messages_sent, a.messages_delivered, a.messages_discarded) == (
            b.messages_sent, b.messages_delivered, b.messages_discarded)


def test_bench_sweep_refuses_vectorised_offsets_drawn_per_trial(tmp_path, capsys):
    """--offsets draws each agent's offset per trial: --engine vectorised is one line
    naming time.offset (auto lets each cell pick, tests/test_timed.py)."""
    from netsim.cli import main

    code = main(["bench", "sweep", "lcsys2022-heterogeneous", "--offsets", "0,0.1",
                 "--estimators", "compensated", "--trials", "1", "--steps", "5",
                 "--out", str(tmp_path / "cells.jsonl"), "--engine", "vectorised",
                 "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "time.offset" in err[0]
    assert not (tmp_path / "cells.jsonl").exists() or not (
        tmp_path / "cells.jsonl").read_text().strip()
