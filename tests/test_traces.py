"""MCAP trace recording, reading back, recovery and inspection (traces package)."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import textwrap
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory
from netsim.models.scenario import DelaySpec, resolve_scenario
from netsim.traces.inspect import delay_statistics, inspect_trace
from netsim.traces.reader import NOT_USED as TRACE_NOT_USED
from netsim.traces.reader import TraceError, read_trace
from netsim.traces.recorder import TRACE_FORMAT, TraceRecorder, to_ns, trace_path
from netsim.traces.schemas import (
    DEFAULT_TIME_ORIGIN_NS,
    MESSAGE_TYPES,
    file_descriptor_set,
    message_class,
)
from netsim.traces.schemas import PACKAGE as PACKAGE2

from netsim.kernel import NOT_USED
from netsim.runner import run_trial, scenario_gains

STEPS = 50
SEED = 7
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def setup():
    scenario = resolve_scenario("lcsys2022-time-varying").with_tau(4)
    return scenario, scenario_gains(scenario)


def _record(path, scenario, gains, observer_wrapper=None, family="compensated", **options):
    with TraceRecorder.for_run(path, scenario, gains, family, 0, seed=SEED, steps=STEPS,
                               **options) as recorder:
        observer = recorder if observer_wrapper is None else observer_wrapper(recorder)
        result = run_trial(scenario, family, gains, SEED, STEPS, record_delays=True,
                           record_messages=True, observer=observer)
    return recorder, result


@pytest.fixture(scope="module", params=[2, 3], ids=["format2", "format3"])
def recorded(setup, tmp_path_factory, request):
    """A kernel run recorded in each trace format (flushed every 5 steps)."""
    scenario, gains = setup
    path = tmp_path_factory.mktemp("trace") / "run.mcap"
    recorder, result = _record(path, scenario, gains, flush_every=5,
                               trace_format=request.param)
    return path, recorder, result


@pytest.fixture(scope="module")
def recorded2(setup, tmp_path_factory):
    """The run in format 2, whose file holds one message per event of the reader's view
    (the damage tests below pair file messages with read ones)."""
    scenario, gains = setup
    path = tmp_path_factory.mktemp("trace2") / "run.mcap"
    recorder, result = _record(path, scenario, gains, flush_every=5, trace_format=2)
    return path, recorder, result


# -- round trip -------------------------------------------------------------------------


def test_read_back_matches_trial_result(setup, recorded):
    scenario, gains = setup
    path, recorder, result = recorded
    trace = read_trace(path)
    assert not trace.truncated
    assert trace.recovered_messages == recorder.messages_written == sum(
        trace.file_counts.values())
    assert trace.status["status"] == "complete"
    assert trace.status["last_step"] == str(STEPS)
    assert trace.family == "compensated" and trace.trial == 0 and trace.seed == str(SEED)
    assert trace.run["trace_format"] == f"netsim-trace/{recorder.trace_format}"
    assert trace.format == recorder.trace_format
    assert trace.scenario["name"] == "lcsys2022-time-varying"
    assert json.loads(trace.scenario["delays"])["tau"] == 4
    assert trace.steps == list(range(STEPS + 1))
    assert trace.agents == [0, 1, 2, 3]
    assert trace.links == sorted(scenario.links)

    np.testing.assert_array_equal(trace.states(), result.states)
    for i in range(scenario.n_agents):
        np.testing.assert_array_equal(trace.measurements(i), result.measurements[i])
    np.testing.assert_array_equal(trace.estimates(), result.estimates)
    np.testing.assert_allclose(trace.squared_errors(), result.squared_errors, rtol=1e-13, atol=0)
    assert TRACE_NOT_USED == NOT_USED
    np.testing.assert_array_equal(trace.effective_delays(), result.effective_delays)
    for msg in trace.topic("/agent_2/update"):
        for r, s in zip(msg.effective_delay, msg.used_timestamp, strict=True):
            assert s == (msg.step - 1 - r if r >= 0 else -1)
    for msg in trace.topic("/agent_1/estimate"):
        assert msg.error_norm == pytest.approx(np.sqrt(msg.squared_error), rel=1e-15)

    sent = sum(len(trace.link_events(j, i, "sent")) for j, i in trace.links)
    delivered = [m for j, i in trace.links for m in trace.link_events(j, i, "delivered")]
    assert sent == result.messages_sent
    assert len(delivered) == result.messages_delivered == len(result.messages)
    assert sum(not m.accepted for m in delivered) == result.messages_discarded

    plant = scenario.plant
    np.testing.assert_array_equal(trace.matrices["A"], plant.A)
    np.testing.assert_array_equal(trace.matrices["P"], scenario.weights)
    np.testing.assert_array_equal(trace.matrices["Q"], plant.Q)
    for i in range(scenario.n_agents):
        np.testing.assert_array_equal(trace.matrices[f"C_{i}"], plant.C[i])
        np.testing.assert_array_equal(trace.matrices[f"R_{i}"], plant.R[i])
        np.testing.assert_array_equal(trace.matrices[f"K_{i}"], gains.K[i])
        np.testing.assert_array_equal(trace.matrices[f"L_{i}"], gains.L[i])


def test_link_events_match_kernel_messages(recorded):
    path, _, result = recorded
    trace = read_trace(path)
    # Deliveries, in delivery order, are exactly the kernel's recorded messages.
    by_time = [r.message for r in trace.messages
               if r.topic.startswith("/link_") and r.topic.endswith("/delivered")]
    assert len(by_time) == len(result.messages)
    for got, want in zip(by_time, result.messages, strict=True):
        assert (got.sender, got.receiver, got.sent_step, got.sequence, got.delay_steps) == (
            want.sender, want.receiver, want.sent_step, want.sequence, want.delay_steps)
        assert got.send_time == want.send_time and got.arrival_time == want.arrival_time
        assert got.usable_step == want.sent_step + 1 + want.delay_steps
    # Each sent event carries the payload that was transmitted.
    assert trace.records["/link_0_1/sent"]
    for record in trace.records["/link_0_1/sent"]:
        np.testing.assert_array_equal(record.message.payload,
                                      result.estimates[record.message.sent_step, 0])


def test_plain_mcap_reader_reads_the_file(setup, recorded):
    path, recorder, result = recorded
    if recorder.trace_format == 3:
        _plain_reader_reads_format3(path, recorder, result, setup[0].links)
        return
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == recorder.messages_written
        assert len(summary.chunk_indexes) > 5  # flushed regularly
        assert all(s.encoding == "protobuf" and s.name.startswith(PACKAGE2 + ".")
                   for s in summary.schemas.values())
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert set(metadata) == {"scenario", "run", "run_status"}
        attachments = {a.name: a for a in reader.iter_attachments()}
        assert "A.npy" in attachments and attachments["A.npy"].media_type == "application/x-npy"

        last = -1
        estimates = np.full_like(result.estimates, np.nan)
        ts = 1.0  # sample period of the scenario
        origin = DEFAULT_TIME_ORIGIN_NS
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            log_time_order=False
        ):
            assert message.log_time >= last, "messages must be in non-decreasing log_time"
            last = message.log_time
            if schema.name == f"{PACKAGE2}.Estimate":
                assert channel.topic == f"/agent_{decoded.agent}/estimate"
                estimates[decoded.step, decoded.agent] = decoded.estimate
                assert message.log_time == message.publish_time == origin + to_ns(
                    decoded.step * ts)
            elif schema.name.startswith(f"{PACKAGE2}.Link"):
                event = {"LinkSent": "sent", "LinkDelivered": "delivered",
                         "LinkDropped": "dropped"}[schema.name.rsplit(".", 1)[1]]
                assert channel.topic == f"/link_{decoded.sender}_{decoded.receiver}/{event}"
                assert message.publish_time == origin + to_ns(decoded.send_time)
                assert message.sequence == decoded.sequence
                if event == "delivered":
                    assert message.log_time == origin + to_ns(decoded.arrival_time)
                elif event == "sent":
                    assert message.log_time == origin + to_ns(decoded.send_time)
        np.testing.assert_array_equal(estimates, result.estimates)

    # A non-seeking (streaming) MCAP reader sees the same messages.
    with open(path, "rb") as f:
        count = sum(1 for _ in NonSeekingReader(f, validate_crcs=True).iter_messages(
            log_time_order=False))
    assert count == recorder.messages_written


def _plain_reader_reads_format3(path, recorder, result, scenario_links):
    """Format 3 with the plain reader: eight topics at most, one message per step each,
    every agent's estimate of step k in /agents/estimate (agent major)."""
    from netsim.traces.schemas3 import PACKAGE as PACKAGE3
    from netsim.traces.schemas3 import TOPICS

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary.statistics.message_count == recorder.messages_written
        assert len(summary.chunk_indexes) > 5  # flushed regularly
        assert {c.topic for c in summary.channels.values()} <= set(TOPICS)
        assert all(s.encoding == "protobuf" and s.name.startswith(PACKAGE3 + ".")
                   for s in summary.schemas.values())
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert set(metadata) == {"scenario", "run", "run_status", "trace_layout"}
        links = {tuple(link) for link in json.loads(metadata["trace_layout"]["links"])}
        assert links == set(scenario_links) and len(links) == len(scenario_links)
        estimates = np.full_like(result.estimates, np.nan)
        N, n = result.estimates.shape[1:]
        for _, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=False):
            assert message.sequence == decoded.step
            assert message.log_time == message.publish_time == DEFAULT_TIME_ORIGIN_NS + to_ns(
                decoded.time) and decoded.time == decoded.step * 1.0
            if channel.topic == "/agents/estimate":
                estimates[decoded.step] = np.reshape(decoded.estimate, (N, n))
        np.testing.assert_array_equal(estimates, result.estimates)


