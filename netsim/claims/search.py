"""Counted, seeded counterexample searches over scalar plants, and their engine.

The engine (:func:`counted_search`) searches instance families counted in instances drawn
from a seed, then an optimiser over the claim's hypothesis set (:class:`Attack`,
scipy.optimize Nelder-Mead from seeded starts, counted in evaluations), and shrinks the
first hit with a counted number of judge calls. The same seed gives the same result on
any machine at any load; a time budget can only cut a search short (``cut_short``).

The scalar instances (:class:`ScalarInstance`) are the consensus papers' own setting: a
row-stochastic ``P`` on a strongly connected, self-looped graph (self-loops undelayed), a
plant ``x_k = a x_{k-1}`` observed by the sensors with ``c_i != 0`` (``(P kron A, D_C)``
observable), gains ``K_i`` with ``rho(A-hat) < 1`` and one common delay ``tau`` on every
link (self-loops excluded); tau* is the largest tau with
``rho((I-KD_C)(P kron A^(tau+1))) < 1``. A judge is an exact computation (the spectral
radius of the augmented closed loop); a hit is shrunk greedily (fewer links, coarser
numbers, smaller ``tau``) while it stays a counterexample, then written as a scenario
file that ``netsim analyze FILE`` and ``netsim run FILE`` reproduce. The papers'
searches themselves are declared by the paper modules (:mod:`netsim.papers`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from netsim.claims.core import Evidence
from netsim.models.augmented import augmented_spectral_radius, spectral_radius, tau_star

__all__ = ["ScalarInstance", "Found", "Phase", "Attack", "counted_search", "random_search",
           "shrink", "encode_scalar", "decode_scalar",
           "scenario_toml", "write_scenario", "MARGIN", "TAU_MAX", "DEFAULT_INSTANCES",
           "MAX_DRAWS_PER_INSTANCE", "SHRINK_EVALUATIONS", "RANDOM_FAMILY", "HARD_FAMILY",
           "OPTIMISER_FAMILY", "random_instance", "hard_instance", "simpler_scalar"]

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
        """tau*: the largest tau with rho((I-KD_C)(P kron A^(tau+1))) < 1 (scanned to
        :data:`TAU_MAX`)."""
        return tau_star(*self.matrices(), tau_max=TAU_MAX)

    def exact_rho(self, tau: int) -> float:
        """Exact spectral radius of the compensated augmented closed loop at ``tau``."""
        return augmented_spectral_radius(*self.matrices(), self.delays(tau), tau,
                                         compensated=True)

    def hypotheses(self) -> str | None:
        """None if the hypotheses of the module docstring hold, else the first one that
        does not."""
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


def random_instance(rng: np.random.Generator, a_max: float = 2.0,
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


def simpler_scalar(inst: ScalarInstance) -> list[ScalarInstance]:
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


#: Random instances a search draws by default (``netsim claims --instances``).
DEFAULT_INSTANCES = 400
#: Draws a family may spend per counted instance before the search says that the family
#: rarely meets the hypotheses (the search is then ``exhausted``, not complete).
MAX_DRAWS_PER_INSTANCE = 50
#: Judge evaluations the shrinking of a hit may spend.
SHRINK_EVALUATIONS = 300


class _CutShort(Exception):
    """The search's time budget ran out (raised inside the optimiser's objective)."""


@dataclass(frozen=True)
class Phase:
    """One instance family of a counted search.

    Attributes
    ----------
    family : str
        The family in words (it names the evidence: "no counterexample in M instances
        of <family>").
    count : int
        Instances satisfying the hypotheses to draw.
    draw : callable(numpy.random.Generator) -> instance or None
        One random instance (None: the draw did not satisfy the hypotheses; not counted).
    """

    family: str
    count: int
    draw: Callable[[np.random.Generator], Any | None]


@dataclass(frozen=True)
class Attack:
    """Optimisation over a claim's hypothesis set (scipy.optimize, Nelder-Mead).

    From ``starts`` seeded start instances, maximise ``score`` (exact spectral radius
    minus one, or minus the claimed bound; > 0: a counterexample) over the continuous
    parameters of the instance, ``evaluations`` objective evaluations per start. Every
    evaluation whose instance satisfies the hypotheses counts as one instance searched.

    Attributes
    ----------
    family : str
        In words.
    starts, evaluations : int
    start : callable(numpy.random.Generator) -> instance or None
        A start instance (None: draw again).
    encode : callable(instance) -> numpy.ndarray
        Its free parameters.
    decode : callable(instance, numpy.ndarray) -> instance or None
        The instance of the start's structure with these parameters (None: none).
    score : callable(instance) -> float
        ``-inf`` where the hypotheses fail; > 0 exactly for a counterexample.
    """

    family: str
    starts: int
    evaluations: int
    start: Callable[[np.random.Generator], Any | None]
    encode: Callable[[Any], np.ndarray]
    decode: Callable[[Any, np.ndarray], Any | None]
    score: Callable[[Any], float]


@dataclass
class Found:
    """What a counted search (:func:`counted_search`) found, for any claim.

    Attributes
    ----------
    claim : str
        The claim searched.
    tried : int
        Instances searched that satisfy the claim's hypotheses (optimiser evaluations
        included).
    hits : int
        Among them, counterexamples.
    elapsed : float
        Seconds spent (reported, never deciding).
    instance : object or None
        The shrunk counterexample (None: none found).
    details : dict or None
        The judge's numbers on ``instance``.
    first : dict or None
        The judge's numbers on the first hit before shrinking.
    confirmed : dict or None
        What the simulation of ``instance`` showed (filled in by the caller).
    planned : int
        Instances the search was to search (the families' counts plus the optimiser's
        evaluations).
    cut_short : bool
        The time budget stopped the search before ``planned``.
    exhausted : list of str
        Families that rarely meet the hypotheses and gave up before their count.
    families : list of dict
        Per family: ``family``, ``planned``, ``tried``, ``hits``.
    seed : int or None
        The seed (entropy) the instances were drawn from.
    violations : dict
        Hits per violated statement, when the judge names them (``violated``).
    """

    claim: str
    tried: int
    hits: int
    elapsed: float
    instance: Any = None
    details: dict[str, Any] | None = None
    first: dict[str, Any] | None = None
    confirmed: dict[str, Any] | None = None
    planned: int = 0
    cut_short: bool = False
    exhausted: list[str] = field(default_factory=list)
    families: list[dict[str, Any]] = field(default_factory=list)
    seed: int | None = None
    violations: dict[str, int] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """Every family ran its count (the optimiser may converge before its evaluations
        are spent): neither cut short by the budget nor exhausted."""
        return not self.cut_short and not self.exhausted

    @property
    def family(self) -> str:
        """The families searched, in words."""
        return " + ".join(f["family"] for f in self.families) or "no family"

    def evidence(self) -> Evidence:
        """The search as the evidence of a ``no counterexample`` verdict."""
        return Evidence(self.tried, self.family, int(self.seed or 0))

    def incomplete_reason(self) -> str:
        """Why the search is not complete, in words ("" when it is)."""
        if self.cut_short:
            return (f"search cut short by its time budget: {self.tried} of {self.planned} "
                    "instances searched")
        if self.exhausted:
            return (f"{self.tried} of {self.planned} instances searched: "
                    + ", ".join(self.exhausted) + " rarely meet the hypotheses")
        return ""

    def count_words(self) -> str:
        """``h of M instances of <family> (seed s)``."""
        return f"{self.hits} of {self.tried} instances of {self.family} (seed {self.seed})"

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form (no seconds: the same seed gives the same dict)."""
        inst = self.instance
        return {"claim": self.claim, "tried": self.tried, "hits": self.hits,
                "planned": self.planned, "cut_short": self.cut_short,
                "exhausted": list(self.exhausted), "families": list(self.families),
                "seed": self.seed, "violations": dict(self.violations),
                "instance": inst.to_dict() if hasattr(inst, "to_dict") else inst,
                "details": self.details, "first": self.first, "confirmed": self.confirmed}


