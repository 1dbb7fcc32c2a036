"""Record one simulation run as an MCAP file (protobuf messages).

:class:`TraceRecorder` implements the kernel's observer hooks by duck typing
(``on_plant``, ``on_sent``, ``on_delivered``, ``on_update``, plus ``on_dropped`` for
links that lose messages); pass it as ``observer=`` to ``netsim.runner.run_trial``.
This module does not import ``netsim`` or ``simpy``.

Files
-----
One MCAP file per run, i.e. per (estimator family, Monte Carlo trial): each family
runs in its own kernel run. :func:`trace_path` names them: a single run writes the
given path; for several runs ``out.mcap`` becomes ``out.<family>.trial<k>.mcap``
(e.g. ``out.compensated.trial3.mcap``).

Contents
--------
Metadata records (written first, so even a file whose writer was killed has them):

- ``scenario``: the scenario configuration, string values (JSON for structured ones).
- ``run``: ``trace_format`` (:data:`TRACE_FORMAT`, ``netsim-trace/2``), ``family``,
  ``trial``, ``seed``, ``sample_period``, ``steps`` (expected, if known),
  ``time_origin_ns`` and ``time_origin`` (ISO 8601), ``time_unit`` and the list of
  matrix attachments.
- ``drop_reasons`` (written once, by :meth:`TraceRecorder.close`, when the run dropped
  messages): ``LinkDropped.reason`` code -> reason text. Traces of earlier versions
  wrote it again per new reason (each copy the table so far); readers take the union.
  A file whose writer was killed has none (its reason codes are then unnamed).
- ``run_status`` (written by :meth:`TraceRecorder.close`): ``status`` =
  ``complete`` | ``interrupted`` (KeyboardInterrupt) | ``failed`` (other exception)
  | anything given to :meth:`TraceRecorder.set_status` (e.g. ``diverged``),
  ``last_step`` (last plant step recorded, -1 if none), ``messages`` (count written),
  ``max_delay_steps`` (largest step delay of a delivered message, -1 if none),
  ``expected_steps`` and a ``note`` if the run ended before them, and after an
  exception ``interrupted_at`` (the last plant step recorded) and ``reason``.
  Missing in a file whose writer never finished.

Attachments: each matrix as ``<name>.npy`` (numpy ``.npy`` bytes, media type
``application/x-npy``): ``A``, ``C_<i>``, ``Q``, ``R_<i>``, ``x0_mean``, ``x0_cov``,
``P`` (consensus weights), ``K_<i>``, ``L_<i>`` (gains), as given.

Topics and messages: format 2, see :mod:`netsim.traces.schemas` and the checked-in
``traces/netsim_trace_v2.proto`` (``/plant/state``, ``/sensor_<i>/measurement``,
``/agent_<i>/estimate`` with ``error_norm``, ``/agent_<i>/update``,
``/agent_<i>/freshness``, ``/link_<j>_<i>/sent``, ``.../delivered``, ``.../dropped``).
Every field of every message is set, so protobuf writes it even when zero and the
messages of a topic have equal lengths.

Times: ``log_time`` is ``time_origin_ns`` (default 2000-01-01T00:00:00Z, see
:data:`netsim.traces.schemas.DEFAULT_TIME_ORIGIN_NS`) plus the event's simulation time
(plant/update at k * Ts; a sent message at its send time; a delivered one at its
arrival time; a drop at the drop time) in integer ns, ``round(t * 1e9)``;
``publish_time`` is the origin plus the send time for link events and equals
``log_time`` otherwise. Messages are written in non-decreasing ``log_time`` order (the
kernel calls the hooks in time order; the recorder checks). The MCAP ``sequence`` is
the per-link sequence number for link events and the step otherwise.

Crash safety: the chunk in progress is closed and flushed to the OS every
``flush_every`` steps (and every ``flush_seconds`` of wall-clock time), so a killed
writer loses at most that much; :func:`netsim.traces.reader.read_trace` recovers every
complete chunk. Used as a context manager, the recorder finishes the file (summary,
indexes, footer) even when the run raises, e.g. on KeyboardInterrupt, and notes the
interruption in ``run_status``.
"""

from __future__ import annotations

