"""A lean MCAP writer whose Message records are packed in bulk with numpy.

:class:`BulkMcapWriter` writes a complete, indexed MCAP file (format specification:
https://mcap.dev/spec): magic, Header (profile and library string), Schema and
Channel records, Metadata and Attachment records, Chunks (zstd compressed, the
uncompressed CRC set), one Message Index record per channel after each chunk, Data
End (with the data section CRC), and a summary section (schemas, channels,
statistics, chunk indexes, attachment and metadata indexes, summary offsets) closed by
the Footer (summary CRC) and the trailing magic.

Messages enter in two ways, through the same chunk builder:

- :meth:`BulkMcapWriter.add_messages`: a batch given as columns (``channel_id``,
  ``sequence``, ``log_time``, ``publish_time``) and payloads (a 2-D uint8 array of
  equal-length payloads, or a concatenated buffer and offsets). The records' bytes are
  built with one numpy structured array (or one scatter for unequal lengths), without
  a Python loop over messages;
- :meth:`BulkMcapWriter.add_message`: one message (the event kernel's observer path).

Schemas and channels are written as top-level records of the data section (outside
the chunks), so a damaged chunk never takes a channel definition with it.

Crash safety: every chunk completed by :meth:`BulkMcapWriter.add_message` or a
waiting :meth:`BulkMcapWriter.flush` is written and flushed to the OS at once (its
message indexes right after it), so a writer killed at any moment leaves a file
readable to its last complete chunk (no summary: readers scan it). Chunks completed by
:meth:`BulkMcapWriter.add_records` (the bulk path) or ``flush(wait=False)`` are
compressed (uncompressed ones: their CRCs computed) on a background thread (zstd and
zlib.crc32 release the GIL) while the caller builds the next ones (chunks of at least
128 KiB), and written in order as soon as done, at most two chunks behind. The
data-section CRC takes up each chunk's bytes by combining CRCs
(:func:`netsim.traces.crc32.crc32_combine`) rather than by a second pass over them. :meth:`close`
(idempotent) finishes the file; use the writer as a context manager (a Ctrl-C
raising KeyboardInterrupt inside the ``with`` still finishes the file) and it also
registers itself with :mod:`atexit` for an interpreter that exits without closing it.

:func:`message_records` is the packing step alone (records' bytes from columns).
"""

from __future__ import annotations

import atexit
import collections
import functools
import os
import struct
import threading
import weakref
import zlib
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import IO, Any, Literal, cast

import numpy as np
import zstandard
from netsim.traces import crc32

__all__ = [
    "MAGIC",
    "LIBRARY_IDENTIFIER",
    "MESSAGE_HEADER_DTYPE",
    "BulkMcapWriter",
    "message_records",
    "OP_HEADER",
    "OP_FOOTER",
    "OP_SCHEMA",
    "OP_CHANNEL",
    "OP_MESSAGE",
    "OP_CHUNK",
    "OP_MESSAGE_INDEX",
    "OP_CHUNK_INDEX",
    "OP_ATTACHMENT",
    "OP_ATTACHMENT_INDEX",
    "OP_STATISTICS",
    "OP_METADATA",
    "OP_METADATA_INDEX",
    "OP_SUMMARY_OFFSET",
    "OP_DATA_END",
]

#: Library identifier of this writer (for an MCAP Header's library string).
LIBRARY_IDENTIFIER = "netsim-bulkmcap/1"
#: Leading and trailing magic of MCAP major version 0.
MAGIC = b"\x89MCAP0\r\n"

OP_HEADER = 0x01
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_MESSAGE_INDEX = 0x07
OP_CHUNK_INDEX = 0x08
OP_ATTACHMENT = 0x09
OP_ATTACHMENT_INDEX = 0x0A
OP_STATISTICS = 0x0B
OP_METADATA = 0x0C
OP_METADATA_INDEX = 0x0D
OP_SUMMARY_OFFSET = 0x0E
OP_DATA_END = 0x0F

