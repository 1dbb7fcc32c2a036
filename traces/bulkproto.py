"""Encode many protobuf messages of one type at once with numpy.

:class:`BulkEncoder` turns column arrays into the serialised messages of a protobuf
message type whose every field has a fixed width, as rows of one ``(n, L)`` uint8
array (all messages of a batch have the same length ``L``), ready for
:meth:`netsim.traces.bulkmcap.BulkMcapWriter.add_messages`.

Supported fields (wire format: https://protobuf.dev/programming-guides/encoding/):

- ``double``, ``fixed64``, ``sfixed64`` (wire type 1, 8 bytes), ``float``,
  ``fixed32``, ``sfixed32`` (wire type 5, 4 bytes), ``bool`` (a one-byte varint);
- varint fields (``uint32``, ``uint64``, ``int32``, ``int64``, ``sint32``,
  ``sint64``, enums) at a fixed width: the varint is padded with continuation bytes
  to 5 bytes (``uint32``, ``sint32``) or 10 (the others; negative ``int32`` values
  take 10 bytes on the wire anyway). Parsers accept such non-minimal varints (the
  value decodes the same); the bytes differ from ``SerializeToString``;
- repeated fields of the types above with a fixed element count per message, given
  in ``lengths``, written packed (wire type 2).

Every field is always written, zeros included. A proto3 field without explicit
presence that holds its default value is omitted by ``SerializeToString``, so for
such values the bytes differ from it while parsing gives the same message (a parser
accepts an explicit default). With explicit presence (proto2 ``optional`` or proto3
``optional``), every field set, and no varint fields, the rows equal
``SerializeToString()`` byte for byte (fields in field-number order, as protobuf
writes them).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from google.protobuf.descriptor import Descriptor, FieldDescriptor
from netsim.traces.schemas import varint as _varint

__all__ = ["BulkEncoder", "UnsupportedField"]

_FD = FieldDescriptor
#: type -> (wire type, numpy dtype of the value)
_FIXED = {
    _FD.TYPE_DOUBLE: (1, "<f8"), _FD.TYPE_FIXED64: (1, "<u8"), _FD.TYPE_SFIXED64: (1, "<i8"),
    _FD.TYPE_FLOAT: (5, "<f4"), _FD.TYPE_FIXED32: (5, "<u4"), _FD.TYPE_SFIXED32: (5, "<i4"),
    _FD.TYPE_BOOL: (0, "u1"),
}
#: varint type -> padded width in bytes
_VARINT = {
    _FD.TYPE_UINT32: 5, _FD.TYPE_SINT32: 5, _FD.TYPE_UINT64: 10, _FD.TYPE_INT64: 10,
    _FD.TYPE_INT32: 10, _FD.TYPE_SINT64: 10, _FD.TYPE_ENUM: 10,
}


class UnsupportedField(ValueError):
    """A field that has no fixed-width encoding (string, bytes, message, map ...)."""


def _padded_varints(values: np.ndarray, width: int, zigzag: bool, bits: int) -> np.ndarray:
    """Varints of ``values`` (any shape) padded to ``width`` bytes: shape (..., width)."""
    v = np.asarray(values)
    if zigzag:
        s = v.astype(np.int64)
        u = ((s << 1) ^ (s >> (bits - 1))).astype(np.uint64)
        if bits == 32:
            u &= np.uint64(0xFFFFFFFF)
    else:
        u = v.astype(np.int64).view(np.uint64) if v.dtype.kind == "i" or v.dtype.kind == "b" \
            else v.astype(np.uint64)
    shifts = (np.arange(width, dtype=np.uint64) * np.uint64(7))
    out = ((u[..., None] >> shifts) & np.uint64(0x7F)).astype(np.uint8)
    out[..., :-1] |= 0x80
    return out


@dataclass(frozen=True)
class _Field:
    name: str
    number: int
    kind: str  # fixed | varint
    dtype: str  # value dtype (fixed) or "u1" (varint bytes)
    width: int  # bytes per element
    count: int | None  # None: singular; else repeated element count
    zigzag: bool = False
    bits: int = 64


class BulkEncoder:
    """Encoder of one message type with fixed-width fields into equal-length rows.

    Parameters
    ----------
    descriptor : google.protobuf.descriptor.Descriptor
        The message type.
    lengths : mapping str -> int, optional
        Element count of each repeated field (required for every repeated field); a
        count of 0 leaves the field out.

    Attributes
    ----------
    payload_length : int
        Length L of every encoded message in bytes.
    dtype : numpy.dtype
        The packed structured dtype of one encoded message (itemsize L).
    """

    def __init__(self, descriptor: Descriptor, lengths: Mapping[str, int] | None = None
                 ) -> None:
        lengths = dict(lengths or {})
        self.descriptor = descriptor
        fields: list[_Field] = []
        for fd in sorted(descriptor.fields, key=lambda f: f.number):
            # protobuf before 6 (pyproject allows >= 4.25) has FieldDescriptor.label and
            # no is_repeated; types-protobuf 7 describes only the newer API
            repeated = (fd.is_repeated if hasattr(fd, "is_repeated")
                        else fd.label == _FD.LABEL_REPEATED)  # type: ignore[attr-defined]
            count: int | None = None
            if repeated:
                if fd.name not in lengths:
                    raise ValueError(f"{descriptor.full_name}.{fd.name}: repeated field "
                                     "needs its element count in lengths")
                count = int(lengths.pop(fd.name))
                if count < 0:
                    raise ValueError(f"{fd.name}: negative length {count}")
            if fd.type in _FIXED:
                wire, dtype = _FIXED[fd.type]
                field = _Field(fd.name, fd.number, "fixed", dtype, np.dtype(dtype).itemsize,
                               count)
            elif fd.type in _VARINT:
                zig = fd.type in (_FD.TYPE_SINT32, _FD.TYPE_SINT64)
                bits = 32 if fd.type in (_FD.TYPE_SINT32, _FD.TYPE_UINT32) else 64
                field = _Field(fd.name, fd.number, "varint", "u1", _VARINT[fd.type], count,
                               zig, bits)
                wire = 0
            else:
                raise UnsupportedField(
                    f"{descriptor.full_name}.{fd.name}: type {fd.type} has no fixed-width "
                    "encoding (supported: double, float, (s)fixed32/64, bool, varint "
                    "integers and enums, and repeated ones of fixed length)")
            if fd.message_type is not None:
                raise UnsupportedField(f"{descriptor.full_name}.{fd.name}: message field")
            if count == 0:
                continue
            fields.append(field)
            del wire
        if lengths:
            raise ValueError(f"lengths names unknown repeated fields: {', '.join(lengths)}")
        self.fields = fields
        spec: list[tuple[Any, ...]] = []
        self._constants: dict[str, np.ndarray] = {}
        for f in fields:
            if f.count is None:
                wire = 0 if f.kind == "varint" or f.dtype == "u1" else (
                    1 if f.width == 8 else 5)
                tag = _varint((f.number << 3) | wire)
                spec.append((f"t{f.number}", "u1", (len(tag),)))
                self._constants[f"t{f.number}"] = np.frombuffer(tag, dtype=np.uint8)
                if f.kind == "varint":
                    spec.append((f"v{f.number}", "u1", (f.width,)))
                else:
                    spec.append((f"v{f.number}", f.dtype))
            else:
                tag = _varint((f.number << 3) | 2) + _varint(f.count * f.width)
                spec.append((f"t{f.number}", "u1", (len(tag),)))
                self._constants[f"t{f.number}"] = np.frombuffer(tag, dtype=np.uint8)
                if f.kind == "varint":
                    spec.append((f"v{f.number}", "u1", (f.count, f.width)))
                else:
                    spec.append((f"v{f.number}", f.dtype, (f.count,)))
        self.dtype = np.dtype(spec)
        self.payload_length = int(self.dtype.itemsize)
        self._record_dtype: np.dtype | None = None

    def encode(self, columns: Mapping[str, Any], n: int | None = None) -> np.ndarray:
        """Return the serialised messages as rows.

        Parameters
        ----------
        columns : mapping str -> array_like
            Per field: shape (n,) for a singular field, (n, count) for a repeated one;
            a scalar (or a (count,) row) is the same for every message. A missing
            field is written as zero.
        n : int, optional
            Number of messages (default: from the first array column).

        Returns
        -------
        numpy.ndarray, shape (n, payload_length), uint8
        """
        self._check(columns)
        if n is None:
            by_name = {f.name: f for f in self.fields}
            n = next((np.shape(v)[0] for k, v in columns.items()
                      if np.ndim(v) == (1 if by_name[k].count is None else 2)), None)
            if n is None:
                raise ValueError("n is needed when every column is a scalar")
        out = np.zeros(n, dtype=self.dtype)
        self._fill(out, columns)
        return out.view(np.uint8).reshape(n, self.payload_length)

    def records(self, columns: Mapping[str, Any], channel_id: Any, sequence: Any,
                log_time: Any, publish_time: Any, n: int | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """Return the messages as consecutive MCAP Message records, built in one pass.

        The same bytes as :func:`netsim.traces.bulkmcap.message_records` applied to
        :meth:`encode`'s rows, without the intermediate rows.

        Parameters
        ----------
        columns : mapping str -> array_like
            As for :meth:`encode`.
        channel_id, sequence, log_time, publish_time : array_like, shape (n,) or scalar

        Returns
        -------
        records : numpy.ndarray, shape (n * (31 + payload_length),), uint8
        starts : numpy.ndarray, shape (n,), int64
        """
        from netsim.traces.bulkmcap import MESSAGE_HEADER_DTYPE, OP_MESSAGE

        self._check(columns)
        if n is None:
            n = int(np.shape(log_time)[0])
        dtype = self._record_dtype
        if dtype is None:
            dtype = self._record_dtype = np.dtype(MESSAGE_HEADER_DTYPE.descr + self.dtype.descr)
        out = np.zeros(n, dtype=dtype)
        out["opcode"] = OP_MESSAGE
        out["length"] = 22 + self.payload_length
        out["channel_id"] = channel_id
        out["sequence"] = sequence
        out["log_time"] = log_time
        out["publish_time"] = publish_time
        self._fill(out, columns)
        return out.view(np.uint8).reshape(-1), np.arange(n, dtype=np.int64) * dtype.itemsize

    def _check(self, columns: Mapping[str, Any]) -> None:
        unknown = set(columns) - {f.name for f in self.fields}
        if unknown:
            raise ValueError(f"{self.descriptor.full_name}: no fields {sorted(unknown)}")

    def _fill(self, out: np.ndarray, columns: Mapping[str, Any]) -> None:
        for key, tag in self._constants.items():
            out[key] = tag
        for f in self.fields:
            if f.name not in columns:
                if f.kind == "varint":
                    out[f"v{f.number}"] = _padded_varints(np.zeros(1, np.uint64), f.width,
                                                          False, f.bits)[0]
                continue
            value = np.asarray(columns[f.name])
            if f.kind == "varint":
                out[f"v{f.number}"] = _padded_varints(value, f.width, f.zigzag, f.bits)
            elif f.dtype == "u1":
                out[f"v{f.number}"] = value.astype(bool)
            else:
                out[f"v{f.number}"] = value
