"""Augmented-matrix analytics for consensus-based estimation with known delays.

This module builds the matrices used in the stability analysis of the
networked estimator of Doostmohammadian, Khan, Pirani and Charalambous,
"Consensus-Based Distributed Estimation in the Presence of Heterogeneous,
Time-Invariant Delays", IEEE Control Systems Letters 6 (2022), referred to
below as LCSYS2022, and of its uncompensated ("delay-tolerant") variant.

Notation (all arrays are ``float64`` numpy arrays):

* ``N`` sensors (agents), ``n`` system states, ``tau`` maximum delay.
* ``P`` is the ``(N, N)`` consensus (fusion) matrix, ``p_ij != 0`` iff agent
  ``i`` receives from agent ``j`` (self-loops included).
* ``A`` is the ``(n, n)`` system matrix.
* ``C`` is a sequence of ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``
  (a 1-D array of length ``n`` is accepted as a single output row).
* ``L`` is a sequence of ``N`` effective gains, ``L[i] = K_i C_i^T`` of shape
  ``(n, m_i)``; it is the only part of the paper's ``K_i`` that enters the
  closed loop, since ``K D_C-bar = blockdiag(K_i C_i^T C_i) = blockdiag(L_i C_i)``.
* ``delays`` is an ``(N, N)`` integer array of effective link delays
  ``r_ij`` (the delay of the message from ``j`` used by ``i``).

Only numpy is used; nothing is imported from the rest of the project.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "DEFAULT_TAU_MAX",
    "augmented_closed_loop",
    "augmented_consensus",
    "delay_bound_lcsys",
    "delay_free_closed_loop",
    "delay_split",
    "gain_product",
    "output_gain_matrix",
    "spectral_radius",
    "tau_star",
]

#: Default upper end of the scan in :func:`tau_star`.
DEFAULT_TAU_MAX: int = 200


# ---------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------


def _as_square(name: str, M: ArrayLike) -> np.ndarray:
    """Return ``M`` as a 2-D square float array or raise ValueError."""
    arr = np.asarray(M, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"{name} must be a square 2-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite entries")
    return arr


def _as_outputs(C: Sequence[ArrayLike], n: int | None = None) -> list[np.ndarray]:
    """Return the output matrices as a list of 2-D ``(m_i, n)`` float arrays."""
    out: list[np.ndarray] = []
    for i, Ci in enumerate(C):
        arr = np.asarray(Ci, dtype=float)
        if arr.ndim == 1:
            arr = arr.reshape(1, -1)
        if arr.ndim != 2:
            raise ValueError(f"C[{i}] must be a 1-D or 2-D array, got shape {arr.shape}")
        if n is None:
            n = arr.shape[1]
        if arr.shape[1] != n:
            raise ValueError(f"C[{i}] has {arr.shape[1]} columns, expected n={n}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"C[{i}] contains non-finite entries")
        out.append(arr)
    if not out:
        raise ValueError("C must contain at least one output matrix")
    return out


def _as_gains(L: Sequence[ArrayLike], C: list[np.ndarray]) -> list[np.ndarray]:
    """Return the gains ``L_i`` as ``(n, m_i)`` float arrays matching ``C``."""
    if len(L) != len(C):
        raise ValueError(f"L has {len(L)} entries but C has {len(C)}")
    out: list[np.ndarray] = []
    for i, (Li, Ci) in enumerate(zip(L, C, strict=True)):
        m_i, n = Ci.shape
        arr = np.asarray(Li, dtype=float)
        if arr.ndim == 1 and m_i == 1:
            arr = arr.reshape(-1, 1)
        if arr.shape != (n, m_i):
            raise ValueError(f"L[{i}] has shape {arr.shape}, expected (n, m_i)=({n}, {m_i})")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"L[{i}] contains non-finite entries")
        out.append(arr)
    return out


def _check_system(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike]
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Validate ``P``, ``A`` and ``C`` together and return them as arrays."""
    P_arr = _as_square("P", P)
    A_arr = _as_square("A", A)
    C_list = _as_outputs(C, A_arr.shape[0])
    if len(C_list) != P_arr.shape[0]:
        raise ValueError(
            f"C has {len(C_list)} output matrices but P is {P_arr.shape[0]}x{P_arr.shape[0]}"
        )
    return P_arr, A_arr, C_list


