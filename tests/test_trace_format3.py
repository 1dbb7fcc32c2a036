"""Trace format 3 reads as format 2: the reader's expansion against the format-2 recorder.

Each case writes one event-kernel run twice, with ``TraceRecorder(trace_format=2)`` and
``trace_format=3``, and reads both back with :func:`netsim.traces.reader.read_trace`:
the format-3 file (one message per step and kind) must give the format-2 view the
format-2 file gives -- the same topics and counts, per topic the same records (log_time,
publish_time, MCAP sequence, message of the format-2 class), the same message order,
link events and arrays -- so everything downstream reads format 3 unchanged
(:mod:`netsim.traces.stepread`). A scripted run drives both recorders with hand-made
observer calls (NaN estimates, mixed payloads, zero and continuous latencies, every drop
kind, a growing layout); an interrupted run, the vectorised engine's format-3 file, the
reports (inspect, replay, analyze) and trace-driven delays read alike; damaged and
truncated format-3 files are read chunk by chunk.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from mcap_protobuf.decoder import DecoderFactory
from netsim.models.scenario import builtin_scenarios, parse_scenario
from netsim.models.seeding import child_sequence
from netsim.traces import schemas3
from netsim.traces.reader import read_trace
from netsim.traces.recorder import TraceRecorder
from netsim.traces.schemas import message_classes, parse_topic

from netsim import interrupt
from netsim.cli import main
from netsim.links import Message as LinkMessage
from netsim.runner import _traced_trial, family_of, run_trial, scenario_gains
from netsim.vectorised import run_batch
from tests.helpers import lcsys, with_delays

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
V2_TYPES = {"PlantState", "Measurement", "Estimate", "EstimatorUpdate", "Freshness",
            "LinkSent", "LinkDelivered", "LinkDropped"}


@cache
def lcsys_gains():
    return scenario_gains(lcsys())


def _lcsys_links(links: dict, delays: dict | None = None, **changes):
    data = tomllib.loads(builtin_scenarios()["lcsys2022-heterogeneous"].read_text())
    data["delays"] = delays or {"model": "none"}
    data["links"] = links
    scenario = parse_scenario(data, "lcsys-links.toml")
    return replace(scenario, **changes) if changes else scenario


def _example(name: str):
    path = EXAMPLES / name
    return parse_scenario(tomllib.loads(path.read_text()), str(path))


def _diverging():
    """A plant blown up by 1e10: the squared errors overflow to inf, the run stops."""
    scenario = lcsys()
    return replace(scenario, plant=replace(scenario.plant, A=scenario.plant.A * 1e10),
                   divergence_threshold=float("inf"))


#: case -> (scenario builder, family, steps, what the run must contain)
CASES = {
    "lcsys-compensated": (lcsys, "compensated", 60, {"delivered"}),
    # continuous latencies, Bernoulli loss, keep-latest buffer: drop-oldest victims and
    # superseded messages, arrivals between steps
    "latency-loss-keep-latest": (
        lambda: _lcsys_links({"delay": {"distribution": "gamma", "shape": 2.0, "scale": 0.7,
                                        "unit": "time"},
                              "loss": {"model": "bernoulli", "p": 0.15},
                              "buffer": {"capacity": 2, "policy": "keep-latest"}}),
        "compensated", 60,
        {"loss: bernoulli", "buffer full (drop-oldest)", "superseded (keep-latest)",
         "between steps"}),
    # zero latency on one link (delivered after the updates of its instant), keep-latest
    "zero-latency-keep-latest": (
        lambda: _lcsys_links({
            "delay": {"distribution": "uniform", "low": 0, "high": 4, "unit": "steps",
                      "mode": "asynchronous"},
            "buffer": {"capacity": 3, "policy": "keep-latest"},
            "per_link": [{"from": 0, "to": 1, "delay": {"distribution": "constant",
                                                        "value": 0.0, "unit": "time"}}]}),
        "compensated", 60, {"zero latency", "superseded (keep-latest)"}),
    "gilbert-elliott-drop-oldest": (
        lambda: _lcsys_links({"loss": {"model": "gilbert-elliott", "p": 0.1, "r": 0.4},
                              "buffer": {"capacity": 2, "policy": "drop-oldest"}},
                             {"model": "asynchronous", "tau": 4}),
        "uncompensated", 60, {"buffer full (drop-oldest)", "loss: gilbert-elliott (bad state)"}),
    # Ts = 0.1 (times not exact in binary), outages
    "sample-period-outage": (
        lambda: _lcsys_links({"delay": {"distribution": "uniform", "unit": "time",
                                        "low": 0.0, "high": 1.5},
                              "buffer": {"capacity": 2, "policy": "keep-latest"},
                              "outages": [[10, 14]]}, sample_period=0.1),
        "compensated", 40, {"outage", "between steps"}),
    "aoi": (lambda: _example("aoi-random-lossy.toml"), "aoi", 50, {"freshness", "link down"}),
    "block": (lambda: with_delays(lcsys(), model="homogeneous", tau=2), "block", 40,
              {"delivered"}),
    "centralized-kf": (lcsys, "centralized-kf", 30, set()),
    # payloads that are not the estimates (stored), a sensor without outputs
    "dkfe-payloads": (lambda: _example("dkfe-example2-lossy.toml"), "dkfe", 40,
                      {"stored payloads", "empty sensor"}),
    "diverging": (_diverging, "uncompensated", 40, {"diverged"}),
}


def _write_pair(folder: Path, name: str, scenario, family: str, steps: int,
                gains=None, **options) -> tuple[Path, Path]:
    if gains is None and family_of(family).traits().get("needs_gains"):
        gains = lcsys_gains()
    paths = []
    for fmt in (2, 3):
        path = folder / f"{name}.format{fmt}.mcap"
        with np.errstate(all="ignore"):
            _traced_trial(scenario, family_of(family), gains, scenario.seed, 0, steps,
                          str(path), True, None,
                          trace_options={"trace_format": fmt, "flush_every": 10,
                                         **options})
        paths.append(path)
    return paths[0], paths[1]


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("format3")
    return {name: _write_pair(folder, name, build(), family, steps)
            for name, (build, family, steps, _) in CASES.items()}


# -- comparing traces ------------------------------------------------------------------


def _same_message(expected, got) -> bool:
    """``got`` (format-2 class) equals ``expected`` (decoded from a format-2 file, whose
    class the decoder built from the file's schema); NaN-aware through the bytes."""
    as_class = type(got).FromString(expected.SerializeToString())
    return as_class == got or as_class.SerializeToString() == got.SerializeToString()


def _first_difference(a: list, b: list):
    for n, (x, y) in enumerate(zip(a, b, strict=False)):
        if x != y:
            return n, x, y
    return min(len(a), len(b)), len(a), len(b)


def _link_events(trace, link) -> list:
    """The link's events, payloads as bytes (NaN-aware)."""
    return [e._replace(payload=np.asarray(e.payload, dtype=float).tobytes())
            for e in trace.link_events(*link)]


def assert_same_view(old, new) -> None:
    """``new`` (format 3) reads as ``old`` (format 2) of the same run."""
    assert (old.format, new.format) == (2, 3)
    assert new.unexpanded == {} and new.note == "" and not new.damaged
    assert set(old.topics) == set(new.topics)
    assert old.topics == new.topics and old.counts == new.counts
    assert list(old.topics) == list(new.topics)  # registration order too
    assert old.file_topics == old.topics and old.file_counts == old.counts
    assert set(new.file_topics) <= set(schemas3.TOPICS)
    assert all(name.startswith(schemas3.PACKAGE + ".") for name in new.file_topics.values())
    assert sum(new.file_counts.values()) == new.recovered_messages
    classes = message_classes()
    for topic, records in old.records.items():
        got = new.records[topic]
        assert len(got) == len(records), topic
        for n, (x, y) in enumerate(zip(records, got, strict=True)):
            assert x[:4] == y[:4], (topic, n, x[:4], y[:4])
            short = old.topics[topic].rsplit(".", 1)[-1]
            assert type(y.message) is classes[short], (topic, type(y.message))
            assert _same_message(x.message, y.message), (topic, n, x.message, y.message)
    # the whole file's order: log_time, and the kernel's order on equal log_time
    a = [r[:4] for r in old.messages]
    b = [r[:4] for r in new.messages]
    assert a == b, _first_difference(a, b)
    assert old.links == new.links and old.agents == new.agents
    assert old.sensors == new.sensors and old.steps == new.steps
    assert (old.n_agents, old.n_states) == (new.n_agents, new.n_states)
    assert old.drop_reasons == new.drop_reasons
    for link in old.links:
        ea, eb = _link_events(old, link), _link_events(new, link)
        assert ea == eb, (link, _first_difference(ea, eb))
    for method in ("states", "estimates", "squared_errors", "effective_delays", "freshness"):
        x, y = getattr(old, method)(), getattr(new, method)()
        assert x.shape == y.shape, method
        np.testing.assert_array_equal(x, y, err_msg=method)
    for i in old.sensors:
        np.testing.assert_array_equal(old.measurements(i), new.measurements(i))
    assert set(old.matrices) == set(new.matrices)
    for name, matrix in old.matrices.items():
        np.testing.assert_array_equal(matrix, new.matrices[name], err_msg=name)


def _features(trace) -> set[str]:
    """What a format-2 trace holds (the premise of a case)."""
    out = set()
    for link in trace.links:
        for e in trace.link_events(*link):
            out.add(e.event)
            if e.event == "dropped":
                out.add(e.reason)
            if e.event == "delivered" and e.arrival_time == e.send_time:
                out.add("zero latency")
            if e.event == "delivered" and (e.arrival_time / trace.sample_period) % 1:
                out.add("between steps")
    if any(t.endswith("/freshness") for t in trace.topics):
        out.add("freshness")
    if (trace.status or {}).get("status") == "diverged":
        out.add("diverged")
    if any(len(m.values) == 0 for i in trace.sensors
           for m in trace.topic(trace.sensor_topic(i))):
        out.add("empty sensor")
    sent = [m for link in trace.links for m in trace.topic(trace.link_topics(*link)[0])]
    estimates = trace.estimates()
    if any(len(m.payload) != trace.n_states or not np.array_equal(
            m.payload, estimates[m.sent_step, m.sender]) for m in sent):
        out.add("stored payloads")
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_format3_reads_as_format2_of_the_same_run(pairs, name):
    old_path, new_path = pairs[name]
    old, new = read_trace(old_path), read_trace(new_path)
    assert CASES[name][3] <= _features(old), _features(old)
    assert new.library.startswith("netsim-trace/3 ")
    assert len(new.file_topics) < len(new.topics) or not new.links
    assert_same_view(old, new)


def test_payloads_not_recorded_read_alike(tmp_path):
    old, new = (read_trace(p) for p in _write_pair(
        tmp_path, "no-payloads", CASES["dkfe-payloads"][0](), "dkfe", 20,
        record_payloads=False))
    assert new.metadata[schemas3.LAYOUT_METADATA]["payload"] == '"none"'
    assert all(not m.payload for link in old.links
               for m in old.topic(old.link_topics(*link)[0]))
    assert_same_view(old, new)


def _report(capsys, command: str, path: Path) -> dict:
    assert main([command, str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    for key in ("path", "trace_format", "recovered_messages", "file_topics"):
        data.pop(key, None)
    data.get("status_detail", {}).pop("messages", None)  # what the file holds
    return data


@pytest.mark.parametrize("name", ["latency-loss-keep-latest", "aoi", "dkfe-payloads"])
def test_reports_are_the_same_for_both_formats(pairs, name, capsys):
    old_path, new_path = pairs[name]
    for command in ("inspect", "replay", "analyze"):
        assert _report(capsys, command, old_path) == _report(capsys, command, new_path), \
            command


def test_trace_driven_delays_read_format3(pairs, capsys):
    """A scenario replaying the links of the format-3 file runs as from the format-2 one."""
    results = []
    base = (ROOT / "models" / "scenarios" / "lcsys2022-heterogeneous.toml").read_text()
    for source in pairs["latency-loss-keep-latest"]:
        scenario = source.with_suffix(".toml")
        scenario.write_text(base + f'\n[links]\ndelay = {{ distribution = "trace", '
                            f'file = "{source}" }}\n')
        assert main(["run", str(scenario), "--estimators", "compensated", "--steps", "40",
                     "--trials", "1", "--json", "--no-progress"]) == 0, capsys.readouterr().err
        results.append(json.loads(capsys.readouterr().out)["estimators"]["compensated"])
    assert results[0] == results[1]


@pytest.mark.parametrize("family", ["compensated", "block"])
def test_vectorised_format3_reads_as_the_kernels_format2(tmp_path, family):
    """The vectorised engine's format-3 file (written from the batch arrays) reads as the
    event kernel's format-2 file of the same trial: the same records, times, sequences
    and link events; estimates and payloads to round-off."""
    scenario = CASES["latency-loss-keep-latest"][0]()
    gains = lcsys_gains()
    batch = run_batch(scenario, family, gains, [child_sequence(scenario.seed, "trial", 0)],
                      40, record_estimates=True)
    kernel, vector = tmp_path / "kernel2.mcap", tmp_path / "vector3.mcap"
    _traced_trial(scenario, family_of(family), gains, scenario.seed, 0, 40, str(kernel),
                  True, None, trace_options={"trace_format": 2})
    _traced_trial(scenario, family_of(family), gains, scenario.seed, 0, 40, str(vector),
                  True, None, batch=batch, batch_trial=0, trace_options={"trace_format": 3})
    old, new = read_trace(kernel), read_trace(vector)
    assert new.format == 3 and new.unexpanded == {}
    assert old.topics == new.topics and old.counts == new.counts
    assert {t: [r[:4] for r in rs] for t, rs in old.records.items()} == \
        {t: [r[:4] for r in rs] for t, rs in new.records.items()}
    for link in old.links:
        assert [e._replace(payload=[]) for e in old.link_events(*link)] == \
            [e._replace(payload=[]) for e in new.link_events(*link)], link
    np.testing.assert_allclose(new.estimates(), old.estimates(), rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(new.effective_delays(), old.effective_delays())


class _Interrupting(TraceRecorder):
    """A recorder requesting a graceful stop (the first Ctrl-C) while step 12 runs."""

    def on_plant(self, k, state, measurements):
        super().on_plant(k, state, measurements)
        if k == 12:
            interrupt._requested = True


def test_interrupted_run_reads_alike(tmp_path, monkeypatch):
    """The run stops after the deliveries due at step 13 (before its plant step): the
    deliveries after the last plant step are read back too."""
    scenario = CASES["latency-loss-keep-latest"][0]()
    seed = child_sequence(scenario.seed, "trial", 0)
    paths = []
    for fmt in (2, 3):
        path = tmp_path / f"interrupted{fmt}.mcap"
        monkeypatch.setattr(interrupt, "_requested", False)
        with pytest.raises(KeyboardInterrupt):
            with _Interrupting.for_run(path, scenario, lcsys_gains(), "compensated", 0,
                                       steps=40, trace_format=fmt) as recorder:
                run_trial(scenario, "compensated", lcsys_gains(), seed, 40,
                          observer=recorder)
        paths.append(path)
    monkeypatch.setattr(interrupt, "_requested", False)
    old, new = read_trace(paths[0]), read_trace(paths[1])
    assert old.status["status"] == "interrupted" and old.steps[-1] == 12
    last = max(e.arrival_time for link in old.links
               for e in old.link_events(*link, "delivered"))
    assert 12 < last / scenario.sample_period <= 13
    assert_same_view(old, new)


# -- a scripted run: the observer calls made by hand --------------------------------------

TS = 0.5
EARLY, STEP, LATE = 0, 1, 2
END = 5  # the last step of the scripted run
#: link -> behaviour; (1, 0) is used from step 3 on (the layout grows)
SCRIPT_LINKS = [(0, 1), (0, 2), (1, 2), (2, 0), (1, 0)]


def _scripted_calls() -> list[tuple]:
    """Observer calls of a 3-agent run in the kernel's order (see netsim.vectrace):

    - 0 -> 1 zero latency (delivered after the updates of its instant), lost at step 4;
    - 0 -> 2 one step of delay; its step-2 delivery refused (stale);
    - 1 -> 2 continuous latency 0.7 Ts, but 2.6 Ts at step 2: that message is superseded
      (keep-latest) by the one of step 3;
    - 2 -> 0 payload 2 x-hat (stored), delay 2 steps, capacity 2 (drop-oldest: step 2
      cancels the message of step 0 in flight);
    - 1 -> 0 from step 3 on, one step of delay.
    Agent 2 skips step 3; agent 1's estimate of step 3 holds NaN and -0.0; agents 0 and 1
    report freshness; agent 1 reports neighbour 0 only, then none at step 4. The run ends
    at step 5: messages arriving later are never delivered.
    """
    rng = np.random.default_rng(3)
    x = rng.normal(size=(6, 2))
    est = rng.normal(size=(6, 3, 2))
    est[3, 1] = [np.nan, -0.0]
    sequence = {link: 0 for link in SCRIPT_LINKS}
    events: list[tuple] = []  # (time in steps, phase, order, hook, arguments)

    def message(link, k, payload, wait, d):
        m = LinkMessage(link[0], link[1], k, sequence[link], payload, k * TS,
                        (k + wait) * TS, d)
        sequence[link] += 1
        return m

    cancelled = {(2, 0): {0}}  # link -> steps whose message drop-oldest cancels
    for k in range(END + 1):
        events.append((k, STEP, (-1,), "on_plant", (k, x[k], [x[k][:1], x[k], np.zeros(0)])))
        for i in range(3):
            if i == 2 and k == 3:
                continue
            delays = {0: {2: -1 if k < 3 else k - 3, 1: 0} if k >= 4 else {2: -1},
                      1: {} if k == 4 else {0: min(k, 1) - 1 if k else -1},
                      2: {1: -1, 0: 0 if k else -1}}[i]
            events.append((k, STEP, (i, 0), "on_update", (i, k, est[k, i], delays)))
            if i < 2:
                size = 2 - i
                fresh = [k - 1 if k else -1] * size
                events.append((k, STEP, (i, 1), "on_freshness",
                               (i, k, fresh, [-1] * size, [1] * size)))
            out = [l_ for l_ in SCRIPT_LINKS if l_[0] == i and (l_ != (1, 0) or k >= 3)]
            for o, link in enumerate(out):
                payload = 2 * est[k, i] if link == (2, 0) else est[k, i]
                order = (i, 2, o)
                if link == (0, 1):
                    m = message(link, k, payload, 0.0, 0)
                    events.append((k, STEP, order, "on_sent", (m,)))
                    if k == 4:
                        events.append((k, STEP, order + (1,), "on_dropped",
                                       (m, "loss: bernoulli", k * TS)))
                    else:
                        events.append((k, LATE, (i, o), "on_delivered", (m, True)))
                elif link in ((0, 2), (1, 0)):
                    m = message(link, k, payload, 2.0, 1)
                    events.append((k, STEP, order, "on_sent", (m,)))
                    if k + 2 <= END:
                        events.append((k + 2, EARLY, (k, i, o), "on_delivered",
                                       (m, not (link == (0, 2) and k == 2))))
                elif link == (1, 2):
                    wait = 2.6 if k == 2 else 0.7
                    m = message(link, k, payload, wait, 2 if k == 2 else 0)
                    events.append((k, STEP, order, "on_sent", (m,)))
                    if k == 2:  # arrives after the message of step 3
                        events.append((k + wait, EARLY, (k, i, o), "on_dropped",
                                       (m, "superseded (keep-latest)", (k + wait) * TS)))
                    elif k + wait <= END:
                        events.append((k + wait, EARLY, (k, i, o), "on_delivered", (m, True)))
                else:  # (2, 0)
                    m = message(link, k, payload, 3.0, 2)
                    events.append((k, STEP, order, "on_sent", (m,)))
                    if k in cancelled[link]:
                        events.append((k + 2, STEP, order + (2,), "on_dropped",
                                       (m, "buffer full (drop-oldest)", (k + 2) * TS)))
                    elif k + 3 <= END:
                        events.append((k + 3, EARLY, (k, i, o), "on_delivered", (m, True)))
    events.sort(key=lambda e: (e[0], e[1], e[2]))
    return [(hook, args) for _, _, _, hook, args in events]


def _record_script(path: Path, fmt: int) -> None:
    with TraceRecorder(path, scenario_metadata={"name": "scripted"}, matrices={},
                       family="scripted", trial=0, sample_period=TS, steps=END,
                       flush_every=2, trace_format=fmt) as recorder:
        for hook, args in _scripted_calls():
            getattr(recorder, hook)(*args)


def test_scripted_calls_read_alike(tmp_path):
    paths = [tmp_path / f"script{fmt}.mcap" for fmt in (2, 3)]
    for fmt, path in zip((2, 3), paths, strict=True):
        _record_script(path, fmt)
    old, new = read_trace(paths[0]), read_trace(paths[1])
    features = _features(old)
    assert {"zero latency", "between steps", "loss: bernoulli", "superseded (keep-latest)",
            "buffer full (drop-oldest)", "stored payloads", "freshness",
            "empty sensor"} <= features, features
    assert np.isnan(old.estimates()[3, 1, 0]) and np.isnan(old.estimates()[3, 2]).all()
    with open(paths[1], "rb") as f:
        layouts = [m for m in make_reader(f).iter_metadata()
                   if m.name == schemas3.LAYOUT_METADATA]
    assert len(layouts) > 1  # the layout grew (link 1 -> 0, agent 0's neighbour 1)
    # a zero-latency delivery at the last step, usable after it
    assert [e.sent_step for e in old.link_events(0, 1, "delivered")][-1] == END
    assert_same_view(old, new)


# -- the file itself ----------------------------------------------------------------------


def test_plain_mcap_reader_decodes_every_format3_message(pairs):
    _, path = pairs["latency-loss-keep-latest"]
    trace = read_trace(path)
    counts: dict[str, int] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for schema, channel, _, decoded in reader.iter_decoded_messages():
            assert schema.name == f"{schemas3.PACKAGE}.{schemas3.TOPICS[channel.topic]}"
            assert decoded.DESCRIPTOR.name == schemas3.TOPICS[channel.topic]
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        assert reader.get_summary().statistics.message_count == sum(counts.values())
    assert counts == trace.file_counts
    assert {parse_topic(t).kind for t in trace.topics} == {"plant", "sensor", "estimate",
                                                           "update", "link"}
    assert {name.rsplit(".", 1)[-1] for name in trace.topics.values()} <= V2_TYPES


def _chunks(path: Path) -> list[tuple[int, int, int]]:
    """(start, end, messages) of each chunk of a finished file."""
    out = []
    with open(path, "rb") as f:
        for index in make_reader(f).get_summary().chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            n = sum(isinstance(r, Message) for r in breakup_chunk(chunk))
            out.append((index.chunk_start_offset,
                        index.chunk_start_offset + index.chunk_length, n))
    return out


def _step_records(trace, last_step: int) -> dict[str, list]:
    """The records of the per-step topics (not links) up to ``last_step``."""
    return {t: [(r[:4], r.message.SerializeToString()) for r in recs
                if r.message.step <= last_step]
            for t, recs in trace.records.items() if parse_topic(t).kind != "link"}


def test_truncated_format3_file_reads_its_complete_chunks(pairs, tmp_path):
    old_path, path = pairs["latency-loss-keep-latest"]
    chunks = _chunks(path)
    assert len(chunks) >= 4
    data = path.read_bytes()
    cut = len(data) // 2
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(data[:cut])
    trace = read_trace(damaged)
    assert trace.truncated and trace.status is None and trace.format == 3
    assert trace.recovered_messages == sum(n for _, end, n in chunks if end <= cut) > 0
    assert trace.unexpanded == {}  # a delivery's sent message is never in a later chunk
    full = read_trace(old_path)
    last = trace.steps[-1]
    assert 0 < last < full.steps[-1]
    assert trace.steps == list(range(last + 1))
    assert _step_records(trace, last) == _step_records(full, last)
    # the drop_reasons record is written once, at close: a file cut short has none,
    # and its drops carry unnamed codes ("reason <code>")
    assert trace.drop_reasons == {} and full.drop_reasons
    named = {f"reason {code}": text for code, text in full.drop_reasons.items()}
    for link in trace.links:  # the link events of the kept chunks, as recorded
        kept = [e._replace(reason=named.get(e.reason, e.reason))
                for e in trace.link_events(*link)]
        assert kept and all(e in full.link_events(*link) for e in kept)


def test_damaged_format3_chunk_is_skipped_and_counted(pairs, tmp_path):
    """A lost chunk in the middle: its steps are missing, deliveries of later chunks
    whose sent message it held are left out and counted, everything else is read."""
    old_path, path = pairs["latency-loss-keep-latest"]
    chunks = _chunks(path)
    data = bytearray(path.read_bytes())
    start, end, _ = chunks[2]
    data[end - 40] ^= 0xFF
    data[end - 41] ^= 0x5A
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    trace = read_trace(bad)
    assert not trace.truncated and trace.damaged
    [lost] = trace.lost_chunks
    assert (lost.index, lost.offset, lost.messages) == (2, start, chunks[2][2])
    full = read_trace(old_path)
    gone = set(full.steps) - set(trace.steps)
    assert gone and set(trace.steps) < set(full.steps)
    assert trace.unexpanded.get("delivered", 0) > 0
    assert "delivered" in trace.note and "could not be rebuilt" in trace.note
    # every step that was kept reads as recorded
    kept = {k for k in trace.steps}
    for topic, records in trace.records.items():
        if parse_topic(topic).kind == "link":
            continue
        expected = [(r[:4], r.message.SerializeToString()) for r in full.records[topic]
                    if r.message.step in kept]
        assert [(r[:4], r.message.SerializeToString()) for r in records] == expected, topic
    assert read_trace(bad).estimates().shape == full.estimates().shape


@pytest.mark.parametrize("layout", ["C", "F", "mixed"])
@pytest.mark.parametrize("steps,first", [(40, 1), (3000, 1), (300, 10**6)])
def test_deliveries_order_is_the_stable_sort_by_usable_step(steps, first, layout):
    """The bulk path's delivery order (packed int32 keys when they fit, the stable
    argsort beyond) is the order the format defines: by usable step, then link, then
    sent step; written out here as a plain sort of tuples."""
    from netsim.vectrace import _in_usable_order

    rng = np.random.default_rng(steps)
    L, S = 7, steps
    usable = np.arange(first, first + S)[None, :] + rng.integers(0, 5, size=(L, S))
    # (the last case's keys need more than 31 bits)
    assert ((usable.max() + 1) * 2 * L * S >= 2**31) == (first > 1)
    delivered = rng.random((L, S)) < 0.8
    flags = rng.random((L, S)) < 0.5
    chosen = sorted((usable[l_, q], l_, q) for l_ in range(L) for q in range(S)
                    if delivered[l_, q])
    expected = [flags[l_, q] for _, l_, q in chosen]
    steps = first + S + 6
    expected_counts = [0] * steps
    for u, _, _ in chosen:
        expected_counts[u] += 1
    first_usable = np.arange(first, first + S)
    delay = usable - first_usable[None, :]
    if layout != "C":  # the schedule's arrays are send-major: column-major (L, S) views
        delay, flags = np.asfortranarray(delay), np.asfortranarray(flags)
        if layout == "F":
            delivered = np.asfortranarray(delivered)
    ordered, counts = _in_usable_order(delay, first_usable, delivered, flags, steps)
    assert ordered.tolist() == expected
    assert counts.tolist() == expected_counts
