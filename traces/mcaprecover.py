"""Read a possibly damaged MCAP file chunk by chunk, skipping the chunks that fail.

:func:`iter_chunks` walks the chunks of an MCAP file: through the summary's chunk
indexes when the footer and summary are intact (summary CRC checked), else by scanning
the records from the start (a file whose writer was killed has no summary). Each chunk
is checked (record structure, decompression, uncompressed size and CRC) and yielded as
a :class:`ChunkRead` holding either its messages or the reason it was lost; a damaged
chunk never stops the walk, so the messages of every intact chunk after it are read.
Chunks are inflated by :func:`netsim.traces.reader.inflate_chunk`: never past their
declared uncompressed size (a chunk inflating to more or less is lost, like one failing
its CRC), and a compressed chunk declaring more than the memory budget stops the walk
with :class:`netsim.traces.reader.ChunkTooLarge` (naming the file and the size).
The scan resynchronises on the next plausible chunk record after bytes whose record
structure is destroyed, and stops at a record cut off by the end of the file.

:func:`recover` collects everything: top-level schemas, channels and metadata, the
messages of every intact chunk (file order), the lost chunks, and whether the file was
truncated. Works on any MCAP file (not only netsim's); decoding the payloads is the
caller's business.
"""

from __future__ import annotations

import mmap
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from netsim.traces.bulkmcap import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE,
    OP_METADATA,
    OP_SCHEMA,
)
from netsim.traces.reader import Budget, ChunkTooLarge, _next_chunk, chunk_budget, inflate_chunk

__all__ = ["RawMessage", "ChunkRead", "Recovered", "iter_chunks", "recover",
           "chunk_messages"]

_KNOWN = set(range(0x01, 0x10))
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4


class RawMessage(NamedTuple):
    """One Message record, payload undecoded."""

    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: bytes


@dataclass
class ChunkRead:
    """One chunk: its place, time range, and messages (None if it was lost)."""

    ordinal: int
    offset: int
    length: int
    start_time: int | None
    end_time: int | None
    messages: list[RawMessage] | None
    error: str = ""
    #: Schema/Channel records found inside the chunk (raw content bytes by opcode).
    records: list[tuple[int, bytes]] = field(default_factory=list)

    @property
    def lost(self) -> bool:
        return self.messages is None


@dataclass
class Recovered:
    """What :func:`recover` read from a file."""

    schemas: dict[int, tuple[str, str, bytes]]  # id -> (name, encoding, data)
    channels: dict[int, tuple[int, str, str]]  # id -> (schema id, topic, encoding)
    metadata: dict[str, dict[str, str]]
    messages: list[RawMessage]
    lost: list[ChunkRead]
    chunks: int
    truncated: bool
    used_summary: bool


