#!/usr/bin/env python
"""Time and peak memory of the gain designs (estimators.gains) against network size.

For each size N the script builds one problem like the LCSYS2022 example, scaled up:

* ``A`` (n x n, default n = 6): block lower-triangular with 4 irreducible diagonal
  blocks (sizes 2, 2, 1, 1 for n = 6), random entries, scaled so rho(A) = 1.04;
* one scalar output per sensor: sensor i measures one random state of block
  ``i mod 4``, so every block is measured and no sensor observes A on its own;
* a random strongly-connected digraph (``netsim.models.network.random_strongly_connected``,
  a Hamiltonian cycle plus extra edges with probability 2/(N-1): about 3
  in-neighbours per agent) with random row-stochastic weights
  (``netsim.models.network.random_weights``).

Every measurement runs in a fresh Python subprocess, so the peak resident set size
``ru_maxrss`` (``resource.getrusage``) includes the solvers' C/Rust memory, which
tracemalloc does not see. Each child gets an address-space cap (``--memory-cap-gb``)
and a wall-clock timeout (``--timeout``); hitting either is reported, not fatal.

Measured per size:

* **lmi**: ``design_gains(P, A, C, method="lmi")``: the block-diagonal LMI with
  bisection on the rate for N <= ``--bisect-max-n``, otherwise one feasibility solve
  at alpha = 1 (``bisect=False``). N n <= 60 uses the eq. (13) form with Clarabel;
  larger problems use the split form (one N n-row cone) with SCS.
* **ccl**: ``design_gains(P, A, C, method="ccl", max_iter=--ccl-max-iter)``: the
  full-Lyapunov cone-complementarity linearisation (SCS), with its time per SDP step.

Columns: the PBH observability test time, the total design time (observability
test, problem construction, compilation and all solves), solves/steps, time per
solve, peak RSS, the resulting rho(A-hat) recomputed in the child with np.kron, the
certified rate, and the solver. Progress goes to stderr; stdout holds the table
(or, with ``--json``, exactly one JSON object).

Usage::

    python benchmarks/gain_design_scaling.py                    # the default sizes
    python benchmarks/gain_design_scaling.py --lmi-sizes 10,50 --ccl-sizes 4
    python benchmarks/gain_design_scaling.py --json > gain_design.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from typing import Any

DEFAULT_LMI_SIZES = (10, 50, 100, 200)
DEFAULT_CCL_SIZES = (4, 10, 20)
GOAL_SECONDS = 300.0  # issue 3: block-diagonal design for N = 200, n = 6 within 5 minutes


# ---------------------------------------------------------------------------
# problem generator (also used in the child)
# ---------------------------------------------------------------------------


def make_problem(n_agents: int, n_states: int = 6, seed: int = 0):
    """Return ``(P, A, C)`` as described in the module docstring."""
    import numpy as np
    from netsim.models.network import random_strongly_connected, random_weights

    rng = np.random.default_rng([seed, n_agents, n_states])
    n = n_states
    if n < 4:
        raise ValueError("n_states must be >= 4 (4 irreducible blocks)")
    sizes = [n - 4 - (n - 4) // 2 + 1, (n - 4) // 2 + 1, 1, 1]  # 2, 2, 1, 1 for n = 6
    starts = np.cumsum([0, *sizes])
    A = np.zeros((n, n))
    for b, (s, e) in enumerate(zip(starts[:-1], starts[1:], strict=True)):
        A[s:e, s:e] = rng.uniform(0.5, 1.0, (e - s, e - s))
        if b:
            A[s:e, :s] = rng.uniform(-0.3, 0.3, (e - s, s)) * (rng.random((e - s, s)) < 0.5)
    A *= 1.04 / np.max(np.abs(np.linalg.eigvals(A)))
    C = []
    for i in range(n_agents):
        b = i % 4
        state = int(rng.integers(starts[b], starts[b + 1]))
        C.append(np.eye(n)[[state]])
    p_extra = min(1.0, 2.0 / max(n_agents - 1, 1))
    graph = random_strongly_connected(n_agents, p_extra, seed=seed + n_agents)
    P = random_weights(graph, seed=seed + n_agents)
    return P, A, C


# ---------------------------------------------------------------------------
# child: one measurement
# ---------------------------------------------------------------------------


def _child(spec: dict[str, Any]) -> dict[str, Any]:
    import numpy as np
    from netsim.estimators.gains import GainDesignError, design_gains
    from netsim.models.observability import distributed_observability
    from scipy.linalg import block_diag

    N, n = spec["N"], spec["n"]
    P, A, C = make_problem(N, n, spec["seed"])
    in_deg = float(np.mean(np.count_nonzero(P, axis=1) - 1))
    out: dict[str, Any] = {**spec, "mean_in_degree": in_deg}
    t0 = time.perf_counter()
    ok = distributed_observability(P, A, C)
    out["observability_s"] = time.perf_counter() - t0
    out["observable"] = ok
    kwargs: dict[str, Any] = {"method": spec["method"]}
    if spec["method"] == "lmi":
        kwargs["bisect"] = spec["bisect"]
    else:
        kwargs["max_iter"] = spec["max_iter"]
    if spec.get("solver"):
        kwargs["solver"] = spec["solver"]
    t0 = time.perf_counter()
    try:
        d = design_gains(P, A, C, **kwargs)
    except GainDesignError as exc:
        out.update(result="design-error", error=str(exc))
    else:
        M = np.kron(P, A)
        KD = block_diag(*[Li @ Ci for Li, Ci in zip(d.L, C, strict=True)])
        out.update(
            result="ok",
            rho=float(np.max(np.abs(np.linalg.eigvals(M - KD @ M)))),
            rho_reported=d.rho,
            certified_rate=d.certified_rate,
            certified=d.certified,
            solver=d.solver,
            status=d.status,
            method_ran=d.method,
            iterations=d.iterations,
            message=d.message,
        )
    out["design_s"] = time.perf_counter() - t0 + out["observability_s"]
    out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def _limit_memory(cap_gb: float) -> None:
    if cap_gb > 0:
        cap = int(cap_gb * 1024**3)
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))


def _run_child(spec: dict[str, Any], timeout: float, cap_gb: float) -> dict[str, Any]:
    cmd = [sys.executable, os.path.abspath(__file__), "--child", json.dumps(spec)]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            cmd,
            capture_output=True,
            text=True,
            timeout=timeout,
            preexec_fn=lambda: _limit_memory(cap_gb),
        )
    except subprocess.TimeoutExpired:
        return {
            **spec,
            "result": "timeout",
            "design_s": time.perf_counter() - t0,
            "error": f"no result within the {timeout:g} s timeout",
        }
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode == 0 and lines:
        return json.loads(lines[-1])
    tail = (proc.stderr or "").strip().splitlines()[-3:]
    oom = any("MemoryError" in ln or "memory allocation" in ln.lower() for ln in tail) or (
        proc.returncode in (-9, 137)
    )
    return {
        **spec,
        "result": "out-of-memory" if oom else "crashed",
        "design_s": time.perf_counter() - t0,
        "error": f"exit code {proc.returncode}: " + " | ".join(tail),
    }


# ---------------------------------------------------------------------------
# driver
# ---------------------------------------------------------------------------


def _sizes(text: str) -> list[int]:
    try:
        vals = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}"
        ) from None
    if any(v < 2 for v in vals):
        raise argparse.ArgumentTypeError("network sizes must be >= 2")
    return vals


def _fmt(v: Any, spec: str = ".3g") -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def _table(rows: list[dict[str, Any]]) -> str:
    head = (
        f"{'design':<5} {'N':>4} {'N n':>5} {'run':<10} {'obs s':>7} {'total s':>8} "
        f"{'solves':>6} {'s/solve':>8} {'RSS MB':>7} {'rho':>8} {'cert rate':>9}  "
        f"{'solver':<8} result"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        run = (
            ("bisection" if r.get("bisect") else "alpha=1")
            if r["method"] == "lmi"
            else (f"<= {r['max_iter']} steps")
        )
        its = r.get("iterations")
        per = r["design_s"] / its if its else None
        res = r["result"] if r["result"] == "ok" else f"{r['result']}: {r.get('error', '')[:70]}"
        lines.append(
            f"{r['method']:<5} {r['N']:>4} {r['N'] * r['n']:>5} {run:<10} "
            f"{_fmt(r.get('observability_s'), '.2f'):>7} {_fmt(r.get('design_s'), '.1f'):>8} "
            f"{_fmt(its):>6} {_fmt(per, '.2f'):>8} {_fmt(r.get('maxrss_mb'), '.0f'):>7} "
            f"{_fmt(r.get('rho'), '.4f'):>8} {_fmt(r.get('certified_rate'), '.4f'):>9}  "
            f"{_fmt(r.get('solver')):<8} {res}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=(
            "Time and peak memory (fresh subprocess, ru_maxrss) of the block-diagonal LMI "
            "and the full-Lyapunov CCL gain designs against the number of sensors N."
        )
    )
    parser.add_argument(
        "--lmi-sizes",
        type=_sizes,
        default=list(DEFAULT_LMI_SIZES),
        help="N for the block-diagonal LMI (default 10,50,100,200)",
    )
    parser.add_argument(
        "--ccl-sizes",
        type=_sizes,
        default=list(DEFAULT_CCL_SIZES),
        help="N for the CCL design (default 4,10,20); empty string: none",
    )
    parser.add_argument("--n", type=int, default=6, help="plant order n (default 6, >= 4)")
    parser.add_argument("--seed", type=int, default=0, help="problem seed (default 0)")
    parser.add_argument(
        "--bisect-max-n",
        type=int,
        default=10,
        help="bisect the LMI rate for N up to this; larger N: one solve at alpha = 1 (default 10)",
    )
    parser.add_argument(
        "--ccl-max-iter",
        type=int,
        default=20,
        help="CCL linearisation steps (SDP solves) per design (default 20)",
    )
    parser.add_argument("--solver", default=None, help="force a cvxpy solver for every run")
    parser.add_argument(
        "--timeout",
        type=float,
        default=900.0,
        help="wall-clock limit per measurement in seconds (default 900)",
    )
    parser.add_argument(
        "--memory-cap-gb",
        type=float,
        default=12.0,
        help="address-space cap per child in GB, 0 for none (default 12)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object, no table")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.child:
        sys.stdout.write(json.dumps(_child(json.loads(args.child))) + "\n")
        return 0
    if args.n < 4:
        parser.error("--n must be >= 4")

    specs: list[dict[str, Any]] = []
    for N in args.lmi_sizes:
        specs.append(
            {
                "method": "lmi",
                "N": N,
                "n": args.n,
                "seed": args.seed,
                "bisect": N <= args.bisect_max_n,
                "solver": args.solver,
            }
        )
    for N in args.ccl_sizes:
        specs.append(
            {
                "method": "ccl",
                "N": N,
                "n": args.n,
                "seed": args.seed,
                "max_iter": args.ccl_max_iter,
                "solver": args.solver,
            }
        )
    rows = []
    for spec in specs:
        print(
            f"[gain_design_scaling] {spec['method']} N={spec['N']} ...", file=sys.stderr, flush=True
        )
        row = _run_child(spec, args.timeout, args.memory_cap_gb)
        print(
            f"[gain_design_scaling]   {row['result']} in {row.get('design_s', 0):.1f} s",
            file=sys.stderr,
            flush=True,
        )
        rows.append(row)

    goal = next((r for r in rows if r["method"] == "lmi" and r["N"] == 200 and r["n"] == 6), None)
    summary = {
        "goal": "block-diagonal design for N = 200, n = 6 within 300 s",
        "goal_met": None
        if goal is None
        else bool(goal["result"] == "ok" and goal["design_s"] <= GOAL_SECONDS),
    }
    if args.json:
        json.dump(
            {
                "benchmark": "gain_design_scaling",
                "python": platform.python_version(),
                "machine": platform.machine(),
                "cpus": os.cpu_count(),
                "settings": {k: v for k, v in vars(args).items() if k not in ("json", "child")},
                "runs": rows,
                **summary,
            },
            sys.stdout,
            indent=2,
        )
        sys.stdout.write("\n")
        return 0
    print(_table(rows))
    if goal is not None:
        print(
            f"\nissue 3 goal ({summary['goal']}): "
            + ("met" if summary["goal_met"] else "NOT met")
            + f" ({goal['result']}, {goal['design_s']:.0f} s)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
