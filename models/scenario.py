"""Scenarios: TOML files describing a plant, a network, delays, gains and a run.

A scenario fixes everything that is *not* Monte Carlo randomness: the plant, the
network and its weights (random weights use ``network.seed``), the fixed delay
realisation (heterogeneous delays use ``delays.seed``), the gains, and which
estimators run. The run seed (``run.seed`` or ``--seed``) drives only the trial
randomness: initial states, noise, and time-varying delays.

An optional ``[links]`` table gives the links more than a delay: per-link delay
distributions (uniform, geometric, shifted gamma / Pareto, empirical from a CSV, replay
of a recorded trace) in asynchronous, synchronous or fixed mode, Bernoulli or
Gilbert-Elliott loss, outages, finite buffers with a drop policy, and serialisation
from a bandwidth and a message size; defaults for every link plus a ``per_link`` list
(:mod:`netsim.models.linkmodels` defines each model; relative file paths are relative to the
scenario file). Without it, links only delay, as ``[delays]`` says.

Agents are numbered from 0. A link ``[j, i]`` means agent i receives from agent j.
Every validation failure raises :class:`ScenarioError` naming the offending key.
See ``models/scenarios/*.toml`` for the built-in scenarios and ``docs/scenarios.rst``
(the scenario reference, generated from this module) for the full schema.
"""

from __future__ import annotations

import difflib
import math
import os
import tomllib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from netsim.models.delays import (
    AsynchronousRandomDelays,
    DelayModel,
    FixedDelays,
    FixedLatencies,
    SynchronousRandomDelays,
    heterogeneous_delays,
    homogeneous_delays,
)
from netsim.models.lazy import issparse, lazy_module
from netsim.models.linkmodels import (
    BUFFER_POLICIES,
    DELAY_DISTRIBUTIONS,
    DELAY_MODES,
    LOSS_MODELS,
    BufferConfig,
    ConstantDelay,
    DelayConfig,
    EmpiricalDelay,
    GeometricDelay,
    LinkConfig,
    LinksSpec,
    LossConfig,
    ShiftedGamma,
    ShiftedPareto,
    UniformDelay,
    Unit,
    load_latency_csv,
    load_trace_replay,
)
from netsim.models.medium import MediumSpec
from netsim.models.network import (
    NetworkError,
    check_consensus_matrix,
    check_sparse_consensus_matrix,
    directed_cycle,
    geometric,
    geometric_link_estimate,
    geometric_links,
    graph_from_weights,
    lazy_metropolis_weights,
    link_random_weights,
    link_uniform_weights,
    links_from_weights,
    random_links,
    random_strongly_connected,
    random_weights,
    sparse_lazy_metropolis_weights,
    sparse_random_weights,
    sparse_uniform_weights,
    uniform_weights,
)
from netsim.models.plant import LinearPlant
from netsim.models.seeding import SeedLike
from netsim.models.topology import GraphSequence, LinkSchedule, TopologyError, as_sequence

if TYPE_CHECKING:
    import networkx as nx
    import scipy.sparse as sp
    from netsim.models.timing import TimeSpec
else:  # imported on first use (start-up latency): small dense scenarios need neither
    nx = lazy_module("networkx")
    sp = lazy_module("scipy.sparse")

__all__ = [
    "ScenarioError",
    "MAX_DELAY_STEPS",
    "ScenarioWarning",
    "DelaySpec",
    "GainSpec",
    "Scenario",
    "DELAY_MODELS",
    "GAIN_METHODS",
    "REFINE_FROM",
    "DEFAULTS",
    "DEFAULT_ESTIMATORS",
    "SPARSE_MIN_AGENTS",
    "SUMMARY_MAX_LINKS",
    "MAX_SPARSE_LINKS",
    "MAX_AGENTS",
    "DENSE_WEIGHTS_MAX_AGENTS",
    "LinkTable",
    "load_scenario",
    "parse_scenario",
    "read_scenario_data",
    "builtin_scenarios",
    "resolve_scenario",
    "ScenarioCounts",
    "scenario_counts",
]

#: The estimators a scenario runs when it lists none under ``run.estimators`` (names
#: of the registry, :mod:`netsim.estimators.registry`, which checks them: models know
#: no families).
DEFAULT_ESTIMATORS = ("compensated", "uncompensated", "block", "centralized-kf")
#: From this many agents on, a generated network (``network.topology`` cycle, random,
#: geometric or edges) is built sparse end to end: link arrays, CSR weights
#: (``Scenario.weights`` is then a ``scipy.sparse.csr_array``), sparse consensus
#: checks; no N x N array and no networkx graph. Below it the historic dense path runs
#: (the same numbers as before for every existing scenario).
SPARSE_MIN_AGENTS = 2048
#: Largest N for which :meth:`Scenario.dense_weights` densifies sparse weights
#: (8 N^2 bytes: 128 MiB at 4096).
DENSE_WEIGHTS_MAX_AGENTS = 4096
#: Largest number of links (estimated before anything is drawn) and of agents a
#: generated sparse network may have: building takes about 200 bytes per link and a
#: run several times that, so larger requests are refused in one line at parse time.
MAX_SPARSE_LINKS = 20_000_000
MAX_AGENTS = 10_000_000
#: Above this N n a scenario without ``gains.method`` uses the local design (the
#: same size rule as ``method = "auto"``, ``netsim.estimators.gains.LOCAL_AUTO_MIN_STATES``).
LOCAL_DEFAULT_MIN_STATES = 1500
#: Largest number of links :meth:`Scenario.summary` lists one by one.
SUMMARY_MAX_LINKS = 20_000
#: Delay models a scenario may name under ``delays.model``.
DELAY_MODELS = (
    "none", "homogeneous", "heterogeneous", "fixed", "synchronous", "asynchronous", "latency",
)
#: Values of ``gains.method``: the designs ``netsim design`` offers (``refined`` is its
#: ``--refine``) and ``given`` (explicit ``gains.K``).
GAIN_METHODS = ("lmi", "ccl", "auto", "local", "refined", "given")
#: Values of ``gains.refine_from``: the design a ``refined`` gain starts from.
REFINE_FROM = ("lmi", "ccl", "auto", "given")
#: Defaults of every optional key, in one place.
DEFAULTS: dict[str, Any] = {
    "run.steps": 200,
    "run.trials": 20,
    "run.seed": 0,
    "run.sample_period": 1.0,
    "run.divergence_threshold": 1e8,
    "run.steady_state_fraction": 0.25,
    "run.estimators": list(DEFAULT_ESTIMATORS),
    "plant.x0_cov": 1.0,
    "network.weights": "random",
    "network.seed": 0,
    "network.edge_probability": 0.1,
    "delays.model": "none",
    "delays.tau": 0,
    "delays.seed": 0,
    "delays.default": 0,
    "gains.method": "lmi",
    "gains.method (N n > 1500)": "local",
    "gains.tau1": 0,
    "gains.refine_from": "auto",
    "links.delay.mode": "asynchronous",
    "links.buffer.policy": "drop-tail",
    "links.buffer.policy (capacity tau+1)": "drop-oldest",
    "links.seed": "delays.seed",
    "links.message_size": "64 * n bits (n doubles)",
}

_SCHEMA: dict[str, set[str]] = {
    "": {"name", "description", "run", "plant", "network", "delays", "gains", "links",
         "topology", "options", "time"},
    "run": {
        "steps", "trials", "seed", "sample_period", "divergence_threshold",
        "steady_state_fraction", "estimators",
    },
    "plant": {"A", "C", "Q", "R", "x0_mean", "x0_cov", "sensors"},
    "network": {"topology", "agents", "edges", "weights", "P", "seed", "edge_probability",
                "radius", "medium"},
    "delays": {"model", "tau", "links", "default", "seed"},
    "gains": {"method", "K", "tau1", "refine_from"},
    "links": {"delay", "loss", "buffer", "outages", "bandwidth", "message_size", "seed",
              "bound", "per_link"},
    "topology": {"graphs", "period", "down", "duty"},
}
#: Keys of one ``links.per_link`` entry.
_LINK_KEYS = {"from", "to", "delay", "loss", "buffer", "outages", "bandwidth", "message_size"}
#: Parameters of each delay distribution (besides ``distribution``, ``unit``, ``mode``).
_DISTRIBUTION_KEYS: dict[str, tuple[set[str], set[str]]] = {
    # name: (required, optional)
    "constant": ({"value"}, set()),
    "uniform": ({"low", "high"}, set()),
    "geometric": ({"p"}, {"shift"}),
    "gamma": ({"shape", "scale"}, {"shift"}),
    "pareto": ({"alpha", "scale"}, {"shift"}),
    "empirical": ({"file"}, {"scale"}),
    "trace": ({"file"}, set()),
}
_DISTRIBUTION_UNITS = {
    "constant": ("steps", "time"), "uniform": ("steps", "time"), "geometric": ("steps",),
    "gamma": ("time",), "pareto": ("time",), "empirical": ("time", "steps"),
}
_LOSS_KEYS = {"none": set(), "bernoulli": {"p"},
              "gilbert-elliott": {"p", "r", "loss_good", "loss_bad"}}


