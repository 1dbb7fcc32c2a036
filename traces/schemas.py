"""Protobuf message types and topic names of a netsim trace (formats 1 and 2).

Format 2 (``netsim-trace/2``, written today) is declared in the checked-in
``traces/netsim_trace_v2.proto`` (package ``netsim.trace.v2``, proto2 syntax) and here,
field by field with **pinned field numbers** (:data:`MESSAGES`); a test holds the two
equal. The descriptors are built at run time as a ``FileDescriptorProto`` and turned
into Python classes with ``message_factory.GetMessageClass`` (no ``protoc``). Each type
is written into the MCAP file as a schema with encoding ``protobuf`` whose data is the
serialized ``FileDescriptorSet`` (what ``mcap-protobuf-support`` does), so any
MCAP/Foxglove reader decodes the messages without this package.

Encoding rules (for bulk encoding: every message of a topic has the same length):

- every scalar field is fixed width (``fixed64``, ``sfixed64``, ``fixed32``,
  ``sfixed32``, ``double``) and proto2 ``optional``: writers set every field, so
  protobuf serialises it even when it is zero;
- every repeated field is ``repeated double [packed = true]`` of a length fixed per
  topic (integers in them are exact);
- fields are serialised in increasing number, i.e. a message is the concatenation of
  ``tag, value`` for fields 1, 2, ... (:func:`field_layout` gives tags and widths).

Topics of format 2 (ROS 2 valid names: no token starts with a digit):

==============================  ===================  ==================================
topic                           type                 one message per
==============================  ===================  ==================================
``/plant/state``                ``PlantState``       step: x_k
``/sensor_<i>/measurement``     ``Measurement``      step and sensor: y^i_k
``/agent_<i>/estimate``         ``Estimate``         update: estimate, error, norms
``/agent_<i>/update``           ``EstimatorUpdate``  update: r_ij[k], s_j per neighbour
``/agent_<i>/freshness``        ``Freshness``        update of an AoI agent
``/agent_<i>/clock``            ``AgentClock``       sample of an agent on its own clock
``/link_<j>_<i>/sent``          ``LinkSent``         message j -> i sent
``/link_<j>_<i>/delivered``     ``LinkDelivered``    message j -> i delivered
``/link_<j>_<i>/dropped``       ``LinkDropped``      message j -> i lost
==============================  ===================  ==================================

``LinkDropped.reason`` is a code; the metadata record ``drop_reasons`` maps codes
(decimal strings, from 1) to the reason text (:mod:`netsim.links`); a writer that meets
a new reason writes the record again with the table so far (readers take the union).

Times: MCAP ``log_time`` = ``time_origin_ns`` + simulation time in integer ns; the origin
is in the ``run`` metadata (:data:`DEFAULT_TIME_ORIGIN_NS`: 2000-01-01T00:00:00Z,
fixed so files are bit-reproducible; :func:`parse_time_origin`).

Format 1 (``netsim-trace/1``, package ``netsim.trace``: one ``MessageEvent`` type on
``/link/<j>/<i>`` with a string ``event``, varint fields numbered by list order, topics
``/agent/<i>/...``, log_time from 0) is still read; :data:`FORMAT1_MESSAGE_TYPES` keeps
its definition.

Only the standard library and ``google.protobuf`` are used.
"""

from __future__ import annotations

import datetime as _dt
import re
from functools import cache
from pathlib import Path
from typing import Any, NamedTuple

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

__all__ = [
    "TraceRecord",
    "varint",
    "FORMAT",
    "TRACE_FORMAT",
    "PACKAGE",
    "PACKAGE_PREFIX",
    "FORMAT1_PACKAGE",
    "PROTO_FILE",
    "PROTO_PATH",
    "MESSAGES",
    "MESSAGE_TYPES",
    "FORMAT1_MESSAGE_TYPES",
    "TOPIC_TYPES",
    "LINK_EVENTS",
    "DROP_REASONS_METADATA",
    "DEFAULT_TIME_ORIGIN_NS",
    "Field",
    "FieldLayout",
    "TopicInfo",
    "field_layout",
    "pinned_file_descriptor",
    "classes_of",
    "descriptor_set_of",
    "file_descriptor_proto",
    "file_descriptor_set",
    "message_class",
    "message_classes",
    "schema_name",
    "parse_time_origin",
    "format_time_origin",
    "plant_topic",
    "sensor_topic",
    "estimate_topic",
    "update_topic",
    "freshness_topic",
    "clock_topic",
    "link_topic",
    "parse_topic",
    "format1_file_descriptor_proto",
    "format1_message_classes",
]

