"""Observability tests: numerical, local, distributed and structural (generic-rank).

Numerical tests
    * :func:`is_observable` -- PBH (Popov-Belevitch-Hautus) eigenvalue test
      ``rank [A - lambda I; C] = n`` for every eigenvalue ``lambda`` of ``A``, with an
      SVD rank decision and a relative tolerance. This is the robust test; the Kalman
      rank of :func:`observability_matrix` (:func:`observability_rank`) is reported
      too but it is ill-conditioned for larger ``n`` (Vandermonde-like powers of A).
    * :func:`local_observability` -- ``(A, [C_j]_{j in {i} u N_i})`` per agent
      (LCSYS2022 Remark 1; delay-tolerant paper Assumption 3: *not* assumed).
    * :func:`distributed_observability` -- ``(P kron A, D_C-bar)`` with
      ``D_C-bar = blockdiag(C_i^T C_i)`` (LCSYS2022 Section III, Lemma 1).

Structural (generic-rank) tests, structured systems theory (LCSYS2022 footnote 3)
    * :func:`structural_rank` -- maximum bipartite matching of a sparsity pattern.
    * :func:`is_structurally_observable` -- output-connectedness plus no contraction
      (generic rank of the pattern of ``[A; C]`` equals ``n``).
    * :func:`is_structurally_distributed_observable` -- the same on the Kronecker
      pattern of ``P kron A`` with the network output matrix, and
      :func:`lemma1_conditions` -- the sufficient conditions of LCSYS2022 Lemma 1
      (A full-rank, (A, C) observable, P irreducible and self-damped).

Conventions
    The *system digraph* of a square matrix ``M`` has the edge ``j -> i`` whenever
    ``M[i, j] != 0`` (state ``j`` drives state ``i``). For a consensus matrix ``P`` this
    is exactly the communication graph of :mod:`netsim.models.network` (edge ``(j, i)``:
    ``i`` receives from ``j``), with self-loops for the diagonal. A sparsity pattern is
    ``|M| > atol`` with ``atol = DEFAULT_PATTERN_ATOL = 0`` (exact zeros) by default.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from netsim.models.lazy import is_digraph, lazy_module
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    import networkx as nx
else:  # imported on first use (start-up latency): the structural tests need it
    nx = lazy_module("networkx")

__all__ = [
    "DEFAULT_RTOL",
    "DEFAULT_PATTERN_ATOL",
    "ObservabilityReport",
    "observability_matrix",
    "observability_rank",
    "is_observable",
    "unobservable_modes",
    "local_observability",
    "distributed_output_matrix",
    "distributed_observability",
    "sparsity_pattern",
    "system_digraph",
    "structural_rank",
    "output_unreachable_states",
    "is_output_connected",
    "is_structurally_observable",
    "kronecker_pattern",
    "is_structurally_distributed_observable",
    "lemma1_conditions",
    "satisfies_lemma1",
    "is_full_rank",
    "is_structurally_full_rank",
    "is_self_damped",
    "is_self_damped_network",
    "is_irreducible",
    "irreducible_blocks",
    "observability_report",
]

#: Relative singular-value threshold of every numerical rank decision (PBH, Kalman,
#: full rank). A singular value ``s`` counts as zero when ``s <= rtol * scale``.
DEFAULT_RTOL: float = 1e-8
#: Entries with ``|M[i, j]| <= DEFAULT_PATTERN_ATOL`` are structural zeros.
DEFAULT_PATTERN_ATOL: float = 0.0
#: Above this many states :func:`unobservable_modes` screens the eigenvalues with one
#: eigendecomposition and runs the exact singular-value test only where in doubt.
_PBH_SVD_MAX_STATES = 60
#: Screening: an isolated eigenvalue with ``||C_s v||`` below this (unit eigenvector
#: ``v``, unit-norm ``C_s``) still gets the exact singular-value test.
_PBH_DOUBT = 1e-3
#: Screening: eigenvalues of ``A_s`` closer than this are tested as a cluster.
_PBH_CLUSTER = 1e-4


# ---------------------------------------------------------------------------
# input handling
# ---------------------------------------------------------------------------


def _square(M: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(M)
    arr = arr.astype(complex if np.iscomplexobj(arr) else float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.shape[0] == 0:
        raise ValueError(f"{name} must be a non-empty square matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite entries")
    return arr


def _output(C: ArrayLike, n: int, name: str = "C") -> np.ndarray:
    arr = np.asarray(C)
    arr = arr.astype(complex if np.iscomplexobj(arr) else float)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2 or arr.shape[1] != n:
        raise ValueError(f"{name} must have shape (m, {n}), got {np.asarray(C).shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite entries")
    return arr


def _outputs(C_list: Sequence[ArrayLike], n: int) -> list[np.ndarray]:
    if isinstance(C_list, np.ndarray) and C_list.ndim == 2:
        raise ValueError("C_list must be a sequence of per-agent output matrices, not one array")
    out = [_output(Ci, n, f"C_list[{i}]") for i, Ci in enumerate(C_list)]
    if not out:
        raise ValueError("C_list must contain at least one output matrix")
    return out


def _weights(P: ArrayLike, n_agents: int) -> np.ndarray:
    arr = _square(P, "P")
    if arr.shape[0] != n_agents:
        raise ValueError(
            f"P is {arr.shape[0]} x {arr.shape[0]} but C_list has {n_agents} output matrices"
        )
    return arr


def _normalise(M: np.ndarray) -> np.ndarray:
    norm = float(np.linalg.norm(M, 2))
    return M / norm if norm > 0.0 else M


# ---------------------------------------------------------------------------
# numerical observability
# ---------------------------------------------------------------------------


def observability_matrix(A: ArrayLike, C: ArrayLike) -> np.ndarray:
    """Return the Kalman observability matrix ``[C; C A; ...; C A^{n-1}]``.

    Parameters
    ----------
    A : array_like, shape (n, n)
        System matrix.
    C : array_like, shape (m, n) or (n,)
        Output matrix (a 1-D array is one output row).

    Returns
    -------
    numpy.ndarray, shape (m n, n)

    Notes
    -----
    The powers of ``A`` make this matrix ill-conditioned for larger ``n``; use
    :func:`is_observable` (PBH) to decide observability.
    """
    A_arr = _square(A, "A")
    n = A_arr.shape[0]
    C_arr = _output(C, n)
    blocks = [C_arr]
    for _ in range(n - 1):
        blocks.append(blocks[-1] @ A_arr)
    return np.vstack(blocks)


def observability_rank(A: ArrayLike, C: ArrayLike, rtol: float = DEFAULT_RTOL) -> int:
    """Numerical rank of the Kalman observability matrix (reported, not decisive).

    ``A`` and ``C`` are first divided by their spectral norms (this scales the block
    rows of the observability matrix and does not change its rank), then the rank is
    the number of singular values above ``rtol * sigma_max``.

    Parameters
    ----------
    A : array_like, shape (n, n)
        System matrix.
    C : array_like, shape (m, n) or (n,)
        Output matrix.
    rtol : float, default DEFAULT_RTOL
        Relative singular-value threshold.

    Returns
    -------
    int
        Between 0 and ``n``. For larger ``n`` this can under-estimate the true rank
        (ill-conditioning); :func:`is_observable` is the robust test.
    """
    A_arr = _square(A, "A")
    C_arr = _output(C, A_arr.shape[0])
    obs = observability_matrix(_normalise(A_arr), _normalise(C_arr))
    s = np.linalg.svd(obs, compute_uv=False)
    if s.size == 0 or s[0] == 0.0:
        return 0
    return int(np.sum(s > rtol * s[0]))


def _screened_candidates(A_s: np.ndarray, C_s: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Eigenvalues of ``A_s`` and the indices that still need the exact PBH test.

    One eigendecomposition decides the clearly observable eigenvalues: an isolated
    eigenvalue with ``||C_s v|| >= _PBH_DOUBT`` for its unit eigenvector ``v``, or a
    cluster of eigenvalues (closer than ``_PBH_CLUSTER``) whose eigenvectors have full
    numerical rank and span a subspace ``Q`` with ``sigma_min(C_s Q) >= _PBH_DOUBT``
    (every eigenvector of the cluster lies in that subspace). Everything else (weakly
    observable, or a cluster with numerically dependent eigenvectors, i.e. close to
    defective) is returned as a candidate. ``A_s`` and ``C_s`` have unit spectral norm
    (or are zero).
    """
    k = A_s.shape[0]
    lams, V = np.linalg.eig(A_s)
    V = V / np.linalg.norm(V, axis=0)
    dv = np.linalg.norm(C_s @ V, axis=0)
    close = np.abs(lams[:, None] - lams[None, :]) <= _PBH_CLUSTER
    # clusters = connected components of the "close" relation
    label = np.arange(k)
    for i, j in np.argwhere(np.triu(close, 1)):
        a, b = label[i], label[j]
        if a != b:
            label[label == b] = a
    candidates: list[int] = []
    for lab in np.unique(label):
        members = np.flatnonzero(label == lab)
        if members.size == 1:
            if dv[members[0]] < _PBH_DOUBT:
                candidates.append(int(members[0]))
            continue
        Vc = V[:, members]
        sv = np.linalg.svd(Vc, compute_uv=False)
        if sv[-1] > 1e-6 * sv[0]:
            Q = np.linalg.qr(Vc)[0]
            if np.linalg.svd(C_s @ Q, compute_uv=False)[-1] >= _PBH_DOUBT:
                continue
        candidates.extend(int(m) for m in members)
    return lams, candidates


