"""Counterexample searches for the claims stated over a class of systems.

Each search draws a counted number of seeded random instances that satisfy a claim's
hypotheses (draws outside them are not counted), for the scalar stability claims also a
family known to be hard (N = 2, self-loops undelayed, a = +-1) and an optimiser over the
hypothesis set; it judges them by the exact analytics (spectral radii of the augmented
closed loops, the exact second-moment radius of the dkfe error chain, the noise-free aoi
run, which is exact), shrinks the first hit with :func:`netsim.claims.search.shrink` and
the checks verify it by simulation (:func:`verify_counterexample`). The engine is
:func:`netsim.claims.search.counted_search`; :data:`SEARCHES`
names the search of each claim, and :func:`run_search` runs one by name (a top-level
function, so that ``netsim claims`` can run the searches in worker processes).

Searches (claim: hypotheses drawn; counterexample):

- ``L-theorem1``: :func:`netsim.claims.search.search_theorem1`.
- ``L-eq26-bound``: Theorem 1's hypotheses, ``1 <= tau <= tau*``, homogeneous or
  heterogeneous fixed delays (one link at tau); exact compensated rho above the eq. (26)
  value rho((I-KD_C)(P kron A^(tau+1)))^(1/(tau+1)).
- ``T-lemma5-bound``: Lemma 1 and rho(A-hat) < 1, fixed delays ``1 <= tau <= 6`` (a
  special case of the arbitrary delays of Assumption 2); exact rho of the eq. (11)
  matrix above rho(A-hat)^(1/(tau+1)).
- ``T-theorem1``: the same hypotheses with a stable or marginal plant (``|a| <= 1``,
  half of the draws ``a = +-1``, gains ``k_i ~ U(-2, 4)``,
  so the state stays bounded and any divergence is the error dynamics') and
  ``rho(A-hat) <= 1 - MARGIN``; exact rho of the eq. (11) matrix ``>= 1 + MARGIN``.
- ``A-corollary1``: random jointly observable systems on random jointly strongly
  connected graph sequences (``netsim.aoi.random_aoi_scenario``), deadbeat gains, no
  noise; the run does not reach zero error by n + 2N(N-1)T, or an index is not
  triggered by (N-1)T (Lemma 3), or exceeds 2(N-1)T after it (Lemma 5).
- ``D-cond75``: random plants with one sink (condition (58) holds), random selection
  probabilities, delays d = 0, 1, 2; (75) feasible (cvxpy) while the exact
  second-moment radius is >= 1 (Theorem 2), or (76) or (74) holds while (75) does not
  (the paper's "less conservative").
"""

from __future__ import annotations

import functools
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from netsim.claims.search import (
    DEFAULT_INSTANCES,
    HARD_FAMILY,
    MARGIN,
    OPTIMISER_FAMILY,
    RANDOM_FAMILY,
    Attack,
    Found,
    Phase,
    ScalarInstance,
    _hard_instance,
    _random_instance,
    _simpler,
    counted_search,
    decode_scalar,
    encode_scalar,
    random_search,
    search_theorem1,
)
from netsim.models.augmented import (
    augmented_spectral_radius,
    delay_bound_lcsys,
    delay_bound_tolerant,
)

__all__ = ["DelayedInstance", "AoiInstance", "DkfeInstance", "aoi_numbers", "dkfe_numbers",
           "SEARCHES", "run_search", "bench_report", "fusion_report", "BENCH_TRIALS",
           "simulate_error_growth",
           "search_eq26", "search_lemma5", "search_tolerant_theorem1", "search_aoi",
           "search_dkfe", "delayed_scenario_toml", "write_delayed_scenario", "confirm_run",
           "verify_counterexample", "BOUND_SLACK", "T1_RANDOM_FAMILY", "T1_HARD_FAMILY",
           "AOI_FAMILY", "DKFE_FAMILY", "SLOW_SEARCH_SHARE"]

#: An exact rho counts as above a bound only if it exceeds it by at least this much
#: (so that a simulation shows the difference plainly).
BOUND_SLACK = 0.01
#: Largest tau drawn by the bound searches.
SEARCH_TAU = 6


