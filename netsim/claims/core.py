"""The claim registry's data types: a paper statement, its check and the check's outcome.

Every checkable statement of a paper is one :class:`Claim`; its ``check`` gets a
:class:`Context` (seed, instance counts, optional time budget, output folder, cached
instances) and returns an :class:`Outcome` in the one verdict vocabulary of
:data:`netsim.verdicts.VERDICT_TABLE`:

- ``refuted``: a counterexample, verified by exact analysis and by simulation (for a
  printed number: the exact recomputation of the paper's own instance);
- ``proved for this instance``: an exact computation on a fixed instance;
- ``no counterexample``: printed ``no counterexample in M instances of <family> (seed
  s)``: a search counted in instances drawn from a seed found none;
- ``undecided``: with the reason (a search cut short by its time budget, a number of the
  paper's unprinted system, a counterexample the simulation did not confirm, ...).

An instance where a claim's hypotheses fail is never evidence for it. No verdict depends on
wall-clock time: searches are counted, and a budget (off by default) can only cut one short,
which makes its verdict ``undecided`` unless a counterexample was already found.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["REFUTED", "PROVED", "NO_COUNTEREXAMPLE", "UNDECIDED", "VERDICTS", "Claim",
           "Context", "Outcome", "Evidence"]

REFUTED = "refuted"
PROVED = "proved for this instance"
NO_COUNTEREXAMPLE = "no counterexample"
UNDECIDED = "undecided"
#: The four verdicts of a check (:data:`netsim.verdicts.VERDICT_TABLE`).
VERDICTS = (REFUTED, PROVED, NO_COUNTEREXAMPLE, UNDECIDED)


@dataclass(frozen=True)
class Evidence:
    """What a ``no counterexample`` verdict rests on: a counted, seeded search.

    Attributes
    ----------
    instances : int
        Instances searched that satisfy the claim's hypotheses (and optimiser
        evaluations, counted the same way).
    family : str
        The instance families searched, in words.
    seed : int
        The seed they were drawn from.
    """

    instances: int
    family: str
    seed: int

    def words(self) -> str:
        """``M instances of <family> (seed s)``."""
        return f"{self.instances} instances of {self.family} (seed {self.seed})"

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"instances": self.instances, "family": self.family, "seed": self.seed}


@dataclass
class Outcome:
    """What a claim's check found.

    Attributes
    ----------
    verdict : str
        One of :data:`VERDICTS`.
    summary : str
        The deciding numbers in one line.
    numbers : dict
        The deciding numbers by name (JSON-safe).
    counterexample : dict or None
        For ``refuted``: the instance that contradicts the statement, with its two
        verifications (and, when written, ``scenario``: the path of a scenario file
        reproducing it).
    reason : str or None
        For ``undecided``: why.
    headline : str or None
        The deciding numbers without seconds; None: ``summary`` has none. The findings
        of docs/findings.rst are made of headlines.
    evidence : Evidence or None
        For ``no counterexample``: the counted search it rests on (required).
    """

    verdict: str
    summary: str
    numbers: dict[str, Any] = field(default_factory=dict)
    counterexample: dict[str, Any] | None = None
    reason: str | None = None
    headline: str | None = None
    evidence: Evidence | None = None

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {VERDICTS}, got {self.verdict!r}")
        if self.verdict == NO_COUNTEREXAMPLE and self.evidence is None:
            raise ValueError("a 'no counterexample' verdict needs its Evidence")
        if self.verdict == UNDECIDED and not self.reason:
            raise ValueError("an 'undecided' verdict needs its reason")

    @property
    def label(self) -> str:
        """The verdict as printed: ``no counterexample in M instances of <family> (seed
        s)``, ``undecided: <reason>``, ``refuted``, ``proved for this instance``."""
        if self.verdict == NO_COUNTEREXAMPLE and self.evidence is not None:
            return f"no counterexample in {self.evidence.words()}"
        if self.verdict == UNDECIDED and self.reason:
            return f"undecided: {self.reason}"
        return self.verdict

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"verdict": self.verdict, "label": self.label, "summary": self.summary,
                "numbers": self.numbers, "counterexample": self.counterexample,
                "reason": self.reason, "headline": self.headline or self.summary,
                "evidence": None if self.evidence is None else self.evidence.to_dict()}


@dataclass
class Context:
    """What every check may use: seed, budget, output folder and shared instances.

    Attributes
    ----------
    seed : int
        Seed of every random search.
    budget : float or None
        Seconds a counterexample search may spend (per search) before it is cut short
        (its verdict then ``undecided``); None (the default): no time limit, the search
        runs its counted instances.
    instances : int or None
        Random instances each search draws (None: each search's default,
        :data:`netsim.claims.search.DEFAULT_INSTANCES`); the hard families and the
        optimiser scale with it.
    out : pathlib.Path or None
        Folder for counterexample scenarios (None: nothing is written).
    cache : dict
        Instances shared between checks (e.g. a paper's instance and its gains).
    """

    seed: int = 0
    budget: float | None = None
    instances: int | None = None
    out: Path | None = None
    cache: dict[str, Any] = field(default_factory=dict)

    def cached(self, key: str, make: Callable[[], Any]) -> Any:
        """Return ``cache[key]``, computing it with ``make()`` the first time."""
        if key not in self.cache:
            self.cache[key] = make()
        return self.cache[key]

    def deadline(self) -> float:
        """``time.monotonic()`` at which a search started now must stop (inf: none)."""
        return math.inf if self.budget is None else time.monotonic() + self.budget


@dataclass(frozen=True)
class Claim:
    """One statement of a paper.

    Attributes
    ----------
    id : str
        Short identifier, a letter of the paper, a dash and the statement (``X-lemma2``).
    paper : str
        The key of the paper that declares it (``netsim.papers.Paper.key``).
    where : str
        Equation, theorem or section.
    statement : str
        The statement in one sentence.
    hypotheses : tuple of str
        Its hypotheses as the paper states them.
    kind : str
        ``theorem`` (should hold for every instance satisfying the hypotheses),
        ``printed`` (a number or table of the paper's own instance) or ``figure`` (a
        Monte Carlo observation of the paper's simulation).
    check : callable(Context) -> Outcome, optional
        The standalone check run by ``netsim claims``.
    printed : mapping
        The paper's printed numbers this claim refers to.
    bench : callable(dict) -> dict, optional
        The form used by ``netsim bench delay-tolerance`` on its report (a bench row).
    searches : tuple of str
        Counterexample searches the check reads (names of the papers' searches,
        ``Paper.searches``, or ``PREFIX:ARGUMENT`` of a job, ``bench:PRESET`` or one of
        ``Paper.jobs``); :func:`netsim.claims.run_claims` runs them first, in parallel
        worker processes.
    """

    id: str
    paper: str
    where: str
    statement: str
    hypotheses: tuple[str, ...] = ()
    kind: str = "theorem"
    check: Callable[[Context], Outcome] | None = None
    printed: Mapping[str, Any] = field(default_factory=dict)
    bench: Callable[[dict[str, Any]], dict[str, Any]] | None = None
    searches: tuple[str, ...] = ()

    def run(self, context: Context) -> Outcome:
        """Run the standalone check (``not checkable`` if there is none)."""
        if self.check is None:
            return Outcome(UNDECIDED, "no standalone check",
                           reason="only checked on a bench report")
        return self.check(context)

    def describe(self) -> dict[str, Any]:
        """The claim without its check (JSON-safe)."""
        return {"id": self.id, "paper": self.paper, "where": self.where,
                "statement": self.statement, "hypotheses": list(self.hypotheses),
                "kind": self.kind, "printed": dict(self.printed),
                "searches": list(self.searches)}
