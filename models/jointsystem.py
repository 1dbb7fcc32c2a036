"""The joint linear system of plant state and estimation error under fixed delays.

The papers analyse the estimation error e_k = x_k - x-hat_k on its own: the augmented
recursion e_k = A-hat-bar e_{k-1} + eta_k of LCSYS2022 eq. (9)-(10) (compensating
estimator) or eq. (11) of the delay-tolerant paper (uncompensated estimator). That is
the whole story only when no term of the state x_k itself is left in eta_k. Under fixed
(time-invariant) delays both estimators are linear, so the plant history
X_k = (x_k; ...; x_{k-D}) and the error history E_k = (e_k; ...; e_{k-D}) (D the largest
delay) form one linear system, block lower-triangular because the plant does not see
the estimates::

    X_k = S X_{k-1} + (nu_k; 0; ...)              S: first block row (A, 0, ..., 0)
    E_k = A-hat-bar E_{k-1} + F X_{k-1} + noise    F: the forcing of the error by the state

Derivation (agent i, step k, link j -> i with effective delay r_ij, B_ij the matrix the
estimator applies to x-hat^j_{k-1-r}: A^(r+1) with compensation, A without). With
x-hat = x - e, eqs. (4)/(6) and (5)/(7) give::

    e^i_k = (I - L_i C_i) [ p_ii A e^i_{k-1} + sum_j p_ij B_ij e^j_{k-1-r_ij}
                            + (1 - p_ii) A x_{k-1} - sum_j p_ij B_ij x_{k-1-r_ij} + nu_k ]
            - L_i zeta^i_k

The state part is F: per agent i, ``(I - L_i C_i) [(1 - p_ii) A x_{k-1} - sum_j p_ij
B_ij x_{k-1-r_ij}]``. With compensation and a row-stochastic P it is
``sum_j p_ij (I - L_i C_i)(A x_{k-1} - A^(r+1) x_{k-1-r})``, pure process noise: the
state's motion cancels. Without compensation it is
``sum_j p_ij (I - L_i C_i) A (x_{k-1} - x_{k-1-r})
= sum_j p_ij (I - L_i C_i) [(A^(r+1) - A) x_{k-1-r} + noise]``: the moving state forces
the error, and eq. (11) leaves this term out.

Spectrum. The joint matrix has the eigenvalues of A-hat-bar (the error recursion) and
those of S (the eigenvalues of A, and zeros). A plant eigenvalue lambda shows in the
error iff (a) the forcing does not annihilate its generalised eigenspace V (for x in V
on a plant trajectory, x_{k-1-r} = T^(-r) x_{k-1} with T = A restricted to V, so the
forcing of agent i is ``(I - L_i C_i) V [(1 - p_ii) T - sum_j p_ij T_ij]``, T_ij = T
(compensated) or T^(1 - r_ij) (uncompensated)) and (b) the mode is excited: the process
noise Q or the prior's second moment x0_cov + x0_mean x0_mean^T has a component on it
(its left generalised eigenspace). The error then grows as

    rho = max(rho(A-hat-bar), max |lambda| over the forced, excited plant modes)

``geometric`` (rho > 1: the MSE grows as rho^2 per step), ``polynomial`` (rho = 1 within
:data:`MODULUS_TOLERANCE`: an error recursion with a unit eigenvalue, or a forced plant
mode on the unit circle driven by noise or in a Jordan block; e.g. a rotation with
noise: the state wanders like a random walk and the MSE grows linearly) or ``bounded``
(rho < 1; also a forced unit-circle mode excited only by the prior: a persistent but
bounded oscillation).

The block update (LCSYS2022 eqs. 15-16) with every delay within its bound tau is the
compensated case on the block time scale (A^(tau+1) for A, no delay), with rates taken
to the power 1/(tau+1) per step.

Only numpy and scipy are used (models layer).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from netsim.models.validation import check_system as _check_system
from numpy.typing import ArrayLike

__all__ = [
    "BOUNDED",
    "CLUSTER_TOLERANCE",
    "EXCITATION_TOLERANCE",
    "FORCING_TOLERANCE",
    "GEOMETRIC",
    "GROWTH_KINDS",
    "MODULUS_TOLERANCE",
    "POLYNOMIAL",
    "RECURSION_BLOCK",
    "RECURSION_COMPENSATED",
    "RECURSION_UNCOMPENSATED",
    "JointAnalysis",
    "PlantMode",
    "block_joint_analysis",
    "forcing_matrix",
    "joint_analysis",
    "joint_matrix",
    "plant_modes",
]

#: The error recursions analysed here, by the identifiers estimator families declare
#: (the same strings as ``netsim.estimators.registry.RECURSION_*``): LCSYS2022 eq. (9)
#: (compensating estimator), the delay-tolerant paper's eq. (11) (uncompensated) and
#: LCSYS2022 eqs. (15)-(16) (block update).
RECURSION_COMPENSATED = "lcsys2022-eq9"
RECURSION_UNCOMPENSATED = "delay-tolerant-eq11"
RECURSION_BLOCK = "lcsys2022-eq15"

GEOMETRIC = "geometric"
POLYNOMIAL = "polynomial"
BOUNDED = "bounded"
#: The growth kinds of :attr:`JointAnalysis.growth`.
GROWTH_KINDS = (GEOMETRIC, POLYNOMIAL, BOUNDED)

#: A spectral radius or eigenvalue modulus within this of 1 counts as 1 (polynomial, not
#: geometric, growth).
MODULUS_TOLERANCE = 1e-9
#: Eigenvalues of A closer than this (relative to max(1, max |lambda|)) form one cluster
#: (a Jordan block's computed eigenvalues spread by about eps^(1/size)); the cluster's
#: mean eigenvalue is accurate to round-off.
CLUSTER_TOLERANCE = 1e-5
#: The forcing of a mode counts when its norm exceeds this times ||T|| (T: A on the mode).
FORCING_TOLERANCE = 1e-9
#: A mode counts as excited when its share of Q (or of the prior's second moment)
#: exceeds this times ||Q|| (the prior's norm).
EXCITATION_TOLERANCE = 1e-12


@dataclass(frozen=True)
class PlantMode:
    """One eigenvalue cluster of A and how it enters the estimation error.

    Attributes
    ----------
    eigenvalue : complex
        The cluster's mean eigenvalue.
    multiplicity : int
        Algebraic multiplicity (the cluster's size).
    defective : bool
        Fewer independent eigenvectors than the multiplicity (a Jordan block: the mode
        grows polynomially even at |lambda| = 1).
    forcing : float
        max_i ||(I - L_i C_i) V G_i|| / ||T||: the relative size of the forcing of the
        error by this mode (0 for a mode the estimator cancels).
    forced : bool
        ``forcing > FORCING_TOLERANCE``.
    noise : bool
        The process noise Q has a component on the mode.
    prior : bool
        The prior's second moment x0_cov + x0_mean x0_mean^T has a component on it.
    """

    eigenvalue: complex
    multiplicity: int
    defective: bool
    forcing: float
    forced: bool
    noise: bool
    prior: bool

    @property
    def modulus(self) -> float:
        """|lambda| (per step)."""
        return abs(self.eigenvalue)

    @property
    def excited(self) -> bool:
        """Excited by the process noise or by the prior."""
        return self.noise or self.prior

    @property
    def enters(self) -> bool:
        """Forced and excited: the mode shows in the error."""
        return self.forced and self.excited

    def to_dict(self) -> dict[str, Any]:
        return {"eigenvalue": [float(self.eigenvalue.real), float(self.eigenvalue.imag)],
                "modulus": float(self.modulus), "multiplicity": self.multiplicity,
                "defective": self.defective, "forcing": float(self.forcing),
                "forced": self.forced, "noise": self.noise, "prior": self.prior}


@dataclass(frozen=True)
class JointAnalysis:
    """How the error of a linear estimator under fixed delays grows (module docstring).

    Attributes
    ----------
    recursion : str
        :data:`RECURSION_COMPENSATED` (LCSYS2022 eq. 9), :data:`RECURSION_UNCOMPENSATED`
        (delay-tolerant eq. 11) or :data:`RECURSION_BLOCK` (LCSYS2022 eqs. 15-16).
    rho_error_recursion : float
        Spectral radius of the error recursion alone (A-hat-bar), per step.
    modes : tuple of PlantMode
        The eigenvalue clusters of A (per step) and how each enters the error.
    rho_forcing : float
        max |lambda| over the forced, excited plant modes (0 if none), per step.
    rho : float
        max(rho_error_recursion, rho_forcing): the error's growth rate per step.
    growth : str
        ``geometric``, ``polynomial`` or ``bounded``.
    mse_growth_factor : float
        Per-step growth factor of the MSE: rho^2 (geometric; bounded: the decay of the
        transient), 1 for polynomial growth.
    reason : str
        One line in words.
    period : int
        Steps per update (tau + 1 for the block update, else 1).
    """

    recursion: str
    rho_error_recursion: float
    modes: tuple[PlantMode, ...]
    rho_forcing: float
    rho: float
    growth: str
    mse_growth_factor: float
    reason: str
    period: int = 1

    @property
    def forced_modes(self) -> tuple[PlantMode, ...]:
        """The plant modes that are forced and excited (they show in the error)."""
        return tuple(m for m in self.modes if m.enters)

    @property
    def forced_eigenvalues(self) -> tuple[complex, ...]:
        """Eigenvalues of the forced, excited plant modes."""
        return tuple(m.eigenvalue for m in self.forced_modes)

    def to_dict(self) -> dict[str, Any]:
        return {
            "recursion": self.recursion,
            "rho_error_recursion": _num(self.rho_error_recursion),
            "rho_forcing": _num(self.rho_forcing),
            "rho": _num(self.rho),
            "growth": self.growth,
            "mse_growth_factor": _num(self.mse_growth_factor),
            "forced_eigenvalues": [[float(z.real), float(z.imag)]
                                   for z in self.forced_eigenvalues],
            "modes": [m.to_dict() for m in self.modes],
            "period": self.period,
            "reason": self.reason,
        }


def _num(value: float) -> float | str | None:
    if value is None or math.isnan(value):
        return None
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return float(value)


# ---------------------------------------------------------------------------
# the explicit joint matrix (small systems; documentation and cross-checks)
# ---------------------------------------------------------------------------


def _delay_matrix(P: np.ndarray, delays: ArrayLike) -> np.ndarray:
    d = np.asarray(delays)
    if d.shape != P.shape:
        raise ValueError(f"delays must have shape {P.shape} like P, got {d.shape}")
    if np.any((d < 0) & (P != 0)):
        raise ValueError("delays of the links must be >= 0")
    return np.where(P != 0, d, 0).astype(np.int64)


def _gains(L: Sequence[ArrayLike], C: list[np.ndarray]) -> list[np.ndarray]:
    out = []
    for i, (Li, Ci) in enumerate(zip(L, C, strict=True)):
        arr = np.asarray(Li, dtype=float).reshape(Ci.shape[1], Ci.shape[0])
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"L[{i}] contains non-finite entries")
        out.append(arr)
    return out


def forcing_matrix(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike],
                   delays: ArrayLike, compensated: bool) -> np.ndarray:
    """The forcing F of the error by the plant history (module docstring).

    Parameters
    ----------
    P, A, C, L, delays
        As in :func:`netsim.models.augmented.augmented_closed_loop` (``delays[i, j]``:
        the effective delay r_ij of link j -> i).
    compensated : bool
        B_ij = A^(r_ij + 1) (True) or A (False).

    Returns
    -------
    numpy.ndarray, shape (N n, n (D+1))
        Row block i: ``(I - L_i C_i) [(1 - p_ii) A, 0, ...] - sum_j p_ij (I - L_i C_i)
        B_ij`` placed at column block r_ij; D = the largest link delay.
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    d = _delay_matrix(P_arr, delays)
    N, n = P_arr.shape[0], A_arr.shape[0]
    D = int(d.max()) if d.size else 0
    powers = [np.eye(n)]
    for _ in range(D + 1):
        powers.append(powers[-1] @ A_arr)
    F = np.zeros((N * n, n * (D + 1)))
    for i, Li in enumerate(_gains(L, C_list)):
        G = np.eye(n) - Li @ C_list[i]
        rows = slice(i * n, (i + 1) * n)
        F[rows, :n] += (1.0 - P_arr[i, i]) * (G @ A_arr)
        for j in np.flatnonzero(P_arr[i]):
            if j == i:
                continue
            r = int(d[i, j])
            B = powers[r + 1] if compensated else A_arr
            F[rows, r * n:(r + 1) * n] -= P_arr[i, j] * (G @ B)
    return F


def joint_matrix(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike],
                 delays: ArrayLike, compensated: bool) -> np.ndarray:
    """The joint matrix [[S, 0], [F, A-hat-bar]] of (X_k; E_k) (module docstring).

    Parameters
    ----------
    P, A, C, L, delays, compensated
        As in :func:`forcing_matrix`.

    Returns
    -------
    numpy.ndarray, shape (n (D+1) + N n (D+1),) * 2
        Rows and columns: x_k, ..., x_{k-D}, then e_k, ..., e_{k-D} (agents stacked).
    """
    from netsim.models.augmented import augmented_closed_loop

    P_arr, A_arr, C_list = _check_system(P, A, C)
    d = _delay_matrix(P_arr, delays)
    N, n = P_arr.shape[0], A_arr.shape[0]
    D = int(d.max()) if d.size else 0
    nx, ne = n * (D + 1), N * n * (D + 1)
    J = np.zeros((nx + ne, nx + ne))
    J[:n, :n] = A_arr
    if D:
        J[n:nx, :nx - n] = np.eye(nx - n)
    J[nx:nx + N * n, :nx] = forcing_matrix(P_arr, A_arr, C_list, L, d, compensated)
    J[nx:, nx:] = augmented_closed_loop(P_arr, A_arr, C_list, L, d, D, compensated)
    return J


