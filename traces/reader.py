"""Read a netsim MCAP trace back: metadata, matrices and decoded messages.

:func:`read_trace` reads a finished file through its summary (schemas, channels,
metadata and attachment indexes, chunk index; the summary CRC is checked) and then every
chunk of the chunk index one by one, checking its CRC, and decodes the protobuf messages
with ``mcap_protobuf.decoder.DecoderFactory`` from the schemas stored in the file.

Damage is recovered chunk by chunk: a chunk that fails its CRC, does not decompress,
or decompresses to more or fewer bytes than its declared ``uncompressed_size`` is
skipped and reported in ``Trace.lost_chunks`` (:class:`LostChunk`: where, which
steps, how many messages its message index lists, why), and every intact chunk around
it is read. A file whose writer never finished (no footer, summary or index: the
process was killed), or whose summary is unusable, is scanned record by record: the
scan skips a damaged chunk the same way, resynchronises on the next chunk after bytes
whose record structure is destroyed, and stops at the first record that extends past
the end of the file (``truncated=True``).

Decompression is bounded (:func:`inflate_chunk`, the one place chunks are inflated;
:func:`stream_records` is the bounded stand-in for the ``mcap`` library's stream reader):
a compressed chunk is inflated only up to its declared size, checked first against the
memory budget (:func:`netsim.budget.memory_limit`); a chunk declaring more than the
budget is refused (:class:`ChunkTooLarge`, naming the file, the chunk and the size), so
a decompression bomb costs neither memory nor time.

Anything else raises :class:`TraceError` with a one-line message naming the file:
not an MCAP file, an MCAP file not written by netsim (no ``scenario`` metadata or no
``netsim.trace`` schemas), a channel without its schema, an undecodable message, or
a damaged summary record.
"""

from __future__ import annotations

import io
import mmap
import os
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple, cast

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    Schema,
)
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap_protobuf.decoder import DecoderFactory
from netsim.traces.schemas import (
    DROP_REASONS_METADATA,
    LINK_EVENTS,
    TraceRecord,
    parse_topic,
)
from netsim.traces.schemas import PACKAGE_PREFIX as PACKAGE
from netsim.traces.schemas import clock_topic as _clock_topic
from netsim.traces.schemas import estimate_topic as _estimate_topic
from netsim.traces.schemas import freshness_topic as _freshness_topic
from netsim.traces.schemas import link_topic as _link_topic
from netsim.traces.schemas import sensor_topic as _sensor_topic
from netsim.traces.schemas import update_topic as _update_topic
from netsim.traces.schemas3 import PACKAGE as _PACKAGE3

__all__ = ["NOT_USED", "TraceError", "ChunkTooLarge", "TraceRecord", "LinkEvent",
           "LostChunk", "Trace", "read_trace", "read_status", "inflate_chunk",
           "chunk_budget", "stream_records", "Budget"]

#: Entry of :meth:`Trace.effective_delays` where agent i did not use j's estimate
#: (equal to ``netsim.kernel.NOT_USED``).
NOT_USED = -2

_MAGIC = bytes([137, 77, 67, 65, 80, 48, 13, 10])
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, crc
_FOOTER_OPCODE = 0x02
_OPCODES = frozenset(int(op) for op in Opcode)


class TraceError(ValueError):
    """A file that cannot be read as a netsim trace (the message names file and cause)."""


class ChunkTooLarge(TraceError):
    """A compressed chunk declares more uncompressed bytes than the memory budget.

    The file is refused, not read (a decompression bomb, or a chunk header too damaged
    to trust): the message names the file, the chunk's offset, the declared size and
    the budget.

    Attributes
    ----------
    declared, limit : int
        The chunk's declared uncompressed size and the budget (bytes).
    """

    def __init__(self, message: str, declared: int, limit: int) -> None:
        super().__init__(message)
        self.declared = declared
        self.limit = limit


class LinkEvent(NamedTuple):
    """One message event of a link, the same for formats 1 and 2.

    ``event`` is ``sent``, ``delivered`` or ``dropped``; ``accepted`` is meaningful for
    a delivery, ``reason`` (text) for a drop and ``payload`` for a sent message (empty
    when not recorded); ``event_time`` is the event's simulation time (send, arrival or
    drop) and ``log_time`` the record's log_time in the file (ns).
    """

    event: str
    sender: int
    receiver: int
    sent_step: int
    usable_step: int
    sequence: int
    send_time: float
    arrival_time: float
    delay_steps: int
    accepted: bool
    reason: str
    event_time: float
    payload: list[float]
    log_time: int


