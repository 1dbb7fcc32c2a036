"""Encode format-3 messages (one per step, packed arrays) in bulk with numpy.

A format-3 message (:mod:`netsim.traces.schemas3`) is ``step`` (fixed64), ``time``
(double) and packed repeated fields of fixed-width elements. :func:`encode_steps` turns
the rows of many steps into the serialised messages at once: when every row has the
same element counts, as one structured array (equal-length rows); otherwise (the
deliveries and drops of a step vary in number) by one gather over all rows. The bytes
equal protobuf's ``SerializeToString`` of the same message (fields in number order,
an empty repeated field left out); a test holds the two equal.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache, lru_cache
from typing import Any, NamedTuple

import numpy as np
from netsim.traces.schemas import varint
from netsim.traces.schemas3 import MESSAGES

__all__ = ["Column", "encode_steps", "encode_records", "field_dtypes"]

_WIDTH_DTYPE = {"double": "<f8", "fixed32": "<u4", "sfixed32": "<i4"}


class Column(NamedTuple):
    """The values of one repeated field for a run of rows.

    ``values`` holds every row's elements back to back (1-D, in the field's dtype, or a
    2-D array of equal-count rows); ``counts`` (shape (rows,)) the elements per row, or
    None when ``values`` is 2-D (every row ``values.shape[1]``)."""

    values: np.ndarray
    counts: np.ndarray | None = None


@cache
def field_dtypes(type_name: str) -> tuple[tuple[str, int, str], ...]:
    """The repeated fields of a format-3 message: (name, number, kind), in number order
    (the scalars ``step`` and ``time`` are fields 1 and 2); kind is a numpy dtype
    (``<f8``) for a fixed-width field, else ``uint32``, ``sint32`` or ``bool``."""
    from google.protobuf.descriptor_pb2 import FieldDescriptorProto as F

    kinds: dict[int, str] = {F.TYPE_DOUBLE: "<f8", F.TYPE_FIXED32: "<u4", F.TYPE_SFIXED32: "<i4",
             F.TYPE_UINT32: "uint32", F.TYPE_SINT32: "sint32", F.TYPE_BOOL: "bool"}
    return tuple((f.name, f.number, kinds[f.type])
                 for f in sorted(MESSAGES[type_name], key=lambda f: f.number)
                 if f.number > 2)


_STEP_TAG = np.frombuffer(varint(1 << 3 | 1), np.uint8)
_TIME_TAG = np.frombuffer(varint(2 << 3 | 1), np.uint8)
_HEAD = np.dtype([("t1", "u1"), ("step", "<u8"), ("t2", "u1"), ("time", "<f8")])


def _varint_bytes(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimal varints of non-negative int64 ``values``: (bytes (n, 5), lengths (n,))."""
    if values.size and int(values.max()) < 128:  # one byte each (e.g. a step's lengths)
        out = np.zeros((values.shape[0], 5), dtype=np.uint8)
        out[:, 0] = values
        return out, np.ones(values.shape, dtype=np.int64)
    v = values.astype(np.uint64)
    length = np.ones(v.shape, dtype=np.int64)
    for bits in (7, 14, 21, 28):
        length += v >= (np.uint64(1) << np.uint64(bits))
    shifts = np.arange(5, dtype=np.uint64) * np.uint64(7)
    out = ((v[:, None] >> shifts) & np.uint64(0x7F)).astype(np.uint8)
    out[np.arange(5)[None, :] < (length[:, None] - 1)] |= 0x80
    return out, length