def _distinct(values: list[complex], atol: float) -> list[complex]:
    """``values`` with entries within ``atol`` of an earlier kept entry dropped."""
    kept: list[complex] = []
    for z in values:
        if not any(abs(z - w) <= atol for w in kept):
            kept.append(z)
    return kept


def unobservable_modes(
    A: ArrayLike, C: ArrayLike, rtol: float = DEFAULT_RTOL, *, distinct: bool = False
) -> list[complex]:
    """Eigenvalues of ``A`` that fail the PBH rank test with output ``C``.

    ``lambda`` is unobservable when ``sigma_min([A_s - lambda_s I; C_s]) <= rtol``,
    with ``A_s = A / ||A||_2``, ``lambda_s = lambda / ||A||_2`` and ``C_s = C / ||C||_2``
    (the test is invariant to scaling ``A`` or ``C``, so the tolerance is relative).
    Up to ``_PBH_SVD_MAX_STATES`` (60) states every computed eigenvalue is tested (for
    real data only one of each conjugate pair); for defective eigenvalues the
    perturbation of the computed eigenvalue is ``O(eps^(1/k))`` but
    ``sigma_min(A - lambda_hat I)`` stays ``O(eps)``. Above 60 states (e.g. the
    ``(N n, N n)`` pair of :func:`distributed_observability`) one eigendecomposition
    first clears the clearly observable eigenvalues (isolated ones with
    ``||C_s v|| >= 1e-3`` for the unit eigenvector ``v``; clusters closer than
    ``1e-4`` whose eigenvector subspace ``Q`` has ``sigma_min(C_s Q) >= 1e-3``), and
    only the rest get the exact singular-value test, once per numerically distinct
    eigenvalue: ``N = 200``, ``n = 6`` takes seconds instead of hours.

    Parameters
    ----------
    A : array_like, shape (n, n)
        System matrix.
    C : array_like, shape (m, n) or (n,)
        Output matrix.
    rtol : float, default DEFAULT_RTOL
        Relative singular-value threshold.
    distinct : bool, default False
        Merge numerically repeated eigenvalues (within ``rtol * ||A||_2``) into one
        entry, e.g. to count the distinct unobservable modes.

    Returns
    -------
    list of complex
        Unobservable eigenvalues of ``A`` (in the scale of ``A``), possibly with
        numerically repeated entries unless ``distinct``; empty iff ``(A, C)`` is
        observable.
    """
    A_arr = _square(A, "A")
    n = A_arr.shape[0]
    C_arr = _output(C, n)
    a_norm = float(np.linalg.norm(A_arr, 2))
    a_scale = a_norm if a_norm > 0.0 else 1.0
    A_s = A_arr / a_scale
    C_s = _normalise(C_arr)
    real = not (np.iscomplexobj(A_arr) or np.iscomplexobj(C_arr))
    if n <= _PBH_SVD_MAX_STATES:
        lams = np.linalg.eigvals(A_s)
        candidates = list(range(n))
        screened = False
    else:
        lams, candidates = _screened_candidates(A_s, C_s)
        screened = True
    eye = np.eye(n)
    bad: list[complex] = []
    tested: list[complex] = []
    for idx in candidates:
        lam = lams[idx]
        if real and lam.imag < 0.0:
            continue  # conjugate of a tested eigenvalue: same singular values
        if screened:
            if any(abs(lam - mu) <= rtol for mu in tested):
                continue  # numerically repeated eigenvalue, already tested
            tested.append(complex(lam))
        smin = np.linalg.svd(np.vstack([A_s - lam * eye, C_s]), compute_uv=False)[-1]
        if smin <= rtol:
            bad.append(complex(lam) * a_scale)
            if real and lam.imag > 0.0:
                bad.append(complex(lam).conjugate() * a_scale)
    if distinct:
        bad = _distinct(bad, rtol * a_scale)
    return bad