def shrink(instance: Any, judge: Callable[[Any], dict[str, Any] | None],
           simpler: Callable[[Any], list[Any]],
           max_evaluations: int = SHRINK_EVALUATIONS) -> Any:
    """Greedy shrinking: replace ``instance`` by its first simpler candidate that is still
    a counterexample (``judge`` not None), until none is or ``max_evaluations`` judge
    calls are spent (a count, so the result does not depend on the machine)."""
    improved, spent = True, 0
    while improved and spent < max_evaluations:
        improved = False
        for cand in simpler(instance):
            if spent >= max_evaluations:
                break
            spent += 1
            if judge(cand) is not None:
                instance = cand
                improved = True
                break
    return instance


def _entropy(seed: Any) -> tuple[np.random.SeedSequence, int]:
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    ent = ss.entropy if isinstance(ss.entropy, int) else 0
    return ss, int(ent)


def counted_search(claim: str, phases: list[Phase],
                   judge: Callable[[Any], dict[str, Any] | None],
                   simpler: Callable[[Any], list[Any]] | None = None, *,
                   seed: Any = 0, attack: Attack | None = None,
                   deadline: float = math.inf,
                   progress: Callable[[float], None] | None = None) -> Found:
    """Search for a counterexample over counted instances from a seed, then shrink the
    first hit.

    The families of ``phases`` are searched in order, each from its own stream
    (``SeedSequence(seed).spawn``), then the optimiser ``attack``. The first hit (in that
    order) is shrunk (:func:`shrink`, a counted number of judge calls). Nothing depends on
    the clock except ``deadline``: past it the search stops (``cut_short``), which a
    verdict must report as ``undecided`` unless a hit was found already.

    Parameters
    ----------
    claim : str
        The claim's id (recorded in the result).
    phases : list of Phase
        The instance families and their counts.
    judge : callable(instance) -> dict or None
        The deciding numbers if the instance contradicts the claim, else None.
    simpler : callable(instance) -> list, optional
        Simpler candidates of an instance, simplest first.
    seed : int or numpy.random.SeedSequence
    attack : Attack, optional
        The optimiser's attack on the hypothesis set.
    deadline : float
        ``time.monotonic()`` past which the search is cut short (default: never).
    progress : callable(float), optional
        Called with the fraction of the planned instances searched.

    Returns
    -------
    Found
    """
    start = time.monotonic()
    ss, entropy = _entropy(seed)
    streams = ss.spawn(len(phases) + 1)
    planned = sum(p.count for p in phases) + (attack.starts * attack.evaluations
                                              if attack is not None else 0)
    found = Found(claim, 0, 0, 0.0, planned=planned, seed=entropy)
    hit: list[Any] = []  # [instance, details] of the first hit

    def record(inst: Any, d: dict[str, Any] | None, row: dict[str, Any]) -> None:
        found.tried += 1
        row["tried"] += 1
        if d is not None:
            found.hits += 1
            row["hits"] += 1
            for v in d.get("violated", ()) or ():
                found.violations[v] = found.violations.get(v, 0) + 1
            if not hit:
                hit.extend([inst, d])
        if progress is not None and planned:
            progress(min(1.0, found.tried / planned))

    for phase, stream in zip(phases, streams, strict=False):
        row: dict[str, Any] = {"family": phase.family, "planned": phase.count, "tried": 0,
                               "hits": 0}
        found.families.append(row)
        rng = np.random.default_rng(stream)
        draws = 0
        while row["tried"] < phase.count:
            if time.monotonic() > deadline:
                found.cut_short = True
                break
            if draws >= MAX_DRAWS_PER_INSTANCE * max(phase.count, 1):
                found.exhausted.append(phase.family)
                break
            draws += 1
            inst = phase.draw(rng)
            if inst is None:
                continue
            record(inst, judge(inst), row)
        if found.cut_short:
            break
    if attack is not None and not found.cut_short:
        _run_attack(attack, streams[-1], judge, record, found, deadline)
    if hit:
        first, first_details = hit
        found.first = {**(first.to_dict() if hasattr(first, "to_dict") else {}),
                       **(first_details or {})}
        small = first if simpler is None else shrink(first, judge, simpler)
        found.instance, found.details = small, judge(small)
    found.elapsed = time.monotonic() - start
    if progress is not None:
        progress(1.0)
    return found