#: Trace format written today.
FORMAT = 2
#: Value of ``run.trace_format`` and first word of the MCAP header's library string.
TRACE_FORMAT = f"netsim-trace/{FORMAT}"
#: Protobuf package of format 2.
PACKAGE = "netsim.trace.v2"
#: Protobuf package of format 1.
FORMAT1_PACKAGE = "netsim.trace"
#: Every netsim schema name starts with this and a dot (formats 1 and 2).
PACKAGE_PREFIX = "netsim.trace"
#: Name of the .proto file in the descriptor set (as checked in, under netsim/traces/).
PROTO_FILE = "netsim/traces/netsim_trace_v2.proto"
#: The checked-in .proto source of format 2.
PROTO_PATH = Path(__file__).with_name("netsim_trace_v2.proto")
#: Metadata record mapping LinkDropped.reason codes to reason text.
DROP_REASONS_METADATA = "drop_reasons"
#: Default time origin: 2000-01-01T00:00:00Z in ns since the Unix epoch.
DEFAULT_TIME_ORIGIN_NS = 946_684_800 * 10**9

_F = descriptor_pb2.FieldDescriptorProto
_ONE, _MANY = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED


class TraceRecord(NamedTuple):
    """One decoded message of a trace (``log_time``, ``publish_time``: as in the file, ns;
    subtract :attr:`netsim.traces.reader.Trace.time_origin_ns` for simulation time).

    Defined here, below :mod:`netsim.traces.reader` and :mod:`netsim.traces.stepread`,
    which both build it; the reader re-exports it."""

    topic: str
    log_time: int
    publish_time: int
    sequence: int
    message: Any


class Field(NamedTuple):
    """One field of a format-2 message: name, pinned number, protobuf type, label."""

    name: str
    number: int
    type: int
    label: int = _ONE


def _f(name: str, number: int, type_: int) -> Field:
    return Field(name, number, type_, _ONE)


def _r(name: str, number: int) -> Field:
    return Field(name, number, _F.TYPE_DOUBLE, _MANY)


_FIXED64, _SFIXED64 = _F.TYPE_FIXED64, _F.TYPE_SFIXED64
_FIXED32, _SFIXED32, _DOUBLE = _F.TYPE_FIXED32, _F.TYPE_SFIXED32, _F.TYPE_DOUBLE

_LINK_COMMON = (
    _f("sender", 1, _FIXED32),
    _f("receiver", 2, _FIXED32),
    _f("sent_step", 3, _FIXED64),
    _f("usable_step", 4, _FIXED64),
    _f("sequence", 5, _FIXED32),
    _f("send_time", 6, _DOUBLE),
    _f("arrival_time", 7, _DOUBLE),
    _f("delay_steps", 8, _FIXED32),
)

