"""``netsim reproduce``: build every item, look up its claims, write the Markdown report."""

from __future__ import annotations

import re
import resource
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from netsim.reproduce.items import REPRODUCE_TRIALS, BuildContext, Item, items_for

__all__ = ["ClaimVerdict", "ItemReport", "ReproduceResult", "claim_verdicts", "output_names",
           "reproduce",
           "item_claim_ids",
           "DEFAULT_TRIALS", "CLAIM_BUDGET"]

#: Default Monte Carlo trials (a paper's own count where it says, ``Paper.mc_trials``).
DEFAULT_TRIALS = 100
#: Seconds after which each claim's counterexample search is cut short (None: never; the
#: searches are counted in instances, netsim.claims.search).
CLAIM_BUDGET: float | None = None


@dataclass
class ClaimVerdict:
    """A registry claim next to an item: the standalone check, and this run's bench row."""

    id: str
    where: str
    statement: str
    verdict: str
    summary: str
    reason: str | None = None
    this_run: str | None = None  # bench status (agrees / differs / DISAGREES / ...)
    this_run_ours: str | None = None
    #: Why the standalone verdict and this run's status differ, when they seem to.
    contrast: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class ItemReport:
    """One figure or table: files, our numbers, differences, claims."""

    item: Item
    png: str
    data_files: list[str]
    ours: list[str]
    differs: list[str]
    claims: list[ClaimVerdict]
    missing_claims: list[str]
    seconds: float
    numbers: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.item.id, "paper": self.item.paper, "label": self.item.label,
                "png": self.png, "data": self.data_files, "ours": self.ours,
                "differs": self.differs, "claims": [c.to_dict() for c in self.claims],
                "missing_claims": self.missing_claims, "seconds": round(self.seconds, 2)}


@dataclass
class ReproduceResult:
    """Everything one run wrote."""

    out: Path
    trials: int
    seed: int
    items: list[ItemReport]
    report: Path
    elapsed: float
    #: CPU seconds of this process (with workers > 1 the benchmark's worker processes,
    #: children of a forkserver, are not included).
    cpu: float

    def to_dict(self) -> dict[str, Any]:
        return {"out": str(self.out), "report": str(self.report), "trials": self.trials,
                "seed": self.seed, "elapsed_s": round(self.elapsed, 2),
                "cpu_s": round(self.cpu, 2), "items": [r.to_dict() for r in self.items]}

    def format_text(self) -> str:
        lines = [f"{r.item.paper} {r.item.label}: {r.png}, {', '.join(r.data_files)}"
                 for r in self.items]
        lines.append(f"{len(self.items)} figures and tables, report {self.report} "
                     f"({self.elapsed:.1f} s wall, {self.cpu:.1f} s CPU in this process, "
                     f"{self.trials} trials)")
        return "\n".join(lines) + "\n"


def _cpu() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _label_pattern(label: str) -> re.Pattern[str]:
    return re.compile(r"(?<![\w.])" + re.escape(label) + r"(?![\w])")


def item_claim_ids(item: Item) -> list[str]:
    """The registry claims an item bears on: its own ids, then every other claim of the
    same paper whose ``where`` names the item's label."""
    from netsim.claims import REGISTRY

    ids = list(item.claims)
    pat = _label_pattern(item.label)
    for cid, claim in REGISTRY.items():
        if claim.paper == item.paper and pat.search(claim.where) and cid not in ids:
            ids.append(cid)
    return ids


def _run_claim_searches(items: Sequence[Item], context: Any, workers: int) -> None:
    """Run the counterexample searches the items' claims read, in ``workers`` processes,
    into ``context``'s cache (the checks then read them, as ``netsim claims`` does)."""
    from netsim.claims import REGISTRY
    from netsim.claims.report import run_searches

    names = [n for it in items for cid in item_claim_ids(it) if cid in REGISTRY
             for n in REGISTRY[cid].searches if ":" not in n]
    if names:
        context.cache.update(run_searches(list(dict.fromkeys(names)), context.seed,
                                          context.budget, max(1, workers)))