import functools
import io
import json
import math
import os
import re
import stat
import time
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any, Literal

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType
from netsim.models.jsonsafe import json_default
from netsim.models.seeding import SEED_LAYOUT
from netsim.traces.bulkmcap import BulkMcapWriter as Writer
from netsim.traces.schemas import (
    DEFAULT_TIME_ORIGIN_NS,
    DROP_REASONS_METADATA,
    TRACE_FORMAT,
    clock_topic,
    estimate_topic,
    file_descriptor_set,
    format_time_origin,
    freshness_topic,
    link_topic,
    message_classes,
    plant_topic,
    schema_name,
    sensor_topic,
    update_topic,
)
from netsim.traces.schemas3 import TRACE_FORMAT as TRACE_FORMAT3
from netsim.traces.stepwriter import StepLog

__all__ = [
    "TRACE_FORMAT",
    "NPY_MEDIA_TYPE",
    "DEFAULT_TRACE_FORMAT",
    "TraceRecorder",
    "TraceOrderError",
    "trace_path",
    "check_trace_target",
    "scenario_metadata",
    "run_matrices",
    "stack_matrices",
    "to_ns",
    "plant_topic",
    "sensor_topic",
    "link_topic",
    "estimate_topic",
    "update_topic",
    "freshness_topic",
]

#: Trace format written unless asked otherwise (``netsim run --trace-format``).
DEFAULT_TRACE_FORMAT = 3
#: Media type of the ``.npy`` matrix attachments.
NPY_MEDIA_TYPE = "application/x-npy"
#: Largest backwards step in log_time (ns) silently absorbed (float rounding).
_ORDER_SLACK_NS = 1000


class TraceOrderError(RuntimeError):
    """An event arrived with a log_time earlier than one already written."""


def to_ns(t: float) -> int:
    """Return simulation time ``t`` (in time units of Ts) as integer nanoseconds."""
    return int(round(float(t) * 1e9))


def trace_path(base: str | os.PathLike[str], family: str | None = None,
               trial: int | None = None) -> Path:
    """Return the file of one run: ``base`` itself, or ``<stem>.<family>.trial<k>.mcap``.

    Either part is left out when None (``<stem>.trial<k>.mcap``, ``<stem>.<family>.mcap``).
    """
    base = Path(base)
    parts = [base.stem if base.suffix == ".mcap" else base.name]
    if family is not None:
        # a user's family may be called module:attribute: keep file names plain
        parts.append(re.sub(r"[^A-Za-z0-9_.+-]", "-", str(family)))
    if trial is not None:
        parts.append(f"trial{int(trial)}")
    if len(parts) == 1:
        return base
    return base.with_name(".".join(parts) + ".mcap")