def _string(data: Any, at: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", data, at)
    return bytes(data[at + 4:at + 4 + n]).decode("utf-8"), at + 4 + n


def _string_map(data: Any, at: int) -> tuple[dict[str, str], int]:
    (n,) = struct.unpack_from("<I", data, at)
    end, at, out = at + 4 + n, at + 4, {}
    while at < end:
        key, at = _string(data, at)
        out[key], at = _string(data, at)
    return out, end


def chunk_messages(content: bytes | memoryview, *, budget: Budget | None = None,
                   where: str = "", offset: int | None = None
                   ) -> tuple[list[RawMessage], list[tuple[int, bytes]]]:
    """Parse the Chunk record content ``content`` (after opcode and length).

    Parameters
    ----------
    content : bytes or memoryview
        The chunk record's content.
    budget, where, offset
        As for :func:`netsim.traces.reader.inflate_chunk` (the memory budget, and the
        file and chunk offset a refusal names).

    Returns
    -------
    (list of RawMessage, list of (int, bytes))
        Its messages and its other records (opcode, content).

    Raises
    ------
    ChunkTooLarge
        Compressed and declaring more than the budget (nothing decompressed).
    ValueError
        Damaged: record structure, decompression, uncompressed size or CRC.
    """
    if len(content) < _CHUNK_FIXED + 8:
        raise ValueError("chunk record too short")
    start, end, usize, crc, clen = struct.unpack_from("<QQQII", content, 0)
    at = _CHUNK_FIXED
    compression = bytes(content[at:at + clen]).decode("ascii", "replace")
    at += clen
    (rlen,) = struct.unpack_from("<Q", content, at)
    at += 8
    if at + rlen != len(content):
        raise ValueError("chunk records length does not match the record")
    records = inflate_chunk(compression, content[at:at + rlen], usize, budget=budget,
                            where=where, offset=offset)
    if crc and zlib.crc32(records) != crc:
        raise ValueError(f"chunk CRC mismatch (expected {crc:#010x}, "
                         f"computed {zlib.crc32(records):#010x})")
    messages: list[RawMessage] = []
    others: list[tuple[int, bytes]] = []
    pos, size = 0, len(records)
    unpack = struct.Struct("<BQHIQQ").unpack_from
    while pos < size:
        if size - pos < 9:
            raise ValueError("a record inside the chunk is cut off")
        opcode, length = struct.unpack_from("<BQ", records, pos)
        stop = pos + 9 + length
        if stop > size:
            raise ValueError("a record inside the chunk is cut off")
        if opcode == OP_MESSAGE:
            _, _, ch, seq, lt, pt = unpack(records, pos)
            messages.append(RawMessage(ch, seq, lt, pt, records[pos + 31:stop]))
        else:
            others.append((opcode, records[pos + 9:stop]))
        pos = stop
    return messages, others


def _read_chunk(data: Any, ordinal: int, offset: int, length: int, size: int,
                budget: Budget, where: str) -> ChunkRead:
    times: tuple[int | None, int | None] = (None, None)
    if offset + 9 + 16 <= size:
        times = struct.unpack_from("<QQ", data, offset + 9)
    read = ChunkRead(ordinal, offset, length, times[0], times[1], None)
    refused: ChunkTooLarge | None = None
    try:
        if offset + length > size or length < 9:
            raise ValueError("chunk extends past the end of the file")
        opcode, content_length = struct.unpack_from("<BQ", data, offset)
        if opcode != OP_CHUNK or 9 + content_length != length:
            raise ValueError("no chunk record at the indexed offset")
        read.messages, read.records = chunk_messages(
            memoryview(data)[offset + 9:offset + length], budget=budget, where=where,
            offset=offset)
    except ChunkTooLarge as exc:  # raised below, without the frames holding the mmap
        refused = exc.with_traceback(None)
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        read.messages = None
        read.error = str(exc)
    if refused is not None:
        raise refused
    return read


def _summary_chunks(data: Any, size: int) -> list[tuple[int, int]] | None:
    """(offset, length) of every chunk from the summary, or None if it is unusable."""
    footer_at = size - 8 - 29
    if footer_at < 8 or bytes(data[size - 8:]) != MAGIC:
        return None
    opcode, length, summary_start, _offsets, crc = struct.unpack_from("<BQQQI", data,
                                                                       footer_at)
    if opcode != OP_FOOTER or length != 20 or not summary_start:
        return None
    if not 8 <= summary_start <= footer_at:
        return None
    if crc:
        actual = zlib.crc32(memoryview(data)[summary_start:footer_at + 25])
        if actual != crc:
            return None
    out: list[tuple[int, int]] = []
    pos = summary_start
    try:
        while pos < footer_at:
            op, n = struct.unpack_from("<BQ", data, pos)
            if op == OP_CHUNK_INDEX:
                _s, _e, chunk_at, chunk_length = struct.unpack_from("<QQQQ", data, pos + 9)
                out.append((chunk_at, chunk_length))
            pos += 9 + n
    except struct.error:
        return None
    return sorted(out)


def _scan(data: Any, size: int, top: list[tuple[int, bytes]], budget: Budget,
          where: str) -> Iterator[ChunkRead | bool]:
    """Chunks by scanning; top-level records go to ``top``; yields True at the end if
    the file was cut off (no footer reached)."""
    pos, ordinal = len(MAGIC), 0
    while pos < size:
        if size - pos < 9:
            yield True
            return
        opcode, length = struct.unpack_from("<BQ", data, pos)
        end = pos + 9 + length
        if opcode not in _KNOWN or end > size:
            resume = _next_chunk(data, pos + 1, size)
            if resume is None:
                if opcode in _KNOWN:  # the last record was cut off
                    yield True
                    return
                yield ChunkRead(-1, pos, size - pos, None, None, None,
                                "unreadable bytes (record structure destroyed)")
                yield True
                return
            yield ChunkRead(-1, pos, resume - pos, None, None, None,
                            "unreadable bytes (record structure destroyed)")
            pos = resume
            continue
        if opcode == OP_CHUNK:
            yield _read_chunk(data, ordinal, pos, 9 + length, size, budget, where)
            ordinal += 1
        elif opcode in (OP_SCHEMA, OP_CHANNEL, OP_METADATA):
            top.append((opcode, bytes(data[pos + 9:end])))
        elif opcode in (OP_FOOTER, OP_DATA_END):
            return
        pos = end
    yield True


def iter_chunks(path: str | os.PathLike[str], *, use_summary: bool = True,
                top_level: list[tuple[int, bytes]] | None = None) -> Iterator[ChunkRead]:
    """Yield every chunk of an MCAP file, intact (with messages) or lost (with why).

    Parameters
    ----------
    path : str or os.PathLike
    use_summary : bool
        Find the chunks through the summary's chunk indexes when it is intact.
    top_level : list, optional
        Receives the (opcode, content) of top-level Schema, Channel and Metadata
        records met while scanning (not filled when the summary is used).

    Raises
    ------
    ChunkTooLarge
        A compressed chunk declares more uncompressed bytes than the memory budget.
    """
    for item in _iter(path, use_summary, [] if top_level is None else top_level):
        if isinstance(item, ChunkRead):
            yield item


def _iter(path: Any, use_summary: bool, top: list[tuple[int, bytes]]
          ) -> Iterator[ChunkRead | bool | str]:
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size < len(MAGIC) or f.read(len(MAGIC)) != MAGIC:
            raise ValueError(f"{path}: not an MCAP file (no magic)")
        data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        budget, where = chunk_budget(), os.fspath(path)
        try:
            chunks = _summary_chunks(data, size) if use_summary else None
            if chunks is not None:
                yield "summary"
                for ordinal, (offset, length) in enumerate(chunks):
                    yield _read_chunk(data, ordinal, offset, length, size, budget, where)
                # top-level records still come from the data section
                _top_level(data, size, top, chunks)
            else:
                yield from _scan(data, size, top, budget, where)
        finally:
            data.close()


def _top_level(data: Any, size: int, top: list[tuple[int, bytes]],
               chunks: list[tuple[int, int]]) -> None:
    """Top-level schema/channel/metadata records of an indexed file (scan that jumps
    over the chunks; stops at the first damaged record)."""
    pos = len(MAGIC)
    while pos + 9 <= size:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        end = pos + 9 + length
        if opcode not in _KNOWN or end > size or opcode in (OP_DATA_END, OP_FOOTER):
            return
        if opcode in (OP_SCHEMA, OP_CHANNEL, OP_METADATA):
            top.append((opcode, bytes(data[pos + 9:end])))
        pos = end


def recover(path: str | os.PathLike[str]) -> Recovered:
    """Read every intact chunk of a (possibly damaged or unfinished) MCAP file.

    Returns
    -------
    Recovered
        Schemas and channels (top-level and inside intact chunks), metadata, the
        messages of the intact chunks in file order, the lost chunks (offset, time
        range, reason), the chunk count, whether the file was cut off, and whether the
        summary was used.

    Raises
    ------
    ChunkTooLarge
        A compressed chunk declares more uncompressed bytes than the memory budget.
    """
    top: list[tuple[int, bytes]] = []
    messages: list[RawMessage] = []
    lost: list[ChunkRead] = []
    chunks, truncated, used_summary = 0, False, False
    inner: list[tuple[int, bytes]] = []
    for item in _iter(path, True, top):
        if item == "summary":
            used_summary = True
        elif item is True:
            truncated = True
        elif isinstance(item, ChunkRead):
            if item.ordinal >= 0:
                chunks += 1
            if item.lost:
                lost.append(item)
            else:
                messages.extend(item.messages or [])
                inner.extend(item.records)
    schemas: dict[int, tuple[str, str, bytes]] = {}
    channels: dict[int, tuple[int, str, str]] = {}
    metadata: dict[str, dict[str, str]] = {}
    for opcode, content in top + inner:
        try:
            if opcode == OP_SCHEMA:
                (sid,) = struct.unpack_from("<H", content, 0)
                name, at = _string(content, 2)
                encoding, at = _string(content, at)
                (n,) = struct.unpack_from("<I", content, at)
                schemas[sid] = (name, encoding, bytes(content[at + 4:at + 4 + n]))
            elif opcode == OP_CHANNEL:
                cid, sid = struct.unpack_from("<HH", content, 0)
                topic, at = _string(content, 4)
                encoding, at = _string(content, at)
                channels[cid] = (sid, topic, encoding)
            elif opcode == OP_METADATA:
                name, at = _string(content, 0)
                metadata[name], _ = _string_map(content, at)
        except (struct.error, UnicodeDecodeError):
            continue
    return Recovered(schemas, channels, metadata, messages, lost, chunks, truncated,
                     used_summary)
