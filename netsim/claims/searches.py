"""Scalar delayed instances, their simulation and verification, and the search dispatch.

The papers' counterexample searches are declared by the paper modules
(:class:`netsim.papers.Search`, ``Paper.searches``); :func:`searches` collects them and
:func:`run_search` runs one by name (a top-level function, so that ``netsim claims`` can
run the searches in worker processes), or a job ``PREFIX:ARGUMENT`` (``bench:PRESET``,
:func:`bench_report`, or a paper's ``Paper.jobs``). Each search draws a counted number
of seeded random instances that satisfy a claim's hypotheses (draws outside them are not
counted), for the scalar stability claims also a family known to be hard (N = 2,
self-loops undelayed, a = +-1) and an optimiser over the hypothesis set
(:func:`scalar_search`); it judges them by exact analytics, shrinks the first hit with
:func:`netsim.claims.search.shrink` and the checks verify it by simulation
(:func:`verify_counterexample`). The engine is :func:`netsim.claims.search.counted_search`.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from netsim.claims.search import (
    DEFAULT_INSTANCES,
    HARD_FAMILY,
    OPTIMISER_FAMILY,
    RANDOM_FAMILY,
    Attack,
    Found,
    Phase,
    ScalarInstance,
    counted_search,
    decode_scalar,
    encode_scalar,
    simpler_scalar,
)
from netsim.models.augmented import augmented_spectral_radius

__all__ = ["DelayedInstance", "SEARCHES", "searches", "run_search", "bench_report",  # noqa: F822
           "BENCH_TRIALS", "simulate_error_growth", "clean_delays", "draw_delays",
           "simpler_delayed", "with_delays", "delayed_attack", "scalar_search",
           "delayed_scenario_toml", "write_delayed_scenario", "confirm_run",
           "verify_counterexample", "BOUND_SLACK", "SEARCH_TAU", "SLOW_SEARCH_SHARE"]

#: An exact rho counts as above a bound only if it exceeds it by at least this much
#: (so that a simulation shows the difference plainly).
BOUND_SLACK = 0.01
#: Largest tau drawn by the bound searches.
SEARCH_TAU = 6
#: Instances of the slower searches per :data:`DEFAULT_INSTANCES` (they cost more).
SLOW_SEARCH_SHARE = 0.75


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
        """Exact spectral radius of the augmented closed loop (with A^(r+1) compensation,
        or with A)."""
        return float(augmented_spectral_radius(*self.matrices(), self.tau,
                                               compensated=compensated))

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {**self.inst.to_dict(), "delays": [list(r) for r in self.delays],
                "tau": self.tau, "homogeneous": self.homogeneous}


def clean_delays(inst: ScalarInstance, delays: np.ndarray) -> DelayedInstance:
    """``inst`` with ``delays`` on its links (0 on self-loops and non-links)."""
    P = np.array(inst.P)
    d = np.where((P != 0) & ~np.eye(len(P), dtype=bool), delays, 0).astype(int)
    return DelayedInstance(inst, tuple(map(tuple, d.tolist())))


def draw_delays(rng: np.random.Generator, inst: ScalarInstance, tau: int) -> DelayedInstance:
    """Homogeneous tau (probability 1/2) or uniform 0..tau per link, the link with the
    largest draw set to tau (the bound is attained)."""
    P = np.array(inst.P)
    off = (P != 0) & ~np.eye(len(P), dtype=bool)
    if rng.random() < 0.5:
        return clean_delays(inst, np.where(off, tau, 0))
    d = np.where(off, rng.integers(0, tau + 1, P.shape), 0)
    idx = np.flatnonzero(off)
    d.flat[idx[int(np.argmax(d.flat[idx]))]] = tau
    return clean_delays(inst, d)


def simpler_delayed(x: DelayedInstance) -> list[DelayedInstance]:
    """Candidate simplifications of ``x`` (smaller tau, simpler instance, a link
    undelayed), simplest first."""
    d = np.array(x.delays)
    out = [clean_delays(c, d) for c in simpler_scalar(x.inst)]
    out = [c for c in out if c.tau >= 1]
    if x.tau > 1:
        out.insert(0, clean_delays(x.inst, np.minimum(d, x.tau - 1)))
    for i, j in zip(*np.nonzero(d), strict=True):
        e = d.copy()
        e[i, j] = 0
        if e.max() >= 1:
            out.append(clean_delays(x.inst, e))
    return out


def with_delays(inst: ScalarInstance, rng: np.random.Generator, up_to_tau_star: bool
                 ) -> DelayedInstance | None:
    """``inst`` with delays drawn by :func:`draw_delays` at a bound tau in
    ``1..SEARCH_TAU`` (and ``<= tau*`` when ``up_to_tau_star``); None if the instance
    breaks the hypotheses (observable, rho(A-hat) < 1; ``tau* >= 1``)."""
    if inst.hypotheses() is not None:
        return None
    top = SEARCH_TAU
    if up_to_tau_star:
        star = inst.tau_star()
        if star is None or star < 1:
            return None
        top = min(star, SEARCH_TAU)
    return draw_delays(rng, inst, int(rng.integers(1, top + 1)))


def delayed_attack(family: str, starts: int, evaluations: int,
                    start: Callable[[np.random.Generator], DelayedInstance | None],
                    score: Callable[[DelayedInstance], float]) -> Attack:
    """An :class:`Attack` on the scalar parameters of a delayed instance (delays fixed)."""
    def decode(t: DelayedInstance, v: np.ndarray) -> DelayedInstance | None:
        inst = decode_scalar(t.inst, v)
        return None if inst is None else DelayedInstance(inst, t.delays)
    return Attack(family, starts, evaluations, start, lambda x: encode_scalar(x.inst),
                  decode, score)


def scalar_search(claim: str, seed: Any, instances: int, deadline: float,
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
    attack = delayed_attack(OPTIMISER_FAMILY, 4, max(1, instances // 8), hard, score)
    return counted_search(claim, phases, judge, simpler_delayed, seed=seed, attack=attack,
                          deadline=deadline)


def simulate_error_growth(x: DelayedInstance, compensated: bool, steps: int = 600,
                          seed: int = 0) -> float:
    """Per-step growth of the noise-free error, simulated from the papers' recursions.

    A second implementation (not :mod:`netsim.models.augmented`): agent ``i``'s error
    obeys ``e_i,k = g_i (p_ii a e_i,k-1 + sum_j p_ij a^(d_ij+1) e_j,k-1-d_ij)``
    (the compensating estimator) or with ``a`` in place of ``a^(d_ij+1)`` (the
    uncompensated one, with a still state), ``g_i = 1 - k_i c_i^2``. Returns the
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


