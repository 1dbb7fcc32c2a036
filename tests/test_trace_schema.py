"""Trace format 2's wire contract: the checked-in .proto equals the runtime descriptors,
every message of a topic serialises to the same length, and the layout
:func:`netsim.traces.schemas.field_layout` gives is what protobuf writes."""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
from google.protobuf import descriptor_pb2
from hypothesis import given, settings
from hypothesis import strategies as st
from netsim.traces import schemas
from netsim.traces.schemas import (
    MESSAGES,
    PROTO_PATH,
    field_layout,
    file_descriptor_proto,
    message_class,
    parse_time_origin,
    parse_topic,
)

_F = descriptor_pb2.FieldDescriptorProto
_TYPES = {"double": _F.TYPE_DOUBLE, "fixed64": _F.TYPE_FIXED64, "sfixed64": _F.TYPE_SFIXED64,
          "fixed32": _F.TYPE_FIXED32, "sfixed32": _F.TYPE_SFIXED32}
#: Types the format-3 .proto uses besides (packed varints).
_VARINT_TYPES = {"uint32": _F.TYPE_UINT32, "sint32": _F.TYPE_SINT32, "bool": _F.TYPE_BOOL}
_LABELS = {"optional": _F.LABEL_OPTIONAL, "repeated": _F.LABEL_REPEATED}


def _parse_proto(text: str) -> tuple[str, str, dict[str, list[tuple]]]:
    """A small parser for the subset of proto2 the file uses: syntax, package, messages
    of ``label type name = number [packed = true];`` fields. Anything else fails."""
    text = re.sub(r"//[^\n]*", "", text)
    syntax = re.search(r'syntax\s*=\s*"(\w+)"\s*;', text).group(1)
    package = re.search(r"package\s+([\w.]+)\s*;", text).group(1)
    messages: dict[str, list[tuple]] = {}
    for name, body in re.findall(r"message\s+(\w+)\s*\{([^}]*)\}", text):
        fields = []
        for statement in filter(None, (s.strip() for s in body.split(";"))):
            m = re.fullmatch(r"(optional|repeated)\s+(\w+)\s+(\w+)\s*=\s*(\d+)"
                             r"(?:\s*\[\s*packed\s*=\s*(true|false)\s*\])?", statement)
            assert m, f"unparsed field in {name}: {statement!r}"
            label, ftype, fname, number, packed = m.groups()
            fields.append((fname, int(number), {**_TYPES, **_VARINT_TYPES}[ftype], _LABELS[label],
                           packed == "true"))
        messages[name] = fields
    rest = re.sub(r"message\s+\w+\s*\{[^}]*\}", "", text)
    rest = re.sub(r'syntax\s*=\s*"\w+"\s*;|package\s+[\w.]+\s*;', "", rest)
    assert not rest.strip(), f"unparsed .proto text: {rest.strip()[:80]!r}"
    return syntax, package, messages


def test_checked_in_proto_equals_runtime_descriptors():
    syntax, package, parsed = _parse_proto(PROTO_PATH.read_text())
    fd = file_descriptor_proto()
    assert (syntax, package) == (fd.syntax, fd.package) == ("proto2", schemas.PACKAGE)
    runtime = {
        m.name: [(f.name, f.number, f.type, f.label, f.options.packed) for f in m.field]
        for m in fd.message_type
    }
    assert list(parsed) == list(runtime)  # same messages, same order
    for name in runtime:
        assert parsed[name] == runtime[name], name


def test_field_numbers_are_unique_and_every_field_fixed_width():
    for name, fields in MESSAGES.items():
        numbers = [f.number for f in fields]
        assert len(set(numbers)) == len(numbers), name
        assert len({f.name for f in fields}) == len(fields), name
        for f in fields:
            if f.label == _F.LABEL_REPEATED:
                assert f.type == _F.TYPE_DOUBLE, (name, f.name)
            else:
                assert f.type in _TYPES.values(), (name, f.name)


def _value(dtype: str, draw_int: int, draw_float: float):
    if dtype == "<f8":
        return draw_float
    bits = int(dtype[-1]) * 8
    if dtype[1] == "i":
        return (draw_int % (1 << bits)) - (1 << (bits - 1))
    return draw_int % (1 << bits)


