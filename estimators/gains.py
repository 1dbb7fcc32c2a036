"""Gain design for consensus-based distributed estimation (LCSYS2022 eq. 13).

The delay-free closed loop of LCSYS2022 eq. (12) is

    A-hat = (I - K D_C-bar)(P kron A) = (I - blockdiag(L_i C_i)) M,  M = P kron A,

where ``L_i = K_i C_i^T`` (shape ``(n, m_i)``) is the only part of the
per-agent gain ``K_i`` that enters ``A-hat``. Schur stability with rate
``alpha`` (``rho(A-hat) < alpha``) holds iff there is ``X > 0`` with
``A-hat^T X A-hat < alpha^2 X`` (eq. 13 scaled by the rate). The gain must be
block-diagonal (each agent uses its own output), which makes the design
non-convex in general. Two designs are implemented:

* ``method="lmi"`` (the default): a *block-diagonal* Lyapunov matrix
  ``X = blockdiag(X_i)`` and ``Z_i = X_i L_i`` make the condition an LMI,

      [[alpha X, (X A-hat)^T], [X A-hat, alpha X]] > 0,   X A-hat = (X - blockdiag(Z_i C_i)) M,

  solved with cvxpy; ``L_i = X_i^{-1} Z_i``. Bisection on ``alpha`` gives the
  smallest rate this (conservative) certificate proves. For ``N n`` above
  :data:`LARGE_LMI_STATES` the same condition is solved in the equivalent
  *split* form (Schur complement on each ``X_i``): with ``W_i`` symmetric,

      [[W_i, H_i^T], [H_i, X_i]] >= 0  (2n x 2n, one per agent),  H_i = X_i - Z_i C_i,
      alpha^2 X - M^T blockdiag(W_i) M > 0                       (N n x N n),

  whose only large cone has ``N n`` instead of ``2 N n`` rows, with SCS as the
  default solver (Clarabel's interior-point KKT system holds a dense block of
  ``(rows (rows + 1) / 2)^2`` entries per cone: about 2 GB at ``2 N n = 240``).
* ``method="ccl"``: cone-complementarity linearisation (El Ghaoui, Oustry and
  AitRami, IEEE TAC 42(8), 1997) with a *full* Lyapunov matrix. With
  ``S = X^{-1}`` the rate condition is ``[[X, A-hat^T/alpha], [A-hat/alpha, S]] > 0``,
  linear in ``(X, S, L)``; the non-convex coupling ``S = X^{-1}`` is relaxed
  to ``[[X, I], [I, S]] >= 0`` and ``trace(X S)`` (which is ``>= N n``, with
  equality iff ``S = X^{-1}``) is driven down by iteratively minimising its
  linearisation ``trace(X_k S + S_k X)``. Every iterate's gain is checked with
  numpy (a target rate counts as reached as soon as ``rho(A-hat) < alpha``), and
  the rate is certified by a full Lyapunov matrix solved from the discrete
  Lyapunov equation and verified with numpy. The rate is minimised by a
  descending target search on ``alpha`` (see ``_design_ccl``), not a plain
  bisection. The steps run on SCS with ``eps = 1e-4`` by default: Clarabel
  took 1.5-3 s per step at ``N n = 24`` against 0.2-0.5 s for SCS.
* ``method="auto"``: CCL when ``N n <= CCL_AUTO_MAX_STATES``, otherwise the
  block-diagonal LMI (:func:`select_method`).

``tau1 > 0`` designs against ``P kron A^(tau1+1)`` instead of ``P kron A``
(LCSYS2022 Discussion 5); :func:`refine_gains` minimises the spectral radius
directly over the ``L_i`` entries, starting from a design.

A scenario's ``[gains]`` table names one of these (``lmi``, ``ccl``, ``auto``,
``refined``, or ``given`` matrices, with an optional ``tau1``);
:func:`design_for_scenario` is the one place that turns it into a :class:`GainDesign`,
for ``netsim run``, ``analyze``, ``bench`` and ``design`` alike.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from netsim.estimators.errors import GainDesignError
from netsim.models.augmented import delay_free_closed_loop, output_gain_matrix, spectral_radius
from netsim.models.observability import DEFAULT_RTOL, unobservable_modes
from netsim.models.validation import check_system
from numpy.typing import ArrayLike

from netsim.threads import single_threaded_blas

if TYPE_CHECKING:
    from netsim.models.scenario import Scenario

__all__ = [
    "CCL_AUTO_MAX_STATES",
    "CCL_CLARABEL_MAX_STATES",
    "DEFAULT_CCL_MAX_ITER",
    "DEFAULT_MARGIN",
    "DEFAULT_OBSERVABILITY_RTOL",
    "DEFAULT_REFINE_MAX_ITER",
    "DEFAULT_SOLVERS",
    "DEFAULT_TOLERANCE",
    "BOUND_STATUS",
    "LARGE_LMI_STATES",
    "LOCAL_AUTO_MIN_STATES",
    "LOCAL_DEFAULT_GAMMA",
    "LOCAL_GAMMAS",
    "LOCAL_SEARCH_MAX_STATES",
    "METHODS",
    "certificate_text",
    "design_local",
    "GainDesign",
    "GainDesignError",
    "design_for_scenario",
    "design_gains",
    "design_request",
    "gains_from_matrices",
    "refine_gains",
    "select_method",
]

#: Lower bound on the smallest eigenvalue of the (symmetrised) LMI matrix.
DEFAULT_MARGIN: float = 1e-6
#: Width of the final bisection interval on the rate ``alpha``.
DEFAULT_TOLERANCE: float = 1e-3
#: Solvers tried in order when none is requested (small problems).
DEFAULT_SOLVERS: tuple[str, ...] = ("CLARABEL", "SCS")
#: Relative singular-value threshold of the observability (PBH) test of the design.
DEFAULT_OBSERVABILITY_RTOL: float = DEFAULT_RTOL
#: ``N n`` above which the block-diagonal LMI uses the split form and SCS by default.
LARGE_LMI_STATES: int = 60
#: ``method="auto"`` runs CCL when ``N n`` is at most this, the block-diagonal LMI otherwise.
CCL_AUTO_MAX_STATES: int = 60
#: ``N n`` up to which CCL uses Clarabel by default (SCS above).
CCL_CLARABEL_MAX_STATES: int = 0
#: Default cap on CCL linearisation steps (SDP solves) per rate ``alpha``.
DEFAULT_CCL_MAX_ITER: int = 60
#: Default iteration cap of each optimiser run in :func:`refine_gains`.
DEFAULT_REFINE_MAX_ITER: int = 200
#: Accepted values of ``method`` (aliases: ``"block-diagonal"``, ``"block-diagonal-lmi"``).
METHODS: tuple[str, ...] = ("lmi", "ccl", "auto", "local")
#: ``method="auto"`` runs the local design (:func:`design_local`) above this ``N n``
#: (the LMI's SDP has an ``N n`` cone; at 1,500 rows it takes minutes and gigabytes);
#: a scenario without ``gains.method`` uses the same rule
#: (``netsim.models.scenario.LOCAL_DEFAULT_MIN_STATES``).
LOCAL_AUTO_MIN_STATES: int = 1500
#: Gain scales ``gamma`` the local design tries when ``N n`` is at most
#: :data:`LOCAL_SEARCH_MAX_STATES` (one exact structured spectral radius each).
LOCAL_GAMMAS: tuple[float, ...] = (0.2, 0.4, 0.6, 0.8)
#: Largest ``N n`` at which the local design searches ``gamma`` (each structured
#: spectral radius costs about 1 s at N n = 12,000, 5-9 s at 60,000 and 2 min at
#: 600,000 here).
LOCAL_SEARCH_MAX_STATES: int = 12_000
#: The local design's ``gamma`` above :data:`LOCAL_SEARCH_MAX_STATES`.
LOCAL_DEFAULT_GAMMA: float = 0.6
#: ``status`` prefix of a local design certified by the weighted-norm upper bound
#: (:func:`netsim.models.augmented.delay_free_rho_bound`) instead of the exact radius;
#: the basis follows (``"weighted-norm-bound-eigenvectors"``).
BOUND_STATUS: str = "weighted-norm-bound"
#: Default SCS options (cvxpy's default ``max_iters`` of 100000 can run for hours).
SCS_DEFAULT_OPTIONS: dict[str, Any] = {"max_iters": 20000}
#: SCS options of the CCL steps: 1e-4 halves the time per step against the default
#: 1e-5 with the same final rho on the LCSYS2022 example; 1e-3 stalls the iteration.
CCL_SCS_OPTIONS: dict[str, Any] = {"eps_abs": 1e-4, "eps_rel": 1e-4}

_METHOD_SINGLE = "block-diagonal-lmi"
_METHOD_BISECTION = "block-diagonal-lmi-bisection"
_METHOD_CCL = "ccl-full-lyapunov"
_METHOD_CCL_SEARCH = "ccl-full-lyapunov-rate-search"
_METHOD_REFINED = "refined"
_METHOD_LOCAL = "local-scaled-projection"
_ALIASES = {
    "local": "local",
    "lmi": "lmi",
    "block-diagonal": "lmi",
    "block-diagonal-lmi": "lmi",
    "ccl": "ccl",
    "auto": "auto",
}


@dataclass(frozen=True)
class GainDesign:
    """Result of a gain design.

    Attributes
    ----------
    L : tuple of numpy.ndarray
        Effective gains ``L_i = K_i C_i^T``, ``L[i]`` of shape ``(n, m_i)``.
    K : tuple of numpy.ndarray
        Per-agent gains ``K_i``, each of shape ``(n, n)``, with
        ``K_i C_i^T = L_i``.
    rho : float
        ``rho(A-hat)`` of the *delay-free* closed loop, LCSYS2022 eq. (12),
        recomputed with numpy from ``L`` (also for delay-bound designs); an upper bound
        on it when ``status`` starts with :data:`BOUND_STATUS` (see
        ``certificate_weights`` and :func:`certificate_text`).
    certified_rate : float or None
        The rate ``alpha`` certified for the design matrix (``rho_design < alpha``),
        or None.
    certified : bool
        True only if the certificate was obtained with solver status
        ``"optimal"`` (never ``"optimal_inaccurate"``) and the recomputed
        ``rho_design`` and ``rho`` are both below 1 (for given gains: ``rho < 1``).
    method : str
        ``"block-diagonal-lmi"``, ``"block-diagonal-lmi-bisection"``,
        ``"ccl-full-lyapunov"``, ``"ccl-full-lyapunov-rate-search"``,
        ``"refined"`` or ``"given"``.
    solver : str
        Name of the SDP solver used (``"none"`` if none).
    status : str
        Solver status of the returned design (``"lyapunov-verified"`` when the
        certificate is a full Lyapunov matrix from the Lyapunov equation).
    message : str
        Human-readable summary (for ``method="auto"`` it says why the method ran).
    design_tau : int
        The delay bound ``tau1`` designed against (0: delay-free design).
    rho_design : float
        ``rho((I - K D_C-bar)(P kron A^(design_tau+1)))``; equals ``rho`` when
        ``design_tau == 0``.
    iterations : int
        SDP solves (LMI, CCL) or optimiser iterations (refinement).
    certificate_weights : tuple of numpy.ndarray
        For ``status`` starting with :data:`BOUND_STATUS` (the local design above
        :data:`LOCAL_SEARCH_MAX_STATES`): the positive ``(N, n)`` weights ``w`` of the
        weighted infinity norm whose value is ``rho`` (and, for ``design_tau > 0``, a
        second one for ``rho_design``); then ``rho`` and ``rho_design`` are rigorous
        *upper bounds* (:func:`netsim.models.augmented.delay_free_rho_bound`), which
        :func:`netsim.models.augmented.weighted_norm_bound` reproduces in one step.
        Empty otherwise.
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
    design_tau: int = 0
    rho_design: float | None = None
    iterations: int = 0
    certificate_weights: tuple[np.ndarray, ...] = ()

    def __post_init__(self) -> None:
        if self.rho_design is None:
            object.__setattr__(self, "rho_design", float(self.rho))