#: Format-2 messages: short name -> fields with their pinned numbers (the wire
#: contract; equal to ``netsim_trace_v2.proto``). Never renumber; add new numbers.
MESSAGES: dict[str, tuple[Field, ...]] = {
    "PlantState": (
        _f("step", 1, _FIXED64),
        _f("time", 2, _DOUBLE),
        _r("state", 3),
    ),
    "Measurement": (
        _f("step", 1, _FIXED64),
        _f("time", 2, _DOUBLE),
        _f("sensor", 3, _FIXED32),
        _r("values", 4),
    ),
    "Estimate": (
        _f("step", 1, _FIXED64),
        _f("time", 2, _DOUBLE),
        _f("agent", 3, _FIXED32),
        _r("estimate", 4),
        _r("error", 5),
        _f("squared_error", 6, _DOUBLE),
        _f("error_norm", 7, _DOUBLE),
    ),
    "EstimatorUpdate": (
        _f("step", 1, _FIXED64),
        _f("time", 2, _DOUBLE),
        _f("agent", 3, _FIXED32),
        _r("neighbours", 4),
        _r("effective_delay", 5),
        _r("used_timestamp", 6),
    ),
    "Freshness": (
        _f("step", 1, _FIXED64),
        _f("time", 2, _DOUBLE),
        _f("agent", 3, _FIXED32),
        _r("index", 4),
        _r("adopted_from", 5),
        _r("substate_dim", 6),
        _f("max_index", 7, _SFIXED32),
    ),
    "LinkSent": _LINK_COMMON + (_r("payload", 9),),
    "LinkDelivered": _LINK_COMMON + (_f("accepted", 9, _FIXED32),),
    "LinkDropped": _LINK_COMMON + (_f("reason", 9, _FIXED32), _f("drop_time", 10, _DOUBLE)),
    # a sample of an agent on its own clock ([time] scenarios, netsim.timedkernel)
    "AgentClock": (
        _f("step", 1, _FIXED64),
        _f("time", 2, _DOUBLE),
        _f("agent", 3, _FIXED32),
        _f("sample", 4, _FIXED64),
        _f("local_time", 5, _DOUBLE),
        _f("sent", 6, _FIXED32),
    ),
}

#: Format-2 message names (as :data:`MESSAGES`), kept for callers of format 1's name.
MESSAGE_TYPES = MESSAGES

#: Link event kinds and their format-2 topic suffix and type.
LINK_EVENTS: dict[str, str] = {
    "sent": "LinkSent", "delivered": "LinkDelivered", "dropped": "LinkDropped",
}

#: Format-2 topic patterns -> message type.
TOPIC_TYPES: dict[str, str] = {
    "/plant/state": "PlantState",
    "/sensor_<i>/measurement": "Measurement",
    "/agent_<i>/estimate": "Estimate",
    "/agent_<i>/update": "EstimatorUpdate",
    "/agent_<i>/freshness": "Freshness",
    "/agent_<i>/clock": "AgentClock",
    "/link_<j>_<i>/sent": "LinkSent",
    "/link_<j>_<i>/delivered": "LinkDelivered",
    "/link_<j>_<i>/dropped": "LinkDropped",
}

_D = _F
#: Format 1 (read only): fields (name, type, label) numbered 1, 2, ... in list order.
FORMAT1_MESSAGE_TYPES: dict[str, tuple[tuple[str, int, int], ...]] = {
    "PlantStep": (("step", _D.TYPE_UINT64, _ONE), ("time", _DOUBLE, _ONE),
                  ("state", _DOUBLE, _MANY)),
    "Measurement": (("step", _D.TYPE_UINT64, _ONE), ("time", _DOUBLE, _ONE),
                    ("sensor", _D.TYPE_UINT32, _ONE), ("values", _DOUBLE, _MANY)),
    "MessageEvent": (
        ("event", _D.TYPE_STRING, _ONE), ("sender", _D.TYPE_UINT32, _ONE),
        ("receiver", _D.TYPE_UINT32, _ONE), ("sent_step", _D.TYPE_UINT64, _ONE),
        ("usable_step", _D.TYPE_UINT64, _ONE), ("sequence", _D.TYPE_UINT32, _ONE),
        ("send_time", _DOUBLE, _ONE), ("arrival_time", _DOUBLE, _ONE),
        ("delay_steps", _D.TYPE_UINT32, _ONE), ("accepted", _D.TYPE_BOOL, _ONE),
        ("reason", _D.TYPE_STRING, _ONE), ("event_time", _DOUBLE, _ONE),
        ("payload", _DOUBLE, _MANY)),
    "Estimate": (("step", _D.TYPE_UINT64, _ONE), ("time", _DOUBLE, _ONE),
                 ("agent", _D.TYPE_UINT32, _ONE), ("estimate", _DOUBLE, _MANY),
                 ("error", _DOUBLE, _MANY), ("squared_error", _DOUBLE, _ONE),
                 ("error_norm", _DOUBLE, _ONE)),
    "EstimatorUpdate": (("step", _D.TYPE_UINT64, _ONE), ("time", _DOUBLE, _ONE),
                        ("agent", _D.TYPE_UINT32, _ONE), ("neighbours", _D.TYPE_UINT32, _MANY),
                        ("effective_delay", _D.TYPE_INT32, _MANY),
                        ("used_timestamp", _D.TYPE_INT64, _MANY)),
    "Freshness": (("step", _D.TYPE_UINT64, _ONE), ("time", _DOUBLE, _ONE),
                  ("agent", _D.TYPE_UINT32, _ONE), ("index", _D.TYPE_INT32, _MANY),
                  ("adopted_from", _D.TYPE_INT32, _MANY),
                  ("substate_dim", _D.TYPE_UINT32, _MANY), ("max_index", _D.TYPE_INT32, _ONE)),
}


