"""Age-of-information observer scenarios in the SimPy kernel (aoi paper).

Built-in scenarios (:data:`AOI_SCENARIOS`):

* ``aoi-example`` -- the paper's Section 3: scalar x[k+1] = a x[k], a = 2, three
  nodes, node 1 (here agent 0) the only one measuring (y = x), the graph alternating
  between Figure 1(a) at even steps and 1(b) at odd steps. The figure is not in the
  text; its edges are inferred from the description of the tree weights ("when G[k]
  is Figure 1(a) (resp. 1(b)), node 2 (resp. node 3) listens to only node 1, while
  node 3 (resp. node 2) listens to only node 2 (resp. node 3)"):
  (a) = {1->2, 2->3}, (b) = {1->3, 3->2} (0-based: {0->1, 1->2}, {0->2, 2->1}).
  No edge enters node 1, so the sequence is *not* jointly strongly connected
  (Assumption 1 fails for every T); it is jointly rooted at the only source, node 1,
  with T = 2 (Remark 1). Edges into node 1 would change nothing: node 1 has perfect
  information and listens to no one.
* ``aoi-random`` -- a random jointly strongly connected sequence (Assumption 1 with a
  given T, single graphs not connected) and a random jointly observable system.

Estimator families: ``aoi`` (:class:`netsim.estimators.aoi.FreshnessObserver`),
``naive-uniform`` and ``naive-tree`` (:class:`netsim.estimators.aoi.NaiveConsensusObserver`,
the paper's two naive weight choices, with the same source update).

Timing: links are delay-free by default (d = 0: a message sent at step s is used at
s + 1), which is the paper's model exactly (see :mod:`netsim.estimators.aoi`); the topology
enters the kernel as its ``availability`` hook, so messages on links that are down at
their sending step are dropped and counted.

Verdicts (per family, from the per-agent error norms ||x-hat_i[k] - x[k]||):
``converged at step k`` (noise-free runs only: every agent's error <= CONVERGED_RTOL *
||x[k]|| from step k to the end: finite-time convergence), ``diverged at step k`` (the
kernel's divergence check fired), else from the growth factor g per step of the
largest agent error over the second half (least-squares fit of its log):
``diverging`` if g^(half) > 2, ``converging`` if g^(half) < 1/2, ``bounded`` otherwise.

Traces: :func:`record_aoi_run` writes one MCAP file per run with
:class:`netsim.traces.recorder.TraceRecorder`. After every update of an ``aoi`` agent the
kernel observer calls the recorder's ``on_freshness(agent, k, freshness, adopted_from,
substate_dims)`` when the recorder has that hook: ``freshness[j]`` = tau_i^(j)[k]
(-1 for omega), ``adopted_from[j]`` = the neighbour whose substate j was adopted at
this update (-1: own source update or open loop), ``substate_dims[j]`` = n_j. The
intended topic is ``/agent/<i>/freshness`` (log_time k * Ts, right after
``/agent/<i>/estimate``).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from operator import itemgetter
from typing import Any

import numpy as np

from netsim.estimators.aoi import (
    OMEGA,
    AoIDesign,
    FreshnessObserver,
    NaiveConsensusObserver,
)
from netsim.kernel import AgentSpec, Simulation, TrialResult
from netsim.models.delays import homogeneous_delays
from netsim.models.jsonsafe import json_default, json_number
from netsim.models.plant import LinearPlant
from netsim.models.seeding import SeedLike, child_sequence, stream
from netsim.models.topology import (
    ConnectivityReport,
    GraphSequence,
    LinkSchedule,
    alternating_sequence,
    as_sequence,
    bfs_parents,
    connectivity_report,
    random_jointly_connected,
)

__all__ = [
    "AOI_FAMILIES",
    "AOI_SCENARIOS",
    "CONVERGED_RTOL",
    "AoIScenario",
    "illustrative_example",
    "random_aoi_scenario",
    "random_jointly_observable_system",
    "is_aoi_scenario",
    "aoi_scenario",
    "aoi_design",
    "corollary_bound",
    "build_aoi_agents",
    "AoITrial",
    "run_aoi_trial",
    "FamilyResult",
    "AoIRunResult",
    "run_aoi_scenario",
    "run_aoi_example",
    "record_aoi_run",
    "freshness_topic",
    "add_aoi_arguments",
    "aoi_command",
]

AOI_FAMILIES = ("aoi", "naive-uniform", "naive-tree")
#: Relative error (to ||x[k]||) under which an agent counts as exact.
CONVERGED_RTOL = 1e-9
#: Growth over the second half beyond which a run is ``diverging`` (as netsim.runner).
GROWTH_TOLERANCE = 2.0


def freshness_topic(agent: int) -> str:
    """Topic of agent i's freshness indices in a trace."""
    return f"/agent/{int(agent)}/freshness"


# -- scenarios ------------------------------------------------------------------------


