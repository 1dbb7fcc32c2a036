"""The vectorised engine traces a run exactly as the event kernel does.

:mod:`netsim.vectrace` replays a trial of a vectorised batch as the kernel's observer
calls. For the same trial of the same scenario, both engines must make the same calls
(hooks, order, integer fields, drop reasons, acceptance, times) with floats within
1e-9 relative to 1 + |x_k|, and the MCAP files written from them must read back the
same (topics, counts, log/publish times, payloads).
"""

from __future__ import annotations

import json
from dataclasses import replace
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from netsim.models.scenario import parse_scenario
from netsim.models.seeding import child_sequence
from netsim.traces.reader import read_trace
from netsim.traces.recorder import TraceRecorder

from netsim import interrupt
from netsim.runner import choose_engine, run_monte_carlo, run_trial
from netsim.vectorised import run_batch
from netsim.vectrace import replay_trial, trial_events, write_trial
from tests.helpers import lcsys, with_delays
from tests.test_vectorised import random_case

TOLERANCE = 1e-9
FAMILIES = ("compensated", "uncompensated", "block", "centralized-kf")


@lru_cache(maxsize=1)
def lcsys_gains():
    from netsim.runner import scenario_gains

    return scenario_gains(lcsys())


class CallLog:
    """Observer keeping every hook call (arrays copied)."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def on_plant(self, k, state, measurements):
        self.calls.append(("on_plant", k, np.array(state, dtype=float),
                           [np.array(y, dtype=float) for y in measurements]))

    def on_sent(self, message):
        self.calls.append(("on_sent", _message(message)))

    def on_delivered(self, message, accepted):
        self.calls.append(("on_delivered", _message(message), accepted))

    def on_dropped(self, message, reason="", drop_time=None):
        self.calls.append(("on_dropped", _message(message), reason, drop_time))

    def on_update(self, agent, k, estimate, delays):
        self.calls.append(("on_update", agent, k, np.array(estimate, dtype=float),
                           list(delays.items())))


def _message(m) -> tuple:
    return (m.sender, m.receiver, m.sent_step, m.sequence, m.send_time, m.arrival_time,
            m.delay_steps, np.array(m.payload, dtype=float))


def _close(a: np.ndarray, b: np.ndarray, scale: float, where: str) -> None:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, where
    finite = np.isfinite(a)
    np.testing.assert_array_equal(finite, np.isfinite(b), err_msg=where)
    np.testing.assert_array_equal(a[~finite], b[~finite], err_msg=where)  # inf signs, NaN
    if finite.any():
        diff = np.max(np.abs(a[finite] - b[finite]))
        assert diff <= TOLERANCE * scale, (where, diff, scale)


def _scales(calls: list[tuple]) -> dict[int, float]:
    """1 + the largest finite |x_k| or |estimate| at each step (round-off scale)."""
    scale: dict[int, float] = {}
    for call in calls:
        if call[0] == "on_plant":
            values = call[2]
        elif call[0] == "on_update":
            values = call[3]
        else:
            continue
        k = call[1] if call[0] == "on_plant" else call[2]
        finite = np.abs(values[np.isfinite(values)])
        scale[k] = max(scale.get(k, 1.0), 1.0 + (finite.max() if finite.size else 0.0))
    return scale


def assert_same_calls(kernel: list[tuple], vector: list[tuple], where: str = "") -> None:
    """Same hooks in the same order, integers exact, floats to 1e-9 of the step's scale."""
    names_a = [c[0] for c in kernel]
    names_b = [c[0] for c in vector]
    assert names_a == names_b, (where, _first_difference(names_a, names_b))
    scale = _scales(kernel)
    for n, (a, b) in enumerate(zip(kernel, vector, strict=True)):
        at = f"{where} call {n} {a[0]}"
        if a[0] == "on_plant":
            assert a[1] == b[1], at
            _close(a[2], b[2], scale[a[1]], at)
            assert len(a[3]) == len(b[3]), at
            for ya, yb in zip(a[3], b[3], strict=True):
                _close(ya, yb, scale[a[1]], at)
        elif a[0] == "on_update":
            assert a[1:3] == b[1:3], at
            _close(a[3], b[3], scale[a[2]], at)
            assert a[4] == b[4], at  # r_ij[k], in the estimator's neighbour order
        else:
            ma, mb = a[1], b[1]
            assert ma[:7] == mb[:7], (at, ma[:7], mb[:7])  # ids, times, delay: exact
            _close(ma[7], mb[7], scale[ma[2]], at)
            assert a[2:] == b[2:], (at, a[2:], b[2:])  # accepted / reason, drop time


