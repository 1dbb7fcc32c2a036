"""The standalone checks of the registry (what ``netsim claims`` runs).

Each ``check_*`` takes a :class:`~netsim.claims.core.Context` and returns an
:class:`~netsim.claims.core.Outcome`. The instance-level helpers
(:func:`theorem1_on`, :func:`eq14_on`, :func:`bound_on`) take explicit matrices so that
the tests can put the same question to an independent computation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from netsim.claims.core import (
    NO_COUNTEREXAMPLE,
    PROVED,
    REFUTED,
    UNDECIDED,
    Context,
    Evidence,
    Outcome,
)
from netsim.models.augmented import (
    augmented_spectral_radius,
    delay_bound_lcsys,
    delay_bound_tolerant,
    tau_star_report,
)

__all__ = ["lcsys_instance", "homogeneous_delays", "theorem1_on", "eq14_on", "bound_on",
           "naive_growth", "HETEROGENEOUS_EXAMPLE", "searched", "confirm_run",
           "convergence_time", "lemma2_on",
           "lemma4_on", "kron_observable", "aoi_rate", "aoi_numbers_example"]

#: The scalar heterogeneous example of :func:`netsim.models.augmented.delay_bound_lcsys`:
#: ``N = 2``, ``a = -1.5``, link 1 -> 0 delayed by one step, every other delay 0.
HETEROGENEOUS_EXAMPLE: dict[str, Any] = {
    "P": [[0.7, 0.3], [0.7, 0.3]], "A": [[-1.5]], "C": [[[1.0]], [[1.0]]],
    "L": [[[1.8]], [[-1.0]]], "delays": [[0, 1], [0, 0]]}


def _r(x: float | None, digits: int = 4) -> float | None:
    return None if x is None else round(float(x), digits)


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


def homogeneous_delays(P: np.ndarray, tau: int) -> np.ndarray:
    """Delay ``tau`` on every link of ``P``, 0 on the self-loops (the papers' setting)."""
    P = np.asarray(P)
    return np.where((P != 0) & ~np.eye(P.shape[0], dtype=bool), tau, 0)


def _exact(P: Any, A: Any, C: Any, L: Any, tau: int, compensated: bool = True) -> float:
    return augmented_spectral_radius(P, A, C, L, homogeneous_delays(P, tau), tau,
                                     compensated=compensated)


def theorem1_on(P: Any, A: Any, C: Any, L: Any, tau_max: int = 30) -> dict[str, Any]:
    """Theorem 1 on one instance: exact rho at every homogeneous ``tau <= tau*``.

    Returns ``{"tau_star", "exact": {tau: rho}, "violations": [tau, ...]}``; a violation
    is a ``tau <= tau*`` with exact rho ``>= 1``.
    """
    star = tau_star_report(P, A, C, L, tau_max=tau_max).contiguous
    exact = {} if star is None else {t: _exact(P, A, C, L, t) for t in range(star + 1)}
    return {"tau_star": star, "exact": exact,
            "violations": [t for t, r in exact.items() if r >= 1.0]}


def eq14_on(P: Any, A: Any, C: Any, L: Any, taus: Sequence[int]) -> dict[str, Any]:
    """Eq. (14)'s "longer delays, slower decay": is the exact rho non-decreasing in tau?

    Returns ``{"exact": {tau: rho}, "decreases": [(tau1, tau2), ...]}``, consecutive
    pairs of ``taus`` where the exact rho decreases (beyond 1e-9).
    """
    exact = {int(t): _exact(P, A, C, L, int(t)) for t in taus}
    ts = sorted(exact)
    drops = [(a, b) for a, b in zip(ts, ts[1:], strict=False)
             if exact[b] < exact[a] - 1e-9]
    return {"exact": exact, "decreases": drops}


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


# -- LCSYS2022 -------------------------------------------------------------------------


def _search_undecided(found: Any, what: str, numbers: dict[str, Any],
                      tail: str = "") -> Outcome:
    """``undecided`` for a search that did not run all its instances and found nothing."""
    why = found.incomplete_reason()
    return Outcome(UNDECIDED, f"{what}: no counterexample, but {why}" + tail, numbers,
                   reason=why, headline=f"{what}: {why}" + tail)


def _unconfirmed(what: str, verification: dict[str, Any], numbers: dict[str, Any],
                 cx: dict[str, Any]) -> Outcome:
    """``undecided``: the exact analysis found a counterexample the simulation did not
    confirm."""
    why = ("the exact analysis finds a counterexample that the simulation does not "
           f"confirm (simulated error growth {verification['simulated_error_growth']:.4f}"
           + (f", netsim run: {_run_words(verification['netsim_run'])}"
              if verification.get("netsim_run") else "") + ")")
    return Outcome(UNDECIDED, f"{what}: {why}", numbers, cx, reason=why)


def check_theorem1(context: Context) -> Outcome:
    """LCSYS2022 Theorem 1: our instance, then the counted counterexample search."""
    from netsim.claims.search import write_scenario
    from netsim.claims.searches import DelayedInstance, verify_counterexample

    inst = lcsys_instance(context)
    ours = theorem1_on(inst["P"], inst["A"], inst["C"], inst["L"])
    numbers: dict[str, Any] = {
        "ours_tau_star": ours["tau_star"],
        "ours_max_exact_rho_up_to_tau_star": _r(max(ours["exact"].values())),
    }
    found = searched(context, "L-theorem1")
    numbers["search"] = {k: v for k, v in found.to_dict().items() if k != "first"}
    tail = (f"; on our LCSYS2022 instance it holds (max exact rho "
            f"{numbers['ours_max_exact_rho_up_to_tau_star']} up to tau* = "
            f"{ours['tau_star']})")
    if found.instance is not None:
        x, d = found.instance, found.details or {}
        delayed = DelayedInstance(x, tuple(map(tuple, x.delays(d["tau"]).tolist())))
        check = verify_counterexample(delayed, True, d["exact_rho"])
        cx: dict[str, Any] = {**x.to_dict(), "tau": d["tau"], "tau_star": d["tau_star"],
                              "exact_rho": d["exact_rho"],
                              "rho_delay_free": d["rho_delay_free"],
                              "theorem1_value": d["bound_eq26"], "verification": check}
        numbers["verification"] = check
        what = (f"counterexample a = {x.a:g}, N = {x.N}, P = {[list(r) for r in x.P]}, "
                f"c = {list(x.c)}, K = {list(x.k)}: rho(A-hat) = "
                f"{d['rho_delay_free']:.4f}, tau* = {d['tau_star']}, exact rho at tau = "
                f"{d['tau']} is {d['exact_rho']:.4f} > 1")
        if not check["confirmed"]:
            return _unconfirmed(what, check, numbers, cx)
        if context.out is not None:
            path = write_scenario(
                x, d["tau"], context.out, "L-theorem1-counterexample",
                f"Counterexample to LCSYS2022 Theorem 1 found by netsim claims (seed "
                f"{context.seed}): rho(A-hat) = {d['rho_delay_free']:.4f} < 1, tau* = "
                f"{d['tau_star']}, yet at homogeneous tau = {d['tau']} (self-loops "
                f"undelayed) the exact augmented rho is {d['exact_rho']:.4f} > 1.")
            cx["scenario"] = str(path)
        verified = (f"verified: exact rho {d['exact_rho']:.4f}; simulated error growth "
                    f"{check['simulated_error_growth']:.4f}/step; netsim run: "
                    f"{_run_words(check['netsim_run'])}")
        return Outcome(REFUTED, f"{what} ({found.count_words()}; shrunk; {verified})" + tail,
                       numbers, cx, headline=f"{what} ({verified})" + tail)
    if ours["violations"]:
        t = ours["violations"][0]
        return Outcome(REFUTED, f"our instance: exact rho {ours['exact'][t]:.4f} >= 1 at tau "
                       f"= {t} <= tau* = {ours['tau_star']}", numbers,
                       {"instance": "lcsys2022-homogeneous", "tau": t})
    ours_words = (f"; our instance: max exact rho "
                  f"{numbers['ours_max_exact_rho_up_to_tau_star']} up to tau* = "
                  f"{ours['tau_star']}")
    if not found.complete:
        return _search_undecided(found, "search", numbers, ours_words)
    return Outcome(NO_COUNTEREXAMPLE, "search: none" + ours_words, numbers,
                   evidence=found.evidence())


def searched(context: Context, claim_id: str) -> Any:
    """The result of ``claim_id``'s counterexample search (run now unless
    :func:`netsim.claims.run_claims` ran it already, in a worker)."""
    from netsim.claims.searches import run_search

    key = "search" if claim_id == "L-theorem1" else f"search:{claim_id}"
    return context.cached(key, lambda: run_search(claim_id, context.seed, context.budget,
                                                  context.instances))


def confirm_run(path: Any, family: str) -> dict[str, Any]:
    """``netsim run`` on a written counterexample (see :mod:`netsim.claims.searches`)."""
    from netsim.claims.searches import confirm_run as run_it

    return run_it(path, family)


def _g(v: Any) -> str:
    return "-" if v is None else f"{v:.3g}"


def _run_words(r: dict[str, Any]) -> str:
    growth = r.get("mse_growth")
    return (f"{r['verdict']} (measured {r['measured']}"
            + (f", MSE growth {growth:.4f}/step" if growth is not None else "")
            + f"), MSE {_g(r['mse_first'])} -> {_g(r['mse_last'])} over {r['steps']} steps")


def _search_words(found: Any) -> str:
    return f"{found.hits} of {found.tried} instances of {found.family} (seed {found.seed})"


def _heterogeneous_example() -> Any:
    """:data:`HETEROGENEOUS_EXAMPLE` as a scalar delayed instance (c_i = 1, so K_i = L_i)."""
    from netsim.claims.search import ScalarInstance
    from netsim.claims.searches import DelayedInstance

    ex = HETEROGENEOUS_EXAMPLE
    inst = ScalarInstance(float(ex["A"][0][0]), tuple(map(tuple, ex["P"])), (1.0, 1.0),
                          tuple(float(L[0][0]) for L in ex["L"]))
    return DelayedInstance(inst, tuple(map(tuple, ex["delays"])))


def _bound_search(context: Context, claim_id: str, compensated: bool, label: str
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


def _bound_outcome(context: Context, claim_id: str, compensated: bool, label: str,
                   ours: list[str], ours_ok: str, numbers: dict[str, Any]) -> Outcome:
    """The verdict of a bound claim from our instance's violations ``ours``, the
    heterogeneous example and the search."""
    from netsim.claims.searches import simulate_error_growth

    which = "eq26" if compensated else "tolerant"
    het = bound_on(**HETEROGENEOUS_EXAMPLE, which=which)
    numbers["heterogeneous_example"] = {k: _r(v) for k, v in het.items()}
    cases = list(ours)
    if het["exact"] > het["bound"] + BOUND_SLACK_FIXED:
        sim = simulate_error_growth(_heterogeneous_example(), compensated)
        numbers["heterogeneous_example"]["simulated_error_growth"] = _r(sim)
        if sim > het["bound"] + BOUND_SLACK_FIXED:
            cases.append(f"scalar heterogeneous example (a = -1.5, link 1->0 delayed 1): "
                         f"exact {het['exact']:.4f} > bound {het['bound']:.4f} (simulated "
                         f"error growth {sim:.4f}/step)")
    found, line, snum, cx = _bound_search(context, claim_id, compensated, label)
    numbers.update(snum)
    if line is not None or cases:
        text = "; ".join(([line] if line else []) + cases)
        return Outcome(REFUTED, f"exact rho above the {label} value: " + text
                       + (f" ({_search_words(found)})" if line else ""), numbers,
                       cx if line else {"cases": cases,
                                        "heterogeneous_example": HETEROGENEOUS_EXAMPLE},
                       headline=f"exact rho above the {label} value: " + text)
    if cx is not None:
        return _unconfirmed("search", cx["verification"], numbers, cx)
    if not found.complete:
        return _search_undecided(found, "search", numbers, "; " + ours_ok)
    return Outcome(NO_COUNTEREXAMPLE, "search: none; " + ours_ok, numbers,
                   evidence=found.evidence())


#: Margin by which a fixed instance's exact rho must exceed a bound to refute it.
BOUND_SLACK_FIXED = 1e-9


def check_eq26_bound(context: Context) -> Outcome:
    """LCSYS2022 eq. (26)/Lemma 5: exact rho <= the eq. (26) value (homogeneous tau)."""
    inst = lcsys_instance(context)
    P, A, C, L = inst["P"], inst["A"], inst["C"], inst["L"]
    star = inst["star"].contiguous or 0
    rows = [bound_on(P, A, C, L, homogeneous_delays(P, t), "eq26") for t in range(star + 1)]
    bad = [r for r in rows if r["exact"] > r["bound"] + BOUND_SLACK_FIXED]
    numbers: dict[str, Any] = {"ours": [{k: _r(v) for k, v in r.items()} for r in rows]}
    ours = [f"our instance (homogeneous, self-loops undelayed) tau = {r['tau']}: "
            f"{r['exact']:.4f} > {r['bound']:.4f}" for r in bad]
    return _bound_outcome(context, "L-eq26-bound", True, "eq. (26)", ours,
                          f"our instance: exact <= eq. (26) for tau = 0..{star}", numbers)


def check_eq14(context: Context) -> Outcome:
    """LCSYS2022 eq. (14): the decay rate falls with tau for tau <= tau* (exact rho)."""
    inst = lcsys_instance(context)
    star = inst["star"].contiguous or 0
    res = eq14_on(inst["P"], inst["A"], inst["C"], inst["L"], range(star + 1))
    series = ", ".join(f"tau {t}: {r:.4f}" for t, r in res["exact"].items())
    numbers = {"exact_rho": {str(t): _r(r) for t, r in res["exact"].items()},
               "decreases": [list(p) for p in res["decreases"]], "tau_star": star}
    if res["decreases"]:
        # verified by simulation: the noise-free error recursion's measured decay
        pairs = res["decreases"]
        taus = sorted({t for p in pairs for t in p})
        sim = {t: _simulated_decay(inst, t) for t in taus}
        confirmed = [p for p in pairs if sim[p[1]] < sim[p[0]] - 1e-6]
        numbers["simulated_decay_per_step"] = {str(t): _r(v, 6) for t, v in sim.items()}
        words = ", ".join(f"tau {t}: {v:.4f}" for t, v in sim.items())
        if not confirmed:
            why = ("the exact rho decreases but the simulated noise-free decay does not "
                   f"({words})")
            return Outcome(UNDECIDED, why, numbers, reason=why)
        return Outcome(REFUTED, "exact asymptotic rho per homogeneous tau is not monotone "
                       f"(decreases at {pairs}): {series}; verified by the simulated "
                       f"noise-free error's decay per step: {words}", numbers,
                       {"instance": "lcsys2022-homogeneous", "pairs": numbers["decreases"],
                        "simulated_decay_per_step": numbers["simulated_decay_per_step"]})
    return Outcome(PROVED, f"exact rho non-decreasing for tau = 0..{star}: {series}", numbers)


def _simulated_decay(inst: dict[str, Any], tau: int, steps: int = 3000) -> float:
    """Per-step decay of the noise-free error of our instance at homogeneous ``tau``,
    simulated by the estimator's own error equations: agent i's error is
    ``e_i,k = (I - L_i C_i)(p_ii A e_i,k-1 + sum_j p_ij A^(tau+1) e_j,k-1-tau)``
    (LCSYS2022 eqs. 4-5), iterated from a random start and renormalised; the geometric
    mean of the growth over the second half."""
    P, A = np.asarray(inst["P"], float), np.asarray(inst["A"], float)
    C, L = [np.atleast_2d(c) for c in inst["C"]], [np.atleast_2d(x) for x in inst["L"]]
    N, n = P.shape[0], A.shape[0]
    G = [np.eye(n) - L[i] @ C[i] for i in range(N)]
    Ad = np.linalg.matrix_power(A, tau + 1)
    hist = list(np.random.default_rng(0).standard_normal((tau + 1, N, n)))  # hist[r]=e_k-1-r
    logs = []
    for _ in range(steps):
        new = np.stack([G[i] @ (P[i, i] * A @ hist[0][i] + sum(
            P[i, j] * Ad @ hist[tau][j] for j in range(N) if j != i and P[i, j] != 0))
            for i in range(N)])
        hist = [new, *hist[:-1]]
        norm = float(np.sqrt(sum(float(np.sum(h * h)) for h in hist)))
        logs.append(math.log(norm))
        hist = [h / norm for h in hist]
    return float(math.exp(np.mean(logs[steps // 2:])))


def _ours_rho(context: Context) -> tuple[float, int | None]:
    inst = lcsys_instance(context)
    return float(inst["gains"].rho), inst["star"].contiguous


def check_printed_rho(context: Context) -> Outcome:
    rho, star = _ours_rho(context)
    from netsim.cliutil import tau_star_text

    return Outcome(UNDECIDED, f"ours: rho(A-hat) = {rho:.4f}, tau* = {tau_star_text(star)} on our "
                   "instance", {"rho_delay_free": _r(rho), "tau_star": star},
                   reason="the paper does not print A, C, P or K")


def check_printed_eq26(context: Context) -> Outcome:
    inst = lcsys_instance(context)
    P, A, C, L = inst["P"], inst["A"], inst["C"], inst["L"]
    ours = {t: float(delay_bound_lcsys(P, A, C, L, t)) for t in (3, 8, 19)}
    return Outcome(UNDECIDED, "ours: " + ", ".join(f"tau {t}: {v:.3f}"
                                                       for t, v in ours.items()),
                   {str(t): _r(v) for t, v in ours.items()},
                   reason="the paper does not print A, C, P or K")


def check_hom19(context: Context) -> Outcome:
    inst = lcsys_instance(context)
    r = _exact(inst["P"], inst["A"], inst["C"], inst["L"], 19)
    return Outcome(UNDECIDED, f"ours: exact rho at homogeneous tau = 19 is {r:.4f}",
                   {"exact_rho_19": _r(r)},
                   reason="rho = 1 is a number of the paper's unprinted system")


def check_stable_038(context: Context) -> Outcome:
    inst = lcsys_instance(context)
    ex = {t: _exact(inst["P"], inst["A"], inst["C"], inst["L"], t) for t in (0, 3, 8, 19)}
    s = ", ".join(f"tau {t}: {r:.4f}" for t, r in ex.items())
    return Outcome(UNDECIDED, f"ours (homogeneous, exact rho): {s}",
                   {str(t): _r(r) for t, r in ex.items()},
                   reason="a Monte Carlo observation of the paper's unprinted system; "
                          "ours: netsim bench delay-tolerance lcsys2022-fig1")


# -- delay-tolerant paper -----------------------------------------------------------------


def check_tolerant_bound(context: Context) -> Outcome:
    """Delay-tolerant Lemma 5 / Theorem 1: rho(eq. 11) <= rho(A-hat)^(1/(tau+1))."""
    inst = lcsys_instance(context)
    P, A, C, L = inst["P"], inst["A"], inst["C"], inst["L"]
    rows = [bound_on(P, A, C, L, homogeneous_delays(P, t), "tolerant") for t in range(11)]
    bad = [r for r in rows if r["exact"] > r["bound"] + BOUND_SLACK_FIXED]
    numbers: dict[str, Any] = {"ours": [{k: _r(v) for k, v in r.items()} for r in rows]}
    ours = [f"our instance tau = {r['tau']}: {r['exact']:.4f} > {r['bound']:.4f} (eq. 11 "
            "matrix)" for r in bad]
    return _bound_outcome(context, "T-lemma5-bound", False, "Lemma 5 (eq. 11 matrix)", ours,
                          "our instance: exact <= bound for tau = 0..10", numbers)


def check_tolerant_theorem1(context: Context) -> Outcome:
    """Delay-tolerant Theorem 1: bounded error for any bounded delay when rho(A-hat) < 1."""
    from netsim.api import run

    inst = lcsys_instance(context)
    scenario = inst["scenario"]
    steps = 120
    res = run(scenario, steps=steps, trials=4, seed=context.seed,
              estimators=["uncompensated"])
    mse = res["uncompensated"].squared_errors.mean(axis=(0, 2))
    k = np.arange(steps // 2, steps + 1)
    slope = np.polyfit(k, np.log(mse[k]), 1)[0]
    growth = float(np.exp(slope))
    rho_a = float(np.max(np.abs(np.linalg.eigvals(inst["A"]))))
    numbers = {"rho_delay_free": _r(inst["gains"].rho), "tau": scenario.delay_bound,
               "mse_growth_per_step": _r(growth), "rho_A_squared": _r(rho_a ** 2)}
    found = searched(context, "T-theorem1")
    numbers["search"] = found.to_dict()
    ours = (f"our LCSYS2022 instance (rho(A) = {rho_a:.4f} > 1), rho(A-hat) = "
            f"{inst['gains'].rho:.4f}, homogeneous tau = {scenario.delay_bound}: uncompensated "
            f"MSE grows by {growth:.4f} per step (rho(A)^2 = {rho_a ** 2:.4f})")
    ours_fails = growth > 1.001 and rho_a > 1
    ours_cx = {"instance": "lcsys2022-homogeneous", "tau": scenario.delay_bound,
               "verification": {"exact": "the error is forced by the moving state through "
                                "(A^(r+1) - A) x, which grows as rho(A)^2 per step in MSE",
                                "rho_A_squared": rho_a ** 2, "simulated_mse_growth": growth}}
    if found.instance is not None:
        from netsim.claims.searches import verify_counterexample, write_delayed_scenario

        x, d = found.instance, found.details
        check = verify_counterexample(x, False, d["exact_rho"])
        cx: dict[str, Any] = {**x.to_dict(), **d, "verification": check}
        numbers["verification"] = check
        kind = "homogeneous" if x.homogeneous else "heterogeneous"
        what = (f"a = {x.inst.a:g}, P = {[list(r) for r in x.inst.P]}, c = "
                f"{list(x.inst.c)}, K = {list(x.inst.k)}, {kind} delays "
                f"{[list(r) for r in x.delays]}: rho(A-hat) = {d['rho_delay_free']:.4f}, exact "
                f"eq. (11) rho {d['exact_rho']:.4f} > 1")
        if check["confirmed"]:
            if context.out is not None:
                path = write_delayed_scenario(
                    x, context.out, "T-theorem1-counterexample",
                    f"Counterexample to the delay-tolerant Theorem 1 found by netsim claims "
                    f"(seed {context.seed}): |a| <= 1, rho(A-hat) = "
                    f"{d['rho_delay_free']:.4f} < 1, fixed delays up to {x.tau}, exact rho "
                    f"of the eq. (11) matrix {d['exact_rho']:.4f} > 1.", ("uncompensated",))
                cx["scenario"] = str(path)
            verified = (f"verified: simulated error growth "
                        f"{check['simulated_error_growth']:.4f}/step; netsim run: "
                        f"{_run_words(check['netsim_run'])}")
            line = (f"search counterexample (|a| <= 1, bounded state; shrunk): {what} "
                    f"({verified}; {_search_words(found)})")
            head = (f"search counterexample (|a| <= 1, bounded state; shrunk): {what} "
                    f"({verified})")
            return Outcome(REFUTED, line + "; " + ours, numbers, cx,
                           headline=head + "; " + ours)
        if not ours_fails:
            return _unconfirmed("search (|a| <= 1): " + what, check, numbers, cx)
    if ours_fails:
        return Outcome(REFUTED, ours + " (the joint system of state and error diverges; "
                       "the search found no verified counterexample with |a| <= 1)", numbers,
                       ours_cx)
    if not found.complete:
        return _search_undecided(found, "search (|a| <= 1)", numbers, "; " + ours)
    return Outcome(NO_COUNTEREXAMPLE, "search (|a| <= 1): none; " + ours, numbers,
                   evidence=found.evidence())


def check_tolerant_decay(context: Context) -> Outcome:
    inst = lcsys_instance(context)
    P, A, C, L = inst["P"], inst["A"], inst["C"], inst["L"]
    ex = {t: _exact(P, A, C, L, t, compensated=False) for t in range(11)}
    drops = [(a, a + 1) for a in range(10) if ex[a + 1] < ex[a] - 1e-9]
    s = ", ".join(f"tau {t}: {r:.4f}" for t, r in ex.items())
    numbers = {"exact_rho_eq11": {str(t): _r(r) for t, r in ex.items()}}
    if drops:
        return Outcome(REFUTED, f"eq. (11) exact rho decreases at {drops}: {s}", numbers)
    return Outcome(PROVED, f"eq. (11) exact rho non-decreasing in homogeneous tau: {s} "
                   "(a statement about the matrix; on a moving state the error is not "
                   "eq. (11), see T-theorem1)", numbers)


def check_tolerant_printed(context: Context) -> Outcome:
    rho, _ = _ours_rho(context)
    return Outcome(UNDECIDED, f"ours: rho(A-hat) = {rho:.4f}, rho^(1/11) = "
                   f"{rho ** (1 / 11):.3f}, rho^(1/26) = {rho ** (1 / 26):.3f}",
                   {"rho_delay_free": _r(rho)}, reason="the paper does not print A, C, P or K "
                   "(0.64^(1/11) = 0.960 and 0.64^(1/26) = 0.983 are consistent)")


def check_tolerant_figures(context: Context) -> Outcome:
    return Outcome(UNDECIDED, "see netsim bench delay-tolerance delay-tolerant-fig1/-fig2",
                   reason="a Monte Carlo observation of the paper's unprinted system")


# -- aoi paper -----------------------------------------------------------------------------


def naive_growth(steps: int = 40) -> dict[str, float]:
    """Per-step error growth of the two naive baselines of the aoi paper's Section 3."""
    from netsim.aoi import illustrative_example
    from netsim.runner import run_monte_carlo

    result = run_monte_carlo(illustrative_example(steps=steps, seed=0), keep_trials=False)
    # the naive baselines have a report
    return {name: float(cast("dict[str, Any]", result.estimators[name].report)["growth_rate"])
            for name in ("naive-uniform", "naive-tree")}


def check_aoi_naive(context: Context) -> Outcome:
    g = naive_growth()
    unstable = all(v > 1.0 for v in g.values())
    return Outcome(PROVED if unstable else REFUTED,
                   f"error growth per step: uniform weights {g['naive-uniform']:.4f}, tree "
                   f"weights {g['naive-tree']:.4f}", {k: _r(v) for k, v in g.items()})


def _aoi_fixed_rows(context: Context) -> list[dict[str, Any]]:
    """The fixed aoi cases: the Section 3 example and three random instances (seeds
    seed..seed+2), each with its numbers (:func:`netsim.claims.searches.aoi_numbers`)."""
    from netsim.claims.searches import AoiInstance, aoi_numbers

    def make() -> list[dict[str, Any]]:
        rows = [{"case": "section-3 example", **aoi_numbers_example()}]
        for s in range(3):
            rows.append({"case": f"random n=4 N=3 T=2 seed {context.seed + s}",
                         **aoi_numbers(AoiInstance(4, 3, 2, context.seed + s))})
        return rows
    return context.cached("aoi-fixed", make)


#: What each aoi statement compares: (the run's number, the bound) in the numbers.
_AOI_KEYS = {"corollary_1": ("converged_at", "corollary_1"),
             "lemma_3": ("triggered_by", "lemma_3"), "lemma_5": ("max_index", "lemma_5")}


def _aoi_confirm(x: Any) -> dict[str, Any]:
    """Run an aoi counterexample again in the event kernel (the search ran the default
    engine): the second, independent simulation of the noise-free run."""
    from netsim.runner import run_monte_carlo

    res = run_monte_carlo(x.scenario(), families=["aoi"], keep_trials=False,
                          engine="events")
    rep = cast("dict[str, Any]", res.estimators["aoi"].report)  # aoi has a report
    fresh = rep.get("freshness") or {}
    return {"converged_at": rep.get("converged_at"),
            "triggered_by": fresh.get("all_triggered_by"),
            "max_index": fresh.get("max_index_after_trigger_bound")}


def _aoi_claim(context: Context, which: str) -> Outcome:
    """aoi Corollary 1 or Lemma 3 or 5: the fixed cases where Assumption 1 holds (the
    others are shown, not counted), then the counted search."""
    key, bound = _AOI_KEYS[which]
    rows = _aoi_fixed_rows(context)
    found = searched(context, "A-corollary1")
    numbers: dict[str, Any] = {"cases": rows, "search": found.to_dict()}

    def broken(r: dict[str, Any]) -> bool:
        return r[key] is None or r[bound] is None or r[key] > r[bound]
    words = []
    for r in rows:
        rel = ">" if broken(r) else "<="
        words.append(f"{r['case']}: {r[key]} {rel} {r[bound]}"
                     + ("" if r["assumption_1"] else " (Assumption 1 fails: not evidence)"))
    s = "; ".join(words)
    valid = [r for r in rows if r["assumption_1"]]
    bad = [r for r in valid if broken(r)]
    if bad:
        return Outcome(REFUTED, f"{bad[0]['case']} (Assumption 1 holds): {bad[0][key]} > "
                       f"{bad[0][bound]}; " + s, numbers, bad[0])
    x = found.instance
    if x is not None and which in found.details["violated"]:
        d = found.details
        again = _aoi_confirm(x)
        numbers["event_kernel"] = again
        cx = {**x.to_dict(), **d, "event_kernel": again}
        what = (f"search counterexample (shrunk) n = {x.n}, N = {x.N}, T = {x.T}, scenario "
                f"seed {x.seed} (netsim.aoi.random_aoi_scenario, Assumption 1 holds): "
                f"{key} {d[key]} > {d[bound]}")
        if again[key] != d[key]:
            why = (f"the event kernel's run gives {key} {again[key]}, the lockstep run "
                   f"{d[key]}")
            return Outcome(UNDECIDED, what + "; " + why, numbers, cx, reason=why)
        verified = f"verified in both engines' noise-free runs ({_search_words(found)})"
        return Outcome(REFUTED, f"{what}, {verified}; fixed cases: {s}", numbers, cx,
                       headline=f"{what}, verified in both engines' noise-free runs; fixed "
                       f"cases: {s}")
    if found.violations.get(which):
        why = (f"{found.violations[which]} searched instance(s) violate it, but the shrunk "
               "first hit violates another statement only")
        return Outcome(UNDECIDED, s + "; " + why, numbers, reason=why)
    if not found.complete:
        return _search_undecided(found, "search", numbers, "; fixed cases: " + s)
    evidence = Evidence(found.tried + len(valid), found.family + f" and {len(valid)} fixed "
                        "cases", int(found.seed or 0))
    return Outcome(NO_COUNTEREXAMPLE, f"fixed cases: {s}", numbers, evidence=evidence)


def check_aoi_corollary1(context: Context) -> Outcome:
    """aoi Corollary 1: converged by n + 2N(N-1)T (fixed cases and the counted search)."""
    return _aoi_claim(context, "corollary_1")


# -- dkfe paper -----------------------------------------------------------------------------


def _table1(context: Context) -> list[dict[str, Any]]:
    from netsim.models.dkfe import table1_rows

    return context.cached("table1", table1_rows)


def check_dkfe_table1(context: Context) -> Outcome:
    rows = _table1(context)
    off = [r["gamma11"] for r in rows if r["agrees"] is False]
    n = sum(r["agrees"] is not None for r in rows)
    return Outcome(REFUTED if off else PROVED,
                   f"{n - len(off)} of {n} rows agree (75)/(76)/(74)"
                   + (f"; differ at gamma11 = {off}" if off else ""),
                   {"rows_agree": n - len(off), "rows": n, "differ": off})


def check_dkfe_75(context: Context) -> Outcome:
    rows = _table1(context)
    bad = [r["gamma11"] for r in rows if r["c75"] and not r["second_moment_radius"] < 1]
    weaker = [r["gamma11"] for r in rows if r["c76"] and not r["c75"]]
    feas = [r["gamma11"] for r in rows if r["c75"]]
    numbers = {"feasible_75": feas, "radius": {str(r["gamma11"]): _r(r["second_moment_radius"])
                                               for r in rows},
               "feasible_76_not_75": weaker}
    if bad or weaker:
        return Outcome(REFUTED, f"(75) feasible but radius >= 1 at {bad}; (76) but not (75) "
                       f"at {weaker}", numbers)
    return Outcome(PROVED, f"(75) feasible at gamma11 = {feas}, each with exact second-moment "
                   "radius < 1; (75) holds wherever (76) does", numbers)


def check_dkfe_77(context: Context) -> Outcome:
    """dkfe (77) on Example 2: rho(A^d (I - H) A) < 1, beside the exact mean-square test
    of the centre's error chain (65), split into what sets it."""
    from netsim.models.dkfe import example2, sink_conditions

    rows = sink_conditions(example2(), lmis=False)
    vals = [float(r["c77_rho"]) for r in rows]
    radii = [float(r["second_moment_radius"]) for r in rows]
    parts = [r["second_moment_parts"] for r in rows]
    ok = all(v < 1 for v in vals) and all(r < 1 for r in radii)
    return Outcome(PROVED if ok else REFUTED,
                   "Example 2: (77) rho(A^d (I - H_i) A) " + ", ".join(
                       f"sink {i + 1}: {v:.4f}" for i, v in enumerate(vals))
                   + "; exact second-moment radius of the centre's error chain (65), "
                   "rho(E{A_i kron A_i}): " + ", ".join(
                       f"sink {i + 1}: {r:.4f} = {p['set_by']} (selection chain "
                       f"{p['selection_chain']:.4f}, local filter {p['local_filter']:.4f})"
                       for i, (r, p) in enumerate(zip(radii, parts, strict=True))),
                   {"c77": [_r(v) for v in vals], "second_moment_radius": [_r(r) for r in radii],
                    "second_moment_parts": parts})


# -- checks added for full coverage -----------------------------------------------------


def _bench(context: Context, preset: str) -> dict[str, Any]:
    """:func:`netsim.claims.searches.bench_report` for the context's seed, cached per
    preset."""
    from netsim.claims.searches import bench_report

    return context.cached(f"bench:{preset}", lambda: bench_report(preset, context.seed))


def _from_bench(context: Context, claim_id: str, preset: str) -> Outcome:
    """A figure's Monte Carlo observation of the paper's unprinted system, on our
    instance (a bench report): agreement is no counterexample in the trials run; a
    disagreement cannot refute a figure of another system, so it is undecided with the
    difference stated."""
    from netsim.bench.claims import CLAIMS as BENCH_CHECKS

    data = _bench(context, preset)
    row = BENCH_CHECKS[claim_id](data)
    numbers = {"bench": preset, "trials": data["trials"], "steps": data["steps"],
               "ours": row["ours"], "status": row["status"]}
    where = (f"netsim bench delay-tolerance {preset} ({data['trials']} trials x "
             f"{data['steps']} steps) on our instance of the unprinted system: ")
    if row["agrees"] is None:
        return Outcome(UNDECIDED, where + row["ours"], numbers,
                       reason="the bench report has no cell for it")
    if row["agrees"]:
        evidence = Evidence(int(data["trials"]), f"Monte Carlo trials of {data['steps']} "
                            f"steps of netsim bench {preset} on our instance", context.seed)
        return Outcome(NO_COUNTEREXAMPLE, where + row["ours"], numbers, evidence=evidence)
    why = ("the figure is of the paper's unprinted system; on our instance it does not "
           "show (" + row["ours"] + ")")
    return Outcome(UNDECIDED, where + row["ours"], numbers,
                   {"bench": preset, "cells": row["ours"]}, reason=why)


def check_stable_038_bench(context: Context) -> Outcome:
    """LCSYS2022 Fig. 1: compensated stable at tau = 0, 3, 8 (bench, our instance)."""
    return _from_bench(context, "L-stable-0-3-8", "lcsys2022-fig1")


def check_het19_bench(context: Context) -> Outcome:
    """LCSYS2022 Fig. 1: heterogeneous tau = 19 stable (bench, our instance)."""
    return _from_bench(context, "L-het-19", "lcsys2022-fig1")


def check_tolerant_fig1(context: Context) -> Outcome:
    """Delay-tolerant Fig. 1 (bench, our instance)."""
    return _from_bench(context, "T-fig1-stable", "delay-tolerant-fig1")


def check_tolerant_fig2(context: Context) -> Outcome:
    """Delay-tolerant Fig. 2 (bench, our instance)."""
    return _from_bench(context, "T-fig2-stable", "delay-tolerant-fig2")


def convergence_time(M: np.ndarray, factor: float = 1e-3, seed: int = 0,
                     max_steps: int = 100_000) -> int | None:
    """Steps until ``||M^k e_0|| <= factor ||e_0||`` for a random ``e_0`` (noise-free error
    recursion e_k = M e_{k-1}); None if not within ``max_steps``."""
    e = np.random.default_rng(seed).standard_normal(int(M.shape[0]))
    e0 = float(np.linalg.norm(e))
    for k in range(1, max_steps + 1):
        e = cast("np.ndarray", M @ e)  # numpy's stubs type this product as float
        if np.linalg.norm(e) <= factor * e0:
            return k
    return None


def lemma2_on(P: Any, A: Any, C: Any, L: Any, taus: Sequence[int],
              compensated: bool = True) -> dict[int, dict[str, float | None]]:
    """Per homogeneous tau: exact rho of (10) (or (11)), the measured convergence time
    (error down by 1e3) and ``time (1 - rho) / ln(1e3)`` (about 1 for a Theta match)."""
    from netsim.models.augmented import augmented_closed_loop

    out: dict[int, dict[str, float | None]] = {}
    for t in taus:
        M = augmented_closed_loop(P, A, C, L, homogeneous_delays(P, t), t,
                                  compensated=compensated)
        r = float(max(abs(np.linalg.eigvals(M))))
        k = convergence_time(M) if r < 1 else None
        out[int(t)] = {"rho": r, "time": k,
                       "ratio": None if k is None else k * (1 - r) / math.log(1e3)}
    return out


def _check_lemma2(context: Context, compensated: bool) -> Outcome:
    inst = lcsys_instance(context)
    star = inst["star"].contiguous or 0
    taus = range(star + 1) if compensated else range(11)
    rows = lemma2_on(inst["P"], inst["A"], inst["C"], inst["L"], taus, compensated)
    ratios = [v["ratio"] for v in rows.values() if v["ratio"] is not None]
    free = float(inst["gains"].rho)
    s = ", ".join(f"tau {t}: {v['time']} steps (rho {v['rho']:.4f})" for t, v in rows.items())
    numbers = {"rows": {str(t): {k: _r(x) for k, x in v.items()} for t, v in rows.items()},
               "ratio_min": _r(min(ratios)), "ratio_max": _r(max(ratios)),
               "rho_delay_free": _r(free)}
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


def check_lemma2(context: Context) -> Outcome:
    """LCSYS2022 Lemma 2: convergence time of (10) is Theta(1/(1 - rho))."""
    return _check_lemma2(context, True)


def check_tolerant_lemma2(context: Context) -> Outcome:
    """Delay-tolerant Lemma 2: convergence time of (13) is Theta(1/(1 - rho))."""
    return _check_lemma2(context, False)


def lemma4_on(P: Any, A: Any, C: Any, L: Any, tau: int) -> dict[str, float]:
    """Every link *and self-loop* delayed by tau: rho of the augmented matrix (2) beside
    rho(A-hat_tau)^(1/(tau+1)), A-hat_tau = (I - K D_C)(P kron A^(tau+1)) (the equality
    case of Lemmas 4-5). The matrix is built here (netsim's models keep self-loops
    undelayed): first block row ``[0, ..., 0, A-hat_tau]``, identities below."""
    from netsim.models.augmented import gain_product

    P, A = np.asarray(P, float), np.asarray(A, float)
    m = P.shape[0] * A.shape[0]
    top = (np.eye(m) - gain_product(L, C)) @ np.kron(P, np.linalg.matrix_power(A, tau + 1))
    M = np.zeros((m * (tau + 1), m * (tau + 1)))
    M[:m, tau * m:] = top
    M[m:, :-m] = np.eye(m * tau)
    exact = float(max(abs(np.linalg.eigvals(M))))
    return {"exact": exact, "bound": float(delay_bound_lcsys(P, A, C, L, tau))}


def check_lemma4(context: Context) -> Outcome:
    """LCSYS2022 Lemmas 4-5, the equality case: all delays (self-loops too) equal tau."""
    inst = lcsys_instance(context)
    rows: dict[int | str, dict[str, float]] = {
        t: lemma4_on(inst["P"], inst["A"], inst["C"], inst["L"], t) for t in (1, 3, 8)}
    found = searched(context, "L-theorem1")
    if found.instance is not None:
        P, A, C, L = found.instance.matrices()
        rows["search"] = lemma4_on(P, A, C, L, 1)
    worst = max(abs(v["exact"] - v["bound"]) for v in rows.values())
    s = ", ".join(f"{'tau ' if k != 'search' else ''}{k}: {v['exact']:.6f} vs "
                  f"{v['bound']:.6f}" for k, v in rows.items())
    numbers = {"rows": {str(k): {a: _r(b, 8) for a, b in v.items()} for k, v in rows.items()},
               "max_difference": worst}
    return Outcome(PROVED if worst < 1e-8 else REFUTED,
                   f"with self-loops delayed too, exact rho = rho(A-hat_tau)^(1/(tau+1)) "
                   f"(largest difference {worst:.1e}): {s}; the papers' setting (self-loops "
                   "undelayed) is not this case, see L-eq26-bound", numbers)


# -- aoi --------------------------------------------------------------------------------


def aoi_numbers_example() -> dict[str, Any]:
    """:func:`netsim.claims.searches.aoi_numbers` for the Section 3 example."""
    from netsim.aoi import illustrative_example
    from netsim.runner import run_monte_carlo

    res = run_monte_carlo(illustrative_example(steps=40), families=["aoi"], keep_trials=False)
    rep = cast("dict[str, Any]", res.estimators["aoi"].report)  # aoi has a report
    b = cast("dict[str, Any]", res.analytics)["aoi"]["bounds"]  # the aoi family's
    fresh = rep.get("freshness") or {}
    return {"converged_at": rep.get("converged_at"), "T": b["T"],
            "corollary_1": b["corollary_1_finite_time"],
            "triggered_by": fresh.get("all_triggered_by"), "lemma_3": b["lemma_3_triggered_by"],
            "max_index": fresh.get("max_index_after_trigger_bound"),
            "lemma_5": b["lemma_5_freshness_max"], "assumption_1": b["assumption_1"]}


def check_aoi_lemma3(context: Context) -> Outcome:
    """aoi Lemma 3: every freshness index is triggered by (N-1)T."""
    return _aoi_claim(context, "lemma_3")


def check_aoi_lemma5(context: Context) -> Outcome:
    """aoi Lemma 5: after (N-1)T every index is at most 2(N-1)T."""
    return _aoi_claim(context, "lemma_5")


def aoi_rate(seed: int, rho: float, n: int = 4, N: int = 3, T: int = 2) -> dict[str, Any]:
    """aoi Theorem 1 on one random instance (rho(A) = 1, noise-free): measured per-step
    decay of the largest agent error with ``gains = "rate"`` at ``rho``: a log-linear fit
    from step min(2N(N-1)T, last/2) to the last step where the error is above
    1e-10 |x| (before round-off)."""
    from netsim.aoi import random_aoi_scenario
    from netsim.runner import run_monte_carlo

    sc = random_aoi_scenario(n, N, T, seed=seed, steps=150, spectral_radius=1.0)
    res = run_monte_carlo(sc.with_options("aoi", gains="rate", rho=float(rho)),
                          families=["aoi"], keep_trials=True)
    t = res.runs["aoi"][0]
    err = np.sqrt(np.asarray(t.squared_errors)).max(axis=1)
    scale = np.linalg.norm(np.asarray(t.states), axis=1)
    above = np.flatnonzero(err > 1e-10 * np.maximum(scale, 1e-300))
    last = int(above[-1]) if above.size else 0
    start = min(2 * N * (N - 1) * T, last // 2)
    ks = np.arange(start, last + 1)
    rate = (float(np.exp(np.polyfit(ks, np.log(err[ks]), 1)[0])) if len(ks) >= 5
            else None)
    return {"seed": seed, "rho": rho, "measured_rate": rate, "window": [start, last]}


#: Random instances of the aoi Theorem 1 check (each with two rates).
AOI_RATE_SEEDS = 5


def check_aoi_theorem1(context: Context) -> Outcome:
    """aoi Theorem 1: with the rate design the error decays at the requested rate rho."""
    rows = [aoi_rate(context.seed + s, rho) for s in range(AOI_RATE_SEEDS)
            for rho in (0.6, 0.85)]
    bad = [r for r in rows if r["measured_rate"] is None or r["measured_rate"] > r["rho"] + 0.02]
    s = "; ".join(f"seed {r['seed']} rho {r['rho']}: measured "
                  + ("-" if r["measured_rate"] is None else f"{r['measured_rate']:.4f}")
                  for r in rows)
    numbers = {"cases": [{k: _r(v) if isinstance(v, float) else v for k, v in r.items()}
                         for r in rows]}
    if bad:
        return Outcome(REFUTED, "decay slower than the requested rate: " + s, numbers, bad[0])
    evidence = Evidence(len(rows), f"random n=4 N=3 T=2 instances (seeds {context.seed}.."
                        f"{context.seed + AOI_RATE_SEEDS - 1}) x rho in (0.6, 0.85)",
                        context.seed)
    return Outcome(NO_COUNTEREXAMPLE, "rho(A) = 1, rate gains; per-step decay of the "
                   "largest noise-free error <= rho + 0.02: " + s, numbers, evidence=evidence)


# -- dkfe printed numbers -----------------------------------------------------------------


def _example2(context: Context) -> dict[str, Any]:
    from netsim.fusion import example2

    return context.cached("example2", lambda: example2(json=True)[0])


def _table1_data(context: Context) -> dict[str, Any]:
    from netsim.fusion import table1

    return context.cached("table1data", lambda: table1(json=True)[0])


def _printed(name: str, ours: Any, printed: Any, tol: float = 5e-5) -> tuple[bool, float]:
    diff = float(np.max(np.abs(np.asarray(ours, float) - np.asarray(printed, float))))
    return diff <= tol, diff


def check_dkfe_eq83(context: Context) -> Outcome:
    """dkfe (83): the printed G_K1 of Example 1."""
    d = _table1_data(context)
    ok, diff = _printed("83", d["Phi_K1"], d["paper_eq83"])
    ok_g, diff_g = _printed("83", d["G_K1"], d["paper_eq83"])
    return Outcome(REFUTED if not (ok or ok_g) else PROVED,
                   f"printed G_K1 {d['paper_eq83']}; ours G_K1 = I - K_1 C_1 = "
                   f"{np.round(d['G_K1'], 4).tolist()} (differs by {diff_g:.4f}); the printed "
                   f"matrix is Phi_K1 = G_K1 A = {np.round(d['Phi_K1'], 4).tolist()} with two "
                   f"digit pairs swapped (largest difference {diff:.4f})",
                   {"diff_G": _r(diff_g), "diff_Phi": _r(diff)})


def check_dkfe_ex1_numbers(context: Context) -> Outcome:
    """dkfe Example 1 at gamma_11 = 0.5: lambda_max = 1.5887, xi_inf,1 = 2.3625, and the
    printed D_1 certifies (75)."""
    from netsim.models.dkfe import condition_74, condition_76, example1, steady_state_local_filter

    setup = example1(0.5)
    sel = setup.selections[0]
    ss = steady_state_local_filter(setup.A, setup.C[0], setup.Q, setup.R[0])
    lam = condition_76(setup.A, sel)
    xi = condition_74(setup.A, ss.Phi, sel, 0)["zeta_inf"]
    cert = _table1_data(context)["paper_D1_check"]
    ok = abs(lam - 1.5887) < 5e-5 and abs(xi - 2.3625) < 5e-5 and cert["certificate"]
    return Outcome(PROVED if ok else REFUTED,
                   f"lambda_max(A^T (I - H_1) A) = {lam:.4f} (printed 1.5887), xi_inf,1 = "
                   f"{xi:.4f} (printed 2.3625); printed D_1: min eig {cert['min_eig_D']:.4f} > 0, "
                   f"max eig f(D_1) - D_1 = {cert['max_eig_f_minus_D']:.4f} < 0 (a valid "
                   "certificate of (75))",
                   {"lambda_max": _r(lam), "xi_inf": _r(xi), "D1": cert})


def check_dkfe_eq88(context: Context) -> Outcome:
    """dkfe (88): the printed Phi_K1, Phi_K2 of Example 2."""
    diffs = _example2(context)["Phi_K_minus_paper_eq88_max_abs"]
    ok = all(v < 5e-5 for v in diffs)
    return Outcome(PROVED if ok else REFUTED,
                   f"largest |ours - printed|: Phi_K1 {diffs[0]:.4f}, Phi_K2 {diffs[1]:.4f} "
                   "(row 4 of Phi_K2: two digit swaps)", {"max_abs_diff": [_r(v) for v in diffs]})


def check_dkfe_eq93(context: Context) -> Outcome:
    """dkfe (93): rho(A^{d_i} (I - H_i) A) = 0.5759, 0.6631."""
    d = _example2(context)
    ours, printed = d["c77_rho"], d["paper_c77_rho_eq93"]
    diffs = [abs(a - b) for a, b in zip(ours, printed, strict=True)]
    return Outcome(PROVED if max(diffs) < 5e-5 else REFUTED,
                   f"ours {ours[0]:.4f}, {ours[1]:.4f}; printed {printed[0]}, {printed[1]} "
                   f"(differences {diffs[0]:.4f}, {diffs[1]:.4f}; both < 1 either way)",
                   {"ours": [_r(v) for v in ours], "printed": printed,
                    "diff": [_r(v) for v in diffs]})


def check_dkfe_eq94(context: Context) -> Outcome:
    """dkfe (94): the printed steady-state weights Omega_1, Omega_2 of Example 2."""
    d = _example2(context)
    diffs = d["weights_minus_paper_max_abs"]
    ss = d["steady_state"]
    return Outcome(PROVED if max(diffs) < 5e-5 else REFUTED,
                   f"largest |ours - printed|: Omega_1 {diffs[0]:.4f}, Omega_2 {diffs[1]:.4f} "
                   f"(ours sum to I within {d['weights_sum_minus_I_max_abs']:.1e}; Xi(t) "
                   f"converged after {ss['steps']} steps; the difference lies in the "
                   "cross-covariances, see netsim fusion example2)",
                   {"max_abs_diff": [_r(v) for v in diffs], "ours": d["weights"],
                    "printed": d["paper_weights_eq94"]})


def check_dkfe_eq95(context: Context) -> Outcome:
    """dkfe (95): zeta_inf,1 = 0.8657, zeta_inf,2 = 1.3554."""
    d = _example2(context)
    ours, printed = d["zeta_inf"], d["paper_zeta_inf_eq95"]
    diffs = [abs(a - b) for a, b in zip(ours, printed, strict=True)]
    return Outcome(PROVED if max(diffs) < 5e-5 else REFUTED,
                   f"ours {ours[0]:.4f}, {ours[1]:.4f}; printed {printed[0]}, {printed[1]} "
                   "(the second computed with H_2: the printed formula's (I_n - H_1) is a typo)",
                   {"ours": [_r(v) for v in ours], "printed": printed})


def check_dkfe_fig6(context: Context) -> Outcome:
    """dkfe Fig. 6 / eq. (57): the DKFE beats each CSE, the ODKFE beats the DKFE."""
    ss = _example2(context)["steady_state"]
    p, xi, po = ss["trace_P"], ss["trace_Xi"], ss["trace_P_odkfe"]
    ok = all(p < x for x in xi) and po < p
    return Outcome(PROVED if ok else REFUTED,
                   f"steady traces (exact covariance recursion): DKFE {p:.4f} < CSEs "
                   f"{xi[0]:.4f}, {xi[1]:.4f}; ODKFE {po:.4f} < DKFE",
                   {"trace_P": _r(p), "trace_Xi": [_r(v) for v in xi], "trace_P_odkfe": _r(po)})


def _iterated_second_moment_growth(A: Any, Phi: Any, sel: Any, d: int,
                                   steps: int = 2000) -> float:
    """Per-step growth of tr f^k(I), f the second-moment map of Lemma 7 (eq. 69): an
    iteration independent of the eigenvalue computation of the radius."""
    from netsim.models.dkfe import lemma7_f

    B = np.eye(2 * np.asarray(A).shape[0])
    logs = []
    for _ in range(steps):
        B = lemma7_f(B, A, Phi, sel, d)
        t = float(np.trace(B))
        logs.append(math.log(t))
        B /= t
    return float(math.exp(np.mean(logs[steps // 2:])))


def check_dkfe_75_search(context: Context) -> Outcome:
    """dkfe Theorem 2 / (75)-(76): Example 1's Table I rows and the counted search."""
    base = check_dkfe_75(context)
    found = searched(context, "D-cond75")
    numbers = {**base.numbers, "search": found.to_dict()}
    if base.verdict == REFUTED:
        return Outcome(REFUTED, base.summary, numbers, base.counterexample)
    if found.instance is not None:
        # the judge is exact (cvxpy for (75), the eigenvalues of E{A_i kron A_i}); the
        # second verification iterates the paper's own second-moment map f (Lemma 7,
        # eq. 69) and measures the growth of its trace
        x, d = found.instance, found.details
        A, sel, Phi, dd = x.parts()
        again = _iterated_second_moment_growth(A, Phi, sel, dd)
        text = (f"search counterexample {x.to_dict()} violates {d['violated']}: (75) "
                f"{'feasible' if d['c75'] else 'infeasible'}, (76) {d['c76']}, (74) "
                f"{d['c74']}, exact second-moment radius {d['radius']:.4f} (iterating "
                f"Lemma 7's f: {again:.4f} per step) ({_search_words(found)})")
        return Outcome(REFUTED, text, numbers, found.to_dict(), headline=text)
    tail = ("Example 1: " + base.summary + "; judged by the exact second-moment radius of "
            "the centre's error chain (65)")
    if not found.complete:
        return _search_undecided(found, "search", numbers, "; " + tail)
    return Outcome(NO_COUNTEREXAMPLE, tail, numbers, evidence=found.evidence())


# -- LCSYS2022 Lemmas 1, 3 and Corollary 1 ------------------------------------------------


def kron_observable(P: Any, A: Any, C: Sequence[Any]) -> bool:
    """Is ``(P kron A, D_C-bar)`` observable (rank of the observability matrix)?"""
    from netsim.models.augmented import output_gain_matrix

    F = np.kron(np.asarray(P, float), np.asarray(A, float))
    D = output_gain_matrix(C)
    m = F.shape[0]
    blocks, M = [], np.eye(m)
    for _ in range(m):
        blocks.append(D @ M)
        M = M @ F
    return bool(np.linalg.matrix_rank(np.vstack(blocks)) == m)


def check_lemma1(context: Context) -> Outcome:
    """LCSYS2022 (and delay-tolerant) Lemma 1: (P kron A, D_C) is structurally observable
    for irreducible self-looped P when (A, C) is observable."""
    from netsim.claims.search import _random_instance

    inst = lcsys_instance(context)
    ours = kron_observable(inst["P"], inst["A"], inst["C"])
    rng = np.random.default_rng(np.random.SeedSequence(context.seed, spawn_key=(101,)))
    tried = bad = 0
    for _ in range(300):
        x = _random_instance(rng)
        if x.a == 0 or not any(x.c):
            continue
        tried += 1
        P, A, C, _ = x.matrices()
        bad += not kron_observable(P, A, C)
    numbers = {"ours": ours, "random_tried": tried, "random_unobservable": bad}
    s = (f"our LCSYS2022 instance: {'observable' if ours else 'NOT observable'}; "
         f"{tried - bad} of {tried} random scalar instances (random weights on irreducible "
         "self-looped graphs, a != 0, some c_i != 0) observable")
    if not ours or bad:
        return Outcome(REFUTED, s, numbers)
    return Outcome(NO_COUNTEREXAMPLE, s, numbers, evidence=Evidence(
        tried, "random scalar instances on irreducible self-looped graphs (a != 0, some "
        "c_i != 0) and our LCSYS2022 instance", context.seed))


def check_lemma3(context: Context) -> Outcome:
    """LCSYS2022 Lemma 3 (eigenvalues of P kron A) and Discussion 2 (rho(P kron A) = rho(A)
    for row-stochastic P)."""
    rng = np.random.default_rng(np.random.SeedSequence(context.seed, spawn_key=(102,)))
    worst = worst_rho = 0.0
    for _ in range(50):
        N, n = int(rng.integers(2, 5)), int(rng.integers(1, 4))
        P, A = rng.random((N, N)), rng.standard_normal((n, n))
        kron = np.sort_complex(np.linalg.eigvals(np.kron(P, A)))
        prod = np.sort_complex(np.outer(np.linalg.eigvals(P), np.linalg.eigvals(A)).ravel())
        worst = max(worst, float(np.max(np.abs(kron - prod))))
        S = P / P.sum(axis=1, keepdims=True)
        worst_rho = max(worst_rho, abs(float(max(abs(np.linalg.eigvals(np.kron(S, A)))))
                                       - float(max(abs(np.linalg.eigvals(A))))))
    ok = worst < 1e-8 and worst_rho < 1e-8
    if ok:
        return Outcome(NO_COUNTEREXAMPLE,
                       f"50 random pairs: eig(P kron A) = {{lambda_i mu_j}} (largest difference "
                       f"{worst:.1e}); rho(P kron A) = rho(A) for row-stochastic P (largest "
                       f"difference {worst_rho:.1e})",
                       {"max_diff": worst, "max_diff_rho": worst_rho}, evidence=Evidence(
                           50, "random pairs (P: N 2..4 nonnegative, A: n 1..3 Gaussian)",
                           context.seed))
    return Outcome(REFUTED,
                   f"50 random pairs: eig(P kron A) = {{lambda_i mu_j}} (largest difference "
                   f"{worst:.1e}); rho(P kron A) = rho(A) for row-stochastic P (largest "
                   f"difference {worst_rho:.1e})", {"max_diff": worst, "max_diff_rho": worst_rho})


def check_corollary1(context: Context) -> Outcome:
    """LCSYS2022 Corollary 1: for observable (P kron A, D_C) a block-diagonal K with
    rho(A-hat) < 1 exists (our LMI design on our instance)."""
    inst = lcsys_instance(context)
    g = inst["gains"]
    from netsim.models.augmented import delay_free_spectral_radius

    hand = float(delay_free_spectral_radius(inst["P"], inst["A"], inst["C"], inst["L"]))
    ok = hand < 1 and kron_observable(inst["P"], inst["A"], inst["C"])
    return Outcome(PROVED if ok else REFUTED,
                   f"our instance: the block-diagonal LMI design ({g.method}) gives rho(A-hat) = "
                   f"{hand:.4f} < 1", {"rho_delay_free": _r(hand), "method": g.method})


# -- dkfe Figs. 6-8 from a Monte Carlo run with the exact covariances ----------------------


def _fusion(context: Context, scale: float = 1.0, trials: int = 20) -> dict[str, Any]:
    """:func:`netsim.claims.searches.fusion_report` for the context's seed, cached."""
    from netsim.claims.searches import fusion_report

    return context.cached(f"fusion:{scale:g}:{trials}",
                          lambda: fusion_report(context.seed, scale, trials))


def check_dkfe_fig6_run(context: Context) -> Outcome:
    """dkfe Fig. 6 / eq. (57): at every step the DKFE's covariance trace is at most each
    CSE's (strictly after t = 0), the ODKFE's below the DKFE's; all converge."""
    d = _fusion(context)
    tr, marks = d["exact_trace"], d["marks"]
    cse = [k for k in tr if k.startswith("CSE")]
    dk, od = tr["DKFE"], tr["ODKFE (d=0)"]
    bad = [m for i, m in enumerate(marks) if any(dk[i] > tr[c][i] + 1e-12 for c in cse)
           or (m > 0 and (any(dk[i] >= tr[c][i] for c in cse) or od[i] >= dk[i]))]
    last = len(marks) - 1
    conv = all(abs(tr[k][last] - tr[k][last - 1]) < 1e-3 * abs(tr[k][last]) for k in tr)
    s = (f"exact traces at t = {marks}: DKFE {[round(v, 4) for v in dk]}, "
         + ", ".join(f"{c} {[round(v, 4) for v in tr[c]]}" for c in cse)
         + f", ODKFE {[round(v, 4) for v in od]}; Monte Carlo ({d['trials']} trials) at "
         f"t = {marks[last]}: DKFE {d['mse']['DKFE'][last]:.3f}")
    numbers = {"marks": marks, "exact_trace": tr, "converged": conv}
    if bad or not conv:
        return Outcome(REFUTED, f"not at t = {bad} (converged: {conv}); " + s, numbers)
    return Outcome(PROVED, s, numbers)


def check_dkfe_fig7(context: Context) -> Outcome:
    """dkfe Fig. 7 / Theorem 3: P(t) converges to a unique matrix from different initial
    values (exact covariance recursion from x(0) ~ N(0, I) and N(0, 10 I))."""
    a, b = _fusion(context), _fusion(context, 10.0, trials=2)
    pa, pb = a["exact_trace"]["DKFE"], b["exact_trace"]["DKFE"]
    diff0, diff = abs(pa[0] - pb[0]), abs(pa[-1] - pb[-1])
    ok = diff < 1e-6 * max(1.0, abs(pa[-1]))
    return Outcome(PROVED if ok else REFUTED,
                   f"tr P(t) from x(0) ~ N(0, I) and N(0, 10 I): {pa[0]:.4f} vs {pb[0]:.4f} at "
                   f"t = 0, {pa[-1]:.6f} vs {pb[-1]:.6f} at t = {a['marks'][-1]} (difference "
                   f"{diff:.1e})", {"diff_t0": diff0, "diff_end": diff})


def check_dkfe_fig8(context: Context) -> Outcome:
    """dkfe Fig. 8: the DKFE and the SDKFE (steady weights) estimates converge."""
    d = _fusion(context)
    gap, marks = d["dkfe_minus_sdkfe_mean_abs"], d["marks"]
    peak = max(gap)
    ok = gap[-1] < 1e-6 * peak
    return Outcome(PROVED if ok else REFUTED,
                   "mean |DKFE - SDKFE| over the components and trials: " + ", ".join(
                       f"t={m}: {g:.2e}" for m, g in zip(marks, gap, strict=True)),
                   {"gap": gap, "marks": marks})
