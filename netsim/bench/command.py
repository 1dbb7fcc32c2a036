"""The ``netsim bench`` command line: its argument parser, :func:`cmd_bench` and ``main``."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, overload

from netsim.bench.delay_tolerance import run_delay_tolerance
from netsim.bench.fmt import fmt_value as _f
from netsim.bench.plots import plot_report
from netsim.bench.presets import DELAY_MODELS, FAMILIES, presets, sweep_presets
from netsim.bench.report import format_report
from netsim.bench.scenario_sweep import run_scenario_sweep
from netsim.bench.variants import DRIFT_PATTERNS, OFFSET_PATTERNS
from netsim.models.jsonsafe import json_tree

__all__ = ["add_bench_parser", "cmd_bench", "main"]


def add_bench_parser(subparsers: Any) -> Any:
    """Add ``bench`` (with ``delay-tolerance`` and ``sweep``) to the ``netsim`` parser."""
    bench = subparsers.add_parser(
        "bench",
        help="benchmarks: delay tolerance of each estimator vs the papers' bounds; sweeps",
        description="Benchmarks that run many Monte Carlo cells on a local process pool "
                    "(default, 2 workers) or a Dask cluster, resumable.",
    )
    from netsim.papers import delay_bounds

    sub = bench.add_subparsers(dest="bench_command", metavar="BENCH")
    named = presets()
    presets_list = ", ".join(named)
    bounds = ", ".join(b.help for b in delay_bounds())
    dt = sub.add_parser(
        "delay-tolerance",
        help="how much delay each estimator tolerates, measured and predicted",
        description=(
            "For each delay setting, delay bound tau and estimator family: Monte Carlo "
            "steady-state MSE, MSE growth and error decay factor, the exact augmented "
            "spectral radius (fixed delays) or the realised growth factor (time-varying), "
            f"the papers' bounds ({bounds}) and a verdict (stable / diverging / undecided / bound "
            "violated (exact > bound) / prediction contradicted / bound conservative); the "
            "largest tolerated delay per estimator, measured vs predicted; the papers' "
            "statements checked, with the numbers where they "
            f"disagree. Presets: {presets_list}."
        ),
    )
    dt.add_argument("scenario", help=f"a preset ({presets_list}), a built-in scenario or a "
                    "scenario TOML file")
    dt.add_argument("--taus", help="comma-separated delay bounds (default: the preset's, "
                    "else 0,3,8,19)")
    dt.add_argument("--delays", help="comma-separated delay settings: "
                    f"{', '.join(DELAY_MODELS)} (default: the preset's, else "
                    "homogeneous,heterogeneous,time-varying)")
    dt.add_argument("--estimators", help="comma-separated estimator families: registered "
                    "('netsim estimators' lists them), module:attribute of your own, or an "
                    "installed entry point (default: the preset's, else the scenario's "
                    "run.estimators)")
    dt.add_argument("--trials", type=int, help="Monte Carlo trials per cell (default: the "
                    "preset's, else the scenario's)")
    dt.add_argument("--steps", type=int, help="steps per trial (default: the preset's, else "
                    "the scenario's)")
    dt.add_argument("--seed", type=int, help="root seed (default: the scenario's run.seed)")
    dt.add_argument("--engine", default="auto", choices=["auto", "vectorised", "events"],
                    help="engine of the Monte Carlo trials: vectorised (all trials of a "
                    "cell in lockstep), events (the SimPy kernel), auto (default: "
                    "vectorised)")
    dt.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    dt.add_argument("--plot", metavar="FILE.png", help="write MSE vs tau per estimator and "
                    "delay setting, and the MSE over time, to a PNG")
    dt.add_argument("--force", action="store_true", help="overwrite an existing --plot file")
    _executor_options(dt)
    dt.add_argument("--resume", metavar="FILE.jsonl", help="results file: finished cells are "
                    "appended as they finish; cells already in it are not recomputed")

    sw = sub.add_parser(
        "sweep",
        help="a parameter grid of Monte Carlo runs, streamed to CSV / JSON lines",
        description=(
            "Run a scenario over the Cartesian product of the given axes (delay settings, "
            "taus, topologies, network sizes, run seeds); each cell runs every estimator "
            "family for M trials. Rows stream into the JSON-lines file as cells finish "
            "(a re-run with the same file computes only the missing cells) and the CSV "
            "table is written in grid order at the end. Each row names the engine that ran "
            "each family: with --engine auto a cell runs batched (vectorised) where that "
            "engine expresses it -- for [time] cells fixed offsets and drifts "
            "(--offset-pattern / --drift-pattern fixed) and threshold 0 -- and on the event "
            "kernel (events) otherwise."
        ),
    )
    sweeps = ", ".join(sweep_presets())
    sw.add_argument("scenario", help="built-in scenario name or TOML file"
                    + (f", or a sweep preset ({sweeps}: its axes, estimators, trials and "
                       "steps unless given)" if sweeps else ""))
    sw.add_argument("--delays", help="comma-separated delay settings or delays.model values")
    sw.add_argument("--taus", help="comma-separated delay bounds")
    sw.add_argument("--topologies", help="comma-separated: cycle, random, geometric")
    sw.add_argument("--sizes", help="comma-separated numbers of agents (agent i carries "
                    "sensor i mod m of the base plant)")
    sw.add_argument("--seeds", help="comma-separated run seeds")
    sw.add_argument("--losses", help="comma-separated loss probabilities p in [0, 1]: every "
                    "link loses each message with probability p ([links] loss, Bernoulli)")
    sw.add_argument("--offsets", help="comma-separated clock offsets o (time units): each "
                    "agent's offset uniform in [-o, o], drawn per trial, or with "
                    "--offset-pattern fixed o x p_i ([time] table)")
    sw.add_argument("--offset-pattern", choices=list(OFFSET_PATTERNS),
                    help="how --offsets spreads over the agents: uniform (default; drawn "
                    "per trial in [-o, o], the event kernel runs it) or fixed (agent i's "
                    "offset o x p_i in every trial, p = (-1, 1, -1/2, 1/2, -1/3, 1/3, ...): "
                    "the batched timed engine runs it)")
    sw.add_argument("--drifts", help="comma-separated clock drifts s, ppm: each agent's "
                    "drift N(0, s^2) drawn per trial, or with --drift-pattern fixed s x p_i "
                    "([time] table)")
    sw.add_argument("--drift-pattern", choices=list(DRIFT_PATTERNS),
                    help="how --drifts spreads over the agents: normal (default; N(0, s^2) "
                    "ppm per agent and trial, the event kernel runs it) or fixed (agent i's "
                    "drift s x p_i ppm in every trial, p as --offset-pattern's: the "
                    "batched timed engine runs it)")
    sw.add_argument("--thresholds", help="comma-separated send-on-delta thresholds: an "
                    "agent sends when its estimate moved by this much; the message rate "
                    "is reported ([time] table)")
    sw.add_argument("--estimators", help="comma-separated estimator families ('netsim "
                    f"estimators' lists them; default: {', '.join(FAMILIES)})")
    sw.add_argument("--trials", type=int, help="trials per cell (default 10)")
    sw.add_argument("--steps", type=int, help="steps per trial (default 200)")
    sw.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    sw.add_argument("--out", metavar="FILE.jsonl", required=True,
                    help="JSON-lines results file (resumed if it exists)")
    sw.add_argument("--csv", metavar="FILE.csv", help="also write the table as CSV")
    sw.add_argument("--engine", default="auto", choices=["auto", "vectorised", "events"],
                    help="engine of the Monte Carlo trials (default auto: vectorised "
                    "where the cell is expressible, else the event kernel)")
    sw.add_argument("--json", action="store_true", help="print the rows as one JSON object")
    _executor_options(sw)
    return bench


def _executor_options(parser: Any) -> None:
    parser.add_argument("--dask", metavar="ADDRESS", help="run the cells on a Dask "
                        "distributed scheduler (e.g. tcp://127.0.0.1:8786)")
    parser.add_argument("--workers", type=int, default=2, help="local worker processes "
                        "(default 2; 1 runs in this process)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _split(text: str, option: str, convert: Callable[[str], Any], what: str) -> list[Any]:
    """The non-blank comma-separated items of ``text`` converted (one-line error)."""
    from netsim.cliutil import CommandError

    try:
        return [convert(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise CommandError(f"{option}: expected comma-separated {what}, got {text!r}"
                           ) from None


@overload
def _ints(text: str, option: str) -> list[int]: ...
@overload
def _ints(text: str | None, option: str) -> list[int] | None: ...
def _ints(text: str | None, option: str) -> list[int] | None:
    from netsim.cliutil import CommandError

    if text is None:
        return None
    values = _split(text, option, int, "integers")
    if not values:
        raise CommandError(f"{option}: empty list")
    if any(v < 0 for v in values):
        raise CommandError(f"{option}: values must be >= 0, got {text!r}")
    return values


def _families(option: str | None, scenario: Any) -> list[Any]:
    """``--estimators`` (any registered family, module:attribute or entry point) or the
    scenario's own estimators, resolved in the registry (one-line error)."""
    from netsim.cliutil import CommandError
    from netsim.estimators.registry import FamilyError, resolve_families
    from netsim.runner import scenario_folder

    base = scenario_folder(scenario)
    try:
        own = resolve_families(scenario.estimators, "run.estimators", base)
        if option is None:
            return own
        return resolve_families(_names(option, "--estimators", None), "--estimators", base)
    except FamilyError as exc:
        raise CommandError(str(exc)) from None


