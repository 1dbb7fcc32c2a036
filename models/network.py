"""Sensor networks: directed graphs and consensus weight matrices.

A network is a :class:`networkx.DiGraph` on nodes ``0..N-1``; an edge ``(j, i)``
means agent ``i`` receives from agent ``j`` (``j`` is an in-neighbour of ``i``).
Self-loops are implied by the positive self-weights and are not stored as links.
The consensus matrix ``P`` (N x N) has ``P[i, j] > 0`` iff ``j == i`` or
``(j, i)`` is an edge, is row-stochastic, and has a positive diagonal
(LCSYS2022 Section II-B).
"""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
from netsim.models.seeding import SeedLike, stream

__all__ = [
    "NetworkError",
    "directed_cycle",
    "random_strongly_connected",
    "geometric",
    "in_neighbours",
    "random_weights",
    "uniform_weights",
    "lazy_metropolis_weights",
    "graph_from_weights",
    "check_consensus_matrix",
    "ROW_SUM_TOLERANCE",
]

#: Tolerance on |row sum - 1| accepted for a row-stochastic matrix.
ROW_SUM_TOLERANCE = 1e-9


class NetworkError(ValueError):
    """A network or weight matrix that violates the estimator's assumptions."""


def directed_cycle(n_agents: int) -> nx.DiGraph:
    """Return the directed cycle 0 -> 1 -> ... -> N-1 -> 0.

    Parameters
    ----------
    n_agents : int
        Number of agents N >= 2.

    Returns
    -------
    networkx.DiGraph
        Edge (j, i) means i receives from j. Self-loops are implicit.
    """
    if n_agents < 2:
        raise NetworkError(f"a directed cycle needs at least 2 agents, got {n_agents}")
    graph = nx.DiGraph()
    graph.add_nodes_from(range(n_agents))
    graph.add_edges_from((i, (i + 1) % n_agents) for i in range(n_agents))
    return graph


def random_strongly_connected(
    n_agents: int, edge_probability: float = 0.1, seed: SeedLike = None
) -> nx.DiGraph:
    """Return a random strongly-connected digraph.

    A random Hamiltonian cycle guarantees strong connectivity; every other ordered
    pair is then added independently with probability ``edge_probability``.

    Parameters
    ----------
    n_agents : int
        Number of agents N >= 2.
    edge_probability : float
        Probability of each extra directed edge.
    seed : int, SeedSequence or None
        Root seed; the stream ``"network/random"`` is used.

    Returns
    -------
    networkx.DiGraph
    """
    if n_agents < 2:
        raise NetworkError(f"a strongly-connected digraph needs at least 2 agents, got {n_agents}")
    rng = stream(seed, "network/random")
    order = rng.permutation(n_agents)
    graph = nx.DiGraph()
    graph.add_nodes_from(range(n_agents))
    graph.add_edges_from(
        (int(order[k]), int(order[(k + 1) % n_agents])) for k in range(n_agents)
    )
    extra = rng.random((n_agents, n_agents)) < edge_probability
    for j, i in zip(*np.nonzero(extra), strict=True):
        if i != j:
            graph.add_edge(int(j), int(i))
    return graph


def geometric(n_agents: int, radius: float | None = None, seed: SeedLike = None) -> nx.DiGraph:
    """Return a random geometric network (symmetric links) in the unit square.

    Agents within ``radius`` of each other communicate both ways. The radius is
    increased by 10% steps until the graph is connected.

    Parameters
    ----------
    n_agents : int
        Number of agents N >= 2.
    radius : float, optional
        Communication radius; default ``sqrt(2 log N / N)`` (connectivity threshold).
    seed : int, SeedSequence or None
        Root seed; the stream ``"network/geometric"`` is used.

    Returns
    -------
    networkx.DiGraph
        With node attribute ``pos`` (x, y).
    """
    if n_agents < 2:
        raise NetworkError(f"a geometric network needs at least 2 agents, got {n_agents}")
    rng = stream(seed, "network/geometric")
    positions = rng.random((n_agents, 2))
    if radius is not None and not radius > 0:
        raise NetworkError(f"geometric network radius must be > 0, got {radius}")
    r = radius if radius is not None else math.sqrt(2.0 * math.log(n_agents) / n_agents)
    dist = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=-1)
    while True:
        graph = nx.DiGraph()
        for i in range(n_agents):
            graph.add_node(i, pos=(float(positions[i, 0]), float(positions[i, 1])))
        for i in range(n_agents):
            for j in range(n_agents):
                if i != j and dist[i, j] <= r:
                    graph.add_edge(j, i)
        if nx.is_strongly_connected(graph):
            return graph
        r *= 1.1


def in_neighbours(graph: nx.DiGraph, agent: int) -> list[int]:
    """Return the sorted in-neighbours of ``agent`` (self excluded)."""
    return sorted(j for j in graph.predecessors(agent) if j != agent)


def _nodes(graph: nx.DiGraph) -> int:
    n_agents = graph.number_of_nodes()
    if sorted(graph.nodes) != list(range(n_agents)):
        raise NetworkError("network nodes must be the integers 0..N-1")
    return n_agents


