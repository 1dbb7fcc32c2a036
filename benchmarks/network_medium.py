#!/usr/bin/env python
"""The network layer (issue 33): closed forms, a shared medium's delays, MSE vs N, events/s.

Parts (``--parts``, default all):

* ``closed-forms``: each MAC model's closed-form check with larger samples than the tests
  (tests/test_medium.py): M/D/1 mean wait on a point-to-point link (Pollaczek-Khinchine),
  TDMA's worst case F + C + propagation, slotted ALOHA's S = N p (1 - p)^(N-1) ~ G e^(-G),
  CAN worst-case response times (response-time analysis) against the critical-instant
  simulation, CSMA/CA's first-transmission collision probability; closed form, simulated
  value and its standard error.
* ``delays``: the delay distribution of a scenario's medium (default
  examples/csma-32.toml): per-message latency quantiles (ms and sampling periods), step
  delays d, the drop reasons, over the first ``--trials`` trial seeds of the run.
* ``mse``: MSE of each estimator family against N (agents on one shared medium, the
  expected in-degree kept at the scenario's) and against the message size (payload bytes
  at the scenario's N): the tail MSE (mean over the second half of the steps and the
  trials), the fraction of messages lost and the mean latency of those delivered.
* ``events``: SimPy events per CPU second of the network layer (the scenario's medium
  under its message schedule) against bare SimPy (one process yielding as many
  timeouts), both timed with ``time.process_time`` (CPU, not wall time: the machine may
  be loaded).

Usage::

    .venv/bin/python benchmarks/network_medium.py                     # everything
    .venv/bin/python benchmarks/network_medium.py --parts mse --agents 8 16 32 48
    .venv/bin/python benchmarks/network_medium.py --json > medium.json
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

__all__ = ["closed_forms", "delay_distribution", "mse_table", "events_per_second", "main"]

FAMILIES = ["compensated", "uncompensated", "kcf", "ci", "diffkf", "local-kf",
            "centralized-kf"]


def closed_forms() -> list[dict[str, Any]]:
    """Closed form vs simulation for every MAC model (larger samples than the tests)."""
    from netsim.models.medium import can_frame_bits

    from netsim.medium import Packet, poisson_source
    from tests.test_medium import (
        _batch_se,
        _can_critical_offsets,
        _can_periodic,
        _can_rta,
        _first_collision_probability,
        _first_transmission_collisions,
        _medium,
    )

    rows = []
    for rho in (0.5, 0.8, 0.9):
        env, med, rec = _medium("point-to-point", 2, [[1], []], bit_rate=1000.0, queue=10**6)
        env.process(poisson_source(env, med, 0, (1,), rho, 1000.0, np.random.default_rng(1)))
        env.run(until=200000.0)
        b = rec.background_arrays()
        w = (b["done"] - b["created"] - 1.0)[2000:]
        rows.append({"model": "point-to-point", "check": f"M/D/1 mean wait, rho = {rho}",
                     "closed_form": rho / (2 * (1 - rho)), "simulated": float(w.mean()),
                     "se": _batch_se(w), "samples": int(w.size)})
    N = 8
    env, med, rec = _medium("tdma", N, [[1]] * N, bit_rate=1e5, header_bytes=10,
                            propagation=1e-4)
    F, C = med.frame, 8 * 18 / 1e5
    K = 2000
    rng = np.random.default_rng(2)
    phases = rng.uniform(0, F, K)

    def source():
        for k in range(K):
            yield env.timeout(2 * k * F + phases[k] - env.now)
            med.submit(Packet(3, (0,), -1, env.now, 8 * 18))

    env.process(source())
    env.run(until=2 * K * F + 3 * F)
    b = rec.background_arrays()
    d = b["done"] - b["created"]
    rows.append({"model": "tdma", "check": "worst-case delay F + C + prop (sup)",
                 "closed_form": F + C + 1e-4, "simulated": float(d.max()), "se": 0.0,
                 "samples": int(d.size)})
    for G in (0.5, 1.0, 2.0):
        n, slots = 200, 20000
        env, med, rec = _medium("aloha", n, [[0]] * n, seed=int(10 * G), p=G / n, queue=10**6,
                                bit_rate=1e3, header_bytes=0, payload_bytes=1)
        for i in range(n):
            for _ in range(int(3 * slots / n) + 10):
                med.submit(Packet(i, (0 if i else 1,), -1, 0.0, 8.0))
        env.run(until=slots * med.slot - 1e-9)
        S = med.stats["successes"] / med.stats["slots"]
        exact = G * (1 - G / n) ** (n - 1)
        rows.append({"model": "aloha", "check": f"throughput S at G = {G} (N = {n})",
                     "closed_form": G * math.exp(-G), "closed_form_finite_n": exact,
                     "simulated": S, "se": math.sqrt(exact * (1 - exact) / slots),
                     "samples": slots})
    rate, tau = 500e3, 2e-6
    data, T = [2, 4, 8, 8], [1.0e-3, 1.5e-3, 2.5e-3, 4.0e-3]
    Cs = [can_frame_bits(s) * tau for s in data]
    R = _can_rta(Cs, T, tau)
    for m in range(4):
        offsets, blocker = _can_critical_offsets(m, Cs, 1e-6)
        src, resp, created = _can_periodic(rate, data, T, offsets, 0.004)
        crit = float(resp[(src == m) & (np.abs(created - 1e-6) < 1e-12)][0])
        crit += 1e-6 if blocker is not None else 0.0
        worst = 0.0
        for trial in range(20):
            offs = list(np.random.default_rng(trial).uniform(0, 2e-3, 4))
            s2, r2, _ = _can_periodic(rate, data, T, offs, 0.2, seed=trial)
            worst = max(worst, float(r2[s2 == m].max()))
        rows.append({"model": "can", "check": f"worst-case response R_{m} (critical instant; "
                     "max over 20 random phasings)", "closed_form": R[m], "simulated": crit,
                     "random_phase_max": worst, "se": 0.0, "samples": 1})
    for n in (2, 4, 8):
        bursts = 4000
        hit = _first_transmission_collisions(n, bursts, seed=n)
        p = _first_collision_probability(n, 8)
        rows.append({"model": "csma", "check": f"P(first transmission collides), {n} nodes",
                     "closed_form": p, "simulated": hit / bursts,
                     "se": math.sqrt(p * (1 - p) / bursts), "samples": bursts})
    return rows


def _load(path: Path) -> dict[str, Any]:
    return tomllib.loads(path.read_text(encoding="utf-8"))


def delay_distribution(path: Path, trials: int, steps: int | None) -> dict[str, Any]:
    """Latencies and drops of a scenario's medium over its first ``trials`` trial seeds."""
    from netsim.models.delays import latency_to_steps
    from netsim.models.scenario import load_scenario
    from netsim.models.seeding import child_sequence

    from netsim.medium import MediumRun

    s = load_scenario(path)
    K = s.steps if steps is None else steps
    lat, reasons, sent = [], {}, 0
    for t in range(trials):
        run = MediumRun(s.medium, s.links, s.sample_period, child_sequence(s.seed, "trial", t))
        for k in range(K + 1):
            for j, i in s.links:
                o = run.outcome(j, i, k)
                sent += 1
                if o.reason is None:
                    lat.append(o.latency)
                else:
                    reasons[o.reason] = reasons.get(o.reason, 0) + 1
    x = np.asarray(lat)
    d = np.array([latency_to_steps(v, s.sample_period) for v in x])
    qs = [0.05, 0.25, 0.5, 0.75, 0.9, 0.99, 0.999, 1.0]
    unit = float(s.medium["time_unit"])
    return {
        "scenario": str(path), "agents": s.n_agents, "links": len(s.links), "trials": trials,
        "steps": K, "sample_period": s.sample_period, "messages": sent,
        "delivered": int(x.size), "dropped": reasons,
        "drop_fraction": 1 - x.size / sent,
        "latency_ms": {f"q{q:g}": float(np.quantile(x, q) * unit * 1e3) for q in qs},
        "latency_mean_ms": float(x.mean() * unit * 1e3),
        "latency_periods": {f"q{q:g}": float(np.quantile(x, q) / s.sample_period) for q in qs},
        "step_delay_histogram": {int(v): int(c) for v, c in zip(*np.unique(d, return_counts=True),
                                                              strict=True)},
        "nominal_bound": s.delay_bound,
        "transmission_ms": s.medium.transmission_time * 1e3,
    }