class ScenarioError(ValueError):
    """An invalid scenario; ``key`` names the offending entry."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}" if key else message)
        self.key = key


class ScenarioWarning(UserWarning):
    """A scenario input accepted by a documented rule that the user should hear about
    (the ``netsim`` command prints it as one ``warning:`` line on stderr); ``key``
    names the entry."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}" if key else message)
        self.key = key


def _warn(key: str, message: str) -> None:
    warnings.warn(ScenarioWarning(key, message), stacklevel=3)


@dataclass(frozen=True)
class DelaySpec:
    """Link delays of a scenario.

    Attributes
    ----------
    model : str
        One of :data:`DELAY_MODELS`.
    tau : int
        Delay bound tau-bar (steps) for homogeneous, heterogeneous and random models.
    links : dict[(sender, receiver), float]
        Per-link delays (``fixed``, steps) or latencies (``latency``, time units).
    default : float
        Delay or latency of links not listed.
    seed : int
        Seed of the heterogeneous delay realisation (fixed across trials).
    """

    model: str = "none"
    tau: int = 0
    links: dict[tuple[int, int], float] = field(default_factory=dict)
    default: float = 0
    seed: int = 0


@dataclass(frozen=True)
class GainSpec:
    """How the innovation gains are obtained (the ``[gains]`` table).

    Attributes
    ----------
    method : str
        One of :data:`GAIN_METHODS`: ``lmi`` (block-diagonal LMI with rate bisection),
        ``ccl`` (cone-complementarity, full Lyapunov matrix), ``auto`` (CCL up to
        ``N n = 60``, LMI up to 1500, ``local`` above), ``local`` (L_i = gamma C_i^T
        (C_i C_i^T)^+, exact rho by the structured method; any N), ``refined`` (the
        ``refine_from`` design, then a direct minimisation of the spectral radius, as
        ``netsim design --refine``) or
        ``given`` (the matrices ``K``).
    K : tuple of numpy.ndarray or None
        The given per-agent gains ``K_i`` (n x n) for ``given``, or for ``refined``
        from ``given``; None otherwise.
    tau1 : int
        Delay bound of the design (LCSYS2022 Discussion 5: design against
        ``P kron A^(tau1+1)``); 0 is the delay-free design. Always 0 for ``given``.
    refine_from : str or None
        For ``refined``: the starting design, one of :data:`REFINE_FROM`; else None.
    """

    method: str = "lmi"
    K: tuple[np.ndarray, ...] | None = None
    tau1: int = 0
    refine_from: str | None = None


