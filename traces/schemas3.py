"""Protobuf message types and topics of trace format 3 (one message per step and kind).

Format 3 (``netsim-trace/3``) holds what format 2 holds (:mod:`netsim.traces.schemas`)
in a few topics with **one message per step**: every agent's estimate of step k in one
packed array, every link's message sent at k in another. Format 2 writes one message
per agent and per link event (about 341 per step at N = 32, each with 47 bytes of MCAP
framing and index); format 3 writes at most 8 per step, so its files are several
times smaller and faster to write, and a network of any size needs 8 channels.

It is declared in the checked-in ``traces/netsim_trace_v3.proto`` (package
``netsim.trace.v3``, proto2) and here (:data:`MESSAGES`, pinned field numbers); a test
holds the two equal. Encoding rules (for bulk encoding with numpy): every scalar is a
fixed-width proto2 ``optional`` field that writers always set; every repeated field is
packed: ``double`` for values, varints (``uint32``, ``sint32``, ``bool``) for small
integers, which take one byte each below 128 (-64 .. 63 for ``sint32``).

Topics (log_time = time origin + k Ts for the message of step k; sequence = k):

==========================  ================  ============================================
topic                       type              one message per step k, holding
==========================  ================  ============================================
``/plant/state``            ``PlantState``    x_k
``/sensors/measurement``    ``Measurements``  y^i_k of every sensor, stacked in sensor order
``/agents/estimate``        ``Estimates``     every agent's x-hat^i_{k|k} (agent major)
                                              and ``error_norm`` ||x-hat^i_{k|k} - x_k||
``/agents/update``          ``Updates``       r_ij[k] per (in-neighbour j, agent i)
``/agents/freshness``       ``Freshness``     AoI freshness indices per (agent, substate)
``/links/sent``             ``LinkSends``     per link: the message sent at k (its delay
                                              d, arrival time; none: (k + 1 + d) Ts)
``/links/delivered``        ``LinkDeliveries`` whether the receiver kept each message
                                              delivered for use from step k on
``/links/dropped``          ``LinkDrops``     the messages lost at times in
                                              ((k-1) Ts, k Ts] (link, time-stamp, reason)
==========================  ================  ============================================

What the arrays are indexed by is the metadata record ``trace_layout``
(:data:`LAYOUT_METADATA`, JSON values): ``links`` (the link list, index l = position
of ``[j, i]``), ``updates`` (entry e of ``Updates.effective_delay`` is r_ij[k] of the
e-th ``[j, i]``), ``sensor_widths`` (m_i), ``agents`` (N),
``n_states`` (n), ``freshness_sizes`` (substates per AoI agent) and ``payload``
(``estimate``: a sent message's payload is the sender's estimate of that step, not
stored; ``message``: stored in ``LinkSends.payload``, ``payload_width`` values per
link; ``none``: not recorded).

Deliveries: the messages delivered for use from step k on are the ones sent at s with
delay d = k - 1 - s on a link, not dropped, that arrived by the end of the run (the last
plant step's time); ``LinkDeliveries.accepted`` lists, for each of them in increasing
(link l, s), whether the receiver kept it (False: older than one it holds). Which
messages they are and their delays and arrival times are in ``/links/sent``.

Drops per link: ``LinkDrops.link_reason[l]`` is, for every link l, the largest reason
code of the messages link l lost in the message's sample period, 0 for none (written for
networks of at most :data:`MAX_LINK_REASON_LINKS` links, else empty; traces of earlier
versions do not have it): one plottable series per link (``link``, ``sent_step`` and
``reason`` list the drops in the order they happened).

Sentinels: :data:`ABSENT` (-3) in an integer array marks an entry with nothing to say
(no message sent on that link at k, an agent that did not report that neighbour);
``Estimates.updated[i]`` is 0 when agent i did not update at k (its values are NaN).
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

from google.protobuf import descriptor_pb2
from netsim.traces.schemas import Field, classes_of, descriptor_set_of, pinned_file_descriptor

__all__ = [
    "FORMAT",
    "TRACE_FORMAT",
    "PACKAGE",
    "PROTO_FILE",
    "PROTO_PATH",
    "MESSAGES",
    "TOPICS",
    "LAYOUT_METADATA",
    "ABSENT",
    "MAX_LINK_REASON_LINKS",
    "file_descriptor_proto",
    "file_descriptor_set",
    "message_classes",
    "schema_name",
]

#: Format number of this layout.
FORMAT = 3
#: Value of ``run.trace_format`` and first word of the header's library string.
TRACE_FORMAT = f"netsim-trace/{FORMAT}"
#: Protobuf package of format 3.
PACKAGE = "netsim.trace.v3"
#: Name of the .proto file in the descriptor set.
PROTO_FILE = "netsim/traces/netsim_trace_v3.proto"
#: The checked-in .proto source.
PROTO_PATH = Path(__file__).with_name("netsim_trace_v3.proto")
#: Metadata record naming what the arrays are indexed by (JSON values).
LAYOUT_METADATA = "trace_layout"
#: Integer sentinel: nothing to say for this entry at this step.
ABSENT = -3
#: ``LinkDrops.link_reason`` is written for networks of at most this many links.
MAX_LINK_REASON_LINKS = 4096

_F = descriptor_pb2.FieldDescriptorProto
_ONE, _MANY = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED
_FIXED64, _FIXED32, _DOUBLE = _F.TYPE_FIXED64, _F.TYPE_FIXED32, _F.TYPE_DOUBLE
_UINT32, _SINT32, _BOOL = _F.TYPE_UINT32, _F.TYPE_SINT32, _F.TYPE_BOOL


def _f(name: str, number: int, type_: int) -> Field:
    return Field(name, number, type_, _ONE)


def _r(name: str, number: int, type_: int = _DOUBLE) -> Field:
    return Field(name, number, type_, _MANY)


_STEP = (_f("step", 1, _FIXED64), _f("time", 2, _DOUBLE))

#: Format-3 messages: name -> fields with pinned numbers (equal to the .proto file).
#: Small integers are packed varints (``uint32``, ``sint32``, ``bool``: one byte each
#: for values below 128, resp. -64 .. 63), values ``double``.
MESSAGES: dict[str, tuple[Field, ...]] = {
    "PlantState": _STEP + (_r("state", 3),),
    "Measurements": _STEP + (_r("values", 3),),
    "Estimates": _STEP + (
        _r("updated", 3, _BOOL),
        _r("estimate", 4),
        _r("error_norm", 5),
    ),
    "Updates": _STEP + (_r("effective_delay", 3, _SINT32),),
    "Freshness": _STEP + (
        _r("index", 3, _SINT32),
        _r("adopted_from", 4, _SINT32),
        _r("substate_dim", 5, _SINT32),
        _r("max_index", 6, _SINT32),
    ),
    "LinkSends": _STEP + (
        _r("delay_steps", 3, _SINT32),
        _r("arrival_time", 4),
        _r("payload", 5),
    ),
    "LinkDeliveries": _STEP + (_r("accepted", 3, _BOOL),),
    "LinkDrops": _STEP + (
        _r("link", 3, _UINT32),
        _r("sent_step", 4, _UINT32),
        _r("reason", 5, _UINT32),
        _r("drop_time", 6),
        _r("link_reason", 7, _UINT32),
    ),
}

#: Topic -> message type, in the order a step's messages are written.
TOPICS: dict[str, str] = {
    "/plant/state": "PlantState",
    "/sensors/measurement": "Measurements",
    "/agents/estimate": "Estimates",
    "/agents/update": "Updates",
    "/agents/freshness": "Freshness",
    "/links/sent": "LinkSends",
    "/links/dropped": "LinkDrops",
    "/links/delivered": "LinkDeliveries",
}


def schema_name(type_name: str) -> str:
    """Return the fully qualified format-3 name, e.g. ``netsim.trace.v3.Estimates``."""
    return f"{PACKAGE}.{type_name}"


@cache
def file_descriptor_proto() -> descriptor_pb2.FileDescriptorProto:
    """Return the format-3 ``FileDescriptorProto`` (proto2, pinned field numbers)."""
    return pinned_file_descriptor(PROTO_FILE, PACKAGE, MESSAGES)


def file_descriptor_set() -> descriptor_pb2.FileDescriptorSet:
    """Return the ``FileDescriptorSet`` written as each format-3 schema's data."""
    return descriptor_set_of(file_descriptor_proto())


@cache
def message_classes() -> dict[str, Any]:
    """Return the format-3 message classes by short name (private descriptor pool)."""
    return classes_of(file_descriptor_proto())