@dataclass(frozen=True)
class DelayedInstance:
    """A :class:`~netsim.claims.search.ScalarInstance` with fixed link delays.

    Attributes
    ----------
    inst : ScalarInstance
    delays : tuple of tuple of int
        ``delays[i][j]``: the delay of link ``j -> i`` (0 on self-loops and non-links).
    """

    inst: ScalarInstance
    delays: tuple[tuple[int, ...], ...]

    @property
    def tau(self) -> int:
        """The largest delay."""
        return int(max(max(r) for r in self.delays))

    @property
    def homogeneous(self) -> bool:
        """Every link has the same delay."""
        P = np.array(self.inst.P)
        d = np.array(self.delays)
        off = (P != 0) & ~np.eye(len(P), dtype=bool)
        return bool(off.any() and np.all(d[off] == d[off].max()))

    def matrices(
        self,
    ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray], np.ndarray]:
        """``(P, A, C, L, delays)``."""
        return (*self.inst.matrices(), np.array(self.delays))

    def exact(self, compensated: bool) -> float:
        """Exact spectral radius of the augmented closed loop (eq. 9 or eq. 11)."""
        return float(augmented_spectral_radius(*self.matrices(), self.tau,
                                               compensated=compensated))

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {**self.inst.to_dict(), "delays": [list(r) for r in self.delays],
                "tau": self.tau, "homogeneous": self.homogeneous}


def _clean(inst: ScalarInstance, delays: np.ndarray) -> DelayedInstance:
    P = np.array(inst.P)
    d = np.where((P != 0) & ~np.eye(len(P), dtype=bool), delays, 0).astype(int)
    return DelayedInstance(inst, tuple(map(tuple, d.tolist())))


def _draw_delays(rng: np.random.Generator, inst: ScalarInstance, tau: int) -> DelayedInstance:
    """Homogeneous tau (probability 1/2) or uniform 0..tau per link, the link with the
    largest draw set to tau (the bound is attained)."""
    P = np.array(inst.P)
    off = (P != 0) & ~np.eye(len(P), dtype=bool)
    if rng.random() < 0.5:
        return _clean(inst, np.where(off, tau, 0))
    d = np.where(off, rng.integers(0, tau + 1, P.shape), 0)
    idx = np.flatnonzero(off)
    d.flat[idx[int(np.argmax(d.flat[idx]))]] = tau
    return _clean(inst, d)


def _simpler_delayed(x: DelayedInstance) -> list[DelayedInstance]:
    d = np.array(x.delays)
    out = [_clean(c, d) for c in _simpler(x.inst)]
    out = [c for c in out if c.tau >= 1]
    if x.tau > 1:
        out.insert(0, _clean(x.inst, np.minimum(d, x.tau - 1)))
    for i, j in zip(*np.nonzero(d), strict=True):
        e = d.copy()
        e[i, j] = 0
        if e.max() >= 1:
            out.append(_clean(x.inst, e))
    return out


# -- LCSYS2022 eq. (26) ---------------------------------------------------------------


def _with_delays(inst: ScalarInstance, rng: np.random.Generator, up_to_tau_star: bool
                 ) -> DelayedInstance | None:
    """``inst`` with delays drawn by :func:`_draw_delays` at a bound tau in
    ``1..SEARCH_TAU`` (and ``<= tau*`` when ``up_to_tau_star``); None if the instance
    breaks the hypotheses (Lemma 1, rho(A-hat) < 1; ``tau* >= 1``)."""
    if inst.hypotheses() is not None:
        return None
    top = SEARCH_TAU
    if up_to_tau_star:
        star = inst.tau_star()
        if star is None or star < 1:
            return None
        top = min(star, SEARCH_TAU)
    return _draw_delays(rng, inst, int(rng.integers(1, top + 1)))


def _eq26_draw(rng: np.random.Generator) -> DelayedInstance | None:
    return _with_delays(_random_instance(rng), rng, True)


def _eq26_hard_draw(rng: np.random.Generator) -> DelayedInstance | None:
    return _with_delays(_hard_instance(rng), rng, True)


