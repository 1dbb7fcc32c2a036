"""The aoi paper: a finite-time distributed observer with age of information.

Its claims (``A-*``: Theorem 1, Lemmas 3 and 5, Corollary 1 and the Section 3 example),
the counted search of Corollary 1 (Lemmas 3 and 5 checked on the same runs) over random
jointly observable systems, and the reproduce item Fig. 2, all declared in :data:`PAPER`
at the end. The observer itself is the ``aoi`` estimator family
(:mod:`netsim.estimators.aoi`); the examples are built by :mod:`netsim.aoi`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from netsim.claims.checks import rounded, search_undecided, search_words, searched
from netsim.claims.core import (
    NO_COUNTEREXAMPLE,
    PROVED,
    REFUTED,
    UNDECIDED,
    Claim,
    Context,
    Evidence,
    Outcome,
)
from netsim.claims.search import DEFAULT_INSTANCES, Found, random_search
from netsim.claims.searches import SLOW_SEARCH_SHARE
from netsim.papers import Paper, Search, register_paper
from netsim.papers._aoi_lemmas import CONVERGENCE_ITEM, check_aoi_lemma2, check_aoi_lemma4
from netsim.reproduce.items import (
    BuildContext,
    Item,
    ItemResult,
    figure,
    fmt,
    write_csv,
    write_json,
)

__all__ = ["PAPER", "AOI", "TEXT_FILE", "AoiInstance", "aoi_numbers", "search_aoi",
           "AOI_FAMILY", "naive_growth", "aoi_numbers_example", "aoi_rate",
           "AOI_RATE_SEEDS", "AOI_STEPS"]

#: The paper's key.
AOI = "aoi"
#: Its text in the shared papers folder.
TEXT_FILE = "aoi-finite-time-distributed-observer.txt"


# -- the Corollary 1 search (Lemmas 3 and 5 too) ----------------------------------------




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
def search_aoi(seed: Any = 0, instances: int = DEFAULT_INSTANCES,
               deadline: float = math.inf) -> Found:
    """Search aoi Corollary 1 (and Lemmas 3, 5) over random jointly observable systems
    (draws where Assumption 1 fails are not counted)."""
    return random_search("A-corollary1", _aoi_draw, _aoi_judge, _aoi_simpler, seed=seed,
                         instances=max(1, int(instances * SLOW_SEARCH_SHARE)),
                         family=AOI_FAMILY, deadline=deadline)



# -- the checks -------------------------------------------------------------------------


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
                   f"weights {g['naive-tree']:.4f}", {k: rounded(v) for k, v in g.items()})


def _aoi_fixed_rows(context: Context) -> list[dict[str, Any]]:
    """The fixed aoi cases: the Section 3 example and three random instances (seeds
    seed..seed+2), each with its numbers (:func:`aoi_numbers`)."""

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
        verified = f"verified in both engines' noise-free runs ({search_words(found)})"
        return Outcome(REFUTED, f"{what}, {verified}; fixed cases: {s}", numbers, cx,
                       headline=f"{what}, verified in both engines' noise-free runs; fixed "
                       f"cases: {s}")
    if found.violations.get(which):
        why = (f"{found.violations[which]} searched instance(s) violate it, but the shrunk "
               "first hit violates another statement only")
        return Outcome(UNDECIDED, s + "; " + why, numbers, reason=why)
    if not found.complete:
        return search_undecided(found, "search", numbers, "; fixed cases: " + s)
    evidence = Evidence(found.tried + len(valid), found.family + f" and {len(valid)} fixed "
                        "cases", int(found.seed or 0))
    return Outcome(NO_COUNTEREXAMPLE, f"fixed cases: {s}", numbers, evidence=evidence)


def check_aoi_corollary1(context: Context) -> Outcome:
    """aoi Corollary 1: converged by n + 2N(N-1)T (fixed cases and the counted search)."""
    return _aoi_claim(context, "corollary_1")


def aoi_numbers_example() -> dict[str, Any]:
    """:func:`aoi_numbers` for the Section 3 example."""
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
    numbers = {"cases": [{k: rounded(v) if isinstance(v, float) else v for k, v in r.items()}
                         for r in rows]}
    if bad:
        return Outcome(REFUTED, "decay slower than the requested rate: " + s, numbers, bad[0])
    evidence = Evidence(len(rows), f"random n=4 N=3 T=2 instances (seeds {context.seed}.."
                        f"{context.seed + AOI_RATE_SEEDS - 1}) x rho in (0.6, 0.85)",
                        context.seed)
    return Outcome(NO_COUNTEREXAMPLE, "rho(A) = 1, rate gains; per-step decay of the "
                   "largest noise-free error <= rho + 0.02: " + s, numbers, evidence=evidence)


# -- Fig. 2 -----------------------------------------------------------------------------


AOI_STEPS = 40


def _build_aoi_fig2(ctx: BuildContext) -> ItemResult:
    from netsim.aoi import illustrative_example, node_errors

    trials = max(1, min(ctx.trials, 20))
    sc = illustrative_example(steps=AOI_STEPS, seed=ctx.seed)
    runs = node_errors(sc, ("naive-uniform", "naive-tree", "aoi"), trials=trials)
    rows = []
    for name, r in runs.items():
        M, K1, N = r.errors.shape
        for m in range(M):
            for k in range(K1):
                for i in range(N):
                    rows.append((name, m, k, i + 1, float(r.errors[m, k, i])))
    files = [write_csv(ctx.out / "aoi-fig2.csv", ("observer", "trial", "step", "node",
                                                   "error"), rows)]
    summary = {name: {"growth_rate": r.growth_rate, "verdict": r.verdict}
               for name, r in runs.items()}
    files.append(write_json(ctx.out / "aoi-fig2.json", {
        "scenario": sc.summary(), "steps": AOI_STEPS, "trials": trials,
        "observers": summary,
        "closed_forms": {"naive-uniform": (1 + 5 ** 0.5) / 2, "naive-tree": 2.0}}))
    fig = figure(figsize=(13, 4.2))
    axes = fig.subplots(1, 3)
    titles = {"naive-uniform": "(left) consensus weights uniform over neighbours",
              "naive-tree": "(right) weights along the tree rooted at node 1",
              "aoi": "freshness-index observer (Sec. 4; not in Fig. 2)"}
    steps = np.arange(AOI_STEPS + 1)
    # (family, freshness observer?) per panel: left, right, ours
    panels = (("naive-uniform", False), ("naive-tree", False), ("aoi", True))
    for ax, (name, freshness) in zip(axes, panels, strict=True):
        e = runs[name].errors[0]
        for i in range(e.shape[1]):
            if freshness:
                ax.plot(steps, e[:, i], "o-", ms=3, lw=1.1, label=f"node {i + 1}")
            else:
                ok = np.isfinite(e[:, i]) & (e[:, i] > 0)
                ax.plot(steps[ok], e[ok, i], "o-", ms=3, lw=1.1, label=f"node {i + 1}")
        if not freshness:
            ax.set_yscale("log")
            ax.set_title(f"{titles[name]}\ngrowth {fmt(runs[name].growth_rate)} per step",
                         fontsize=9)
        else:
            ax.set_xlim(-0.5, 12)
            ax.set_title(f"{titles[name]}\n{runs[name].verdict}", fontsize=9)
        ax.set_xlabel("time-step k")
        ax.set_ylabel(r"estimation error $|x[k] - \hat{x}_i[k]|$")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("aoi Fig. 2 (ours): estimation errors of the nodes, x[k+1] = 2 x[k], "
                 "trial 0", fontsize=11)
    ours = [f"Growth of the largest node error per step: uniform weights "
            f"{fmt(runs['naive-uniform'].growth_rate)} (golden ratio 1.6180), tree weights "
            f"{fmt(runs['naive-tree'].growth_rate)} (a = 2).",
            f"Freshness-index observer: {runs['aoi'].verdict}.",
            f"{trials} trials (x[0] ~ N(0, 1)); the figure shows trial 0, the CSV all."]
    return ItemResult(fig, files, ours, numbers=summary)


# -- the declaration ---------------------------------------------------------------------

_AOI_HYP = ("Assumption 1: the graph sequence is jointly strongly connected over windows of "
            "T steps", "(A, C) jointly observable", "noise-free")

CLAIMS = (
    Claim("A-theorem1", AOI, "Theorem 1",
          "the gains can be designed so that every node's error converges to zero "
          "exponentially at any desired rate rho",
          _AOI_HYP[:2] + ("rate design: A_jj - L_j C_jj with distinct real eigenvalues, "
                          "rho_1 < ... < rho_N < rho",), "theorem", check_aoi_theorem1),
    Claim("A-lemma2", AOI, "Lemma 2",
          "a non-source node adopts the source's value (index 1) at every step at which "
          "the source is its in-neighbour", ("the rules (7)-(14); no assumption on the "
                                             "graphs",),
          "theorem", check_aoi_lemma2),
    Claim("A-lemma3", AOI, "Lemma 3",
          "every freshness index is triggered (finite) by step (N-1)T", _AOI_HYP[:1],
          "theorem", check_aoi_lemma3, searches=("A-corollary1",)),
    Claim("A-lemma4", AOI, "Lemma 4, eq. (18)",
          "a non-source estimate with freshness index m >= 1 is the source's estimate m "
          "steps old propagated by A_jj, plus the lower substates of nodes v(t) != j "
          "(eq. 18)", ("the rules (7)-(14); no assumption on the graphs",), "theorem",
          check_aoi_lemma4),
    Claim("A-lemma5", AOI, "Lemma 5",
          "from step (N-1)T on every freshness index is at most 2(N-1)T", _AOI_HYP[:1],
          "theorem", check_aoi_lemma5, searches=("A-corollary1",)),
    Claim("A-corollary1", AOI, "Corollary 1",
          "with deadbeat gains the freshness-index observer's error is zero after at most "
          "n + 2N(N-1)T steps",
          _AOI_HYP, "theorem", check_aoi_corollary1, searches=("A-corollary1",)),
    Claim("A-naive-growth", AOI, "Section 3, Fig. 2",
          "naive consensus with uniform weights or with weights along the tree rooted at "
          "node 1 has unstable errors on the Section 3 example (x[k+1] = 2 x[k])",
          ("the Section 3 example",), "theorem", check_aoi_naive),
)

ITEMS = (
    Item("aoi-fig2", AOI, "Fig. 2",
         "Estimation error plots of the nodes for the model in Figure 1. Simulations are "
         "performed for a model where a = 2. The figure on the left corresponds to the "
         "case where consensus weights are distributed uniformly among neighbors, while the "
         "one on the right is the case where weights are placed along a tree rooted at "
         "node 1.",
         "In each case (uniform weights, tree weights) the error dynamics are unstable; "
         "node 1 has perfect information of the state.",
         ("Figure 1's two graphs are an image; we infer them from the text: (a) = "
          "{1->2, 2->3}, (b) = {1->3, 3->2} (netsim.aoi).",
          "The initial state and the horizon are not given: x[0] ~ N(0, 1), 40 steps; the "
          "errors are on a log axis (zeros, exact estimates, are not drawn).",
          "The third panel (freshness-index observer, Section 4) is ours, for comparison."),
         ("A-naive-growth", "A-corollary1"),
         _build_aoi_fig2, seeded=True),
    CONVERGENCE_ITEM,
)

PAPER = register_paper(Paper(
    key=AOI,
    title="Finite-time distributed observer with age of information (aoi)",
    text_file=TEXT_FILE,
    scenarios=("aoi-example", "aoi-random"),
    claims=CLAIMS,
    items=ITEMS,
    searches=(Search("A-corollary1", search_aoi),),
))
