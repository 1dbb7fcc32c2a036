#!/usr/bin/env python
"""Issue 32's curves on the LCSYS2022 plant: MSE against clock offset and drift, and
MSE and message rate against the send-on-delta threshold.

Base scenario: ``lcsys2022-heterogeneous`` (n = 6, rho(A) = 1.04, N = 4 on the cycle,
fixed heterogeneous delays in 0..3 steps, LMI gains). Every point runs on the timed
event kernel (``netsim.timedkernel``, the reference) and, where it can express the
point, on the vectorised engine too (``netsim.timedlockstep``: fixed clocks, no
trigger -- the offset sweep, its true-clock reference and threshold 0); the others
(drifts drawn per trial, thresholds > 0) run on the kernel alone, and each row says
which (column ``engines``: ``both`` with the largest relative difference of the two
engines' MSE curves, or ``kernel``). Every point is a Monte Carlo run with the same
trial seeds, so the curves differ only by the swept setting.

* ``offset``: the agents' clock offsets o * (-1, 1, -1/2, 1/2) (o in units of T), no
  drift; compensated and uncompensated estimators. Each agent samples when its own
  clock reads m T, so an offset also moves its sampling instants; the reference row
  ``true clocks`` samples at the same true instants (phases -o_i mod T) on true clocks,
  so the difference between the two is what the wrong stamps cost.
* ``drift``: each agent's drift drawn per trial N(0, sigma^2) ppm, no offset.
* ``trigger``: send-on-delta with threshold delta, perfect clocks; the message rate is
  the estimates sent per agent and per period T.

Reported per point: the network MSE averaged over the window of steps (``--window``,
default the second half), its value at the last step, the verdict (measured: the
step model's exact analyses do not decide [time] runs) and the measured MSE growth
per step (all from the kernel's run); for the trigger also the message rate; the
engines that ran it, with each engine's seconds and, for both, the vectorised
engine's window MSE and the largest relative MSE difference. Two PNGs (offset,
trigger) are written with ``--plots DIR``.

Usage::

    python benchmarks/time_curves.py                       # about a minute
    python benchmarks/time_curves.py --trials 20 --steps 200 --plots /tmp
    python benchmarks/time_curves.py --json > curves.json

stdout holds the tables (or, with ``--json``, one JSON object); nothing is asserted.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

OFFSETS = (0.0, 0.001, 0.01, 0.03, 0.1, 0.3, 1.0)
#: Offsets of the four agents, per unit of the swept offset o.
PATTERN = (-1.0, 1.0, -0.5, 0.5)
DRIFTS = (0.0, 10.0, 100.0, 1000.0, 10000.0)
THRESHOLDS = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)


def _scenario(base: dict[str, Any], time_table: dict[str, Any]) -> Any:
    from netsim.models.scenario import parse_scenario

    data = copy.deepcopy(base)
    data["time"] = time_table
    return parse_scenario(data, "builtin:lcsys2022-heterogeneous")


def _point(scenario: Any, gains: Any, families: list[str], steps: int, trials: int,
           seed: int, window: slice) -> dict[str, Any]:
    """One point on the kernel, and on the vectorised engine where it expresses it."""
    from netsim.runner import run_monte_carlo
    from netsim.timedlockstep import lockstep_refusal

    why = lockstep_refusal(scenario)
    results, seconds = {}, {}
    for engine in ("events", "vectorised") if why is None else ("events",):
        start = time.perf_counter()
        results[engine] = run_monte_carlo(scenario, steps=steps, trials=trials, seed=seed,
                                          families=families, gains=gains, engine=engine)
        seconds[engine] = time.perf_counter() - start
    out: dict[str, Any] = {}
    for name, s in results["events"].estimators.items():
        mse = s.mse
        out[name] = {
            "window_mse": float(np.nanmean(mse[window])),
            "final_mse": float(mse[-1]),
            "verdict": s.verdict,
            "growth_per_step": float(s.growth_rate),
            "message_rate": s.message_rate,
            "send_fraction": s.send_fraction,
            "engines": list(results),
            "seconds": seconds,
            **({"kernel_only": why} if why is not None else {}),
        }
        if "vectorised" in results:
            other = results["vectorised"].estimators[name].mse
            scale = np.maximum(np.abs(mse), np.finfo(float).tiny)
            with np.errstate(invalid="ignore"):
                rel = np.abs(other - mse) / scale
            out[name]["vectorised_window_mse"] = float(np.nanmean(other[window]))
            out[name]["max_relative_difference"] = float(np.nanmax(rel, initial=0.0))
    return out


def _engines(row: dict[str, Any]) -> str:
    """``both <largest relative difference>`` or ``kernel``."""
    if "max_relative_difference" not in row:
        return "kernel"
    return f"both {row['max_relative_difference']:.0e}"


def run(trials: int, steps: int, seed: int, window_from: int | None) -> dict[str, Any]:
    """All three sweeps; returns a JSON-ready dict."""
    from netsim.models.scenario import builtin_scenarios, read_scenario_data

    from netsim.runner import scenario_gains

    base = read_scenario_data(builtin_scenarios()["lcsys2022-heterogeneous"])
    start = steps // 2 if window_from is None else window_from
    window = slice(start, steps + 1)
    gains = scenario_gains(_scenario(base, {}))
    both = ["compensated", "uncompensated"]
    report: dict[str, Any] = {"scenario": "lcsys2022-heterogeneous", "trials": trials,
                              "steps": steps, "seed": seed, "window": [start, steps],
                              "engine": "events, and vectorised (netsim.timedlockstep) "
                                        "where it expresses the point",
                              "offset": [], "drift": [], "trigger": []}
    for o in OFFSETS:
        offsets = [o * p for p in PATTERN]
        table = {"offset": offsets} if o else {}
        point = _point(_scenario(base, table), gains, both, steps, trials, seed, window)
        phases = [(-x) % 1.0 for x in offsets]  # the same sampling instants, true clocks
        reference = _point(_scenario(base, {"phases": phases} if o else {}), gains,
                           ["compensated"], steps, trials, seed, window)
        report["offset"].append({"offset": o, **point,
                                 "true_clocks": reference["compensated"]})
        print(f"offset {o:g}: done", file=sys.stderr)
    for d in DRIFTS:
        table = {"drift_ppm": {"distribution": "normal", "std": d}} if d else {}
        point = _point(_scenario(base, table), gains, both, steps, trials, seed, window)
        report["drift"].append({"drift_ppm_std": d, **point})
        print(f"drift {d:g} ppm: done", file=sys.stderr)
    for delta in THRESHOLDS:
        table = {"trigger": {"kind": "send-on-delta", "threshold": delta}}
        point = _point(_scenario(base, table), gains, ["compensated"], steps, trials,
                       seed, window)
        report["trigger"].append({"threshold": delta, **point})
        print(f"threshold {delta:g}: done", file=sys.stderr)
    return report


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.4g}" if math.isfinite(x) else str(x)
    return str(x)


def tables(report: dict[str, Any]) -> str:
    """The three sweeps as text tables."""
    lines = [f"{report['scenario']}: {report['trials']} trials x {report['steps']} steps, "
             f"seed {report['seed']}, MSE averaged over steps {report['window'][0]}.."
             f"{report['window'][1]}; engine {report['engine']}"]
    for key, label in (("offset", "offset o (T)"), ("drift", "drift std (ppm)")):
        lines.append("")
        extra = f"  {'true clocks MSE':>16} {'verdict':>10}" if key == "offset" else ""
        lines.append(f"{label:>16}  {'compensated MSE':>16} {'verdict':>10} {'growth':>8}"
                     f"  {'uncompensated MSE':>18} {'verdict':>10} {'growth':>8}{extra}"
                     f"  {'engines':>10}")
        for row in report[key]:
            c, u = row["compensated"], row["uncompensated"]
            x = row.get("offset", row.get("drift_ppm_std"))
            ref = row.get("true_clocks")
            tail = (f"  {_fmt(ref['window_mse']):>16} {ref['verdict']:>10}"
                    if ref is not None else "")
            lines.append(f"{_fmt(x):>16}  {_fmt(c['window_mse']):>16} {c['verdict']:>10} "
                         f"{_fmt(c['growth_per_step']):>8}  {_fmt(u['window_mse']):>18} "
                         f"{u['verdict']:>10} {_fmt(u['growth_per_step']):>8}{tail}"
                         f"  {_engines(c):>10}")
    lines.append("")
    lines.append(f"{'threshold':>10}  {'message rate':>12} {'sent/updates':>12} "
                 f"{'compensated MSE':>16} {'verdict':>10} {'growth':>8}  {'engines':>10}")
    for row in report["trigger"]:
        c = row["compensated"]
        lines.append(f"{_fmt(row['threshold']):>10}  {_fmt(c['message_rate']):>12} "
                     f"{_fmt(c['send_fraction']):>12} {_fmt(c['window_mse']):>16} "
                     f"{c['verdict']:>10} {_fmt(c['growth_per_step']):>8}  {_engines(c):>10}")
    points = [r["compensated"] for k in ("offset", "drift", "trigger") for r in report[k]]
    points += [r["true_clocks"] for r in report["offset"]]
    kernel = sum(p["seconds"]["events"] for p in points if "vectorised" in p["seconds"])
    lockstep = sum(p["seconds"]["vectorised"] for p in points if "vectorised" in p["seconds"])
    reasons = sorted({p["kernel_only"] for p in points if "kernel_only" in p})
    lines.append("")
    if lockstep > 0:
        lines.append(f"points on both engines: kernel {kernel:.1f} s, vectorised "
                     f"{lockstep:.1f} s ({kernel / lockstep:.1f}x)")
    lines += [f"kernel only: {why}" for why in reasons]
    return "\n".join(lines)


def plots(report: dict[str, Any], folder: Path) -> list[str]:
    """Two PNGs: compensated MSE against offset; MSE against message rate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    fig, ax = plt.subplots(figsize=(6, 4))
    rows = report["offset"]
    xs = [max(r["offset"], 1e-4) for r in rows]
    for family, marker in (("compensated", "o"), ("uncompensated", "s")):
        ax.loglog(xs, [r[family]["window_mse"] for r in rows], marker=marker, label=family)
    ax.loglog(xs, [r["true_clocks"]["window_mse"] for r in rows], marker="^",
              linestyle="--", label="compensated, true clocks, same sampling instants")
    ax.set_xlabel("clock offset o (offsets o x (-1, 1, -1/2, 1/2); 0 drawn at 1e-4)")
    ax.set_ylabel(f"network MSE, steps {report['window'][0]}..{report['window'][1]}")
    ax.set_title("LCSYS2022 plant: MSE against clock offset")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    path = folder / "time-mse-vs-offset.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    written.append(str(path))
    fig, ax = plt.subplots(figsize=(6, 4))
    rows = report["trigger"]
    rate = [r["compensated"]["message_rate"] for r in rows]
    mse = [r["compensated"]["window_mse"] for r in rows]
    ax.semilogy(rate, mse, marker="o")
    for r, x, y in zip(rows, rate, mse, strict=True):
        ax.annotate(f"{r['threshold']:g}", (x, y), textcoords="offset points", xytext=(4, 4),
                    fontsize=8)
    ax.set_xlabel("message rate (estimates sent per agent per T)")
    ax.set_ylabel(f"network MSE, steps {report['window'][0]}..{report['window'][1]}")
    ax.set_title("send-on-delta: MSE against message rate (threshold labelled)",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    path = folder / "time-mse-vs-message-rate.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    written.append(str(path))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--seed", type=int, default=2022)
    parser.add_argument("--window-from", type=int, default=None,
                        help="first step of the MSE window (default steps // 2)")
    parser.add_argument("--plots", type=Path, default=None, help="folder for the PNGs")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)
    report = run(args.trials, args.steps, args.seed, args.window_from)
    if args.plots is not None:
        report["plots"] = plots(report, args.plots)
    if args.json:
        print(json.dumps(report))
    else:
        print(tables(report))
        for p in report.get("plots", []):
            print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
