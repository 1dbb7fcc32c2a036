"""The numpy bulk protobuf encoder against protobuf's own serialiser and parser."""

from __future__ import annotations

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from netsim.traces.bulkproto import BulkEncoder, UnsupportedField

_F = descriptor_pb2.FieldDescriptorProto
FIXED = [("d", _F.TYPE_DOUBLE), ("f", _F.TYPE_FLOAT), ("u64", _F.TYPE_FIXED64),
         ("s64", _F.TYPE_SFIXED64), ("u32", _F.TYPE_FIXED32), ("s32", _F.TYPE_SFIXED32),
         ("b", _F.TYPE_BOOL)]
VARINT = [("vu32", _F.TYPE_UINT32), ("vu64", _F.TYPE_UINT64), ("vi32", _F.TYPE_INT32),
          ("vi64", _F.TYPE_INT64), ("vs32", _F.TYPE_SINT32), ("vs64", _F.TYPE_SINT64)]
REPEATED = [("rd", _F.TYPE_DOUBLE, 3), ("rf", _F.TYPE_FLOAT, 2), ("ri", _F.TYPE_SFIXED32, 4)]


def _message_class(syntax: str, fields, repeated, name: str):
    fd = descriptor_pb2.FileDescriptorProto(name=f"bulk_{name}.proto", package="bulktest",
                                            syntax=syntax)
    message = fd.message_type.add(name=name)
    number = 1
    # field numbers out of declaration order and past 15 (two-byte tags) on purpose
    for fname, ftype in fields:
        message.field.add(name=fname, number=number * 3 if number % 2 else 16 + number,
                          type=ftype, label=_F.LABEL_OPTIONAL)
        number += 1
    for fname, ftype, _ in repeated:
        added = message.field.add(name=fname, number=100 + number, type=ftype,
                                  label=_F.LABEL_REPEATED)
        if syntax == "proto2":
            added.options.packed = True
        number += 1
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(f"bulktest.{name}"))


def _columns(rng, n, fields, repeated, zeros=0.0):
    cols = {}
    for fname, ftype in fields:
        if ftype in (_F.TYPE_DOUBLE, _F.TYPE_FLOAT):
            v = rng.normal(size=n) * 10.0 ** rng.integers(-5, 5, n)
            if ftype == _F.TYPE_FLOAT:
                v = v.astype(np.float32)
        elif ftype == _F.TYPE_BOOL:
            v = rng.integers(0, 2, n).astype(bool)
        elif ftype in (_F.TYPE_FIXED64, _F.TYPE_UINT64):
            v = rng.integers(0, 2**63, n, dtype=np.uint64) * np.uint64(2) + np.uint64(1)
        elif ftype in (_F.TYPE_SFIXED64, _F.TYPE_INT64, _F.TYPE_SINT64):
            v = rng.integers(-2**63, 2**63 - 1, n, dtype=np.int64)
        elif ftype in (_F.TYPE_FIXED32, _F.TYPE_UINT32):
            v = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
        else:
            v = rng.integers(-2**31, 2**31, n, dtype=np.int64).astype(np.int32)
        v = np.where(rng.random(n) < zeros, np.zeros_like(v), v)
        cols[fname] = v
    for fname, ftype, count in repeated:
        if ftype == _F.TYPE_SFIXED32:
            cols[fname] = rng.integers(-2**31, 2**31, (n, count), dtype=np.int64).astype(
                np.int32)
        else:
            v = rng.normal(size=(n, count))
            cols[fname] = v.astype(np.float32) if ftype == _F.TYPE_FLOAT else v
    return cols


def _protobuf(cls, cols, i):
    kwargs = {}
    for name, v in cols.items():
        item = v[i]
        kwargs[name] = item.tolist() if np.ndim(item) else item.item()
    return cls(**kwargs)


def test_explicit_presence_rows_equal_serialize_to_string():
    """proto2 optional fields, all set: the rows are SerializeToString byte for byte."""
    rng = np.random.default_rng(1)
    cls = _message_class("proto2", FIXED, REPEATED, "Explicit")
    encoder = BulkEncoder(cls.DESCRIPTOR, {name: c for name, _, c in REPEATED})
    n = 200
    cols = _columns(rng, n, FIXED, REPEATED, zeros=0.3)
    rows = encoder.encode(cols)
    assert rows.shape == (n, encoder.payload_length) and rows.dtype == np.uint8
    for i in range(n):
        assert rows[i].tobytes() == _protobuf(cls, cols, i).SerializeToString()


def test_implicit_presence_decodes_equal_including_zeros_and_varints():
    """proto3 (zeros omitted by protobuf, written by the encoder) and padded varints:
    protobuf's parser reads every row as the message built from the same values."""
    rng = np.random.default_rng(2)
    cls = _message_class("proto3", FIXED + VARINT, REPEATED, "Implicit")
    encoder = BulkEncoder(cls.DESCRIPTOR, {name: c for name, _, c in REPEATED})
    n = 300
    cols = _columns(rng, n, FIXED + VARINT, REPEATED, zeros=0.4)
    rows = encoder.encode(cols)
    assert len(set(map(len, (r.tobytes() for r in rows)))) == 1
    differs = 0
    for i in range(n):
        expected = _protobuf(cls, cols, i)
        parsed = cls.FromString(rows[i].tobytes())
        assert parsed == expected, i
        differs += rows[i].tobytes() != expected.SerializeToString()
    assert differs == n  # the padded varints never equal the minimal encoding


def test_missing_columns_are_zero_and_unsupported_fields_are_named():
    cls = _message_class("proto3", FIXED, [], "Missing")
    rows = BulkEncoder(cls.DESCRIPTOR).encode({"d": np.array([1.5, 2.5])})
    assert [cls.FromString(r.tobytes()) for r in rows] == [cls(d=1.5), cls(d=2.5)]
    fd = descriptor_pb2.FileDescriptorProto(name="bad.proto", package="bad", syntax="proto3")
    fd.message_type.add(name="Bad").field.add(name="s", number=1, type=_F.TYPE_STRING,
                                              label=_F.LABEL_OPTIONAL)
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    with pytest.raises(UnsupportedField, match="Bad.s"):
        BulkEncoder(pool.FindMessageTypeByName("bad.Bad"))
    with pytest.raises(ValueError, match="element count"):
        BulkEncoder(_message_class("proto3", [], REPEATED, "NoLen").DESCRIPTOR)


def test_records_equal_message_records_of_the_rows():
    from netsim.traces.bulkmcap import message_records

    rng = np.random.default_rng(3)
    cls = _message_class("proto2", FIXED, REPEATED, "Records")
    encoder = BulkEncoder(cls.DESCRIPTOR, {name: c for name, _, c in REPEATED})
    n = 50
    cols = _columns(rng, n, FIXED, REPEATED)
    head = (rng.integers(0, 9, n), rng.integers(0, 2**32, n, dtype=np.uint64),
            rng.integers(0, 2**63, n, dtype=np.uint64), rng.integers(0, 2**63, n, dtype=np.uint64))
    records, starts = encoder.records(cols, *head)
    expected, expected_starts = message_records(*head, encoder.encode(cols))
    assert records.tobytes() == expected.tobytes()
    assert np.array_equal(starts, expected_starts)
