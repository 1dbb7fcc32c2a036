"""Scenario analytics: the papers' bounds next to exact spectral radii.

For a scenario and its gains this module reports (LCSYS2022 and the delay-tolerant
paper): rho(A-hat) delay-free; Theorem 1's tau* (the largest tau with every smaller
tau passing, and any isolated passing values above it, since rho((I-KD)(P kron
A^(tau+1))) need not be monotone in tau); for homogeneous delays tau = 0..tau_max the
exact spectral radius of the augmented closed loop, compensated (LCSYS2022 eq. 9-10)
and uncompensated (delay-tolerant eq. 11), beside the bounds of LCSYS2022 eq. (26) and
the delay-tolerant paper's rho(A-hat)^(1/(tau+1)), each with a verdict; the exact value
for the scenario's own fixed delay realisation; and the convergence-time orders.

Verdicts: ``respected`` (exact <= bound), ``conservative`` (respected, but the bound is
>= 1 while the exact value is < 1: the bound fails to predict a stability that holds),
``violated`` (exact > bound + BOUND_SLACK: printed as violated with both numbers) --
"bound violated" means only this, here and in ``netsim bench``. A prediction (Theorem 1:
stable for tau <= tau*) that the exact rho contradicts is listed apart, as ``prediction
contradicted`` (``AnalysisReport.contradictions``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from netsim.estimators.gains import GainDesign
from netsim.models.augmented import (
    AUGMENTED_DENSE_SIZE_THRESHOLD,
    augmented_radius_and_method,
    augmented_spectral_radius,
    delay_bound_lcsys,
    tau_star_report,
)
from netsim.models.jsonsafe import json_tree as _jsonable
from netsim.models.scenario import Scenario
from netsim.parallel import ordered_map
from netsim.threads import single_threaded_blas

__all__ = ["BOUND_SLACK", "DEFAULT_TAU_RANGE", "DENSE_SECONDS_PER_CUBE",
           "STRUCTURED_SECONDS_PER_CALL", "STRUCTURED_SECONDS_PER_ROW", "BoundRow",
           "ANALYSIS_PARALLEL_MIN_SECONDS",
           "AnalysisReport", "analysis_seconds", "analyze", "radii_line"]

#: Numerical slack before an exact value above a bound counts as a violation.
BOUND_SLACK = 1e-9
#: Homogeneous delays analysed by default: tau = 0..30.
DEFAULT_TAU_RANGE = 30


def _verdict(exact: float, bound: float) -> str:
    if exact > bound + BOUND_SLACK:
        return "violated"
    if bound >= 1.0 > exact:
        return "conservative"  # respected, but the bound does not predict stability
    return "respected"


def _order(rho: float) -> float:
    """Convergence-time order 1/(1 - rho) (LCSYS2022 Lemma 2); inf if rho >= 1."""
    return math.inf if rho >= 1 else 1.0 / (1.0 - rho)


@dataclass(frozen=True)
class BoundRow:
    """Homogeneous delay tau on every link: exact values and bounds.

    Attributes
    ----------
    tau : int
    rho_compensated : float
        Exact rho of the augmented closed loop, LCSYS2022 eq. (9)-(10).
    bound_eq26 : float
        rho((I - K D)(P kron A^(tau+1)))^(1/(tau+1)), LCSYS2022 eq. (26).
    verdict_eq26 : str
    theorem1_predicts_stable : bool
        tau <= tau* (contiguous) or tau is an isolated passing value.
    rho_uncompensated : float
        Exact rho of the delay-tolerant paper's eq. (11) closed loop.
    bound_tolerant : float
        rho(A-hat)^(1/(tau+1)), delay-tolerant paper Theorem 1 / Lemma 5.
    verdict_tolerant : str
    decay_rate_eq14 : float
        1 - bound_eq26 (LCSYS2022 eq. 14; negative: no decay predicted).
    source_compensated, source_uncompensated : str
        How the exact value was computed (one of
        :data:`netsim.models.augmented.RADIUS_METHODS`), or ``"cache (<method>)"``
        when it was read from the radius cache (:mod:`netsim.radiuscache`).
    """

    tau: int
    rho_compensated: float
    bound_eq26: float
    verdict_eq26: str
    theorem1_predicts_stable: bool
    rho_uncompensated: float
    bound_tolerant: float
    verdict_tolerant: str
    decay_rate_eq14: float
    source_compensated: str = ""
    source_uncompensated: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {k: _jsonable(v) for k, v in self.__dict__.items()}


@dataclass
class AnalysisReport:
    """Everything :func:`analyze` computed."""

    scenario: str
    rho_delay_free: float
    tau_star: int | None
    tau_star_isolated: tuple[int, ...]
    tau_star_values: tuple[float, ...]
    convergence_order_delay_free: float
    rows: list[BoundRow] = field(default_factory=list)
    realised: dict[str, Any] | None = None
    violations: list[str] = field(default_factory=list)
    #: Predictions (Theorem 1's "stable for tau <= tau*") that the exact rho contradicts.
    contradictions: list[str] = field(default_factory=list)
    #: How the exact radii were obtained: ``{"computed": {method: count}, "cached":
    #: {method: count}, "cache": folder or None}`` (:func:`radii_line` says it in a line).
    radii: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        """One line (the rows are in ``rows``, ``to_dict()`` or ``_repr_html_``)."""
        taus = f"tau {self.rows[0].tau}..{self.rows[-1].tau}" if self.rows else "no tau"
        return (f"<AnalysisReport {self.scenario}: rho delay-free "
                f"{self.rho_delay_free:.6g}, tau* {self.tau_star}, {taus}, "
                f"{len(self.violations)} violation(s), "
                f"{len(self.contradictions)} contradiction(s)>")

    def _repr_html_(self) -> str:
        """The homogeneous-delay rows as an HTML table (Jupyter), every value escaped."""
        import html

        heads = ("tau", "rho compensated", "eq. (26) bound", "verdict", "Theorem 1 stable",
                 "rho uncompensated", "tolerant bound", "verdict")
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in (
                r.tau, f"{r.rho_compensated:.6g}", f"{r.bound_eq26:.6g}", r.verdict_eq26,
                r.theorem1_predicts_stable, f"{r.rho_uncompensated:.6g}",
                f"{r.bound_tolerant:.6g}", r.verdict_tolerant)) + "</tr>"
            for r in self.rows)
        head = "".join(f"<th>{html.escape(h)}</th>" for h in heads)
        return (f"<div><p>{html.escape(repr(self))}</p><table><thead><tr>{head}</tr>"
                f"</thead><tbody>{body}</tbody></table></div>")

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "rho_delay_free": _jsonable(self.rho_delay_free),
            "tau_star": self.tau_star,
            "tau_star_isolated": list(self.tau_star_isolated),
            "tau_star_values": [_jsonable(v) for v in self.tau_star_values],
            "convergence_order_delay_free": _jsonable(self.convergence_order_delay_free),
            "homogeneous": [row.to_dict() for row in self.rows],
            "realised_delays": None if self.realised is None else {
                k: _jsonable(v) if not isinstance(v, dict) else v
                for k, v in self.realised.items()
            },
            "violations": self.violations,
            "contradictions": self.contradictions,
            "radii": self.radii,
        }


#: An exact radius and how it was computed (:func:`augmented_radius_and_method`).
_Radius = tuple[float, str]


def _exact_pair(task: tuple[Any, ...]) -> tuple[float, float, float]:
    """One delay pattern: (exact rho compensated, uncompensated, eq. (26) bound).

    ``task = (P, A, C, L, delays, depth)``; a module-level function so that
    :func:`netsim.parallel.ordered_map` can send it to a worker process.
    """
    P, A, C, L, delays, depth = task
    exact_c = augmented_spectral_radius(P, A, C, L, delays, depth, compensated=True)
    exact_u = augmented_spectral_radius(P, A, C, L, delays, depth, compensated=False)
    return exact_c, exact_u, float(delay_bound_lcsys(P, A, C, L, depth))


def _exact_task(task: tuple[Any, ...]) -> tuple[_Radius | None, _Radius | None, float]:
    """One delay pattern's radii not in the cache, and its eq. (26) bound.

    ``task = (P, A, C, L, delays, depth, flags)``, ``flags`` a pair for (compensated,
    uncompensated): the flag where that radius is to be computed, None where the cache
    has it. Returns ``((rho, method) or None, (rho, method) or None, bound)``, the same
    numbers as :func:`_exact_pair`; a module-level function so that
    :func:`netsim.parallel.ordered_map` can send it to a worker process.
    """
    P, A, C, L, delays, depth, flags = task
    c, u = (augmented_radius_and_method(P, A, C, L, delays, depth, compensated=flag)
            if flag is not None else None for flag in flags)
    return c, u, float(delay_bound_lcsys(P, A, C, L, depth))


def _radii_summary(sources: Sequence[tuple[str, str]], folder: Any) -> dict[str, Any]:
    """How the exact radii were obtained: counts by method, computed now or cached."""
    computed: dict[str, int] = {}
    cached: dict[str, int] = {}
    for pair in sources:
        for source in pair:
            if source.startswith("cache ("):
                how = source[len("cache ("):-1]
                cached[how] = cached.get(how, 0) + 1
            else:
                computed[source] = computed.get(source, 0) + 1
    return {"computed": computed, "cached": cached,
            "cache": None if folder is None else str(folder)}


def radii_line(radii: dict[str, Any]) -> str:
    """One line saying how the report's exact radii were obtained (``AnalysisReport.radii``)."""
    def counts(by: dict[str, int]) -> str:
        return ", ".join(f"{k} {v}" for k, v in sorted(by.items()))

    n_new, n_old = sum(radii["computed"].values()), sum(radii["cached"].values())
    where = ("radius cache off" if radii["cache"] is None
             else f"radius cache {radii['cache']}")
    parts = []
    if n_new:
        parts.append(f"{n_new} computed now ({counts(radii['computed'])})")
    if n_old:
        parts.append(f"{n_old} read from the cache (computed by {counts(radii['cached'])})")
    return f"exact radii: {'; '.join(parts) or 'none'} [{where}]"


