"""Seeded counterexample search for LCSYS2022 Theorem 1 over scalar plants.

Theorem 1's hypotheses, in the papers' own setting: a row-stochastic ``P`` on a
strongly connected, self-looped graph (Lemma 1; self-loops undelayed), a plant
``x_k = a x_{k-1}`` observed by the sensors with ``c_i != 0`` (``(P kron A, D_C)``
observable), gains ``K_i`` with ``rho(A-hat) < 1`` and one common delay ``tau`` on every
link (self-loops excluded). The theorem says the compensating estimator is stable for
every ``tau <= tau*``; the judge is the exact spectral radius of the augmented closed
loop (LCSYS2022 eq. 9-10). A hit is shrunk greedily (fewer links, coarser numbers,
smaller ``tau``) while it stays a counterexample, then written as a scenario file that
``netsim analyze FILE`` and ``netsim run FILE`` reproduce.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from netsim.models.augmented import augmented_spectral_radius, spectral_radius, tau_star

__all__ = ["ScalarInstance", "SearchResult", "Found", "random_search", "shrink",
           "search_theorem1", "scenario_toml", "write_scenario", "MARGIN", "TAU_MAX"]

#: A counterexample must have exact rho >= 1 + MARGIN (so that a run visibly diverges
#: and round-off cannot flip the verdict).
MARGIN = 0.01
#: Largest tau* scanned.
TAU_MAX = 20


@dataclass(frozen=True)
class ScalarInstance:
    """A scalar plant ``x_k = a x_{k-1}`` on ``N`` agents with given gains.

    Attributes
    ----------
    a : float
        The plant.
    P : tuple of tuple of float
        Row-stochastic consensus weights (self-loops on the diagonal).
    c : tuple of float
        Output of each agent (``y_i = c_i x``; 0: measures nothing).
    k : tuple of float
        Gains ``K_i`` (1 x 1 each); ``L_i = K_i c_i``.
    """

    a: float
    P: tuple[tuple[float, ...], ...]
    c: tuple[float, ...]
    k: tuple[float, ...]

    @property
    def N(self) -> int:
        """Number of agents."""
        return len(self.c)

    def matrices(self) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """``(P, A, C, L)`` in the form of :mod:`netsim.models.augmented`."""
        P = np.array(self.P, dtype=float)
        A = np.array([[self.a]])
        C = [np.array([[ci]]) for ci in self.c]
        L = [np.array([[ki * ci]]) for ki, ci in zip(self.k, self.c, strict=True)]
        return P, A, C, L

    def delays(self, tau: int) -> np.ndarray:
        """Delay ``tau`` on every link, 0 on the self-loops."""
        P = np.array(self.P)
        return np.where((P != 0) & ~np.eye(self.N, dtype=bool), tau, 0)

    def rho_delay_free(self) -> float:
        """``rho(A-hat) = rho(diag(1 - k_i c_i^2) P a)``."""
        P, A, C, L = self.matrices()
        G = np.diag([1.0 - ki * ci * ci for ki, ci in zip(self.k, self.c, strict=True)])
        return spectral_radius(G @ P * self.a)

    def tau_star(self) -> int | None:
        """Theorem 1's tau* (scanned to :data:`TAU_MAX`)."""
        return tau_star(*self.matrices(), tau_max=TAU_MAX)

    def exact_rho(self, tau: int) -> float:
        """Exact spectral radius of the compensated augmented closed loop at ``tau``."""
        return augmented_spectral_radius(*self.matrices(), self.delays(tau), tau,
                                         compensated=True)

    def hypotheses(self) -> str | None:
        """None if Theorem 1's hypotheses hold, else the first one that does not."""
        P = np.array(self.P)
        if np.any(P < 0) or not np.allclose(P.sum(axis=1), 1.0, atol=1e-12):
            return "P is not row-stochastic"
        if np.any(np.diag(P) <= 0):
            return "a self-loop is missing"
        reach = (P > 0).astype(int)
        closure = np.linalg.matrix_power(reach + np.eye(self.N, dtype=int), self.N)
        if not np.all(closure > 0):
            return "the graph is not strongly connected"
        obs = np.vstack([np.diag(self.c) @ np.linalg.matrix_power(P * self.a, i)
                       for i in range(self.N)])
        if np.linalg.matrix_rank(obs) < self.N:
            return "(P kron A, D_C) is not observable"
        if not self.rho_delay_free() < 1.0:
            return "rho(A-hat) >= 1"
        return None

    def violation(self) -> tuple[int, int, float] | None:
        """``(tau*, tau, exact rho)`` of the smallest ``1 <= tau <= tau*`` with exact rho
        ``>= 1 + MARGIN``, or None (hypotheses violated or no such tau)."""
        if self.hypotheses() is not None:
            return None
        star = self.tau_star()
        if star is None or star < 1:
            return None
        for tau in range(1, star + 1):
            r = self.exact_rho(tau)
            if r >= 1.0 + MARGIN:
                return star, tau, r
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"a": self.a, "P": [list(r) for r in self.P], "c": list(self.c),
                "k": list(self.k)}


