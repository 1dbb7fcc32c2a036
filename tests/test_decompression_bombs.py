"""Decompression bombs (issue 29): a chunk is inflated only up to its declared size.

The bomb files are real MCAP files: a trace written by ``netsim run``, re-chunked by the
``mcap`` library's own writer with one chunk's compressed payload replaced by zeros
that inflate to 3 GiB (zstd with and without the frame's content size, LZ4 frames)
while the chunk declares its true small size; and files whose chunk declares a huge
uncompressed size. Each command runs as a subprocess under a 4 GB address-space limit
(as in ``tests/test_resource_guards.py``); the assertions are on the exit code, the
stderr line and the child's peak resident memory (``os.wait4``), not on speed (the
timeout is only a backstop).

A normal trace must read exactly as it did through the ``mcap`` library's unbounded
decompression (``breakup_chunk``): same records, same bytes per chunk.
"""

from __future__ import annotations

import io
import json
import os
import re
import resource
import struct
import subprocess
import sys
import textwrap
import threading
import tracemalloc
import types
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import mcap.writer as mcap_writer
import numpy as np
import pytest
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, IndexType, Writer
from netsim.traces import reader as trace_reader
from netsim.traces.reader import (
    ChunkTooLarge,
    Trace,
    TraceError,
    inflate_chunk,
    read_trace,
    stream_records,
)

lz4_frame = pytest.importorskip("lz4.frame")

LIMIT_BYTES = 4_000_000 * 1024  # ulimit -v 4000000, as tests/test_resource_guards.py
TIMEOUT = 60  # a backstop only: nothing here asserts on speed
INFLATE = 3 << 30  # what a bomb chunk inflates to
MAX_RSS = 1 << 30  # a bounded reader stays far below; inflating a bomb takes 3 GiB
HUGE = 1 << 62  # a declared uncompressed size no machine can give
BOMB_CHUNK = 1  # the chunk (file order) whose payload is replaced
ROOT = Path(__file__).resolve().parents[1]
KINDS = ["zstd", "zstd-no-content-size", "lz4"]


# -- building the files ---------------------------------------------------------------


def _zeros(n: int) -> Iterator[bytes]:
    block = bytes(1 << 24)
    while n > 0:
        yield block[:min(n, len(block))]
        n -= len(block)


def _bomb_payload(kind: str, n: int = INFLATE) -> bytes:
    """Compressed data inflating to ``n`` zero bytes, built as a stream (~30000:1 for
    zstd, ~250:1 for LZ4)."""
    out: list[bytes] = []
    if kind.startswith("zstd"):
        compressor = zstandard.ZstdCompressor(level=1,
                                              write_content_size=kind == "zstd")
        stream = compressor.compressobj(size=n if kind == "zstd" else -1)
        out += [stream.compress(block) for block in _zeros(n)]
        out.append(stream.flush())
    else:
        compressor = lz4_frame.LZ4FrameCompressor(block_size=lz4_frame.BLOCKSIZE_MAX4MB)
        out.append(compressor.begin())
        out += [compressor.compress(block) for block in _zeros(n)]
        out.append(compressor.flush())
    return b"".join(out)


@contextmanager
def _chunk_payloads(compression: str, bomb: bytes | None) -> Iterator[None]:
    """Make the mcap writer compress its chunks as usual, except chunk
    :data:`BOMB_CHUNK`, whose payload becomes ``bomb`` (its declared size and CRC stay
    those of its real records)."""
    calls = [0]
    real = (zstandard.compress if compression == "zstd" else lz4_frame.compress)

    def compress(data: bytes) -> bytes:
        calls[0] += 1
        return bomb if bomb is not None and calls[0] - 1 == BOMB_CHUNK else real(data)

    saved = mcap_writer.zstandard, mcap_writer.lz4
    mcap_writer.zstandard = types.SimpleNamespace(compress=compress)
    mcap_writer.lz4 = types.SimpleNamespace(frame=types.SimpleNamespace(compress=compress))
    try:
        yield
    finally:
        mcap_writer.zstandard, mcap_writer.lz4 = saved
    assert calls[0] > BOMB_CHUNK, "too few chunks to plant the bomb in"


