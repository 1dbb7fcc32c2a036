"""Scenario runner: build agents for an estimator family, run trials, summarise.

Every trial uses the child seed ``(seed, "trial", t)``; within a trial the plant
draws from stream ``"plant"`` and random delay models from ``"delays/..."``.
Each estimator family runs in its own kernel run on the *same* trial seed, so all
families see the same initial state and noise (and the same link delays, when the
delay model is fixed or when they send on the same steps).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from netsim import budget, interrupt, verdicts
from netsim.estimators.gains import GainDesign, design_for_scenario
from netsim.estimators.registry import (
    EstimatorFamily,
    FamilyContext,
    get_family,
    resolve_families,
)
from netsim.models.augmented import (
    augmented_closed_loop,
    delay_bound_lcsys,
    spectral_radius,
    tau_star,
)
from netsim.models.delays import latency_to_steps
from netsim.models.jointsystem import (
    RECURSION_BLOCK,
    RECURSION_COMPENSATED,
    RECURSION_UNCOMPENSATED,
    JointAnalysis,
    block_joint_analysis,
    joint_analysis,
)
from netsim.models.jsonsafe import json_number as _json_float
from netsim.models.jsonsafe import json_tree as _json_tree
from netsim.models.lazy import issparse
from netsim.models.scenario import Scenario
from netsim.models.seeding import SEED_LAYOUT, SeedLike, child_sequence, stream
from netsim.threads import single_threaded_blas

if TYPE_CHECKING:  # the event kernel (and simpy) loads when a run uses it (issue 34)
    from netsim.kernel import AgentSpec, KernelObserver, TrialResult

__all__ = [
    "GROWTH_TOLERANCE",
    "EstimatorSummary",
    "MonteCarloResult",
    "scenario_gains",
    "build_agents",
    "ENGINES",
    "scenario_folder",
    "family_of",
    "check_agents",
    "engines_for",
    "timed_engine_line",
    "planned_engines",
    "kernel_fallbacks",
    "choose_engine",
    "run_trial",
    "run_trials",
    "run_monte_carlo",
    "delay_analytics",
    "joint_system_analyses",
    "TraceWriteError",
    "trace_files",
    "fixed_link_delays",
]

#: Simulation engines: ``events`` (the SimPy kernel, the reference), ``vectorised``
#: (all trials in lockstep, :mod:`netsim.vectorised`), ``auto`` (vectorised when every
#: family has a vectorised form; traced runs too, see :mod:`netsim.vectrace`).
ENGINES = ("auto", "vectorised", "events")

#: Factor by which the fitted MSE trend may grow over the fitted window before a run
#: without blow-up counts as diverging (re-exported from :mod:`netsim.verdicts`).
GROWTH_TOLERANCE = verdicts.GROWTH_TOLERANCE


@single_threaded_blas()
def scenario_gains(scenario: Scenario) -> GainDesign:
    """Return the gains of the scenario's ``[gains]`` table (:func:`design_for_scenario`),
    from the disk cache when it holds them (:mod:`netsim.gaincache`).

    Raises :class:`netsim.budget.ResourceError` first if the design (its PBH test and
    SDP) cannot run on this machine (:func:`netsim.budget.check_gain_design`).
    """
    from netsim.estimators.gains import design_request
    from netsim.gaincache import cached_design

    budget.check_gain_design(scenario)
    return cached_design(scenario, design_request(scenario),
                         lambda: design_for_scenario(scenario))


def _measure(sensors: Sequence[int], n_sensors: int) -> Callable[[Sequence[np.ndarray]], Any]:
    """The selector of an agent's measurement from all sensors' y^j_k."""
    if len(sensors) == 1:
        return itemgetter(sensors[0])
    if tuple(sensors) == tuple(range(n_sensors)):
        return np.concatenate
    if not sensors:
        empty = np.zeros(0)
        return lambda ys: empty
    picked = itemgetter(*sensors)
    return lambda ys: np.concatenate(picked(ys))


def scenario_folder(scenario: Scenario) -> Path | None:
    """The folder of a scenario file (searched for ``module:attribute`` estimators)."""
    source = scenario.source
    if not source or source.startswith("builtin:"):
        return None
    return Path(source).resolve().parent


def family_of(family: str | EstimatorFamily, scenario: Scenario | None = None,
              key: str = "family") -> EstimatorFamily:
    """The registered family of a name (module:attribute and entry points included;
    a module beside ``scenario``'s file is found)."""
    if isinstance(family, EstimatorFamily):
        return family
    return get_family(family, key, None if scenario is None else scenario_folder(scenario))


def build_agents(scenario: Scenario, family: str | EstimatorFamily, gains: GainDesign | None,
                 trial_seed: SeedLike = 0) -> list[AgentSpec]:
    """Return the kernel agents of one estimator family for one trial.

    Parameters
    ----------
    scenario : Scenario
    family : str or EstimatorFamily
        A registered family (:mod:`netsim.estimators.registry`), ``module:attribute``
        of a user's estimator, or an installed entry point.
    gains : GainDesign or None
        Innovation gains L_i (for families that declare ``needs_gains``).
    trial_seed : seed-like
        The trial's seed (a plugin's agents draw their own streams from it).
    """
    from netsim.kernel import AgentSpec

    declared = family_of(family)
    plans = declared.agents(FamilyContext(scenario, gains, trial_seed))
    n_sensors = scenario.plant.n_sensors
    return [AgentSpec(plan.estimator, _measure(plan.sensors, n_sensors),
                      list(plan.out_neighbours)) for plan in plans]


def check_agents(scenario: Scenario, families: Sequence[str | EstimatorFamily],
                 gains: GainDesign | None, key: str = "run.estimators") -> None:
    """Build trial 0's agents of every family not shipped with netsim, so that one that
    breaks the contract is refused before anything runs (FamilyError, a ValueError,
    naming ``key``: the scenario key or option that listed the families)."""
    for family in families:
        declared = family_of(family, scenario)
        if declared.source != "builtin":
            declared.agents(FamilyContext(scenario, gains, child_sequence(0, "check")), key)


def run_trial(
    scenario: Scenario,
    family: str | EstimatorFamily,
    gains: GainDesign | None,
    trial_seed: SeedLike,
    steps: int | None = None,
    *,
    record_delays: bool = True,
    record_messages: bool = False,
    observer: KernelObserver | None = None,
) -> TrialResult:
    """Run one trial of one estimator family in the event kernel.

    A time-varying ``scenario.topology`` is the kernel's ``availability`` hook; a
    family's own observer (``EstimatorFamily.observer``) wraps ``observer`` and what it
    collects is ``TrialResult.extras``.
    """
    from netsim.kernel import AgentSpec, Simulation

    steps = scenario.steps if steps is None else int(steps)
    budget.check_memory(budget.kernel_trial_bytes(scenario, steps, record_delays=record_delays),
                        "steps", "one event-kernel trial", steps)
    declared = family_of(family, scenario)
    if scenario.timing is not None:  # clocks, asynchronous sampling, triggers
        from netsim.timedkernel import run_timed_trial

        return run_timed_trial(scenario, declared, gains, trial_seed, steps,
                               record_delays=record_delays, record_messages=record_messages,
                               observer=observer)
    context = FamilyContext(scenario, gains, trial_seed, declared.name)
    plans = declared.agents(context)
    n_sensors = scenario.plant.n_sensors
    agents = [AgentSpec(plan.estimator, _measure(plan.sensors, n_sensors),
                        list(plan.out_neighbours)) for plan in plans]
    tap = None if declared.observer is None else declared.observer(context, plans, steps,
                                                                    observer)
    topology = scenario.topology
    simulation = Simulation(
        scenario.plant,
        agents,
        scenario.delay_model(trial_seed),
        stream(trial_seed, "plant"),
        sample_period=scenario.sample_period,
        divergence_threshold=scenario.divergence_threshold,
        record_delays=record_delays,
        record_messages=record_messages,
        observer=observer if tap is None else tap,
        availability=None if topology is None else topology.is_up,
    )
    result = simulation.run(steps)
    if tap is not None:
        result.extras = dict(tap.collect())
    return result


def engines_for(engine: str, families: Sequence[str | EstimatorFamily],
                scenario: Scenario | None = None, *, traced: bool = False) -> dict[str, str]:
    """The engine each family runs on: ``vectorised`` or ``events``.

    ``auto`` gives the vectorised engine to every family with a batched form and the
    event kernel to the others (:func:`kernel_fallbacks` names them); ``vectorised``
    refuses a family without one (ValueError); ``events`` runs all in the kernel. A
    scenario with a time-varying topology runs in the kernel (the lockstep engine
    does not model links going up and down). A ``[time]`` scenario runs on the timed
    lockstep (:mod:`netsim.timedlockstep`) where it can express the case and the run
    is not traced, else on the timed kernel (:func:`_timed_engines`).
    """
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; expected one of {', '.join(ENGINES)}")
    declared = [family_of(f, scenario) for f in families]
    if scenario is not None and scenario.timing is not None:  # netsim.timedkernel
        return _timed_engines(engine, declared, scenario, traced)
    if scenario is not None and scenario.topology is not None:
        if engine == "vectorised":
            raise ValueError("the vectorised engine does not model a time-varying "
                             "[topology]; only the event kernel runs it (--engine events "
                             "or auto)")
        return {f.name: "events" for f in declared}
    if engine == "vectorised":
        bad = [f.name for f in declared if not f.vectorised]
        if bad:
            raise ValueError(f"the vectorised engine has no estimator family {bad[0]!r} "
                             "(it has no batched form; use --engine events or auto)")
    if engine == "events":
        return {f.name: "events" for f in declared}
    return {f.name: "vectorised" if f.vectorised else "events" for f in declared}


def _timed_engines(engine: str, declared: Sequence[EstimatorFamily], scenario: Scenario,
                   traced: bool) -> dict[str, str]:
    """:func:`engines_for` of a ``[time]`` scenario: ``vectorised`` (the timed lockstep,
    :mod:`netsim.timedlockstep`) for a family with a batched form whose case it
    expresses, unless traced (traces of timed runs are the kernel's); ``--engine
    vectorised`` on any other is one ValueError naming why."""
    from netsim.timedlockstep import lockstep_refusal

    if engine == "events":
        return {f.name: "events" for f in declared}
    why = ("a traced [time] run is written by the event kernel" if traced
           else lockstep_refusal(scenario))
    reasons = {f.name: why or (None if f.vectorised else "it has no batched form")
               or lockstep_refusal(scenario, f) for f in declared}
    if engine == "vectorised":
        for name, reason in reasons.items():
            if reason is not None:
                raise ValueError(f"{reason} (family {name!r}: --engine events or auto)")
    return {name: "events" if reason else "vectorised" for name, reason in reasons.items()}


def timed_engine_line(engine: str, families: Sequence[str | EstimatorFamily],
                      scenario: Scenario, *, traced: bool = False) -> str | None:
    """The note a run of a ``[time]`` scenario prints about its engines (None for
    another scenario, or when the request is invalid): which families run on the timed
    lockstep and which on the kernel, and why."""
    if scenario.timing is None:
        return None
    declared = [family_of(f, scenario) for f in families]
    try:
        engines = engines_for(engine, declared, scenario, traced=traced)
    except ValueError:
        return None
    kernel = [name for name, e in engines.items() if e == "events"]
    if not kernel:
        return ("the [time] table runs on the vectorised engine (netsim.timedlockstep: "
                "every trial samples at the same instants)")
    from netsim.timedlockstep import lockstep_refusal

    why = ("--engine events" if engine == "events" else
           "a traced [time] run is written by the event kernel" if traced else
           lockstep_refusal(scenario) or "; ".join(
               filter(None, (lockstep_refusal(scenario, f) or
                             (None if f.vectorised else f"{f.name!r} has no batched form")
                             for f in declared if f.name in kernel))))
    return (f"the [time] table runs {', '.join(kernel)} on the event kernel: {why}")


def planned_engines(engine: str, families: Sequence[str | EstimatorFamily],
                    scenario: Scenario | None = None) -> list[str]:
    """The engines a run will use, for the budget (:func:`netsim.budget.guard_run`):
    :func:`engines_for`'s values, or both engines when the request is invalid (the run
    itself then reports the bad choice)."""
    try:
        return list(engines_for(engine, families, scenario).values())
    except ValueError:
        return ["events", "vectorised"]


def kernel_fallbacks(engine: str, families: Sequence[str | EstimatorFamily],
                     scenario: Scenario | None = None) -> list[str]:
    """Families with no batched form, which ``engine`` (``auto``) runs in the event
    kernel (none are named when the scenario's topology sends every family there)."""
    if engine != "auto" or (scenario is not None and (scenario.topology is not None
                                                      or scenario.timing is not None)):
        return []
    return [name for name, e in engines_for(engine, families).items() if e == "events"]


def choose_engine(engine: str, families: Sequence[str | EstimatorFamily], *,
                  traced: bool = False, scenario: Scenario | None = None) -> str:
    """Resolve ``auto`` and check that the engine can run the request.

    Returns ``"vectorised"`` when every family runs on the vectorised engine, else
    ``"events"`` for a request that runs wholly in the kernel, or ``"mixed"``
    (``auto`` with some families lacking a batched form; see :func:`engines_for`).
    Raises ValueError for a request the chosen engine cannot serve. Both engines write
    the same traces, so ``traced`` does not change the choice.
    """
    # both engines trace; a [time] scenario's traces are the timed kernel's
    chosen = set(engines_for(engine, families, scenario, traced=traced).values())
    if len(chosen) == 1:
        return chosen.pop()
    return "vectorised" if not chosen else "mixed"


def run_trials(
    scenario: Scenario,
    family: str | EstimatorFamily,
    gains: GainDesign | None,
    trial_seeds: Sequence[SeedLike],
    steps: int | None = None,
    *,
    engine: str = "auto",
    record_delays: bool | Collection[int] = False,
    record_estimates: bool = True,
    progress: Callable[[int], None] | None = None,
) -> list[TrialResult]:
    """Run several trials of one estimator family on the chosen engine.

    The engines give the same results (to round-off) for the same trial seeds; the
    vectorised one runs all trials in lockstep through the family's batched form.
    ``record_delays``: True, False or the indices of the trials whose effective delays
    to keep.
    """
    declared = family_of(family)
    if scenario.timing is not None:  # the timed lockstep, or the timed kernel below
        if engines_for(engine, [declared], scenario)[declared.name] == "vectorised":
            from netsim.timedlockstep import run_timed_lockstep

            return run_timed_lockstep(scenario, declared.name, gains, trial_seeds, steps,
                                      record_delays=record_delays,
                                      record_estimates=record_estimates, progress=progress)
    elif engines_for(engine, [declared])[declared.name] == "vectorised":
        batched = declared.batched_form()
        return list(batched(scenario, declared.name, gains, trial_seeds, steps,
                            record_delays=record_delays, record_estimates=record_estimates,
                            progress=progress))
    wanted = set(range(len(trial_seeds))) if record_delays is True else set(
        record_delays or ())
    results = []
    for t, seed in enumerate(trial_seeds):
        results.append(run_trial(scenario, declared, gains, seed, steps,
                                 record_delays=t in wanted))
        if progress is not None:
            progress(1)
    return results


def fixed_link_delays(scenario: Scenario) -> np.ndarray | None:
    """Return the step delay d_ij of every link of a time-invariant delay model, in the
    order of ``scenario.links`` (shape (L,), int), else None. Plain fixed delays
    (homogeneous, heterogeneous, fixed) are looked up in one vectorised step."""
    from netsim.models.delays import FixedDelays

    model = scenario.delay_model(0)
    if not model.time_invariant:
        return None
    table = scenario.link_table
    if type(model) is FixedDelays:
        return model.link_delays(table.src, table.dst).astype(int)
    out = np.zeros(len(table), dtype=int)
    for q, (j, i) in enumerate(scenario.links):
        raw = model.draw(j, i, 0)
        out[q] = (
            int(raw) if model.unit == "steps" else latency_to_steps(raw, scenario.sample_period)
        )
    return out


def fixed_delay_matrix(scenario: Scenario) -> np.ndarray | None:
    """Return the (N, N) step delays d_ij of a time-invariant delay model, else None
    (small networks; large ones use :func:`fixed_link_delays`)."""
    per_link = fixed_link_delays(scenario)
    if per_link is None:
        return None
    delays = np.zeros((scenario.n_agents, scenario.n_agents), dtype=int)
    table = scenario.link_table
    delays[table.dst, table.src] = per_link
    return delays


def delay_analytics(scenario: Scenario, gains: GainDesign) -> dict[str, Any]:
    """Spectral quantities of the scenario's delays next to the papers' bounds.

    Returns rho(A-hat) delay-free; Theorem 1's tau* (LCSYS2022); at the delay bound
    tau: the eq. (26) bound rho((I-KD)(P kron A^(tau+1)))^(1/(tau+1)) and the
    delay-tolerant paper's rho(A-hat)^(1/(tau+1)); for time-invariant delays, the exact
    spectral radius of the augmented closed loop of the realised delays, with
    compensation (LCSYS2022 eq. 9-10) and without (delay-tolerant eq. 11; that matrix is
    the error recursion alone, which leaves out the forcing of the error by a moving
    state); and ``joint_system``: per declared error recursion (the registry's
    ``RECURSION_*`` identifiers of eq. 9, eq. 11 and eqs. 15-16) the analysis of the joint
    system of plant state and error (:func:`joint_system_analyses`), or
    ``joint_system_note`` saying why there is none.
    """
    return _delay_analytics(scenario, gains)[0]


#: Largest N n (tau + 1) for the exact augmented radii and the joint-system analysis.
_EXACT_MAX_SIZE = 4000


def _delay_analytics(scenario: Scenario, gains: GainDesign
                     ) -> tuple[dict[str, Any], dict[str, JointAnalysis]]:
    plant = scenario.plant
    P, A, C, L = scenario.weights, plant.A, plant.C, gains.L
    tau = scenario.delay_bound
    rho0 = float(gains.rho)
    if issparse(P):
        # large sparse network: the delay-free rho of the design and the tolerant bound
        # only; tau*, eq. (26) and the exact augmented radii need dense P here
        return {
            "delay_bound": tau,
            "rho_delay_free": rho0,
            "tau_star": None,
            "bound_lcsys_eq26": None,
            "bound_delay_tolerant": rho0 ** (1.0 / (tau + 1)),
            "rho_exact_compensated": None,
            "rho_exact_uncompensated": None,
            "note": f"N = {scenario.n_agents} agents (sparse weights): tau*, the eq. (26) "
                    "bound and the exact augmented spectral radii were not computed",
            "joint_system_note": "sparse network: no exact analysis; the measured growth "
                                 "decides",
        }, {}
    out: dict[str, Any] = {
        "delay_bound": tau,
        "rho_delay_free": rho0,
        "tau_star": tau_star(P, A, C, L),
        "bound_lcsys_eq26": float(delay_bound_lcsys(P, A, C, L, tau)),
        "bound_delay_tolerant": rho0 ** (1.0 / (tau + 1)),
        "rho_exact_compensated": None,
        "rho_exact_uncompensated": None,
    }
    delays = fixed_delay_matrix(scenario)
    timing = scenario.timing
    if timing is not None and not timing.neutral:  # netsim.timedkernel: measured verdicts
        from netsim.timedanalysis import lifted_summary

        lifted = lifted_summary(scenario, gains, delays)  # exact where it applies
        delays = None
        out["time"] = {"note": timing.analytics_note(), **lifted,
                       "summary_lines": [f"analytics: {timing.analytics_note()}",
                                         *(lifted.get("summary_lines")
                                           or [f"analytics: {lifted.get('lifted_note')}"])]}
    if delays is not None and scenario.n_agents * plant.n_states * (tau + 1) <= _EXACT_MAX_SIZE:
        depth = int(delays.max())
        out["realised_delays"] = {
            f"{j}->{i}": int(delays[i, j]) for j, i in scenario.links
        }
        out["rho_exact_compensated"] = spectral_radius(
            augmented_closed_loop(P, A, C, L, delays, depth, compensated=True)
        )
        out["rho_exact_uncompensated"] = spectral_radius(
            augmented_closed_loop(P, A, C, L, delays, depth, compensated=False)
        )
    analyses, note = _joint_system(scenario, gains, delays, out["rho_exact_compensated"],
                                   out["rho_exact_uncompensated"])
    if analyses:
        out["joint_system"] = {kind: a.to_dict() for kind, a in analyses.items()}
    if note:
        out["joint_system_note"] = note
    return out, analyses


def joint_system_analyses(scenario: Scenario, gains: GainDesign) -> dict[str, JointAnalysis]:
    """The exact analyses of the joint system of plant state and estimation error
    (:mod:`netsim.models.jointsystem`) that apply to the scenario, by the error recursion
    a family declares (``EstimatorFamily.error_recursion``).

    LCSYS2022 eq. (9) (compensating) and the delay-tolerant eq. (11) (uncompensated) when
    the delays are fixed (a time-invariant delay model without losses, outages or
    buffers), the topology does not vary and the dense analysis fits
    (N n (tau+1) <= 4000); ``block`` (eqs. 15-16) when, in addition, every delay is
    within the bound tau (the block update, eqs. 15-16). Empty otherwise: there the
    measured growth decides.
    """
    return _delay_analytics(scenario, gains)[1]


def _joint_system(scenario: Scenario, gains: GainDesign, delays: np.ndarray | None,
                  rho_comp: float | None, rho_uncomp: float | None
                  ) -> tuple[dict[str, JointAnalysis], str]:
    """The joint-system analyses that apply, and a note on what does not."""
    if scenario.timing is not None and not scenario.timing.neutral:
        return {}, scenario.timing.analytics_note()
    if scenario.topology is not None:
        return {}, ("time-varying topology: no exact analysis of the joint system of state "
                    "and error; the measured growth decides")
    if delays is None:
        return {}, ("delays not fixed (time-varying delays, losses, outages or buffers): no "
                    "exact analysis of the joint system of state and error; the measured "
                    "growth decides")
    plant = scenario.plant
    tau = scenario.delay_bound
    if scenario.n_agents * plant.n_states * (tau + 1) > _EXACT_MAX_SIZE:
        return {}, (f"N n (tau+1) = {scenario.n_agents * plant.n_states * (tau + 1)} > "
                    f"{_EXACT_MAX_SIZE}: no exact analysis; the measured growth decides")
    P, A, C, L = scenario.weights, plant.A, plant.C, gains.L
    common = {"Q": plant.Q, "x0_mean": plant.x0_mean, "x0_cov": plant.x0_cov}
    out = {
        RECURSION_COMPENSATED: joint_analysis(P, A, C, L, delays, compensated=True,
                                              rho_error=rho_comp, **common),
        RECURSION_UNCOMPENSATED: joint_analysis(P, A, C, L, delays, compensated=False,
                                                rho_error=rho_uncomp, **common),
    }
    note = ""
    edge = (np.asarray(P) != 0) & ~np.eye(scenario.n_agents, dtype=bool)
    if not np.any(edge) or int(delays[edge].max()) <= tau:
        out[RECURSION_BLOCK] = block_joint_analysis(P, A, C, L, tau, **common)
    else:
        note = (f"block update: a link delay exceeds its bound tau = {tau}, so its error is "
                "not the eqs. (15)-(16) recursion; the measured growth decides")
    return out, note


@dataclass
class EstimatorSummary:
    """Monte Carlo summary of one estimator family.

    Attributes
    ----------
    family : str
    mse : numpy.ndarray, shape (K+1,)
        Network MSE (1/N) sum_i ||x_k - x-hat^i_k||^2 averaged over the trials that
        did not diverge (NaN if all diverged).
    steady_state_mse : float
        Mean of ``mse`` over the last ``steady_state_fraction`` of the trusted steps
        (those before the precision horizon, :mod:`netsim.verdicts`), for a run judged
        stable (:func:`netsim.verdicts.has_steady_state`); NaN for any other verdict
        (a diverging or unbounded MSE has no steady state: see ``last_trusted_mse``).
    growth_rate : float
        exp of the mean over trials of the least-squares slope of log(trial MSE) over
        the second half of the trusted steps: the per-step MSE growth factor (about 1
        at steady state, < 1 while decaying).
    diverged : list of (trial, step)
        Trials whose error blew up, with the step it happened.
    verdict : str
        ``diverged`` (some trial blew up), ``diverging``, ``unbounded``, ``stable`` or
        ``undecided`` by the rule of :mod:`netsim.verdicts` (or a family's own word from
        its report).
    judgement : netsim.verdicts.Verdict or None
        The verdict with its basis, reason, growth estimate and precision horizon.
    last_trusted_mse : float
        ``mse`` at the last trusted step (before the precision horizon).
    last_trusted_step : int or None
        That step.
    tail_mse : float
        Mean of ``mse`` over the last ``steady_state_fraction`` of the trusted steps,
        whatever the verdict (``steady_state_mse`` once the run is judged stable).
    """

    family: str
    mse: np.ndarray
    steady_state_mse: float
    growth_rate: float
    diverged: list[tuple[int, int]]
    verdict: str
    messages_sent: int = 0
    messages_delivered: int = 0
    messages_discarded: int = 0
    #: The family's own numbers (``EstimatorFamily.report``), or None.
    report: dict[str, Any] | None = None
    #: Trials summarised when the run stopped early (a trace could not be written),
    #: else None (all of them).
    trials_finished: int | None = None
    judgement: verdicts.Verdict | None = None
    last_trusted_mse: float = math.nan
    last_trusted_step: int | None = None
    tail_mse: float = math.nan
    #: Under a ``[time]`` table (:mod:`netsim.timedkernel`): estimates sent per agent and
    #: time unit, and the fraction of updates sent (the triggers' doing), mean over
    #: trials; None otherwise.
    message_rate: float | None = None
    send_fraction: float | None = None

    def settle(self) -> None:
        """Set ``steady_state_mse`` from the final verdict: the tail mean for a run with
        a steady state (:func:`netsim.verdicts.has_steady_state`), else NaN."""
        self.steady_state_mse = (self.tail_mse if verdicts.has_steady_state(self.verdict)
                                 else math.nan)

    @property
    def has_steady_state(self) -> bool:
        """Whether the verdict gives the run a steady MSE."""
        return verdicts.has_steady_state(self.verdict)

    @property
    def precision_horizon(self) -> int | None:
        """First step whose errors are below float64 resolution of the state, or None."""
        return None if self.judgement is None else self.judgement.precision_horizon

    def to_dict(self) -> dict[str, Any]:
        k = len(self.mse) - 1
        marks = sorted({0, k // 10, k // 4, k // 2, (3 * k) // 4, k})
        return {
            "family": self.family,
            "verdict": self.verdict,
            # a steady MSE belongs to stable runs only (netsim.verdicts.has_steady_state)
            **({"steady_state_mse": _json_float(self.steady_state_mse)}
               if self.has_steady_state else {}),
            "last_trusted_mse": _json_float(self.last_trusted_mse),
            "last_trusted_step": self.last_trusted_step,
            "growth_rate": _json_float(self.growth_rate),
            "mse_at": {str(m): _json_float(self.mse[m]) for m in marks},
            "diverged_trials": [{"trial": t, "step": s} for t, s in self.diverged],
            "precision_horizon": self.precision_horizon,
            # the MSE@ values from the precision horizon on are rounding, not errors
            "mse_at_beyond_horizon": verdicts.beyond_horizon(marks, self.precision_horizon),
            "mse_at_trusted": verdicts.trusted_values(
                {str(m): _json_float(self.mse[m]) for m in marks}, self.precision_horizon),
            **({"verdict_detail": self.judgement.to_dict()}
               if self.judgement is not None else {}),
            "messages": {
                "sent": self.messages_sent,
                "delivered": self.messages_delivered,
                "discarded_stale": self.messages_discarded,
                **({"rate": _json_float(self.message_rate),
                    "send_fraction": _json_float(self.send_fraction)}
                   if self.message_rate is not None else {}),
            },
            **({"report": _json_tree(self.report)} if self.report is not None else {}),
            **({"trials_finished": self.trials_finished}
               if self.trials_finished is not None else {}),
        }


@dataclass
class MonteCarloResult:
    """Result of :func:`run_monte_carlo`."""

    scenario: Scenario
    gains: GainDesign | None
    steps: int
    trials: int
    seed: int
    estimators: dict[str, EstimatorSummary] = field(default_factory=dict)
    analytics: dict[str, Any] | None = None
    engine: str = "events"
    engines: dict[str, str] = field(default_factory=dict)
    #: Every trial's result per family (with ``keep_trials``), else empty.
    runs: dict[str, list[TrialResult]] = field(default_factory=dict)
    #: Layout of the random streams the seed was spawned into
    #: (:data:`netsim.models.seeding.SEED_LAYOUT`): the same seed gives other numbers
    #: under another layout.
    seed_layout: int = SEED_LAYOUT

    def to_dict(self) -> dict[str, Any]:
        gains = None
        if self.gains is not None:
            gains = {
                "method": self.gains.method,
                "solver": self.gains.solver,
                "status": self.gains.status,
                "certified": self.gains.certified,
                "certified_rate": _json_float(self.gains.certified_rate),
                "rho_delay_free": _json_float(self.gains.rho),
                "L": [np.asarray(L).tolist() for L in self.gains.L],
            }
        return {
            "scenario": self.scenario.summary(),
            "steps": self.steps,
            "trials": self.trials,
            "seed": self.seed,
            "seed_layout": self.seed_layout,
            "engine": self.engine,
            **({"engines": dict(self.engines)} if self.engine == "mixed" else {}),
            "gains": gains,
            "analytics": _json_tree(self.analytics),
            "estimators": {name: s.to_dict() for name, s in self.estimators.items()},
        }


def _summarise(
    family: str, trials: list[TrialResult], fraction: float, n_steps: int,
    reported: Sequence[int] | None = None, analysis: JointAnalysis | None = None,
) -> EstimatorSummary:
    columns = slice(None) if reported is None else list(reported)
    per_trial = [r.squared_errors[:, columns].mean(axis=1) for r in trials]
    length = len(per_trial[0]) if per_trial else n_steps + 1
    states = [r.states for r in trials] if trials and all(
        r.states is not None and len(r.states) == length for r in trials) else None
    judgement = verdicts.judge(np.array(per_trial) if per_trial else np.zeros((0, length)),
                               states=states, diverged_at=[r.diverged_at for r in trials],
                               analysis=analysis)
    horizon = judgement.precision_horizon
    diverged = [(t, r.diverged_at) for t, r in enumerate(trials) if r.diverged_at is not None
                and (horizon is None or r.diverged_at < horizon)]
    good = [m for t, m in enumerate(per_trial) if t not in {d for d, _ in diverged}]
    if good:
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mse = np.nanmean(good, axis=0) if horizon is not None else np.mean(good, axis=0)
    else:
        mse = np.full(length, np.nan)
    window = verdicts.steady_slice(len(mse), fraction, horizon)
    steady = float(np.mean(mse[window])) if good else math.nan
    last = window.stop - 1
    summary = EstimatorSummary(
        family=family,
        mse=mse,
        steady_state_mse=steady,
        growth_rate=judgement.growth.rate,
        diverged=diverged,
        verdict=judgement.verdict,
        messages_sent=sum(r.messages_sent for r in trials),
        messages_delivered=sum(r.messages_delivered for r in trials),
        messages_discarded=sum(r.messages_discarded for r in trials),
        judgement=judgement,
        last_trusted_mse=float(mse[last]) if good and len(mse) else math.nan,
        last_trusted_step=last if good and len(mse) else None,
        tail_mse=steady,
    )
    timed = [r.extras["timing"] for r in trials if "timing" in r.extras]
    if timed:  # netsim.timedkernel's counts
        summary.message_rate = float(np.mean([t["message_rate"] for t in timed]))
        summary.send_fraction = float(np.mean([t["send_fraction"] for t in timed]))
    summary.settle()
    return summary


def _analysis_of(family: EstimatorFamily, analyses: Mapping[str, JointAnalysis]
                 ) -> JointAnalysis | None:
    """The exact joint-system analysis of the family's error, where one applies: a
    declared error recursion (compensated, uncompensated, block) under fixed delays
    (:func:`joint_system_analyses`); None otherwise (the measured growth decides)."""
    return analyses.get(family.error_recursion or "")


class TraceWriteError(OSError):
    """A trace file could not be written (e.g. the disk is full).

    ``path`` is the file; ``partial`` the :class:`MonteCarloResult` of what finished
    before (every finished family, and the finished trials of the one that failed,
    with ``EstimatorSummary.trials_finished`` set), filled in by
    :func:`run_monte_carlo`.
    """

    def __init__(self, path: str | Path, cause: OSError) -> None:
        super().__init__(cause.errno, cause.strerror or str(cause), str(path))
        self.path = str(path)
        self.cause = cause
        self.partial: MonteCarloResult | None = None


def trace_files(trace: str | Path, families: Sequence[str], trials: int) -> list[Path]:
    """The files ``run_monte_carlo(trace=...)`` writes: ``trace`` itself for a single
    run, else one per family and trial (:func:`netsim.traces.recorder.trace_path`)."""
    from netsim.traces.recorder import trace_path

    if trials == 1 and len(families) == 1:
        return [trace_path(trace)]
    return [trace_path(trace, family_of(f).name, t) for f in families for t in range(trials)]


def _replayable_lockstep(family: EstimatorFamily) -> bool:
    """Whether the family's batched form is the vectorised engine's own lockstep, whose
    batches :mod:`netsim.vectrace` replays into a trace."""
    return family.batched == "netsim.vectorised:run_vectorised"


def _traced_trial(scenario, family, gains, seed, t, steps, trace, single, on_trace,
                  batch=None, batch_trial=None, trace_options=None):
    """Run (event kernel) or replay (``batch``: a vectorised batch) trial t into a trace."""
    from netsim.traces.recorder import TraceRecorder, trace_path

    declared = family_of(family)
    family = declared.name
    path = trace_path(trace) if single else trace_path(trace, family, t)
    options = dict(trace_options or {})
    if scenario.timing is not None and not scenario.timing.neutral:
        # format 3 lays messages out per step; clocks and samples need format 2
        options.setdefault("trace_format", 2)
    try:
        recorder = TraceRecorder.for_run(path, scenario, gains, family, t, seed=seed,
                                         steps=steps, family_traits=declared.traits(),
                                         **options)
    except OSError as exc:
        raise TraceWriteError(path, exc) from exc
    written = False
    try:
        with recorder:
            if batch is None:
                result = run_trial(
                    scenario, declared, gains, child_sequence(seed, "trial", t), steps,
                    record_delays=False, observer=recorder,
                )
            else:
                from netsim.vectrace import write_trial

                index = t if batch_trial is None else batch_trial
                write_trial(batch, index, scenario, family, recorder)
                result = batch.results[index]
            if result.diverged_at is not None:
                recorder.set_status("diverged", diverged_at=result.diverged_at)
        written = True
    except OSError as exc:  # the file could not be written: it is not finished
        raise TraceWriteError(path, exc) from exc
    except BaseException:
        written = True  # finished, with run_status "interrupted" or "failed"
        raise
    finally:
        if on_trace is not None and written:
            on_trace(str(path))
    return result


@single_threaded_blas()
def run_monte_carlo(
    scenario: Scenario,
    *,
    steps: int | None = None,
    trials: int | None = None,
    seed: int | None = None,
    families: Sequence[str | EstimatorFamily] | None = None,
    progress: Callable[[int], None] | None = None,
    gains: GainDesign | None = None,
    trace: str | None = None,
    on_trace: Callable[[str], None] | None = None,
    engine: str = "auto",
    keep_trials: bool = False,
    trace_options: Mapping[str, Any] | None = None,
) -> MonteCarloResult:
    """Run every estimator family of the scenario over Monte Carlo trials.

    Parameters
    ----------
    scenario : Scenario
    steps, trials, seed : int, optional
        Override the scenario's run settings.
    families : sequence of str or EstimatorFamily, optional
        Families to run (default: the scenario's estimators).
    progress : callable(int), optional
        Called with 1 after every finished trial (e.g. a tqdm ``update``).
    gains : GainDesign, optional
        Pre-computed gains (otherwise designed or taken from the scenario).
    trace : str, optional
        Record every run to MCAP: the file ``trace`` itself for a single run, else one
        file per family and trial, ``<stem>.<family>.trial<k>.mcap``
        (:func:`netsim.traces.recorder.trace_path`).
    on_trace : callable(str), optional
        Called with each trace file's path once it is finished.
    engine : str
        One of :data:`ENGINES` (``auto``: the vectorised engine for every family with
        a batched form, the event kernel for the others; traced or not).
    keep_trials : bool
        Keep every trial's :class:`TrialResult` (states, estimates, squared errors,
        effective delays) in ``MonteCarloResult.runs``.
    trace_options : mapping, optional
        Keyword arguments of every trace's
        :class:`netsim.traces.recorder.TraceRecorder` (e.g. ``time_origin_ns``).

    Returns
    -------
    MonteCarloResult
    """
    steps = scenario.steps if steps is None else int(steps)
    trials = scenario.trials if trials is None else int(trials)
    seed = scenario.seed if seed is None else int(seed)
    if families is None:
        declared = resolve_families(scenario.estimators, "run.estimators",
                                    scenario_folder(scenario))
    else:
        declared = [family_of(f, scenario, "estimators") for f in families]
    families = tuple(f.name for f in declared)
    engines = engines_for(engine, declared, scenario, traced=trace is not None)
    engine = choose_engine(engine, declared, traced=trace is not None, scenario=scenario)
    budget.check_run(scenario, steps, trials, list(engines.values()), keep_trials=keep_trials)
    if trace is not None:
        budget.check_trace_size(scenario, trace, (trace_options or {}).get("trace_format"),
                                steps=steps, engine=engine)
    needs_gains = any(f.needs_gains for f in declared)
    if gains is None and needs_gains:
        gains = scenario_gains(scenario)
    result = MonteCarloResult(scenario, gains, steps, trials, seed, engine=engine,
                              engines=engines)
    analyses: dict[str, JointAnalysis] = {}
    if gains is not None:
        result.analytics, analyses = _delay_analytics(scenario, gains)
    for fam in declared:  # the families' own analytics, once per key
        if fam.analytics is not None:
            result.analytics = result.analytics or {}
            key = fam.analytics_key or fam.name
            if key not in result.analytics:
                result.analytics[key] = fam.analytics(scenario, gains)
    seeds = [child_sequence(seed, "trial", t) for t in range(trials)]
    for fam in declared:
        family = fam.name
        runs: list[TrialResult] = []
        try:
            runs = _family_runs(scenario, fam, gains, seeds, steps, seed, trials, engines,
                                trace, families, keep_trials, progress, on_trace, runs,
                                trace_options)
        except TraceWriteError as exc:
            if runs:  # the trials that finished before the trace failed
                reported = None if fam.reported is None else list(fam.reported(scenario))
                summary = _summarise(family, runs, scenario.steady_state_fraction, steps,
                                     reported, _analysis_of(fam, analyses))
                summary.trials_finished = len(runs)
                result.estimators[family] = summary
            exc.partial = result
            raise
        reported = None if fam.reported is None else list(fam.reported(scenario))
        summary = _summarise(family, runs, scenario.steady_state_fraction, steps, reported,
                             _analysis_of(fam, analyses))
        if fam.report is not None:
            summary.report = dict(fam.report(FamilyContext(scenario, gains, None, family),
                                             runs))
            summary.verdict = summary.report.get("verdict", summary.verdict)
            summary.settle()
        result.estimators[family] = summary
        if keep_trials:
            result.runs[family] = runs
    return result


def _family_runs(scenario, fam, gains, seeds, steps, seed, trials, engines, trace, families,
                 keep_trials, progress, on_trace, runs, trace_options=None):
    """One family's trials (appended to ``runs`` as they finish, traced or not)."""
    family = fam.name
    if trace is None:
        runs.extend(run_trials(scenario, fam, gains, seeds, steps,
                               engine=engines[family], record_estimates=keep_trials,
                               record_delays=keep_trials, progress=progress))
    else:
        single = trials == 1 and len(families) == 1
        if engines[family] == "vectorised" and _replayable_lockstep(fam):
            from netsim.vectorised import run_batch

            # the trials' estimates are kept for the trace: batches of at most
            # 2^24 values (steps x trials x agents x states)
            width = 1 if fam.centralised else scenario.n_agents
            size = max(1, (1 << 24) // ((steps + 1) * width * scenario.plant.n_states))
            for first in range(0, trials, size):
                batch = run_batch(scenario, family, gains, seeds[first:first + size],
                                  steps, record_estimates=True)
                for index in range(len(batch.results)):
                    # a safe point between traces: a trial short enough to be written
                    # in one window never reaches the writer's own checks, and a batch
                    # holds up to 2^24 values (hundreds of trials)
                    interrupt.check()
                    runs.append(_traced_trial(scenario, fam, gains, seed, first + index,
                                              steps, trace, single, on_trace, batch=batch,
                                              batch_trial=index,
                                              trace_options=trace_options))
                    if progress is not None:
                        progress(1)
                del batch
        else:
            for t in range(trials):
                runs.append(_traced_trial(scenario, fam, gains, seed, t, steps, trace,
                                          single, on_trace, trace_options=trace_options))
                if progress is not None:
                    progress(1)
    return runs