@overload
def _names(text: str, option: str, allowed: Sequence[str] | None) -> list[str]: ...
@overload
def _names(text: str | None, option: str, allowed: Sequence[str] | None) -> list[str] | None: ...
def _names(text: str | None, option: str, allowed: Sequence[str] | None) -> list[str] | None:
    from netsim.cliutil import CommandError

    if text is None:
        return None
    values = [v.strip() for v in text.split(",") if v.strip()]
    if not values:
        raise CommandError(f"{option}: empty list")
    if allowed is not None:
        bad = [v for v in values if v not in allowed]
        if bad:
            raise CommandError(f"{option}: unknown {', '.join(bad)}; expected some of "
                               f"{', '.join(allowed)}")
    return values


def _floats(text: str | None, option: str) -> list[float] | None:
    """Comma-separated non-negative finite numbers (the [time] axes), or None."""
    from netsim.cliutil import CommandError

    if text is None:
        return None
    values = _split(text, option, float, "numbers")
    if not values or any(not math.isfinite(v) or v < 0 for v in values):
        raise CommandError(f"{option}: expected non-negative finite numbers, got {text!r}")
    return values


def cmd_bench(args: Any) -> int:
    """Run ``netsim bench ...``; raise ``netsim.cliutil.CommandError`` on bad input."""
    from netsim.cliutil import CommandError

    command = getattr(args, "bench_command", None)
    if command is None:
        raise CommandError("bench: name a benchmark: delay-tolerance or sweep")
    if args.workers is not None and args.workers < 1:
        raise CommandError(f"--workers must be a positive integer, got {args.workers}")
    if command == "sweep":
        return _cmd_sweep(args)
    return _cmd_delay_tolerance(args)