# -- descriptors ---------------------------------------------------------------------


def schema_name(type_name: str) -> str:
    """Return the fully qualified format-2 name, e.g. ``netsim.trace.v2.Estimate``."""
    return f"{PACKAGE}.{type_name}"


def pinned_file_descriptor(proto_file: str, package: str,
                           messages: dict[str, tuple[Field, ...]]
                           ) -> descriptor_pb2.FileDescriptorProto:
    """A proto2 ``FileDescriptorProto`` of ``messages`` (name -> fields with their pinned
    numbers; repeated fields packed): formats 2 and 3 are built by it."""
    fd = descriptor_pb2.FileDescriptorProto(name=proto_file, package=package, syntax="proto2")
    for name, fields in messages.items():
        message = fd.message_type.add(name=name)
        for field in fields:
            added = message.field.add(name=field.name, number=field.number, type=field.type,
                                      label=field.label)
            if field.label == _MANY:
                added.options.packed = True
    return fd


def classes_of(fd: descriptor_pb2.FileDescriptorProto) -> dict[str, Any]:
    """The message classes of one file descriptor by short name, from a private
    descriptor pool (no clash with other protobuf definitions in the process)."""
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    return {m.name: message_factory.GetMessageClass(
        pool.FindMessageTypeByName(f"{fd.package}.{m.name}")) for m in fd.message_type}


@cache
def file_descriptor_proto() -> descriptor_pb2.FileDescriptorProto:
    """Return the format-2 ``FileDescriptorProto`` (proto2, pinned field numbers)."""
    return pinned_file_descriptor(PROTO_FILE, PACKAGE, MESSAGES)


def descriptor_set_of(fd: descriptor_pb2.FileDescriptorProto
                      ) -> descriptor_pb2.FileDescriptorSet:
    """Return ``fd`` as the ``FileDescriptorSet`` written as MCAP schema data (one file,
    no dependencies)."""
    fds = descriptor_pb2.FileDescriptorSet()
    fds.file.append(fd)
    return fds


def file_descriptor_set() -> descriptor_pb2.FileDescriptorSet:
    """Return the format-2 ``FileDescriptorSet`` written as MCAP schema data."""
    return descriptor_set_of(file_descriptor_proto())


@cache
def message_classes() -> dict[str, Any]:
    """Return the format-2 message classes by short name (``"Estimate"`` ...).

    The classes live in a private descriptor pool, so they never clash with other
    protobuf definitions loaded in the same process.
    """
    return classes_of(file_descriptor_proto())


def message_class(type_name: str) -> Any:
    """Return the format-2 message class of one type, by short or qualified name."""
    short = type_name.removeprefix(PACKAGE + ".")
    try:
        return message_classes()[short]
    except KeyError:
        raise KeyError(
            f"unknown netsim trace type {type_name!r}; known: {', '.join(MESSAGES)}"
        ) from None


class FieldLayout(NamedTuple):
    """Wire layout of one field of a format-2 message (for bulk encoders).

    ``tag`` is the encoded key (field number << 3 | wire type) as bytes; ``width`` the
    value's width in bytes (scalar) or of one element (repeated, packed: after the tag
    comes the varint byte length, then the elements); ``dtype`` the little-endian numpy
    type string of the value (``<u8``, ``<i8``, ``<u4``, ``<i4``, ``<f8``).
    """

    name: str
    number: int
    tag: bytes
    width: int
    dtype: str
    repeated: bool