# ---------------------------------------------------------------------------
# input handling
# ---------------------------------------------------------------------------


def _tau1(tau1: Any) -> int:
    if isinstance(tau1, bool) or not isinstance(tau1, (int, np.integer)) or tau1 < 0:
        raise ValueError(f"tau1 must be a non-negative integer, got {tau1!r}")
    return int(tau1)


def _design_matrix(A: np.ndarray, tau1: int) -> np.ndarray:
    """``A^(tau1+1)``, the matrix the delay-bound design uses in place of ``A``."""
    with np.errstate(over="ignore", invalid="ignore"):
        Ad = np.linalg.matrix_power(A, tau1 + 1)
    if not np.all(np.isfinite(Ad)):
        raise GainDesignError(
            f"delay-bound design for tau1={tau1} is infeasible: A^{tau1 + 1} overflows"
        )
    return Ad


def _gain_from_effective(Li: np.ndarray, Ci: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(L_i, K_i)`` with ``K_i = L_i (C_i C_i^T)^+ C_i`` and ``K_i C_i^T = L_i``.

    ``L_i`` is projected onto the row space that ``C_i`` can realise (a no-op when
    ``C_i`` has full row rank); the projection leaves ``L_i C_i`` unchanged.
    """
    G_pinv = np.linalg.pinv(Ci @ Ci.T)
    L_eff = Li @ G_pinv @ (Ci @ Ci.T)
    K = L_eff @ G_pinv @ Ci
    return L_eff, K


def _gains(L_eff: Sequence[np.ndarray], C: list[np.ndarray]):
    pairs = [_gain_from_effective(Li, Ci) for Li, Ci in zip(L_eff, C, strict=True)]
    return [p[0] for p in pairs], [p[1] for p in pairs]


def _rho(P: np.ndarray, A: np.ndarray, C: list[np.ndarray], L: Sequence[np.ndarray]) -> float:
    return spectral_radius(delay_free_closed_loop(P, A, C, L))


# ---------------------------------------------------------------------------
# observability (the PBH test itself is netsim.models.observability.unobservable_modes)
# ---------------------------------------------------------------------------


def _observability_reason(
    P: np.ndarray, A: np.ndarray, C: list[np.ndarray], rtol: float, label: str
) -> str:
    """Empty if ``(P kron A, D_C-bar)`` passes the PBH test, else a one-line reason."""
    bad = unobservable_modes(np.kron(P, A), output_gain_matrix(C), rtol, distinct=True)
    if not bad:
        return ""
    worst = max(abs(lam) for lam in bad)
    return (
        f"({label}, D_C-bar) is not observable: the PBH rank test fails for "
        f"{len(bad)} distinct eigenvalue(s) of {label} (largest modulus {worst:.4g})"
    )


# ---------------------------------------------------------------------------
# method and solver selection
# ---------------------------------------------------------------------------


def select_method(
    n_agents: int, n_states: int, threshold: int = CCL_AUTO_MAX_STATES
) -> tuple[str, str]:
    """Choose the design for ``method="auto"`` from the problem size alone.

    Parameters
    ----------
    n_agents : int
        Number of agents ``N``.
    n_states : int
        Plant order ``n``.
    threshold : int, default CCL_AUTO_MAX_STATES
        Largest ``N n`` for which CCL is chosen.

    Returns
    -------
    method : str
        ``"ccl"`` if ``N n <= threshold``, else ``"lmi"``.
    reason : str
        One sentence saying why.
    """
    size = int(n_agents) * int(n_states)
    if size > LOCAL_AUTO_MIN_STATES:
        return "local", (
            f"auto: N n = {size} > {LOCAL_AUTO_MIN_STATES}, so the local scaled-projection "
            f"design ran (the block-diagonal LMI's SDP has an {size}-row cone: too slow "
            f"and memory-hungry at this size)"
        )
    if size <= threshold:
        return "ccl", (
            f"auto: N n = {size} <= {threshold}, so the full-Lyapunov CCL design ran "
            f"(less conservative than a block-diagonal Lyapunov matrix)"
        )
    return "lmi", (
        f"auto: N n = {size} > {threshold}, so the block-diagonal LMI ran (CCL has "
        f"two full {size}x{size} matrix variables, two {2 * size}-row SDP cones and one SDP "
        f"solve per linearisation step; it is too slow and memory-hungry at this size)"
    )


def _normalise_method(method: str) -> str:
    key = str(method).lower()
    if key not in _ALIASES:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    return _ALIASES[key]


def _pick_solver(solver: str | None, large: bool = False) -> str:
    import cvxpy as cp

    installed = set(cp.installed_solvers())
    if solver is not None:
        name = solver.upper()
        if name not in installed:
            raise GainDesignError(
                f"requested solver {solver!r} is not installed (installed: {sorted(installed)})"
            )
        return name
    order = ("SCS", *DEFAULT_SOLVERS) if large else DEFAULT_SOLVERS
    for name in order:
        if name in installed:
            return name
    raise GainDesignError(
        f"no SDP solver available: need one of {DEFAULT_SOLVERS}, installed: {sorted(installed)}"
    )


def _solve_kwargs(solver: str, options: dict[str, Any] | None) -> dict[str, Any]:
    kwargs: dict[str, Any] = {}
    if solver == "SCS":
        kwargs.update(SCS_DEFAULT_OPTIONS)
        kwargs["warm_start"] = True
    if options:
        kwargs.update(options)
    return kwargs


def _run(problem: Any, solver: str, kwargs: dict[str, Any]) -> tuple[str, str]:
    """Solve; return ``(status, error)`` with status ``"solver_error"`` on exceptions."""
    try:
        with warnings.catch_warnings():
            # cvxpy warns on inaccurate solutions; the status is reported instead.
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=solver, **kwargs)
    except Exception as exc:  # noqa: BLE001 - any solver failure is "not certified"
        return "solver_error", f"{type(exc).__name__}: {exc}"
    return str(problem.status), ""


# ---------------------------------------------------------------------------
# block-diagonal LMI
# ---------------------------------------------------------------------------


@dataclass
class _Attempt:
    alpha: float
    status: str
    L: list[np.ndarray] | None
    K: list[np.ndarray] | None
    rho: float
    error: str
    iterations: int = 1
    X: np.ndarray | None = None
    S: np.ndarray | None = None
    verified: bool = True


def _blockdiag_expr(blocks: list, n_rows: int) -> Any:
    import cvxpy as cp

    N = len(blocks)
    return cp.bmat(
        [[blocks[i] if i == j else np.zeros((n_rows, n_rows)) for j in range(N)] for i in range(N)]
    )


class _LMI:
    """The rate-parametrised block-diagonal LMI, built once and re-solved (DPP).

    ``fixed_L`` adds ``Z_i = X_i L_i`` so the problem certifies given gains.
    """

    def __init__(
        self,
        P: np.ndarray,
        A: np.ndarray,
        C: list[np.ndarray],
        margin: float,
        solver: str,
        options: dict[str, Any] | None = None,
        fixed_L: Sequence[np.ndarray] | None = None,
    ) -> None:
        import cvxpy as cp

        self.P, self.A, self.C, self.solver = P, A, C, solver
        self.kwargs = _solve_kwargs(solver, options)
        N, n = P.shape[0], A.shape[0]
        M = np.kron(P, A)
        self.alpha = cp.Parameter(nonneg=True, name="alpha")
        self.X = [cp.Variable((n, n), symmetric=True, name=f"X_{i}") for i in range(N)]
        self.Z = [cp.Variable((n, Ci.shape[0]), name=f"Z_{i}") for i, Ci in enumerate(C)]

        X = _blockdiag_expr(self.X, n)
        ZC = _blockdiag_expr([Zi @ Ci for Zi, Ci in zip(self.Z, C, strict=True)], n)
        Y = (X - ZC) @ M  # = X A-hat, linear in (X_i, Z_i)
        S = cp.bmat([[self.alpha * X, Y.T], [Y, self.alpha * X]])
        S_sym = (S + S.T) / 2  # `>>` only constrains the symmetric part anyway
        cons = [S_sym >> margin * np.eye(2 * N * n)]
        cons += [Xi >> np.eye(n) for Xi in self.X]
        if fixed_L is not None:
            cons += [Zi == Xi @ Li for Zi, Xi, Li in zip(self.Z, self.X, fixed_L, strict=True)]
        self.problem = cp.Problem(cp.Minimize(0), cons)

    def _blocks(self) -> list[np.ndarray]:
        return [np.asarray(Xi.value, dtype=float) for Xi in self.X]

    def solve(self, alpha: float) -> _Attempt:
        self.alpha.value = float(alpha)
        return self._finish(alpha)

    def _finish(self, alpha: float) -> _Attempt:
        status, error = _run(self.problem, self.solver, self.kwargs)
        if status == "solver_error":
            return _Attempt(alpha, status, None, None, float("inf"), error)
        if status not in ("optimal", "optimal_inaccurate"):
            return _Attempt(alpha, status, None, None, float("inf"), "")
        try:
            L_raw = []
            for Xv, Zi, Ci in zip(self._blocks(), self.Z, self.C, strict=True):
                Zv = np.asarray(Zi.value, dtype=float).reshape(Xv.shape[0], Ci.shape[0])
                L_raw.append(np.linalg.solve((Xv + Xv.T) / 2, Zv))
            L, K = _gains(L_raw, self.C)
            rho = _rho(self.P, self.A, self.C, L)
        except (np.linalg.LinAlgError, TypeError, ValueError) as exc:
            return _Attempt(
                alpha, status, None, None, float("inf"), f"could not recover gains: {exc}"
            )
        return _Attempt(alpha, status, L, K, rho, "")


class _SplitLMI(_LMI):
    """The same certificate in split form, for large ``N n`` (one ``N n``-row cone).

    ``[[A X, Y^T], [Y, A X]] > 0`` with ``Y = H M``, ``H = blockdiag(H_i)`` is, by a
    Schur complement, ``alpha^2 X > M^T blockdiag(H_i^T X_i^{-1} H_i) M``; with
    ``W_i >= H_i^T X_i^{-1} H_i`` (an LMI of size ``2n``) this is
    ``alpha^2 X - M^T blockdiag(W_i) M > 0``, and the two are equivalent for strict
    inequalities. ``M^T blockdiag(W_i) M`` is assembled as one sparse linear map.
    """

    def __init__(
        self,
        P: np.ndarray,
        A: np.ndarray,
        C: list[np.ndarray],
        margin: float,
        solver: str,
        options: dict[str, Any] | None = None,
        fixed_L: Sequence[np.ndarray] | None = None,
    ) -> None:
        import cvxpy as cp
        import scipy.sparse as sp

        self.P, self.A, self.C, self.solver = P, A, C, solver
        self.kwargs = _solve_kwargs(solver, options)
        N, n = P.shape[0], A.shape[0]
        Nn = N * n
        t = n * (n + 1) // 2
        r_idx, c_idx = np.triu_indices(n)

        # vec_F(X_i) = T_small @ x_i for the upper-triangle coordinates x_i
        rows = np.concatenate([c_idx * n + r_idx, r_idx * n + c_idx])
        cols = np.concatenate([np.arange(t), np.arange(t)])
        T_small = sp.csc_matrix((np.ones(2 * t), (rows, cols)), shape=(n * n, t))
        T_small.data[:] = 1.0  # diagonal entries were entered twice (summed): reset
        # vec_F(blockdiag(X_i)) = T_X @ x
        off = (np.arange(N) * n)[:, None]
        R = (off + r_idx[None, :]).ravel()
        Cc = (off + c_idx[None, :]).ravel()
        col = np.arange(N * t)
        T_X = sp.csc_matrix(
            (
                np.ones(2 * N * t),
                (np.concatenate([Cc * Nn + R, R * Nn + Cc]), np.concatenate([col, col])),
            ),
            shape=(Nn * Nn, N * t),
        )
        T_X.data[:] = 1.0
        # vec_F(M^T blockdiag(W_i) M) = K_W @ w, M_i = (row i of P) kron A:
        # M_i^T E M_i = (p_i^T p_i) kron (A^T E A)
        G = np.einsum("sa,sb->sab", A[r_idx], A[c_idx])
        G = G + np.transpose(G, (0, 2, 1))
        G[r_idx == c_idx] /= 2.0  # E = e_r e_r^T on the diagonal
        kr, kc, kv = [], [], []
        a_idx, b_idx = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        for i in range(N):
            supp = np.flatnonzero(P[i])
            if supp.size == 0:
                continue
            outer = np.outer(P[i, supp], P[i, supp])
            # value[s, j, k, a, b] = outer[j, k] * G[s, a, b] at (supp[j] n + a, supp[k] n + b)
            val = outer[None, :, :, None, None] * G[:, None, None, :, :]
            rr = supp[:, None, None, None] * n + a_idx[None, None, :, :]
            cc = supp[None, :, None, None] * n + b_idx[None, None, :, :]
            vec = np.broadcast_to(cc * Nn + rr, val.shape[1:])
            kr.append(np.broadcast_to(vec, val.shape).ravel())
            kc.append(
                np.broadcast_to(
                    (i * t + np.arange(t))[:, None, None, None, None], val.shape
                ).ravel()
            )
            kv.append(val.ravel())
        K_W = sp.csc_matrix(
            (np.concatenate(kv), (np.concatenate(kr), np.concatenate(kc))),
            shape=(Nn * Nn, N * t),
        )

        self.alpha2 = cp.Parameter(nonneg=True, name="alpha2")
        self.x = cp.Variable(N * t, name="x")
        self.w = cp.Variable(N * t, name="w")
        self.Z = [cp.Variable((n, Ci.shape[0]), name=f"Z_{i}") for i, Ci in enumerate(C)]
        self._T_small, self._t, self._n = T_small, t, n
        cons = []
        for i, (Zi, Ci) in enumerate(zip(self.Z, C, strict=True)):
            Xi = cp.reshape(T_small @ self.x[i * t : (i + 1) * t], (n, n), order="F")
            Wi = cp.reshape(T_small @ self.w[i * t : (i + 1) * t], (n, n), order="F")
            Hi = Xi - Zi @ Ci
            B = cp.bmat([[Wi, Hi.T], [Hi, Xi]])
            cons.append((B + B.T) / 2 >> 0)
            cons.append(Xi >> np.eye(n))
            if fixed_L is not None:
                cons.append(Zi == Xi @ fixed_L[i])
        big = cp.reshape(self.alpha2 * (T_X @ self.x) - K_W @ self.w, (Nn, Nn), order="F")
        cons.append(big >> margin * np.eye(Nn))
        self.problem = cp.Problem(cp.Minimize(0), cons)

    def _blocks(self) -> list[np.ndarray]:
        x = np.asarray(self.x.value, dtype=float)
        n, t = self._n, self._t
        return [
            (self._T_small @ x[i * t : (i + 1) * t]).reshape((n, n), order="F")
            for i in range(len(self.Z))
        ]

    def solve(self, alpha: float) -> _Attempt:
        self.alpha2.value = float(alpha) ** 2
        return self._finish(alpha)


def _accepted(att: _Attempt) -> bool:
    """A solve certifies ``alpha`` only if optimal, verified, and the recomputed rho is below."""
    return att.status == "optimal" and att.L is not None and att.verified and att.rho < att.alpha


def _failure(att: _Attempt, solver: str, what: str = "LMI") -> GainDesignError:
    a = f"{att.alpha:.6g}"
    if att.status == "solver_error":
        why = f"solver {solver} failed at alpha={a}: {att.error}"
    elif att.status in ("infeasible", "infeasible_inaccurate"):
        why = f"{what} infeasible at alpha={a} (solver {solver} status {att.status})"
    elif att.L is None:
        why = f"{what} not solved at alpha={a} (solver {solver} status {att.status}) {att.error}"
    else:
        why = (
            f"{what} not certified at alpha={a}: solver {solver} status {att.status}, "
            f"recomputed rho={att.rho:.6g}"
        )
        if att.error:
            why += f"; {att.error}"
    return GainDesignError(why.strip())


@dataclass
class _Outcome:
    att: _Attempt
    method: str
    solver: str
    message: str
    certified_rate: float | None
    iterations: int


def _design_lmi(
    P: np.ndarray,
    A: np.ndarray,
    C: list[np.ndarray],
    *,
    rate: float | None,
    bisect: bool,
    margin: float,
    tolerance: float,
    solver: str | None,
    options: dict[str, Any] | None,
    what: str = "rho(A-hat)",
) -> _Outcome:
    Nn = P.shape[0] * A.shape[0]
    large = Nn > LARGE_LMI_STATES
    name = _pick_solver(solver, large)
    form = "split" if large else "full"
    try:
        cls = _SplitLMI if large else _LMI
        lmi = cls(P, A, C, margin, name, options)
    except Exception as exc:  # noqa: BLE001 - never leak a modelling-layer traceback
        raise GainDesignError(f"could not build the LMI: {type(exc).__name__}: {exc}") from None
    note = (
        f" (split form with one {Nn}-row cone because N n = {Nn} > {LARGE_LMI_STATES})"
        if form == "split"
        else ""
    )

    alpha0 = 1.0 if rate is None else float(rate)
    first = lmi.solve(alpha0)
    n_solves = 1
    if not _accepted(first):
        if first.status == "optimal_inaccurate" and first.L is not None and first.rho < alpha0:
            return _Outcome(
                first,
                _METHOD_SINGLE,
                name,
                f"solver {name} returned optimal_inaccurate at alpha={alpha0:.6g}; "
                f"recomputed {what}={first.rho:.6g} but the rate is NOT certified{note}",
                None,
                n_solves,
            )
        raise _failure(first, name) from None

    if rate is not None or not bisect:
        return _Outcome(
            first,
            _METHOD_SINGLE,
            name,
            f"block-diagonal LMI certified {what} < {alpha0:.6g} "
            f"(recomputed {what}={first.rho:.6g}, solver {name}){note}",
            alpha0,
            n_solves,
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
    return _Outcome(
        best,
        _METHOD_BISECTION,
        name,
        f"block-diagonal LMI certified {what} < {best.alpha:.6g} "
        f"(bisection to {tolerance:g}, {n_solves} solves, infeasible/uncertified "
        f"below {lo:.6g}); recomputed {what}={best.rho:.6g}, solver {name}{note}",
        best.alpha,
        n_solves,
    )


# ---------------------------------------------------------------------------
# cone-complementarity linearisation (full Lyapunov matrix)
# ---------------------------------------------------------------------------


def _lyapunov_certificate(Ahat: np.ndarray, alpha: float) -> np.ndarray | None:
    """Full Lyapunov matrix ``X > 0`` with ``A-hat^T X A-hat < alpha^2 X``, or None.

    Solves ``F^T X F - X + I = 0`` (``F = A-hat / alpha``; it has a positive
    definite solution iff ``rho(F) < 1``) and verifies with numpy that ``X > 0``
    and ``X - F^T X F >= I/2`` (it should be ``I``: the check fails when rounding
    in the ill-conditioned case ``rho(F) -> 1`` is no longer negligible).
    """
    from scipy.linalg import solve_discrete_lyapunov

    F = np.asarray(Ahat, dtype=float) / float(alpha)
    k = F.shape[0]
    try:
        with np.errstate(all="ignore"):
            X = solve_discrete_lyapunov(F.T, np.eye(k))
    except (np.linalg.LinAlgError, ValueError):
        return None
    X = (X + X.T) / 2
    if not np.all(np.isfinite(X)):
        return None
    try:
        if np.linalg.eigvalsh(X)[0] <= 0:
            return None
        R = X - F.T @ X @ F
        if np.linalg.eigvalsh((R + R.T) / 2)[0] < 0.5:
            return None
    except np.linalg.LinAlgError:
        return None
    return X


def _balanced_pair(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(c X, (c X)^{-1})`` with ``c`` balancing the two norms."""
    S = np.linalg.inv(X)
    c = math.sqrt(np.linalg.norm(S, 2) / np.linalg.norm(X, 2))
    Xc, Sc = c * X, S / c
    return (Xc + Xc.T) / 2, (Sc + Sc.T) / 2


class _CCL:
    """CCL subproblem ``min trace(X_k S + S_k X)`` over the relaxed LMIs (DPP)."""

    def __init__(
        self,
        P: np.ndarray,
        A: np.ndarray,
        C: list[np.ndarray],
        margin: float,
        solver: str,
        options: dict[str, Any] | None = None,
    ) -> None:
        import cvxpy as cp

        self.P, self.A, self.C, self.solver = P, A, C, solver
        self.kwargs = _solve_kwargs(solver, options)
        N, n = P.shape[0], A.shape[0]
        Nn = self.size = N * n
        M = np.kron(P, A)
        self.inv_alpha = cp.Parameter(nonneg=True, name="inv_alpha")
        self.Xk = cp.Parameter((Nn, Nn), symmetric=True, name="X_k")
        self.Sk = cp.Parameter((Nn, Nn), symmetric=True, name="S_k")
        self.X = cp.Variable((Nn, Nn), symmetric=True, name="X")
        self.S = cp.Variable((Nn, Nn), symmetric=True, name="S")
        self.L = [cp.Variable((n, Ci.shape[0]), name=f"L_{i}") for i, Ci in enumerate(C)]
        LC = _blockdiag_expr([Li @ Ci for Li, Ci in zip(self.L, C, strict=True)], n)
        B = self.inv_alpha * (M - LC @ M)  # A-hat / alpha, affine in L
        T1 = cp.bmat([[self.X, B.T], [B, self.S]])
        eye = np.eye(Nn)
        T2 = cp.bmat([[self.X, eye], [eye, self.S]])
        cons = [(T1 + T1.T) / 2 >> margin * np.eye(2 * Nn), (T2 + T2.T) / 2 >> 0]
        objective = cp.sum(cp.multiply(self.Xk, self.S)) + cp.sum(cp.multiply(self.Sk, self.X))
        self.problem = cp.Problem(cp.Minimize(objective), cons)

    def step(self, alpha: float, Xk: np.ndarray, Sk: np.ndarray) -> tuple[_Attempt, float]:
        """One linearisation step; returns the attempt and the objective value."""
        self.inv_alpha.value = 1.0 / float(alpha)
        self.Xk.value = (Xk + Xk.T) / 2
        self.Sk.value = (Sk + Sk.T) / 2
        status, error = _run(self.problem, self.solver, self.kwargs)
        if status not in ("optimal", "optimal_inaccurate"):
            return _Attempt(alpha, status, None, None, float("inf"), error), float("nan")
        try:
            X = np.asarray(self.X.value, dtype=float)
            S = np.asarray(self.S.value, dtype=float)
            L_raw = [
                np.asarray(Li.value, dtype=float).reshape(self.A.shape[0], Ci.shape[0])
                for Li, Ci in zip(self.L, self.C, strict=True)
            ]
            L, K = _gains(L_raw, self.C)
            rho = _rho(self.P, self.A, self.C, L)
        except (np.linalg.LinAlgError, TypeError, ValueError) as exc:
            return (
                _Attempt(
                    alpha, status, None, None, float("inf"), f"could not recover gains: {exc}"
                ),
                float("nan"),
            )
        att = _Attempt(alpha, status, L, K, rho, "", X=(X + X.T) / 2, S=(S + S.T) / 2)
        return att, float(self.problem.value)


#: CCL: a target rate is abandoned after this many steps without a new best rho.
_CCL_PATIENCE = 8
#: CCL: relative decrease of the best rho that counts as progress.
_CCL_PROGRESS = 1e-4
#: CCL: first distance of the target rate below the best rho.
_CCL_FIRST_STEP = 0.05


def _design_ccl(
    P: np.ndarray,
    A: np.ndarray,
    C: list[np.ndarray],
    *,
    rate: float | None,
    bisect: bool,
    margin: float,
    tolerance: float,
    solver: str | None,
    options: dict[str, Any] | None,
    max_iter: int,
    what: str = "rho(A-hat)",
) -> _Outcome:
    """CCL with a descending target rate.

    Every linearisation step is one SDP at the current target rate ``alpha``,
    started from the previous step's ``(X, S)``. The gain of every iterate is
    checked with numpy; an iterate whose ``rho`` beats the best so far becomes
    the new best once a full Lyapunov matrix (discrete Lyapunov equation,
    verified with numpy) certifies it at ``rho + tolerance/2``. When an iterate
    reaches ``rho < alpha``, ``delta`` doubles; when ``_CCL_PATIENCE`` steps bring
    no new best, ``delta`` halves; either way the target moves to
    ``best rho - delta`` and the iteration continues from the current ``(X, S)``
    (restarting from the best iterate was tried: it repeats the first steps'
    rise of rho and loses the progress). This replaces a plain bisection,
    which costs a whole CCL run per failed rate. The search ends when
    ``delta < tolerance / 2`` or after ``max_iter`` SDP solves in total. With
    ``rate`` (or ``bisect=False``) it stops at the first iterate certified at
    ``rate`` (or 1).
    """
    Nn = P.shape[0] * A.shape[0]
    name = _pick_solver(solver, Nn > CCL_CLARABEL_MAX_STATES)
    if name == "SCS":  # the linearisation steps need no high accuracy (see module notes)
        options = {**CCL_SCS_OPTIONS, **(options or {})}
    try:
        ccl = _CCL(P, A, C, margin, name, options)
    except Exception as exc:  # noqa: BLE001 - never leak a modelling-layer traceback
        raise GainDesignError(
            f"could not build the CCL problem: {type(exc).__name__}: {exc}"
        ) from None

    alpha0 = 1.0 if rate is None else float(rate)
    single = rate is not None or not bisect
    Xk = Sk = np.eye(Nn)
    target, delta = alpha0, _CCL_FIRST_STEP
    best: _Attempt | None = None
    cert: float | None = None
    last: _Attempt | None = None
    steps = at_target = stalled = 0
    log: list[str] = []
    end = ""

    def retarget(reached: bool, why: str) -> bool:
        """Move the target after success/failure; False when the search is over."""
        nonlocal target, delta, at_target, stalled, end
        log.append(
            f"alpha={target:.6g} {'reached' if reached else 'not reached'} ({at_target} step(s))"
        )
        delta = 2.0 * delta if reached else 0.5 * delta
        if single or best is None:
            end = why
            return False
        if delta < 0.5 * tolerance:
            end = f"{why}; target step {delta:.3g} below tolerance/2"
            return False
        if best.rho <= 0.5 * tolerance:
            end = f"{why}; rho={best.rho:.3g} is within tolerance/2 of 0"
            return False
        # the SDP scales by 1/alpha: never aim at 0, halve the best rate instead
        target = best.rho - delta if best.rho > delta else 0.5 * best.rho
        at_target = stalled = 0
        return True

    while True:
        if steps >= max_iter:
            end = f"step budget max_iter={max_iter} exhausted"
            break
        att, _ = ccl.step(target, Xk, Sk)
        steps += 1
        at_target += 1
        if att.L is None:  # solver failure or infeasible subproblem
            last = att
            why = f"SDP at alpha={target:.6g}: status {att.status} {att.error}".strip()
            if not retarget(False, why):
                break
            continue
        last = att
        r = att.rho
        improved = False
        if att.status == "optimal" and (best is None or r < best.rho):
            cand = alpha0 if single else min(alpha0, r + 0.5 * tolerance)
            Ahat = delay_free_closed_loop(P, A, C, att.L)
            if r < cand and _lyapunov_certificate(Ahat, cand) is not None:
                improved = best is None or r < best.rho * (1 - _CCL_PROGRESS)
                best, cert = att, cand
        assert att.X is not None and att.S is not None
        Xk, Sk = att.X, att.S
        if best is att and r < target:
            if not retarget(True, f"alpha={target:.6g} reached"):
                break
            continue
        stalled = 0 if improved else stalled + 1
        if stalled >= _CCL_PATIENCE:
            why = f"no new best rho in {_CCL_PATIENCE} steps at alpha={target:.6g}"
            if not retarget(False, why):
                break

    if best is None or cert is None:
        fail = last if last is not None else _Attempt(alpha0, "not_run", None, None, math.inf, "")
        fail.alpha = alpha0
        fail.verified = False
        fail.error = (
            f"CCL found no gain with rho < {alpha0:.6g} in {steps} SDP solve(s) "
            f"({end}); last iterate rho={fail.rho:.6g}"
        )
        raise _failure(fail, name, "CCL") from None
    best.alpha = cert
    if single:
        return _Outcome(
            best,
            _METHOD_CCL,
            name,
            f"CCL (full Lyapunov matrix) certified {what} < {cert:.6g} after {steps} "
            f"linearisation step(s); recomputed {what}={best.rho:.6g}, solver {name}",
            cert,
            steps,
        )
    return _Outcome(
        best,
        _METHOD_CCL_SEARCH,
        name,
        f"CCL (full Lyapunov matrix) certified {what} < {cert:.6g} ({steps} SDP solves, "
        f"{end}; targets: "
        + "; ".join(log)
        + f"); recomputed {what}={best.rho:.6g}, solver {name}",
        cert,
        steps,
    )


# ---------------------------------------------------------------------------
# public design entry point
# ---------------------------------------------------------------------------


def _finalise(
    out: _Outcome,
    P: np.ndarray,
    A: np.ndarray,
    C: list[np.ndarray],
    tau1: int,
    note: str,
) -> GainDesign:
    att = out.att
    assert att.L is not None and att.K is not None
    rho_design = float(att.rho)
    rho = rho_design if tau1 == 0 else _rho(P, A, C, att.L)
    ok = att.status == "optimal" and out.certified_rate is not None
    rate = float(out.certified_rate) if ok and out.certified_rate is not None else None
    certified = bool(ok and rho_design < 1.0 and rho < 1.0)
    message = out.message
    if tau1:
        message = (
            f"delay-bound design for tau1={tau1} (P kron A^{tau1 + 1} in place of P kron A, "
            f"LCSYS2022 Discussion 5): rho_design={rho_design:.6g}"
            + (f" certified < {rate:.6g}" if rate is not None else " (not certified)")
            + f"; delay-free rho(A-hat)={rho:.6g}"
            + (" (Schur stable)" if rho < 1 else " (NOT Schur stable: not certified)")
            + f". {message}"
        )
    if note:
        message = f"{note}. {message}"
    return GainDesign(
        L=tuple(att.L),
        K=tuple(att.K),
        rho=float(rho),
        certified_rate=rate,
        certified=certified,
        method=out.method,
        solver=out.solver,
        status=att.status,
        message=message,
        design_tau=tau1,
        rho_design=rho_design,
        iterations=int(out.iterations),
    )


def design_gains(
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    *,
    method: str = "lmi",
    rate: float | None = None,
    bisect: bool = True,
    margin: float = DEFAULT_MARGIN,
    tolerance: float = DEFAULT_TOLERANCE,
    solver: str | None = None,
    tau1: int = 0,
    max_iter: int = DEFAULT_CCL_MAX_ITER,
    solver_options: dict[str, Any] | None = None,
) -> GainDesign:
    """Design block-diagonal gains with ``rho(A-hat) < alpha`` (LCSYS2022 eq. 13).

    ``method="lmi"`` (default) solves, for ``X = blockdiag(X_i)`` (``X_i`` of
    shape ``(n, n)``) and ``Z = blockdiag(Z_i)`` (``Z_i`` of shape ``(n, m_i)``),

        [[alpha X, ((X - Z D_C) M)^T], [(X - Z D_C) M, alpha X]] >= margin I,
        X_i >= I,

    with ``M = P kron A`` (shape ``(N n, N n)``) and ``Z D_C = blockdiag(Z_i C_i)``,
    then sets ``L_i = X_i^{-1} Z_i`` and ``K_i = L_i (C_i C_i^T)^{-1} C_i``
    (split form and SCS for ``N n > LARGE_LMI_STATES``, see the module notes).
    ``method="ccl"`` uses a full Lyapunov matrix and the cone-complementarity
    linearisation; ``method="auto"`` picks one by size (:func:`select_method`).

    Parameters
    ----------
    P : array_like, shape (N, N)
        Consensus matrix.
    A : array_like, shape (n, n)
        System matrix.
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    method : {"lmi", "ccl", "auto"}, default "lmi"
        Design method (``"block-diagonal"`` is an alias of ``"lmi"``).
    rate : float, optional
        If given, solve once at ``alpha = rate`` (CCL: iterate until a gain is
        certified at ``rate``) instead of the default feasibility check at
        ``alpha = 1`` followed by the rate minimisation.
    bisect : bool, default True
        After the ``alpha = 1`` check, minimise the certified rate (LMI:
        bisection of ``alpha`` in ``(0, 1]``; CCL: descending target search)
        and return the design at the smallest certified ``alpha``.
    margin : float, default DEFAULT_MARGIN
        Strictness margin of the LMI.
    tolerance : float, default DEFAULT_TOLERANCE
        LMI: final width of the bisection interval. CCL: the certified rate is
        ``rho + tolerance/2``, and the target search stops when its step falls
        below ``tolerance/2``.
    solver : str, optional
        cvxpy solver name; default: Clarabel, or SCS for large problems.
    tau1 : int, default 0
        Delay bound of LCSYS2022 Discussion 5: design against
        ``P kron A^(tau1+1)``. ``rho`` stays the delay-free ``rho(A-hat)``;
        ``rho_design`` and ``certified_rate`` refer to the design matrix.
    max_iter : int, default DEFAULT_CCL_MAX_ITER
        CCL linearisation steps per rate (ignored by the LMI).
    solver_options : dict, optional
        Extra keyword arguments for ``cvxpy.Problem.solve`` (e.g. SCS
        ``max_iters`` or ``time_limit_secs``).

    Returns
    -------
    GainDesign
        The design; ``rho`` and ``rho_design`` are recomputed with numpy from ``L``.

    Raises
    ------
    GainDesignError
        If the pair ``(P kron A^(tau1+1), D_C-bar)`` is not observable, the design
        is infeasible or not certified at ``alpha = 1`` (or at ``rate``), or the
        solver fails. For ``tau1 > 0`` the message starts with
        ``"delay-bound design for tau1=... is infeasible"``.
    ValueError
        On inconsistent shapes or invalid parameters.
    """
    kind = _normalise_method(method)
    if kind == "auto" and (_sparse(P) or np.shape(P)[0] * np.shape(A)[0] > LOCAL_AUTO_MIN_STATES):
        kind, note = select_method(np.shape(P)[0], np.shape(A)[0])
        return design_local(P, A, C, tau1=tau1, note=note)
    if kind == "local":
        return design_local(P, A, C, tau1=tau1)
    if _sparse(P):
        raise GainDesignError(
            f"method {method!r} needs the dense N x N consensus matrix (N = {np.shape(P)[0]}): "
            "use [gains] method = 'local' or 'auto' for large sparse networks")
    P_arr, A_arr, C_list = check_system(P, A, C)
    if rate is not None and not (np.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a positive finite number, got {rate}")
    if not margin > 0:
        raise ValueError(f"margin must be > 0, got {margin}")
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    tau = _tau1(tau1)
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")

    note = ""
    if kind == "auto":
        kind, note = select_method(P_arr.shape[0], A_arr.shape[0])

    A_design = _design_matrix(A_arr, tau)
    reason = _observability_reason(P_arr, A_arr, C_list, DEFAULT_OBSERVABILITY_RTOL, "P kron A")
    if reason:
        if tau:
            raise GainDesignError(f"delay-bound design for tau1={tau} is infeasible: {reason}")
        raise GainDesignError(reason)
    if tau:
        # (P kron A^(tau1+1), D) can lose observability even when (P kron A, D) has it:
        # eigenvalues of A whose powers coincide, or (numerically) powers of small
        # eigenvalues that collapse to 0. Only modes of modulus >= 1 make the design
        # infeasible; stable ones only bound the achievable rate from below.
        label = f"P kron A^{tau + 1}"
        bad = unobservable_modes(
            np.kron(P_arr, A_design),
            output_gain_matrix(C_list),
            DEFAULT_OBSERVABILITY_RTOL,
            distinct=True,
        )
        fatal = [lam for lam in bad if abs(lam) >= 1.0]
        if fatal:
            raise GainDesignError(
                f"delay-bound design for tau1={tau} is infeasible: ({label}, D_C-bar) is not "
                f"detectable: the PBH rank test fails for {len(fatal)} distinct eigenvalue(s) "
                f"of modulus >= 1 (largest {max(abs(lam) for lam in fatal):.4g})"
            )
        if bad:
            extra = (
                f"({label}, D_C-bar) fails the PBH test only for {len(bad)} stable "
                f"eigenvalue(s) (largest modulus {max(abs(lam) for lam in bad):.3g}); "
                f"designed anyway"
            )
            note = f"{note}; {extra}" if note else extra

    common: dict[str, Any] = dict(
        rate=rate,
        bisect=bisect,
        margin=margin,
        tolerance=tolerance,
        solver=solver,
        options=solver_options,
        what="rho(A-hat)" if tau == 0 else f"rho((I-KD)(P kron A^{tau + 1}))",
    )
    try:
        if kind == "lmi":
            out = _design_lmi(P_arr, A_design, C_list, **common)
        else:
            out = _design_ccl(P_arr, A_design, C_list, max_iter=int(max_iter), **common)
    except GainDesignError as exc:
        if tau:
            raise GainDesignError(
                f"delay-bound design for tau1={tau} is infeasible with method {kind!r} "
                f"(designing against P kron A^{tau + 1}): {exc}"
            ) from None
        if note:
            raise GainDesignError(f"{note}; {exc}") from None
        raise
    return _finalise(out, P_arr, A_arr, C_list, tau, note)


# ---------------------------------------------------------------------------
# local design for large networks
# ---------------------------------------------------------------------------


def _sparse(P: Any) -> bool:
    import scipy.sparse as sp

    return bool(sp.issparse(P))


def _lemma1_structural(P: Any, A: np.ndarray, stacked: np.ndarray) -> str:
    """The sufficient conditions of LCSYS2022 Lemma 1 for structural observability of
    (P kron A, D_C-bar), checked in O(N + nnz(P)): A structurally full rank, (A, C)
    structurally observable (C: the distinct output rows, each at most n times), P
    irreducible (strongly connected, scipy.sparse.csgraph) and self-damped."""
    from netsim.models.network import links_from_weights, strongly_connected
    from netsim.models.observability import (
        is_structurally_full_rank,
        is_structurally_observable,
        sparsity_pattern,
    )

    n = A.shape[0]
    A_pat = sparsity_pattern(A)
    rows, counts = np.unique(sparsity_pattern(stacked), axis=0, return_counts=True)
    C_pat = np.repeat(rows, np.minimum(counts, n), axis=0)
    N = P.shape[0]
    diag = P.diagonal() if _sparse(P) else np.diag(np.asarray(P))
    conditions = {
        "A structurally full rank": is_structurally_full_rank(A_pat),
        "(A, C) structurally observable": is_structurally_observable(A_pat, C_pat),
        "P irreducible": N < 2 or strongly_connected(N, *links_from_weights(P))[0],
        "P self-damped": bool(np.all(diag != 0)),
    }
    failed = [name for name, ok in conditions.items() if not ok]
    if not failed:
        return ("structural: the LCSYS2022 Lemma 1 conditions hold (" +
                ", ".join(conditions) + ")")
    return f"structural: Lemma 1 not applicable ({', '.join(failed)} fails)"


def design_local(
    P: Any,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    *,
    gamma: float | None = None,
    tau1: int = 0,
    note: str = "",
) -> GainDesign:
    """Local gains ``L_i = gamma C_i^T (C_i C_i^T)^+`` for networks of any size.

    Each agent corrects the fraction ``gamma`` of its own innovation in the
    directions it measures (a projection, scaled); no SDP and no N x N matrix.
    The delay-free spectral radius ``rho((I - K D_C-bar)(P kron A))`` (LCSYS2022
    eq. 12) is then computed exactly: dense eigenvalues for a dense ``P`` with
    ``N n <=`` :data:`netsim.models.augmented.DENSE_SIZE_THRESHOLD`, otherwise the
    structured matrix-free method (ARPACK on the block-sparse operator,
    :func:`netsim.models.augmented.delay_free_spectral_radius`). ``gamma`` (unless
    given) is the best of :data:`LOCAL_GAMMAS` when ``N n <=``
    :data:`LOCAL_SEARCH_MAX_STATES`, else :data:`LOCAL_DEFAULT_GAMMA`; the design
    counts as certified iff the exact ``rho`` (and ``rho_design`` for ``tau1 > 0``)
    is below 1.

    Observability: the numeric PBH test of ``(A, C stacked)`` (necessary for the
    network pair; n-dimensional), always; the ``N n``-dimensional PBH test of
    ``(P kron A, D_C-bar)`` only where it is affordable (``N n <= 1500``, dense P).
    Above that, the sufficient conditions of LCSYS2022 Lemma 1 for structural
    observability are checked instead (A structurally full rank, (A, C) structurally
    observable, P irreducible and self-damped; O(N + nnz(P))). The message says which
    ran.

    Parameters
    ----------
    P : numpy.ndarray or scipy.sparse matrix, shape (N, N)
    A : array_like, shape (n, n)
    C : sequence of N arrays, shapes (m_i, n)
    gamma : float, optional
        Gain scale in (0, 2).
    tau1 : int
        Also report ``rho_design`` for ``P kron A^(tau1+1)`` (the gains are the same).
    note : str
        Prefix of the message (why ``auto`` chose this).

    Returns
    -------
    GainDesign
        ``method = "local-scaled-projection"``, ``solver = "none"``, ``status`` names
        the spectral-radius method (``"structured-arpack"`` or ``"dense-eigvals"``).
    """
    from netsim.models.augmented import DENSE_SIZE_THRESHOLD, delay_free_spectral_radius

    tau = _tau1(tau1)
    A_arr = np.asarray(A, dtype=float)
    n = A_arr.shape[0]
    C_list = [np.atleast_2d(np.asarray(Ci, dtype=float)) if np.size(Ci) else
              np.zeros((0, n)) for Ci in C]
    N = P.shape[0]
    if len(C_list) != N:
        raise ValueError(f"C has {len(C_list)} output matrices but P is {N}x{N}")
    if gamma is not None and not 0 < gamma < 2:
        raise ValueError(f"gamma must be in (0, 2), got {gamma}")
    sparse = _sparse(P)
    Nn = N * n
    dense_rho = not sparse and Nn <= DENSE_SIZE_THRESHOLD
    rho_method = "dense-eigvals" if dense_rho else "structured-arpack"
    checks = []
    stacked = np.vstack(C_list)
    bad = unobservable_modes(A_arr, stacked, DEFAULT_OBSERVABILITY_RTOL, distinct=True)
    if bad:
        raise GainDesignError(
            f"(A, C stacked) is not observable: the PBH rank test fails for {len(bad)} "
            f"eigenvalue(s) of A (largest modulus {max(abs(lam) for lam in bad):.4g}); "
            "no gains can stabilise (P kron A, D_C-bar)")
    checks.append("PBH (A, C stacked)")
    if dense_rho:
        # detectability is what the gains need: only modes of modulus >= 1 are fatal
        lost = unobservable_modes(np.kron(np.asarray(P, dtype=float), A_arr),
                                  output_gain_matrix(C_list), DEFAULT_OBSERVABILITY_RTOL,
                                  distinct=True)
        fatal = [lam for lam in lost if abs(lam) >= 1.0]
        if fatal:
            raise GainDesignError(
                f"(P kron A, D_C-bar) is not detectable: the PBH rank test fails for "
                f"{len(fatal)} distinct eigenvalue(s) of modulus >= 1 (largest "
                f"{max(abs(lam) for lam in fatal):.4g})")
        checks.append("PBH (P kron A, D_C-bar)" + (
            f" ({len(lost)} stable unobservable mode(s))" if lost else ""))
    else:
        checks.append(f"not the N n = {Nn} PBH test of (P kron A, D_C-bar) (too large)")
        checks.append(_lemma1_structural(P, A_arr, stacked))
    # the unit gain per distinct output matrix (agents often share one C_i object)
    unit: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for Ci in C_list:
        if id(Ci) not in unit:
            G = np.linalg.pinv(Ci @ Ci.T) if Ci.shape[0] else np.zeros((0, 0))
            unit[id(Ci)] = _gain_from_effective(Ci.T @ G, Ci)
    method = "dense" if dense_rho else "structured"

    def rho_of(g: float, Amat: np.ndarray) -> float:
        L = [g * unit[id(Ci)][0] for Ci in C_list]
        return float(delay_free_spectral_radius(P, Amat, C_list, L, method=method))

    weights: tuple[np.ndarray, ...] = ()
    bound_note = ""
    if gamma is None and Nn > LOCAL_SEARCH_MAX_STATES:
        g = LOCAL_DEFAULT_GAMMA
        how = f"default (no search above N n = {LOCAL_SEARCH_MAX_STATES})"
    else:
        g = float(gamma) if gamma is not None else LOCAL_DEFAULT_GAMMA
        how = "given"
    if not dense_rho and Nn > LOCAL_SEARCH_MAX_STATES:
        # large: the linear-work upper bound first, the exact (ARPACK) radius only if it
        # does not certify
        from netsim.models.augmented import delay_free_rho_bound

        L_g = [g * unit[id(Ci)][0] for Ci in C_list]
        bounds = [delay_free_rho_bound(P, A_arr, C_list, L_g)]
        if tau and bounds[0].bound < 1.0:
            bounds.append(delay_free_rho_bound(P, _design_matrix(A_arr, tau), C_list, L_g,
                                               bases=(bounds[0].basis,)))
        if all(b.bound < 1.0 for b in bounds):
            rho = bounds[0].bound
            rho_design = bounds[-1].bound
            weights = tuple(b.weights for b in bounds)
            rho_method = f"{BOUND_STATUS}-{bounds[0].basis}"
        else:
            bound_note = (f"the weighted-norm bound does not certify (rho(A-hat) <= "
                          f"{bounds[-1].bound:.6g} is not below 1), so ")
    if not weights:
        if gamma is None and Nn <= LOCAL_SEARCH_MAX_STATES:
            tried = [(rho_of(gg, A_arr), gg) for gg in LOCAL_GAMMAS]
            rho, g = min(tried)
            how = f"best rho of gamma in {list(LOCAL_GAMMAS)}"
        else:
            rho = rho_of(g, A_arr)
        rho_design = rho if tau == 0 else rho_of(g, _design_matrix(A_arr, tau))
    L = tuple(g * unit[id(Ci)][0] for Ci in C_list)
    K = tuple(g * unit[id(Ci)][1] for Ci in C_list)
    certified = bool(rho < 1 and rho_design < 1)
    if weights:
        radius = (f"delay-free rho(A-hat) <= {rho:.6f} (rigorous upper bound: the weighted "
                  f"infinity norm ||T^-1 A-hat T||_inf, T = (I kron S) diag(w), S the "
                  f"{bounds[0].basis} basis, w from {bounds[0].iterations} power steps)"
                  f"{'' if tau == 0 else f', rho_design (A^{tau + 1}) <= {rho_design:.6f}'}")
    else:
        radius = (f"{bound_note}exact delay-free rho(A-hat) = {rho:.6f} by the {rho_method} "
                  f"spectral radius"
                  f"{'' if tau == 0 else f', rho_design (A^{tau + 1}) = {rho_design:.6f}'}")
    message = (f"local design L_i = gamma C_i^T (C_i C_i^T)^+, gamma = {g:g} ({how}); "
               f"{radius}; "
               f"{'certified (rho < 1)' if certified else 'NOT certified (rho >= 1)'}; "
               f"observability checks: {', '.join(checks)}")
    if note:
        message = f"{note}; {message}"
    return GainDesign(L=L, K=K, rho=rho, certified_rate=None, certified=certified,
                      method=_METHOD_LOCAL, solver="none", status=rho_method,
                      message=message, design_tau=tau, rho_design=rho_design,
                      iterations=0, certificate_weights=weights)


def certificate_text(certified: bool, status: str, rho: float | None) -> str:
    """What a design's certificate says, in one phrase (the ``gains:`` line of ``netsim run``).

    ``"certified by weighted-norm-bound-eigenvectors: rho(A-hat) <= 0.974776"`` (an
    upper bound, :func:`netsim.models.augmented.delay_free_rho_bound`), ``"certified
    by structured-arpack: rho(A-hat) = 0.968800 (ARPACK)"``, ``"... (dense
    eigenvalues)"``, or ``"NOT certified: rho(A-hat) = ..."``.

    Parameters
    ----------
    certified : bool
        :attr:`GainDesign.certified`.
    status : str
        :attr:`GainDesign.status` (how the certificate was obtained).
    rho : float or None
        :attr:`GainDesign.rho`.

    Returns
    -------
    str
    """
    value = "-" if rho is None else f"{rho:.6f}"
    if str(status).startswith(BOUND_STATUS):
        relation = f"rho(A-hat) <= {value}"
    elif status == "structured-arpack":
        relation = f"rho(A-hat) = {value} (ARPACK)"
    elif status == "dense-eigvals":
        relation = f"rho(A-hat) = {value} (dense eigenvalues)"
    else:
        relation = f"rho(A-hat) = {value}"
    return f"certified by {status}: {relation}" if certified else f"NOT certified: {relation}"


# ---------------------------------------------------------------------------
# direct refinement of the spectral radius
# ---------------------------------------------------------------------------


def _certify_fixed(
    P: np.ndarray,
    A: np.ndarray,
    C: list[np.ndarray],
    L: list[np.ndarray],
    rho: float,
    *,
    margin: float,
    tolerance: float,
    solver: str | None,
    options: dict[str, Any] | None,
) -> tuple[float | None, str, str, str]:
    """Certify given gains: block-diagonal Lyapunov LMI in ``X`` only, else full Lyapunov.

    Returns ``(rate, solver, status, description)``; ``rate`` is None if neither
    certificate exists at ``rho + tolerance`` (capped below 1).
    """
    alpha = rho + tolerance
    if alpha >= 1.0:
        alpha = 0.5 * (rho + 1.0)
    if not rho < alpha:
        return None, "none", "not-certified", f"rho_design={rho:.6g} is not below 1"
    Nn = P.shape[0] * A.shape[0]
    name = "none"
    if Nn > LARGE_LMI_STATES:
        lmi_note = (
            f"block-diagonal Lyapunov LMI with L fixed not tried (N n = {Nn} > {LARGE_LMI_STATES})"
        )
    else:
        try:
            name = _pick_solver(solver)
            lmi = _LMI(P, A, C, margin, name, options, fixed_L=L)
            att = lmi.solve(alpha)
            if att.status == "optimal":
                return (
                    alpha,
                    name,
                    "optimal",
                    (f"block-diagonal Lyapunov LMI with L fixed is feasible at alpha={alpha:.6g}"),
                )
            lmi_note = (
                f"block-diagonal Lyapunov LMI with L fixed: status {att.status} "
                f"at alpha={alpha:.6g}"
            )
        except GainDesignError as exc:
            lmi_note = f"block-diagonal Lyapunov LMI not tried: {exc}"
        except Exception as exc:  # noqa: BLE001
            lmi_note = f"block-diagonal Lyapunov LMI failed: {type(exc).__name__}: {exc}"
    Ahat = delay_free_closed_loop(P, A, C, L)
    if _lyapunov_certificate(Ahat, alpha) is not None:
        return (
            alpha,
            "none",
            "lyapunov-verified",
            (
                f"{lmi_note}; full Lyapunov matrix from the discrete Lyapunov equation "
                f"verified with numpy at alpha={alpha:.6g}"
            ),
        )
    return None, name, "not-certified", f"{lmi_note}; no full Lyapunov certificate either"


def refine_gains(
    design: GainDesign,
    P: ArrayLike,
    A: ArrayLike,
    C: Sequence[ArrayLike],
    *,
    tau1: int = 0,
    max_iter: int = DEFAULT_REFINE_MAX_ITER,
    certify: bool = True,
    tolerance: float = DEFAULT_TOLERANCE,
    margin: float = DEFAULT_MARGIN,
    solver: str | None = None,
    solver_options: dict[str, Any] | None = None,
) -> GainDesign:
    """Minimise ``rho((I - blockdiag(L_i C_i))(P kron A^(tau1+1)))`` over the ``L_i``.

    Starting from ``design.L``, BFGS runs on the spectral radius with its
    gradient ``d|lambda| = Re(conj(lambda) v^H dA-hat u / (|lambda| v^H u))``
    (``u``, ``v`` right and left eigenvectors of the dominant eigenvalue); the
    spectral radius is not smooth where dominant eigenvalues coalesce, so up to
    three restarts follow while they improve, and for at most 60 unknowns a
    Nelder-Mead polish. The best point seen is returned, so the result is never
    worse than the start. The result is certified, if possible, by the
    block-diagonal Lyapunov LMI with ``L`` fixed (linear in ``X`` only) at
    ``alpha = rho + tolerance`` (tried only for ``N n <= LARGE_LMI_STATES``),
    else by a full Lyapunov matrix solved from the discrete Lyapunov equation
    and verified with numpy (``status="lyapunov-verified"``). Each evaluation
    costs one dense eigendecomposition of size ``N n``.

    Parameters
    ----------
    design : GainDesign
        Starting gains.
    P, A, C
        As for :func:`design_gains`.
    tau1 : int, default 0
        Optimise the design matrix ``P kron A^(tau1+1)`` (LCSYS2022 Discussion 5).
    max_iter : int, default DEFAULT_REFINE_MAX_ITER
        Iteration cap of each optimiser run.
    certify : bool, default True
        Try to certify the result (one SDP solve).
    tolerance : float, default DEFAULT_TOLERANCE
        Certificate rate ``alpha = rho + tolerance``.
    margin, solver, solver_options
        As for :func:`design_gains` (used by the certificate).

    Returns
    -------
    GainDesign
        ``method="refined"``; ``certified`` only with a certificate.
    """
    from scipy.linalg import eig
    from scipy.optimize import minimize

    P_arr, A_arr, C_list = check_system(P, A, C)
    tau = _tau1(tau1)
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    if len(design.L) != len(C_list):
        raise ValueError(f"design has {len(design.L)} gains but there are {len(C_list)} agents")
    n = A_arr.shape[0]
    shapes = [(n, Ci.shape[0]) for Ci in C_list]
    L0 = []
    for i, (Li, shp) in enumerate(zip(design.L, shapes, strict=True)):
        arr = np.asarray(Li, dtype=float)
        if arr.shape != shp:
            raise ValueError(f"design.L[{i}] (agent {i}) has shape {arr.shape}, expected {shp}")
        L0.append(arr)
    A_design = _design_matrix(A_arr, tau)
    M = np.kron(P_arr, A_design)
    sizes = [a * b for a, b in shapes]
    splits = np.cumsum(sizes)[:-1]

    def unpack(x: np.ndarray) -> list[np.ndarray]:
        return [p.reshape(s) for p, s in zip(np.split(x, splits), shapes, strict=True)]

    best: dict[str, Any] = {"f": math.inf, "x": None}  # best value and point so far
    evals = {"n": 0}

    def f_and_grad(x: np.ndarray) -> tuple[float, np.ndarray]:
        evals["n"] += 1
        L = unpack(x)
        KD = np.zeros_like(M)
        for i, (Li, Ci) in enumerate(zip(L, C_list, strict=True)):
            KD[i * n : (i + 1) * n, i * n : (i + 1) * n] = Li @ Ci
        Ahat = M - KD @ M
        if not np.all(np.isfinite(Ahat)):
            return math.inf, np.zeros_like(x)
        w, vl, vr = eig(Ahat, left=True, right=True)
        k = int(np.argmax(np.abs(w)))
        lam, u, v = w[k], vr[:, k], vl[:, k]
        val = float(abs(lam))
        if val < best["f"]:
            best["f"], best["x"] = val, x.copy()
        denom = np.vdot(v, u)  # v^H u
        if val == 0.0 or abs(denom) < 1e-14:
            return val, np.zeros_like(x)
        c = np.conj(lam) / (val * denom)
        y = M @ u
        grads = []
        for i, Ci in enumerate(C_list):
            vi, yi = v[i * n : (i + 1) * n], y[i * n : (i + 1) * n]
            grads.append(-np.real(c * np.outer(np.conj(vi), Ci @ yi)).ravel())
        return val, np.concatenate(grads)

    x0 = np.concatenate([Li.ravel() for Li in L0])
    f0, _ = f_and_grad(x0)
    rho_start = f0
    nit = 0
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        for _ in range(4):
            before = best["f"]
            res = minimize(
                f_and_grad,
                best["x"],
                jac=True,
                method="BFGS",
                options={"maxiter": int(max_iter), "gtol": 1e-12},
            )
            nit += int(res.nit)
            if not best["f"] < before - 1e-9:
                break
        if x0.size <= 60:
            def value(z: np.ndarray) -> float:
                return f_and_grad(z)[0]

            res = minimize(
                value,
                best["x"],
                method="Nelder-Mead",
                options={
                    "maxiter": int(max_iter) * 10,
                    "maxfev": int(max_iter) * 20,
                    "xatol": 1e-9,
                    "fatol": 1e-12,
                    "adaptive": True,
                },
            )
            nit += int(res.nit)

    L_best, K_best = _gains(unpack(best["x"]), C_list)
    rho_design = _rho(P_arr, A_design, C_list, L_best)
    rho = rho_design if tau == 0 else _rho(P_arr, A_arr, C_list, L_best)
    if rho_design > rho_start:  # the K projection changed nothing in theory; be safe
        L_best, K_best = _gains(L0, C_list)
        rho_design = _rho(P_arr, A_design, C_list, L_best)
        rho = rho_design if tau == 0 else _rho(P_arr, A_arr, C_list, L_best)

    rate: float | None = None
    name, status, cert_note = "none", "not-certified", "certification not requested"
    if certify:
        rate, name, status, cert_note = _certify_fixed(
            P_arr,
            A_design,
            C_list,
            L_best,
            rho_design,
            margin=margin,
            tolerance=tolerance,
            solver=solver,
            options=solver_options,
        )
    certified = rate is not None and rho_design < 1.0 and rho < 1.0
    what = "rho(A-hat)" if tau == 0 else f"rho((I-KD)(P kron A^{tau + 1}))"
    message = (
        f"refined from {design.method}: {what} {rho_start:.6g} -> {rho_design:.6g} "
        f"({nit} optimiser iterations, {evals['n']} evaluations); "
        + (f"certified < {rate:.6g}: " if rate is not None else "NOT certified: ")
        + cert_note
    )
    if tau:
        message += f"; delay-free rho(A-hat)={rho:.6g}" + ("" if rho < 1 else " (NOT stable)")
    return GainDesign(
        L=tuple(L_best),
        K=tuple(K_best),
        rho=float(rho),
        certified_rate=rate,
        certified=bool(certified),
        method=_METHOD_REFINED,
        solver=name,
        status=status,
        message=message,
        design_tau=tau,
        rho_design=float(rho_design),
        iterations=nit,
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
    P_arr, A_arr, C_list = check_system(P, A, C)
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


# ---------------------------------------------------------------------------
# a scenario's [gains] table
# ---------------------------------------------------------------------------


def design_request(
    scenario: Scenario,
    *,
    method: str | None = None,
    tau1: int | None = None,
    refine: bool = False,
) -> dict[str, Any]:
    """Resolve what :func:`design_for_scenario` designs: the scenario's ``[gains]``, overridden.

    Parameters
    ----------
    scenario : Scenario
        Its ``gains`` (``method``, ``tau1``, ``refine_from``, ``K``) are the defaults.
    method : {"lmi", "ccl", "auto"}, optional
        Replace the scenario's method (a ``refined`` scenario is then not refined
        unless ``refine``).
    tau1 : int, optional
        Replace the scenario's ``gains.tau1``.
    refine : bool, default False
        Refine the resulting design (:func:`refine_gains`), as ``netsim design --refine``.

    Returns
    -------
    dict
        ``{"method", "refine_from", "tau1"}`` in the scenario's vocabulary: ``method``
        is one of ``lmi``, ``ccl``, ``auto``, ``refined``, ``given``; ``refine_from``
        is the starting design of ``refined`` (else None).

    Raises
    ------
    ValueError
        On an unknown ``method`` or a negative ``tau1``, or a ``tau1 > 0`` for given
        gains that are not refined.
    """
    spec = scenario.gains
    if method is None:
        refined = spec.method == "refined"
        base = (spec.refine_from or "auto") if refined else spec.method
        refined = refined or bool(refine)
    else:
        key = str(method).lower()
        if key not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        base, refined = key, bool(refine)
    tau = spec.tau1 if tau1 is None else _tau1(tau1)
    if base == "given" and tau and not refined:
        raise ValueError(
            f"tau1={tau}: the scenario's gains are given (gains.method = 'given'), which "
            f"has no delay bound; refine them or choose a design method"
        )
    return {
        "method": "refined" if refined else base,
        "refine_from": base if refined else None,
        "tau1": int(tau),
    }


@single_threaded_blas()
def design_for_scenario(
    scenario: Scenario,
    *,
    method: str | None = None,
    tau1: int | None = None,
    refine: bool = False,
) -> GainDesign:
    """Return the gains a scenario's ``[gains]`` table asks for.

    ``lmi``, ``ccl`` and ``auto`` run :func:`design_gains` with that method and
    ``gains.tau1``; ``refined`` runs the ``gains.refine_from`` design (or wraps the
    given ``K``) and then :func:`refine_gains` with the same ``tau1``; ``given``
    wraps ``gains.K`` (:func:`gains_from_matrices`). The keyword arguments override
    the table (see :func:`design_request`); without them this is what ``netsim run``,
    ``analyze``, ``bench`` and ``design`` use.

    Parameters
    ----------
    scenario : Scenario
        The scenario (consensus matrix, plant and ``gains``).
    method : {"lmi", "ccl", "auto"}, optional
        Override ``gains.method``.
    tau1 : int, optional
        Override ``gains.tau1``.
    refine : bool, default False
        Refine the design afterwards (``netsim design --refine``).

    Returns
    -------
    GainDesign
        For the built-in scenarios (``method = "lmi"``, no ``tau1``) exactly
        ``design_gains(P, A, C)``.

    Raises
    ------
    GainDesignError
        If the design fails (unobservable, infeasible, not certified, solver error).
    ValueError
        On an invalid override (see :func:`design_request`).
    """
    request = design_request(scenario, method=method, tau1=tau1, refine=refine)
    P, A, C = scenario.weights, scenario.plant.A, scenario.plant.C
    tau = request["tau1"]
    base = request["refine_from"] or request["method"]
    if base == "given":
        if scenario.gains.K is None:
            raise ValueError("gains.K: the scenario gives no gain matrices")
        design = gains_from_matrices(scenario.gains.K, P, A, C)
    else:
        design = design_gains(P, A, C, method=base, tau1=tau)
    if request["method"] == "refined":
        design = refine_gains(design, P, A, C, tau1=tau)
    return design
