"""Trace format 3's bulk encoder against protobuf: the rows :func:`encode_steps` packs
are, byte for byte, what ``SerializeToString`` writes for the same message (uniform and
ragged rows, one-byte and longer varints, negative sint32, empty fields), and the
checked-in ``netsim_trace_v3.proto`` equals the runtime descriptors."""

from __future__ import annotations

import numpy as np
import pytest
from google.protobuf import descriptor_pb2
from netsim.traces import schemas3
from netsim.traces.stepcodec import Column, encode_steps, field_dtypes

_F = descriptor_pb2.FieldDescriptorProto


def _random_column(rng, kind: str, counts: np.ndarray, big: bool) -> np.ndarray:
    size = int(counts.sum())
    if kind == "<f8":
        return rng.normal(size=size) * 10.0 ** rng.integers(-5, 5, size)
    if kind == "bool":
        return rng.integers(0, 2, size).astype(bool)
    high = 2**31 - 1 if big else 60
    if kind == "sint32":
        return rng.integers(-high, high, size)
    return rng.integers(0, 2 * high, size)


def _message(cls, k, t, columns, counts, r):
    fields = {}
    for name, values in columns.items():
        a = int(counts[name][:r].sum())
        b = a + int(counts[name][r])
        fields[name] = [v.item() for v in values[a:b]]
    return cls(step=int(k), time=float(t), **fields)


@pytest.mark.parametrize("type_name", list(schemas3.MESSAGES))
@pytest.mark.parametrize("shape", ["uniform", "ragged", "ragged-big", "empty-rows"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rows_equal_protobuf_serialisation(type_name, shape, seed):
    rng = np.random.default_rng([seed, len(type_name), len(shape)])
    cls = schemas3.message_classes()[type_name]
    rows = int(rng.integers(1, 9))
    step = rng.integers(0, 2**40, rows)
    time = rng.normal(size=rows)
    columns, counts, given = {}, {}, {}
    for name, _, kind in field_dtypes(type_name):
        if rng.random() < 0.2:
            continue  # a field left out
        if shape == "uniform":
            c = np.full(rows, int(rng.integers(0, 5)))
        elif shape == "empty-rows":
            c = np.where(rng.random(rows) < 0.5, 0, int(rng.integers(1, 4)))
        else:
            c = rng.integers(0, 200 if shape == "ragged-big" else 6, rows)
        values = _random_column(rng, kind, c, big=shape == "ragged-big")
        columns[name], counts[name] = values, c
        given[name] = (Column(values.reshape(rows, int(c[0]))) if shape == "uniform"
                       and rng.random() < 0.5 else Column(values, c))
    payloads, offsets = encode_steps(type_name, step, time, given)
    assert offsets.shape == (rows + 1,) and offsets[-1] == payloads.shape[0]
    for r in range(rows):
        expected = _message(cls, step[r], time[r], columns, counts, r).SerializeToString()
        assert payloads[offsets[r]:offsets[r + 1]].tobytes() == expected, (type_name, r)


def test_bad_columns_are_refused():
    with pytest.raises(ValueError, match="no repeated fields"):
        encode_steps("PlantState", np.arange(2), np.zeros(2), {"nope": Column(np.zeros((2, 1)))})
    with pytest.raises(ValueError, match="counts"):
        encode_steps("PlantState", np.arange(2), np.zeros(2),
                     {"state": Column(np.zeros(3), np.array([1, 1]))})
    with pytest.raises(ValueError, match="out of range"):
        encode_steps("Updates", np.arange(1), np.zeros(1),
                     {"effective_delay": Column(np.array([[2**40]]))})


def test_checked_in_proto_equals_runtime_descriptors():
    from tests.test_trace_schema import _parse_proto

    syntax, package, parsed = _parse_proto(schemas3.PROTO_PATH.read_text())
    fd = schemas3.file_descriptor_proto()
    assert (syntax, package) == (fd.syntax, fd.package) == ("proto2", schemas3.PACKAGE)
    runtime = {m.name: [(f.name, f.number, f.type, f.label, f.options.packed)
                        for f in m.field] for m in fd.message_type}
    assert list(parsed) == list(runtime)
    for name in runtime:
        assert parsed[name] == runtime[name], name
    for name, fields in schemas3.MESSAGES.items():
        assert len({f.number for f in fields}) == len(fields), name
        assert [f.name for f in fields[:2]] == ["step", "time"], name


@pytest.mark.parametrize("big", [False, True])
def test_one_ragged_field_records_equal_message_records(big):
    """The one-field path (a step's deliveries) builds the same bytes."""
    rng = np.random.default_rng(int(big))
    rows = 9
    step = np.arange(rows) + 2**33
    time = rng.normal(size=rows)
    counts = rng.integers(0, 300 if big else 5, rows)
    counts[3] = 0
    columns = {"accepted": Column(rng.integers(0, 2, counts.sum()).astype(bool), counts)}
    log_time = rng.integers(0, 2**60, rows).astype(np.uint64)
    _assert_records_are_message_records("LinkDeliveries", step, time, columns, 7, log_time)


@pytest.mark.parametrize("ragged", [False, True])
def test_records_equal_message_records_of_the_encoded_rows(ragged):
    rng = np.random.default_rng(5)
    rows = 7
    step = np.arange(3, 3 + rows)
    time = step * 0.25
    counts = rng.integers(0, 5, rows) if ragged else np.full(rows, 3)
    columns = {"link": Column(rng.integers(0, 300, counts.sum()), counts),
               "sent_step": Column(rng.integers(0, 9, counts.sum()), counts),
               "reason": Column(rng.integers(1, 4, counts.sum()), counts),
               "drop_time": Column(rng.normal(size=counts.sum()), counts)}
    log_time = (10**9 + step * 250_000_000).astype(np.uint64)
    _assert_records_are_message_records("LinkDrops", step, time, columns, 4, log_time)


def _assert_records_are_message_records(type_name, step, time, columns, channel, log_time):
    """encode_records' bytes and starts are bulkmcap.message_records applied to
    encode_steps' messages (sequence = step, publish_time = log_time)."""
    from netsim.traces.bulkmcap import message_records
    from netsim.traces.stepcodec import encode_records

    records, starts = encode_records(type_name, step, time, columns, channel, log_time)
    payloads, offsets = encode_steps(type_name, step, time, columns)
    expected, expected_starts = message_records(channel, step.astype(np.uint32), log_time,
                                                log_time, payloads, offsets)
    assert records.tobytes() == expected.tobytes()
    np.testing.assert_array_equal(starts, expected_starts)