def _block_diag(blocks: Sequence[np.ndarray]) -> np.ndarray:
    """Block-diagonal matrix of 2-D arrays (numpy only)."""
    rows = sum(b.shape[0] for b in blocks)
    cols = sum(b.shape[1] for b in blocks)
    out = np.zeros((rows, cols))
    r = c = 0
    for b in blocks:
        out[r : r + b.shape[0], c : c + b.shape[1]] = b
        r += b.shape[0]
        c += b.shape[1]
    return out


# ---------------------------------------------------------------------------
# delay-free quantities
# ---------------------------------------------------------------------------


def output_gain_matrix(C: Sequence[ArrayLike]) -> np.ndarray:
    """Return D_C-bar = blockdiag(C_i^T C_i) of LCSYS2022 eq. (10).

    Parameters
    ----------
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)`` (a 1-D array of
        length ``n`` is read as ``(1, n)``).

    Returns
    -------
    numpy.ndarray
        ``D_C-bar = D_C^T D_C``, shape ``(N n, N n)``.
    """
    C_list = _as_outputs(C)
    return _block_diag([Ci.T @ Ci for Ci in C_list])


def gain_product(L: Sequence[ArrayLike], C: Sequence[ArrayLike]) -> np.ndarray:
    """Return K D_C-bar = blockdiag(L_i C_i), the feedback term of LCSYS2022 eq. (12).

    Parameters
    ----------
    L : sequence of array_like
        ``N`` effective gains ``L_i = K_i C_i^T``, each of shape ``(n, m_i)``.
    C : sequence of array_like
        ``N`` output matrices, each of shape ``(m_i, n)``.

    Returns
    -------
    numpy.ndarray
        ``blockdiag(K_i C_i^T C_i) = blockdiag(L_i C_i)``, shape ``(N n, N n)``.
    """
    C_list = _as_outputs(C)
    L_list = _as_gains(L, C_list)
    return _block_diag([Li @ Ci for Li, Ci in zip(L_list, C_list, strict=True)])


