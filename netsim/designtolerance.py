"""What a gain design tolerates: gains designed for a delay bound, and delay-free designs
under unknown time-varying delays.

Two statements of the consensus papers are about the gain design rather than about the
estimator:

* LCSYS2022 Discussion 5: gains designed (LMI (13)) against
  ``A-hat_tau1 = (I - K D_C-bar)(P kron A^(tau1+1))`` give a stable delayed closed loop
  (10) for every delay bound ``tau <= tau1`` ("from Theorem 1 and (26)"). Its hypothesis
  is only ``rho(A-hat_tau1) < 1``: nothing asks ``rho(A-hat_0) < 1``. :func:`redesign_on`
  computes, for ``tau = 0..tau1``, ``rho(A-hat_tau)`` and the exact spectral radius of
  (10) with homogeneous delays (self-loops undelayed, the papers' setting);
  :func:`search_redesign` is the counted search over scalar instances.
* Delay-tolerant Discussion 5: gains designed by the LMI (16) for the *delay-free*
  ``nN`` matrix ``A-hat`` need no knowledge of the delays ``P-bar[k]`` (anonymous,
  time-varying, Assumption 2): the delayed error (13) stays stable.
  :func:`switching_growth_on` measures the realised growth of the switched product of
  the eq. (11) matrices over a physically realisable delay sequence (every message
  delayed uniformly in ``0..tau``, the freshest arrival used), beside the exact radius
  of the constant worst pattern (every link at ``tau``); :func:`simulate_switching_error`
  is a second implementation (the per-agent recursion of eqs. (6)-(7) with a still
  state); :func:`search_tolerant_design` is the counted search over small vector
  systems whose gains netsim's LMI (:func:`netsim.estimators.gains.design_gains`,
  feasibility at ``alpha = 1``, as (16)) designs.

Both searches return :class:`netsim.claims.search.Found` (counted in instances from a
seed; a deadline can only cut them short).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from netsim.models.augmented import (
    augmented_spectral_radius,
    closed_loop_sequence_growth,
    delay_free_spectral_radius,
    tau_star_report,
)

__all__ = ["RedesignReport", "RedesignInstance", "redesign_on", "search_redesign",
           "homogeneous_link_delays", "realised_delay_patterns", "SwitchingReport",
           "switching_growth_on", "simulate_switching_error", "TolerantDesignInstance",
           "search_tolerant_design", "REDESIGN_FAMILY", "REDESIGN_HARD_FAMILY",
           "TOLERANT_DESIGN_FAMILY", "REDESIGN_TAU1_MAX", "SWITCHING_STEPS",
           "TOLERANT_DESIGN_SHARE"]

#: Largest tau1 drawn by :func:`search_redesign`.
REDESIGN_TAU1_MAX = 6
#: Steps of the realised delay sequence of :func:`switching_growth_on` in the search.
SWITCHING_STEPS = 200
#: Instances of :func:`search_tolerant_design` per requested instance (an LMI each).
TOLERANT_DESIGN_SHARE = 1 / 8

REDESIGN_FAMILY = ("random scalar plants, N 2..4, a ~ U(-2, 2), K_i ~ U(-1, 3), tau1 1..6, "
                   "rho(A-hat_tau1) <= 0.99")
REDESIGN_HARD_FAMILY = ("scalar N = 2, self-loops undelayed, a = +-1 or +-U(1, 2), "
                        "tau1 1..6, rho(A-hat_tau1) <= 0.99")
TOLERANT_DESIGN_FAMILY = ("random systems N 2..4, n 2..3, one output per agent, rho(A) "
                          "in [0.9, 1], LMI (16) gains, realised delays uniform in 0..tau "
                          "(tau 1..6, freshest arrival), 200 steps, and the fixed patterns "
                          "every link at tau, one link at tau")


def homogeneous_link_delays(P: ArrayLike, tau: int) -> np.ndarray:
    """Delay ``tau`` on every link of ``P``, 0 on the self-loops and non-links, shape
    ``(N, N)``."""
    P_arr = np.asarray(P)
    return np.where((P_arr != 0) & ~np.eye(P_arr.shape[0], dtype=bool), int(tau), 0)


# -- LCSYS2022 Discussion 5 -----------------------------------------------------------------


@dataclass(frozen=True)
class RedesignReport:
    """Discussion 5 on one instance: gains designed for ``tau1``, every ``tau <= tau1``.

    Attributes
    ----------
    tau1 : int
        The delay bound the gains were designed for.
    rho_hat : tuple of float
        ``rho((I - K D_C-bar)(P kron A^(tau+1)))`` for ``tau = 0..tau1``.
    exact : tuple of float
        Exact spectral radius of the compensated closed loop (10) with every link
        delayed by ``tau`` (self-loops undelayed), ``tau = 0..tau1``.
    """

    tau1: int
    rho_hat: tuple[float, ...]
    exact: tuple[float, ...]

    @property
    def hypothesis(self) -> bool:
        """Discussion 5's hypothesis: ``rho(A-hat_tau1) < 1``."""
        return self.rho_hat[self.tau1] < 1.0

    @property
    def violations(self) -> tuple[int, ...]:
        """The ``tau <= tau1`` whose exact rho is ``>= 1`` (the claim says none)."""
        return tuple(t for t, r in enumerate(self.exact) if r >= 1.0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"tau1": self.tau1, "rho_hat": list(self.rho_hat), "exact": list(self.exact),
                "hypothesis": self.hypothesis, "violations": list(self.violations)}