@dataclass
class SearchResult:
    """What :func:`search_theorem1` found.

    Attributes
    ----------
    tried : int
        Instances satisfying the hypotheses with ``tau* >= 1``.
    hits : int
        Among them, those with a ``tau <= tau*`` of exact rho ``>= 1 + MARGIN``.
    elapsed : float
        Seconds spent (search and shrinking).
    instance : ScalarInstance or None
        The shrunk counterexample.
    tau, tau_star : int or None
        Its delay and Theorem 1's tau*.
    exact_rho, rho_delay_free, bound_eq26 : float or None
        Its exact augmented rho at ``tau``, ``rho(A-hat)`` and the eq. (26) value at tau.
    first : dict or None
        The first hit before shrinking.
    """

    tried: int
    hits: int
    elapsed: float
    instance: ScalarInstance | None = None
    tau: int | None = None
    tau_star: int | None = None
    exact_rho: float | None = None
    rho_delay_free: float | None = None
    bound_eq26: float | None = None
    first: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"tried": self.tried, "hits": self.hits, "elapsed_s": round(self.elapsed, 3),
                "instance": None if self.instance is None else self.instance.to_dict(),
                "tau": self.tau, "tau_star": self.tau_star, "exact_rho": self.exact_rho,
                "rho_delay_free": self.rho_delay_free, "bound_eq26": self.bound_eq26,
                "first": self.first}


def _random_instance(rng: np.random.Generator, a_max: float = 2.0,
                     k_range: tuple[float, float] = (-1.0, 2.0),
                     a_edge: float = 0.0) -> ScalarInstance:
    """A random scalar instance: N in 2..4 agents on a directed cycle plus random links
    (self-loops on), random row-stochastic weights, random sensors and gains
    ``k_i ~ U(k_range)``, ``a ~ U(-a_max, a_max)`` (or, with probability ``a_edge``,
    ``a = +-a_max``)."""
    N = int(rng.choice([2, 3, 4], p=[0.5, 0.3, 0.2]))
    adj = np.eye(N, dtype=bool)
    for i in range(N):
        adj[(i + 1) % N, i] = True  # a directed cycle: strongly connected
    adj |= rng.random((N, N)) < 0.3
    W = np.where(adj, rng.random((N, N)) + 0.05, 0.0)
    P = W / W.sum(axis=1, keepdims=True)
    c = rng.integers(0, 2, N).astype(float)
    if c.sum() == 0:
        c[int(rng.integers(N))] = 1.0
    k = np.where(c != 0, rng.uniform(k_range[0], k_range[1], N), 0.0)
    if a_edge and rng.random() < a_edge:
        a = float(rng.choice([-a_max, a_max]))
    else:
        a = float(rng.uniform(-a_max, a_max))
    return ScalarInstance(a, tuple(map(tuple, P.tolist())), tuple(c.tolist()),
                          tuple(k.tolist()))


def _with_P(inst: ScalarInstance, P: np.ndarray) -> ScalarInstance:
    P = P.copy()
    np.fill_diagonal(P, 0.0)
    P[np.diag_indices_from(P)] = np.round(1.0 - P.sum(axis=1), 12)
    return replace(inst, P=tuple(map(tuple, P.tolist())))