def _first_difference(a: list, b: list) -> tuple:
    for n, (x, y) in enumerate(zip(a, b, strict=False)):
        if x != y:
            return n, a[max(0, n - 3): n + 3], b[max(0, n - 3): n + 3]
    return min(len(a), len(b)), len(a), len(b)


def engines_calls(scenario, family, gains, seeds, steps, trial):
    """The observer calls of one trial: event kernel, vectorised replay (and the batch)."""
    log = CallLog()
    run_trial(scenario, family, gains, seeds[trial], steps, record_delays=False, observer=log)
    batch = run_batch(scenario, family, gains, seeds, steps, record_estimates=True)
    replayed = CallLog()
    replay_trial(batch, trial, scenario, family, replayed)
    return log.calls, replayed.calls, batch


def assert_engines_trace_alike(scenario, family, gains, steps, trials=2, seed=0):
    seeds = [child_sequence(seed, "trial", t) for t in range(trials)]
    batch = run_batch(scenario, family, gains, seeds, steps, record_estimates=True)
    for t in range(trials):
        log = CallLog()
        run_trial(scenario, family, gains, seeds[t], steps, record_delays=False, observer=log)
        replayed = CallLog()
        replay_trial(batch, t, scenario, family, replayed)
        assert_same_calls(log.calls, replayed.calls, f"{family} trial {t}")


# -- scenarios ----------------------------------------------------------------------------


def _links_scenario(links: dict, delays: dict | None = None, **run) -> object:
    """A small random-plant scenario (N = 4, n = 2) with a [links] table."""
    rng = np.random.default_rng(7)
    n = 2
    A = rng.normal(size=(n, n))
    A *= 0.95 / np.max(np.abs(np.linalg.eigvals(A)))
    data = {
        "name": "links",
        "run": {"steps": 60, "trials": 2, "seed": 3, **run},
        "plant": {"A": A.tolist(), "C": [rng.normal(size=(1, n)).tolist() for _ in range(4)],
                  "Q": 0.01, "R": 0.01},
        "network": {"topology": "random", "agents": 4, "seed": 5, "edge_probability": 0.6,
                    "weights": "random"},
        "delays": delays or {"model": "asynchronous", "tau": 3, "seed": 1},
        "gains": {"method": "lmi"},
        "links": {"seed": 11, **links},
    }
    return parse_scenario(data, "test")


def _small_gains(scenario):
    rng = np.random.default_rng(1)
    return SimpleNamespace(L=[0.3 * rng.normal(size=(scenario.plant.n_states, C.shape[0]))
                              for C in scenario.plant.C])


LINK_CASES = {
    "bernoulli-loss": {"loss": {"model": "bernoulli", "p": 0.3}},
    "gilbert-elliott": {"loss": {"model": "gilbert-elliott", "p": 0.2, "r": 0.3}},
    "drop-tail": {"buffer": {"capacity": 1, "policy": "drop-tail"},
                  "delay": {"distribution": "uniform", "low": 0, "high": 4}},
    "drop-oldest": {"buffer": {"capacity": 2, "policy": "drop-oldest"},
                    "delay": {"distribution": "uniform", "low": 0, "high": 5}},
    "keep-latest": {"buffer": {"capacity": 3, "policy": "keep-latest"},
                    "delay": {"distribution": "geometric", "p": 0.3}},
    "outage": {"outages": [[10, 25]], "loss": {"model": "bernoulli", "p": 0.1}},
    "gamma-latency": {"delay": {"distribution": "gamma", "shape": 2.0, "scale": 0.6,
                                "shift": 0.4, "mode": "asynchronous"}},
    "zero-latency": {"delay": {"distribution": "uniform", "unit": "time", "low": 0.0,
                               "high": 1.5}, "buffer": {"capacity": 2,
                                                        "policy": "keep-latest"}},
    "constant-zero-time": {"delay": {"distribution": "constant", "value": 0.0,
                                     "unit": "time"}},
    "per-link": {"per_link": [{"from": 0, "to": 1, "loss": {"model": "bernoulli", "p": 0.5},
                               "buffer": {"capacity": 1, "policy": "drop-oldest"}}]},
}


@pytest.mark.parametrize("case", sorted(LINK_CASES))
@pytest.mark.parametrize("family", ["compensated", "uncompensated", "block"])
def test_link_models_trace_alike(case, family):
    scenario = _links_scenario(LINK_CASES[case])
    assert_engines_trace_alike(scenario, family, _small_gains(scenario), 45)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("delays", [
    {"model": "homogeneous", "tau": 3},
    {"model": "heterogeneous", "tau": 6, "seed": 2022},
    {"model": "asynchronous", "tau": 4},
    {"model": "synchronous", "tau": 3},
    {"model": "latency", "default": 1.7},
])
def test_lcsys2022_traces_alike(family, delays):
    scenario = with_delays(lcsys(), **delays)
    assert_engines_trace_alike(scenario, family, lcsys_gains(), 40)