def _bound_margin(x: DelayedInstance, compensated: bool
                  ) -> tuple[float, dict[str, Any] | None]:
    """Exact rho minus the claimed bound minus BOUND_SLACK (``-inf`` outside the
    hypotheses), and the judge's numbers: LCSYS2022 eq. (26) (``compensated``, tau <=
    tau*) or the delay-tolerant Lemma 5 bound rho(A-hat)^(1/(tau+1))."""
    if x.tau < 1 or x.inst.hypotheses() is not None:
        return -math.inf, None
    numbers: dict[str, Any] = {"tau": x.tau}
    if compensated:
        star = x.inst.tau_star()
        if star is None or x.tau > star:
            return -math.inf, None
        numbers["tau_star"] = star
        bound = float(delay_bound_lcsys(*x.inst.matrices(), x.tau))
    else:
        bound = float(delay_bound_tolerant(*x.inst.matrices(), x.tau))
    exact = x.exact(compensated)
    return exact - (bound + BOUND_SLACK), {
        **numbers, "homogeneous": x.homogeneous, "exact_rho": exact, "bound": bound,
        "rho_delay_free": x.inst.rho_delay_free()}


def _eq26_judge(x: DelayedInstance) -> dict[str, Any] | None:
    margin, numbers = _bound_margin(x, True)
    return numbers if margin >= 0 else None


def _delayed_attack(family: str, starts: int, evaluations: int,
                    start: Callable[[np.random.Generator], DelayedInstance | None],
                    score: Callable[[DelayedInstance], float]) -> Attack:
    """An :class:`Attack` on the scalar parameters of a delayed instance (delays fixed)."""
    def decode(t: DelayedInstance, v: np.ndarray) -> DelayedInstance | None:
        inst = decode_scalar(t.inst, v)
        return None if inst is None else DelayedInstance(inst, t.delays)
    return Attack(family, starts, evaluations, start, lambda x: encode_scalar(x.inst),
                  decode, score)