# ---------------------------------------------------------------------------
# the plant's modes and how they enter the error
# ---------------------------------------------------------------------------


def _clusters(values: np.ndarray) -> list[np.ndarray]:
    """Indices of eigenvalue clusters (single linkage at CLUSTER_TOLERANCE)."""
    scale = max(1.0, float(np.max(np.abs(values)))) if values.size else 1.0
    tol = CLUSTER_TOLERANCE * scale
    parent = list(range(len(values)))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a in range(len(values)):
        for b in range(a + 1, len(values)):
            if abs(values[a] - values[b]) <= tol:
                parent[root(a)] = root(b)
    groups: dict[int, list[int]] = {}
    for a in range(len(values)):
        groups.setdefault(root(a), []).append(a)
    return [np.array(g) for g in groups.values()]


def _invariant_subspace(M: np.ndarray, centre: complex, radius: float,
                        multiplicity: int = 0) -> np.ndarray:
    """Orthonormal basis of M's invariant subspace for the eigenvalues within ``radius``
    of ``centre``.

    A simple eigenvalue (``multiplicity == 1``): its eigenvector, the right singular
    vector of ``M - centre I`` for the smallest singular value (numpy only: scipy.linalg
    costs 0.2 s CPU to import, issue 34). Otherwise the ordered complex Schur form.
    """
    if multiplicity == 1:
        shifted = M.astype(complex) - centre * np.eye(M.shape[0])
        _, _, vh = np.linalg.svd(shifted)
        return vh[-1:].conj().T
    from scipy.linalg import schur

    # scipy-stubs type ``sort`` as Callable[[float, float], bool] (the real Schur form's
    # (re, im) callable); with output="complex" scipy calls it with one complex number.
    _, Z, sdim = schur(M.astype(complex), output="complex",  # type: ignore[call-overload]
                       sort=lambda z: abs(z - centre) <= radius)
    return Z[:, :sdim]