# -- inspection -------------------------------------------------------------------------


def _kernel_link_stats(messages):
    delays, reordered = {}, Counter()
    newest: dict[tuple[int, int], int] = {}
    for m in messages:
        key = (m.sender, m.receiver)
        delays.setdefault(key, []).append(m.delay_steps)
        if m.sent_step < newest.get(key, -1):
            reordered[key] += 1
        newest[key] = max(newest.get(key, -1), m.sent_step)
    return delays, reordered


def test_inspect_report_statistics(recorded):
    path, _, result = recorded
    report = inspect_trace(read_trace(path))
    delays, reordered = _kernel_link_stats(result.messages)
    assert set(report.links) == {f"{j}->{i}" for j, i in delays}
    for (j, i), values in delays.items():
        stats = report.links[f"{j}->{i}"]
        assert stats.delivered == len(values)
        assert stats.delay["min"] == min(values) and stats.delay["max"] == max(values)
        assert stats.delay["mean"] == pytest.approx(np.mean(values), rel=1e-12)
        assert stats.delay["histogram"] == dict(sorted(Counter(values).items()))
        assert stats.reordered == reordered[(j, i)]
        assert stats.dropped == 0
        assert stats.in_flight == stats.sent - stats.delivered
    assert report.totals["sent"] == result.messages_sent
    assert report.totals["delivered"] == result.messages_delivered
    assert report.totals["discarded"] == result.messages_discarded
    assert sum(reordered.values()) > 0  # asynchronous delays reorder

    for i, agent in report.agents.items():
        assert agent.mse == pytest.approx(result.squared_errors[:, i].mean(), rel=1e-12)
        assert agent.final_squared_error == pytest.approx(result.squared_errors[-1, i],
                                                          rel=1e-12)
    # effective delays per link as used by the receiver
    r = result.effective_delays
    for (j, i) in delays:
        used = r[:, i, j][r[:, i, j] >= 0]
        assert report.links[f"{j}->{i}"].effective_delay == delay_statistics(used)

    d = report.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["scenario"] == "lcsys2022-time-varying" and d["status"] == "complete"
    assert d["steps"] == {"first": 0, "last": STEPS, "recorded": STEPS + 1}
    assert d["topics"]["/plant/state"] == STEPS + 1
    text = report.format_text()
    assert "lcsys2022-time-varying" in text and "compensated" in text and "0->1" in text


