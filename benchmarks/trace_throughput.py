#!/usr/bin/env python
"""Throughput of trace writers: netsim's bulk and per-event MCAP writers against the
plain ``mcap_protobuf`` writer, the raw ``mcap`` writer and the zstd-plus-write floor.

For each network size N the script builds the messages of a trace of a traced run:
per step the plant state, N measurements, N estimates and N estimator updates, and per
link one ``sent`` and one ``delivered`` message (a ring plus chords, about
``--in-degree`` in-neighbours per agent; n = ``--states`` states, one output per
sensor); values are random, sizes and topics are the trace's (format 2 types of
:mod:`netsim.traces.schemas` when present, else the same shapes declared here).
Then it writes that same message set, in one process, with:

* **bulk**: :class:`netsim.traces.bulkmcap.BulkMcapWriter` fed from column arrays:
  every type's columns encoded at once straight into Message records by
  :meth:`netsim.traces.bulkproto.BulkEncoder.records` (timed), then one
  ``add_records`` call per type and window of steps (a window holds about one chunk
  of records), the chunk closed at the window's end: what the vectorised engine's
  trace path (:func:`netsim.vectrace.write_trial`) does;
* **per-event**: the same writer's ``add_message``, one call per message in time
  order, payloads pre-serialised (the event kernel's path without the protobuf
  construction);
* **mcap_protobuf**: ``mcap_protobuf.writer.Writer.write_message`` with protobuf
  message objects built beforehand (untimed): it serialises and writes;
* **raw mcap**: ``mcap.writer.Writer.add_message`` with pre-serialised bytes;
* **floor**: the bulk writer's uncompressed chunk records (built untimed), each chunk
  compressed with the same zstd compressor and level and written to a file: the cost
  no MCAP writer with this compression can go below.

A second table, **traced run**, measures what tracing adds to a run of one trial
(``compensated`` estimator, ``--run-steps`` steps, vectorised engine): the untraced
trial (``netsim.runner.run_trials``, what ``netsim run`` does without ``--trace``)
against the traced one (``run_batch(record_estimates=True)`` and the runner's
``_traced_trial``, i.e. the recorder's metadata and attachments plus
:func:`netsim.vectrace.write_trial`, what ``netsim run --trace`` does), and the traced
trial through the per-event observer replay (:func:`netsim.vectrace.replay_trial`, the
path before the bulk writer) for comparison. N = 4 is the built-in
``lcsys2022-heterogeneous`` scenario; other N a synthetic one (random digraph, mean
in-degree about 3, n = 6, asynchronous delays tau = 3, given gains K_i = 0.1 I). The
delay analytics ``netsim run`` also computes (tau*, exact spectral radius) are left
out of both sides: at N = 32 they take seconds and would hide the ratio. The three are
timed in ``--repeat`` interleaved rounds (untraced and traced best of 5 within a round,
replay once), each the best over all rounds, so that a change of the machine's load
hits all three alike (a traced run writes a new file: the previous round's is removed
untimed). Goal: traced / untraced <= 1.5.

Beside it, two floors: the trace's own records, written once more uncompressed
(``MB``), and the bare arrays of the trial (``numMB``: states, estimates and
measurements as float64, each message's step delay as int16), each compressed with
the recorder's zstd level in 1 MiB pieces and written to a file. ``1 + floor time /
untraced`` is the best ratio a traced run could reach with any writer of that content:
when it exceeds 1.5 the goal is out of reach of the writer, whatever it does.

Every writer uses 1 MiB chunks (``--chunk-size``) and zstd at ``--level``; times are the
best of ``--repeat`` runs (``time.perf_counter``, file closed and flushed to the OS
inside the timed region); messages/s = messages / time. Ratios are against the other
writers measured in the same run. Goals (issue 20): bulk >= 1,000,000 msg/s, >= 5x
mcap_protobuf, within 4x of the floor (floor / bulk >= 0.25).

Usage::

    python benchmarks/trace_throughput.py                  # N = 4 and 32
    python benchmarks/trace_throughput.py --sizes 4,32,128 --messages 300000
    python benchmarks/trace_throughput.py --json > trace.json

Progress goes to stderr; stdout holds the table (or, with ``--json``, one JSON object).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zstandard
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.writer import CompressionType
from mcap.writer import Writer as RawWriter
from mcap_protobuf.writer import Writer as ProtobufWriter
from netsim.traces.bulkmcap import BulkMcapWriter, message_records
from netsim.traces.bulkproto import BulkEncoder

_F = descriptor_pb2.FieldDescriptorProto
_D, _F64, _F32 = _F.TYPE_DOUBLE, _F.TYPE_FIXED64, _F.TYPE_FIXED32
_ONE, _MANY = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED

#: The trace's message shapes (format 2: fixed-width scalars, packed doubles).
_SHAPES = {
    "PlantState": [("step", _F64, _ONE), ("time", _D, _ONE), ("state", _D, _MANY)],
    "Measurement": [("step", _F64, _ONE), ("time", _D, _ONE), ("sensor", _F32, _ONE),
                    ("values", _D, _MANY)],
    "Estimate": [("step", _F64, _ONE), ("time", _D, _ONE), ("agent", _F32, _ONE),
                 ("estimate", _D, _MANY), ("error", _D, _MANY), ("squared_error", _D, _ONE),
                 ("error_norm", _D, _ONE)],
    "EstimatorUpdate": [("step", _F64, _ONE), ("time", _D, _ONE), ("agent", _F32, _ONE),
                        ("neighbours", _D, _MANY), ("effective_delay", _D, _MANY),
                        ("used_timestamp", _D, _MANY)],
    "LinkSent": [("sender", _F32, _ONE), ("receiver", _F32, _ONE), ("sent_step", _F64, _ONE),
                 ("usable_step", _F64, _ONE), ("sequence", _F32, _ONE),
                 ("send_time", _D, _ONE), ("arrival_time", _D, _ONE),
                 ("delay_steps", _F32, _ONE), ("payload", _D, _MANY)],
    "LinkDelivered": [("sender", _F32, _ONE), ("receiver", _F32, _ONE),
                      ("sent_step", _F64, _ONE), ("usable_step", _F64, _ONE),
                      ("sequence", _F32, _ONE), ("send_time", _D, _ONE),
                      ("arrival_time", _D, _ONE), ("delay_steps", _F32, _ONE),
                      ("accepted", _F32, _ONE)],
}


def message_types() -> tuple[dict[str, Any], bytes, str]:
    """The message classes, the FileDescriptorSet bytes and where they come from."""
    try:
        from netsim.traces import schemas

        classes = schemas.message_classes()
        if all(name in classes for name in _SHAPES):
            return ({name: classes[name] for name in _SHAPES},
                    schemas.file_descriptor_set().SerializeToString(), "netsim.traces.schemas")
    except Exception:  # noqa: BLE001 - fall back to the shapes declared here
        pass
    descriptors, fds = declare_types("bench.trace", _SHAPES)
    return ({name: message_factory.GetMessageClass(d) for name, d in descriptors.items()},
            fds, "declared in the benchmark")


def declare_types(package: str, shapes: dict[str, list[tuple[str, int, int]]]
                  ) -> tuple[dict[str, Any], bytes]:
    """proto2 message types from ``shapes`` (type -> fields (name, type, label),
    numbered from 1, repeated ones packed) in ``package``: the descriptors by name and
    the FileDescriptorSet bytes."""
    fd = descriptor_pb2.FileDescriptorProto(name=f"{package.replace('.', '/')}.proto",
                                            package=package, syntax="proto2")
    for name, fields in shapes.items():
        message = fd.message_type.add(name=name)
        for number, (field, ftype, label) in enumerate(fields, start=1):
            added = message.field.add(name=field, number=number, type=ftype, label=label)
            if label == _MANY:
                added.options.packed = True
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    fds = descriptor_pb2.FileDescriptorSet()
    fds.file.append(fd)
    return ({name: pool.FindMessageTypeByName(f"{package}.{name}") for name in shapes},
            fds.SerializeToString())


@dataclass
class Group:
    """Messages of one type: topics, per-message channel index into ``topics``, times,
    sequences and encoder columns (rows in time order)."""

    type_name: str
    topics: list[str]
    topic: np.ndarray  # (m,) index into topics
    log_time: np.ndarray  # (m,) uint64 ns
    step: np.ndarray  # (m,) the step of each message (window assignment)
    sequence: np.ndarray
    columns: dict[str, np.ndarray]
    lengths: dict[str, int]
    rank: int  # order of this type within a step


def workload(n_agents: int, steps: int, n_states: int, in_degree: int, seed: int
             ) -> list[Group]:
    """The messages of a traced run of ``steps`` steps with ``n_agents`` agents."""
    rng = np.random.default_rng(seed)
    ts_ns = 100_000_000
    N, K, n = n_agents, steps, n_states
    k = np.arange(K)
    offsets = [1] + [1 + (N // (d + 1)) for d in range(1, in_degree)]
    links = sorted({((i - o) % N, i) for i in range(N) for o in offsets[:min(in_degree,
                                                                              N - 1)]})
    in_nb = [sorted(j for j, r in links if r == i) for i in range(N)]
    deg = max(len(nb) for nb in in_nb)
    groups: list[Group] = []

    def per_step(count: int) -> tuple[np.ndarray, np.ndarray]:
        return np.repeat(k, count), np.tile(np.arange(count), K)

    states = rng.normal(size=(K, n))
    groups.append(Group("PlantState", ["/plant/state"], np.zeros(K, np.int64),
                        (k * ts_ns).astype(np.uint64), k, k.astype(np.uint32),
                        {"step": k, "time": k * 0.1, "state": states}, {"state": n}, 0))
    kk, ii = per_step(N)
    groups.append(Group("Measurement", [f"/sensor_{i}/measurement" for i in range(N)], ii,
                        (kk * ts_ns).astype(np.uint64), kk, kk.astype(np.uint32),
                        {"step": kk, "time": kk * 0.1, "sensor": ii,
                         "values": rng.normal(size=(K * N, 1))}, {"values": 1}, 1))
    estimate = rng.normal(size=(K * N, n))
    error = estimate - states[kk]
    sq = np.einsum("ij,ij->i", error, error)
    groups.append(Group("Estimate", [f"/agent_{i}/estimate" for i in range(N)], ii,
                        (kk * ts_ns).astype(np.uint64), kk, kk.astype(np.uint32),
                        {"step": kk, "time": kk * 0.1, "agent": ii, "estimate": estimate,
                         "error": error, "squared_error": sq, "error_norm": np.sqrt(sq)},
                        {"estimate": n, "error": n}, 2))
    nb = np.array([(in_nb[i] + in_nb[i][:1] * deg)[:deg] for i in range(N)], dtype=float)
    r = rng.integers(-1, 4, (K * N, deg)).astype(float)
    groups.append(Group("EstimatorUpdate", [f"/agent_{i}/update" for i in range(N)], ii,
                        (kk * ts_ns).astype(np.uint64), kk, kk.astype(np.uint32),
                        {"step": kk, "time": kk * 0.1, "agent": ii, "neighbours": nb[ii],
                         "effective_delay": r, "used_timestamp": kk[:, None] - 1 - r},
                        {"neighbours": deg, "effective_delay": deg, "used_timestamp": deg}, 3))
    L = len(links)
    kk, ll = per_step(L)
    sender = np.array([j for j, _ in links])[ll]
    receiver = np.array([i for _, i in links])[ll]
    d = rng.integers(0, 4, K * L)
    link = {"sender": sender, "receiver": receiver, "sent_step": kk, "usable_step": kk + 1 + d,
            "sequence": kk, "send_time": kk * 0.1, "arrival_time": (kk + d) * 0.1,
            "delay_steps": d}
    groups.append(Group("LinkSent", [f"/link_{j}_{i}/sent" for j, i in links], ll,
                        (kk * ts_ns).astype(np.uint64), kk, kk.astype(np.uint32),
                        dict(link, payload=estimate.reshape(K, N, n)[kk, sender]),
                        {"payload": n}, 4))
    arrive = kk + d
    keep = arrive < K
    groups.append(Group("LinkDelivered", [f"/link_{j}_{i}/delivered" for j, i in links],
                        ll[keep], (arrive[keep] * ts_ns).astype(np.uint64), arrive[keep],
                        kk[keep].astype(np.uint32),
                        {key: v[keep] for key, v in dict(link, accepted=np.ones(K * L,
                                                                           int)).items()},
                        {}, 5))
    return groups


class Prepared:
    """Channels and, for the per-message writers, every message in time order."""

    def __init__(self, groups: list[Group], classes: dict[str, Any]) -> None:
        self.groups = groups
        self.classes = classes
        self.encoders = {g.type_name: BulkEncoder(classes[g.type_name].DESCRIPTOR, g.lengths)
                         for g in groups}
        self.topics: list[str] = []
        self.topic_type: list[str] = []
        self.base: dict[str, int] = {}
        for g in groups:
            self.base[g.type_name] = len(self.topics)
            self.topics += g.topics
            self.topic_type += [g.type_name] * len(g.topics)
        rows = {g.type_name: self.encoders[g.type_name].encode(g.columns) for g in groups}
        self.rows = rows
        # all messages, time order (step, then type rank, then row order)
        channel = np.concatenate([g.topic + self.base[g.type_name] for g in groups])
        log_time = np.concatenate([g.log_time for g in groups])
        sequence = np.concatenate([g.sequence for g in groups])
        rank = np.concatenate([np.full(len(g.log_time), g.rank) for g in groups])
        which = np.concatenate([np.full(len(g.log_time), t) for t, g in enumerate(groups)])
        row = np.concatenate([np.arange(len(g.log_time)) for g in groups])
        order = np.lexsort((row, rank, log_time))
        self.channel = channel[order].tolist()
        self.log_time = log_time[order].tolist()
        self.sequence = sequence[order].tolist()
        self.payloads = [rows[groups[w].type_name][r].tobytes()
                         for w, r in zip(which[order].tolist(), row[order].tolist(),
                                         strict=True)]
        self.n = len(self.payloads)
        # protobuf objects for mcap_protobuf (parsed from the same bytes)
        self.objects = [classes[self.topic_type[c]].FromString(p)
                        for c, p in zip(self.channel, self.payloads, strict=True)]


def windows(groups: list[Group], steps: int, bytes_per_step: float, chunk_size: int
            ) -> tuple[int, dict[str, np.ndarray]]:
    """Steps per window (about one chunk) and each group's row boundaries per window."""
    per = max(1, int(chunk_size // max(bytes_per_step, 1.0)))
    edges = np.arange(0, steps + per, per)
    return per, {g.type_name: np.searchsorted(g.step, edges, side="left") for g in groups}


def write_bulk(path: str, prep: Prepared, fds: bytes, chunk_size: int, level: int,
               steps: int) -> None:
    groups = prep.groups
    with BulkMcapWriter(path, library="netsim-trace/2 bench", chunk_size=chunk_size * 2,
                        level=level) as w:
        ids = {name: w.add_schema(name, "protobuf", fds) for name in prep.classes}
        for topic, type_name in zip(prep.topics, prep.topic_type, strict=True):
            w.add_channel(topic, "protobuf", ids[type_name])
        packed = []
        for g in groups:
            encoder = prep.encoders[g.type_name]
            channel = (g.topic + prep.base[g.type_name]).astype(np.uint16)
            records, _ = encoder.records(g.columns, channel, g.sequence, g.log_time,
                                         g.log_time)
            packed.append((channel, g.log_time, records, 31 + encoder.payload_length))
        per_step = sum(r.nbytes for _, _, r, _ in packed) / steps
        _, cuts = windows(groups, steps, per_step, chunk_size)
        n_windows = len(next(iter(cuts.values()))) - 1
        for wi in range(n_windows):
            for g, (channel, log_time, records, size) in zip(groups, packed, strict=True):
                a, b = cuts[g.type_name][wi], cuts[g.type_name][wi + 1]
                if b > a:
                    w.add_records(records[a * size:b * size],
                                  np.arange(b - a, dtype=np.int64) * size, channel[a:b],
                                  log_time[a:b])
            w.flush()


def write_per_event(path: str, prep: Prepared, fds: bytes, chunk_size: int, level: int
                    ) -> None:
    with BulkMcapWriter(path, library="bench", chunk_size=chunk_size, level=level) as w:
        ids = {name: w.add_schema(name, "protobuf", fds) for name in prep.classes}
        for topic, type_name in zip(prep.topics, prep.topic_type, strict=True):
            w.add_channel(topic, "protobuf", ids[type_name])
        add = w.add_message
        for c, t, p, s in zip(prep.channel, prep.log_time, prep.payloads, prep.sequence,
                              strict=True):
            add(c, t, p, t, s)


def write_mcap_protobuf(path: str, prep: Prepared, chunk_size: int) -> None:
    with open(path, "wb") as f:
        w = ProtobufWriter(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        topics = prep.topics
        for c, t, m, s in zip(prep.channel, prep.log_time, prep.objects, prep.sequence,
                              strict=True):
            w.write_message(topics[c], m, t, t, s)
        w.finish()


def write_raw_mcap(path: str, prep: Prepared, fds: bytes, chunk_size: int) -> None:
    with open(path, "wb") as f:
        w = RawWriter(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        w.start(profile="", library="bench")
        ids = {name: w.register_schema(name, "protobuf", fds) for name in prep.classes}
        chans = [w.register_channel(topic, "protobuf", ids[t])
                 for topic, t in zip(prep.topics, prep.topic_type, strict=True)]
        add = w.add_message
        for c, t, p, s in zip(prep.channel, prep.log_time, prep.payloads, prep.sequence,
                              strict=True):
            add(chans[c], t, p, t, s)
        w.finish()


def floor_chunks(prep: Prepared, chunk_size: int) -> list[np.ndarray]:
    """The uncompressed chunk contents (message records in time order, ~chunk_size)."""
    lengths = np.array([len(p) for p in prep.payloads])
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    records, starts = message_records(np.array(prep.channel), np.array(prep.sequence),
                                      np.array(prep.log_time, dtype=np.uint64),
                                      np.array(prep.log_time, dtype=np.uint64),
                                      b"".join(prep.payloads), offsets)
    cuts = np.searchsorted(starts, np.arange(0, records.shape[0], chunk_size)[1:])
    bounds = [0] + [int(starts[c]) for c in cuts if c < len(starts)] + [records.shape[0]]
    return [records[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]


def write_floor(path: str, chunks: list[np.ndarray], level: int) -> None:
    cctx = zstandard.ZstdCompressor(level=level)
    with open(path, "wb") as f:
        for chunk in chunks:
            f.write(cctx.compress(chunk))


def best(fn: Callable[[], None], repeat: int, cpu: list[float] | None = None,
         setup: Callable[[], None] | None = None) -> float:
    """Best wall time of ``repeat`` calls (the best process CPU time goes to ``cpu``);
    ``setup`` runs untimed before each call."""
    times, cpus = [], []
    for _ in range(repeat):
        if setup is not None:
            setup()
        gc.collect()
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - start)
        cpus.append(time.process_time() - start_cpu)
    if cpu is not None:
        cpu.append(min(cpus))
    return min(times)


def measure(n_agents: int, args: argparse.Namespace, classes: dict[str, Any], fds: bytes,
            folder: str) -> dict[str, Any]:
    probe = workload(n_agents, 2, args.states, args.in_degree, args.seed)
    per_step = sum(len(g.log_time) for g in probe) / 2
    steps = max(2, int(round(args.messages / per_step)))
    groups = workload(n_agents, steps, args.states, args.in_degree, args.seed)
    prep = Prepared(groups, classes)
    chunks = floor_chunks(prep, args.chunk_size)
    path = os.path.join(folder, f"n{n_agents}.mcap")
    print(f"N = {n_agents}: {prep.n} messages ({steps} steps, {per_step:.0f} per step)",
          file=sys.stderr)
    writers = {
        "bulk": lambda: write_bulk(path + ".bulk", prep, fds, args.chunk_size, args.level,
                                   steps),
        "per-event": lambda: write_per_event(path + ".event", prep, fds, args.chunk_size,
                                             args.level),
        "mcap_protobuf": lambda: write_mcap_protobuf(path + ".pb", prep, args.chunk_size),
        "raw mcap": lambda: write_raw_mcap(path + ".raw", prep, fds, args.chunk_size),
        "floor": lambda: write_floor(path + ".floor", chunks, args.level),
    }
    seconds = {}
    for name, fn in writers.items():
        seconds[name] = best(fn, args.repeat)
        print(f"  {name}: {prep.n / seconds[name]:,.0f} msg/s", file=sys.stderr)
    rate = {name: prep.n / s for name, s in seconds.items()}
    sizes = {name: os.path.getsize(path + ext) for name, ext in
             [("bulk", ".bulk"), ("per-event", ".event"), ("mcap_protobuf", ".pb"),
              ("raw mcap", ".raw"), ("floor", ".floor")]}
    check = _check_same(path + ".bulk", path + ".raw")
    return {
        "n_agents": n_agents, "steps": steps, "messages": prep.n,
        "messages_per_step": per_step,
        "seconds": seconds, "messages_per_second": rate, "file_bytes": sizes,
        "ratios": {
            "bulk_over_mcap_protobuf": rate["bulk"] / rate["mcap_protobuf"],
            "bulk_over_raw_mcap": rate["bulk"] / rate["raw mcap"],
            "per_event_over_mcap_protobuf": rate["per-event"] / rate["mcap_protobuf"],
            "floor_over_bulk": rate["floor"] / rate["bulk"],
        },
        "goals": {
            "bulk_at_least_1M_per_s": rate["bulk"] >= 1e6,
            "bulk_at_least_5x_mcap_protobuf": rate["bulk"] >= 5 * rate["mcap_protobuf"],
            "bulk_within_4x_of_floor": rate["floor"] <= 4 * rate["bulk"],
        },
        "same_messages_as_raw_mcap": check,
    }


def _check_same(a: str, b: str) -> bool:
    """Both files hold the same messages (mcap reader, CRCs validated; log_time order)."""
    from mcap.reader import make_reader

    def read(path: str) -> list[tuple[str, int, bytes]]:
        with open(path, "rb") as f:
            return sorted((c.topic, m.log_time, m.data) for _, c, m in
                          make_reader(f, validate_crcs=True).iter_messages())

    return read(a) == read(b)


def run_scenario(n_agents: int, seed: int = 1):
    """The scenario of the traced-run table (see the module docstring)."""
    from netsim.models.scenario import parse_scenario, resolve_scenario

    if n_agents == 4:
        return resolve_scenario("lcsys2022-heterogeneous")
    n = 6
    rng = np.random.default_rng([seed, n_agents, n])
    A = rng.normal(size=(n, n))
    A /= np.max(np.abs(np.linalg.eigvals(A)))
    C = rng.normal(size=(n_agents, n))
    C /= np.linalg.norm(C, axis=1, keepdims=True)
    return parse_scenario({
        "name": f"trace-N{n_agents}", "run": {"seed": seed, "divergence_threshold": 1e12},
        "plant": {"A": A.tolist(), "C": [[row.tolist()] for row in C], "Q": 0.004,
                  "R": 0.004, "x0_cov": 1.0},
        "network": {"topology": "random", "agents": n_agents, "seed": seed,
                    "weights": "random", "edge_probability": min(1.0, 3.1 / (n_agents - 1))},
        "delays": {"model": "asynchronous", "tau": 3, "seed": seed},
        "gains": {"method": "given", "K": [(0.1 * np.eye(n)).tolist()] * n_agents},
    }, "trace_throughput")


def _recorder_level() -> int:
    from netsim.traces import recorder

    return int(recorder._ZSTD_LEVEL)


def bare_numbers(batch: Any, scenario: Any) -> bytes:
    """The least any trace of the trial must hold, as raw bytes: the states
    (K+1, n) and every agent's estimates (K+1, N, n) and measurements (K+1, M) as
    float64, and each link's per-message step delay (L, S) as int16 (fates and times
    follow from them when nothing is dropped)."""
    result = batch.results[0]
    parts = [np.ascontiguousarray(result.states, dtype=np.float64),
             np.ascontiguousarray(result.estimates, dtype=np.float64),
             np.ascontiguousarray(np.concatenate(result.measurements, axis=1),
                                  dtype=np.float64)]
    if batch.schedule is not None:
        parts.append(np.ascontiguousarray(batch.schedule.delay_steps[0], dtype=np.int16))
    return b"".join(p.tobytes() for p in parts)


def measure_run(n_agents: int, steps: int, repeat: int, folder: str) -> dict[str, Any]:
    """Untraced vs traced trial of the vectorised engine: format 3 as ``netsim run
    --trace`` writes it (uncompressed) and with zstd, format 2 (bulk), and format 2
    through the per-event observer replay."""
    import warnings

    from netsim.models.seeding import child_sequence
    from netsim.traces.recorder import TraceRecorder

    from netsim.runner import _traced_trial, family_of, run_trials, scenario_gains
    from netsim.vectorised import run_batch
    from netsim.vectrace import replay_trial

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scenario = run_scenario(n_agents)
        gains = scenario_gains(scenario)
    fam = family_of("compensated")
    seed = scenario.seed
    seeds = [child_sequence(seed, "trial", 0)]
    path = os.path.join(folder, f"run{n_agents}.mcap")

    def untraced() -> None:
        run_trials(scenario, fam, gains, seeds, steps, engine="vectorised",
                   record_estimates=False, record_delays=False)

    def fresh() -> None:
        # untimed: a traced run writes a new file (unlinking or truncating the previous
        # round's, whose pages ext4 may still be writing back, costs 0.5-2.5 ms here)
        if os.path.exists(path):
            os.remove(path)

    def traced_with(options: dict[str, Any]) -> Callable[[], None]:
        def traced() -> None:
            batch = run_batch(scenario, fam.name, gains, seeds, steps, record_estimates=True)
            _traced_trial(scenario, fam, gains, seed, 0, steps, path, True, None,
                          batch=batch, batch_trial=0, trace_options=options)
        return traced

    variants = {"traced": {"trace_format": 3},
                "traced_format3_zstd": {"trace_format": 3, "compression": "zstd"},
                "traced_format2": {"trace_format": 2}}

    def replayed() -> None:
        batch = run_batch(scenario, fam.name, gains, seeds, steps, record_estimates=True)
        with TraceRecorder.for_run(path, scenario, gains, fam.name, 0, seed=seed,
                                   steps=steps, trace_format=2) as recorder:
            replay_trial(batch, 0, scenario, fam.name, recorder)

    seconds, cpu = {}, {}
    untraced()  # warm up (imports, caches)
    sizes, messages = {}, {}
    from mcap.reader import make_reader

    for name, options in variants.items():
        fresh()
        traced_with(options)()
        sizes[name] = os.path.getsize(path)
        with open(path, "rb") as f:
            messages[name] = make_reader(
                f, validate_crcs=True).get_summary().statistics.message_count
    # the floors: what no trace of this trial can cost less than, with the recorder's
    # compression (zstd at its level, one call per chunk_size piece) and a file write
    fresh()
    batch = run_batch(scenario, fam.name, gains, seeds, steps, record_estimates=True)
    _traced_trial(scenario, fam, gains, seed, 0, steps, path, True, None, batch=batch,
                  batch_trial=0, trace_options={"trace_format": 2, "compression": "none"})
    with open(path, "rb") as f:
        uncompressed = f.read()  # format 2's records (and indexes), uncompressed
    numbers = bare_numbers(batch, scenario)
    floor_path = path + ".floor"
    level, chunk = _recorder_level(), 1024 * 1024

    def floor_of(data: bytes) -> Callable[[], None]:
        def write() -> None:
            cctx = zstandard.ZstdCompressor(level=level)
            with open(floor_path, "wb") as f:
                for at in range(0, len(data), chunk):
                    f.write(cctx.compress(data[at:at + chunk]))
        return write

    def fresh_floor() -> None:
        if os.path.exists(floor_path):
            os.remove(floor_path)

    # interleaved rounds, best of each: on a shared machine a load change then hits all
    # alike; the runs of a few hundredths of a second are repeated 5 times per round
    fns = [("untraced", untraced, 5, None)]
    fns += [(name, traced_with(options), 5, fresh) for name, options in variants.items()]
    fns += [("traced_replay", replayed, 1, fresh),
            ("trace_floor", floor_of(uncompressed), 5, fresh_floor),
            ("numbers_floor", floor_of(numbers), 5, fresh_floor)]
    spent: dict[str, list[float]] = {name: [] for name, *_ in fns}
    walls: dict[str, list[float]] = {name: [] for name, *_ in fns}
    for _ in range(repeat):
        for name, fn, inner, setup in fns:
            walls[name].append(best(fn, inner, spent[name], setup))
    for name in walls:
        seconds[name], cpu[name] = min(walls[name]), min(spent[name])
    print(f"  run N = {n_agents}: " + ", ".join(f"{k} {v:.4f} s" for k, v in seconds.items()),
          file=sys.stderr)
    ratio = {name: seconds[name] / seconds["untraced"] for name in seconds}
    return {"n_agents": n_agents, "steps": steps, "messages": messages, "file_bytes": sizes,
            "seconds": seconds, "cpu_seconds": cpu, "ratio_to_untraced": ratio,
            "traced_over_untraced": ratio["traced"],
            "traced_over_untraced_cpu": cpu["traced"] / cpu["untraced"],
            "replay_over_untraced": ratio["traced_replay"],
            "trace_bytes_uncompressed": len(uncompressed), "numbers_bytes": len(numbers),
            # a traced run costs at least untraced + floor: the best ratio reachable
            "trace_floor_ratio": 1 + seconds["trace_floor"] / seconds["untraced"],
            "numbers_floor_ratio": 1 + seconds["numbers_floor"] / seconds["untraced"],
            "goal_traced_at_most_1_5x": seconds["traced"] <= 1.5 * seconds["untraced"]}


def size_list(text: str) -> list[int]:
    """``--sizes``: comma-separated network sizes, each at least 2."""
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or min(sizes) < 2:
        raise argparse.ArgumentTypeError(f"expected integers >= 2, e.g. 4,32; got {text!r}")
    return sizes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="4,32", type=size_list,
                        help="network sizes N (default 4,32)")
    parser.add_argument("--messages", type=int, default=150_000,
                        help="messages per size (default 150000)")
    parser.add_argument("--states", type=int, default=2, help="state dimension n")
    parser.add_argument("--in-degree", type=int, default=4, help="in-neighbours per agent")
    parser.add_argument("--chunk-size", type=int, default=1024 * 1024)
    parser.add_argument("--level", type=int, default=3, help="zstd level (default 3)")
    parser.add_argument("--repeat", type=int, default=3, help="best of (default 3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--run-steps", type=int, default=500,
                        help="steps of the traced-run table (default 500; 0 skips it)")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)
    sizes = args.sizes
    if args.messages < 100 or args.repeat < 1:
        print("trace_throughput: --messages needs >= 100, --repeat >= 1", file=sys.stderr)
        return 2
    classes, fds, source = message_types()
    with tempfile.TemporaryDirectory() as folder:
        results = [measure(n, args, classes, fds, folder) for n in sizes]
        runs = ([measure_run(n, args.run_steps, args.repeat, folder) for n in sizes]
                if args.run_steps > 0 else [])
    out = {"benchmark": "trace_throughput", "python": platform.python_version(),
           "schemas": source, "chunk_size": args.chunk_size, "zstd_level": args.level,
           "repeat": args.repeat, "sizes": results, "traced_run": runs}
    if args.json:
        print(json.dumps(out))
        return 0
    names = ["bulk", "per-event", "mcap_protobuf", "raw mcap", "floor"]
    print(f"messages/s (best of {args.repeat}; zstd level {args.level}, "
          f"{args.chunk_size // 1024} KiB chunks; schemas {source})")
    print(f"{'N':>4} {'msgs':>8} " + " ".join(f"{n:>14}" for n in names)
          + f" {'bulk/pb':>8} {'bulk/raw':>8} {'floor/bulk':>10}")
    for r in results:
        rate = r["messages_per_second"]
        q = r["ratios"]
        print(f"{r['n_agents']:>4} {r['messages']:>8} "
              + " ".join(f"{rate[n]:>14,.0f}" for n in names)
              + f" {q['bulk_over_mcap_protobuf']:>8.1f} {q['bulk_over_raw_mcap']:>8.1f}"
              f" {q['floor_over_bulk']:>10.2f}")
    if runs:
        print(f"\ntraced run of one trial ({args.run_steps} steps, compensated, vectorised; "
              f"seconds, best of {args.repeat} interleaved rounds; ratio to untraced)")
        print(f"{'N':>4} {'untraced':>9} {'format 3':>9} {'ratio':>6} {'MB':>5} "
              f"{'3 + zstd':>9} {'ratio':>6} {'MB':>5} {'format 2':>9} {'ratio':>6} {'MB':>5} "
              f"{'replay':>8} {'ratio':>6} {'cpu':>5}")
        for r in runs:
            sec, q, mb = r["seconds"], r["ratio_to_untraced"], r["file_bytes"]
            cells = [f"{sec[k]:>9.4f} {q[k]:>6.2f} {mb[k] / 1e6:>5.2f}"
                     for k in ("traced", "traced_format3_zstd", "traced_format2")]
            print(f"{r['n_agents']:>4} {sec['untraced']:>9.4f} " + " ".join(cells)
                  + f" {sec['traced_replay']:>8.3f} {q['traced_replay']:>6.1f}"
                  f" {r['traced_over_untraced_cpu']:>5.2f}")
        print("format 3: what 'netsim run --trace' writes (uncompressed); cpu: the CPU-time "
              "ratio of format 3; replay: format 2 through the per-event observer calls")
        print(f"{'N':>4} {'f2 MB raw':>10} {'f2 floor':>9} {'numbers MB':>11} {'floor':>6}")
        for r in runs:
            print(f"{r['n_agents']:>4} {r['trace_bytes_uncompressed'] / 1e6:>10.2f} "
                  f"{r['trace_floor_ratio']:>9.2f} {r['numbers_bytes'] / 1e6:>11.2f} "
                  f"{r['numbers_floor_ratio']:>6.2f}")
        print("floors: 1 + (zstd at the recorder's level in 1 MiB pieces and a file write of "
              "format 2's uncompressed records / of the bare arrays: states, estimates, "
              "measurements float64, step delays int16) / untraced")
    for r in results:
        goals = ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in r["goals"].items())
        print(f"N = {r['n_agents']}: {goals}; bulk file holds the raw writer's messages: "
              f"{'yes' if r['same_messages_as_raw_mcap'] else 'NO'}")
    for r in runs:
        print(f"N = {r['n_agents']}: traced run at most 1.5x the untraced: "
              f"{'yes' if r['goal_traced_at_most_1_5x'] else 'NO'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