def _scalar_search(claim: str, seed: Any, instances: int, deadline: float,
                   draw: Callable[[np.random.Generator], DelayedInstance | None],
                   hard: Callable[[np.random.Generator], DelayedInstance | None],
                   judge: Callable[[DelayedInstance], dict[str, Any] | None],
                   score: Callable[[DelayedInstance], float],
                   families: tuple[str, str] = (RANDOM_FAMILY, HARD_FAMILY)) -> Found:
    """The counted search of a scalar delayed claim: ``instances`` random draws,
    ``instances // 2`` of the hard family, then the optimiser (4 starts from the hard
    family, ``instances // 8`` evaluations each) maximising ``score``; hits shrunk."""
    phases = [Phase(families[0], instances, draw),
              Phase(families[1], max(1, instances // 2), hard)]
    attack = _delayed_attack(OPTIMISER_FAMILY, 4, max(1, instances // 8), hard, score)
    return counted_search(claim, phases, judge, _simpler_delayed, seed=seed, attack=attack,
                          deadline=deadline)


def search_eq26(seed: Any = 0, instances: int = DEFAULT_INSTANCES,
                deadline: float = math.inf) -> Found:
    """Search LCSYS2022 eq. (26) / Lemma 5 (compensated loop) for an exact rho above it."""
    return _scalar_search("L-eq26-bound", seed, instances, deadline, _eq26_draw,
                          _eq26_hard_draw, _eq26_judge, lambda x: _bound_margin(x, True)[0])


# -- delay-tolerant Lemma 5 and Theorem 1 ---------------------------------------------


def _tolerant_draw(rng: np.random.Generator, a_max: float = 2.0, **kw: Any
                   ) -> DelayedInstance | None:
    return _with_delays(_random_instance(rng, a_max=a_max, **kw), rng, False)


def _tolerant_hard_draw(rng: np.random.Generator, a_max: float = 2.0, **kw: Any
                        ) -> DelayedInstance | None:
    return _with_delays(_hard_instance(rng, a_max=a_max, **kw), rng, False)


def _lemma5_judge(x: DelayedInstance) -> dict[str, Any] | None:
    margin, numbers = _bound_margin(x, False)
    return numbers if margin >= 0 else None


def search_lemma5(seed: Any = 0, instances: int = DEFAULT_INSTANCES,
                  deadline: float = math.inf) -> Found:
    """Search the delay-tolerant Lemma 5 bound rho(A-hat)^(1/(tau+1)) (eq. 11 matrix)."""
    return _scalar_search("T-lemma5-bound", seed, instances, deadline, _tolerant_draw,
                          _tolerant_hard_draw, _lemma5_judge,
                          lambda x: _bound_margin(x, False)[0])


def _t1_draw(rng: np.random.Generator) -> DelayedInstance | None:
    # |a| <= 1 (half of the draws marginal, a = +-1); gains k_i in (-2, 4): the
    # hypotheses ask only rho(A-hat) < 1
    return _tolerant_draw(rng, a_max=1.0, k_range=(-2.0, 4.0), a_edge=0.5)


def _t1_margin(x: DelayedInstance) -> tuple[float, dict[str, Any] | None]:
    """Exact eq. (11) rho minus (1 + MARGIN) (``-inf`` outside the hypotheses: |a| <= 1,
    rho(A-hat) <= 1 - MARGIN), and the judge's numbers."""
    if x.tau < 1 or abs(x.inst.a) > 1 or x.inst.hypotheses() is not None:
        return -math.inf, None
    if not x.inst.rho_delay_free() <= 1.0 - MARGIN:
        return -math.inf, None  # rho(A-hat) not clearly below 1
    exact = x.exact(False)
    return exact - (1.0 + MARGIN), {"tau": x.tau, "homogeneous": x.homogeneous,
                                    "exact_rho": exact,
                                    "rho_delay_free": x.inst.rho_delay_free()}


def _t1_judge(x: DelayedInstance) -> dict[str, Any] | None:
    margin, numbers = _t1_margin(x)
    return numbers if margin >= 0 else None


def _t1_hard_draw(rng: np.random.Generator) -> DelayedInstance | None:
    return _tolerant_hard_draw(rng, a_max=1.0, k_range=(-2.0, 4.0))


#: The families of the delay-tolerant Theorem 1 search, in words.
T1_RANDOM_FAMILY = "random scalar plants, N 2..4, |a| <= 1 (half a = +-1)"
T1_HARD_FAMILY = "scalar N = 2, self-loops undelayed, a = +-1"


def search_tolerant_theorem1(seed: Any = 0, instances: int = DEFAULT_INSTANCES,
                             deadline: float = math.inf) -> Found:
    """Search the delay-tolerant Theorem 1 (|a| <= 1): eq. (11) exact rho >= 1 + MARGIN."""
    return _scalar_search("T-theorem1", seed, instances, deadline, _t1_draw, _t1_hard_draw,
                          _t1_judge, lambda x: _t1_margin(x)[0],
                          (T1_RANDOM_FAMILY, T1_HARD_FAMILY))


def simulate_error_growth(x: DelayedInstance, compensated: bool, steps: int = 600,
                          seed: int = 0) -> float:
    """Per-step growth of the noise-free error, simulated from the papers' recursions.

    A second implementation (not :mod:`netsim.models.augmented`): agent ``i``'s error
    obeys ``e_i,k = g_i (p_ii a e_i,k-1 + sum_j p_ij a^(d_ij+1) e_j,k-1-d_ij)``
    (LCSYS2022 eq. 4-5, compensated) or with ``a`` in place of ``a^(d_ij+1)``
    (delay-tolerant eq. 6-7 with a still state), ``g_i = 1 - k_i c_i^2``. Returns the
    geometric mean of the per-step growth of the error history's norm over the second
    half (renormalised every step), which tends to the exact spectral radius.
    """
    P = np.array(x.inst.P)
    d = np.array(x.delays)
    g = np.array([1 - k * c * c for k, c in zip(x.inst.k, x.inst.c, strict=True)])
    a, N, tau = x.inst.a, len(g), x.tau
    coef = P * np.where(compensated, a ** (d + 1), a)
    hist = np.random.default_rng(seed).standard_normal((tau + 1, N))  # hist[r] = e_{k-r}
    logs = []
    for _ in range(steps):
        new = g * np.array([sum(coef[i, j] * hist[d[i, j], j] for j in range(N))
                            for i in range(N)])
        hist = np.vstack([new, hist[:-1]])
        norm = float(np.linalg.norm(hist))
        logs.append(math.log(norm))
        hist /= norm
    return float(math.exp(np.mean(logs[steps // 2:])))


# -- aoi paper Corollary 1, Lemmas 3 and 5 ------------------------------------------------


@dataclass(frozen=True)
class AoiInstance:
    """Parameters of :func:`netsim.aoi.random_aoi_scenario` (n, N, T, seed)."""

    n: int
    N: int
    T: int
    seed: int

    def scenario(self, extra_steps: int = 10) -> Any:
        """The scenario, run long enough to see the Corollary 1 bound."""
        from netsim.aoi import random_aoi_scenario

        bound = self.n + 2 * self.N * (self.N - 1) * self.T
        return random_aoi_scenario(self.n, self.N, self.T, seed=self.seed,
                                   steps=bound + extra_steps)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"n": self.n, "N": self.N, "T": self.T, "seed": self.seed}


def aoi_numbers(x: AoiInstance) -> dict[str, Any]:
    """Run the instance (noise-free, deadbeat): converged step, freshness, the bounds."""
    from netsim.runner import run_monte_carlo

    res = run_monte_carlo(x.scenario(), families=["aoi"], keep_trials=False)
    rep = cast("dict[str, Any]", res.estimators["aoi"].report)  # aoi has a report
    b = cast("dict[str, Any]", res.analytics)["aoi"]["bounds"]  # the aoi family's
    fresh = rep.get("freshness") or {}
    return {"converged_at": rep.get("converged_at"), "T": b["T"],
            "corollary_1": b["corollary_1_finite_time"],
            "triggered_by": fresh.get("all_triggered_by"),
            "lemma_3": b["lemma_3_triggered_by"],
            "max_index": fresh.get("max_index_after_trigger_bound"),
            "lemma_5": b["lemma_5_freshness_max"], "assumption_1": b["assumption_1"]}


@functools.lru_cache(maxsize=16)
def _aoi_numbers_or_none(x: AoiInstance) -> dict[str, Any] | None:
    try:
        return aoi_numbers(x)
    except Exception:  # noqa: BLE001 - a draw the generator cannot build is skipped
        return None


def _aoi_draw(rng: np.random.Generator) -> AoiInstance | None:
    """A random instance whose run exists and satisfies Assumption 1 (else None: a draw
    outside the hypotheses is not counted)."""
    x = AoiInstance(int(rng.integers(2, 7)), int(rng.integers(2, 6)),
                    int(rng.integers(1, 4)), int(rng.integers(0, 2 ** 31)))
    v = _aoi_numbers_or_none(x)
    return x if v is not None and v["assumption_1"] else None


def _aoi_judge(x: AoiInstance) -> dict[str, Any] | None:
    v = _aoi_numbers_or_none(x)
    if v is None or not v["assumption_1"]:
        return None
    bad = []
    conv, bound = v["converged_at"], v["corollary_1"]
    if conv is None or bound is None or conv > bound:
        bad.append("corollary_1")
    if v["triggered_by"] is None or v["lemma_3"] is None or v["triggered_by"] > v["lemma_3"]:
        bad.append("lemma_3")
    if v["max_index"] is not None and v["lemma_5"] is not None and v["max_index"] > v["lemma_5"]:
        bad.append("lemma_5")
    return {**v, "violated": bad} if bad else None


def _aoi_simpler(x: AoiInstance) -> list[AoiInstance]:
    out = []
    for n, N, T in ((x.n - 1, x.N, x.T), (x.n, x.N - 1, x.T), (x.n, x.N, x.T - 1)):
        if n >= 1 and N >= 2 and T >= 1:
            out.append(AoiInstance(n, N, T, x.seed))
    return out


#: The family of the aoi search, in words.
AOI_FAMILY = ("random jointly observable systems on jointly strongly connected graph "
              "sequences (n 2..6, N 2..5, T 1..3), Assumption 1 checked")
#: Instances of the aoi and dkfe searches per :data:`DEFAULT_INSTANCES` (they cost more).
SLOW_SEARCH_SHARE = 0.75


def search_aoi(seed: Any = 0, instances: int = DEFAULT_INSTANCES,
               deadline: float = math.inf) -> Found:
    """Search aoi Corollary 1 (and Lemmas 3, 5) over random jointly observable systems
    (draws where Assumption 1 fails are not counted)."""
    return random_search("A-corollary1", _aoi_draw, _aoi_judge, _aoi_simpler, seed=seed,
                         instances=max(1, int(instances * SLOW_SEARCH_SHARE)),
                         family=AOI_FAMILY, deadline=deadline)


# -- dkfe (75)-(76), Theorem 2 ------------------------------------------------------------


@dataclass(frozen=True)
class DkfeInstance:
    """One sink: plant A (n x n), C (1 x n), Q = I, R = 1, r of n components sent with
    the given probabilities over the r-subsets, delay d."""

    A: tuple[tuple[float, ...], ...]
    C: tuple[float, ...]
    r: int
    probabilities: tuple[float, ...]
    d: int

    def parts(self) -> tuple[np.ndarray, Any, np.ndarray, int]:
        """``(A, selection, Phi_K, d)`` (Phi_K of the steady local Kalman filter)."""
        from netsim.models.dkfe import SelectionScheme, steady_state_local_filter

        A = np.array(self.A)
        n = A.shape[0]
        sel = SelectionScheme.all_subsets(n, self.r, self.probabilities)
        ss = steady_state_local_filter(A, np.array([self.C]), np.eye(n), np.eye(1))
        return A, sel, ss.Phi, self.d

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"A": [list(r) for r in self.A], "C": list(self.C), "Q": "I", "R": 1.0,
                "r": self.r, "probabilities": list(self.probabilities), "d": self.d}


def dkfe_numbers(x: DkfeInstance) -> dict[str, Any]:
    """(75) by cvxpy, the exact second-moment radius, (76) (d = 0), (74), (77)."""
    from netsim.models.dkfe import (
        condition_74,
        condition_76,
        condition_77,
        lmi_75,
        second_moment_radius,
    )

    A, sel, Phi, d = x.parts()
    return {"c75": bool(lmi_75(A, Phi, sel, d).feasible),
            "radius": second_moment_radius(A, Phi, sel, d),
            "c76": bool(d == 0 and condition_76(A, sel) < 1),
            "c74": bool(condition_74(A, Phi, sel, d)["holds"]),
            "c77_rho": condition_77(A, sel, d)}


def _dkfe_draw(rng: np.random.Generator) -> DkfeInstance | None:
    from netsim.models.dkfe import condition_58

    n = int(rng.integers(2, 4))
    A = rng.standard_normal((n, n))
    A *= float(rng.uniform(0.7, 1.4)) / max(abs(np.linalg.eigvals(A)))
    C = rng.standard_normal(n)
    if not condition_58(A, np.eye(n), C[None, :])["holds"]:
        return None
    r = int(rng.integers(1, n))
    m = math.comb(n, r)
    probs = rng.dirichlet(np.ones(m))
    probs = np.round(probs / probs.sum(), 12)
    probs[-1] = 1.0 - probs[:-1].sum()
    if np.any(probs < 0):
        return None
    x = DkfeInstance(tuple(map(tuple, np.round(A, 6).tolist())),
                     tuple(np.round(C, 6).tolist()), r, tuple(probs.tolist()),
                     int(rng.integers(0, 3)))
    return x if _dkfe_numbers_or_none(x) is not None else None


@functools.lru_cache(maxsize=16)
def _dkfe_numbers_or_none(x: DkfeInstance) -> dict[str, Any] | None:
    try:
        return dkfe_numbers(x)
    except Exception:  # noqa: BLE001 - e.g. a Riccati equation without a solution
        return None


def _dkfe_judge(x: DkfeInstance) -> dict[str, Any] | None:
    v = _dkfe_numbers_or_none(x)
    if v is None:
        return None
    bad = []
    if v["c75"] and not v["radius"] < 1:
        bad.append("theorem_2")  # (75) feasible, Tr Xi does not converge
    if (v["c76"] or v["c74"]) and not v["c75"]:
        bad.append("less_conservative")
    return {**v, "violated": bad} if bad else None


#: The family of the dkfe search, in words.
DKFE_FAMILY = "random one-sink instances (n 2..3, d 0..2, (58) holds)"


def search_dkfe(seed: Any = 0, instances: int = DEFAULT_INSTANCES,
                deadline: float = math.inf) -> Found:
    """Search Theorem 2 ((75) => Tr Xi converges) and "(75) less conservative than (76),
    (74)" over random one-sink instances."""
    return random_search("D-cond75", _dkfe_draw, _dkfe_judge, None, seed=seed,
                         instances=max(1, int(instances * SLOW_SEARCH_SHARE)),
                         family=DKFE_FAMILY, deadline=deadline)


# -- scenario files and confirmation by `netsim run` ------------------------------------


def delayed_scenario_toml(x: DelayedInstance, name: str, note: str,
                          estimators: tuple[str, ...] = ("compensated",)) -> str:
    """A scenario file (TOML) of ``x``: homogeneous delays as ``model = "homogeneous"``,
    heterogeneous ones as ``model = "fixed"`` with one ``[[delays.links]]`` per link."""
    from netsim.claims.search import scenario_toml

    text = scenario_toml(x.inst, x.tau, name, note)
    text = text.replace('estimators = ["compensated"]',
                        "estimators = [" + ", ".join(f'"{e}"' for e in estimators) + "]")
    if x.homogeneous:
        return text
    lines = ["[delays]", 'model = "fixed"', "default = 0"]
    d = np.array(x.delays)
    P = np.array(x.inst.P)
    for i, j in zip(*np.nonzero((P != 0) & ~np.eye(len(P), dtype=bool)), strict=True):
        lines += ["[[delays.links]]", f"from = {int(j)}", f"to = {int(i)}",
                  f"delay = {int(d[i, j])}"]
    head, rest = text.split("[delays]\n", 1)
    rest = rest.split("\n\n", 1)[1]
    return head + "\n".join(lines) + "\n\n" + rest


def write_delayed_scenario(x: DelayedInstance, folder: Path, name: str, note: str,
                           estimators: tuple[str, ...] = ("compensated",)) -> Path:
    """Write :func:`delayed_scenario_toml` to ``folder/name.toml``; return the path."""
    folder.mkdir(parents=True, exist_ok=True)
    from netsim.outfiles import write_text_safely

    return write_text_safely(folder / f"{name}.toml",
                             delayed_scenario_toml(x, name, note, estimators), "--out")


def confirm_run(scenario: Path | str | dict[str, Any], family: str, steps: int = 400,
                trials: int = 2) -> dict[str, Any]:
    """``netsim run`` on a scenario (file or parsed TOML): the family's verdict, what the
    measured growth alone says, the fitted MSE growth per step and the MSE ratio."""
    from netsim.api import run

    data = run(scenario, steps=steps, trials=trials, estimators=[family]).to_dict()
    e = data["estimators"][family]
    marks = sorted(e["mse_at"], key=int)
    first, last = e["mse_at"][marks[0]], e["mse_at"][marks[-1]]
    detail = e.get("verdict_detail") or {}
    return {"verdict": e["verdict"], "measured": detail.get("measured"),
            "mse_growth": e.get("growth_rate"), "mse_first": first, "mse_last": last,
            "steps": steps}


def verify_counterexample(x: DelayedInstance, compensated: bool, exact: float,
                          bound: float | None = None, run: bool = True) -> dict[str, Any]:
    """Verify a scalar counterexample twice: by exact analysis and by simulation.

    The exact analysis is ``exact`` (the augmented closed loop's spectral radius, from
    :mod:`netsim.models.augmented`). The simulations are independent of it: the
    noise-free error recursion written from the papers' equations
    (:func:`simulate_error_growth`) and, for a stability claim (``bound`` None) with
    ``run``, the real estimator in ``netsim run`` (400 steps x 2 trials), whose measured
    growth must say ``diverging`` (or a blow-up).

    Returns
    -------
    dict
        ``exact_rho``, ``simulated_error_growth``, ``netsim_run`` (or None) and
        ``confirmed`` (both verifications agree that the claim fails).
    """
    family = "compensated" if compensated else "uncompensated"
    sim = simulate_error_growth(x, compensated)
    threshold = (1.0 if bound is None else bound) + BOUND_SLACK / 2
    ok = exact > threshold and sim > threshold
    run_words = None
    if bound is None and run:
        text = delayed_scenario_toml(x, "counterexample", "verification run", (family,))
        run_words = confirm_run(tomllib.loads(text), family)
        ok = ok and (run_words["measured"] == "diverging"
                     or str(run_words["verdict"]).startswith("diverged"))
    return {"exact_rho": exact, "simulated_error_growth": sim, "netsim_run": run_words,
            "confirmed": bool(ok)}


def _theorem1(seed: Any, instances: int, deadline: float) -> Any:
    return search_theorem1(seed=seed, instances=instances, deadline=deadline)


#: The search of each claim: ``SEARCHES[claim_id](seed, instances, deadline)``.
SEARCHES: dict[str, Callable[[Any, int, float], Any]] = {
    "L-theorem1": _theorem1,
    "L-eq26-bound": search_eq26,
    "T-lemma5-bound": search_lemma5,
    "T-theorem1": search_tolerant_theorem1,
    "A-corollary1": search_aoi,
    "D-cond75": search_dkfe,
}
_ORDER = tuple(SEARCHES)


#: Trials of the bench runs behind the figure claims (``bench:PRESET``).
BENCH_TRIALS = 10


def bench_report(preset: str, seed: int) -> dict[str, Any]:
    """A small ``netsim bench delay-tolerance PRESET`` report: BENCH_TRIALS trials, the
    preset's steps, its focus family only (serial: it may run in a worker process)."""
    from netsim.bench.delay_tolerance import run_delay_tolerance
    from netsim.bench.presets import PRESETS
    from netsim.models.scenario import resolve_scenario

    p = PRESETS[preset]
    return run_delay_tolerance(resolve_scenario(p.scenario), taus=p.taus, delays=p.delays,
                               trials=BENCH_TRIALS, steps=p.steps, seed=seed,
                               families=[p.focus], preset=p, executor="serial",
                               progress=False)


def fusion_report(seed: int, scale: float = 1.0, trials: int = 20) -> dict[str, Any]:
    """``netsim fusion`` on Example 2 (300 steps, lockstep), x(0) ~ N(0, scale I)."""
    from dataclasses import replace

    from netsim.fusion import run_fusion
    from netsim.models.dkfe import example2

    setup = example2()
    setup = replace(setup, x0_cov=scale * np.eye(setup.n))
    return run_fusion(setup, steps=300, trials=trials, seed=seed, engine="lockstep").to_dict()


def run_search(claim_id: str, seed: int, budget: float | None = None,
               instances: int | None = None) -> Any:
    """Run the search of ``claim_id`` (L-theorem1 with ``seed`` itself, the others with
    their own stream ``SeedSequence(seed, spawn_key=(index,))``), over ``instances``
    random instances (default :data:`DEFAULT_INSTANCES`), cut short after ``budget``
    seconds if given.

    Also runs the claims' other long computations by name, so that they can share the
    worker processes: ``bench:PRESET`` (:func:`bench_report`) and ``fusion:SCALE:TRIALS``
    (:func:`fusion_report`).
    """
    import time

    if claim_id.startswith("bench:"):
        return bench_report(claim_id.split(":", 1)[1], seed)
    if claim_id.startswith("fusion:"):
        _, scale, trials = claim_id.split(":")
        return fusion_report(seed, float(scale), int(trials))
    count = DEFAULT_INSTANCES if instances is None else int(instances)
    deadline = math.inf if budget is None else time.monotonic() + float(budget)
    if claim_id == "L-theorem1":
        return SEARCHES[claim_id](seed, count, deadline)
    ss = np.random.SeedSequence(seed, spawn_key=(_ORDER.index(claim_id),))
    return SEARCHES[claim_id](ss, count, deadline)