@dataclass(frozen=True)
class AoIScenario:
    """An AoI scenario: plant, time-varying topology, gains and run settings.

    Attributes
    ----------
    plant : LinearPlant
        One sensor per agent (C_i may have zero rows).
    topology : GraphSequence or LinkSchedule
    gains : str
        ``deadbeat`` (Corollary 1) or ``rate`` (Theorem 1, with ``rho``).
    delay : int
        Homogeneous link delay in steps (0: the paper's model).
    delayed : str
        What the AoI observer does with delayed messages (``discard`` | ``age``).
    """

    name: str
    description: str
    plant: LinearPlant
    topology: GraphSequence | LinkSchedule
    steps: int = 60
    trials: int = 1
    seed: int = 0
    gains: str = "deadbeat"
    rho: float | None = None
    estimators: tuple[str, ...] = AOI_FAMILIES
    divergence_threshold: float = 1e8
    tie_rule: str = "lowest"
    delay: int = 0
    delayed: str = "discard"
    source: str = ""

    @property
    def n_agents(self) -> int:
        return self.plant.n_sensors

    @property
    def n_states(self) -> int:
        return self.plant.n_states

    def links(self) -> list[tuple[int, int]]:
        return sorted(self.topology.links())

    def with_noise(self, process: float = 0.0, measurement: float = 0.0) -> AoIScenario:
        """The same scenario with Q = process * I and R_i = measurement * I."""
        p = self.plant
        if process < 0 or measurement < 0:
            raise ValueError("noise variances must be >= 0")
        plant = replace(p, Q=process * np.eye(p.n_states),
                        R=tuple(measurement * np.eye(C.shape[0]) for C in p.C))
        return replace(self, plant=plant)

    def summary(self) -> dict[str, Any]:
        p = self.plant
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source or f"builtin:{self.name}",
            "n_states": p.n_states,
            "n_agents": self.n_agents,
            "links": [list(e) for e in self.links()],
            "topology": as_sequence(self.topology).to_dict(),
            "estimators": list(self.estimators),
            "gains": self.gains,
            "rho": self.rho,
            "delays": {"model": "none" if self.delay == 0 else "homogeneous",
                       "tau": self.delay, "max_delay": self.delay},
            "delayed_messages": self.delayed,
            "tie_rule": self.tie_rule,
            "process_noise": float(np.max(np.abs(p.Q))) if p.Q.size else 0.0,
            "measurement_noise": max((float(np.max(np.abs(R))) for R in p.R if R.size),
                                     default=0.0),
        }


def _plant(A, C, *, x0_mean=None, x0_cov=None, process=0.0, measurement=0.0) -> LinearPlant:
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    Cs = tuple(np.asarray(Ci, dtype=float).reshape(-1, n) for Ci in C)
    return LinearPlant(
        A=A, C=Cs, Q=process * np.eye(n), R=tuple(measurement * np.eye(Ci.shape[0]) for Ci in Cs),
        x0_mean=np.zeros(n) if x0_mean is None else np.asarray(x0_mean, dtype=float),
        x0_cov=np.eye(n) if x0_cov is None else np.asarray(x0_cov, dtype=float),
    )


#: Figure 1 of the aoi paper, 0-based (see the module doc for how it was inferred).
EXAMPLE_GRAPH_A = ((0, 1), (1, 2))
EXAMPLE_GRAPH_B = ((0, 2), (2, 1))


def illustrative_example(a: float = 2.0, *, process_noise: float = 0.0,
                         measurement_noise: float = 0.0, steps: int = 60,
                         seed: int = 0) -> AoIScenario:
    """The aoi paper's Section 3 example (a = 2, three nodes, alternating graphs)."""
    plant = _plant([[a]], [[[1.0]], np.zeros((0, 1)), np.zeros((0, 1))],
                   process=process_noise, measurement=measurement_noise)
    return AoIScenario(
        name="aoi-example",
        description=(
            f"aoi paper Section 3: x[k+1] = {a:g} x[k]; node 0 measures y = x, nodes 1, 2 "
            "measure nothing; G[k] alternates between {0->1, 1->2} (even k, Figure 1a) and "
            "{0->2, 2->1} (odd k, Figure 1b). Naive consensus with uniform or tree weights "
            "diverges; the freshness-index observer converges in finite time."
        ),
        plant=plant,
        topology=alternating_sequence(3, EXAMPLE_GRAPH_A, EXAMPLE_GRAPH_B),
        steps=steps,
        seed=seed,
    )


