#!/usr/bin/env python
"""Every goal of issue 34 measured in one run, each beside its anchor.

One command runs, one after the other, the measurements the other scripts in
``benchmarks/`` make, and prints one table: the goal, its anchor, the measured figure,
the ratio or limit, whether it is met, and the command line that reproduces the row.
Nothing here measures anything itself; the figures come from (in this order):

* ``benchmarks/startup.py --json``: CPU time of a warm ``netsim run
  lcsys2022-heterogeneous`` and a warm ``netsim analyze lcsys2022-homogeneous`` against
  ``python -c "import numpy, scipy"`` in the same rounds (goals: at most 2x and 4x);
* ``benchmarks/engine_scaling.py --only anchor --json``: the vectorised engine at N = 32
  (100 trials x 500 steps, tau = 3) against the plain numpy script with one delay on
  every link (goal: at least 3x), the numba loop with asynchronous delays (at least
  1x) and the arithmetic floor (within 8x), each with the engine's default numpy step
  and, with numba installed, its compiled step (opt-in: ``NETSIM_NUMBA=1``); both rows
  are shown, so a goal met only with the opt-in reads as such;
* ``benchmarks/cold_start.py --json``: ``netsim run examples/geometric-100k.toml`` from
  an empty gain cache, beside the warm run and a bare sparse mat-vec loop (goals: under
  30 s wall and under 2 GiB peak RSS);
* the 1,000,000-agent scenario (``examples/geometric-100k.toml`` with 1,000,000 agents
  and sensors and the radius scaled for the same mean degree, as in
  ``tests/test_counts_precheck.py``), ``NETSIM_MEMORY_LIMIT=16G netsim run million.toml``
  measured with ``cold_start.measure`` (wall, CPU and peak RSS by ``os.wait4``) under a
  ``timeout`` of 330 s (goal: it runs within 16 GiB and 5 minutes, or is refused, exit
  2, in under 5 s).

The header records the commit, uncommitted changes under ``netsim/ models/ estimators/``,
the number of CPUs, the load average before and after every part and the share of CPU
time the host stole during the run (``/proc/stat``), since the machine may be shared.
Nothing is asserted; the exit status is 0 whether or not the goals are met (1 if a
measurement fails).

Usage::

    python benchmarks/goals.py            # everything: 1 min idle, 3 min at load 6-9
    python benchmarks/goals.py --quick            # fewer rounds, every row
    python benchmarks/goals.py --only startup,million
    python benchmarks/goals.py --json > goals.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

#: Goal ids (what ``--only`` takes, beside the part names) and the part measuring each.
GOALS: dict[str, str] = {
    "startup-run": "startup",
    "startup-analyze": "startup",
    "startup-analyze-cold": "startup",
    "engine-numpy-anchor": "engine",
    "engine-numba-loop": "engine",
    "engine-floor": "engine",
    "cold-time": "cold",
    "cold-memory": "cold",
    "million": "million",
}
PARTS = ("startup", "engine", "cold", "million")

#: Rounds per part: (full, --quick). engine_scaling.py times at least 3 rounds.
REPEATS = {"startup": (5, 2), "engine": (5, 3)}

GIB = 1024.0 ** 3
MILLION_TIMEOUT_S = 330
MILLION_LIMIT = "16G"
#: The 100,000-agent example made 1,000,000 agents, as tests/test_counts_precheck.py does.
MILLION_EDITS = (("sensors = 100000", "sensors = 1000000"),
                 ("agents = 100000", "agents = 1000000"),
                 ("radius = 0.005641895835477563", "radius = 0.0017841241161527712"))


@dataclass
class Row:
    """One line of the table."""

    goal_id: str
    goal: str
    step: str
    anchor: str
    measured: str
    ratio: str
    limit: str
    met: bool | None
    command: str
    value: float | None = None


def progress(message: str) -> None:
    """One line of progress on stderr."""
    print(message, file=sys.stderr, flush=True)


def python_shown() -> str:
    """This interpreter as a user types it (relative to the repository when inside)."""
    rel = os.path.relpath(sys.executable, ROOT)
    return sys.executable if rel.startswith("..") else rel


def load() -> list[float]:
    """The 1, 5 and 15 minute load averages."""
    return [round(x, 2) for x in os.getloadavg()]


def cpu_ticks() -> list[int] | None:
    """The aggregate ``cpu`` line of ``/proc/stat`` (None where there is none)."""
    try:
        with open("/proc/stat") as f:
            return [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None


def steal_share(before: list[int] | None, after: list[int] | None) -> float | None:
    """Share of all CPU ticks between two samples that the host stole (field 8)."""
    if not before or not after or len(before) < 8 or len(after) < 8:
        return None
    delta = [a - b for a, b in zip(after, before, strict=False)]
    total = sum(delta[:8])  # guest time is already counted in user
    return delta[7] / total if total > 0 else None


def revision() -> dict[str, Any]:
    """Commit and uncommitted changes to the measured code."""
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                                  timeout=30).stdout.rstrip()
        except (OSError, subprocess.SubprocessError):
            return ""
    changed = git("status", "--porcelain", "--", "netsim", "models", "estimators",
                  "traces", "benchmarks").splitlines()
    return {"commit": git("rev-parse", "--short", "HEAD").strip(),
            "uncommitted": [line[3:] for line in changed]}


def run_script(argv: list[str]) -> dict[str, Any]:
    """Run one benchmark script with ``--json``; its JSON object (progress passes through)."""
    proc = subprocess.run([sys.executable, *argv], cwd=ROOT, stdout=subprocess.PIPE,
                          text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited with {proc.returncode}")
    try:
        data: dict[str, Any] = json.loads(proc.stdout)
    except json.JSONDecodeError as exc:
        raise RuntimeError(f"{' '.join(argv)}: no JSON object on stdout ({exc})") from exc
    return data


def x(value: float | None, digits: int = 2) -> str:
    """A ratio as text."""
    return "-" if value is None else f"{value:.{digits}f}x"


# ------------------------------------------------------------------ the parts


def part_startup(repeat: int, wanted: set[str]) -> tuple[dict[str, Any], list[Row]]:
    argv = ["benchmarks/startup.py", "--repeat", str(repeat), "--json"]
    data = run_script(argv)
    command = f"{python_shown()} {' '.join(argv[:-1])}"
    cpu, ratio = data["cpu_s"], data["ratio_to_anchor"]
    anchor = f"python -c \"import numpy, scipy\": {cpu['anchor']:.3f} s CPU"
    rows = []
    for goal_id, name, text, limit in (
            ("startup-run", "run", "warm `netsim run lcsys2022-heterogeneous`, CPU", 2.0),
            ("startup-analyze", "analyze", "warm `netsim analyze lcsys2022-homogeneous`, CPU",
             4.0)):
        if goal_id in wanted:
            rows.append(Row(goal_id, text, "", anchor, f"{cpu[name]:.3f} s CPU",
                            x(ratio[name]), f"<= {limit:g}x", ratio[name] <= limit, command,
                            ratio[name]))
    if "startup-analyze-cold" in wanted and "analyze-cold" in cpu:  # no goal: a reference
        rows.append(Row("startup-analyze-cold", "the same analyze with its 62 exact radii "
                        "computed now (NETSIM_RADIUS_CACHE=off), CPU", "", anchor,
                        f"{cpu['analyze-cold']:.3f} s CPU", x(ratio["analyze-cold"]), "-",
                        None, command, ratio["analyze-cold"]))
    return data, rows


def part_engine(repeat: int, wanted: set[str]) -> tuple[dict[str, Any], list[Row]]:
    argv = ["benchmarks/engine_scaling.py", "--only", "anchor", "--repeat", str(repeat),
            "--json"]
    data = run_script(argv)
    command = f"{python_shown()} {' '.join(argv[:-1])}"
    a = data["anchor"]
    engines: dict[str, dict[str, Any]] = a["engines"]
    cpu = a["best_cpu_s"]
    steps = (("vectorised", "asynchronous", "numpy (default)"),
             ("vectorised_numba", "asynchronous_numba", "numba (NETSIM_NUMBA=1)"))
    size = f"N = {a['agents']}, {a['trials']} x {a['steps']}, tau = {a['tau']}"
    floor = a["floor"]
    floor_text = (f"floor {floor['floor_s'] * 1e3:.1f} ms ({floor['flops_per_trial_step']:,} "
                  f"FLOP/trial-step at {floor['dgemm_flops_per_s'] / 1e9:.1f} GFLOP/s)")
    rows = []

    def add(goal_id: str, text: str, key: str, step: str, anchor: str, field: str,
            limit: float | None, at_most: bool) -> None:
        if goal_id not in wanted:
            return
        if key not in engines:
            rows.append(Row(goal_id, text, step, anchor, "numba not installed", "-",
                            "-" if limit is None else f"{'<=' if at_most else '>='} "
                            f"{limit:g}x", None, command))
            return
        e = engines[key]
        value = e[field]
        met = None if limit is None or value is None else (
            value <= limit if at_most else value >= limit)
        rows.append(Row(goal_id, text, step, anchor, f"{e['cpu_s']:.3f} s CPU", x(value),
                        "no goal" if limit is None else
                        f"{'<=' if at_most else '>='} {limit:g}x", met, command, value))

    for one, _, step in steps:
        add("engine-numpy-anchor", f"vectorised, one delay on every link ({size}): "
            "numpy script / engine, CPU", one, step,
            f"plain numpy script: {cpu['anchor']:.3f} s CPU",
            "numpy_anchor_over_engine_cpu", 3.0, False)
    loop = cpu.get("numba_loop_asynchronous")
    for _, asyn, step in steps:
        add("engine-numba-loop", f"vectorised, asynchronous delays ({size}): "
            "numba loop / engine, CPU", asyn, step,
            "numba loop: not installed" if loop is None else f"numba loop: {loop:.3f} s CPU",
            "numba_loop_over_engine_cpu", 1.0, False)
    for one, _, step in steps:
        add("engine-floor", f"vectorised, one delay on every link ({size}): "
            "engine / arithmetic floor, CPU", one, step, floor_text,
            "engine_over_floor_cpu", 8.0, True)
    for _, asyn, step in steps:  # the table gives this case too; no goal of its own
        add("engine-floor", f"vectorised, asynchronous delays ({size}): engine / "
            "arithmetic floor, CPU (for reference)", asyn, step, floor_text,
            "engine_over_floor_cpu", None, True)
    if not a.get("agree", False):
        progress("engine: the squared errors of the anchors and steps do not agree "
                 "(see checks in --json)")
    return data, rows


def part_cold(wanted: set[str]) -> tuple[dict[str, Any], list[Row]]:
    argv = ["benchmarks/cold_start.py", "--json"]
    data = run_script(argv)
    command = f"{python_shown()} {argv[0]}"
    r = data["results"]
    cold, warm, matvec = r["cold"], r["warm"], r["matvec"]
    ok = cold["exit"] == 0
    rows = []
    text = "`netsim run examples/geometric-100k.toml`, empty gain cache"
    if "cold-time" in wanted:
        rows.append(Row(
            "cold-time", f"{text}: wall time", "",
            f"warm run {warm['wall_s']:.2f} s wall; sparse mat-vec loop "
            f"{matvec['wall_s']:.2f} s wall",
            f"{cold['wall_s']:.2f} s wall ({cold['cpu_s']:.2f} s CPU), exit {cold['exit']}",
            f"cold / warm {x(cold['wall_s'] / warm['wall_s'] if warm['wall_s'] else None)}",
            "< 30 s", ok and cold["wall_s"] < 30.0, command, cold["wall_s"]))
    if "cold-memory" in wanted:
        rows.append(Row(
            "cold-memory", f"{text}: peak RSS", "",
            f"warm run {warm['peak_rss_mib']:.0f} MiB",
            f"{cold['peak_rss_mib']:.0f} MiB",
            f"cold / warm {x(cold['peak_rss_mib'] / warm['peak_rss_mib'] if warm['peak_rss_mib'] else None)}",  # noqa: E501
            "< 2 GiB", ok and cold["peak_rss_mib"] < 2048.0, command, cold["peak_rss_mib"]))
    return data, rows


def part_million(wanted: set[str]) -> tuple[dict[str, Any], list[Row]]:
    sys.path.insert(0, HERE)
    from cold_start import measure  # the same wall / wait4 CPU and RSS as the 100k row

    netsim = os.path.join(os.path.dirname(sys.executable), "netsim")
    with open(os.path.join(ROOT, "examples", "geometric-100k.toml")) as f:
        text = f.read()
    for old, new in MILLION_EDITS:
        if old not in text:
            raise RuntimeError(f"examples/geometric-100k.toml: no {old!r} to make the "
                               "1,000,000-agent scenario from")
        text = text.replace(old, new)
    with tempfile.TemporaryDirectory(prefix="netsim-million-") as folder:
        path = os.path.join(folder, "million.toml")
        with open(path, "w") as f:
            f.write(text)
        env = dict(os.environ, NETSIM_MEMORY_LIMIT=MILLION_LIMIT)
        progress(f"million: NETSIM_MEMORY_LIMIT={MILLION_LIMIT} netsim run million.toml ...")
        result: dict[str, Any] = measure(
            ["timeout", "--kill-after=10", str(MILLION_TIMEOUT_S), netsim, "run", path,
             "--no-progress"], env)
    line = str(result.pop("gains_line", "")).strip().replace(path, "million.toml")
    result["message"] = line.splitlines()[-1] if line else ""
    wall, rss_gib, code = result["wall_s"], result["peak_rss_mib"] / 1024.0, result["exit"]
    refused = code == 2 and "1,000,000 agents" in result["message"]
    if code == 0:
        outcome = "ran"
        met = wall < 300.0 and rss_gib < 16.0
    elif refused:
        outcome = "refused (exit 2)"
        met = wall < 5.0
    elif code == 124:
        outcome = f"killed after {MILLION_TIMEOUT_S} s"
        met = False
    else:
        outcome = f"exit {code}"
        met = False
    result["outcome"] = outcome
    rows = []
    if "million" in wanted:
        rows.append(Row(
            "million", "1,000,000 agents (geometric-100k scaled), NETSIM_MEMORY_LIMIT=16G",
            "", "none (absolute limits)",
            f"{outcome} in {wall:.2f} s wall ({result['cpu_s']:.2f} s CPU), "
            f"{result['peak_rss_mib']:.0f} MiB",
            "-", "run < 5 min and < 16 GiB, or refused < 5 s", met,
            f"{python_shown()} benchmarks/goals.py --only million  (= NETSIM_MEMORY_LIMIT=16G "
            "netsim run million.toml --no-progress)", wall))
    return result, rows


# ------------------------------------------------------------------ output


def yes_no(met: bool | None) -> str:
    return "-" if met is None else ("yes" if met else "NO")


def render(report: dict[str, Any]) -> str:
    """The markdown table and its header."""
    m = report["machine"]
    rev = report["revision"]
    out = [
        f"issue 34 goals, {report['date']} ({report['total_wall_s']:.0f} s"
        f"{', --quick' if report['quick'] else ''})",
        f"commit {rev['commit']}"
        + (f", uncommitted: {', '.join(rev['uncommitted'])}" if rev["uncommitted"] else ""),
        f"machine: {m['cpus']} CPUs ({m['usable_cpus']} usable), Python {m['python']}, "
        f"numba {m['numba'] or 'not installed'}; load average (1, 5, 15 min) "
        f"{report['load_start']} at start, {report['load_end']} at end; host steal "
        + ("n/a" if report["steal_share"] is None else f"{100 * report['steal_share']:.1f} %")
        + " of CPU time during the run",
        "per part: " + "; ".join(
            f"{name} {p['wall_s']:.0f} s, load {p['load_before'][0]} -> {p['load_after'][0]}"
            for name, p in report["parts"].items()),
        "",
        "| goal | step | anchor | measured | ratio | limit | met | command |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        out.append(f"| {r['goal']} | {r['step'] or '-'} | {r['anchor']} | {r['measured']} | "
                   f"{r['ratio']} | {r['limit']} | {yes_no(r['met'])} | `{r['command']}` |")
    s = report["summary"]
    out += ["",
            f"goals met with the default numpy step: {s['met_default']} of {s['goals']}; "
            f"counting the opt-in compiled step (NETSIM_NUMBA=1): {s['met_with_opt_in']} of "
            f"{s['goals']}",
            "start-up and engine ratios are CPU-time ratios taken in the same rounds (see "
            "the scripts); the 100,000- and 1,000,000-agent limits are on wall time, as the "
            "goals state, with the CPU time beside it (on a loaded machine the wall time "
            "grows with the load above); nothing is asserted"]
    return "\n".join(out)


def summarise(rows: list[Row]) -> dict[str, Any]:
    """Per goal id: met with the default step, and met when the opt-in step counts."""
    default: dict[str, bool] = {}
    opt_in: dict[str, bool] = {}
    for r in rows:
        if r.met is None:
            continue
        is_opt_in = r.step.startswith("numba")
        if not is_opt_in:
            default[r.goal_id] = default.get(r.goal_id, True) and r.met
        opt_in[r.goal_id] = opt_in.get(r.goal_id, False) or r.met
    goals = sorted(set(default) | set(opt_in))
    return {"goals": len(goals),
            "met_default": sum(default.get(g, False) for g in goals),
            "met_with_opt_in": sum(opt_in.get(g, False) for g in goals),
            "per_goal": {g: {"default": default.get(g), "with_opt_in": opt_in.get(g)}
                         for g in goals}}


def parse_only(text: str) -> set[str]:
    """Goal ids from ``--only`` (goal ids or part names); exit 2 naming an unknown one."""
    wanted: set[str] = set()
    for item in (p.strip() for p in text.split(",")):
        if not item:
            continue
        if item in GOALS:
            wanted.add(item)
        elif item in PARTS:
            wanted |= {g for g, part in GOALS.items() if part == item}
        else:
            print(f"goals.py: error: --only: unknown row {item!r} (rows: "
                  f"{', '.join(GOALS)}; parts: {', '.join(PARTS)})", file=sys.stderr)
            raise SystemExit(2)
    if not wanted:
        print("goals.py: error: --only: no rows named", file=sys.stderr)
        raise SystemExit(2)
    return wanted


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="goals.py",
        description="Measure every goal of issue 34 in one run, each beside its anchor "
                    "(by running benchmarks/startup.py, engine_scaling.py --only anchor, "
                    "cold_start.py and the 1,000,000-agent refusal), and print one table: "
                    "goal, anchor, measured, ratio, limit, met, and the command that "
                    "reproduces the row. Rows of a goal met only with the opt-in compiled "
                    "step (NETSIM_NUMBA=1) are shown beside the default numpy step's. "
                    "Nothing is asserted.")
    parser.add_argument("--quick", action="store_true",
                        help="fewer rounds (startup 2, engine 3 instead of 5 each); every "
                             "row is still measured")
    parser.add_argument("--only", default=",".join(PARTS), metavar="ROWS",
                        help="comma-separated goal rows (" + ", ".join(GOALS) + ") or parts ("
                             + ", ".join(PARTS) + "); default: all")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object on stdout instead of the table (with "
                             "each script's own JSON report)")
    args = parser.parse_args(argv)
    wanted = parse_only(args.only)

    try:
        import numba  # noqa: F401
        numba_version: str | None = numba.__version__
    except ImportError:
        numba_version = None
    report: dict[str, Any] = {
        "benchmark": "goals",
        "issue": 34,
        "command": shlex.join([python_shown(), "benchmarks/goals.py",
                               *(sys.argv[1:] if argv is None else argv)]),
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "quick": args.quick,
        "machine": {"cpus": os.cpu_count(), "usable_cpus": len(os.sched_getaffinity(0)),
                    "python": platform.python_version(), "platform": platform.platform(),
                    "numba": numba_version},
        "revision": revision(),
        "load_start": load(),
    }
    ticks0 = cpu_ticks()
    t0 = time.perf_counter()
    parts: dict[str, dict[str, Any]] = {}
    rows: list[Row] = []
    runners: dict[str, Callable[[], tuple[dict[str, Any], list[Row]]]] = {
        "startup": lambda: part_startup(REPEATS["startup"][args.quick], wanted),
        "engine": lambda: part_engine(REPEATS["engine"][args.quick], wanted),
        "cold": lambda: part_cold(wanted),
        "million": lambda: part_million(wanted),
    }
    failed = False
    for name in PARTS:
        if not any(GOALS[g] == name for g in wanted):
            continue
        progress(f"== {name} ==")
        before, start = load(), time.perf_counter()
        try:
            data, part_rows = runners[name]()
        except (RuntimeError, KeyError, OSError) as exc:
            progress(f"{name}: failed: {exc!r}")
            data, part_rows, failed = {"error": repr(exc)}, [], True
        parts[name] = {"wall_s": time.perf_counter() - start, "load_before": before,
                       "load_after": load(), "report": data}
        rows += part_rows
    report["total_wall_s"] = time.perf_counter() - t0
    report["load_end"] = load()
    report["steal_share"] = steal_share(ticks0, cpu_ticks())
    report["parts"] = parts
    report["rows"] = [asdict(r) for r in rows]
    report["summary"] = summarise(rows)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(render(report))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
