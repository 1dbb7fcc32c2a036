#!/usr/bin/env python
"""What a per-step trace layout would cost: a measurement for issue 20's traced-run goal.

netsim's format 2 writes one message per agent and per link event (at N = 32 about 341
per step); :mod:`trace_throughput` shows that compressing and writing those records
alone costs about 3x an untraced run of the vectorised engine, so no writer of that
format reaches "traced <= 1.5x untraced". This script measures the alternative
**netsim does not write**: one message per step and kind, every agent's or link's
values in one packed array:

* ``/plant/state``: step, time, state[n];
* ``/sensors/measurement``: step, time, values[M] (all sensors' outputs stacked);
* ``/agents/estimate``: step, time, estimate[N n] (agent-major), error_norm[N];
* ``/agents/update``: step, time, effective_delay[L] (per link, ``sfixed32``);
* ``/links/sent``: step, time, delay_steps[L] (``fixed32``), arrival_time[L];
* ``/links/delivered``: step, time, link[D], sent_step[D], accepted[D] (the messages
  usable at that step; D = the most of any step, shorter steps padded with -1).

The values are the trial's own (states, estimates, measurements, the link schedule's
step delays in place of the effective delays: the same shapes and about the same
entropy); the file has the recorder's metadata and matrix attachments too, and is
written by :class:`netsim.traces.bulkmcap.BulkMcapWriter` (the recorder's zstd level,
1 MiB chunks, the bulk path's windows) with rows encoded by
:class:`netsim.traces.bulkproto.BulkEncoder`. It is a sketch of the cost, not a
format: there is no reader for it, the kernel does not write it, and padding the
delivered arrays stands in for a ragged encoding.

Timed, in ``--repeat`` interleaved rounds (best of 5 each): the untraced trial
(``run_trials``, as in :mod:`trace_throughput`), the traced trial (run_batch with
estimates + format 2 through the runner's ``_traced_trial``), and run_batch with
estimates + this sketch. Ratios are against the untraced run of the same round.

Usage::

    python benchmarks/trace_layout_sketch.py             # N = 4 and 32
    python benchmarks/trace_layout_sketch.py --sizes 32,128 --json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import warnings
from typing import Any

import numpy as np
from google.protobuf import descriptor_pb2

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import trace_throughput as tt  # noqa: E402  (the scenarios and the timing helper)

_D = descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE
_F64 = descriptor_pb2.FieldDescriptorProto.TYPE_FIXED64
_F32 = descriptor_pb2.FieldDescriptorProto.TYPE_FIXED32
_S32 = descriptor_pb2.FieldDescriptorProto.TYPE_SFIXED32
_ONE = descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL
_MANY = descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED

#: message type -> fields (name, type, label), numbered from 1
_TYPES = {
    "StepState": [("step", _F64, _ONE), ("time", _D, _ONE), ("state", _D, _MANY)],
    "StepMeasurements": [("step", _F64, _ONE), ("time", _D, _ONE), ("values", _D, _MANY)],
    "StepEstimates": [("step", _F64, _ONE), ("time", _D, _ONE), ("estimate", _D, _MANY),
                      ("error_norm", _D, _MANY)],
    "StepUpdates": [("step", _F64, _ONE), ("time", _D, _ONE),
                    ("effective_delay", _S32, _MANY)],
    "StepSent": [("step", _F64, _ONE), ("time", _D, _ONE), ("delay_steps", _F32, _MANY),
                 ("arrival_time", _D, _MANY)],
    "StepDelivered": [("step", _F64, _ONE), ("time", _D, _ONE), ("link", _S32, _MANY),
                      ("sent_step", _S32, _MANY), ("accepted", _S32, _MANY)],
}
_TOPICS = {"StepState": "/plant/state", "StepMeasurements": "/sensors/measurement",
           "StepEstimates": "/agents/estimate", "StepUpdates": "/agents/update",
           "StepSent": "/links/sent", "StepDelivered": "/links/delivered"}

__all__ = ["step_types", "step_columns", "write_sketch", "measure", "main"]


def step_types() -> tuple[dict[str, Any], bytes]:
    """The sketch's message descriptors by name, and their FileDescriptorSet bytes."""
    return tt.declare_types("bench.perstep", _TYPES)