def claim_verdicts(item: Item, bench_rows: Sequence[dict[str, Any]], context: Any,
                   cache: dict[str, Any]) -> tuple[list[ClaimVerdict], list[str]]:
    """The registry claims an item bears on, each with its standalone verdict.

    The claims are the item's ids (a missing id is reported, not an error) and any other
    claim of the same paper whose ``where`` names the item's label (``Fig. 6``). Checks
    run once per id (``cache``). ``bench_rows``: the bench's rows for this run's data.
    """
    from netsim.claims import get_claim

    ids = item_claim_ids(item)
    rows = {r.get("id"): r for r in bench_rows}
    out, missing = [], []
    for cid in ids:
        try:
            claim = get_claim(cid)
        except KeyError:
            missing.append(cid)
            continue
        if cid not in cache:
            try:
                cache[cid] = claim.run(context)
            except Exception as exc:  # a broken check must not lose the whole report
                from netsim.claims import UNDECIDED, Outcome

                cache[cid] = Outcome(UNDECIDED, f"the check raised {type(exc).__name__}",
                                     reason=f"the check raised {type(exc).__name__}: {exc}")
        o = cache[cid]
        row = rows.get(cid)
        status = None if row is None else row.get("status")
        out.append(ClaimVerdict(cid, claim.where, claim.statement, o.label, o.summary,
                                o.reason, status, None if row is None else row.get("ours"),
                                _contrast(o.verdict, status)))
    return out, missing


def _contrast(verdict: str, status: str | None) -> str | None:
    """The reason a standalone verdict and this run's bench status differ (None: they do
    not seem to)."""
    from netsim.claims import NO_COUNTEREXAMPLE, PROVED, REFUTED

    if status is None:
        return None
    agrees = status.lower().startswith("agree")
    if verdict == REFUTED and agrees:
        return ("this run's cells agree with the statement, but the standalone check refutes "
                "it on cases this run does not contain (its counterexample is in the numbers)")
    if verdict in (PROVED, NO_COUNTEREXAMPLE) and status.lower().startswith("disagree"):
        return ("this run's cells contradict the statement, while the standalone check "
                "found no counterexample in its own cases: see this run's numbers")
    return None


def _md_escape(text: str) -> str:
    return str(text).replace("|", "/").replace("\n", " ")


def output_names(items: Sequence[Item]) -> list[str]:
    """The file names :func:`reproduce` writes into its folder (checked before any work):
    the report, each item's figure and its data files as most items name them (an item's
    other data files are checked as they are written)."""
    names = ["report.md"]
    for item in items:
        names += [f"{item.id}.png", f"{item.id}.csv", f"{item.id}.json"]
    return names