def _executor(args: Any) -> dict[str, Any]:
    if args.dask:
        _require("distributed", "dask", "--dask")
        return {"executor": "dask", "dask_address": args.dask, "workers": args.workers}
    return {"executor": "serial" if args.workers == 1 else "local", "workers": args.workers}


def _cmd_delay_tolerance(args: Any) -> int:
    from netsim.cliutil import (
        EXIT_INTERRUPTED,
        CommandError,
        gains_if_needed,
        note_kernel_fallbacks,
    )
    from netsim.models.scenario import ScenarioError, resolve_scenario
    from netsim.sweep import SweepInterrupted

    named = presets()
    preset = named.get(args.scenario)
    for option in ("trials", "steps"):
        value = getattr(args, option)
        if value is not None and value < 1:
            raise CommandError(f"--{option} must be a positive integer, got {value}")
    if args.seed is not None and args.seed < 0:
        raise CommandError(f"--seed must be a non-negative integer, got {args.seed}")
    if args.plot and not args.plot.lower().endswith(".png"):
        raise CommandError(f"--plot {args.plot}: the output must be a .png file")
    if args.plot:  # before the runs, not after them
        _require("matplotlib", "plot", "--plot")
    _check_outputs(args.scenario, [("--plot", args.plot, True), ("--resume", args.resume, False)],
                   getattr(args, "force", False))
    try:
        scenario = resolve_scenario(preset.scenario if preset else args.scenario)
        scenario = scenario.densified("netsim bench")
    except ScenarioError as exc:
        extra = "" if preset else f" (or a preset: {', '.join(named)})"
        raise CommandError(f"scenario {args.scenario}: {exc}{extra}") from None
    if scenario.link_spec is not None and scenario.link_spec.sets_delays:
        raise CommandError(f"scenario {args.scenario}: its [links] table sets the link delays; "
                           "the benchmark sets them per cell (drop links.delay)")
    if scenario.delays.model in ("fixed", "latency"):
        raise CommandError(f"scenario {args.scenario}: per-link '{scenario.delays.model}' "
                           "delays have no bound tau to vary; use a homogeneous, heterogeneous "
                           "or time-varying scenario")
    taus = _ints(args.taus, "--taus") or list(preset.taus if preset else (0, 3, 8, 19))
    delays = _names(args.delays, "--delays", list(DELAY_MODELS)) or list(
        preset.delays if preset else ("homogeneous", "heterogeneous", "time-varying"))
    chosen = args.estimators
    if chosen is None and preset is not None and preset.families:
        chosen = ",".join(preset.families)
    declared = _families(chosen, scenario)
    families = [f.name for f in declared]
    trials = args.trials or (preset.trials if preset else scenario.trials)
    steps = args.steps or (preset.steps if preset else scenario.steps)
    seed = scenario.seed if args.seed is None else args.seed
    gains = gains_if_needed(scenario, declared, args.scenario)
    if args.resume:
        parent = Path(args.resume).resolve().parent
        if not parent.is_dir():
            raise CommandError(f"--resume {args.resume}: directory {parent} does not exist")
    from netsim.runner import kernel_fallbacks

    try:
        fallbacks = kernel_fallbacks(args.engine, declared)
    except ValueError as exc:
        raise CommandError(f"--engine {args.engine}: {exc}") from None
    note_kernel_fallbacks("bench", fallbacks, "the cells")
    try:
        data = run_delay_tolerance(
            scenario, taus=taus, delays=delays, trials=trials, steps=steps, seed=seed,
            families=families, gains=gains, preset=preset, results=args.resume,
            progress=not args.no_progress, engine=args.engine, **_executor(args))
    except SweepInterrupted as exc:
        raise CommandError(str(exc), EXIT_INTERRUPTED) from None
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    except OSError as exc:
        raise CommandError(f"cannot write results: {exc}") from None
    if args.plot:
        from netsim.outfiles import atomic_output

        try:
            with atomic_output(args.plot) as tmp:
                plot_report(data, tmp)
            data["plot"] = str(args.plot)
        except OSError as exc:
            raise CommandError(f"cannot write {args.plot}: {exc.strerror or exc}") from None
    if args.json:
        json.dump(json_tree(data), sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(format_report(data))
        if args.plot:
            sys.stdout.write(f"plot: {data['plot']}\n")
    return 0


def _check_outputs(scenario: str, outputs: list[tuple[str, str | None, bool]],
                   force: bool = False) -> None:
    """Check the command's output files by :mod:`netsim.outfiles`' rule: ``outputs`` is
    (option, path or None, overwrites); the scenario file is an input."""
    import os

    from netsim.cliutil import CommandError
    from netsim.outfiles import OutputFileError, check_output

    named = [(o, p, w) for o, p, w in outputs if p]
    inputs = [scenario] if os.path.isfile(scenario) else []
    try:
        for option, path, overwrites in named:
            check_output(path, option, force=force or not overwrites, inputs=inputs,
                         others=[p for o, p, _ in named if o != option],
                         overwrites=overwrites)
    except OutputFileError as exc:
        raise CommandError(str(exc)) from None


#: Bytes per agent, trial, state and step of delay history a sweep cell holds at most
#: (estimates, their ring buffer and the engine's temporaries; generous), and per agent
#: for the network (weights, links, schedule).
SWEEP_BYTES_PER_AGENT_STATE = 64
SWEEP_BYTES_PER_AGENT = 4096
#: Seconds per agent-trial-step of a sweep cell (generous; for refusing absurd sizes).
SWEEP_SECONDS_PER_AGENT_STEP = 2e-6


def _check_sweep_sizes(scenario: str, agents: int, tau: int, trials: int, steps: int) -> None:
    """Refuse --sizes whose largest cell this machine cannot hold or finish within the time
    limit, estimated from the counts alone (the network is not built)."""
    from netsim.budget import check_duration, check_memory
    from netsim.cliutil import CommandError
    from netsim.models.scenario import ScenarioError, resolve_scenario

    try:
        base = resolve_scenario(scenario)
    except ScenarioError as exc:
        raise CommandError(f"scenario {scenario}: {exc}") from None
    depth = max(tau, base.delay_bound) + 2
    n = base.plant.n_states
    check_memory(agents * (trials * n * depth * SWEEP_BYTES_PER_AGENT_STATE
                           + SWEEP_BYTES_PER_AGENT), "--sizes",
                 f"a sweep cell of {agents} agents ({trials} trials, n = {n})", agents)
    check_duration(agents * trials * steps * SWEEP_SECONDS_PER_AGENT_STEP, "--sizes", agents,
                   f"a sweep cell of {agents} agents x {trials} trials x {steps} steps")


#: (pattern axis, its option, the axis it spreads, that axis' option, the default).
_PATTERN_OPTIONS = (
    ("offset_pattern", "--offset-pattern", "offset", "--offsets", OFFSET_PATTERNS[0]),
    ("drift_pattern", "--drift-pattern", "drift_ppm", "--drifts", DRIFT_PATTERNS[0]),
)


def _cmd_sweep(args: Any) -> int:
    from netsim.cliutil import EXIT_INTERRUPTED, CommandError
    from netsim.models.scenario import ScenarioError
    from netsim.sweep import SweepInterrupted

    preset = sweep_presets().get(args.scenario)
    scenario = preset.scenario if preset is not None else args.scenario
    trials = args.trials if args.trials is not None else (preset.trials if preset else 10)
    steps = args.steps if args.steps is not None else (preset.steps if preset else 200)
    for option, value in (("trials", trials), ("steps", steps)):
        if value < 1:
            raise CommandError(f"--{option} must be a positive integer")
    taus, agents = _ints(args.taus, "--taus"), _ints(args.sizes, "--sizes")
    axes: dict[str, list[Any] | None] = {
        "delays": _names(args.delays, "--delays", None),
        "tau": taus,
        "topology": _names(args.topologies, "--topologies", ["cycle", "random", "geometric"]),
        "agents": agents,
        "seed": _ints(args.seeds, "--seeds"),
        "loss": _floats(args.losses, "--losses"),
        "offset": _floats(args.offsets, "--offsets"),
        "drift_ppm": _floats(args.drifts, "--drifts"),
        "threshold": _floats(args.thresholds, "--thresholds"),
    }
    # a pattern other than the default is an axis of one value (the default is no axis,
    # so the cells' keys stay those of a sweep without the option)
    for axis, _, _, _, default in _PATTERN_OPTIONS:
        chosen = getattr(args, axis, None)
        if chosen is not None:
            axes[axis] = [] if chosen == default else [chosen]
    if preset is not None:  # the preset's axes, unless given
        for axis, values in preset.axes.items():
            if axes.get(axis) is None:
                axes[axis] = list(values)
        agents, taus = axes.get("agents"), axes.get("tau")
    for axis, option, spread, spread_option, _ in _PATTERN_OPTIONS:
        if getattr(args, axis, None) is not None and not axes.get(spread):
            raise CommandError(f"{option} {getattr(args, axis)}: needs {spread_option} (the "
                               "values it spreads over the agents)")
    if agents and min(agents) < 2:
        raise CommandError("--sizes: a network needs at least 2 agents")
    if axes["loss"] and max(axes["loss"]) > 1:
        raise CommandError(f"--losses: probabilities must be in [0, 1], got {args.losses!r}")
    families = _names(args.estimators, "--estimators", None) or list(
        preset.families if preset is not None and preset.families else FAMILIES)
    # the results file is resumed and the CSV regenerated from it: neither needs --force,
    # but neither may be a link, an input or the other output
    _check_outputs(scenario, [("--out", args.out, False), ("--csv", args.csv, False)])
    if agents:
        _check_sweep_sizes(scenario, max(agents), max(taus or [0]), trials, steps)
    try:
        result = run_scenario_sweep(
            scenario, axes=axes, trials=trials, steps=steps,
            families=families, seed=args.seed, results=args.out, csv_path=args.csv,
            progress=not args.no_progress, description=f"sweep {args.scenario}",
            engine=args.engine, **_executor(args))
    except ScenarioError as exc:
        raise CommandError(f"scenario {args.scenario}: {exc}") from None
    except SweepInterrupted as exc:
        raise CommandError(str(exc), EXIT_INTERRUPTED) from None
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    except OSError as exc:  # e.g. the disk filled while rows were written
        from netsim.sweep import read_results

        try:
            kept = len(read_results(args.out))
        except (OSError, ValueError):
            kept = 0
        raise CommandError(f"--out {args.out}: cannot write the results "
                           f"({exc.strerror or exc}); the {kept} row(s) written before are "
                           "kept: the same command resumes from them") from None
    if args.json:
        json.dump({"rows": result.rows, "computed": result.computed, "reused": result.reused,
                   "results": result.path, "csv": result.csv_path}, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    lines = [f"{len(result.rows)} cells ({result.computed} computed, {result.reused} reused) "
             f"in {result.elapsed_s:.1f} s; rows in {result.path}"
             + (f", table in {result.csv_path}" if result.csv_path else "")]
    for row in result.rows:
        p = {k: v for k, v in row["params"].items() if not k.startswith("_")}
        res = row["result"]
        if "error" in res:
            lines.append(f"  {p}: ERROR {res['error']}")
            continue
        # a steady MSE for stable runs only; the others show their last trusted MSE
        verdicts = ", ".join(
            (f"{k} {v['verdict']} (MSE {_f(v['steady_state_mse'])})" if "steady_state_mse" in v
             else f"{k} {v['verdict']} (last MSE {_f(v.get('last_trusted_mse'))})")
            + (f" rate {_f(v['message_rate'])}" if "message_rate" in v else "")
            + (f" [{v['engine']}]" if "engine" in v else "")
            for k, v in res["estimators"].items())
        lines.append(f"  {p}: {verdicts}")
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


def _require(module: str, extra: str, needed_for: str) -> None:
    """An optional dependency (:func:`netsim.models.extras.require`), else CommandError."""
    from netsim.cliutil import CommandError
    from netsim.models.extras import MissingExtra, require

    try:
        require(module, extra, needed_for)
    except MissingExtra as exc:
        raise CommandError(str(exc)) from None


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m netsim.bench ...``: the ``bench`` subcommand on its own (same exit
    codes as ``netsim``; ``netsim bench`` once registered in :mod:`netsim.cli`)."""
    import argparse

    from netsim.cliutil import EXIT_BAD_INPUT, EXIT_INTERRUPTED, CommandError, scenario_warnings

    parser = argparse.ArgumentParser(prog="netsim")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    add_bench_parser(sub)
    args = parser.parse_args(["bench", *(sys.argv[1:] if argv is None else argv)])
    try:
        with scenario_warnings("bench"):
            return cmd_bench(args)
    except CommandError as exc:
        sys.stderr.write(f"netsim bench: error: {exc}\n")
        return exc.code
    except KeyboardInterrupt:
        sys.stderr.write("netsim bench: interrupted\n")
        return EXIT_INTERRUPTED
    del EXIT_BAD_INPUT