#: Seconds per ``D^3`` of a dense eigenvalue call (``D`` rows), and per row of a
#: structured (ARPACK) call, plus a fixed cost per structured call; fitted (issue 34,
#: 2026-12-02) to the CPU time of one augmented radius on lcsys2022-homogeneous (N = 4,
#: n = 6: dense 3-10 ms at D = 72-120; structured, ARPACK on M^48 with 40 Krylov
#: vectors, 10-16 ms at D = 144-312 and 30-90 ms at D = 744) on the 2-core development
#: machine (single-threaded BLAS); only used to decide whether :func:`analyze` starts
#: worker processes.
DENSE_SECONDS_PER_CUBE = 2.5e-9
STRUCTURED_SECONDS_PER_ROW = 6.0e-5
STRUCTURED_SECONDS_PER_CALL = 0.008
#: ``analyze(workers=None)`` runs serially below this many estimated serial seconds
#: (:func:`analysis_seconds`). Measured on the 2-core machine, lcsys2022-homogeneous
#: (about 2 s of serial work): two workers took 3.2-3.4 s wall and 2.3-2.6 s CPU, the
#: serial run 2.8-2.9 s wall and 2.2-2.4 s CPU; the workers pay their start and the
#: transfer of every task and result, which this much work does not repay.
ANALYSIS_PARALLEL_MIN_SECONDS = 4.0