def _markdown(result: ReproduceResult) -> str:
    out = ["# netsim reproduce: the papers' figures and tables", "",
           f"{len(result.items)} items, {result.trials} Monte Carlo trials, seed "
           f"{result.seed}; {result.elapsed:.0f} s wall, {result.cpu:.0f} s CPU in this process. "
           "Each item: "
           "our figure, what the paper states, where our system differs, and the verdicts "
           "of the claims it bears on (`netsim claims`; *this run* is the same claim "
           "checked on this run's data where the benchmark has such a check).", ""]
    from netsim.papers import papers

    titles = {p.key: p.title for p in papers()}
    for paper in titles:
        mine = [r for r in result.items if r.item.paper == paper]
        if not mine:
            continue
        out += [f"- **{titles[paper]}**: "
                + ", ".join(f"[{r.item.label}](#{r.item.id})" for r in mine)]
    out.append("")
    for paper in titles:
        mine = [r for r in result.items if r.item.paper == paper]
        if not mine:
            continue
        out += [f"## {titles[paper]}", ""]
        for r in mine:
            it = r.item
            out += [f'<a id="{it.id}"></a>', "", f"### {paper} {it.label}", "",
                    f"![{paper} {it.label}]({r.png})", "",
                    "Data: " + ", ".join(f"[{f}]({f})" for f in r.data_files), "",
                    f"**The paper's caption:** {it.caption}", "",
                    f"**What the paper states:** {it.paper_says}", "",
                    "**Ours:**", *[f"- {line}" for line in r.ours], "",
                    "**Where our system differs from the paper's:**",
                    *[f"- {line}" for line in r.differs], ""]
            if r.claims:
                out += ["**Claims:**", "", "| claim | where | verdict | this run | numbers |",
                        "|---|---|---|---|---|"]
                for c in r.claims:
                    why = f" ({c.reason})" if c.reason else ""
                    run = (f"{c.this_run}: {c.this_run_ours}" if c.this_run else "-")
                    if c.contrast:
                        run += f" [{c.contrast}]"
                    out.append(f"| {c.id} | {_md_escape(c.where)} | **{c.verdict}** | "
                               f"{_md_escape(run)} | {_md_escape(c.summary + why)} |")
                out.append("")
            if r.missing_claims:
                out += ["Claim ids not in this registry: " + ", ".join(r.missing_claims), ""]
    return "\n".join(out) + "\n"


def reproduce(papers: Sequence[str] | None = None, *, out: str | Path = "reproduce-out",
              trials: int = DEFAULT_TRIALS, seed: int = 0, workers: int = 2,
              claim_budget: float | None = CLAIM_BUDGET,
              progress: Callable[[str], None] | None = None) -> ReproduceResult:
    """Regenerate the figures and tables of ``papers`` (default all) into ``out``.

    Parameters
    ----------
    papers : sequence of str, optional
        Keys of the registered papers (:func:`netsim.papers.paper_keys`,
        case-insensitive).
    out : path
        Folder for ``<item>.png``, its data (CSV / JSON) and ``report.md``.
    trials : int
        Monte Carlo trials of every simulated curve (precision against time).
    seed : int
        Seed of the items' own runs (the delay benchmarks use their scenario's seed).
    workers : int
        Local processes of the delay benchmarks.
    claim_budget : float, optional
        Seconds after which each claim check's counterexample search is cut short (its
        verdict then undecided); None: no time limit.
    progress : callable(str), optional
        Called with each item's id when it is done.

    Returns
    -------
    ReproduceResult
    """
    from netsim.claims import Context
    from netsim.outfiles import check_output_folder, safe_output, write_text_safely

    chosen = items_for(papers)
    if trials < 1:
        raise ValueError(f"trials must be a positive integer, got {trials}")
    folder = check_output_folder(out, "--out", output_names(chosen))
    folder.mkdir(parents=True, exist_ok=True)
    ctx = BuildContext(folder, int(trials), int(seed), int(workers))
    claim_ctx = Context(seed=int(seed), budget=None if claim_budget is None
                        else float(claim_budget), out=None)
    claim_ctx.cache[REPRODUCE_TRIALS] = int(trials)
    checks: dict[str, Any] = {}
    start, cpu0 = time.perf_counter(), _cpu()
    _run_claim_searches(chosen, claim_ctx, int(workers))
    reports = []
    for item in chosen:
        t0 = time.perf_counter()
        built = item.build(ctx)
        png = f"{item.id}.png"
        with safe_output(folder / png, "--out") as tmp:
            built.figure.savefig(tmp, format="png")
        claims, missing = claim_verdicts(item, built.bench_claims, claim_ctx, checks)
        reports.append(ItemReport(item, png, built.data_files, built.ours,
                                  list(item.differs) + built.differs, claims, missing,
                                  time.perf_counter() - t0, built.numbers))
        if progress is not None:
            progress(item.id)
    result = ReproduceResult(folder, int(trials), int(seed), reports, folder / "report.md",
                             time.perf_counter() - start, _cpu() - cpu0)
    write_text_safely(result.report, _markdown(result), "--out")
    return result