def check_trace_target(path: str | os.PathLike[str], *, force: bool = False) -> None:
    """Refuse a file a trace must not be written to (ValueError naming it): a
    directory, a symbolic link or special file (device, pipe, socket), a file in a
    directory that does not exist or is not writable, or an existing trace unless
    ``force``."""
    path = Path(path)
    if str(path).endswith(os.sep) or path.is_dir():
        raise ValueError(f"{path}: is a directory; give a file name, e.g. {path}/run.mcap")
    if path.is_symlink():
        raise ValueError(f"{path}: is a symbolic link; netsim does not write through links "
                         "(name the target file itself)")
    if path.exists():
        mode = path.stat().st_mode if path.exists() else 0
        if path.exists() and not stat.S_ISREG(mode):
            kind = ("a character device" if stat.S_ISCHR(mode) else
                    "a block device" if stat.S_ISBLK(mode) else
                    "a named pipe" if stat.S_ISFIFO(mode) else
                    "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
            raise ValueError(f"{path}: is {kind}, not a regular file; traces are written "
                             "to regular files")
        if not force:
            raise ValueError(f"{path}: exists; pass --force to overwrite it")
    folder = path.parent
    if not folder.is_dir():
        raise ValueError(f"{path}: directory {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{path}: directory {folder} is not writable")


def _meta_value(value: Any) -> str:
    if isinstance(value, str):
        return value
    return json.dumps(value, sort_keys=True, default=partial(json_default, fallback=str))


def scenario_metadata(scenario: Any) -> dict[str, str]:
    """Return a ``netsim.models.scenario.Scenario`` as MCAP metadata (string values).

    Every key of ``scenario.summary()`` (structured values as JSON), the sample
    period, divergence threshold, gains method and the delay specification.
    """
    summary = dict(scenario.summary())
    out = {str(k): _meta_value(v) for k, v in summary.items()}
    spec = scenario.delays
    out["delay_spec"] = _meta_value({
        "model": spec.model,
        "tau": spec.tau,
        "default": spec.default,
        "seed": spec.seed,
        "links": [[j, i, d] for (j, i), d in sorted(spec.links.items())],
    })
    out["sample_period"] = repr(float(scenario.sample_period))
    out["divergence_threshold"] = repr(float(scenario.divergence_threshold))
    out["gains_method"] = str(scenario.gains.method)
    return out


def run_matrices(scenario: Any, gains: Any = None) -> dict[str, np.ndarray]:
    """Return the matrices of a run: A, C_i, Q, R_i, x0_mean, x0_cov, P, K_i, L_i."""
    plant = scenario.plant
    out: dict[str, np.ndarray] = {"A": np.asarray(plant.A)}
    out.update({f"C_{i}": np.asarray(C) for i, C in enumerate(plant.C)})
    out["Q"] = np.asarray(plant.Q)
    out.update({f"R_{i}": np.asarray(R) for i, R in enumerate(plant.R)})
    out["x0_mean"] = np.asarray(plant.x0_mean)
    out["x0_cov"] = np.asarray(plant.x0_cov)
    weights = scenario.weights
    if hasattr(weights, "toarray"):  # sparse (large networks): stored dense, as P.npy
        weights = scenario.densified("a trace (it stores the consensus matrix P)").weights
    out["P"] = np.asarray(weights)
    if gains is not None:
        out.update({f"K_{i}": np.asarray(K) for i, K in enumerate(gains.K)})
        out.update({f"L_{i}": np.asarray(L) for i, L in enumerate(gains.L)})
    return out


def stack_matrices(matrices: Mapping[str, np.ndarray]
                   ) -> tuple[dict[str, np.ndarray], list[str]]:
    """Per-agent matrices ``X_0 .. X_{N-1}`` of one shape as one array ``X`` (N, ...).

    Format 3 attaches them so (``run.stacked_matrices`` lists the stacked names; the
    reader gives ``X_i`` back): at N = 32 a run has 133 matrices, whose attachment
    records cost more than writing its 500 steps' messages. Returns the matrices to
    attach and the names stacked."""
    arrays = {name: np.asarray(matrix) for name, matrix in matrices.items()}
    groups: dict[str, list[str]] = {}
    for name in arrays:
        prefix, _, index = name.rpartition("_")
        if prefix and index.isdigit():
            groups.setdefault(prefix, []).append(name)
    members_of: dict[str, str] = {}  # name -> the prefix it is stacked under
    for prefix, members in groups.items():
        if (prefix not in arrays
                and len({(arrays[m].shape, arrays[m].dtype) for m in members}) == 1
                and members == [f"{prefix}_{i}" for i in range(len(members))]):
            members_of.update(dict.fromkeys(members, prefix))
    out: dict[str, np.ndarray] = {}
    stacked: list[str] = []
    for name, array in arrays.items():
        group = members_of.get(name)
        if group is None:
            out[name] = array
        elif group not in out:  # (np.array of equal shapes: np.stack, 3x faster)
            out[group] = np.array([arrays[m] for m in groups[group]])
            stacked.append(group)
    return out, stacked


@functools.lru_cache(maxsize=256)
def _npy_header(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """The .npy header (format 1.0, C order) of an array of ``dtype`` and ``shape``.

    Cached by the dtype, which is hashable: its .npy descr is a list for a structured
    dtype, which is not."""
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buffer, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                 "shape": shape})
    return buffer.getvalue()


def _npy_bytes(array: np.ndarray) -> bytes:
    """``array`` as a .npy file (the bytes ``np.save`` writes for a C-ordered array;
    the header is built once per dtype and shape: a trace has one attachment per
    matrix, 133 at N = 32)."""
    array = np.asarray(array)
    if not array.flags.c_contiguous:  # (ascontiguousarray would make a 0-d array 1-d)
        array = np.ascontiguousarray(array)
    if array.dtype.hasobject:
        raise ValueError("object arrays cannot be stored as .npy attachments")
    return _npy_header(array.dtype, array.shape) + \
        array.tobytes()


#: zstd level of trace chunks. Level 1 against level 3 on the traces of
#: ``benchmarks/trace_throughput.py``'s traced run: N = 32 (21 MB of records) 0.3%
#: larger, compressed in 0.6x the time; N = 4 (1.1 MB) 24% larger, in 0.3x the time.
_ZSTD_LEVEL = 1


def _compression(name: str) -> CompressionType:
    name = name.lower()
    if name == "zstd":
        return CompressionType.ZSTD
    if name == "lz4":
        return CompressionType.LZ4
    if name in ("none", ""):
        return CompressionType.NONE
    raise ValueError(f"unknown compression {name!r}; expected zstd, lz4 or none")


