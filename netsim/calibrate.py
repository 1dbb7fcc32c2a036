"""Calibrated instances: ``netsim calibrate lcsys2022`` (issue 31).

LCSYS2022 (Section IV) prints no A, C, P or K, only properties and numbers: ``n = 6``
states, full rank, unstable with ``rho(A) = 1.04``, structurally cyclic with 4 irreducible
blocks; ``N = 4`` sensors with one output each, one per irreducible block, observable
together but not in any sensor's neighbourhood; a directed self-damped cycle
``1 -> 2 -> 3 -> 4 -> 1`` with random row-stochastic weights; a block-diagonal gain from
the LMI (13); and the numbers ``rho(A-hat) = 0.64``, ``tau* = 10``, the eq. (26) values
0.74, 0.94, 1.45 at ``tau = 3, 8, 19``, homogeneous ``tau = 19`` at ``rho = 1``
(marginally unstable) and heterogeneous ``tau = 19`` stable.

This module searches for an instance with every stated property that matches those
numbers. Every number is computed by the project's own analytics
(:mod:`netsim.models.augmented`): ``delay_free_spectral_radius``, ``tau_star_report``,
``delay_bound_lcsys`` and ``augmented_spectral_radius``.

The search is seeded least squares (``scipy.optimize.least_squares``) from starts drawn
with :class:`numpy.random.SeedSequence` (never global seeding) over a parametrisation
that has the stated properties by construction (:func:`unpack`). Its length is a count of
objective evaluations, never wall time: a search that its budget stops is "undecided",
and a match is only declared when an evaluated instance meets every target (the search
then stops). Stage 1 fits the cheap targets (Theorem 1's values over ``tau = 0..30``);
stage 2 adds the two exact spectral radii at ``tau = 19``.

Two readings of the printed eq. (26) values are searched:

``as-printed``
    ``rho((I - K D_C-bar)(P kron A^(tau+1)))^(1/(tau+1))``, eq. (26) as the paper writes it.
``no-root``
    ``rho((I - K D_C-bar)(P kron A^(tau+1)))`` without the root, Theorem 1's quantity.
    The printed values behave like it: ``value / 1.04^tau`` is nearly constant
    (0.64, 0.66, 0.69, 0.68 at ``tau = 0, 3, 8, 19``), and ``0.66 * 1.04^tau < 1``
    exactly for ``tau <= 10``, the printed ``tau*``.

:func:`contradictions` states what the printed numbers imply against each other (with
closed forms the tests recompute).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "PAPERS",
    "PRINTED",
    "READINGS",
    "TOLERANCE",
    "Instance",
    "CalibrationResult",
    "unpack",
    "measure",
    "properties",
    "search",
    "calibrate",
    "contradictions",
    "scenario_toml",
    "add_calibrate_parser",
    "cmd_calibrate",
]

#: Papers ``netsim calibrate`` knows.
PAPERS: tuple[str, ...] = ("lcsys2022",)

#: The readings of the printed eq. (26) values (see the module docstring).
READINGS: tuple[str, ...] = ("as-printed", "no-root")

#: LCSYS2022 Section IV's printed numbers.
PRINTED: dict[str, float] = {
    "rho_delay_free": 0.64,
    "tau_star": 10,
    "eq26_tau3": 0.74,
    "eq26_tau8": 0.94,
    "eq26_tau19": 1.45,
    "homogeneous_tau19": 1.0,
}

#: A printed two-decimal number is matched when the achieved value rounds to it.
TOLERANCE: float = 0.005

#: Stated plant and network facts (Section IV).
N_STATES, N_AGENTS, RHO_A, NOISE = 6, 4, 1.04, 0.004
#: Irreducible blocks of A (state index ranges); sensor i measures block i.
BLOCKS: tuple[tuple[int, int], ...] = ((0, 2), (2, 4), (4, 5), (5, 6))
#: Largest tau of the Theorem 1 scan (tau* = 10 must also be the largest passing tau).
TAU_MAX = 30
#: Delay seed of the heterogeneous realisation (as the built-in LCSYS2022 scenarios).
DELAY_SEED = 2022
#: Default objective evaluations per reading and starts per reading.
DEFAULT_EVALUATIONS = 10000
DEFAULT_STARTS = 4
#: Share of a start's budget for stage 1 (cheap targets); the rest is stage 2's.
STAGE1_SHARE = 0.8
#: Stage 2 (exact radii) runs from a stage-1 end whose weighted cost is below this.
STAGE2_BELOW = 0.5
#: Parameters: A (10 block entries, 5 couplings), C (2 angles), P (4 logits), L (24).
N_PARAMS = 45
_WEIGHT = 10.0
_MARGIN = 0.003


@dataclass(frozen=True)
class Instance:
    """A candidate LCSYS2022 instance.

    Attributes
    ----------
    A : numpy.ndarray
        ``(6, 6)`` plant matrix.
    C : tuple of numpy.ndarray
        ``N = 4`` output rows, each ``(1, 6)``.
    P : numpy.ndarray
        ``(4, 4)`` row-stochastic consensus matrix on the self-looped cycle.
    K : tuple of numpy.ndarray
        Block-diagonal gain: ``K_i`` of shape ``(6, 6)``.
    L : tuple of numpy.ndarray
        ``L_i = K_i C_i^T`` (what enters the closed loop), each ``(6, 1)``.
    """

    A: np.ndarray
    C: tuple[np.ndarray, ...]
    P: np.ndarray
    K: tuple[np.ndarray, ...]
    L: tuple[np.ndarray, ...]

    def heterogeneous_delays(self, tau: int = 19, seed: int = DELAY_SEED) -> np.ndarray:
        """The scenario's heterogeneous fixed delays for bound ``tau`` (``(N, N)``).

        The realisation of :func:`netsim.models.delays.heterogeneous_delays`, which a
        scenario with ``[delays] model = "heterogeneous"``, ``seed = seed`` uses.
        """
        from netsim.models.delays import heterogeneous_delays

        links = [(j, i) for i, j in zip(*np.nonzero(self.P), strict=True) if i != j]
        model = heterogeneous_delays(links, tau, seed)
        d = np.zeros(self.P.shape, dtype=np.int64)
        for j, i in links:
            d[i, j] = int(model.draw(j, i, 0))
        return d


def _homogeneous(P: np.ndarray, tau: int) -> np.ndarray:
    """Delay ``tau`` on every link, 0 on the self-loops (as netsim.claims.checks)."""
    return np.where((P != 0) & ~np.eye(P.shape[0], dtype=bool), tau, 0)


def unpack(x: Sequence[float] | np.ndarray) -> Instance:
    """Map a parameter vector (length :data:`N_PARAMS`) to an instance.

    The stated properties hold by construction: ``A`` is block lower triangular with
    irreducible diagonal blocks of sizes 2, 2, 1, 1, block 0 driving block 1 and block 2
    driving block 3 (so that no sensor neighbourhood on the cycle sees all four blocks:
    Remark 1), scaled to ``rho(A) = 1.04``; ``C_i`` is
    one output row supported on block ``i``; ``P`` has ``p_ii`` in ``(0, 1)`` and
    ``p_i,i-1 = 1 - p_ii`` (the directed self-looped cycle); ``K_i = L_i C_i / |C_i|^2``
    (block diagonal, ``K_i C_i^T = L_i``).
    """
    x = np.asarray(x, dtype=float)
    if x.shape != (N_PARAMS,):
        raise ValueError(f"expected {N_PARAMS} parameters, got shape {x.shape}")
    n, N = N_STATES, N_AGENTS
    A = np.zeros((n, n))
    A[0:2, 0:2] = x[0:4].reshape(2, 2)
    A[2:4, 2:4] = x[4:8].reshape(2, 2)
    A[4, 4], A[5, 5] = x[8], x[9]
    A[2:4, 0:2] = x[10:14].reshape(2, 2)
    A[5, 4] = x[14]
    radius = float(np.max(np.abs(np.linalg.eigvals(A))))
    if radius > 0:
        A = A * (RHO_A / radius)
    C = [np.zeros((1, n)) for _ in range(N)]
    C[0][0, 0:2] = (math.cos(x[15]), math.sin(x[15]))
    C[1][0, 2:4] = (math.cos(x[16]), math.sin(x[16]))
    C[2][0, 4] = 1.0
    C[3][0, 5] = 1.0
    p = 1.0 / (1.0 + np.exp(-x[17:21]))
    P = np.diag(p)
    for i in range(N):
        P[i, (i - 1) % N] = 1.0 - p[i]
    K = tuple(x[21 + n * i: 21 + n * (i + 1)].reshape(n, 1) @ C[i]
              / float((C[i] @ C[i].T)[0, 0])
              for i in range(N))
    L = tuple(Ki @ Ci.T for Ki, Ci in zip(K, C, strict=True))
    return Instance(A, tuple(C), P, K, L)


def _tau_values(inst: Instance) -> Any:
    from netsim.models.augmented import tau_star_report

    return tau_star_report(inst.P, inst.A, inst.C, inst.L, tau_max=TAU_MAX)


def measure(inst: Instance, *, exact: bool = True) -> dict[str, Any]:
    """The printed quantities of ``inst``, by the project's analytics.

    Parameters
    ----------
    inst : Instance
        The instance.
    exact : bool, default True
        Also the exact spectral radii of the augmented closed loop at ``tau = 19``
        (homogeneous; heterogeneous with the scenario's delay seed).

    Returns
    -------
    dict
        ``rho_delay_free``; ``tau_star`` (contiguous) and ``tau_star_isolated``;
        ``eq26_tau{3,8,19}`` (:func:`delay_bound_lcsys`, with the root) and
        ``theorem1_tau{3,8,19}`` (its ``(tau+1)``-th power, ``rho((I-KD)(P kron
        A^(tau+1)))``, from :func:`tau_star_report`); with ``exact``,
        ``homogeneous_tau19``, ``heterogeneous_tau19`` and ``heterogeneous_delays``.
    """
    from netsim.models.augmented import (
        augmented_spectral_radius,
        delay_bound_lcsys,
        delay_free_spectral_radius,
    )

    report = _tau_values(inst)
    out: dict[str, Any] = {
        "rho_delay_free": float(delay_free_spectral_radius(inst.P, inst.A, inst.C, inst.L)),
        "tau_star": report.contiguous,
        "tau_star_isolated": list(report.isolated),
    }
    for t in (3, 8, 19):
        out[f"eq26_tau{t}"] = float(delay_bound_lcsys(inst.P, inst.A, inst.C, inst.L, t))
        out[f"theorem1_tau{t}"] = float(report.values[t])
    if exact:
        P = inst.P
        out["homogeneous_tau19"] = float(augmented_spectral_radius(
            P, inst.A, inst.C, inst.L, _homogeneous(P, 19), 19))
        d = inst.heterogeneous_delays(19)
        out["heterogeneous_tau19"] = float(augmented_spectral_radius(
            P, inst.A, inst.C, inst.L, d, 19))
        out["heterogeneous_delays"] = d.tolist()
    return out


def properties(inst: Instance) -> dict[str, Any]:
    """The properties LCSYS2022 states, each checked on ``inst``.

    Returns
    -------
    dict
        Name -> ``{"value", "holds"}``: ``rho(A) = 1.04`` (unstable), ``det(A) != 0``,
        self-damped (non-zero diagonal), 4 irreducible blocks (strongly connected
        components of A's graph), one output per block, ``(A, C)`` observable, no
        neighbourhood observable (Remark 1), ``P`` row-stochastic on the self-looped
        cycle, ``K`` block diagonal, and the LMI (13) feasible (a Lyapunov ``X > 0`` with
        ``X - A-hat^T X A-hat > 0``, from the discrete Lyapunov equation).
    """
    import networkx as nx
    from scipy.linalg import solve_discrete_lyapunov

    from netsim.models.augmented import delay_free_closed_loop
    from netsim.models.observability import is_observable, local_observability

    A, P = inst.A, inst.P
    n, N = A.shape[0], P.shape[0]
    rho_A = float(np.max(np.abs(np.linalg.eigvals(A))))
    det = float(np.linalg.det(A))
    graph: nx.DiGraph[int] = nx.DiGraph()
    graph.add_nodes_from(range(n))
    graph.add_edges_from((j, i) for i, j in zip(*np.nonzero(A), strict=True))
    comps = sorted(sorted(c) for c in nx.strongly_connected_components(graph))
    blocks_seen = [sorted({b for b, (lo, hi) in enumerate(BLOCKS)
                           if np.any(Ci[0, lo:hi] != 0)}) for Ci in inst.C]
    local = local_observability(A, list(inst.C), P)
    cycle = np.zeros((N, N), dtype=bool)
    for i in range(N):
        cycle[i, i] = cycle[i, (i - 1) % N] = True
    Ahat = delay_free_closed_loop(P, A, inst.C, inst.L)
    with np.errstate(all="ignore"):
        X = solve_discrete_lyapunov(Ahat.T, np.eye(Ahat.shape[0]))
    X = (X + X.T) / 2
    R = X - Ahat.T @ X @ Ahat
    lmi = (float(np.linalg.eigvalsh(X)[0]), float(np.linalg.eigvalsh((R + R.T) / 2)[0]))
    gains_ok = len(inst.K) == N and all(
        Ki.shape == (n, n) and np.allclose(Ki @ Ci.T, Li, rtol=1e-12, atol=0)
        for Ki, Ci, Li in zip(inst.K, inst.C, inst.L, strict=True))
    return {
        "rho_A": {"value": rho_A, "holds": abs(rho_A - RHO_A) < 1e-9},
        "full_rank": {"value": det, "holds": abs(det) > 1e-9},
        "self_damped": {"value": [float(v) for v in np.diag(A)],
                        "holds": bool(np.all(np.diag(A) != 0))},
        "irreducible_blocks": {"value": comps, "holds": len(comps) == 4},
        "one_output_per_block": {"value": blocks_seen,
                                 "holds": blocks_seen == [[b] for b in range(N)]},
        "observable": {"value": bool(is_observable(A, np.vstack(inst.C))),
                       "holds": bool(is_observable(A, np.vstack(inst.C)))},
        "no_local_observability": {"value": [bool(v) for v in local],
                                   "holds": not any(local)},
        "cycle_row_stochastic": {
            "value": P.tolist(),
            "holds": bool(np.allclose(P.sum(axis=1), 1.0) and np.all((P > 0) == cycle)
                          and np.all(P[cycle] < 1))},
        "block_diagonal_K": {"value": [list(Ki.shape) for Ki in inst.K],
                             "holds": gains_ok},
        "lmi13_feasible": {"value": {"min_eig_X": lmi[0], "min_eig_X_minus_AXA": lmi[1]},
                           "holds": lmi[0] > 0 and lmi[1] > 0},
    }


def _targets(m: dict[str, Any], reading: str) -> list[dict[str, Any]]:
    """One row per printed number: printed, achieved, gap, matched."""
    key = "eq26" if reading == "as-printed" else "theorem1"
    rows = [{"name": "rho(A-hat)", "printed": PRINTED["rho_delay_free"],
             "achieved": m["rho_delay_free"]}]
    star = m["tau_star"]
    rows.append({"name": "tau*", "printed": 10, "achieved": star,
                 "gap": None if star is None else star - 10,
                 "matched": star == 10 and not m["tau_star_isolated"]})
    for t in (3, 8, 19):
        rows.append({"name": f"eq. (26) at tau = {t}", "printed": PRINTED[f"eq26_tau{t}"],
                     "achieved": m[f"{key}_tau{t}"]})
    if "homogeneous_tau19" in m:
        rows.append({"name": "homogeneous tau = 19 (exact rho)", "printed": 1.0,
                     "achieved": m["homogeneous_tau19"]})
        h = m["heterogeneous_tau19"]
        rows.append({"name": "heterogeneous tau = 19 (exact rho)", "printed": "stable (< 1)",
                     "achieved": h, "gap": max(0.0, h - 1.0), "matched": h < 1.0})
    for r in rows:
        if "matched" not in r:
            r["gap"] = r["achieved"] - r["printed"]
            r["matched"] = abs(r["gap"]) <= TOLERANCE
    return rows


def _residuals(report: Any, reading: str, exact: tuple[float, ...] | None) -> np.ndarray:
    v = np.asarray(report.values, dtype=float)
    v = np.where(np.isfinite(v), v, 1e6)
    f = v ** (1.0 / (np.arange(v.size) + 1.0)) if reading == "as-printed" else v
    r = [v[0] - PRINTED["rho_delay_free"]]
    r += [f[t] - PRINTED[f"eq26_tau{t}"] for t in (3, 8, 19)]
    r += [max(0.0, v[t] - (1.0 - _MARGIN)) for t in range(11)]
    r += [max(0.0, (1.0 + _MARGIN) - v[t]) for t in range(11, v.size)]
    if exact is not None:
        r += [exact[0] - PRINTED["homogeneous_tau19"], max(0.0, exact[1] - (1.0 - _MARGIN))]
    return _WEIGHT * np.asarray(r)


class _Stop(Exception):
    """The evaluation budget is spent, or every target is met."""


@dataclass
class _Objective:
    reading: str
    budget: int
    tick: Callable[[int], Any]
    evaluations: int = 0
    exact_evaluations: int = 0
    best: tuple[float, np.ndarray] | None = None
    found: np.ndarray | None = None

    def __call__(self, x: np.ndarray, exact: bool) -> np.ndarray:
        if self.evaluations >= self.budget:
            raise _Stop("budget")
        self.evaluations += 1
        self.tick(1)
        inst = unpack(x)
        report = _tau_values(inst)
        ex = None
        if exact:
            from netsim.models.augmented import augmented_spectral_radius

            self.exact_evaluations += 1
            ex = tuple(float(augmented_spectral_radius(inst.P, inst.A, inst.C, inst.L, d, 19))
                       for d in (_homogeneous(inst.P, 19), inst.heterogeneous_delays(19)))
        r = _residuals(report, self.reading, ex)
        cost = float(r @ r)
        if self.best is None or cost < self.best[0]:
            self.best = (cost, np.array(x, dtype=float))
        if exact and self._meets(report, ex):
            self.found = np.array(x, dtype=float)
            raise _Stop("found")
        return r

    def _meets(self, report: Any, ex: Any) -> bool:
        v = np.asarray(report.values)
        f = v ** (1.0 / (np.arange(v.size) + 1.0)) if self.reading == "as-printed" else v
        return bool(report.contiguous == 10 and not report.isolated
                    and abs(v[0] - PRINTED["rho_delay_free"]) <= TOLERANCE
                    and all(abs(f[t] - PRINTED[f"eq26_tau{t}"]) <= TOLERANCE
                            for t in (3, 8, 19))
                    and abs(ex[0] - 1.0) <= TOLERANCE and ex[1] < 1.0)


@dataclass(frozen=True)
class CalibrationResult:
    """One reading's search and its verified outcome.

    Attributes
    ----------
    reading : str
        ``"as-printed"`` or ``"no-root"``.
    verdict : str
        ``"matched"`` (an instance meets every target, properties included),
        ``"not matched"`` (every start ran to convergence without one) or
        ``"undecided"`` (the evaluation budget stopped the search first).
    instance : Instance or None
        The matched instance, else the closest found (``None`` if none was evaluated
        with the exact radii).
    numbers : dict
        :func:`measure` of ``instance``.
    targets : list of dict
        Printed vs achieved per number.
    properties : dict
        :func:`properties` of ``instance``.
    evaluations, exact_evaluations, budget, starts, seed : int
        The search's counts and settings.
    """

    reading: str
    verdict: str
    instance: Instance | None
    numbers: dict[str, Any]
    targets: list[dict[str, Any]]
    properties: dict[str, Any]
    evaluations: int
    exact_evaluations: int
    budget: int
    starts: int
    seed: int
    parameters: list[float] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        inst = self.instance
        return {
            "reading": self.reading, "verdict": self.verdict,
            "evaluations": self.evaluations, "exact_evaluations": self.exact_evaluations,
            "budget": self.budget, "starts": self.starts, "seed": self.seed,
            "targets": self.targets, "numbers": self.numbers,
            "properties": self.properties,
            "instance": None if inst is None else {
                "A": inst.A.tolist(), "C": [c.tolist() for c in inst.C],
                "P": inst.P.tolist(), "K": [k.tolist() for k in inst.K]},
        }


def _start(rng: np.random.Generator) -> np.ndarray:
    x = np.concatenate([rng.normal(0.0, 0.6, 15), rng.uniform(0.0, np.pi, 2),
                        rng.normal(0.0, 1.0, 4), rng.normal(0.0, 0.5, 24)])
    x[[0, 3, 4, 7, 8, 9]] += 1.0
    return x


def search(reading: str, *, evaluations: int = DEFAULT_EVALUATIONS,
           starts: int = DEFAULT_STARTS, seed: int = DELAY_SEED,
           tick: Callable[[int], Any] | None = None) -> CalibrationResult:
    """Search one reading's targets (see the module docstring).

    Parameters
    ----------
    reading : {"as-printed", "no-root"}
        How the printed eq. (26) values are read.
    evaluations : int
        Budget: objective evaluations (cheap and exact together).
    starts : int
        Seeded starts (``SeedSequence(seed).spawn(starts)``).
    seed : int
        Root seed.
    tick : callable, optional
        Called with 1 per evaluation (a progress bar's ``update``).

    Returns
    -------
    CalibrationResult
    """
    from scipy.optimize import least_squares

    if reading not in READINGS:
        raise ValueError(f"reading must be one of {READINGS}, got {reading!r}")
    evaluations, starts = int(evaluations), int(starts)
    if evaluations < 1 or starts < 1:
        raise ValueError("evaluations and starts must be positive")
    obj = _Objective(reading, evaluations, tick or (lambda k: None))
    per_start = max(1, evaluations // starts)
    stage1 = max(1, int(per_start * STAGE1_SHARE))
    cheap_best: tuple[float, np.ndarray] | None = None
    stopped = None
    cut = False  # a stage was stopped by its share of the budget, not by convergence
    tight: dict[str, Any] = {"method": "trf", "ftol": 1e-12, "xtol": 1e-12, "gtol": 1e-12}
    try:
        for child in np.random.SeedSequence(seed).spawn(starts):
            x0 = _start(np.random.default_rng(child))
            end = min(obj.evaluations + per_start, evaluations)
            cap = _Objective(reading, min(obj.evaluations + stage1, end), obj.tick,
                             evaluations=obj.evaluations)
            x1: np.ndarray | None
            try:
                sol = least_squares(partial(cap, exact=False), x0,
                                    max_nfev=10 * stage1, **tight)
                x1, cost = sol.x, float(sol.fun @ sol.fun)
            except _Stop:  # its share is spent: continue from its best point
                cut = True
                x1, cost = (None, math.inf) if cap.best is None else (cap.best[1], cap.best[0])
            obj.evaluations = cap.evaluations
            if x1 is not None and (cheap_best is None or cost < cheap_best[0]):
                cheap_best = (cost, x1)
            if x1 is not None and cost < STAGE2_BELOW:
                stage2 = _Objective(reading, end, obj.tick, evaluations=obj.evaluations,
                                    best=obj.best)
                try:
                    least_squares(partial(stage2, exact=True), x1,
                                  max_nfev=10 * per_start, **tight)
                except _Stop:
                    cut = cut or stage2.found is None
                obj.evaluations = stage2.evaluations
                obj.exact_evaluations += stage2.exact_evaluations
                obj.best, obj.found = stage2.best, stage2.found
                if obj.found is not None:
                    raise _Stop("found")
            if obj.evaluations >= evaluations:
                raise _Stop("budget")
    except _Stop as stop:
        stopped = str(stop)
    if obj.best is None and cheap_best is not None:
        obj.best = cheap_best
    x: np.ndarray | None
    if obj.found is not None:
        x, verdict = obj.found, "matched"
    else:
        x = None if obj.best is None else obj.best[1]
        verdict = "undecided" if stopped == "budget" or cut else "not matched"
    if x is None:
        return CalibrationResult(reading, verdict, None, {}, [], {}, obj.evaluations,
                                 obj.exact_evaluations, evaluations, starts, seed)
    inst = unpack(x)
    numbers = measure(inst)
    targets = _targets(numbers, reading)
    props = properties(inst)
    if verdict == "matched" and not (all(t["matched"] for t in targets)
                                     and all(p["holds"] for p in props.values())):
        verdict = "not matched"  # the recomputation disagrees: never claim a match
    return CalibrationResult(reading, verdict, inst, numbers, targets, props,
                             obj.evaluations, obj.exact_evaluations, evaluations, starts,
                             seed, [float(v) for v in x])


# ---------------------------------------------------------------------------
# what the printed numbers imply against each other
# ---------------------------------------------------------------------------


def contradictions(inst: Instance | None = None) -> list[dict[str, Any]]:
    """What the printed numbers imply, with closed forms.

    1. Lemma 4's equality case: with *every* delay, self-loops included, equal to
       ``tau``, the augmented closed loop has first block row ``[0, ..., 0, M(tau)]``
       (``M(tau) = (I - K D_C-bar)(P kron A^(tau+1))``), so its eigenvalues are the
       ``(tau+1)``-th roots of those of ``M(tau)``: exact rho = eq. (26) value. Then the
       printed ``eq. (26) at 19 = 1.45`` and "homogeneous tau = 19: rho = 1" cannot both
       hold (1.45 != 1). They can in netsim's setting (self-loops undelayed,
       Section II-C's ``tau_ii = 0``), where eq. (26) is no identity. With ``inst``, the
       equality is shown on it: the companion matrix is built and its exact rho
       compared with :func:`delay_bound_lcsys`.
    2. As printed (with the root), 0.94 at ``tau = 8`` and 1.45 at ``tau = 19`` mean
       ``rho(M(8)) = 0.94^9`` and ``rho(M(19)) = 1.45^20``; since
       ``M(19) = M(8) (I kron A^11)`` and ``rho(A)^11 = 1.04^11``, the ratio needs a
       non-normal amplification of ``ratio / 1.04^11`` (no contradiction by spectral
       radii alone, but the bound's value tends to ``rho(A) = 1.04`` as ``tau`` grows).
    3. Read without the root, the printed values over ``1.04^tau`` are nearly constant
       and ``c 1.04^tau < 1`` holds exactly up to ``tau = 10`` for ``c`` in their range:
       the printed ``tau* = 10`` follows, and ``1.45^(1/20) = 1.019`` is a marginally
       unstable homogeneous ``tau = 19``.
    """
    rows: list[dict[str, Any]] = []
    item: dict[str, Any] = {
        "numbers": ["eq. (26) at tau = 19: 1.45", "homogeneous tau = 19: rho = 1"],
        "setting": "every delay, self-loops included, equal to tau (Lemmas 4-5)",
        "closed_form": "exact rho = rho(M(tau))^(1/(tau+1)) = eq. (26) value",
        "contradiction": True,
        "text": "in Lemma 4's equality case the exact rho at tau = 19 is the eq. (26) "
                "value, so 1.45 and rho = 1 contradict; with self-loops undelayed "
                "(Section II-C, netsim) eq. (26) is not an identity and both can hold",
    }
    if inst is not None:
        item["evidence"] = lemma4_equality(inst, 19)
    rows.append(item)
    m8, m19 = PRINTED["eq26_tau8"] ** 9, PRINTED["eq26_tau19"] ** 20
    rows.append({
        "numbers": ["eq. (26) at tau = 8: 0.94", "eq. (26) at tau = 19: 1.45",
                    "rho(A) = 1.04"],
        "setting": "eq. (26) as printed (with the root)",
        "closed_form": "M(19) = M(8) (I kron A^11)",
        "contradiction": False,
        "evidence": {"rho_M8": m8, "rho_M19": m19, "ratio": m19 / m8,
                     "rho_A_pow_11": RHO_A ** 11,
                     "amplification_needed": m19 / m8 / RHO_A ** 11},
        "text": f"rho(M(19)) / rho(M(8)) = {m19 / m8:.0f} while rho(A)^11 = "
                f"{RHO_A ** 11:.2f}: a non-normal amplification of "
                f"{m19 / m8 / RHO_A ** 11:.0f} is needed (not excluded by spectral radii)",
    })
    ratios = {t: PRINTED[k] / RHO_A ** t for t, k in
              ((0, "rho_delay_free"), (3, "eq26_tau3"), (8, "eq26_tau8"),
               (19, "eq26_tau19"))}
    lo, hi = min(ratios.values()), max(ratios.values())
    star_lo = math.floor(-math.log(hi) / math.log(RHO_A) - 1e-12)
    star_hi = math.floor(-math.log(lo) / math.log(RHO_A) - 1e-12)
    rows.append({
        "numbers": ["0.64", "0.74", "0.94", "1.45", "tau* = 10", "rho = 1 at hom. 19"],
        "setting": "printed values read without the root (Theorem 1's rho(M(tau)))",
        "closed_form": "value(tau) ~ c 1.04^tau; tau* = max tau with c 1.04^tau < 1",
        "contradiction": False,
        "evidence": {"c": {str(t): r for t, r in ratios.items()},
                     "tau_star_range": [star_lo, star_hi],
                     "root_of_1.45_at_19": PRINTED["eq26_tau19"] ** (1 / 20)},
        "text": f"value/1.04^tau = {', '.join(f'{r:.3f}' for r in ratios.values())}; "
                f"c 1.04^tau < 1 up to tau = {star_lo}..{star_hi} (printed tau* = 10); "
                f"1.45^(1/20) = {PRINTED['eq26_tau19'] ** (1 / 20):.4f}",
    })
    return rows


def lemma4_equality(inst: Instance, tau: int) -> dict[str, float]:
    """Exact rho with every delay (self-loops too) equal to ``tau`` vs eq. (26).

    Builds the companion matrix with first block row ``[0, ..., 0, M(tau)]`` (dense
    eigenvalues; Lemma 4) and compares with :func:`delay_bound_lcsys`.
    """
    from netsim.models.augmented import delay_bound_lcsys, gain_product

    m = inst.P.shape[0] * inst.A.shape[0]
    top = (np.eye(m) - gain_product(inst.L, inst.C)) @ np.kron(
        inst.P, np.linalg.matrix_power(inst.A, tau + 1))
    M = np.zeros((m * (tau + 1), m * (tau + 1)))
    M[:m, tau * m:] = top
    M[m:, :-m] = np.eye(m * tau)
    exact = float(np.max(np.abs(np.linalg.eigvals(M))))
    bound = float(delay_bound_lcsys(inst.P, inst.A, inst.C, inst.L, tau))
    return {"tau": tau, "exact_all_delayed": exact, "eq26": bound,
            "difference": abs(exact - bound)}


# ---------------------------------------------------------------------------
# scenario file, report, command line
# ---------------------------------------------------------------------------


def _row(v: np.ndarray) -> str:
    return "[" + ", ".join(repr(float(a)) for a in v) + "]"


def _mat(M: np.ndarray, indent: str = "    ") -> str:
    return "[\n" + "".join(f"{indent}{_row(r)},\n" for r in M) + "]"


def scenario_toml(result: CalibrationResult, name: str = "lcsys2022-calibrated") -> str:
    """The calibrated instance as a scenario TOML (heterogeneous delays, given gains)."""
    inst = result.instance
    if inst is None:
        raise ValueError("the search evaluated no instance")
    shown = "; ".join(
        f"{t['name']} {t['printed']} -> {_fmt(t['achieved'])}"
        for t in result.targets)
    status = ("matches every printed number" if result.verdict == "matched"
              else f"does NOT match every printed number ({result.verdict})")
    desc = (
        "LCSYS2022 Section IV, calibrated by 'netsim calibrate lcsys2022' "
        f"(reading {result.reading}, seed {result.seed}, {result.evaluations} evaluations): "
        "n = 6 full-rank, self-damped, unstable system (rho(A) = 1.04) with 4 irreducible "
        "blocks; N = 4 sensors, one output per block, observable together but in no "
        "neighbourhood; the directed self-looped cycle 0->1->2->3->0 with row-stochastic "
        "weights; block-diagonal gains K_i (LMI (13) feasible). This instance "
        f"{status}: {shown}. Fixed heterogeneous delays, uniform in 0..tau per link.")
    C = "[\n" + "".join(f"    [{_row(c[0])}],\n" for c in inst.C) + "]"
    K = "[\n" + "".join(f"    {_mat(k, '        ')[:-1]}    ],\n" for k in inst.K) + "]"
    return (
        f'name = "{name}"\n'
        f'description = """{desc}"""\n\n'
        "[run]\nsteps = 300\ntrials = 20\nseed = 2022\n"
        'estimators = ["compensated", "uncompensated", "block", "centralized-kf"]\n\n'
        f"[plant]\nA = {_mat(inst.A)}\nC = {C}\nQ = {NOISE}\nR = {NOISE}\nx0_cov = 1.0\n\n"
        f"[network]\nP = {_mat(inst.P)}\n\n"
        f'[delays]\nmodel = "heterogeneous"\ntau = 3\nseed = {DELAY_SEED}\n\n'
        f'[gains]\nmethod = "given"\nK = {K}\n'
    )


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4f}"
    return str(v)


def report_text(results: Sequence[CalibrationResult], notes: list[dict[str, Any]]) -> str:
    """Plain-text report of the searches and the contradiction analysis."""
    lines: list[str] = []
    for res in results:
        lines.append(f"reading {res.reading}: {res.verdict.upper()} ({res.evaluations} of "
                     f"{res.budget} evaluations, {res.exact_evaluations} with exact radii; "
                     f"{res.starts} starts, seed {res.seed})")
        lines.append(f"  {'quantity':38s} {'paper':>14s} {'achieved':>10s} {'gap':>9s}  match")
        for t in res.targets:
            gap = "" if t["gap"] is None else f"{t['gap']:+.4f}"
            lines.append(f"  {t['name']:38s} {_fmt(t['printed']):>14s} "
                         f"{_fmt(t['achieved']):>10s} {gap:>9s}  "
                         f"{'yes' if t['matched'] else 'NO'}")
        bad = [k for k, p in res.properties.items() if not p["holds"]]
        lines.append("  stated properties: " + ("all hold" if not bad else
                                                 "FAIL " + ", ".join(bad)))
        if res.numbers:
            other = "theorem1" if res.reading == "as-printed" else "eq26"
            lines.append("  other reading's values at tau 3/8/19: " + " / ".join(
                f"{res.numbers[f'{other}_tau{t}']:.4g}" for t in (3, 8, 19)))
        lines.append("")
    lines.append("what the printed numbers imply:")
    for i, c in enumerate(notes, 1):
        tag = "CONTRADICTION" if c["contradiction"] else "note"
        lines.append(f"  {i}. [{tag}] {c['setting']}: {c['text']}")
        ev = c.get("evidence")
        if ev and "exact_all_delayed" in ev:
            lines.append(f"     on the instance: exact rho (all delayed, tau = 19) = "
                         f"{ev['exact_all_delayed']:.10f}, eq. (26) = {ev['eq26']:.10f}")
    return "\n".join(lines) + "\n"


def calibrate(paper: str = "lcsys2022", *, readings: Sequence[str] = READINGS,
              evaluations: int = DEFAULT_EVALUATIONS, starts: int = DEFAULT_STARTS,
              seed: int = DELAY_SEED, progress: bool | None = None
              ) -> tuple[list[CalibrationResult], list[dict[str, Any]]]:
    """Run the search for each reading; return the results and :func:`contradictions`.

    ``evaluations`` is the budget of each reading. ``progress``: a tqdm bar on stderr
    (None: only on a terminal; False: never).
    """
    if paper not in PAPERS:
        raise ValueError(f"unknown paper {paper!r}; netsim calibrates {', '.join(PAPERS)}")
    from tqdm import tqdm

    bar = tqdm(total=int(evaluations) * len(readings), desc=f"netsim calibrate {paper}",
               unit="eval", disable=None if progress is None else not progress,
               file=sys.stderr, leave=False)
    try:
        results = []
        for reading in readings:
            before = bar.n
            results.append(search(reading, evaluations=evaluations, starts=starts, seed=seed,
                                  tick=bar.update))
            bar.update(before + int(evaluations) - bar.n)
    finally:
        bar.close()
    chosen = _chosen(results)
    return results, contradictions(None if chosen is None else chosen.instance)


def _chosen(results: Sequence[CalibrationResult]) -> CalibrationResult | None:
    """The result written to ``--out``: the first matched, else the first with an instance."""
    with_inst = [r for r in results if r.instance is not None]
    matched = [r for r in with_inst if r.verdict == "matched"]
    first = matched or with_inst
    return first[0] if first else None


def add_calibrate_parser(sub: Any) -> argparse.ArgumentParser:
    """Register ``netsim calibrate`` on the subparsers ``sub``."""
    p = sub.add_parser(
        "calibrate", help="search an instance matching a paper's printed numbers",
        description="Search plant A, sensors C_i, network P and block-diagonal gains K_i "
        "with every property LCSYS2022 Section IV states that match its printed numbers "
        "(rho(A-hat) = 0.64, tau* = 10, eq. (26) at tau = 3/8/19 = 0.74/0.94/1.45, "
        "homogeneous tau = 19 at rho = 1, heterogeneous tau = 19 stable), by seeded least "
        "squares with a budget of objective evaluations; report each printed number "
        "against the value achieved, and what the numbers imply against each other.")
    p.add_argument("paper", choices=PAPERS, help="the paper")
    p.add_argument("--evaluations", type=int, default=DEFAULT_EVALUATIONS, metavar="N",
                   help=f"objective evaluations per reading (default {DEFAULT_EVALUATIONS})")
    p.add_argument("--starts", type=int, default=DEFAULT_STARTS, metavar="S",
                   help=f"seeded starts per reading (default {DEFAULT_STARTS})")
    p.add_argument("--seed", type=int, default=DELAY_SEED, help="root seed of the starts")
    p.add_argument("--reading", choices=(*READINGS, "both"), default="both",
                   help="how the printed eq. (26) values are read (default both)")
    p.add_argument("--out", metavar="FILE", help="write the calibrated scenario TOML")
    p.add_argument("--force", action="store_true", help="overwrite --out")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    return p


def cmd_calibrate(args: argparse.Namespace) -> int:
    """``netsim calibrate``: run, print the report, write ``--out``."""
    from netsim.cliutil import CommandError
    from netsim.outfiles import OutputFileError, atomic_output, check_output

    if args.evaluations < 1 or args.starts < 1:
        raise CommandError("--evaluations and --starts must be positive integers")
    out = None
    if args.out:
        try:
            out = check_output(args.out, "--out", force=args.force)
        except OutputFileError as exc:
            raise CommandError(str(exc)) from None
    readings = READINGS if args.reading == "both" else (args.reading,)
    results, notes = calibrate(args.paper, readings=readings, evaluations=args.evaluations,
                               starts=args.starts, seed=args.seed,
                               progress=False if args.no_progress else None)
    chosen = _chosen(results)
    written = None
    if out is not None and chosen is not None:
        with atomic_output(out) as tmp:
            Path(tmp).write_text(scenario_toml(chosen), encoding="utf-8")
        written = str(out)
    if args.json:
        from netsim.models.jsonsafe import json_tree

        print(json.dumps(json_tree({"paper": args.paper,
                                "results": [r.to_dict() for r in results],
                                "contradictions": notes, "written": written},
                               str_keys=True)))
    else:
        sys.stdout.write(report_text(results, notes))
        if written and chosen is not None:  # (written: chosen was)
            sys.stdout.write(f"wrote {written} (reading {chosen.reading}, "
                             f"{chosen.verdict})\n")
    return 0