def test_delay_statistics_helper():
    assert delay_statistics([2, 0, 2, 1]) == {
        "count": 4, "min": 0, "mean": 1.25, "max": 2, "histogram": {0: 1, 1: 1, 2: 2}}
    assert delay_statistics([])["count"] == 0


# -- crash safety -----------------------------------------------------------------------


def _chunk_message_counts(path):
    """(end offset, message count) of each chunk, from the finished file's index."""
    out = []
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            n = sum(isinstance(r, Message) for r in breakup_chunk(chunk))
            out.append((index.chunk_start_offset + index.chunk_length, n))
    return out


def _signature(records):
    return [(r.topic, r.log_time, r.publish_time, r.sequence, r.message.SerializeToString())
            for r in records]


@pytest.mark.parametrize("where", ["middle", "last-chunk"])
def test_truncated_file_recovers_complete_chunks(recorded, tmp_path, where):
    path, _, _ = recorded
    data = path.read_bytes()
    chunks = _chunk_message_counts(path)
    if where == "middle":
        cut = len(data) // 2
    else:  # footer, summary and half of the last chunk gone
        start = chunks[-2][0]
        cut = start + (chunks[-1][0] - start) // 2
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(data[:cut])
    with open(damaged, "rb") as f, pytest.raises(Exception):  # noqa: B017
        make_reader(f).get_summary()  # the premise: indexed reading fails

    trace = read_trace(damaged)
    expected = sum(n for end, n in chunks if end <= cut)
    assert trace.truncated
    assert trace.status is None
    assert trace.recovered_messages == expected > 0
    full = read_trace(path)
    if trace.format == 2:  # a file message per read message
        assert _signature(trace.messages) == _signature(full.messages[:expected])
    # every topic holds the first records of the full trace's, every step up to the cut
    assert trace.records and set(trace.records) <= set(full.records)
    for topic, records in trace.records.items():
        assert _signature(records) == _signature(full.records[topic][:len(records)]), topic
    assert trace.steps == full.steps[:len(trace.steps)] and len(trace.steps) > 1
    assert trace.scenario == full.scenario
    assert set(trace.matrices) == set(full.matrices)

    report = inspect_trace(trace)
    assert report.truncated and report.status == "truncated"
    assert report.recovered_messages == expected
    assert "TRUNCATED" in report.format_text()