def redesign_on(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike], L: Sequence[ArrayLike],
                tau1: int) -> RedesignReport:
    """LCSYS2022 Discussion 5 on one instance.

    Parameters
    ----------
    P : array_like, shape (N, N)
    A : array_like, shape (n, n)
    C : sequence of array_like, ``C[i]`` of shape (m_i, n)
    L : sequence of array_like, ``L[i] = K_i C_i^T`` of shape (n, m_i)
    tau1 : int
        The delay bound the gains were designed for (``>= 0``).

    Returns
    -------
    RedesignReport
    """
    tau1 = int(tau1)
    if tau1 < 0:
        raise ValueError(f"tau1 must be >= 0, got {tau1}")
    rho_hat = tau_star_report(P, A, C, L, tau_max=tau1).values
    exact = tuple(float(augmented_spectral_radius(P, A, C, L, homogeneous_link_delays(P, t),
                                                  t, compensated=True))
                  for t in range(tau1 + 1))
    return RedesignReport(tau1, tuple(float(v) for v in rho_hat), exact)


@functools.lru_cache(maxsize=4096)
def _scalar_report(a: float, P: tuple[tuple[float, ...], ...], g: tuple[float, ...],
                   tau1: int) -> RedesignReport:
    """:func:`redesign_on` for a scalar plant in closed form: ``rho(A-hat_tau) =
    |a|^(tau+1) rho(diag(g) P)``, and the (10) matrix of size ``N (tau+1)`` built
    directly (first block row ``diag(g) diag(P) a`` at lag 0 and ``diag(g) (P -
    diag(P)) a^(tau+1)`` at lag tau, identities below)."""
    Pa = np.array(P, dtype=float)
    G = np.diag(g)
    N = Pa.shape[0]
    base = float(max(abs(np.linalg.eigvals(G @ Pa))))
    rho_hat = tuple(abs(a) ** (t + 1) * base for t in range(tau1 + 1))
    exact = [float(max(abs(np.linalg.eigvals(G @ Pa * a))))]
    own = G @ np.diag(np.diag(Pa)) * a
    for t in range(1, tau1 + 1):
        M = np.zeros((N * (t + 1), N * (t + 1)))
        M[:N, :N] = own
        M[:N, t * N:] = G @ (Pa - np.diag(np.diag(Pa))) * a ** (t + 1)
        M[N:, :-N] = np.eye(N * t)
        exact.append(float(max(abs(np.linalg.eigvals(M)))))
    return RedesignReport(int(tau1), rho_hat, tuple(exact))


