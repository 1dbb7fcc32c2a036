#!/usr/bin/env python
"""``netsim run`` of the 100,000-agent example from an empty gain cache, beside anchors.

Three fresh subprocesses, one after the other, each measured with ``os.wait4`` (its
own CPU time, user + sys, and peak resident set size) and the wall clock:

* **cold**: ``netsim run examples/geometric-100k.toml`` with ``NETSIM_CACHE_DIR`` an
  empty folder: build, gain design, certificate and run (issue 34's goal: under 30 s
  and 2 GiB);
* **warm** (anchor): the same command again, with the entry the cold run wrote (the
  certificate is then re-verified from its stored weights, one step);
* **matvec** (anchor): a bare scipy script that builds the same-sized random sparse
  matrix (N = 100,000, 15 entries a row) and does 100 products with an ``(N, 6)``
  block: the floor of one sparse sweep per certificate step.

The table reports each beside the ratios cold / warm and cold / matvec; nothing is
asserted (timings depend on the machine and its load).

Usage::

    python benchmarks/cold_start.py [--scenario examples/geometric-100k.toml] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

MATVEC = """
import numpy as np, scipy.sparse as sp
r = np.random.default_rng(0)
N, d = 100_000, 15
P = sp.random_array((N, N), density=d / N, format="csr", random_state=r)
W = np.ones((N, 6))
for _ in range(100):
    W = P @ W
    W /= W.max()
"""


def measure(argv: list[str], env: dict[str, str]) -> dict[str, float]:
    """Wall, CPU (user + sys) and peak RSS of one child process."""
    start = time.perf_counter()
    with tempfile.TemporaryFile() as errfile:
        proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=errfile,
                                cwd=ROOT)
        out = proc.stdout.read()  # type: ignore[union-attr]
        # wait4 reaps the child with its own rusage (CPU time, peak RSS)
        _, status, usage = os.wait4(proc.pid, 0)
        errfile.seek(0)
        err = errfile.read()
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - start
    gains = [line for line in out.decode(errors="replace").splitlines()
             if line.startswith("gains:")]
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "peak_rss_mib": usage.ru_maxrss / 1024.0, "exit": proc.returncode,
            "gains_line": gains[0] if gains else err.decode(errors="replace")[-300:]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default=os.path.join("examples", "geometric-100k.toml"))
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    netsim = os.path.join(os.path.dirname(sys.executable), "netsim")
    results: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="netsim-cold-") as cache:
        env = dict(os.environ, NETSIM_CACHE_DIR=cache)
        for name in ("cold", "warm"):
            print(f"{name} ...", file=sys.stderr, flush=True)
            results[name] = measure([netsim, "run", args.scenario], env)
    print("matvec ...", file=sys.stderr, flush=True)
    results["matvec"] = measure([sys.executable, "-c", MATVEC], dict(os.environ))
    cold = results["cold"]
    ratios = {f"cold/{a}_{k}": cold[k] / results[a][k] for a in ("warm", "matvec")
              for k in ("wall_s", "cpu_s") if results[a][k] > 0}
    if args.json:
        print(json.dumps({"results": results, "ratios": ratios}, indent=2))
        return 0
    print(f"{'':8} {'wall s':>8} {'CPU s':>8} {'peak RSS MiB':>13}  exit")
    for name, r in results.items():
        print(f"{name:8} {r['wall_s']:8.2f} {r['cpu_s']:8.2f} {r['peak_rss_mib']:13.0f}  "
              f"{r['exit']}")
    print("ratios: " + ", ".join(f"{k} = {v:.2f}" for k, v in ratios.items()))
    print(f"cold: {cold['gains_line']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