@pytest.mark.parametrize("trace_format", [2, 3])
def test_unfinished_file_readable_while_open(setup, tmp_path, trace_format):
    scenario, gains = setup
    path = tmp_path / "open.mcap"
    recorder = TraceRecorder.for_run(path, scenario, gains, "compensated", 0, steps=STEPS,
                                     trace_format=trace_format)
    try:
        result = run_trial(scenario, "compensated", gains, SEED, STEPS, observer=recorder)
        recorder.flush()
        trace = read_trace(path)  # no footer yet: as if the process died now
        assert trace.truncated and trace.recovered_messages == recorder.messages_written
        # format 3 writes a step when the next one starts (or at close): the last step,
        # which could still have had events, is not in the file yet
        last = STEPS if trace_format == 2 else STEPS - 1
        assert trace.steps == list(range(last + 1))
        np.testing.assert_array_equal(trace.estimates(), result.estimates[:last + 1])
    finally:
        recorder.close()
    assert not read_trace(path).truncated


class _Interrupt:
    """Observer forwarding to a recorder and raising KeyboardInterrupt at a step."""

    def __init__(self, recorder, at):
        self.recorder, self.at = recorder, at

    def on_plant(self, k, state, measurements):
        self.recorder.on_plant(k, state, measurements)
        if k == self.at:
            raise KeyboardInterrupt

    def on_sent(self, message):
        self.recorder.on_sent(message)

    def on_delivered(self, message, accepted):
        self.recorder.on_delivered(message, accepted)

    def on_update(self, agent, k, estimate, delays):
        self.recorder.on_update(agent, k, estimate, delays)


