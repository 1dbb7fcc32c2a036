"""The ``netsim`` command line.

Exit codes: 0 success (an estimator that diverged is a result, not an error);
2 bad input (scenario, arguments);
3 gain design failed; 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

__all__ = ["main", "build_parser"]

EXIT_BAD_INPUT = 2
EXIT_DESIGN_FAILED = 3
EXIT_INTERRUPTED = 130


class CommandError(Exception):
    """A user-facing error: one line on stderr and an exit code."""

    def __init__(self, message: str, code: int = EXIT_BAD_INPUT) -> None:
        super().__init__(message)
        self.code = code


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``netsim``."""
    parser = argparse.ArgumentParser(
        prog="netsim",
        description=(
            "Discrete-event simulation of distributed state estimation over networks with "
            "communication delays: consensus + innovation estimators (LCSYS2022, delay-"
            "tolerant), their delay-compensating and block-update variants, and a "
            "centralised Kalman filter reference."
        ),
        epilog="Run 'netsim COMMAND --help' for the options of a command.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    run = sub.add_parser(
        "run",
        help="Monte Carlo runs of every estimator in a scenario",
        description=(
            "Run every estimator family of SCENARIO over Monte Carlo trials in the SimPy "
            "kernel and print, per estimator, the network MSE over time, the steady-state "
            "MSE and a verdict (stable / diverging / diverged at step k). The same seed "
            "gives the same numbers, bit for bit."
        ),
    )
    run.add_argument("scenario", help="built-in scenario name (see 'netsim scenarios') or a "
                     "path to a scenario TOML file")
    run.add_argument("--steps", type=int, help="number of steps K (default: the scenario's)")
    run.add_argument("--trials", type=int, help="Monte Carlo trials M (default: the scenario's)")
    run.add_argument("--seed", type=int, help="root seed of the trial randomness")
    run.add_argument("--tau", type=int, help="override the scenario's delay bound tau "
                     "(homogeneous, heterogeneous or time-varying delays)")
    run.add_argument("--estimators", help="comma-separated subset of the scenario's estimators")
    run.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    run.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")

    scen = sub.add_parser("scenarios", help="list the built-in scenarios",
                          description="List the built-in scenarios with their descriptions.")
    scen.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    return parser


def _positive(value: int | None, option: str) -> None:
    if value is not None and value < 1:
        raise CommandError(f"{option} must be a positive integer, got {value}")


def _cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from estimators.gains import GainDesignError
    from models.scenario import ScenarioError, resolve_scenario
    from netsim.runner import run_monte_carlo, scenario_gains

    _positive(args.steps, "--steps")
    _positive(args.trials, "--trials")
    if args.seed is not None and args.seed < 0:
        raise CommandError(f"--seed must be a non-negative integer, got {args.seed}")
    try:
        scenario = resolve_scenario(args.scenario)
        if args.tau is not None:
            scenario = scenario.with_tau(args.tau)
    except ScenarioError as exc:
        where = f"scenario {args.scenario}"
        raise CommandError(f"{where}: {exc}") from None
    families = scenario.estimators
    if args.estimators:
        families = tuple(f.strip() for f in args.estimators.split(",") if f.strip())
        if not families:
            raise CommandError("--estimators: empty list; name at least one estimator")
        unknown = [f for f in families if f not in scenario.estimators]
        if unknown:
            raise CommandError(
                f"--estimators: {', '.join(unknown)} not in the scenario's estimators "
                f"({', '.join(scenario.estimators)})"
            )
    gains = None
    if any(f != "centralized-kf" for f in families):
        try:
            gains = scenario_gains(scenario)
        except (GainDesignError, ValueError) as exc:
            raise CommandError(f"scenario {args.scenario}: gain design failed: {exc}",
                               EXIT_DESIGN_FAILED) from None
    trials = args.trials or scenario.trials
    total = trials * len(families)
    bar = tqdm(total=total, desc=f"netsim run {scenario.name}", unit="trial",
               disable=True if args.no_progress else None, file=sys.stderr, leave=False)
    try:
        result = run_monte_carlo(
            scenario, steps=args.steps, trials=args.trials, seed=args.seed, families=families,
            progress=bar.update, gains=gains,
        )
    finally:
        bar.close()
    data = result.to_dict()
    if args.json:
        json.dump(data, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(_format_run(data))
    return 0


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, str):
        return value
    if value == 0 or (1e-3 <= abs(value) < 1e4):
        return f"{value:.4f}"
    return f"{value:.3e}"


def _format_run(data: dict[str, Any]) -> str:
    s = data["scenario"]
    lines = [
        f"scenario {s['name']} ({s['source']}): n = {s['n_states']} states, "
        f"N = {s['n_agents']} agents, {len(s['links'])} links",
        f"delays: {s['delays']['model']}, tau = {s['delays']['tau']} "
        f"(max step delay {s['delays']['max_delay']})",
        f"run: {data['steps']} steps x {data['trials']} trials, seed {data['seed']}",
    ]
    g = data["gains"]
    if g is not None:
        cert = "certified" if g["certified"] else "NOT certified"
        lines.append(
            f"gains: {g['method']} ({g['solver']}, {g['status']}, {cert}); "
            f"rho(A-hat) delay-free = {_fmt(g['rho_delay_free'])}"
        )
    a = data.get("analytics")
    if a:
        lines.append(
            f"analytics at tau = {a['delay_bound']}: tau* (LCSYS2022 Thm 1) = {a['tau_star']}, "
            f"eq. (26) bound = {_fmt(a['bound_lcsys_eq26'])}, delay-tolerant bound "
            f"rho^(1/(tau+1)) = {_fmt(a['bound_delay_tolerant'])}"
        )
        if a.get("rho_exact_compensated") is not None:
            lines.append(
                f"exact rho of the augmented closed loop for the realised delays: "
                f"compensated (eq. 9) = {_fmt(a['rho_exact_compensated'])}, "
                f"uncompensated (eq. 11, valid only for a still state) = "
                f"{_fmt(a['rho_exact_uncompensated'])}"
            )
    lines.append("")
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
        row = f"{name:<16}{verdict:<22}{_fmt(e['steady_state_mse']):>12}"
        row += f"{_fmt(e['growth_rate']):>13}  "
        row += " ".join(f"{_fmt(e['mse_at'][m]):>11}" for m in marks)
        lines.append(row)
    lines.append("")
    lines.append("MSE: (1/N) sum_i ||x_k - xhat^i_k||^2 averaged over non-diverged trials; "
                 "growth/step: exp(slope of log MSE) over the second half.")
    return "\n".join(lines) + "\n"


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from models.scenario import ScenarioError, builtin_scenarios, load_scenario

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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``netsim`` command; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    handlers = {"run": _cmd_run, "scenarios": _cmd_scenarios}
    try:
        return handlers[args.command](args)
    except CommandError as exc:
        sys.stderr.write(f"netsim {args.command}: error: {exc}\n")
        return exc.code
    except KeyboardInterrupt:
        sys.stderr.write(f"netsim {args.command}: interrupted\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