@dataclass(frozen=True)
class LinkTable:
    """The links of a scenario as arrays, sorted by sender then receiver.

    Attributes
    ----------
    src, dst : numpy.ndarray, shape (L,), int64
        Sender j and receiver i of every link (j, i).
    weight : numpy.ndarray, shape (L,)
        Consensus weight p_ij = P[i, j] of each link (LCSYS2022 eq. 4).
    """

    src: np.ndarray
    dst: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return len(self.src)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.

    Attributes
    ----------
    name, description : str
    plant : LinearPlant
    weights : numpy.ndarray, shape (N, N)
        Consensus matrix P (row-stochastic, positive diagonal, strongly connected).
    delays : DelaySpec
    gains : GainSpec
    estimators : tuple of str
    steps, trials, seed : int
    sample_period, divergence_threshold, steady_state_fraction : float
    source : str
        File path or ``builtin:<name>``.
    link_spec : LinksSpec or None
        The ``[links]`` table: per-link delay distributions, losses, outages, buffers,
        serialisation (None: links only delay, as ``[delays]`` says).
    topology : GraphSequence or LinkSchedule or None
        The ``[topology]`` table: a time-varying communication graph (which links are
        up at each sending step). The links are then the union of its graphs, and a
        message sent on a link that is down is dropped. None: every link is always up.
    options : dict of str -> dict
        The ``[options.<name>]`` tables: settings of estimator families, validated by
        the families that read them (:mod:`netsim.estimators.registry`).
    """

    name: str
    description: str
    plant: LinearPlant
    weights: np.ndarray
    delays: DelaySpec
    gains: GainSpec
    estimators: tuple[str, ...]
    steps: int
    trials: int
    seed: int
    sample_period: float
    divergence_threshold: float
    steady_state_fraction: float
    source: str = ""
    #: The ``[network.medium]`` table (:mod:`netsim.models.medium`): delays and losses
    #: made by a simulated network; None: the link models draw them.
    medium: MediumSpec | None = None
    link_spec: LinksSpec | None = None
    topology: GraphSequence | LinkSchedule | None = None
    options: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: The ``[time]`` table: clocks, asynchronous sampling, triggers
    #: (:mod:`netsim.models.timing`); None: the papers' one sampling clock.
    timing: TimeSpec | None = None

    @cached_property
    def graph(self) -> nx.DiGraph:
        """Communication graph, edge (j, i): i receives from j (built once; do not
        modify it). With a time-varying ``topology``: the union of its graphs. (A
        networkx graph costs about 1 kB per link: large-N code reads
        :attr:`link_table` instead.)"""
        if self.topology is not None:
            graph: nx.DiGraph[int] = nx.DiGraph()
            graph.add_nodes_from(range(self.topology.n_agents))
            graph.add_edges_from(self.topology.links())
            return graph
        if issparse(self.weights):
            graph = nx.DiGraph()
            graph.add_nodes_from(range(self.n_agents))
            table = self.link_table
            graph.add_edges_from(zip(table.src.tolist(), table.dst.tolist(), strict=True))
            return graph
        return graph_from_weights(self.weights)

    @cached_property
    def link_table(self) -> LinkTable:
        """The links as arrays, sorted by sender then receiver (the order of
        :attr:`links`), with their consensus weights p_ij; built once."""
        if self.topology is not None:
            links = sorted(self.topology.links())
            arr = np.array(links, dtype=np.int64).reshape(-1, 2)
            src, dst = arr[:, 0], arr[:, 1]
            W = self.weights_sparse
            return LinkTable(src, dst, np.asarray(W[dst, src]).ravel() if len(src)
                             else np.zeros(0))
        if not issparse(self.weights):  # the same table without scipy.sparse
            dense = np.asarray(self.weights, dtype=float)
            j, i = np.nonzero(dense.T)  # sender-major, then receiver: the link order
            j, i = j.astype(np.int64), i.astype(np.int64)
            keep = i != j
            return LinkTable(j[keep], i[keep], dense[i[keep], j[keep]])
        # column-major (CSC, a counting sort) is sender-major: the link order
        csc = sp.csc_array(self.weights_sparse)
        csc.sum_duplicates()
        j = np.repeat(np.arange(self.n_agents, dtype=np.int64), np.diff(csc.indptr))
        i = csc.indices.astype(np.int64)
        keep = (i != j) & (csc.data != 0)
        return LinkTable(j[keep], i[keep], csc.data[keep])

    @cached_property
    def weights_sparse(self) -> sp.csr_array:
        """The consensus matrix P as CSR (shape (N, N), sorted indices); built once."""
        P = sp.csr_array(self.weights, dtype=float)
        P.sort_indices()
        return P

    def dense_weights(self) -> np.ndarray:
        """P as a dense (N, N) array; ScenarioError (one line) above
        :data:`DENSE_WEIGHTS_MAX_AGENTS` agents when P is stored sparse."""
        if not issparse(self.weights):
            return np.asarray(self.weights, dtype=float)
        N = self.n_agents
        if N > DENSE_WEIGHTS_MAX_AGENTS:
            raise ScenarioError("network", f"this needs the dense N x N consensus matrix, "
                                f"{8 * N * N / 2**30:.1f} GiB at N = {N} agents (sparse "
                                f"paths go up to any N; dense ones to "
                                f"{DENSE_WEIGHTS_MAX_AGENTS})")
        return cast("sp.csr_array", self.weights).toarray()

    def densified(self, what: str = "this command") -> Scenario:
        """This scenario with dense weights (itself if they are dense already).

        Sparse weights are densified up to :data:`DENSE_WEIGHTS_MAX_AGENTS` agents;
        above, ScenarioError in one line saying that ``what`` needs the dense N x N
        matrix and what runs at that size instead.
        """
        if not issparse(self.weights):
            return self
        N = self.n_agents
        if N > DENSE_WEIGHTS_MAX_AGENTS:
            raise ScenarioError("network.agents", f"{what} needs the dense N x N consensus "
                                f"matrix ({8 * N * N / 2**30:.1f} GiB at N = {N}; dense "
                                f"paths go up to {DENSE_WEIGHTS_MAX_AGENTS} agents); at this "
                                "size `netsim run` (vectorised engine, [gains] method = "
                                "'local' or 'auto') is supported")
        return replace(self, weights=cast("sp.csr_array", self.weights).toarray())

    @cached_property
    def links(self) -> list[tuple[int, int]]:
        """Sorted links (sender, receiver); built once."""
        table = self.link_table
        return list(zip(table.src.tolist(), table.dst.tolist(), strict=True))

    @property
    def n_agents(self) -> int:
        return self.weights.shape[0]

    @cached_property
    def max_delay(self) -> int:
        """Delay bound tau-bar in steps implied by the delay specification (built once:
        it builds a delay model)."""
        return int(self.delay_model(0).max_delay)

    @property
    def delay_bound(self) -> int:
        """The bound tau-bar the agents know: ``delays.tau`` for the models that have
        one (homogeneous, heterogeneous, synchronous, asynchronous), else the largest
        per-link step delay. With a ``[links]`` table that sets delays: ``links.bound``
        if given, else the largest step delay of the links' distributions (their
        99.9 % quantile for unbounded ones) and serialisation."""
        if self.medium is not None:
            return self._medium_bound()
        if self.link_spec is not None and (self.link_spec.bound is not None
                                           or self.link_spec.sets_delays):
            return self._links_bound(self.link_spec, self._base_delay_model(0))
        if self.delays.model in ("homogeneous", "heterogeneous", "synchronous", "asynchronous"):
            return int(self.delays.tau)
        return self.max_delay

    def _medium_bound(self) -> int:
        """``bound`` of ``[network.medium]``, else the pilot run's nominal bound
        (:func:`netsim.models.medium.nominal_bound`, the scenario's seed)."""
        from netsim.models.medium import nominal_bound

        assert self.medium is not None
        if self.medium.bound is not None:
            return self.medium.bound
        return nominal_bound(self.medium, self.links, sample_period=self.sample_period,
                             seed=self.seed, steps=self.steps)

    def _links_bound(self, spec: LinksSpec, base: DelayModel) -> int:
        if spec.bound is not None:
            return int(spec.bound)
        if spec.sets_delays:
            return spec.max_delay(self.links, int(base.max_delay), self.sample_period,
                                  self.plant.n_states)
        if self.delays.model in ("homogeneous", "heterogeneous", "synchronous", "asynchronous"):
            return int(self.delays.tau)
        return int(base.max_delay)

    def with_tau(self, tau: int) -> Scenario:
        """Return a copy with delay bound ``tau`` (model ``none`` becomes homogeneous)."""
        if int(tau) != tau or tau < 0:
            raise ScenarioError("delays.tau", f"must be a non-negative integer, got {tau}")
        if tau > MAX_DELAY_STEPS:
            raise ScenarioError("delays.tau", f"must be <= {MAX_DELAY_STEPS} (the largest "
                                f"netsim represents), got {tau}")
        model = self.delays.model
        if model in ("fixed", "latency"):
            raise ScenarioError(
                "delays.tau", f"cannot override tau of per-link '{model}' delays"
            )
        if self.link_spec is not None and self.link_spec.sets_delays:
            raise ScenarioError(
                "delays.tau", "cannot override tau: the [links] table sets the link delays"
            )
        if self.medium is not None:
            raise ScenarioError("delays.tau", "cannot override tau: [network.medium] makes "
                                "the link delays")
        if model == "none":
            model = "homogeneous"
        return replace(self, delays=replace(self.delays, model=model, tau=int(tau)))

    def with_noise(self, process: float | None = None,
                   measurement: float | None = None) -> Scenario:
        """Return a copy with Q = process * I and/or every R_i = measurement * I."""
        plant = self.plant
        if process is not None:
            if not (process >= 0 and math.isfinite(process)):
                raise ScenarioError("plant.Q", f"variance must be finite and >= 0, got "
                                    f"{process}")
            plant = replace(plant, Q=float(process) * np.eye(plant.n_states))
        if measurement is not None:
            if not (measurement >= 0 and math.isfinite(measurement)):
                raise ScenarioError("plant.R", f"variance must be finite and >= 0, got "
                                    f"{measurement}")
            plant = replace(plant, R=tuple(float(measurement) * np.eye(C.shape[0])
                                           for C in plant.C))
        return replace(self, plant=plant)

    def with_options(self, name: str, **settings: Any) -> Scenario:
        """Return a copy with ``[options.<name>]`` updated by ``settings``."""
        options = {k: dict(v) for k, v in self.options.items()}
        options.setdefault(name, {}).update(settings)
        return replace(self, options=options)

    def delay_model(self, trial_seed: SeedLike) -> DelayModel:
        """Build the delay model; random models draw from the trial's streams.

        With a ``[links]`` table this is a :class:`netsim.models.linkmodels.NetworkLinks`
        (a delay model whose ``link(j, i)`` gives the kernel each link's model).
        """
        base = self._base_delay_model(trial_seed)
        if self.medium is not None:
            from netsim.models.medium import medium_links

            return medium_links(self.medium, self.links, base, trial_seed,
                                sample_period=self.sample_period, max_delay=self.delay_bound)
        if self.link_spec is None:
            return base
        return self.link_spec.build(
            self.links, base, trial_seed, sample_period=self.sample_period,
            tau=self._links_bound(self.link_spec, base), n_states=self.plant.n_states,
        )

    def _base_delay_model(self, trial_seed: SeedLike) -> DelayModel:
        spec = self.delays
        links = self.links
        if spec.model == "none":
            return homogeneous_delays(links, 0)
        if spec.model == "homogeneous":
            return homogeneous_delays(links, spec.tau)
        if spec.model == "heterogeneous":
            return heterogeneous_delays(links, spec.tau, spec.seed)
        if spec.model == "fixed":
            return FixedDelays({k: int(v) for k, v in spec.links.items()}, int(spec.default))
        if spec.model == "latency":
            return FixedLatencies(dict(spec.links), float(spec.default), self.sample_period)
        if spec.model == "synchronous":
            return SynchronousRandomDelays(spec.tau, trial_seed)
        if spec.model == "asynchronous":
            return AsynchronousRandomDelays(spec.tau, trial_seed, links)
        raise ScenarioError("delays.model", f"unknown model {spec.model!r}")

    def summary(self) -> dict[str, Any]:
        """Return a JSON-ready description of the scenario."""
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "n_states": self.plant.n_states,
            "n_agents": self.n_agents,
            "n_links": len(self.link_table),
            # the list itself only for networks up to SUMMARY_MAX_LINKS links (a
            # 100,000-agent geometric graph has 1.5 million)
            **({"links": [list(link) for link in self.links]}
               if len(self.link_table) <= SUMMARY_MAX_LINKS else {}),
            "delays": {
                "model": self.delays.model,
                "tau": self.delays.tau,
                "bound": self.delay_bound,
                "max_delay": self.max_delay,
            },
            **({"link_models": self.link_spec.describe(self.plant.n_states)}
               if self.link_spec is not None else {}),
            **({"medium": self.medium.describe()} if self.medium is not None else {}),
            "estimators": list(self.estimators),
            "steps": self.steps,
            "trials": self.trials,
            "seed": self.seed,
            **({"topology": as_sequence(self.topology).to_dict()}
               if self.topology is not None else {}),
            **({"options": {k: dict(v) for k, v in self.options.items()}}
               if self.options else {}),
            **({"time": self.timing.describe()} if self.timing is not None else {}),
        }


# -- parsing helpers -----------------------------------------------------------