def test_keyboard_interrupt_leaves_finished_file(setup, tmp_path):
    scenario, gains = setup
    path = tmp_path / "interrupted.mcap"
    with pytest.raises(KeyboardInterrupt):
        _record(path, scenario, gains, lambda rec: _Interrupt(rec, 20))
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        status = {m.name: m.metadata for m in reader.iter_metadata()}["run_status"]
    assert status["status"] == "interrupted"
    assert status["interrupted_at"] == "20" and status["last_step"] == "20"
    assert "KeyboardInterrupt" in status["reason"]

    trace = read_trace(path)
    assert not trace.truncated
    assert trace.steps == list(range(21))
    assert max(m.step for m in trace.topic("/agent_0/estimate")) == 19
    report = inspect_trace(trace)
    assert report.status == "interrupted" and "interrupted_at 20" in report.format_text()


def test_killed_writer_subprocess(setup, tmp_path):
    """A process killed mid-run (os._exit) leaves a file the reader recovers."""
    scenario, gains = setup
    gains_file = tmp_path / "gains.pkl"
    gains_file.write_bytes(pickle.dumps(gains))
    path = tmp_path / "killed.mcap"
    script = textwrap.dedent(f"""
        import os, pickle
        from netsim.models.scenario import DelaySpec, resolve_scenario
        from netsim.runner import run_trial
        from netsim.traces.recorder import TraceRecorder
        s = resolve_scenario("lcsys2022-time-varying").with_tau(4)
        gains = pickle.loads(open({str(gains_file)!r}, "rb").read())
        rec = TraceRecorder.for_run({str(path)!r}, s, gains, "compensated", 0,
                                    flush_every=10, flush_seconds=None)
        class Kill:
            def __getattr__(self, name):
                return getattr(rec, name)
            def on_plant(self, k, x, ys):
                if k == 35:
                    os._exit(3)
                rec.on_plant(k, x, ys)
        run_trial(s, "compensated", gains, {SEED}, {STEPS}, observer=Kill())
    """)
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 3, done.stderr
    trace = read_trace(path)
    assert trace.truncated and trace.status is None
    # flushed at steps 10, 20, 30: everything before step 30's plant record survives
    assert trace.steps == list(range(30))
    assert trace.recovered_messages > 0
    assert trace.scenario["name"] == "lcsys2022-time-varying"


def test_failure_inside_context_is_noted(setup, tmp_path):
    scenario, gains = setup
    path = tmp_path / "failed.mcap"

    class Boom(_Interrupt):
        def on_plant(self, k, state, measurements):
            self.recorder.on_plant(k, state, measurements)
            if k == 5:
                raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        _record(path, scenario, gains, lambda rec: Boom(rec, 5))
    trace = read_trace(path)
    assert trace.status["status"] == "failed"
    assert trace.status["reason"] == "RuntimeError: disk on fire"


# -- bad files --------------------------------------------------------------------------