def test_sample_period_scales_every_time():
    scenario = replace(_links_scenario(LINK_CASES["gamma-latency"]), sample_period=0.25)
    assert_engines_trace_alike(scenario, "compensated", _small_gains(scenario), 40)


def test_divergence_stops_both_traces_at_the_same_event():
    """The uncompensated estimator diverges: no events after the monitor at k_d (except
    deliveries still due at k_d), in both engines."""
    scenario = replace(with_delays(lcsys(), model="asynchronous", tau=3),
                       divergence_threshold=20.0)
    seeds = [child_sequence(2, "trial", t) for t in range(2)]
    kernel, vector, batch = engines_calls(scenario, "uncompensated", lcsys_gains(), seeds,
                                          300, 0)
    diverged_at = batch.results[0].diverged_at
    assert diverged_at is not None and diverged_at < 300
    assert_same_calls(kernel, vector, "diverged")
    plants = [c[1] for c in vector if c[0] == "on_plant"]
    assert plants[-1] == diverged_at


def test_zero_latency_deliveries_follow_the_updates():
    """A message with zero latency arrives at its sending instant, after all updates."""
    scenario = _links_scenario(LINK_CASES["constant-zero-time"])
    seeds = [child_sequence(0, "trial", 0)]
    kernel, vector, _ = engines_calls(scenario, "compensated", _small_gains(scenario), seeds,
                                      5, 0)
    assert_same_calls(kernel, vector)
    names = [c[0] for c in vector]
    last_update = max(n for n, c in enumerate(vector) if c[0] == "on_update" and c[2] == 5)
    assert "on_delivered" in names[last_update:]


def test_events_helper_lists_the_calls():
    scenario = with_delays(lcsys(), model="homogeneous", tau=2)
    seeds = [child_sequence(0, "trial", 0)]
    batch = run_batch(scenario, "block", lcsys_gains(), seeds, 10)
    calls = trial_events(batch, 0, scenario, "block")
    updates = [c for c in calls if c[0] == "on_update"]
    first = [c[4] for c in updates if c[2] == 0]
    assert all(d and set(d.values()) == {-1} for d in first)  # step 0: nothing arrived
    assert all(c[4] == {} for c in updates if c[2] % 3)  # block: no update between


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_case())
def test_random_scenarios_trace_alike(case):
    scenario, family, gains, steps = case
    assert_engines_trace_alike(scenario, family, gains, steps, trials=2, seed=scenario.seed)


# -- MCAP files ---------------------------------------------------------------------------


def _fields(message) -> dict:
    return {f.name: v for f, v in message.ListFields()}


def assert_same_files(path_a, path_b, *more) -> None:
    """Both files hold the same trace: metadata, attachments, topics, counts, and per
    topic the same messages in the same order (times, sequence, every field; floats to
    round-off). Files of the bulk path (``write_trial``) group a window's messages by
    type, so messages of different topics at one log_time may be in another order in
    the file: the order across topics is compared as the multiset of (log_time,
    topic) per instant."""
    for other in more:
        assert_same_files(path_a, other)
    a, b = read_trace(path_a), read_trace(path_b)
    assert not a.truncated and not b.truncated
    assert not a.damaged and not b.damaged
    if a.format == 3:  # the engines may list links and update entries in another order
        la, lb = a.metadata["trace_layout"], b.metadata["trace_layout"]
        assert la.keys() == lb.keys()
        for key in la:
            va, vb = json.loads(la[key]), json.loads(lb[key])
            assert (sorted(va) if key in ("links", "updates") else va) == (
                sorted(vb) if key in ("links", "updates") else vb), key
        assert {k: v for k, v in a.metadata.items() if k != "trace_layout"} == {
            k: v for k, v in b.metadata.items() if k != "trace_layout"}
    else:
        assert a.metadata == b.metadata
    assert a.attachments == b.attachments
    assert a.topics == b.topics
    assert a.counts == b.counts
    ka = sorted((r.log_time, r.topic, r.publish_time, r.sequence) for r in a.messages)
    kb = sorted((r.log_time, r.topic, r.publish_time, r.sequence) for r in b.messages)
    assert ka == kb
    scale = 1.0 + np.nanmax(np.abs(np.nan_to_num(a.states(), posinf=0, neginf=0)))
    assert a.records.keys() == b.records.keys()
    for topic, records in a.records.items():
        assert len(records) == len(b.records[topic]), topic
        for ra, rb in zip(records, b.records[topic], strict=True):
            assert (ra.log_time, ra.publish_time, ra.sequence) == (
                rb.log_time, rb.publish_time, rb.sequence), topic
            _same_message(ra, rb, scale)


