"""What the two consensus papers (LCSYS2022 and the delay-tolerant paper) share: our
instance of the LCSYS2022 system, the delay bounds on explicit matrices and the verdict of
a bound claim (the paper's bound against the exact rho on our instance, a scalar example
and a counted search). Private to :mod:`netsim.papers.lcsys2022` and
:mod:`netsim.papers.delay_tolerant`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from netsim.bench.cells import find_cell
from netsim.bench.claims import claim_row
from netsim.bench.fmt import fmt_value
from netsim.claims.checks import (
    BOUND_SLACK_FIXED,
    exact_rho,
    homogeneous_delays,
    lemma2_on,
    rounded,
    search_undecided,
    search_words,
    searched,
    unconfirmed,
)
from netsim.claims.core import NO_COUNTEREXAMPLE, PROVED, REFUTED, Context, Outcome
from netsim.claims.search import DEFAULT_INSTANCES, Found, hard_instance, random_instance
from netsim.claims.searches import BOUND_SLACK, DelayedInstance, scalar_search, with_delays
from netsim.models.augmented import (
    augmented_spectral_radius,
    delay_bound_lcsys,
    delay_bound_tolerant,
    tau_star_report,
)
from netsim.reproduce.items import fmt

__all__ = ["HETEROGENEOUS_EXAMPLE", "lcsys_instance", "bound_on", "bound_margin",
           "bound_judge", "delayed_draw", "search_bound", "heterogeneous_example",
           "bound_search", "bound_outcome", "check_lemma2_on",
           "homogeneous_delays", "exact_rho", "rho_row", "decay_row", "bench_common"]


#: The scalar heterogeneous example of :func:`netsim.models.augmented.delay_bound_lcsys`:
#: ``N = 2``, ``a = -1.5``, link 1 -> 0 delayed by one step, every other delay 0.
HETEROGENEOUS_EXAMPLE: dict[str, Any] = {
    "P": [[0.7, 0.3], [0.7, 0.3]], "A": [[-1.5]], "C": [[[1.0]], [[1.0]]],
    "L": [[[1.8]], [[-1.0]]], "delays": [[0, 1], [0, 0]]}


def lcsys_instance(context: Context) -> dict[str, Any]:
    """Our instance of the LCSYS2022 system with its block-diagonal LMI gains (cached)."""
    def make() -> dict[str, Any]:
        from netsim.api import load_scenario
        from netsim.runner import scenario_gains

        scenario = load_scenario("lcsys2022-homogeneous")
        gains = scenario_gains(scenario)
        P, A, C, L = scenario.weights, scenario.plant.A, scenario.plant.C, gains.L
        return {"scenario": scenario, "gains": gains, "P": P, "A": A, "C": C, "L": L,
                "star": tau_star_report(P, A, C, L, tau_max=30)}
    return context.cached("lcsys", make)


def bound_on(P: Any, A: Any, C: Any, L: Any, delays: Any, which: str) -> dict[str, float]:
    """Exact rho beside a paper's bound for one delay pattern.

    ``which``: ``"eq26"`` (LCSYS2022, compensated, eq. 9) or ``"tolerant"``
    (delay-tolerant Lemma 5, uncompensated eq. 11 matrix).
    """
    d = np.asarray(delays)
    tau = int(d[np.asarray(P) != 0].max()) if np.any(np.asarray(P) != 0) else 0
    comp = which == "eq26"
    exact = augmented_spectral_radius(P, A, C, L, d, tau, compensated=comp)
    bound = (delay_bound_lcsys(P, A, C, L, tau) if comp
             else delay_bound_tolerant(P, A, C, L, tau))
    return {"tau": tau, "exact": float(exact), "bound": float(bound)}


def bound_margin(x: DelayedInstance, compensated: bool
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


def bound_judge(x: DelayedInstance, compensated: bool) -> dict[str, Any] | None:
    """The judge of a bound search: :func:`bound_margin`'s numbers where the exact rho
    exceeds the bound by BOUND_SLACK or more, else None."""
    margin, numbers = bound_margin(x, compensated)
    return numbers if margin >= 0 else None


def delayed_draw(rng: np.random.Generator, compensated: bool, hard: bool = False,
                 **kw: Any) -> DelayedInstance | None:
    """A scalar instance (:func:`~netsim.claims.search.random_instance`, or of the hard
    family, ``hard_instance``, with ``kw``) with delays by
    :func:`~netsim.claims.searches.with_delays` (up to tau* when ``compensated``)."""
    inst = hard_instance(rng, **kw) if hard else random_instance(rng, **kw)
    return with_delays(inst, rng, compensated)


def search_bound(claim_id: str, compensated: bool, seed: Any = 0,
                 instances: int = DEFAULT_INSTANCES, deadline: float = math.inf) -> Found:
    """The counted search of a bound claim (LCSYS2022 eq. (26), ``compensated``, or the
    delay-tolerant Lemma 5): :func:`delayed_draw` instances judged by
    :func:`bound_judge`, the optimiser maximising :func:`bound_margin`."""
    return scalar_search(claim_id, seed, instances, deadline,
                         lambda rng: delayed_draw(rng, compensated),
                         lambda rng: delayed_draw(rng, compensated, hard=True),
                         lambda x: bound_judge(x, compensated),
                         lambda x: bound_margin(x, compensated)[0])


def heterogeneous_example() -> Any:
    """:data:`HETEROGENEOUS_EXAMPLE` as a scalar delayed instance (c_i = 1, so K_i = L_i)."""
    from netsim.claims.search import ScalarInstance
    from netsim.claims.searches import DelayedInstance

    ex = HETEROGENEOUS_EXAMPLE
    inst = ScalarInstance(float(ex["A"][0][0]), tuple(map(tuple, ex["P"])), (1.0, 1.0),
                          tuple(float(L[0][0]) for L in ex["L"]))
    return DelayedInstance(inst, tuple(map(tuple, ex["delays"])))


def bound_search(context: Context, claim_id: str, compensated: bool, label: str
                  ) -> tuple[Any, str | None, dict[str, Any], dict[str, Any] | None]:
    """The search of a bound claim: the search, the line of its verified counterexample
    (None: none), numbers and the counterexample (with both verifications and, when
    written, the scenario file)."""
    from netsim.claims.searches import verify_counterexample, write_delayed_scenario

    found = searched(context, claim_id)
    numbers: dict[str, Any] = {"search": found.to_dict()}
    if found.instance is None:
        return found, None, numbers, None
    x, d = found.instance, found.details
    check = verify_counterexample(x, compensated, d["exact_rho"], d["bound"], run=False)
    cx: dict[str, Any] = {**x.to_dict(), **d, "verification": check}
    numbers["verification"] = check
    if not check["confirmed"]:
        return found, None, numbers, cx
    if context.out is not None:
        path = write_delayed_scenario(
            x, context.out, f"{claim_id}-counterexample",
            f"Counterexample to {label} found by netsim claims (seed {context.seed}): "
            f"{'homogeneous' if x.homogeneous else 'heterogeneous fixed'} delays up to tau = "
            f"{x.tau}, exact augmented rho {d['exact_rho']:.4f} > bound {d['bound']:.4f}.",
            ("compensated",) if compensated else ("uncompensated",))
        cx["scenario"] = str(path)
    kind = "homogeneous" if x.homogeneous else "heterogeneous"
    what = (f"search counterexample (shrunk) a = {x.inst.a:g}, P = "
            f"{[list(r) for r in x.inst.P]}, c = {list(x.inst.c)}, K = {list(x.inst.k)}, "
            f"{kind} delays {[list(r) for r in x.delays]}: exact {d['exact_rho']:.4f} > "
            f"bound {d['bound']:.4f}, verified by the simulated error growth "
            f"{check['simulated_error_growth']:.4f}/step")
    return found, what, numbers, cx


def bound_outcome(context: Context, claim_id: str, compensated: bool, label: str,
                   ours: list[str], ours_ok: str, numbers: dict[str, Any]) -> Outcome:
    """The verdict of a bound claim from our instance's violations ``ours``, the
    heterogeneous example and the search."""
    from netsim.claims.searches import simulate_error_growth

    which = "eq26" if compensated else "tolerant"
    het = bound_on(**HETEROGENEOUS_EXAMPLE, which=which)
    numbers["heterogeneous_example"] = {k: rounded(v) for k, v in het.items()}
    cases = list(ours)
    if het["exact"] > het["bound"] + BOUND_SLACK_FIXED:
        sim = simulate_error_growth(heterogeneous_example(), compensated)
        numbers["heterogeneous_example"]["simulated_error_growth"] = rounded(sim)
        if sim > het["bound"] + BOUND_SLACK_FIXED:
            cases.append(f"scalar heterogeneous example (a = -1.5, link 1->0 delayed 1): "
                         f"exact {het['exact']:.4f} > bound {het['bound']:.4f} (simulated "
                         f"error growth {sim:.4f}/step)")
    found, line, snum, cx = bound_search(context, claim_id, compensated, label)
    numbers.update(snum)
    if line is not None or cases:
        text = "; ".join(([line] if line else []) + cases)
        return Outcome(REFUTED, f"exact rho above the {label} value: " + text
                       + (f" ({search_words(found)})" if line else ""), numbers,
                       cx if line else {"cases": cases,
                                        "heterogeneous_example": HETEROGENEOUS_EXAMPLE},
                       headline=f"exact rho above the {label} value: " + text)
    if cx is not None:
        return unconfirmed("search", cx["verification"], numbers, cx)
    if not found.complete:
        return search_undecided(found, "search", numbers, "; " + ours_ok)
    return Outcome(NO_COUNTEREXAMPLE, "search: none; " + ours_ok, numbers,
                   evidence=found.evidence())


def check_lemma2_on(context: Context, compensated: bool) -> Outcome:
    inst = lcsys_instance(context)
    star = inst["star"].contiguous or 0
    taus = range(star + 1) if compensated else range(11)
    rows = lemma2_on(inst["P"], inst["A"], inst["C"], inst["L"], taus, compensated)
    ratios = [v["ratio"] for v in rows.values() if v["ratio"] is not None]
    free = float(inst["gains"].rho)
    s = ", ".join(f"tau {t}: {v['time']} steps (rho {v['rho']:.4f})" for t, v in rows.items())
    numbers = {"rows": {str(t): {k: rounded(x) for k, x in v.items()} for t, v in rows.items()},
               "ratio_min": rounded(min(ratios)), "ratio_max": rounded(max(ratios)),
               "rho_delay_free": rounded(free)}
    eq = "(10)" if compensated else "(13)"
    if not ratios or len(ratios) < len(rows):
        return Outcome(REFUTED, f"{eq} does not converge at some tau: {s}", numbers)
    return Outcome(PROVED, f"time to reduce the noise-free error {eq} by 1e3 x (1 - exact rho) "
                   f"/ ln 1e3 stays in [{min(ratios):.2f}, {max(ratios):.2f}] over tau = "
                   f"{min(rows)}..{max(rows)} ({s}); in units of 1/(1 - rho(A-hat)) = "
                   f"{1 / (1 - free):.1f} the time grows with tau (our reading: Theta in the "
                   "exact rho of the delayed loop)"
                   + ("; (12) printed with rho(A) = 1.04 > 1 has no positive time, read as "
                      "rho(A-hat) it is the tau = 0 row" if compensated else ""), numbers)


def rho_row(data: dict[str, Any], paper: str, cid: str, printed: float) -> dict[str, Any]:
    """Bench row: the paper's printed rho(A-hat) beside ours (a number of its system)."""
    rho = (data["gains"] or {}).get("rho_delay_free")
    agrees = None if rho is None else abs(rho - printed) < 0.01
    return claim_row(cid, paper, f"LMI gains give rho(A-hat) = {printed:g}",
                     f"rho(A-hat) = {fmt_value(rho)} with our LMI design on our instance of "
                     "the unprinted A, C, P (a different system, not a contradiction of the "
                     "theory)", agrees, kind="instance")


