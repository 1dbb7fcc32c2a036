#!/usr/bin/env python
"""Wall and CPU time of short ``netsim`` commands, cold and warm gain cache, as ratios.

Commands (each a fresh process, as a user types them):

* ``netsim --help``
* ``netsim run lcsys2022-heterogeneous --no-progress``
* ``netsim analyze lcsys2022-homogeneous --no-progress``

each with a **cold** gain cache (``NETSIM_CACHE_DIR`` a new, empty temporary folder for
every run: the gains are designed, cvxpy and all) and a **warm** one (a temporary folder
filled by an untimed run first). The anchors ``python -c pass`` (interpreter start-up)
and ``python -c "import numpy, scipy"`` run in the same rounds, and every time is also
given as a ratio to them, so a loaded machine shows as slower anchors rather than a
slower netsim.

Method: one untimed warm-up of every command (writes the bytecode caches and fills the
OS file cache; ``PYTHONDONTWRITEBYTECODE`` is removed from the children's environment
unless ``--no-bytecode``, since without ``.pyc`` files every run compiles about 100
modules, 0.2 s); then ``--repeat`` rounds, each running every (command, cache) once, in
the same order (interleaved, so drifting load hits all alike). Per case: best and median
wall time (``time.perf_counter`` around ``subprocess.run``) and the best CPU time (user +
system of the child, from ``resource.getrusage(RUSAGE_CHILDREN)``). The goals of issue 19
(warm ``run`` under 1 s of wall time, warm ``analyze`` under 3 s) are checked on the best
wall time and reported with the load average; nothing is asserted.

Usage::

    python benchmarks/latency.py                 # 3 rounds, about 1-2 min idle
    python benchmarks/latency.py --repeat 5
    python benchmarks/latency.py --json > latency.json

Progress goes to stderr; stdout holds the table (or, with ``--json``, exactly one JSON
object and no table). The ``netsim`` executable next to this Python is used, else
``python -m netsim.cli``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ANCHORS = {
    "python -c pass": ["-c", "pass"],
    "python -c 'import numpy, scipy'": ["-c", "import numpy, scipy"],
}
COMMANDS = {
    "netsim --help": ["--help"],
    "netsim run lcsys2022-heterogeneous": ["run", "lcsys2022-heterogeneous", "--no-progress"],
    "netsim analyze lcsys2022-homogeneous": ["analyze", "lcsys2022-homogeneous",
                                             "--no-progress"],
}
#: Goals of issue 19 on the best warm wall time (seconds).
GOALS = {"netsim run lcsys2022-heterogeneous": 1.0,
         "netsim analyze lcsys2022-homogeneous": 3.0}


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def netsim_command() -> list[str]:
    """The ``netsim`` console script beside this interpreter, else ``python -m``."""
    script = Path(sys.executable).with_name("netsim")
    if script.exists():
        return [str(script)]
    found = shutil.which("netsim")
    return [found] if found else [sys.executable, "-m", "netsim.cli"]


def timed(argv: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    """(wall seconds, child CPU seconds, exit code) of one run of ``argv``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode != 0:
        log(f"  {' '.join(argv)} exited {done.returncode}: "
            f"{done.stderr.decode(errors='replace').strip()[-300:]}")
    return wall, cpu, done.returncode


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Wall and CPU time of netsim --help / run / analyze, cold and warm "
                    "gain cache, against python start-up anchors.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("Usage::")[1] if __doc__ else None,
    )
    ap.add_argument("--repeat", type=int, default=3, help="rounds (default 3)")
    ap.add_argument("--no-bytecode", action="store_true",
                    help="keep PYTHONDONTWRITEBYTECODE as it is (no .pyc files written)")
    ap.add_argument("--netsim", default=None, metavar="CMD",
                    help="how to start netsim (default: the console script beside this "
                    "Python); e.g. --netsim 'python -m netsim.cli' with PYTHONPATH set to "
                    "measure another checkout")
    ap.add_argument("--without-no-progress", action="store_true",
                    help="drop --no-progress from analyze (checkouts before it existed; the "
                    "bar is off anyway, stderr being a pipe)")
    ap.add_argument("--json", action="store_true", help="print one JSON object, no table")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error(f"--repeat must be at least 1, got {args.repeat}")

    base_env = dict(os.environ)
    if not args.no_bytecode:
        base_env.pop("PYTHONDONTWRITEBYTECODE", None)
    base_env.pop("NETSIM_WORKERS", None)
    netsim = shlex.split(args.netsim) if args.netsim else netsim_command()
    root = Path(tempfile.mkdtemp(prefix="netsim-latency-"))
    warm_dir = root / "warm"
    cases: list[tuple[str, str, list[str]]] = []  # (name, cache, argv)
    for name, extra in ANCHORS.items():
        cases.append((name, "-", [sys.executable, *extra]))
    for name, extra in COMMANDS.items():
        if args.without_no_progress and name.startswith("netsim analyze"):
            extra = [a for a in extra if a != "--no-progress"]
        for cache in ("cold", "warm"):
            cases.append((name, cache, [*netsim, *extra]))

    def env_for(cache: str, counter: list[int]) -> dict[str, str]:
        env = dict(base_env)
        if cache == "warm":
            env["NETSIM_CACHE_DIR"] = str(warm_dir)
        elif cache == "cold":
            counter[0] += 1
            env["NETSIM_CACHE_DIR"] = str(root / f"cold{counter[0]}")
        return env

    counter = [0]
    times: dict[tuple[str, str], dict[str, list[float]]] = {
        (name, cache): {"wall": [], "cpu": []} for name, cache, _ in cases
    }
    failures: dict[str, int] = {}
    load_start = os.getloadavg()
    try:
        log("warm-up (untimed): bytecode, OS file cache, the warm gain cache ...")
        for _name, cache, cmd in cases:
            timed(cmd, env_for(cache, counter))
        for r in range(args.repeat):
            log(f"round {r + 1}/{args.repeat}")
            for name, cache, cmd in cases:
                wall, cpu, code = timed(cmd, env_for(cache, counter))
                if code != 0:
                    failures[f"{name} ({cache})"] = code
                times[(name, cache)]["wall"].append(wall)
                times[(name, cache)]["cpu"].append(cpu)
                log(f"  {name} [{cache}]: {wall:.3f} s wall, {cpu:.3f} s CPU")
    finally:
        shutil.rmtree(root, ignore_errors=True)
    load_end = os.getloadavg()

    anchor_pass = min(times[("python -c pass", "-")]["wall"])
    anchor_np = min(times[("python -c 'import numpy, scipy'", "-")]["wall"])
    anchor_np_cpu = min(times[("python -c 'import numpy, scipy'", "-")]["cpu"])
    rows = []
    for (name, cache), t in times.items():
        best = min(t["wall"])
        rows.append({
            "command": name, "cache": cache,
            "wall_best_s": best, "wall_median_s": statistics.median(t["wall"]),
            "cpu_best_s": min(t["cpu"]), "walls_s": t["wall"], "cpus_s": t["cpu"],
            "ratio_python_pass": best / anchor_pass,
            "ratio_numpy_scipy": best / anchor_np,
            "cpu_ratio_numpy_scipy": min(t["cpu"]) / anchor_np_cpu if anchor_np_cpu else None,
        })
    goals = {}
    for name, limit in GOALS.items():
        best = min(times[(name, "warm")]["wall"])
        goals[name] = {"limit_s": limit, "warm_wall_best_s": best, "met": best < limit}
    summary: dict[str, Any] = {
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                    "python": platform.python_version(), "loadavg_start": load_start,
                    "loadavg_end": load_end},
        "config": {"repeat": args.repeat, "bytecode": not args.no_bytecode,
                   "netsim": netsim},
        "rows": rows,
        "goals": goals,
        "failures": failures,
    }
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    head = (f"{'command':<38} {'cache':>5} {'best s':>7} {'median s':>8} {'CPU s':>6} "
            f"{'/ pass':>7} {'/ np+sp':>8} {'CPU / np+sp':>11}")
    print(head)
    print("-" * len(head))
    for r in rows:
        cpu_ratio = r["cpu_ratio_numpy_scipy"]
        print(f"{r['command']:<38} {r['cache']:>5} {r['wall_best_s']:>7.3f} "
              f"{r['wall_median_s']:>8.3f} {r['cpu_best_s']:>6.3f} "
              f"{r['ratio_python_pass']:>7.1f} {r['ratio_numpy_scipy']:>8.2f} "
              f"{'-' if cpu_ratio is None else f'{cpu_ratio:.2f}':>11}")
    m = summary["machine"]
    print(f"\n{m['cpu_count']} CPUs; load average {m['loadavg_start'][0]:.2f} at start, "
          f"{m['loadavg_end'][0]:.2f} at end; best of {args.repeat} rounds; "
          f"bytecode caches {'on' if not args.no_bytecode else 'as the environment says'}.")
    for name, g in goals.items():
        verdict = "MET" if g["met"] else "NOT MET"
        print(f"goal: {name} (warm) under {g['limit_s']:g} s: {g['warm_wall_best_s']:.3f} s, "
              f"{verdict}")
    if failures:
        print(f"failed runs: {failures}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
