"""[network.medium] in scenarios: parsing, one path for delays and drops, both engines."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from netsim.models.delays import latency_to_steps
from netsim.models.scenario import ScenarioError, parse_scenario

import netsim

ROOT = Path(__file__).resolve().parents[1]

BASE = {
    "name": "medium-small",
    "run": {"steps": 40, "trials": 2, "seed": 3, "sample_period": 0.01,
            "estimators": ["compensated", "uncompensated"]},
    "plant": {"A": [[0.95, 0.1], [-0.1, 0.95]], "C": [[[1.0, 0.0]], [[0.0, 1.0]]],
              "sensors": 6, "Q": 0.01, "R": 0.01},
    "network": {"topology": "cycle", "agents": 6, "weights": "uniform",
                "medium": {"model": "csma", "jitter": 0.004, "queue": 2,
                           "policy": "drop-oldest"}},
    "gains": {"method": "lmi", "tau1": 1},
}


def _scenario(**medium):
    data = copy.deepcopy(BASE)
    if medium.get("model", "csma") != "csma":  # the CSMA/CA-only keys of BASE
        data["network"]["medium"] = {"model": medium["model"]}
    data["network"]["medium"].update(medium)
    return parse_scenario(data, "test")


@pytest.mark.parametrize(("medium", "key"), [
    ({"model": "wifi"}, "network.medium.model"),
    ({"bit_rate": -1}, "network.medium.bit_rate"),
    ({"queue": 0}, "network.medium.queue"),
    ({"policy": "random"}, "network.medium.policy"),
    ({"max_be": 1}, "network.medium.max_be"),
    ({"slots": 3}, "network.medium.slots"),
    ({"model": "tdma", "slot": 1e-6}, "network.medium.slot"),
    ({"model": "can", "priorities": [1, 1, 2, 3, 4, 5]}, "network.medium.priorities"),
    ({"model": "aloha", "p": 1.5}, "network.medium.p"),
    ({"payload_bytes": 200}, "network.medium.payload_bytes"),
    ({"model": "point-to-point", "per_link": [{"from": 0, "to": 9}]},
     "network.medium.per_link[0]"),
    ({"model": "point-to-point", "per_link": [{"from": 0, "to": 1, "bit_rate": 0}]},
     "network.medium.per_link[0].bit_rate"),
])
def test_bad_medium_parameters_name_the_key_in_one_line(medium, key):
    with pytest.raises(ScenarioError) as err:
        _scenario(**medium)
    assert err.value.key == key
    assert "\n" not in str(err.value) and str(err.value).startswith(key)


def test_a_medium_excludes_the_link_tables():
    data = copy.deepcopy(BASE)
    data["links"] = {"loss": {"model": "bernoulli", "p": 0.1}}
    with pytest.raises(ScenarioError, match="^links: cannot be combined"):
        parse_scenario(data, "test")
    data = copy.deepcopy(BASE)
    data["delays"] = {"model": "homogeneous", "tau": 1}
    with pytest.raises(ScenarioError, match="^delays.model"):
        parse_scenario(data, "test")


def test_kernel_messages_are_the_medium_outcomes():
    """Every message the kernel sends gets the medium's latency for (link, step), and
    exactly the medium's drops are dropped, with its reasons."""
    from netsim.medium import MediumRun

    scenario = _scenario()
    one = netsim.run_one(scenario, "compensated", trial=0, steps=30)
    # the run's own medium, re-simulated from the same trial seed
    from netsim.models.seeding import child_sequence

    run = MediumRun(scenario.medium, scenario.links, scenario.sample_period,
                    child_sequence(scenario.seed, "trial", 0))
    expected_drops = set()
    for k in range(31):
        for j, i in scenario.links:
            out = run.outcome(j, i, k)
            if out.reason is not None:
                expected_drops.add((j, i, k, f"medium: {out.reason}"))
    got = {(j, i, s, reason) for j, i, s, _, reason in one.drops}
    assert expected_drops  # the busy channel does drop (collisions, full queues)
    assert got == expected_drops
    assert one.messages_dropped == len(expected_drops)
    assert one.messages_sent == 31 * len(scenario.links)
    # the effective delays the agents used are at least the medium's step delays
    delays = one.effective_delays
    for k in range(1, 31):
        for j, i in scenario.links:
            r = delays[k, i, j]
            if r >= 0:
                s = k - 1 - r  # the time-stamp used
                out = run.outcome(j, i, s)
                assert out.reason is None
                assert latency_to_steps(out.latency, scenario.sample_period) <= r


