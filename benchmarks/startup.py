#!/usr/bin/env python
"""Start-up cost of the command line beside ``python -c "import numpy, scipy"`` (issue 34).

Each command runs as a fresh subprocess, one after the other and interleaved over
``--repeat`` rounds; each is measured with ``os.wait4`` (its own CPU time, user + sys,
including the processes it started and waited for) and the best round is kept:

* **anchor**: ``python -c "import numpy, scipy"``;
* **help**: ``netsim --help``;
* **run**: ``netsim run lcsys2022-heterogeneous`` (the whole run, default steps and
  trials, with a warm gain cache: the script runs it once first);
* **analyze**: ``netsim analyze lcsys2022-homogeneous`` (warm gain cache; its exact
  radii read from the radius cache, :mod:`netsim.radiuscache`);
* **analyze-cold**: the same with ``NETSIM_RADIUS_CACHE=off`` (warm gains, the 62 exact
  radii computed now; no goal, for reference).

"Warm" also means Python's byte-code cache: the children run without
``PYTHONDONTWRITEBYTECODE``, so the warm-up run writes the ``.pyc`` files of modules
edited since (an environment that sets it would compile them again on every start).

It prints each CPU time and its ratio to the anchor measured in the same run (issue
34's goals: run at most 2x, analyze at most 4x), and the modules each command imports
that it should not need (by ``sys.modules`` of the same command in-process); nothing is
asserted (timings depend on the machine and its load; tests/test_cli_imports.py
asserts the imports).

``--importtime`` also prints the 15 largest top-level imports of ``netsim run``
(``python -X importtime``).

Usage::

    python benchmarks/startup.py [--repeat 5] [--json] [--importtime]
    # before/after: an extracted checkout laid out as a package (netsim/, with models/,
    # estimators/, traces/ inside), without site's editable-install hook (-S):
    PYTHONPATH=/tmp/before/pkg:$SITE_PACKAGES python benchmarks/startup.py \
        --netsim "python -S -m netsim.cli" --cwd /tmp
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

#: Modules that none of the measured commands needs on these scenarios.
HEAVY = ("cvxpy", "matplotlib", "mcap", "dask", "distributed", "pandas", "networkx",
         "scipy.spatial", "netsim.aoi", "netsim.fusion", "netsim.estimators.aoi",
         "netsim.estimators.fusion")

PROBE = ("import sys\nfrom netsim.cli import main\n"
         "try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
         "print(sorted(m for m in {heavy!r} if m in sys.modules), file=sys.stderr)\n"
         "print(sorted(m for m in ('scipy.linalg', 'scipy.sparse', 'simpy', 'tqdm', "
         "'importlib.metadata', 'numpy.ma') "
         "if m in sys.modules), file=sys.stderr)")


def cpu_seconds(argv: list[str], env: dict[str, str], cwd: str) -> float:
    """CPU time (user + sys) of one child process and its waited-for children."""
    proc = subprocess.Popen(argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(argv)} failed (exit {status})")
    return usage.ru_utime + usage.ru_stime


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5, help="rounds (best kept; default 5)")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    parser.add_argument("--importtime", action="store_true",
                        help="also the largest top-level imports of netsim run")
    parser.add_argument("--netsim", default=None, metavar="CMD",
                        help="the command that runs netsim (default: the netsim next to "
                        "this Python; e.g. \"python -S -m netsim.cli\" for another checkout "
                        "on PYTHONPATH)")
    parser.add_argument("--cwd", default=ROOT, help="folder the commands run in")
    args = parser.parse_args()
    netsim = (shlex.split(args.netsim) if args.netsim else
              [os.path.join(os.path.dirname(sys.executable), "netsim")])
    commands = {
        "anchor": [sys.executable, "-c", "import numpy, scipy"],
        "help": [*netsim, "--help"],
        "run": [*netsim, "run", "lcsys2022-heterogeneous", "--no-progress"],
        "analyze": [*netsim, "analyze", "lcsys2022-homogeneous", "--no-progress"],
        "analyze-cold": [*netsim, "analyze", "lcsys2022-homogeneous", "--no-progress"],
    }
    # the radius cache off for this command alone (the gains stay cached)
    extra_env = {"analyze-cold": {"NETSIM_RADIUS_CACHE": "off"}}
    prefix = len(netsim)
    env = dict(os.environ)
    # "warm" includes Python's byte-code cache: with PYTHONDONTWRITEBYTECODE set, every
    # module edited since its last .pyc was written is compiled again on every start
    # (0.3-0.4 s in a tree being edited), which no installed netsim pays
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    print("warming the gain cache ...", file=sys.stderr, flush=True)
    for name in ("run", "analyze"):
        cpu_seconds(commands[name], env, args.cwd)
    best = {name: float("inf") for name in commands}
    start = time.perf_counter()
    for round_ in range(args.repeat):
        print(f"round {round_ + 1}/{args.repeat} ...", file=sys.stderr, flush=True)
        for name, argv in commands.items():
            best[name] = min(best[name], cpu_seconds(argv, {**env, **extra_env.get(name, {})},
                                                     args.cwd))
    ratios = {name: best[name] / best["anchor"] for name in commands if name != "anchor"}
    imports: dict[str, dict[str, list[str]]] = {}
    python = [sys.executable, "-S"] if "-S" in netsim else [sys.executable]
    for name in ("help", "run", "analyze"):
        code = PROBE.format(argv=commands[name][prefix:], heavy=HEAVY)
        err = subprocess.run([*python, "-c", code], env=env, cwd=args.cwd,
                             capture_output=True, text=True).stderr.strip().splitlines()
        imports[name] = {"unneeded": json.loads(err[-2].replace("'", '"')),
                         "scipy_and_co": json.loads(err[-1].replace("'", '"'))}
    top: list[tuple[int, str]] = []
    if args.importtime:
        with tempfile.TemporaryFile(mode="w+") as errfile:
            subprocess.run([*python, "-X", "importtime", "-m", "netsim.cli",
                            *commands["run"][prefix:]], env=env, cwd=args.cwd,
                           stdout=subprocess.DEVNULL, stderr=errfile)
            errfile.seek(0)
            for line in errfile:
                parts = line.split("|")
                if len(parts) == 3 and parts[1].strip().isdigit():
                    name = parts[2].rstrip("\n")
                    if not name.startswith("  "):  # top level: the command's own imports
                        top.append((int(parts[1]), name.strip()))
        top = sorted(top, reverse=True)[:15]
    if args.json:
        print(json.dumps({"cpu_s": best, "ratio_to_anchor": ratios, "imports": imports,
                          "goals": {"run": 2.0, "analyze": 4.0}, "repeat": args.repeat,
                          "importtime_us": dict((n, t) for t, n in top)}, indent=2))
        return 0
    goals = {"run": "<= 2", "analyze": "<= 4"}
    print(f"{'command':12} {'CPU s':>7} {'x anchor':>9} {'goal':>6}  imports")
    for name, argv in commands.items():
        ratio = "" if name == "anchor" else f"{ratios[name]:9.2f}"
        seen = imports.get(name)
        what = (f"unneeded {seen['unneeded'] or 'none'}; loads "
                f"{', '.join(seen['scipy_and_co'])}" if seen else
                " ".join(os.path.basename(a) for a in argv[:3]))
        print(f"{name:12} {best[name]:7.3f} {ratio:>9} {goals.get(name, ''):>6}  {what}")
    print(f"(best of {args.repeat} rounds, CPU user + sys by os.wait4; "
          f"{time.perf_counter() - start:.0f} s)")
    if top:
        print("\nlargest top-level imports of netsim run (python -X importtime, cumulative):")
        for t, name in top:
            print(f"  {t / 1000:8.1f} ms  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