def step_columns(batch: Any, scenario: Any) -> dict[str, tuple[dict[str, Any], dict[str, int]]]:
    """Per type: the encoder columns (one row per step) and the repeated fields' lengths.

    ``batch``: a one-trial :func:`netsim.vectorised.run_batch` with estimates.
    """
    result = batch.results[0]
    x = np.asarray(result.states, dtype=float)
    K1 = x.shape[0]
    k = np.arange(K1)
    t = k * float(scenario.sample_period)
    est = np.asarray(result.estimates, dtype=float)  # (K+1, N, n)
    N, n = est.shape[1], est.shape[2]
    norm = np.sqrt(np.einsum("kia,kia->ki", est - x[:, None], est - x[:, None]))
    y = np.concatenate([np.asarray(m, dtype=float).reshape(K1, -1)
                        for m in result.measurements], axis=1)
    d = np.asarray(batch.schedule.delay_steps[0], dtype=np.int64)[:, :K1]  # (L, S)
    L = d.shape[0]
    steps = np.zeros((K1, L), dtype=np.int64)
    steps[:d.shape[1]] = d.T
    sent = np.broadcast_to(np.arange(d.shape[1])[None, :], d.shape)
    usable = sent + 1 + d
    keep = usable < K1
    link = np.broadcast_to(np.arange(L)[:, None], d.shape)[keep]
    s_of, u_of = sent[keep], usable[keep]
    order = np.lexsort((link, u_of))
    link, s_of, u_of = link[order], s_of[order], u_of[order]
    counts = np.bincount(u_of, minlength=K1)
    D = max(1, int(counts.max()))
    slot = np.arange(len(u_of)) - np.repeat(np.cumsum(counts) - counts, counts)
    links = np.full((K1, D), -1, dtype=np.int32)
    sent_steps = np.full((K1, D), -1, dtype=np.int32)
    links[u_of, slot], sent_steps[u_of, slot] = link, s_of
    accepted = (links >= 0).astype(np.int32)
    common = {"step": k, "time": t}
    return {
        "StepState": ({**common, "state": x}, {"state": n}),
        "StepMeasurements": ({**common, "values": y}, {"values": y.shape[1]}),
        "StepEstimates": ({**common, "estimate": est.reshape(K1, N * n), "error_norm": norm},
                          {"estimate": N * n, "error_norm": N}),
        "StepUpdates": ({**common, "effective_delay": steps.astype(np.int32)},
                        {"effective_delay": L}),
        "StepSent": ({**common, "delay_steps": steps.astype(np.uint32),
                      "arrival_time": (k[:, None] + 1 + steps) * float(scenario.sample_period)},
                     {"delay_steps": L, "arrival_time": L}),
        "StepDelivered": ({**common, "link": links, "sent_step": sent_steps,
                           "accepted": accepted},
                          {"link": D, "sent_step": D, "accepted": D}),
    }