def test_foreign_mcap_file(tmp_path):
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("Pose", "jsonschema", b'{"type": "object"}')
        channel = writer.register_channel("/pose", "json", schema)
        writer.add_message(channel, 1, b'{"x": 1}', 1)
        writer.add_metadata("robot", {"name": "r2"})
        writer.finish()
    with pytest.raises(TraceError, match="not a netsim trace") as info:
        read_trace(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_file_with_missing_schema(tmp_path):
    path = tmp_path / "noschema.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.add_metadata("scenario", {"name": "x"})
        writer.add_metadata("run", {"trace_format": TRACE_FORMAT})
        channel = writer.register_channel("/plant/state", "protobuf", 0)
        writer.add_message(channel, 1, b"", 1)
        writer.finish()
    with pytest.raises(TraceError, match="'/plant/state' has no schema"):
        read_trace(path)


def _chunk_spans(path):
    """(start, end, message signatures) of each chunk of an intact finished file, read
    with the mcap library chunk by chunk (independent of netsim's reader)."""
    full = read_trace(path)
    spans, first = [], 0
    with open(path, "rb") as f:
        for index in make_reader(f).get_summary().chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            n = sum(isinstance(r, Message) for r in breakup_chunk(chunk))
            spans.append((index.chunk_start_offset, index.chunk_start_offset
                          + index.chunk_length, _signature(full.messages[first:first + n])))
            first += n
    return spans


def _damage(data, at):
    data = bytearray(data)
    data[at] ^= 0xFF
    data[at - 1] ^= 0x5A
    return bytes(data)


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_corrupted_chunk_is_skipped_and_every_other_chunk_read(setup, tmp_path, compression):
    scenario, gains = setup
    path = tmp_path / f"crc-{compression}.mcap"
    _record(path, scenario, gains, compression=compression, flush_every=10, trace_format=2)
    spans = _chunk_spans(path)
    assert len(spans) >= 4
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_damage(path.read_bytes(), spans[2][1] - 40))  # inside the third chunk
    trace = read_trace(bad)
    kept = [m for i, (_, _, sig) in enumerate(spans) if i != 2 for m in sig]
    assert _signature(trace.messages) == kept
    assert not trace.truncated and trace.damaged
    [lost] = trace.lost_chunks
    assert (lost.index, lost.offset, lost.length) == (2, spans[2][0],
                                                      spans[2][1] - spans[2][0])
    assert lost.messages == len(spans[2][2]) == trace.lost_messages
    if compression == "none":
        assert "crc" in lost.reason.lower()
    report = inspect_trace(trace)
    assert report.to_dict()["lost_chunks"][0]["chunk"] == 2
    assert report.to_dict()["lost_messages"] == len(spans[2][2])
    text = report.format_text()
    assert "DAMAGED" in text and f"lost chunk 2 at byte {spans[2][0]}" in text


def test_corrupted_chunk_in_unfinished_file_is_skipped(recorded2, tmp_path):
    """Corruption before the truncation point loses that chunk only."""
    path, _, _ = recorded2
    spans = _chunk_spans(path)
    cut = spans[-1][1] - 10  # the last chunk cut off: truncated
    bad = tmp_path / "bad-unfinished.mcap"
    bad.write_bytes(_damage(path.read_bytes()[:cut], spans[1][1] - 30))
    trace = read_trace(bad)
    assert trace.truncated and trace.status is None
    kept = [m for i, (_, _, sig) in enumerate(spans[:-1]) if i != 1 for m in sig]
    assert _signature(trace.messages) == kept
    [lost] = trace.lost_chunks
    assert lost.index == 1 and lost.messages == len(spans[1][2])


def test_destroyed_chunk_header_resynchronises_on_the_next_chunk(recorded2, tmp_path):
    path, _, _ = recorded2
    spans = _chunk_spans(path)
    data = bytearray(path.read_bytes()[: spans[-1][1] - 10])
    start = spans[2][0]
    data[start:start + 9] = b"\xee" * 9  # opcode and length of the third chunk
    bad = tmp_path / "no-header.mcap"
    bad.write_bytes(bytes(data))
    trace = read_trace(bad)
    kept = [m for i, (_, _, sig) in enumerate(spans[:-1]) if i != 2 for m in sig]
    assert _signature(trace.messages) == kept
    assert trace.lost_chunks[0].offset == start and trace.lost_chunks[0].index is None