def _varint_column(kind: str, values: np.ndarray, counts: np.ndarray | None,
                   rows: int) -> tuple[np.ndarray, np.ndarray | None]:
    """A varint field's packed bytes: (bytes, byte counts per row or None when every
    element takes one byte and ``counts`` is None: then shape (rows, count))."""
    v = np.asarray(values)
    if kind == "bool" or v.dtype == np.bool_:
        return v.astype(bool, copy=False).view(np.uint8), counts
    if not v.size:
        return v.astype(np.uint8), counts
    low, high = int(v.min()), int(v.max())
    if kind == "sint32":
        if low < -2**31 or high >= 2**31:
            raise ValueError(f"sint32 value out of range: {low} .. {high}")
        if -64 <= low and high <= 63:  # one byte each: the zigzag value, in int8
            # (temporaries a quarter the size of int32 ones: fewer fresh pages)
            b = v.astype(np.int8)
            z = b << 1
            z ^= b >> 7
            return z.view(np.uint8), counts
        s = v.astype(np.int64)
        u = ((s << 1) ^ (s >> 63)).astype(np.uint64)
    else:
        if low < 0 or high >= 2**32:
            raise ValueError(f"uint32 value out of range: {low} .. {high}")
        if high < 128:
            return v.astype(np.uint8), counts
        u = v.astype(np.uint64)
    flat = u.reshape(-1)
    if counts is None:
        counts = np.full(rows, u.shape[1] if u.ndim == 2 else 0, dtype=np.int64)
    data, length = _varint_bytes(flat)
    stream = data[np.arange(5)[None, :] < length[:, None]]
    ends = np.cumsum(length)
    bounds = np.concatenate([[0], np.cumsum(counts)])
    before = np.concatenate([[0], ends])[bounds]
    return stream, np.diff(before)


def encode_steps(type_name: str, step: np.ndarray, time: np.ndarray,
                 columns: Mapping[str, Column]) -> tuple[np.ndarray, np.ndarray]:
    """Serialise one format-3 message per row.

    Parameters
    ----------
    type_name : str
        A message of :data:`netsim.traces.schemas3.MESSAGES`.
    step : numpy.ndarray, shape (rows,)
        The step k of each message.
    time : numpy.ndarray, shape (rows,)
        k Ts of each message.
    columns : mapping str -> Column
        The repeated fields; a field not given is left out (empty).

    Returns
    -------
    payloads : numpy.ndarray, shape (total,), uint8
        The messages back to back.
    offsets : numpy.ndarray, shape (rows + 1,), int64
        Message r is ``payloads[offsets[r]:offsets[r + 1]]``.
    """
    rows = int(np.shape(step)[0])
    parts, uniform = _prepare(type_name, rows, columns)
    if uniform:
        out, size = _uniform_rows(rows, step, time, parts)
        return out.view(np.uint8).reshape(-1), np.arange(rows + 1, dtype=np.int64) * size
    return _encode_ragged(rows, step, time, parts)