def delay_free_closed_loop(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike]
) -> np.ndarray:
    """Return the delay-free closed-loop matrix A-hat of LCSYS2022 eq. (12).

    ``A-hat = (I - K D_C-bar)(P kron A)`` with ``K D_C-bar = blockdiag(L_i C_i)``.

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    L : sequence of array_like
        ``N`` effective gains ``L_i = K_i C_i^T``, ``L[i]`` of shape ``(n, m_i)``.

    Returns
    -------
    numpy.ndarray
        ``A-hat``, shape ``(N n, N n)``.
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    KD = gain_product(L, C_list)
    M = np.kron(P_arr, A_arr)
    return M - KD @ M


# ---------------------------------------------------------------------------
# augmented (delayed) quantities
# ---------------------------------------------------------------------------


def augmented_consensus(P_r: Sequence[ArrayLike]) -> np.ndarray:
    """Return the augmented consensus matrix P-bar of LCSYS2022 eq. (2).

    Parameters
    ----------
    P_r : sequence of array_like
        ``[P_0, P_1, ..., P_tau]``, each of shape ``(N, N)`` (eq. 3).

    Returns
    -------
    numpy.ndarray
        ``P-bar`` of shape ``(N (tau+1), N (tau+1))``: first block row
        ``[P_0, ..., P_tau]``, identity blocks ``I_N`` on the first block
        sub-diagonal, zeros elsewhere.
    """
    blocks = [_as_square(f"P_r[{r}]", Pr) for r, Pr in enumerate(P_r)]
    if not blocks:
        raise ValueError("P_r must contain at least P_0")
    N = blocks[0].shape[0]
    for r, Pr in enumerate(blocks):
        if Pr.shape != (N, N):
            raise ValueError(f"P_r[{r}] has shape {Pr.shape}, expected ({N}, {N})")
    return _companion(blocks)


def _companion(first_row: Sequence[np.ndarray]) -> np.ndarray:
    """Block companion matrix: given first block row, identity shift below."""
    b = first_row[0].shape[0]
    T = len(first_row)
    out = np.zeros((b * T, b * T))
    out[:b, :] = np.hstack(list(first_row))
    if T > 1:
        out[b:, : b * (T - 1)] = np.eye(b * (T - 1))
    return out


def _max_edge_delay(P: np.ndarray, delays: np.ndarray) -> int:
    edge = P != 0
    return int(delays[edge].max()) if np.any(edge) else 0


def _as_delays(P: np.ndarray, delays: ArrayLike) -> np.ndarray:
    """Validate an ``(N, N)`` integer delay array against ``P``."""
    N = P.shape[0]
    d = np.asarray(delays)
    if d.shape != (N, N):
        raise ValueError(f"delays must have shape ({N}, {N}) like P, got {d.shape}")
    if d.dtype.kind == "f" and np.all(np.isfinite(d)) and np.all(d == np.round(d)):
        d = d.astype(np.int64)
    if d.dtype.kind not in "iu":
        raise ValueError(f"delays must contain integers, got dtype {d.dtype}")
    d = d.astype(np.int64)
    diag = np.diag(d)
    bad = np.flatnonzero((diag != 0) & (np.diag(P) != 0))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"self-loop delays must be 0 (an agent knows its own estimate), "
            f"got delays[{i},{i}]={int(diag[i])}"
        )
    return d


def delay_split(P: ArrayLike, delays: ArrayLike, tau: int) -> list[np.ndarray]:
    """Split ``P`` by link delay into ``[P_0, ..., P_tau]`` as in LCSYS2022 eq. (3).

    ``P_r(i, j) = p_ij`` if ``delays[i, j] == r`` and 0 otherwise, so that
    ``sum_r P_r == P``.

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix; ``p_ij != 0`` marks the link ``j -> i``.
    delays : array_like of int, shape (N, N)
        Effective delay ``r_ij`` of each link. Self-loop delays (diagonal
        entries with ``p_ii != 0``) must be 0; entries where ``p_ij == 0``
        (non-edges) are ignored.
    tau : int
        Maximum delay; the result has ``tau + 1`` blocks.

    Returns
    -------
    list of numpy.ndarray
        ``tau + 1`` arrays of shape ``(N, N)``.

    Raises
    ------
    ValueError
        If shapes mismatch, ``tau < 0``, a self-loop delay is non-zero, or an
        edge delay lies outside ``0..tau``.
    """
    P_arr = _as_square("P", P)
    d = _as_delays(P_arr, delays)
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    edge = P_arr != 0
    bad = edge & ((d < 0) | (d > tau))
    if np.any(bad):
        i, j = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(
            f"delay of edge {j}->{i} is delays[{i},{j}]={int(d[i, j])}, "
            f"outside the allowed range 0..{tau}"
        )
    return [np.where(edge & (d == r), P_arr, 0.0) for r in range(tau + 1)]


def augmented_closed_loop(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    delays: ArrayLike,
    tau: int | None = None,
    compensated: bool = True,
) -> np.ndarray:
    """Return the augmented closed-loop error matrix of LCSYS2022 eq. (10).

    The error ``e_k = (e_k; e_{k-1}; ...; e_{k-tau})`` (each block of size
    ``N n``) evolves as ``e_k = A-hat-bar e_{k-1} + eta_k`` with first block row
    ``(I - K D_C-bar) [P_0 kron A, P_1 kron A^2, ..., P_tau kron A^(tau+1)]``
    when the estimator compensates the delay with ``A^(r+1)`` (LCSYS2022
    eq. 9), or ``(I - K D_C-bar) [P_0 kron A, P_1 kron A, ..., P_tau kron A]``
    for the uncompensated estimator (eq. 11 of the delay-tolerant paper), and
    identity blocks ``I_{Nn}`` on the first block sub-diagonal.

    For ``compensated=False`` the matrix describes the homogeneous part of the
    estimate recursion; it is the error recursion only if the true state does
    not move (``A x = x``).

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    L : sequence of array_like
        ``N`` effective gains ``L_i = K_i C_i^T``, ``L[i]`` of shape ``(n, m_i)``.
    delays : array_like of int, shape (N, N)
        Effective link delays, see :func:`delay_split`.
    tau : int, optional
        Maximum delay (augmentation depth); defaults to the largest edge delay.
    compensated : bool, default True
        Use ``A^(r+1)`` (True, eq. 9) or ``A`` (False, eq. 11) in block ``r``.

    Returns
    -------
    numpy.ndarray
        Shape ``(N n (tau+1), N n (tau+1))``.
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    if tau is None:
        tau = _max_edge_delay(P_arr, _as_delays(P_arr, delays))
    P_r = delay_split(P_arr, delays, tau)
    G = np.eye(P_arr.shape[0] * A_arr.shape[0]) - gain_product(L, C_list)
    first_row: list[np.ndarray] = []
    Ak = A_arr.copy()
    for r, Pr in enumerate(P_r):
        if compensated and r > 0:
            Ak = Ak @ A_arr
        first_row.append(G @ np.kron(Pr, Ak))
    return _companion(first_row)