def is_observable(A: ArrayLike, C: ArrayLike, rtol: float = DEFAULT_RTOL) -> bool:
    """PBH test: ``rank [A - lambda I; C] = n`` for every eigenvalue ``lambda`` of A.

    Global observability of LCSYS2022 Assumption 1 is ``is_observable(A, vstack(C_i))``.

    Parameters
    ----------
    A : array_like, shape (n, n)
        System matrix.
    C : array_like, shape (m, n) or (n,)
        Output matrix.
    rtol : float, default DEFAULT_RTOL
        Relative singular-value threshold (see :func:`unobservable_modes`).

    Returns
    -------
    bool
    """
    return not unobservable_modes(A, C, rtol)


def _in_neighbourhoods(P_or_graph: ArrayLike | nx.DiGraph, n_agents: int) -> list[list[int]]:
    if is_digraph(P_or_graph):
        graph = cast("nx.DiGraph", P_or_graph)
        if sorted(graph.nodes) != list(range(n_agents)):
            raise ValueError(f"graph nodes must be 0..{n_agents - 1} (one per output matrix)")
        return [
            [i, *sorted(j for j in graph.predecessors(i) if j != i)]
            for i in range(n_agents)
        ]
    P = _weights(cast("ArrayLike", P_or_graph), n_agents)
    return [
        [i, *(int(j) for j in np.flatnonzero(P[i] != 0) if j != i)] for i in range(n_agents)
    ]


