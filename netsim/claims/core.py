"""The claim registry's data types: a paper statement, its check and the check's outcome.

Every checkable statement of the four papers is one :class:`Claim`; its ``check`` gets a
:class:`Context` (seed, time budget, output folder, cached instances) and returns an
:class:`Outcome`: ``holds``, ``fails`` (with the deciding numbers and a counterexample)
or ``not checkable`` (with the reason). A theorem with a counterexample ``fails``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["HOLDS", "FAILS", "NOT_CHECKABLE", "VERDICTS", "Claim", "Context", "Outcome"]

HOLDS = "holds"
FAILS = "fails"
NOT_CHECKABLE = "not checkable"
#: The three verdicts of a check.
VERDICTS = (HOLDS, FAILS, NOT_CHECKABLE)


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
        For ``fails``: the instance that contradicts the statement (and, when written,
        ``scenario``: the path of a scenario file reproducing it).
    reason : str or None
        For ``not checkable``: why.
    headline : str or None
        The deciding numbers without what depends on the machine's speed (how many
        instances a search tried in its budget, seconds); None: ``summary`` has none.
        The README's findings are made of headlines.
    """

    verdict: str
    summary: str
    numbers: dict[str, Any] = field(default_factory=dict)
    counterexample: dict[str, Any] | None = None
    reason: str | None = None
    headline: str | None = None

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {VERDICTS}, got {self.verdict!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"verdict": self.verdict, "summary": self.summary, "numbers": self.numbers,
                "counterexample": self.counterexample, "reason": self.reason,
                "headline": self.headline or self.summary}


@dataclass
class Context:
    """What every check may use: seed, budget, output folder and shared instances.

    Attributes
    ----------
    seed : int
        Seed of every random search.
    budget : float
        Seconds a counterexample search may spend (per search).
    out : pathlib.Path or None
        Folder for counterexample scenarios (None: nothing is written).
    cache : dict
        Instances shared between checks (e.g. the LCSYS2022 instance and its gains).
    """

    seed: int = 0
    budget: float = 20.0
    out: Path | None = None
    cache: dict[str, Any] = field(default_factory=dict)

    def cached(self, key: str, make: Callable[[], Any]) -> Any:
        """Return ``cache[key]``, computing it with ``make()`` the first time."""
        if key not in self.cache:
            self.cache[key] = make()
        return self.cache[key]

    def deadline(self) -> float:
        """``time.monotonic()`` at which a search started now must stop."""
        return time.monotonic() + self.budget


@dataclass(frozen=True)
class Claim:
    """One statement of a paper.

    Attributes
    ----------
    id : str
        Short identifier (``L-`` LCSYS2022, ``T-`` delay-tolerant, ``A-`` aoi, ``D-`` dkfe).
    paper : str
        The paper's short name (``LCSYS2022``, ``delay-tolerant``, ``aoi``, ``dkfe``).
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
        Counterexample searches the check reads (names in
        :data:`netsim.claims.searches.SEARCHES`); :func:`netsim.claims.run_claims` runs
        them first, in parallel worker processes.
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
            return Outcome(NOT_CHECKABLE, "no standalone check",
                           reason="only checked on a bench report")
        return self.check(context)

    def describe(self) -> dict[str, Any]:
        """The claim without its check (JSON-safe)."""
        return {"id": self.id, "paper": self.paper, "where": self.where,
                "statement": self.statement, "hypotheses": list(self.hypotheses),
                "kind": self.kind, "printed": dict(self.printed),
                "searches": list(self.searches)}