#: Opcode, record length and the fixed fields of a Message record (31 bytes, packed).
MESSAGE_HEADER_DTYPE = np.dtype([
    ("opcode", "u1"), ("length", "<u8"), ("channel_id", "<u2"), ("sequence", "<u4"),
    ("log_time", "<u8"), ("publish_time", "<u8"),
])
_HEAD = MESSAGE_HEADER_DTYPE.itemsize  # 31
_FIXED = _HEAD - 9  # Message fields before the data: 22 bytes
_MESSAGE_STRUCT = struct.Struct("<BQHIQQ")


def _string(value: str) -> bytes:
    raw = value.encode("utf-8")
    return struct.pack("<I", len(raw)) + raw


def _string_map(mapping: Mapping[str, str]) -> bytes:
    body = b"".join(_string(str(k)) + _string(str(v)) for k, v in mapping.items())
    return struct.pack("<I", len(body)) + body


def _record(opcode: int, content: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(content)) + content


def _column(value: Any, n: int, dtype: str, name: str) -> np.ndarray:
    array = np.asarray(value)
    if array.ndim == 0:
        return np.full(n, array, dtype=dtype)
    if array.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},), got {array.shape}")
    return array.astype(dtype, copy=False)


@functools.cache
def _record_dtype(width: int) -> np.dtype:
    return np.dtype(MESSAGE_HEADER_DTYPE.descr + [("data", "u1", (width,))])


