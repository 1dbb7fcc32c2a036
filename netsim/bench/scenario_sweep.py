"""``netsim bench sweep``: a parameter grid of Monte Carlo runs of one base scenario."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from netsim.bench.variants import scenario_data, scenario_fingerprint, sweep_variant
from netsim.models.scenario import DelaySpec

__all__ = ["run_scenario_sweep", "scenario_sweep_cell"]


_GAIN_CACHE: dict[str, Any] = {}


def scenario_sweep_cell(params: dict[str, Any], seed: Any, context: dict[str, Any]
                        ) -> dict[str, Any]:
    """One cell of ``netsim bench sweep``: a Monte Carlo run of a scenario variant.

    ``context``: ``{"data": TOML dict, "source": str, "families": [...], "trials": M,
    "steps": K}``. Gains are designed per variant (cached per worker process).
    """
    from netsim.estimators.gains import GainDesignError
    from netsim.models.scenario import ScenarioError
    from netsim.runner import run_monte_carlo, scenario_gains

    try:
        scenario = sweep_variant(context["data"], context["source"], params)
    except ScenarioError as exc:
        return {"error": f"scenario: {exc}"}
    from netsim.runner import family_of

    # the families by the keys that resolve them here (a plugin by its reference)
    families = [f for f in context["families"] if f in scenario.estimators] or \
        list(context["families"])
    gains = None
    if any(family_of(f, scenario).needs_gains for f in families):
        fp = scenario_fingerprint(replace(scenario, delays=DelaySpec()))
        gains = _GAIN_CACHE.get(fp)
        if gains is None:
            try:
                gains = _GAIN_CACHE[fp] = scenario_gains(scenario)
            except (GainDesignError, ValueError) as exc:
                return {"error": f"gain design failed: {exc}"}
    result = run_monte_carlo(scenario, steps=context["steps"], trials=context["trials"],
                             seed=scenario.seed, families=families, gains=gains,
                             engine=params.get("_engine", "events"))
    data = result.to_dict()
    out: dict[str, Any] = {
        "n_agents": scenario.n_agents,
        "links": len(scenario.links),
        "delay_bound": scenario.delay_bound,
    }
    if data["analytics"]:
        a = data["analytics"]
        out["analytics"] = {k: a.get(k) for k in (
            "rho_delay_free", "tau_star", "bound_lcsys_eq26", "bound_delay_tolerant",
            "rho_exact_compensated", "rho_exact_uncompensated", "joint_system")}
    out["estimators"] = {
        # a steady MSE for stable runs only (netsim.verdicts.has_steady_state)
        name: {"verdict": e["verdict"],
               **({"steady_state_mse": e["steady_state_mse"]} if "steady_state_mse" in e
                  else {}),
               "last_trusted_mse": e["last_trusted_mse"],
               "growth_rate": e["growth_rate"], "diverged_trials": len(e["diverged_trials"]),
               "messages_sent": e["messages"]["sent"],
               "messages_delivered": e["messages"]["delivered"]}
        for name, e in data["estimators"].items()
    }
    return out


def run_scenario_sweep(scenario: str, *, axes: dict[str, list[Any] | None], trials: int, steps: int,
                       families: Sequence[str], seed: int, engine: str = "auto",
                       **options: Any):
    """Grid over ``axes`` (delays, tau, topology, agents, seed) of one base scenario.

    ``engine`` runs the trials (``auto``: vectorised); it is part of every cell's key.
    """
    from netsim.runner import choose_engine, family_of
    from netsim.sweep import grid, run_sweep

    data, source = scenario_data(scenario)
    base = sweep_variant(data, source, {})
    from netsim.estimators.registry import resolve_families
    from netsim.runner import scenario_folder

    # the scenario's own first, so --estimators may use their short names
    resolve_families(base.estimators, "run.estimators", scenario_folder(base))
    declared = [family_of(f, base, "--estimators") for f in families]
    engine = choose_engine(engine, declared)
    if engine == "mixed":  # each run picks per family (auto)
        engine = "auto"
    cells = grid(**{k: v for k, v in axes.items() if v})
    context = {"data": data, "source": source, "families": [f.key for f in declared],
               "trials": trials, "steps": steps, "fingerprint": scenario_fingerprint(base)}
    from netsim.verdicts import VERDICT_RULES

    cells = [{**c, "_scenario": context["fingerprint"], "_trials": trials, "_steps": steps,
              "_rules": VERDICT_RULES,
              "_engine": engine} for c in cells]
    return run_sweep(scenario_sweep_cell, cells, root_seed=seed, sweep="scenario-sweep",
                     context=context, **options)
