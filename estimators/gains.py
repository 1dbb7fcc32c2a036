"""Block-diagonal gain design for consensus-based distributed estimation.

The delay-free closed loop of LCSYS2022 eq. (12) is

    A-hat = (I - K D_C-bar)(P kron A) = (I - blockdiag(L_i C_i)) M,  M = P kron A,

where ``L_i = K_i C_i^T`` (shape ``(n, m_i)``) is the only part of the
per-agent gain ``K_i`` that enters ``A-hat``. Schur stability with rate
``alpha`` (``rho(A-hat) < alpha``) is implied by the LMI of eq. (13) in the
scaled form

    [[alpha X, (X A-hat)^T], [X A-hat, alpha X]] > 0,   X > 0.

With a block-diagonal Lyapunov matrix ``X = blockdiag(X_i)`` (each ``X_i`` of
shape ``(n, n)``, symmetric) and ``Z_i = X_i L_i``, the product
``X A-hat = (X - blockdiag(Z_i C_i)) M`` is linear in ``(X_i, Z_i)``, so the
condition is an LMI solved here with cvxpy (Clarabel, SCS as fallback). The
gain is recovered as ``L_i = X_i^{-1} Z_i``. Bisection on ``alpha`` gives the
smallest rate the block-diagonal certificate can prove.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from models.augmented import delay_free_closed_loop, output_gain_matrix, spectral_radius

__all__ = [
    "DEFAULT_MARGIN",
    "DEFAULT_OBSERVABILITY_RTOL",
    "DEFAULT_SOLVERS",
    "DEFAULT_TOLERANCE",
    "GainDesign",
    "GainDesignError",
    "design_gains",
    "gains_from_matrices",
    "is_observable",
]

#: Lower bound on the smallest eigenvalue of the (symmetrised) LMI matrix.
DEFAULT_MARGIN: float = 1e-6
#: Width of the final bisection interval on the rate ``alpha``.
DEFAULT_TOLERANCE: float = 1e-3
#: Solvers tried in order when none is requested.
DEFAULT_SOLVERS: tuple[str, ...] = ("CLARABEL", "SCS")
#: Relative singular-value threshold of the observability rank test.
DEFAULT_OBSERVABILITY_RTOL: float = 1e-8

_METHOD_SINGLE = "block-diagonal-lmi"
_METHOD_BISECTION = "block-diagonal-lmi-bisection"


class GainDesignError(ValueError):
    """Raised when no certified block-diagonal gain can be designed."""


@dataclass(frozen=True)
class GainDesign:
    """Result of a block-diagonal gain design.

    Attributes
    ----------
    L : tuple of numpy.ndarray
        Effective gains ``L_i = K_i C_i^T``, ``L[i]`` of shape ``(n, m_i)``.
    K : tuple of numpy.ndarray
        Per-agent gains ``K_i``, each of shape ``(n, n)``, with
        ``K_i C_i^T = L_i``.
    rho : float
        ``rho(A-hat)`` of LCSYS2022 eq. (12), recomputed with numpy from ``L``.
    certified_rate : float or None
        The rate ``alpha`` certified by the LMI (``rho < alpha``), or None.
    certified : bool
        True only if the solver status is optimal and the recomputed ``rho < 1``
        (for given gains: ``rho < 1``).
    method : str
        ``"block-diagonal-lmi"``, ``"block-diagonal-lmi-bisection"`` or ``"given"``.
    solver : str
        Name of the SDP solver used (``"none"`` for given gains).
    status : str
        Solver status of the returned design.
    message : str
        Human-readable summary.
    """

    L: tuple[np.ndarray, ...]
    K: tuple[np.ndarray, ...]
    rho: float
    certified_rate: float | None
    certified: bool
    method: str
    solver: str
    status: str
    message: str


# ---------------------------------------------------------------------------
# input handling
# ---------------------------------------------------------------------------


def _square(name: str, M: ArrayLike) -> np.ndarray:
    arr = np.asarray(M, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"{name} must be a square 2-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite entries")
    return arr


def _system(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike]
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Validate ``(P, A, C)``; return ``P`` (N, N), ``A`` (n, n), ``C_i`` (m_i, n)."""
    P_arr = _square("P", P)
    A_arr = _square("A", A)
    n = A_arr.shape[0]
    C_list: list[np.ndarray] = []
    for i, Ci in enumerate(C):
        arr = np.asarray(Ci, dtype=float)
        if arr.ndim == 1:
            arr = arr.reshape(1, -1)
        if arr.ndim != 2 or arr.shape[1] != n:
            raise ValueError(f"C[{i}] (agent {i}) must have shape (m_i, {n}), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"C[{i}] (agent {i}) contains non-finite entries")
        C_list.append(arr)
    if len(C_list) != P_arr.shape[0]:
        raise ValueError(
            f"C has {len(C_list)} output matrices but P is {P_arr.shape[0]}x{P_arr.shape[0]}"
        )
    return P_arr, A_arr, C_list


def _gain_from_effective(Li: np.ndarray, Ci: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(L_i, K_i)`` with ``K_i = L_i (C_i C_i^T)^+ C_i`` and ``K_i C_i^T = L_i``.

    ``L_i`` is projected onto the row space that ``C_i`` can realise (a no-op when
    ``C_i`` has full row rank); the projection leaves ``L_i C_i`` unchanged.
    """
    G_pinv = np.linalg.pinv(Ci @ Ci.T)
    L_eff = Li @ G_pinv @ (Ci @ Ci.T)
    K = L_eff @ G_pinv @ Ci
    return L_eff, K


# ---------------------------------------------------------------------------
# observability
# ---------------------------------------------------------------------------


def is_observable(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    rtol: float = DEFAULT_OBSERVABILITY_RTOL,
) -> tuple[bool, str]:
    """PBH rank test of observability of ``(P kron A, D_C-bar)`` (LCSYS2022 Lemma 1).

    The pair is observable iff ``[lambda I - M; D_C-bar]`` (shape ``(2 N n, N n)``,
    ``M = P kron A``) has full column rank for every eigenvalue ``lambda`` of
    ``M``. The rank is decided by the smallest singular value relative to
    ``max(1, ||M||_2, ||D_C-bar||_2)``. Cost: ``N n`` SVDs of ``(2 N n, N n)``
    matrices, negligible next to the LMI itself.

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    rtol : float, default DEFAULT_OBSERVABILITY_RTOL
        Relative singular-value threshold below which a mode is unobservable.

    Returns
    -------
    observable : bool
        True if every eigenvalue passes the PBH test.
    reason : str
        Empty if observable, otherwise a description of the unobservable modes.
    """
    P_arr, A_arr, C_list = _system(P, A, C)
    M = np.kron(P_arr, A_arr)
    D = output_gain_matrix(C_list)
    scale = max(1.0, float(np.linalg.norm(M, 2)), float(np.linalg.norm(D, 2)))
    eye = np.eye(M.shape[0])
    bad: list[tuple[complex, float]] = []
    checked: list[complex] = []
    for lam in np.linalg.eigvals(M):
        if any(abs(lam - mu) <= rtol * scale for mu in checked):
            continue  # numerically repeated eigenvalue, already tested
        checked.append(lam)
        smin = np.linalg.svd(np.vstack([lam * eye - M, D]), compute_uv=False)[-1] / scale
        if smin < rtol:
            bad.append((lam, smin))
    if not bad:
        return True, ""
    worst = max(abs(lam) for lam, _ in bad)
    return False, (
        f"(P kron A, D_C-bar) is not observable: the PBH rank test fails for "
        f"{len(bad)} distinct eigenvalue(s) of P kron A (largest modulus {worst:.4g})"
    )


# ---------------------------------------------------------------------------
# LMI
# ---------------------------------------------------------------------------


def _pick_solver(solver: str | None) -> str:
    import cvxpy as cp

    installed = set(cp.installed_solvers())
    if solver is not None:
        name = solver.upper()
        if name not in installed:
            raise GainDesignError(
                f"requested solver {solver!r} is not installed (installed: {sorted(installed)})"
            )
        return name
    for name in DEFAULT_SOLVERS:
        if name in installed:
            return name
    raise GainDesignError(
        f"no SDP solver available: need one of {DEFAULT_SOLVERS}, installed: {sorted(installed)}"
    )


@dataclass
class _Attempt:
    alpha: float
    status: str
    L: list[np.ndarray] | None
    K: list[np.ndarray] | None
    rho: float
    error: str


class _LMI:
    """The rate-parametrised block-diagonal LMI, built once and re-solved (DPP)."""

    def __init__(
        self, P: np.ndarray, A: np.ndarray, C: list[np.ndarray], margin: float, solver: str
    ) -> None:
        import cvxpy as cp

        self.P, self.A, self.C, self.solver = P, A, C, solver
        N, n = P.shape[0], A.shape[0]
        M = np.kron(P, A)
        self.alpha = cp.Parameter(nonneg=True, name="alpha")
        self.X = [cp.Variable((n, n), symmetric=True, name=f"X_{i}") for i in range(N)]
        self.Z = [cp.Variable((n, Ci.shape[0]), name=f"Z_{i}") for i, Ci in enumerate(C)]

        def blockdiag(blocks: list) -> cp.Expression:
            return cp.bmat(
                [[blocks[i] if i == j else np.zeros((n, n)) for j in range(N)] for i in range(N)]
            )

        X = blockdiag(self.X)
        ZC = blockdiag([Zi @ Ci for Zi, Ci in zip(self.Z, C, strict=True)])
        Y = (X - ZC) @ M  # = X A-hat, linear in (X_i, Z_i)
        S = cp.bmat([[self.alpha * X, Y.T], [Y, self.alpha * X]])
        S_sym = (S + S.T) / 2  # `>>` only constrains the symmetric part anyway
        cons = [S_sym >> margin * np.eye(2 * N * n)]
        cons += [Xi >> np.eye(n) for Xi in self.X]
        self.problem = cp.Problem(cp.Minimize(0), cons)

    def solve(self, alpha: float) -> _Attempt:
        self.alpha.value = float(alpha)
        try:
            with warnings.catch_warnings():
                # cvxpy warns on inaccurate solutions; the status is reported instead.
                warnings.simplefilter("ignore", UserWarning)
                self.problem.solve(solver=self.solver)
        except Exception as exc:  # noqa: BLE001 - any solver failure is "not certified"
            return _Attempt(
                alpha, "solver_error", None, None, float("inf"), f"{type(exc).__name__}: {exc}"
            )
        status = str(self.problem.status)
        if status not in ("optimal", "optimal_inaccurate"):
            return _Attempt(alpha, status, None, None, float("inf"), "")
        L: list[np.ndarray] = []
        K: list[np.ndarray] = []
        try:
            for Xi, Zi, Ci in zip(self.X, self.Z, self.C, strict=True):
                Xv = np.asarray(Xi.value, dtype=float)
                Zv = np.asarray(Zi.value, dtype=float).reshape(Xv.shape[0], Ci.shape[0])
                Li, KiC = _gain_from_effective(np.linalg.solve((Xv + Xv.T) / 2, Zv), Ci)
                L.append(Li)
                K.append(KiC)
            rho = spectral_radius(delay_free_closed_loop(self.P, self.A, self.C, L))
        except (np.linalg.LinAlgError, TypeError, ValueError) as exc:
            return _Attempt(
                alpha, status, None, None, float("inf"), f"could not recover gains: {exc}"
            )
        return _Attempt(alpha, status, L, K, rho, "")


def _accepted(att: _Attempt) -> bool:
    """A solve certifies ``alpha`` only if optimal and the recomputed rho is below it."""
    return att.status == "optimal" and att.L is not None and att.rho < att.alpha


def _failure(att: _Attempt, solver: str) -> GainDesignError:
    a = f"{att.alpha:.6g}"
    if att.status == "solver_error":
        why = f"solver {solver} failed at alpha={a}: {att.error}"
    elif att.status in ("infeasible", "infeasible_inaccurate"):
        why = f"LMI infeasible at alpha={a} (solver {solver} status {att.status})"
    elif att.L is None:
        why = f"LMI not solved at alpha={a} (solver {solver} status {att.status}) {att.error}"
    else:
        why = (
            f"LMI not certified at alpha={a}: solver {solver} status {att.status}, "
            f"recomputed rho(A-hat)={att.rho:.6g}"
        )
    return GainDesignError(why.strip())


def _design(att: _Attempt, method: str, solver: str, message: str) -> GainDesign:
    assert att.L is not None and att.K is not None
    ok = att.status == "optimal"
    return GainDesign(
        L=tuple(att.L),
        K=tuple(att.K),
        rho=float(att.rho),
        certified_rate=float(att.alpha) if ok and att.rho < att.alpha else None,
        certified=bool(ok and att.rho < 1.0),
        method=method,
        solver=solver,
        status=att.status,
        message=message,
    )


def design_gains(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    *,
    rate: float | None = None,
    bisect: bool = True,
    margin: float = DEFAULT_MARGIN,
    tolerance: float = DEFAULT_TOLERANCE,
    solver: str | None = None,
) -> GainDesign:
    """Design block-diagonal gains with ``rho(A-hat) < alpha`` via the LMI of LCSYS2022 eq. (13).

    Solves, for ``X = blockdiag(X_i)`` (``X_i`` of shape ``(n, n)``) and
    ``Z = blockdiag(Z_i)`` (``Z_i`` of shape ``(n, m_i)``),

        [[alpha X, ((X - Z D_C) M)^T], [(X - Z D_C) M, alpha X]] >= margin I,
        X_i >= I,

    with ``M = P kron A`` (shape ``(N n, N n)``) and ``Z D_C = blockdiag(Z_i C_i)``,
    then sets ``L_i = X_i^{-1} Z_i`` and ``K_i = L_i (C_i C_i^T)^{-1} C_i``.

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    rate : float, optional
        If given, solve once at ``alpha = rate`` instead of the default
        feasibility check at ``alpha = 1`` followed by bisection.
    bisect : bool, default True
        After the ``alpha = 1`` check, bisect ``alpha`` in ``(0, 1]`` and
        return the design at the smallest certified ``alpha``.
    margin : float, default DEFAULT_MARGIN
        Strictness margin of the LMI.
    tolerance : float, default DEFAULT_TOLERANCE
        Final width of the bisection interval.
    solver : str, optional
        cvxpy solver name; default: Clarabel, else SCS.

    Returns
    -------
    GainDesign
        The design; ``rho`` is recomputed with numpy from ``L``.

    Raises
    ------
    GainDesignError
        If ``(P kron A, D_C-bar)`` is not observable, the LMI is infeasible or
        not certified at ``alpha = 1`` (or at ``rate``), or the solver fails.
    ValueError
        On inconsistent shapes or invalid parameters.
    """
    P_arr, A_arr, C_list = _system(P, A, C)
    if rate is not None and not (np.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a positive finite number, got {rate}")
    if not margin > 0:
        raise ValueError(f"margin must be > 0, got {margin}")
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")

    observable, reason = is_observable(P_arr, A_arr, C_list)
    if not observable:
        raise GainDesignError(reason)

    name = _pick_solver(solver)
    try:
        lmi = _LMI(P_arr, A_arr, C_list, margin, name)
    except Exception as exc:  # noqa: BLE001 - never leak a modelling-layer traceback
        raise GainDesignError(f"could not build the LMI: {type(exc).__name__}: {exc}") from None

    alpha0 = 1.0 if rate is None else float(rate)
    first = lmi.solve(alpha0)
    n_solves = 1
    if not _accepted(first):
        if first.status == "optimal_inaccurate" and first.L is not None and first.rho < alpha0:
            return _design(
                first,
                _METHOD_SINGLE,
                name,
                f"solver {name} returned optimal_inaccurate at alpha={alpha0:.6g}; "
                f"recomputed rho(A-hat)={first.rho:.6g} but the rate is NOT certified",
            )
        raise _failure(first, name) from None

    if rate is not None or not bisect:
        return _design(
            first,
            _METHOD_SINGLE,
            name,
            f"block-diagonal LMI certified rho(A-hat) < {alpha0:.6g} "
            f"(recomputed rho(A-hat)={first.rho:.6g}, solver {name})",
        )

    best = first
    lo, hi = 0.0, alpha0
    while hi - lo > tolerance:
        mid = 0.5 * (lo + hi)
        att = lmi.solve(mid)
        n_solves += 1
        if _accepted(att):
            best, hi = att, mid
        else:
            lo = mid
    return _design(
        best,
        _METHOD_BISECTION,
        name,
        f"block-diagonal LMI certified rho(A-hat) < {best.alpha:.6g} "
        f"(bisection to {tolerance:g}, {n_solves} solves, infeasible/uncertified "
        f"below {lo:.6g}); recomputed rho(A-hat)={best.rho:.6g}, solver {name}",
    )


def gains_from_matrices(
    K: Sequence[ArrayLike], P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike]
) -> GainDesign:
    """Wrap explicitly given per-agent gains ``K_i`` into a :class:`GainDesign`.

    Computes ``L_i = K_i C_i^T`` and ``rho(A-hat)`` of LCSYS2022 eq. (12).

    Parameters
    ----------
    K : sequence of array_like
        ``N`` gains, ``K[i]`` of shape ``(n, n)``.
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.

    Returns
    -------
    GainDesign
        ``method="given"``, ``certified = rho < 1``, ``certified_rate=None``.

    Raises
    ------
    ValueError
        If the number or shapes of the ``K_i`` are inconsistent (the message
        names the agent).
    """
    P_arr, A_arr, C_list = _system(P, A, C)
    n = A_arr.shape[0]
    K_list = list(K)
    if len(K_list) != len(C_list):
        raise ValueError(f"K has {len(K_list)} gains but there are {len(C_list)} agents")
    Ks: list[np.ndarray] = []
    Ls: list[np.ndarray] = []
    for i, (Ki, Ci) in enumerate(zip(K_list, C_list, strict=True)):
        arr = np.asarray(Ki, dtype=float)
        if arr.shape != (n, n):
            raise ValueError(f"K[{i}] (agent {i}) must have shape ({n}, {n}), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"K[{i}] (agent {i}) contains non-finite entries")
        Ks.append(arr.copy())
        Ls.append(arr @ Ci.T)
    rho = spectral_radius(delay_free_closed_loop(P_arr, A_arr, C_list, Ls))
    stable = rho < 1.0
    return GainDesign(
        L=tuple(Ls),
        K=tuple(Ks),
        rho=float(rho),
        certified_rate=None,
        certified=bool(stable),
        method="given",
        solver="none",
        status="given",
        message=(
            f"given gains: rho(A-hat)={rho:.6g} "
            + ("(Schur stable)" if stable else "(NOT Schur stable)")
        ),
    )