def random_jointly_observable_system(
    rng: np.random.Generator, n_states: int, n_agents: int, *, outputs: int = 1,
    spectral_radius: float = 1.1, structured: bool = True,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """A random (A, [C_i]) with (A, C) observable but, typically, no (A, C_i) observable.

    ``structured``: in hidden coordinates A is block lower-triangular with random
    blocks (sizes a random composition of n over the agents, empty blocks allowed) and
    agent pi(j) (pi a random permutation) measures ``outputs`` random combinations of
    blocks 0..j; the system is then rotated by a random orthogonal matrix. Otherwise A
    and C_i are i.i.d. normal (C_i on a random subset of the states). A is scaled to
    the given spectral radius; draws are repeated until (A, C) is observable.
    """
    from netsim.models.decomposition import NotObservableError, multi_sensor_decomposition

    n, N = int(n_states), int(n_agents)
    for _ in range(200):
        if structured:
            cuts = np.sort(rng.integers(0, n + 1, size=N - 1))
            sizes = np.diff(np.concatenate([[0], cuts, [n]])).astype(int)
            off = np.concatenate([[0], np.cumsum(sizes)])
            A = np.tril(rng.standard_normal((n, n)))
            for j in range(N):  # dense diagonal blocks, zero blocks above them
                A[off[j]:off[j + 1], off[j]:off[j + 1]] = rng.standard_normal((sizes[j],) * 2)
            perm = rng.permutation(N)
            C = [np.zeros((0, n))] * N
            for j in range(N):
                Cj = np.zeros((outputs, n))
                Cj[:, : off[j + 1]] = rng.standard_normal((outputs, int(off[j + 1])))
                C[int(perm[j])] = Cj if sizes[j] > 0 or rng.random() < 0.5 else np.zeros((0, n))
            Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
            A = Q @ A @ Q.T
            C = [Ci @ Q.T for Ci in C]
        else:
            A = rng.standard_normal((n, n))
            C = [rng.standard_normal((outputs, n)) * (rng.random(n) < 0.5) for _ in range(N)]
        radius = max(abs(np.linalg.eigvals(A)))
        if radius < 1e-3:
            continue
        A *= spectral_radius / radius
        try:
            multi_sensor_decomposition(A, C)
        except NotObservableError:
            continue
        return A, C
    raise RuntimeError("could not draw an observable system")  # pragma: no cover


def random_aoi_scenario(n_states: int = 4, n_agents: int = 3, T: int = 2, *,
                        seed: int = 0, outputs: int = 1, spectral_radius: float = 1.1,
                        windows: int = 4, process_noise: float = 0.0,
                        measurement_noise: float = 0.0, steps: int = 80,
                        structured: bool = True) -> AoIScenario:
    """A random jointly observable system (:func:`random_jointly_observable_system`)
    on a random jointly strongly connected sequence (Assumption 1 with this T; the
    single graphs are generally not connected)."""
    rng = stream(seed, "aoi", "system")
    A, C = random_jointly_observable_system(rng, n_states, n_agents, outputs=outputs,
                                            spectral_radius=spectral_radius,
                                            structured=structured)
    topology = random_jointly_connected(n_agents, T, windows=windows, seed=seed)
    return AoIScenario(
        name="aoi-random",
        description=(
            f"random system n = {n_states}, N = {n_agents} agents with up to {outputs} "
            f"output(s) each, jointly but not locally observable, rho(A) = "
            f"{spectral_radius:g}; random graph sequence jointly strongly connected over "
            f"windows of T = {T} steps (period {windows * T}), single graphs not"
        ),
        plant=_plant(A, C, process=process_noise, measurement=measurement_noise),
        topology=topology,
        steps=steps,
        seed=seed,
    )


AOI_SCENARIOS: dict[str, Callable[..., AoIScenario]] = {
    "aoi-example": illustrative_example,
    "aoi-random": random_aoi_scenario,
}


def is_aoi_scenario(name: str) -> bool:
    """Whether ``name`` is a built-in AoI scenario (``netsim run`` dispatch)."""
    return name in AOI_SCENARIOS


def aoi_scenario(name: str, **options: Any) -> AoIScenario:
    """Build a built-in AoI scenario by name."""
    try:
        factory = AOI_SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown AoI scenario {name!r}; built-in: "
                         f"{', '.join(AOI_SCENARIOS)}") from None
    return factory(**options)


def aoi_design(scenario: AoIScenario) -> AoIDesign:
    """Lemma 1 decomposition and source gains of the scenario (prior: x0_mean)."""
    p = scenario.plant
    return AoIDesign.from_plant(p.A, p.C, p.x0_mean, method=scenario.gains, rho=scenario.rho)


def corollary_bound(n_states: int, n_agents: int, T: int | None) -> int | None:
    """Corollary 1's finite-time bound n + 2N(N-1)T (None without a T)."""
    if T is None:
        return None
    return n_states + 2 * n_agents * (n_agents - 1) * T


# -- agents and trials -----------------------------------------------------------------


class _TreeParents:
    """parent(j, i, k): BFS tree of G[k] rooted at j (cached per graph index)."""

    def __init__(self, topology: GraphSequence | LinkSchedule) -> None:
        self.sequence = as_sequence(topology)
        self._cache: dict[tuple[int, int], dict[int, int]] = {}

    def __call__(self, j: int, i: int, k: int) -> int | None:
        idx = self.sequence.index(k)
        key = (idx, j)
        parents = self._cache.get(key)
        if parents is None:
            parents = bfs_parents(self.sequence.n_agents, self.sequence.graphs[idx], j)
            self._cache[key] = parents
        return parents.get(i)


def build_aoi_agents(scenario: AoIScenario, family: str, design: AoIDesign,
                     trial_seed: SeedLike = 0) -> list[AgentSpec]:
    """The kernel agents of one family; out-links: every link ever up."""
    N = scenario.n_agents
    out = {i: sorted(r for s, r in scenario.topology.links() if s == i) for i in range(N)}
    parents = _TreeParents(scenario.topology) if family == "naive-tree" else None
    agents = []
    for i in range(N):
        if family == "aoi":
            rng = stream(trial_seed, "aoi", "ties", i) if scenario.tie_rule == "random" else None
            est: Any = FreshnessObserver(i, design, tie_rule=scenario.tie_rule, rng=rng,
                                         delayed=scenario.delayed)
        elif family == "naive-uniform":
            est = NaiveConsensusObserver(i, design, weights="uniform")
        elif family == "naive-tree":
            est = NaiveConsensusObserver(i, design, weights="tree", parent=parents)
        else:
            raise ValueError(f"unknown AoI estimator family {family!r}; known: "
                             f"{', '.join(AOI_FAMILIES)}")
        agents.append(AgentSpec(est, itemgetter(i), out[i]))
    return agents