@dataclass(frozen=True)
class RedesignInstance:
    """A scalar instance (:class:`netsim.claims.search.ScalarInstance`) with the delay
    bound ``tau1`` its gains are meant to tolerate."""

    inst: Any
    tau1: int

    def report(self) -> RedesignReport:
        """:func:`redesign_on` on the instance (closed forms for the scalar plant, equal
        to :func:`redesign_on` up to round-off; tests/test_unchecked_claims.py)."""
        g = tuple(1.0 - k * c * c for k, c in zip(self.inst.k, self.inst.c, strict=True))
        return _scalar_report(float(self.inst.a), tuple(map(tuple, self.inst.P)), g,
                              int(self.tau1))

    def hypotheses(self) -> str | None:
        """None if Discussion 5's hypotheses hold (Lemma 1: row-stochastic irreducible
        self-looped ``P``, observable ``(P kron A, D_C)``; ``rho(A-hat_tau1) <= 1 -
        MARGIN``), else the first that fails. ``rho(A-hat_0) < 1`` is *not* among them."""
        return _redesign_hypotheses(self)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {**self.inst.to_dict(), "tau1": self.tau1}


@functools.lru_cache(maxsize=4096)
def _redesign_hypotheses(x: RedesignInstance) -> str | None:
    from netsim.claims.search import MARGIN

    if not x.report().rho_hat[x.tau1] <= 1.0 - MARGIN:  # the cheap one first
        return "rho(A-hat_tau1) > 1 - MARGIN"
    why = x.inst.hypotheses()
    return None if why is None or why == "rho(A-hat) >= 1" else why


def _redesign_judge(x: RedesignInstance) -> dict[str, Any] | None:
    """The smallest ``tau <= tau1`` with exact rho ``>= 1 + MARGIN``, or None (``violated``:
    ``delay-free`` for ``tau = 0``, the delay-free estimator itself unstable; else
    ``delayed, rho(A-hat) < 1`` when the delay-free design is stable too (also a
    counterexample to Theorem 1), ``delayed`` when it is not)."""
    from netsim.claims.search import MARGIN

    if x.hypotheses() is not None:
        return None
    rep = x.report()
    for t, r in enumerate(rep.exact):
        if r >= 1.0 + MARGIN:
            return {"tau1": x.tau1, "tau": t, "exact_rho": r, "rho_hat_tau": rep.rho_hat[t],
                    "rho_hat_tau1": rep.rho_hat[x.tau1],
                    "rho_delay_free": rep.rho_hat[0],
                    "violated": ["delay-free" if t == 0 else
                                 "delayed" if rep.rho_hat[0] >= 1.0 else
                                 "delayed, rho(A-hat) < 1"]}
    return None


def _redesign_draw(make: Callable[[np.random.Generator], Any]
                   ) -> Callable[[np.random.Generator], RedesignInstance | None]:
    def draw(rng: np.random.Generator) -> RedesignInstance | None:
        x = RedesignInstance(make(rng), int(rng.integers(1, REDESIGN_TAU1_MAX + 1)))
        return x if x.hypotheses() is None else None
    return draw


def _redesign_simpler(x: RedesignInstance) -> list[RedesignInstance]:
    from netsim.claims.search import _simpler

    out = [RedesignInstance(x.inst, t) for t in range(1, x.tau1)]
    return out + [RedesignInstance(c, x.tau1) for c in _simpler(x.inst)]


