"""Age-of-information scenarios of the aoi paper as ordinary netsim scenarios.

The built-in ``aoi-example`` and ``aoi-random`` are TOML files in
``models/scenarios/`` (``[topology]``: the graph sequence; ``[options.aoi]``: the
source gains and tie rule), run by ``netsim run`` like any scenario. The families
``aoi`` (:class:`netsim.estimators.aoi.FreshnessObserver`), ``naive-uniform`` and
``naive-tree`` (:class:`netsim.estimators.aoi.NaiveConsensusObserver`) are declared in
:mod:`netsim.estimators.aoi`. This module builds such scenarios in Python:

* :func:`illustrative_example` -- the paper's Section 3: scalar x[k+1] = a x[k], a = 2,
  three nodes, node 1 (here agent 0) the only one measuring (y = x), the graph
  alternating between Figure 1(a) at even steps and 1(b) at odd steps. The figure is
  not in the text; its edges are inferred from the description of the tree weights
  ("when G[k] is Figure 1(a) (resp. 1(b)), node 2 (resp. node 3) listens to only node
  1, while node 3 (resp. node 2) listens to only node 2 (resp. node 3)"):
  (a) = {1->2, 2->3}, (b) = {1->3, 3->2} (0-based: {0->1, 1->2}, {0->2, 2->1}).
  No edge enters node 1, so the sequence is *not* jointly strongly connected
  (Assumption 1 fails for every T); it is jointly rooted at the only source, node 1,
  with T = 2 (Remark 1).
* :func:`random_aoi_scenario` -- a random jointly strongly connected sequence
  (Assumption 1 with a given T, single graphs not connected) and a random jointly
  observable system (the built-in ``aoi-random`` was drawn by it, seed 0).

:func:`node_errors` runs a scenario's observers and returns every node's estimation
error over time (the aoi paper's Fig. 2), and this module gives ``netsim run`` its AoI
options (:func:`add_aoi_arguments`, :func:`apply_aoi_arguments`: ``--gains``, ``--rho``,
``--ties``, ``--delayed``, which set ``[options.aoi]``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

# the run options live in the light netsim.aoiargs (re-exported here), so that building
# netsim run's parser does not import this module
from netsim.aoiargs import add_aoi_arguments, apply_aoi_arguments, check_aoi_arguments
from netsim.estimators.aoi import AOI_OPTIONS, corollary_bound
from netsim.models.network import uniform_weights
from netsim.models.plant import LinearPlant
from netsim.models.scenario import DEFAULTS, DelaySpec, GainSpec, Scenario, ScenarioError
from netsim.models.seeding import stream
from netsim.models.topology import (
    GraphSequence,
    LinkSchedule,
    alternating_sequence,
    random_jointly_connected,
)

__all__ = [
    "AOI_FAMILIES",
    "EXAMPLE_GRAPH_A",
    "EXAMPLE_GRAPH_B",
    "aoi_scenario_from",
    "illustrative_example",
    "random_jointly_observable_system",
    "random_aoi_scenario",
    "corollary_bound",
    "add_aoi_arguments",
    "apply_aoi_arguments",
    "check_aoi_arguments",
    "NodeErrors",
    "node_errors",
]

#: The estimators an AoI scenario built here runs.
AOI_FAMILIES = ("aoi", "naive-uniform", "naive-tree")
#: Figure 1 of the aoi paper, 0-based (see the module doc for how it was inferred).
EXAMPLE_GRAPH_A = ((0, 1), (1, 2))
EXAMPLE_GRAPH_B = ((0, 2), (2, 1))


def aoi_scenario_from(name: str, description: str, A: Any, C: Sequence[Any],
                      topology: GraphSequence | LinkSchedule, *, steps: int = 60,
                      trials: int = 1, seed: int = 0, process_noise: float = 0.0,
                      measurement_noise: float = 0.0, x0_mean: Any = None, x0_cov: Any = None,
                      delay: int = 0, estimators: Sequence[str] = AOI_FAMILIES,
                      **options: Any) -> Scenario:
    """A scenario on a time-varying topology, as a ``[topology]`` TOML file gives it.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : sequence of array_like, each (m_i, n)
        One output matrix per agent (m_i may be 0).
    topology : GraphSequence or LinkSchedule
    process_noise, measurement_noise : float
        Q = process_noise I, R_i = measurement_noise I.
    delay : int
        A homogeneous link delay (0: the paper's model).
    **options
        ``[options.aoi]`` settings (gains, rho, tie_rule, delayed).
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    Cs = tuple(np.asarray(Ci, dtype=float).reshape(-1, n) for Ci in C)
    plant = LinearPlant(
        A=A, C=Cs, Q=process_noise * np.eye(n),
        R=tuple(measurement_noise * np.eye(Ci.shape[0]) for Ci in Cs),
        x0_mean=np.zeros(n) if x0_mean is None else np.asarray(x0_mean, dtype=float),
        x0_cov=np.eye(n) if x0_cov is None else np.asarray(x0_cov, dtype=float),
    )
    import networkx as nx

    union: nx.DiGraph[int] = nx.DiGraph()
    union.add_nodes_from(range(len(Cs)))
    union.add_edges_from(topology.links())
    unknown = sorted(set(options) - set(AOI_OPTIONS))
    if unknown:
        raise ScenarioError(f"options.aoi.{unknown[0]}", "unknown key")
    return Scenario(
        name=name, description=description, plant=plant, weights=uniform_weights(union),
        delays=DelaySpec("homogeneous", int(delay)) if delay else DelaySpec(),
        gains=GainSpec(), estimators=tuple(estimators), steps=int(steps),
        trials=int(trials), seed=int(seed), sample_period=1.0,
        divergence_threshold=float(DEFAULTS["run.divergence_threshold"]),
        steady_state_fraction=float(DEFAULTS["run.steady_state_fraction"]),
        source="", topology=topology, options={"aoi": dict(options)} if options else {},
    )


def illustrative_example(a: float = 2.0, *, process_noise: float = 0.0,
                         measurement_noise: float = 0.0, steps: int = 60,
                         seed: int = 0) -> Scenario:
    """The aoi paper's Section 3 example (a = 2, three nodes, alternating graphs)."""
    return aoi_scenario_from(
        "aoi-example",
        f"aoi paper Section 3: x[k+1] = {a:g} x[k]; node 0 measures y = x, nodes 1, 2 "
        "measure nothing; G[k] alternates between {0->1, 1->2} (even k, Figure 1a) and "
        "{0->2, 2->1} (odd k, Figure 1b). Naive consensus with uniform or tree weights "
        "diverges; the freshness-index observer converges in finite time.",
        [[a]], [[[1.0]], np.zeros((0, 1)), np.zeros((0, 1))],
        alternating_sequence(3, EXAMPLE_GRAPH_A, EXAMPLE_GRAPH_B),
        steps=steps, seed=seed, process_noise=process_noise,
        measurement_noise=measurement_noise)


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
                        structured: bool = True) -> Scenario:
    """A random jointly observable system (:func:`random_jointly_observable_system`)
    on a random jointly strongly connected sequence (Assumption 1 with this T; the
    single graphs are generally not connected)."""
    rng = stream(seed, "aoi", "system")
    A, C = random_jointly_observable_system(rng, n_states, n_agents, outputs=outputs,
                                            spectral_radius=spectral_radius,
                                            structured=structured)
    topology = random_jointly_connected(n_agents, T, windows=windows, seed=seed)
    return aoi_scenario_from(
        "aoi-random",
        f"random system n = {n_states}, N = {n_agents} agents with up to {outputs} "
        f"output(s) each, jointly but not locally observable, rho(A) = "
        f"{spectral_radius:g}; random graph sequence jointly strongly connected over "
        f"windows of T = {T} steps (period {windows * T}), single graphs not",
        A, C, topology, steps=steps, seed=seed, process_noise=process_noise,
        measurement_noise=measurement_noise)