class _FreshnessTap:
    """Kernel observer: records freshness/adoption after every update, forwards all
    hooks to an inner observer (a trace recorder), and calls its ``on_freshness``."""

    def __init__(self, estimators: Sequence[Any], freshness: np.ndarray, adopted: np.ndarray,
                 dims: Sequence[int], inner: Any = None) -> None:
        self.estimators = list(estimators)
        self.freshness = freshness
        self.adopted = adopted
        self.dims = list(dims)
        self.inner = inner
        self._on_freshness = getattr(inner, "on_freshness", None)

    def on_plant(self, k, state, measurements):
        if self.inner is not None:
            self.inner.on_plant(k, state, measurements)

    def on_sent(self, message):
        if self.inner is not None:
            self.inner.on_sent(message)

    def on_delivered(self, message, accepted):
        if self.inner is not None:
            self.inner.on_delivered(message, accepted)

    def on_dropped(self, message, reason="", drop_time=None):
        if self.inner is not None and hasattr(self.inner, "on_dropped"):
            self.inner.on_dropped(message, reason, drop_time)

    def on_update(self, agent, k, estimate, delays):
        est = self.estimators[agent]
        tau = getattr(est, "freshness", None)
        if k < len(self.adopted):
            self.adopted[k, agent] = est.adopted_from
            if tau is not None:
                self.freshness[k, agent] = tau
        if self.inner is not None:
            self.inner.on_update(agent, k, estimate, delays)
            if self._on_freshness is not None and isinstance(est, FreshnessObserver):
                self._on_freshness(agent, k, np.asarray(tau).copy(),
                                   np.asarray(est.adopted_from).copy(), self.dims)


@dataclass
class AoITrial:
    """One kernel run of one family.

    Attributes
    ----------
    result : TrialResult
        The kernel's result (states, estimates, squared errors, message counts).
    freshness : numpy.ndarray (K+1, N, N) int
        tau_i^(j)[k] at [k, i, j] (OMEGA = -1); only filled for ``aoi`` (the naive
        families keep no indices: all OMEGA).
    adopted : numpy.ndarray (K+1, N, N) int
        Whose information agent i used for substate j at step k (-1 own, -2 average).
    estimators : list
        The estimator objects after the run.
    """

    family: str
    result: TrialResult
    freshness: np.ndarray
    adopted: np.ndarray
    estimators: list[Any]

    @property
    def error_norms(self) -> np.ndarray:
        """(K+1, N) ||x-hat_i[k] - x[k]|| (NaN after divergence)."""
        return np.sqrt(self.result.squared_errors)

    @property
    def state_norms(self) -> np.ndarray:
        return np.linalg.norm(self.result.states, axis=1)


def run_aoi_trial(scenario: AoIScenario, family: str, design: AoIDesign | None = None, *,
                  trial_seed: SeedLike = 0, steps: int | None = None, observer: Any = None,
                  record_messages: bool = False) -> AoITrial:
    """Run one family of the scenario once in the SimPy kernel."""
    design = aoi_design(scenario) if design is None else design
    steps = scenario.steps if steps is None else int(steps)
    agents = build_aoi_agents(scenario, family, design, trial_seed)
    N = scenario.n_agents
    freshness = np.full((steps + 1, N, N), OMEGA, dtype=np.int64)
    adopted = np.full((steps + 1, N, N), -1, dtype=np.int64)
    estimators = [a.estimator for a in agents]
    tap = _FreshnessTap(estimators, freshness, adopted, design.decomposition.dims, observer)
    simulation = Simulation(
        scenario.plant, agents, homogeneous_delays(scenario.links(), scenario.delay),
        stream(trial_seed, "plant"), divergence_threshold=scenario.divergence_threshold,
        record_delays=False, record_messages=record_messages, observer=tap,
        availability=scenario.topology.is_up,
    )
    result = simulation.run(steps)
    return AoITrial(family, result, freshness, adopted, estimators)


# -- summaries --------------------------------------------------------------------------


def _nanmax(a: np.ndarray, axis: Any) -> np.ndarray:
    """nanmax without the all-NaN warning (all-NaN slices give NaN)."""
    filled = np.where(np.isnan(a), -np.inf, a)
    out = np.max(filled, axis=axis)
    return np.where(np.isneginf(out), np.nan, out)


