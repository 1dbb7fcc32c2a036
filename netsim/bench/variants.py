"""The scenario of a benchmark cell: delay-setting and sweep variants, fingerprints."""

from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from netsim.bench.presets import DELAY_MODELS, NO_DELAY
from netsim.models.scenario import DelaySpec, Scenario

__all__ = ["DRIFT_PATTERNS", "OFFSET_PATTERNS", "TIME_AXES", "check_time_patterns",
           "delay_variant", "fixed_pattern", "scenario_data", "scenario_fingerprint",
           "sweep_variant"]


def delay_variant(scenario: Scenario, setting: str, tau: int) -> Scenario:
    """The scenario with the delay setting's model at bound tau (tau 0: no delay)."""
    model = "none" if setting == NO_DELAY or tau == 0 else DELAY_MODELS[setting]
    spec = DelaySpec(model=model, tau=int(tau), links={}, default=0,
                     seed=scenario.delays.seed)
    return replace(scenario, delays=spec)


def scenario_fingerprint(scenario: Scenario, gains: Any = None) -> str:
    """16 hex digits identifying the scenario's matrices, settings and gains."""
    h = hashlib.sha256()
    plant = scenario.plant
    arrays = [plant.A, plant.Q, plant.x0_mean, plant.x0_cov, scenario.weights,
              *plant.C, *plant.R]
    if gains is not None:
        arrays += list(gains.L)
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a, dtype=float))
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    summary = scenario.summary()
    summary.pop("source", None)
    h.update(json.dumps(summary, sort_keys=True, default=str).encode())
    h.update(repr((scenario.sample_period, scenario.divergence_threshold,
                   scenario.steady_state_fraction, scenario.delays.seed)).encode())
    return h.hexdigest()[:16]


def scenario_data(name_or_path: str) -> tuple[dict[str, Any], str]:
    """Return the TOML table of a built-in scenario or scenario file, and its source.

    Raises
    ------
    netsim.models.scenario.ScenarioError
        If the file cannot be read or parsed as TOML.
    """
    from netsim.models.scenario import builtin_scenarios, read_scenario_data

    builtins = builtin_scenarios()
    if name_or_path in builtins:
        path = builtins[name_or_path]
        source = f"builtin:{name_or_path}"
    else:
        path = Path(name_or_path)
        source = str(path)
    return read_scenario_data(path), source


def sweep_variant(data: dict[str, Any], source: str, params: dict[str, Any]) -> Scenario:
    """The scenario of one sweep cell: ``delays`` (a delay setting or ``delays.model``),
    ``tau``, ``topology``, ``agents`` (agent i carries sensor i mod m of the base plant),
    ``seed`` (run seed), ``loss`` (every link loses each message with this probability,
    Bernoulli, ``[links] loss``), and the ``[time]`` axes (:mod:`netsim.models.timing`):
    ``offset`` (clock offsets uniform in [-o, o]), ``drift_ppm`` (drifts N(0, s^2) ppm),
    ``threshold`` (a send-on-delta trigger), with ``offset_pattern`` (``uniform``, the
    default: drawn per trial; ``fixed``: :func:`fixed_pattern`) and ``drift_pattern``
    (``normal``, the default; ``fixed``)."""
    from netsim.models.scenario import parse_scenario

    data = copy.deepcopy(data)
    net = data.setdefault("network", {})
    plant = data.setdefault("plant", {})
    delays = data.setdefault("delays", {})
    if "agents" in params:
        n_agents = int(params["agents"])
        C = plant["C"]
        plant["C"] = [C[i % len(C)] for i in range(n_agents)]
        plant.pop("sensors", None)  # C now has one entry per agent
        if isinstance(plant.get("R"), list):
            plant["R"] = [plant["R"][i % len(plant["R"])] for i in range(n_agents)]
        net["agents"] = n_agents
        net.pop("P", None)
        if net.get("topology", "edges") == "edges":
            net["topology"] = "cycle"
        net.pop("edges", None)
        net.setdefault("weights", "random")
    if "topology" in params:
        net["topology"] = params["topology"]
        net.pop("P", None)
        if params["topology"] != "edges":
            net.pop("edges", None)
        net.setdefault("agents", len(plant["C"]))
    if "delays" in params:
        setting = params["delays"]
        delays["model"] = DELAY_MODELS.get(setting, setting)
        delays.pop("links", None)
    if "tau" in params:
        delays["tau"] = int(params["tau"])
        if delays.get("model", "none") == "none" and int(params["tau"]) > 0:
            delays["model"] = "homogeneous"
    if "seed" in params:
        data.setdefault("run", {})["seed"] = int(params["seed"])
    if float(params.get("loss", 0.0)) > 0:  # every link loses each message w.p. loss
        links = data["links"] = dict(data.get("links") or {})
        links["loss"] = {"model": "bernoulli", "p": float(params["loss"])}
    _time_axes(data, params)
    return parse_scenario(data, source)