# -- per-node errors (Fig. 2) ---------------------------------------------------------------


@dataclass
class NodeErrors:
    """Per-node estimation errors of one observer family over Monte Carlo trials.

    Attributes
    ----------
    family : str
    errors : ndarray, shape (M, K+1, N)
        ||x[k] - x-hat_i[k]|| of node i at step k in trial m (NaN after a divergence).
    growth_rate : float
        Per-step growth factor of the largest node error (the family's report).
    verdict : str
        The family's verdict (``converged at step k``, ``diverging``, ...).
    """

    family: str
    errors: np.ndarray
    growth_rate: float
    verdict: str


def node_errors(scenario: Scenario | None = None,
                families: Sequence[str] = AOI_FAMILIES, *, steps: int | None = None,
                trials: int | None = None, seed: int | None = None) -> dict[str, NodeErrors]:
    """Every node's estimation error for each family (default: the Section 3 example).

    Runs :func:`netsim.runner.run_monte_carlo` with every trial kept; the growth rate
    and verdict are those of :func:`netsim.estimators.aoi.aoi_report`.
    """
    from netsim.runner import run_monte_carlo

    sc = illustrative_example() if scenario is None else scenario
    result = run_monte_carlo(sc, steps=steps, trials=trials, seed=seed,
                             families=list(families), keep_trials=True)
    out: dict[str, NodeErrors] = {}
    for name in families:
        runs = result.runs[name]
        errs = np.sqrt(np.stack([r.squared_errors for r in runs]))
        report = result.estimators[name].report or {}
        out[name] = NodeErrors(name, errs, float(report.get("growth_rate", math.nan)),
                               str(report.get("verdict", "")))
    return out