def write_sketch(path: str, batch: Any, scenario: Any, gains: Any,
                 descriptors: dict[str, Any], fds: bytes) -> int:
    """Write the per-step sketch of the batch's trial 0 to ``path``; return its messages."""
    from netsim.traces import recorder as rec
    from netsim.traces.bulkmcap import BulkMcapWriter
    from netsim.traces.bulkproto import BulkEncoder

    columns = step_columns(batch, scenario)
    origin = rec.DEFAULT_TIME_ORIGIN_NS
    with BulkMcapWriter(path, level=rec._ZSTD_LEVEL, library="bench-perstep") as writer:
        writer.add_metadata("scenario", {str(a): str(b) for a, b in
                                         rec.scenario_metadata(scenario).items()})
        writer.add_metadata("run", {"trace_format": "bench-perstep/0"})
        for name, matrix in rec.run_matrices(scenario, gains).items():
            writer.add_attachment(0, 0, f"{name}.npy", rec.NPY_MEDIA_TYPE,
                                  rec._npy_bytes(matrix))
        packed = []
        total = 0
        for name, (cols, lengths) in columns.items():
            schema = writer.add_schema(f"bench.perstep.{name}", "protobuf", fds)
            channel = writer.add_channel(_TOPICS[name], "protobuf", schema)
            encoder = BulkEncoder(descriptors[name], lengths)
            K1 = len(cols["step"])
            log_time = (origin + np.round(cols["time"] * 1e9).astype(np.int64)).astype(
                np.uint64)
            records, starts = encoder.records(cols, channel, np.arange(K1), log_time,
                                              log_time, n=K1)
            size = 31 + encoder.payload_length
            packed.append((records, size, channel, log_time))
            total += size * K1
        K1 = len(columns["StepState"][0]["step"])
        window = max(1, int(writer.chunk_size // max(1.0, total / K1)))
        for lo in range(0, K1, window):
            hi = min(K1, lo + window)
            for records, size, channel, log_time in packed:
                writer.add_records(records[lo * size:hi * size],
                                   np.arange(hi - lo, dtype=np.int64) * size,
                                   np.full(hi - lo, channel, dtype=np.uint16),
                                   log_time[lo:hi])
            writer.flush(wait=hi >= K1)
        return K1 * len(packed)


def measure(n_agents: int, steps: int, repeat: int, folder: str) -> dict[str, Any]:
    """Untraced, traced (format 2) and sketch-traced trials, interleaved."""
    from netsim.models.seeding import child_sequence

    from netsim.runner import _traced_trial, family_of, run_trials, scenario_gains
    from netsim.vectorised import run_batch

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scenario = tt.run_scenario(n_agents)
        gains = scenario_gains(scenario)
    fam = family_of("compensated")
    seeds = [child_sequence(scenario.seed, "trial", 0)]
    descriptors, fds = step_types()
    v2 = os.path.join(folder, f"v2-{n_agents}.mcap")
    sketch = os.path.join(folder, f"sketch-{n_agents}.mcap")

    def untraced() -> None:
        run_trials(scenario, fam, gains, seeds, steps, engine="vectorised",
                   record_estimates=False, record_delays=False)

    def traced() -> None:
        batch = run_batch(scenario, fam.name, gains, seeds, steps, record_estimates=True)
        _traced_trial(scenario, fam, gains, scenario.seed, 0, steps, v2, True, None,
                      batch=batch, batch_trial=0)

    def sketched() -> None:
        batch = run_batch(scenario, fam.name, gains, seeds, steps, record_estimates=True)
        write_sketch(sketch, batch, scenario, gains, descriptors, fds)

    def fresh(path: str):
        def remove() -> None:
            if os.path.exists(path):
                os.remove(path)
        return remove

    fns = [("untraced", untraced, None), ("traced_format2", traced, fresh(v2)),
           ("traced_per_step_sketch", sketched, fresh(sketch))]
    for _, fn, setup in fns:  # warm up
        if setup:
            setup()
        fn()
    walls: dict[str, list[float]] = {name: [] for name, _, _ in fns}
    cpus: dict[str, list[float]] = {name: [] for name, _, _ in fns}
    for _ in range(repeat):
        for name, fn, setup in fns:
            walls[name].append(tt.best(fn, 5, cpus[name], setup))
    seconds = {name: min(v) for name, v in walls.items()}
    cpu = {name: min(v) for name, v in cpus.items()}
    from mcap.reader import make_reader

    counts = {}
    for name, path in (("traced_format2", v2), ("traced_per_step_sketch", sketch)):
        with open(path, "rb") as f:  # a complete, indexed MCAP with valid CRCs
            reader = make_reader(f, validate_crcs=True)
            counts[name] = sum(1 for _ in reader.iter_messages())
        counts[name + "_bytes"] = os.path.getsize(path)
    print(f"  N = {n_agents}: " + ", ".join(f"{k} {v:.4f} s" for k, v in seconds.items()),
          file=sys.stderr)
    return {"n_agents": n_agents, "steps": steps, "seconds": seconds, "cpu_seconds": cpu,
            "messages": {k: v for k, v in counts.items() if not k.endswith("_bytes")},
            "file_bytes": {k[:-6]: v for k, v in counts.items() if k.endswith("_bytes")},
            "ratio": {k: seconds[k] / seconds["untraced"] for k in seconds},
            "cpu_ratio": {k: cpu[k] / cpu["untraced"] for k in cpu}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="4,32", type=tt.size_list,
                        help="network sizes N (default 4,32)")
    parser.add_argument("--steps", type=int, default=500, help="steps (default 500)")
    parser.add_argument("--repeat", type=int, default=3, help="interleaved rounds")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)
    sizes = args.sizes
    if args.steps < 10 or args.repeat < 1:
        print("trace_layout_sketch: --steps needs >= 10, --repeat >= 1", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as folder:
        runs = [measure(n, args.steps, args.repeat, folder) for n in sizes]
    if args.json:
        print(json.dumps({"benchmark": "trace_layout_sketch", "runs": runs}))
        return 0
    print(f"one trial, {args.steps} steps, compensated, vectorised; seconds, best of "
          f"{args.repeat} interleaved rounds x 5; ratio = / untraced (CPU ratio)")
    print(f"{'N':>4} {'untraced':>9} {'format 2':>9} {'ratio':>12} {'MB':>6} "
          f"{'per-step':>9} {'ratio':>12} {'MB':>6}")
    for r in runs:
        s, q, c, b = r["seconds"], r["ratio"], r["cpu_ratio"], r["file_bytes"]
        print(f"{r['n_agents']:>4} {s['untraced']:>9.4f} {s['traced_format2']:>9.4f} "
              f"{q['traced_format2']:>5.2f} ({c['traced_format2']:.2f}) "
              f"{b['traced_format2'] / 1e6:>6.2f} {s['traced_per_step_sketch']:>9.4f} "
              f"{q['traced_per_step_sketch']:>5.2f} ({c['traced_per_step_sketch']:.2f}) "
              f"{b['traced_per_step_sketch'] / 1e6:>6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