def random_weights(graph: nx.DiGraph, seed: SeedLike = None) -> np.ndarray:
    """Return random row-stochastic consensus weights on ``graph``.

    Each row draws uniform(0.1, 1) weights on the self-loop and the in-neighbours
    and normalises them to sum to one, so every weight lies in (0, 1).

    Parameters
    ----------
    graph : networkx.DiGraph
        Edge (j, i): i receives from j.
    seed : int, SeedSequence or None
        Root seed; the stream ``"network/weights"`` is used.

    Returns
    -------
    numpy.ndarray, shape (N, N)
    """
    n_agents = _nodes(graph)
    rng = stream(seed, "network/weights")
    weights = np.zeros((n_agents, n_agents))
    for i in range(n_agents):
        support = [i, *in_neighbours(graph, i)]
        w = rng.uniform(0.1, 1.0, size=len(support))
        weights[i, support] = w / w.sum()
    return weights


def uniform_weights(graph: nx.DiGraph) -> np.ndarray:
    """Return the uniform weights p_ij = 1 / (|N_i| + 1) (Hadjicostis-Charalambous).

    Returns
    -------
    numpy.ndarray, shape (N, N)
    """
    n_agents = _nodes(graph)
    weights = np.zeros((n_agents, n_agents))
    for i in range(n_agents):
        support = [i, *in_neighbours(graph, i)]
        weights[i, support] = 1.0 / len(support)
    return weights


def lazy_metropolis_weights(graph: nx.DiGraph) -> np.ndarray:
    """Return lazy Metropolis weights on the undirected version of ``graph``.

    p_ij = 1 / (2 max(d_i, d_j)) for each neighbour pair, p_ii = 1 - sum_j p_ij,
    with d the undirected degree. The result is symmetric and doubly stochastic, so
    the graph's links are used in both directions.

    Returns
    -------
    numpy.ndarray, shape (N, N)
    """
    n_agents = _nodes(graph)
    undirected = graph.to_undirected()
    undirected.remove_edges_from(nx.selfloop_edges(undirected))
    degree = dict(undirected.degree())
    weights = np.zeros((n_agents, n_agents))
    for i, j in undirected.edges:
        w = 1.0 / (2.0 * max(degree[i], degree[j]))
        weights[i, j] = weights[j, i] = w
    weights[np.diag_indices(n_agents)] = 1.0 - weights.sum(axis=1)
    return weights


def graph_from_weights(weights: np.ndarray) -> nx.DiGraph:
    """Return the communication graph whose edges are the off-diagonal nonzeros of P.

    Parameters
    ----------
    weights : numpy.ndarray, shape (N, N)
        Consensus matrix; ``weights[i, j] != 0`` gives the edge (j, i).

    Returns
    -------
    networkx.DiGraph
    """
    n_agents = weights.shape[0]
    graph = nx.DiGraph()
    graph.add_nodes_from(range(n_agents))
    rows, cols = np.nonzero(weights)
    graph.add_edges_from((int(j), int(i)) for i, j in zip(rows, cols, strict=True) if i != j)
    return graph


def check_consensus_matrix(weights: np.ndarray, name: str = "P") -> None:
    """Check the assumptions of LCSYS2022 Section II-B on a consensus matrix.

    Parameters
    ----------
    weights : numpy.ndarray, shape (N, N)
        Candidate consensus matrix.
    name : str
        Name used in error messages (e.g. the scenario key).

    Raises
    ------
    NetworkError
        Naming the first violated property: shape, finiteness, sign, row sums,
        positive self-weights, strong connectivity.
    """
    weights = np.asarray(weights, dtype=float)
    if weights.ndim != 2 or weights.shape[0] != weights.shape[1]:
        raise NetworkError(f"{name}: expected a square N x N matrix, got shape {weights.shape}")
    if not np.all(np.isfinite(weights)):
        i, j = np.argwhere(~np.isfinite(weights))[0]
        raise NetworkError(f"{name}[{i}][{j}] is not finite ({weights[i, j]})")
    if np.any(weights < 0):
        i, j = np.argwhere(weights < 0)[0]
        raise NetworkError(f"{name}[{i}][{j}] = {weights[i, j]} is negative")
    sums = weights.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > ROW_SUM_TOLERANCE)
    if bad.size:
        i = int(bad[0])
        raise NetworkError(
            f"{name} is not row-stochastic: row {i} sums to {sums[i]:.12g}, expected 1"
        )
    zero_diag = np.flatnonzero(np.diag(weights) <= 0)
    if zero_diag.size:
        i = int(zero_diag[0])
        raise NetworkError(
            f"{name}[{i}][{i}] is {weights[i, i]}: self-weights must be positive"
        )
    graph = graph_from_weights(weights)
    if weights.shape[0] > 1 and not nx.is_strongly_connected(graph):
        components = sorted(nx.strongly_connected_components(graph), key=min)
        raise NetworkError(
            f"{name}: the communication graph is not strongly connected "
            f"({len(components)} strongly connected components, e.g. {sorted(components[0])})"
        )
