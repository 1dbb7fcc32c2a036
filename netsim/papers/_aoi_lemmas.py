"""The aoi paper's Lemmas 2 and 4 as claims, and the convergence-time experiment as a
reproduce item (issue 31).

The computations are in :mod:`netsim.aoichecks`: the lemmas are checked at every step,
node and substate of noise-free runs of netsim's freshness-index observer (a counted,
seeded search, run in the check and cached under ``search:A-lemmas-2-4``), and a hit
is re-checked on a second implementation of the paper's rules (eqs. 7-14). The
experiment measures the step at which every node's error reaches zero against
Corollary 1's bound n + 2N(N-1)T over seeded random instances, without and with link
delays (the latter outside the paper, with netsim's ``age`` extension).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from netsim.claims.core import NO_COUNTEREXAMPLE, REFUTED, UNDECIDED, Context, Outcome
from netsim.claims.search import DEFAULT_INSTANCES
from netsim.reproduce.items import BuildContext, Item, ItemResult

__all__ = ["check_aoi_lemma2", "check_aoi_lemma4", "build_aoi_convergence",
           "AOI_CONVERGENCE_INSTANCES", "AOI_CONVERGENCE_MIN_INSTANCES",
           "CONVERGENCE_ITEM"]

#: Random instances of the convergence-time experiment (each run at every delay): the
#: run's ``--trials`` between these bounds.
AOI_CONVERGENCE_INSTANCES = 60
AOI_CONVERGENCE_MIN_INSTANCES = 10


def _lemma_search(context: Context) -> Any:
    from netsim.aoichecks import search_lemmas

    count = DEFAULT_INSTANCES if context.instances is None else int(context.instances)
    ss = np.random.SeedSequence(context.seed, spawn_key=(31, 4))
    return context.cached("search:A-lemmas-2-4",
                          lambda: search_lemmas(ss, count, context.deadline()))


def _example(context: Context) -> dict[str, Any]:
    """Both lemmas on the Section 3 example (Assumption 1 fails there; the lemmas do
    not ask it)."""
    from netsim.aoi import illustrative_example
    from netsim.aoichecks import lemma2_check, lemma4_check, netsim_record

    def make() -> dict[str, Any]:
        rec = netsim_record(illustrative_example(steps=40))
        return {"lemma_2": lemma2_check(rec).to_dict(), "lemma_4": lemma4_check(rec).to_dict()}
    return context.cached("aoi-lemmas-example", make)


def _lemma_claim(context: Context, which: str) -> Outcome:
    from netsim.aoichecks import paper_recheck

    found = _lemma_search(context)
    ex = _example(context)[which]
    row = found.families[0] if found.families else {}
    numbers: dict[str, Any] = {"search": found.to_dict(), "section_3_example": ex}
    if which == "lemma_2":
        counted = (f"{row.get('lemma_2_events', 0)} steps at which a source was an "
                   "in-neighbour, each followed by its adoption with index 1")
        ex_words = (f"Section 3 example: {ex['events']} such steps, "
                    f"{len(ex['violations'])} violations")
        ex_bad = bool(ex["violations"])
    else:
        counted = (f"{row.get('lemma_4_identities', 0)} identities (18) with index >= 1, "
                   f"largest relative residual {row.get('lemma_4_max_residual', 0):.1e}")
        ex_words = (f"Section 3 example: {ex['checked']} identities, largest residual "
                    f"{ex['max_residual']:.1e}")
        ex_bad = bool(ex["violations"])
    hits = found.instance is not None and which in (found.details or {}).get("violated", [])
    if hits or ex_bad:
        if hits:
            again = paper_recheck(found.instance)
            numbers["second_implementation"] = again
            what = f"search instance {found.instance.to_dict()}: {found.details[which]}"
            if again[which]["violations"]:
                return Outcome(REFUTED, f"{what}; the paper's rules re-implemented violate it "
                               f"too ({again[which]['violations'][:3]})", numbers,
                               {**found.instance.to_dict(), "details": found.details})
        else:
            what = ex_words
        why = (f"netsim's observer violates it ({what}) but the re-implemented rules do not: "
               "a fault of the implementation, not of the lemma")
        return Outcome(UNDECIDED, why, numbers, reason=why)
    if not found.complete:
        why = found.incomplete_reason()
        return Outcome(UNDECIDED, f"{counted}; {ex_words}; but {why}", numbers, reason=why)
    return Outcome(NO_COUNTEREXAMPLE, f"{counted}; {ex_words}", numbers,
                   evidence=found.evidence())


def check_aoi_lemma2(context: Context) -> Outcome:
    """aoi Lemma 2: a non-source node adopts the source whenever it is an in-neighbour."""
    return _lemma_claim(context, "lemma_2")


def check_aoi_lemma4(context: Context) -> Outcome:
    """aoi Lemma 4: an estimate with index m is the source's estimate m steps old,
    propagated (eq. 18)."""
    return _lemma_claim(context, "lemma_4")


# -- the reproduce item -------------------------------------------------------------------


def build_aoi_convergence(ctx: BuildContext) -> ItemResult:
    """The convergence time against n + 2N(N-1)T over random instances (the run's
    ``--trials``, clipped to AOI_CONVERGENCE_MIN_INSTANCES..AOI_CONVERGENCE_INSTANCES),
    link delays 0, 1, 2 (figure, CSV of every run, JSON summary)."""
    from netsim.aoichecks import CONVERGENCE_DELAYS, convergence_times
    from netsim.reproduce.items import figure, write_csv, write_json

    count = min(AOI_CONVERGENCE_INSTANCES, max(AOI_CONVERGENCE_MIN_INSTANCES, ctx.trials))
    ct = ctx.cached("aoi-convergence", lambda: convergence_times(ctx.seed, count,
                                                                 CONVERGENCE_DELAYS))
    summary = ct.summary()
    rows = [(s.n, s.N, s.T, s.seed, s.delay, s.converged_at, s.bound, s.ratio, s.steps,
             s.tolerance) for s in ct.samples]
    files = [write_csv(ctx.out / "aoi-convergence-time.csv",
                       ("n", "N", "T", "seed", "delay", "converged_at", "bound", "ratio",
                        "steps", "tolerance"), rows),
             write_json(ctx.out / "aoi-convergence-time.json", ct.to_dict())]
    fig = figure(figsize=(12, 4.2))
    left, right = fig.subplots(1, 2)
    top = max([s.ratio for s in ct.samples if s.ratio is not None] + [1.0])
    bins = np.linspace(0.0, max(1.05, top * 1.05), 30)
    for d in sorted(summary):
        r = [s.ratio for s in ct.by_delay(d) if s.ratio is not None]
        left.hist(r, bins=bins, histtype="step", lw=1.5,
                  label=f"delay {d}" + (" (paper's model)" if d == 0 else " ('age')"))
        pts = [(s.bound, s.converged_at) for s in ct.by_delay(d) if s.converged_at is not None]
        if pts:
            b, c = zip(*pts, strict=True)
            right.scatter(b, c, s=12, alpha=0.7, label=f"delay {d}")
    left.axvline(1.0, color="k", ls="--", lw=1, label="bound n + 2N(N-1)T")
    left.set_xlabel("converged step / (n + 2N(N-1)T)")
    left.set_ylabel("instances")
    left.legend(fontsize=8)
    lim = max(s.bound for s in ct.samples) * 1.05
    right.plot([0, lim], [0, lim], "k--", lw=1, label="converged step = bound")
    right.set_xlabel("Corollary 1 bound n + 2N(N-1)T")
    right.set_ylabel("converged step (all nodes' errors zero)")
    right.legend(fontsize=8)
    fig.suptitle(f"aoi Corollary 1: finite-time convergence against its bound, "
                 f"{ct.instances} random instances (seed {ct.seed})", fontsize=11)
    ours = []
    for d, v in summary.items():
        q = v["ratio_quantiles"]
        ours.append(
            f"Delay {d}{' (paper)' if d == 0 else ' (age extension)'}: converged in "
            f"{v['converged']} of {v['instances']} instances; converged step / bound: "
            + ("-" if q is None else
               f"min {q[0]:.2f}, median {q[1]:.2f}, 90th percentile {q[2]:.2f}, max "
               f"{q[3]:.2f}")
            + f"; {v['above_bound']} above the bound"
            + ("" if d == 0 or v["max_ratio_delay_scaled"] is None else
               f" (max against n + 2N(N-1)T(d+1): {v['max_ratio_delay_scaled']:.2f})") + ".")
    return ItemResult(fig, files, ours, numbers={str(d): v for d, v in summary.items()})


#: The reproduce item (declared by the aoi paper module).
CONVERGENCE_ITEM = Item(
    "aoi-convergence-time", "aoi", "Corollary 1 (experiment)",
    "(Not a figure of the paper: an experiment it leaves out.) Convergence time of the "
    "freshness-index observer with deadbeat gains against Corollary 1's bound "
    "n + 2N(N-1)T, as a distribution over random instances, without and with link delays.",
    "Corollary 1: the observer gains can be designed so that the estimation error of each "
    "node converges to zero in at most n + 2N(N-1)T time-steps. The paper reports no "
    "experiment on it.",
    ("An experiment the paper leaves out: seeded random jointly observable systems on "
     "random graph sequences jointly strongly connected over T steps (netsim.aoi."
     "random_aoi_scenario; n 2..6, N 2..5, T 1..3, Assumption 1 checked), noise-free, "
     "x(0) ~ N(0, I), deadbeat gains.",
     "Delays are outside the paper: with a link delay d > 0 netsim's 'age' extension "
     "ages a delayed message (the default 'discard' would drop every message and never "
     "converge); n + 2N(N-1)T(d+1) is our scaling, not the paper's."),
    ("A-corollary1",),
    build_aoi_convergence, seeded=True)
