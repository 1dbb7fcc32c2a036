"""Multi-sensor observable decomposition (aoi paper, Lemma 1; Mitra & Sundaram [9]).

Given A (n x n) and sensor outputs C_1..C_N with (A, C) observable, find a similarity
transform x = T z such that

    A-bar = T^-1 A T   is block lower-triangular, blocks A_jq (n_j x n_q), A_jq = 0 for q > j,
    C-bar_i = C_i T = [C_i1 ... C_ii 0 ... 0],

with (A_jj, C_jj) observable for every j. Substate z^(j) (dimension n_j >= 0, possibly
empty) is the part of the state that sensor j observes beyond what sensors 1..j-1
observe; node j is its unique *source node*.

Construction (orthogonal, no powers of A): let W_0 = I. For j = 1..N, with W_{j-1}
an orthonormal basis of the unobservable subspace of (A, [C_1; ...; C_{j-1}]) (an
A-invariant subspace, so A W = W A_r with A_r = W^T A W), compute the unobservable
subspace U of (A_r, C_j W) as the largest A_r-invariant subspace inside ker(C_j W),
by the orthogonal iteration

    N_0 = ker C,   N_{t+1} = { v in N_t : A v in N_t }   (SVD null spaces),

take an orthonormal complement V of U, and set the j-th block of T to W V and
W_j = W U. Then T = [W_0 V_1, W_1 V_2, ..., W_{N-1} V_N] is orthogonal (T^-1 = T^T),
later blocks span A-invariant subspaces (hence the zero blocks above the diagonal of
A-bar) inside ker C_j (hence the zeros of C-bar_j), and (A_jj, C_jj) is observable
(Kalman decomposition of (A_r, C_j W)). If W_N is not empty, (A, C) is not observable
and :class:`NotObservableError` says so, with the dimension of the unobservable
subspace.

Rank decisions use singular values against ``rtol`` times the norm of the matrix
concerned (C_j for its null space, A for the invariance test); the smallest kept and
largest dropped singular values are kept in :attr:`MultiSensorDecomposition.margins`
so a near-unobservable decision is visible.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "DEFAULT_RTOL",
    "NotObservableError",
    "MultiSensorDecomposition",
    "unobservable_subspace",
    "multi_sensor_decomposition",
]

#: Relative tolerance of the rank decisions.
DEFAULT_RTOL = 1e-9


class NotObservableError(ValueError):
    """(A, C) with C = [C_1; ...; C_N] is not observable; Lemma 1 does not apply."""

    def __init__(self, message: str, unobservable_dimension: int) -> None:
        super().__init__(message)
        self.unobservable_dimension = unobservable_dimension


def _null_space(M: np.ndarray, tol: float) -> tuple[np.ndarray, float, float]:
    """Orthonormal basis of {v : M v ~ 0} (singular values <= tol), with margins.

    Returns (basis (c x k), smallest singular value kept as rank, largest one dropped).
    """
    cols = M.shape[1]
    if M.shape[0] == 0 or cols == 0:
        return np.eye(cols), np.inf, 0.0
    _, s, vt = np.linalg.svd(M, full_matrices=True)
    rank = int(np.sum(s > tol))
    kept = float(s[rank - 1]) if rank > 0 else np.inf
    dropped = float(s[rank]) if rank < len(s) else 0.0
    return vt[rank:].T.copy(), kept, dropped


def unobservable_subspace(A: ArrayLike, C: ArrayLike, rtol: float = DEFAULT_RTOL, *,
                          scale_a: float | None = None, scale_c: float | None = None
                          ) -> tuple[np.ndarray, float, float]:
    """Orthonormal basis of the unobservable subspace of (A, C).

    The largest A-invariant subspace contained in ker C, by the orthogonal iteration
    N_0 = ker C, N_{t+1} = {v in N_t : (I - P_t) A v = 0} (P_t the projector on N_t).
    Singular values below ``rtol * scale_c`` (null space of C) or ``rtol * scale_a``
    (invariance) count as zero; the scales default to ||C|| and ||A||. When (A, C) is
    a restriction of a larger system (as in the decomposition), pass the norms of the
    original matrices: a restricted C that is rounding noise must not count as a rank.

    Returns
    -------
    (U, kept, dropped) : (numpy.ndarray (n x u), float, float)
        The basis and the rank margins (smallest singular value counted as non-zero,
        largest counted as zero, over all rank decisions).
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    C = np.asarray(C, dtype=float).reshape(-1, n)
    if scale_c is None:
        scale_c = float(np.linalg.norm(C, 2)) if C.size else 0.0
    if scale_a is None:
        scale_a = float(np.linalg.norm(A, 2)) if A.size else 0.0
    U, kept, dropped = _null_space(C, rtol * scale_c)
    while U.shape[1] > 0:
        AU = A @ U
        residual = AU - U @ (U.T @ AU)
        basis, k2, d2 = _null_space(residual, rtol * max(scale_a, np.finfo(float).tiny))
        kept, dropped = min(kept, k2), max(dropped, d2)
        if basis.shape[1] == U.shape[1]:
            break
        U = U @ basis
        # re-orthonormalise against drift
        U, _ = np.linalg.qr(U)
    return U, kept, dropped