def plant_modes(A: ArrayLike, forcing_blocks: Sequence[tuple[np.ndarray, Sequence[tuple[
                float, int]]]] | None = None, Q: ArrayLike | None = None,
                prior: ArrayLike | None = None) -> list[PlantMode]:
    """The eigenvalue clusters of A, each with its forcing and excitation.

    Parameters
    ----------
    A : array_like, shape (n, n)
    forcing_blocks : sequence of (G_i, [(w, e), ...]), optional
        Per agent i: G_i = I - L_i C_i and the terms of its forcing: the mode's forcing
        is ``G_i V (sum over terms of w T^e)`` (T: A on the mode's subspace V). None: no
        forcing (every mode unforced).
    Q : array_like, shape (n, n), optional
        Process noise covariance.
    prior : array_like, shape (n, n), optional
        The prior's second moment x0_cov + x0_mean x0_mean^T.

    Returns
    -------
    list of PlantMode
        Largest modulus first.
    """
    A_arr = np.asarray(A, dtype=float)
    n = A_arr.shape[0]
    values = np.linalg.eigvals(A_arr)
    scale = max(1.0, float(np.max(np.abs(values)))) if n else 1.0
    radius = CLUSTER_TOLERANCE * scale
    Q_arr = None if Q is None else np.asarray(Q, dtype=float)
    S_arr = None if prior is None else np.asarray(prior, dtype=float)
    Q_norm, S_norm = _spectral_norm(Q_arr), _spectral_norm(S_arr)  # once, not per mode
    modes = []
    for group in _clusters(values):
        lam = complex(np.mean(values[group]))
        m = len(group)
        if abs(lam) <= radius:  # nilpotent part: dies out within n steps
            modes.append(PlantMode(lam, m, False, 0.0, False, False, False))
            continue
        V = _invariant_subspace(A_arr, lam, radius * 1.0001, m)
        W = _invariant_subspace(A_arr.T, lam.conjugate(), radius * 1.0001, m)
        T = V.conj().T @ A_arr @ V
        sv = np.linalg.svd(T - lam * np.eye(T.shape[0]), compute_uv=False)
        geometric = int(np.sum(sv <= 10 * m * radius))
        defective = geometric < T.shape[0]
        forcing = 0.0
        if forcing_blocks is not None and T.shape[0]:
            Tinv = np.linalg.inv(T)
            norm_T = max(float(np.linalg.norm(T, 2)), np.finfo(float).tiny)
            powers: dict[int, np.ndarray] = {}  # T^e, shared by the agents' terms
            forced = []
            for G, terms in forcing_blocks:
                acc = np.zeros_like(T)
                for w, e in terms:
                    if w == 0:
                        continue
                    if e not in powers:
                        powers[e] = (np.linalg.matrix_power(T, e) if e >= 0
                                     else np.linalg.matrix_power(Tinv, -e))
                    acc = acc + w * powers[e]
                forced.append(G @ V @ acc)
            if forced:  # the largest singular value of each, in one batched call
                top = np.linalg.svd(np.stack(forced), compute_uv=False).max(axis=-1)
                for value in top:
                    forcing = max(forcing, float(value) / norm_T)
        modes.append(PlantMode(lam, m, bool(defective), forcing,
                               bool(forcing > FORCING_TOLERANCE),
                               _excited(W, Q_arr, Q_norm), _excited(W, S_arr, S_norm)))
    modes.sort(key=lambda md: -md.modulus)
    return modes