#: Sweep axes that set the ``[time]`` table (clocks, triggers).
TIME_AXES = ("offset", "drift_ppm", "threshold")
#: How ``offset`` spreads over the agents: ``uniform`` draws each agent's offset per
#: trial uniform in [-o, o] (the event kernel runs it); ``fixed`` gives agent i the offset
#: o * p_i of :func:`fixed_pattern` in every trial (the batched timed engine runs it).
OFFSET_PATTERNS = ("uniform", "fixed")
#: How ``drift_ppm`` spreads over the agents: ``normal`` draws N(0, s^2) ppm per agent and
#: trial; ``fixed`` gives agent i the drift s * p_i ppm in every trial.
DRIFT_PATTERNS = ("normal", "fixed")
_PATTERN_AXES = {"offset_pattern": ("offset", OFFSET_PATTERNS),
                 "drift_pattern": ("drift_ppm", DRIFT_PATTERNS)}


def fixed_pattern(n_agents: int) -> list[float]:
    """The fixed clock pattern (-1, 1, -1/2, 1/2, -1/3, 1/3, ...): agent i gets
    (-1)^(i+1) / (i // 2 + 1), so the agents' clocks disagree by every fraction of the
    swept value up to its double, and the mean of an even count is 0.

    Parameters
    ----------
    n_agents : int
        The number of agents N.

    Returns
    -------
    list of float
        N multipliers p_i (agent i's offset is o p_i time units, its drift s p_i ppm).
    """
    return [(1.0 if i % 2 else -1.0) / (i // 2 + 1) for i in range(int(n_agents))]


def check_time_patterns(params: dict[str, Any]) -> None:
    """Raise ValueError (one line naming the axis) for an unknown ``offset_pattern`` or
    ``drift_pattern`` value in ``params``."""
    for axis, (_, allowed) in _PATTERN_AXES.items():
        if axis in params and params[axis] not in allowed:
            raise ValueError(f"{axis}: unknown pattern {params[axis]!r}; expected "
                             f"{' or '.join(allowed)}")


def _agent_count(data: dict[str, Any]) -> int:
    """The number of agents of the scenario's TOML dict (parsed without its ``[time]``
    table, which costs a matrix logarithm)."""
    from netsim.models.scenario import parse_scenario

    plain = {k: v for k, v in data.items() if k != "time"}
    return parse_scenario(plain, "sweep").n_agents


def _time_axes(data: dict[str, Any], params: dict[str, Any]) -> None:
    """Write the cell's ``[time]`` axes into the scenario's TOML dict (in place)."""
    if not any(k in params for k in TIME_AXES):
        return
    check_time_patterns(params)
    time = data.get("time")
    time = data["time"] = dict(time) if isinstance(time, dict) else {}
    fixed = [axis for axis, (value, _) in _PATTERN_AXES.items()
             if params.get(axis) == "fixed" and float(params.get(value, 0.0))]
    pattern = fixed_pattern(_agent_count(data)) if fixed else []
    if "offset" in params:
        o = float(params["offset"])
        if "offset_pattern" in fixed:
            time["offset"] = [o * p for p in pattern]
        else:
            time["offset"] = {"distribution": "uniform", "low": -o, "high": o} if o else 0.0
    if "drift_ppm" in params:
        s = float(params["drift_ppm"])
        if "drift_pattern" in fixed:
            time["drift_ppm"] = [s * p for p in pattern]
        else:
            time["drift_ppm"] = {"distribution": "normal", "std": s} if s else 0.0
    if "threshold" in params:
        time["trigger"] = {"kind": "send-on-delta", "threshold": float(params["threshold"])}