def test_corrupted_summary_is_read_by_scanning(recorded, tmp_path):
    path, _, _ = recorded
    data = bytearray(path.read_bytes())
    data[-8 - 29 - 20] ^= 0xFF  # inside the summary section, before the footer
    bad = tmp_path / "bad-summary.mcap"
    bad.write_bytes(bytes(data))
    trace = read_trace(bad)
    assert "summary" in trace.note and not trace.truncated
    assert _signature(trace.messages) == _signature(read_trace(path).messages)
    assert trace.status == read_trace(path).status


def test_not_an_mcap_file(tmp_path):
    noise = tmp_path / "noise.mcap"
    noise.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(TraceError, match="not an MCAP file") as info:
        read_trace(noise)
    assert str(noise) in str(info.value)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(TraceError, match="not an MCAP file"):
        read_trace(empty)
    with pytest.raises(TraceError, match="cannot read"):
        read_trace(tmp_path / "missing.mcap")


# -- API details ------------------------------------------------------------------------


def test_trace_path_convention():
    assert trace_path("out/run.mcap") == Path("out/run.mcap")
    assert trace_path("out/run.mcap", "compensated", 3) == Path(
        "out/run.compensated.trial3.mcap")
    assert trace_path("run.mcap", trial=0) == Path("run.trial0.mcap")


def test_schemas_are_self_describing():
    fds = file_descriptor_set()
    assert [f.package for f in fds.file] == [PACKAGE2]
    assert {m.name for m in fds.file[0].message_type} == set(MESSAGE_TYPES)
    estimate = message_class(f"{PACKAGE2}.Estimate")(step=3, agent=1, estimate=[1.0, 2.0],
                                                     error_norm=0.5)
    again = message_class("Estimate").FromString(estimate.SerializeToString())
    assert again.error_norm == 0.5 and list(again.estimate) == [1.0, 2.0]
    fields = {f.name for f in message_class("EstimatorUpdate").DESCRIPTOR.fields}
    assert {"neighbours", "effective_delay", "used_timestamp"} <= fields


def test_centralized_family_without_gains(setup, tmp_path):
    scenario, _ = setup
    path = tmp_path / "kf.mcap"
    with TraceRecorder.for_run(path, scenario, None, "centralized-kf", 1, steps=10) as rec:
        result = run_trial(scenario, "centralized-kf", None, SEED, 10, observer=rec)
        rec.set_status("diverged", diverged_at=4)  # what the CLI does for a blown-up run
    trace = read_trace(path)
    assert trace.status["status"] == "diverged" and trace.status["diverged_at"] == "4"
    assert trace.family == "centralized-kf" and trace.links == []
    assert "K_0" not in trace.matrices
    np.testing.assert_array_equal(trace.estimates(), result.estimates)


def test_continuous_latencies_with_sample_period(setup, tmp_path):
    """Ts != 1 and deliveries between sampling instants keep log_time ordered."""
    scenario, gains = setup
    scenario = replace(scenario, sample_period=0.1, delays=DelaySpec(
        model="latency", default=0.23, links={(0, 1): 0.1, (1, 2): 0.05}))
    path = tmp_path / "latency.mcap"
    with TraceRecorder.for_run(path, scenario, gains, "compensated", 0, steps=30) as rec:
        result = run_trial(scenario, "compensated", gains, SEED, 30, record_messages=True,
                           observer=rec)
    trace = read_trace(path)
    times = [r.log_time for r in trace.messages]
    assert times == sorted(times)
    assert trace.sample_period == 0.1
    assert trace.records["/plant/state"][3].log_time == trace.time_origin_ns + 300_000_000
    assert trace.sim_time_ns(trace.records["/plant/state"][3].log_time) == 300_000_000
    arrivals = {to_ns(m.arrival_time) for m in result.messages}
    assert any(t % 100_000_000 for t in arrivals)  # some arrive between instants
    np.testing.assert_array_equal(trace.estimates(), result.estimates)
    np.testing.assert_array_equal(trace.effective_delays(), result.effective_delays)
    report = inspect_trace(trace)
    assert report.links["2->3"].delay["histogram"] == {2: report.links["2->3"].delivered}