def _spectral_norm(S: np.ndarray | None) -> float:
    """||S||_2 (0 for None)."""
    return 0.0 if S is None else float(np.linalg.norm(S, 2))


def _excited(W: np.ndarray, S: np.ndarray | None, total: float) -> bool:
    """Whether the covariance ``S`` (``total`` = ||S||_2) reaches the mode's left
    subspace ``W`` beyond :data:`EXCITATION_TOLERANCE`."""
    if S is None or W.shape[1] == 0:
        return False
    if total == 0 or not math.isfinite(total):
        return False
    share = float(np.linalg.norm(W.conj().T @ S @ W, 2))
    return share > EXCITATION_TOLERANCE * total


# ---------------------------------------------------------------------------
# the analysis
# ---------------------------------------------------------------------------


def _prior_moment(n: int, x0_mean: ArrayLike | None, x0_cov: ArrayLike | None
                  ) -> np.ndarray | None:
    if x0_mean is None and x0_cov is None:
        return None
    S = np.zeros((n, n)) if x0_cov is None else np.array(x0_cov, dtype=float).reshape(n, n)
    if x0_mean is not None:
        m = np.asarray(x0_mean, dtype=float).reshape(n)
        S = S + np.outer(m, m)
    return S


def joint_analysis(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike],
                   delays: ArrayLike, *, compensated: bool, Q: ArrayLike | None = None,
                   x0_mean: ArrayLike | None = None, x0_cov: ArrayLike | None = None,
                   rho_error: float | None = None) -> JointAnalysis:
    """Analyse the joint system of plant state and error under fixed delays.

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix (p_ij: weight of j's estimate at agent i).
    A : array_like, shape (n, n)
    C : sequence of array_like
        Output matrices C_i, shape (m_i, n).
    L : sequence of array_like
        Innovation gains L_i = K_i C_i^T, shape (n, m_i).
    delays : array_like of int, shape (N, N)
        Effective delay r_ij of link j -> i (entries off the links are ignored).
    compensated : bool
        The estimator compensates a neighbour's estimate with A^(r+1) (LCSYS2022 eq. 4)
        or applies A (delay-tolerant eq. 6).
    Q : array_like, shape (n, n), optional
        Process noise covariance (which modes the noise drives).
    x0_mean, x0_cov : array_like, optional
        The initial state's mean and covariance (which modes the prior excites).
    rho_error : float, optional
        The error recursion's spectral radius, if already known (else computed with
        :func:`netsim.models.augmented.augmented_spectral_radius`).

    Returns
    -------
    JointAnalysis
    """
    P_arr, A_arr, C_list = _check_system(P, A, C)
    d = _delay_matrix(P_arr, delays)
    if rho_error is None:
        from netsim.models.augmented import augmented_spectral_radius

        with np.errstate(over="ignore", invalid="ignore"):
            rho_error = float(augmented_spectral_radius(P_arr, A_arr, C_list, L, d, None,
                                                        compensated=compensated))
    n = A_arr.shape[0]
    blocks = []
    for i, Li in enumerate(_gains(L, C_list)):
        G = np.eye(n) - Li @ C_list[i]
        terms: list[tuple[float, int]] = [(1.0 - float(P_arr[i, i]), 1)]
        for j in np.flatnonzero(P_arr[i]):
            if j != i:
                e = 1 if compensated else 1 - int(d[i, j])
                terms.append((-float(P_arr[i, j]), e))
        blocks.append((G, _merge(terms)))
    modes = plant_modes(A_arr, blocks, Q, _prior_moment(n, x0_mean, x0_cov))
    kind = RECURSION_COMPENSATED if compensated else RECURSION_UNCOMPENSATED
    lagged = bool(np.any((d > 0) & (P_arr != 0) & ~np.eye(len(P_arr), dtype=bool)))
    return _conclude(kind, float(rho_error), modes, 1, _forcing_words(kind, lagged))