@dataclass(frozen=True)
class MultiSensorDecomposition:
    """Result of :func:`multi_sensor_decomposition` (Lemma 1).

    Attributes
    ----------
    T : numpy.ndarray (n x n)
        Orthogonal similarity transform, x = T z, z = T^T x.
    A_bar : numpy.ndarray (n x n)
        T^T A T, block lower-triangular.
    C_bar : tuple of numpy.ndarray
        C_i T, each (m_i x n), zero beyond block i.
    dims : tuple of int
        n_j, the dimension of substate j (0 allowed); sum = n.
    margins : tuple of (float, float)
        Per sensor, the smallest singular value decided non-zero and the largest
        decided zero (relative decisions, see module doc).
    residual : float
        Largest entry of T^T A T and C_i T that the structure says is zero (A_jq for
        q > j, C_iq for q > i), relative to the norm of A resp. C_i, before those
        entries were set to exact zeros in ``A_bar`` and ``C_bar``.
    """

    T: np.ndarray
    A_bar: np.ndarray
    C_bar: tuple[np.ndarray, ...]
    dims: tuple[int, ...]
    margins: tuple[tuple[float, float], ...]
    residual: float = 0.0

    @property
    def n_states(self) -> int:
        return self.T.shape[0]

    @property
    def n_sensors(self) -> int:
        return len(self.dims)

    @property
    def offsets(self) -> tuple[int, ...]:
        """Start index of each substate in z (length N + 1, last = n)."""
        out = [0]
        for d in self.dims:
            out.append(out[-1] + d)
        return tuple(out)

    def block(self, j: int) -> slice:
        """The slice of substate j in z."""
        o = self.offsets
        return slice(o[j], o[j + 1])

    def A_block(self, j: int, q: int) -> np.ndarray:
        """A_jq (n_j x n_q)."""
        return self.A_bar[self.block(j), self.block(q)]

    def C_block(self, i: int, q: int) -> np.ndarray:
        """C_iq (m_i x n_q)."""
        return self.C_bar[i][:, self.block(q)]

    @property
    def sources(self) -> tuple[int, ...]:
        """Source nodes of non-empty substates (node j is the source of substate j)."""
        return tuple(j for j, d in enumerate(self.dims) if d > 0)

    def to_z(self, x: ArrayLike) -> np.ndarray:
        return self.T.T @ np.asarray(x, dtype=float)

    def to_x(self, z: ArrayLike) -> np.ndarray:
        return self.T @ np.asarray(z, dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {
            "dims": list(self.dims),
            "sources": list(self.sources),
            # smallest singular value counted as a rank (None: no decision), largest
            # counted as zero
            "margins": [[float(a) if np.isfinite(a) else None, float(b)]
                        for a, b in self.margins],
            "residual": float(self.residual),
        }


def multi_sensor_decomposition(A: ArrayLike, C: Sequence[ArrayLike], *,
                               rtol: float = DEFAULT_RTOL) -> MultiSensorDecomposition:
    """Compute the Lemma 1 decomposition of (A, C_1..C_N) with orthogonal transforms.

    Parameters
    ----------
    A : array (n x n)
    C : sequence of arrays (m_i x n); m_i = 0 (a sensor with no output) is allowed.
    rtol : float
        Relative tolerance of the rank decisions.

    Raises
    ------
    NotObservableError
        If (A, [C_1; ...; C_N]) is not observable.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"A must be square, got shape {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError("A has non-finite entries")
    Cs = []
    for i, Ci in enumerate(C):
        Ci = np.asarray(Ci, dtype=float)
        if Ci.size == 0:
            Ci = np.zeros((0, n))
        Ci = Ci.reshape(-1, n) if Ci.ndim < 2 else Ci
        if Ci.shape[1] != n:
            raise ValueError(f"C_{i} must have {n} columns, got shape {Ci.shape}")
        if not np.all(np.isfinite(Ci)):
            raise ValueError(f"C_{i} has non-finite entries")
        Cs.append(Ci)
    if not Cs:
        raise ValueError("at least one sensor is needed")
    norm_a = float(np.linalg.norm(A, 2)) if n else 0.0
    W = np.eye(n)
    blocks: list[np.ndarray] = []
    dims: list[int] = []
    margins: list[tuple[float, float]] = []
    for Ci in Cs:
        r = W.shape[1]
        if r == 0:
            blocks.append(np.zeros((n, 0)))
            dims.append(0)
            margins.append((np.inf, 0.0))
            continue
        Ar = W.T @ A @ W
        Cr = Ci @ W
        norm_c = float(np.linalg.norm(Ci, 2)) if Ci.size else 0.0
        U, kept, dropped = unobservable_subspace(Ar, Cr, rtol, scale_a=norm_a, scale_c=norm_c)
        margins.append((kept, dropped))
        # orthonormal complement of U in R^r
        if U.shape[1] == 0:
            V = np.eye(r)
        else:
            q, _ = np.linalg.qr(np.hstack([U, np.eye(r)]), mode="complete")
            V = q[:, U.shape[1]:r]
            # make V exactly orthogonal to U (numerically) via the projector's range
            V = V - U @ (U.T @ V)
            V, _ = np.linalg.qr(V)
        blocks.append(W @ V)
        dims.append(V.shape[1])
        W = W @ U
    if W.shape[1] > 0:
        raise NotObservableError(
            f"(A, C) is not observable: the unobservable subspace of (A, [C_1; ...; "
            f"C_{len(Cs)}]) has dimension {W.shape[1]} of n = {n}, so no sensor is the "
            "source of those states (aoi paper Lemma 1 needs (A, C) observable)",
            W.shape[1],
        )
    T = np.hstack(blocks) if blocks else np.zeros((n, 0))
    A_bar = T.T @ A @ T
    C_bar = tuple(Ci @ T for Ci in Cs)
    # exact structural zeros (they are zero up to rounding by construction)
    offsets = np.cumsum([0] + dims)
    tiny = np.finfo(float).tiny
    residual = 0.0
    na = max(float(np.linalg.norm(A, 2)), tiny)
    for j in range(len(dims)):
        upper = A_bar[offsets[j]:offsets[j + 1], offsets[j + 1]:]
        if upper.size:
            residual = max(residual, float(np.abs(upper).max()) / na)
        A_bar[offsets[j]:offsets[j + 1], offsets[j + 1]:] = 0.0
    for i, Ci in enumerate(C_bar):
        tail = Ci[:, offsets[i + 1]:]
        if tail.size:
            nc = max(float(np.linalg.norm(Cs[i], 2)), tiny)
            residual = max(residual, float(np.abs(tail).max()) / nc)
    C_bar = tuple(np.concatenate([Ci[:, :offsets[i + 1]],
                                  np.zeros((Ci.shape[0], n - offsets[i + 1]))], axis=1)
                  for i, Ci in enumerate(C_bar))
    return MultiSensorDecomposition(T=T, A_bar=A_bar, C_bar=C_bar, dims=tuple(dims),
                                    margins=tuple(margins), residual=residual)