def analysis_seconds(n_agents: int, n: int, depths: Sequence[int]) -> float:
    """Estimated serial seconds of :func:`_exact_pair` over delay depths ``depths``.

    Two augmented spectral radii (dimension ``D = N n (depth + 1)``) per depth: dense
    (``D^3``) up to :data:`netsim.models.augmented.AUGMENTED_DENSE_SIZE_THRESHOLD`, structured
    (linear in ``D``) above. A rough model, used only to choose serial or parallel.
    """
    total = 0.0
    for depth in depths:
        D = n_agents * n * (int(depth) + 1)
        if D <= AUGMENTED_DENSE_SIZE_THRESHOLD:
            total += 2 * DENSE_SECONDS_PER_CUBE * float(D) ** 3
        else:
            total += 2 * (STRUCTURED_SECONDS_PER_CALL + STRUCTURED_SECONDS_PER_ROW * D)
    return total


@single_threaded_blas()
def analyze(
    scenario: Scenario, gains: GainDesign, tau_max: int = DEFAULT_TAU_RANGE, *,
    progress: Callable[[int], None] | None = None,
    workers: int | None = 1,
    cache: bool = True,
) -> AnalysisReport:
    """Compute the bounds and exact spectral radii of a scenario's closed loop.

    Parameters
    ----------
    scenario : Scenario
    gains : GainDesign
        Gains L_i (n x m_i each).
    tau_max : int
        Homogeneous delays 0..tau_max are analysed.
    progress : callable(int), optional
        Called with 1 after each tau (and once more for the scenario's own delays).
    workers : int or None, default 1
        Processes for the independent delay patterns (:func:`netsim.parallel.ordered_map`):
        1 runs them in this process; ``None`` chooses (the local cores, if the
        estimated serial work, :func:`analysis_seconds`, is at least
        :data:`ANALYSIS_PARALLEL_MIN_SECONDS` and
        :data:`netsim.parallel.PARALLEL_MIN_SECONDS`). The report is the same either way.
    cache : bool, default True
        Read the exact radii from the radius cache (:mod:`netsim.radiuscache`) and
        store those computed; False (or ``--no-cache``, ``NETSIM_CACHE_DIR=off``,
        ``NETSIM_RADIUS_CACHE=off``): compute every one. The numbers are the same bits
        either way; ``AnalysisReport.radii`` and the rows' ``source_*`` say which.

    Raises
    ------
    netsim.budget.ResourceError
        Before any eigenvalue is computed, if the estimated memory or time of the
        augmented closed loops (dimension N n (tau+1)) exceeds this machine's limits
        (:func:`netsim.budget.check_analysis`).

    Returns
    -------
    AnalysisReport
    """
    from netsim import budget, interrupt
    from netsim.runner import fixed_delay_matrix

    plant = scenario.plant
    P, A, C, L = scenario.weights, plant.A, plant.C, gains.L
    N = scenario.n_agents
    n = plant.n_states
    budget.check_analysis(n, N, range(tau_max + 1), "--tau-max",
                          f"the exact spectral radii for tau = 0..{tau_max} "
                          f"(dimension N n (tau+1) up to {N * n * (tau_max + 1)})", tau_max)
    fixed = fixed_delay_matrix(scenario)
    if fixed is not None:
        top = int(fixed.max())
        budget.check_analysis(n, N, [top], "the scenario's delays",
                              f"the exact spectral radius of its augmented closed loop "
                              f"(dimension N n (max + 1) = {N * n * (top + 1)})",
                              f"max {top} steps")
    rho0 = float(gains.rho)
    star = tau_star_report(P, A, C, L, tau_max=max(tau_max, 1))
    passing = set(range(0, (star.contiguous if star.contiguous is not None else -1) + 1))
    passing |= set(star.isolated)
    report = AnalysisReport(
        scenario=scenario.name,
        rho_delay_free=rho0,
        tau_star=star.contiguous,
        tau_star_isolated=tuple(star.isolated),
        tau_star_values=tuple(star.values),
        convergence_order_delay_free=_order(rho0),
    )
    edge_mask = (P > 0) & ~np.eye(N, dtype=bool)
    tasks: list[tuple[Any, ...]] = [
        (P, A, C, L, np.where(edge_mask, tau, 0), tau) for tau in range(tau_max + 1)
    ]
    # the scenario's own delays, unless they are one of the homogeneous patterns above
    # (then its row's radii are reused: the same matrices, the same numbers)
    same_as = None
    if fixed is not None:
        top_fixed = int(fixed.max())
        if top_fixed <= tau_max and np.array_equal(fixed, tasks[top_fixed][4]):
            same_as = top_fixed
        else:
            tasks.append((P, A, C, L, fixed, top_fixed))
    depths = [t[-1] for t in tasks]
    # the exact radii already in the radius cache (netsim.radiuscache) are not recomputed
    from netsim import radiuscache

    folder = radiuscache.radius_dir() if cache else None
    keys = ([(radiuscache.radius_key(P, A, C, L, t[4], t[5], True),
              radiuscache.radius_key(P, A, C, L, t[4], t[5], False))
             for t in tasks] if folder is not None else [])
    found = (radiuscache.load(folder, [k for pair in keys for k in pair])
             if folder is not None else {})
    flags = [tuple(flag if not keys or keys[i][j] not in found else None
                   for j, flag in enumerate((True, False))) for i in range(len(tasks))]
    todo = [i for i, f in enumerate(flags) if f != (None, None)]
    todo_depths = [depths[i] for i in todo]
    # each worker holds one augmented problem at a time: as many as fit in memory
    memory, _ = budget.analysis_cost(n, N, todo_depths or [0])
    fit = max(1, int(budget.memory_limit()[0] // max(memory, 1.0)))
    if todo and N * n * (max(todo_depths) + 1) > AUGMENTED_DENSE_SIZE_THRESHOLD:  # ARPACK:
        # load it here, before ordered_map may fork workers that would each import
        # it again (0.2-0.35 s of CPU apiece)
        import scipy.sparse.csgraph  # noqa: F401
        import scipy.sparse.linalg  # noqa: F401
    estimate = analysis_seconds(N, n, todo_depths)
    if workers is None and estimate < ANALYSIS_PARALLEL_MIN_SECONDS:
        workers = 1  # small: serial (the same report; ANALYSIS_PARALLEL_MIN_SECONDS)
    for _ in range(len(tasks) - len(todo)):
        if progress is not None:
            progress(1)  # a delay pattern whose radii are all in the cache
    computed = ordered_map(
        _exact_task, [(*tasks[i], flags[i]) for i in todo], estimated_seconds=estimate,
        workers=workers, max_workers=fit, progress=progress, check=interrupt.check,
    ) if todo else []
    by_task = dict(zip(todo, computed, strict=True))
    fresh: dict[str, tuple[float, str]] = {}
    results: list[tuple[float, float, float]] = []
    sources: list[tuple[str, str]] = []
    for i, task in enumerate(tasks):
        got = by_task.get(i)
        pair: list[float] = []
        source: list[str] = []
        for j in range(2):
            value = None if got is None else (got[0], got[1])[j]
            if value is None:  # from the cache
                rho, how = found[keys[i][j]]
                source.append(f"cache ({how})")
            else:
                rho, how = value
                source.append(how)
                if keys:
                    fresh[keys[i][j]] = (rho, how)
            pair.append(rho)
        b26 = got[2] if got is not None else float(delay_bound_lcsys(P, A, C, L, task[5]))
        results.append((pair[0], pair[1], b26))
        sources.append((source[0], source[1]))
    if folder is not None:
        radiuscache.store(folder, fresh)
    report.radii = _radii_summary(sources, folder)
    if same_as is not None:
        results = [*results, results[same_as]]
        sources = [*sources, sources[same_as]]
        if progress is not None:
            progress(1)  # the scenario's own delays: done with their homogeneous row
    for tau, (exact_c, exact_u, b26) in enumerate(results[: tau_max + 1]):
        btol = rho0 ** (1.0 / (tau + 1))
        row = BoundRow(
            tau=tau,
            rho_compensated=exact_c,
            bound_eq26=b26,
            verdict_eq26=_verdict(exact_c, b26),
            theorem1_predicts_stable=tau in passing,
            rho_uncompensated=exact_u,
            bound_tolerant=btol,
            verdict_tolerant=_verdict(exact_u, btol),
            decay_rate_eq14=1.0 - b26,
            source_compensated=sources[tau][0],
            source_uncompensated=sources[tau][1],
        )
        report.rows.append(row)
        if row.verdict_eq26 == "violated":
            report.violations.append(
                f"tau = {tau}: LCSYS2022 eq. (26) bound {b26:.6f} violated by the exact "
                f"rho {exact_c:.6f} (compensated, homogeneous delays)"
            )
        if row.verdict_tolerant == "violated":
            report.violations.append(
                f"tau = {tau}: delay-tolerant bound rho(A-hat)^(1/(tau+1)) = {btol:.6f} violated "
                f"by the exact rho {exact_u:.6f} of its eq. (11) closed loop"
            )
        if row.theorem1_predicts_stable and exact_c >= 1:
            report.contradictions.append(
                f"tau = {tau}: Theorem 1 predicts stability but the exact rho is {exact_c:.6f}"
            )
    delays = fixed
    if delays is not None:
        depth = int(delays.max())
        exact_c, exact_u, b26 = results[-1]
        btol = rho0 ** (1.0 / (depth + 1))
        report.realised = {
            "delays": {f"{j}->{i}": int(delays[i, j]) for j, i in scenario.links},
            "max_delay": depth,
            "rho_compensated": exact_c,
            "bound_eq26": b26,
            "verdict_eq26": _verdict(exact_c, b26),
            "rho_uncompensated": exact_u,
            "bound_tolerant": btol,
            "verdict_tolerant": _verdict(exact_u, btol),
            "source_compensated": sources[-1][0],
            "source_uncompensated": sources[-1][1],
        }
        if report.realised["verdict_eq26"] == "violated":
            report.violations.append(
                f"scenario delays (max {depth}): eq. (26) bound {b26:.6f} violated by the "
                f"exact rho {exact_c:.6f}"
            )
    return report