_WIRE: dict[int, tuple[int, int, str]] = {  # protobuf type -> (wire type, width, dtype)
    _FIXED64: (1, 8, "<u8"), _SFIXED64: (1, 8, "<i8"), _DOUBLE: (1, 8, "<f8"),
    _FIXED32: (5, 4, "<u4"), _SFIXED32: (5, 4, "<i4"),
}


def varint(value: int) -> bytes:
    """The protobuf base-128 varint encoding of a non-negative integer (a field's tag)."""
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def field_layout(type_name: str) -> tuple[FieldLayout, ...]:
    """Return the wire layout of a format-2 message's fields, in serialisation order.

    A message with every field set serialises as, per field in this order: ``tag`` then
    the value (``width`` bytes, little endian) for a scalar; ``tag``, the varint of
    ``width * length`` and the elements for a repeated field (nothing when empty).
    """
    out = []
    for field in sorted(MESSAGES[type_name], key=lambda f: f.number):
        if field.label == _MANY:
            wire, width, dtype = 2, 8, "<f8"
        else:
            wire, width, dtype = _WIRE[field.type]
        out.append(FieldLayout(field.name, field.number, varint(field.number << 3 | wire),
                               width, dtype, field.label == _MANY))
    return tuple(out)


# -- time origin ---------------------------------------------------------------------


def parse_time_origin(text: str | int | float) -> int:
    """Return a time origin as integer ns since the Unix epoch.

    Accepts an ISO 8601 date or date-time (``2000-01-01``, ``2026-05-01T12:00:00Z``,
    ``...+02:00``; without a zone, UTC), a number of seconds since the epoch
    (``1700000000``, ``1.5e9``), or ``0`` (log_time = simulation time, as format 1).
    Raises ValueError (naming the value) for anything else or a time before 1970.
    """
    ns: int | None
    if isinstance(text, int | float):
        ns = int(round(float(text) * 1e9))
    else:
        value = str(text).strip()
        try:
            ns = int(round(float(value) * 1e9)) if re.fullmatch(
                r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", value) else None
        except (OverflowError, ValueError):
            ns = None
        if ns is None:
            try:
                when = _dt.datetime.fromisoformat(value.replace("Z", "+00:00"))
            except ValueError:
                raise ValueError(
                    f"time origin {value!r} is neither an ISO 8601 date-time (e.g. "
                    "2000-01-01T00:00:00Z) nor seconds since 1970-01-01"
                ) from None
            if when.tzinfo is None:
                when = when.replace(tzinfo=_dt.UTC)
            delta = when - _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC)
            ns = (delta.days * 86_400 + delta.seconds) * 10**9 + delta.microseconds * 1000
    if ns < 0 or ns >= 2**63:
        raise ValueError(f"time origin {text!r} is outside 1970-01-01 .. 2262-04-11")
    return ns


def format_time_origin(ns: int) -> str:
    """Return a time origin (ns since the epoch) as ISO 8601 UTC, e.g. ``2000-01-01T00:00:00Z``."""
    seconds, rest = divmod(int(ns), 10**9)
    when = _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC) + _dt.timedelta(seconds=seconds)
    text = when.strftime("%Y-%m-%dT%H:%M:%S")
    return text + (f".{rest:09d}".rstrip("0") if rest else "") + "Z"


# -- topics --------------------------------------------------------------------------


def plant_topic(fmt: int = FORMAT) -> str:
    """Topic of the true state (both formats: ``/plant/state``)."""
    return "/plant/state"


def sensor_topic(i: int, fmt: int = FORMAT) -> str:
    """Topic of sensor i: ``/sensor_<i>/measurement`` (format 1: ``/sensor/<i>/...``)."""
    return f"/sensor/{int(i)}/measurement" if fmt == 1 else f"/sensor_{int(i)}/measurement"


def _agent(agent: int, leaf: str, fmt: int) -> str:
    return f"/agent/{int(agent)}/{leaf}" if fmt == 1 else f"/agent_{int(agent)}/{leaf}"


def estimate_topic(agent: int, fmt: int = FORMAT) -> str:
    """Topic of agent i's estimates: ``/agent_<i>/estimate``."""
    return _agent(agent, "estimate", fmt)