def _rewrite(src: Path, dst: Path, compression: str, bomb: bytes | None = None,
             summary: bool = True) -> Path:
    """Write ``src``'s records again with the mcap library's writer: small chunks of
    ``compression`` (zstd or lz4), optionally with a bomb payload and no summary."""
    kind = CompressionType.ZSTD if compression == "zstd" else CompressionType.LZ4
    options = {} if summary else {
        "index_types": IndexType(0), "repeat_channels": False, "repeat_schemas": False,
        "use_statistics": False, "use_summary_offsets": False}
    with open(src, "rb") as f, open(dst, "wb") as out, _chunk_payloads(compression, bomb):
        reader = make_reader(f)
        info = reader.get_summary()
        assert info is not None
        writer = Writer(out, chunk_size=2048, compression=kind, **options)
        writer.start(library=reader.get_header().library)
        schemas = {k: writer.register_schema(s.name, s.encoding, s.data)
                   for k, s in info.schemas.items()}
        channels = {k: writer.register_channel(c.topic, c.message_encoding,
                                               schemas[c.schema_id], c.metadata)
                    for k, c in info.channels.items()}
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        for a in reader.iter_attachments():
            writer.add_attachment(a.log_time, a.create_time, a.name, a.media_type, a.data)
        for _, channel, m in reader.iter_messages(log_time_order=False):
            writer.add_message(channels[channel.id], m.log_time, m.data, m.publish_time,
                               m.sequence)
        writer.finish()
    return dst


def _chunk_offsets(path: Path) -> list[int]:
    """Offsets of the chunk records, found by walking the top-level records."""
    data = path.read_bytes()
    offsets, pos = [], 8
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x06:
            offsets.append(pos)
        if opcode == 0x02:  # footer
            break
        pos += 9 + length
    return offsets


def _declare(path: Path, size: int) -> int:
    """Overwrite the bomb chunk's declared uncompressed size; return its offset."""
    at = _chunk_offsets(path)[BOMB_CHUNK]
    data = bytearray(path.read_bytes())
    struct.pack_into("<Q", data, at + 9 + 16, size)  # after start and end times
    path.write_bytes(bytes(data))
    return at


def _unfinished(path: Path, dst: Path) -> Path:
    """A copy without the closing magic: read by scanning, as a killed writer's file."""
    dst.write_bytes(path.read_bytes()[:-8])
    return dst


def _netsim_run(tmp: Path, name: str, *extra: str) -> dict[str, Path]:
    out = tmp / f"{name}.mcap"
    done = subprocess.run(
        [sys.executable, "-m", "netsim.cli", "run", "lcsys2022-heterogeneous", "--steps",
         "20", "--trials", "1", "--trace", str(out), "--no-progress", *extra],
        capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    files = {p.name.split(".")[1]: p for p in tmp.glob(f"{name}.*.trial0.mcap")}
    assert "compensated" in files, sorted(tmp.iterdir())
    return files


@dataclass
class Files:
    trace: Path  # format 3, as `netsim run` writes it
    trace2: Path  # format 2 (zstd chunks)
    bombs: dict[tuple[str, str], Path]  # (kind, how it is read) -> file
    honest: Path  # declares the 3 GiB it inflates to
    honest_cut: Path  # the same, unfinished (read by scanning)
    absurd: Path  # declares 2**62 bytes
    honest_offset: int


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Files:
    tmp = tmp_path_factory.mktemp("bombs")
    trace = _netsim_run(tmp, "t")["compensated"]
    trace2 = _netsim_run(tmp, "f2", "--trace-format", "2")["compensated"]
    bombs: dict[tuple[str, str], Path] = {}
    for kind in KINDS:
        payload = _bomb_payload(kind)
        compression = kind.split("-")[0]
        summary = _rewrite(trace, tmp / f"{kind}.mcap", compression, payload)
        bombs[kind, "summary"] = summary
        bombs[kind, "scan"] = _unfinished(summary, tmp / f"{kind}-unfinished.mcap")
        bombs[kind, "no-summary"] = _rewrite(trace, tmp / f"{kind}-nosummary.mcap",
                                             compression, payload, summary=False)
    honest = _rewrite(trace, tmp / "honest.mcap", "zstd", _bomb_payload("zstd"))
    offset = _declare(honest, INFLATE)
    absurd = _rewrite(trace, tmp / "absurd.mcap", "zstd")
    _declare(absurd, HUGE)
    return Files(trace, trace2, bombs, honest,
                 _unfinished(honest, tmp / "honest-unfinished.mcap"), absurd, offset)


# -- running commands under the address-space limit -----------------------------------

# Runs `netsim` command lines one after the other in one interpreter (netsim.cli.main,
# what the `netsim` script calls), each with its own stdout, stderr and environment, so
# the many cases cost one interpreter start; the parent reads the process's peak RSS.
DRIVER = textwrap.dedent("""
    import contextlib, io, json, os, sys, traceback
    from netsim.cli import main
    results = []
    for argv, env in json.load(open(sys.argv[1])):
        saved = dict(os.environ)
        os.environ.update(env)
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 1
            except BaseException:
                traceback.print_exc()
                code = 1
        os.environ.clear()
        os.environ.update(saved)
        results.append({"code": code, "stdout": out.getvalue(), "stderr": err.getvalue()})
    json.dump(results, open(sys.argv[2], "w"))
""")


@dataclass
class Ran:
    code: int
    stdout: str
    stderr: str
    peak_rss: int  # bytes (of the whole process, for DRIVER runs)


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT_BYTES, LIMIT_BYTES))


