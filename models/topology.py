"""Time-varying communication topologies: graph sequences, link schedules, checks.

Conventions (as in :mod:`netsim.models.network`): agents are ``0..N-1``; an edge
``(j, i)`` means agent ``i`` receives from agent ``j`` at that step (the aoi paper
writes ``(j, i) in E[k]``: "node j can send information directly to node i at time
step k", so ``j`` is in ``N_i[k]``). Self-loops are never stored.

A topology answers, for every step ``k >= 0``, which directed edges are up:

* :class:`GraphSequence` -- an explicit list of edge sets ``E[0], E[1], ...``; after
  the list ends it repeats its last ``period`` graphs (``period`` defaults to the
  length of the list: a purely periodic sequence). An optional transient prefix is
  therefore ``graphs[:len(graphs) - period]``.
* :class:`LinkSchedule` -- a base topology (a fixed edge set or a
  :class:`GraphSequence`) with per-link outages: down intervals ``[start, stop)``
  (``stop=None``: down for good) and periodic duty cycles (up ``up`` steps out of
  every ``period``, shifted by ``phase``).
* :func:`random_jointly_connected` -- a random periodic sequence whose union over
  every window ``[mT, (m+1)T)`` is strongly connected (the aoi paper's Assumption
  1), while the single graphs are typically not; :func:`random_jointly_rooted` --
  only a spanning tree rooted at each given source per window (Remark 1).

``topology.is_up(sender, receiver, step)`` is usable directly as the ``availability``
hook of :class:`netsim.kernel.Simulation`: a message sent on a link that is down at
its sending step is dropped (counted and traced). With delay-free links (d = 0) a
message sent at step s is usable at step s + 1, which is exactly the aoi paper's
"node i uses N_i[k]'s step-k values to form its step-(k+1) estimate".

Checks (:func:`smallest_joint_period`, :func:`smallest_rooted_period`,
:func:`connectivity_report`) work on eventually periodic sequences exactly, by
enumerating every distinct window.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from netsim.models.lazy import lazy_module
from netsim.models.seeding import SeedLike, stream

if TYPE_CHECKING:
    import networkx as nx
else:  # imported on first use (start-up latency)
    nx = lazy_module("networkx")

__all__ = [
    "Edge",
    "TopologyError",
    "Topology",
    "GraphSequence",
    "LinkSchedule",
    "as_sequence",
    "static_sequence",
    "alternating_sequence",
    "random_jointly_connected",
    "random_jointly_rooted",
    "is_strongly_connected",
    "reaches_all",
    "bfs_parents",
    "window_unions",
    "satisfies_joint_connectivity",
    "satisfies_jointly_rooted",
    "smallest_joint_period",
    "smallest_rooted_period",
    "ConnectivityReport",
    "connectivity_report",
]

Edge = tuple[int, int]


class TopologyError(ValueError):
    """An ill-formed topology (bad node index, self-loop, empty sequence, ...)."""


class Topology(Protocol):
    """What the kernel, the estimators and the checks need from a topology."""

    n_agents: int

    def edges(self, step: int) -> frozenset[Edge]:
        """Edges (sender, receiver) up at ``step``."""
        ...

    def is_up(self, sender: int, receiver: int, step: int) -> bool:
        """Whether link sender -> receiver is up at ``step`` (kernel availability)."""
        ...

    def links(self) -> frozenset[Edge]:
        """Every edge that is ever up (the kernel's static out-links)."""
        ...


def _check_edges(edges: Iterable[Sequence[int]], n_agents: int, where: str) -> frozenset[Edge]:
    out = set()
    for edge in edges:
        if len(edge) != 2:
            raise TopologyError(f"{where}: an edge is a pair (sender, receiver), got {edge!r}")
        j, i = int(edge[0]), int(edge[1])
        if not (0 <= j < n_agents and 0 <= i < n_agents):
            raise TopologyError(f"{where}: edge ({j}, {i}) outside agents 0..{n_agents - 1}")
        if j == i:
            raise TopologyError(f"{where}: self-loop ({j}, {i}); self-loops are implicit")
        out.add((j, i))
    return frozenset(out)


@dataclass(frozen=True)
class GraphSequence:
    """An explicit graph sequence E[0], E[1], ..., eventually periodic.

    Parameters
    ----------
    n_agents : int
        Number of agents N >= 1.
    graphs : sequence of edge sets
        ``graphs[k]`` is E[k] (pairs (sender, receiver)) for k < len(graphs).
    period : int, optional
        For k >= len(graphs), E[k] = E[k - period] (the last ``period`` graphs
        repeat). Default: ``len(graphs)`` (purely periodic).
    """

    n_agents: int
    graphs: tuple[frozenset[Edge], ...]
    period: int

    def __init__(self, n_agents: int, graphs: Sequence[Iterable[Sequence[int]]],
                 period: int | None = None) -> None:
        n_agents = int(n_agents)
        if n_agents < 1:
            raise TopologyError(f"a topology needs at least one agent, got {n_agents}")
        if len(graphs) == 0:
            raise TopologyError("a graph sequence needs at least one graph")
        checked = tuple(_check_edges(g, n_agents, f"graph {k}") for k, g in enumerate(graphs))
        period = len(checked) if period is None else int(period)
        if not 1 <= period <= len(checked):
            raise TopologyError(f"period must be in 1..{len(checked)}, got {period}")
        object.__setattr__(self, "n_agents", n_agents)
        object.__setattr__(self, "graphs", checked)
        object.__setattr__(self, "period", period)

    @property
    def prefix(self) -> int:
        """Length of the transient before the periodic part."""
        return len(self.graphs) - self.period

    def index(self, step: int) -> int:
        """Index into ``graphs`` of E[step]."""
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        if step < len(self.graphs):
            return step
        return self.prefix + (step - self.prefix) % self.period

    def edges(self, step: int) -> frozenset[Edge]:
        return self.graphs[self.index(step)]

    def is_up(self, sender: int, receiver: int, step: int) -> bool:
        return (int(sender), int(receiver)) in self.graphs[self.index(step)]

    __call__ = is_up

    def links(self) -> frozenset[Edge]:
        out: set[Edge] = set()
        for g in self.graphs:
            out |= g
        return frozenset(out)

    def in_neighbours(self, agent: int, step: int) -> tuple[int, ...]:
        """N_i[k]: agents that agent i receives from at ``step``, sorted."""
        return tuple(sorted(j for j, i in self.edges(step) if i == agent))

    def out_neighbours(self, agent: int, step: int) -> tuple[int, ...]:
        return tuple(sorted(i for j, i in self.edges(step) if j == agent))

    def union(self, start: int, stop: int) -> frozenset[Edge]:
        """Edges of the union graph over steps [start, stop)."""
        out: set[Edge] = set()
        seen: set[int] = set()
        for k in range(start, stop):
            idx = self.index(k)
            if idx in seen:
                continue
            seen.add(idx)
            out |= self.graphs[idx]
            if len(seen) == len(self.graphs):
                break
        return frozenset(out)

    def digraph(self, step: int) -> nx.DiGraph:
        g: nx.DiGraph[int] = nx.DiGraph()
        g.add_nodes_from(range(self.n_agents))
        g.add_edges_from(self.edges(step))
        return g

    def to_dict(self) -> dict[str, Any]:
        return {
            "n_agents": self.n_agents,
            "period": self.period,
            "graphs": [sorted([int(j), int(i)] for j, i in g) for g in self.graphs],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GraphSequence:
        return cls(int(data["n_agents"]), [list(map(tuple, g)) for g in data["graphs"]],
                   data.get("period"))


def static_sequence(n_agents: int, edges: Iterable[Sequence[int]]) -> GraphSequence:
    """The time-invariant topology with the given edges."""
    return GraphSequence(n_agents, [list(edges)])


def alternating_sequence(n_agents: int, *graphs: Iterable[Sequence[int]]) -> GraphSequence:
    """E[k] = graphs[k mod len(graphs)] (e.g. the aoi paper's Figure 1: two graphs)."""
    return GraphSequence(n_agents, [list(g) for g in graphs])


@dataclass(frozen=True)
class _Duty:
    period: int
    up: int
    phase: int

    def is_up(self, step: int) -> bool:
        return (step - self.phase) % self.period < self.up


@dataclass(frozen=True, eq=False)
class LinkSchedule:
    """Links that go down for intervals or follow a duty cycle, over a base topology.

    Parameters
    ----------
    base : GraphSequence or iterable of edges
        The topology when every link is up (a fixed edge set is a static topology).
    n_agents : int, optional
        Needed when ``base`` is an edge set.
    down : mapping (sender, receiver) -> list of (start, stop)
        Link (sender, receiver) is down at steps start <= k < stop (stop None: for
        good).
    duty : mapping (sender, receiver) -> (period, up[, phase])
        Link is up at step k iff (k - phase) mod period < up.
    """

    base: GraphSequence
    down: Mapping[Edge, tuple[tuple[int, int | None], ...]] = field(default_factory=dict)
    duty: Mapping[Edge, _Duty] = field(default_factory=dict)

    def __init__(self, base: GraphSequence | Iterable[Sequence[int]], *,
                 n_agents: int | None = None,
                 down: Mapping[Edge, Iterable[tuple[int, int | None]]] | None = None,
                 duty: Mapping[Edge, Sequence[int]] | None = None) -> None:
        if not isinstance(base, GraphSequence):
            if n_agents is None:
                raise TopologyError("LinkSchedule over an edge set needs n_agents")
            base = static_sequence(n_agents, base)
        n = base.n_agents
        intervals: dict[Edge, tuple[tuple[int, int | None], ...]] = {}
        for edge, spans in (down or {}).items():
            (key,) = _check_edges([edge], n, "down")
            out = []
            for span in spans:
                start, stop = int(span[0]), None if span[1] is None else int(span[1])
                if start < 0 or (stop is not None and stop < start):
                    raise TopologyError(f"down interval {span!r} of link {key}: need "
                                        "0 <= start <= stop")
                out.append((start, stop))
            intervals[key] = tuple(out)
        cycles: dict[Edge, _Duty] = {}
        for edge, spec in (duty or {}).items():
            (key,) = _check_edges([edge], n, "duty")
            period, up = int(spec[0]), int(spec[1])
            phase = int(spec[2]) if len(spec) > 2 else 0
            if period < 1 or not 0 <= up <= period:
                raise TopologyError(f"duty cycle {tuple(spec)!r} of link {key}: need "
                                    "period >= 1 and 0 <= up <= period")
            cycles[key] = _Duty(period, up, phase % period)
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "down", intervals)
        object.__setattr__(self, "duty", cycles)

    @property
    def n_agents(self) -> int:
        return self.base.n_agents

    def _link_up(self, edge: Edge, step: int) -> bool:
        for start, stop in self.down.get(edge, ()):
            if step >= start and (stop is None or step < stop):
                return False
        cycle = self.duty.get(edge)
        return cycle is None or cycle.is_up(step)

    def is_up(self, sender: int, receiver: int, step: int) -> bool:
        edge = (int(sender), int(receiver))
        return self.base.is_up(*edge, step) and self._link_up(edge, step)

    __call__ = is_up

    def edges(self, step: int) -> frozenset[Edge]:
        return frozenset(e for e in self.base.edges(step) if self._link_up(e, step))

    def links(self) -> frozenset[Edge]:
        return self.base.links()

    def to_sequence(self) -> GraphSequence:
        """The same topology as an explicit eventually periodic :class:`GraphSequence`."""
        ends = [self.base.prefix]
        for spans in self.down.values():
            for start, stop in spans:
                ends.append(start if stop is None else stop)
        period = self.base.period
        for cycle in self.duty.values():
            period = math.lcm(period, cycle.period)
        prefix = max(ends)
        return GraphSequence(self.n_agents,
                             [self.edges(k) for k in range(prefix + period)], period)

    def to_dict(self) -> dict[str, Any]:
        return {
            "base": self.base.to_dict(),
            "down": [[j, i, [list(s) for s in spans]] for (j, i), spans in self.down.items()],
            "duty": [[j, i, c.period, c.up, c.phase] for (j, i), c in self.duty.items()],
        }


def as_sequence(topology: GraphSequence | LinkSchedule) -> GraphSequence:
    """Return the topology as an explicit :class:`GraphSequence`."""
    if isinstance(topology, GraphSequence):
        return topology
    if isinstance(topology, LinkSchedule):
        return topology.to_sequence()
    raise TypeError(f"not a topology: {type(topology).__name__}")


# -- graph predicates -------------------------------------------------------------


def _reach(n_agents: int, edges: Iterable[Edge], root: int) -> set[int]:
    out: dict[int, list[int]] = {}
    for j, i in edges:
        out.setdefault(j, []).append(i)
    seen = {root}
    todo = [root]
    while todo:
        u = todo.pop()
        for v in out.get(u, ()):
            if v not in seen:
                seen.add(v)
                todo.append(v)
    return seen


def reaches_all(n_agents: int, edges: Iterable[Edge], root: int) -> bool:
    """Whether the graph has a spanning tree rooted at ``root`` (root reaches everyone)."""
    return len(_reach(n_agents, edges, root)) == n_agents


def is_strongly_connected(n_agents: int, edges: Iterable[Edge]) -> bool:
    """Whether the directed graph on 0..N-1 is strongly connected."""
    edges = list(edges)
    if n_agents <= 1:
        return True
    if not reaches_all(n_agents, edges, 0):
        return False
    return reaches_all(n_agents, [(i, j) for j, i in edges], 0)


def bfs_parents(n_agents: int, edges: Iterable[Edge], root: int) -> dict[int, int]:
    """Parents of a breadth-first spanning tree rooted at ``root`` (nodes it reaches).

    Among equally close candidates the lowest-numbered parent is chosen, so the tree
    is deterministic. The root and unreached nodes have no entry.
    """
    out: dict[int, list[int]] = {}
    for j, i in edges:
        out.setdefault(j, []).append(i)
    parents: dict[int, int] = {}
    level = [root]
    seen = {root}
    while level:
        nxt: list[int] = []
        for u in sorted(level):
            for v in sorted(out.get(u, ())):
                if v not in seen:
                    seen.add(v)
                    parents[v] = u
                    nxt.append(v)
        level = nxt
    return parents


# -- joint connectivity (Assumption 1, Remark 1) ------------------------------------


def window_unions(sequence: GraphSequence, T: int) -> list[tuple[int, frozenset[Edge]]]:
    """Every distinct aligned window [mT, (m+1)T) of the sequence and its union.

    Windows that lie inside the transient are listed one by one; after it the window
    pattern repeats every lcm(period, T) steps, so one repetition is listed. Returns
    (start step, union edges) pairs.
    """
    T = int(T)
    if T < 1:
        raise ValueError(f"T must be >= 1, got {T}")
    prefix, period = sequence.prefix, sequence.period
    first_periodic = math.ceil(prefix / T)  # first window starting at or after the prefix
    cycle = math.lcm(period, T) // T
    return [(m * T, sequence.union(m * T, (m + 1) * T))
            for m in range(first_periodic + cycle)]


def satisfies_joint_connectivity(topology: GraphSequence | LinkSchedule, T: int) -> bool:
    """Assumption 1 with this T: the union over every [mT, (m+1)T) is strongly connected."""
    seq = as_sequence(topology)
    return all(is_strongly_connected(seq.n_agents, edges) for _, edges in window_unions(seq, T))


def satisfies_jointly_rooted(topology: GraphSequence | LinkSchedule, T: int,
                             roots: Iterable[int]) -> bool:
    """Remark 1 with this T: every window union has a spanning tree rooted at each root."""
    seq = as_sequence(topology)
    roots = list(roots)
    return all(reaches_all(seq.n_agents, edges, r)
               for _, edges in window_unions(seq, T) for r in roots)


def _smallest(seq: GraphSequence, test) -> int | None:
    # If T works, so does any window containing a full period of the periodic part;
    # with T >= prefix + period every window does, so searching 1..prefix+period is
    # exhaustive (not monotone below that: T may work while T + 1 fails).
    for T in range(1, seq.prefix + seq.period + 1):
        if all(test(edges) for _, edges in window_unions(seq, T)):
            return T
    return None


def smallest_joint_period(topology: GraphSequence | LinkSchedule) -> int | None:
    """The smallest T of Assumption 1 (jointly strongly connected), None if none exists."""
    seq = as_sequence(topology)
    return _smallest(seq, lambda e: is_strongly_connected(seq.n_agents, e))


def smallest_rooted_period(topology: GraphSequence | LinkSchedule,
                           roots: Iterable[int]) -> int | None:
    """The smallest T for which every window union is rooted at every given root
    (Remark 1's relaxation; roots = the source nodes of non-empty substates)."""
    seq = as_sequence(topology)
    roots = list(roots)
    return _smallest(seq, lambda e: all(reaches_all(seq.n_agents, e, r) for r in roots))


@dataclass(frozen=True)
class ConnectivityReport:
    """Connectivity of a (eventually periodic) topology.

    Attributes
    ----------
    n_agents, prefix, period : int
    joint_T : int or None
        Smallest T of Assumption 1 (None: the sequence is not jointly strongly
        connected for any T).
    rooted_T : dict root -> int or None
        Per root, the smallest T with every window union rooted at it.
    rooted_all_T : int or None
        Smallest T rooted at every root simultaneously (Remark 1).
    graphs_strongly_connected : int
        How many of the listed graphs are strongly connected on their own.
    """

    n_agents: int
    prefix: int
    period: int
    joint_T: int | None
    rooted_T: dict[int, int | None]
    rooted_all_T: int | None
    graphs_strongly_connected: int
    graphs: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "n_agents": self.n_agents,
            "prefix": self.prefix,
            "period": self.period,
            "joint_T": self.joint_T,
            "rooted_T": {str(k): v for k, v in self.rooted_T.items()},
            "rooted_all_T": self.rooted_all_T,
            "graphs_strongly_connected": self.graphs_strongly_connected,
            "graphs": self.graphs,
        }