def _simpler(inst: ScalarInstance) -> list[ScalarInstance]:
    """Candidate simplifications of ``inst``, simplest first."""
    out = []
    P = np.array(inst.P)
    N = inst.N
    for i in range(N):  # drop a link that is not on the cycle
        for j in range(N):
            if i != j and P[i, j] != 0 and i != (j + 1) % N:
                Q = P.copy()
                Q[i, j] = 0.0
                out.append(_with_P(inst, Q))
    for digits in (0, 1, 2):
        def r(x: float, d: int = digits) -> float:
            return float(round(x, d))
        if r(inst.a) != inst.a:
            out.append(replace(inst, a=r(inst.a)))
        for i in range(N):
            if r(inst.k[i]) != inst.k[i]:
                k = list(inst.k)
                k[i] = r(k[i])
                out.append(replace(inst, k=tuple(k)))
            for j in range(N):
                if i != j and P[i, j] != 0 and r(P[i, j]) != P[i, j] and r(P[i, j]) > 0:
                    Q = P.copy()
                    Q[i, j] = r(P[i, j])
                    out.append(_with_P(inst, Q))
    return out


@dataclass
class Found:
    """What :func:`random_search` found (any claim).

    Attributes
    ----------
    claim : str
        The claim searched.
    tried : int
        Instances drawn that satisfy the claim's hypotheses.
    hits : int
        Among them, counterexamples.
    elapsed : float
        Seconds spent (search and shrinking).
    instance : object or None
        The shrunk counterexample (None: none found).
    details : dict or None
        The judge's numbers on ``instance``.
    first : dict or None
        The judge's numbers on the first hit before shrinking.
    confirmed : dict or None
        What the simulation of ``instance`` showed (filled in by the caller).
    """

    claim: str
    tried: int
    hits: int
    elapsed: float
    instance: Any = None
    details: dict[str, Any] | None = None
    first: dict[str, Any] | None = None
    confirmed: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        inst = self.instance
        return {"claim": self.claim, "tried": self.tried, "hits": self.hits,
                "elapsed_s": round(self.elapsed, 3),
                "instance": inst.to_dict() if hasattr(inst, "to_dict") else inst,
                "details": self.details, "first": self.first, "confirmed": self.confirmed}


def shrink(instance: Any, judge: Callable[[Any], dict[str, Any] | None],
           simpler: Callable[[Any], list[Any]], deadline: float) -> Any:
    """Greedy shrinking: replace ``instance`` by its first simpler candidate that is still
    a counterexample (``judge`` not None), until none is or ``deadline`` passes."""
    improved = True
    while improved and time.monotonic() < deadline:
        improved = False
        for cand in simpler(instance):
            if time.monotonic() >= deadline:
                break
            if judge(cand) is not None:
                instance = cand
                improved = True
                break
    return instance


def random_search(claim: str, draw: Callable[[np.random.Generator], Any | None],
                  judge: Callable[[Any], dict[str, Any] | None],
                  simpler: Callable[[Any], list[Any]] | None = None, *, seed: int = 0,
                  budget: float = 10.0, max_instances: int = 400,
                  stop_at_hit: bool = False,
                  progress: Callable[[float], None] | None = None) -> Found:
    """Seeded random search for a counterexample, then shrinking of the first hit.

    Parameters
    ----------
    claim : str
        The claim's id (recorded in the result).
    draw : callable(numpy.random.Generator) -> instance or None
        A random instance satisfying the claim's hypotheses (None: the draw did not,
        and does not count).
    judge : callable(instance) -> dict or None
        The deciding numbers if the instance contradicts the claim, else None.
    simpler : callable(instance) -> list, optional
        Simpler candidates of an instance, simplest first (for :func:`shrink`).
    seed : int
        Seed of the generator (``numpy.random.default_rng(seed)``).
    budget : float
        Seconds for search and shrinking; a quarter (at least 1 s) is kept for
        shrinking once there is a hit.
    max_instances : int
        Stop after this many instances satisfying the hypotheses.
    stop_at_hit : bool
        Stop drawing at the first hit.
    progress : callable(float), optional
        Called with the fraction of the budget used.

    Returns
    -------
    Found
    """
    start = time.monotonic()
    end = start + budget
    rng = np.random.default_rng(seed)
    tried = hits = 0
    first: Any = None
    first_details: dict[str, Any] | None = None
    reserve = max(1.0, budget / 4)
    while tried < max_instances and time.monotonic() < end - (0 if first is not None
                                                              else reserve):
        inst = draw(rng)
        if inst is None:
            continue
        tried += 1
        d = judge(inst)
        if d is not None:
            hits += 1
            if first is None:
                first, first_details = inst, d
                if stop_at_hit:
                    break
        if progress is not None:
            progress(min(1.0, (time.monotonic() - start) / budget))
    found = Found(claim, tried, hits, 0.0)
    if first is not None:
        found.first = {**(first.to_dict() if hasattr(first, "to_dict") else {}),
                       **(first_details or {})}
        small = first if simpler is None else shrink(first, judge, simpler,
                                                     max(end, time.monotonic() + 1.0))
        found.instance, found.details = small, judge(small)
    found.elapsed = time.monotonic() - start
    if progress is not None:
        progress(1.0)
    return found