def test_both_engines_see_the_same_network():
    """The vectorised engine reads the same per-message delays and drops as the event
    kernel (the medium does not depend on the estimates)."""
    scenario = _scenario()
    events = netsim.run(scenario, engine="events", estimators=["compensated"])
    vector = netsim.run(scenario, engine="vectorised", estimators=["compensated"])
    a, b = events["compensated"], vector["compensated"]
    np.testing.assert_allclose(a.squared_errors, b.squared_errors, rtol=1e-9, atol=1e-12)
    assert a.drops is not None and b.drops is not None
    assert any(a.drops)
    assert [sorted(d) for d in a.drops] == [sorted(d) for d in b.drops]


def test_a_busier_medium_is_slower():
    """More agents on one CSMA/CA channel: longer delays (the network makes them)."""
    from netsim.medium import MediumRun

    def mean_latency(agents):
        data = copy.deepcopy(BASE)
        data["plant"]["sensors"] = agents
        data["network"]["agents"] = agents
        s = parse_scenario(data, "test")
        run = MediumRun(s.medium, s.links, s.sample_period, 0)
        lat = [o.latency for k in range(20) for j, i in s.links
               if (o := run.outcome(j, i, k)).reason is None]
        return float(np.mean(lat))

    assert mean_latency(12) > 1.3 * mean_latency(3)


def test_cli_bad_medium_is_one_stderr_line(tmp_path):
    path = tmp_path / "bad.toml"
    text = (ROOT / "examples" / "csma-32.toml").read_text(encoding="utf-8")
    path.write_text(text.replace('model = "csma"', 'model = "csma"\nmin_be = -1'),
                    encoding="utf-8")
    out = subprocess.run([sys.executable, "-m", "netsim.cli", "run", str(path), "--steps",
                          "2"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode != 0
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "network.medium.min_be" in lines[0], out.stderr


def test_bench_sweep_resizes_a_medium_scenario_with_a_sensors_key():
    """netsim bench sweep --sizes on examples/csma-32.toml (plant.sensors = 32): each cell
    has the requested number of agents on the same medium."""
    from netsim.models.scenario import read_scenario_data

    from netsim.bench.variants import sweep_variant

    path = ROOT / "examples" / "csma-32.toml"
    data = read_scenario_data(path)
    for agents in (8, 16):
        s = sweep_variant(data, str(path), {"agents": agents})
        assert s.n_agents == agents and s.medium is not None
        assert s.medium.n_agents == agents


@pytest.mark.parametrize("model", ["point-to-point", "switched", "tdma", "can", "aloha"])
def test_every_medium_runs_on_both_engines_alike(model):
    """Each MAC model through a scenario: the engines agree, and what is dropped is
    dropped for the medium's reasons."""
    scenario = _scenario(model=model, **({"bit_rate": 2e4} if model in (
        "point-to-point", "switched") else {}))
    events = netsim.run(scenario, engine="events", estimators=["compensated"], steps=15,
                        trials=1)
    vector = netsim.run(scenario, engine="vectorised", estimators=["compensated"],
                        steps=15, trials=1)
    a, b = events["compensated"], vector["compensated"]
    np.testing.assert_allclose(a.squared_errors, b.squared_errors, rtol=1e-9, atol=1e-12)
    assert [sorted(d) for d in a.drops] == [sorted(d) for d in b.drops]
    assert all(reason.startswith("medium: ") for d in a.drops for *_, reason in d)


def test_tau_cannot_be_overridden_on_a_medium():
    with pytest.raises(ScenarioError, match="^delays.tau: cannot override tau: "
                       r"\[network.medium\]"):
        _scenario().with_tau(2)