def _check_keys(table: dict[str, Any], section: str) -> None:
    allowed = _SCHEMA[section]
    for key in table:
        if key not in allowed:
            full = f"{section}.{key}" if section else key
            close = difflib.get_close_matches(key, sorted(allowed), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ScenarioError(
                full, f"unknown key{hint}; allowed: {', '.join(sorted(allowed))}"
            )


def _number(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ScenarioError(key, f"expected a number, got {value!r}")
    if math.isnan(value):
        raise ScenarioError(key, "is NaN")
    if math.isinf(value):
        raise ScenarioError(key, "is infinite")
    return float(value)


#: The largest delay (steps) or delay bound netsim represents: the engines hold delays
#: and send steps in int64 arithmetic (s + 1 + d), so bounds stay far below 2^63; a delay
#: longer than a run never arrives anyway (netsim.budget.delay_horizon).
MAX_DELAY_STEPS = 2 ** 31 - 1


def _int(value: Any, key: str, minimum: int | None = None,
         maximum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ScenarioError(key, f"expected an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise ScenarioError(key, f"must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ScenarioError(key, f"must be <= {maximum} (the largest netsim represents), "
                            f"got {value}")
    return int(value)


def _matrix(
    value: Any, key: str, shape: tuple[int | None, int | None] = (None, None)
) -> np.ndarray:
    if not isinstance(value, list) or not value:
        raise ScenarioError(key, f"expected a non-empty matrix (list of rows), got {value!r}")
    rows = value if isinstance(value[0], list) else None
    if rows is None:
        raise ScenarioError(key, "expected a matrix (list of rows), got a flat list")
    width = len(rows[0])
    for r, row in enumerate(rows):
        if not isinstance(row, list):
            raise ScenarioError(f"{key}[{r}]", f"expected a row (list of numbers), got {row!r}")
        if len(row) != width:
            raise ScenarioError(
                key, f"row {r} has {len(row)} entries, row 0 has {width}: rows must be equal length"
            )
        for c, entry in enumerate(row):
            _number(entry, f"{key}[{r}][{c}]")
    matrix = np.array(rows, dtype=float)
    rows_expected, cols_expected = shape
    if (rows_expected is not None and matrix.shape[0] != rows_expected) or (
        cols_expected is not None and matrix.shape[1] != cols_expected
    ):
        want = f"({rows_expected or 'any'}, {cols_expected or 'any'})"
        raise ScenarioError(key, f"has shape {matrix.shape}, expected {want}")
    return matrix


def _vector(value: Any, key: str, length: int) -> np.ndarray:
    if not isinstance(value, list):
        raise ScenarioError(key, f"expected a list of {length} numbers, got {value!r}")
    if len(value) != length:
        raise ScenarioError(key, f"has {len(value)} entries, expected n = {length}")
    return np.array([_number(v, f"{key}[{i}]") for i, v in enumerate(value)])


def _covariance(value: Any, key: str, size: int) -> np.ndarray:
    if isinstance(value, int | float) and not isinstance(value, bool):
        scale = _number(value, key)
        if scale < 0:
            raise ScenarioError(key, f"variance must be >= 0, got {scale}")
        return scale * np.eye(size)
    matrix = _matrix(value, key, (size, size))
    if not np.allclose(matrix, matrix.T, atol=1e-12):
        raise ScenarioError(key, "covariance must be symmetric")
    if np.linalg.eigvalsh(matrix).min() < -1e-12:
        raise ScenarioError(key, "covariance must be positive semi-definite")
    return matrix


def _require(table: dict[str, Any], key: str, section: str) -> Any:
    if key not in table:
        raise ScenarioError(f"{section}.{key}", "is missing")
    return table[key]


def _section(data: dict[str, Any], name: str, required: bool = True) -> dict[str, Any]:
    if name not in data:
        if required:
            raise ScenarioError(name, "section is missing")
        return {}
    table = data[name]
    if not isinstance(table, dict):
        raise ScenarioError(name, f"expected a table, got {table!r}")
    _check_keys(table, name)
    return table


def _parse_plant(table: dict[str, Any]) -> LinearPlant:
    A = _matrix(_require(table, "A", "plant"), "plant.A")
    n = A.shape[0]
    if A.shape != (n, n):
        raise ScenarioError("plant.A", f"must be square, got shape {A.shape}")
    C_raw = _require(table, "C", "plant")
    if not isinstance(C_raw, list) or not C_raw:
        raise ScenarioError("plant.C", "expected a list with one output matrix per sensor")
    C = []
    for i, Ci in enumerate(C_raw):
        if isinstance(Ci, list) and not Ci:
            C.append(np.zeros((0, n)))  # a sensor that measures nothing: []
            continue
        if isinstance(Ci, list) and Ci and not isinstance(Ci[0], list):
            Ci = [Ci]  # a single row given flat
        C.append(_matrix(Ci, f"plant.C[{i}]", (None, n)))
    Q = _covariance(_require(table, "Q", "plant"), "plant.Q", n)
    R_raw = _require(table, "R", "plant")
    if isinstance(R_raw, list):
        # one entry per sensor: a variance (times I) or an m_i x m_i matrix
        if len(R_raw) != len(C):
            raise ScenarioError(
                "plant.R", f"has {len(R_raw)} entries but plant.C has {len(C)} sensors"
            )
        R = [_covariance(r, f"plant.R[{i}]", C[i].shape[0]) for i, r in enumerate(R_raw)]
    else:
        R = [_covariance(R_raw, "plant.R", Ci.shape[0]) for Ci in C]
    if "sensors" in table:
        # N sensors cycling through the listed ones: sensor i is C[i mod len(C)]
        # (with its R); the same matrices are shared, not copied
        sensors = _int(table["sensors"], "plant.sensors", len(C))
        if sensors > MAX_AGENTS:
            raise ScenarioError("plant.sensors", f"= {sensors}: at most {MAX_AGENTS} sensors "
                                "(one per agent) are supported")
        C = (C * (sensors // len(C) + 1))[:sensors]  # C[i mod len(C)], list-level
        R = (R * (sensors // len(R) + 1))[:sensors]
    x0_mean = (
        _vector(table["x0_mean"], "plant.x0_mean", n) if "x0_mean" in table else np.zeros(n)
    )
    x0_cov = _covariance(table.get("x0_cov", DEFAULTS["plant.x0_cov"]), "plant.x0_cov", n)
    return LinearPlant(A, tuple(C), Q, tuple(R), x0_mean, x0_cov)


def _parse_network(table: dict[str, Any], n_sensors: int) -> np.ndarray:
    seed = _int(table.get("seed", DEFAULTS["network.seed"]), "network.seed", 0)
    weights_spec = table.get("weights", DEFAULTS["network.weights"])
    if "P" in table:
        for other in ("weights", "topology", "edges", "edge_probability", "radius"):
            if other in table:
                raise ScenarioError(f"network.{other}", "give either the matrix network.P "
                                    f"or network.{other}, not both (P fixes the graph "
                                    "and the weights)")
        if "agents" in table and table["agents"] != n_sensors:
            raise ScenarioError("network.agents", f"is {table['agents']!r} but plant.C has "
                                f"{n_sensors} sensors (one per agent)")
        P = _matrix(table["P"], "network.P", (n_sensors, n_sensors))
        _check_weights(P, "network.P")
        return P
    agents = _int(table.get("agents", n_sensors), "network.agents", 2)
    if agents != n_sensors:
        raise ScenarioError(
            "network.agents", f"is {agents} but plant.C has {n_sensors} sensors (one per agent)"
        )
    topology = table.get("topology")
    if topology is None:
        raise ScenarioError("network.topology", "is missing (or give the matrix network.P)")
    if agents >= SPARSE_MIN_AGENTS:
        # CSR from SPARSE_MIN_AGENTS agents on (Scenario.weights is annotated as the
        # dense array that every size below that gives)
        return cast(np.ndarray, _parse_sparse_network(table, agents, topology, weights_spec,
                                                      seed))
    if topology in ("cycle", "random") and weights_spec in ("random", "uniform"):
        # the weights from the links alone: no networkx graph (start-up latency)
        P = _link_weights(table, agents, topology, weights_spec, seed)
        _check_weights(P, "network")
        return P
    if topology == "cycle":
        graph = directed_cycle(agents)
    elif topology == "random":
        prob = _edge_probability(table, warn=True)
        graph = random_strongly_connected(agents, prob, seed)
    elif topology == "geometric":
        radius = _network_radius(table)
        graph = geometric(agents, radius, seed)
    elif topology == "edges":
        edges = _require(table, "edges", "network")
        graph = nx.DiGraph()
        graph.add_nodes_from(range(agents))
        graph.add_edges_from(_parse_edge_list(edges, "network.edges", agents))
    else:
        raise ScenarioError(
            "network.topology",
            f"unknown topology {topology!r}; expected cycle, random, geometric or edges",
        )
    _check_weight_scheme(weights_spec)
    if weights_spec == "random":
        P = random_weights(graph, seed)
    elif weights_spec == "uniform":
        P = uniform_weights(graph)
    else:
        P = lazy_metropolis_weights(graph)
        _warn_symmetrised(graph.number_of_edges() - sum(1 for i, j in graph.edges if i == j),
                          int(np.count_nonzero(P) - P.shape[0]))
    _check_weights(P, "network.edges" if topology == "edges" else "network")
    return P


def _edge_probability(table: dict[str, Any], warn: bool = False) -> float:
    """``network.edge_probability`` of a random network, in [0, 1] (ScenarioError
    otherwise); ``warn``: say that 0 leaves only the random Hamiltonian cycle."""
    prob = _number(table.get("edge_probability", DEFAULTS["network.edge_probability"]),
                   "network.edge_probability")
    if not 0 <= prob <= 1:
        raise ScenarioError("network.edge_probability", f"must be in [0, 1], got {prob}")
    if warn and prob == 0:
        _warn("network.edge_probability", "is 0: the random graph is only its random "
              "Hamiltonian cycle (every 'random' graph has one, for strong connectivity)")
    return prob


def _network_radius(table: dict[str, Any]) -> float | None:
    """``network.radius`` of a geometric network, > 0, or None for the default rule."""
    radius = table.get("radius")
    if radius is not None:
        radius = _number(radius, "network.radius")
        if radius <= 0:
            raise ScenarioError("network.radius", f"must be > 0, got {radius}")
    return radius


def _link_weights(table: dict[str, Any], agents: int, topology: str, weights_spec: str,
                  seed: int) -> np.ndarray:
    """:func:`_parse_network`'s dense random or uniform weights of a cycle or random
    graph (the same graph, draws and numbers) from its links, without networkx."""
    if topology == "cycle":
        src = np.arange(agents, dtype=np.int64)
        dst = (src + 1) % agents
    else:
        prob = _edge_probability(table, warn=True)
        src, dst = random_links(agents, prob, seed)
    if weights_spec == "random":
        return link_random_weights(agents, src, dst, seed)
    return link_uniform_weights(agents, src, dst)


def _warn_symmetrised(directed: int, used: int) -> None:
    """Lazy Metropolis weights are symmetric: say so when that adds links."""
    if used > directed:
        _warn("network.weights", f"lazy-metropolis weights are symmetric: the graph's "
              f"{directed} directed links are used in both directions ({used} links)")


def _check_weight_scheme(weights_spec: Any) -> None:
    """``network.weights`` names a scheme both the dense and the sparse path build."""
    if weights_spec not in ("random", "uniform", "lazy-metropolis"):
        raise ScenarioError(
            "network.weights",
            f"unknown scheme {weights_spec!r}; expected random, uniform or lazy-metropolis "
            "(or give the matrix network.P)",
        )


def _parse_sparse_network(table: dict[str, Any], agents: int, topology: Any,
                          weights_spec: Any, seed: int) -> sp.csr_array:
    """:func:`_parse_network` from :data:`SPARSE_MIN_AGENTS` agents on: the same
    graphs (k-d tree for geometric, geometric skips for random) and weights as arrays
    and CSR, O(L log N) time, O(N + L) memory."""
    if agents > MAX_AGENTS:
        raise ScenarioError("network.agents", f"= {agents}: at most {MAX_AGENTS} agents are "
                            "supported (the arrays per agent alone would not fit)")
    if topology == "cycle":
        src = np.arange(agents, dtype=np.int64)
        dst = (src + 1) % agents
        order = np.lexsort((dst, src))
        src, dst = src[order], dst[order]
    elif topology == "random":
        prob = _edge_probability(table)
        if prob * agents * agents > MAX_SPARSE_LINKS:
            raise ScenarioError("network.edge_probability", f"= {prob:g} gives about "
                                f"{prob * agents * agents:.3g} links at N = {agents}; "
                                f"at most {MAX_SPARSE_LINKS:.0e} are supported (lower it)")
        src, dst = random_links(agents, prob, seed)
    elif topology == "geometric":
        radius = _network_radius(table)
        r = radius if radius is not None else math.sqrt(2.0 * math.log(agents) / agents)
        expected = min(math.pi * r * r, 1.0) * agents * (agents - 1)
        if expected > MAX_SPARSE_LINKS:
            raise ScenarioError("network.radius", f"= {r:g}{'' if radius else ' (default)'} "
                                f"gives about {expected:.3g} links at N = {agents}; at most "
                                f"{MAX_SPARSE_LINKS:.0e} are supported (lower the radius or "
                                "the agents)")
        src, dst, _ = geometric_links(agents, radius, seed)
    elif topology == "edges":
        edges = _parse_edge_list(_require(table, "edges", "network"), "network.edges", agents)
        arr = np.array(edges, dtype=np.int64).reshape(-1, 2)
        order = np.lexsort((arr[:, 1], arr[:, 0]))
        src, dst = arr[order, 0], arr[order, 1]
    else:
        raise ScenarioError(
            "network.topology",
            f"unknown topology {topology!r}; expected cycle, random, geometric or edges",
        )
    _check_weight_scheme(weights_spec)
    if weights_spec == "random":
        P = sparse_random_weights(agents, src, dst, seed)
    elif weights_spec == "uniform":
        P = sparse_uniform_weights(agents, src, dst)
    else:
        P = sparse_lazy_metropolis_weights(agents, src, dst)
        _warn_symmetrised(int(np.count_nonzero(np.asarray(src) != np.asarray(dst))),
                          int(P.count_nonzero() - agents))
    _check_weights(P, "network.edges" if topology == "edges" else "network")
    return P


def _check_weights(P: np.ndarray | sp.csr_array, key: str) -> None:
    try:
        if isinstance(P, np.ndarray):
            check_consensus_matrix(P, key)
        else:
            check_sparse_consensus_matrix(P, key)
    except NetworkError as exc:
        error = ScenarioError("", str(exc))  # the message already starts with the key
        error.key = key
        raise error from None


def _parse_delays(table: dict[str, Any], links: list[tuple[int, int]]) -> DelaySpec:
    model = table.get("model", DEFAULTS["delays.model"])
    if model not in DELAY_MODELS:
        raise ScenarioError(
            "delays.model", f"unknown model {model!r}; expected one of {', '.join(DELAY_MODELS)}"
        )
    tau = _int(table.get("tau", DEFAULTS["delays.tau"]), "delays.tau",
               maximum=MAX_DELAY_STEPS)
    if tau < 0:
        raise ScenarioError("delays.tau", f"delay bound must be >= 0, got {tau}")
    if model == "none" and tau != 0:
        raise ScenarioError("delays.tau", f"is {tau} but delays.model = 'none' has no "
                            "delays (use model = 'homogeneous' for tau on every link, or "
                            "drop tau)")
    seed = _int(table.get("seed", DEFAULTS["delays.seed"]), "delays.seed", 0)
    default = _number(table.get("default", DEFAULTS["delays.default"]), "delays.default")
    if default < 0:
        raise ScenarioError("delays.default", f"delay must be >= 0, got {default}")
    per_link: dict[tuple[int, int], float] = {}
    raw_links = table.get("links", [])
    if not isinstance(raw_links, list):
        raise ScenarioError("delays.links", "expected a list of {from, to, delay} tables")
    link_set = set(links)
    for e, entry in enumerate(raw_links):
        key = f"delays.links[{e}]"
        if not isinstance(entry, dict) or set(entry) != {"from", "to", "delay"}:
            raise ScenarioError(key, f"expected {{from, to, delay}}, got {entry!r}")
        link = (_int(entry["from"], f"{key}.from", 0), _int(entry["to"], f"{key}.to", 0))
        if link not in link_set:
            raise ScenarioError(key, f"link {link[0]} -> {link[1]} is not in the network")
        delay = _number(entry["delay"], f"{key}.delay")
        if delay < 0:
            raise ScenarioError(f"{key}.delay", f"delay must be >= 0, got {delay:g}")
        if delay > MAX_DELAY_STEPS:
            raise ScenarioError(f"{key}.delay", f"must be <= {MAX_DELAY_STEPS} (the largest "
                                f"netsim represents), got {delay:g}")
        if model == "fixed" and delay != int(delay):
            raise ScenarioError(f"{key}.delay", f"fixed delays are integer steps, got {delay}")
        if link in per_link:
            earlier = next(k for k, entry in enumerate(raw_links)
                           if (entry.get("from"), entry.get("to")) == link)
            raise ScenarioError(key, f"link {link[0]} -> {link[1]} is listed twice (also "
                                f"delays.links[{earlier}])")
        per_link[link] = delay
    if per_link and model not in ("fixed", "latency"):
        raise ScenarioError("delays.links", f"per-link delays need model 'fixed' or 'latency', "
                            f"not {model!r}")
    if model == "fixed" and default != int(default):
        raise ScenarioError("delays.default", f"fixed delays are integer steps, got {default}")
    return DelaySpec(model, tau, per_link, default, seed)


# -- [links] -----------------------------------------------------------------------


def _table(value: Any, key: str, allowed: set[str]) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ScenarioError(key, f"expected a table, got {value!r}")
    for k in value:
        if k not in allowed:
            close = difflib.get_close_matches(k, sorted(allowed), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ScenarioError(f"{key}.{k}",
                                f"unknown key{hint}; allowed: {', '.join(sorted(allowed))}")
    return value


def _choice(value: Any, key: str, options: Sequence[str]) -> str:
    if value not in options:
        raise ScenarioError(key, f"unknown value {value!r}; expected one of {', '.join(options)}")
    return value


def _probability(value: Any, key: str) -> float:
    p = _number(value, key)
    if not 0 <= p <= 1:
        raise ScenarioError(key, f"must be in [0, 1], got {p:g}")
    return p


def _file(value: Any, key: str, base: Path) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise ScenarioError(key, f"expected a file path, got {value!r}")
    path = Path(value).expanduser()
    return path if path.is_absolute() else base / path


def _parse_link_delay(value: Any, key: str, base: Path) -> DelayConfig:
    if not isinstance(value, dict):
        raise ScenarioError(key, f"expected a table with a 'distribution', got {value!r}")
    name = _choice(_require(value, "distribution", key), f"{key}.distribution",
                   DELAY_DISTRIBUTIONS)
    required, optional = _DISTRIBUTION_KEYS[name]
    common = {"distribution"} if name == "trace" else {"distribution", "unit", "mode"}
    table = _table(value, key, common | required | optional)
    for k in sorted(required):
        _require(table, k, key)
    mode = _choice(table.get("mode", DEFAULTS["links.delay.mode"]), f"{key}.mode", DELAY_MODES)
    if name == "trace":
        path = _file(table["file"], f"{key}.file", base)
        try:
            replay = load_trace_replay(path)
        except ValueError as exc:
            raise ScenarioError(f"{key}.file", str(exc)) from None
        return DelayConfig(replay, "asynchronous")
    units = _DISTRIBUTION_UNITS[name]
    unit = cast(Unit, _choice(table.get("unit", units[0]), f"{key}.unit", units))

    def num(k: str, default: float | None = None) -> float:
        return _number(table.get(k, default), f"{key}.{k}")

    try:
        if name == "constant":
            dist: Any = ConstantDelay(num("value"), unit)
        elif name == "uniform":
            dist = UniformDelay(num("low"), num("high"), unit)
        elif name == "geometric":
            shift = table.get("shift", 0)
            dist = GeometricDelay(num("p"), _int(shift, f"{key}.shift", 0))
        elif name == "gamma":
            dist = ShiftedGamma(num("shape"), num("scale"), num("shift", 0.0))
        elif name == "pareto":
            dist = ShiftedPareto(num("alpha"), num("scale"), num("shift", 0.0))
        else:
            path = _file(table["file"], f"{key}.file", base)
            dist = load_latency_csv(path, scale=num("scale", 1.0), unit=unit)
    except ValueError as exc:
        if isinstance(exc, ScenarioError):
            raise
        # name the parameter the message starts with, else the table
        first = str(exc).split()[0] if str(exc) else ""
        where = f"{key}.{first}" if first in required | optional else (
            f"{key}.file" if name == "empirical" else key)
        raise ScenarioError(where, str(exc)) from None
    if isinstance(dist, EmpiricalDelay) and dist.values.size == 0:  # pragma: no cover
        raise ScenarioError(f"{key}.file", "no values")
    return DelayConfig(dist, mode)


def _parse_loss(value: Any, key: str) -> LossConfig:
    if not isinstance(value, dict):
        raise ScenarioError(key, f"expected a table with a 'model', got {value!r}")
    model = _choice(_require(value, "model", key), f"{key}.model", LOSS_MODELS)
    table = _table(value, key, {"model"} | _LOSS_KEYS[model])
    if model == "none":
        return LossConfig("none")
    p = _probability(_require(table, "p", key), f"{key}.p")
    if model == "bernoulli":
        return LossConfig("bernoulli", p=p)
    r = _probability(_require(table, "r", key), f"{key}.r")
    if p + r <= 0:
        raise ScenarioError(f"{key}.r", "p + r must be > 0 (the chain must be able to move)")
    good = _probability(table.get("loss_good", 0.0), f"{key}.loss_good")
    bad = _probability(table.get("loss_bad", 1.0), f"{key}.loss_bad")
    return LossConfig("gilbert-elliott", p=p, r=r, loss_good=good, loss_bad=bad)


def _parse_buffer(value: Any, key: str) -> BufferConfig:
    table = _table(value, key, {"capacity", "policy"})
    capacity: int | str | None = None
    if "capacity" in table:
        raw = table["capacity"]
        if raw == "tau+1":
            capacity = "tau+1"
        elif isinstance(raw, str):
            raise ScenarioError(f"{key}.capacity", f"expected an integer >= 1 or 'tau+1', "
                                f"got {raw!r}")
        else:
            capacity = _int(raw, f"{key}.capacity", 1)
    default = (DEFAULTS["links.buffer.policy (capacity tau+1)"] if capacity == "tau+1"
               else DEFAULTS["links.buffer.policy"])
    policy = _choice(table.get("policy", default), f"{key}.policy", BUFFER_POLICIES)
    if capacity is None and policy != "keep-latest":
        raise ScenarioError(f"{key}.capacity", f"is missing (policy {policy!r} needs a "
                            "capacity; only 'keep-latest' works without one)")
    return BufferConfig(capacity, policy)


def _parse_outages(value: Any, key: str) -> tuple[tuple[int, int], ...]:
    if not isinstance(value, list):
        raise ScenarioError(key, "expected a list of [start, end] step intervals")
    out = []
    for e, entry in enumerate(value):
        k = f"{key}[{e}]"
        if not (isinstance(entry, list) and len(entry) == 2):
            raise ScenarioError(k, f"expected [start, end] (sending steps, end excluded), "
                                f"got {entry!r}")
        start, end = (_int(v, k, 0) for v in entry)
        if end < start:
            raise ScenarioError(k, f"end ({end}) must be >= start ({start})")
        out.append((start, end))
    return tuple(out)


def _parse_link_settings(table: dict[str, Any], key: str, base: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if "delay" in table:
        out["delay"] = _parse_link_delay(table["delay"], f"{key}delay", base)
    if "loss" in table:
        out["loss"] = _parse_loss(table["loss"], f"{key}loss")
    if "buffer" in table:
        out["buffer"] = _parse_buffer(table["buffer"], f"{key}buffer")
    if "outages" in table:
        out["outages"] = _parse_outages(table["outages"], f"{key}outages")
    if "bandwidth" in table:
        bw = _number(table["bandwidth"], f"{key}bandwidth")
        if bw <= 0:
            raise ScenarioError(f"{key}bandwidth", f"must be > 0 (bits per time unit), "
                                f"got {bw:g}")
        out["bandwidth"] = bw
    if "message_size" in table:
        size = _number(table["message_size"], f"{key}message_size")
        if size < 0:
            raise ScenarioError(f"{key}message_size", f"must be >= 0 (bits), got {size:g}")
        out["message_size"] = size
    return out


def _check_trace_links(config: LinkConfig, links: Sequence[tuple[int, int]], key: str) -> None:
    dist = config.delay.distribution if config.delay is not None else None
    if dist is None or not hasattr(dist, "records"):
        return
    missing = [link for link in links if link not in dist.records]
    if missing:
        names = ", ".join(f"{j}->{i}" for j, i in missing)
        raise ScenarioError(key, f"trace {dist.source} has no messages for link(s) {names}")


def _parse_links(table: dict[str, Any], links: list[tuple[int, int]], delays: DelaySpec,
                 base: Path) -> LinksSpec:
    default = LinkConfig(**_parse_link_settings(table, "links.", base))
    seed = _int(table.get("seed", delays.seed), "links.seed", 0)
    bound = None
    if "bound" in table:
        bound = _int(table["bound"], "links.bound", 0)
    raw = table.get("per_link", [])
    if not isinstance(raw, list):
        raise ScenarioError("links.per_link", "expected a list of tables with from, to and "
                            "link settings")
    link_set = set(links)
    per_link: dict[tuple[int, int], LinkConfig] = {}
    for e, entry in enumerate(raw):
        key = f"links.per_link[{e}]"
        entry = _table(entry, key, _LINK_KEYS)
        link = (_int(_require(entry, "from", key), f"{key}.from", 0),
                _int(_require(entry, "to", key), f"{key}.to", 0))
        if link not in link_set:
            raise ScenarioError(key, f"link {link[0]} -> {link[1]} is not in the network")
        if link in per_link:
            raise ScenarioError(key, f"link {link[0]} -> {link[1]} is listed twice")
        settings = _parse_link_settings(entry, f"{key}.", base)
        per_link[link] = default.merged(settings)
        _check_trace_links(per_link[link], [link], f"{key}.delay.file")
    _check_trace_links(default, [link for link in links if link not in per_link],
                       "links.delay.file")
    return LinksSpec(default, per_link, seed, bound)


def _parse_gains(table: dict[str, Any], plant: LinearPlant) -> GainSpec:
    default = DEFAULTS["gains.method"]
    if plant.n_sensors * plant.n_states > LOCAL_DEFAULT_MIN_STATES:
        default = "local"  # the LMI is not affordable at this size
    method = table.get("method", default)
    if not isinstance(method, str) or method not in GAIN_METHODS:
        raise ScenarioError(
            "gains.method", f"unknown method {method!r}; expected one of {', '.join(GAIN_METHODS)}"
        )
    refine_from = None
    if method == "refined":
        refine_from = table.get("refine_from", DEFAULTS["gains.refine_from"])
        if not isinstance(refine_from, str) or refine_from not in REFINE_FROM:
            raise ScenarioError(
                "gains.refine_from",
                f"unknown design {refine_from!r}; expected one of {', '.join(REFINE_FROM)}",
            )
    elif "refine_from" in table:
        raise ScenarioError("gains.refine_from", "is only used with gains.method = 'refined'")
    tau1 = _int(table.get("tau1", DEFAULTS["gains.tau1"]), "gains.tau1", minimum=0)
    if method == "given" and "tau1" in table:
        raise ScenarioError(
            "gains.tau1", "given gains have no design delay bound (use method = 'refined' "
            "with refine_from = 'given' to optimise them for tau1)"
        )
    uses_K = method == "given" or refine_from == "given"
    if not uses_K:
        if "K" in table:
            raise ScenarioError("gains.K", "given gains need gains.method = 'given' "
                                "(or 'refined' with refine_from = 'given')")
        return GainSpec(method, None, tau1, refine_from)
    K_raw = _require(table, "K", "gains")
    if not isinstance(K_raw, list) or len(K_raw) != plant.n_sensors:
        raise ScenarioError("gains.K", f"expected {plant.n_sensors} matrices, one per agent")
    n = plant.n_states
    K = tuple(_matrix(Ki, f"gains.K[{i}]", (n, n)) for i, Ki in enumerate(K_raw))
    return GainSpec(method, K, tau1, refine_from)


@dataclass(frozen=True)
class ScenarioCounts:
    """The sizes of a scenario, read from its table before any network is built.

    What a budget needs to refuse a scenario that cannot fit before building it
    (:func:`parse_scenario`'s ``precheck``): building a million-agent network alone
    takes seconds and gigabytes.

    Attributes
    ----------
    n_states : int
        n, the plant's states.
    n_agents : int
        N.
    links : int
        L, the network's directed links: exact for ``cycle`` and ``edges``, the expected
        count for ``random`` and ``geometric`` (:func:`geometric_link_estimate`).
    measurements : int
        The sum of the sensors' m_i.
    max_measurements : int
        The largest m_i.
    noise_width : int
        Width of one step's noise vector (:attr:`LinearPlant.noise_width`).
    steps, trials : int
        ``run.steps`` and ``run.trials``.
    max_delay : int
        ``delays.tau``, the delay bound in steps.
    """

    n_states: int
    n_agents: int
    links: int
    measurements: int
    max_measurements: int
    noise_width: int
    steps: int
    trials: int
    max_delay: int


def _link_estimate(table: dict[str, Any], agents: int) -> int | None:
    """The links of a ``[network]`` table, counted or estimated without building them
    (None where only the build can say, e.g. a matrix ``P``)."""
    topology = table.get("topology")
    seed = _int(table.get("seed", DEFAULTS["network.seed"]), "network.seed", 0)
    if "P" in table or agents < 2:
        return None
    if topology == "cycle":
        return agents
    if topology == "random":
        prob = _edge_probability(table)
        return agents + int(round(prob * agents * (agents - 1)))
    if topology == "geometric":
        radius = _network_radius(table)
        return geometric_link_estimate(agents, radius, seed)[0]
    if topology == "edges" and isinstance(table.get("edges"), list):
        return len(table["edges"])
    return None


def scenario_counts(data: dict[str, Any], plant: LinearPlant) -> ScenarioCounts | None:
    """:class:`ScenarioCounts` of a parsed TOML document whose plant is parsed (None when
    the links cannot be counted without building the network, e.g. a ``[topology]``)."""
    if "topology" in data or not isinstance(data.get("network"), dict):
        return None
    table = data["network"]
    agents = _int(table.get("agents", plant.n_sensors), "network.agents", 2)
    links = _link_estimate(table, agents)
    if links is None:
        return None
    run = data.get("run", {}) if isinstance(data.get("run"), dict) else {}
    delays = data.get("delays", {}) if isinstance(data.get("delays"), dict) else {}
    # len(C_i) = m_i, counted by C-level map (1,000,000 sensors in about 30 ms)
    measurements = sum(map(len, plant.C))
    return ScenarioCounts(
        n_states=int(plant.n_states), n_agents=agents, links=links,
        measurements=measurements, max_measurements=max(map(len, plant.C), default=0),
        noise_width=int(plant.n_states) + measurements,
        steps=_int(run.get("steps", DEFAULTS["run.steps"]), "run.steps", 1),
        trials=_int(run.get("trials", DEFAULTS["run.trials"]), "run.trials", 1),
        max_delay=_int(delays.get("tau", DEFAULTS["delays.tau"]), "delays.tau",
                       maximum=MAX_DELAY_STEPS))


def parse_scenario(data: dict[str, Any], source: str = "",
                   precheck: Callable[[ScenarioCounts], None] | None = None) -> Scenario:
    """Validate a parsed TOML document and build the :class:`Scenario`.

    Parameters
    ----------
    data : dict
        The TOML document.
    source : str
        Where it came from (a path, or ``builtin:NAME``).
    precheck : callable, optional
        Called with the scenario's :class:`ScenarioCounts` after the plant is parsed and
        before the network is built (not called when the links cannot be counted without
        building it); it may raise to refuse the scenario, e.g. a memory budget.

    Raises
    ------
    ScenarioError
        Naming the first offending key.
    """
    _check_keys(data, "")
    name = data.get("name", Path(source).stem if source else "scenario")
    if not isinstance(name, str):
        raise ScenarioError("name", f"expected a string, got {name!r}")
    description = data.get("description", "")
    run = _section(data, "run", required=False)
    plant = _parse_plant(_timed_plant_table(data, run))
    if precheck is not None:
        counts = scenario_counts(data, plant)
        if counts is not None:
            precheck(counts)
    topology = None
    if "topology" in data:
        topology = _parse_topology(_section(data, "topology"), plant.n_sensors)
    if topology is not None and "network" not in data:
        # consensus weights of the union graph, for families that need a P
        union: nx.DiGraph[int] = nx.DiGraph()
        union.add_nodes_from(range(plant.n_sensors))
        union.add_edges_from(topology.links())
        P = uniform_weights(union)
        links = sorted(union.edges)
    else:
        P = _parse_network(_section(data, "network"), plant.n_sensors)
        delays_raw = data.get("delays", {})
        if ("links" in data or topology is not None
                or (isinstance(delays_raw, dict) and "links" in delays_raw)):
            src, dst = links_from_weights(P)
            links = list(zip(src.tolist(), dst.tolist(), strict=True))
        else:
            links = []  # only per-link tables need them (Scenario.links builds them once)
        if topology is not None and set(topology.links()) - set(links):
            extra = sorted(set(topology.links()) - set(links))[0]
            raise ScenarioError("topology.graphs", f"link {list(extra)} is not an edge of "
                                "[network] (leave [network] out to use the union graph)")
    options = _parse_options(data.get("options", {}))
    delays_table = _section(data, "delays", required=False)
    delays = _parse_delays(delays_table, links)
    link_spec = None
    if "links" in data:
        link_spec = _parse_links(_section(data, "links"), links, delays,
                                 Path(source).parent if source and not
                                 source.startswith("builtin:") else Path.cwd())
    gains = _parse_gains(_section(data, "gains", required=False), plant)
    estimators = run.get("estimators", DEFAULTS["run.estimators"])
    if not isinstance(estimators, list) or not estimators:
        raise ScenarioError("run.estimators", "expected a non-empty list of estimator names")
    for index, e in enumerate(estimators):
        if not isinstance(e, str) or not e.strip():
            raise ScenarioError(f"run.estimators[{index}]",
                                f"expected an estimator name (a string), got {e!r}")
    if len(set(estimators)) != len(estimators):
        raise ScenarioError("run.estimators", "an estimator is listed twice")
    fraction = _number(run.get("steady_state_fraction", DEFAULTS["run.steady_state_fraction"]),
                       "run.steady_state_fraction")
    if not 0 < fraction <= 1:
        raise ScenarioError("run.steady_state_fraction", f"must be in (0, 1], got {fraction}")
    period = _number(run.get("sample_period", DEFAULTS["run.sample_period"]),
                     "run.sample_period")
    if period <= 0:
        raise ScenarioError("run.sample_period", f"must be > 0, got {period}")
    threshold = _number(run.get("divergence_threshold", DEFAULTS["run.divergence_threshold"]),
                        "run.divergence_threshold")
    if threshold <= 0:
        raise ScenarioError("run.divergence_threshold", f"must be > 0, got {threshold}")
    medium = _parse_medium(data, plant)
    scenario = Scenario(
        name=name,
        description=str(description),
        plant=plant,
        weights=P,
        delays=delays,
        gains=gains,
        estimators=tuple(estimators),
        steps=_int(run.get("steps", DEFAULTS["run.steps"]), "run.steps", 1),
        trials=_int(run.get("trials", DEFAULTS["run.trials"]), "run.trials", 1),
        seed=_int(run.get("seed", DEFAULTS["run.seed"]), "run.seed", 0),
        sample_period=period,
        divergence_threshold=threshold,
        steady_state_fraction=fraction,
        source=source,
        medium=medium,
        link_spec=link_spec,
        topology=topology,
        options=options,
        timing=_parse_timing(data, plant, period),
    )
    if link_spec is not None:
        _check_links_bound(scenario, "tau" in delays_table)
    return scenario


def _timed_plant_table(data: dict[str, Any], run: dict[str, Any]) -> dict[str, Any]:
    """The ``[plant]`` table, A and Q filled in from ``time.Ac``/``time.Qc`` if given."""
    if "time" not in data:
        return _section(data, "plant")
    from netsim.models.timing import TimeError, plant_table_with_continuous

    period = _number(run.get("sample_period", DEFAULTS["run.sample_period"]),
                     "run.sample_period")
    _section(data, "plant")
    try:
        return plant_table_with_continuous(data, period if period > 0 else 1.0)
    except TimeError as exc:
        raise ScenarioError(exc.key, exc.message) from None


def _parse_timing(data: dict[str, Any], plant: LinearPlant, period: float) -> TimeSpec | None:
    """The ``[time]`` table (:func:`netsim.models.timing.parse_time`), or None."""
    if "time" not in data:
        return None
    from netsim.models.timing import TimeError, parse_time

    try:
        return parse_time(data["time"], plant.A, plant.Q, period, plant.n_sensors)
    except TimeError as exc:
        raise ScenarioError(exc.key, exc.message) from None


def _parse_medium(data: dict[str, Any], plant: LinearPlant) -> MediumSpec | None:
    """``[network.medium]`` (:func:`netsim.models.medium.scenario_medium`), or None."""
    network = data.get("network")
    if not isinstance(network, dict) or "medium" not in network:
        return None
    from netsim.models.medium import MediumError, scenario_medium

    try:
        return scenario_medium(data, n_agents=plant.n_sensors, n_states=plant.n_states)
    except MediumError as exc:
        raise ScenarioError(exc.key, exc.detail) from None


_TAU_MODELS = ("homogeneous", "heterogeneous", "synchronous", "asynchronous")


def _check_links_bound(scenario: Scenario, tau_given: bool) -> None:
    """``links.bound`` below a step delay that a bounded link delay (constant, uniform,
    empirical, the ``[delays]`` model, serialisation included) reaches is an error: the
    agents and the analytics would assume a tau-bar that messages exceed. (Unbounded
    distributions, geometric, gamma and Pareto, have only a nominal bound: any
    ``links.bound`` is a choice there.) A bound that replaces an explicit
    ``delays.tau`` is a warning."""
    spec = scenario.link_spec
    assert spec is not None
    base = scenario._base_delay_model(0)
    args = (int(base.max_delay), scenario.sample_period, scenario.plant.n_states)
    if spec.bound is not None:
        worst, where = -1, None
        for link in scenario.links:
            cfg = spec.config(link)
            if cfg.delay is not None and not math.isfinite(
                    getattr(cfg.delay.distribution, "upper", math.inf)):
                continue
            d = spec.max_delay([link], *args)
            if d > worst:
                worst, where = d, link
        if where is not None and spec.bound < worst:
            cfg = spec.config(where)
            source = ("[delays]" if cfg.delay is None else
                      "links.per_link" if where in spec.per_link
                      and spec.per_link[where].delay is not spec.default.delay
                      else "links.delay")
            raise ScenarioError("links.bound", f"is {spec.bound} but link {where[0]} -> "
                                f"{where[1]} has step delays up to {worst} ({source}): "
                                "agents and the analytics would assume a bound its messages "
                                f"exceed; give links.bound >= {worst} or leave it out")
    tau = scenario.delays.tau
    if tau_given and scenario.delays.model in _TAU_MODELS and scenario.delay_bound != tau:
        what = (f"{spec.bound} replaces" if spec.bound is not None else
                "the [links] delay distributions replace")
        _warn("links.bound" if spec.bound is not None else "links.delay",
              f"{what} delays.tau = {tau}: agents and the analytics assume the delay "
              f"bound tau-bar = {scenario.delay_bound}")


def _parse_edge_list(value: Any, key: str, n_agents: int) -> list[tuple[int, int]]:
    """``[[sender, receiver], ...]``: agent indices in range, no self-loop, no duplicate."""
    if not isinstance(value, list):
        raise ScenarioError(key, f"expected a list of [sender, receiver] pairs, got {value!r}")
    first: dict[tuple[int, int], int] = {}
    for e, edge in enumerate(value):
        where = f"{key}[{e}]"
        if not (isinstance(edge, list) and len(edge) == 2):
            raise ScenarioError(where, f"expected [sender, receiver], got {edge!r}")
        j, i = (_int(v, where, 0) for v in edge)
        if j >= n_agents or i >= n_agents:
            raise ScenarioError(where, f"agent index out of range 0..{n_agents - 1}")
        if i == j:
            raise ScenarioError(where, f"[{j}, {i}] is a self-loop, not a link (every "
                                "agent always weighs its own estimate: p_ii > 0)")
        if (j, i) in first:
            raise ScenarioError(where, f"edge {j} -> {i} is listed twice (also "
                                f"{key}[{first[(j, i)]}])")
        first[(j, i)] = e
    return list(first)


def _parse_topology(table: dict[str, Any], n_agents: int) -> GraphSequence | LinkSchedule:
    """``[topology]``: graphs = [[[j, i], ...], ...] (E[0], E[1], ...; the last
    ``period`` repeat, default all), optional link outages ``down = [[j, i, [[start,
    stop], ...]], ...]`` (stop -1: for good) and duty cycles ``duty = [[j, i, period,
    up, phase], ...]``."""
    graphs = _require(table, "graphs", "topology")
    if not isinstance(graphs, list) or not graphs:
        raise ScenarioError("topology.graphs", "expected a non-empty list of edge lists")
    edge_sets = [_parse_edge_list(g, f"topology.graphs[{k}]", n_agents)
                 for k, g in enumerate(graphs)]
    period = None
    if "period" in table:
        period = _int(table["period"], "topology.period", 1)
        if period > len(edge_sets):
            raise ScenarioError("topology.period", f"must be at most the number of graphs "
                                f"({len(edge_sets)}), got {period}")
    try:
        sequence = GraphSequence(n_agents, edge_sets, period)
    except TopologyError as exc:
        raise ScenarioError("topology.graphs", str(exc)) from None
    if "down" not in table and "duty" not in table:
        return sequence
    down: dict[tuple[int, int], list[tuple[int, int | None]]] = {}
    for e, entry in enumerate(table.get("down", [])):
        key = f"topology.down[{e}]"
        if not (isinstance(entry, list) and len(entry) == 3 and isinstance(entry[2], list)):
            raise ScenarioError(key, "expected [sender, receiver, [[start, stop], ...]]")
        (edge,) = _parse_edge_list([entry[:2]], key, n_agents)
        spans = []
        for span in entry[2]:
            if not (isinstance(span, list) and len(span) == 2):
                raise ScenarioError(key, f"expected [start, stop] intervals, got {span!r}")
            start = _int(span[0], key, 0)
            stop = _int(span[1], key, -1)
            spans.append((start, None if stop == -1 else stop))
        down[edge] = spans
    duty = {}
    for e, entry in enumerate(table.get("duty", [])):
        key = f"topology.duty[{e}]"
        if not (isinstance(entry, list) and len(entry) in (4, 5)):
            raise ScenarioError(key, "expected [sender, receiver, period, up, phase]")
        (edge,) = _parse_edge_list([entry[:2]], key, n_agents)
        duty[edge] = [_int(v, key, 0) for v in entry[2:]]
    try:
        return LinkSchedule(sequence, down=down, duty=duty)
    except TopologyError as exc:
        raise ScenarioError("topology", str(exc)) from None


def _parse_options(value: Any) -> dict[str, dict[str, Any]]:
    """``[options.<name>]``: one table per estimator family (or group of families); the
    families check their own keys."""
    if not isinstance(value, dict):
        raise ScenarioError("options", f"expected a table of tables, got {value!r}")
    out = {}
    for name, table in value.items():
        if not isinstance(table, dict):
            raise ScenarioError(f"options.{name}", f"expected a table, got {table!r}")
        out[str(name)] = dict(table)
    return out


def load_scenario(path: str | Path,
                  precheck: Callable[[ScenarioCounts], None] | None = None) -> Scenario:
    """Read and validate a scenario TOML file (``precheck``: see :func:`parse_scenario`).

    Raises
    ------
    ScenarioError
        If the file cannot be read, is not valid TOML, or fails validation.
    """
    path = Path(path)
    return parse_scenario(read_scenario_data(path), str(path), precheck)


def read_scenario_data(path: str | Path) -> dict[str, Any]:
    """The parsed TOML document of a scenario file (ScenarioError naming the file if it
    cannot be read or parsed). A UTF-8 byte-order mark at the start is skipped, with a
    warning (TOML has none; some editors write one)."""
    from netsim.models.inputfiles import (
        MAX_SCENARIO_BYTES,
        InputFileError,
        check_toml_depth,
        read_input_bytes,
    )

    path = Path(path)
    cap = MAX_SCENARIO_BYTES
    env = os.environ.get("NETSIM_MAX_SCENARIO_BYTES")
    if env and env.strip().isdigit():
        cap = int(env)
    try:
        raw = read_input_bytes(path, "scenario file", cap)
    except InputFileError as exc:
        raise ScenarioError("", str(exc) + (" (NETSIM_MAX_SCENARIO_BYTES sets the cap)"
                                            if "MiB" in str(exc) else "")) from None
    bom = raw.startswith(b"\xef\xbb\xbf")
    try:
        text = raw[3 if bom else 0:].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(
            "", f"scenario file {path} is not UTF-8 text (byte {exc.start + (3 if bom else 0)}"
            f": {exc.reason})"
        ) from None
    text = text.replace("\r\n", "\n").replace("\r", "\n")  # as text mode reads it
    if bom:
        _warn("", f"scenario file {path} starts with a UTF-8 BOM (byte-order mark); "
              "ignored it")
    try:
        check_toml_depth(text, f"scenario file {path}")
    except InputFileError as exc:
        raise ScenarioError("", str(exc)) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError("", f"{path} is not valid TOML: {exc}") from None


def builtin_scenarios() -> dict[str, Path]:
    """Return the built-in scenario files by name."""
    folder = resources.files("netsim.models") / "scenarios"
    return {
        Path(entry.name).stem: Path(str(entry))
        for entry in sorted(folder.iterdir(), key=lambda e: e.name)
        if entry.name.endswith(".toml")
    }


def resolve_scenario(name_or_path: str,
                     precheck: Callable[[ScenarioCounts], None] | None = None) -> Scenario:
    """Load a built-in scenario by name, or a scenario file by path (``precheck``: see
    :func:`parse_scenario`)."""
    builtins = builtin_scenarios()
    if not name_or_path.strip():
        raise ScenarioError("", "empty scenario name; give a built-in name or a TOML file path")
    if name_or_path in builtins:
        scenario = load_scenario(builtins[name_or_path], precheck)
        return replace(scenario, source=f"builtin:{name_or_path}")
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        return load_scenario(path, precheck)
    close = difflib.get_close_matches(name_or_path, list(builtins), n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    raise ScenarioError(
        "", f"no built-in scenario or file named {name_or_path!r}{hint}; "
        f"built-ins: {', '.join(builtins)}"
    )