def search_redesign(seed: Any = 0, instances: int = 400, deadline: float = math.inf) -> Any:
    """Counted search for a counterexample to LCSYS2022 Discussion 5.

    ``instances`` random scalar instances and ``instances // 2`` of the hard family
    (:func:`netsim.claims.search._random_instance`, ``_hard_instance``, gains
    ``K_i ~ U(-1, 3)``), each with ``tau1`` drawn in ``1..6``, counted when Discussion 5's
    hypotheses hold (:meth:`RedesignInstance.hypotheses`); a counterexample is a
    ``tau <= tau1`` whose exact rho of (10) is ``>= 1 + MARGIN``; the first is shrunk,
    keeping its kind of violation (``violated``: delay-free, delayed with rho(A-hat) < 1,
    delayed with rho(A-hat) >= 1).

    Returns
    -------
    netsim.claims.search.Found
    """
    from netsim.claims.search import Phase, _hard_instance, _random_instance, counted_search

    phases = [
        Phase(REDESIGN_FAMILY, int(instances),
              _redesign_draw(lambda r: _random_instance(r, k_range=(-1.0, 3.0)))),
        Phase(REDESIGN_HARD_FAMILY, max(1, int(instances) // 2),
              _redesign_draw(lambda r: _hard_instance(r, k_range=(-1.0, 3.0)))),
    ]
    found = counted_search("L-discussion5", phases, _redesign_judge, _redesign_simpler,
                           seed=seed, deadline=deadline)
    first = found.first
    if first is not None and found.details is not None \
            and found.details["violated"] != first["violated"]:
        # shrinking changed the kind of violation (e.g. rounding pushed rho(A-hat) over
        # 1): shrink the first hit again, keeping its kind
        from netsim.claims.search import ScalarInstance, shrink

        kind = first["violated"]

        def same_kind(x: RedesignInstance) -> dict[str, Any] | None:
            d = _redesign_judge(x)
            return d if d is not None and d["violated"] == kind else None

        start = RedesignInstance(ScalarInstance(
            float(first["a"]), tuple(tuple(float(v) for v in r) for r in first["P"]),
            tuple(float(v) for v in first["c"]), tuple(float(v) for v in first["k"])),
            int(first["tau1"]))
        small = shrink(start, same_kind, _redesign_simpler)
        found.instance, found.details = small, _redesign_judge(small)
    return found


# -- delay-tolerant Discussion 5 --------------------------------------------------------------


def realised_delay_patterns(P: ArrayLike, tau: int, steps: int,
                            rng: np.random.Generator) -> list[np.ndarray]:
    """Effective delays of a physical time-varying channel, steps ``1..steps``.

    Every message on every link (self-loops excluded) sent at step ``s`` is delayed
    ``d ~ U{0..tau}`` (usable at ``s + 1 + d``); at step ``k`` agent ``i`` uses the
    freshest message from ``j`` that has arrived, whose effective delay is
    ``r_ij[k] = k - 1 - s``; before the first arrival ``r = tau`` (the oldest slot).
    Returns ``steps`` arrays of shape ``(N, N)`` (0 on self-loops and non-links).
    """
    P_arr = np.asarray(P)
    N, tau = P_arr.shape[0], int(tau)
    links = np.argwhere((P_arr != 0) & ~np.eye(N, dtype=bool))
    arrive = {}
    for i, j in links:
        # sent at s = 0..steps-1, usable from s + 1 + d
        arrive[(int(i), int(j))] = np.arange(steps) + 1 + rng.integers(0, tau + 1, steps)
    freshest = {key: -1 for key in arrive}
    out = []
    for k in range(1, steps + 1):
        pat = np.zeros((N, N), dtype=int)
        for key, times in arrive.items():
            # messages sent at s <= k - 1 that arrived by k; the freshest one
            s_max = freshest[key]
            for s in range(max(s_max + 1, k - 1 - tau), k):
                if times[s] <= k:
                    s_max = s
            freshest[key] = s_max
            pat[key] = tau if s_max < 0 else min(tau, k - 1 - s_max)
        out.append(pat)
    return out


@dataclass(frozen=True)
class SwitchingReport:
    """The delayed error (13) under a delay sequence, for one instance.

    Attributes
    ----------
    tau : int
    rho_hat : float
        ``rho(A-hat)`` of the delay-free design.
    growth : float
        Realised per-step growth of the switched product of the eq. (11) matrices
        (:func:`netsim.models.augmented.closed_loop_sequence_growth`, exponentiated).
    homogeneous_exact : float
        Exact spectral radius of the eq. (11) matrix with every link at ``tau``.
    single_link_exact : float
        The largest exact spectral radius over the fixed patterns with one link at
        ``tau`` and the others at 0 (0: not computed).
    """

    tau: int
    rho_hat: float
    growth: float
    homogeneous_exact: float
    single_link_exact: float = 0.0

    @property
    def worst(self) -> float:
        """The largest of the three."""
        return max(self.growth, self.homogeneous_exact, self.single_link_exact)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"tau": self.tau, "rho_hat": self.rho_hat, "growth": self.growth,
                "homogeneous_exact": self.homogeneous_exact,
                "single_link_exact": self.single_link_exact}


