"""Running a selection of claims: results, the Markdown report, the JSON form."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from netsim.claims.core import (
    NO_COUNTEREXAMPLE,
    PROVED,
    REFUTED,
    UNDECIDED,
    VERDICTS,
    Claim,
    Context,
    Outcome,
)
from netsim.threads import limit_worker_threads, single_threaded_blas

__all__ = ["ClaimResult", "ClaimsReport", "run_claims", "run_searches", "search_names"]


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):
        return _jsonable(v.item())
    return v


@dataclass
class ClaimResult:
    """One claim with its outcome and the seconds its check took."""

    claim: Claim
    outcome: Outcome
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return _jsonable({**self.claim.describe(), **self.outcome.to_dict(),
                          "seconds": round(self.seconds, 3)})

    def line(self) -> str:
        """One line: id, verdict (with its evidence), the deciding numbers."""
        o = self.outcome
        return f"{self.claim.id:<16} {o.label.upper()}: {o.summary}"


@dataclass
class ClaimsReport:
    """Everything one ``netsim claims`` run checked.

    Attributes
    ----------
    results : list of ClaimResult
    seed : int
    budget : float or None
        Seconds after which a search was cut short (None: no time limit).
    instances : int or None
        Random instances per search (None: each search's default).
    elapsed : float
    out : str or None
        The folder of the report and the counterexample scenarios.
    files : list of str
        Files written there.
    """

    results: list[ClaimResult]
    seed: int
    budget: float | None
    elapsed: float = 0.0
    out: str | None = None
    files: list[str] = field(default_factory=list)
    instances: int | None = None

    def counts(self) -> dict[str, int]:
        """How many claims got each verdict."""
        return {v: sum(r.outcome.verdict == v for r in self.results) for v in VERDICTS}

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form (what ``--json`` prints)."""
        return {"claims": [r.to_dict() for r in self.results], "counts": self.counts(),
                "seed": self.seed, "budget_s": self.budget, "instances": self.instances,
                "elapsed_s": round(self.elapsed, 3), "out": self.out, "files": self.files}

    def format_text(self) -> str:
        """One line per claim and a count."""
        c = self.counts()
        lines = [r.line() for r in self.results]
        lines.append(f"{len(self.results)} claims: {c[REFUTED]} refuted, {c[PROVED]} proved "
                     f"for this instance, {c[NO_COUNTEREXAMPLE]} without a counterexample in "
                     f"the instances searched, {c[UNDECIDED]} undecided ({self.elapsed:.1f} s, "
                     f"seed {self.seed})" + (f"; report and scenarios in {self.out}"
                                              if self.out else ""))
        return "\n".join(lines) + "\n"

    def markdown(self) -> str:
        """The report file: a table, then each claim with its hypotheses and numbers."""
        out = ["# Paper claims checked by `netsim claims`", "",
               f"seed {self.seed}, "
               + (f"{self.instances} random instances per search"
                  if self.instances is not None else "the searches' default instance counts")
               + (f", time budget {self.budget:g} s per search" if self.budget is not None
                  else ", no time budget") + f", {self.elapsed:.1f} s", "",
               "| id | paper | where | verdict | deciding numbers |", "|---|---|---|---|---|"]
        for r in self.results:
            s = r.outcome.summary.replace("|", "/")
            out.append(f"| {r.claim.id} | {r.claim.paper} | {r.claim.where} | "
                       f"{r.outcome.label.replace('|', '/')} | {s} |")
        for r in self.results:
            o = r.outcome
            out += ["", f"## {r.claim.id}: {r.claim.paper}, {r.claim.where}", "",
                    f"Statement: {r.claim.statement}.", ""]
            if r.claim.hypotheses:
                out += ["Hypotheses:", *[f"- {h}" for h in r.claim.hypotheses], ""]
            out.append(f"Verdict: **{o.label}**. {o.summary}")
            if o.counterexample:
                out += ["", "Counterexample:", "```json",
                        json.dumps(_jsonable(o.counterexample), indent=1), "```"]
        return "\n".join(out) + "\n"


def _search_key(name: str) -> str:
    """The context cache key of a search's or job's result."""
    if ":" in name:  # a job, PREFIX:ARGUMENT
        return name
    from netsim.claims.searches import searches

    found = searches().get(name)
    return found.key if found is not None else f"search:{name}"


def search_names(claims: Sequence[Claim]) -> list[str]:
    """The distinct searches and runs (``Claim.searches``) the checks of ``claims`` read."""
    return list(dict.fromkeys(n for c in claims for n in c.searches))


def run_searches(names: Sequence[str], seed: int, budget: float | None = None,
                 workers: int = 2,
                 progress: Callable[[str], None] | None = None,
                 instances: int | None = None) -> dict[str, Any]:
    """Run the counterexample searches ``names`` (each over its counted instances, cut
    short after ``budget`` seconds if given), in up to
    ``workers`` worker processes (forkserver, as :mod:`netsim.sweep`); returns the
    :class:`~netsim.claims.core.Context` cache entries by key. ``progress`` is called
    with each name as its search finishes."""
    from netsim.claims.searches import run_search

    names = list(dict.fromkeys(names))
    tick = progress if progress is not None else (lambda _name: None)
    if workers <= 1 or len(names) <= 1:
        found = {}
        for n in names:
            found[_search_key(n)] = run_search(n, seed, budget, instances)
            tick(n)
        return found
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = multiprocessing.get_context("forkserver")
    # the counterexample searches first, then the shorter jobs
    names.sort(key=lambda n: ":" in n)
    with ProcessPoolExecutor(max_workers=min(workers, len(names)), mp_context=ctx,
                             initializer=limit_worker_threads) as pool:
        futures = {pool.submit(run_search, n, seed, budget, instances): n for n in names}
        for future in as_completed(futures):
            future.result()  # a failed search fails loudly here
            tick(futures[future])
        return {_search_key(n): f.result() for f, n in futures.items()}


@single_threaded_blas()
def run_claims(claims: Sequence[Claim], *, seed: int = 0, budget: float | None = None,
               instances: int | None = None,
               out: str | Path | None = None,
               progress: Callable[[str], None] | None = None,
               workers: int = 2,
               search_progress: Callable[[str], None] | None = None) -> ClaimsReport:
    """Run the checks of ``claims``; write ``claims.md`` and counterexamples into ``out``.

    Parameters
    ----------
    claims : sequence of Claim
    seed : int
        Seed of the random searches.
    budget : float, optional
        Seconds after which each counterexample search is cut short (its verdict then
        ``undecided`` unless it found a counterexample); None (default): no time limit,
        every search runs its counted instances, so the verdicts depend on the seed only.
    instances : int, optional
        Random instances per search (default: each search's own count).
    out : str or path, optional
        Folder for the report and the scenario files (None: nothing is written).
    progress : callable(str), optional
        Called with each claim's id after its check.
    workers : int
        Worker processes for the counterexample searches the claims read (they run
        first; 1: in this process).
    search_progress : callable(str), optional
        Called with each search's name (:func:`search_names`) as it finishes.

    Returns
    -------
    ClaimsReport
    """
    folder = None if out is None else Path(out)
    context = Context(seed=seed, budget=budget, instances=instances, out=folder)
    start = time.monotonic()
    context.cache.update(run_searches(search_names(claims), seed, budget, workers,
                                      search_progress, instances))
    results = []
    for claim in claims:
        t0 = time.monotonic()
        outcome = claim.run(context)
        results.append(ClaimResult(claim, outcome, time.monotonic() - t0))
        if progress is not None:
            progress(claim.id)
    report = ClaimsReport(results, seed, budget, time.monotonic() - start,
                          None if folder is None else str(folder), instances=instances)
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
        for r in results:
            cx = r.outcome.counterexample or {}
            if cx.get("scenario"):
                report.files.append(cx["scenario"])
        md = folder / "claims.md"
        report.files.insert(0, str(md))
        from netsim.outfiles import write_text_safely

        write_text_safely(md, report.markdown(), "--out")
    return report


