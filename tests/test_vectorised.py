"""Differential tests: the vectorised engine against the SimPy event kernel.

The event kernel is the reference. For random scenarios (plant, graph, weights, gains,
delay model, per-link delay distributions, losses, outages, buffers, sample period)
and every estimator family, both engines must give, for the same seeds, the same
estimates to 1e-9 (relative to 1 + |x_k|), the same divergence step, the same
effective delays r_ij[k] and the same message counts and drop reasons.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from netsim.models.scenario import parse_scenario
from netsim.models.seeding import child_sequence

from netsim.runner import run_monte_carlo, run_trial
from netsim.vectorised import run_vectorised, simulate_plant
from tests.helpers import lcsys, with_delays

FAMILIES = ("compensated", "uncompensated", "block", "centralized-kf")
TOLERANCE = 1e-9


@lru_cache(maxsize=1)
def lcsys_gains():
    """The LMI gains of the LCSYS2022 scenario (they do not depend on the delays)."""
    from netsim.runner import scenario_gains

    return scenario_gains(lcsys())


def assert_engines_agree(scenario, family, gains, seeds, steps):
    """Run both engines on the same seeds and compare everything they report."""
    events = [run_trial(scenario, family, gains, s, steps, record_delays=True) for s in seeds]
    vector = run_vectorised(scenario, family, gains, seeds, steps, record_delays=True)
    assert len(vector) == len(events)
    for t, (a, b) in enumerate(zip(events, vector, strict=True)):
        where = f"{family}, trial {t}"
        assert a.diverged_at == b.diverged_at, where
        end = steps if a.diverged_at is None else a.diverged_at
        # round-off relative to the magnitudes in play at each step (a diverging
        # estimate amplifies its own round-off, not the state's)
        scale = 1.0 + np.maximum(np.nanmax(np.abs(a.states[: end + 1]), axis=1),
                                 np.nanmax(np.abs(np.nan_to_num(a.estimates[: end + 1],
                                                                posinf=0, neginf=0)),
                                           axis=(1, 2)))[:, None, None]
        np.testing.assert_array_equal(np.isnan(a.states), np.isnan(b.states), err_msg=where)
        assert np.nanmax(np.abs(a.states - b.states) / (1 + np.abs(a.states))) <= TOLERANCE
        for ya, yb in zip(a.measurements, b.measurements, strict=True):
            np.testing.assert_allclose(yb, ya, rtol=TOLERANCE, atol=TOLERANCE, err_msg=where)
        ea, eb = a.estimates[: end + 1], b.estimates[: end + 1]
        finite = np.isfinite(ea)
        np.testing.assert_array_equal(finite, np.isfinite(eb), err_msg=where)
        diff = np.abs(ea - eb)[finite] / np.broadcast_to(scale, ea.shape)[finite]
        assert diff.size == 0 or diff.max() <= TOLERANCE, (where, diff.max())
        assert np.all(np.isnan(b.estimates[end + 1:])), where
        np.testing.assert_array_equal(a.effective_delays, b.effective_delays, err_msg=where)
        for name in ("messages_sent", "messages_delivered", "messages_discarded",
                     "messages_dropped", "drop_reasons"):
            assert getattr(a, name) == getattr(b, name), (where, name)
        ok = np.isfinite(a.squared_errors) & np.isfinite(b.squared_errors)
        np.testing.assert_array_equal(np.isnan(a.squared_errors), np.isnan(b.squared_errors))
        steps_scale = np.broadcast_to(scale[:, :, 0], (end + 1, ok.shape[1]))
        ok = ok[: end + 1]
        err_a = np.sqrt(a.squared_errors[: end + 1][ok])
        err_b = np.sqrt(b.squared_errors[: end + 1][ok])
        assert np.all(np.abs(err_a - err_b) <= 10 * TOLERANCE * steps_scale[ok]), where


# -- random scenarios -------------------------------------------------------------------


def _random_plant(rng: np.random.Generator, n: int, sizes: list[int]) -> dict:
    A = rng.normal(size=(n, n))
    A *= rng.uniform(0.7, 1.06) / max(np.max(np.abs(np.linalg.eigvals(A))), 1e-9)
    return {
        "A": A.tolist(),
        "C": [rng.normal(size=(m, n)).tolist() for m in sizes],
        "Q": float(rng.uniform(0.001, 0.05)),
        "R": float(rng.uniform(0.001, 0.05)),
    }


def _delay_table(draw) -> dict:
    distribution = draw(st.sampled_from(["constant", "uniform", "geometric", "gamma",
                                         "pareto", "uniform-time"]))
    mode = draw(st.sampled_from(["asynchronous", "synchronous", "fixed"]))
    if distribution == "constant":
        return {"distribution": "constant", "value": draw(st.integers(0, 3)), "mode": mode}
    if distribution == "uniform":
        low = draw(st.integers(0, 2))
        return {"distribution": "uniform", "low": low, "high": low + draw(st.integers(0, 4)),
                "mode": mode}
    if distribution == "uniform-time":
        low = draw(st.floats(0.0, 2.0))
        return {"distribution": "uniform", "unit": "time", "low": low,
                "high": low + draw(st.floats(0.0, 3.0)), "mode": mode}
    if distribution == "geometric":
        return {"distribution": "geometric", "p": draw(st.floats(0.2, 0.9)), "mode": mode}
    if distribution == "gamma":
        return {"distribution": "gamma", "shape": draw(st.floats(0.5, 3.0)),
                "scale": draw(st.floats(0.2, 1.5)), "mode": mode}
    return {"distribution": "pareto", "alpha": draw(st.floats(1.5, 4.0)),
            "scale": draw(st.floats(0.2, 1.0)), "mode": mode}


def _link_settings(draw, *, delay: bool) -> dict:
    table: dict = {}
    if delay and draw(st.booleans()):
        table["delay"] = _delay_table(draw)
    loss = draw(st.sampled_from(["none", "bernoulli", "gilbert-elliott"]))
    if loss == "bernoulli":
        table["loss"] = {"model": "bernoulli", "p": draw(st.floats(0.0, 0.6))}
    elif loss == "gilbert-elliott":
        table["loss"] = {"model": "gilbert-elliott", "p": draw(st.floats(0.05, 0.5)),
                         "r": draw(st.floats(0.1, 0.9)), "loss_good": draw(st.floats(0, 0.2))}
    if draw(st.booleans()):
        policy = draw(st.sampled_from(["drop-tail", "drop-oldest", "keep-latest"]))
        table["buffer"] = {"policy": policy, "capacity": draw(st.integers(1, 3))}
    if draw(st.booleans()):
        start = draw(st.integers(0, 30))
        table["outages"] = [[start, start + draw(st.integers(0, 15))]]
    if draw(st.integers(0, 4)) == 0:
        table["bandwidth"] = draw(st.floats(100.0, 2000.0))
    return table


@st.composite
def random_case(draw):
    seed = draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    N = draw(st.integers(2, 5))
    n = draw(st.integers(1, 3))
    sizes = [draw(st.integers(1, 2)) for _ in range(N)]
    topology = draw(st.sampled_from(["cycle", "random"]))
    network = {"topology": topology, "agents": N, "seed": seed % 1000,
               "weights": draw(st.sampled_from(["random", "uniform", "lazy-metropolis"]))}
    if topology == "random":
        network["edge_probability"] = draw(st.floats(0.2, 0.8))
    model = draw(st.sampled_from(["none", "homogeneous", "heterogeneous", "synchronous",
                                  "asynchronous", "latency"]))
    delays: dict = {"model": model, "tau": draw(st.integers(0, 4)), "seed": seed % 997}
    if model == "none":
        del delays["tau"]  # no delays: a tau would be refused (drawn all the same)
    if model == "latency":
        delays = {"model": "latency", "default": draw(st.floats(0.0, 3.5))}
    data = {
        "name": "random",
        "run": {"steps": 60, "trials": 2, "seed": seed % 10007,
                "sample_period": draw(st.sampled_from([1.0, 0.5])),
                "divergence_threshold": draw(st.sampled_from([1e8, 1e3]))},
        "plant": _random_plant(rng, n, sizes),
        "network": network,
        "delays": delays,
        "gains": {"method": "lmi"},
    }
    if draw(st.booleans()):
        links = _link_settings(draw, delay=True)
        links["seed"] = seed % 991
        data["links"] = links
    scenario = parse_scenario(data, "hypothesis")
    if "links" in data and scenario.links and draw(st.booleans()):
        j, i = scenario.links[draw(st.integers(0, len(scenario.links) - 1))]
        entry = {"from": j, "to": i, **_link_settings(draw, delay=True)}
        data["links"]["per_link"] = [entry]
        scenario = parse_scenario(data, "hypothesis")
    # gains need not be stabilising: unstable ones exercise the divergence rule
    gains = SimpleNamespace(L=[rng.normal(scale=0.5, size=(n, m)) for m in sizes])
    family = draw(st.sampled_from(FAMILIES))
    steps = draw(st.integers(1, 70))
    return scenario, family, gains, steps


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_case())
def test_engines_agree_on_random_scenarios(case):
    scenario, family, gains, steps = case
    seeds = [child_sequence(scenario.seed, "trial", t) for t in range(3)]
    assert_engines_agree(scenario, family, gains, seeds, steps)


# -- the built-in scenarios --------------------------------------------------------------


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("delays", [
    {"model": "homogeneous", "tau": 8},
    {"model": "heterogeneous", "tau": 19, "seed": 2022},
    {"model": "asynchronous", "tau": 5},
    {"model": "synchronous", "tau": 5},
])
def test_engines_agree_on_lcsys2022(family, delays):
    scenario = with_delays(lcsys(), **delays)
    seeds = [child_sequence(11, "trial", t) for t in range(3)]
    assert_engines_agree(scenario, family, lcsys_gains(), seeds, 300)


def test_divergence_is_reported_at_the_same_step():
    """The uncompensated estimator on the unstable plant blows up; both engines agree when."""
    scenario = replace(with_delays(lcsys(), model="homogeneous", tau=3),
                       divergence_threshold=50.0)
    gains = lcsys_gains()
    seeds = [child_sequence(3, "trial", t) for t in range(3)]
    results = run_vectorised(scenario, "uncompensated", gains, seeds, 400)
    assert all(r.diverged_at is not None for r in results)
    assert_engines_agree(scenario, "uncompensated", gains, seeds, 400)


def test_plant_noise_is_the_kernels_stream():
    """States follow x_k = A x_{k-1} + nu_k with the kernel's draws (independent recursion)."""
    scenario = lcsys()
    seeds = [child_sequence(5, "trial", t) for t in range(2)]
    batch = simulate_plant(scenario, seeds, 20)
    plant = scenario.plant
    from netsim.models.seeding import stream

    for t, seed in enumerate(seeds):
        rng = stream(seed, "plant")
        x = plant.sample_initial(rng)
        for k in range(21):
            if k:
                x = plant.step(x, rng)
            ys = plant.measure(x, rng)
            np.testing.assert_allclose(batch.states[k, t], x, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(batch.measurements[k, t], np.concatenate(ys),
                                       rtol=1e-12, atol=1e-12)


def test_monte_carlo_summary_is_the_same_on_both_engines():
    scenario = with_delays(lcsys(), model="heterogeneous", tau=3, seed=2022)
    kwargs = dict(steps=150, trials=6, seed=4)
    events = run_monte_carlo(scenario, engine="events", gains=lcsys_gains(), **kwargs)
    vector = run_monte_carlo(scenario, engine="vectorised", gains=lcsys_gains(), **kwargs)
    assert events.engine == "events" and vector.engine == "vectorised"
    for family, summary in events.estimators.items():
        other = vector.estimators[family]
        assert summary.verdict == other.verdict
        np.testing.assert_allclose(other.mse, summary.mse, rtol=1e-7)
        assert summary.messages_sent == other.messages_sent
        assert summary.messages_delivered == other.messages_delivered
        assert summary.messages_discarded == other.messages_discarded


def test_same_seed_same_numbers_bit_for_bit():
    scenario = with_delays(lcsys(), model="asynchronous", tau=4)
    gains = lcsys_gains()
    seeds = [child_sequence(9, "trial", t) for t in range(3)]
    a = run_vectorised(scenario, "compensated", gains, seeds, 100)
    b = run_vectorised(scenario, "compensated", gains, seeds, 100)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.estimates, y.estimates)
        assert np.array_equal(x.squared_errors, y.squared_errors)


