"""The ``netsim reproduce`` command line: its parser and :func:`cmd_reproduce`."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from netsim.cliutil import REPRODUCE_HELP
from netsim.reproduce.items import items
from netsim.reproduce.report import CLAIM_BUDGET, DEFAULT_TRIALS, reproduce

__all__ = ["add_reproduce_parser", "cmd_reproduce", "MAX_TRIALS"]

#: Largest --trials accepted (the delay benchmarks keep trials x 500 steps x 6 states per
#: cell in memory; netsim.budget checks the memory of the largest).
MAX_TRIALS = 100_000


def add_reproduce_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``reproduce`` to the ``netsim`` parser (its help lists the registered
    papers and their items)."""
    from netsim.papers import papers

    registered = papers()
    keys = [p.key for p in registered]
    every = items()
    listing = "; ".join(f"{p}: " + ", ".join(i.label for i in every if i.paper == p)
                        for p in keys)
    own = [p.key for p in registered if p.mc_trials == DEFAULT_TRIALS]
    seeded = [p for p in keys if any(i.seeded for i in every if i.paper == p)]
    rep = subparsers.add_parser(
        "reproduce",
        help=REPRODUCE_HELP,
        description=(
            "Regenerate the figures and tables of the papers that have data (diagrams "
            f"excepted) -- {listing} -- as PNG plus CSV/JSON data, and write report.md: "
            "for each item our figure, the paper's caption and statement, where our "
            "system differs from the paper's, and the verdicts of the claims it bears on "
            "(netsim claims). The default run takes a few minutes on 2 cores; --trials "
            "trades time for precision (below the default, a quick look: an item's costly "
            "searches and LMI tables may also do that share of their work, and the report "
            "says so)."),
    )
    rep.add_argument("papers", nargs="*", metavar="PAPER",
                     help=f"papers to reproduce ({', '.join(keys)}); default all")
    rep.add_argument("--out", default="reproduce-out",
                     help="output folder (default ./reproduce-out)")
    rep.add_argument("--trials", type=int, default=DEFAULT_TRIALS,
                     help=f"Monte Carlo trials per curve (default {DEFAULT_TRIALS}"
                     + "".join(f", the {k} paper's" for k in own[:1]) + ")")
    rep.add_argument("--seed", type=int, default=0, help="seed of the "
                     + " and ".join(seeded) + " runs (default 0; the delay benchmarks use "
                     "their scenario's seed)")
    rep.add_argument("--workers", type=int, default=2,
                     help="local processes of the delay benchmarks (default 2)")
    rep.add_argument("--claim-budget", type=float, default=CLAIM_BUDGET, metavar="SECONDS",
                     help="cut each claim check's counterexample search short after this "
                     "many seconds (default: no time limit, the searches run their counted "
                     "instances; a search cut short is 'undecided')")
    rep.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    rep.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    return rep


def _check_budget(trials: int) -> None:
    """Refuse a --trials whose largest benchmark cell (of any preset) cannot fit in
    memory."""
    from netsim.bench.presets import presets
    from netsim.budget import check_run
    from netsim.models.scenario import resolve_scenario

    for scenario, steps in dict.fromkeys((p.scenario, p.steps) for p in presets().values()):
        check_run(resolve_scenario(scenario), steps, trials, ["vectorised"],
                  trials_name="--trials")


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Run ``netsim reproduce`` (CommandError for bad input)."""
    from tqdm import tqdm

    from netsim.cliutil import CommandError
    from netsim.outfiles import OutputFileError
    from netsim.reproduce.items import items_for

    if not 1 <= args.trials <= MAX_TRIALS:
        raise CommandError(f"--trials must be an integer in 1..{MAX_TRIALS}, got {args.trials}")
    if args.seed < 0:
        raise CommandError(f"--seed must be a non-negative integer, got {args.seed}")
    if args.claim_budget is not None and not (math.isfinite(args.claim_budget)
                                              and args.claim_budget > 0):
        raise CommandError(f"--claim-budget must be a positive number of seconds, got "
                           f"{args.claim_budget}")
    if args.workers < 1:
        raise CommandError(f"--workers must be a positive integer, got {args.workers}")
    try:
        chosen = items_for(args.papers)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    _check_budget(args.trials)
    bar = tqdm(total=len(chosen), desc="netsim reproduce", unit="item", file=sys.stderr,
               leave=False, disable=True if args.no_progress else None)
    names = iter([*(i.id for i in chosen[1:]), "report"])

    def step(_: str) -> None:
        bar.set_postfix_str(next(names, ""), refresh=False)
        bar.update(1)

    if chosen:
        bar.set_postfix_str(chosen[0].id)
    try:
        result = reproduce(args.papers, out=args.out, trials=args.trials, seed=args.seed,
                           workers=args.workers, claim_budget=args.claim_budget,
                           progress=step)
    except OutputFileError as exc:
        raise CommandError(str(exc)) from None
    except OSError as exc:
        raise CommandError(f"--out {args.out}: {exc.strerror or exc}") from None
    finally:
        bar.close()
    if args.json:
        print(json.dumps(result.to_dict(), indent=1, allow_nan=False, default=str))
    else:
        sys.stdout.write(result.format_text())
    return 0