def local_observability(
    A: ArrayLike,
    C_list: Sequence[ArrayLike],
    P_or_graph: ArrayLike | nx.DiGraph,
    rtol: float = DEFAULT_RTOL,
) -> list[bool]:
    """Observability in each agent's closed in-neighbourhood (LCSYS2022 Remark 1).

    Agent ``i`` is locally observable when ``(A, [C_j; j in {i} u N_i])`` is
    observable, with ``N_i = {j | (j, i) in E}`` the in-neighbours of ``i``. LCSYS2022
    Remark 1 (and Assumption 3 of the delay-tolerant paper) does *not* assume this.

    Parameters
    ----------
    A : array_like, shape (n, n)
        System matrix.
    C_list : sequence of array_like, length N
        ``C_list[i]`` has shape ``(m_i, n)``.
    P_or_graph : array_like, shape (N, N), or networkx.DiGraph
        Consensus matrix (``P[i, j] != 0``, ``j != i``: ``j`` is an in-neighbour of
        ``i``) or communication graph on nodes ``0..N-1`` (edge ``(j, i)``: ``i``
        receives from ``j``).
    rtol : float, default DEFAULT_RTOL
        PBH tolerance.

    Returns
    -------
    list of bool, length N
    """
    A_arr = _square(A, "A")
    C_arr = _outputs(C_list, A_arr.shape[0])
    hoods = _in_neighbourhoods(P_or_graph, len(C_arr))
    return [is_observable(A_arr, np.vstack([C_arr[j] for j in hood]), rtol) for hood in hoods]


def distributed_output_matrix(C_list: Sequence[ArrayLike]) -> np.ndarray:
    """Return ``D_C-bar = D_C^T D_C = blockdiag(C_i^T C_i)`` (LCSYS2022 eq. 10).

    Parameters
    ----------
    C_list : sequence of array_like, length N
        ``C_list[i]`` has shape ``(m_i, n)`` (all with the same ``n``).

    Returns
    -------
    numpy.ndarray, shape (N n, N n)
    """
    if not len(C_list):
        raise ValueError("C_list must contain at least one output matrix")
    n = np.atleast_2d(np.asarray(C_list[0])).shape[1]
    C_arr = _outputs(C_list, n)
    from scipy.linalg import block_diag

    return block_diag(*[Ci.conj().T @ Ci for Ci in C_arr])


def distributed_observability(
    P: ArrayLike, A: ArrayLike, C_list: Sequence[ArrayLike], rtol: float = DEFAULT_RTOL
) -> bool:
    """Distributed observability: ``(P kron A, D_C-bar)`` observable (LCSYS2022 Lemma 1).

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C_list : sequence of array_like, length N
        ``C_list[i]`` has shape ``(m_i, n)``.
    rtol : float, default DEFAULT_RTOL
        PBH tolerance.

    Returns
    -------
    bool
        PBH test on the ``(N n, N n)`` pair; this is the condition for a gain ``K``
        with ``rho(P kron A - K D_C-bar (P kron A)) < 1`` (Corollary 1).
    """
    A_arr = _square(A, "A")
    C_arr = _outputs(C_list, A_arr.shape[0])
    P_arr = _weights(P, len(C_arr))
    return is_observable(np.kron(P_arr, A_arr), distributed_output_matrix(C_arr), rtol)


# ---------------------------------------------------------------------------
# structural (generic-rank) observability
# ---------------------------------------------------------------------------