def block_joint_analysis(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike],
                         L: Sequence[ArrayLike], tau: int, *, Q: ArrayLike | None = None,
                         x0_mean: ArrayLike | None = None, x0_cov: ArrayLike | None = None
                         ) -> JointAnalysis:
    """The joint analysis of the block update (LCSYS2022 eqs. 15-16), every link's delay
    within the bound ``tau``: on the block time scale the compensated estimator with
    A^(tau+1) and no delay; rates per step are the block's to the power 1/(tau+1).

    Parameters
    ----------
    P, A, C, L, Q, x0_mean, x0_cov
        As in :func:`joint_analysis`.
    tau : int
        The delay bound; the block length is tau + 1.

    Returns
    -------
    JointAnalysis
        Its rates, moduli and MSE factor per step (``period`` = tau + 1).
    """
    from netsim.models.augmented import delay_bound_lcsys

    P_arr, A_arr, C_list = _check_system(P, A, C)
    period = int(tau) + 1
    with np.errstate(over="ignore", invalid="ignore"):
        A_block = np.linalg.matrix_power(A_arr, period)
        rho_step = float(delay_bound_lcsys(P_arr, A_arr, C_list, L, int(tau)))
        Q_block = None
        if Q is not None:
            Q_arr = np.asarray(Q, dtype=float)
            Q_block = np.zeros_like(Q_arr)
            Ak = np.eye(A_arr.shape[0])
            for _ in range(period):
                Q_block += Ak @ Q_arr @ Ak.T
                Ak = A_arr @ Ak
    n = A_arr.shape[0]
    blocks = [(np.eye(n) - Li @ C_list[i], [(1.0 - float(P_arr[i].sum()), 1)])
              for i, Li in enumerate(_gains(L, C_list))]
    modes = plant_modes(A_block, blocks, Q_block, _prior_moment(n, x0_mean, x0_cov))
    per_step = tuple(PlantMode(_root(m.eigenvalue, period), m.multiplicity, m.defective,
                               m.forcing, m.forced, m.noise, m.prior) for m in modes)
    return _conclude(RECURSION_BLOCK, rho_step, per_step, period,
                     _forcing_words(RECURSION_BLOCK, False))


