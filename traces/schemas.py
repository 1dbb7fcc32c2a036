"""Protobuf message types of a netsim trace, built at run time.

The types are declared here as a ``FileDescriptorProto`` (file ``netsim/trace.proto``,
package ``netsim.trace``, proto3) and turned into Python classes with
``message_factory.GetMessageClass``: no ``protoc`` or generated code is needed.
Each type is written into the MCAP file as a schema with encoding ``protobuf`` whose
data is the serialized ``FileDescriptorSet`` (what ``mcap-protobuf-support`` does), so
any MCAP/Foxglove reader can decode the messages without this package.

The equivalent ``.proto`` text (see :data:`PROTO_TEXT`)::

    syntax = "proto3";
    package netsim.trace;

    message PlantStep {            // topic /plant/state
      uint64 step = 1;             // k
      double time = 2;             // k * Ts
      repeated double state = 3;   // x_k
    }
    message Measurement {          // topic /sensor/<i>/measurement
      uint64 step = 1;
      double time = 2;
      uint32 sensor = 3;           // i
      repeated double values = 4;  // y^i_k
    }
    message MessageEvent {         // topic /link/<j>/<i>  (j sends to i)
      string event = 1;            // "sent" | "delivered" | "dropped"
      uint32 sender = 2;           // j
      uint32 receiver = 3;         // i
      uint64 sent_step = 4;        // s, the time-stamp
      uint64 usable_step = 5;      // s + 1 + d: first update that may use it
      uint32 sequence = 6;         // per-link sequence number 0, 1, 2, ...
      double send_time = 7;        // s * Ts
      double arrival_time = 8;     // scheduled/actual delivery time
      uint32 delay_steps = 9;      // d
      bool accepted = 10;          // delivered: kept by the receiver (freshest rule)
      string reason = 11;          // dropped: why
      double event_time = 12;      // time of this event (send, arrival or drop)
      repeated double payload = 13;// sent: the transmitted estimate
    }
    message Estimate {             // topic /agent/<i>/estimate
      uint64 step = 1;
      double time = 2;
      uint32 agent = 3;
      repeated double estimate = 4;// x-hat^i_{k|k}
      repeated double error = 5;   // x-hat^i_{k|k} - x_k
      double squared_error = 6;    // ||error||^2
      double error_norm = 7;       // ||error||  (plot /agent/<i>/estimate.error_norm)
    }
    message EstimatorUpdate {      // topic /agent/<i>/update
      uint64 step = 1;
      double time = 2;
      uint32 agent = 3;
      repeated uint32 neighbours = 4;      // j, in increasing order
      repeated int32 effective_delay = 5;  // r_ij[k] = k - 1 - s_j; -1: own estimate substituted
      repeated int64 used_timestamp = 6;   // s_j used; -1 when substituted
    }
    message Freshness {            // topic /agent/<i>/freshness (AoI observer)
      uint64 step = 1;
      double time = 2;
      uint32 agent = 3;
      repeated int32 index = 4;        // freshness index per substate, -1 = omega
      repeated int32 adopted_from = 5; // neighbour adopted, -1 = own update / open loop
      repeated uint32 substate_dim = 6;
      int32 max_index = 7;             // over non-empty substates, -1 if any is omega
    }

Only the standard library and ``google.protobuf`` are used.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

__all__ = [
    "PACKAGE",
    "PROTO_FILE",
    "MESSAGE_TYPES",
    "PROTO_TEXT",
    "file_descriptor_proto",
    "file_descriptor_set",
    "message_class",
    "message_classes",
    "schema_name",
]

#: Protobuf package of every netsim trace type.
PACKAGE = "netsim.trace"
#: Name of the (virtual) .proto file in the descriptor set.
PROTO_FILE = "netsim/trace.proto"

_F = descriptor_pb2.FieldDescriptorProto
_DOUBLE, _UINT64, _UINT32 = _F.TYPE_DOUBLE, _F.TYPE_UINT64, _F.TYPE_UINT32
_INT32, _INT64, _BOOL, _STRING = _F.TYPE_INT32, _F.TYPE_INT64, _F.TYPE_BOOL, _F.TYPE_STRING
_ONE, _MANY = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED

#: Fields of each message type: (name, type, label), numbered 1, 2, ... in order.
MESSAGE_TYPES: dict[str, tuple[tuple[str, int, int], ...]] = {
    "PlantStep": (
        ("step", _UINT64, _ONE),
        ("time", _DOUBLE, _ONE),
        ("state", _DOUBLE, _MANY),
    ),
    "Measurement": (
        ("step", _UINT64, _ONE),
        ("time", _DOUBLE, _ONE),
        ("sensor", _UINT32, _ONE),
        ("values", _DOUBLE, _MANY),
    ),
    "MessageEvent": (
        ("event", _STRING, _ONE),
        ("sender", _UINT32, _ONE),
        ("receiver", _UINT32, _ONE),
        ("sent_step", _UINT64, _ONE),
        ("usable_step", _UINT64, _ONE),
        ("sequence", _UINT32, _ONE),
        ("send_time", _DOUBLE, _ONE),
        ("arrival_time", _DOUBLE, _ONE),
        ("delay_steps", _UINT32, _ONE),
        ("accepted", _BOOL, _ONE),
        ("reason", _STRING, _ONE),
        ("event_time", _DOUBLE, _ONE),
        ("payload", _DOUBLE, _MANY),
    ),
    "Estimate": (
        ("step", _UINT64, _ONE),
        ("time", _DOUBLE, _ONE),
        ("agent", _UINT32, _ONE),
        ("estimate", _DOUBLE, _MANY),
        ("error", _DOUBLE, _MANY),
        ("squared_error", _DOUBLE, _ONE),
        ("error_norm", _DOUBLE, _ONE),
    ),
    "EstimatorUpdate": (
        ("step", _UINT64, _ONE),
        ("time", _DOUBLE, _ONE),
        ("agent", _UINT32, _ONE),
        ("neighbours", _UINT32, _MANY),
        ("effective_delay", _INT32, _MANY),
        ("used_timestamp", _INT64, _MANY),
    ),
    "Freshness": (
        ("step", _UINT64, _ONE),
        ("time", _DOUBLE, _ONE),
        ("agent", _UINT32, _ONE),
        ("index", _INT32, _MANY),
        ("adopted_from", _INT32, _MANY),
        ("substate_dim", _UINT32, _MANY),
        ("max_index", _INT32, _ONE),
    ),
}

_TYPE_NAMES = {
    _DOUBLE: "double", _UINT64: "uint64", _UINT32: "uint32", _INT32: "int32",
    _INT64: "int64", _BOOL: "bool", _STRING: "string",
}


def _proto_text() -> str:
    lines = ['syntax = "proto3";', f"package {PACKAGE};", ""]
    for name, fields in MESSAGE_TYPES.items():
        lines.append(f"message {name} {{")
        for number, (field, ftype, label) in enumerate(fields, start=1):
            rep = "repeated " if label == _MANY else ""
            lines.append(f"  {rep}{_TYPE_NAMES[ftype]} {field} = {number};")
        lines.append("}")
    return "\n".join(lines) + "\n"


#: The schema as .proto source text (for documentation and debugging).
PROTO_TEXT = _proto_text()


def schema_name(type_name: str) -> str:
    """Return the fully qualified name, e.g. ``netsim.trace.Estimate``."""
    return f"{PACKAGE}.{type_name}"


@cache
def file_descriptor_proto() -> descriptor_pb2.FileDescriptorProto:
    """Return the ``FileDescriptorProto`` declaring every netsim trace type."""
    fd = descriptor_pb2.FileDescriptorProto(name=PROTO_FILE, package=PACKAGE, syntax="proto3")
    for name, fields in MESSAGE_TYPES.items():
        message = fd.message_type.add(name=name)
        for number, (field, ftype, label) in enumerate(fields, start=1):
            message.field.add(name=field, number=number, type=ftype, label=label)
    return fd


def file_descriptor_set() -> descriptor_pb2.FileDescriptorSet:
    """Return the ``FileDescriptorSet`` written as MCAP schema data (one file, no deps)."""
    fds = descriptor_pb2.FileDescriptorSet()
    fds.file.append(file_descriptor_proto())
    return fds


@cache
def message_classes() -> dict[str, Any]:
    """Return the generated message classes by short name (``"Estimate"`` ...).

    The classes live in a private descriptor pool, so they never clash with other
    protobuf definitions loaded in the same process.
    """
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file_descriptor_proto())
    return {
        name: message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name(name)))
        for name in MESSAGE_TYPES
    }


def message_class(type_name: str) -> Any:
    """Return the message class of one type, by short or fully qualified name."""
    short = type_name.removeprefix(PACKAGE + ".")
    try:
        return message_classes()[short]
    except KeyError:
        raise KeyError(
            f"unknown netsim trace type {type_name!r}; known: {', '.join(MESSAGE_TYPES)}"
        ) from None