def connectivity_report(topology: GraphSequence | LinkSchedule,
                        roots: Iterable[int] | None = None) -> ConnectivityReport:
    """Assumption 1's smallest T and Remark 1's rooted T (roots default: every agent)."""
    seq = as_sequence(topology)
    roots = list(range(seq.n_agents)) if roots is None else sorted(set(int(r) for r in roots))
    return ConnectivityReport(
        n_agents=seq.n_agents,
        prefix=seq.prefix,
        period=seq.period,
        joint_T=smallest_joint_period(seq),
        rooted_T={r: smallest_rooted_period(seq, [r]) for r in roots},
        rooted_all_T=smallest_rooted_period(seq, roots),
        graphs_strongly_connected=sum(is_strongly_connected(seq.n_agents, g)
                                      for g in seq.graphs),
        graphs=len(seq.graphs),
    )


# -- random sequences -----------------------------------------------------------------


def _spread(rng: np.random.Generator, edges: list[Edge], T: int,
            extra_copies: float) -> list[set[Edge]]:
    """Assign every edge to one random step of the window (plus random extra steps)."""
    window: list[set[Edge]] = [set() for _ in range(T)]
    for e in edges:
        window[int(rng.integers(T))].add(e)
        if extra_copies > 0:
            for t in range(T):
                if rng.random() < extra_copies:
                    window[t].add(e)
    return window