def _encode(name: str, values: dict) -> bytes:
    """Encoding from field_layout alone (an independent bulk-style encoder)."""
    out = bytearray()
    for lay in field_layout(name):
        value = values[lay.name]
        if lay.repeated:
            if len(value) == 0:
                continue
            data = np.asarray(value, dtype="<f8").tobytes()
            out += lay.tag + schemas.varint(len(data)) + data
        else:
            out += lay.tag + np.asarray(value, dtype=lay.dtype).tobytes()
    return bytes(out)


@settings(max_examples=40, deadline=None)
@given(ints=st.lists(st.integers(0, 2**64 - 1), min_size=10, max_size=10),
       floats=st.lists(st.floats(allow_nan=False), min_size=10, max_size=10),
       length=st.integers(0, 5))
def test_protobuf_serialises_every_field_at_a_fixed_length(ints, floats, length):
    for name in MESSAGES:
        values = {}
        for index, lay in enumerate(field_layout(name)):
            if lay.repeated:
                values[lay.name] = [floats[(index + q) % 10] for q in range(length)]
            else:
                values[lay.name] = _value(lay.dtype, ints[index], floats[index])
        data = message_class(name)(**values).SerializeToString()
        assert data == _encode(name, values), name  # zeros are written too
        again = message_class(name).FromString(data)
        for key, value in values.items():
            got = getattr(again, key)
            assert (list(got) if isinstance(value, list) else got) == value


def test_nan_round_trips():
    data = message_class("Estimate")(step=0, time=0.0, agent=0, estimate=[np.nan],
                                     error=[np.nan], squared_error=np.nan,
                                     error_norm=np.nan).SerializeToString()
    assert struct.unpack_from("<d", data, len(data) - 8)[0] != 0.0
    assert np.isnan(message_class("Estimate").FromString(data).error_norm)


@pytest.mark.parametrize("topic, info", [
    ("/plant/state", ("plant", None, None, None, 2)),
    ("/agent_12/estimate", ("estimate", 12, None, None, 2)),
    ("/agent_0/freshness", ("freshness", 0, None, None, 2)),
    ("/sensor_3/measurement", ("sensor", 3, None, None, 2)),
    ("/link_0_11/dropped", ("link", 0, 11, "dropped", 2)),
    ("/link/2/1", ("link", 2, 1, None, 1)),
    ("/agent/4/update", ("update", 4, None, None, 1)),
    ("/tf", None),
])
def test_topic_names(topic, info):
    assert parse_topic(topic) == (None if info is None else schemas.TopicInfo(*info))


def test_format2_topics_are_valid_ros2_names():
    # ROS 2 rules: tokens of [A-Za-z0-9_], not starting with a digit, no "__", no
    # trailing "/" (design article "Topic and Service name mapping to DDS")
    topics = [schemas.plant_topic(), schemas.sensor_topic(10), schemas.estimate_topic(3),
              schemas.update_topic(31), schemas.freshness_topic(0)]
    topics += [schemas.link_topic(12, 3, e) for e in schemas.LINK_EVENTS]
    for topic in topics:
        assert topic.startswith("/") and not topic.endswith("/") and "__" not in topic
        for token in topic[1:].split("/"):
            assert re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", token), topic
        assert parse_topic(topic) is not None and parse_topic(topic).format == 2


def test_time_origin():
    assert parse_time_origin("2000-01-01T00:00:00Z") == schemas.DEFAULT_TIME_ORIGIN_NS
    assert parse_time_origin("2000-01-01") == schemas.DEFAULT_TIME_ORIGIN_NS
    assert parse_time_origin("946684800") == schemas.DEFAULT_TIME_ORIGIN_NS
    assert parse_time_origin("2000-01-01T02:00:00+02:00") == schemas.DEFAULT_TIME_ORIGIN_NS
    assert parse_time_origin("0") == 0
    assert schemas.format_time_origin(schemas.DEFAULT_TIME_ORIGIN_NS) == "2000-01-01T00:00:00Z"
    assert schemas.format_time_origin(1_500_000_000) == "1970-01-01T00:00:01.5Z"
    for bad in ("yesterday", "-5", "1969-12-31", "1e30"):
        with pytest.raises(ValueError, match="time origin"):
            parse_time_origin(bad)
