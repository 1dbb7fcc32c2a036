"""The ``netsim`` command line.

Exit codes: 0 success (an estimator that diverged is a result, not an error);
2 bad input (scenario, arguments; an optional dependency not installed: the message
names the extra, netsim.models.extras);
3 gain design failed; 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Collection, Sequence
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from netsim.budget import ResourceError
from netsim.cliutil import (
    EXIT_BAD_INPUT,
    EXIT_DESIGN_FAILED,
    EXIT_INTERRUPTED,
    REPRODUCE_HELP,
    CommandError,
    OneLineParser,
    analyze_with_progress,
    gains_if_needed,
    note_kernel_fallbacks,
    progress_bar,
    scenario_warnings,
    tau_star_text,
)
from netsim.models.extras import MissingExtra
from netsim.models.jsonsafe import json_number as _num

# CommandError and the exit codes live in netsim.cliutil (shared with netsim.bench);
# re-exported here so ``from netsim.cli import CommandError`` keeps working.
__all__ = ["main", "build_parser", "CommandError", "EXIT_BAD_INPUT", "EXIT_DESIGN_FAILED",
           "EXIT_INTERRUPTED"]


#: ``netsim bench``'s line in ``netsim --help`` (the bench parser itself, in
#: :mod:`netsim.bench.command`, is only built when the command is bench; a test checks
#: that both say the same).
_BENCH_HELP = "benchmarks: delay tolerance of each estimator vs the papers' bounds; sweeps"


def _command_in(argv: Sequence[str], commands: Collection[str]) -> str | None:
    """The subcommand argparse will pick from ``argv``: its first token if that is one
    of ``commands`` (the top level has no option but ``-h``); ``""`` for no command or
    ``-h``/``--help``; None otherwise (anything unusual: build everything)."""
    if not argv or argv[0] in ("-h", "--help"):
        return ""
    return argv[0] if argv[0] in commands else None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """Return the argument parser of ``netsim``.

    Parameters
    ----------
    only : str, optional
        None (default): the whole parser. A command name: a parser that parses that
        command exactly as the whole one does; the other commands may lack options
        whose definitions import heavy modules (the bench and reproduce
        subcommands). ``""``: enough for the top-level ``--help`` (every
        command listed). :func:`main` passes what its arguments need, which keeps
        ``netsim --help`` and ``netsim run`` from importing what they do not use.
    """
    parser = OneLineParser(
        prog="netsim",
        description=(
            "Discrete-event simulation of distributed state estimation over networks with "
            "communication delays: consensus + innovation estimators (LCSYS2022, delay-"
            "tolerant) with their delay-compensating and block-update variants, the "
            "age-of-information observer (aoi), delayed Kalman fusion (dkfe), local and "
            "centralised Kalman filter references, and estimators of your own "
            "('netsim estimators' lists them)."
        ),
        epilog="Run 'netsim COMMAND --help' for the options of a command.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    from netsim.cliutil import TableEpilogFormatter
    from netsim.verdicts import VERDICT_TABLE

    run = sub.add_parser(
        "run",
        help="Monte Carlo runs of every estimator in a scenario",
        description=(
            "Run the estimator families of SCENARIO (its run.estimators, or --estimators) "
            "over Monte Carlo trials (in the "
            "vectorised engine, or the SimPy event kernel with --engine events) and "
            "print, per estimator, the network MSE over time, a verdict (stable / "
            "diverging / unbounded / undecided / diverged at step k, by the rule of "
            "netsim.verdicts: for fixed delays the exact analysis of the joint system of "
            "plant state and error decides, otherwise the measured growth; on an unstable "
            "plant, the float64 precision horizon), and the steady-state MSE of a stable "
            "run or, for any other verdict, its last trusted MSE and growth. The same "
            "seed gives the same numbers, bit for bit."
        ),
        epilog=VERDICT_TABLE, formatter_class=TableEpilogFormatter,
    )
    run.add_argument("scenario", help="built-in scenario name (see 'netsim scenarios') or a "
                     "path to a scenario TOML file")
    run.add_argument("--steps", type=int, help="number of steps K (default: the scenario's)")
    run.add_argument("--trials", type=int, help="Monte Carlo trials M (default: the scenario's)")
    run.add_argument("--seed", type=int, help="root seed of the trial randomness")
    run.add_argument("--tau", type=int, help="override the scenario's delay bound tau "
                     "(homogeneous, heterogeneous or time-varying delays)")
    run.add_argument("--estimators", metavar="NAME,...",
                     help="comma-separated estimator families to run instead of the "
                     "scenario's run.estimators: any registered family ('netsim "
                     "estimators' lists them), an installed entry point, or "
                     "module:attribute of your own estimator (looked for in the "
                     "scenario's folder, the current directory and the Python path)")
    run.add_argument("--trace", metavar="FILE.mcap",
                     help="record every run to MCAP: FILE.mcap for a single run, else one "
                     "file per estimator and trial, FILE.<estimator>.trial<k>.mcap")
    run.add_argument("--force", action="store_true",
                     help="overwrite trace files that exist (default: refuse, naming them)")
    run.add_argument("--time-origin", metavar="WHEN",
                     help="with --trace: log_time of simulation time 0, an ISO 8601 UTC "
                     "date-time (2026-05-01T12:00:00Z) or seconds since 1970 (0: log_time "
                     "= simulation time); default 2000-01-01T00:00:00Z, fixed so traces "
                     "are bit-reproducible")
    run.add_argument("--layout", action="store_true",
                     help="with --trace: write a Foxglove layout beside each trace, "
                     "FILE.layout.json for FILE.mcap (see 'netsim layout')")
    run.add_argument("--trace-format", type=int, choices=[2, 3], default=None,
                     metavar="{2,3}",
                     help="with --trace: 3 (default) one message per step and kind "
                     "(/agents/estimate holds every agent's estimate; 8 topics at any "
                     "network size); 2 one message per agent and per link event "
                     "(/agent_<i>/estimate, /link_<j>_<i>/sent ...)")
    run.add_argument("--trace-compression", choices=["none", "zstd"], default=None,
                     help="with --trace: chunk compression (default: none for format 3, "
                     "whose float64 arrays zstd shrinks by a fifth to a third for about half "
                     "again the trace's cost; zstd for format 2)")
    run.add_argument("--engine", default="auto", choices=["auto", "vectorised", "events"],
                     help="vectorised: all trials advance together in numpy arrays (fast; "
                     "same results and traces as the kernel, to round-off); events: the "
                     "SimPy event kernel, the reference; auto (default): vectorised")
    run.add_argument("--noise", type=float, default=None, metavar="VAR",
                     help="process and measurement noise variance (Q = VAR I, R_i = VAR I)")
    run.add_argument("--process-noise", type=float, default=None, metavar="VAR",
                     help="process noise variance (Q = VAR I)")
    run.add_argument("--measurement-noise", type=float, default=None, metavar="VAR",
                     help="measurement noise variance (every R_i = VAR I)")
    run.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    from netsim.aoiargs import add_aoi_arguments

    add_aoi_arguments(run)
    run.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    run.add_argument("--live", nargs="?", const="127.0.0.1:8765", metavar="ADDR",
                     help="serve the run to Foxglove (or any viewer that speaks the "
                     "foxglove.sdk.v1 WebSocket subprotocol) at ADDR (default "
                     "127.0.0.1:8765; needs pip install 'netsim[live]'): the trace's "
                     "topics and schemas, paced in simulation time; waits for a viewer, "
                     "then serves until Ctrl-C (see netsim.live)")
    run.add_argument("--speed", type=float, default=1.0, metavar="X",
                     help="with --live: simulation seconds per wall-clock second (default 1; "
                     "0 or inf: as fast as possible)")
    run.add_argument("--live-linger", type=float, default=None, metavar="SECONDS",
                     help="with --live: end this long after the run was served (default: "
                     "serve until Ctrl-C)")

    design = sub.add_parser(
        "design",
        help="design the block-diagonal gains K of a scenario and report tau*",
        description=(
            "Design block-diagonal innovation gains K_i for SCENARIO with cvxpy: the "
            "block-diagonal Lyapunov LMI of LCSYS2022 eq. (13) with bisection on the decay "
            "rate, the cone-complementarity iteration with a full Lyapunov matrix (small "
            "networks), a delay-bound design against P kron A^(tau1+1) (LCSYS2022 "
            "Discussion 5), and an optional direct refinement of rho(A-hat). By default it "
            "designs what the scenario's [gains] table says, i.e. the gains netsim run, "
            "analyze and bench use; --method, --tau1 and --refine override it. rho(A-hat) "
            "of the returned gains is always recomputed with numpy, whatever the solver said."
        ),
    )
    design.add_argument("scenario", help="built-in scenario name or TOML file")
    design.add_argument("--method", default=None, choices=["auto", "lmi", "ccl", "local"],
                        help="override the scenario's [gains] method (default: the "
                        "scenario's, which netsim run uses); auto: cone-complementarity "
                        "for small networks, block-diagonal LMI up to N n = 1500, the local "
                        "design above; local: L_i = gamma C_i^T (C_i C_i^T)^+ with the "
                        "exact rho (any size)")
    design.add_argument("--tau1", type=int, default=None,
                        help="design to tolerate delays up to tau1 (default: the scenario's "
                        "gains.tau1, 0 if unset: delay-free)")
    design.add_argument("--refine", action="store_true",
                        help="then minimise rho(A-hat) directly from that design "
                        "(reported as uncertified unless a certificate is found)")
    design.add_argument("--json", action="store_true", help="print one JSON object on stdout")

    analyze = sub.add_parser(
        "analyze",
        help="exact spectral radii of the augmented closed loop beside the papers' bounds",
        description=(
            "For SCENARIO and its gains: rho(A-hat) delay-free, Theorem 1's tau* "
            "(contiguous and isolated passing values), and for homogeneous delays "
            "0..TAU_MAX the exact spectral radius of the augmented closed loop "
            "(compensated, LCSYS2022 eq. 9-10; uncompensated, delay-tolerant eq. 11) beside "
            "the LCSYS2022 eq. (26) bound and the delay-tolerant bound rho(A-hat)^(1/(tau+1)); "
            "a bound that the exact value violates is flagged with both numbers."
        ),
    )
    analyze.add_argument("scenario", help="built-in scenario name, TOML file, or an MCAP trace "
                         "(FILE.mcap: the analytics are recomputed from the trace alone: "
                         "delay-free rho, exact rho of each delay pattern seen, the bounds at "
                         "the observed maximum delay, the realised growth rate and the "
                         "empirical decay rate of the error, each with a verdict)")
    analyze.add_argument("--tau-max", type=int, default=30,
                         help="largest homogeneous delay analysed (default 30)")
    analyze.add_argument("--workers", type=int, default=None, metavar="W",
                         help="processes for the independent delay patterns (default: this "
                         "machine's cores when the estimated work is at least a second, "
                         "else 1; NETSIM_WORKERS sets the default); the output is the same")
    analyze.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    analyze.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")

    insp = sub.add_parser(
        "inspect",
        help="summarise an MCAP trace written by 'netsim run --trace'",
        description=(
            "What is in TRACE (scenario, estimator, trial, topics and counts, steps, agents), "
            "per-link delay statistics (min, mean, max, histogram), drops and reorderings, "
            "per-agent MSE, and whether the file is truncated (a file whose writer was "
            "killed is still read: every complete chunk is recovered and counted)."
        ),
    )
    insp.add_argument("trace", help="an MCAP file written by netsim")
    insp.add_argument("--json", action="store_true", help="print one JSON object on stdout")

    replay = sub.add_parser(
        "replay",
        help="rebuild A-hat[k] from a trace's delays and rerun the error recursion",
        description=(
            "Rebuild each step's augmented closed-loop matrix A-hat[k] from the effective "
            "delays recorded in TRACE, rerun e_k = A-hat[k] e_{k-1} + eta_k with the noise "
            "recorded in the trace, and report the largest deviation from the recorded "
            "errors: with the exact eta_k from the estimator's equations (floating-point "
            "round-off for the compensating estimator) and with the paper's eta_k "
            "(LCSYS2022 eq. 11), saying why they differ."
        ),
    )
    replay.add_argument("trace", help="an MCAP file written by netsim")
    replay.add_argument("--json", action="store_true", help="print one JSON object on stdout")

    plot = sub.add_parser(
        "plot",
        help="PNG of MSE over time, delay histogram and spectral radius vs bounds",
        description=(
            "Plot one or more traces (e.g. the estimators of one run) into one PNG: MSE "
            "over time per estimator (log scale), a delay histogram, and the exact "
            "spectral radius of the augmented closed loop versus the papers' bounds."
        ),
    )
    plot.add_argument("traces", nargs="+", metavar="TRACE", help="MCAP files written by netsim")
    plot.add_argument("-o", "--output", required=True, metavar="FILE.png", help="PNG to write")
    plot.add_argument("--force", action="store_true", help="overwrite an existing PNG")
    plot.add_argument("--json", action="store_true",
                      help="print {\"output\": FILE.png, ...} as JSON on stdout")

    layout = sub.add_parser(
        "layout",
        help="Foxglove layout JSON for a trace (error norms, state vs estimates, delays, "
        "drops, age of information)",
        description=(
            "Write a Foxglove layout for a trace written by 'netsim run --trace' (format "
            "3 or 2): Plot panels of each agent's error norm, the state against the "
            "agents' estimates, the effective delay per link, message delays, drops and, "
            "for AoI traces, the freshness indices (format 3: indexed message paths such "
            "as /agents/estimate.error_norm[2]). In Foxglove: open the .mcap file, then "
            "Layouts > Import from file. Optionally a PNG of the same panels drawn from "
            "the trace."
        ),
    )
    layout.add_argument("trace", help="an MCAP file written by netsim (format 2 or 3)")
    layout.add_argument("-o", "--output", metavar="FILE.json",
                        help="layout file to write (default: beside the trace, "
                        "TRACE.layout.json)")
    layout.add_argument("--figure", metavar="FILE.png",
                        help="also draw the layout's panels from the trace's data (matplotlib)")
    layout.add_argument("--tabs", metavar="TAB,...",
                        help="with --figure: draw only these tabs (e.g. Errors,Drops)")
    layout.add_argument("--force", action="store_true",
                        help="overwrite an existing layout file (and --figure PNG)")
    layout.add_argument("--json", action="store_true",
                        help="print {\"layout\": FILE.json, ...} as JSON on stdout")

    claims = sub.add_parser(
        "claims", help="the papers' statements as executable checks (refuted / proved for "
        "this instance / no counterexample in M instances / undecided)",
        description="Run the claim registry's checks (netsim.claims): one line per claim "
        "with its verdict, its evidence and the deciding numbers. Claims stated over a "
        "class of systems are searched for counterexamples: a counted number of instances "
        "drawn from --seed (random, a family known to be hard, and an optimiser over the "
        "hypothesis set), so the same seed gives the same verdicts on any machine at any "
        "load. A counterexample is shrunk and verified by exact analysis and by "
        "simulation. A Markdown report and the counterexample scenarios (netsim analyze "
        "FILE / netsim run FILE reproduce them) go to --out.",
        epilog=VERDICT_TABLE, formatter_class=TableEpilogFormatter)
    claims.add_argument("names", nargs="*", metavar="PAPER|CLAIM",
                        help="papers (LCSYS2022, delay-tolerant, aoi, dkfe) or claim ids; "
                        "default all")
    claims.add_argument("--instances", type=int, default=None, metavar="M",
                        help="random instances per search (default: each search's own, "
                        "400 for the LCSYS2022 Theorem 1 search; its hard family and "
                        "optimiser scale with M)")
    claims.add_argument("--budget", type=float, default=None, metavar="SECONDS",
                        help="cut each search short after this many seconds (default: no "
                        "time limit). A search cut short before it finds a counterexample "
                        "is 'undecided', never evidence that a claim holds")
    claims.add_argument("--seed", type=int, default=0, help="seed of the search (default 0)")
    claims.add_argument("--out", default="claims-out",
                        help="folder of the report and scenarios (default ./claims-out)")
    claims.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    claims.add_argument("--no-progress", action="store_true", help="no progress bar")

    scen = sub.add_parser("scenarios", help="list the built-in scenarios",
                          description="List the built-in scenarios with their descriptions.")
    scen.add_argument("--json", action="store_true", help="print one JSON object on stdout")

    est = sub.add_parser(
        "estimators", help="list the registered estimator families",
        description="List every estimator family a scenario's run.estimators or "
        "--estimators can name: the built-in ones and those of installed packages "
        "(entry-point group netsim.estimators), each with where it comes from and what "
        "it declares (paper, gains, time-stamps, error recursion, vectorised form). A "
        "family of your own can also be named as module:attribute; it is not listed "
        "until a command resolves it.")
    est.add_argument("--json", action="store_true", help="print one JSON object on stdout")

    fusion = sub.add_parser(
        "fusion",
        help="dkfe paper: sink nodes, random dimensionality reduction, delayed fusion centre",
        description=(
            "The distributed Kalman fusion estimator of the dkfe paper: sink nodes with "
            "local Kalman filters send r_i randomly chosen components over delayed links "
            "to a fusion centre that forms compensating estimates (15) and fuses them with "
            "the optimal weights (31)-(32) from the exact error covariances (DKFE), or with "
            "the steady-state weights (79) (SDKFE). 'table1': Example 1's Table I; "
            "'example2': Example 2's steady-state weights and condition (77) against the "
            "printed numbers; 'run': Monte Carlo of an example in the SimPy kernel."
        ),
    )
    fsub = fusion.add_subparsers(dest="fusion_command", metavar="WHAT")
    f_t1 = fsub.add_parser(
        "table1", help="Example 1: conditions (75), (76), (74) over gamma_11 = 0..1 (Table I)",
        description="Example 1 (d_1 = 0): the LMI (75) with cvxpy, the exact mean-square "
        "radius, (76) and (74) for gamma_11 = 0, 0.1, ..., 1, beside the paper's Table I.")
    f_t1.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    f_e2 = fsub.add_parser(
        "example2", help="Example 2: steady-state weights (79) and condition (77)",
        description="Example 2 (d_1 = 1, d_2 = 2): the steady-state weights, condition (77), "
        "(74), Theorem 2's LMIs and Phi_K, each against the printed number.")
    f_e2.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    f_run = fsub.add_parser(
        "run", help="Monte Carlo: sinks, CSEs, DKFE, SDKFE, ODKFE, centralised KF",
        description="Monte Carlo trials of an example: empirical MSE of every estimator "
        "beside the trace of its exact error covariance, and the stability conditions.")
    f_run.add_argument("example", choices=["dkfe-example1", "dkfe-example2"])
    f_run.add_argument("--steps", type=int, default=100, help="steps K (default 100)")
    f_run.add_argument("--trials", type=int, default=50, help="Monte Carlo trials (default 50)")
    f_run.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    f_run.add_argument("--engine", choices=["events", "vectorised", "kernel", "lockstep"],
                       default="events",
                       help="events (alias kernel): each trial in the SimPy kernel "
                       "(default); vectorised (alias lockstep): all trials at once")
    f_run.add_argument("--time-varying", action="store_true",
                       help="random link delays in 0..d_i - 1, padded to d_i at the centre "
                       "(Remark 1; kernel engine)")
    f_run.add_argument("--gamma", type=float, default=None, metavar="G",
                       help="dkfe-example1 only: gamma_11, the probability that the sink "
                       "sends component 1 (eq. 84; default 0.5), in [0, 1] (Figs. 3-4)")
    f_run.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    if only in (None, "bench"):
        from netsim.bench import add_bench_parser

        add_bench_parser(sub)
    elif only == "":  # the listing only: importing netsim.bench costs 0.2-0.3 s
        sub.add_parser("bench", help=_BENCH_HELP)
    if only in (None, "reproduce"):
        from netsim.reproduce import add_reproduce_parser

        add_reproduce_parser(sub)
    elif only == "":  # the listing only: netsim.reproduce imports the claims and plots
        sub.add_parser("reproduce", help=REPRODUCE_HELP)
    if only in (None, "", "calibrate"):  # netsim.calibrate: only where it is listed
        from netsim.calibrate import add_calibrate_parser

        add_calibrate_parser(sub)
    for name, command in sub.choices.items():
        _add_no_cache(name, command)
    return parser


def _add_no_cache(name: str, parser: argparse.ArgumentParser) -> None:
    """``--no-cache`` on every command that designs gains (and on bench's subcommands)."""
    if name in ("run", "design", "analyze"):
        parser.add_argument("--no-cache", action="store_true",
                            help="design the gains afresh instead of reading them from the "
                            "gain cache (netsim.gaincache; NETSIM_CACHE_DIR=off disables it)")
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and name == "bench":
            for sub_name, sub_parser in action.choices.items():
                _add_no_cache("run" if sub_name in ("delay-tolerance", "sweep") else sub_name,
                              sub_parser)


def _families(scenario: Any, option: str | None) -> list[Any]:
    """Resolve the scenario's estimators, or those of ``--estimators``, in the registry.

    ``--estimators`` may name any registered family, ``module:attribute`` of a user's
    estimator or an installed entry point, not only the scenario's own.
    """
    from netsim.estimators.registry import FamilyError, resolve_families
    from netsim.runner import scenario_folder

    listed = scenario.estimators
    key = "run.estimators"
    try:  # the scenario's own (so --estimators may use their short names)
        own = resolve_families(listed, key, scenario_folder(scenario))
    except FamilyError as exc:
        raise CommandError(f"scenario {scenario.source or scenario.name}: {exc}") from None
    if option is None:
        return own
    if option is not None:
        listed = tuple(f.strip() for f in option.split(",") if f.strip())
        if not listed:
            raise CommandError("--estimators: empty list; name at least one estimator")
        key = "--estimators"
    try:
        return resolve_families(listed, key, scenario_folder(scenario))
    except FamilyError as exc:
        where = "" if option is not None else f"scenario {scenario.source or scenario.name}: "
        raise CommandError(f"{where}{exc}") from None


def _apply_noise(args: argparse.Namespace, scenario: Any) -> Any:
    """``--noise VAR`` (both), ``--process-noise``, ``--measurement-noise``."""
    noise = getattr(args, "noise", None)
    process = getattr(args, "process_noise", None)
    measurement = getattr(args, "measurement_noise", None)
    for label, v in (("--noise", noise), ("--process-noise", process),
                     ("--measurement-noise", measurement)):
        if v is not None and not (v >= 0 and math.isfinite(v)):
            raise CommandError(f"{label} must be a finite variance >= 0, got {v}")
    if noise is None and process is None and measurement is None:
        return scenario
    return scenario.with_noise(noise if process is None else process,
                               noise if measurement is None else measurement)


def _positive(value: int | None, option: str) -> None:
    if value is not None and value < 1:
        raise CommandError(f"{option} must be a positive integer, got {value}")


def _cmd_run(args: argparse.Namespace) -> int:
    if getattr(args, "live", None) is not None:  # netsim.live serves the run, then calls back
        from netsim.live import run_live

        return run_live(args, _cmd_run)
    from netsim.estimators.contract import EstimatorFailure
    from netsim.models.scenario import ScenarioError, resolve_scenario
    from netsim.runner import TraceWriteError, run_monte_carlo

    _positive(args.steps, "--steps")
    _positive(args.trials, "--trials")
    if args.seed is not None and args.seed < 0:
        raise CommandError(f"--seed must be a non-negative integer, got {args.seed}")
    from netsim.aoiargs import apply_aoi_arguments
    from netsim.budget import check_counts

    def precheck(counts: Any) -> None:
        """Refuse from the counts alone what cannot fit, before the network is built."""
        if args.tau is not None:
            counts = replace(counts, max_delay=int(args.tau))
        check_counts(counts, args.steps, args.trials,
                     ["events", "vectorised"] if args.engine == "auto" else [args.engine],
                     steps_name="--steps" if args.steps is not None else "run.steps",
                     trials_name="--trials" if args.trials is not None else "run.trials")

    try:
        scenario = resolve_scenario(args.scenario, precheck)
        if args.tau is not None:
            try:
                scenario = scenario.with_tau(args.tau)
            except ScenarioError as exc:
                raise CommandError(f"--tau {args.tau}: {exc}") from None
        scenario = _apply_noise(args, scenario)
        scenario = apply_aoi_arguments(args, scenario)
    except ScenarioError as exc:
        where = f"scenario {args.scenario}"
        raise CommandError(f"{where}: {exc}") from None
    declared = _families(scenario, args.estimators)
    families = tuple(f.name for f in declared)
    from netsim.aoiargs import check_aoi_arguments

    try:
        check_aoi_arguments(args, declared)
    except ScenarioError as exc:
        raise CommandError(f"scenario {args.scenario}: {exc}") from None
    from netsim.budget import guard_run
    from netsim.runner import check_agents, choose_engine, kernel_fallbacks, planned_engines

    for note in guard_run(scenario, args.steps, args.trials,
                          planned_engines(args.engine, declared, scenario),
                          args.trace):  # before designing gains
        sys.stderr.write(f"netsim run: note: {note}\n")
    gains = gains_if_needed(scenario, declared, args.scenario)

    try:
        check_agents(scenario, declared, gains,
                     "run.estimators" if args.estimators is None else "--estimators")
    except ValueError as exc:
        raise CommandError(f"scenario {args.scenario}: {exc}") from None
    try:
        choose_engine(args.engine, declared, traced=args.trace is not None,
                      scenario=scenario)
    except ValueError as exc:
        raise CommandError(f"--engine {args.engine}: scenario {args.scenario}: {exc}"
                           ) from None
    note_kernel_fallbacks("run", kernel_fallbacks(args.engine, declared, scenario))
    if scenario.timing is not None and args.engine == "auto":  # timed lockstep or kernel
        from netsim.runner import timed_engine_line

        line = timed_engine_line(args.engine, declared, scenario,
                                 traced=args.trace is not None)
        if line is not None:
            sys.stderr.write(f"netsim run: note: {line}\n")
    trials = args.trials or scenario.trials
    trace_options = _trace_options(args)
    if args.trace is not None:
        _check_traces(args.trace, families, trials, args.force,
                      [args.scenario] if os.path.isfile(args.scenario) else [])
    total = trials * len(families)
    bar = progress_bar(total=total, desc=f"netsim run {scenario.name}", unit="trial",
                       disable=True if args.no_progress else None)
    written: list[str] = []
    done = [0]

    def _progress(count: int) -> None:
        done[0] += count
        bar.update(count)

    from netsim.interrupt import graceful_interrupts

    try:
        with graceful_interrupts():
            result = run_monte_carlo(
                scenario, steps=args.steps, trials=args.trials, seed=args.seed,
                families=families, progress=_progress, gains=gains, trace=args.trace,
                on_trace=_on_trace(args, written), engine=args.engine,
                trace_options=trace_options,
            )
    except KeyboardInterrupt:
        family = families[min(done[0] // trials, len(families) - 1)]
        where = f"estimator {family}, trial {done[0] % trials} of {trials}"
        kept = f"; trace files finished: {len(written)}" if args.trace else ""
        raise CommandError(f"interrupted during {where} ({done[0]} of {total} trials "
                           f"done){kept}", EXIT_INTERRUPTED) from None
    except TraceWriteError as exc:
        bar.close()
        return _partial_run(args, exc, scenario, written, families)
    except OSError as exc:
        raise CommandError(f"cannot write trace {args.trace}: "
                           f"{exc.strerror or exc}") from None
    except EstimatorFailure as exc:  # a plugin's step() raised: name it, one line
        raise CommandError(str(exc)) from None
    except ValueError as exc:
        # e.g. a trace-driven link asked for more messages than its trace recorded
        raise CommandError(f"scenario {args.scenario}: {exc}") from None
    finally:
        bar.close()
    data = _run_data(result, scenario, None if getattr(args, "live_scratch", False)
                     else args.trace, written)
    if args.json:
        json.dump(data, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(_format_run(data))
    return 0


def _trace_options(args: argparse.Namespace) -> dict[str, Any]:
    """``--time-origin``, ``--layout``, ``--trace-format`` and ``--trace-compression``
    (they need ``--trace``)."""
    for flag, value in (("--time-origin", args.time_origin), ("--layout", args.layout),
                        ("--trace-format", args.trace_format),
                        ("--trace-compression", args.trace_compression)):
        if value not in (None, False) and args.trace is None:
            raise CommandError(f"{flag} needs --trace FILE.mcap")
    options: dict[str, Any] = {}
    if getattr(args, "live_tap", None) is not None:  # netsim.live's tee
        options["writer_tap"] = args.live_tap
    if args.trace_format is not None:
        options["trace_format"] = args.trace_format
    if args.trace_compression is not None:
        options["compression"] = args.trace_compression
    if args.time_origin is None:
        return options
    from netsim.traces.schemas import parse_time_origin

    try:
        options["time_origin_ns"] = parse_time_origin(args.time_origin)
    except ValueError as exc:
        raise CommandError(f"--time-origin: {exc}") from None
    return options


def _on_trace(args: argparse.Namespace, written: list[str]) -> Any:
    """Collect each finished trace; with ``--layout`` write its Foxglove layout."""
    if not args.layout:
        return written.append

    def finished(path: str) -> None:
        written.append(path)
        from netsim.traces.layout import write_layout
        from netsim.traces.reader import read_status

        status = read_status(path)
        if status is not None and status.get("status") in ("interrupted", "failed"):
            return  # the run stops; no layout for a file left by an interruption
        try:
            write_layout(path)
        except (OSError, ValueError) as exc:
            raise CommandError(f"cannot write the layout of {path}: {exc}") from None

    return finished


def _check_traces(trace: str, families: Sequence[str], trials: int, force: bool,
                  inputs: Sequence[str] = ()) -> None:
    """Refuse --trace paths that are special files, directories, symbolic links, in a
    missing or read-only directory, existing files without --force, or one of the
    command's inputs (the scenario file), naming the file (:mod:`netsim.outfiles`)."""
    from netsim.outfiles import same_file
    from netsim.runner import trace_files
    from netsim.traces.recorder import check_trace_target

    try:
        check_trace_target(trace, force=True)  # the base: no special file, a real folder
        for path in trace_files(trace, families, trials):
            for source in inputs:
                if same_file(path, source):
                    raise ValueError(f"{path}: is also an input of this command ({source}); "
                                     "choose another trace file")
            check_trace_target(path, force=force)
    except (ValueError, OSError) as exc:
        raise CommandError(f"--trace {exc}") from None


def _partial_run(args: argparse.Namespace, exc: Any, scenario: Any, written: list[str],
                 families: Sequence[str]) -> int:
    """A trace could not be written: print what finished, then one error line."""
    reason = exc.cause.strerror or str(exc.cause)
    message = f"cannot write trace {exc.path}: {reason}"
    partial = exc.partial
    finished = sum(e.trials_finished or partial.trials
                   for e in partial.estimators.values()) if partial else 0
    if partial is not None and (partial.estimators or args.json):
        data = _run_data(partial, scenario, args.trace, written)
        data["error"] = message
        data["incomplete_trace"] = exc.path
        data["families"] = list(families)
        if args.json:
            json.dump(data, sys.stdout, indent=2, allow_nan=False)
            sys.stdout.write("\n")
        elif partial.estimators:
            sys.stdout.write(_format_run(data))
    kept = (f"; results of the {finished} finished trials printed, {len(written)} traces "
            "complete" if finished else "; no trial had finished")
    sys.stderr.write(f"netsim run: error: {message} (the file is incomplete{kept})\n")
    return EXIT_BAD_INPUT


def _run_data(result: Any, scenario: Any, trace: str | None,
              written: list[str]) -> dict[str, Any]:
    data = result.to_dict()
    kind, quantile = delay_bound_kind(scenario)
    data["delay_bound"] = {"value": data["scenario"]["delays"]["bound"], "kind": kind,
                           "quantile": quantile, "realised_max": None}
    if trace:
        data["traces"] = list(written)
        data["delay_bound"]["realised_max"] = _trace_max_delay(written)
    return data


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, str):
        return value
    if value == 0 or (1e-3 <= abs(value) < 1e4):
        return f"{value:.4f}"
    return f"{value:.3e}"


def delay_bound_kind(scenario: Any) -> tuple[str, float | None]:
    """What the scenario's delay bound ``summary()['delays']['bound']`` is: ``("bound",
    None)`` a hard bound no delay exceeds, ``("links.bound", None)`` the bound the
    ``[links]`` table states, or ``("quantile", q)`` the q-quantile of an unbounded
    delay distribution of the ``[links]`` table (delays beyond it do occur) or of a
    ``[network.medium]`` pilot run's step delays (``("network.medium.bound", None)``
    when the table states its bound)."""
    import math as _math

    from netsim.models.linkmodels import NOMINAL_QUANTILE

    medium = getattr(scenario, "medium", None)
    if medium is not None:
        from netsim.models.medium import PILOT_QUANTILE

        return (("network.medium.bound", None) if medium.bound is not None
                else ("quantile", PILOT_QUANTILE))
    spec = scenario.link_spec
    if spec is None:
        return "bound", None
    if spec.bound is not None:
        return "links.bound", None
    for link in scenario.links:
        cfg = spec.config(link).delay
        upper = getattr(getattr(cfg, "distribution", None), "upper", None)
        if upper is not None and not _math.isfinite(upper):
            return "quantile", NOMINAL_QUANTILE
    return "bound", None


def _trace_max_delay(paths: Sequence[str]) -> int | None:
    """The largest delivered step delay recorded in the traces' ``run_status``."""
    from netsim.traces.reader import read_status

    worst = None
    for path in paths:
        value = (read_status(path) or {}).get("max_delay_steps", "")
        if value.lstrip("-").isdigit() and int(value) >= 0:
            worst = int(value) if worst is None else max(worst, int(value))
    return worst


def _format_delays(s: dict[str, Any], bound: dict[str, Any] | None) -> str:
    d = s["delays"]
    text = f"delays: {d['model']}, tau = {d['tau']}; bound {d['bound']}"
    b = bound or {}
    kind = b.get("kind", "bound")
    m = s.get("medium")
    if m is not None:
        text = (f"delays: network medium {m['model']} ({m['bit_rate']:g} bit/s, "
                f"{m['packet_bits']:g} bits = {m['transmission_time'] * 1e3:.3g} ms a packet); "
                f"bound {d['bound']}")
        if kind == "quantile":
            text += (f" (the {b['quantile']:.1%} quantile of a pilot run's step delays; "
                     "delays beyond it occur)")
        elif kind == "network.medium.bound":
            text += " (network.medium.bound)"
    elif kind == "quantile":
        text += (f" (the {b['quantile']:.1%} quantile of the links' unbounded delay "
                 "distributions; delays beyond it occur)")
    elif kind == "links.bound":
        text += " (links.bound)"
    if b.get("realised_max") is not None:
        text += f"; realised max step delay {b['realised_max']} (traces)"
    return text


def _format_run(data: dict[str, Any]) -> str:
    s = data["scenario"]
    lines = [
        f"scenario {s['name']} ({s['source']}): n = {s['n_states']} states, "
        f"N = {s['n_agents']} agents, {s.get('n_links', len(s.get('links', ())))} links",
        _format_delays(s, data.get("delay_bound")),
        f"run: {data['steps']} steps x {data['trials']} trials, seed {data['seed']}, "
        f"{data.get('engine', 'events')} engine",
    ]
    g = data["gains"]
    if g is not None:
        from netsim.estimators.gains import certificate_text

        lines.append(
            f"gains: {g['method']} ({g['solver']}); delay-free "
            f"{certificate_text(g['certified'], g['status'], g['rho_delay_free'])}"
        )
    a = data.get("analytics") or {}
    for section in a.values():  # the families' own analytics (their papers' bounds)
        if isinstance(section, dict):
            lines += section.get("summary_lines", [])
    if "delay_bound" in a:
        lines.append(
            f"analytics at tau = {a['delay_bound']}: tau* (LCSYS2022 Thm 1) = "
            f"{tau_star_text(a['tau_star'])}, "
            f"eq. (26) bound = {_fmt(a['bound_lcsys_eq26'])}, delay-tolerant bound "
            f"rho^(1/(tau+1)) = {_fmt(a['bound_delay_tolerant'])}"
        )
        if a.get("note"):
            lines.append(f"analytics: {a['note']}")
        if a.get("rho_exact_compensated") is not None:
            lines.append(
                f"exact rho of the augmented closed loop for the realised delays: "
                f"compensated (eq. 9) = {_fmt(a['rho_exact_compensated'])}, "
                f"uncompensated (eq. 11, the error recursion alone) = "
                f"{_fmt(a['rho_exact_uncompensated'])}"
            )
            from netsim.models.jointsystem import RECURSION_UNCOMPENSATED

            moving = [j for j in (a.get("joint_system") or {}).values()
                      if j.get("recursion") == RECURSION_UNCOMPENSATED]
            if moving and moving[0].get("forced_eigenvalues"):
                lines.append(
                    "  eq. (11) does not apply here: on a moving state the uncompensated "
                    "error is also forced by (A^(r+1) - A) x_(k-1-r), which eq. (11) leaves "
                    "out; the joint system of state and error below gives its growth")
    joint = [(name, e["verdict_detail"]["analysis"]) for name, e in data["estimators"].items()
             if (e.get("verdict_detail") or {}).get("analysis")]
    if joint:
        lines.append("joint system of plant state and error (exact, fixed delays):")
        for name, j in joint:
            forced = _fmt(j["rho_forcing"]) if j["forced_eigenvalues"] else "none"
            growth = {"geometric": f"geometric, MSE x{_fmt(j['mse_growth_factor'])}/step",
                      "polynomial": "polynomial (e.g. linear), MSE unbounded",
                      "bounded": "bounded"}.get(j["growth"], j["growth"])
            lines.append(f"  {name}: rho = {_fmt(j['rho'])} = max(error recursion "
                         f"{_fmt(j['rho_error_recursion'])}, forced plant modes {forced}): "
                         f"{growth}")
    elif a.get("joint_system_note"):
        lines.append(f"joint system of plant state and error: {a['joint_system_note']}")
    lines.append("")
    from netsim.verdicts import BEYOND_HORIZON

    marks = list(next(iter(data["estimators"].values()))["mse_at"])
    header = f"{'estimator':<16}{'verdict':<22}{'steady MSE':>12}{'growth/step':>13}  " + " ".join(
        f"{'MSE@' + m:>11}" for m in marks
    )
    lines.append(header)
    lines.append("-" * len(header))
    for name, e in data["estimators"].items():
        verdict = e["verdict"]
        if e["diverged_trials"]:
            first = min(d["step"] for d in e["diverged_trials"])
            verdict = f"diverged at step {first} ({len(e['diverged_trials'])} trials)"
        # a steady MSE belongs to stable runs only (netsim.verdicts.has_steady_state)
        row = f"{name:<16}{verdict:<22}{_fmt(e.get('steady_state_mse')):>12}"
        row += f"{_fmt(e['growth_rate']):>13}  "
        untrusted = set(e.get("mse_at_beyond_horizon") or ())
        row += " ".join(f"{BEYOND_HORIZON if m in untrusted else _fmt(e['mse_at'][m]):>11}"
                        for m in marks)
        lines.append(row)
    for name, e in data["estimators"].items():  # [time] runs (netsim.timedkernel)
        if (e.get("messages") or {}).get("rate") is not None:
            lines.append(f"{name}: message rate {_fmt(e['messages']['rate'])} estimates sent "
                         f"per agent per time unit ({_fmt(e['messages']['send_fraction'])} "
                         "of its updates)")
    for name, e in data["estimators"].items():
        if e.get("mse_at_beyond_horizon"):
            lines.append(f"{name}: MSE@ {', '.join(e['mse_at_beyond_horizon'])} not shown "
                         f"{BEYOND_HORIZON}: beyond the float64 precision horizon at step "
                         f"{e['precision_horizon']} (rounding of the state, not trusted)")
    for name, e in data["estimators"].items():
        if "steady_state_mse" not in e and e.get("last_trusted_step") is not None:
            detail = e.get("verdict_detail") or {}
            exact = (detail.get("analysis") or {}) if detail.get("basis") == \
                "exact analysis" else {}
            growth = (f"MSE growth x{_fmt(exact['mse_growth_factor'])}/step (exact "
                      "analysis), " if exact.get("growth") == "geometric" else
                      "MSE growth polynomial (exact analysis), "
                      if exact.get("growth") == "polynomial" else "")
            lines.append(f"{name}: no steady MSE ({e['verdict']}): last trusted MSE "
                         f"{_fmt(e['last_trusted_mse'])} at step {e['last_trusted_step']}; "
                         f"{growth}measured x{_fmt(e['growth_rate'])}/step")
    for e in data["estimators"].values():
        lines += (e.get("report") or {}).get("summary_lines", [])
    for name, e in data["estimators"].items():
        detail = e.get("verdict_detail")
        if detail and not e["diverged_trials"]:
            lines.append(f"{name}: {e['verdict']} ({detail['basis']}): {detail['reason']}")
    for name, e in data["estimators"].items():
        if e.get("trials_finished") is not None:
            lines.append(f"{name}: only {e['trials_finished']} of {data['trials']} trials "
                         "finished (a trace could not be written)")
    missing = [f for f in data.get("families", []) if f not in data["estimators"]]
    if data.get("error"):
        lines.append(f"INCOMPLETE: {data['error']}"
                     + (f"; not run: {', '.join(missing)}" if missing else ""))
    lines.append("")
    lines.append("MSE: (1/N) sum_i ||x_k - xhat^i_k||^2 averaged over non-diverged trials; "
                 "growth/step: exp(mean slope of each trial's log MSE) over the second half "
                 "of the trusted steps; verdict rule: netsim.verdicts.")
    return "\n".join(lines) + "\n"


def _load(name: str, tau: int | None = None, what: str | None = None):
    from netsim.models.scenario import ScenarioError, resolve_scenario

    try:
        scenario = resolve_scenario(name)
        if tau is not None:
            scenario = scenario.with_tau(tau)
        if what is not None:  # the command's analytics need the dense P
            scenario = scenario.densified(what)
    except ScenarioError as exc:
        raise CommandError(f"scenario {name}: {exc}") from None
    return scenario


def _design_dict(design) -> dict[str, Any]:
    return {
        "method": design.method,
        "solver": design.solver,
        "status": design.status,
        "certified": design.certified,
        "certified_rate": _num(design.certified_rate),
        "rho_delay_free": _num(design.rho),
        "design_tau": getattr(design, "design_tau", 0),
        "rho_design": _num(getattr(design, "rho_design", design.rho)),
        "message": design.message,
        "K": [np.asarray(K).tolist() for K in design.K],
        "L": [np.asarray(L).tolist() for L in design.L],
    }


def _gains_label(request: dict[str, Any]) -> str:
    label = request["method"]
    if request["refine_from"]:
        label += f" from {request['refine_from']}"
    return label + (f", tau1 = {request['tau1']}" if request["tau1"] else "")


def _cmd_design(args: argparse.Namespace) -> int:
    from netsim.estimators.gains import GainDesignError, design_for_scenario, design_request
    from netsim.models.augmented import tau_star_report
    from netsim.models.observability import observability_report

    if args.tau1 is not None and args.tau1 < 0:
        raise CommandError(f"--tau1 must be a non-negative integer, got {args.tau1}")
    scenario = _load(args.scenario, what="netsim design")
    P, A, C = scenario.weights, scenario.plant.A, scenario.plant.C
    overrides = {"method": args.method, "tau1": args.tau1, "refine": args.refine}
    try:
        own = design_request(scenario)
        request = design_request(scenario, **overrides)
    except ValueError as exc:
        raise CommandError(f"scenario {args.scenario}: --tau1: {exc}") from None
    from netsim.budget import check_gain_design

    check_gain_design(scenario)
    from netsim.gaincache import cached_design

    try:
        design = cached_design(scenario, request,
                               lambda: design_for_scenario(scenario, **overrides))
    except (GainDesignError, ValueError) as exc:
        raise CommandError(f"scenario {args.scenario}: gain design failed: {exc}",
                           EXIT_DESIGN_FAILED) from None
    overridden = [f"--{k}" for k, v in overrides.items() if v not in (None, False)]
    star = tau_star_report(P, A, C, design.L)
    obs = observability_report(P, A, C)
    data = {
        "scenario": scenario.summary(),
        "observability": obs.to_dict(),
        "gains": {**request, "scenario_gains": request == own, "overridden": overridden,
                  "scenario": own},
        "design": _design_dict(design),
        "tau_star": star.contiguous,
        "tau_star_isolated": list(star.isolated),
    }
    if args.json:
        json.dump(data, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    d = data["design"]
    cert = (f"certified rate {_fmt(d['certified_rate'])}" if d["certified"]
            else "NOT certified")
    local = sum(obs.locally_observable)
    lines = [
        f"scenario {scenario.name}: n = {scenario.plant.n_states}, N = {scenario.n_agents}",
        f"observability: global {obs.observable}, distributed (P kron A, D_C) "
        f"{obs.distributed_observable}, structural {obs.structurally_observable}, locally "
        f"observable agents {local}/{scenario.n_agents}; A full rank {obs.full_rank}, "
        f"self-damped {obs.self_damped}; {len(obs.irreducible_blocks)} irreducible blocks; "
        f"Lemma 1 conditions {'hold' if obs.lemma1_satisfied else 'do NOT hold'}",
        (f"gains: {_gains_label(request)}: the scenario's [gains], as netsim run uses"
         if request == own else
         f"gains: {_gains_label(request)} ({', '.join(overridden)}; NOT the scenario's "
         f"[gains] {_gains_label(own)}, which netsim run uses)"),
        f"method: {d['method']} (solver {d['solver']}, status {d['status']}); {cert}",
        f"rho(A-hat) delay-free, recomputed with numpy: {_fmt(d['rho_delay_free'])}",
    ]
    if d["design_tau"]:
        lines.append(f"designed for delays up to tau1 = {d['design_tau']}: "
                     f"rho((I-KD)(P kron A^(tau1+1))) = {_fmt(d['rho_design'])}")
    iso = f", isolated passing values {data['tau_star_isolated']}" if star.isolated else ""
    lines.append(f"tau* (LCSYS2022 Theorem 1) = {tau_star_text(data['tau_star'])}{iso}")
    if d["message"]:
        lines.append(d["message"])
    lines.append("gains K_i (n x n, K_i = L_i (C_i C_i^T)^-1 C_i):")
    for i, K in enumerate(design.K):
        lines.append(f"  K_{i} = " + np.array2string(np.asarray(K), precision=4,
                                                     suppress_small=True,
                                                     prefix="  K_i = "))
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


def _cmd_analyze(args: argparse.Namespace) -> int:
    from netsim.analysis import analyze
    from netsim.estimators.gains import GainDesignError
    from netsim.runner import scenario_gains

    if args.tau_max < 0:
        raise CommandError(f"--tau-max must be a non-negative integer, got {args.tau_max}")
    if args.workers is not None and args.workers < 1:
        raise CommandError(f"--workers must be a positive integer, got {args.workers}")
    from netsim.parallel import env_workers

    try:
        env_workers()
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    if args.scenario.endswith(".mcap"):
        from netsim.traces.analysis import analyze_trace

        report = analyze_trace(_read(args.scenario, "analyze"))
        return _emit(args, report.to_dict(), report.format_text())
    scenario = _load(args.scenario, what="netsim analyze")
    try:
        gains = scenario_gains(scenario)
    except (GainDesignError, ValueError) as exc:
        raise CommandError(f"scenario {args.scenario}: gain design failed: {exc}",
                           EXIT_DESIGN_FAILED) from None
    report = analyze_with_progress(scenario, gains, args.tau_max, analyze,
                                   disable=True if args.no_progress else None,
                                   workers=args.workers)
    data = {"gains": _design_dict(gains), **report.to_dict()}
    if args.json:
        json.dump(data, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    iso = (f"; isolated passing values above it: {list(report.tau_star_isolated)}"
           if report.tau_star_isolated else "")
    lines = [
        f"scenario {scenario.name}: gains {gains.method} ({gains.solver}), "
        f"rho(A-hat) delay-free = {_fmt(report.rho_delay_free)}, convergence-time order "
        f"1/(1-rho) = {_fmt(report.convergence_order_delay_free)}",
        f"tau* (LCSYS2022 Theorem 1: largest tau with rho((I-KD)(P kron A^(tau+1))) < 1 "
        f"for all smaller tau) = {tau_star_text(report.tau_star)}{iso}",
        "",
        "homogeneous delay tau on every link (self-loops undelayed):",
        f"{'tau':>4} {'exact comp':>11} {'eq.26 bound':>12} {'verdict':>10} {'Thm1':>6} "
        f"{'exact uncomp':>13} {'tol. bound':>11} {'verdict':>10}",
    ]
    for row in report.rows:
        lines.append(
            f"{row.tau:>4} {_fmt(row.rho_compensated):>11} {_fmt(row.bound_eq26):>12} "
            f"{row.verdict_eq26:>10} {'stable' if row.theorem1_predicts_stable else '-':>6} "
            f"{_fmt(row.rho_uncompensated):>13} {_fmt(row.bound_tolerant):>11} "
            f"{row.verdict_tolerant:>10}"
        )
    if report.realised is not None:
        r = report.realised
        lines += ["", f"the scenario's own fixed delays {r['delays']}:",
                  f"  exact comp {_fmt(r['rho_compensated'])} vs eq. (26) bound "
                  f"{_fmt(r['bound_eq26'])}: {r['verdict_eq26']}; exact uncomp "
                  f"{_fmt(r['rho_uncompensated'])} vs tolerant bound "
                  f"{_fmt(r['bound_tolerant'])}: {r['verdict_tolerant']}"]
    lines.append("")
    if report.violations:
        lines.append(f"{len(report.violations)} bound violations:")
        lines += [f"  VIOLATED {v}" for v in report.violations]
    else:
        lines.append("no bound is violated by the exact values")
    if report.contradictions:
        lines.append(f"{len(report.contradictions)} predictions contradicted by the exact rho:")
        lines += [f"  PREDICTION CONTRADICTED {v}" for v in report.contradictions]
    from netsim.analysis import radii_line

    lines.append(radii_line(report.radii))
    lines.append("Note: the uncompensated eq. (11) matrix is the error recursion only for a "
                 "plant whose state does not move; on a moving state its error also carries "
                 "(A^(r+1) - A) x_{k-1-r}.")
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


def _read(path: str, command: str):
    """The trace at ``path`` (one error line if unreadable); a damaged trace is read as
    far as it can be, and one warning line on stderr says so, so that results computed
    from it are never taken for the whole run's."""
    from netsim.traces.reader import TraceError, read_trace

    try:
        trace = read_trace(path)
    except TraceError as exc:
        raise CommandError(str(exc)) from None
    if trace.damaged:
        lost = trace.lost_messages
        sys.stderr.write(
            f"netsim {command}: warning: {path}: damaged: {len(trace.lost_chunks)} chunk(s) "
            f"lost ({'an unknown number of' if lost is None else lost} messages); the results "
            f"use what could be read (netsim inspect {path} lists it)\n")
    return trace


def _emit(args: argparse.Namespace, data: dict[str, Any], text: str) -> int:
    if args.json:
        json.dump(data, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(text.rstrip("\n") + "\n")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from netsim.traces.replay import replay_trace

    report = replay_trace(_read(args.trace, "replay"))
    return _emit(args, report.to_dict(), report.format_text())


def _cmd_plot(args: argparse.Namespace) -> int:
    from netsim.outfiles import OutputFileError, atomic_output, check_output
    from netsim.traces.plot import plot_traces

    if not args.output.lower().endswith(".png"):
        raise CommandError(f"-o {args.output}: the output must be a .png file")
    try:
        path = check_output(args.output, "-o", force=args.force, inputs=args.traces)
    except OutputFileError as exc:
        raise CommandError(str(exc)) from None
    traces = [_read(p, "plot") for p in args.traces]
    try:
        with atomic_output(path) as tmp:
            plot_traces(traces, tmp)
    except OSError as exc:
        raise CommandError(f"cannot write {args.output}: {exc.strerror}") from None
    data = {"output": str(path), "traces": list(args.traces)}
    return _emit(args, data, f"wrote {path}")


def _cmd_layout(args: argparse.Namespace) -> int:

    from netsim.traces.layout import (
        foxglove_layout,
        layout_path_for,
        layout_paths,
        layout_source,
        render_layout,
    )
    from netsim.traces.reader import TraceError

    if args.output is not None and not args.output.lower().endswith(".json"):
        raise CommandError(f"-o {args.output}: the layout must be a .json file")
    if args.figure is not None and not args.figure.lower().endswith(".png"):
        raise CommandError(f"--figure {args.figure}: the figure must be a .png file")
    if args.figure is not None:  # before the layout is written
        from netsim.models.extras import require

        require("matplotlib", "plot", "--figure")
    from netsim.outfiles import OutputFileError, atomic_output, check_output

    out = layout_path_for(args.trace) if args.output is None else Path(args.output)
    try:
        check_output(out, "-o", force=args.force, inputs=[args.trace],
                     others=[args.figure] if args.figure else [])
        if args.figure is not None:
            check_output(args.figure, "--figure", force=args.force, inputs=[args.trace],
                         others=[out])
    except OutputFileError as exc:
        raise CommandError(str(exc)) from None
    try:
        source = layout_source(args.trace)
        layout = foxglove_layout(source)
    except (TraceError, ValueError) as exc:
        raise CommandError(str(exc)) from None
    tabs = [t["title"] for t in layout["configById"][layout["layout"]]["tabs"]]
    chosen = None
    if args.tabs is not None:
        chosen = [t.strip() for t in args.tabs.split(",") if t.strip()]
        unknown = [t for t in chosen if t not in tabs]
        if unknown or not chosen:
            raise CommandError(f"--tabs {args.tabs}: this layout's tabs are "
                               f"{', '.join(tabs)}")
    try:
        with atomic_output(out) as tmp:
            tmp.write_text(json.dumps(layout, indent=2) + "\n")
    except OSError as exc:
        raise CommandError(f"cannot write {out}: {exc.strerror or exc}") from None
    data: dict[str, Any] = {"trace": args.trace, "layout": str(out), "tabs": tabs,
                            "panels": sum(k.startswith("Plot!") for k in layout["configById"]),
                            "paths": len(layout_paths(layout)), "figure": None}
    if args.figure is not None:
        try:
            with atomic_output(args.figure) as tmp:
                render_layout(_read(args.trace, "layout"), layout, tmp, tabs=chosen)
            data["figure"] = str(args.figure)
        except OSError as exc:
            raise CommandError(f"cannot write {args.figure}: {exc.strerror or exc}") from None
    text = (f"wrote {out}: {data['panels']} plot panels ({', '.join(tabs)}), "
            f"{data['paths']} message paths; in Foxglove open {args.trace}, then "
            "Layouts > Import from file")
    if data["figure"]:
        text += f"\nwrote {data['figure']}"
    return _emit(args, data, text)


def _cmd_inspect(args: argparse.Namespace) -> int:
    from netsim.traces.inspect import inspect_trace
    from netsim.traces.reader import TraceError, read_trace

    try:
        trace = read_trace(args.trace)
    except TraceError as exc:
        raise CommandError(str(exc)) from None
    report = inspect_trace(trace)
    if args.json:
        json.dump(report.to_dict(), sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(report.format_text().rstrip("\n") + "\n")
    return 0


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from netsim.models.scenario import ScenarioError, builtin_scenarios, load_scenario

    items = []
    for name, path in builtin_scenarios().items():
        try:
            scenario = load_scenario(path)
        except ScenarioError as exc:  # a broken built-in is a bug: say so loudly
            raise CommandError(f"built-in scenario {name} is invalid: {exc}", 1) from None
        items.append({**scenario.summary(), "name": name, "source": f"builtin:{name}"})
    if args.json:
        json.dump({"scenarios": items}, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        for item in items:
            d = item["delays"]
            sys.stdout.write(
                f"{item['name']}\n    n = {item['n_states']}, N = {item['n_agents']}, delays "
                f"{d['model']} tau = {d['tau']}, estimators {', '.join(item['estimators'])}\n"
                f"    {' '.join(item['description'].split())}\n"
            )
    return 0


#: The traits ``netsim estimators`` shows, as (key, words when set).
_TRAIT_WORDS = (("needs_gains", "gains L_i"), ("timestamps", "time-stamps"),
                ("vectorised", "vectorised"), ("centralised", "centralised"),
                ("delay_free", "delay-free"), ("needs_graph_sequence", "graph sequence"))


def _cmd_estimators(args: argparse.Namespace) -> int:
    from netsim.estimators.registry import family_listing

    items = family_listing()
    if args.json:
        return _emit(args, {"estimators": items}, "")
    lines = []
    for item in items:
        lines.append(f"{item['name']}  [{item['origin']}]")
        if item.get("error"):
            lines.append(f"    failed to load: {item['error']}")
            continue
        traits = item["traits"] or {}
        if item["description"]:
            lines.append(f"    {' '.join(item['description'].split())}")
        if traits.get("paper"):
            lines.append(f"    paper: {traits['paper']}")
        flags = [words for key, words in _TRAIT_WORDS if traits.get(key)]
        if not traits.get("timestamps", True):
            flags.append("no time-stamps")
        recursion = traits.get("error_recursion")
        lines.append(f"    traits: {', '.join(flags) if flags else 'none declared'}; error "
                     f"recursion: {recursion or 'none (no replay or augmented analytics)'}")
    lines.append("A family of your own: --estimators module:attribute (or run.estimators in "
                 "a scenario); installed packages add families through the entry-point group "
                 "netsim.estimators.")
    return _emit(args, {}, "\n".join(lines))


def _cmd_fusion(args: argparse.Namespace) -> int:
    from netsim import fusion as nf

    if args.fusion_command is None:
        raise CommandError("name what to do: table1, example2 or run")
    if args.fusion_command == "table1":
        data, text = nf.table1(args.json)
        return _emit(args, data, text)
    if args.fusion_command == "example2":
        data, text = nf.example2(args.json)
        return _emit(args, data, text)
    _positive(args.steps, "--steps")
    _positive(args.trials, "--trials")
    if args.seed < 0:
        raise CommandError(f"--seed must be a non-negative integer, got {args.seed}")
    try:
        engine = {"events": "kernel", "vectorised": "lockstep"}.get(args.engine, args.engine)
        result = nf.run_fusion(args.example, args.steps, args.trials, args.seed,
                               engine=engine, time_varying=args.time_varying,
                               gamma11=args.gamma)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    return _emit(args, result.to_dict(), result.format_text())


#: Estimated seconds of the claims' searches per requested instance (all searches; a
#: generous figure from the reference machine, for refusing absurd --instances).
CLAIMS_SECONDS_PER_INSTANCE = 0.15


def _cmd_claims(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from netsim.claims import run_claims, select

    if args.budget is not None and not (math.isfinite(args.budget) and args.budget > 0):
        raise CommandError(f"--budget must be a positive number of seconds, got {args.budget}")
    if args.instances is not None:
        if args.instances < 1:
            raise CommandError(f"--instances must be a positive integer, got {args.instances}")
        from netsim.budget import check_duration

        check_duration(args.instances * CLAIMS_SECONDS_PER_INSTANCE, "--instances",
                       args.instances, "the counterexample searches")
    if args.seed < 0:
        raise CommandError(f"--seed must be a non-negative integer, got {args.seed}")
    try:
        chosen = select(args.names)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    from netsim.claims.report import search_names

    # one tick per search or run the checks read (they go first, on the local cores) and
    # one per claim checked
    bar = tqdm(total=len(search_names(chosen)) + len(chosen), desc="netsim claims",
               unit="job", file=sys.stderr, leave=False,
               disable=True if args.no_progress else None)
    from netsim.outfiles import OutputFileError, check_output_folder

    try:  # the files it will write there: never through a link
        check_output_folder(args.out, "--out", ["claims.md", *(
            f"{c.id}-counterexample.toml" for c in chosen)])
    except OutputFileError as exc:
        raise CommandError(str(exc)) from None

    def claim_done(_: str) -> None:
        bar.update(1)

    def search_done(name: str) -> None:
        bar.set_postfix_str(name)
        bar.update(1)

    try:
        report = run_claims(chosen, seed=args.seed, budget=args.budget, out=args.out,
                            instances=args.instances, progress=claim_done,
                            search_progress=search_done)
    except OSError as exc:
        raise CommandError(f"--out {args.out}: {exc.strerror or exc}") from None
    except OutputFileError as exc:
        raise CommandError(str(exc)) from None
    finally:
        bar.close()
    return _emit(args, report.to_dict(), report.format_text())


def _cmd_bench(args: argparse.Namespace) -> int:
    from netsim.bench import cmd_bench

    return cmd_bench(args)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from netsim.calibrate import cmd_calibrate

    return cmd_calibrate(args)


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from netsim.models.extras import require

    require("matplotlib", "plot", "netsim reproduce (its figures)")
    from netsim.reproduce import cmd_reproduce

    return cmd_reproduce(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``netsim`` command; returns the exit code."""
    handlers = {
        "run": _cmd_run,
        "design": _cmd_design,
        "analyze": _cmd_analyze,
        "inspect": _cmd_inspect,
        "replay": _cmd_replay,
        "plot": _cmd_plot,
        "layout": _cmd_layout,
        "fusion": _cmd_fusion,
        "bench": _cmd_bench,
        "claims": _cmd_claims,
        "reproduce": _cmd_reproduce,
        "calibrate": _cmd_calibrate,
        "scenarios": _cmd_scenarios,
        "estimators": _cmd_estimators,
    }
    parser = build_parser(_command_in(sys.argv[1:] if argv is None else list(argv), handlers))
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    from netsim import gaincache

    fresh = gaincache.disabled() if getattr(args, "no_cache", False) else nullcontext()
    try:
        with scenario_warnings(args.command), fresh:
            return handlers[args.command](args)
    except CommandError as exc:
        sys.stderr.write(f"netsim {args.command}: error: {exc}\n")
        return exc.code
    except ResourceError as exc:  # refused before allocating (netsim.budget)
        sys.stderr.write(f"netsim {args.command}: error: {exc}\n")
        return EXIT_BAD_INPUT
    except MissingExtra as exc:  # an optional dependency (netsim.models.extras): pip install ...
        sys.stderr.write(f"netsim {args.command}: error: {exc}\n")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        sys.stderr.write(f"netsim {args.command}: interrupted\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