def _root(z: complex, period: int) -> complex:
    """A per-step eigenvalue of the same modulus and (principal) argument / period."""
    if period == 1 or z == 0:
        return z
    return complex(abs(z) ** (1.0 / period) * np.exp(1j * np.angle(z) / period))


def _merge(terms: list[tuple[float, int]]) -> list[tuple[float, int]]:
    out: dict[int, float] = {}
    for w, e in terms:
        out[e] = out.get(e, 0.0) + w
    return [(w, e) for e, w in sorted(out.items())]


def _forcing_words(kind: str, lagged: bool) -> str:
    if kind == RECURSION_UNCOMPENSATED and lagged:
        return ("error forced by the moving state through (A^(r+1) - A) x_(k-1-r) on the "
                "links with delay r >= 1 (eq. (11) leaves this term out)")
    if kind == RECURSION_BLOCK:
        return "error forced by the state through (1 - sum_j p_ij) A^(tau+1) x"
    return "error forced by the state through (1 - sum_j p_ij) A x_(k-1)"


def _fmt(v: float) -> str:
    return f"{v:.4f}" if math.isfinite(v) else str(v)


def _eig_text(z: complex) -> str:
    if abs(z.imag) <= 1e-12 * max(1.0, abs(z)):
        return f"{z.real:.6g}"
    return f"{z.real:.4g} +- {abs(z.imag):.4g}i"