def test_traces_package_does_not_import_netsim_or_simpy():
    code = ("import sys, netsim.traces.schemas, netsim.traces.recorder, netsim.traces.reader, "
            "netsim.traces.inspect; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'simpy' or "
            "(m.startswith('netsim.') and "
            "m.split('.')[1] not in ('models', 'traces', 'estimators'))); "
            "assert not bad, bad")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_recorder_rejects_events_out_of_time_order(tmp_path):
    class Msg:
        sender, receiver, sent_step, sequence, delay_steps = 0, 1, 5, 0, 0
        payload = np.zeros(2)
        send_time, arrival_time = 5.0, 6.0

    with TraceRecorder(tmp_path / "order.mcap", scenario_metadata={"name": "t"}, matrices={},
                       family="f", trial=0, trace_format=2) as rec:
        rec.on_plant(7, np.zeros(2), [np.zeros(1)])
        with pytest.raises(RuntimeError, match="time order"):
            rec.on_sent(Msg())
    # format 3 files every event under its step: one of another step is refused
    from netsim.traces.stepwriter import TraceLayoutError

    with TraceRecorder(tmp_path / "order3.mcap", scenario_metadata={"name": "t"}, matrices={},
                       family="f", trial=0, trace_format=3) as rec:
        rec.on_plant(7, np.zeros(2), [np.zeros(1)])
        with pytest.raises(TraceLayoutError, match="outside plant step 7"):
            rec.on_sent(Msg())


@pytest.mark.parametrize("array", [
    np.eye(3), np.zeros((0, 4)), np.arange(5, dtype=np.int64), np.float64(2.5),
    np.ones((2, 3), dtype=np.float32), np.asfortranarray(np.arange(12.0).reshape(3, 4)),
    np.array([True, False]),
])
def test_matrix_attachments_are_the_bytes_np_save_writes(array):
    import io

    from netsim.traces.recorder import _npy_bytes

    expected = io.BytesIO()
    np.save(expected, array if array.flags.c_contiguous else np.ascontiguousarray(array),
            allow_pickle=False)
    assert _npy_bytes(array) == _npy_bytes(array) == expected.getvalue()
    assert np.array_equal(np.load(io.BytesIO(_npy_bytes(array))), array)


@pytest.mark.parametrize("names", [
    ["A", "C_0", "C_1", "C_2", "K_0", "K_1", "P", "R_0", "x0_mean"],
    ["C_0", "C_2", "C_3", "C_4", "K_7"], [], ["Q"],
])
def test_matrix_names_fold_into_ranges_that_unfold_to_them(names):
    from netsim.traces.inspect import _name_ranges

    unfolded = []
    for part in _name_ranges(names):
        for piece in part.split(", "):
            if " .. " in piece:
                lo, hi = piece.split(" .. ")
                prefix = lo.rpartition("_")[0]
                unfolded += [f"{prefix}_{i}" for i in range(int(lo.rpartition("_")[2]),
                                                            int(hi.rpartition("_")[2]) + 1)]
            else:
                unfolded.append(piece)
    assert unfolded == names


def test_inspect_text_shows_the_first_rows_and_says_how_many_are_left(recorded,
                                                                       monkeypatch):
    from netsim.traces import inspect as ins

    path, _, _ = recorded
    report = inspect_trace(read_trace(path))
    monkeypatch.setattr(ins, "TEXT_ROWS", 3)
    lines = report.format_text().splitlines()
    for what, table in (("topics", report.topics), ("links", report.links),
                        ("agents", report.agents)):
        if len(table) > 3:
            assert f"  ... and {len(table) - 3} more {what} (all of them: --json)" in lines
    assert len(report.to_dict()["topics"]) == len(report.topics)  # --json: all