def _run(tmp_path: Path, argv: list[str], env: dict[str, str] | None = None) -> Ran:
    """Run ``argv`` under RLIMIT_AS 4 GB; its own peak RSS from ``os.wait4``."""
    environment = {k: v for k, v in os.environ.items()
                   if not k.startswith("NETSIM_") or k == "NETSIM_CACHE_DIR"}
    environment.update(env or {})
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with open(out, "wb") as fo, open(err, "wb") as fe:
        proc = subprocess.Popen(argv, stdout=fo, stderr=fe, preexec_fn=_limit,
                                env=environment, cwd=tmp_path)
        timer = threading.Timer(TIMEOUT, proc.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            timer.cancel()
        proc.returncode = os.waitstatus_to_exitcode(status)
    return Ran(proc.returncode, out.read_text(), err.read_text(), usage.ru_maxrss * 1024)


def _argv(command: str, trace: Path, out: Path) -> list[str]:
    """``command trace`` (plot: ``-o out/<trace stem>.png``, plotted once per trace)."""
    if command != "plot":
        return [command, str(trace)]
    return [command, str(trace), "-o", str(out / f"{trace.stem}.png")]


RECOVERING = ["inspect", "replay", "analyze", "plot"]


@pytest.fixture(scope="module")
def ran(files: Files, tmp_path_factory: pytest.TempPathFactory) -> dict[tuple, Ran]:
    """Every command on every bomb file, keyed by (command, file name), and inspect on
    the honest bomb under NETSIM_MEMORY_LIMIT=1G, keyed by ("inspect", name, "1G")."""
    tmp = tmp_path_factory.mktemp("runs")
    cases: list[tuple[tuple, list[str], dict[str, str]]] = []
    for path in files.bombs.values():
        for command in RECOVERING if path.name in ("zstd.mcap", "lz4.mcap") else ["inspect"]:
            cases.append(((command, path.name), _argv(command, path, tmp), {}))
    for command in RECOVERING:
        cases.append(((command, files.absurd.name), _argv(command, files.absurd, tmp), {}))
    for path in (files.honest, files.honest_cut):
        cases.append((("inspect", path.name, "1G"), _argv("inspect", path, tmp),
                      {"NETSIM_MEMORY_LIMIT": "1G"}))
    plan, results = tmp / "plan.json", tmp / "results.json"
    plan.write_text(json.dumps([[argv, env] for _, argv, env in cases]))
    whole = _run(tmp, [sys.executable, "-c", DRIVER, str(plan), str(results)])
    assert whole.code == 0, whole.stderr[-3000:]
    out = json.loads(results.read_text())
    assert len(out) == len(cases)
    return {key: Ran(r["code"], r["stdout"], r["stderr"], whole.peak_rss)
            for (key, _, _), r in zip(cases, out, strict=True)}


def _bounded(ran: Ran, path: Path) -> None:
    """Exit 0 or 2, never a traceback, memory far below the bomb; exit 2 is one line
    naming the file."""
    assert ran.code in (0, 2), (ran.code, ran.stderr[-2000:])
    assert "Traceback" not in ran.stderr, ran.stderr[-2000:]
    assert ran.peak_rss < MAX_RSS, f"peak RSS {ran.peak_rss / 2**20:.0f} MiB"
    if ran.code == 2:
        lines = ran.stderr.strip().splitlines()
        assert len(lines) == 1 and str(path) in lines[0], ran.stderr


def _reports_damage(ran: Ran) -> bool:
    return bool(re.search(r"damaged|lost chunk|inflates past", ran.stdout + ran.stderr,
                          re.IGNORECASE))


# -- bombs: bounded, reported as damage --------------------------------------------------


def _inspected_around_the_bomb(ran: Ran) -> None:
    assert ran.code == 0
    assert "DAMAGED" in ran.stdout, ran.stdout
    lost = [line for line in ran.stdout.splitlines() if "lost chunk" in line]
    assert len(lost) == 1 and "inflates past the declared uncompressed size" in lost[0], \
        ran.stdout
    # the chunks around it were read
    assert re.search(r"every intact chunk around them was read \(\d+ messages\)",
                     ran.stdout)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("how", ["summary", "scan", "no-summary"])
def test_inspect_reads_around_a_bomb_and_reports_it(files, ran, kind, how):
    path = files.bombs[kind, how]
    result = ran["inspect", path.name]
    _bounded(result, path)
    _inspected_around_the_bomb(result)


def test_the_netsim_script_reads_around_a_bomb(files, tmp_path):
    """The same through its own process (``python -m netsim.cli``): its own peak RSS."""
    path = files.bombs["zstd", "summary"]
    result = _run(tmp_path, [sys.executable, "-m", "netsim.cli", "inspect", str(path)])
    _bounded(result, path)
    _inspected_around_the_bomb(result)


@pytest.mark.parametrize("command", ["replay", "analyze", "plot"])
@pytest.mark.parametrize("kind", ["zstd", "lz4"])
def test_recovering_commands_stay_bounded_on_a_bomb(files, ran, command, kind):
    path = files.bombs[kind, "summary"]
    _bounded(ran[command, path.name], path)


@pytest.mark.parametrize("command", ["replay", "analyze", "plot"])
def test_recovering_commands_report_the_bomb(files, ran, command):
    result = ran[command, files.bombs["zstd", "summary"].name]
    assert result.code == 2 or _reports_damage(result), result.stdout + result.stderr


def test_mcaprecover_loses_only_the_bomb_chunks(files, tmp_path):
    paths = [str(files.bombs[kind, how]) for kind in KINDS for how in ("summary", "scan")]
    script = ("import sys\nfrom netsim.traces.mcaprecover import recover\n"
              "for path in sys.argv[1:]:\n"
              "    r = recover(path)\n"
              "    print(r.chunks, len(r.messages), '|'.join(c.error for c in r.lost))\n")
    result = _run(tmp_path, [sys.executable, "-c", script, *paths])
    _bounded(result, Path())
    assert result.code == 0, result.stderr
    rows = [line.split(" ", 2) for line in result.stdout.strip().splitlines()]
    assert len(rows) == len(paths)
    chunks = len(_chunk_offsets(files.bombs["zstd", "summary"]))
    intact = sum(len(breakup_chunk(c)) for i, c in
                 enumerate(_chunks(_rewrite(files.trace, tmp_path / "ok.mcap", "zstd")))
                 if i != BOMB_CHUNK)
    for n, messages, errors in rows:
        assert errors.count("inflates past the declared uncompressed size") == 1, errors
        assert "|" not in errors
        assert int(n) == chunks
        assert 0 < int(messages) <= intact


def test_read_status_never_inflates_a_chunk(files, tmp_path):
    script = ("import sys\nfrom netsim.traces.reader import read_status\n"
              "for path in sys.argv[1:]:\n"
              "    print((read_status(path) or {}).get('status'))\n")
    paths = [str(files.bombs[kind, "no-summary"]) for kind in KINDS]
    result = _run(tmp_path, [sys.executable, "-c", script, *paths])
    _bounded(result, Path())
    assert result.code == 0, result.stderr
    expected = trace_reader.read_status(files.trace)
    assert expected is not None
    assert result.stdout.split() == [expected["status"]] * len(paths)


def test_stream_records_stops_at_a_bomb_without_inflating_it(files, tmp_path):
    """The bounded stand-in for mcap's StreamReader: the records before the bomb chunk,
    then the damage, as a ValueError."""
    script = textwrap.dedent("""
        import sys
        from netsim.traces.reader import stream_records
        for path in sys.argv[1:]:
            n = 0
            try:
                with open(path, "rb") as f:
                    for _ in stream_records(f, where=path):
                        n += 1
            except ValueError as exc:
                print(n, exc)
    """)
    paths = [str(files.bombs[kind, how]) for kind in KINDS for how in ("summary", "scan")]
    result = _run(tmp_path, [sys.executable, "-c", script, *paths])
    _bounded(result, Path())
    assert result.code == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert len(lines) == len(paths)
    assert all("inflates past the declared uncompressed size" in line for line in lines)
    assert all(int(line.split()[0]) > 0 for line in lines)


# -- declared sizes over the budget: refused in one line --------------------------------


@pytest.mark.parametrize("command", RECOVERING)
def test_a_chunk_declaring_more_than_the_budget_is_refused(files, ran, command):
    path = files.absurd
    result = ran[command, path.name]
    _bounded(result, path)
    assert result.code == 2
    line = result.stderr.strip()
    assert f"declares {HUGE} bytes" in line and "uncompressed" in line, line
    assert "refused" in line and "this machine can give" in line, line


def test_the_netsim_script_refuses_in_one_line(files, tmp_path):
    path = files.absurd
    result = _run(tmp_path, [sys.executable, "-m", "netsim.cli", "plot", str(path), "-o",
                             str(tmp_path / "p.png")])
    _bounded(result, path)
    assert result.code == 2 and f"declares {HUGE} bytes" in result.stderr
    assert not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("how", ["summary", "scan"])
def test_an_honest_bomb_over_the_budget_is_refused(files, ran, how):
    path = files.honest if how == "summary" else files.honest_cut
    result = ran["inspect", path.name, "1G"]
    _bounded(result, path)
    assert result.code == 2
    line = result.stderr.strip()
    assert f"chunk at byte {files.honest_offset} declares {INFLATE} bytes (3.0 GiB)" in line
    assert "1.0 GiB (NETSIM_MEMORY_LIMIT)" in line, line


def test_mcaprecover_refuses_a_chunk_over_the_budget(files):
    from netsim.traces.mcaprecover import recover

    with pytest.raises(ChunkTooLarge) as info:
        recover(files.absurd)
    assert str(files.absurd) in str(info.value) and info.value.declared == HUGE


# -- the bounded function itself ----------------------------------------------------------

RECORDS = bytes(range(256)) * 64  # 16 KiB


def _compressed(kind: str, data: bytes) -> bytes:
    if kind == "zstd":
        return zstandard.ZstdCompressor().compress(data)
    if kind == "zstd-no-content-size":
        return zstandard.ZstdCompressor(write_content_size=False).compress(data)
    return lz4_frame.compress(data)


@pytest.mark.parametrize("kind", KINDS)
def test_inflate_chunk_returns_exactly_the_declared_records(kind):
    compression = kind.split("-")[0]
    data = _compressed(kind, RECORDS)
    assert inflate_chunk(compression, data, len(RECORDS), budget=(1 << 20, "test")) \
        == RECORDS
    assert inflate_chunk(compression, memoryview(data), len(RECORDS),
                         budget=(1 << 20, "test")) == RECORDS
    # two frames back to back (a writer may flush mid-chunk)
    two = _compressed(kind, RECORDS[:1000]) + _compressed(kind, RECORDS[1000:])
    assert inflate_chunk(compression, two, len(RECORDS), budget=(1 << 20, "test")) == RECORDS


@pytest.mark.parametrize("kind", KINDS)
def test_inflate_chunk_calls_more_or_fewer_bytes_damage(kind):
    compression = kind.split("-")[0]
    data = _compressed(kind, RECORDS)
    with pytest.raises(ValueError, match="inflates past the declared uncompressed size"):
        inflate_chunk(compression, data, len(RECORDS) - 1, budget=(1 << 20, "test"))
    with pytest.raises(ValueError, match=f"inflates to {len(RECORDS)} bytes"):
        inflate_chunk(compression, data, len(RECORDS) + 1, budget=(1 << 20, "test"))
    with pytest.raises(ValueError) as info:
        inflate_chunk(compression, b"\x00garbage" * 8, len(RECORDS), budget=(1 << 20, "t"))
    assert not isinstance(info.value, ChunkTooLarge)


def test_inflate_chunk_produces_no_more_than_the_declared_size():
    """64 MiB of zeros declared as 4 KiB: Python allocations stay near 4 KiB (the
    bomb's size would show in tracemalloc's peak)."""
    bomb = _bomb_payload("zstd", 64 << 20)
    lz4_bomb = _bomb_payload("lz4", 64 << 20)
    for compression, data in (("zstd", bomb), ("lz4", lz4_bomb)):
        tracemalloc.start()
        try:
            with pytest.raises(ValueError, match="inflates past"):
                inflate_chunk(compression, data, 4096, budget=(1 << 30, "test"))
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert peak < 1 << 20, (compression, peak)


def test_inflate_chunk_checks_the_budget_before_decompressing(monkeypatch):
    with pytest.raises(ChunkTooLarge) as info:
        inflate_chunk("zstd", b"not even zstd", 5000, budget=(4999, "test budget"),
                      where="x.mcap", offset=123)
    text = str(info.value)
    assert text.startswith("x.mcap: zstd chunk at byte 123 declares 5000 bytes"), text
    assert "(test budget)" in text and "\n" not in text
    assert isinstance(info.value, TraceError)
    # the budget comes from netsim.budget by default, NETSIM_MEMORY_LIMIT included
    monkeypatch.setenv("NETSIM_MEMORY_LIMIT", "1M")
    with pytest.raises(ChunkTooLarge) as info:
        inflate_chunk("lz4", b"", (1 << 20) + 1)
    assert info.value.limit == 1 << 20 and "NETSIM_MEMORY_LIMIT" in str(info.value)
    assert inflate_chunk("lz4", lz4_frame.compress(bytes(1 << 20)), 1 << 20) \
        == bytes(1 << 20)
    # uncompressed chunks are in the file already: only their length is checked
    assert inflate_chunk("", RECORDS, len(RECORDS), budget=(0, "none")) == RECORDS
    with pytest.raises(ValueError, match="declares"):
        inflate_chunk("", RECORDS, len(RECORDS) + 1, budget=(0, "none"))


# -- a normal trace reads exactly as before ----------------------------------------------


def _library_inflate(chunk: Chunk) -> bytes:
    """The mcap library's own (unbounded) decompression, as the reader used it."""
    if chunk.compression == "zstd":
        return zstandard.decompress(chunk.data, chunk.uncompressed_size)
    if chunk.compression == "lz4":
        return lz4_frame.decompress(chunk.data)
    return bytes(chunk.data)


def _chunks(path: Path) -> list[Chunk]:
    data = path.read_bytes()
    return [Chunk.read(ReadDataStream(io.BytesIO(data[at + 9:])))
            for at in _chunk_offsets(path)]


def _previous_reader(chunk: Chunk, budget: object, where: str, offset: int | None,
                     validate_crc: bool = True) -> list:
    """The reader's chunk path before this change: the mcap library's breakup_chunk."""
    return list(breakup_chunk(chunk, validate_crc=validate_crc))


def _until_error(records: Iterator) -> tuple[list, str]:
    """The records an iterator yields, and the error that stopped it ("" for none: an
    unfinished file ends in the mcap library's EndOfFile)."""
    out: list = []
    try:
        for record in records:
            out.append(record)
    except Exception as exc:  # noqa: BLE001 - compared, not handled
        return out, type(exc).__name__
    return out, ""


def _same_trace(a: Trace, b: Trace) -> None:
    assert a.metadata == b.metadata and a.topics == b.topics and a.counts == b.counts
    assert a.file_topics == b.file_topics and a.file_counts == b.file_counts
    assert (a.truncated, a.lost_chunks, a.note, a.unexpanded) == \
        (b.truncated, b.lost_chunks, b.note, b.unexpanded)
    assert sorted(a.matrices) == sorted(b.matrices)
    for name, matrix in a.matrices.items():
        np.testing.assert_array_equal(matrix, b.matrices[name])
    assert len(a.messages) == len(b.messages) > 0
    for x, y in zip(a.messages, b.messages, strict=True):
        assert (x.topic, x.log_time, x.publish_time, x.sequence) == \
            (y.topic, y.log_time, y.publish_time, y.sequence)
        assert x.message.SerializeToString() == y.message.SerializeToString()


@pytest.mark.parametrize("variant", ["format3", "format2", "format3-zstd", "format2-lz4",
                                     "format2-unfinished"])
def test_a_normal_trace_reads_as_through_the_library(files, tmp_path, variant,
                                                     monkeypatch):
    if variant == "format3":
        path = files.trace
    elif variant == "format2":
        path = files.trace2
    elif variant == "format3-zstd":
        path = _rewrite(files.trace, tmp_path / "z.mcap", "zstd")
    elif variant == "format2-lz4":
        path = _rewrite(files.trace2, tmp_path / "l.mcap", "lz4")
    else:
        path = _unfinished(files.trace2, tmp_path / "cut.mcap")
    chunks = _chunks(path)
    assert chunks
    for chunk in chunks:
        assert inflate_chunk(chunk.compression, chunk.data, chunk.uncompressed_size,
                             budget=(1 << 30, "test")) == _library_inflate(chunk)
    if variant in ("format3-zstd", "format2-lz4"):
        assert len(chunks) > 2 and {c.compression for c in chunks} == \
            {variant.rsplit("-", 1)[1]}
    with open(path, "rb") as f:
        library = _until_error(StreamReader(f).records)
    assert len(library[0]) > 10
    with open(path, "rb") as f:
        assert _until_error(stream_records(f, validate_crcs=True)) == library
    new = read_trace(path)
    monkeypatch.setattr(trace_reader, "_chunk_records_of", _previous_reader)
    old = read_trace(path)
    _same_trace(new, old)
    assert not new.lost_chunks


def test_the_bomb_files_are_what_they_claim(files):
    """The fixtures themselves: the bomb chunk really inflates to 3 GiB and declares its
    real records' size (checked with a streaming decompressor, never all at once)."""
    for (kind, how), path in files.bombs.items():
        if how != "summary":
            continue
        chunk = _chunks(path)[BOMB_CHUNK]
        assert chunk.uncompressed_size < 1 << 16
        total = 0
        if kind.startswith("zstd"):
            reader = zstandard.ZstdDecompressor().stream_reader(chunk.data)
            while piece := reader.read(1 << 24):
                total += len(piece)
        else:
            decompressor = lz4_frame.LZ4FrameDecompressor()
            rest = chunk.data
            while not decompressor.eof:
                piece = decompressor.decompress(rest, max_length=1 << 24)
                rest = b""
                total += len(piece)
        assert total == INFLATE, kind
    assert _chunks(files.absurd)[BOMB_CHUNK].uncompressed_size == HUGE


@pytest.mark.parametrize("kind", ["zstd", "lz4"])
def test_layout_stays_bounded_on_a_bomb(files, tmp_path, kind):
    """netsim layout (its summary read, first messages and message-path series) streams
    chunks through the same bounded inflation."""
    path = files.bombs[kind, "summary"]
    result = _run(tmp_path, [sys.executable, "-m", "netsim.cli", "layout", str(path), "-o",
                             str(tmp_path / "l.json"), "--figure", str(tmp_path / "l.png")])
    _bounded(result, path)