def _variant(data: dict[str, Any], agents: int | None = None,
             payload: int | None = None) -> dict[str, Any]:
    out = copy.deepcopy(data)
    if agents is not None:
        degree = data["network"]["edge_probability"] * (data["network"]["agents"] - 1)
        out["plant"]["sensors"] = agents
        out["network"]["agents"] = agents
        out["network"]["edge_probability"] = min(1.0, degree / (agents - 1))
    if payload is not None:
        out["network"]["medium"]["payload_bytes"] = payload
    return out


def mse_table(path: Path, agents: list[int], payloads: list[int], families: list[str],
              steps: int, trials: int) -> dict[str, Any]:
    """Tail MSE of each family vs N and vs payload size on the scenario's medium."""
    from netsim.models.scenario import parse_scenario

    import netsim

    data = _load(path)
    rows = []
    cases = [("agents", n, _variant(data, agents=n)) for n in agents]
    cases += [("payload_bytes", p, _variant(data, payload=p)) for p in payloads]
    for axis, value, variant in cases:
        scenario = parse_scenario(variant, str(path))
        started = time.process_time()
        result = netsim.run(scenario, steps=steps, trials=trials, estimators=families)
        cpu = time.process_time() - started
        row: dict[str, Any] = {"axis": axis, "value": value, "agents": scenario.n_agents,
                               "packet_bits": scenario.medium.packet_bits, "cpu_s": cpu}
        for fam in families:
            se = result[fam].squared_errors  # (M, K+1, N)
            tail = se[:, se.shape[1] // 2:, :]
            row[fam] = float(np.nanmean(tail))
        # what the network did (the first family's drops: the same medium for all)
        first = result[families[0]]
        if first.drops is not None:
            sent = (steps + 1) * len(scenario.links) * trials
            row["drop_fraction"] = sum(len(d) for d in first.drops) / sent
        rows.append(row)
    return {"families": families, "steps": steps, "trials": trials, "rows": rows}


def events_per_second(path: Path, steps: int) -> dict[str, Any]:
    """SimPy events per CPU second: the network layer vs bare SimPy timeouts."""
    import simpy
    from netsim.models.scenario import load_scenario

    from netsim.medium import MediumRun

    s = load_scenario(path)
    run = MediumRun(s.medium, s.links, s.sample_period, 0)
    horizon = steps * s.sample_period * float(s.medium["time_unit"])
    t0 = time.process_time()
    run.run_until(horizon)
    medium_cpu = time.process_time() - t0
    events = run.events
    env = simpy.Environment()

    def bare():
        timeout = env.timeout
        for _ in range(events):
            yield timeout(1e-6)

    env.process(bare())
    t0 = time.process_time()
    env.run()
    bare_cpu = time.process_time() - t0
    packets = len(run.recorder.outcomes)
    return {"scenario": str(path), "model": s.medium.model, "steps": steps,
            "events": events, "packets_resolved": packets,
            "medium_events_per_s": events / medium_cpu, "bare_events_per_s": events / bare_cpu,
            "ratio": (medium_cpu / events) / (bare_cpu / events)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--parts", nargs="+", default=["closed-forms", "delays", "mse", "events"],
                   choices=["closed-forms", "delays", "mse", "events"])
    p.add_argument("--scenario", type=Path, default=ROOT / "examples" / "csma-32.toml")
    p.add_argument("--agents", type=int, nargs="+", default=[8, 16, 32, 48])
    p.add_argument("--payloads", type=int, nargs="+", default=[16, 48, 96])
    p.add_argument("--families", nargs="+", default=FAMILIES)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--trials", type=int, default=4)
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    a = p.parse_args(argv)
    out: dict[str, Any] = {}
    if "closed-forms" in a.parts:
        out["closed_forms"] = closed_forms()
        if not a.json:
            print("closed forms vs simulation")
            for r in out["closed_forms"]:
                extra = "".join(f", {k} {v:.6g}" for k, v in r.items()
                                if k in ("closed_form_finite_n", "random_phase_max"))
                print(f"  {r['model']:15s} {r['check']:60s} closed {r['closed_form']:.6g}  "
                      f"sim {r['simulated']:.6g} +- {r['se']:.2g}{extra}")
    if "delays" in a.parts:
        out["delays"] = delay_distribution(a.scenario, a.trials, a.steps)
        if not a.json:
            d = out["delays"]
            print(f"\ndelays of {d['scenario']}: {d['agents']} agents, {d['links']} links, "
                  f"{d['trials']} trials x {d['steps'] + 1} steps, Ts = {d['sample_period']}")
            print(f"  messages {d['messages']}, delivered {d['delivered']}, dropped "
                  f"{d['drop_fraction']:.1%}: {d['dropped']}")
            print("  latency (ms): " + ", ".join(f"{k} {v:.3g}" for k, v in
                                                d["latency_ms"].items())
                  + f"; mean {d['latency_mean_ms']:.3g}; one packet on the air "
                  f"{d['transmission_ms']:.3g} ms")
            print("  latency (Ts): " + ", ".join(f"{k} {v:.3g}" for k, v in
                                                d["latency_periods"].items()))
            print(f"  step delays d: {d['step_delay_histogram']}; nominal bound "
                  f"{d['nominal_bound']}")
    if "mse" in a.parts:
        out["mse"] = mse_table(a.scenario, a.agents, a.payloads, a.families, a.steps, a.trials)
        if not a.json:
            m = out["mse"]
            print(f"\ntail MSE (second half of {m['steps']} steps, {m['trials']} trials)")
            print("  " + f"{'axis':14s} {'value':>6s} {'bits':>6s} {'lost':>6s} "
                  + " ".join(f"{f:>14s}" for f in m["families"]) + "   cpu s")
            for r in m["rows"]:
                print(f"  {r['axis']:14s} {r['value']:6d} {r['packet_bits']:6.0f} "
                      f"{r.get('drop_fraction', float('nan')):6.1%} "
                      + " ".join(f"{r[f]:14.4g}" for f in m["families"])
                      + f"   {r['cpu_s']:.0f}")
    if "events" in a.parts:
        out["events"] = events_per_second(a.scenario, a.steps)
        if not a.json:
            e = out["events"]
            print(f"\nevents/s ({e['model']}, {e['steps']} steps, {e['events']} events, CPU "
                  f"time): network layer {e['medium_events_per_s']:,.0f}, bare SimPy "
                  f"{e['bare_events_per_s']:,.0f}; {e['ratio']:.2f}x bare's cost per event")
    if a.json:
        print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