def _same_message(ra, rb, scale) -> None:
    fa, fb = _fields(ra.message), _fields(rb.message)
    assert fa.keys() == fb.keys(), ra.topic
    for name, va in fa.items():
        vb = fb[name]
        if isinstance(va, float) or (hasattr(va, "__len__") and len(va)
                                      and isinstance(va[0], float)):
            _close(np.asarray(va), np.asarray(vb),
                   scale * (1e3 if name == "squared_error" else 1.0),
                   f"{ra.topic} {name}")
        else:
            assert list(va) == list(vb) if hasattr(va, "__len__") and not isinstance(
                va, str) else va == vb, (ra.topic, name, va, vb)


def _write_both(tmp_path, scenario, family, gains, steps, trial=0, seed=0, trace_format=2):
    seeds = [child_sequence(seed, "trial", t) for t in range(trial + 1)]
    batch = run_batch(scenario, family, gains, seeds, steps, record_estimates=True)
    paths = []
    for engine in ("events", "vectorised", "bulk"):
        path = tmp_path / f"{engine}.mcap"
        recorder = TraceRecorder.for_run(path, scenario, gains if hasattr(gains, "K") else None,
                                         family, trial, seed=seed, steps=steps,
                                         trace_format=trace_format)
        with recorder:
            if engine == "events":
                result = run_trial(scenario, family, gains, seeds[trial], steps,
                                   record_delays=False, observer=recorder)
            elif engine == "vectorised":
                replay_trial(batch, trial, scenario, family, recorder)
                result = batch.results[trial]
            else:  # the bulk path the runner uses
                write_trial(batch, trial, scenario, family, recorder)
                result = batch.results[trial]
            if result.diverged_at is not None:
                recorder.set_status("diverged", diverged_at=result.diverged_at)
        paths.append(path)
    return paths


@pytest.mark.parametrize("trace_format", [2, 3])
@pytest.mark.parametrize("family", FAMILIES)
def test_mcap_files_read_back_the_same(tmp_path, family, trace_format):
    scenario = with_delays(lcsys(), model="asynchronous", tau=4)
    assert_same_files(*_write_both(tmp_path, scenario, family, lcsys_gains(), 60, trial=1,
                                   trace_format=trace_format))


@pytest.mark.parametrize("trace_format", [2, 3])
@pytest.mark.parametrize("case", ["drop-oldest", "keep-latest", "outage", "zero-latency",
                                  "gamma-latency", "bernoulli-loss", "per-link"])
def test_mcap_files_with_drops_read_back_the_same(tmp_path, case, trace_format):
    scenario = _links_scenario(LINK_CASES[case])
    assert_same_files(*_write_both(tmp_path, scenario, "compensated", _small_gains(scenario),
                                   50, trace_format=trace_format))


@pytest.mark.parametrize("trace_format", [2, 3])
def test_mcap_files_of_a_diverged_run_read_back_the_same(tmp_path, trace_format):
    scenario = replace(with_delays(lcsys(), model="homogeneous", tau=3),
                       divergence_threshold=50.0)
    paths = _write_both(tmp_path, scenario, "uncompensated", lcsys_gains(), 300,
                        trace_format=trace_format)
    assert read_trace(paths[1]).status["status"] == "diverged"
    assert read_trace(paths[2]).status["status"] == "diverged"
    assert_same_files(*paths)


# -- the runner ---------------------------------------------------------------------------


def test_auto_engine_traces_with_the_vectorised_engine():
    assert choose_engine("auto", ["compensated", "block"], traced=True) == "vectorised"
    assert choose_engine("vectorised", ["compensated"], traced=True) == "vectorised"
    assert choose_engine("events", ["compensated"], traced=True) == "events"


