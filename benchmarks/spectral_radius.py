#!/usr/bin/env python
"""Spectral radius of the augmented closed loop: structured (ARPACK) vs dense eigvals.

For each total size ``D = N n (tau+1)`` (default 1,000, 5,000 and 20,000, with
``n = 5`` states and ``tau = 9``, so N = 20, 100, 400 agents) the script builds one
instance:

* a random digraph: self-loops, a directed ring (strong connectivity) and
  ``--in-degree - 1`` further random in-neighbours per agent; random
  row-stochastic weights;
* a random ``n x n`` system matrix scaled to spectral radius 1.02 (unstable);
* one output per agent, ``C_i`` a random row of ``I_n``, gain ``L_i = 0.3 C_i^T``;
* heterogeneous delays uniform in ``0..tau`` on the links (self-loops 0), with one
  link at ``tau`` so the augmentation depth is exactly ``tau + 1``;

and computes the spectral radius of the compensated augmented closed loop
(LCSYS2022 eq. 10) in one run:

* **structured**: ``netsim.models.augmented.augmented_spectral_radius(...,
  method="structured")`` (matrix-free companion operator, ARPACK), best of
  ``--repeat`` wall times (``time.perf_counter``), in this process;
* **dense**: ``numpy.linalg.eigvals`` of the dense ``D x D`` matrix from
  ``augmented_closed_loop``, in a child process (so it can be stopped after
  ``--dense-timeout`` seconds), timed around ``eigvals`` only; once with the
  default BLAS threading and once with ``OPENBLAS_NUM_THREADS=1``
  (``--dense-threads``). On a loaded machine threaded OpenBLAS can be many times
  slower than single-threaded; the ratio uses the faster of the two. Dense is
  skipped above ``--dense-max`` (default 5,000) unless ``--force-dense``.

Reported per size: the times, ``ratio = dense / structured`` and
``|rho_dense - rho_structured|``; the goal line checks ratio >= 100 and agreement
<= 1e-8 at D = 5,000. Where dense is skipped, an untimed cross-check runs ARPACK on
``M`` itself (no power ``M^q``) and reports ``|d plain|``.

Usage::

    python benchmarks/spectral_radius.py                  # D = 1000, 5000, 20000
    python benchmarks/spectral_radius.py --sizes 1000,5000 --dense-threads single
    python benchmarks/spectral_radius.py --force-dense    # also dense at 20000 (hours, ~10 GB)
    python benchmarks/spectral_radius.py --json > rho.json

Crossover mode (``--crossover``) chooses ``DENSE_SIZE_THRESHOLD``: for small instances
of the shapes ``netsim analyze`` meets -- N = 4 agents, n = 6 states, homogeneous delays
on every link (the lcsys2022-homogeneous shape; ``--crossover-shapes`` adds N = 10,
n = 3 with heterogeneous delays), tau = 0..``--crossover-tau``, compensated and
uncompensated -- it times, in this process and best of ``--repeat``,
``augmented_spectral_radius(..., method="dense")`` (single-threaded eigvals, as ``auto``
runs it) against ``method="structured"``, checks that they agree to 1e-10 and that the
structured call gave no RuntimeWarning (dense fallback), and prints per shape the
smallest size from which structured is faster at every larger size measured: the
crossover. The largest crossover over the shapes is the recommended threshold.

    python benchmarks/spectral_radius.py --crossover      # about 30 s idle
    python benchmarks/spectral_radius.py --crossover --json

Krylov reuse mode (``--krylov-reuse``, issue 34: "reuse Krylov bases across the gamma
grid"): the local gain design's grid (``LOCAL_GAMMAS``, one ARPACK radius per gamma of
the delay-free loop) on ``examples/geometric-100k.toml`` shrunk to ``--reuse-agents``
agents (default 2,000: ``N n = 12,000``, the largest size the design still searches),
three ways in one run: **cold** (each gamma from the seeded random start vector, as
:func:`netsim.models.augmented._arpack_rho` runs it), **warm-1** (ARPACK's ``v0`` = the
previous gamma's top Ritz vector, real plus imaginary part) and **warm-k** (``v0`` = the
sum of the previous gamma's ``k`` Ritz vectors). It prints per gamma the CPU seconds
(``time.process_time``), the operator applications and the radius, and the totals; the
radii must agree to 1e-12.

    python benchmarks/spectral_radius.py --krylov-reuse [--reuse-agents 2000]

Progress goes to stderr; stdout holds the table (or, with ``--json``, exactly one
JSON object and no table).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from typing import Any

import numpy as np

GOAL_SIZE = 5000
GOAL_RATIO = 100.0
GOAL_AGREEMENT = 1e-8


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def build_instance(N: int, n: int, tau: int, in_degree: int, seed: int):
    """Random instance (see the module docstring); returns P, A, C, L, delays."""
    rng = np.random.default_rng([seed, N, n, tau])
    mask = np.eye(N, dtype=bool)
    mask[np.arange(N), (np.arange(N) - 1) % N] = True  # ring i-1 -> i
    for i in range(N):
        extra = rng.choice(N, size=min(max(in_degree - 1, 0), N), replace=False)
        mask[i, extra] = True
    W = mask * rng.uniform(0.2, 1.0, (N, N))
    P = W / W.sum(axis=1, keepdims=True)
    A = rng.standard_normal((n, n))
    A *= 1.02 / np.max(np.abs(np.linalg.eigvals(A)))
    C = [np.eye(n)[[int(rng.integers(n))]] for _ in range(N)]
    L = [0.3 * Ci.T for Ci in C]
    delays = rng.integers(0, tau + 1, (N, N))
    np.fill_diagonal(delays, 0)
    delays[0, N - 1] = tau  # the ring link N-1 -> 0 carries the maximum delay
    return P, A, C, L, delays


def dense_worker(spec: dict[str, Any]) -> dict[str, Any]:
    """Child-process body: dense eigvals of the augmented closed loop."""
    from netsim.models.augmented import augmented_closed_loop

    P, A, C, L, delays = build_instance(
        spec["N"], spec["n"], spec["tau"], spec["in_degree"], spec["seed"]
    )
    t0 = time.perf_counter()
    M = augmented_closed_loop(P, A, C, L, delays, spec["tau"], compensated=True)
    t1 = time.perf_counter()
    ev = np.linalg.eigvals(M)
    t2 = time.perf_counter()
    return {"rho": float(np.max(np.abs(ev))), "build_s": t1 - t0, "eigvals_s": t2 - t1}


def run_dense(spec: dict[str, Any], threads: str, timeout: float) -> dict[str, Any]:
    """Run :func:`dense_worker` in a child process; ``threads`` is "default" or "single"."""
    env = dict(os.environ)
    if threads == "single":
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            env[var] = "1"
    cmd = [sys.executable, os.path.abspath(__file__), "--_dense-worker", json.dumps(spec)]
    try:
        out = subprocess.run(
            cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False
        )
    except subprocess.TimeoutExpired:
        return {"status": "timeout", "timeout_s": timeout}
    if out.returncode != 0:
        return {"status": "error", "stderr": out.stderr[-2000:]}
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["status"] = "ok"
    return result


def _first_row(aug, P, A, C, L, delays, tau):
    """The structured operator ``augmented_spectral_radius`` builds (compensated)."""
    G = aug._gain_blocks(L, aug._as_outputs(C))
    return aug._FirstRow(G, P, np.where(P != 0, delays, 0), aug._delay_blocks(A, tau + 1, True))


def run_structured(spec: dict[str, Any], repeat: int) -> dict[str, Any]:
    import netsim.models.augmented as aug

    P, A, C, L, delays = build_instance(
        spec["N"], spec["n"], spec["tau"], spec["in_degree"], spec["seed"]
    )
    times, rho = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        value = aug.augmented_spectral_radius(
            P, A, C, L, delays, spec["tau"], compensated=True, method="structured"
        )
        times.append(time.perf_counter() - t0)
        if rho is not None and value != rho:
            log(f"  note: structured value changed between repeats ({rho!r} -> {value!r})")
        rho = value
    # untimed cross-check that needs no dense matrix: ARPACK on M itself (no power M^q)
    saved = aug.ARPACK_POWER
    try:
        aug.ARPACK_POWER = 1
        t0 = time.perf_counter()
        rho_plain = aug._companion_rho(_first_row(aug, P, A, C, L, delays, spec["tau"]), "check")
        plain_s = time.perf_counter() - t0
    finally:
        aug.ARPACK_POWER = saved
    # diagnostics (not timed): operator representation and cyclic index
    row = _first_row(aug, P, A, C, L, delays, spec["tau"])
    p, _ = aug._cyclic_class(row)
    return {
        "rho": rho,
        "best_s": min(times),
        "times_s": times,
        "rho_plain_arpack": rho_plain,
        "plain_arpack_s": plain_s,
        "operator": row.kind,
        "cyclic_index": p,
        "first_row_nnz": int(row._S.nnz) if row.kind == "bsr" else None,
    }


def crossover_instance(shape: str, tau: int, seed: int):
    """Instance of one crossover shape at delay ``tau`` (P, A, C, L, delays)."""
    rng = np.random.default_rng([seed, tau, len(shape)])
    if shape == "homogeneous":  # lcsys2022-homogeneous's shape: N = 4, n = 6, ring + chords
        N, n = 4, 6
        mask = np.eye(N, dtype=bool) | np.roll(np.eye(N, dtype=bool), 1, axis=1)
        mask[0, 2] = mask[3, 1] = True
    else:  # "heterogeneous": N = 10, n = 3, random digraph, delays 0..tau
        N, n = 10, 3
        mask = np.eye(N, dtype=bool) | np.roll(np.eye(N, dtype=bool), 1, axis=1)
        mask |= rng.random((N, N)) < 0.2
    W = mask * rng.uniform(0.2, 1.0, (N, N))
    P = W / W.sum(axis=1, keepdims=True)
    A = rng.standard_normal((n, n))
    A *= 1.05 / np.max(np.abs(np.linalg.eigvals(A)))
    C = [np.eye(n)[[i % n]] for i in range(N)]
    L = [0.4 * Ci.T for Ci in C]
    if shape == "homogeneous":
        delays = np.full((N, N), tau)
    else:
        delays = rng.integers(0, tau + 1, (N, N))
        delays[0, N - 1] = tau
    np.fill_diagonal(delays, 0)
    return P, A, C, L, delays


def _best(fn, repeat: int) -> tuple[float, Any, int]:
    import warnings

    times, value, warned = [], None, 0
    for _ in range(repeat):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            value = fn()
            times.append(time.perf_counter() - t0)
        warned += len(caught)
    return min(times), value, warned


def run_crossover(args: argparse.Namespace) -> dict[str, Any]:
    """Dense vs structured per shape and size; the crossover sizes."""
    import netsim.models.augmented as aug

    shapes = [s.strip() for s in args.crossover_shapes.split(",") if s.strip()]
    rows: list[dict[str, Any]] = []
    crossover: dict[str, int | None] = {}
    load_start = os.getloadavg()
    for shape in shapes:
        shape_rows = []
        for tau in range(0, args.crossover_tau + 1, args.crossover_step):
            P, A, C, L, delays = crossover_instance(shape, tau, args.seed)
            D = P.shape[0] * A.shape[0] * (tau + 1)
            for comp in (True, False):
                system = (P, A, C, L, delays, tau)

                def call(method: str, system=system, comp=comp):
                    return aug.augmented_spectral_radius(*system, compensated=comp,
                                                         method=method)

                td, rd, _ = _best(lambda: call("dense"), args.repeat)
                ts, rs, warned = _best(lambda: call("structured"), args.repeat)
                row = {"shape": shape, "tau": tau, "compensated": comp, "size": D,
                       "dense_s": td, "structured_s": ts, "rho": rd,
                       "abs_diff": abs(rd - rs), "structured_warnings": warned}
                log(f"{shape} tau={tau} comp={comp} D={D}: dense {td * 1e3:.1f} ms, "
                    f"structured {ts * 1e3:.1f} ms, |drho| {abs(rd - rs):.1e}"
                    + (f", {warned} warning(s)" if warned else ""))
                shape_rows.append(row)
        rows += shape_rows
        # smallest size from which structured wins at every larger size measured
        cut = None
        for row in sorted(shape_rows, key=lambda r: r["size"], reverse=True):
            if row["structured_s"] < row["dense_s"]:
                cut = row["size"]
            else:
                break
        crossover[shape] = cut
    known = [c for c in crossover.values() if c is not None]
    return {
        "machine": {"cpu_count": os.cpu_count(), "loadavg_start": load_start,
                    "loadavg_end": os.getloadavg(), "numpy": np.__version__},
        "current_threshold": aug.DENSE_SIZE_THRESHOLD,
        "rows": rows,
        "crossover": crossover,
        "recommended_threshold": max(known) if known else None,
        "max_abs_diff": max(r["abs_diff"] for r in rows),
        "structured_warnings": sum(r["structured_warnings"] for r in rows),
    }


def print_crossover(summary: dict[str, Any]) -> None:
    head = (f"{'shape':>13} {'tau':>3} {'comp':>5} {'D':>5} {'dense ms':>9} "
            f"{'struct ms':>9} {'dense/struct':>12} {'|drho|':>8}")
    print(head)
    print("-" * len(head))
    for r in summary["rows"]:
        print(f"{r['shape']:>13} {r['tau']:>3} {str(r['compensated']):>5} {r['size']:>5} "
              f"{r['dense_s'] * 1e3:>9.2f} {r['structured_s'] * 1e3:>9.2f} "
              f"{r['dense_s'] / r['structured_s']:>12.2f} {r['abs_diff']:>8.1e}"
              + ("  (fallback warning)" if r["structured_warnings"] else ""))
    m = summary["machine"]
    print(f"\n{m['cpu_count']} CPUs; load average {m['loadavg_start'][0]:.2f} at start, "
          f"{m['loadavg_end'][0]:.2f} at end; max |drho| {summary['max_abs_diff']:.1e}; "
          f"structured fallbacks: {summary['structured_warnings']}")
    for shape, cut in summary["crossover"].items():
        print(f"crossover {shape}: structured faster from D = {cut} up")
    print(f"recommended DENSE_SIZE_THRESHOLD: below {summary['recommended_threshold']} "
          f"(current {summary['current_threshold']})")


def run_krylov_reuse(agents: int) -> dict[str, Any]:
    """ARPACK on the local design's gamma grid: cold vs warm-started (see the docstring)."""
    import time
    import tomllib

    from netsim.estimators import gains as G
    from netsim.models import augmented as aug
    from netsim.models.scenario import parse_scenario
    from scipy.sparse.linalg import LinearOperator, eigs

    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        "examples", "geometric-100k.toml")
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    scale = (data["network"]["agents"] / agents) ** 0.5  # the same mean degree
    data["network"]["agents"] = data["plant"]["sensors"] = agents
    data["network"]["radius"] *= scale
    scenario = parse_scenario(data, f"geometric-100k shrunk to {agents} agents")
    P = scenario.weights_sparse
    A = np.asarray(scenario.plant.A, dtype=float)
    C = [np.atleast_2d(np.asarray(Ci, dtype=float)) for Ci in scenario.plant.C]
    unit: dict[int, np.ndarray] = {}
    for Ci in C:
        if id(Ci) not in unit:
            unit[id(Ci)] = G._gain_from_effective(Ci.T @ np.linalg.pinv(Ci @ Ci.T), Ci)[0]
    q, k = aug.ARPACK_POWER, aug.ARPACK_K
    modes: dict[str, list[dict[str, Any]]] = {}
    for mode in ("cold", "warm-1", "warm-k"):
        previous = None
        rows = []
        for gamma in G.LOCAL_GAMMAS:
            L = [gamma * unit[id(Ci)] for Ci in C]
            row = aug._FirstRow(aug._gain_blocks(L, C), P, None, A[None])
            D = row.Nn
            count = [0]

            def apply(X: np.ndarray, row: Any = row, count: list[int] = count) -> np.ndarray:
                count[0] += 1
                return row.companion_power(X, q)

            op = LinearOperator((D, D), matvec=apply, matmat=apply, dtype=float)
            v0 = (np.random.default_rng(0).standard_normal(D) if previous is None
                  else previous)
            log(f"krylov reuse: {mode}, gamma {gamma} ...")
            start = time.process_time()
            with aug._single_threaded_blas():
                vals, vecs = eigs(op, k=k, which="LM", tol=aug.ARPACK_TOL,
                                  ncv=min(aug.ARPACK_NCV, D), v0=v0,
                                  maxiter=aug.ARPACK_MAXITER)
            cpu = time.process_time() - start
            top = int(np.argmax(np.abs(vals)))
            if mode == "warm-1":
                previous = vecs[:, top].real + vecs[:, top].imag
            elif mode == "warm-k":
                previous = (vecs.real + vecs.imag).sum(axis=1)
            rows.append({"gamma": gamma, "cpu_s": cpu, "applications": count[0],
                         "power": q, "rho": float(np.max(np.abs(vals))) ** (1.0 / q)})
        modes[mode] = rows
    cold = [r["rho"] for r in modes["cold"]]
    return {"agents": agents, "states": int(P.shape[0]) * A.shape[0], "modes": modes,
            "totals": {m: sum(r["cpu_s"] for r in rows) for m, rows in modes.items()},
            "max_abs_diff": max(abs(r["rho"] - c) for rows in modes.values()
                                for r, c in zip(rows, cold, strict=True))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Structured (ARPACK) vs dense spectral radius of the augmented closed loop.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("Usage::")[1] if __doc__ else None,
    )
    ap.add_argument(
        "--sizes",
        default="1000,5000,20000",
        help="comma-separated total sizes N n (tau+1); each must be divisible by n (tau+1)",
    )
    ap.add_argument("--n", type=int, default=5, help="states per agent (default 5)")
    ap.add_argument("--tau", type=int, default=9, help="maximum delay (default 9)")
    ap.add_argument("--in-degree", type=int, default=3, help="in-neighbours per agent (3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="structured timing: best of (3)")
    ap.add_argument(
        "--dense-max",
        type=int,
        default=5000,
        help="skip dense above this size unless --force-dense (default 5000)",
    )
    ap.add_argument("--force-dense", action="store_true", help="run dense at every size")
    ap.add_argument(
        "--dense-threads",
        choices=("both", "default", "single"),
        default="both",
        help="BLAS threading for dense: default, single (OPENBLAS_NUM_THREADS=1) or both",
    )
    ap.add_argument(
        "--dense-timeout",
        type=float,
        default=600.0,
        help="seconds before a dense child process is stopped (default 600)",
    )
    ap.add_argument("--json", action="store_true", help="print one JSON object, no table")
    ap.add_argument("--crossover", action="store_true",
                    help="measure the dense/structured crossover on small sizes instead")
    ap.add_argument("--crossover-tau", type=int, default=30,
                    help="crossover: tau = 0..this (default 30)")
    ap.add_argument("--crossover-step", type=int, default=2,
                    help="crossover: tau step (default 2)")
    ap.add_argument("--crossover-shapes", default="homogeneous,heterogeneous",
                    help="crossover shapes (homogeneous: N=4, n=6; heterogeneous: N=10, n=3)")
    ap.add_argument("--krylov-reuse", action="store_true",
                    help="measure ARPACK warm starts across the local design's gamma grid")
    ap.add_argument("--reuse-agents", type=int, default=2000,
                    help="krylov reuse: agents of the shrunk geometric example (2000)")
    ap.add_argument("--_dense-worker", dest="dense_worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.krylov_reuse:
        reuse = run_krylov_reuse(args.reuse_agents)
        if args.json:
            print(json.dumps(reuse, indent=2))
        else:
            for mode, rows in reuse["modes"].items():
                for r in rows:
                    print(f"{mode:7} gamma {r['gamma']:.1f}: {r['cpu_s']:6.3f} s CPU, "
                          f"{r['applications']:4d} applications of M^{r['power']}, "
                          f"rho {r['rho']:.15f}")
                print(f"{mode:7} total {reuse['totals'][mode]:.3f} s CPU")
            print(f"largest |rho - rho cold| {reuse['max_abs_diff']:.2e}")
        return 0

    if args.dense_worker is not None:
        print(json.dumps(dense_worker(json.loads(args.dense_worker))))
        return 0
    if args.crossover:
        summary = run_crossover(args)
        if args.json:
            print(json.dumps(summary, indent=2))
        else:
            print_crossover(summary)
        return 0

    sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    per_agent = args.n * (args.tau + 1)
    for size in sizes:
        if size % per_agent:
            ap.error(f"size {size} is not divisible by n (tau+1) = {per_agent}")
    threads = ["single", "default"] if args.dense_threads == "both" else [args.dense_threads]

    results: list[dict[str, Any]] = []
    load_start = os.getloadavg()
    for size in sizes:
        spec = {
            "N": size // per_agent,
            "n": args.n,
            "tau": args.tau,
            "in_degree": args.in_degree,
            "seed": args.seed,
        }
        log(f"D={size} (N={spec['N']}, n={args.n}, tau={args.tau}): structured ...")
        st = run_structured(spec, args.repeat)
        log(f"  structured rho={st['rho']:.15g} best {st['best_s']:.3f} s")
        log(
            f"  check: plain ARPACK on M rho={st['rho_plain_arpack']:.15g} "
            f"({st['plain_arpack_s']:.3f} s)"
        )
        dense: dict[str, Any] = {}
        if size <= args.dense_max or args.force_dense:
            for th in threads:
                log(f"  dense ({th} BLAS threads) ...")
                dense[th] = run_dense(spec, th, args.dense_timeout)
                d = dense[th]
                if d["status"] == "ok":
                    log(f"  dense {th}: rho={d['rho']:.15g} eigvals {d['eigvals_s']:.2f} s")
                else:
                    log(f"  dense {th}: {d['status']}")
        else:
            log("  dense skipped (above --dense-max; --force-dense to run it)")
        ok = {th: d for th, d in dense.items() if d["status"] == "ok"}
        row: dict[str, Any] = {"size": size, **spec, "structured": st, "dense": dense}
        if ok:
            best_th = min(ok, key=lambda th: ok[th]["eigvals_s"])
            row["dense_best"] = best_th
            row["ratio"] = ok[best_th]["eigvals_s"] / st["best_s"]
            row["abs_diff"] = max(abs(d["rho"] - st["rho"]) for d in ok.values())
        results.append(row)

    goal = next((r for r in results if r["size"] == GOAL_SIZE and "ratio" in r), None)
    summary: dict[str, Any] = {
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "loadavg_start": load_start,
            "loadavg_end": os.getloadavg(),
        },
        "config": {k: v for k, v in vars(args).items() if k != "dense_worker"},
        "results": results,
        "goal": None
        if goal is None
        else {
            "size": GOAL_SIZE,
            "ratio": goal["ratio"],
            "abs_diff": goal["abs_diff"],
            "met": bool(goal["ratio"] >= GOAL_RATIO and goal["abs_diff"] <= GOAL_AGREEMENT),
        },
    }
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0

    def fmt_dense(d: dict[str, Any] | None) -> str:
        if d is None:
            return "-"
        if d["status"] != "ok":
            return d["status"]
        return f"{d['eigvals_s']:.2f}"

    head = (
        f"{'D':>6} {'N':>4} {'n':>2} {'tau':>3} {'op':>8} {'p':>2} {'struct s':>9} "
        f"{'dense s (1 thr)':>15} {'dense s (default)':>17} {'ratio':>8} {'|drho|':>9} "
        f"{'rho':>18} {'|d plain|':>9}"
    )
    print(head)
    print("-" * len(head))
    for r in results:
        st = r["structured"]
        ratio = f"{r['ratio']:.0f}x" if "ratio" in r else "-"
        diff = f"{r['abs_diff']:.1e}" if "abs_diff" in r else "-"
        print(
            f"{r['size']:>6} {r['N']:>4} {r['n']:>2} {r['tau']:>3} {st['operator']:>8} "
            f"{st['cyclic_index']:>2} {st['best_s']:>9.3f} "
            f"{fmt_dense(r['dense'].get('single')):>15} "
            f"{fmt_dense(r['dense'].get('default')):>17} {ratio:>8} {diff:>9} "
            f"{st['rho']:>18.15f} {abs(st['rho'] - st['rho_plain_arpack']):>9.1e}"
        )
    m = summary["machine"]
    print(
        f"\n{m['cpu_count']} CPUs; load average {m['loadavg_start'][0]:.2f} at start, "
        f"{m['loadavg_end'][0]:.2f} at end. ratio = fastest dense eigvals / best structured;\n"
        "|d plain| = |rho - rho from ARPACK on M itself (no power M^q), untimed|."
    )
    if summary["goal"] is not None:
        g = summary["goal"]
        verdict = "MET" if g["met"] else "NOT MET"
        print(
            f"goal at D={GOAL_SIZE}: ratio {g['ratio']:.0f}x (>= {GOAL_RATIO:.0f}x), "
            f"|drho| {g['abs_diff']:.1e} (<= {GOAL_AGREEMENT:g}): {verdict}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