def _growth(errors: np.ndarray) -> float:
    """exp(slope) of log(max_i error) over the second half of the finite part."""
    worst = _nanmax(errors, axis=1)
    finite = np.isfinite(worst)
    if not finite.any():
        return math.nan
    last = int(np.flatnonzero(finite)[-1])
    half = worst[(last + 1) // 2: last + 1]
    if len(half) < 2 or np.any(half <= 0):
        return math.nan
    slope = np.polyfit(np.arange(len(half)), np.log(half), 1)[0]
    return float(np.exp(slope))


def _converged_at(errors: np.ndarray, states: np.ndarray, diverged: bool) -> int | None:
    if diverged:
        return None
    scale = np.maximum(np.linalg.norm(states, axis=1), np.finfo(float).tiny)
    ok = np.all(errors <= CONVERGED_RTOL * scale[:, None], axis=1)
    if not ok[-1] or len(ok) < 2:
        return None
    bad = np.flatnonzero(~ok)
    k = 0 if bad.size == 0 else int(bad[-1]) + 1
    return k if k < len(ok) - 1 else None


@dataclass
class FamilyResult:
    """Summary of one family over the trials."""

    family: str
    verdict: str
    growth_rate: float
    converged_at: int | None
    diverged_at: int | None
    error_at: dict[int, float]
    relative_error_at: dict[int, float]
    messages_sent: int
    messages_delivered: int
    messages_dropped: int
    messages_discarded: int
    trials: list[AoITrial] = field(default_factory=list, repr=False)
    freshness_max_after: int | None = None
    triggered_by: int | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {
            "family": self.family,
            "verdict": self.verdict,
            "growth_rate": json_number(self.growth_rate),
            "converged_at": self.converged_at,
            "diverged_at": self.diverged_at,
            "max_error_at": {str(k): json_number(v) for k, v in self.error_at.items()},
            "max_relative_error_at": {str(k): json_number(v)
                                      for k, v in self.relative_error_at.items()},
            "messages": {"sent": self.messages_sent, "delivered": self.messages_delivered,
                         "dropped_link_down": self.messages_dropped,
                         "discarded": self.messages_discarded},
        }
        if self.family == "aoi":
            out["freshness"] = {"all_triggered_by": self.triggered_by,
                                "max_index_after_trigger_bound": self.freshness_max_after}
        return out


def _noise_free(scenario: AoIScenario) -> bool:
    p = scenario.plant
    return not np.any(p.Q) and not any(np.any(R) for R in p.R)


def _summarise(family: str, trials: list[AoITrial], steps: int, lemma_start: int | None,
               sources: Sequence[int] = (), noise_free: bool = True) -> FamilyResult:
    diverged = [t.result.diverged_at for t in trials if t.result.diverged_at is not None]
    errs = np.stack([t.error_norms for t in trials])        # (M, K+1, N)
    states = np.stack([t.state_norms for t in trials])      # (M, K+1)
    worst = _nanmax(errs, axis=(0, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = _nanmax(errs / np.maximum(states, np.finfo(float).tiny)[:, :, None],
                      axis=(0, 2))
    # exactness (finite-time convergence) is only a meaningful verdict without noise:
    # with noise on an unstable plant the *relative* error vanishes as the state grows
    conv = [_converged_at(t.error_norms, t.result.states, t.result.diverged_at is not None)
            if noise_free else None for t in trials]
    converged_at = max(conv) if conv and all(c is not None for c in conv) else None
    growths = [_growth(t.error_norms) for t in trials]
    growth = max((g for g in growths if math.isfinite(g)), default=math.nan)
    if diverged:
        verdict = f"diverged at step {min(diverged)}"
    elif converged_at is not None:
        verdict = f"converged at step {converged_at}"
    else:
        half = (steps + 1) - (steps + 1) // 2
        if not math.isfinite(growth):
            verdict = "bounded"
        elif growth ** half > GROWTH_TOLERANCE:
            verdict = "diverging"
        elif growth ** half < 1.0 / GROWTH_TOLERANCE:
            verdict = "converging"
        else:
            verdict = "bounded"
    marks = sorted({0, steps // 10, steps // 4, steps // 2, (3 * steps) // 4, steps})
    fresh_max = trig = None
    if family == "aoi":
        # indices of the non-empty substates only (an empty substate's index may stay
        # omega: nothing to estimate, and Remark 1 only asks for rooted sources)
        f = np.stack([t.freshness for t in trials])[..., list(sources)]  # (M, K+1, N, S)
        triggered = np.all(f != OMEGA, axis=(0, 2, 3))
        trig = int(np.argmax(triggered)) if triggered.any() else None
        if lemma_start is not None and lemma_start <= steps:
            fresh_max = int(f[:, lemma_start:].max())
    return FamilyResult(
        family=family, verdict=verdict, growth_rate=growth, converged_at=converged_at,
        diverged_at=min(diverged) if diverged else None,
        error_at={m: float(worst[m]) for m in marks if m < len(worst)},
        relative_error_at={m: float(rel[m]) for m in marks if m < len(rel)},
        messages_sent=sum(t.result.messages_sent for t in trials),
        messages_delivered=sum(t.result.messages_delivered for t in trials),
        messages_dropped=sum(t.result.messages_dropped for t in trials),
        messages_discarded=sum(t.result.messages_discarded for t in trials),
        trials=trials, freshness_max_after=fresh_max, triggered_by=trig,
    )


@dataclass
class AoIRunResult:
    """Result of :func:`run_aoi_scenario`: every family's verdict and the paper's bounds."""

    scenario: AoIScenario
    design: AoIDesign
    steps: int
    trials: int
    seed: int
    connectivity: ConnectivityReport
    families: dict[str, FamilyResult]
    traces: list[str] = field(default_factory=list)

    @property
    def T(self) -> int | None:
        """T used in the bounds: Assumption 1's, else Remark 1's (rooted at sources)."""
        c = self.connectivity
        return c.joint_T if c.joint_T is not None else c.rooted_all_T

    @property
    def bound(self) -> int | None:
        return corollary_bound(self.scenario.n_states, self.scenario.n_agents, self.T)

    def to_dict(self) -> dict[str, Any]:
        c = self.connectivity
        N = self.scenario.n_agents
        T = self.T
        return {
            "scenario": self.scenario.summary(),
            "steps": self.steps,
            "trials": self.trials,
            "seed": self.seed,
            "design": self.design.to_dict(),
            "connectivity": c.to_dict(),
            "bounds": {
                "T": T,
                "assumption_1": c.joint_T is not None,
                "remark_1_rooted_at_sources": c.rooted_all_T is not None,
                "lemma_3_triggered_by": None if T is None else (N - 1) * T,
                "lemma_5_freshness_max": None if T is None else 2 * (N - 1) * T,
                "corollary_1_finite_time": self.bound,
                "applies": self.scenario.gains == "deadbeat" and self.scenario.delay == 0,
            },
            "estimators": {name: f.to_dict() for name, f in self.families.items()},
            "traces": list(self.traces),
        }

    def format_text(self) -> str:
        d = self.to_dict()
        s = d["scenario"]
        b = d["bounds"]
        c = self.connectivity
        dims = self.design.decomposition.dims
        lines = [
            f"scenario {s['name']} ({s['source']}): n = {s['n_states']} states, "
            f"N = {s['n_agents']} agents, {len(s['links'])} links, graph period {c.period}",
            f"  {' '.join(s['description'].split())}",
            f"run: {self.steps} steps x {self.trials} trial(s), seed {self.seed}; delays "
            f"{s['delays']['model']} (d = {s['delays']['tau']}); noise: process "
            f"{s['process_noise']:g}, measurement {s['measurement_noise']:g}",
            f"Lemma 1 decomposition: substate dims {list(dims)} (sources "
            f"{list(self.design.decomposition.sources)}); gains {self.design.gains.method}"
            + ("" if self.design.gains.rho is None or self.design.gains.method == "deadbeat"
               else f", rho = {self.design.gains.rho:g}, rho_j = "
                    f"{[round(r, 4) for r in self.design.gains.rhos]}"),
            "connectivity: Assumption 1 (jointly strongly connected) "
            + (f"holds with T = {c.joint_T}" if c.joint_T is not None else "fails for every T")
            + "; Remark 1 (jointly rooted at the sources) "
            + (f"holds with T = {c.rooted_all_T}" if c.rooted_all_T is not None else "fails"),
        ]
        if T := b["T"]:
            lines.append(
                f"paper's bounds with T = {T}: all indices triggered by (N-1)T = "
                f"{b['lemma_3_triggered_by']} (Lemma 3), indices <= 2(N-1)T = "
                f"{b['lemma_5_freshness_max']} after that (Lemma 5), finite-time "
                f"convergence by n + 2N(N-1)T = {b['corollary_1_finite_time']} (Corollary 1"
                + (")" if b["applies"] else ", not applicable: needs deadbeat gains, no delays)")
            )
        lines.append("")
        header = f"{'estimator':<15}{'verdict':<26}{'growth/step':>12}  " + " ".join(
            f"{'err@' + str(m):>10}" for m in next(iter(self.families.values())).error_at)
        lines.append(header)
        lines.append("-" * len(header))
        for name, f in self.families.items():
            g = "-" if not math.isfinite(f.growth_rate) or f.converged_at is not None \
                else f"{f.growth_rate:.4f}"
            row = f"{name:<15}{f.verdict:<26}{g:>12}  " + " ".join(
                f"{_fmt(v):>10}" for v in f.error_at.values())
            lines.append(row)
        aoi = self.families.get("aoi")
        if aoi is not None:
            lines.append("")
            lines.append(
                f"aoi freshness: all indices triggered by step {aoi.triggered_by}"
                + ("" if aoi.freshness_max_after is None
                   else f"; largest index from step {b['lemma_3_triggered_by']} on: "
                        f"{aoi.freshness_max_after}")
            )
        lines.append("")
        lines.append("err@k: largest agent error ||x-hat_i[k] - x[k]|| over agents and trials; "
                     "growth/step: exp(slope of its log) over the second half; converged: "
                     f"every agent within {CONVERGED_RTOL:g} ||x[k]|| from that step on.")
        for path in self.traces:
            lines.append(f"trace: {path}")
        return "\n".join(lines) + "\n"


def _fmt(value: float) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if value == 0 or 1e-3 <= abs(value) < 1e4:
        return f"{value:.4f}"
    return f"{value:.3e}"


def run_aoi_scenario(
    scenario: AoIScenario,
    *,
    steps: int | None = None,
    trials: int | None = None,
    seed: int | None = None,
    families: Sequence[str] | None = None,
    trace: str | None = None,
    on_trace: Callable[[str], None] | None = None,
    progress: Callable[[int], None] | None = None,
) -> AoIRunResult:
    """Run every family of the scenario in the kernel and summarise the verdicts.

    Trial t uses the child seed (seed, "trial", t) (x_0, noise, random ties); all
    families see the same plant realisation. ``trace``: write MCAP files (see
    :func:`record_aoi_run`), ``FILE.mcap`` for a single run, else
    ``FILE.<family>.trial<t>.mcap``.
    """
    steps = scenario.steps if steps is None else int(steps)
    trials = scenario.trials if trials is None else int(trials)
    seed = scenario.seed if seed is None else int(seed)
    families = tuple(scenario.estimators if families is None else families)
    for f in families:
        if f not in AOI_FAMILIES:
            raise ValueError(f"unknown AoI estimator family {f!r}; known: "
                             f"{', '.join(AOI_FAMILIES)}")
    design = aoi_design(scenario)
    conn = connectivity_report(scenario.topology, design.decomposition.sources)
    T = conn.joint_T if conn.joint_T is not None else conn.rooted_all_T
    lemma_start = None if T is None else (scenario.n_agents - 1) * T
    results: dict[str, FamilyResult] = {}
    written: list[str] = []
    for family in families:
        runs = []
        for t in range(trials):
            trial_seed = child_sequence(seed, "trial", t)
            if trace is None:
                runs.append(run_aoi_trial(scenario, family, design, trial_seed=trial_seed,
                                          steps=steps))
            else:
                single = trials == 1 and len(families) == 1
                run, path = record_aoi_run(trace, scenario, family, design=design, seed=seed,
                                           trial=t, steps=steps, single=single)
                runs.append(run)
                written.append(str(path))
                if on_trace is not None:
                    on_trace(str(path))
            if progress is not None:
                progress(1)
        results[family] = _summarise(family, runs, steps, lemma_start,
                                     design.decomposition.sources, _noise_free(scenario))
    return AoIRunResult(scenario, design, steps, trials, seed, conn, results, written)


def run_aoi_example(steps: int = 60, seed: int = 0, noise: float = 0.0, *,
                    process_noise: float | None = None, measurement_noise: float | None = None,
                    a: float = 2.0, gains: str = "deadbeat", rho: float | None = None,
                    trials: int = 1, families: Sequence[str] | None = None,
                    trace: str | None = None) -> AoIRunResult:
    """The Section 3 example with its three estimators; ``noise`` sets both variances
    unless ``process_noise`` / ``measurement_noise`` are given."""
    scenario = illustrative_example(
        a,
        process_noise=noise if process_noise is None else process_noise,
        measurement_noise=noise if measurement_noise is None else measurement_noise,
        steps=steps, seed=seed,
    )
    scenario = replace(scenario, gains=gains, rho=rho)
    return run_aoi_scenario(scenario, trials=trials, families=families, trace=trace)


# -- traces ------------------------------------------------------------------------------


def _metadata(scenario: AoIScenario, design: AoIDesign) -> dict[str, str]:
    def js(v: Any) -> str:
        return v if isinstance(v, str) else json.dumps(
            v, sort_keys=True, default=partial(json_default, fallback=str))

    out = {str(k): js(v) for k, v in scenario.summary().items()}
    out["sample_period"] = "1.0"
    out["divergence_threshold"] = repr(float(scenario.divergence_threshold))
    out["gains_method"] = scenario.gains
    out["aoi_design"] = js(design.to_dict())
    out["delay_spec"] = js({"model": "none" if scenario.delay == 0 else "homogeneous",
                            "tau": scenario.delay, "default": scenario.delay, "seed": 0,
                            "links": [[j, i, scenario.delay] for j, i in scenario.links()]})
    return out


def _matrices(scenario: AoIScenario, design: AoIDesign) -> dict[str, np.ndarray]:
    p = scenario.plant
    out: dict[str, np.ndarray] = {"A": np.asarray(p.A)}
    out.update({f"C_{i}": np.asarray(C) for i, C in enumerate(p.C)})
    out["Q"] = np.asarray(p.Q)
    out.update({f"R_{i}": np.asarray(R) for i, R in enumerate(p.R)})
    out["x0_mean"] = np.asarray(p.x0_mean)
    out["x0_cov"] = np.asarray(p.x0_cov)
    d = design.decomposition
    out["aoi_T"] = d.T
    out["aoi_A_bar"] = d.A_bar
    out["aoi_dims"] = np.asarray(d.dims, dtype=np.int64)
    out.update({f"aoi_L_{j}": np.asarray(L) for j, L in enumerate(design.gains.L)})
    return out


def record_aoi_run(path: str, scenario: AoIScenario, family: str, *,
                   design: AoIDesign | None = None, seed: int = 0, trial: int = 0,
                   steps: int | None = None, single: bool = True,
                   recorder_class: Any = None, **options: Any) -> tuple[AoITrial, Any]:
    """Run one family once (trial seed (seed, "trial", trial)) and record it to MCAP.

    ``single``: write exactly ``path``; else ``<stem>.<family>.trial<t>.mcap``. The
    trace has the usual topics (plant, sensors, links with sent/delivered/dropped --
    dropped = link down -- agent estimates and updates), metadata ``scenario`` (with
    the topology as JSON) and the matrices A, C_i, Q, R_i, x0, plus ``aoi_T``,
    ``aoi_A_bar``, ``aoi_dims`` and ``aoi_L_<j>`` (z coordinates). Freshness indices
    are written if the recorder implements ``on_freshness`` (``recorder_class``:
    default :class:`netsim.traces.recorder.TraceRecorder`). Returns (trial, path).
    """
    from netsim.traces.recorder import TraceRecorder, trace_path

    if recorder_class is None:
        recorder_class = TraceRecorder

    design = aoi_design(scenario) if design is None else design
    steps = scenario.steps if steps is None else int(steps)
    target = trace_path(path) if single else trace_path(path, family, trial)
    run_meta = {"gains_method": scenario.gains, "aoi": "1",
                "freshness_topics": "/agent/<i>/freshness"}
    recorder = recorder_class(
        target, scenario_metadata=_metadata(scenario, design),
        matrices=_matrices(scenario, design), family=family, trial=trial, seed=seed,
        sample_period=1.0, steps=steps, run_metadata=run_meta, **options,
    )
    with recorder:
        run = run_aoi_trial(scenario, family, design,
                            trial_seed=child_sequence(seed, "trial", trial), steps=steps,
                            observer=recorder)
        if run.result.diverged_at is not None:
            recorder.set_status("diverged", diverged_at=run.result.diverged_at)
    return run, target


# -- command line ---------------------------------------------------------------------------


def add_aoi_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the AoI options to a parser that already has ``--steps``, ``--trials``,
    ``--seed``, ``--estimators``, ``--trace`` and ``--json`` (``netsim run``)."""
    group = parser.add_argument_group("age-of-information scenarios (aoi-example, aoi-random)")
    group.add_argument("--noise", type=float, default=None, metavar="VAR",
                       help="process and measurement noise variance (default 0)")
    group.add_argument("--process-noise", type=float, default=None, metavar="VAR")
    group.add_argument("--measurement-noise", type=float, default=None, metavar="VAR")
    group.add_argument("--gains", choices=["deadbeat", "rate"], default=None,
                       help="source gains: deadbeat (Corollary 1, default) or rate "
                       "(Theorem 1, with --rho)")
    group.add_argument("--rho", type=float, default=None,
                       help="desired convergence rate for --gains rate (0 < rho)")
    group.add_argument("--ties", choices=["lowest", "highest", "random"], default=None,
                       help="freshness tie rule (default lowest agent number)")
    group.add_argument("--delayed", choices=["discard", "age"], default=None,
                       help="what the AoI observer does with a message delayed by --tau: "
                       "discard it (the paper has no delays; default) or age it (extension)")


def aoi_command(args: argparse.Namespace) -> tuple[dict[str, Any], str]:
    """Run an AoI scenario from parsed ``netsim run`` arguments.

    Returns (JSON-able dict, text). Raises ValueError for bad input (the caller maps
    it to exit code 2) and estimators.aoi.GainDesignError (a ValueError) when a gain
    cannot be designed.
    """
    name = args.scenario
    noise = getattr(args, "noise", None)
    process = getattr(args, "process_noise", None)
    measurement = getattr(args, "measurement_noise", None)
    for label, v in (("--noise", noise), ("--process-noise", process),
                     ("--measurement-noise", measurement)):
        if v is not None and not (v >= 0 and math.isfinite(v)):
            raise ValueError(f"{label} must be a finite variance >= 0, got {v}")
    scenario = aoi_scenario(name)
    pn = process if process is not None else (noise or 0.0)
    mn = measurement if measurement is not None else (noise or 0.0)
    if pn or mn:
        scenario = scenario.with_noise(pn, mn)
    gains = getattr(args, "gains", None) or scenario.gains
    rho = getattr(args, "rho", None)
    if gains == "rate" and rho is None:
        rho = 0.5
    if rho is not None and not (rho > 0 and math.isfinite(rho)):
        raise ValueError(f"--rho must be > 0, got {rho}")
    scenario = replace(scenario, gains=gains, rho=rho)
    if getattr(args, "ties", None):
        scenario = replace(scenario, tie_rule=args.ties)
    tau = getattr(args, "tau", None)
    if tau is not None:
        if tau < 0:
            raise ValueError(f"--tau must be >= 0, got {tau}")
        scenario = replace(scenario, delay=int(tau))
    if getattr(args, "delayed", None):
        scenario = replace(scenario, delayed=args.delayed)
    families = None
    if getattr(args, "estimators", None):
        families = tuple(f.strip() for f in args.estimators.split(",") if f.strip())
        if not families:
            raise ValueError("--estimators: empty list; name at least one estimator")
        unknown = [f for f in families if f not in AOI_FAMILIES]
        if unknown:
            raise ValueError(f"--estimators: {', '.join(unknown)} not in "
                             f"{', '.join(AOI_FAMILIES)}")
    for label in ("steps", "trials"):
        v = getattr(args, label, None)
        if v is not None and v < 1:
            raise ValueError(f"--{label} must be a positive integer, got {v}")
    seed = getattr(args, "seed", None)
    if seed is not None and seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {seed}")
    result = run_aoi_scenario(scenario, steps=getattr(args, "steps", None),
                              trials=getattr(args, "trials", None), seed=seed,
                              families=families, trace=getattr(args, "trace", None))
    return result.to_dict(), result.format_text()
