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
from typing import TYPE_CHECKING

import numpy as np
from netsim.models.lazy import issparse, lazy_module
from netsim.models.seeding import SeedLike, stream

if TYPE_CHECKING:
    import networkx as nx
    import scipy.sparse as sp
    from scipy.spatial import cKDTree
else:  # imported on first use (start-up latency): dense scenarios need neither
    nx = lazy_module("networkx")
    sp = lazy_module("scipy.sparse")

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
    "DENSE_RANDOM_MAX_AGENTS",
    "geometric_links",
    "geometric_link_estimate",
    "random_links",
    "strongly_connected",
    "links_of_graph",
    "sparse_random_weights",
    "sparse_uniform_weights",
    "sparse_lazy_metropolis_weights",
    "links_from_weights",
    "check_sparse_consensus_matrix",
]

#: Tolerance on |row sum - 1| accepted for a row-stochastic matrix.
ROW_SUM_TOLERANCE = 1e-9
#: Largest N for which :func:`random_links` (and :func:`random_strongly_connected`)
#: draws the historic dense N x N uniform matrix, so existing seeds keep their graphs;
#: above it the extra edges are drawn by geometric skips, O(edges).
DENSE_RANDOM_MAX_AGENTS = 2048


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
    graph: nx.DiGraph[int] = nx.DiGraph()
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
    src, dst = random_links(n_agents, edge_probability, seed)
    graph: nx.DiGraph[int] = nx.DiGraph()
    graph.add_nodes_from(range(n_agents))
    graph.add_edges_from(zip(src.tolist(), dst.tolist(), strict=True))
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
    src, dst, positions = geometric_links(n_agents, radius, seed)
    graph: nx.DiGraph[int] = nx.DiGraph()
    for i in range(n_agents):
        graph.add_node(i, pos=(float(positions[i, 0]), float(positions[i, 1])))
    graph.add_edges_from(zip(src.tolist(), dst.tolist(), strict=True))
    return graph


