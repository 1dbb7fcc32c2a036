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
from functools import cache
from typing import Any, NamedTuple

import numpy as np
from netsim.traces.schemas import varint
from netsim.traces.schemas3 import MESSAGES

__all__ = ["Column", "encode_steps", "field_dtypes"]

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
    """The repeated fields of a format-3 message: (name, number, numpy dtype), in
    number order (the scalars ``step`` and ``time`` are fields 1 and 2)."""
    from google.protobuf.descriptor_pb2 import FieldDescriptorProto as F

    names = {F.TYPE_DOUBLE: "<f8", F.TYPE_FIXED32: "<u4", F.TYPE_SFIXED32: "<i4"}
    out = []
    for f in sorted(MESSAGES[type_name], key=lambda f: f.number):
        if f.number <= 2:
            continue
        out.append((f.name, f.number, names[f.type]))
    return tuple(out)


_STEP_TAG = np.frombuffer(varint(1 << 3 | 1), np.uint8)
_TIME_TAG = np.frombuffer(varint(2 << 3 | 1), np.uint8)
_HEAD = np.dtype([("t1", "u1"), ("step", "<u8"), ("t2", "u1"), ("time", "<f8")])


def _varint_bytes(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimal varints of non-negative int64 ``values``: (bytes (n, 5), lengths (n,))."""
    v = values.astype(np.uint64)
    length = np.ones(v.shape, dtype=np.int64)
    for bits in (7, 14, 21, 28):
        length += v >= (np.uint64(1) << np.uint64(bits))
    shifts = np.arange(5, dtype=np.uint64) * np.uint64(7)
    out = ((v[:, None] >> shifts) & np.uint64(0x7F)).astype(np.uint8)
    out[np.arange(5)[None, :] < (length[:, None] - 1)] |= 0x80
    return out, length


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
    fields = field_dtypes(type_name)
    unknown = set(columns) - {name for name, _, _ in fields}
    if unknown:
        raise ValueError(f"{type_name}: no repeated fields {sorted(unknown)}")
    parts = []  # (number, dtype, values 1-D, counts (rows,))
    uniform = True
    for name, number, dtype in fields:
        column = columns.get(name)
        if column is None:
            continue
        values = np.asarray(column.values)
        if column.counts is None:
            if values.ndim != 2 or values.shape[0] != rows:
                raise ValueError(f"{type_name}.{name}: expected shape ({rows}, count), got "
                                 f"{values.shape}")
            count = values.shape[1]
            if count == 0:
                continue
            parts.append((number, dtype, values, None, count))
        else:
            counts = np.asarray(column.counts, dtype=np.int64)
            if counts.shape != (rows,) or int(counts.sum()) != values.reshape(-1).shape[0]:
                raise ValueError(f"{type_name}.{name}: {values.size} values for counts "
                                 f"summing to {int(counts.sum())} over {rows} rows")
            if rows and np.all(counts == counts[0]):
                if counts[0]:
                    parts.append((number, dtype, values.reshape(rows, int(counts[0])), None,
                                  int(counts[0])))
                continue
            uniform = False
            parts.append((number, dtype, values.reshape(-1), counts, None))
    if uniform:
        return _encode_uniform(rows, step, time, parts)
    return _encode_ragged(rows, step, time, parts)


def _encode_uniform(rows: int, step: np.ndarray, time: np.ndarray,
                    parts: list[tuple[Any, ...]]) -> tuple[np.ndarray, np.ndarray]:
    spec = list(_HEAD.descr)
    tags = {}
    for number, dtype, _, _, count in parts:
        width = np.dtype(dtype).itemsize
        tag = varint(number << 3 | 2) + varint(count * width)
        tags[f"t{number}"] = np.frombuffer(tag, np.uint8)
        spec += [(f"t{number}", "u1", (len(tag),)), (f"v{number}", dtype, (count,))]
    dtype_row = np.dtype(spec)
    out = np.empty(rows, dtype=dtype_row)
    out["t1"] = _STEP_TAG[0]
    out["step"] = step
    out["t2"] = _TIME_TAG[0]
    out["time"] = time
    for number, _, values, _, _ in parts:
        out[f"t{number}"] = tags[f"t{number}"]
        out[f"v{number}"] = values
    size = dtype_row.itemsize
    return out.view(np.uint8).reshape(-1), np.arange(rows + 1, dtype=np.int64) * size


def _encode_ragged(rows: int, step: np.ndarray, time: np.ndarray,
                   parts: list[tuple[Any, ...]]) -> tuple[np.ndarray, np.ndarray]:
    # every row: head (18 bytes), then per field (count > 0) tag, varint length, data
    head = np.empty(rows, dtype=_HEAD)
    head["t1"], head["step"] = _STEP_TAG[0], step
    head["t2"], head["time"] = _TIME_TAG[0], time
    # segments per row, in order: head, then (prefix_f, data_f) per field
    seg_len = [np.full(rows, _HEAD.itemsize, dtype=np.int64)]
    sources: list[np.ndarray] = [head.view(np.uint8).reshape(-1)]
    seg_src = [np.arange(rows, dtype=np.int64) * _HEAD.itemsize]
    base = sources[0].shape[0]
    for number, dtype, values, counts, count in parts:
        width = np.dtype(dtype).itemsize
        if counts is None:
            counts = np.full(rows, count, dtype=np.int64)
            values = values.reshape(-1)
        data_len = counts * width
        vbytes, vlen = _varint_bytes(data_len)
        present = counts > 0
        tag = varint(number << 3 | 2)[0]
        prefix = np.zeros((rows, 6), dtype=np.uint8)
        prefix[:, 0] = tag
        prefix[:, 1:] = vbytes
        prefix_len = np.where(present, 1 + vlen, 0)
        sources.append(prefix.reshape(-1))
        seg_len.append(prefix_len)
        seg_src.append(base + np.arange(rows, dtype=np.int64) * 6)
        base += rows * 6
        raw = np.ascontiguousarray(values, dtype=dtype).view(np.uint8).reshape(-1)
        starts = np.concatenate([[0], np.cumsum(data_len)[:-1]]) if rows else data_len
        sources.append(raw)
        seg_len.append(data_len)
        seg_src.append(base + starts)
        base += raw.shape[0]
    lengths = np.stack(seg_len, axis=1)  # (rows, segments)
    src = np.stack(seg_src, axis=1)
    flat_len = lengths.reshape(-1)
    flat_src = src.reshape(-1)
    total = int(flat_len.sum())
    dst_start = np.cumsum(flat_len) - flat_len
    index = np.repeat(flat_src - dst_start, flat_len) + np.arange(total, dtype=np.int64)
    buffer = np.concatenate(sources)
    payloads = buffer[index]
    row_len = lengths.sum(axis=1)
    offsets = np.zeros(rows + 1, dtype=np.int64)
    np.cumsum(row_len, out=offsets[1:])
    return payloads, offsets
