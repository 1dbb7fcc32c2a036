"""Age-of-information ("freshness-index") distributed observer, aoi paper Section 4.

Mitra, Richards, Bagchi, Sundaram, "Finite-time distributed state estimation over
time-varying graphs: exploiting the age-of-information". The state is estimated in
the coordinates z = T^T x of the Lemma 1 decomposition
(:func:`netsim.models.decomposition.multi_sensor_decomposition`): substate z^(j) has node j
as its source. Agent i keeps an estimate z-hat_i (all substates) and, per substate j,
a freshness index tau_i^(j) in {omega} u N (here: ``OMEGA = -1``).

Update of agent i from step k to k + 1 (N_i[k]: the agents i hears at step k):

* substate j = i (source, eq. 7; tau_i^(i) = 0 always):
  z_i^(i)[k+1] = (A_ii - L_i C_ii) z_i^(i)[k] + sum_{q<i} (A_iq - L_i C_iq) z_i^(q)[k]
                 + L_i y_i[k];
* substate j != i, with M = {l in N_i[k] : tau_l^(j)[k] != omega} (eq. 8):
  - Case 1, tau_i^(j)[k] = omega: if M is non-empty, u = argmin_{l in M} tau_l^(j)[k],
    tau_i^(j)[k+1] = tau_u^(j)[k] + 1 (eq. 9) and
    z_i^(j)[k+1] = A_jj z_u^(j)[k] + sum_{q<j} A_jq z_i^(q)[k] (eq. 10); otherwise
    tau stays omega (eq. 11) and z_i^(j)[k+1] = A_jj z_i^(j)[k] + sum_{q<j} A_jq
    z_i^(q)[k] (eq. 12);
  - Case 2, tau_i^(j)[k] != omega: F = {l in M : tau_l^(j)[k] < tau_i^(j)[k]} (eq. 13);
    if F is non-empty, u = argmin_{l in F} tau_l^(j)[k] and (9), (10); otherwise
    tau_i^(j)[k+1] = tau_i^(j)[k] + 1 (eq. 14) and (12).
  - Ties ("picks any such one arbitrarily"): ``tie_rule`` = ``lowest`` (smallest
    agent number, default), ``highest`` or ``random`` (seeded generator).

Initialisation: tau_j^(j)[0] = 0, tau_i^(j)[0] = omega (i != j); z-hat_i[0] = T^T x0_mean
(the common prior). Every agent's estimate of x is x-hat_i[k] = T z-hat_i[k].

Timing in the event kernel (DESIGN.md: a message sent at step s with delay d is usable
at step s + 1 + d). The paper's step k -> k + 1 update uses the neighbours' step-k
values over the step-k graph G[k], and the source's measurement y_j[k]. Hosted in the
kernel, :meth:`FreshnessObserver.step` at step k computes z-hat_i[k] from z-hat_i[k-1],
from the messages sent at step k - 1 (the payload carries z-hat_l[k-1] and
tau_l[k-1]; a link is up at step k - 1 iff it is in G[k-1], via the kernel's
``availability``) and from the measurement y_i[k-1] stored at the previous step; then
:meth:`outgoing` sends z-hat_i[k] and tau_i[k]. With d = 0 this is exactly the paper's
recursion, step for step: the estimate reported at step k is the paper's x-hat_i[k], a
one-step *predictor* (it uses measurements up to k - 1, so the measurement y_i[k] the
kernel passes at step k is used at step k + 1). At step 0 every agent reports the prior.

Delays (d > 0) are outside the paper. ``delayed="discard"`` (default) ignores a
message that is not from the previous step (the kernel counts it as discarded): it is
as if the link had been down when it was sent, and the paper's analysis applies to
the graph sequence thinned accordingly. ``delayed="age"`` is an extension: a message
sent at s with index tau is treated as a neighbour value at step k - 1 of age
tau + (k - 1 - s), its substate propagated with A_jj and agent i's own lower-substate
estimates over s..k-2 (the form of Lemma 4 with v(t) = i over the delay), so the
freshness comparison and Lemma 4's identity still hold. With d = 0 both modes are
identical.

Baselines of the paper's Section 3 (:class:`NaiveConsensusObserver`): the same
source update (7), but every non-source substate by consensus over N_i[k] u {i},
z_i^(j)[k+1] = A_jj sum_l w_il[k] z_l^(j)[k] + sum_{q<j} A_jq z_i^(q)[k], with
``weights="uniform"`` (w = 1/(|N_i[k]|+1)) or ``weights="tree"`` (all weight on the
parent of i in a spanning tree of G[k] rooted at j; a node outside the tree runs open
loop). For the Section 3 example (scalar, only node 1 measures, deadbeat L_1 = a)
this is eq. (6) with x-hat_1[k] = x[k] for k >= 1.

Gains (:func:`design_source_gains`): for Theorem 1, the eigenvalues of A_jj - L_j C_jj
are placed distinct and real with spectral radius rho_j, rho_1 < ... < rho_N < rho
(``scipy.signal.place_poles`` on the dual pair); for Corollary 1 (``deadbeat``) at zero
by an orthogonal staircase recursion (:func:`deadbeat_gain`), nilpotency verified.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from netsim.estimators.errors import GainDesignError
from netsim.models.decomposition import MultiSensorDecomposition, multi_sensor_decomposition
from numpy.typing import ArrayLike

__all__ = [
    "OMEGA",
    "GainDesignError",
    "deadbeat_gain",
    "rate_gain",
    "nilpotency_index",
    "transient_gain",
    "SourceGains",
    "design_source_gains",
    "default_rates",
    "AoIDesign",
    "AoIMessage",
    "FreshnessObserver",
    "NaiveConsensusObserver",
    "TIE_RULES",
    "CONVERGED_RTOL",
    "converged_tolerance",
]

#: The dummy value omega of a freshness index ("infinite delay": nothing heard yet).
OMEGA = -1
#: Tie rules of the argmin in Cases 1 and 2.
TIE_RULES = ("lowest", "highest", "random")
#: Relative tolerance of the nilpotency check of a deadbeat gain.
NILPOTENCY_RTOL = 1e-8


# -- gain design -------------------------------------------------------------------


def _deadbeat_feedback(F: np.ndarray, G: np.ndarray, tol: float) -> np.ndarray:
    """K (m x n) with F - G K nilpotent, (F, G) controllable (orthogonal staircase).

    In coordinates x = U [x1; x2] with U^T G = [G1; 0] (G1 full row rank r), the
    subsystem x2+ = F22 x2 + F21 x1 is controlled by x1: recursively pick K2 with
    F22 - F21 K2 nilpotent, then choose u so that w1 = x1 + K2 x2 is zero after one
    step. In (w1, x2) the closed loop is [[0, 0], [F21, F22 - F21 K2]]: nilpotent.
    """
    n, m = G.shape
    if n == 0:
        return np.zeros((m, 0))
    U, s, Vt = np.linalg.svd(G, full_matrices=True)
    r = int(np.sum(s > tol))
    if r == 0:
        raise GainDesignError("the pair is not observable (staircase step with no rank)")
    G1_pinv = Vt[:r].T / s[:r]  # (m x r), G1 = diag(s) Vt[:r]
    Ft = U.T @ F @ U
    if r == n:
        Kt = G1_pinv @ Ft
    else:
        F11, F12 = Ft[:r, :r], Ft[:r, r:]
        F21, F22 = Ft[r:, :r], Ft[r:, r:]
        K2 = _deadbeat_feedback(F22, F21, tol)
        Kt = G1_pinv @ np.hstack([F11 + K2 @ F21, F12 + K2 @ F22])
    return Kt @ U.T


def nilpotency_index(M: np.ndarray, rtol: float = NILPOTENCY_RTOL,
                     scale: float | None = None) -> int | None:
    """Smallest p <= n with M^p = 0 numerically, None if there is none.

    M^p counts as zero when ||M^p|| <= rtol ||M^(p-1)|| s, s = max(||M||, ``scale``),
    the scale of the rounding error of the product M^(p-1) M; pass as ``scale`` the
    size of the terms M was computed from (e.g. max(||A||, ||L|| ||C||) for M = A - L C,
    whose exact zeros come out as rounding noise of that size). A test against
    ||M||^p alone would accept a large transient ||M^p|| when ||M|| is large.
    """
    n = M.shape[0]
    if n == 0:
        return 0
    norm = max(float(np.linalg.norm(M, 2)), 0.0 if scale is None else float(scale))
    if norm == 0.0:
        return 1
    P = np.eye(n)
    prev = 1.0
    for p in range(1, n + 1):
        P = P @ M
        cur = float(np.linalg.norm(P, 2))
        if cur <= rtol * prev * norm:
            return p
        prev = cur
    return None


def transient_gain(M: np.ndarray) -> float:
    """max_{0 <= t <= n} ||M^t|| (1 for an empty matrix): how much the closed loop of a
    source can amplify an error (and rounding) before it dies out."""
    n = M.shape[0]
    out, P = 1.0, np.eye(n)
    for _ in range(n):
        P = P @ M
        out = max(out, float(np.linalg.norm(P, 2)))
    return out


def _product_scale(A: np.ndarray, L: np.ndarray, C: np.ndarray) -> float:
    """max(||A||, ||L|| ||C||): the size of the terms of A - L C."""
    if A.size == 0:
        return 0.0
    lc = float(np.linalg.norm(L, 2) * np.linalg.norm(C, 2)) if L.size and C.size else 0.0
    return max(float(np.linalg.norm(A, 2)), lc)


def _pair(A: ArrayLike, C: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    C = np.asarray(C, dtype=float)
    if C.ndim != 2:
        C = C.reshape(-1, n) if n else C.reshape(C.size, 0)
    return A, C


def deadbeat_gain(A: ArrayLike, C: ArrayLike, *, rtol: float = 1e-10) -> np.ndarray:
    """L with A - L C nilpotent (all eigenvalues at 0; Corollary 1).

    ``place_poles`` cannot place a pole with multiplicity above rank(C); this uses the
    dual staircase recursion of :func:`_deadbeat_feedback` (orthogonal transforms and
    a pseudo-inverse of a full-rank block per step), whose nilpotency index is the
    observability index of (A, C). The result is verified numerically.

    Raises
    ------
    GainDesignError
        If (A, C) is not observable or the result is not nilpotent to tolerance.
    """
    A, C = _pair(A, C)
    n = A.shape[0]
    if n == 0:
        return np.zeros((0, C.shape[0]))
    scale = max(float(np.linalg.norm(A, 2)), float(np.linalg.norm(C, 2)) if C.size else 0.0,
                np.finfo(float).tiny)
    K = _deadbeat_feedback(A.T, C.T, rtol * scale)
    L = K.T
    if nilpotency_index(A - L @ C, scale=_product_scale(A, L, C)) is None:
        raise GainDesignError(
            f"deadbeat design is not nilpotent to tolerance: spectral radius of A - L C = "
            f"{max(abs(np.linalg.eigvals(A - L @ C))):.3e}"
        )
    return L


def rate_gain(A: ArrayLike, C: ArrayLike, rho: float,
              poles: Sequence[float] | None = None) -> np.ndarray:
    """L with A - L C having distinct real eigenvalues of spectral radius ``rho``
    (Theorem 1's design), by ``scipy.signal.place_poles`` on (A^T, C^T).

    Default poles: rho * (1 - 0.5 t / n), t = 0..n-1. C is first compressed to its row
    space (place_poles needs an input matrix of full column rank).
    """
    from scipy.signal import place_poles

    A, C = _pair(A, C)
    n = A.shape[0]
    if n == 0:
        return np.zeros((0, C.shape[0]))
    if not rho > 0:
        raise GainDesignError(f"rate design needs rho > 0 (use deadbeat for 0), got {rho}")
    if poles is None:
        poles = [rho * (1.0 - 0.5 * t / n) for t in range(n)]
    wanted = np.asarray(poles, dtype=float)
    if wanted.shape != (n,) or len(set(wanted.tolist())) != n:
        raise GainDesignError(f"need {n} distinct poles, got {wanted.tolist()}")
    u, s, vt = np.linalg.svd(C, full_matrices=False)
    scale = max(float(np.linalg.norm(A, 2)), float(s[0]) if s.size else 0.0)
    r = int(np.sum(s > 1e-10 * scale))
    if r == 0:
        raise GainDesignError("the pair is not observable (C = 0)")
    Cr = s[:r, None] * vt[:r]  # r x n, C = u[:, :r] Cr
    try:
        result = place_poles(A.T, Cr.T, wanted)
    except ValueError as exc:
        raise GainDesignError(f"pole placement failed: {exc}") from None
    Lr = result.gain_matrix.T  # n x r
    L = Lr @ u[:, :r].T
    got = np.sort(np.linalg.eigvals(A - L @ C).real)
    if not np.allclose(got, np.sort(wanted), rtol=1e-6, atol=1e-8 * max(1.0, scale)):
        raise GainDesignError(f"poles placed at {got.tolist()}, wanted {sorted(wanted)}")
    return L


def default_rates(rho: float, dims: Sequence[int]) -> tuple[float, ...]:
    """rho_j for the non-empty substates in order, rho_1 < ... < rho_S < rho:
    rho_j = rho (r + 1) / (S + 1) for the r-th non-empty substate (0 for empty ones)."""
    sources = [j for j, d in enumerate(dims) if d > 0]
    out = [0.0] * len(dims)
    for r, j in enumerate(sources):
        out[j] = rho * (r + 1) / (len(sources) + 1)
    return tuple(out)


@dataclass(frozen=True)
class SourceGains:
    """Output-injection gains L_j of the source nodes (eq. 7).

    Attributes
    ----------
    L : tuple of numpy.ndarray
        L_j (n_j x m_j) for every substate j (empty for n_j = 0).
    method : str
        ``deadbeat``, ``rate`` or ``given``.
    rho : float or None
        Requested convergence rate (``rate``), 0 for deadbeat.
    rhos : tuple of float
        rho_j, the spectral radius of A_jj - L_j C_jj.
    nilpotency : tuple of (int or None)
        Nilpotency index of A_jj - L_j C_jj (None if not nilpotent).
    transients : tuple of float
        max_t ||(A_jj - L_j C_jj)^t|| (:func:`transient_gain`).
    """

    L: tuple[np.ndarray, ...]
    method: str
    rho: float | None
    rhos: tuple[float, ...]
    nilpotency: tuple[int | None, ...]
    transients: tuple[float, ...] = ()

    @property
    def conditioning(self) -> float:
        """max_j max(1, ||L_j||) * transient_j: the factor by which rounding errors of
        the source updates can be amplified (a deadbeat observer's floor is about
        machine epsilon times this, relative to the state)."""
        out = 1.0
        for L, t in zip(self.L, self.transients, strict=False):
            nl = float(np.linalg.norm(L, 2)) if L.size else 0.0
            out = max(out, max(1.0, nl) * t)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "rho": self.rho,
            "rhos": list(self.rhos),
            "nilpotency_index": list(self.nilpotency),
            "L_norms": [float(np.linalg.norm(L, 2)) if L.size else 0.0 for L in self.L],
            "transient_gains": list(self.transients),
            "conditioning": self.conditioning,
        }


def design_source_gains(
    decomposition: MultiSensorDecomposition,
    method: str = "deadbeat",
    *,
    rho: float | None = None,
    rhos: Sequence[float] | None = None,
    poles: Sequence[Sequence[float] | None] | None = None,
    L: Sequence[ArrayLike] | None = None,
) -> SourceGains:
    """Design L_j for every source (Theorem 1: ``rate``; Corollary 1: ``deadbeat``).

    Parameters
    ----------
    decomposition : MultiSensorDecomposition
    method : str
        ``deadbeat`` (eigenvalues of A_jj - L_j C_jj at 0), ``rate`` (distinct real,
        spectral radius rho_j) or ``given`` (``L``).
    rho : float
        ``rate``: the desired convergence rate; rho_j from :func:`default_rates`
        unless ``rhos`` is given (then it must be strictly increasing over the
        non-empty substates and below rho).
    poles : per substate, optional
        ``rate``: explicit poles of substate j (overrides rho_j).
    """
    d = decomposition
    N = d.n_sensors
    Ls: list[np.ndarray] = []
    if method == "given":
        if L is None or len(L) != N:
            raise GainDesignError(f"given gains: need {N} matrices L_j")
        for j in range(N):
            Lj = np.asarray(L[j], dtype=float).reshape(d.dims[j], d.C_bar[j].shape[0])
            Ls.append(Lj)
        rates = tuple(_spectral_radius(d.A_block(j, j) - Ls[j] @ d.C_block(j, j))
                      for j in range(N))
        rho_out = None
    elif method == "deadbeat":
        for j in range(N):
            Ls.append(deadbeat_gain(d.A_block(j, j), d.C_block(j, j)))
        rates = tuple(0.0 for _ in range(N))
        rho_out = 0.0
    elif method == "rate":
        if rho is None or not 0 < rho:
            raise GainDesignError(f"rate design needs rho > 0, got {rho}")
        if rhos is None:
            rhos = default_rates(rho, d.dims)
        rhos = tuple(float(r) for r in rhos)
        active = [rhos[j] for j in d.sources]
        if any(b <= a for a, b in zip(active, active[1:], strict=False)) or (
            active and max(active) >= rho
        ):
            raise GainDesignError(
                f"Theorem 1 needs rho_1 < ... < rho_N < rho over the sources; got "
                f"{active} with rho = {rho}"
            )
        for j in range(N):
            pj = None if poles is None else poles[j]
            if d.dims[j] == 0:
                Ls.append(np.zeros((0, d.C_bar[j].shape[0])))
            else:
                Ls.append(rate_gain(d.A_block(j, j), d.C_block(j, j), rhos[j], pj))
        rates = tuple(_spectral_radius(d.A_block(j, j) - Ls[j] @ d.C_block(j, j))
                      for j in range(N))
        rho_out = float(rho)
    else:
        raise GainDesignError(f"unknown gain method {method!r} (deadbeat, rate, given)")
    closed = [d.A_block(j, j) - Ls[j] @ d.C_block(j, j) for j in range(N)]
    nil = tuple(nilpotency_index(M, scale=_product_scale(d.A_block(j, j), Ls[j],
                                                         d.C_block(j, j)))
                for j, M in enumerate(closed))
    return SourceGains(L=tuple(Ls), method=method, rho=rho_out, rhos=rates, nilpotency=nil,
                       transients=tuple(transient_gain(M) for M in closed))


def _spectral_radius(M: np.ndarray) -> float:
    if M.size == 0:
        return 0.0
    return float(max(abs(np.linalg.eigvals(M))))


# -- shared design -----------------------------------------------------------------


@dataclass(frozen=True)
class AoIDesign:
    """Everything the agents share: the decomposition, the gains and the prior.

    Build with :meth:`from_plant`. Per substate j, ``rows[j]`` is the block row
    [A_j1 ... A_jj] of A-bar, ``lower[j]`` = [A_j1 ... A_j(j-1)], ``source_rows[j]`` =
    [A_j1 - L_j C_j1, ..., A_jj - L_j C_jj] (eq. 7).
    """

    decomposition: MultiSensorDecomposition
    gains: SourceGains
    prior_z: np.ndarray
    lower: tuple[np.ndarray, ...] = field(repr=False)
    diag: tuple[np.ndarray, ...] = field(repr=False)
    source_rows: tuple[np.ndarray, ...] = field(repr=False)

    @classmethod
    def build(cls, decomposition: MultiSensorDecomposition, gains: SourceGains,
              prior_x: ArrayLike | None = None) -> AoIDesign:
        d = decomposition
        n = d.n_states
        prior_x = np.zeros(n) if prior_x is None else np.asarray(prior_x, dtype=float)
        o = d.offsets
        lower, diag, rows = [], [], []
        for j in range(d.n_sensors):
            blk = d.block(j)
            lower.append(d.A_bar[blk, : o[j]].copy())
            diag.append(d.A_bar[blk, blk].copy())
            rows.append(d.A_bar[blk, : o[j + 1]] - gains.L[j] @ d.C_bar[j][:, : o[j + 1]])
        return cls(d, gains, d.to_z(prior_x), tuple(lower), tuple(diag), tuple(rows))

    @classmethod
    def from_plant(cls, A: ArrayLike, C: Sequence[ArrayLike], prior_x: ArrayLike | None = None,
                   *, method: str = "deadbeat", rho: float | None = None,
                   rhos: Sequence[float] | None = None, rtol: float | None = None
                   ) -> AoIDesign:
        """Decompose (A, C) (Lemma 1) and design the source gains."""
        kwargs = {} if rtol is None else {"rtol": rtol}
        d = multi_sensor_decomposition(A, C, **kwargs)
        return cls.build(d, design_source_gains(d, method, rho=rho, rhos=rhos), prior_x)

    @property
    def n_agents(self) -> int:
        return self.decomposition.n_sensors

    @property
    def n_states(self) -> int:
        return self.decomposition.n_states

    def to_dict(self) -> dict[str, Any]:
        return {"decomposition": self.decomposition.to_dict(), "gains": self.gains.to_dict()}


class AoIMessage:
    """Payload of agent l after step k: z-hat_l[k] and tau_l[k] (all substates).

    ``numpy.asarray(message)`` gives the estimate in x coordinates, so a trace
    recorder that stores payloads as float arrays records the transmitted estimate.
    """

    __slots__ = ("z", "freshness", "x")

    def __init__(self, z: np.ndarray, freshness: np.ndarray, x: np.ndarray) -> None:
        self.z = z
        self.freshness = freshness
        self.x = x

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        return self.x if dtype is None else self.x.astype(dtype)

    def __repr__(self) -> str:
        return f"AoIMessage(freshness={self.freshness.tolist()})"


# -- agents --------------------------------------------------------------------------


class _SubstateObserverBase:
    """Shared state, message handling and source update (eq. 7) of agent i."""

    family = "aoi"

    def __init__(self, agent: int, design: AoIDesign, *, delayed: str = "discard",
                 history: int = 64) -> None:
        if delayed not in ("discard", "age"):
            raise ValueError(f"delayed must be 'discard' or 'age', got {delayed!r}")
        self.agent = int(agent)
        self.design = design
        self.delayed = delayed
        d = design.decomposition
        self._N = d.n_sensors
        self._blocks = [d.block(j) for j in range(self._N)]
        self._offsets = d.offsets
        self._T = d.T
        self._z = design.prior_z.copy()
        self._estimate = d.to_x(self._z)
        self._y_prev: np.ndarray | None = None
        self._inbox: dict[int, tuple[int, AoIMessage]] = {}
        self._history: deque[tuple[int, np.ndarray]] = deque(maxlen=max(1, int(history)))
        self.last_step: int | None = None
        #: Effective delay r = k - 1 - s of every neighbour message used at the last step.
        self.last_delays: dict[int, int] = {}
        #: Per substate, whose information the last update used: -1 own (source update
        #: or open loop), else the neighbour adopted (or the tree parent / -2 for a
        #: uniform-weight average in the naive baselines).
        self.adopted_from = np.full(self._N, -1, dtype=np.int64)
        self.discarded = 0

    # -- kernel interface ---------------------------------------------------------
    def message_arrived(self, sender: int, sent_step: int, payload: AoIMessage) -> bool:
        """Store a neighbour's (z-hat, tau); False if it can never be used (stale)."""
        ready = -1 if self.last_step is None else self.last_step  # next update: last + 1
        current = self._inbox.get(sender)
        if current is not None and sent_step <= current[0]:
            self.discarded += 1
            return False
        if self.delayed == "discard" and sent_step != ready:
            self.discarded += 1
            return False
        self._inbox[sender] = (int(sent_step), payload)
        return True

    @property
    def estimate(self) -> np.ndarray:
        """x-hat_i[k] = T z-hat_i[k], shape (n,)."""
        return self._estimate

    @property
    def z(self) -> np.ndarray:
        """z-hat_i[k], shape (n,)."""
        return self._z

    def outgoing(self, step: int) -> AoIMessage:
        """The payload sent after step k: z-hat_i[k], tau_i[k] (all omega for the naive
        baselines, which keep no indices) and x-hat_i[k]."""
        tau = getattr(self, "_tau", None)
        tau = np.full(self._N, OMEGA, dtype=np.int64) if tau is None else tau.copy()
        return AoIMessage(self._z.copy(), tau, self._estimate.copy())

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Report z-hat_i[k] (mapped to x): the prior at k = 0, else the update from
        step k - 1 with the messages sent at k - 1 and y_i[k - 1]."""
        k = int(k)
        if self.last_step is not None and k != self.last_step + 1:
            raise RuntimeError(f"agent {self.agent}: step {k} after step {self.last_step}")
        if self.last_step is None:
            self.last_delays = {}
        else:
            heard = self._heard(k)
            self._update(k, heard)
        self._history.append((k, self._z.copy()))
        self._estimate = self._T @ self._z
        self._y_prev = np.asarray(y, dtype=float).ravel().copy()
        self.last_step = k
        return self._estimate

    # -- helpers ----------------------------------------------------------------------
    def _heard(self, k: int) -> dict[int, tuple[int, AoIMessage]]:
        """Messages usable at step k: sent at k - 1 (``discard``) or any (``age``)."""
        if self.delayed == "discard":
            out = {u: m for u, m in self._inbox.items() if m[0] == k - 1}
            # messages from k - 1 are used once; drop everything older
            self._inbox = dict(out)
            return out
        return {u: m for u, m in self._inbox.items() if m[0] <= k - 1}

    def _source_update(self, j: int, z_old: np.ndarray) -> np.ndarray:
        """Eq. (7) for the agent's own substate j = i."""
        L = self.design.gains.L[j]
        y = self._y_prev
        out = self.design.source_rows[j] @ z_old[: self._offsets[j + 1]]
        if L.size and y is not None and y.size:
            out = out + L @ y
        return out

    def _lower(self, j: int, z: np.ndarray) -> np.ndarray:
        return self.design.lower[j] @ z[: self._offsets[j]]

    def _update(self, k: int, heard: dict[int, tuple[int, AoIMessage]]) -> None:
        raise NotImplementedError


class FreshnessObserver(_SubstateObserverBase):
    """Agent i of the freshness-index observer (aoi paper eqs. 7-14).

    Parameters
    ----------
    agent : int
    design : AoIDesign
    tie_rule : str
        ``lowest`` | ``highest`` | ``random`` (argmin ties, "picks any such one").
    rng : numpy.random.Generator, optional
        For ``tie_rule="random"``.
    delayed : str
        ``discard`` (the paper: only the previous step's messages) or ``age`` (see the
        module doc).

    Attributes
    ----------
    freshness : numpy.ndarray of int, shape (N,)
        tau_i^(j)[k] per substate j, ``OMEGA`` (-1) for omega.
    """

    family = "aoi"

    def __init__(self, agent: int, design: AoIDesign, *, tie_rule: str = "lowest",
                 rng: np.random.Generator | None = None, delayed: str = "discard",
                 history: int = 64) -> None:
        super().__init__(agent, design, delayed=delayed, history=history)
        if tie_rule not in TIE_RULES:
            raise ValueError(f"tie_rule must be one of {TIE_RULES}, got {tie_rule!r}")
        if tie_rule == "random" and rng is None:
            raise ValueError("tie_rule='random' needs rng")
        self.tie_rule = tie_rule
        self._rng = rng
        self._tau = np.full(self._N, OMEGA, dtype=np.int64)
        self._tau[self.agent] = 0

    @property
    def freshness(self) -> np.ndarray:
        return self._tau

    def _pick(self, candidates: list[int], ages: dict[int, int]) -> int:
        best = min(ages[c] for c in candidates)
        tied = sorted(c for c in candidates if ages[c] == best)
        if len(tied) == 1 or self.tie_rule == "lowest":
            return tied[0]
        if self.tie_rule == "highest":
            return tied[-1]
        rng = cast(np.random.Generator, self._rng)  # tie_rule "random" has one
        return tied[int(rng.integers(len(tied)))]

    def _neighbour_value(self, k: int, j: int, sent: int, msg: AoIMessage,
                         z_old: np.ndarray) -> tuple[int, np.ndarray]:
        """(tau, z^(j)) of a neighbour message as a value at step k - 1."""
        tau = int(msg.freshness[j])
        zj = msg.z[self._blocks[j]]
        lag = k - 1 - sent
        if lag == 0 or tau == OMEGA:
            return tau, zj
        # delayed="age": propagate over s..k-2 with A_jj and own lower substates
        # (Lemma 4's form with v(t) = i over the delay); too old for the history: omega
        own = dict(self._history)
        Ajj = self.design.diag[j]
        for t in range(sent, k - 1):
            zt = own.get(t)
            if zt is None:
                return OMEGA, zj
            zj = Ajj @ zj + self._lower(j, zt)
        return tau + lag, zj

    def _update(self, k: int, heard: dict[int, tuple[int, AoIMessage]]) -> None:
        z_old = self._z
        z_new = np.empty_like(z_old)
        tau_old = self._tau
        tau_new = tau_old.copy()
        adopted = np.full(self._N, -1, dtype=np.int64)
        used: dict[int, int] = {}
        for j in range(self._N):
            blk = self._blocks[j]
            if j == self.agent:
                z_new[blk] = self._source_update(j, z_old)
                tau_new[j] = 0
                continue
            values = {u: self._neighbour_value(k, j, s, m, z_old) for u, (s, m) in heard.items()
                      if u != self.agent}
            ages = {u: v[0] for u, v in values.items()}
            M = [u for u, a in ages.items() if a != OMEGA]              # eq. (8)
            if tau_old[j] == OMEGA:                                      # Case 1
                candidates = M
            else:                                                        # Case 2, eq. (13)
                candidates = [u for u in M if ages[u] < tau_old[j]]
            lower = self._lower(j, z_old)
            if candidates:
                u = self._pick(candidates, ages)
                tau_new[j] = ages[u] + 1                                 # eq. (9)
                z_new[blk] = self.design.diag[j] @ values[u][1] + lower  # eq. (10)
                adopted[j] = u
                used[u] = k - 1 - heard[u][0]
            else:
                tau_new[j] = OMEGA if tau_old[j] == OMEGA else tau_old[j] + 1  # (11), (14)
                z_new[blk] = self.design.diag[j] @ z_old[blk] + lower    # eq. (12)
        self._z = z_new
        self._tau = tau_new
        self.adopted_from = adopted
        self.last_delays = used


class NaiveConsensusObserver(_SubstateObserverBase):
    """The naive baselines of the aoi paper's Section 3 (uniform or tree weights).

    Parameters
    ----------
    agent : int
    design : AoIDesign
    weights : str
        ``uniform``: w_il = 1 / (|N_i[k]| + 1) over N_i[k] u {i}; ``tree``: weight 1 on
        ``parent(j, i, k)``, the parent of i in a spanning tree of G[k] rooted at the
        source j (open loop when i has no parent or did not hear it).
    parent : callable(j, i, k) -> int or None
        Needed for ``tree`` (global knowledge of G[k]; see
        :func:`netsim.models.topology.bfs_parents`).
    """

    def __init__(self, agent: int, design: AoIDesign, *, weights: str = "uniform",
                 parent: Callable[[int, int, int], int | None] | None = None) -> None:
        super().__init__(agent, design, delayed="discard")
        if weights not in ("uniform", "tree"):
            raise ValueError(f"weights must be 'uniform' or 'tree', got {weights!r}")
        if weights == "tree" and parent is None:
            raise ValueError("tree weights need parent(j, i, k)")
        self.weights = weights
        self.family = f"naive-{weights}"
        self._parent = parent

    def _update(self, k: int, heard: dict[int, tuple[int, AoIMessage]]) -> None:
        z_old = self._z
        z_new = np.empty_like(z_old)
        adopted = np.full(self._N, -1, dtype=np.int64)
        used: dict[int, int] = {}
        others = sorted(u for u in heard if u != self.agent)
        for j in range(self._N):
            blk = self._blocks[j]
            if j == self.agent:
                z_new[blk] = self._source_update(j, z_old)
                continue
            lower = self._lower(j, z_old)
            if self.weights == "uniform":
                mix = z_old[blk].copy()
                for u in others:
                    mix = mix + heard[u][1].z[blk]
                mix = mix / (len(others) + 1)
                if others:
                    adopted[j] = -2
                    for u in others:
                        used[u] = 0
            else:
                parent = cast("Callable[[int, int, int], int | None]", self._parent)  # tree: given
                p = parent(j, self.agent, k - 1)
                if p is not None and p in heard:
                    mix = heard[p][1].z[blk]
                    adopted[j] = p
                    used[p] = 0
                else:
                    mix = z_old[blk]
            z_new[blk] = self.design.diag[j] @ mix + lower
        self._z = z_new
        self.adopted_from = adopted
        self.last_delays = used


# -- the families this module declares (netsim.estimators.registry) --------------------
#
# ``aoi`` (the freshness-index observer), ``naive-uniform`` and ``naive-tree`` (the
# Section 3 baselines) run on a scenario with a time-varying ``[topology]`` (a static
# graph is the one-graph sequence) and read their settings from ``[options.aoi]``:
# gains = "deadbeat" | "rate", rho (for rate), tie_rule, delayed.

import math  # noqa: E402

from netsim.estimators.registry import (  # noqa: E402  (declared after the classes)
    AgentPlan,
    EstimatorFamily,
    FamilyContext,
    FamilyError,
    ObserverTap,
    register,
)
from netsim.models.seeding import stream  # noqa: E402
from netsim.models.topology import (  # noqa: E402
    ConnectivityReport,
    GraphSequence,
    LinkSchedule,
    as_sequence,
    bfs_parents,
    connectivity_report,
    static_sequence,
)

#: Settings of ``[options.aoi]`` and their defaults.
AOI_OPTIONS: dict[str, Any] = {"gains": "deadbeat", "rho": None, "tie_rule": "lowest",
                               "delayed": "discard"}
#: Relative error (to ||x[k]||) under which an agent counts as exact.
CONVERGED_RTOL = 1e-9
#: Growth over the second half beyond which a run is ``diverging`` (as netsim.runner).
GROWTH_TOLERANCE = 2.0


def aoi_options(scenario: Any) -> dict[str, Any]:
    """The scenario's ``[options.aoi]`` over :data:`AOI_OPTIONS`, checked (FamilyError
    naming the key)."""
    given = dict(scenario.options.get("aoi", {}))
    unknown = sorted(set(given) - set(AOI_OPTIONS))
    if unknown:
        raise FamilyError(f"options.aoi.{unknown[0]}", "unknown key; allowed: "
                          f"{', '.join(sorted(AOI_OPTIONS))}")
    out = {**AOI_OPTIONS, **given}
    if out["gains"] not in ("deadbeat", "rate"):
        raise FamilyError("options.aoi.gains", f"expected deadbeat or rate, got "
                          f"{out['gains']!r}")
    rho = out["rho"]
    if out["gains"] == "rate" and rho is None:
        out["rho"] = rho = 0.5
    if rho is not None and (isinstance(rho, bool) or not isinstance(rho, int | float)
                            or not (rho > 0 and math.isfinite(rho))):
        raise FamilyError("options.aoi.rho", f"must be a number > 0, got {rho!r}")
    if out["tie_rule"] not in TIE_RULES:
        raise FamilyError("options.aoi.tie_rule", f"expected one of {', '.join(TIE_RULES)}, "
                          f"got {out['tie_rule']!r}")
    if out["delayed"] not in ("discard", "age"):
        raise FamilyError("options.aoi.delayed", f"expected discard or age, got "
                          f"{out['delayed']!r}")
    return out


def reads_aoi_options(family: Any) -> bool:
    """Whether an estimator family reads ``[options.aoi]``: the families this module
    declares, which share the analysis ``analytics_key = "aoi"``."""
    return getattr(family, "analytics_key", "") == "aoi"


def aoi_topology(scenario: Any) -> GraphSequence | LinkSchedule:
    """The scenario's time-varying topology, or its static graph as a one-graph sequence."""
    if scenario.topology is not None:
        return scenario.topology
    return static_sequence(scenario.n_agents, scenario.links)


_DESIGNS: dict[int, tuple[Any, AoIDesign]] = {}


def aoi_design(scenario: Any) -> AoIDesign:
    """Lemma 1 decomposition and source gains of the scenario (prior: x0_mean); cached
    for the last few scenarios (the design is deterministic)."""
    cached = _DESIGNS.get(id(scenario))
    if cached is not None and cached[0] is scenario:
        return cached[1]
    options = aoi_options(scenario)
    p = scenario.plant
    design = AoIDesign.from_plant(p.A, p.C, p.x0_mean, method=options["gains"],
                                  rho=options["rho"])
    if len(_DESIGNS) > 8:
        _DESIGNS.clear()
    _DESIGNS[id(scenario)] = (scenario, design)
    return design


def corollary_bound(n_states: int, n_agents: int, T: int | None) -> int | None:
    """Corollary 1's finite-time bound n + 2N(N-1)T (None without a T)."""
    if T is None:
        return None
    return n_states + 2 * n_agents * (n_agents - 1) * T


class _TreeParents:
    """parent(j, i, k): BFS tree of G[k] rooted at j (cached per graph index)."""

    def __init__(self, topology: GraphSequence | LinkSchedule) -> None:
        self.sequence = as_sequence(topology)
        self._cache: dict[tuple[int, int], dict[int, int]] = {}

    def __call__(self, j: int, i: int, k: int) -> int | None:
        idx = self.sequence.index(k)
        key = (idx, j)
        parents = self._cache.get(key)
        if parents is None:
            parents = bfs_parents(self.sequence.n_agents, self.sequence.graphs[idx], j)
            self._cache[key] = parents
        return parents.get(i)


def _aoi_agents(kind: str) -> Callable[[FamilyContext], list[AgentPlan]]:
    def build(context: FamilyContext) -> list[AgentPlan]:
        scenario = context.scenario
        options = aoi_options(scenario)
        design = aoi_design(scenario)
        topology = aoi_topology(scenario)
        links = sorted(topology.links())
        parents = _TreeParents(topology) if kind == "tree" else None
        plans = []
        for i in range(scenario.n_agents):
            if kind == "freshness":
                rng = (stream(context.trial_seed, "aoi", "ties", i)
                       if options["tie_rule"] == "random" else None)
                estimator: Any = FreshnessObserver(i, design, tie_rule=options["tie_rule"],
                                                   rng=rng, delayed=options["delayed"])
            else:
                estimator = NaiveConsensusObserver(i, design, weights=kind, parent=parents)
            plans.append(AgentPlan(estimator, (i,), tuple(r for s, r in links if s == i)))
        return plans

    return build


class FreshnessTap(ObserverTap):
    """Kernel observer of one AoI run: records every agent's freshness indices and
    adoptions after each update, forwards every hook to ``inner`` (a trace recorder)
    and calls its ``on_freshness(agent, k, freshness, adopted_from, substate_dims)``
    when it has that hook (the ``/agent/<i>/freshness`` topic).

    ``collect()`` gives ``freshness`` (K+1, N, N) (tau_i^(j)[k] at [k, i, j], OMEGA for
    omega) and ``adopted`` (K+1, N, N) (-1 own, -2 average).
    """

    def __init__(self, estimators: Sequence[Any], steps: int, dims: Sequence[int],
                 inner: Any = None) -> None:
        super().__init__(inner)
        N = len(estimators)
        self.estimators = list(estimators)
        self.freshness = np.full((steps + 1, N, N), OMEGA, dtype=np.int64)
        self.adopted = np.full((steps + 1, N, N), -1, dtype=np.int64)
        self.dims = list(dims)
        self._on_freshness = getattr(inner, "on_freshness", None)

    def on_update(self, agent, k, estimate, delays):
        est = self.estimators[agent]
        tau = getattr(est, "freshness", None)
        if k < len(self.adopted):
            self.adopted[k, agent] = est.adopted_from
            if tau is not None:
                self.freshness[k, agent] = tau
        super().on_update(agent, k, estimate, delays)
        if self._on_freshness is not None and isinstance(est, FreshnessObserver):
            self._on_freshness(agent, k, np.asarray(tau).copy(),
                               np.asarray(est.adopted_from).copy(), self.dims)

    def collect(self) -> dict[str, np.ndarray]:
        return {"freshness": self.freshness, "adopted": self.adopted}


def _tap(context: FamilyContext, plans: Sequence[AgentPlan], steps: int,
         inner: Any) -> FreshnessTap:
    dims = aoi_design(context.scenario).decomposition.dims
    return FreshnessTap([p.estimator for p in plans], steps, dims, inner)


def _nanmax(a: np.ndarray, axis: Any) -> np.ndarray:
    """nanmax without the all-NaN warning (all-NaN slices give NaN)."""
    filled = np.where(np.isnan(a), -np.inf, a)
    out = np.max(filled, axis=axis)
    return np.where(np.isneginf(out), np.nan, out)


def _growth(errors: np.ndarray) -> float:
    """exp(slope) of log(max_i error) over the second half of the finite part."""
    worst = _nanmax(errors, axis=1)
    finite = np.isfinite(worst)
    if not finite.any():
        return math.nan
    last = int(np.flatnonzero(finite)[-1])
    half = worst[(last + 1) // 2: last + 1]
    if len(half) < 2 or np.any(half <= 0):
        return math.nan
    slope = np.polyfit(np.arange(len(half)), np.log(half), 1)[0]
    return float(np.exp(slope))


def converged_tolerance(scenario: Any) -> float:
    """Relative error under which an agent of ``scenario`` counts as exact.

    :data:`CONVERGED_RTOL`, or the deadbeat design's round-off floor
    ``1e3 eps conditioning`` (:attr:`SourceGains.conditioning`) when that is larger:
    large gains amplify rounding, and a fixed tolerance below the floor would call a
    run unconverged although its error reached the floor.
    """
    floor = 1e3 * float(np.finfo(float).eps) * aoi_design(scenario).gains.conditioning
    return max(CONVERGED_RTOL, floor)


def _converged_at(errors: np.ndarray, states: np.ndarray, diverged: bool,
                  rtol: float = CONVERGED_RTOL) -> int | None:
    if diverged:
        return None
    scale = np.maximum(np.linalg.norm(states, axis=1), np.finfo(float).tiny)
    ok = np.all(errors <= rtol * scale[:, None], axis=1)
    if not ok[-1] or len(ok) < 2:
        return None
    bad = np.flatnonzero(~ok)
    k = 0 if bad.size == 0 else int(bad[-1]) + 1
    return k if k < len(ok) - 1 else None


def _connectivity(scenario: Any) -> tuple[ConnectivityReport, int | None]:
    design = aoi_design(scenario)
    conn = connectivity_report(aoi_topology(scenario), design.decomposition.sources)
    T = conn.joint_T if conn.joint_T is not None else conn.rooted_all_T
    return conn, T


def _merged(counts: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for c in counts:
        for reason, n in c.items():
            out[reason] = out.get(reason, 0) + int(n)
    return dict(sorted(out.items()))


def aoi_report(context: FamilyContext, trials: Sequence[Any]) -> dict[str, Any]:
    """The aoi paper's numbers of one family over its trials (``TrialResult``s).

    ``verdict``: ``diverged at step k``; ``converged at step k`` (noise-free runs only:
    every agent within ``converged_tolerance(scenario) ||x[k]||`` from step k to the
    end, finite-time
    convergence); else from the growth factor g per step of the largest agent error
    over the second half: ``diverging`` (g^half > 2), ``converging`` (g^half < 1/2) or
    ``bounded``. For ``aoi``: the step by which every index was triggered (Lemma 3) and
    the largest index after (N-1)T (Lemma 5's bound 2(N-1)T).
    """
    scenario = context.scenario
    p = scenario.plant
    noise_free = not np.any(p.Q) and not any(np.any(R) for R in p.R)
    steps = len(trials[0].states) - 1
    diverged = [t.diverged_at for t in trials if t.diverged_at is not None]
    errs = np.stack([np.sqrt(t.squared_errors) for t in trials])  # (M, K+1, N)
    states = np.stack([np.linalg.norm(t.states, axis=1) for t in trials])  # (M, K+1)
    worst = _nanmax(errs, axis=(0, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = _nanmax(errs / np.maximum(states, np.finfo(float).tiny)[:, :, None],
                      axis=(0, 2))
    rtol = converged_tolerance(scenario) if noise_free else CONVERGED_RTOL
    conv = [_converged_at(e, t.states, t.diverged_at is not None, rtol) if noise_free
            else None for e, t in zip(errs, trials, strict=True)]
    known = [c for c in conv if c is not None]
    converged_at = max(known) if conv and len(known) == len(conv) else None
    growths = [_growth(e) for e in errs]
    growth = max((g for g in growths if math.isfinite(g)), default=math.nan)
    if diverged:
        verdict = f"diverged at step {min(diverged)}"
    elif converged_at is not None:
        verdict = f"converged at step {converged_at}"
    else:
        half = (steps + 1) - (steps + 1) // 2
        if not math.isfinite(growth):
            verdict = "bounded"
        elif growth ** half > GROWTH_TOLERANCE:
            verdict = "diverging"
        elif growth ** half < 1.0 / GROWTH_TOLERANCE:
            verdict = "converging"
        else:
            verdict = "bounded"
    marks = sorted({0, steps // 10, steps // 4, steps // 2, (3 * steps) // 4, steps})
    out: dict[str, Any] = {
        "verdict": verdict,
        "growth_rate": growth,
        "converged_at": converged_at,
        "diverged_at": min(diverged) if diverged else None,
        "max_error_at": {str(m): float(worst[m]) for m in marks
                         if m < len(worst)},
        "max_relative_error_at": {str(m): float(rel[m]) for m in marks
                                  if m < len(rel)},
        "messages": {"sent": sum(t.messages_sent for t in trials),
                     "delivered": sum(t.messages_delivered for t in trials),
                     "dropped": sum(t.messages_dropped for t in trials),
                     "drop_reasons": _merged(t.drop_reasons for t in trials),
                     "discarded": sum(t.messages_discarded for t in trials)},
    }
    if all("freshness" in t.extras for t in trials) and context.family == "aoi":
        _, T = _connectivity(scenario)
        lemma_start = None if T is None else (scenario.n_agents - 1) * T
        sources = list(aoi_design(scenario).decomposition.sources)
        # indices of the non-empty substates only (an empty substate's index may stay
        # omega: nothing to estimate, and Remark 1 only asks for rooted sources)
        f = np.stack([t.extras["freshness"] for t in trials])[..., sources]
        triggered = np.all(f != OMEGA, axis=(0, 2, 3))
        trig = int(np.argmax(triggered)) if triggered.any() else None
        fresh_max = None
        if lemma_start is not None and lemma_start <= steps:
            fresh_max = int(f[:, lemma_start:].max())
        out["freshness"] = {"all_triggered_by": trig,
                            "max_index_after_trigger_bound": fresh_max}
        out["summary_lines"] = [
            f"aoi freshness: all indices triggered by step {trig}"
            + ("" if fresh_max is None else
               f"; largest index from step {lemma_start} on: {fresh_max}")]
    return out


def aoi_analytics(scenario: Any, gains: Any = None) -> dict[str, Any]:
    """The Lemma 1 design, the graph sequence's connectivity and the paper's bounds
    (Lemma 3, Lemma 5, Corollary 1) for the scenario."""
    design = aoi_design(scenario)
    options = aoi_options(scenario)
    conn, T = _connectivity(scenario)
    N, n = scenario.n_agents, scenario.plant.n_states
    delay_free = scenario.max_delay == 0 and (scenario.link_spec is None)
    dims = design.decomposition.dims
    gains = design.gains
    lines = [
        f"Lemma 1 decomposition: substate dims {list(dims)} (sources "
        f"{list(design.decomposition.sources)}); gains {gains.method}"
        + ("" if gains.rho is None or gains.method == "deadbeat"
           else f", rho = {gains.rho:g}, rho_j = {[round(r, 4) for r in gains.rhos]}"),
        "connectivity: Assumption 1 (jointly strongly connected) "
        + (f"holds with T = {conn.joint_T}" if conn.joint_T is not None
           else "fails for every T")
        + "; Remark 1 (jointly rooted at the sources) "
        + (f"holds with T = {conn.rooted_all_T}" if conn.rooted_all_T is not None
           else "fails"),
    ]
    applies = options["gains"] == "deadbeat" and delay_free
    if T:
        lines.append(
            f"paper's bounds with T = {T}: all indices triggered by (N-1)T = {(N - 1) * T} "
            f"(Lemma 3), indices <= 2(N-1)T = {2 * (N - 1) * T} after that (Lemma 5), "
            f"finite-time convergence by n + 2N(N-1)T = {corollary_bound(n, N, T)} "
            f"(Corollary 1" + (")" if applies
                               else ", not applicable: needs deadbeat gains, no delays)"))
    return {
        "summary_lines": lines,
        "design": design.to_dict(),
        "options": options,
        "connectivity": conn.to_dict(),
        "bounds": {
            "T": T,
            "assumption_1": conn.joint_T is not None,
            "remark_1_rooted_at_sources": conn.rooted_all_T is not None,
            "lemma_3_triggered_by": None if T is None else (N - 1) * T,
            "lemma_5_freshness_max": None if T is None else 2 * (N - 1) * T,
            "corollary_1_finite_time": corollary_bound(n, N, T),
            "applies": options["gains"] == "deadbeat" and delay_free,
        },
    }


_AOI_PAPER = "aoi paper (Mitra et al.), Section 4, eqs. (7)-(14)"
for _name, _kind, _text in (
    ("aoi", "freshness", "age-of-information freshness-index observer (finite time)"),
    ("naive-uniform", "uniform", "naive consensus baseline, uniform weights (Section 3)"),
    ("naive-tree", "tree", "naive consensus baseline, spanning-tree weights (Section 3)"),
):
    register(EstimatorFamily(
        name=_name, build=_aoi_agents(_kind), description=_text, paper=_AOI_PAPER,
        needs_graph_sequence=True, timestamps=True, observer=_tap, report=aoi_report,
        analytics=aoi_analytics, analytics_key="aoi", source="builtin",
    ))