def _theorem1_draw(rng: np.random.Generator) -> ScalarInstance | None:
    inst = _random_instance(rng)
    if inst.hypotheses() is not None:
        return None
    star = inst.tau_star()
    return inst if star is not None and star >= 1 else None


def _theorem1_judge(inst: ScalarInstance) -> dict[str, Any] | None:
    v = inst.violation()
    return None if v is None else {"tau_star": v[0], "tau": v[1], "exact_rho": v[2]}


def search_theorem1(seed: int = 0, budget: float = 10.0, max_instances: int = 400,
                    progress: Callable[[float], None] | None = None) -> SearchResult:
    """Random search (seeded) for a counterexample to LCSYS2022 Theorem 1.

    Uses :func:`random_search` over :func:`_random_instance` draws that satisfy the
    hypotheses with ``tau* >= 1``, judged by :meth:`ScalarInstance.violation`.

    Parameters
    ----------
    seed : int
        Seed of the instance generator.
    budget : float
        Seconds for the whole search; a quarter of it (at least 1 s) is kept for
        shrinking the first hit.
    max_instances : int
        Stop after this many instances satisfying the hypotheses (with ``tau* >= 1``).
    progress : callable(float), optional
        Called with the fraction of the budget used.

    Returns
    -------
    SearchResult
    """
    found = random_search("L-theorem1", _theorem1_draw, _theorem1_judge, _simpler,
                          seed=seed, budget=budget, max_instances=max_instances,
                          progress=progress)
    result = SearchResult(tried=found.tried, hits=found.hits, elapsed=found.elapsed)
    if found.instance is not None:
        from netsim.models.augmented import delay_bound_lcsys

        shrunk, d = found.instance, found.details or {}
        result.first = found.first
        result.instance, result.tau, result.tau_star = shrunk, d["tau"], d["tau_star"]
        result.exact_rho = d["exact_rho"]
        result.rho_delay_free = shrunk.rho_delay_free()
        result.bound_eq26 = float(delay_bound_lcsys(*shrunk.matrices(), d["tau"]))
    return result


def _toml_list(v: Any) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_list(x) for x in v) + "]"
    return repr(float(v)) if not math.isnan(v) else "nan"


def scenario_toml(inst: ScalarInstance, tau: int, name: str, note: str) -> str:
    """A scenario file (TOML text) of ``inst`` with homogeneous delay ``tau`` and given K."""
    return "\n".join([
        f'name = "{name}"',
        f'description = """{note}"""',
        "",
        "[run]",
        "steps = 300",
        "trials = 4",
        "seed = 0",
        'estimators = ["compensated"]',
        "",
        "[plant]",
        f"A = [[{inst.a!r}]]",
        "C = " + _toml_list([[[c]] for c in inst.c]),
        "Q = 0.0001",
        "R = 0.0001",
        "",
        "[network]",
        "P = " + _toml_list([list(r) for r in inst.P]),
        "",
        "[delays]",
        'model = "homogeneous"',
        f"tau = {int(tau)}",
        "",
        "[gains]",
        'method = "given"',
        "K = " + _toml_list([[[k]] for k in inst.k]),
        "",
    ])


def write_scenario(inst: ScalarInstance, tau: int, folder: Path, name: str, note: str) -> Path:
    """Write :func:`scenario_toml` to ``folder/name.toml``; return the path."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_text(scenario_toml(inst, tau, name, note), encoding="utf-8")
    return path