def _sorted_links(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Links sorted by sender, then receiver (one argsort of an int64 key)."""
    src = np.asarray(src, dtype=np.int64)
    dst = np.asarray(dst, dtype=np.int64)
    if not len(src):
        return src, dst
    base = int(max(src.max(), dst.max())) + 1
    # a counting sort by sender (CSR construction), then receivers within each row
    M = sp.csr_array((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(base, base))
    M.sum_duplicates()
    rows = np.repeat(np.arange(base, dtype=np.int64), np.diff(M.indptr))
    return rows, M.indices.astype(np.int64)


def strongly_connected(n_agents: int, src: np.ndarray, dst: np.ndarray) -> tuple[bool, int]:
    """Whether the digraph with links ``src[l] -> dst[l]`` is strongly connected.

    ``scipy.sparse.csgraph.connected_components(connection="strong")`` on the
    adjacency in CSR form, O(N + L).

    Parameters
    ----------
    n_agents : int
        Number of nodes N.
    src, dst : numpy.ndarray, shape (L,)
        Link endpoints (sender, receiver).

    Returns
    -------
    connected : bool
    components : int
        Number of strongly connected components.
    """
    adjacency = sp.csr_array((np.ones(len(src), dtype=np.int8), (np.asarray(src),
                              np.asarray(dst))), shape=(n_agents, n_agents))
    from scipy.sparse.csgraph import connected_components

    count, _ = connected_components(adjacency, directed=True, connection="strong")
    return count == 1, int(count)


def geometric_links(n_agents: int, radius: float | None = None, seed: SeedLike = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The links of :func:`geometric` as arrays, by a k-d tree in O(L log N).

    The points (stream ``"network/geometric"``, uniform in the unit square) and the
    radius rule (default ``sqrt(2 log N / N)``, grown by 10% until the graph is
    connected) are those of :func:`geometric`; the pairs within the radius come from
    ``scipy.spatial.cKDTree.query_pairs`` (distance at most r), re-queried at each
    growth (O(L log N) each time, never N^2).

    Returns
    -------
    src, dst : numpy.ndarray, shape (L,), int64
        Links sender -> receiver, both directions of every pair, sorted by sender
        then receiver.
    positions : numpy.ndarray, shape (N, 2)
    """
    if n_agents < 2:
        raise NetworkError(f"a geometric network needs at least 2 agents, got {n_agents}")
    rng = stream(seed, "network/geometric")
    positions = rng.random((n_agents, 2))
    if radius is not None and not radius > 0:
        raise NetworkError(f"geometric network radius must be > 0, got {radius}")
    r = radius if radius is not None else math.sqrt(2.0 * math.log(n_agents) / n_agents)
    from scipy.spatial import cKDTree

    tree = cKDTree(positions)
    r = _grown_past_isolation(r, positions, tree)
    while True:
        pairs = tree.query_pairs(r, output_type="ndarray")
        src = np.concatenate([pairs[:, 0], pairs[:, 1]])
        dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
        # symmetric links: strongly connected iff connected
        if len(src) and strongly_connected(n_agents, src, dst)[0]:
            src, dst = _sorted_links(src, dst)
            return src, dst, positions
        r *= 1.1


#: Points alone in their grid cell that :func:`_nearest_distances` measures by brute force
#: (one pass over all points each); more build a k-d tree.
_BRUTE_FORCE_POINTS = 64
#: Finer grids than this many cells per row (int64 cell numbers) are not built.
_MAX_CELLS_PER_ROW = 2 ** 31


def _lonely_points(r: float, positions: np.ndarray) -> np.ndarray:
    """Indices of the points that may have no other point within distance ``r``.

    The unit square is cut into equal square cells of side at most just under
    ``r / sqrt(2)``, whose diagonal is below r: two points in one cell are within r of
    each other, so only a point alone in its cell can be isolated. O(N) time and
    memory, no k-d tree. (Checking each lonely point against the cells around it in
    numpy was measured slower than a k-d tree query of the lonely points: 2.6 s against
    1.4 s for 204,000 of 1,000,000 points.)
    """
    side = r / math.sqrt(2.0) * (1.0 - 1e-9)  # the diagonal strictly below r
    if not side * _MAX_CELLS_PER_ROW > 1.0:  # a grid this fine: every point is a suspect
        return np.arange(len(positions))
    cells_per_row = int(math.ceil(1.0 / side))  # equal cells tiling the unit square
    cell = np.floor(positions * cells_per_row).astype(np.int64)
    np.clip(cell, 0, cells_per_row - 1, out=cell)
    flat = cell[:, 0] * cells_per_row + cell[:, 1]
    if cells_per_row * cells_per_row > 4 * len(positions) + 1024:
        # far more cells than points: count the occupied ones only
        _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
        return np.flatnonzero(counts[inverse] == 1)
    occupancy = np.bincount(flat, minlength=cells_per_row * cells_per_row)
    return np.flatnonzero(occupancy[flat] == 1)


def _nearest_distances(points: np.ndarray, positions: np.ndarray,
                       tree: cKDTree | None) -> np.ndarray:
    """Distance from each ``positions[points]`` to its nearest other point, exactly."""
    if tree is None and len(points) <= _BRUTE_FORCE_POINTS:
        out = np.empty(len(points))
        for row, i in enumerate(points):
            d2 = np.sum((positions - positions[i]) ** 2, axis=1)
            d2[i] = np.inf
            out[row] = math.sqrt(float(d2.min()))
        return out
    if tree is None:
        from scipy.spatial import cKDTree

        tree = cKDTree(positions, balanced_tree=False, compact_nodes=False)
    nearest, _ = tree.query(positions[points], k=2)
    return np.asarray(nearest)[:, 1]


def _grown_past_isolation(r: float, positions: np.ndarray,
                          tree: cKDTree | None = None) -> float:
    """The first radius of the 10% growth from ``r`` at which no agent is isolated.

    A graph with an isolated agent is not connected, so every radius of the growth
    below the largest nearest-neighbour distance fails: skipping them gives the same
    final radius as trying each. Only the points alone in their cell of a grid finer
    than r (:func:`_lonely_points`, O(N)) can be isolated; their nearest neighbours are
    measured exactly (brute force for a few, else a k-d tree), so the radius is the one
    a nearest-neighbour query of every point gives (issue 34: 1,000,000 points in about
    0.1 s instead of 3-4 s of CPU).
    """
    if len(positions) < 2:
        return r
    lonely = _lonely_points(r, positions)
    if len(lonely) == 0:
        return r
    needed = float(_nearest_distances(lonely, positions, tree).max())
    while r < needed:
        r *= 1.1
    return r


def geometric_link_estimate(n_agents: int, radius: float | None = None,
                            seed: SeedLike = None) -> tuple[int, float]:
    """About how many links :func:`geometric_links` builds, without building them.

    The same points and radius rule as :func:`geometric_links`, grown until no agent is
    isolated (:func:`_grown_past_isolation`); the links are then the expected number of
    ordered pairs within that radius, ``N (N - 1) p(r)`` with ``p(r) = pi r^2 - 8 r^3 / 3
    + r^4 / 2`` the probability that two uniform points of the unit square lie within r
    (r <= 1). The real graph may need one more 10% growth to be connected (rarely: in
    random geometric graphs the last isolated agent and connectivity go together).
    O(N) time and memory (a grid, and a k-d tree only when many points are alone in their
    cells).

    Returns
    -------
    links : int
        The estimated number of (directed) links L.
    radius : float
        The radius the estimate is for.
    """
    if n_agents < 2:
        raise NetworkError(f"a geometric network needs at least 2 agents, got {n_agents}")
    rng = stream(seed, "network/geometric")
    positions = rng.random((n_agents, 2))
    r = radius if radius is not None else math.sqrt(2.0 * math.log(n_agents) / n_agents)
    r = _grown_past_isolation(r, positions)
    q = min(r, 1.0)
    p = min(1.0, math.pi * q * q - 8.0 * q ** 3 / 3.0 + q ** 4 / 2.0)
    return int(round(n_agents * (n_agents - 1) * p)), r


def random_links(n_agents: int, edge_probability: float = 0.1, seed: SeedLike = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The links of :func:`random_strongly_connected` as sorted arrays (sender, receiver).

    A random Hamiltonian cycle, then every other ordered pair independently with
    probability ``edge_probability``. Up to :data:`DENSE_RANDOM_MAX_AGENTS` agents the
    extra pairs come from the historic dense draw (the same graphs as before for the
    same seed); above, from geometric skips over the N^2 ordered pairs (the same
    distribution, O(L) time and memory).
    """
    if n_agents < 2:
        raise NetworkError(f"a strongly-connected digraph needs at least 2 agents, got {n_agents}")
    rng = stream(seed, "network/random")
    order = rng.permutation(n_agents)
    cycle_src, cycle_dst = order, np.roll(order, -1)
    if n_agents <= DENSE_RANDOM_MAX_AGENTS:
        extra = rng.random((n_agents, n_agents)) < edge_probability
        ej, ei = np.nonzero(extra)
    elif edge_probability <= 0:
        ej = ei = np.zeros(0, dtype=np.int64)
    else:
        total = n_agents * n_agents
        chunks, position = [], -1
        expected = int(total * edge_probability * 1.05) + 64
        while True:
            if edge_probability >= 1:
                gaps = np.ones(expected, dtype=np.int64)
            else:
                gaps = rng.geometric(edge_probability, size=expected)
            flat = position + np.cumsum(gaps)
            position = int(flat[-1])
            chunks.append(flat[flat < total])
            if position >= total:
                break
        flat = np.concatenate(chunks)
        ej, ei = np.divmod(flat, n_agents)
    keep = ej != ei
    src = np.concatenate([cycle_src, ej[keep]])
    dst = np.concatenate([cycle_dst, ei[keep]])
    key = np.unique(src.astype(np.int64) * n_agents + dst)
    return _sorted_links(key // n_agents, key % n_agents)


def links_of_graph(graph: nx.DiGraph) -> tuple[int, np.ndarray, np.ndarray]:
    """N and the sorted links (sender, receiver) of a networkx graph, self-loops dropped."""
    n_agents = _nodes(graph)
    edges = np.array([e for e in graph.edges if e[0] != e[1]], dtype=np.int64).reshape(-1, 2)
    src, dst = _sorted_links(edges[:, 0], edges[:, 1])
    return n_agents, src, dst


def _row_support(n_agents: int, src: np.ndarray, dst: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows (receivers) and columns (self, then in-neighbours ascending) of every
    nonzero of P, in the order :func:`random_weights` draws them, and the row starts."""
    # in-neighbours of each receiver ascending (CSR: a counting sort), then the self
    # entry put in front of every row
    M = sp.csr_array((np.ones(len(src), dtype=np.int8), (np.asarray(dst), np.asarray(src))),
                     shape=(n_agents, n_agents))
    M.sum_duplicates()
    degree = np.diff(M.indptr)
    starts = np.concatenate([[0], np.cumsum(degree + 1)]).astype(np.int64)
    rows = np.repeat(np.arange(n_agents, dtype=np.int64), degree + 1)
    cols = np.empty(len(rows), dtype=np.int64)
    cols[starts[:-1]] = np.arange(n_agents)
    neighbour_rows = np.repeat(np.arange(n_agents, dtype=np.int64), degree)
    cols[np.arange(len(M.indices)) + neighbour_rows + 1] = M.indices
    return rows, cols, starts


def _csr(rows: np.ndarray, cols: np.ndarray, values: np.ndarray, n_agents: int) -> sp.csr_array:
    P = sp.csr_array((values, (rows, cols)), shape=(n_agents, n_agents))
    P.sort_indices()
    return P


def sparse_random_weights(n_agents: int, src: np.ndarray, dst: np.ndarray,
                          seed: SeedLike = None) -> sp.csr_array:
    """:func:`random_weights` as a CSR matrix, O(N + L): the same draws in the same
    order (row by row: the self weight, then the in-neighbours ascending), normalised
    per row.

    Returns
    -------
    scipy.sparse.csr_array, shape (N, N)
    """
    rng = stream(seed, "network/weights")
    rows, cols, starts = _row_support(n_agents, src, dst)
    w = rng.uniform(0.1, 1.0, size=len(rows))
    sums = np.add.reduceat(w, starts[:-1])
    return _csr(rows, cols, w / sums[rows], n_agents)


def sparse_uniform_weights(n_agents: int, src: np.ndarray, dst: np.ndarray) -> sp.csr_array:
    """:func:`uniform_weights` as a CSR matrix: p_ij = 1 / (|N_i| + 1), O(N + L)."""
    rows, cols, starts = _row_support(n_agents, src, dst)
    size = np.diff(starts)
    return _csr(rows, cols, 1.0 / size[rows], n_agents)


def sparse_lazy_metropolis_weights(n_agents: int, src: np.ndarray, dst: np.ndarray
                                   ) -> sp.csr_array:
    """:func:`lazy_metropolis_weights` as a CSR matrix, O(N + L): symmetric, doubly
    stochastic, on the undirected version of the links."""
    a, b = np.minimum(src, dst), np.maximum(src, dst)
    key = np.unique(a.astype(np.int64) * n_agents + b)
    a, b = key // n_agents, key % n_agents
    degree = np.bincount(a, minlength=n_agents) + np.bincount(b, minlength=n_agents)
    w = 1.0 / (2.0 * np.maximum(degree[a], degree[b]))
    off = sp.csr_array((np.concatenate([w, w]), (np.concatenate([a, b]),
                        np.concatenate([b, a]))), shape=(n_agents, n_agents))
    diag = 1.0 - np.asarray(off.sum(axis=1)).ravel()
    P = sp.csr_array(off + sp.diags_array(diag, format="csr"))
    P.sort_indices()
    return P


def links_from_weights(weights: sp.csr_array | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted links (sender j, receiver i) of the off-diagonal nonzeros ``P[i, j]``,
    dense or sparse, without building a graph."""
    if issparse(weights):
        # column-major (CSC, a counting sort) is sender-major: already in link order
        csc = sp.csc_array(weights)
        csc.sum_duplicates()
        j = np.repeat(np.arange(csc.shape[1], dtype=np.int64), np.diff(csc.indptr))
        i = csc.indices.astype(np.int64)
        keep = (i != j) & (csc.data != 0)
        return j[keep], i[keep]
    else:
        i, j = np.nonzero(np.asarray(weights))
        keep = i != j
        i, j = i[keep], j[keep]
    return _sorted_links(np.asarray(j), np.asarray(i))


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


def _supports(n_agents: int, src: np.ndarray, dst: np.ndarray) -> list[list[int]]:
    """Each agent i's weight support: i, then its sorted in-neighbours (self excluded),
    as :func:`in_neighbours` gives them for the graph of the links (src, dst)."""
    incoming: list[set[int]] = [set() for _ in range(n_agents)]
    for j, i in zip(np.asarray(src).tolist(), np.asarray(dst).tolist(), strict=True):
        if j != i:
            incoming[i].add(j)
    return [[i, *sorted(incoming[i])] for i in range(n_agents)]


def link_random_weights(n_agents: int, src: np.ndarray, dst: np.ndarray,
                        seed: SeedLike = None) -> np.ndarray:
    """:func:`random_weights` of the graph with the links (src[k], dst[k]) and nodes
    0..N-1, the same numbers, without building a networkx graph."""
    rng = stream(seed, "network/weights")
    weights = np.zeros((n_agents, n_agents))
    for i, support in enumerate(_supports(n_agents, src, dst)):
        w = rng.uniform(0.1, 1.0, size=len(support))
        weights[i, support] = w / w.sum()
    return weights


def link_uniform_weights(n_agents: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """:func:`uniform_weights` of the graph with the links (src[k], dst[k]), without
    building a networkx graph."""
    weights = np.zeros((n_agents, n_agents))
    for i, support in enumerate(_supports(n_agents, src, dst)):
        weights[i, support] = 1.0 / len(support)
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
    weights : numpy.ndarray or scipy.sparse matrix, shape (N, N)
        Consensus matrix; ``weights[i, j] != 0`` gives the edge (j, i).

    Returns
    -------
    networkx.DiGraph
    """
    n_agents = weights.shape[0]
    graph: nx.DiGraph[int] = nx.DiGraph()
    graph.add_nodes_from(range(n_agents))
    if issparse(weights):  # no N x N array (a networkx graph still costs ~1 kB a link)
        src, dst = links_from_weights(weights)
        graph.add_edges_from(zip(src.tolist(), dst.tolist(), strict=True))
        return graph
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
    if weights.shape[0] > 1 and not _strongly_connected_dense(weights > 0):
        graph = graph_from_weights(weights)
        components = sorted(nx.strongly_connected_components(graph), key=min)
        raise NetworkError(
            f"{name}: the communication graph is not strongly connected "
            f"({len(components)} strongly connected components, e.g. {sorted(components[0])})"
        )


def _strongly_connected_dense(adjacency: np.ndarray) -> bool:
    """Whether the digraph of a dense boolean adjacency matrix is strongly connected:
    every node reached from node 0 along the edges and against them (breadth-first,
    each node's row read once: O(N^2); networkx is not imported)."""
    n = adjacency.shape[0]
    for M in (adjacency, adjacency.T):
        seen = np.zeros(n, dtype=bool)
        seen[0] = True
        frontier = seen.copy()
        while frontier.any():
            frontier = M[frontier].any(axis=0) & ~seen
            seen |= frontier
        if not seen.all():
            return False
    return True


def check_sparse_consensus_matrix(weights: sp.csr_array, name: str = "P") -> None:
    """:func:`check_consensus_matrix` on a sparse matrix, O(N + nnz).

    The same properties and messages: square, finite, nonnegative, row sums 1,
    positive self-weights (the stored diagonal), strong connectivity
    (``scipy.sparse.csgraph.connected_components(connection="strong")``).
    """
    P = sp.csr_array(weights)
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise NetworkError(f"{name}: expected a square N x N matrix, got shape {P.shape}")
    coo = P.tocoo()
    bad = ~np.isfinite(coo.data)
    if bad.any():
        q = int(np.flatnonzero(bad)[0])
        raise NetworkError(f"{name}[{coo.row[q]}][{coo.col[q]}] is not finite ({coo.data[q]})")
    neg = coo.data < 0
    if neg.any():
        q = int(np.flatnonzero(neg)[0])
        raise NetworkError(f"{name}[{coo.row[q]}][{coo.col[q]}] = {coo.data[q]} is negative")
    sums = np.asarray(P.sum(axis=1)).ravel()
    badrow = np.flatnonzero(np.abs(sums - 1.0) > ROW_SUM_TOLERANCE)
    if badrow.size:
        i = int(badrow[0])
        raise NetworkError(
            f"{name} is not row-stochastic: row {i} sums to {sums[i]:.12g}, expected 1"
        )
    diag = P.diagonal()
    zero_diag = np.flatnonzero(diag <= 0)
    if zero_diag.size:
        i = int(zero_diag[0])
        raise NetworkError(f"{name}[{i}][{i}] is {diag[i]}: self-weights must be positive")
    n_agents = P.shape[0]
    if n_agents > 1:
        src, dst = links_from_weights(P)
        ok, count = strongly_connected(n_agents, src, dst)
        if not ok:
            adjacency = sp.csr_array((np.ones(len(src), dtype=np.int8), (src, dst)),
                                     shape=(n_agents, n_agents))
            from scipy.sparse.csgraph import connected_components

            _, labels = connected_components(adjacency, directed=True, connection="strong")
            first = np.flatnonzero(labels == labels[0])
            raise NetworkError(
                f"{name}: the communication graph is not strongly connected "
                f"({count} strongly connected components, e.g. {first.tolist()[:20]})"
            )