def sparsity_pattern(M: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> np.ndarray:
    """Boolean sparsity pattern ``|M| > atol`` (a boolean input is returned as is).

    Parameters
    ----------
    M : array_like, shape (p, q)
    atol : float, default DEFAULT_PATTERN_ATOL
        Entries with modulus at most ``atol`` are structural zeros.

    Returns
    -------
    numpy.ndarray of bool, shape (p, q)
    """
    arr = np.asarray(M)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2:
        raise ValueError(f"a pattern must be a 2-D array, got shape {arr.shape}")
    if arr.dtype == bool:
        return arr.copy()
    return np.abs(arr) > atol


def system_digraph(A: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> nx.DiGraph:
    """System digraph of ``A``: nodes ``0..n-1``, edge ``j -> i`` iff ``A[i, j] != 0``.

    Parameters
    ----------
    A : array_like, shape (n, n)
        Matrix or boolean pattern.
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    networkx.DiGraph
        Including self-loops for non-zero diagonal entries.
    """
    pat = sparsity_pattern(A, atol)
    if pat.shape[0] != pat.shape[1]:
        raise ValueError(f"the system digraph needs a square matrix, got shape {pat.shape}")
    graph: nx.DiGraph[int] = nx.DiGraph()
    graph.add_nodes_from(range(pat.shape[0]))
    rows, cols = np.nonzero(pat)
    graph.add_edges_from((int(j), int(i)) for i, j in zip(rows, cols, strict=True))
    return graph


def structural_rank(pattern: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> int:
    """Generic rank of a sparsity pattern: size of a maximum bipartite matching.

    The rank of a matrix with the given zero pattern whose non-zero entries are
    independent parameters equals the maximum number of non-zeros no two of which
    share a row or a column, for almost all parameter values (Konig / Hall; the
    rows-columns bipartite graph is matched with Hopcroft-Karp).

    Parameters
    ----------
    pattern : array_like, shape (p, q)
        Boolean pattern or numerical matrix (its pattern ``|M| > atol`` is used).
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    int
        Between 0 and ``min(p, q)``; an upper bound on the rank of every matrix with
        that pattern, attained generically.
    """
    pat = sparsity_pattern(pattern, atol)
    p, q = pat.shape
    graph: nx.Graph[tuple[str, int]] = nx.Graph()
    rows = [("r", i) for i in range(p)]
    graph.add_nodes_from(rows, bipartite=0)
    graph.add_nodes_from((("c", j) for j in range(q)), bipartite=1)
    ii, jj = np.nonzero(pat)
    graph.add_edges_from((("r", int(i)), ("c", int(j))) for i, j in zip(ii, jj, strict=True))
    matching = nx.bipartite.hopcroft_karp_matching(graph, top_nodes=rows)
    return len(matching) // 2


def output_unreachable_states(
    A: ArrayLike, C: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL
) -> list[int]:
    """States with no path to a measured state in the system digraph of ``A``.

    A state ``k`` is measured when column ``k`` of ``C`` has a non-zero. State ``j``
    reaches it when there is a path ``j -> ... -> k`` (edge ``j -> i`` iff
    ``A[i, j] != 0``).

    Parameters
    ----------
    A : array_like, shape (n, n)
        Matrix or boolean pattern.
    C : array_like, shape (m, n) or (n,)
        Output matrix or boolean pattern.
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    list of int
        Sorted; empty iff ``(A, C)`` is output-connected.
    """
    A_pat = sparsity_pattern(A, atol)
    C_pat = sparsity_pattern(C, atol)
    n = A_pat.shape[0]
    if A_pat.shape != (n, n) or C_pat.shape[1] != n:
        raise ValueError(f"A must be square and C have n columns, got {A_pat.shape}, {C_pat.shape}")
    graph = system_digraph(A_pat)
    reaching: set[int] = set()
    for k in np.flatnonzero(C_pat.any(axis=0)):
        if int(k) not in reaching:
            reaching |= nx.ancestors(graph, int(k)) | {int(k)}
    return [k for k in range(n) if k not in reaching]


def is_output_connected(A: ArrayLike, C: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> bool:
    """Whether every state has a path to some measured state (no unreachable state).

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (m, n) or (n,)
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    bool
    """
    return not output_unreachable_states(A, C, atol)


def is_structurally_observable(
    A: ArrayLike, C: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL
) -> bool:
    """Structural observability of the pattern pair ``(A, C)`` (Lin's conditions, dual).

    ``(A, C)`` is structurally observable -- observable for almost all values of its
    non-zero entries (LCSYS2022 footnote 3) -- iff

    (i) every state has a path to a measured state in the system digraph
        (:func:`is_output_connected`), and
    (ii) there is no contraction: ``structural_rank([A; C]) = n``.

    Parameters
    ----------
    A : array_like, shape (n, n)
        Matrix or boolean pattern.
    C : array_like, shape (m, n) or (n,)
        Output matrix or boolean pattern.
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    bool
    """
    A_pat = sparsity_pattern(A, atol)
    C_pat = sparsity_pattern(C, atol)
    n = A_pat.shape[0]
    if A_pat.shape != (n, n) or C_pat.shape[1] != n:
        raise ValueError(f"A must be square and C have n columns, got {A_pat.shape}, {C_pat.shape}")
    return (
        is_output_connected(A_pat, C_pat)
        and structural_rank(np.vstack([A_pat, C_pat])) == n
    )


def kronecker_pattern(
    P: ArrayLike, A: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL
) -> np.ndarray:
    """Sparsity pattern of ``P kron A``, shape ``(N n, N n)``.

    Parameters
    ----------
    P : array_like, shape (N, N)
    A : array_like, shape (n, n)
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    numpy.ndarray of bool, shape (N n, N n)
        Entry ``(i n + k, j n + l)`` is True iff ``P[i, j] != 0`` and ``A[k, l] != 0``.
    """
    return np.kron(sparsity_pattern(P, atol), sparsity_pattern(A, atol)).astype(bool)


def _network_output_pattern(C_list: Sequence[ArrayLike], n: int, atol: float) -> np.ndarray:
    from scipy.linalg import block_diag

    return block_diag(*[sparsity_pattern(_output(Ci, n, f"C_list[{i}]"), atol)
                        for i, Ci in enumerate(C_list)]).astype(bool)


def is_structurally_distributed_observable(
    P: ArrayLike, A: ArrayLike, C_list: Sequence[ArrayLike], atol: float = DEFAULT_PATTERN_ATOL
) -> bool:
    """Structural observability of ``(P kron A, D_C-bar)`` (LCSYS2022 Lemma 1, [26]).

    :func:`is_structurally_observable` applied to the pattern of ``P kron A``
    (:func:`kronecker_pattern`) and the network output pattern. The row space of
    ``D_C-bar = D_C^T D_C`` equals that of ``D_C = blockdiag(C_i)``, so the two pairs
    are observable together; the pattern of ``D_C`` is used because ``C_i^T C_i`` has
    rank ``m_i`` and its entries are not independent (its pattern can overstate the
    generic rank).

    The entries of ``P kron A`` are products ``p_ij a_kl``, not independent
    parameters, and row-stochasticity constrains ``P`` further (a row with one
    non-zero is exactly a unit vector). Hence the result is

    * necessary: ``False`` means ``(P kron A, D_C-bar)`` is unobservable for *every*
      choice of values with these patterns;
    * sufficient for almost all values only under extra conditions, e.g. those of
      Lemma 1 / [26, Th. 4] (:func:`lemma1_conditions`). Without them it can
      over-claim (e.g. ``A`` not structurally full rank, or repeated unit rows in
      ``P``): check :func:`distributed_observability` on the actual values.

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix or pattern.
    A : array_like, shape (n, n)
        System matrix or pattern.
    C_list : sequence of array_like, length N
        ``C_list[i]`` has shape ``(m_i, n)``.
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    bool
    """
    A_pat = sparsity_pattern(A, atol)
    n = A_pat.shape[0]
    P_pat = sparsity_pattern(P, atol)
    if P_pat.shape != (len(C_list), len(C_list)):
        raise ValueError(f"P has shape {P_pat.shape} but C_list has {len(C_list)} matrices")
    return is_structurally_observable(
        kronecker_pattern(P_pat, A_pat), _network_output_pattern(C_list, n, atol)
    )


def is_full_rank(A: ArrayLike, rtol: float = DEFAULT_RTOL) -> bool:
    """Numerical full rank, ``det(A) != 0``: ``sigma_min(A) > rtol * sigma_max(A)``.

    Equivalent to ``cond_2(A) < 1 / rtol`` (LCSYS2022 Section II assumes
    ``det(A) != 0``).

    Parameters
    ----------
    A : array_like, shape (n, n)
    rtol : float, default DEFAULT_RTOL

    Returns
    -------
    bool
    """
    s = np.linalg.svd(_square(A, "A"), compute_uv=False)
    return bool(s[0] > 0.0 and s[-1] > rtol * s[0])


def is_structurally_full_rank(A: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> bool:
    """Structural full rank (structurally cyclic): the pattern has a perfect matching.

    Equivalently the system digraph is covered by disjoint cycles (self-loops
    included) [25]; generically ``det(A) != 0``.

    Parameters
    ----------
    A : array_like, shape (n, n)
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    bool
    """
    pat = sparsity_pattern(A, atol)
    if pat.shape[0] != pat.shape[1]:
        raise ValueError(f"A must be square, got shape {pat.shape}")
    return structural_rank(pat) == pat.shape[0]


def is_self_damped(A: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> bool:
    """Self-damped system: every diagonal entry of ``A`` is non-zero (LCSYS2022 fn. 1).

    Self-damped implies structurally full rank (the diagonal is a perfect matching).

    Parameters
    ----------
    A : array_like, shape (n, n)
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    bool
    """
    pat = sparsity_pattern(A, atol)
    if pat.shape[0] != pat.shape[1]:
        raise ValueError(f"A must be square, got shape {pat.shape}")
    return bool(np.all(np.diag(pat)))


def is_self_damped_network(P: ArrayLike) -> bool:
    """Self-damped network: a self-link at every node, ``P[i, i] > 0`` (LCSYS2022 fn. 1).

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.

    Returns
    -------
    bool
    """
    P_arr = _square(P, "P")
    return bool(np.all(np.real(np.diag(P_arr)) > 0.0))


def is_irreducible(M: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> bool:
    """Irreducibility: the system digraph of ``M`` is strongly connected.

    For a consensus matrix this is the strong connectivity of the network
    (LCSYS2022 Section II-B). A 1 x 1 matrix counts as irreducible.

    Parameters
    ----------
    M : array_like, shape (N, N)
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    bool
    """
    return bool(nx.is_strongly_connected(system_digraph(M, atol)))


def irreducible_blocks(A: ArrayLike, atol: float = DEFAULT_PATTERN_ATOL) -> list[list[int]]:
    """Irreducible blocks of ``A``: strongly connected components of its system digraph.

    Ordered topologically (a block comes before every block it drives, ties broken by
    smallest state index), so permuting ``A`` accordingly gives a block lower
    triangular form. LCSYS2022 Section II: one output in every irreducible block
    (sufficient; every *sink* block suffices) gives output-connectedness.

    Parameters
    ----------
    A : array_like, shape (n, n)
        Matrix or boolean pattern.
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    list of list of int
        Each block sorted; the blocks partition ``0..n-1``.
    """
    graph = system_digraph(A, atol)
    condensed = nx.condensation(graph)
    members = condensed.graph["mapping"]
    blocks: dict[int, list[int]] = {}
    for state, block in members.items():
        blocks.setdefault(block, []).append(state)
    order = nx.lexicographical_topological_sort(condensed, key=lambda b: min(blocks[b]))
    return [sorted(blocks[b]) for b in order]


def lemma1_conditions(
    P: ArrayLike,
    A: ArrayLike,
    C_list: Sequence[ArrayLike],
    atol: float = DEFAULT_PATTERN_ATOL,
) -> dict[str, bool]:
    """Sufficient conditions of LCSYS2022 Lemma 1 for structural distributed observability.

    Lemma 1 ([26, Th. 4]): for full-rank ``A`` with ``(A, C)`` (structurally)
    observable, ``(P kron A, D_C-bar)`` is structurally observable if ``P`` is
    irreducible and self-damped (``p_ii != 0``).

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C_list : sequence of array_like, length N
        ``C_list[i]`` has shape ``(m_i, n)``.
    atol : float, default DEFAULT_PATTERN_ATOL

    Returns
    -------
    dict of str to bool
        ``A_structurally_full_rank``, ``AC_structurally_observable``,
        ``P_irreducible``, ``P_self_damped`` (pattern-based: ``P[i, i] != 0``).
    """
    A_pat = sparsity_pattern(A, atol)
    n = A_pat.shape[0]
    C_pat = np.vstack([sparsity_pattern(_output(Ci, n, f"C_list[{i}]"), atol)
                       for i, Ci in enumerate(C_list)])
    P_pat = sparsity_pattern(P, atol)
    return {
        "A_structurally_full_rank": is_structurally_full_rank(A_pat),
        "AC_structurally_observable": is_structurally_observable(A_pat, C_pat),
        "P_irreducible": is_irreducible(P_pat),
        "P_self_damped": is_self_damped(P_pat),
    }


def satisfies_lemma1(
    P: ArrayLike,
    A: ArrayLike,
    C_list: Sequence[ArrayLike],
    atol: float = DEFAULT_PATTERN_ATOL,
) -> bool:
    """Whether every condition of :func:`lemma1_conditions` holds."""
    return all(lemma1_conditions(P, A, C_list, atol).values())


# ---------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ObservabilityReport:
    """Observability properties of ``(P, A, C_list)`` (LCSYS2022 Sections II-III).

    Attributes
    ----------
    n_states, n_agents, n_outputs : int
        ``n``, ``N`` and ``sum_i m_i``.
    spectral_radius : float
        ``rho(A)`` (also ``rho(P kron A)`` for row-stochastic ``P``).
    observable : bool
        PBH test of ``(A, C)``, ``C = vstack(C_i)`` (Assumption 1, global).
    unobservable_modes : tuple of complex
        Eigenvalues of ``A`` failing the PBH test.
    kalman_rank : int
        Numerical rank of the observability matrix (reported; ill-conditioned).
    sensor_observable : tuple of bool, length N
        ``(A, C_i)`` observable per sensor (not assumed, Assumption 1).
    locally_observable : tuple of bool, length N
        Neighbourhood observability per agent (not assumed, Remark 1).
    distributed_observable : bool
        PBH test of ``(P kron A, D_C-bar)`` (Lemma 1).
    full_rank, structurally_full_rank, self_damped : bool
        Properties of ``A`` (Section II, footnote 1).
    network_self_damped, network_irreducible : bool
        ``P[i, i] > 0`` for all ``i``; ``P`` irreducible.
    irreducible_blocks : tuple of tuple of int
        Topologically sorted strongly connected components of ``A``'s digraph.
    output_unreachable_states : tuple of int
        States with no path to a measured state.
    structural_rank_AC : int
        Generic rank of the pattern of ``[A; C]``.
    structurally_observable : bool
        Structural observability of ``(A, C)``.
    structurally_distributed_observable : bool
        Structural test on the pattern of ``(P kron A, D_C)``.
    lemma1_satisfied : bool
        All sufficient conditions of Lemma 1 hold.
    """

    n_states: int
    n_agents: int
    n_outputs: int
    spectral_radius: float
    observable: bool
    unobservable_modes: tuple[complex, ...]
    kalman_rank: int
    sensor_observable: tuple[bool, ...]
    locally_observable: tuple[bool, ...]
    distributed_observable: bool
    full_rank: bool
    structurally_full_rank: bool
    self_damped: bool
    network_self_damped: bool
    network_irreducible: bool
    irreducible_blocks: tuple[tuple[int, ...], ...]
    output_unreachable_states: tuple[int, ...]
    structural_rank_AC: int
    structurally_observable: bool
    structurally_distributed_observable: bool
    lemma1_satisfied: bool

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dict (complex modes as ``[re, im]`` pairs)."""
        out = asdict(self)
        out["unobservable_modes"] = [[z.real, z.imag] for z in self.unobservable_modes]
        for key in ("sensor_observable", "locally_observable", "output_unreachable_states"):
            out[key] = list(out[key])
        out["irreducible_blocks"] = [list(b) for b in self.irreducible_blocks]
        return out


def observability_report(
    P: ArrayLike,
    A: ArrayLike,
    C_list: Sequence[ArrayLike],
    rtol: float = DEFAULT_RTOL,
    atol: float = DEFAULT_PATTERN_ATOL,
) -> ObservabilityReport:
    """Collect every observability property of ``(P, A, C_list)``.

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C_list : sequence of array_like, length N
        ``C_list[i]`` has shape ``(m_i, n)``.
    rtol : float, default DEFAULT_RTOL
        Numerical rank tolerance.
    atol : float, default DEFAULT_PATTERN_ATOL
        Structural-zero threshold.

    Returns
    -------
    ObservabilityReport
    """
    A_arr = _square(A, "A")
    n = A_arr.shape[0]
    C_arr = _outputs(C_list, n)
    P_arr = _weights(P, len(C_arr))
    C = np.vstack(C_arr)
    modes = unobservable_modes(A_arr, C, rtol)
    A_pat = sparsity_pattern(A_arr, atol)
    C_pat = sparsity_pattern(C, atol)
    return ObservabilityReport(
        n_states=n,
        n_agents=len(C_arr),
        n_outputs=C.shape[0],
        spectral_radius=float(np.max(np.abs(np.linalg.eigvals(A_arr)))),
        observable=not modes,
        unobservable_modes=tuple(complex(z) for z in modes),
        kalman_rank=observability_rank(A_arr, C, rtol),
        sensor_observable=tuple(is_observable(A_arr, Ci, rtol) for Ci in C_arr),
        locally_observable=tuple(local_observability(A_arr, C_arr, P_arr, rtol)),
        distributed_observable=distributed_observability(P_arr, A_arr, C_arr, rtol),
        full_rank=is_full_rank(A_arr, rtol),
        structurally_full_rank=is_structurally_full_rank(A_pat),
        self_damped=is_self_damped(A_pat),
        network_self_damped=is_self_damped_network(P_arr),
        network_irreducible=is_irreducible(P_arr, atol),
        irreducible_blocks=tuple(tuple(b) for b in irreducible_blocks(A_pat)),
        output_unreachable_states=tuple(output_unreachable_states(A_pat, C_pat)),
        structural_rank_AC=structural_rank(np.vstack([A_pat, C_pat])),
        structurally_observable=is_structurally_observable(A_pat, C_pat),
        structurally_distributed_observable=is_structurally_distributed_observable(
            P_arr, A_arr, C_arr, atol
        ),
        lemma1_satisfied=satisfies_lemma1(P_arr, A_arr, C_arr, atol),
    )
