"""The bulk MCAP writer against the reference Python ``mcap`` reader and writer, crash
safety (kill -9, Ctrl-C) and chunk-by-chunk recovery of a damaged file."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from netsim.traces.bulkmcap import BulkMcapWriter, message_records
from netsim.traces.mcaprecover import recover

REPO = Path(__file__).resolve().parents[1]


def _batch(rng, n, channels, width=None):
    channel = rng.integers(0, channels, n).astype(np.uint16)
    log_time = np.sort(rng.integers(0, 10**12, n)).astype(np.uint64)
    publish = log_time - rng.integers(0, 1000, n).astype(np.uint64)
    sequence = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
    if width is not None:
        return channel, log_time, publish, sequence, rng.integers(0, 256, (n, width),
                                                                  dtype=np.uint8)
    lengths = rng.integers(0, 40, n)
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    return channel, log_time, publish, sequence, (
        rng.integers(0, 256, int(offsets[-1]), dtype=np.uint8).tobytes(), offsets)


def _payload(payloads, i):
    if isinstance(payloads, tuple):
        buffer, offsets = payloads
        return buffer[offsets[i]:offsets[i + 1]]
    return payloads[i].tobytes()


def _write_both(tmp_path, batches, events, chunk_size):
    """The same messages through BulkMcapWriter and mcap's own Writer."""
    ours, theirs = tmp_path / "bulk.mcap", tmp_path / "ref.mcap"
    with BulkMcapWriter(ours, library="t", chunk_size=chunk_size) as w, \
            open(theirs, "wb") as f:
        ref = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        ref.start(profile="", library="t")
        sid = w.add_schema("s", "protobuf", b"\x01\x02")
        rsid = ref.register_schema("s", "protobuf", b"\x01\x02")
        for c in range(3):
            assert w.add_channel(f"/c{c}", "protobuf", sid, {"c": str(c)}) == c
            ref.register_channel(f"/c{c}", "protobuf", rsid, {"c": str(c)})
        w.add_metadata("run", {"a": "1"})
        ref.add_metadata("run", {"a": "1"})
        w.add_attachment(6, 5, "m.npy", "application/x-npy", b"abc")
        ref.add_attachment(6, 5, "m.npy", "application/x-npy", b"abc")
        for channel, log_time, publish, sequence, payloads in batches:
            if isinstance(payloads, tuple):
                w.add_messages(channel, log_time, payloads[0], publish_time=publish,
                               sequence=sequence, offsets=payloads[1])
            else:
                w.add_messages(channel, log_time, payloads, publish_time=publish,
                               sequence=sequence)
            for i in range(len(log_time)):
                ref.add_message(int(channel[i]) + 1, int(log_time[i]), _payload(payloads, i),
                                int(publish[i]), int(sequence[i]))
        for channel, log_time, data in events:
            w.add_message(channel, log_time, data, log_time, 7)
            ref.add_message(channel + 1, log_time, data, log_time, 7)
        ref.finish()
    return ours, theirs


def _read(path):
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        messages = [(c.topic, m.sequence, m.log_time, m.publish_time, m.data)
                    for _, c, m in reader.iter_messages(log_time_order=False)]
        metadata = [(m.name, m.metadata) for m in reader.iter_metadata()]
        attachments = [(a.name, a.media_type, a.data, a.log_time, a.create_time)
                       for a in reader.iter_attachments()]
        by_time = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]
    return summary, messages, metadata, attachments, by_time


@pytest.mark.parametrize("chunk_size", [700, 64 * 1024])
def test_file_reads_back_like_mcaps_own_writer(tmp_path, chunk_size):
    rng = np.random.default_rng(3)
    batches = [_batch(rng, 400, 3, width=17), _batch(rng, 300, 3), _batch(rng, 1, 3, 5)]
    events = [(int(c), 10**12 + i, bytes(rng.integers(0, 256, i % 9, dtype=np.uint8)))
              for i, c in enumerate(rng.integers(0, 3, 200))]
    ours, theirs = _write_both(tmp_path, batches, events, chunk_size)
    a, b = _read(ours), _read(theirs)
    assert a[1] == b[1]  # every message, in file order
    assert a[2:] == b[2:]  # metadata, attachments, log_time order
    sa, sb = a[0], b[0]
    for name in ("message_count", "channel_count", "schema_count", "attachment_count",
                 "metadata_count", "message_start_time", "message_end_time"):
        assert getattr(sa.statistics, name) == getattr(sb.statistics, name), name
    assert dict(sa.statistics.channel_message_counts) == {
        k - 1: v for k, v in sb.statistics.channel_message_counts.items()}
    assert sa.statistics.chunk_count == len(sa.chunk_indexes) > (2 if chunk_size < 1000
                                                                  else 0)
    # chunk indexes point at chunks whose message indexes list their messages
    assert sum(len(r.records) for r in _message_indexes(ours, sa)) == len(a[1])
    _check_message_indexes(ours, sa)