def switching_growth_on(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike],
                        L: Sequence[ArrayLike], tau: int,
                        patterns: Sequence[ArrayLike], *,
                        full_max: int | None = None,
                        single_links: bool = False) -> SwitchingReport:
    """Delay-tolerant Discussion 5 on one instance and one delay sequence.

    Parameters
    ----------
    P, A, C, L
        As in :func:`redesign_on` (``L`` the delay-free design).
    tau : int
        The delay bound (``patterns`` have entries in ``0..tau``).
    patterns : sequence of array_like of int, shape (N, N)
        Effective delays per step (e.g. :func:`realised_delay_patterns`).
    full_max : int, optional
        Passed to :func:`netsim.models.augmented.closed_loop_sequence_growth` (0: track
        a random block of vectors instead of the whole product, for large ``N n tau``).
    single_links : bool
        Also the exact rho of every fixed pattern with one link at ``tau`` and the others
        at 0 (the heterogeneous patterns that break the papers' bounds in the scalar
        examples); 0 when not computed.

    Returns
    -------
    SwitchingReport
    """
    kw = {} if full_max is None else {"full_max": int(full_max)}
    growth = math.exp(closed_loop_sequence_growth(P, A, C, L, patterns, int(tau),
                                                  compensated=False, **kw))
    hom = float(augmented_spectral_radius(P, A, C, L, homogeneous_link_delays(P, tau),
                                          int(tau), compensated=False))
    single = 0.0
    if single_links:
        P_arr = np.asarray(P)
        for i, j in np.argwhere((P_arr != 0) & ~np.eye(P_arr.shape[0], dtype=bool)):
            d = np.zeros(P_arr.shape, dtype=int)
            d[i, j] = int(tau)
            single = max(single, float(augmented_spectral_radius(
                P, A, C, L, d, int(tau), compensated=False)))
    return SwitchingReport(int(tau), float(delay_free_spectral_radius(P, A, C, L)),
                           growth, hom, single)