def random_jointly_connected(
    n_agents: int,
    T: int,
    *,
    windows: int = 4,
    seed: SeedLike = 0,
    extra_edge_probability: float = 0.0,
    repeat_probability: float = 0.0,
) -> GraphSequence:
    """A random periodic sequence satisfying Assumption 1 with this T.

    Each of ``windows`` windows of T steps gets its own random strongly connected
    union: a random Hamiltonian cycle plus every other ordered pair with probability
    ``extra_edge_probability``. Each edge of the union is switched on at one random
    step of the window (and at each other step with probability
    ``repeat_probability``), so for T >= 2 the single graphs are typically not
    strongly connected, nor need they be. The period is ``windows * T``.

    Parameters
    ----------
    n_agents : int
    T : int
        Window length of Assumption 1 (the sequence may also satisfy it for a
        smaller T; :func:`smallest_joint_period` tells).
    windows : int
        Number of distinct windows in one period.
    seed : int or SeedSequence
        Stream ``("topology", "joint")`` of this seed.
    """
    if n_agents < 1 or T < 1 or windows < 1:
        raise TopologyError("need n_agents >= 1, T >= 1 and windows >= 1")
    rng = stream(seed, "topology", "joint")
    graphs: list[set[Edge]] = []
    for _ in range(windows):
        order = rng.permutation(n_agents)
        union = {(int(order[t]), int(order[(t + 1) % n_agents]))
                 for t in range(n_agents)} if n_agents > 1 else set()
        for j in range(n_agents):
            for i in range(n_agents):
                if i != j and (j, i) not in union and rng.random() < extra_edge_probability:
                    union.add((j, i))
        graphs.extend(_spread(rng, sorted(union), T, repeat_probability))
    return GraphSequence(n_agents, graphs)


def random_jointly_rooted(
    n_agents: int,
    T: int,
    roots: Sequence[int],
    *,
    windows: int = 4,
    seed: SeedLike = 0,
    repeat_probability: float = 0.0,
) -> GraphSequence:
    """A random periodic sequence whose window unions are rooted at every root
    (Remark 1) but, in general, not strongly connected: per window, the union of one
    random spanning arborescence out of each root."""
    if n_agents < 1 or T < 1 or windows < 1:
        raise TopologyError("need n_agents >= 1, T >= 1 and windows >= 1")
    rng = stream(seed, "topology", "rooted")
    graphs: list[set[Edge]] = []
    for _ in range(windows):
        union: set[Edge] = set()
        for root in roots:
            others = [v for v in rng.permutation(n_agents).tolist() if v != root]
            placed = [int(root)]
            for v in others:
                parent = placed[int(rng.integers(len(placed)))]
                union.add((parent, int(v)))
                placed.append(int(v))
        graphs.extend(_spread(rng, sorted(union), T, repeat_probability))
    return GraphSequence(n_agents, graphs)