def decay_row(data: dict[str, Any], cid: str, paper: str, family: str,
              settings: Sequence[str], limit: int | None, text: str) -> dict[str, Any]:
    """Bench row: ``family``'s decay factor per step grows with tau (stable cells up to
    ``limit``) in each of ``settings``."""
    parts, agrees, checked = [], True, False
    for setting in settings:
        series = []
        for tau in data["taus"]:
            if limit is not None and tau > limit:
                continue
            c = find_cell(data, setting, tau, family)
            if c is None or c["measured"]["verdict"] != "stable":
                continue
            f = c["measured"]["decay_factor"]
            if f is None or (isinstance(f, float) and math.isnan(f)):
                continue
            series.append((tau, f))
        if len(series) < 2:
            continue
        checked = True
        monotone = all(b[1] >= a[1] - 0.005 for a, b in zip(series, series[1:], strict=False))
        agrees = agrees and monotone
        parts.append(f"{setting}: decay factor per step " + ", ".join(
            f"tau {t}: {fmt_value(f)}" for t, f in series)
            + ("" if monotone else " (NOT monotone)"))
    return claim_row(cid, paper, text, "; ".join(parts) or "-", agrees if checked else None)


def bench_common(data: dict[str, Any], printed_rho: float, printed_tau_star: int
                 ) -> tuple[list[str], list[str]]:
    """The report lines of a delay benchmark on our instance: ours and how it differs
    from the paper's (its printed rho(A-hat) and tau*)."""
    scan = data.get("analysis") or {}
    g = data.get("gains") or {}
    ours = [f"Monte Carlo: {data['trials']} trials x {data['steps']} steps per curve "
            f"(vectorised engine), seed {data['seed']}, scenario "
            f"`{data['scenario']['name']}`.",
            f"Our gains: rho(A-hat) = {fmt(g.get('rho_delay_free'))}, tau* (Theorem 1) = "
            f"{scan.get('tau_star')}."]
    differs = [f"Our instance has rho(A-hat) = {fmt(g.get('rho_delay_free'))} (paper "
               f"{printed_rho:g}) and tau* = {scan.get('tau_star')} (paper "
               f"{printed_tau_star}): the LMI gains of the paper "
               "cannot be reproduced without its matrices."]
    return ours, differs