def _conclude(kind: str, rho_err: float, modes: Sequence[PlantMode], period: int,
              forcing_words: str) -> JointAnalysis:
    tol = MODULUS_TOLERANCE
    entering = [m for m in modes if m.enters and m.modulus > 0]
    rho_f = max((m.modulus for m in entering), default=0.0)
    rho = max(rho_err, rho_f) if math.isfinite(rho_err) else math.inf
    recursion = {RECURSION_COMPENSATED: "the error recursion (LCSYS2022 eq. (9))",
                 RECURSION_UNCOMPENSATED: "eq. (11), the error recursion alone,",
                 RECURSION_BLOCK: "the block recursion (LCSYS2022 eqs. (15)-(16))"}[kind]
    per = " per step" if period == 1 else f" per step (blocks of {period} steps)"
    top = max(entering, key=lambda m: m.modulus) if entering else None
    plant_rho = max((m.modulus for m in modes), default=0.0)

    def symbol(m: PlantMode) -> str:
        return ("rho(A)" if abs(m.modulus - plant_rho) <= tol * max(1.0, plant_rho)
                else "|lambda|")

    def plant_growth(m: PlantMode) -> str:
        what = symbol(m)
        if what != "rho(A)":
            what += f" (lambda = {_eig_text(m.eigenvalue)})"
        return f"{what} = {_fmt(m.modulus)}"

    if not math.isfinite(rho_err) or rho_err > 1 + tol or rho_f > 1 + tol:
        growth, factor = GEOMETRIC, rho * rho
        if top is not None and rho_f >= rho_err:
            reason = (f"{forcing_words}; the plant grows as {plant_growth(top)}{per}, so the "
                      f"MSE grows as {symbol(top)}^2 = {_fmt(factor)} per step; "
                      f"{recursion} has rho {_fmt(rho_err)}")
        else:
            reason = (f"{recursion} has rho {_fmt(rho_err)} > 1{per}: the MSE grows as "
                      f"rho^2 = {_fmt(factor)} per step")
        return JointAnalysis(kind, rho_err, tuple(modes), rho_f, rho, growth, factor, reason,
                             period)
    unit_err = abs(rho_err - 1) <= tol
    unit_modes = [m for m in entering if abs(m.modulus - 1) <= tol]
    driven = [m for m in unit_modes if m.noise or m.defective]
    if unit_err or driven:
        if driven:
            m = driven[0]
            how = ("in a Jordan block (the state grows polynomially)" if m.defective else
                   "driven by the process noise (the state wanders like a random walk)")
            reason = (f"{forcing_words}; the plant mode lambda = {_eig_text(m.eigenvalue)} "
                      f"(|lambda| = 1) enters the error, {how}, so the MSE grows without "
                      f"bound, polynomially (linearly under noise alone); {recursion} has "
                      f"rho {_fmt(rho_err)}")
        else:
            reason = (f"{recursion} has rho = 1 (within {tol:g}): the noise it integrates "
                      "makes the MSE grow without bound, polynomially")
        return JointAnalysis(kind, rho_err, tuple(modes), rho_f, 1.0, POLYNOMIAL, 1.0, reason,
                             period)
    factor = rho * rho
    if unit_modes:
        m = unit_modes[0]
        reason = (f"{forcing_words}; the plant mode lambda = {_eig_text(m.eigenvalue)} "
                  f"(|lambda| = 1, excited only by the prior, no noise on it) keeps a "
                  f"bounded, persistent error; {recursion} has rho {_fmt(rho_err)} < 1")
    elif top is not None:  # some mode enters
        reason = (f"{recursion} has rho {_fmt(rho_err)} < 1 and the plant modes that force "
                  f"the error decay ({plant_growth(top)} < 1): the MSE is bounded; its "
                  f"MSE transient decays as {_fmt(factor)} = rho^2 per step")
    else:
        cancel = {RECURSION_COMPENSATED: "A^(r+1) compensation cancels the state's motion",
                  RECURSION_UNCOMPENSATED: ("no plant mode that grows or persists enters "
                                            "the error"),
                  RECURSION_BLOCK: "A^(tau+1) compensation cancels the state's motion"}[kind]
        if kind == RECURSION_UNCOMPENSATED and not any(m.forced for m in modes):
            cancel = "no link delay leaves a state term in the error"
        reason = (f"{recursion} has rho {_fmt(rho_err)} < 1{per} and {cancel}: the MSE is "
                  f"bounded; its MSE transient decays as {_fmt(factor)} = rho^2 per step")
    return JointAnalysis(kind, rho_err, tuple(modes), rho_f, rho, BOUNDED, factor, reason,
                         period)