# ---------------------------------------------------------------------------
# spectral quantities and the paper's bounds
# ---------------------------------------------------------------------------


def spectral_radius(M: ArrayLike) -> float:
    """Return the spectral radius ``max |eig(M)|`` of a square matrix (dense eigvals).

    Parameters
    ----------
    M : array_like, shape (k, k)
        Square matrix; non-finite entries give ``inf``.

    Returns
    -------
    float
        The spectral radius (0.0 for an empty matrix).
    """
    arr = np.asarray(M, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"M must be a square 2-D array, got shape {arr.shape}")
    if arr.size == 0:
        return 0.0
    if not np.all(np.isfinite(arr)):
        return float("inf")
    return float(np.max(np.abs(np.linalg.eigvals(arr))))


def _delayed_rho(G: np.ndarray, P: np.ndarray, A_pow: np.ndarray) -> float:
    """``rho(G (P kron A_pow))`` with overflow mapped to ``inf``."""
    if not np.all(np.isfinite(A_pow)):
        return float("inf")
    with np.errstate(over="ignore", invalid="ignore"):
        M = G @ np.kron(P, A_pow)
    return spectral_radius(M)


def delay_bound_lcsys(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike], tau: int
) -> float:
    """Return the LCSYS2022 eq. (26) bound rho((I - K D_C-bar)(P kron A^(tau+1)))^(1/(tau+1)).

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    L : sequence of array_like
        ``N`` effective gains, ``L[i]`` of shape ``(n, m_i)``.
    tau : int
        Delay bound ``tau >= 0``.

    Returns
    -------
    float
        The bound; it equals the exact spectral radius of the augmented closed
        loop when every link, self-loops included, has delay ``tau`` (Lemma 4).
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    G = np.eye(P_arr.shape[0] * A_arr.shape[0]) - gain_product(L, C_list)
    with np.errstate(over="ignore", invalid="ignore"):
        A_pow = np.linalg.matrix_power(A_arr, tau + 1)
    rho = _delayed_rho(G, P_arr, A_pow)
    return float(rho ** (1.0 / (tau + 1)))


def tau_star(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    tau_max: int = DEFAULT_TAU_MAX,
) -> int | None:
    """Return tau* of LCSYS2022 Theorem 1.

    Scans ``tau = 0, 1, ..., tau_max`` and returns the last ``tau`` of the
    initial run for which ``rho((I - K D_C-bar)(P kron A^(tau+1))) < 1``
    (i.e. the first failing ``tau`` minus one).

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    L : sequence of array_like
        ``N`` effective gains, ``L[i]`` of shape ``(n, m_i)``.
    tau_max : int, default DEFAULT_TAU_MAX
        Largest ``tau`` scanned.

    Returns
    -------
    int or None
        ``tau*``; ``None`` if the condition already fails at ``tau = 0``
        (the delay-free design is not stable); ``tau_max`` if it never fails
        in the scanned range (e.g. for a Schur-stable ``A``).
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    tau_max = int(tau_max)
    if tau_max < 0:
        raise ValueError(f"tau_max must be >= 0, got {tau_max}")
    G = np.eye(P_arr.shape[0] * A_arr.shape[0]) - gain_product(L, C_list)
    A_pow = A_arr.copy()
    for tau in range(tau_max + 1):
        if tau > 0:
            with np.errstate(over="ignore", invalid="ignore"):
                A_pow = A_pow @ A_arr
        if not _delayed_rho(G, P_arr, A_pow) < 1.0:
            return tau - 1 if tau > 0 else None
    return tau_max