def update_topic(agent: int, fmt: int = FORMAT) -> str:
    """Topic of agent i's updates (effective delays): ``/agent_<i>/update``."""
    return _agent(agent, "update", fmt)


def freshness_topic(agent: int, fmt: int = FORMAT) -> str:
    """Topic of AoI agent i's freshness indices: ``/agent_<i>/freshness``."""
    return _agent(agent, "freshness", fmt)


def clock_topic(agent: int, fmt: int = FORMAT) -> str:
    """Topic of agent i's samples on its own clock: ``/agent_<i>/clock`` (format 2;
    scenarios with a ``[time]`` table)."""
    return _agent(agent, "clock", fmt)


def link_topic(sender: int, receiver: int, event: str | None = None,
               fmt: int = FORMAT) -> str:
    """Topic of link sender -> receiver: ``/link_<j>_<i>/<event>`` (event one of
    :data:`LINK_EVENTS`); format 1 has one topic ``/link/<j>/<i>`` for all events."""
    if fmt == 1:
        return f"/link/{int(sender)}/{int(receiver)}"
    if event not in LINK_EVENTS:
        raise ValueError(f"link event {event!r}: expected one of {', '.join(LINK_EVENTS)}")
    return f"/link_{int(sender)}_{int(receiver)}/{event}"


class TopicInfo(NamedTuple):
    """What a netsim topic carries: ``kind`` (plant, sensor, estimate, update,
    freshness, link), the agent/sensor ``index`` (sender for a link), the link
    ``receiver``, the link ``event`` (None in format 1: all events) and the format."""

    kind: str
    # the field shadows tuple.index (mypy: incompatible with the base class); the name
    # is part of the public topic API, so it stays
    index: int | None  # type: ignore[assignment]
    receiver: int | None
    event: str | None
    format: int


_PATTERNS = (
    (re.compile(r"^/plant/state$"), "plant", 2),
    (re.compile(r"^/sensor_(\d+)/measurement$"), "sensor", 2),
    (re.compile(r"^/agent_(\d+)/(estimate|update|freshness|clock)$"), None, 2),
    (re.compile(r"^/link_(\d+)_(\d+)/(sent|delivered|dropped)$"), "link", 2),
    (re.compile(r"^/sensor/(\d+)/measurement$"), "sensor", 1),
    (re.compile(r"^/agent/(\d+)/(estimate|update|freshness)$"), None, 1),
    (re.compile(r"^/link/(\d+)/(\d+)$"), "link", 1),
)


def parse_topic(topic: str) -> TopicInfo | None:
    """Return what a netsim topic (format 1 or 2) carries, None for another topic."""
    for pattern, kind, fmt in _PATTERNS:
        m = pattern.match(topic)
        if m is None:
            continue
        groups = m.groups()
        if kind == "plant":
            return TopicInfo("plant", None, None, None, fmt)
        if kind == "sensor":
            return TopicInfo("sensor", int(groups[0]), None, None, fmt)
        if kind == "link":
            event = groups[2] if fmt == 2 else None
            return TopicInfo("link", int(groups[0]), int(groups[1]), event, fmt)
        return TopicInfo(groups[1], int(groups[0]), None, None, fmt)
    return None


@cache
def format1_file_descriptor_proto() -> descriptor_pb2.FileDescriptorProto:
    """Return format 1's ``FileDescriptorProto`` (proto3, ``netsim.trace``; read only)."""
    fd = descriptor_pb2.FileDescriptorProto(name="netsim/trace.proto", package=FORMAT1_PACKAGE,
                                            syntax="proto3")
    for name, fields in FORMAT1_MESSAGE_TYPES.items():
        message = fd.message_type.add(name=name)
        for number, (field, ftype, label) in enumerate(fields, start=1):
            message.field.add(name=field, number=number, type=ftype, label=label)
    return fd


@cache
def format1_message_classes() -> dict[str, Any]:
    """Return format 1's message classes by short name (to write format-1 test files)."""
    pool = descriptor_pool.DescriptorPool()
    pool.Add(format1_file_descriptor_proto())
    return {name: message_factory.GetMessageClass(
        pool.FindMessageTypeByName(f"{FORMAT1_PACKAGE}.{name}"))
        for name in FORMAT1_MESSAGE_TYPES}