class TraceRecorder:
    """Kernel observer writing one run to an MCAP file.

    Parameters
    ----------
    path : str or os.PathLike
        The MCAP file to create (overwritten).
    scenario_metadata : mapping str -> str
        Written as the metadata record ``scenario`` (see :func:`scenario_metadata`).
    matrices : mapping str -> numpy.ndarray
        Written as ``<name>.npy`` attachments (see :func:`run_matrices`).
    family : str
        Estimator family of the run.
    trial : int
        Monte Carlo trial index.
    seed : object, optional
        Seed of the trial (stored as ``str(seed)``).
    sample_period : float
        Ts: plant step k happens at simulation time k * Ts.
    steps : int, optional
        Expected last step (stored; ``run_status`` says if the run ended early).
    flush_every : int
        Close the chunk in progress and flush it to the OS every this many steps.
    flush_seconds : float or None
        Also flush when this much wall-clock time passed since the last flush.
    chunk_size : int
        Close a chunk when it exceeds this many (uncompressed) bytes.
    compression : str, optional
        ``zstd`` (level 1: compressed chunks 0.3-24% larger than level 3's in 0.3-0.6x
        the time, benchmarks/README.md) or ``none``. Default: ``zstd`` for format 2,
        ``none`` for format 3, whose messages are mostly float64 arrays that zstd
        shrinks by a fifth to a third for about half again the cost of writing them
        (benchmarks/trace_throughput.py).
    record_payloads : bool
        Store each sent message's payload (the transmitted estimate).
    run_metadata : mapping str -> str, optional
        Extra entries of the ``run`` metadata record.
    time_origin_ns : int
        log_time of simulation time 0, ns since the Unix epoch (default
        2000-01-01T00:00:00Z; 0 gives log_time = simulation time).
    trace_format : int, optional
        :data:`DEFAULT_TRACE_FORMAT` unless given. 2: a message per agent and per link
        event (:mod:`netsim.traces.schemas`); 3: a
        message per step and kind (:mod:`netsim.traces.schemas3`, written by
        :class:`netsim.traces.stepwriter.StepLog`).
    writer_tap : callable, optional
        ``writer_tap(writer, recorder)`` returns the object the recorder writes through
        instead of its MCAP writer (the same methods; e.g. :mod:`netsim.live`'s tee,
        which also serves every record to a live viewer). Default: the writer itself.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        scenario_metadata: Mapping[str, str],
        matrices: Mapping[str, np.ndarray],
        family: str,
        trial: int,
        seed: Any = None,
        sample_period: float = 1.0,
        steps: int | None = None,
        flush_every: int = 25,
        flush_seconds: float | None = 2.0,
        chunk_size: int = 1024 * 1024,
        compression: str | None = None,
        record_payloads: bool = True,
        run_metadata: Mapping[str, str] | None = None,
        time_origin_ns: int = DEFAULT_TIME_ORIGIN_NS,
        trace_format: int | None = None,
        writer_tap: Callable[[Any, Any], Any] | None = None,
    ) -> None:
        if trace_format is None:
            trace_format = DEFAULT_TRACE_FORMAT
        if trace_format not in (2, 3):
            raise ValueError(f"trace_format must be 2 or 3, got {trace_format!r}")
        if compression is None:
            compression = "zstd" if trace_format == 2 else "none"
        if flush_every < 1:
            raise ValueError(f"flush_every must be >= 1, got {flush_every}")
        if not sample_period > 0:
            raise ValueError(f"sample_period must be > 0, got {sample_period}")
        if not 0 <= int(time_origin_ns) < 2**63:
            raise ValueError(f"time_origin_ns must be in 0 .. 2**63 - 1, got {time_origin_ns}")
        #: log_time of simulation time 0 (ns since the Unix epoch).
        self.time_origin_ns = int(time_origin_ns)
        #: Drop reason -> code of ``LinkDropped.reason`` (metadata ``drop_reasons``).
        self.drop_reasons: dict[str, int] = {}
        self.path = Path(path)
        self.family = str(family)
        self.trial = int(trial)
        self.sample_period = float(sample_period)
        self.expected_steps = None if steps is None else int(steps)
        self.flush_every = int(flush_every)
        self.flush_seconds = flush_seconds
        self.record_payloads = record_payloads
        #: Last plant step recorded (-1 before the first).
        self.last_step = -1
        #: Step at which the run was interrupted (exception inside the context), or None.
        self.interrupted_at: int | None = None
        #: Messages written per topic.
        self.counts: dict[str, int] = {}
        self.messages_written = 0
        #: Largest ``delay_steps`` of a delivered message so far (-1 before the first).
        self.max_delay_steps = -1
        self.closed = False
        self._status: str | None = None
        self._status_info: dict[str, str] = {}

        #: Trace format written: 2 (a message per agent and link event) or 3 (a message
        #: per step and kind, :mod:`netsim.traces.schemas3`).
        self.trace_format = int(trace_format)
        fmt_name = TRACE_FORMAT if self.trace_format == 2 else TRACE_FORMAT3
        self._classes = message_classes()
        self._stream = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        try:
            self._writer = Writer(
                self._stream, chunk_size=int(chunk_size), compression=_compression(compression),
                level=_ZSTD_LEVEL,
            )
            if writer_tap is not None:
                self._writer = writer_tap(self._writer, self)
            self._writer.start(profile="", library=f"{fmt_name} {_mcap_library()}")
            self._writer.add_metadata(
                "scenario", {str(k): str(v) for k, v in scenario_metadata.items()}
            )
            run = {
                "trace_format": fmt_name,
                "family": self.family,
                "trial": str(self.trial),
                "seed": "" if seed is None else str(seed),
                "seed_layout": str(SEED_LAYOUT),
                "sample_period": repr(self.sample_period),
                "steps": "" if steps is None else str(int(steps)),
                "time_origin_ns": str(self.time_origin_ns),
                "time_origin": format_time_origin(self.time_origin_ns),
                "time_unit": "log_time/publish_time: time_origin_ns + integer ns of "
                             "simulation time, round(t * 1e9), t = k * Ts",
                "matrices": ",".join(matrices),
            }
            attached: Mapping[str, np.ndarray] = matrices
            if self.trace_format == 3:  # per-agent matrices of one shape: one attachment
                attached, stacked = stack_matrices(matrices)
                run["stacked_matrices"] = ",".join(stacked)
            run.update({str(k): str(v) for k, v in (run_metadata or {}).items()})
            self._writer.add_metadata("run", run)
            for name, matrix in attached.items():
                self._writer.add_attachment(
                    create_time=0, log_time=0, name=f"{name}.npy",
                    media_type=NPY_MEDIA_TYPE, data=_npy_bytes(matrix),
                )
            self._steps: StepLog | None = None
            if self.trace_format == 2:
                descriptor_set = file_descriptor_set().SerializeToString()
                self._schema_ids = {
                    name: self._writer.register_schema(
                        name=schema_name(name), encoding=SchemaEncoding.Protobuf,
                        data=descriptor_set,
                    )
                    for name in self._classes
                }
            else:
                self._schema_ids = {}
                self._steps = StepLog(self, record_payloads)
            self._writer.flush()
        except BaseException:
            self._stream.close()
            raise
        self._channels: dict[str, int] = {}
        self._last_log_time = self.time_origin_ns
        self._last_flush = time.monotonic()
        self._state: np.ndarray | None = None
        self._state_step = -1

    # -- construction from project objects ---------------------------------------

    @classmethod
    def for_run(
        cls,
        path: str | os.PathLike[str],
        scenario: Any,
        gains: Any,
        family: str,
        trial: int,
        seed: Any = None,
        *,
        steps: int | None = None,
        **options: Any,
    ) -> TraceRecorder:
        """Recorder for one run of ``scenario`` (a ``netsim.models.scenario.Scenario``) with
        ``gains`` (an ``netsim.estimators.gains.GainDesign`` or None).

        ``steps`` defaults to ``scenario.steps``; ``family_traits`` (what the family
        declares in :mod:`netsim.estimators.registry`, e.g. ``error_recursion``) is
        recorded in the ``run`` metadata as ``family_<trait>``, so a reader knows what
        analytics apply without the family being installed; ``options`` go to the
        constructor.
        """
        run = dict(options.pop("run_metadata", None) or {})
        traits = options.pop("family_traits", None) or {}
        for key, value in traits.items():
            if key != "name":
                run.setdefault(f"family_{key}", "" if value is None else str(value))
        if gains is not None:
            run.setdefault("gains_method", str(getattr(gains, "method", "")))
            run.setdefault("gains_solver", str(getattr(gains, "solver", "")))
            run.setdefault("gains_certified", str(getattr(gains, "certified", "")))
            run.setdefault("rho_delay_free", repr(float(getattr(gains, "rho", math.nan))))
        return cls(
            path,
            scenario_metadata=scenario_metadata(scenario),
            matrices=run_matrices(scenario, gains),
            family=family,
            trial=trial,
            seed=seed,
            sample_period=scenario.sample_period,
            steps=scenario.steps if steps is None else steps,
            run_metadata=run,
            **options,
        )

    # -- kernel observer hooks ----------------------------------------------------

    def on_plant(self, k: int, state: np.ndarray, measurements: Sequence[np.ndarray]) -> None:
        """Record x_k on ``/plant/state`` and each y^i_k on ``/sensor_<i>/measurement``."""
        self._check_open()
        k = int(k)
        due = k > 0 and (
            k % self.flush_every == 0
            or (self.flush_seconds is not None
                and time.monotonic() - self._last_flush >= self.flush_seconds)
        )
        if self._steps is not None:
            self._steps.plant(k, state, measurements)
            current = self._steps.current
            assert current is not None  # plant() opens step k
            self._state = current.state
            self._state_step = self.last_step = k
            if due:  # the steps before k are complete: write them as a chunk
                self.flush()
            return
        if due:
            self.flush()
        t = k * self.sample_period
        ns = self._ns(t)
        self._state = np.array(state, dtype=float).ravel()
        self._state_step = k
        self.last_step = k
        c = self._classes
        self._write(plant_topic(), "PlantState",
                    c["PlantState"](step=k, time=t, state=self._state.tolist()), ns, ns, k)
        for i, y in enumerate(measurements):
            msg = c["Measurement"](step=k, time=t, sensor=i,
                                   values=np.asarray(y, dtype=float).ravel().tolist())
            self._write(sensor_topic(i), "Measurement", msg, ns, ns, k)

    def on_update(self, agent: int, k: int, estimate: np.ndarray,
                  delays: Mapping[int, int]) -> None:
        """Record agent i's estimate (``/agent_<i>/estimate``) and the effective
        delays r_ij[k] and time-stamps s_j = k - 1 - r_ij[k] it used
        (``/agent_<i>/update``; r = -1 means i substituted its own estimate)."""
        self._check_open()
        agent, k = int(agent), int(k)
        x_hat = np.asarray(estimate, dtype=float).ravel()
        error = sq = None
        if self._state is not None and self._state_step == k:
            error = x_hat - self._state
            sq = float(np.einsum("i,i->", error, error))
        norm = math.nan if sq is None or not sq >= 0 else math.sqrt(sq)
        if self._steps is not None:
            self._steps.update(agent, k, x_hat, delays, norm)
            return
        t = k * self.sample_period
        ns = self._ns(t)
        c = self._classes
        fields: dict[str, Any] = (  # NaN: no true state for this step (never in the kernel)
            {"error": [math.nan] * x_hat.size, "squared_error": math.nan} if error is None
            else {"error": error.tolist(), "squared_error": sq})
        fields["error_norm"] = norm
        self._write(estimate_topic(agent), "Estimate",
                    c["Estimate"](step=k, time=t, agent=agent, estimate=x_hat.tolist(),
                                  **fields), ns, ns, k)
        neighbours = sorted(int(j) for j in delays)
        steps = [int(delays[j]) for j in neighbours]
        used = [float(k - 1 - d) if d >= 0 else -1.0 for d in steps]
        r = [float(d) for d in steps]
        self._write(update_topic(agent), "EstimatorUpdate",
                    c["EstimatorUpdate"](step=k, time=t, agent=agent, neighbours=neighbours,
                                         effective_delay=r, used_timestamp=used), ns, ns, k)

    def on_freshness(self, agent: int, k: int, freshness: Any, adopted_from: Any,
                     substate_dims: Any) -> None:
        """Record an AoI agent's freshness indices (``/agent_<i>/freshness``).

        ``freshness[j]`` is the age of agent i's information on substate j relative
        to its source (-1 for the dummy value omega), ``adopted_from[j]`` the
        neighbour whose estimate it adopted (-1: own update or open loop)."""
        self._check_open()
        agent, k = int(agent), int(k)
        t = k * self.sample_period
        ns = self._ns(t)
        index = [int(v) for v in freshness]
        dims = [int(d) for d in substate_dims]
        live = [v for v, d in zip(index, dims, strict=False) if d > 0]
        max_index = -1 if any(v < 0 for v in live) or not live else max(live)
        if self._steps is not None:
            self._steps.freshness(agent, k, index, [int(v) for v in adopted_from], dims,
                                  max_index)
            return
        self._write(freshness_topic(agent), "Freshness",
                    self._classes["Freshness"](
                        step=k, time=t, agent=agent, index=[float(v) for v in index],
                        adopted_from=[float(int(v)) for v in adopted_from],
                        substate_dim=[float(d) for d in dims], max_index=max_index), ns, ns, k)

    def on_clock(self, agent: int, sample: int, true_time: float, local_time: float,
                 sent: bool) -> None:
        """Record a sample of agent i on its own clock (``/agent_<i>/clock``; scenarios
        with a ``[time]`` table, :mod:`netsim.timedkernel`): its true time (log_time),
        the agent's clock reading (the stamp on what it sends) and whether its trigger
        sent the new estimate. Format 2 only."""
        self._check_open()
        if self._steps is not None:
            raise ValueError("trace format 3 does not record agent clocks ([time] "
                             "scenarios); use trace format 2")
        t = float(true_time)
        ns = self._ns(t)
        step = max(0, int(math.floor(t / self.sample_period + 1e-9)))
        self._write(clock_topic(agent), "AgentClock",
                    self._classes["AgentClock"](step=step, time=t, agent=int(agent),
                                                sample=int(sample),
                                                local_time=float(local_time),
                                                sent=int(bool(sent))), ns, ns, int(sample))

    def on_sent(self, message: Any) -> None:
        """Record a message leaving its sender (log_time = send time)."""
        self._check_open()
        if self._steps is not None:
            self._steps.sent(message)
            return
        self._link_event(message, "sent", message.send_time, payload=self.record_payloads)

    def on_delivered(self, message: Any, accepted: bool) -> None:
        """Record a delivery (log_time = arrival time); ``accepted``: the receiver kept
        it (False: stale under the freshest-message rule)."""
        self._check_open()
        self.max_delay_steps = max(self.max_delay_steps, int(message.delay_steps))
        if self._steps is not None:
            self._steps.delivered(message, accepted)
            return
        self._link_event(message, "delivered", message.arrival_time, accepted=bool(accepted))

    def on_dropped(self, message: Any, reason: str = "", drop_time: float | None = None) -> None:
        """Record a lost message (log_time = ``drop_time``, default its send time)."""
        self._check_open()
        when = message.send_time if drop_time is None else drop_time
        if self._steps is not None:
            self._steps.dropped(message, self._drop_code(str(reason)), float(when))
            return
        self._link_event(message, "dropped", when, reason=str(reason))

    # -- file management ----------------------------------------------------------

    def flush(self, wait: bool = True) -> None:
        """Close the chunk in progress and hand everything written to the OS
        (``wait=False``: chunks still compressing in the background follow later, at
        most two behind; :meth:`netsim.traces.bulkmcap.BulkMcapWriter.flush`)."""
        self._check_open()
        if self._steps is not None:
            self._steps.flush()
        self._writer.flush(wait=wait)
        self._last_flush = time.monotonic()

    def set_status(self, status: str | None = None, **info: Any) -> None:
        """Set what :meth:`close` writes as ``run_status`` (e.g. after the run returned:
        ``set_status("diverged", diverged_at=result.diverged_at)``); an exception
        leaving the context still overrides the status with interrupted/failed."""
        if status is not None:
            self._status = str(status)
        self._status_info.update({str(k): str(v) for k, v in info.items()})

    def close(self, status: str | None = None, **info: Any) -> None:
        """Write ``run_status`` and finish the file (summary, indexes, footer).

        ``status`` defaults to the one given to :meth:`set_status`, else ``complete``
        (``interrupted`` after an interruption); ``info`` adds entries to the
        ``run_status`` record. Idempotent.
        """
        if self.closed:
            return
        self.closed = True
        try:
            if status is None:
                status = self._status
            if status is None:
                status = "complete" if self.interrupted_at is None else "interrupted"
            record = {
                "status": status,
                "last_step": str(self.last_step),
                "messages": str(self.messages_written),
                "max_delay_steps": str(self.max_delay_steps),
            }
            if self.interrupted_at is not None:
                record["interrupted_at"] = str(self.interrupted_at)
            if self.expected_steps is not None:
                record["expected_steps"] = str(self.expected_steps)
                if status == "complete" and self.last_step < self.expected_steps:
                    record.setdefault("note", f"run ended at step {self.last_step} "
                                              f"of {self.expected_steps}")
            record.update(self._status_info)
            record.update({str(k): str(v) for k, v in info.items()})
            if self._steps is not None:
                self._steps.close()
                record["messages"] = str(self.messages_written)
            self._writer.flush()
            if self.drop_reasons:  # one record, the complete table
                self._writer.add_metadata(DROP_REASONS_METADATA, {
                    str(c): r for r, c in self.drop_reasons.items()})
            self._writer.add_metadata("run_status", record)
            self._writer.finish()
        finally:
            self._stream.close()

    def __enter__(self) -> TraceRecorder:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> Literal[False]:
        if self.closed:
            return False
        if exc_type is None:
            self.close()
        else:
            self.interrupted_at = self.last_step
            status = "interrupted" if issubclass(exc_type, KeyboardInterrupt) else "failed"
            reason = exc_type.__name__ + (f": {exc}" if str(exc) else "")
            self.close(status, reason=reason)
        return False

    # -- internals ----------------------------------------------------------------

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError(f"trace recorder for {self.path} is closed")

    def _ns(self, t: float) -> int:
        return self.time_origin_ns + to_ns(t)

    def _drop_code(self, reason: str) -> int:
        code = self.drop_reasons.get(reason)
        if code is None:  # a new reason (the table is written by close())
            code = self.drop_reasons[reason] = len(self.drop_reasons) + 1
        return code

    def _link_event(self, message: Any, event: str, when: float, *, payload: bool = False,
                    accepted: bool = False, reason: str = "") -> None:
        sent_step = int(message.sent_step)
        d = int(message.delay_steps)
        fields: dict[str, Any] = {
            "sender": int(message.sender),
            "receiver": int(message.receiver),
            "sent_step": sent_step,
            "usable_step": sent_step + 1 + d,
            "sequence": int(message.sequence),
            "send_time": float(message.send_time),
            "arrival_time": float(message.arrival_time),
            "delay_steps": d,
        }
        if event == "sent":
            type_name = "LinkSent"
            fields["payload"] = ([] if not payload or message.payload is None else
                                 np.asarray(message.payload, dtype=float).ravel().tolist())
        elif event == "delivered":
            type_name = "LinkDelivered"
            fields["accepted"] = int(bool(accepted))
        else:
            type_name = "LinkDropped"
            fields["reason"] = self._drop_code(reason)
            fields["drop_time"] = float(when)
        msg = self._classes[type_name](**fields)
        self._write(link_topic(message.sender, message.receiver, event), type_name, msg,
                    self._ns(when), self._ns(message.send_time), int(message.sequence))

    @property
    def writer(self) -> Writer:
        """The MCAP writer (:class:`netsim.traces.bulkmcap.BulkMcapWriter`)."""
        return self._writer

    def bulk_channels(self, type_name: str, topics: Sequence[str],
                      topic_index: np.ndarray) -> np.ndarray:
        """Channel ids of ``topics`` (shape (len(topics),), uint16), for messages of one
        type about to be written in bulk through :attr:`writer` (the vectorised engine's
        path, :func:`netsim.vectrace.write_trial`) on ``topics[topic_index]``: the
        channels in use are registered, and the messages counted as :meth:`_write`
        counts single ones."""
        self._check_open()
        ids = np.zeros(len(topics), dtype=np.uint16)
        used = np.bincount(np.asarray(topic_index, dtype=np.int64), minlength=len(topics))
        for t in np.flatnonzero(used).tolist():
            topic = topics[t]
            ids[t] = self._channel(topic, type_name)
            self.counts[topic] = self.counts.get(topic, 0) + int(used[t])
        self.messages_written += int(used.sum())
        return ids

    def _channel(self, topic: str, type_name: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf,
                schema_id=self._schema_ids[type_name],
            )
            self._channels[topic] = channel
        return channel

    def _write(self, topic: str, type_name: str, msg: Any, log_time: int,
               publish_time: int, sequence: int) -> None:
        if log_time < self._last_log_time:
            if self._last_log_time - log_time > _ORDER_SLACK_NS:
                raise TraceOrderError(
                    f"{topic}: event at {log_time} ns after one at {self._last_log_time} ns; "
                    "trace messages must be recorded in time order"
                )
            log_time = self._last_log_time
        self._last_log_time = log_time
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channel(topic, type_name)
        self._writer.add_message(
            channel_id=channel, log_time=log_time, data=msg.SerializeToString(),
            publish_time=max(self.time_origin_ns, publish_time),
            sequence=sequence & 0xFFFFFFFF,
        )
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.messages_written += 1


def _mcap_library() -> str:
    from netsim.traces.bulkmcap import LIBRARY_IDENTIFIER

    return LIBRARY_IDENTIFIER