def test_batches_of_trials_give_the_trials_results(monkeypatch):
    """Splitting a Monte Carlo run into lockstep batches changes nothing but memory."""
    import netsim.vectorised as vectorised

    scenario = with_delays(lcsys(), model="asynchronous", tau=3)
    seeds = [child_sequence(2, "trial", t) for t in range(5)]
    whole = run_vectorised(scenario, "compensated", lcsys_gains(), seeds, 60,
                           record_delays=[3])
    monkeypatch.setattr(vectorised, "BATCH_ELEMENTS", 2 * len(scenario.links) * 62)
    calls = []
    split = run_vectorised(scenario, "compensated", lcsys_gains(), seeds, 60,
                           record_delays=[3], progress=calls.append)
    assert calls == [2, 2, 1]
    for t, (a, b) in enumerate(zip(whole, split, strict=True)):
        np.testing.assert_allclose(b.estimates, a.estimates, rtol=1e-12, atol=1e-12)
        assert (a.effective_delays is None) == (t != 3) == (b.effective_delays is None)
    np.testing.assert_array_equal(whole[3].effective_delays, split[3].effective_delays)


def test_engines_agree_on_trace_driven_links(tmp_path):
    """Links replaying a recorded trace (delays and drops, by sequence number)."""
    from netsim.models.scenario import parse_scenario

    base = lcsys()
    data = {
        "name": "recorded",
        "run": {"steps": 80, "trials": 1, "seed": 3},
        "plant": {"A": base.plant.A.tolist(), "C": [C.tolist() for C in base.plant.C],
                  "Q": 0.004, "R": 0.004},
        "network": {"P": np.asarray(base.weights).tolist()},
        "delays": {"model": "asynchronous", "tau": 3},
        "links": {"loss": {"model": "bernoulli", "p": 0.2},
                  "buffer": {"capacity": 2, "policy": "drop-oldest"}},
    }
    recorded = parse_scenario(data, str(tmp_path / "recorded.toml"))
    path = tmp_path / "recorded.mcap"
    run_monte_carlo(recorded, families=["compensated"], gains=lcsys_gains(),
                    trace=str(path), engine="events")
    data["delays"] = {"model": "none"}
    data["links"] = {"delay": {"distribution": "trace", "file": str(path)}}
    replayed = parse_scenario(data, str(tmp_path / "replayed.toml"))
    seeds = [child_sequence(8, "trial", t) for t in range(2)]
    for family in ("compensated", "uncompensated"):
        assert_engines_agree(replayed, family, lcsys_gains(), seeds, 80)
    dropped = run_vectorised(replayed, "compensated", lcsys_gains(), seeds, 80)
    assert all(r.messages_dropped > 0 for r in dropped)
