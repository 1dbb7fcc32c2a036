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

Structured spectral radius
--------------------------
The augmented closed loop is block companion with first block row
``[M_0, ..., M_tau]``, ``M_r = (I - K D_C-bar)(P_r kron B_r)``, ``B_r = A^(r+1)``
(compensated) or ``A`` (uncompensated). Since every edge ``j -> i`` lies in exactly
one ``P_r``, the whole first block row has only ``nnz(P)`` non-zero ``n x n``
blocks, ``p_ij (I - L_i C_i) B_(r_ij)``. :func:`augmented_spectral_radius` applies
the companion matrix matrix-free (that block-sparse first row, or the factored form
``(I - K D) vec(B_r X P_r^T)`` when ``P`` is dense) and runs ARPACK
(``scipy.sparse.linalg.eigs``) for the largest-magnitude eigenvalues; it never builds
an ``Nn x Nn`` dense block. Two exact reductions keep ARPACK fast and convergent: a
cyclic (periodic) block graph of index ``p`` makes the spectrum invariant under
rotation by ``2 pi / p`` (``p``-fold ties of the largest modulus; e.g. all links with
the same delay, LCSYS2022 Lemma 4), so ARPACK runs on ``M^p`` restricted to one
colour class; and the first ARPACK run works on a power ``M^q``, since ARPACK's own
work per step costs more than a sparse product (``M^48`` with 40 Krylov vectors for
the augmented closed loop). Its roots are first scaled towards the unit circle, ``z =
2^k w`` (exact in floating point, :func:`_root_scale`): without that, ARPACK on a
companion whose first-row blocks are far larger or smaller than its identity blocks
returned wrong values that passed the residual check. Every result is
residual-checked (for the augmented loop also: the top Ritz vector must be an
eigenvector of ``M`` itself, :func:`_base_pair_error`); failures fall back to dense
eigenvalues (small) or raise.

Only numpy and scipy are used; nothing is imported from the rest of the project.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from netsim.models.validation import as_outputs as _as_outputs
from netsim.models.validation import as_square as _as_square
from netsim.models.validation import check_system as _check_system
from numpy.typing import ArrayLike

# scipy.sparse (and its csgraph and ARPACK) costs about 0.1 s to import and only the
# structured method needs it: it is imported on first use (``netsim run`` and
# ``netsim --help`` import this module without computing a structured radius).
# ``eigs`` stays a module attribute (tests replace it) through __getattr__ below.
_SPARSE_LINALG_NAMES = ("ArpackError", "ArpackNoConvergence", "LinearOperator", "eigs")