def encode_records(type_name: str, step: np.ndarray, time: np.ndarray,
                   columns: Mapping[str, Column], channel_id: int, log_time: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Serialise one format-3 message per row as consecutive MCAP Message records
    (sequence = step, publish_time = log_time): the bytes of
    :func:`netsim.traces.bulkmcap.message_records` applied to :func:`encode_steps`'s
    messages, built in one pass when every row has the same length.

    Returns
    -------
    records : numpy.ndarray, shape (total,), uint8
    starts : numpy.ndarray, shape (rows,), int64
    """
    from netsim.traces.bulkmcap import OP_MESSAGE, message_records

    rows = int(np.shape(step)[0])
    parts, uniform = _prepare(type_name, rows, columns)
    if not uniform and len(parts) == 1:
        return _one_ragged_field_records(rows, step, time, parts[0], channel_id, log_time)
    if not uniform:
        payloads, offsets = _encode_ragged(rows, step, time, parts)
        return message_records(channel_id, np.asarray(step).astype(np.uint32), log_time,
                               log_time, payloads, offsets)
    out, size = _uniform_rows(rows, step, time, parts, record=True)
    out["opcode"] = OP_MESSAGE
    out["length"] = size - 9
    out["channel_id"] = channel_id
    out["sequence"] = step
    out["log_time"] = log_time
    out["publish_time"] = log_time
    return out.view(np.uint8).reshape(-1), np.arange(rows, dtype=np.int64) * size


def _prepare(type_name: str, rows: int, columns: Mapping[str, Column]
             ) -> tuple[list[tuple[Any, ...]], bool]:
    """Each given field as (number, dtype, values, counts or None, count or None), and
    whether every row has the same length."""
    fields = field_dtypes(type_name)
    unknown = set(columns) - {name for name, _, _ in fields}
    if unknown:
        raise ValueError(f"{type_name}: no repeated fields {sorted(unknown)}")
    parts: list[tuple[Any, ...]] = []  # (number, dtype, values, counts or None, count or None)
    uniform = True
    for name, number, kind in fields:
        column = columns.get(name)
        if column is None:
            continue
        values = np.asarray(column.values)
        counts = column.counts
        if counts is None:
            if values.ndim != 2 or values.shape[0] != rows:
                raise ValueError(f"{type_name}.{name}: expected shape ({rows}, count), got "
                                 f"{values.shape}")
        else:
            counts = np.asarray(counts, dtype=np.int64)
            if counts.shape != (rows,) or int(counts.sum()) != values.reshape(-1).shape[0]:
                raise ValueError(f"{type_name}.{name}: {values.size} values for counts "
                                 f"summing to {int(counts.sum())} over {rows} rows")
        dtype = kind
        if not kind.startswith("<"):  # varint: packed bytes
            values, counts = _varint_column(kind, values, counts, rows)
            dtype = "u1"
        if counts is None:
            if values.shape[1]:
                parts.append((number, dtype, values, None, values.shape[1]))
            continue
        if rows and np.all(counts == counts[0]):
            if counts[0]:
                parts.append((number, dtype, values.reshape(rows, int(counts[0])), None,
                              int(counts[0])))
            continue
        uniform = False
        parts.append((number, dtype, values.reshape(-1), counts, None))
    return parts, uniform


@lru_cache(maxsize=256)
def _row_dtype(fields: tuple[tuple[int, str, int], ...], record: bool
               ) -> tuple[np.dtype, dict[str, np.ndarray]]:
    """The structured dtype of equal-length rows (an MCAP Message record header first
    when ``record``) of fields (number, dtype, count), and each field's tag bytes."""
    from netsim.traces.bulkmcap import MESSAGE_HEADER_DTYPE

    spec = (list(MESSAGE_HEADER_DTYPE.descr) if record else []) + list(_HEAD.descr)
    tags = {}
    for number, dtype, count in fields:
        width = np.dtype(dtype).itemsize
        tag = varint(number << 3 | 2) + varint(count * width)
        tags[f"t{number}"] = np.frombuffer(tag, np.uint8)
        spec += [(f"t{number}", "u1", (len(tag),)), (f"v{number}", dtype, (count,))]
    return np.dtype(spec), tags


def _uniform_rows(rows: int, step: np.ndarray, time: np.ndarray,
                  parts: list[tuple[Any, ...]], record: bool = False
                  ) -> tuple[np.ndarray, int]:
    """Equal-length rows as a structured array (an MCAP record header first when
    ``record``) and its size."""
    dtype_row, tags = _row_dtype(tuple((number, dtype, count)
                                       for number, dtype, _, _, count in parts), record)
    out = np.empty(rows, dtype=dtype_row)
    out["t1"] = _STEP_TAG[0]
    out["step"] = step
    out["t2"] = _TIME_TAG[0]
    out["time"] = time
    for number, _, values, _, _ in parts:
        out[f"t{number}"] = tags[f"t{number}"]
        out[f"v{number}"] = values
    return out, dtype_row.itemsize


def _encode_ragged(rows: int, step: np.ndarray, time: np.ndarray,
                   parts: list[tuple[Any, ...]]) -> tuple[np.ndarray, np.ndarray]:
    """Rows of unequal lengths: head (18 bytes), then per field with elements its tag,
    varint byte length and data; every piece scattered once into the output."""
    head = np.empty(rows, dtype=_HEAD)
    head["t1"], head["step"] = _STEP_TAG[0], step
    head["t2"], head["time"] = _TIME_TAG[0], time
    n_fields = len(parts)
    data_len = np.empty((rows, n_fields), dtype=np.int64)
    prefix = np.zeros((rows, n_fields, 6), dtype=np.uint8)
    prefix_len = np.empty((rows, n_fields), dtype=np.int64)
    sources = []
    for f, (number, dtype, values, counts, count) in enumerate(parts):
        width = np.dtype(dtype).itemsize
        if counts is None:
            counts = np.full(rows, count, dtype=np.int64)
        data_len[:, f] = counts * width
        vbytes, vlen = _varint_bytes(data_len[:, f])
        prefix[:, f, 0] = varint(number << 3 | 2)[0]
        prefix[:, f, 1:] = vbytes
        prefix_len[:, f] = np.where(counts > 0, 1 + vlen, 0)
        sources.append(np.ascontiguousarray(values, dtype=dtype).reshape(-1).view(np.uint8))
    segment = prefix_len + data_len
    row_len = _HEAD.itemsize + segment.sum(axis=1)
    offsets = np.zeros(rows + 1, dtype=np.int64)
    np.cumsum(row_len, out=offsets[1:])
    out = np.empty(int(offsets[-1]), dtype=np.uint8)
    starts = offsets[:-1]
    out[(starts[:, None] + np.arange(_HEAD.itemsize)).reshape(-1)] = (
        head.view(np.uint8).reshape(-1))
    field_start = starts[:, None] + _HEAD.itemsize + np.cumsum(segment, axis=1) - segment
    used = np.arange(6)[None, None, :] < prefix_len[:, :, None]
    out[(field_start[:, :, None] + np.arange(6))[used]] = prefix[used]
    data_start = field_start + prefix_len
    for f, raw in enumerate(sources):
        lengths = data_len[:, f]
        if not raw.shape[0]:
            continue
        source_start = np.cumsum(lengths) - lengths
        out[np.repeat(data_start[:, f] - source_start, lengths)
            + np.arange(raw.shape[0], dtype=np.int64)] = raw
    return out, offsets


@cache
def _ragged_head_dtype() -> np.dtype:
    """The fixed part of a one-ragged-field record: MCAP Message header, step and time,
    the field's tag and byte length (at most 6 bytes, the used ones first)."""
    from netsim.traces.bulkmcap import MESSAGE_HEADER_DTYPE

    return np.dtype(MESSAGE_HEADER_DTYPE.descr + _HEAD.descr + [("prefix", "u1", (6,))])


def _one_ragged_field_records(rows: int, step: np.ndarray, time: np.ndarray,
                              part: tuple[Any, ...], channel_id: int, log_time: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray]:
    """MCAP records of messages with one repeated field of unequal lengths (e.g. a
    step's deliveries): each record is a fixed part (record header, step, time, the
    field's tag and length) and the field's data, which lies in the source in record
    order, so one mask puts every data byte in place."""
    from netsim.traces.bulkmcap import OP_MESSAGE

    number, dtype, values, counts, _ = part
    width = np.dtype(dtype).itemsize
    data_len = np.asarray(counts, dtype=np.int64) * width
    vbytes, vlen = _varint_bytes(data_len)
    fixed = _ragged_head_dtype()
    meta = np.empty(rows, dtype=fixed)
    meta["opcode"] = OP_MESSAGE
    prefix_len = np.where(data_len > 0, 1 + vlen, 0)
    meta_len = fixed.itemsize - 6 + prefix_len
    meta["length"] = meta_len - 9 + data_len
    meta["channel_id"] = channel_id
    meta["sequence"] = step
    meta["log_time"] = log_time
    meta["publish_time"] = log_time
    meta["t1"], meta["step"] = _STEP_TAG[0], step
    meta["t2"], meta["time"] = _TIME_TAG[0], time
    meta["prefix"][:, 0] = varint(number << 3 | 2)[0]
    meta["prefix"][:, 1:] = vbytes
    sizes = meta_len + data_len
    starts = np.cumsum(sizes) - sizes
    out = np.empty(int(sizes.sum()), dtype=np.uint8)
    # which bytes are the fixed parts: runs of meta_len True, data_len False, per record
    # (a bool per byte; no index arrays)
    runs = np.empty(2 * rows, dtype=np.int64)
    runs[0::2], runs[1::2] = meta_len, data_len
    is_meta = np.repeat(np.tile(np.array([True, False]), rows), runs)
    used = np.arange(fixed.itemsize)[None, :] < meta_len[:, None]
    out[is_meta] = meta.view(np.uint8).reshape(rows, fixed.itemsize)[used]
    np.logical_not(is_meta, out=is_meta)
    out[is_meta] = np.ascontiguousarray(values, dtype=dtype).reshape(-1).view(np.uint8)
    return out, starts