def simulate_switching_error(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike],
                             L: Sequence[ArrayLike], patterns: Sequence[ArrayLike],
                             seed: int = 0) -> float:
    """Per-step growth of the noise-free error of the uncompensated estimator (delay-
    tolerant eqs. (6)-(7)) with a still state, simulated agent by agent.

    A second implementation (not :mod:`netsim.models.augmented`):
    ``e_i[k] = (I - L_i C_i)(p_ii A e_i[k-1] + sum_j p_ij A e_j[k-1-r_ij[k]])``, from a
    random start, renormalised every step; the geometric mean of the growth of the
    history's norm over the second half of the steps.
    """
    P_arr = np.asarray(P, dtype=float)
    A_arr = np.atleast_2d(np.asarray(A, dtype=float))
    N, n = P_arr.shape[0], A_arr.shape[0]
    G = [np.eye(n) - np.atleast_2d(np.asarray(L[i], float)).reshape(n, -1)
         @ np.atleast_2d(np.asarray(C[i], float)).reshape(-1, n) for i in range(N)]
    pats = [np.asarray(p, dtype=int) for p in patterns]
    depth = max(int(p.max()) for p in pats) + 1
    hist = np.random.default_rng(seed).standard_normal((depth, N, n))  # hist[r] = e[k-1-r]
    logs = []
    for pat in pats:
        new = np.empty((N, n))
        for i in range(N):
            acc = P_arr[i, i] * (A_arr @ hist[0, i])
            for j in np.flatnonzero(P_arr[i]):
                if j != i:
                    acc = acc + P_arr[i, j] * (A_arr @ hist[pat[i, j], j])
            new[i] = G[i] @ acc
        hist = np.concatenate([new[None], hist[:-1]])
        norm = float(np.linalg.norm(hist))
        if norm == 0.0:
            return 0.0
        logs.append(math.log(norm))
        hist /= norm
    return float(math.exp(np.mean(logs[len(logs) // 2:])))


@dataclass(frozen=True)
class TolerantDesignInstance:
    """A small vector system with the delay-free LMI (16) design, a delay bound and the
    seed of its realised delay sequence."""

    P: tuple[tuple[float, ...], ...]
    A: tuple[tuple[float, ...], ...]
    C: tuple[tuple[float, ...], ...]
    L: tuple[tuple[float, ...], ...]
    tau: int
    delay_seed: int

    def matrices(self) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """``(P, A, C, L)`` (one output per agent: ``C[i]`` 1 x n, ``L[i]`` n x 1)."""
        return (np.array(self.P), np.array(self.A), [np.array([c]) for c in self.C],
                [np.array(v)[:, None] for v in self.L])

    def patterns(self) -> list[np.ndarray]:
        """The realised delay sequence (:func:`realised_delay_patterns`)."""
        return realised_delay_patterns(np.array(self.P), self.tau, SWITCHING_STEPS,
                                       np.random.default_rng(self.delay_seed))

    def report(self) -> SwitchingReport:
        """:func:`switching_growth_on` on the instance (single-link patterns included)."""
        P, A, C, L = self.matrices()
        return switching_growth_on(P, A, C, L, self.tau, self.patterns(), single_links=True)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"P": [list(r) for r in self.P], "A": [list(r) for r in self.A],
                "C": [list(r) for r in self.C], "L": [list(r) for r in self.L],
                "tau": self.tau, "delay_seed": self.delay_seed}


def _tolerant_design_draw(rng: np.random.Generator) -> TolerantDesignInstance | None:
    """A random system whose LMI (16) at alpha = 1 is feasible (else None, not counted)."""
    from netsim.estimators.errors import GainDesignError
    from netsim.estimators.gains import design_gains

    N, n = int(rng.integers(2, 5)), int(rng.integers(2, 4))
    adj = np.eye(N, dtype=bool)
    for i in range(N):
        adj[(i + 1) % N, i] = True  # a directed cycle: strongly connected
    adj |= rng.random((N, N)) < 0.3
    W = np.where(adj, rng.random((N, N)) + 0.05, 0.0)
    P = np.round(W / W.sum(axis=1, keepdims=True), 12)
    P[np.diag_indices(N)] += 1.0 - P.sum(axis=1)
    A = rng.standard_normal((n, n))
    A *= float(rng.uniform(0.9, 1.0)) / max(abs(np.linalg.eigvals(A)))
    C = rng.standard_normal((N, n))
    try:
        design = design_gains(P, A, [c[None, :] for c in C], method="lmi", bisect=False)
    except (GainDesignError, ValueError):
        return None
    if not design.rho < 1.0:
        return None
    L = tuple(tuple(float(v) for v in np.asarray(Li).ravel()) for Li in design.L)
    return TolerantDesignInstance(tuple(map(tuple, P.tolist())), tuple(map(tuple, A.tolist())),
                                  tuple(map(tuple, C.tolist())), L,
                                  int(rng.integers(1, 7)), int(rng.integers(0, 2 ** 31)))


def _tolerant_design_judge(x: TolerantDesignInstance) -> dict[str, Any] | None:
    """A realised growth, or the exact rho of every link at tau or of one link at tau,
    ``>= 1 + MARGIN``, else None."""
    from netsim.claims.search import MARGIN

    rep = x.report()
    return rep.to_dict() if rep.worst >= 1.0 + MARGIN else None


def search_tolerant_design(seed: Any = 0, instances: int = 400,
                           deadline: float = math.inf) -> Any:
    """Counted search for a counterexample to delay-tolerant Discussion 5.

    ``max(1, instances * TOLERANT_DESIGN_SHARE)`` random systems (each an LMI solve):
    :data:`TOLERANT_DESIGN_FAMILY`; a counterexample is a realised growth of the switched
    eq. (11) product, or an exact rho with every link at tau or with one link at tau and
    the others at 0, ``>= 1 + MARGIN``.

    Returns
    -------
    netsim.claims.search.Found
    """
    from netsim.claims.search import random_search

    return random_search("T-discussion5", _tolerant_design_draw, _tolerant_design_judge,
                         None, seed=seed,
                         instances=max(1, int(instances * TOLERANT_DESIGN_SHARE)),
                         family=TOLERANT_DESIGN_FAMILY, deadline=deadline)
