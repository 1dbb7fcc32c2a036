"""The delay-tolerance benchmark: the grid of cells, run on the sweep machinery, as a report."""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

from netsim.bench.cells import delay_tolerance_cell
from netsim.bench.cells import find_cell as _cell
from netsim.bench.claims import bench_rows, default_rows, disagreements
from netsim.bench.fmt import describe_cell, fmt_value
from netsim.bench.presets import DELAY_MODELS, FAMILIES, NO_DELAY, Preset, delay_settings
from netsim.bench.variants import scenario_fingerprint
from netsim.estimators.registry import (
    RECURSION_BLOCK,
    RECURSION_UNCOMPENSATED,
    EstimatorFamily,
)
from netsim.models.scenario import Scenario
from netsim.models.seeding import SEED_LAYOUT
from netsim.verdicts import VERDICT_RULES

__all__ = ["SCAN_TAU_MIN", "run_delay_tolerance"]


#: Smallest tau_max of the exact homogeneous scan (it goes to the largest tau benchmarked).
SCAN_TAU_MIN = 10


def _family_params(family: EstimatorFamily, engines: dict[str, str]) -> dict[str, Any]:
    """A cell's family and engine; a plugin also its reference (resolved in workers)."""
    params: dict[str, Any] = {"family": family.name, "engine": engines[family.name]}
    if family.reference:
        params["family_ref"] = family.reference
    return params


def _shared(family: EstimatorFamily, setting: str, tau: int) -> tuple[str, int]:
    """The (setting, tau) a cell is computed as: once for a family whose results do not
    depend on the links, once for tau = 0 for the others."""
    if family.delay_free or tau == 0:
        return NO_DELAY, 0
    return setting, tau


def _cells(taus: Sequence[int], settings: Sequence[str], families: Sequence[EstimatorFamily],
           trials: int, steps: int, seed: int, fingerprint: str, engines: dict[str, str]
           ) -> list[dict[str, Any]]:
    """Distinct computations, longest first (big tau, time-varying). Each cell's key
    holds the verdict rule's version (:data:`netsim.verdicts.VERDICT_RULES`), so a
    results file written under another rule is computed afresh, not reused."""
    out = []
    seen = set()
    common = {"kind": "mc", "scenario": fingerprint, "trials": trials, "steps": steps,
              "seed": seed, "rules": VERDICT_RULES}
    for setting in settings:
        for tau in taus:
            for family in families:
                key = (*_shared(family, setting, tau), family.name)
                if key not in seen:
                    seen.add(key)
                    out.append({**common, **_family_params(family, engines),
                                "setting": key[0], "tau": key[1]})
    weight = {"time-varying": 3, "synchronous": 3}
    out.sort(key=lambda c: -(c["tau"] + 1) * weight.get(c["setting"], 1))
    return out


def run_delay_tolerance(
    scenario: Scenario,
    *,
    taus: Sequence[int],
    delays: Sequence[str],
    trials: int,
    steps: int,
    seed: int,
    families: Sequence[str] = FAMILIES,
    gains: Any = None,
    preset: Preset | None = None,
    executor: str = "local",
    workers: int = 2,
    dask_address: Any = None,
    results: str | None = None,
    progress: bool = True,
    stop_after: int | None = None,
    engine: str = "auto",
) -> dict[str, Any]:
    """Run the delay-tolerance benchmark; return the JSON-ready report.

    ``engine`` (``auto``, ``vectorised`` or ``events``) runs each cell's trials; it is
    part of the cell's key in a results file, so a resumed run never mixes engines.
    """
    from netsim.bench.scenario_sweep import plugin_code
    from netsim.runner import choose_engine, engines_for, family_of, scenario_gains
    from netsim.sweep import run_sweep

    started = time.perf_counter()
    declared = [family_of(f, scenario, "--estimators") for f in families]
    families = [f.name for f in declared]
    engines = engines_for(engine, declared)
    engine = choose_engine(engine, declared)
    taus = sorted({int(t) for t in taus})
    for s in delays:
        if s not in DELAY_MODELS:
            raise ValueError(f"unknown delay setting {s!r}")
    if gains is None and any(f.needs_gains for f in declared):
        gains = scenario_gains(scenario)
    fingerprint = scenario_fingerprint(scenario, gains)
    cells = _cells(taus, delays, declared, trials, steps, seed, fingerprint, engines)
    scan = {"kind": "scan", "scenario": fingerprint,
            "tau_max": max(SCAN_TAU_MIN, max(taus) if taus else 0)}
    has_consensus = gains is not None
    todo = ([scan] if has_consensus else []) + cells
    sweep = run_sweep(
        delay_tolerance_cell, todo, root_seed=seed, sweep="delay-tolerance",
        results=results, executor=executor, workers=workers, dask_address=dask_address,
        context={"scenario": scenario, "gains": gains,
                 "plugins": plugin_code(declared)}, progress=progress,
        description=f"bench {preset.name if preset else scenario.name}", stop_after=stop_after,
    )
    by_params = {json.dumps(row["params"], sort_keys=True): row for row in sweep.rows}

    def lookup(cell: dict[str, Any]) -> dict[str, Any]:
        return by_params[json.dumps(json.loads(json.dumps(cell)), sort_keys=True)]

    scan_result = lookup(scan)["result"] if has_consensus else None
    common = {"kind": "mc", "scenario": fingerprint, "trials": trials, "steps": steps,
              "seed": seed, "rules": VERDICT_RULES}
    table = []
    for setting in delays:
        for tau in taus:
            for fam in declared:
                family = fam.name
                shared = _shared(fam, setting, tau)
                row = lookup({**common, **_family_params(fam, engines),
                              "setting": shared[0], "tau": shared[1]})
                table.append({"setting": setting, "tau": tau, "family": family,
                              **({"computed_as": f"{shared[0]}, tau {shared[1]}"}
                                 if shared != (setting, tau) else {}),
                              **row["result"]})
    described = delay_settings()
    data: dict[str, Any] = {
        "bench": "delay-tolerance",
        "preset": None if preset is None else {
            "name": preset.name, "description": preset.description, "focus": preset.focus,
            "trials": preset.trials, "steps": preset.steps, "taus": list(preset.taus),
            "delays": list(preset.delays),
            **({"families": list(preset.families)} if preset.families else {})},
        "scenario": scenario.summary(),
        "fingerprint": fingerprint,
        "gains": None if gains is None else {
            "method": gains.method, "solver": gains.solver, "certified": gains.certified,
            "rho_delay_free": float(gains.rho)},
        "settings": {s: described[s][1] for s in delays},
        "taus": taus,
        "families": list(families),
        "family_traits": {f.name: f.traits() for f in declared},
        "trials": trials,
        "steps": steps,
        "seed": seed,
        "seed_layout": SEED_LAYOUT,
        "engine": engine,
        **({"engines": engines} if engine == "mixed" else {}),
        "analysis": scan_result,
        "cells": table,
    }
    data["tolerance"] = _tolerance(data, {f.name: f for f in declared})
    rows = bench_rows()
    claims = preset.claims if preset is not None else default_rows()
    data["claims"] = [rows[c](data) for c in claims]
    data["disagreements"] = disagreements(data) + _contradictions(data)
    data["run"] = {
        "elapsed_s": round(time.perf_counter() - started, 3),
        "executor": sweep.executor,
        "workers": sweep.workers,
        "cells_computed": sweep.computed,
        "cells_reused": sweep.reused,
        "results_file": results,
    }
    return data


