"""``netsim bench sweep``: a parameter grid of Monte Carlo runs of one base scenario."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import replace
from functools import partial
from typing import Any

from netsim.bench.variants import scenario_data, scenario_fingerprint, sweep_variant
from netsim.models.scenario import DelaySpec

__all__ = ["design_sweep_gains", "plugin_code", "run_scenario_sweep", "scenario_sweep_cell"]


_GAIN_CACHE: dict[str, Any] = {}


def _gain_key(scenario: Any) -> str:
    """The variant's key in the gain table: its fingerprint with the delays left out
    (the design does not depend on them)."""
    return scenario_fingerprint(replace(scenario, delays=DelaySpec()))


def _cell_families(context: dict[str, Any], scenario: Any) -> list[Any]:
    """The families a cell runs: every key of ``context["families"]`` (what the sweep
    was asked for, listed by the scenario or not), each the object shipped in
    ``context["plugins"]`` (a plugin's code, by value) if there is one, else resolved
    here by its key."""
    from netsim.runner import family_of

    keys = list(context["families"])
    shipped = context.get("plugins")
    shipped = (shipped.value if shipped is not None else None) or {}
    return [shipped[f] if f in shipped else family_of(f, scenario) for f in keys]


def design_sweep_gains(context: dict[str, Any], cells: Sequence[dict[str, Any]]
                       ) -> dict[str, Any]:
    """Design the gains of every variant among ``cells`` once, in this process.

    Parameters
    ----------
    context : dict
        The sweep's context (``data``, ``source``, ``families``, ``plugins``).
    cells : sequence of dict
        The parameters of the cells to compute.

    Returns
    -------
    dict
        ``context`` with ``"gains"``: the design of each variant by :func:`_gain_key`
        (a :class:`netsim.estimators.gains.GainDesign`, or the cell's error text when the
        design fails), for the variants whose families need gains. A cell whose variant
        cannot be built is left out (the cell reports its own scenario error).
    """
    from netsim.estimators.gains import GainDesignError
    from netsim.models.scenario import ScenarioError
    from netsim.runner import scenario_gains
    from netsim.threads import single_threaded_blas

    table: dict[str, Any] = {}
    with single_threaded_blas():
        for params in cells:
            try:
                scenario = sweep_variant(context["data"], context["source"], params)
            except ScenarioError:
                continue
            if not any(f.needs_gains for f in _cell_families(context, scenario)):
                continue
            key = _gain_key(scenario)
            if key in table:
                continue
            try:
                table[key] = scenario_gains(scenario)
            except (GainDesignError, ValueError) as exc:
                table[key] = f"gain design failed: {exc}"
    return {**context, "gains": table}


def plugin_code(families: Sequence[Any]) -> Any:
    """The ``module:attribute`` families among ``families``, with their modules' code.

    A worker on another machine has no copy of a user's module file, so the families
    travel by value (:class:`netsim.sweep.ByValue`) keyed by their reference; built-in
    and installed (entry-point) families travel by name as before.

    Parameters
    ----------
    families : sequence of EstimatorFamily
        The resolved families of a sweep.

    Returns
    -------
    netsim.sweep.ByValue or None
        ``{family.key: family}`` of the plugins, None when there is none.
    """
    from netsim.sweep import ByValue

    plugins = {f.key: f for f in families if f.source == "scenario"}
    if not plugins:
        return None
    modules = [sys.modules[name] for name in
               sorted({(f.reference or "").partition(":")[0] for f in plugins.values()})
               if name in sys.modules and name.split(".")[0] != "netsim"]
    return ByValue(plugins, modules)


def scenario_sweep_cell(params: dict[str, Any], seed: Any, context: dict[str, Any]
                        ) -> dict[str, Any]:
    """One cell of ``netsim bench sweep``: a Monte Carlo run of a scenario variant.

    ``context``: ``{"data": TOML dict, "source": str, "families": [...], "trials": M,
    "steps": K}``, and from :func:`run_scenario_sweep` also ``"plugins"`` (the plugin
    families' code, :class:`netsim.sweep.ByValue`) and ``"gains"`` (every variant's
    design, made once on the client by :func:`design_sweep_gains`). A context without
    ``"gains"`` designs them here (cached per worker process).
    """
    from netsim.estimators.gains import GainDesignError
    from netsim.models.scenario import ScenarioError
    from netsim.papers import delay_bounds
    from netsim.runner import run_monte_carlo, scenario_gains

    try:
        scenario = sweep_variant(context["data"], context["source"], params)
    except ScenarioError as exc:
        return {"error": f"scenario: {exc}"}
    # the families by the keys that resolve them here (a plugin by its shipped code)
    families = _cell_families(context, scenario)
    gains = None
    if any(f.needs_gains for f in families):
        fp = _gain_key(scenario)
        table = context.get("gains")
        if table is not None and fp in table:
            gains = table[fp]
            if isinstance(gains, str):
                return {"error": gains}
        else:
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
            "rho_delay_free", "tau_star", *(b.run_key for b in delay_bounds()),
            "rho_exact_compensated", "rho_exact_uncompensated", "joint_system")}
    out["estimators"] = {
        # a steady MSE for stable runs only (netsim.verdicts.has_steady_state)
        name: {"verdict": e["verdict"],
               **({"steady_state_mse": e["steady_state_mse"]} if "steady_state_mse" in e
                  else {}),
               "last_trusted_mse": e["last_trusted_mse"],
               "growth_rate": e["growth_rate"], "diverged_trials": len(e["diverged_trials"]),
               # the engine that ran the family: vectorised (batched) or events
               "engine": result.engines.get(name, result.engine),
               "messages_sent": e["messages"]["sent"],
               "messages_delivered": e["messages"]["delivered"],
               # [time] scenarios: estimates sent per agent and time unit (triggers)
               **({"message_rate": e["messages"]["rate"]} if "rate" in e["messages"]
                  else {})}
        for name, e in data["estimators"].items()
    }
    return out


def run_scenario_sweep(scenario: str, *, axes: dict[str, list[Any] | None], trials: int, steps: int,
                       families: Sequence[str], seed: int, engine: str = "auto",
                       **options: Any):
    """Grid over ``axes`` (delays, tau, topology, agents, seed, loss, offset, drift_ppm,
    threshold, offset_pattern, drift_pattern; :func:`netsim.bench.variants.sweep_variant`)
    of one base scenario.

    ``engine`` runs the trials (``auto``: vectorised where it can); it is part of every
    cell's key. With ``auto`` each ``[time]`` cell runs on the batched timed engine where
    it expresses the cell (fixed offsets and drifts, no trigger holding updates back),
    else on the event kernel; each family's row names its ``engine``. An unknown pattern
    value is a ValueError naming its axis.
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
    from netsim.bench.variants import TIME_AXES, check_time_patterns

    patterns = {k: v for k, v in axes.items() if k.endswith("_pattern") and v}
    for axis, values in patterns.items():
        for value in values:
            check_time_patterns({axis: value})
    probe = base
    timed = any(axes.get(k) for k in TIME_AXES)
    if timed:
        probe = sweep_variant(data, source, {k: 0.0 for k in TIME_AXES if axes.get(k)})
        if engine == "vectorised":  # every [time] cell must be one the lockstep expresses
            for k in TIME_AXES:
                for value in axes.get(k) or ():
                    for pattern in grid(**patterns):
                        choose_engine(engine, declared, scenario=sweep_variant(
                            data, source, {k: value, **pattern}))
    requested = engine
    engine = choose_engine(engine, declared, scenario=probe)
    if engine == "mixed" or (timed and requested == "auto"):
        # each run picks per family (auto); a [time] cell runs on the timed lockstep
        # where it expresses the cell (fixed clocks, no trigger), else on the kernel
        engine = "auto"
    cells = grid(**{k: v for k, v in axes.items() if v})
    context = {"data": data, "source": source, "families": [f.key for f in declared],
               "trials": trials, "steps": steps, "fingerprint": scenario_fingerprint(base)}
    from netsim.verdicts import VERDICT_RULES

    cells = [{**c, "_scenario": context["fingerprint"], "_trials": trials, "_steps": steps,
              "_rules": VERDICT_RULES,
              "_engine": engine} for c in cells]
    context["plugins"] = plugin_code(declared)
    return run_sweep(scenario_sweep_cell, cells, root_seed=seed, sweep="scenario-sweep",
                     prepare=partial(design_sweep_gains, context), **options)