def test_traced_monte_carlo_writes_the_same_files_on_both_engines(tmp_path):
    scenario = with_delays(lcsys(), model="heterogeneous", tau=3, seed=2022)
    families = ("compensated", "block", "centralized-kf")
    results, written = {}, {}
    for engine in ("events", "vectorised"):
        out = tmp_path / engine
        out.mkdir()
        files: list[str] = []
        results[engine] = run_monte_carlo(
            scenario, steps=40, trials=2, seed=4, families=families, gains=lcsys_gains(),
            trace=str(out / "run.mcap"), on_trace=files.append, engine=engine)
        written[engine] = files
    names = [[p.rsplit("/", 1)[1] for p in written[e]] for e in ("events", "vectorised")]
    assert names[0] == names[1] and len(names[0]) == 6
    for a, b in zip(written["events"], written["vectorised"], strict=True):
        assert_same_files(a, b)
    for family in families:
        np.testing.assert_allclose(results["vectorised"].estimators[family].mse,
                                   results["events"].estimators[family].mse, rtol=1e-7)


class _Interrupting(CallLog):
    """Requests a graceful stop (as the first Ctrl-C does) while step ``at`` runs."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.at = at

    def on_plant(self, k, state, measurements):
        super().on_plant(k, state, measurements)
        if k == self.at:
            interrupt._requested = True


def test_a_graceful_interrupt_stops_both_engines_at_the_same_event(monkeypatch):
    scenario = _links_scenario(LINK_CASES["gamma-latency"])
    gains = _small_gains(scenario)
    seeds = [child_sequence(1, "trial", 0)]
    batch = run_batch(scenario, "compensated", gains, seeds, 40)
    logs = []
    for engine in ("events", "vectorised"):
        monkeypatch.setattr(interrupt, "_requested", False)
        log = _Interrupting(12)
        with pytest.raises(KeyboardInterrupt):
            if engine == "events":
                run_trial(scenario, "compensated", gains, seeds[0], 40, observer=log)
            else:
                replay_trial(batch, 0, scenario, "compensated", log)
        logs.append(log.calls)
    monkeypatch.setattr(interrupt, "_requested", False)
    assert_same_calls(*logs)
    assert logs[1][-1][0] == "on_delivered" and 12 < logs[1][-1][1][5] <= 13


def test_an_interrupt_between_windows_finishes_a_format3_trace(tmp_path, monkeypatch):
    """The bulk format-3 path checks for a graceful Ctrl-C between its windows: the file
    then ends with the last complete window, finished and indexed, status interrupted."""
    import netsim.vectrace as vectrace

    scenario = with_delays(lcsys(), model="asynchronous", tau=4)
    gains = lcsys_gains()
    seeds = [child_sequence(0, "trial", 0)]
    steps = 200
    batch = run_batch(scenario, "compensated", gains, seeds, steps, record_estimates=True)
    monkeypatch.setattr(vectrace, "ENCODE_BLOCK_BYTES", 8 * 1024)  # windows of ~10 steps
    path = tmp_path / "cut.mcap"
    recorder = TraceRecorder.for_run(path, scenario, gains, "compensated", 0, steps=steps,
                                     trace_format=3)
    flushes = []

    def flush(wait=True):
        flushes.append(recorder.last_step)
        TraceRecorder.flush(recorder, wait)
        monkeypatch.setattr(interrupt, "_requested", True)  # Ctrl-C after a window

    monkeypatch.setattr(recorder, "flush", flush)
    with pytest.raises(KeyboardInterrupt), recorder:
        write_trial(batch, 0, scenario, "compensated", recorder)
    monkeypatch.setattr(interrupt, "_requested", False)
    trace = read_trace(path)
    assert not trace.truncated and trace.status["status"] == "interrupted"
    assert flushes and 0 < flushes[0] < steps
    assert trace.steps == list(range(flushes[0] + 1))
    np.testing.assert_array_equal(trace.estimates(), batch.results[0].estimates[:flushes[0] + 1])


def test_a_stop_requested_between_replayed_traces_ends_the_batch_there(tmp_path):
    """A graceful stop requested while trial 0's trace is finished (as a Ctrl-C then
    does) stops before trial 1 is replayed, though the whole batch (here 30 trials)
    is already computed and each short trial is written in one window that never
    reaches the writer's own checks."""
    scenario = with_delays(lcsys(), model="heterogeneous", tau=3, seed=2022)
    written: list[str] = []

    def on_trace(path: str) -> None:
        written.append(path)
        interrupt._requested = True  # what the graceful SIGINT handler sets

    try:
        with pytest.raises(KeyboardInterrupt):
            run_monte_carlo(scenario, steps=20, trials=30, seed=1, families=["compensated"],
                            gains=lcsys_gains(), trace=str(tmp_path / "run.mcap"),
                            on_trace=on_trace, engine="vectorised")
    finally:
        interrupt._requested = False
    assert [p.rsplit("/", 1)[1] for p in written] == ["run.compensated.trial0.mcap"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.compensated.trial0.mcap"]