def _contradictions(data: dict[str, Any]) -> list[str]:
    """Cells whose bound predicts stability while the run diverges (verdict
    ``prediction contradicted``), each as a disagreement with both facts."""
    out = []
    for c in data["cells"]:
        if c["verdict"] == "prediction contradicted" and not c.get("computed_as"):
            a = c["analytics"]
            out.append(f"{c['family']}, {c['setting']}, tau {c['tau']}: prediction "
                       f"contradicted: {a['bound_name']} = {fmt_value(a['bound'])} < 1 predicts "
                       f"stability; the run: {describe_cell(c)}")
    return out


def _tolerance(data: dict[str, Any], declared: dict[str, EstimatorFamily]
               ) -> list[dict[str, Any]]:
    from netsim.papers import delay_bounds

    scan = data["analysis"] or {}
    bounds = delay_bounds()
    out = []
    for family in data["families"]:
        recursion = declared[family].error_recursion
        if declared[family].delay_free:
            continue  # the reference: its results do not depend on the delays
        for setting in data["settings"]:
            stable: list[int] = []
            undecided: list[int] = []
            measured = None
            broken = False
            for tau in data["taus"]:
                c = _cell(data, setting, tau, family)
                ok = c is not None and c["measured"]["verdict"] == "stable"
                if c is not None and c["measured"]["verdict"] == "undecided":
                    undecided.append(tau)
                if ok:
                    stable.append(tau)
                    if not broken:
                        measured = tau
                else:
                    broken = True
            censored = scan.get("exact_tolerance_censored") or {}
            bound = next((b for b in bounds if recursion in b.recursions), None)
            if bound is None:
                predicted = None
                why = ("no prediction: the family declares no augmented error recursion"
                       if recursion is None else
                       "no prediction: no paper's bound covers the family's error recursion")
            elif bound.prediction == "any":
                predicted = ("any" if (scan.get("rho_delay_free") or 2) < 1 else None)
                why = bound.predicted_by
            else:
                predicted = scan.get("tau_star")
                why = bound.predicted_by
            if recursion is None:
                exact = None
                exact_why = "no exact analysis for this family"
            elif recursion == RECURSION_UNCOMPENSATED:
                exact = scan.get("exact_tolerance_uncompensated_eq11")
                if censored.get("uncompensated_eq11"):
                    exact = f">={exact}"
                exact_why = ("eq. (11) alone, homogeneous (ignores the moving state's "
                             "forcing (A^(r+1) - A) x)")
            elif recursion == RECURSION_BLOCK:
                exact = scan.get("tau_star")
                exact_why = "block rate < 1 (= Theorem 1's condition)"
            else:
                exact = scan.get("exact_tolerance_compensated")
                if censored.get("compensated"):
                    exact = f">={exact}"
                exact_why = "exact augmented rho < 1, homogeneous"
            out.append({
                "family": family, "setting": setting,
                "measured_max": measured, "stable_taus": stable,
                "unstable_taus": [t for t in data["taus"]
                                  if t not in stable and t not in undecided],
                "undecided_taus": undecided,
                "predicted": predicted, "predicted_by": why,
                "exact_homogeneous": exact, "exact_by": exact_why,
                "scan_tau_max": scan.get("tau_max"),
            })
    return out