def _run_attack(attack: Attack, stream: np.random.SeedSequence,
                judge: Callable[[Any], dict[str, Any] | None],
                record: Callable[[Any, dict[str, Any] | None, dict[str, Any]], None],
                found: Found, deadline: float) -> None:
    """Nelder-Mead from ``attack.starts`` seeded starts, ``attack.evaluations`` each."""
    from scipy.optimize import minimize

    row = {"family": attack.family, "planned": attack.starts * attack.evaluations,
           "tried": 0, "hits": 0}
    found.families.append(row)
    rng = np.random.default_rng(stream)
    for _ in range(attack.starts):
        template = None
        for _draw in range(MAX_DRAWS_PER_INSTANCE):
            template = attack.start(rng)
            if template is not None:
                break
        if template is None:
            found.exhausted.append(attack.family)
            return
        spent = [0]

        def objective(v: np.ndarray, template: Any = template, spent: list[int] = spent
                      ) -> float:
            if time.monotonic() > deadline:
                raise _CutShort
            spent[0] += 1
            inst = attack.decode(template, v)
            value = -math.inf if inst is None else attack.score(inst)
            if math.isfinite(value):
                record(inst, judge(inst) if value > 0 else None, row)
                return -value
            return 1e6  # outside the hypotheses: a wall
        x0 = attack.encode(template)
        try:
            minimize(objective, x0, method="Nelder-Mead",
                     options={"maxfev": attack.evaluations, "xatol": 1e-9, "fatol": 1e-12,
                              "initial_simplex": x0 + np.vstack(
                                  [np.zeros(len(x0)), 0.3 * np.eye(len(x0))])})
        except _CutShort:
            found.cut_short = True
            return


