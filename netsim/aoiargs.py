"""``netsim run``'s options of the age-of-information observer (``--gains``, ``--rho``,
``--ties``, ``--delayed``), which set the scenario's ``[options.aoi]``.

A light module (argparse and math only) so that building ``netsim run``'s parser
imports neither :mod:`netsim.aoi` nor the estimators and graphs it needs (start-up
latency, issue 34); :mod:`netsim.aoi` re-exports these functions.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from netsim.models.scenario import Scenario

__all__ = ["add_aoi_arguments", "apply_aoi_arguments", "check_aoi_arguments"]


def add_aoi_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``[options.aoi]`` overrides to ``netsim run``."""
    group = parser.add_argument_group(
        "age-of-information observer (families aoi, naive-uniform, naive-tree)")
    group.add_argument("--gains", choices=["deadbeat", "rate"], default=None,
                       help="source gains: deadbeat (Corollary 1, default) or rate "
                       "(Theorem 1, with --rho); sets options.aoi.gains")
    group.add_argument("--rho", type=float, default=None,
                       help="desired convergence rate for --gains rate (0 < rho)")
    group.add_argument("--ties", choices=["lowest", "highest", "random"], default=None,
                       help="freshness tie rule (default lowest agent number)")
    group.add_argument("--delayed", choices=["discard", "age"], default=None,
                       help="what the AoI observer does with a delayed message: discard it "
                       "(the paper has no delays; default) or age it (extension)")


def apply_aoi_arguments(args: argparse.Namespace, scenario: Scenario) -> Scenario:
    """The scenario with ``--gains``, ``--rho``, ``--ties`` and ``--delayed`` applied to
    its ``[options.aoi]`` (ScenarioError naming the option for a bad value)."""
    from netsim.models.scenario import ScenarioError

    settings: dict[str, Any] = {}
    if getattr(args, "gains", None):
        settings["gains"] = args.gains
    rho = getattr(args, "rho", None)
    if rho is not None:
        if not (rho > 0 and math.isfinite(rho)):
            raise ScenarioError("--rho", f"must be > 0, got {rho}")
        settings["rho"] = float(rho)
    if getattr(args, "ties", None):
        settings["tie_rule"] = args.ties
    if getattr(args, "delayed", None):
        settings["delayed"] = args.delayed
    return scenario.with_options("aoi", **settings) if settings else scenario


#: The options given on the command line by :func:`add_aoi_arguments`.
_AOI_FLAGS = (("--gains", "gains"), ("--rho", "rho"), ("--ties", "ties"),
              ("--delayed", "delayed"))


def check_aoi_arguments(args: argparse.Namespace, families: Sequence[Any]) -> None:
    """Refuse ``--gains``, ``--rho``, ``--ties`` or ``--delayed`` when none of the run's
    ``families`` reads ``[options.aoi]`` (they would change nothing): ScenarioError
    naming the first such option."""
    given = [flag for flag, attr in _AOI_FLAGS if getattr(args, attr, None) is not None]
    if not given:  # (the AoI estimators are imported only when an option is given)
        return
    from netsim.estimators.aoi import reads_aoi_options

    if any(reads_aoi_options(f) for f in families):
        return
    from netsim.estimators.registry import families as registered
    from netsim.models.scenario import ScenarioError

    aoi = [f.name for f in registered() if reads_aoi_options(f)]
    run = ", ".join(f.name for f in families)
    raise ScenarioError(given[0], f"sets [options.aoi], which none of this run's estimators "
                        f"({run}) reads; it is for {', '.join(aoi)} (add one with "
                        "--estimators)")