def message_records(
    channel_id: Any,
    sequence: Any,
    log_time: Any,
    publish_time: Any,
    payloads: np.ndarray | bytes,
    offsets: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pack a batch of messages into consecutive MCAP Message records.

    Parameters
    ----------
    channel_id, sequence, log_time, publish_time : array_like, shape (n,) or scalar
        The Message fields (uint16, uint32, uint64, uint64 ns); a scalar applies to
        every message.
    payloads : numpy.ndarray, shape (n, L), uint8; or bytes-like
        Equal-length payloads as rows, or (with ``offsets``) all payloads concatenated.
    offsets : numpy.ndarray, shape (n + 1,), optional
        Payload i is ``payloads[offsets[i]:offsets[i + 1]]`` (``offsets[0] == 0``).

    Returns
    -------
    records : numpy.ndarray, shape (total_bytes,), uint8
        The records, opcode and length prefix included, back to back.
    starts : numpy.ndarray, shape (n,), int64
        Offset of each record in ``records``.
    """
    if offsets is None:
        rows = np.asarray(payloads, dtype=np.uint8)
        if rows.ndim != 2:
            raise ValueError(f"payloads: expected a 2-D uint8 array, got shape {rows.shape}")
        n, width = rows.shape
        dtype = _record_dtype(width)
        out = np.empty(n, dtype=dtype)
        out["opcode"] = OP_MESSAGE
        out["length"] = _FIXED + width
        out["data"] = rows
        lengths = None
    else:
        offsets = np.asarray(offsets, dtype=np.int64)
        n = offsets.shape[0] - 1
        buffer = np.frombuffer(payloads, dtype=np.uint8) if not isinstance(
            payloads, np.ndarray) else payloads.reshape(-1).view(np.uint8)
        if n < 0 or offsets[0] != 0 or offsets[-1] != buffer.shape[0] or np.any(
                np.diff(offsets) < 0):
            raise ValueError("offsets: expected n + 1 non-decreasing offsets from 0 to "
                             "the buffer's length")
        out = np.empty(n, dtype=MESSAGE_HEADER_DTYPE)
        lengths = np.diff(offsets)
        out["opcode"] = OP_MESSAGE
        out["length"] = _FIXED + lengths
    out["channel_id"] = _column(channel_id, n, "<u2", "channel_id")
    out["sequence"] = _column(sequence, n, "<u4", "sequence")
    out["log_time"] = _column(log_time, n, "<u8", "log_time")
    out["publish_time"] = _column(publish_time, n, "<u8", "publish_time")
    if lengths is None:
        records = out.view(np.uint8).reshape(-1)
        starts = np.arange(n, dtype=np.int64) * dtype.itemsize
        return records, starts
    sizes = _HEAD + lengths
    ends = np.cumsum(sizes)
    starts = ends - sizes
    total = int(ends[-1]) if n else 0
    is_head = np.zeros(total, dtype=bool)
    head_at = (starts[:, None] + np.arange(_HEAD)).reshape(-1)
    is_head[head_at] = True
    records = np.empty(total, dtype=np.uint8)
    records[head_at] = out.view(np.uint8).reshape(-1)
    records[~is_head] = buffer
    return records, starts


_INDEX_HEAD_DTYPE = np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel_id", "<u2"),
                              ("bytes", "<u4")])
_INDEX_MAP_DTYPE = np.dtype([("channel_id", "<u2"), ("offset", "<u8")])


class _ChunkBuilder:
    """Records of the chunk in progress and the (channel, log_time, offset) of each."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.pieces: list[Any] = []
        self.size = 0
        self.count = 0
        self.start_time: int | None = None
        self.end_time = 0
        self.bulk: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.events: list[int] = []  # flat channel, log_time, offset triples

    def add_one(self, channel_id: int, sequence: int, log_time: int, publish_time: int,
                data: bytes) -> None:
        self.pieces.append(_MESSAGE_STRUCT.pack(OP_MESSAGE, _FIXED + len(data), channel_id,
                                                sequence, log_time, publish_time))
        self.pieces.append(data)
        self.events += (channel_id, log_time, self.size)
        self.size += _HEAD + len(data)
        self.count += 1
        if self.start_time is None or log_time < self.start_time:
            self.start_time = log_time
        if log_time > self.end_time:
            self.end_time = log_time

    def add_bulk(self, records: np.ndarray, starts: np.ndarray, channel_id: np.ndarray,
                 log_time: np.ndarray) -> None:
        if not starts.shape[0]:
            return
        self.bulk.append((channel_id, log_time, starts.astype(np.uint64) + np.uint64(self.size)))
        self.pieces.append(records)
        self.size += records.shape[0]
        self.count += starts.shape[0]
        lo, hi = int(log_time.min()), int(log_time.max())
        if self.start_time is None or lo < self.start_time:
            self.start_time = lo
        self.end_time = max(self.end_time, hi)

    def message_indexes(self, base: int) -> tuple[np.ndarray, bytes]:
        """The Message Index records of the chunk, one per channel (increasing id),
        entries sorted by log_time (ties in file order), written at file offset
        ``base``; and the chunk index's map channel -> record offset (its bytes)."""
        parts = list(self.bulk)
        if self.events:
            flat = np.asarray(self.events, dtype=np.uint64).reshape(-1, 3)
            parts.append((flat[:, 0], flat[:, 1], flat[:, 2]))
        if len(parts) == 1:
            channel, log_time, offset = parts[0]
        else:
            channel = np.concatenate([p[0] for p in parts])
            log_time = np.concatenate([p[1] for p in parts])
            offset = np.concatenate([p[2] for p in parts])
        channel = channel.astype(np.uint16, copy=False)
        # entries arrive in file order (offsets increasing): a stable sort by channel
        # (radix sort for uint16) keeps file order within a channel, which is log_time
        # order unless a channel's messages were added out of time order
        order = np.argsort(channel, kind="stable")
        by_channel = channel[order]
        t_sorted = log_time[order]
        backwards = (t_sorted[1:] < t_sorted[:-1]) & (by_channel[1:] == by_channel[:-1])
        if backwards.any() or (self.events and self.bulk):
            order = np.lexsort((offset, log_time, channel))
            by_channel = channel[order]
        channel = by_channel
        pairs = np.empty((order.shape[0], 2), dtype="<u8")
        pairs[:, 0] = log_time[order]
        pairs[:, 1] = offset[order]
        first = np.concatenate([[0], np.flatnonzero(np.diff(channel)) + 1])
        counts = np.diff(np.append(first, channel.shape[0]))
        heads = np.empty(first.shape[0], dtype=_INDEX_HEAD_DTYPE)
        heads["opcode"] = OP_MESSAGE_INDEX
        heads["length"] = 6 + 16 * counts
        heads["channel_id"] = channel[first]
        heads["bytes"] = 16 * counts
        sizes = 15 + 16 * counts
        starts = np.cumsum(sizes) - sizes
        out = np.empty(int(sizes.sum()), dtype=np.uint8)
        is_head = np.zeros(out.shape[0], dtype=bool)
        head_at = (starts[:, None] + np.arange(15)).reshape(-1)
        is_head[head_at] = True
        out[head_at] = heads.view(np.uint8).reshape(-1)
        out[~is_head] = pairs.view(np.uint8).reshape(-1)
        offsets = np.empty(first.shape[0], dtype=_INDEX_MAP_DTYPE)
        offsets["channel_id"] = heads["channel_id"]
        offsets["offset"] = starts + base
        return out, offsets.tobytes()

    def content(self) -> bytes:
        return b"".join(p if isinstance(p, bytes) else memoryview(p) for p in self.pieces)


_LIVE: weakref.WeakSet[BulkMcapWriter] = weakref.WeakSet()

#: Chunks compressed in the background at most this far ahead of the file (per writer).
_AHEAD = 2
#: Smaller chunks are compressed at once (handing them to a thread costs more than it
#: saves: measured on the N = 4 traces of ``benchmarks/trace_throughput.py``).
_BACKGROUND_MIN = 128 * 1024
_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()
_LOCAL = threading.local()


def _pool() -> ThreadPoolExecutor:
    """The shared pool compressing chunks (zstd and zlib.crc32 release the GIL)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=max(1, min(2, os.cpu_count() or 1)),
                                       thread_name_prefix="bulkmcap-zstd")
        return _POOL


def _compress(level: int | None, pieces: list[Any], size: int
              ) -> tuple[int, Any, int | None]:
    """(CRC32 of the uncompressed records, the chunk's compressed records, CRC32 of the
    compressed records or None); zstd at ``level`` (None: uncompressed, the pieces as
    given), one compressor per thread and level.

    The third is what the data-section CRC takes up by combination
    (:func:`netsim.traces.crc32.crc32_combine`) instead of a second pass over the bytes
    written; None when no combination is available."""
    crc = 0
    for piece in pieces:
        crc = zlib.crc32(piece, crc)
    if level is None:  # written piece by piece (no copy of the chunk)
        return crc, pieces, crc if crc32.AVAILABLE else None
    cctxs = getattr(_LOCAL, "cctxs", None)
    if cctxs is None:
        cctxs = _LOCAL.cctxs = {}
    cctx = cctxs.get(level)
    if cctx is None:
        cctx = cctxs[level] = zstandard.ZstdCompressor(level=level)
    # one call on the whole chunk: ZstdCompressor.compress releases the GIL (a
    # compressobj's compress does not)
    compressed = cctx.compress(pieces[0] if len(pieces) == 1 else b"".join(pieces))
    return crc, compressed, zlib.crc32(compressed) if crc32.AVAILABLE else None


@atexit.register
def _close_all() -> None:  # pragma: no cover - runs at interpreter exit
    for writer in list(_LIVE):
        try:
            writer.close()
        except Exception:  # noqa: BLE001 - best effort at exit
            pass


class BulkMcapWriter:
    """Write an indexed MCAP file, messages packed in bulk with numpy.

    Parameters
    ----------
    output : str, os.PathLike or binary file object
        The file to create (overwritten), or an open stream (left open by close()).
    profile : str
        The Header's profile ("" for none).
    library : str or None
        The Header's library string, written at once; None (default): the header is
        written by :meth:`start` (or with defaults by the first record)
        (``mcap.writer.Writer``'s protocol: construct, ``start(profile, library)``,
        ``register_schema``, ``register_channel``, ``add_message``, ``finish``).
    chunk_size : int
        Close a chunk once its uncompressed records reach this many bytes (a bulk
        batch is split across chunks at record boundaries).
    compression : str or mcap.writer.CompressionType
        ``zstd`` (default) or ``none`` (``CompressionType.ZSTD`` / ``NONE``).
    level : int
        zstd compression level.
    fsync : bool
        Also ``os.fsync`` after each chunk (default: flush to the OS only).
    background : bool
        Compress chunks (uncompressed: compute their CRCs) on a shared pool of (at most
        2) threads while the caller builds the next ones (default True; chunks of at
        least 128 KiB; zlib.crc32 and zstd release the GIL). Chunks are
        written in order, each as soon as it is compressed and at most two chunks behind
        the one in progress; :meth:`flush` and :meth:`close` wait for all of them, so
        the file's bytes do not depend on the threads' timing.
    """

    def __init__(
        self,
        output: str | os.PathLike[str] | IO[bytes],
        chunk_size: int = 1024 * 1024,
        compression: Any = "zstd",
        *,
        profile: str = "",
        library: str | None = None,
        level: int = 3,
        fsync: bool = False,
        background: bool = True,
    ) -> None:
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
        # a string, or mcap.writer.CompressionType (ZSTD, NONE)
        compression = str(getattr(compression, "name", compression)).lower()
        if compression not in ("zstd", "none", ""):
            raise ValueError(f"unknown compression {compression!r}; expected zstd or none")
        self.compression = "zstd" if compression == "zstd" else ""
        self.level = int(level)
        self.background = bool(background)
        self._pending: collections.deque[tuple[_ChunkBuilder, Any]] = collections.deque()
        self.chunk_size = int(chunk_size)
        self.fsync = fsync
        if isinstance(output, (str, os.PathLike)):
            self.path: Path | None = Path(output)
            self._stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - close()
            self._own = True
        else:
            self.path = None
            self._stream = output
            self._own = False
        self._position = 0
        self._crc = 0
        self.closed = False
        self._schemas: dict[int, bytes] = {}  # id -> record bytes
        self._channels: dict[int, bytes] = {}
        self._channel_ids: dict[str, int] = {}
        self._chunk_indexes: list[bytes] = []
        self._attachment_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._counts: list[int] = []  # messages per channel id (add_message)
        self._bulk_counts = np.zeros(0, dtype=np.int64)  # and add_records
        self.message_count = 0
        self.chunk_count = 0
        self._start_time: int | None = None
        self._end_time = 0
        self._chunk = _ChunkBuilder()
        self._started = False
        if library is not None:
            try:
                self.start(profile, library)
            except BaseException:
                if self._own:
                    self._stream.close()
                raise
        _LIVE.add(self)

    def start(self, profile: str = "", library: str = LIBRARY_IDENTIFIER) -> None:
        """Write the magic and the Header (done by the constructor unless it was given
        ``library=None``; as ``mcap.writer.Writer.start``)."""
        if self._started:
            raise RuntimeError("the MCAP writer was already started")
        self._started = True
        self._write(MAGIC)
        self._write(_record(OP_HEADER, _string(profile) + _string(library)))
        self._stream.flush()

    # -- definitions ----------------------------------------------------------------

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a Schema record; return its id (1, 2, ...)."""
        self._check_open()
        schema_id = len(self._schemas) + 1
        record = _record(OP_SCHEMA, struct.pack("<H", schema_id) + _string(name)
                         + _string(encoding) + struct.pack("<I", len(data)) + bytes(data))
        self._schemas[schema_id] = record
        self._write(record)
        return schema_id

    def add_channel(self, topic: str, message_encoding: str, schema_id: int,
                    metadata: Mapping[str, str] | None = None) -> int:
        """Write a Channel record; return its id (0, 1, ...; the same id for a topic
        already added)."""
        self._check_open()
        known = self._channel_ids.get(topic)
        if known is not None:
            return known
        if schema_id and schema_id not in self._schemas:
            raise ValueError(f"channel {topic!r}: unknown schema id {schema_id}")
        channel_id = len(self._channels)
        if channel_id > 0xFFFF:
            raise ValueError("more than 65536 channels")
        record = _record(OP_CHANNEL, struct.pack("<HH", channel_id, schema_id)
                         + _string(topic) + _string(message_encoding)
                         + _string_map(metadata or {}))
        self._channels[channel_id] = record
        self._channel_ids[topic] = channel_id
        self._counts.append(0)
        self._write(record)
        return channel_id

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a Metadata record (and index it in the summary); handed to the OS with
        the next chunk or :meth:`flush`."""
        self._check_open()
        offset = self._position
        record = _record(OP_METADATA, _string(name) + _string_map(data))
        self._write(record)
        self._metadata_indexes.append(_record(OP_METADATA_INDEX, struct.pack(
            "<QQ", offset, len(record)) + _string(name)))

    def add_attachment(self, create_time: int, log_time: int, name: str, media_type: str,
                       data: bytes) -> None:
        """Write an Attachment record (CRC set; indexed in the summary); the arguments
        of ``mcap.writer.Writer.add_attachment``; handed to the OS with the next chunk
        or :meth:`flush`."""
        self._check_open()
        offset = self._position
        body = (struct.pack("<QQ", log_time, create_time) + _string(name)
                + _string(media_type) + struct.pack("<Q", len(data)) + bytes(data))
        record = _record(OP_ATTACHMENT, body + struct.pack("<I", zlib.crc32(body)))
        self._write(record)
        self._attachment_indexes.append(_record(OP_ATTACHMENT_INDEX, struct.pack(
            "<QQQQQ", offset, len(record), log_time, create_time, len(data))
            + _string(name) + _string(media_type)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """:meth:`add_schema` under ``mcap.writer.Writer``'s name."""
        return self.add_schema(name, encoding, data)

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: Mapping[str, str] | None = None) -> int:
        """:meth:`add_channel` under ``mcap.writer.Writer``'s name."""
        return self.add_channel(topic, message_encoding, schema_id, metadata)

    # -- messages --------------------------------------------------------------------

    def add_message(self, channel_id: int, log_time: int, data: bytes,
                    publish_time: int = 0, sequence: int = 0) -> None:
        """Append one message to the chunk in progress (closed when full)."""
        if self.closed:
            raise RuntimeError("the MCAP writer is closed")
        self._counts[channel_id] += 1  # IndexError for a channel never added
        chunk = self._chunk
        chunk.add_one(channel_id, sequence, log_time, publish_time, data)
        if chunk.size >= self.chunk_size:
            # the event kernel's path: every closed chunk is in the file at once
            self._finish_chunk()

    def add_messages(self, channel_id: Any, log_time: Any, payloads: np.ndarray | bytes,
                     *, publish_time: Any = None, sequence: Any = 0,
                     offsets: np.ndarray | None = None) -> None:
        """Append a batch of messages (records packed by :func:`message_records`).

        Parameters
        ----------
        channel_id : array_like, shape (n,), or int
        log_time : array_like, shape (n,), uint64 ns
        payloads : numpy.ndarray, shape (n, L), uint8; or bytes-like with ``offsets``
        publish_time : array_like, shape (n,), optional
            Defaults to ``log_time``.
        sequence : array_like, shape (n,), or int
        offsets : numpy.ndarray, shape (n + 1,), optional
            Payload boundaries in a concatenated ``payloads`` buffer.

        Messages keep their given order in the file; the message indexes are sorted by
        log_time (ties in file order).
        """
        self._check_open()
        log_time = np.asarray(log_time, dtype=np.uint64).reshape(-1)
        n = log_time.shape[0]
        if n == 0:
            return
        channel = _column(channel_id, n, "<u2", "channel_id")
        if int(channel.max()) >= len(self._channels):
            raise ValueError(f"channel_id: {int(channel.max())} was never added")
        publish = log_time if publish_time is None else publish_time
        records, starts = message_records(channel, sequence, log_time, publish, payloads,
                                          offsets)
        self.add_records(records, starts, channel, log_time)

    def add_records(self, records: np.ndarray, starts: np.ndarray, channel_id: np.ndarray,
                    log_time: np.ndarray) -> None:
        """Append Message records packed beforehand by :func:`message_records`.

        Parameters
        ----------
        records : numpy.ndarray, shape (total_bytes,), uint8
        starts : numpy.ndarray, shape (n,), int64
            Offset of each record in ``records`` (``starts[0] == 0``).
        channel_id : numpy.ndarray, shape (n,), uint16
            The records' channels (as written in them).
        log_time : numpy.ndarray, shape (n,), uint64
            The records' log times (as written in them).
        """
        self._check_open()
        channel = np.asarray(channel_id, dtype=np.uint16)
        log_time = np.asarray(log_time, dtype=np.uint64)
        n = starts.shape[0]
        if n == 0:
            return
        if int(channel.max()) >= len(self._channels):
            raise ValueError(f"channel_id: {int(channel.max())} was never added")
        counts = np.bincount(channel)
        if self._bulk_counts.shape[0] < counts.shape[0]:
            grown = np.zeros(len(self._channels), dtype=np.int64)
            grown[:self._bulk_counts.shape[0]] = self._bulk_counts
            self._bulk_counts = grown
        self._bulk_counts[:counts.shape[0]] += counts
        total = records.shape[0]
        first = 0
        while first < n:
            room = self.chunk_size - self._chunk.size
            begin = int(starts[first])
            # the records that fit in the room left (at least one)
            last = int(np.searchsorted(starts, begin + room, side="left"))
            last = min(max(last, first + 1), n)
            stop = total if last == n else int(starts[last])
            self._chunk.add_bulk(records[begin:stop], starts[first:last] - begin,
                                 channel[first:last], log_time[first:last])
            first = last
            if self._chunk.size >= self.chunk_size:
                self._finish_chunk(wait=False)

    # -- file management ------------------------------------------------------------

    def flush(self, wait: bool = True) -> None:
        """Close the chunk in progress (if any) and hand the file to the OS.

        ``wait=False``: chunks still being compressed in the background are written
        later (at most two behind; by the next waiting flush or :meth:`close` at the
        latest)."""
        self._check_open()
        self._finish_chunk(wait=wait)
        self._stream.flush()

    def close(self) -> None:
        """Finish the file: last chunk, Data End, summary, Footer, magic. Idempotent."""
        if self.closed:
            return
        self.closed = True
        _LIVE.discard(self)
        try:
            if not self._started:
                self.start()
            self._finish_chunk()
            self._write(_record(OP_DATA_END, struct.pack("<I", self._crc)))
            self._write_summary()
            self._stream.flush()
        finally:
            if self._own:
                self._stream.close()

    finish = close

    def __enter__(self) -> BulkMcapWriter:
        return self

    def __exit__(self, *exc: Any) -> Literal[False]:
        self.close()
        return False

    # -- internals ------------------------------------------------------------------

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError("the MCAP writer is closed")
        if not self._started:
            self.start()

    def _write(self, data: Any) -> None:
        self._stream.write(data)
        self._crc = zlib.crc32(data, self._crc)
        self._position += len(data) if not isinstance(data, np.ndarray) else data.nbytes

    def _finish_chunk(self, wait: bool = True) -> None:
        """Close the chunk in progress (compressed in the background if enabled) and
        write the closed chunks that are due: all (``wait``) or all but ``_AHEAD``."""
        chunk = self._chunk
        if chunk.count:
            self._chunk = _ChunkBuilder()
            level = self.level if self.compression else None
            # one buffer: the worker then needs the GIL only to start and to return
            # (zlib.crc32 and ZstdCompressor.compress release it)
            pieces = [chunk.content()] if level is not None else [
                p if isinstance(p, bytes) else memoryview(p) for p in chunk.pieces]
            job: Any = None
            # (a waiting flush computes its own chunk here: handing it over gains nothing)
            if self.background and not wait and chunk.size >= _BACKGROUND_MIN:
                try:
                    job = _pool().submit(_compress, level, pieces, chunk.size)
                except RuntimeError:  # interpreter shutting down: compress here
                    job = None
            if job is None:
                job = _compress(level, pieces, chunk.size)
            self._pending.append((chunk, job))
        limit = 0 if wait else _AHEAD
        while len(self._pending) > limit:
            self._write_chunk(*self._pending[0])
            self._pending.popleft()

    def _write_chunk(self, chunk: _ChunkBuilder, job: Any) -> None:
        crc, compressed, written_crc = job.result() if isinstance(job, Future) else job
        pieces = compressed if isinstance(compressed, list) else [compressed]
        compressed_size = sum(p.nbytes if isinstance(p, (np.ndarray, memoryview)) else len(p)
                              for p in pieces)
        size = chunk.size
        # a chunk is written with at least one message: its times are set
        start, end = int(cast(int, chunk.start_time)), int(chunk.end_time)
        body = (struct.pack("<QQQI", start, end, size, crc) + _string(self.compression)
                + struct.pack("<Q", compressed_size))
        head = struct.pack("<BQ", OP_CHUNK, len(body) + compressed_size)
        chunk_start = self._position
        self._write(head + body)
        if written_crc is None:
            for piece in pieces:
                self._write(piece)
        else:  # the data-section CRC by combination (no second pass over the bytes)
            for piece in pieces:
                self._stream.write(piece)
            self._position += compressed_size
            self._crc = crc32.crc32_combine(self._crc, written_crc, compressed_size)
        chunk_length = self._position - chunk_start
        index_start = self._position
        indexes, offsets_map = chunk.message_indexes(index_start)
        self._write(indexes)
        self._chunk_indexes.append(_record(OP_CHUNK_INDEX, struct.pack(
            "<QQQQ", start, end, chunk_start, chunk_length)
            + struct.pack("<I", len(offsets_map)) + offsets_map
            + struct.pack("<Q", self._position - index_start) + _string(self.compression)
            + struct.pack("<QQ", compressed_size, size)))
        self.message_count += chunk.count
        self.chunk_count += 1
        if self._start_time is None or start < self._start_time:
            self._start_time = start
        self._end_time = max(self._end_time, end)
        self._stream.flush()
        if self.fsync and hasattr(self._stream, "fileno"):
            os.fsync(self._stream.fileno())

    def _write_summary(self) -> None:
        summary_start = self._position
        parts: list[bytes] = []
        groups: list[tuple[int, int, int]] = []
        at = summary_start

        def group(opcode: int, records: list[bytes]) -> None:
            nonlocal at
            if not records:
                return
            data = b"".join(records)
            groups.append((opcode, at, len(data)))
            parts.append(data)
            at += len(data)

        totals = np.asarray(self._counts, dtype=np.int64)
        totals[:self._bulk_counts.shape[0]] += self._bulk_counts
        counts = {ch: int(c) for ch, c in enumerate(totals.tolist()) if c}
        counts_map = b"".join(struct.pack("<HQ", ch, c) for ch, c in counts.items())
        statistics = _record(OP_STATISTICS, struct.pack(
            "<QHIIIIQQ", self.message_count, len(self._schemas), len(self._channels),
            len(self._attachment_indexes), len(self._metadata_indexes), self.chunk_count,
            self._start_time or 0, self._end_time) + struct.pack("<I", len(counts_map))
            + counts_map)
        group(OP_SCHEMA, list(self._schemas.values()))
        group(OP_CHANNEL, list(self._channels.values()))
        group(OP_STATISTICS, [statistics])
        group(OP_CHUNK_INDEX, self._chunk_indexes)
        group(OP_ATTACHMENT_INDEX, self._attachment_indexes)
        group(OP_METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = at
        parts.append(b"".join(_record(OP_SUMMARY_OFFSET, struct.pack("<BQQ", op, s, n))
                              for op, s, n in groups))
        summary = b"".join(parts)
        footer_head = struct.pack("<BQQQ", OP_FOOTER, 20, summary_start, summary_offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(summary))
        self._write(summary)
        self._write(footer_head + struct.pack("<I", crc))
        self._write(MAGIC)
