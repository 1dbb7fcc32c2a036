#!/usr/bin/env python
"""netsim at scale: build, gain design and run time and peak memory per network size.

For each N (``--sizes``, default 1000,10000,100000) two fresh subprocesses run, so
each peak resident set size (``resource.getrusage(RUSAGE_SELF).ru_maxrss``) belongs to
one size and one program (the parent imports nothing heavy, so what Linux carries
over fork and exec is a few tens of MB):

* **netsim**: a scenario TOML (written before the clock starts) with the LCSYS2022
  n = 6 plant, ``plant.sensors = N`` (agent i carries sensor i mod 4), a random
  geometric graph (``network.topology = "geometric"``, radius sqrt(10 / (pi N)) for a
  mean in-degree of about 10 before the connectivity growth), random weights,
  homogeneous delays tau = 3, 100 steps, 1 trial, the compensated estimator,
  ``[gains] method = "auto"``. Timed: *build* (``load_scenario`` and the link table),
  *design* (``netsim.runner.scenario_gains`` from an empty gain cache, then again
  from the warm cache) and *run* (``netsim.runner.run_monte_carlo``, vectorised
  engine).
* **anchor**: a plain script doing the same work by hand: cKDTree pairs (the same
  radius rule), CSR random row-stochastic weights, gains L_i = 0.6 C_i^T (no design, no
  certificate), and a plain numpy lockstep of the compensating estimator (LCSYS2022
  eqs. 4-5 with one constant delay: a ring of past estimates, one sparse product per
  step). Timed: build and run.

The table reports both and their ratios (netsim / anchor). Nothing is asserted.

Usage::

    python benchmarks/scale.py                          # 1000, 10000, 100000
    python benchmarks/scale.py --sizes 1000,10000 --json

Progress goes to stderr; stdout holds the table (or, with ``--json``, one JSON object).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

A = [
    [0.90, 0.30, 0.00, 0.00, 0.00, 0.00],
    [-0.30, 0.90, 0.00, 0.00, 0.00, 0.00],
    [0.00, 0.20, 0.95, 0.20, 0.00, 0.00],
    [0.00, 0.00, -0.20, 0.95, 0.00, 0.00],
    [0.00, 0.00, 0.00, 0.00, 1.01, 0.00],
    [0.00, 0.00, 0.00, 0.00, 0.00, 1.04],
]
SENSORS = (0, 2, 4, 5)  # sensor type i mod 4 measures this state
TAU = 3
STEPS = 100


def radius(n_agents: int) -> float:
    """Radius for a mean degree of about 10 in the unit square (before growth)."""
    import math

    return math.sqrt(10.0 / (math.pi * n_agents))


def scenario_toml(n_agents: int) -> str:
    """The benchmark scenario (see examples/geometric-100k.toml for the 100k file)."""
    C = ", ".join("[[" + ", ".join("1.0" if c == s else "0.0" for c in range(6)) + "]]"
                  for s in SENSORS)
    rows = ",\n    ".join("[" + ", ".join(f"{v:.2f}" for v in row) + "]" for row in A)
    return f"""name = "scale-{n_agents}"
[run]
steps = {STEPS}
trials = 1
seed = 0
estimators = ["compensated"]
divergence_threshold = 1e150

[plant]
A = [
    {rows},
]
C = [{C}]
sensors = {n_agents}
Q = 0.004
R = 0.004

[network]
topology = "geometric"
agents = {n_agents}
radius = {radius(n_agents)!r}
weights = "random"
seed = 0

[delays]
model = "homogeneous"
tau = {TAU}