@dataclass
class LostChunk:
    """A damaged part of a trace that the reader skipped.

    Attributes
    ----------
    index : int or None
        The chunk's ordinal among the file's chunks (0 = first); None for bytes that
        were not a readable record (their structure destroyed) or another record.
    offset, length : int
        Where in the file (bytes).
    start_time, end_time : int or None
        log_time range (ns) of the chunk's messages, from its header or the index.
    messages : int or None
        Messages it held, from its message index (None if unknown).
    reason : str
        Why it was skipped (CRC mismatch, decompression failure, ...).
    """

    index: int | None
    offset: int
    length: int
    start_time: int | None
    end_time: int | None
    messages: int | None
    reason: str
    #: The trace's time origin (ns) subtracted from start_time/end_time for steps.
    origin: int = 0

    def steps(self, sample_period: float = 1.0) -> tuple[int, int] | None:
        """The plant steps its log_time range covers (None if unknown)."""
        if self.start_time is None or self.end_time is None:
            return None
        ts = sample_period * 1e9
        return (int(max(0, self.start_time - self.origin) // ts),
                int(max(0, self.end_time - self.origin) // ts))

    def to_dict(self, sample_period: float = 1.0) -> dict[str, Any]:
        steps = self.steps(sample_period)
        return {"chunk": self.index, "offset": self.offset, "length": self.length,
                "start_time_ns": self.start_time, "end_time_ns": self.end_time,
                "steps": None if steps is None else list(steps),
                "messages": self.messages, "reason": self.reason}


@dataclass
class Trace:
    """A trace read back from an MCAP file.

    Attributes
    ----------
    path : str
    metadata : dict of str -> dict of str -> str
        Every metadata record by name (``scenario``, ``run``, ``run_status``).
    matrices : dict of str -> numpy.ndarray
        The ``.npy`` attachments by name without extension (``A``, ``C_0``, ...).
    attachments : dict of str -> bytes
        Any other attachments.
    topics : dict of str -> str
        Topic -> schema name.
    counts : dict of str -> int
        Messages read per topic.
    records : dict of str -> list of TraceRecord
        Decoded messages per netsim topic, in log_time order.
    messages : list of TraceRecord
        All decoded messages in file order (= non-decreasing log_time).
    truncated : bool
        The file was never finished; only complete chunks were read.
    recovered_messages : int
        Messages read (all of them for a finished file; format 3: the file's messages,
        :attr:`file_counts`).
    foreign_topics : list of str
        Topics with schemas not from this project (counted, not decoded).
    library : str
        The MCAP header's library string.
    lost_chunks : list of LostChunk
        Damaged chunks (and unreadable bytes) skipped; every intact chunk around them
        was read. Empty for an undamaged file.
    orphaned_messages : int
        Messages read from intact chunks whose channel was defined only in a lost
        chunk (counted, not decoded).
    note : str
        How the file was read when its summary was unusable, else ""; for format 3 also
        what could not be expanded (see :attr:`unexpanded`).
    file_topics : dict of str -> str
        Topic -> schema name of the MCAP channels in the file. Format 3 (one message per
        step and kind) is read as the format-2 view: :attr:`topics`, :attr:`counts`,
        :attr:`records` and :attr:`messages` hold the format-2 records the format-2
        recorder writes for the same run (:mod:`netsim.traces.stepread`), and
        ``file_topics`` the file's own per-step topics. Formats 1 and 2: equal to
        :attr:`topics`.
    file_counts : dict of str -> int
        Messages read per topic of the file (formats 1 and 2: equal to :attr:`counts`).
    unexpanded : dict of str -> int
        Format 3: what the file holds but could not be expanded into format-2 records,
        by kind (e.g. ``delivered``: deliveries of a step some of whose sends or drops
        were in a lost chunk); empty for an intact file and formats 1 and 2.
    """

    path: str
    metadata: dict[str, dict[str, str]]
    matrices: dict[str, np.ndarray]
    attachments: dict[str, bytes]
    topics: dict[str, str]
    counts: dict[str, int]
    records: dict[str, list[TraceRecord]]
    messages: list[TraceRecord]
    truncated: bool
    recovered_messages: int
    foreign_topics: list[str] = field(default_factory=list)
    library: str = ""
    lost_chunks: list[LostChunk] = field(default_factory=list)
    orphaned_messages: int = 0
    note: str = ""
    #: Drop reason codes (format 2's LinkDropped.reason) -> text.
    drop_reasons: dict[int, str] = field(default_factory=dict)
    file_topics: dict[str, str] = field(default_factory=dict)
    file_counts: dict[str, int] = field(default_factory=dict)
    unexpanded: dict[str, int] = field(default_factory=dict)
    _link_cache: dict[tuple[int, int], list[LinkEvent]] | None = field(
        default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.file_topics and not self.file_counts:
            self.file_topics, self.file_counts = dict(self.topics), dict(self.counts)

    def __repr__(self) -> str:
        """One line: the file, its format and message count (not the records)."""
        state = "truncated" if self.truncated else "finished"
        return (f"<Trace {self.path}: format {self.format}, {state}, "
                f"{len(self.messages)} message(s) on {len(self.topics)} topic(s), "
                f"{len(self.lost_chunks)} lost chunk(s)>")

    @property
    def format(self) -> int:
        """Trace format: 1, 2 or 3 (from ``run.trace_format`` ``netsim-trace/<n>``)."""
        fmt = self.run.get("trace_format", "netsim-trace/1").rsplit("/", 1)[-1]
        return int(fmt) if fmt.isdigit() else 1

    @property
    def time_origin_ns(self) -> int:
        """log_time of simulation time 0 (ns since the Unix epoch; 0 in format 1)."""
        value = self.run.get("time_origin_ns", "0")
        return int(value) if value.isdigit() else 0

    def sim_time_ns(self, log_time: int) -> int:
        """Simulation time (ns) of a record's log_time."""
        return int(log_time) - self.time_origin_ns

    # -- topic names of this trace's format ------------------------------------------

    def sensor_topic(self, i: int) -> str:
        return _sensor_topic(i, self.format)

    def estimate_topic(self, i: int) -> str:
        return _estimate_topic(i, self.format)

    def update_topic(self, i: int) -> str:
        return _update_topic(i, self.format)

    def freshness_topic(self, i: int) -> str:
        return _freshness_topic(i, self.format)

    def link_topics(self, sender: int, receiver: int) -> list[str]:
        """The topic(s) of a link: one in format 1, one per event in format 2."""
        if self.format == 1:
            return [_link_topic(sender, receiver, fmt=1)]
        return [_link_topic(sender, receiver, e) for e in LINK_EVENTS]

    @property
    def damaged(self) -> bool:
        """Some chunk or record could not be read (see :attr:`lost_chunks`)."""
        return bool(self.lost_chunks) or self.orphaned_messages > 0

    @property
    def lost_messages(self) -> int | None:
        """Messages in the lost chunks (None if a count is unknown)."""
        counts = [c.messages for c in self.lost_chunks]
        known = [n for n in counts if n is not None]
        if len(known) != len(counts):
            return None
        return sum(known) + self.orphaned_messages

    # -- metadata ------------------------------------------------------------------

    @property
    def scenario(self) -> dict[str, str]:
        return self.metadata.get("scenario", {})

    @property
    def run(self) -> dict[str, str]:
        return self.metadata.get("run", {})

    @property
    def status(self) -> dict[str, str] | None:
        """The ``run_status`` record, None if the writer never finished."""
        return self.metadata.get("run_status")

    @property
    def family(self) -> str:
        return self.run.get("family", "")

    def family_trait(self, trait: str) -> Any:
        """What the run's family declares (:mod:`netsim.estimators.registry`): from the
        trace's ``run`` metadata (``family_<trait>``, as a string), or, for a trace
        written before families recorded their traits, from the registry's family of
        that name (None when neither knows)."""
        value = self.run.get(f"family_{trait}")
        if value is not None:
            return value
        if not self.family or ":" in self.family:
            return None
        from netsim.estimators.registry import FamilyError, get_family

        try:
            return getattr(get_family(self.family), trait, None)
        except FamilyError:
            return None

    @property
    def error_recursion(self) -> str | None:
        """The augmented error recursion the run's family declares (one of the
        ``RECURSION_*`` of :mod:`netsim.estimators.registry`) or None
        (:meth:`family_trait`)."""
        return self.family_trait("error_recursion") or None

    @property
    def recursion_compensated(self) -> bool | None:
        """Which consensus error recursion replays the run: True, the A^(r+1)-compensated
        one (LCSYS2022 eq. 9); False, the uncompensated one (delay-tolerant eq. 11);
        None, neither (the block update has its own, see :attr:`error_recursion`)."""
        from netsim.estimators.registry import RECURSION_COMPENSATED, RECURSION_UNCOMPENSATED

        compensated: dict[str | None, bool] = {RECURSION_COMPENSATED: True,
                                               RECURSION_UNCOMPENSATED: False}
        return compensated.get(self.error_recursion)

    @property
    def centralised(self) -> bool:
        """Whether the run's family is one agent on every sensor (no network)."""
        return str(self.family_trait("centralised")) == "True"

    @property
    def trial(self) -> int | None:
        value = self.run.get("trial", "")
        return int(value) if value.lstrip("-").isdigit() else None

    @property
    def seed(self) -> str:
        return self.run.get("seed", "")

    @property
    def sample_period(self) -> float:
        try:
            return float(self.run.get("sample_period", "1.0"))
        except ValueError:
            return 1.0

    # -- structure -----------------------------------------------------------------

    def _parsed(self) -> list[tuple[str, Any]]:
        return [(t, info) for t in self.topics if (info := parse_topic(t)) is not None]

    @property
    def agents(self) -> list[int]:
        """Agents with an estimate or update topic."""
        return sorted({info.index for _, info in self._parsed()
                       if info.kind in ("estimate", "update")})

    @property
    def sensors(self) -> list[int]:
        return sorted({info.index for _, info in self._parsed() if info.kind == "sensor"})

    @property
    def links(self) -> list[tuple[int, int]]:
        """Links (sender, receiver) with a topic, sorted."""
        return sorted({(info.index, info.receiver) for _, info in self._parsed()
                       if info.kind == "link"})

    @property
    def n_agents(self) -> int:
        """Agents that ran (one, the fusion centre, for ``centralized-kf``)."""
        agents = self.agents
        if agents:
            return agents[-1] + 1
        value = self.scenario.get("n_agents", "0")
        return int(value) if value.isdigit() else 0

    @property
    def n_states(self) -> int:
        plant = self.records.get("/plant/state")
        if plant:
            return len(plant[0].message.state)
        if "A" in self.matrices:
            return int(self.matrices["A"].shape[0])
        return 0

    @property
    def steps(self) -> list[int]:
        """Plant steps recorded, in order."""
        return [int(r.message.step) for r in self.records.get("/plant/state", [])]

    def topic(self, name: str) -> list[Any]:
        """The decoded messages of one topic (empty if absent)."""
        return [r.message for r in self.records.get(name, [])]

    # -- arrays --------------------------------------------------------------------

    def _length(self) -> int:
        last = -1
        for topic, recs in self.records.items():
            info = parse_topic(topic)
            if info is not None and info.kind in ("plant", "estimate", "update",
                                                  "freshness"):
                for r in recs:
                    last = max(last, int(r.message.step))
        return last + 1

    def states(self) -> np.ndarray:
        """True states, shape (K+1, n), row k = x_k (NaN where not recorded)."""
        out = np.full((self._length(), self.n_states), np.nan)
        for msg in self.topic("/plant/state"):
            out[msg.step] = msg.state
        return out

    def measurements(self, sensor: int) -> np.ndarray:
        """Sensor i's measurements, shape (K+1, m_i) (NaN where not recorded)."""
        msgs = self.topic(self.sensor_topic(sensor))
        width = len(msgs[0].values) if msgs else 0
        out = np.full((self._length(), width), np.nan)
        for msg in msgs:
            out[msg.step] = msg.values
        return out

    def estimates(self) -> np.ndarray:
        """Estimates, shape (K+1, N, n): [k, i] = x-hat^i_{k|k} (NaN where not recorded)."""
        out = np.full((self._length(), self.n_agents, self.n_states), np.nan)
        for i in self.agents:
            for msg in self.topic(self.estimate_topic(i)):
                out[msg.step, i] = msg.estimate
        return out

    def squared_errors(self) -> np.ndarray:
        """||x-hat^i_k - x_k||^2, shape (K+1, N) (NaN where not recorded)."""
        out = np.full((self._length(), self.n_agents), np.nan)
        for i in self.agents:
            for msg in self.topic(self.estimate_topic(i)):
                out[msg.step, i] = msg.squared_error
        return out

    def effective_delays(self) -> np.ndarray:
        """r_ij[k], shape (K+1, N, N), int: -1 own estimate substituted, NOT_USED (-2)
        where j's estimate was not used (same convention as ``TrialResult``)."""
        n = self.n_agents
        out = np.full((self._length(), n, n), NOT_USED, dtype=np.int32)
        for i in self.agents:
            for msg in self.topic(self.update_topic(i)):
                for j, r in zip(msg.neighbours, msg.effective_delay, strict=True):
                    out[msg.step, i, int(j)] = int(r)
        return out

    def freshness(self) -> np.ndarray:
        """Largest freshness index (age of information) of each AoI agent per step.

        Shape (K+1, N), int: -1 where some substate still holds the dummy value
        omega, -2 where nothing was recorded (not an AoI trace)."""
        out = np.full((self._length(), self.n_agents), -2, dtype=np.int32)
        for i in self.agents:
            for msg in self.topic(self.freshness_topic(i)):
                out[msg.step, i] = msg.max_index
        return out

    def clocks(self) -> dict[int, dict[str, np.ndarray]]:
        """Each agent's samples on its own clock (``/agent_<i>/clock``, scenarios with a
        ``[time]`` table): arrays ``sample``, ``true_time``, ``local_time`` (the stamp on
        what it sent) and ``sent`` (bool), in sample order; {} for a trace without them."""
        out: dict[int, dict[str, np.ndarray]] = {}
        for i in self.agents:
            msgs = self.topic(_clock_topic(i))
            if not msgs:
                continue
            out[i] = {
                "sample": np.array([m.sample for m in msgs], dtype=np.int64),
                "true_time": np.array([m.time for m in msgs], dtype=float),
                "local_time": np.array([m.local_time for m in msgs], dtype=float),
                "sent": np.array([bool(m.sent) for m in msgs], dtype=bool),
            }
        return out

    def link_events(self, sender: int, receiver: int,
                    event: str | None = None) -> list[LinkEvent]:
        """Message events of link sender -> receiver in log_time order (file order on
        ties), optionally of one kind (``sent``, ``delivered``, ``dropped``)."""
        if self._link_cache is None:
            self._link_cache = self._collect_link_events()
        events = self._link_cache.get((int(sender), int(receiver)), [])
        return [e for e in events if event is None or e.event == event]

    def _collect_link_events(self) -> dict[tuple[int, int], list[LinkEvent]]:
        out: dict[tuple[int, int], list[LinkEvent]] = {}
        reasons = self.drop_reasons
        infos = {t: info for t in self.topics if t not in self.foreign_topics
                 and (info := parse_topic(t)) is not None and info.kind == "link"}
        for record in self.messages:
            info = infos.get(record.topic)
            if info is None:
                continue
            m = record.message
            if info.format == 1:
                event = str(m.event)
                accepted, reason, when = bool(m.accepted), str(m.reason), float(m.event_time)
            else:
                event = cast(str, info.event)  # a link topic of format 2 on names its event
                accepted = event == "delivered" and bool(m.accepted)
                reason = ""
                when = float(m.send_time)
                if event == "dropped":
                    code = int(m.reason)
                    reason = reasons.get(code, f"reason {code}")
                    when = float(m.drop_time)
                elif event == "delivered":
                    when = float(m.arrival_time)
            payload = list(m.payload) if event == "sent" or info.format == 1 else []
            link = cast("tuple[int, int]", (info.index, info.receiver))  # a link topic's
            out.setdefault(link, []).append(LinkEvent(
                event, int(m.sender), int(m.receiver), int(m.sent_step),
                int(m.usable_step), int(m.sequence), float(m.send_time),
                float(m.arrival_time), int(m.delay_steps), accepted, reason, when, payload,
                int(record.log_time)))
        return out


# -- reading -------------------------------------------------------------------------


def read_trace(path: str | os.PathLike[str]) -> Trace:
    """Read a netsim trace.

    Raises
    ------
    TraceError
        Not an MCAP file, corrupted, not a netsim trace, or missing schemas.
    """
    path = Path(path)
    where = str(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(8)
            if len(head) < 8 or head != _MAGIC:
                raise TraceError(f"{where}: not an MCAP file (bad or missing magic bytes)")
            finished = False
            if size >= 8 + _FOOTER_SIZE + 8:
                f.seek(size - 8)
                finished = f.read(8) == _MAGIC
            if finished:
                return _read_finished(f, where, size)
            return _scan(f, where, size)
    except TraceError:
        raise
    except OSError as exc:
        raise TraceError(f"{where}: cannot read file ({exc.strerror or exc})") from None


def read_status(path: str | os.PathLike[str]) -> dict[str, str] | None:
    """The ``run_status`` metadata of a finished trace, read from its index alone (None
    for a file that is unreadable, unfinished or has none)."""
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            if reader.get_summary() is not None:
                records: Any = reader.iter_metadata()
            else:  # no index: the top-level records, chunks skipped (never inflated)
                f.seek(0)
                records = StreamReader(f, emit_chunks=True).records
            for record in records:
                if isinstance(record, Metadata) and record.name == "run_status":
                    return dict(record.metadata)
    except Exception:  # noqa: BLE001 - any failure: no status to report
        return None
    return None


class _Collector:
    """Accumulates records of either reading path and builds the Trace."""

    def __init__(self, where: str, lenient: bool = False) -> None:
        self.where = where
        #: Count (do not refuse) messages on channels never defined: their definition
        #: may have been in a lost chunk.
        self.lenient = lenient
        self.orphaned = 0
        self.metadata: dict[str, dict[str, str]] = {}
        self.matrices: dict[str, np.ndarray] = {}
        self.attachments: dict[str, bytes] = {}
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.topics: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self.records: dict[str, list[TraceRecord]] = {}
        self.messages: list[TraceRecord] = []
        self.foreign: set[str] = set()
        self.library = ""
        self._factory = DecoderFactory()
        self._decoders: dict[int, Any] = {}

    def metadata_record(self, record: Metadata) -> None:
        if record.name == DROP_REASONS_METADATA:  # written again per new reason: union
            self.metadata.setdefault(record.name, {}).update(record.metadata)
            return
        self.metadata[record.name] = dict(record.metadata)

    def attachment(self, record: Attachment) -> None:
        name = record.name
        if name.endswith(".npy"):
            try:
                array = np.load(io.BytesIO(record.data), allow_pickle=False)
            except Exception as exc:  # noqa: BLE001 - any failure is a corrupt attachment
                raise TraceError(
                    f"{self.where}: attachment {name!r} is not a valid .npy array ({exc})"
                ) from None
            self.matrices[name[: -len(".npy")]] = array
        else:
            self.attachments[name] = bytes(record.data)

    def channel(self, channel: Channel) -> None:
        if channel.schema_id == 0 or channel.schema_id not in self.schemas:
            raise TraceError(
                f"{self.where}: channel {channel.topic!r} has no schema "
                f"(schema id {channel.schema_id} missing)"
            )
        schema = self.schemas[channel.schema_id]
        self.channels[channel.id] = channel
        self.topics[channel.topic] = schema.name
        self.counts.setdefault(channel.topic, 0)
        if not _is_netsim(schema, channel):
            self.foreign.add(channel.topic)

    def message(self, message: Message) -> None:
        channel = self.channels.get(message.channel_id)
        if channel is None and self.lenient:
            self.orphaned += 1
            return
        if channel is None:
            raise TraceError(
                f"{self.where}: message on unknown channel id {message.channel_id}"
            )
        topic = channel.topic
        self.counts[topic] += 1
        if topic in self.foreign:
            return
        decoder = self._decoders.get(channel.id)
        if decoder is None:
            try:
                decoder = self._factory.decoder_for(
                    channel.message_encoding, self.schemas[channel.schema_id]
                )
            except Exception as exc:  # noqa: BLE001 - bad descriptor data
                raise TraceError(
                    f"{self.where}: schema of topic {topic!r} is unusable ({exc})"
                ) from None
            if decoder is None:
                raise TraceError(f"{self.where}: no protobuf decoder for topic {topic!r}")
            self._decoders[channel.id] = decoder
        try:
            decoded = decoder(message.data)
        except Exception as exc:  # noqa: BLE001 - protobuf DecodeError and friends
            raise TraceError(
                f"{self.where}: message on {topic!r} at log_time {message.log_time} "
                f"does not decode ({exc})"
            ) from None
        record = TraceRecord(topic, message.log_time, message.publish_time,
                             message.sequence, decoded)
        self.records.setdefault(topic, []).append(record)
        self.messages.append(record)

    def sort_messages(self) -> None:
        """log_time order, file order on ties (the recorder writes in that order)."""
        self.messages.sort(key=lambda r: r.log_time)
        for records in self.records.values():
            records.sort(key=lambda r: r.log_time)

    def build(self, truncated: bool, lost: list[LostChunk] | None = None,
              note: str | None = None) -> Trace:
        where = self.where
        lost = list(lost or [])
        if self.orphaned and not lost:
            raise TraceError(f"{where}: {self.orphaned} messages on unknown channels")
        netsim_topics = [t for t in self.topics if t not in self.foreign]
        if "scenario" not in self.metadata:
            if truncated and not self.metadata:
                raise TraceError(
                    f"{where}: truncated before its metadata; nothing recoverable"
                )
            schemas = sorted(set(self.topics.values())) or ["none"]
            raise TraceError(
                f"{where}: not a netsim trace (no 'scenario' metadata; schemas: "
                f"{', '.join(schemas)})"
            )
        fmt = self.metadata.get("run", {}).get("trace_format", "")
        if not fmt.startswith("netsim-trace/"):
            raise TraceError(
                f"{where}: not a netsim trace (run.trace_format is {fmt!r}, "
                "expected netsim-trace/...)"
            )
        if self.topics and not netsim_topics:
            raise TraceError(
                f"{where}: not a netsim trace (no {PACKAGE} schemas; found "
                f"{', '.join(sorted(set(self.topics.values())))})"
            )
        run = self.metadata.get("run", {})
        origin = run.get("time_origin_ns", "0")
        for chunk in lost:
            chunk.origin = int(origin) if origin.isdigit() else 0
        reasons = {int(c): r for c, r in self.metadata.get(DROP_REASONS_METADATA, {}).items()
                   if c.isdigit()}
        topics, counts, records, messages = self.topics, self.counts, self.records, self.messages
        unexpanded: dict[str, int] = {}
        if any(name.startswith(_PACKAGE3 + ".") for t, name in self.topics.items()
               if t not in self.foreign):  # format 3: read as the format-2 view
            from netsim.traces.stepread import expand_steps

            view = expand_steps(self.records, self.topics, self.counts, self.metadata,
                                self.foreign)
            topics, counts, records, messages = (view.topics, view.counts, view.records,
                                                 view.messages)
            unexpanded = view.unexpanded
            note = "; ".join(text for text in (note, view.note) if text)
        matrices = self.matrices
        if run.get("stacked_matrices"):  # format 3: per-agent matrices stacked as one
            from netsim.traces.stepread import unstack_matrices

            matrices = unstack_matrices(matrices, run)
        return Trace(
            drop_reasons=reasons,
            path=where,
            metadata=self.metadata,
            matrices=matrices,
            attachments=self.attachments,
            topics=topics,
            counts=counts,
            records=records,
            messages=messages,
            truncated=truncated,
            recovered_messages=sum(self.counts.values()),
            foreign_topics=sorted(self.foreign),
            library=self.library,
            lost_chunks=lost,
            orphaned_messages=self.orphaned,
            note=note or "",
            file_topics=dict(self.topics),
            file_counts=dict(self.counts),
            unexpanded=unexpanded,
        )


def _is_netsim(schema: Schema, channel: Channel) -> bool:
    return (
        schema.encoding == SchemaEncoding.Protobuf
        and channel.message_encoding == MessageEncoding.Protobuf
        and schema.name.startswith(PACKAGE + ".")
    )


def _describe(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text and text[0] else type(exc).__name__


def _read_finished(f: Any, where: str, size: int) -> Trace:
    """A file with a footer: the summary's schemas, channels, metadata and attachment
    indexes, then every chunk of its chunk index, CRC checked one by one: a damaged
    chunk is skipped and reported (with the message count its message index lists)."""
    try:
        _check_summary_crc(f, where, size)
    except TraceError as exc:
        f.seek(0)
        return _scan(f, where, size, finished=True,
                     note=f"summary unusable ({str(exc).split(': ', 1)[-1]}); read by scanning")
    collect = _Collector(where)
    lost: list[LostChunk] = []
    try:
        f.seek(0)
        reader = make_reader(f, validate_crcs=True)
        collect.library = reader.get_header().library
        summary = reader.get_summary()
        stats = summary.statistics if summary is not None else None
        if summary is None or (not summary.chunk_indexes and stats is not None
                               and stats.message_count):
            f.seek(0)  # finished without a summary or chunk index: read it sequentially
            return _scan(f, where, size, finished=True)
        for record in reader.iter_metadata():
            collect.metadata_record(record)
        for attachment in reader.iter_attachments():
            collect.attachment(attachment)
        collect.schemas.update(summary.schemas)
        for channel in summary.channels.values():
            collect.channel(channel)
    except TraceError:
        raise
    except Exception as exc:  # noqa: BLE001 - mcap, struct errors in the summary
        raise TraceError(f"{where}: corrupted MCAP file ({_describe(exc)})") from None
    # Decoding is done here (DecoderFactory from the stored FileDescriptorSet) so a
    # decoding failure names its topic; messages in log_time order, file order on ties.
    budget = chunk_budget()
    for ordinal, index in enumerate(sorted(summary.chunk_indexes,
                                           key=lambda c: c.chunk_start_offset)):
        try:
            f.seek(index.chunk_start_offset)
            opcode, length = struct.unpack("<BQ", f.read(9))
            if opcode != Opcode.CHUNK or 9 + length != index.chunk_length:
                raise ValueError("the chunk index points at no chunk record")
            chunk = Chunk.read(ReadDataStream(f))
            records = _chunk_records_of(chunk, budget, where, index.chunk_start_offset)
        except ChunkTooLarge:
            raise
        except Exception as exc:  # noqa: BLE001 - CRC, decompression, parse errors
            lost.append(LostChunk(ordinal, index.chunk_start_offset, index.chunk_length,
                                  index.message_start_time, index.message_end_time,
                                  _indexed_count(f, index), _describe(exc)))
            continue
        for item in records:
            if isinstance(item, Message):
                collect.message(item)
    collect.sort_messages()
    read = sum(collect.counts.values())
    if stats is not None and not lost and stats.message_count != read:
        raise TraceError(
            f"{where}: summary lists {stats.message_count} messages, {read} were read"
        )
    if stats is not None and lost and stats.message_count >= read:
        _share_out(lost, stats.message_count - read)
    return collect.build(truncated=False, lost=lost)


def _indexed_count(f: Any, index: Any) -> int | None:
    """Messages of a chunk according to its message index records (None if unreadable)."""
    total = 0
    try:
        for offset in index.message_index_offsets.values():
            f.seek(offset)
            opcode, _length = struct.unpack("<BQ", f.read(9))
            if opcode != Opcode.MESSAGE_INDEX:
                return None
            total += len(MessageIndex.read(ReadDataStream(f)).records)
    except Exception:  # noqa: BLE001 - the count stays unknown
        return None
    return total


def _share_out(lost: list[LostChunk], missing: int) -> None:
    """With the summary's message count: a single lost chunk whose message index is
    unreadable lost exactly the messages not read."""
    unknown = [c for c in lost if c.messages is None]
    if len(unknown) == 1:
        unknown[0].messages = missing - sum(c.messages or 0 for c in lost)


def _check_summary_crc(f: Any, where: str, size: int) -> None:
    footer_at = size - 8 - _FOOTER_SIZE
    f.seek(footer_at)
    raw = f.read(_FOOTER_SIZE)
    opcode, length, summary_start, summary_offset_start, crc = struct.unpack("<BQQQI", raw)
    if opcode != _FOOTER_OPCODE or length != _FOOTER_SIZE - 9:
        raise TraceError(f"{where}: corrupted MCAP file (bad footer record)")
    if crc == 0:
        return
    start = summary_start if summary_start else footer_at
    if not 8 <= start <= footer_at:
        raise TraceError(f"{where}: corrupted MCAP file (summary offset out of range)")
    f.seek(start)
    actual = zlib.crc32(f.read(footer_at - start))
    actual = zlib.crc32(raw[:-4], actual)
    if actual != crc:
        raise TraceError(
            f"{where}: corrupted MCAP file (summary CRC mismatch: "
            f"expected {crc:#010x}, computed {actual:#010x})"
        )


def _take(collect: _Collector, record: Any) -> None:
    if isinstance(record, Schema):
        collect.schemas[record.id] = record
    elif isinstance(record, Channel):
        collect.channel(record)
    elif isinstance(record, Message):
        collect.message(record)
    elif isinstance(record, Metadata):
        collect.metadata_record(record)
    elif isinstance(record, Attachment):
        collect.attachment(record)
    elif type(record).__name__ == "Header":
        collect.library = record.library


# -- bounded decompression -----------------------------------------------------------

#: A memory budget: (bytes, where the limit comes from), or a callable returning it.
Budget = tuple[int, str] | Callable[[], tuple[int, str]]


def chunk_budget() -> Callable[[], tuple[int, str]]:
    """The memory budget of one file's chunks: a callable asking
    :func:`netsim.budget.memory_limit` once, at its first call (the first compressed
    chunk), and returning that answer from then on."""
    known: list[tuple[int, str]] = []

    def budget() -> tuple[int, str]:
        if not known:
            from netsim.budget import memory_limit

            known.append(memory_limit())
        return known[0]

    return budget


def inflate_chunk(compression: str, data: bytes | memoryview, uncompressed_size: int, *,
                  budget: Budget | None = None, where: str = "",
                  offset: int | None = None) -> bytes:
    """Decompress a chunk's records to exactly its declared uncompressed size.

    The one place chunks are inflated. A compressed chunk's declared size is checked
    against the memory budget first, then the data is decompressed as a stream that
    produces at most ``uncompressed_size + 1`` bytes, whatever the compressed data
    (or its frame header) says: a decompression bomb costs neither memory nor time.

    Parameters
    ----------
    compression : str
        The chunk's compression: ``""`` (none), ``"zstd"`` or ``"lz4"`` (LZ4 frames).
    data : bytes or memoryview
        The chunk's records as stored (compressed).
    uncompressed_size : int
        The chunk's declared ``uncompressed_size``.
    budget : (int, str) or callable, optional
        The budget (bytes, where the limit comes from) the declared size of a
        compressed chunk may not exceed, or a callable returning it (see
        :func:`chunk_budget`); default :func:`netsim.budget.memory_limit`.
    where : str, optional
        The file, named by the refusal.
    offset : int, optional
        The chunk's offset in the file, named by the refusal.

    Returns
    -------
    bytes
        The records, exactly ``uncompressed_size`` bytes.

    Raises
    ------
    ChunkTooLarge
        The chunk is compressed and declares more than the budget (nothing was
        decompressed).
    ValueError
        The chunk is damaged: unknown compression, data that does not decompress, or
        that decompresses to more or fewer bytes than declared.
    """
    if compression == "":
        if len(data) != uncompressed_size:
            raise ValueError(f"uncompressed chunk holds {len(data)} bytes, "
                             f"it declares {uncompressed_size}")
        return bytes(data)
    if compression not in ("zstd", "lz4"):
        raise ValueError(f"unsupported chunk compression {compression!r}")
    limit, source = (budget() if callable(budget) else budget) if budget is not None \
        else _memory_limit()
    if uncompressed_size > limit:
        from netsim.budget import format_bytes

        head = f"{where}: " if where else ""
        at = f" at byte {offset}" if offset is not None else ""
        raise ChunkTooLarge(
            f"{head}{compression} chunk{at} declares {uncompressed_size} bytes "
            f"({format_bytes(uncompressed_size)}) uncompressed; this machine can give "
            f"{format_bytes(limit)} ({source}); refused without decompressing it",
            uncompressed_size, limit)
    wanted = uncompressed_size + 1  # one byte more shows data inflating past the size
    if compression == "zstd":
        records = _inflate_zstd(data, wanted)
    else:
        records = _inflate_lz4(data, wanted)
    if len(records) > uncompressed_size:
        raise ValueError(f"{compression} data inflates past the declared uncompressed "
                         f"size ({uncompressed_size} bytes)")
    if len(records) < uncompressed_size:
        raise ValueError(f"{compression} data inflates to {len(records)} bytes, the chunk "
                         f"declares {uncompressed_size}")
    return records


def _memory_limit() -> tuple[int, str]:
    from netsim.budget import memory_limit

    return memory_limit()


def _inflate_zstd(data: bytes | memoryview, wanted: int) -> bytes:
    """At most ``wanted`` bytes of the zstd frames in ``data`` (the frames' own content
    sizes are not trusted: the output buffer is ``wanted`` bytes)."""
    parts: list[bytes] = []
    got = 0
    try:
        reader = zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True)
        while got < wanted:
            piece = reader.read(wanted - got)
            if not piece:
                break
            parts.append(piece)
            got += len(piece)
    except zstandard.ZstdError as exc:
        raise ValueError(f"zstd: {exc}") from None
    return b"".join(parts)


def _inflate_lz4(data: bytes | memoryview, wanted: int) -> bytes:
    """At most ``wanted`` bytes of the LZ4 frames in ``data``."""
    try:
        import lz4.frame
    except ImportError:
        raise ValueError("lz4 chunk, but the lz4 package is not installed") from None
    parts: list[bytes] = []
    got = 0
    rest: bytes | memoryview = data
    try:
        while got < wanted and len(rest):
            inflater = lz4.frame.LZ4FrameDecompressor()
            piece = inflater.decompress(rest, max_length=wanted - got)
            parts.append(piece)
            got += len(piece)
            if got >= wanted:
                break
            if not inflater.eof:
                raise ValueError("lz4 data is cut off (frame not finished)")
            rest = inflater.unused_data or b""
    except RuntimeError as exc:  # lz4's decompression errors
        raise ValueError(f"lz4: {exc}") from None
    return b"".join(parts)


def _chunk_records_of(chunk: Chunk, budget: Budget | None, where: str,
                      offset: int | None, validate_crc: bool = True) -> list[Any]:
    """The records of a chunk (inflated by :func:`inflate_chunk`, CRC checked and split
    by the mcap library as before); raises if damaged, :class:`ChunkTooLarge` if
    refused."""
    records = inflate_chunk(chunk.compression, chunk.data, chunk.uncompressed_size,
                            budget=budget, where=where, offset=offset)
    inflated = replace(chunk, compression="", data=records)
    try:
        return list(breakup_chunk(inflated, validate_crc=validate_crc))
    except CRCValidationError as exc:
        exc.record = chunk
        raise


def stream_records(stream: Any, *, where: str = "", validate_crcs: bool = False,
                   budget: Budget | None = None) -> Iterator[Any]:
    """The records of an MCAP stream in file order, chunks inflated by
    :func:`inflate_chunk`.

    A drop-in for the ``mcap`` library's ``StreamReader(stream).records``, whose chunk
    decompression is unbounded: the same records, but a chunk is never inflated past
    its declared size and its declared size is checked against the memory budget.

    Parameters
    ----------
    stream : file object
        The MCAP file, positioned at its magic.
    where : str, optional
        The file, named by a refusal.
    validate_crcs : bool
        Check each chunk's CRC (as ``StreamReader(..., validate_crcs=True)``).
    budget : (int, str) or callable, optional
        As for :func:`inflate_chunk` (default: :func:`chunk_budget`).

    Yields
    ------
    mcap record
        Top-level records and the records inside the chunks.

    Raises
    ------
    ChunkTooLarge
        A compressed chunk declares more than the budget.
    ValueError
        A chunk is damaged (inflates to more or fewer bytes than declared, does not
        decompress, or fails its CRC); the mcap library's errors for damaged records.
    """
    budget = chunk_budget() if budget is None else budget
    for record in StreamReader(stream, emit_chunks=True, validate_crcs=validate_crcs).records:
        if isinstance(record, Chunk):
            yield from _chunk_records_of(record, budget, where, None, validate_crcs)
        else:
            yield record


# -- chunk-by-chunk recovery ---------------------------------------------------------

_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4  # start, end, uncompressed size, crc, compression length
_COMPRESSIONS = (b"", b"zstd", b"lz4")
#: the top-level record classes (each with a read(stream) class method)
_RECORD_TYPES: dict[int, Any] = {
    Opcode.ATTACHMENT: Attachment, Opcode.CHANNEL: Channel, Opcode.SCHEMA: Schema,
    Opcode.METADATA: Metadata, Opcode.HEADER: Header, Opcode.FOOTER: Footer,
    Opcode.MESSAGE_INDEX: MessageIndex,
}


def _chunk_header_plausible(data: Any, position: int, size: int) -> bool:
    """Whether a chunk record could start at ``position`` (used to find the next chunk
    after bytes whose record structure is destroyed)."""
    if position + 9 + _CHUNK_FIXED + 8 > size or data[position] != Opcode.CHUNK:
        return False
    (length,) = struct.unpack_from("<Q", data, position + 1)
    if position + 9 + length > size or length < _CHUNK_FIXED + 8:
        return False
    start, end, _usize, _crc, clen = struct.unpack_from("<QQQII", data, position + 9)
    if clen > 4 or start > end:
        return False
    at = position + 9 + _CHUNK_FIXED
    if bytes(data[at:at + clen]) not in _COMPRESSIONS:
        return False
    (records,) = struct.unpack_from("<Q", data, at + clen)
    return records == length - _CHUNK_FIXED - clen - 8


def _next_chunk(data: Any, position: int, size: int) -> int | None:
    """The first position >= ``position`` where a plausible chunk record starts."""
    while True:
        position = data.find(bytes([Opcode.CHUNK]), position, size)
        if position < 0:
            return None
        if _chunk_header_plausible(data, position, size):
            return position
        position += 1


def _chunk_records(data: Any, position: int, length: int, budget: Budget,
                   where: str) -> list[Any]:
    """The records of the chunk at ``position`` (bounded inflation, CRC checked; raises
    if damaged, :class:`ChunkTooLarge` if refused)."""
    content = bytes(data[position + 9:position + 9 + length])
    chunk = Chunk.read(ReadDataStream(io.BytesIO(content)))
    return _chunk_records_of(chunk, budget, where, position)


def _chunk_times(data: Any, position: int, size: int) -> tuple[int | None, int | None]:
    if position + 9 + 16 > size:
        return None, None
    return struct.unpack_from("<QQ", data, position + 9)


def _scan(f: Any, where: str, size: int, finished: bool = False,
          note: str | None = None) -> Trace:
    """Read record by record: every intact chunk is kept, a damaged one is skipped and
    reported (:class:`LostChunk`, with the messages its message index lists), and the
    scan resynchronises on the next chunk after bytes whose structure is destroyed; a
    last record that does not fit in the file is the truncation point."""
    collect = _Collector(where, lenient=True)
    data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    lost: list[LostChunk] = []
    chunks = 0
    truncated = False
    saw_footer = False
    counting: LostChunk | None = None  # the lost chunk whose message indexes follow
    budget = chunk_budget()
    position = 8
    try:
        while position < size:
            if size - position < 9:
                truncated = True
                break
            opcode, length = struct.unpack_from("<BQ", data, position)
            end = position + 9 + length
            known = opcode in _OPCODES
            if not known or end > size:
                resume = _next_chunk(data, position + 1, size)
                if resume is None and known and not finished:
                    truncated = True  # the last record was cut off
                    break
                stop = size if resume is None else resume
                lost.append(LostChunk(None, position, stop - position, None, None, None,
                                      "unreadable bytes (record structure destroyed)"))
                counting = None
                if resume is None:
                    truncated = not finished
                    break
                position = resume
                continue
            if opcode == Opcode.CHUNK:
                start, stop_time = _chunk_times(data, position, size)
                try:
                    records = _chunk_records(data, position, length, budget, where)
                except ChunkTooLarge:
                    raise
                except Exception as exc:  # noqa: BLE001 - CRC, decompression, parse
                    counting = LostChunk(chunks, position, 9 + length, start, stop_time, None,
                                         _describe(exc))
                    lost.append(counting)
                else:
                    counting = None
                    for item in records:
                        _take(collect, item)
                chunks += 1
            elif opcode == Opcode.MESSAGE_INDEX and counting is not None:
                try:
                    index = MessageIndex.read(ReadDataStream(io.BytesIO(
                        bytes(data[position + 9:end]))))
                    counting.messages = (counting.messages or 0) + len(index.records)
                except Exception:  # noqa: BLE001 - the count stays unknown
                    pass
            elif opcode in _RECORD_TYPES:
                counting = None
                content = bytes(data[position + 9:end])
                try:
                    record = _RECORD_TYPES[opcode].read(ReadDataStream(io.BytesIO(content)))
                except Exception as exc:  # noqa: BLE001 - a damaged top-level record
                    lost.append(LostChunk(None, position, 9 + length, None, None, None,
                                          f"unreadable {Opcode(opcode).name.lower()} "
                                          f"record ({_describe(exc)})"))
                else:
                    if isinstance(record, Footer):
                        saw_footer = True
                        break
                    _take(collect, record)
            elif opcode == Opcode.MESSAGE:
                counting = None
                try:
                    _take(collect, Message.read(ReadDataStream(io.BytesIO(
                        bytes(data[position + 9:end]))), length))
                except TraceError:
                    raise
                except Exception as exc:  # noqa: BLE001
                    lost.append(LostChunk(None, position, 9 + length, None, None, 1,
                                          f"unreadable message record ({_describe(exc)})"))
            position = end
    finally:
        data.close()
    if not saw_footer and not truncated and not finished:
        truncated = True  # ended exactly on a record boundary without a footer
    return collect.build(truncated=truncated, lost=lost, note=note)