def random_search(claim: str, draw: Callable[[np.random.Generator], Any | None],
                  judge: Callable[[Any], dict[str, Any] | None],
                  simpler: Callable[[Any], list[Any]] | None = None, *, seed: Any = 0,
                  instances: int = DEFAULT_INSTANCES, family: str = "random instances",
                  deadline: float = math.inf,
                  progress: Callable[[float], None] | None = None) -> Found:
    """:func:`counted_search` over one family: ``instances`` draws of ``draw``."""
    return counted_search(claim, [Phase(family, instances, draw)], judge, simpler,
                          seed=seed, deadline=deadline, progress=progress)


# -- the scalar families ----------------------------------------------------------------

#: The families of the scalar searches, in words.
RANDOM_FAMILY = "random scalar plants, N 2..4, a ~ U(-2, 2)"
HARD_FAMILY = "scalar N = 2, self-loops undelayed, a = +-1 or +-U(1, 2)"
OPTIMISER_FAMILY = "Nelder-Mead on (a, K, P)"


def hard_instance(rng: np.random.Generator, a_max: float = 2.0,
                   k_range: tuple[float, float] = (-1.0, 2.0)) -> ScalarInstance:
    """A member of the family known to be hard: N = 2 with both links (self-loops
    undelayed), one or two sensors, a = +-1 (half of the draws) or +-U(1, a_max)."""
    w = rng.uniform(0.05, 0.95, 2)
    P = np.array([[1 - w[0], w[0]], [w[1], 1 - w[1]]])
    c = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]][int(rng.integers(3))])
    k = np.where(c != 0, rng.uniform(k_range[0], k_range[1], 2), 0.0)
    sign = float(rng.choice([-1.0, 1.0]))
    a = sign * (1.0 if rng.random() < 0.5 or a_max <= 1 else float(rng.uniform(1.0, a_max)))
    return ScalarInstance(a, tuple(map(tuple, P.tolist())), tuple(c.tolist()),
                          tuple(k.tolist()))


def _links(inst: ScalarInstance) -> list[tuple[int, int]]:
    P = np.array(inst.P)
    return [(i, j) for i in range(inst.N) for j in range(inst.N) if i != j and P[i, j] != 0]


def encode_scalar(inst: ScalarInstance) -> np.ndarray:
    """The free parameters of a scalar instance: ``a``, the gains of the sensing agents
    and the log-ratio ``log(p_ij / p_ii)`` of each link."""
    P = np.array(inst.P)
    ks = [k for k, c in zip(inst.k, inst.c, strict=True) if c != 0]
    ratios = [math.log(P[i, j] / P[i, i]) for i, j in _links(inst)]
    return np.array([inst.a, *ks, *ratios], dtype=float)


def decode_scalar(template: ScalarInstance, v: np.ndarray) -> ScalarInstance | None:
    """The instance of ``template``'s graph and sensors with parameters ``v``
    (:func:`encode_scalar`), rounded to 12 digits; None if not finite."""
    if not np.all(np.isfinite(v)) or np.any(np.abs(v) > 50):
        return None
    N = template.N
    sensing = [i for i in range(N) if template.c[i] != 0]
    k = list(template.k)
    for n, i in enumerate(sensing):
        k[i] = float(v[1 + n])
    W = np.eye(N)
    for (i, j), r in zip(_links(template), v[1 + len(sensing):], strict=True):
        W[i, j] = math.exp(float(r))
    P = np.round(W / W.sum(axis=1, keepdims=True), 12)
    P[np.diag_indices(N)] = 0.0
    P[np.diag_indices(N)] = 1.0 - P.sum(axis=1)
    return ScalarInstance(float(round(v[0], 12)), tuple(map(tuple, P.tolist())),
                          template.c, tuple(round(x, 12) for x in k))


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
    from netsim.outfiles import write_text_safely

    return write_text_safely(folder / f"{name}.toml", scenario_toml(inst, tau, name, note),
                             "--out")


# The names other modules imported before the paper modules split (kept for them).
_random_instance = random_instance
_hard_instance = hard_instance
_simpler = simpler_scalar