[gains]
method = "auto"
"""


def _rss_mib() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


def child_netsim(n_agents: int) -> dict:
    folder = tempfile.mkdtemp(prefix="netsim-scale-")
    path = os.path.join(folder, "scenario.toml")
    with open(path, "w") as out:
        out.write(scenario_toml(n_agents))
    os.environ["NETSIM_CACHE_DIR"] = os.path.join(folder, "cache")
    import_start = time.perf_counter()
    from netsim.models.scenario import load_scenario

    from netsim import runner

    imports = time.perf_counter() - import_start
    start = time.perf_counter()
    scenario = load_scenario(path)
    table = scenario.link_table
    build = time.perf_counter() - start
    rss_build = _rss_mib()
    start = time.perf_counter()
    gains = runner.scenario_gains(scenario)
    design = time.perf_counter() - start
    rss_design = _rss_mib()
    start = time.perf_counter()
    runner.scenario_gains(scenario)
    design_warm = time.perf_counter() - start
    start = time.perf_counter()
    result = runner.run_monte_carlo(scenario, engine="vectorised")
    run = time.perf_counter() - start
    summary = result.to_dict() if hasattr(result, "to_dict") else {}
    return {"program": "netsim", "N": n_agents, "links": len(table),
            "mean_in_degree": len(table) / n_agents, "imports_s": imports,
            "build_s": build, "design_s": design, "design_warm_s": design_warm,
            "run_s": run, "rss_after_build_mib": rss_build,
            "rss_after_design_mib": rss_design, "peak_rss_mib": _rss_mib(),
            "gain_method": gains.method, "gain_status": gains.status,
            "rho": float(gains.rho), "certified": bool(gains.certified),
            "gain_message": gains.message, "has_summary": bool(summary)}


def child_anchor(n_agents: int) -> dict:
    start = time.perf_counter()
    import numpy as np
    import scipy.sparse as sp
    from scipy.spatial import cKDTree

    imports = time.perf_counter() - start
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    points = rng.random((n_agents, 2))
    pairs = cKDTree(points).query_pairs(radius(n_agents) * 1.21, output_type="ndarray")
    i = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n_agents)])
    j = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n_agents)])
    w = rng.uniform(0.1, 1.0, size=len(i))
    P = sp.csr_array((w, (i, j)), shape=(n_agents, n_agents))
    P = sp.csr_array(sp.diags_array(1.0 / np.asarray(P.sum(axis=1)).ravel()) @ P)
    own = P.diagonal().copy()
    off = sp.csr_array(P - sp.diags_array(own))
    build = time.perf_counter() - start
    start = time.perf_counter()
    n = 6
    Amat = np.array(A)
    sensor = np.array(SENSORS)[np.arange(n_agents) % 4]
    gain = 0.6
    powers = [np.eye(n)]
    for _ in range(TAU + 1):
        powers.append(Amat @ powers[-1])
    x = rng.standard_normal(n)
    history = np.zeros((TAU + 2, n_agents, n))
    est = np.zeros((n_agents, n))
    agents = np.arange(n_agents)
    sq = np.empty(STEPS + 1)
    for k in range(STEPS + 1):
        if k == 0:
            prior = est
        elif k <= TAU:  # nothing arrived yet: the own prediction stands in
            x = Amat @ x + 0.063 * rng.standard_normal(n)
            prior = est @ Amat.T
        else:  # eq. (4): neighbours' estimates of step k - 1 - tau, A^(tau + 1)
            x = Amat @ x + 0.063 * rng.standard_normal(n)
            prior = own[:, None] * (est @ Amat.T)
            prior += (off @ history[(k - 1 - TAU) % (TAU + 2)]) @ powers[TAU + 1].T
        y = x[sensor] + 0.063 * rng.standard_normal(n_agents)
        innovation = y - prior[agents, sensor]
        est = prior.copy()
        est[agents, sensor] += gain * innovation
        history[k % (TAU + 2)] = est
        sq[k] = float(np.mean(np.sum((est - x) ** 2, axis=1)))
    run = time.perf_counter() - start
    return {"program": "anchor", "N": n_agents, "links": int(len(pairs) * 2),
            "imports_s": imports, "build_s": build, "run_s": run,
            "peak_rss_mib": _rss_mib(), "final_mse": float(sq[-1])}


def run_child(kind: str, n_agents: int) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, __file__, "--child", kind, str(n_agents)],
                          capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        return {"program": kind, "N": n_agents, "error": proc.stderr.strip()[-2000:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1000,10000,100000",
                        help="comma-separated numbers of agents (default 1000,10000,100000)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--child", nargs=2, metavar=("KIND", "N"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, n = args.child[0], int(args.child[1])
        out = child_netsim(n) if kind == "netsim" else child_anchor(n)
        print(json.dumps(out))
        return 0
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        print(f"scale.py: error: --sizes {args.sizes!r}: expected integers", file=sys.stderr)
        return 2
    if not sizes or min(sizes) < 2:
        print("scale.py: error: --sizes: every size must be >= 2", file=sys.stderr)
        return 2
    rows = []
    for n in sizes:
        for kind in ("anchor", "netsim"):
            print(f"[scale] N = {n}: {kind} ...", file=sys.stderr, flush=True)
            rows.append(run_child(kind, n))
    if args.json:
        print(json.dumps({"sizes": sizes, "steps": STEPS, "tau": TAU, "results": rows}))
        return 0
    print(f"n = 6, random geometric graph, tau = {TAU}, {STEPS} steps, 1 trial "
          f"(each row a fresh subprocess; times in s, RSS = peak ru_maxrss in MiB)")
    head = ("N", "links", "program", "build", "design", "design warm", "run",
            "build+run", "peak RSS")
    print(" | ".join(head))
    by = {(r["program"], r["N"]): r for r in rows}
    for n in sizes:
        for kind in ("anchor", "netsim"):
            r = by[(kind, n)]
            if "error" in r:
                print(f"{n} | - | {kind} | error: {r['error'].splitlines()[-1]}")
                continue
            design = f"{r['design_s']:.2f}" if "design_s" in r else "-"
            warm = f"{r['design_warm_s']:.2f}" if "design_warm_s" in r else "-"
            print(f"{n} | {r['links']} | {kind} | {r['build_s']:.2f} | {design} | {warm} | "
                  f"{r['run_s']:.2f} | {r['build_s'] + r['run_s']:.2f} | "
                  f"{r['peak_rss_mib']:.0f}")
        a, b = by[("anchor", n)], by[("netsim", n)]
        if "error" not in a and "error" not in b:
            print(f"{n} | ratio netsim/anchor: build {b['build_s'] / a['build_s']:.1f}x, run "
                  f"{b['run_s'] / a['run_s']:.1f}x, peak RSS "
                  f"{b['peak_rss_mib'] / a['peak_rss_mib']:.1f}x; gains: {b['gain_method']} "
                  f"rho = {b['rho']:.6f} ({b['gain_status']}, certified {b['certified']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
