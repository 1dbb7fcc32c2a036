"""Paper claims as executable checks.

Every registered paper (:mod:`netsim.papers`) declares its checkable statements as
:class:`Claim` objects: id, paper, equation or section, the statement, its hypotheses and
a check returning an :class:`Outcome` in the one vocabulary of
:data:`netsim.verdicts.VERDICT_TABLE` (``refuted`` with a twice-verified counterexample,
``proved for this instance``, ``no counterexample in M instances of <family> (seed s)``,
or ``undecided`` with the reason). :data:`REGISTRY` collects them;
:func:`run_claims` runs a selection (``netsim claims``),
first the counterexample searches and long runs the claims read, in worker processes;
:mod:`netsim.claims.search` is the seeded search and shrinking engine,
:mod:`netsim.claims.searches` the scalar delayed instances and the dispatch of the
papers' searches (``Paper.searches``), :mod:`netsim.claims.checks` the helpers the
papers' checks share; :mod:`netsim.bench.claims` runs the claims' bench rows on a
``netsim bench delay-tolerance`` report; :mod:`netsim.claims.findings`
generates the documentation's findings (``docs/findings.rst``) from a report.
"""

from __future__ import annotations

from typing import Any

from netsim.claims.core import (
    NO_COUNTEREXAMPLE,
    PROVED,
    REFUTED,
    UNDECIDED,
    VERDICTS,
    Claim,
    Context,
    Evidence,
    Outcome,
)
from netsim.claims.registry import all_claims, get_claim, select
from netsim.claims.report import ClaimResult, ClaimsReport, run_claims

__all__ = ["REFUTED", "PROVED", "NO_COUNTEREXAMPLE", "UNDECIDED", "VERDICTS", "Claim",
           "Context", "Evidence", "Outcome",
           "CLAIM_IDS", "REGISTRY", "all_claims", "get_claim", "select", "ClaimResult",
           "ClaimsReport", "run_claims"]


def __getattr__(name: str) -> Any:
    # REGISTRY and CLAIM_IDS come from the paper modules: computed on access
    if name in ("REGISTRY", "CLAIM_IDS"):
        from netsim.claims import registry

        return getattr(registry, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