def searches() -> dict[str, Any]:
    """Every registered paper's searches by name (:class:`netsim.papers.Search`), in
    registry order (a search's index seeds its stream)."""
    from netsim.papers import papers

    return {s.name: s for p in papers() for s in p.searches}


def __getattr__(name: str) -> Any:
    if name == "SEARCHES":  # name -> search(seed, instances, deadline)
        return {n: s.run for n, s in searches().items()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: Trials of the bench runs behind the figure claims (``bench:PRESET``).
BENCH_TRIALS = 10


def bench_report(preset: str, seed: int) -> dict[str, Any]:
    """A small ``netsim bench delay-tolerance PRESET`` report: BENCH_TRIALS trials, the
    preset's steps, its focus family only (serial: it may run in a worker process)."""
    from netsim.bench.delay_tolerance import run_delay_tolerance
    from netsim.bench.presets import presets
    from netsim.models.scenario import resolve_scenario

    p = presets()[preset]
    return run_delay_tolerance(resolve_scenario(p.scenario), taus=p.taus, delays=p.delays,
                               trials=BENCH_TRIALS, steps=p.steps, seed=seed,
                               families=[p.focus], preset=p, executor="serial",
                               progress=False)


def run_search(claim_id: str, seed: int, budget: float | None = None,
               instances: int | None = None) -> Any:
    """Run the search named ``claim_id`` (with ``own_seed`` on ``seed`` itself, the
    others on their own stream ``SeedSequence(seed, spawn_key=(index,))``, index its
    place in :func:`searches`), over ``instances`` random instances (default
    :data:`DEFAULT_INSTANCES`), cut short after ``budget`` seconds if given.

    Also runs the claims' other long computations by name, so that they can share the
    worker processes: ``bench:PRESET`` (:func:`bench_report`) and a paper's jobs
    ``PREFIX:ARGUMENT`` (``Paper.jobs[PREFIX](ARGUMENT, seed)``).
    """
    import time

    if ":" in claim_id:
        prefix, argument = claim_id.split(":", 1)
        if prefix == "bench":
            return bench_report(argument, seed)
        from netsim.papers import papers

        jobs = {k: job for p in papers() for k, job in p.jobs.items()}
        return jobs[prefix](argument, seed)
    found = searches()
    count = DEFAULT_INSTANCES if instances is None else int(instances)
    deadline = math.inf if budget is None else time.monotonic() + float(budget)
    search = found[claim_id]
    if search.own_seed:
        return search.run(seed, count, deadline)
    ss = np.random.SeedSequence(seed, spawn_key=(list(found).index(claim_id),))
    return search.run(ss, count, deadline)