def _add_in_parts(w, channels, parts, channel, log_time, publish, sequence, rows):
    """A schema, ``channels`` channels, and the batch in ``parts`` bulk calls, each
    followed by a non-waiting flush (chunks in flight on the pool)."""
    sid = w.add_schema("s", "protobuf", b"")
    for c in range(channels):
        w.add_channel(f"/c{c}", "protobuf", sid)
    for part in np.array_split(np.arange(len(log_time)), parts):
        w.add_messages(channel[part], log_time[part], rows[part],
                       publish_time=publish[part], sequence=sequence[part])
        w.flush(wait=False)


def test_background_compression_writes_the_bytes_of_the_synchronous_writer(tmp_path):
    """Chunks compressed on the pool (>= 128 KiB each, several in flight) give the file
    the writer gives compressing each chunk at once; it reads back with CRCs."""
    rng = np.random.default_rng(5)
    channel, log_time, publish, sequence, rows = _batch(rng, 30000, 4, width=40)
    rows[:, ::2] = 7  # compressible, like trace payloads
    paths = []
    for background in (True, False):
        path = tmp_path / f"bg{background}.mcap"
        with BulkMcapWriter(path, chunk_size=200 * 1024, background=background) as w:
            _add_in_parts(w, 4, 7, channel, log_time, publish, sequence, rows)
        paths.append(path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    with open(paths[0], "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        got = [(m.channel_id, m.log_time, m.sequence, bytes(m.data))
               for _, _, m in reader.iter_messages(log_time_order=False)]
    assert summary.statistics.chunk_count >= 6
    assert got == [(int(c), int(t), int(q), rows[i].tobytes()) for i, (c, t, q) in
                   enumerate(zip(channel, log_time, sequence, strict=True))]
    _check_message_indexes(paths[0], summary)


def _check_message_indexes(path, summary):
    """Every message index entry points at a message of its channel with its log_time,
    entries sorted by log_time, every message listed once."""
    import struct

    import zstandard

    data = Path(path).read_bytes()
    for index in summary.chunk_indexes:
        at = index.chunk_start_offset + 9
        start, end, usize, _crc, clen = struct.unpack_from("<QQQII", data, at)
        at += 32 + clen
        (rlen,) = struct.unpack_from("<Q", data, at)
        records = zstandard.ZstdDecompressor().decompress(data[at + 8:at + 8 + rlen],
                                                          max_output_size=usize)
        listed = []
        for channel, offset in index.message_index_offsets.items():
            (n,) = struct.unpack_from("<I", data, offset + 11)
            pairs = np.frombuffer(data, "<u8", n // 8, offset + 15).reshape(-1, 2)
            assert np.all(np.diff(pairs[:, 0].astype(np.int64)) >= 0)
            for log_time, where in pairs.tolist():
                op, _, ch, _, lt = struct.unpack_from("<BQHIQ", records, where)
                assert (op, ch, lt) == (5, channel, log_time)
                assert start <= lt <= end
                listed.append(where)
        assert len(set(listed)) == len(listed)


def _message_indexes(path, summary):
    from mcap.data_stream import ReadDataStream
    from mcap.records import MessageIndex

    out = []
    with open(path, "rb") as f:
        for index in summary.chunk_indexes:
            for offset in index.message_index_offsets.values():
                f.seek(offset + 9)
                out.append(MessageIndex.read(ReadDataStream(f)))
    return out


def test_message_records_match_the_per_message_layout():
    rng = np.random.default_rng(4)
    channel, log_time, publish, sequence, (buffer, offsets) = _batch(rng, 50, 4)
    records, starts = message_records(channel, sequence, log_time, publish, buffer, offsets)
    import struct

    expected = b"".join(
        struct.pack("<BQHIQQ", 5, 22 + offsets[i + 1] - offsets[i], channel[i], sequence[i],
                    log_time[i], publish[i]) + buffer[offsets[i]:offsets[i + 1]]
        for i in range(50))
    assert records.tobytes() == expected
    assert starts[0] == 0 and np.all(np.diff(starts) == 31 + np.diff(offsets)[:-1])


def _three_chunk_file(path, chunks=5, per_chunk=200):
    rng = np.random.default_rng(5)
    with BulkMcapWriter(path, library="t", chunk_size=10**9) as w:
        sid = w.add_schema("s", "protobuf", b"")
        w.add_channel("/a", "protobuf", sid)
        w.add_channel("/b", "protobuf", sid)
        for c in range(chunks):
            n = per_chunk
            w.add_messages(np.arange(n) % 2, c * 10**9 + np.arange(n), rng.integers(
                0, 256, (n, 24), dtype=np.uint8), sequence=np.arange(n))
            w.flush()
    return _read(path)[1]


@pytest.mark.parametrize("summary", [True, False])
def test_a_corrupted_middle_chunk_loses_only_itself(tmp_path, summary):
    path = tmp_path / "damaged.mcap"
    messages = _three_chunk_file(path)
    with open(path, "rb") as f:
        index = make_reader(f).get_summary().chunk_indexes
    middle = sorted(index, key=lambda c: c.chunk_start_offset)[2]
    data = bytearray(path.read_bytes())
    data[middle.chunk_start_offset + middle.chunk_length // 2] ^= 0x5A
    if not summary:  # the writer was killed: no summary, footer or index
        data = data[:sorted(index, key=lambda c: c.chunk_start_offset)[-1].chunk_start_offset
                    + 100]
    path.write_bytes(bytes(data))
    got = recover(path)
    assert got.used_summary is summary and got.truncated is (not summary)
    assert [c.offset for c in got.lost] == [middle.chunk_start_offset]
    assert got.lost[0].offset == middle.chunk_start_offset
    assert got.lost[0].start_time == middle.message_start_time
    assert "CRC" in got.lost[0].error or "zstd" in got.lost[0].error
    lost_times = range(middle.message_start_time, middle.message_end_time + 1)
    expected = [m for m in messages if m[2] not in lost_times]
    if not summary:  # the cut-off last chunk is not there either
        expected = [m for m in expected if m[2] < 4 * 10**9]
    assert [(got.channels[m.channel_id][1], m.sequence, m.log_time, m.publish_time,
             bytes(m.data)) for m in got.messages] == expected
    assert {c[1] for c in got.channels.values()} == {"/a", "/b"}


_WRITER = textwrap.dedent("""
    import os, signal, sys, time
    import numpy as np
    from netsim.traces.bulkmcap import BulkMcapWriter
    mode, path = sys.argv[1], sys.argv[2]
    with BulkMcapWriter(path, chunk_size=2000) as w:
        sid = w.add_schema("s", "protobuf", b"")
        ch = w.add_channel("/a", "protobuf", sid)
        for k in range(10**9):
            w.add_message(ch, k, b"x" * 40, k, k)
            if k == 500:
                print("ready", flush=True)
                if mode == "kill":
                    os.kill(os.getpid(), signal.SIGKILL)
                time.sleep(30)
""")


@pytest.mark.parametrize("mode", ["kill", "interrupt"])
def test_killed_writer_leaves_its_chunks_and_ctrl_c_finishes_the_file(tmp_path, mode):
    path = tmp_path / f"{mode}.mcap"
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, mode, str(path)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    if mode == "interrupt":
        proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    got = recover(path)
    per_chunk = 2000 // 71 + 1  # records of 71 bytes; a chunk closes at >= 2000 bytes
    if mode == "kill":
        assert got.truncated and not got.lost
        assert len(got.messages) == (501 // per_chunk) * per_chunk
    else:  # KeyboardInterrupt inside the with: the file is finished and indexed
        assert got.used_summary and not got.truncated and not got.lost
        assert len(got.messages) == 501
        with open(path, "rb") as f:
            assert make_reader(f, validate_crcs=True).get_summary().statistics \
                .message_count == 501
    assert [m.sequence for m in got.messages] == list(range(len(got.messages)))


JS = REPO / "benchmarks" / "js"


@pytest.mark.skipif(shutil.which("node") is None or not (JS / "node_modules" / "@mcap"
                                                         / "core").is_dir(),
                    reason="node or benchmarks/js/node_modules (npm install) not present")
@pytest.mark.parametrize("trace_format", [2, 3])
def test_typescript_reader_validates_and_decodes_a_traced_run(tmp_path, trace_format):
    """@mcap/core (CRCs validated) and protobufjs read a trace the vectorised engine
    wrote in bulk: every message, the same counts and values as the Python reader."""
    import warnings

    from netsim.models.scenario import resolve_scenario
    from netsim.traces.reader import read_trace

    from netsim.runner import run_monte_carlo, scenario_gains

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scenario = resolve_scenario("lcsys2022-heterogeneous")
        gains = scenario_gains(scenario)
    path = tmp_path / "run.mcap"
    run_monte_carlo(scenario, steps=60, trials=1, families=["compensated"], gains=gains,
                    trace=str(path), engine="vectorised",
                    trace_options={"trace_format": trace_format})
    out = subprocess.run(["node", str(JS / "check_mcap.mjs"), str(path), "--json"],
                         capture_output=True, text=True, timeout=120)
    report = json.loads(out.stdout)
    assert out.returncode == 0 and not report["errors"], report["errors"]
    assert report["data_section_crc"] == "ok"
    trace = read_trace(path)
    assert report["messages"] == sum(trace.file_counts.values()) == report[
        "statistics_messages"]
    assert {t: e["count"] for t, e in report["topics"].items()} == trace.file_counts
    if trace_format == 3:  # every agent's estimate of step 0 in one message
        first = report["topics"]["/agents/estimate"]["first"]
        assert first["estimate"] == trace.estimates()[0].ravel().tolist()
        assert first["error_norm"] == [m[0].message.error_norm for m in (
            trace.records[f"/agent_{i}/estimate"] for i in trace.agents)]
        assert int(first["step"]) == 0
        return
    first = report["topics"]["/agent_1/estimate"]["first"]
    ours = trace.records["/agent_1/estimate"][0].message
    assert first["estimate"] == list(ours.estimate)
    assert first["error_norm"] == ours.error_norm
    assert int(first["step"]) == ours.step == 0


def _data_section_crc(path):
    """(stored, recomputed) data-section CRC: the Data End record lies just before the
    summary section (the Footer's summary_start); the data section is every byte
    before it, magic included."""
    import struct
    import zlib

    data = Path(path).read_bytes()
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)[0]
    assert data[summary_start - 13] == 0x0F  # Data End opcode
    stored = struct.unpack_from("<I", data, summary_start - 4)[0]
    return stored, zlib.crc32(data[:summary_start - 13])


@pytest.mark.parametrize("compression", ["zstd", "none"])
@pytest.mark.parametrize("combine", [True, False])
def test_data_section_crc_is_the_crc_of_the_data_section(tmp_path, monkeypatch,
                                                         compression, combine):
    """Whether the chunks enter the data-section CRC by combination (zlib's
    crc32_combine) or by a second pass, it is the CRC of the bytes written."""
    from netsim.traces import crc32

    if combine and not crc32.AVAILABLE:
        pytest.skip("no zlib library to call on this machine")
    monkeypatch.setattr(crc32, "AVAILABLE", combine)
    rng = np.random.default_rng(9)
    channel, log_time, publish, sequence, rows = _batch(rng, 20000, 3, width=30)
    path = tmp_path / f"{compression}{combine}.mcap"
    with BulkMcapWriter(path, chunk_size=150 * 1024, compression=compression) as w:
        _add_in_parts(w, 3, 5, channel, log_time, publish, sequence, rows)
        w.add_message(0, int(log_time[-1]), b"last", int(log_time[-1]), 1)
    stored, recomputed = _data_section_crc(path)
    assert stored == recomputed != 0
    with open(path, "rb") as f:
        summary = make_reader(f, validate_crcs=True).get_summary()
    assert summary.statistics.chunk_count >= 4


def test_crc32_combine_is_the_crc_of_the_concatenation():
    import zlib

    from netsim.traces import crc32

    if not crc32.AVAILABLE:
        pytest.skip("no zlib library to call on this machine")
    rng = np.random.default_rng(2)
    for length in (0, 1, 7, 4096, 1 << 20, 3_000_001):
        a = rng.integers(0, 256, int(rng.integers(0, 100)), dtype=np.uint8).tobytes()
        b = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
        assert crc32.crc32_combine(zlib.crc32(a), zlib.crc32(b), len(b)) == zlib.crc32(a + b)