def __getattr__(name: str) -> Any:
    if name in _SPARSE_LINALG_NAMES:
        import scipy.sparse.linalg as _spla

        value = getattr(_spla, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _sparse_linalg(name: str) -> Any:
    """``scipy.sparse.linalg.<name>``, or what replaced this module's attribute ``name``."""
    return globals().get(name) or __getattr__(name)

__all__ = [
    "ARPACK_BASIS_BYTES",
    "ARPACK_K",
    "ARPACK_MAXITER",
    "ARPACK_NCV",
    "ARPACK_POWER",
    "ARPACK_RETRIES",
    "ARPACK_TOL",
    "PAIR_CHECK_RTOL",
    "ROOT_SCALE_FREE",
    "AUGMENTED_ARPACK_NCV",
    "AUGMENTED_ARPACK_POWER",
    "AUGMENTED_DENSE_SIZE_THRESHOLD",
    "DEFAULT_TAU_MAX",
    "DENSE_FALLBACK_MAX",
    "DENSE_SIZE_THRESHOLD",
    "GROWTH_BLOCK",
    "GROWTH_FULL_MAX",
    "LIMIT_BLAS_THREADS",
    "RADIUS_METHODS",
    "TauStar",
    "augmented_closed_loop",
    "augmented_consensus",
    "augmented_radius_and_method",
    "augmented_spectral_radius",
    "closed_loop_sequence_growth",
    "convergence_time_augmented",
    "convergence_time_delay_free",
    "convergence_time_order",
    "decay_rate",
    "decay_rate_lcsys",
    "decay_rate_tolerant",
    "delay_bound_lcsys",
    "delay_bound_tolerant",
    "delay_free_closed_loop",
    "delay_free_rho_bound",
    "delay_free_spectral_radius",
    "RhoBound",
    "weighted_norm_bound",
    "delay_split",
    "gain_product",
    "output_gain_matrix",
    "spectral_radius",
    "tau_star",
    "tau_star_report",
]

#: Default upper end of the scan in :func:`tau_star`.
DEFAULT_TAU_MAX: int = 200

#: ``method="auto"`` uses dense ``numpy.linalg.eigvals`` when the matrix dimension
#: (``N n (tau+1)`` for the augmented closed loop, ``N n`` for the delay-free one)
#: is at most this, and the structured ARPACK method above it. Chosen by measurement
#: (``python benchmarks/spectral_radius.py --crossover``, 2-core machine): structured
#: is faster at every size from 168 rows up for the lcsys2022-homogeneous shape
#: (N = 4, n = 6) and from 330 rows up for N = 10, n = 3 with heterogeneous delays;
#: below that ARPACK's fixed cost (10-30 ms) loses to a dense call of a few ms.
DENSE_SIZE_THRESHOLD: int = 300

#: If ARPACK fails (no convergence, or a Ritz pair that does not pass the residual
#: check), the structured method falls back to dense eigenvalues up to this
#: dimension (with a RuntimeWarning) and raises RuntimeError above it.
DENSE_FALLBACK_MAX: int = 6000

#: Number of largest-magnitude eigenvalues ARPACK converges. Several eigenvalues
#: often share the largest modulus (complex pairs; (tau+1)-th roots from the
#: companion structure, LCSYS2022 Lemma 4), so the wanted/unwanted boundary is kept
#: well below the top.
ARPACK_K: int = 6

#: ARPACK relative accuracy of the Ritz values.
ARPACK_TOL: float = 1e-12

#: ARPACK restart limit of the first run (retries get half, a quarter). Converging
#: runs need at most about 25 with :data:`ARPACK_NCV` vectors (lcsys2022-homogeneous,
#: uncompensated, tau = 12..40); the limit bounds the time a failing run costs.
ARPACK_MAXITER: int = 100

#: Krylov vectors of the first ARPACK run (each retry doubles it), see
#: :func:`_arpack_attempts`.
ARPACK_NCV: int = 80

#: ARPACK retries after a failed first run, each with twice the power and twice the
#: Krylov space, before the dense fallback.
ARPACK_RETRIES: int = 2

#: Largest Krylov basis (``8 D ncv`` bytes) ARPACK may keep.
ARPACK_BASIS_BYTES: int = 256 * 2**20

#: The first ARPACK run works on ``M^ARPACK_POWER`` (fewer, equally informative ARPACK
#: steps; ``rho(M) = rho(M^q)^(1/q)``), see :func:`_arpack_rho`.
ARPACK_POWER: int = 8

#: The power and Krylov size of the first ARPACK run for the augmented closed loop
#: (:func:`augmented_spectral_radius`; None: :data:`ARPACK_POWER`, :data:`ARPACK_NCV`).
#: Measured (issue 34, 2026-12-02, 2-core machine, lcsys2022-homogeneous, tau = 5..30
#: both loops, 52 radii): CPU 2.3-2.4 s with (8, 80), 1.4 s (32, 80), 1.32 s (48, 40),
#: 1.33 s (64 or 96, 40), 1.5 s (48 or 64, 30), 1.75 s (48, 20); every value within
#: 5e-15 of the (8, 80) one. A higher power separates the clustered top moduli
#: (``|mu_2 / mu_1|^q``) for the cost of ``q`` cheap sparse products per ARPACK step;
#: if it over- or underflows (``rho`` far from 1) the run takes :data:`ARPACK_POWER`.
AUGMENTED_ARPACK_POWER: int | None = 48
AUGMENTED_ARPACK_NCV: int | None = 40

#: ``method="auto"`` of :func:`augmented_spectral_radius` uses dense eigenvalues up to
#: this dimension and the structured method above it (with
#: :data:`AUGMENTED_ARPACK_POWER`): measured on lcsys2022-homogeneous (2-core machine,
#: single-threaded BLAS), dense took 10 ms at 120 rows, 18 at 144, 28-30 at 168, 94-104
#: at 288; structured 10-16 ms at every size from 72 to 312 rows.
AUGMENTED_DENSE_SIZE_THRESHOLD: int = 120

#: :func:`closed_loop_sequence_growth` tracks the whole product (applied to the
#: identity) when the augmented dimension is at most this, else a random block.
GROWTH_FULL_MAX: int = 600

#: Number of random orthonormal vectors tracked by
#: :func:`closed_loop_sequence_growth` above :data:`GROWTH_FULL_MAX`.
GROWTH_BLOCK: int = 8


# ---------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------


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
    tau = _check_delay_range(P_arr, d, tau)
    edge = P_arr != 0
    return [np.where(edge & (d == r), P_arr, 0.0) for r in range(tau + 1)]


def _check_delay_range(P: np.ndarray, d: np.ndarray, tau: int) -> int:
    """Check ``tau >= 0`` and every edge delay in ``0..tau``; return ``int(tau)``."""
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    edge = P != 0
    bad = edge & ((d < 0) | (d > tau))
    if np.any(bad):
        i, j = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(
            f"delay of edge {j}->{i} is delays[{i},{j}]={int(d[i, j])}, "
            f"outside the allowed range 0..{tau}"
        )
    return tau


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

    Notes
    -----
    Up to :data:`DENSE_SIZE_THRESHOLD` rows, OpenBLAS runs single-threaded during
    the call (see :func:`_single_threaded_blas`).
    """
    arr = np.asarray(M, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"M must be a square 2-D array, got shape {arr.shape}")
    if arr.size == 0:
        return 0.0
    if not np.all(np.isfinite(arr)):
        return float("inf")
    if arr.shape[0] <= DENSE_SIZE_THRESHOLD:
        # small LAPACK problems gain nothing from BLAS threads, and lose 10x or
        # more when the machine is loaded (OpenBLAS threads spin)
        with _single_threaded_blas():
            return float(np.max(np.abs(np.linalg.eigvals(arr))))
    return float(np.max(np.abs(np.linalg.eigvals(arr))))


# ---------------------------------------------------------------------------
# structured (matrix-free) spectral radius
# ---------------------------------------------------------------------------

#: Methods accepted by the spectral-radius functions.
_METHODS = ("auto", "dense", "structured")

#: Set to False to leave the BLAS thread count alone while ARPACK runs.
LIMIT_BLAS_THREADS: bool = True


def _check_method(method: str) -> str:
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    return method


def _gain_blocks(L: Sequence[ArrayLike], C_list: list[np.ndarray]) -> np.ndarray:
    """Return the ``(N, n, n)`` stack of the blocks ``I - L_i C_i`` of ``I - K D_C-bar``."""
    L_list = _as_gains(L, C_list)
    n = C_list[0].shape[1]
    return np.stack([np.eye(n) - Li @ Ci for Li, Ci in zip(L_list, C_list, strict=True)])


def _delay_blocks(A: np.ndarray, depth: int, compensated: bool) -> np.ndarray:
    """``(depth, n, n)`` stack of ``B_r = A^(r+1)`` (compensated) or ``A`` (not); may overflow."""
    n = A.shape[0]
    B = np.empty((depth, n, n))
    B[0] = A
    with np.errstate(over="ignore", invalid="ignore"):
        for r in range(1, depth):
            B[r] = B[r - 1] @ A if compensated else A
    return B


class _FirstRow:
    """Matrix-free first block row ``[M_0, ..., M_(R-1)]``, ``M_r = G (P_r kron B_r)``.

    ``G = blockdiag(G_i)`` with ``G_i = I - L_i C_i``, ``P_r`` the entries of ``P`` on the
    edges with ``index == r``. Two representations, chosen by a flop count per vector:

    * ``"bsr"``: the row as a sparse matrix of ``nnz(P)`` dense ``n x n`` blocks
      ``p_ij G_i B_(r_ij)`` (each edge lies in exactly one ``P_r``), applied as CSR;
      ``nnz(P) n^2`` flops and storage.
    * ``"factored"``: ``G vec(B_r X_r P_r^T)`` with ``X_r`` the ``(n, N)`` reshape of
      block ``r``, ``P_r`` sparse; ``nnz(P) n + (#r + 1) N n^2`` flops, used for dense ``P``.

    ``block_edges = (src, dst)`` lists the (possibly) non-zero ``n x n`` blocks of the
    first row as edges of the block graph of the companion matrix, whose node
    ``s N + j`` is agent ``j``'s slot ``s``: ``(j, r_ij) -> (i, 0)``.
    """

    def __init__(
        self,
        G: np.ndarray,
        P: np.ndarray,
        index: np.ndarray,
        B: np.ndarray,
        kind: str = "auto",
    ) -> None:
        import scipy.sparse as sp

        N, n = G.shape[0], G.shape[1]
        self.N, self.n, self.R = N, n, B.shape[0]
        #: :meth:`_csr_power`'s vector buffer and views per (power, thread)
        self._plans: dict[tuple[int, int], Any] = {}
        self.Nn = N * n
        if sp.issparse(P):
            # sparse P (large N): ``index`` is per stored entry in CSR order, or None
            # (every entry r = 0); no N x N array is formed
            csr = sp.csr_array(P)
            csr.sort_indices()
            rows = np.repeat(np.arange(N), np.diff(csr.indptr))
            cols = csr.indices.astype(np.int64)
            vals = csr.data.astype(float)
            nonzero = vals != 0
            rows, cols, vals = rows[nonzero], cols[nonzero], vals[nonzero]
            r_edge = (np.zeros(rows.size, dtype=np.int64) if index is None
                      else np.asarray(index, dtype=np.int64)[nonzero])
        else:
            rows, cols = np.nonzero(P)
            vals = P[rows, cols]
            r_edge = index[rows, cols].astype(np.int64)
        used = np.unique(r_edge)
        self.nnz = rows.size
        bsr_cost = self.nnz * n * n
        fact_cost = self.nnz * n + (used.size + 1) * N * n * n
        if kind == "auto":
            kind = "bsr" if bsr_cost <= 2 * fact_cost else "factored"
        if kind not in ("bsr", "factored"):
            raise ValueError(f"unknown first-row representation {kind!r}")
        self.kind = kind
        with np.errstate(over="ignore", invalid="ignore"):
            if kind == "bsr":
                block_col = r_edge * N + cols
                order = np.lexsort((block_col, rows))
                rows, cols, r_edge, block_col, vals = (
                    rows[order],
                    cols[order],
                    r_edge[order],
                    block_col[order],
                    vals[order],
                )
                data = vals[:, None, None] * (G[rows] @ B[r_edge])
                indptr = np.searchsorted(rows, np.arange(N + 1))
                self.finite = bool(np.all(np.isfinite(data)))
                self._S = sp.csr_array(
                    sp.bsr_array((data, block_col, indptr), shape=(self.Nn, self.Nn * self.R))
                )
                self._S.eliminate_zeros()
                self.is_zero = self._S.nnz == 0
                live = np.any(data != 0, axis=(1, 2))
                self.block_edges = (r_edge[live] * N + cols[live], rows[live])
            else:
                self._parts = []
                for r in used:
                    sel = r_edge == r
                    part = sp.csr_array((vals[sel], (rows[sel], cols[sel])), shape=(N, N))
                    self._parts.append((int(r), part, B[r]))
                self._G = G
                self.finite = bool(np.all(np.isfinite(B[used])) and np.all(np.isfinite(G)))
                self.is_zero = self.nnz == 0 or not np.any(G) or not np.any(B[used])
                self.block_edges = (r_edge * N + cols, rows)

    def apply(self, X: np.ndarray) -> np.ndarray:
        """Return the first block row times ``X`` (shape ``(R N n,)`` or ``(R N n, m)``)."""
        if self.kind == "bsr":
            return self._S @ X
        N, n, Nn = self.N, self.n, self.Nn
        X2 = X.reshape(Nn * self.R, -1)
        m = X2.shape[1]
        Y = np.zeros((N, n, m), dtype=np.result_type(X.dtype, float))
        for r, Pr, Br in self._parts:
            W = (Pr @ X2[r * Nn : (r + 1) * Nn].reshape(N, n * m)).reshape(N, n, m)
            Y += np.matmul(Br, W)
        Y = np.matmul(self._G, Y)
        return Y.reshape(Nn) if X.ndim == 1 else Y.reshape(Nn, m)

    def companion_power(self, X: np.ndarray, q: int = 1) -> np.ndarray:
        """Apply ``M^q`` (``M`` the block companion matrix) to ``X``, shape ``(R N n[, m])``.

        ``M`` shifts the blocks down and puts the first row's product on top, so
        ``M^q x`` is computed in one buffer of ``q + R`` blocks holding
        ``(y_q, ..., y_1, x_0, ..., x_(R-1))``, ``y_t = row (y_(t-1), ...)``: no shift copies.
        """
        X = np.asarray(X)
        Nn, R = self.Nn, self.R
        kind = X.dtype.kind  # float64 products (np.result_type costs several us here)
        if self.kind == "bsr" and X.ndim <= 2 and (kind in "biu" or (
                kind == "f" and X.dtype.itemsize <= 8)):
            return self._csr_power(X, q)
        buf = np.empty(((q + R) * Nn, *X.shape[1:]), dtype=np.result_type(X.dtype, float))
        buf[q * Nn :] = X
        for t in range(q - 1, -1, -1):
            buf[t * Nn : (t + 1) * Nn] = self.apply(buf[(t + 1) * Nn : (t + 1 + R) * Nn])
        return buf[: R * Nn]

    def _csr_power(self, X: np.ndarray, q: int) -> np.ndarray:
        """:meth:`companion_power` of the ``"bsr"`` row on float64 data.

        It calls scipy's own CSR kernel (``csr_matvec``/``csr_matvecs``, the ones
        ``S @ x`` calls: the same sums in the same order, bit for bit) straight into the
        power buffer; the Python-level dispatch of ``@`` cost several times the product
        itself in ARPACK's many small products. For a vector the buffer and its ``q``
        (source, target) views are kept per ``(q, thread)`` and the result is a copy; a
        block ``(D, m)`` gets a fresh buffer and a view of it (no second copy of a
        possibly large block).
        """
        from scipy.sparse._sparsetools import csr_matvec, csr_matvecs

        Nn, R = self.Nn, self.R
        S = self._S
        rows, cols = S.shape
        if X.ndim == 2:
            width = X.shape[1]
            buf = np.empty(((q + R) * Nn, width), dtype=np.float64)
            buf[q * Nn :] = X
            for t in range(q - 1, -1, -1):
                dst = buf[t * Nn : (t + 1) * Nn]
                dst.fill(0.0)  # the kernels add into their output
                csr_matvecs(rows, cols, width, S.indptr, S.indices, S.data,
                            buf[(t + 1) * Nn : (t + 1 + R) * Nn].reshape(-1),
                            dst.reshape(-1))
            return buf[: R * Nn]
        key = (q, threading.get_ident())
        plan = self._plans.get(key)
        if plan is None:
            buf = np.empty((q + R) * Nn, dtype=np.float64)
            views = [(buf[(t + 1) * Nn : (t + 1 + R) * Nn], buf[t * Nn : (t + 1) * Nn])
                     for t in range(q - 1, -1, -1)]
            plan = (buf[q * Nn :], buf[: R * Nn], (rows, cols, S.indptr, S.indices, S.data),
                    views)
            self._plans[key] = plan
        tail, result, (rows, cols, indptr, indices, data), views = plan
        tail[...] = X
        for src, dst in views:
            dst.fill(0.0)
            csr_matvec(rows, cols, indptr, indices, data, src, dst)
        return result.copy()

    def companion_apply(self, X: np.ndarray) -> np.ndarray:
        """Apply the block companion matrix (first row, identity shift below) to ``X``."""
        return self.companion_power(X, 1)


@lru_cache(maxsize=1)
def _openblas_thread_setters() -> tuple[Callable[[int], int], ...]:
    """``openblas_set_num_threads_local`` of every OpenBLAS already loaded (Linux only)."""
    setters: list[Callable[[int], int]] = []
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line.lower()}
    except OSError:
        return ()
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path, mode=getattr(os, "RTLD_NOLOAD", 0) | os.RTLD_LOCAL)
            fn = lib.openblas_set_num_threads_local
        except (OSError, AttributeError):
            continue
        fn.restype = ctypes.c_int
        fn.argtypes = [ctypes.c_int]
        setters.append(fn)
    return tuple(setters)


# nesting depth of _single_threaded_blas over all threads, and the counts to restore
_blas_limit_lock = threading.Lock()
_blas_limit_depth = 0
_blas_saved_counts: list[tuple[Callable[[int], int], int]] = []


@contextmanager
def _single_threaded_blas() -> Iterator[None]:
    """Run OpenBLAS single-threaded inside the block, restoring the previous count after.

    ARPACK's work is many small BLAS-2 calls (``D x ncv`` Gram-Schmidt); threading
    them gains nothing, and on a loaded machine OpenBLAS's spinning threads made the
    structured method 5-50x slower. The setting is process-wide while it lasts: the
    first of nested or concurrent entries (any thread) saves the thread counts and
    the last exit restores them.
    """
    global _blas_limit_depth
    with _blas_limit_lock:
        if _blas_limit_depth == 0 and LIMIT_BLAS_THREADS:
            _blas_saved_counts[:] = [(fn, int(fn(1))) for fn in _openblas_thread_setters()]
        _blas_limit_depth += 1
    try:
        yield
    finally:
        with _blas_limit_lock:
            _blas_limit_depth -= 1
            if _blas_limit_depth == 0:
                for fn, count in reversed(_blas_saved_counts):
                    fn(count)
                _blas_saved_counts.clear()


def _cyclic_class(row: _FirstRow) -> tuple[int, np.ndarray]:
    """Cyclic index ``p`` of the companion matrix's block graph and one colour class.

    Colour the block graph (nodes ``(agent, slot)``; edges ``(j, s-1) -> (j, s)`` of
    the identity shift and ``row.block_edges``) by potentials along a spanning forest
    of the undirected graph, ``c(v) = c(u) + 1`` along each edge ``u -> v``; ``p`` is
    the gcd over all edges of ``c(u) + 1 - c(v)``. Then ``c mod p`` is consistent on
    every edge, so with ``W = diag(omega^c)``, ``omega = exp(2 pi i / p)``,
    ``W M W^-1 = omega M``: the spectrum is invariant under rotation by ``2 pi / p``,
    ``M^p`` maps each colour class into itself and the non-zero eigenvalues of ``M``
    are the ``p``-th roots of those of ``M^p`` on any single class (for ``lambda != 0``
    an eigenvector has a non-zero part in every class of its weak component).
    ``p = 0`` means the block graph has no cycle: ``M`` is nilpotent.

    Returns
    -------
    (p, nodes)
        ``p`` and the state indices (into the augmented vector) of the smallest
        colour class; ``nodes`` is everything when ``p <= 1``.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    N, n, R = row.N, row.n, row.R
    V = N * R
    src, dst = row.block_edges
    shift_src = np.arange(N * (R - 1))
    src = np.concatenate([src, shift_src])
    dst = np.concatenate([dst, shift_src + N])
    everything = np.arange(row.Nn * R)
    if src.size == 0:
        return 0, everything
    adj = sp.csr_matrix((np.ones(src.size), (src, dst)), shape=(V, V))
    n_comp, labels = connected_components(adj, directed=True, connection="weak")
    pot = np.zeros(V, dtype=np.int64)
    seen = np.zeros(n_comp, dtype=bool)
    for root in range(V):
        if seen[labels[root]]:
            continue
        seen[labels[root]] = True
        order, pred = breadth_first_order(adj, root, directed=False, return_predecessors=True)
        child = order[1:]
        parent = pred[child]
        forward = np.asarray(adj[parent, child]).ravel() != 0  # edge parent -> child
        step = np.where(forward, 1, -1)
        for v, u, d in zip(child.tolist(), parent.tolist(), step.tolist(), strict=True):
            pot[v] = pot[u] + d
    p = int(np.gcd.reduce(np.abs(pot[src] + 1 - pot[dst])))
    if p <= 1:
        return p, everything
    colour = np.mod(pot, p)
    sizes = np.bincount(colour, minlength=p)
    c = int(np.argmin(np.where(sizes > 0, sizes, V + 1)))
    block_nodes = np.flatnonzero(colour == c)
    # block node s N + j holds the states (s N + j) n .. (s N + j) n + n - 1
    return p, (block_nodes[:, None] * n + np.arange(n)[None, :]).ravel()


def _companion_rho(row: _FirstRow, what: str, first_power: int | None = None,
                   ncv: int | None = None, pair_check: bool = False) -> float:
    """Spectral radius of ``row``'s block companion matrix ``M`` (structured).

    Uses the cyclic reduction of :func:`_cyclic_class` (``rho(M) = rho(M^p on one
    colour class)^(1/p)``; this removes the ``p``-fold ties of equal moduli that keep
    ARPACK from converging), then :func:`_arpack_rho` on a power of that operator.
    """
    if not row.finite:
        return float("inf")
    if row.is_zero:
        return 0.0  # nilpotent block companion matrix
    p, nodes = _cyclic_class(row)
    if p == 0:
        return 0.0
    D = row.Nn * row.R

    def power(q: int) -> Callable[[np.ndarray], np.ndarray]:
        steps = p * q
        if p == 1:
            return lambda X: row.companion_power(X, steps)

        def apply_class(X: np.ndarray) -> np.ndarray:
            X = np.asarray(X)
            vec = X.ndim == 1
            X2 = X.reshape(nodes.size, -1)
            Z = np.zeros((D, X2.shape[1]), dtype=np.result_type(X2.dtype, float))
            Z[nodes] = X2
            Y = row.companion_power(Z, steps)[nodes]
            return Y.ravel() if vec else Y

        return apply_class

    label = what if p == 1 else f"{what} (cyclic index {p})"
    q = max(1, round((ARPACK_POWER if first_power is None else first_power) / p))
    safe = max(1, round(ARPACK_POWER / p))
    return _arpack_rho(power, nodes.size, label, q, ncv=ncv,
                       safe_power=safe if q > safe else None,
                       pair_check=pair_check) ** (1.0 / p)


def _arpack_attempts(q: int, D: int, k: int, ncv: int | None = None
                     ) -> list[tuple[int, int, int]]:
    """The ``(power, ncv, maxiter)`` of each ARPACK run of :func:`_arpack_rho`, in order.

    The first run uses :data:`ARPACK_NCV` Krylov vectors (fewer if the basis would
    exceed :data:`ARPACK_BASIS_BYTES`) and :data:`ARPACK_MAXITER` restarts; each retry
    doubles the power and the Krylov space, which is what separates clustered top
    moduli (the uncompensated loop of lcsys2022-homogeneous at tau = 30 has its top ten
    moduli within 2e-4 of each other: ncv = 40 never converged, ncv = 80 does), with
    half the restarts (a larger space needs fewer). A retry whose Krylov space would
    exceed ``D / 4`` is not run: the dense fallback is cheaper. This bounds the work of a
    failure to about three times that of the first run's restart limit.
    """
    cap = max(2 * k + 1, ARPACK_BASIS_BYTES // (8 * max(D, 1)))
    ncv = max(2 * k + 1, min(ARPACK_NCV if ncv is None else ncv, cap))
    out = [(q, min(ncv, D), ARPACK_MAXITER)]
    for step in range(1, ARPACK_RETRIES + 1):
        size = min(ncv * 2**step, cap)
        if size > D // 4:  # a Krylov space this large costs about what dense does
            break
        out.append((q * 2**step, size, max(10, ARPACK_MAXITER >> step)))
    return out


def _arpack_rho(
    power: Callable[[int], Callable[[np.ndarray], np.ndarray]],
    D: int,
    what: str,
    q: int,
    *,
    k: int = ARPACK_K,
    tol: float = ARPACK_TOL,
    seed: int = 0,
    ncv: int | None = None,
    safe_power: int | None = None,
    pair_check: bool = False,
) -> float:
    """Spectral radius of a ``D x D`` operator ``M`` by ARPACK (``which="LM"``).

    ``power(j)`` returns a function applying ``M^j`` to a vector or a ``(D, m)``
    block. ARPACK's cost per step (Gram-Schmidt against ``ncv`` vectors of length
    ``D``) is several times that of one sparse application of ``M``, so the first run
    works on ``M^q`` (the same ``k`` largest moduli, raised to the power ``q``, and
    ``q`` times fewer ARPACK steps) and returns ``max |mu|^(1/q)``. If a run fails,
    the next (:func:`_arpack_attempts`) doubles the power and the Krylov space, with
    another random start vector (or, once a power maps the start vector to zero, works
    on ``M`` itself: nilpotent-like operators); each run has at most :data:`ARPACK_MAXITER`
    restarts, so a failure costs a bounded time. A run is accepted only if ARPACK
    converged and the residual of its top Ritz pair, recomputed with the operator,
    is at most ``1e-8 max(|mu|, ||M^j x|| / ||x||)``. ``ncv`` replaces
    :data:`ARPACK_NCV`; with ``safe_power``, a first run whose ``||M^q v0|| / ||v0||``
    lies outside ``[1e-150, 1e150]`` (the power would over- or underflow) uses
    ``M^safe_power`` instead. With ``pair_check``, the top Ritz vector must also be an
    eigenvector of ``M`` itself (:func:`_base_pair_error`). If every run fails: dense
    eigenvalues of ``M`` up to :data:`DENSE_FALLBACK_MAX` (with a RuntimeWarning),
    else RuntimeError.
    """
    if D <= k + 2:  # ARPACK needs k < D - 1
        _last_structured.method = RADIUS_METHODS[0]
        return _dense_operator_rho(power(1), D)
    eigs = _sparse_linalg("eigs")
    LinearOperator = _sparse_linalg("LinearOperator")  # noqa: N806
    ArpackError = _sparse_linalg("ArpackError")  # noqa: N806
    ArpackNoConvergence = _sparse_linalg("ArpackNoConvergence")  # noqa: N806
    rng = np.random.default_rng(seed)
    failures: list[str] = []
    annihilated = False  # M^j v0 = 0 happened: the powers are (nearly) nilpotent
    attempts = _arpack_attempts(q, D, k, ncv)
    for step, (j, ncv, maxiter) in enumerate(attempts):
        if annihilated:
            j = 1
        apply = power(j)
        op = LinearOperator((D, D), matvec=apply, matmat=apply, dtype=float)
        v0 = rng.standard_normal(D)
        label = f"M^{j}, ncv={ncv}"
        try:
            with _single_threaded_blas():
                with np.errstate(over="ignore", invalid="ignore", under="ignore"):
                    norm_est = float(np.linalg.norm(apply(v0)) / np.linalg.norm(v0))
                    if (step == 0 and safe_power is not None and j > safe_power
                            and not 1e-150 <= norm_est <= 1e150):
                        # a high first power over- or underflows (rho far from 1):
                        # this run takes the default power instead
                        j = safe_power
                        apply = power(j)
                        op = LinearOperator((D, D), matvec=apply, matmat=apply, dtype=float)
                        label = f"M^{j}, ncv={ncv}"
                        norm_est = float(np.linalg.norm(apply(v0)) / np.linalg.norm(v0))
                if not math.isfinite(norm_est):
                    failures.append(f"{label}: the operator overflows")
                    continue
                if norm_est == 0.0 and j > 1:
                    failures.append(f"{label}: M^{j} maps the start vector to zero")
                    if not annihilated and step == len(attempts) - 1:
                        attempts.append((1, ncv, ARPACK_MAXITER))  # one run on M itself
                    annihilated = True
                    continue
                vals, vecs = eigs(
                    op, k=k, which="LM", tol=tol, ncv=ncv, v0=v0, maxiter=maxiter
                )
        except ArpackNoConvergence as exc:
            failures.append(f"{label}: no convergence ({len(exc.eigenvalues)} of {k} converged)")
            continue
        except (ArpackError, ValueError) as exc:
            failures.append(f"{label}: {exc}")
            continue
        i = int(np.argmax(np.abs(vals)))
        mu, v = complex(vals[i]), vecs[:, i]
        with np.errstate(over="ignore", invalid="ignore"):
            res = float(np.linalg.norm(apply(v) - mu * v) / np.linalg.norm(v))
        if math.isfinite(res) and res <= 1e-8 * max(abs(mu), norm_est):
            bad = _base_pair_error(power, v, mu, j) if pair_check else None
            if bad is None:
                _last_structured.method = RADIUS_METHODS[1]
                return float(np.max(np.abs(vals))) ** (1.0 / j)
            failures.append(f"{label}: {bad}")
            continue
        failures.append(f"{label}: top Ritz pair residual {res:.3g} for |mu|={abs(mu):.6g}")
    reason = "; ".join(failures)
    if D <= DENSE_FALLBACK_MAX:
        warnings.warn(
            f"ARPACK failed for the {what} (dimension {D}): {reason}; "
            "falling back to dense eigenvalues",
            RuntimeWarning,
            stacklevel=4,
        )
        _last_structured.method = RADIUS_METHODS[2]
        return _dense_operator_rho(power(1), D)
    raise RuntimeError(
        f"ARPACK could not compute the spectral radius of the {what} "
        f"(dimension {D}): {reason}. Use method='dense' if it fits in memory."
    )


#: :func:`_base_pair_error`: largest ``||M v - z v|| / (|z| ||v||)`` accepted.
PAIR_CHECK_RTOL: float = 1e-7


def _base_pair_error(power: Callable[[int], Callable[[np.ndarray], np.ndarray]],
                     v: np.ndarray, mu: complex, j: int) -> str | None:
    """Why the Ritz pair ``(mu, v)`` of ``M^j`` is not an eigenpair of ``M``, or None.

    ``z`` is the Rayleigh quotient of ``v`` for ``M = power(1)``; the pair passes if
    ``||M v - z v|| <=`` :data:`PAIR_CHECK_RTOL` ``|z| ||v||`` and ``|z|^j = |mu|`` to
    1e-6. The residual check of :func:`_arpack_rho` is relative to ``||M^j||``; on a
    strongly non-normal companion (``rho^j`` far below ``||M^j||``) ARPACK returned
    Ritz values that are no eigenvalue (issue 34: a radius 0.3981 for the true
    0.3962) and passed it; this check, relative to the eigenvalue, rejects them.
    """
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        Mv = power(1)(v)
        vv = float(np.real(np.vdot(v, v)))
        z = complex(np.vdot(v, Mv)) / vv
        res = float(np.linalg.norm(Mv - z * v)) / math.sqrt(vv)
        ratio = abs(z) ** j / abs(mu) if mu != 0 else math.inf
    if not (math.isfinite(res) and res <= PAIR_CHECK_RTOL * abs(z)):
        return f"the top Ritz vector is no eigenvector of M (residual {res:.3g}, |z|={abs(z):.6g})"
    if not abs(ratio - 1.0) <= 1e-6:
        return f"the top Ritz value {abs(mu):.6g} is not |z|^{j} = {abs(z) ** j:.6g}"
    return None


def _dense_operator_rho(apply: Callable[[np.ndarray], np.ndarray], D: int) -> float:
    """Spectral radius of the operator ``apply`` by dense eigenvalues of ``apply(I_D)``."""
    return spectral_radius(apply(np.eye(D)))


def _block_rho(G: np.ndarray, P: np.ndarray, B: np.ndarray, method: str = "auto") -> float:
    """``rho(blockdiag(G_i) (P kron B))`` with overflow mapped to ``inf``.

    Dense eigenvalues if ``method == "dense"`` or (``"auto"`` and ``N n`` is at most
    :data:`DENSE_SIZE_THRESHOLD`), else ARPACK on the structured operator.
    """
    if not np.all(np.isfinite(B)):
        return float("inf")
    N, n = G.shape[0], G.shape[1]
    if method == "dense" or (method == "auto" and N * n <= DENSE_SIZE_THRESHOLD):
        with np.errstate(over="ignore", invalid="ignore"):
            return spectral_radius(_block_diag(list(G)) @ np.kron(P, B))
    row = _FirstRow(G, P, np.zeros(P.shape, dtype=np.int64), B[None])
    return _companion_rho(row, "matrix (I - K D)(P kron B)")


# ---------------------------------------------------------------------------
# spectral radii and the paper's bounds
# ---------------------------------------------------------------------------


def delay_free_spectral_radius(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    method: str = "auto",
) -> float:
    """Return rho(A-hat) of the delay-free closed loop (LCSYS2022 eq. 12).

    Parameters
    ----------
    P, A, C, L
        As in :func:`delay_free_closed_loop`.
    method : {"auto", "dense", "structured"}, default "auto"
        ``"dense"``: ``numpy.linalg.eigvals`` of the ``(N n, N n)`` matrix;
        ``"structured"``: ARPACK on the block-sparse operator; ``"auto"``: dense
        when ``N n <=`` :data:`DENSE_SIZE_THRESHOLD`.

    Returns
    -------
    float
        ``rho((I - K D_C-bar)(P kron A))``.
    """
    import scipy.sparse as sp

    if sp.issparse(P):
        # large sparse networks: always the structured operator (no N x N array)
        A_arr = np.asarray(A, dtype=float)
        C_list = [np.atleast_2d(np.asarray(Ci, dtype=float)) for Ci in C]
        if len(C_list) != P.shape[0]:
            raise ValueError(f"C has {len(C_list)} output matrices but P is "
                             f"{P.shape[0]}x{P.shape[1]}")
        method = _check_method(method)
        if method == "dense":
            raise ValueError("method='dense' needs a dense P")
        G = _gain_blocks(L, C_list)
        if not np.all(np.isfinite(A_arr)):
            return float("inf")
        row = _FirstRow(G, P, None, A_arr[None])
        return _companion_rho(row, "matrix (I - K D)(P kron A)")
    P_arr, A_arr, C_list = _check_system(P, A, C)
    return _block_rho(_gain_blocks(L, C_list), P_arr, A_arr, _check_method(method))


# ---------------------------------------------------------------------------
# a rigorous upper bound on rho(A-hat) in linear work: weighted infinity norm
# ---------------------------------------------------------------------------

#: Power steps :func:`delay_free_rho_bound` takes per basis (half plain, half lazy).
BOUND_MAX_ITER: int = 200
#: Once the bound is below 1 the steps stop when it improved by less than this
#: (relative) over the last :data:`BOUND_STALL_STEPS` steps.
BOUND_STALL_RTOL: float = 1e-3
#: See :data:`BOUND_STALL_RTOL`.
BOUND_STALL_STEPS: int = 10
#: The eigenvector basis of ``A`` is tried only if its condition number is at most this.
BOUND_MAX_COND: float = 1e6
#: Bases tried by :func:`delay_free_rho_bound`, in order.
BOUND_BASES: tuple[str, ...] = ("eigenvectors", "identity")
#: Weights below this fraction of the largest are raised to it (keeps them positive).
_BOUND_FLOOR: float = 1e-30


@dataclass(frozen=True)
class RhoBound:
    """A rigorous upper bound ``rho(A-hat) <= bound`` (:func:`delay_free_rho_bound`).

    Attributes
    ----------
    bound : float
        ``||T^-1 A-hat T||_inf`` with ``T = (I_N kron S) diag(w)``, inflated for
        rounding; ``inf`` if nothing finite was found.
    basis : str
        ``S``: ``"eigenvectors"`` (of ``A``, complex) or ``"identity"``.
    iterations : int
        Power steps taken to find the weights.
    weights : numpy.ndarray, shape (N, n)
        The positive weights ``w`` (agent, coordinate in the basis ``S``); with
        :func:`weighted_norm_bound` they reproduce ``bound`` in one step.
    """

    bound: float
    basis: str
    iterations: int
    weights: np.ndarray


def _bound_basis(A: np.ndarray, basis: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(S, S_inv)`` for ``basis`` (``S_inv`` the computed inverse), or None."""
    n = A.shape[0]
    if basis == "identity":
        eye = np.eye(n)
        return eye, eye
    if basis != "eigenvectors":
        raise ValueError(f"unknown basis {basis!r}; expected one of {BOUND_BASES}")
    if not np.all(np.isfinite(A)):
        return None
    _, V = np.linalg.eig(A)
    with np.errstate(all="ignore"):
        cond = np.linalg.cond(V)
    if not (math.isfinite(cond) and cond <= BOUND_MAX_COND):
        return None
    return V, np.linalg.inv(V)


def _bound_operator(
    P: Any, A: np.ndarray, G: np.ndarray, basis: str
) -> tuple[Any, np.ndarray, float] | None:
    """``(|P| as CSR, H, inflation)`` with ``|T^-1 A-hat T| w`` = ``H_i (|P| W)_i`` bounded.

    ``H_i`` (``(N, n, n)``, non-negative) bounds ``|S^-1 G_i A S|`` elementwise *including
    rounding*: ``|fl(S_inv G_i A S)| + c |S_inv| |G_i| |A| |S|`` (``c = 32 (n + 2) eps``,
    above the error bound of the three floating-point products), times
    ``I + delta / (1 - delta) J`` on the right, which bounds ``|(I + F)^-1|`` for the exact
    inverse ``S_inv^-1 = S (I + F)^-1``, ``F = S_inv S - I``, ``delta >= ||F||_inf``
    (every entry of ``F^k`` is at most ``delta^k``). ``inflation`` covers the rounding
    of the non-negative sums of one step (``|P| W``, then ``H_i x``, then the ratio).
    """
    import scipy.sparse as sp

    pair = _bound_basis(A, basis)
    if pair is None:
        return None
    S, S_inv = pair
    n = A.shape[0]
    eps = float(np.finfo(float).eps)
    c = 32.0 * (n + 2) * eps
    with np.errstate(over="ignore", invalid="ignore"):
        AS = A @ S
        H = np.abs(S_inv[None] @ G @ AS[None])
        H += c * (np.abs(S_inv)[None] @ np.abs(G) @ (np.abs(A) @ np.abs(S))[None])
        F = np.abs(S_inv @ S - np.eye(n)) + c * (np.abs(S_inv) @ np.abs(S))
        delta = float(np.max(F.sum(axis=1)))
        if not delta < 0.5:
            return None
        if delta > 0.0:
            H = H @ (np.eye(n) + delta / (1.0 - delta) * np.ones((n, n)))[None]
    if not np.all(np.isfinite(H)):
        return None
    absP = sp.csr_array(P, dtype=float, copy=True)
    absP.data = np.abs(absP.data)
    deg = int(np.max(np.diff(absP.indptr))) if absP.shape[0] else 0
    inflation = 1.0 + 4.0 * (deg + n + 4) * eps
    return absP, H, inflation


def _bound_gains(P: Any, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(A, G)`` as float arrays, ``G`` the ``(N, n, n)`` stack of ``I - L_i C_i``."""
    A_arr = np.asarray(A, dtype=float)
    C_list = [np.atleast_2d(np.asarray(Ci, dtype=float)) for Ci in C]
    if len(C_list) != P.shape[0]:
        raise ValueError(f"C has {len(C_list)} output matrices but P is "
                         f"{P.shape[0]}x{P.shape[1]}")
    return A_arr, _gain_blocks(L, C_list)


def _bound_step(absP: Any, H: np.ndarray, W: np.ndarray) -> np.ndarray:
    """``|T^-1 A-hat T|`` (bounded elementwise) times the weights: ``H_i (|P| W)_i``."""
    with np.errstate(over="ignore", invalid="ignore"):
        return np.einsum("ikl,il->ik", H, absP @ W)


def weighted_norm_bound(
    P: Any, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike],
    weights: np.ndarray, basis: str,
) -> float:
    """``||T^-1 A-hat T||_inf``, ``T = (I_N kron S) diag(w)``: an upper bound on rho(A-hat).

    One step of :func:`delay_free_rho_bound` with given weights (what a gain cache
    entry is verified with). See there for the bound and why it is rigorous.

    Parameters
    ----------
    P, A, C, L
        As in :func:`delay_free_spectral_radius` (``P`` dense or sparse).
    weights : numpy.ndarray, shape (N, n)
        Positive weights.
    basis : {"eigenvectors", "identity"}
        The basis ``S``.

    Returns
    -------
    float
        The bound (``inf`` if the basis is not usable or the weights not positive).
    """
    A_arr, G = _bound_gains(P, A, C, L)
    W = np.asarray(weights, dtype=float)
    if W.shape != G.shape[:2] or not np.all(W > 0) or not np.all(np.isfinite(W)):
        return float("inf")
    op = _bound_operator(P, A_arr, G, basis)
    if op is None:
        return float("inf")
    absP, H, inflation = op
    Y = _bound_step(absP, H, W)
    value = float(np.max(Y / W)) * inflation if Y.size else 0.0
    return value if math.isfinite(value) else float("inf")


def delay_free_rho_bound(
    P: Any,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    *,
    max_iter: int = BOUND_MAX_ITER,
    bases: Sequence[str] = BOUND_BASES,
) -> RhoBound:
    """A rigorous upper bound on rho(A-hat), A-hat = (I - K D_C-bar)(P kron A) (LCSYS2022
    eq. 12), in ``O(nnz(P) n + N n^2)`` work per step.

    The bound is an induced matrix norm, so it bounds the spectral radius
    (``rho(M) <= ||M||`` for every induced norm; Horn and Johnson, *Matrix Analysis*,
    Thm 5.6.9):

        rho(A-hat) = rho(T^-1 A-hat T) <= ||T^-1 A-hat T||_inf = max_k (|M| w)_k / w_k,

    with ``T = (I_N kron S) diag(w)``, ``M = (I_N kron S^-1) A-hat (I_N kron S)`` and
    ``w > 0``: the weighted infinity norm ``||x|| = max_k |x_k| / w_k`` in the basis
    ``S`` on every agent (the Collatz-Wielandt upper bound of the non-negative matrix
    ``|M|``, Horn and Johnson Thm 8.1.26, which bounds ``rho(M)`` by Thm 8.1.18). The
    blocks of ``M`` are ``p_ij S^-1 (I - L_i C_i) A S``, so
    ``(|M| w)_i = |S^-1 G_i A S| (|P| W)_i``: one sparse product with ``n`` columns and
    ``N`` small ones, linear in the links. ``S`` is the (complex) eigenvector basis of
    ``A`` when its condition number is at most :data:`BOUND_MAX_COND` (a rotation of
    ``A`` then costs nothing: ``|S^-1 A S|`` is diagonal with ``|lambda|``), else the
    identity. The weights ``w`` come from power steps on the non-negative ``|M|``
    (``w <- |M| w``, then the lazy ``w <- |M| w + r w`` for periodic graphs; every
    ``w`` gives a valid bound, the smallest is kept), which converge towards the
    Perron vector, where the bound is ``rho(|M|)``. It is a sufficient condition: it can
    exceed 1 while ``rho(A-hat) < 1`` (``rho(|M|) >= rho(M)``), then the caller falls
    back to the exact radius.

    Rounding is covered (so the bound holds for the exact ``A-hat``): the ``n x n``
    blocks are bounded elementwise with their product error and the inexact inverse of
    ``S`` (:func:`_bound_operator`), and the result is multiplied by
    ``1 + 4 (deg_max + n + 4) eps`` for the non-negative sums of the step.

    Parameters
    ----------
    P, A, C, L
        As in :func:`delay_free_spectral_radius` (``P`` dense or sparse).
    max_iter : int
        Power steps per basis.
    bases : sequence of str
        Bases ``S`` tried in order (the first that gives a bound below 1 ends the search).

    Returns
    -------
    RhoBound
        The smallest bound found, its basis, the steps taken and the weights.
    """
    A_arr, G = _bound_gains(P, A, C, L)
    N, n = G.shape[0], A_arr.shape[0]
    best = RhoBound(float("inf"), bases[0] if bases else "identity", 0, np.ones((N, n)))
    for basis in bases:
        op = _bound_operator(P, A_arr, G, basis)
        if op is None:
            continue
        absP, H, inflation = op
        W = np.ones((N, n))
        history: list[float] = []
        top, top_W, top_k = float("inf"), W, 0
        for k in range(1, max_iter + 1):
            Y = _bound_step(absP, H, W)
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                r = float(np.max(Y / W)) * inflation if Y.size else 0.0
            if not math.isfinite(r):
                break
            if r < top:
                top, top_W, top_k = r, W, k
            history.append(top)
            if top == 0.0:
                break
            if (top < 1.0 and len(history) > BOUND_STALL_STEPS
                    and history[-1 - BOUND_STALL_STEPS] - top < BOUND_STALL_RTOL * top):
                break
            # plain power steps first; lazy ones (not fooled by a periodic graph) after
            Z = Y if 2 * k <= max_iter else Y + r * W
            peak = float(np.max(Z))
            if not (peak > 0.0 and math.isfinite(peak)):
                break
            W = np.maximum(Z / peak, _BOUND_FLOOR)
        if top < best.bound:
            best = RhoBound(top, basis, top_k, top_W)
        if best.bound < 1.0:
            break
    return best


def augmented_spectral_radius(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    delays: ArrayLike,
    tau: int | None = None,
    compensated: bool = True,
    method: str = "auto",
) -> float:
    """Return the spectral radius of the augmented closed loop of :func:`augmented_closed_loop`.

    The matrix is block companion with first block row ``[M_0, ..., M_tau]``,
    ``M_r = (I - K D_C-bar)(P_r kron B_r)``, ``B_r = A^(r+1)`` (compensated,
    LCSYS2022 eq. 9) or ``A`` (uncompensated, delay-tolerant eq. 11); its eigenvalues
    are the roots of ``det(lambda^(tau+1) I - sum_r lambda^(tau-r) M_r)``.

    Parameters
    ----------
    P, A, C, L, delays, tau, compensated
        As in :func:`augmented_closed_loop`.
    method : {"auto", "dense", "structured"}, default "auto"
        ``"dense"``: ``max |numpy.linalg.eigvals|`` of the full
        ``(N n (tau+1))``-square matrix from :func:`augmented_closed_loop`.
        ``"structured"``: ARPACK (``scipy.sparse.linalg.eigs``, ``which="LM"``,
        ``k =`` :data:`ARPACK_K`, ``tol =`` :data:`ARPACK_TOL`, first run on the power
        :data:`AUGMENTED_ARPACK_POWER` with :data:`AUGMENTED_ARPACK_NCV` Krylov vectors)
        on a matrix-free companion operator. Its first block row is kept as ``nnz(P)`` blocks
        ``p_ij (I - L_i C_i) B_(r_ij)`` (block-sparse), or for dense ``P`` applied as
        ``(I - K D) vec(B_r X_r P_r^T)``; the identity shift is a copy. Trailing
        empty delay slots (``r`` above the largest edge delay) only add zero
        eigenvalues and are dropped. If ARPACK fails, dense eigenvalues are used up to
        :data:`DENSE_FALLBACK_MAX` (RuntimeWarning), else RuntimeError.
        ``"auto"``: dense when ``N n (tau+1) <=`` :data:`AUGMENTED_DENSE_SIZE_THRESHOLD`.

    Returns
    -------
    float
        ``rho`` of the augmented closed loop; ``inf`` if ``A^(r+1)`` overflows.
    """
    return augmented_radius_and_method(P, A, C, L, delays, tau, compensated, method)[0]


#: How :func:`augmented_radius_and_method` computed a radius: dense eigenvalues of the
#: whole matrix, ARPACK on the structured operator, dense eigenvalues after ARPACK
#: failed (with a RuntimeWarning), or no eigenproblem (the structured operator
#: overflows: ``inf``; or it is nilpotent: 0).
RADIUS_METHODS: tuple[str, ...] = ("dense eigenvalues", "ARPACK",
                                   "dense eigenvalues (ARPACK failed)", "no eigenproblem")

#: What the last structured radius of this thread used (set by :func:`_arpack_rho`).
_last_structured = threading.local()


def augmented_radius_and_method(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    delays: ArrayLike,
    tau: int | None = None,
    compensated: bool = True,
    method: str = "auto",
) -> tuple[float, str]:
    """:func:`augmented_spectral_radius` and how it was computed (one of :data:`RADIUS_METHODS`).

    Parameters
    ----------
    P, A, C, L, delays, tau, compensated, method
        As in :func:`augmented_spectral_radius`.

    Returns
    -------
    (float, str)
        The spectral radius (the same value :func:`augmented_spectral_radius` returns)
        and the method that computed it.
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    _check_method(method)
    d = _as_delays(P_arr, delays)
    if tau is None:
        tau = _max_edge_delay(P_arr, d)
    tau = _check_delay_range(P_arr, d, tau)
    G = _gain_blocks(L, C_list)
    N, n = P_arr.shape[0], A_arr.shape[0]
    if method == "dense" or (method == "auto"
                             and N * n * (tau + 1) <= AUGMENTED_DENSE_SIZE_THRESHOLD):
        with np.errstate(over="ignore", invalid="ignore"):
            M = augmented_closed_loop(P_arr, A_arr, C_list, L, d, tau, compensated)
        return spectral_radius(M), RADIUS_METHODS[0]
    index = np.where(P_arr != 0, d, 0)
    depth = _max_edge_delay(P_arr, d) + 1
    B = _delay_blocks(A_arr, depth, compensated)
    k = _root_scale(G, P_arr, index, A_arr, depth, compensated) if np.all(
        np.isfinite(B)) else 0  # overflow: inf, as the dense method gives
    if k and compensated:  # B_r = (A / 2^k)^(r+1): the same bits as A^(r+1) / 2^(k (r+1))
        B = _delay_blocks(np.ldexp(A_arr, -k), depth, True)
    elif k:
        B = np.ldexp(B, -k * np.arange(1, depth + 1)[:, None, None])
    row = _FirstRow(G, P_arr, index, B)
    _last_structured.method = RADIUS_METHODS[3]
    rho = _companion_rho(row, "augmented closed loop", AUGMENTED_ARPACK_POWER,
                         AUGMENTED_ARPACK_NCV, pair_check=True)
    return float(np.ldexp(rho, k)), _last_structured.method


#: :func:`_root_scale` leaves the companion unscaled when its root-size estimate lies
#: within ``2^-ROOT_SCALE_FREE .. 2^ROOT_SCALE_FREE``.
ROOT_SCALE_FREE: int = 3


def _root_scale(G: np.ndarray, P: np.ndarray, index: np.ndarray, A: np.ndarray,
                depth: int, compensated: bool) -> int:
    """The exponent ``k`` of the root scaling ``z = 2^k w`` of the block companion matrix.

    The companion with first row ``M_r / c^(r+1)`` has the eigenvalues ``z / c``, so
    ``rho = c rho(scaled)`` exactly (``c = 2^k``: every scaling is exact in floating
    point). ``c`` is the smallest power of two at least
    ``max_r ||M_r||_F^(1/(r+1))`` (the Fujiwara-type bound on the roots of
    ``det(z^R I - sum_r z^(R-1-r) M_r)``, up to a factor 2), so that the scaled
    problem has its roots near the unit circle; ``k = 0`` when that is within
    ``2^-``:data:`ROOT_SCALE_FREE` .. ``2^``:data:`ROOT_SCALE_FREE`. Without it ARPACK
    on the companion (the shift's identity blocks beside first-row blocks of size
    ``c^(r+1)``) returned values off by 1 % (``rho`` near 600) to 80x (``rho`` near
    6e-5) that passed its residual check (issue 34). The norms are computed from
    ``A`` divided by its norm (``A^(r+1)`` itself may overflow).
    """
    rows, cols = np.nonzero(P)
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        a = float(np.linalg.norm(A))
    if rows.size == 0 or not math.isfinite(a) or a == 0.0:
        return 0
    r_edge = index[rows, cols]
    Q = A / a
    Qr = Q.copy()
    best = -math.inf
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        for r in range(depth):
            if compensated and r > 0:
                Qr = Qr @ Q
                scale = float(np.linalg.norm(Qr))
                if not math.isfinite(scale) or scale == 0.0:
                    break
                log_a_r = (r + 1) * math.log2(a)  # ||M_r|| = 2^log_a_r ||G (P_r kron Qr)||
            else:
                log_a_r = math.log2(a)
            sel = r_edge == r
            if not np.any(sel):
                continue
            blocks = P[rows[sel], cols[sel], None, None] * (G[rows[sel]] @ Qr)
            norm = float(np.linalg.norm(blocks))
            if norm > 0 and math.isfinite(norm):
                best = max(best, (log_a_r + math.log2(norm)) / (r + 1))
    if not math.isfinite(best) or abs(best) <= ROOT_SCALE_FREE:
        return 0
    return math.ceil(best)


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
        For ``tau = 0`` it is ``rho(A-hat)``. For heterogeneous delays it is *not* an
        upper bound in general (the paper's Lemma 5 generalises from the homogeneous
        case without proof): e.g. ``N = 2``, ``n = 1``, ``A = -1.5``,
        ``P = [[0.7, 0.3], [0.7, 0.3]]``, ``L = (1.8, -1.0)``, ``C_i = 1``, link
        ``1 -> 0`` delayed by 1: bound 0.3, exact 1.258. Compare with
        :func:`augmented_spectral_radius`.
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    rho = _lcsys_rho(P_arr, A_arr, _gain_blocks(L, C_list), tau)
    return float(rho ** (1.0 / (tau + 1)))


def _lcsys_rho(P: np.ndarray, A: np.ndarray, G: np.ndarray, tau: int) -> float:
    """``rho((I - K D_C-bar)(P kron A^(tau+1)))`` (Theorem 1's quantity)."""
    with np.errstate(over="ignore", invalid="ignore"):
        A_pow = np.linalg.matrix_power(A, tau + 1)
    return _block_rho(G, P, A_pow)


def delay_bound_tolerant(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike], tau: int
) -> float:
    """Return the delay-tolerant paper's bound rho(A-hat)^(1/(tau+1)) (its Theorem 1, Lemma 5).

    ``A-hat = (I - K D_C-bar)(P kron A)`` is the delay-free closed loop. The paper
    claims ``rho`` of the uncompensated augmented closed loop (its eq. 11) is at most
    this value for delays bounded by ``tau``; for ``tau = 0`` it is ``rho(A-hat)``.
    The claim does not hold in general for heterogeneous delays: in the example of
    :func:`delay_bound_lcsys`, ``rho(A-hat) = 0.06``, bound 0.245, exact 1.206.

    Parameters
    ----------
    P, A, C, L
        As in :func:`delay_free_closed_loop`.
    tau : int
        Delay bound ``tau >= 0``.

    Returns
    -------
    float
        ``rho(A-hat) ** (1 / (tau + 1))``.
    """
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    return float(delay_free_spectral_radius(P, A, C, L) ** (1.0 / (tau + 1)))


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
    (i.e. the first failing ``tau`` minus one). This is
    ``tau_star_report(...).contiguous``; the scan stops at the first failure. When
    ``A`` has negative or complex unstable eigenvalues the condition need not be
    monotone in ``tau``; :func:`tau_star_report` lists the isolated passing values.

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
    G = _gain_blocks(L, C_list)
    A_pow = A_arr.copy()
    for tau in range(tau_max + 1):
        if tau > 0:
            with np.errstate(over="ignore", invalid="ignore"):
                A_pow = A_pow @ A_arr
        if not _block_rho(G, P_arr, A_pow) < 1.0:
            return tau - 1 if tau > 0 else None
    return tau_max


@dataclass(frozen=True)
class TauStar:
    """Theorem 1's condition ``rho((I - K D_C-bar)(P kron A^(tau+1))) < 1`` over ``tau``.

    Attributes
    ----------
    contiguous : int or None
        Largest ``tau`` such that every ``tau' <= tau`` passes (Theorem 1's tau*,
        what :func:`tau_star` returns); ``None`` if ``tau = 0`` fails.
    isolated : tuple of int
        Passing ``tau`` above ``contiguous + 1`` (up to ``tau_max``): the condition is
        not monotone in ``tau`` when ``A`` has negative or complex unstable
        eigenvalues. Theorem 1 as stated covers only ``tau <= contiguous``; for an
        isolated ``tau`` the eq. (26) bound is below 1 at that ``tau`` only.
    values : tuple of float
        ``rho((I - K D_C-bar)(P kron A^(tau+1)))`` for ``tau = 0, ..., tau_max``
        (``inf`` once ``A^(tau+1)`` overflows).
    """

    contiguous: int | None
    isolated: tuple[int, ...]
    values: tuple[float, ...]

    @property
    def tau_max(self) -> int:
        """Largest ``tau`` scanned."""
        return len(self.values) - 1

    @property
    def passing(self) -> tuple[int, ...]:
        """Every ``tau`` in ``0..tau_max`` whose value is below 1."""
        return tuple(t for t, v in enumerate(self.values) if v < 1.0)

    @property
    def monotone(self) -> bool:
        """Whether ``values`` is non-decreasing in ``tau``."""
        v = np.asarray(self.values)
        return bool(np.all(v[1:] >= v[:-1]))


def tau_star_report(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    tau_max: int = DEFAULT_TAU_MAX,
    method: str = "auto",
) -> TauStar:
    """Scan Theorem 1's condition over ``tau = 0..tau_max`` without assuming monotonicity.

    Parameters
    ----------
    P, A, C, L
        As in :func:`tau_star`.
    tau_max : int, default DEFAULT_TAU_MAX
        Largest ``tau`` scanned.
    method : {"auto", "dense", "structured"}, default "auto"
        How each ``(N n)``-square spectral radius is computed, see
        :func:`delay_free_spectral_radius`.

    Returns
    -------
    TauStar
        ``values[tau] = rho((I - K D_C-bar)(P kron A^(tau+1)))``, the contiguous
        tau* and the isolated passing ``tau``.
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    _check_method(method)
    tau_max = int(tau_max)
    if tau_max < 0:
        raise ValueError(f"tau_max must be >= 0, got {tau_max}")
    G = _gain_blocks(L, C_list)
    values: list[float] = []
    A_pow = A_arr.copy()
    for tau in range(tau_max + 1):
        if tau > 0:
            with np.errstate(over="ignore", invalid="ignore"):
                A_pow = A_pow @ A_arr
        values.append(_block_rho(G, P_arr, A_pow, method))
    passing = [v < 1.0 for v in values]
    contiguous = None
    for tau, ok in enumerate(passing):
        if not ok:
            break
        contiguous = tau
    start = (contiguous + 2) if contiguous is not None else 1
    isolated = tuple(t for t in range(start, tau_max + 1) if passing[t])
    return TauStar(contiguous=contiguous, isolated=isolated, values=tuple(values))


# ---------------------------------------------------------------------------
# convergence time and decay rate (LCSYS2022 Lemma 2, eq. 14; delay-tolerant eq. 17)
# ---------------------------------------------------------------------------


def _check_rho(rho: float) -> float:
    rho = float(rho)
    if math.isnan(rho) or rho < 0:
        raise ValueError(f"a spectral radius must be >= 0, got {rho}")
    return rho


def convergence_time_order(rho: float) -> float:
    """Return ``1 / (1 - rho)``, the order of the convergence time (LCSYS2022 Lemma 2).

    Lemma 2: the error dynamics with spectral radius ``rho`` converge in time
    ``Theta(1 / (1 - rho))``. ``rho`` is ``rho(A-hat)`` for the delay-free loop
    (eq. 12) or the augmented closed loop's spectral radius for eq. (10).

    Parameters
    ----------
    rho : float
        Spectral radius, ``>= 0``.

    Returns
    -------
    float
        ``1 / (1 - rho)``; ``inf`` if ``rho >= 1`` (no convergence).
    """
    rho = _check_rho(rho)
    return 1.0 / (1.0 - rho) if rho < 1.0 else math.inf


def decay_rate(rho: float, tau: int) -> float | None:
    """Return ``1 - rho^(1/(tau+1))``, the form of LCSYS2022 eq. (14) and delay-tolerant eq. (17).

    Parameters
    ----------
    rho : float
        Spectral radius, ``>= 0``: ``rho((I - K D_C-bar)(P kron A^(tau+1)))`` for
        eq. (14), ``rho(A-hat)`` for eq. (17).
    tau : int
        Delay bound ``tau >= 0``.

    Returns
    -------
    float or None
        The rate, in ``(0, 1]``; ``None`` if ``rho >= 1`` (the expression is not a
        decay rate: no decay is guaranteed).
    """
    rho = _check_rho(rho)
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    return 1.0 - rho ** (1.0 / (tau + 1)) if rho < 1.0 else None


def decay_rate_lcsys(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike], tau: int
) -> float | None:
    """Return LCSYS2022 eq. (14), ``1 - rho((I - K D_C-bar)(P kron A^(tau+1)))^(1/(tau+1))``.

    The geometric decay rate of the error (10) for homogeneous delays ``tau``
    (``1 -`` :func:`delay_bound_lcsys`). ``None`` if the spectral radius is ``>= 1``
    (``tau`` above Theorem 1's condition).
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    return decay_rate(_lcsys_rho(P_arr, A_arr, _gain_blocks(L, C_list), tau), tau)


def decay_rate_tolerant(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike], tau: int
) -> float | None:
    """Return delay-tolerant eq. (17), ``1 - rho(A-hat)^(1/(tau+1))``.

    The paper's best-case decay rate of its uncompensated error (13) for delays
    bounded by ``tau`` (``1 -`` :func:`delay_bound_tolerant`). ``None`` if
    ``rho(A-hat) >= 1``.
    """
    return decay_rate(delay_free_spectral_radius(P, A, C, L), tau)


def convergence_time_delay_free(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike]
) -> float:
    """Return ``1 / (1 - rho(A-hat))`` (Lemma 2, delay-free error eq. 12); ``inf`` if unstable."""
    return convergence_time_order(delay_free_spectral_radius(P, A, C, L))


def convergence_time_augmented(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    delays: ArrayLike,
    tau: int | None = None,
    compensated: bool = True,
    method: str = "auto",
) -> float:
    """Return ``1 / (1 - rho)`` of the augmented closed loop (Lemma 2, eq. 10); ``inf`` if unstable.

    Arguments as in :func:`augmented_spectral_radius`.
    """
    return convergence_time_order(
        augmented_spectral_radius(P, A, C, L, delays, tau, compensated, method)
    )


# ---------------------------------------------------------------------------
# time-varying delays
# ---------------------------------------------------------------------------


def closed_loop_sequence_growth(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    L: Sequence[ArrayLike],
    delay_patterns: Sequence[ArrayLike],
    tau: int,
    compensated: bool = True,
    *,
    full_max: int = GROWTH_FULL_MAX,
    block: int = GROWTH_BLOCK,
    seed: int = 0,
) -> float:
    """Return the realised growth rate ``(1/k) log ||A-hat[k] ... A-hat[1]||_2``.

    ``A-hat[s]`` is the augmented closed loop (:func:`augmented_closed_loop`, depth
    ``tau``) of ``delay_patterns[s-1]``, applied matrix-free. The product is never
    formed by multiplying the factors out: each step applies ``A-hat[s]`` to the
    running block ``Q``, divides ``Q`` by its Frobenius norm and accumulates the log
    of that norm; at the end ``log ||Q||_2`` is added, so the result is exact up to
    rounding and cannot overflow.

    * Augmented dimension ``D = N n (tau+1) <= full_max``: ``Q`` starts as ``I_D``,
      the value is ``(1/k) log ||A-hat[k] ... A-hat[1]||_2`` itself.
    * Larger ``D``: ``Q`` starts as ``block`` random orthonormal vectors ``V``
      (``numpy.random.default_rng(seed)``) and the value is
      ``(1/k) log ||A-hat[k] ... A-hat[1] V||_2``, a lower bound on the full value
      that differs from it by ``O(1/k)`` for generic ``V`` (same asymptotic rate).

    For a constant pattern the value tends to ``log rho`` of its augmented matrix
    (Gelfand's formula).

    Parameters
    ----------
    P, A, C, L, compensated
        As in :func:`augmented_closed_loop`.
    delay_patterns : sequence of array_like of int, shape (N, N)
        Effective delays at steps ``1..k``; edge delays in ``0..tau``.
    tau : int
        Augmentation depth shared by all steps.
    full_max, block, seed : int
        See above.

    Returns
    -------
    float
        The growth rate; ``-inf`` if the product is exactly zero, ``inf`` if
        ``A^(tau+1)`` overflows.
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    tau = int(tau)
    if tau < 0:
        raise ValueError(f"tau must be >= 0, got {tau}")
    patterns = list(delay_patterns)
    if not patterns:
        raise ValueError("delay_patterns must contain at least one step")
    G = _gain_blocks(L, C_list)
    N, n = P_arr.shape[0], A_arr.shape[0]
    D = N * n * (tau + 1)
    B = _delay_blocks(A_arr, tau + 1, compensated)
    if not np.all(np.isfinite(B)):
        return math.inf
    edge = P_arr != 0
    if D <= int(full_max):
        Q = np.eye(D)
    else:
        block = int(block)
        if block < 1:
            raise ValueError(f"block must be >= 1, got {block}")
        rng = np.random.default_rng(seed)
        Q = np.linalg.qr(rng.standard_normal((D, min(block, D))))[0]
    rows: dict[bytes, _FirstRow] = {}
    log_norm = 0.0
    for s, pattern in enumerate(patterns):
        try:
            d = _as_delays(P_arr, pattern)
            _check_delay_range(P_arr, d, tau)
        except ValueError as exc:
            raise ValueError(f"delay_patterns[{s}]: {exc}") from None
        index = np.where(edge, d, 0)
        key = index.tobytes()
        row = rows.get(key)
        if row is None:
            if len(rows) >= 256:
                rows.clear()
            row = rows[key] = _FirstRow(G, P_arr, index, B)
        with np.errstate(over="ignore", invalid="ignore"):
            Q = row.companion_apply(Q)
            scale = float(np.linalg.norm(Q))
        if scale == 0.0:
            return -math.inf
        if not math.isfinite(scale):
            return math.inf
        Q /= scale
        log_norm += math.log(scale)
    return (log_norm + math.log(float(np.linalg.norm(Q, 2)))) / len(patterns)
