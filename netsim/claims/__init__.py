"""Paper claims as executable checks.

:data:`REGISTRY` holds every checkable statement of the four papers (LCSYS2022, the
delay-tolerant paper, the aoi paper, the dkfe paper) as a :class:`Claim`: its id, paper,
equation or section, the statement, its hypotheses and a check returning an
:class:`Outcome` in the one vocabulary of :data:`netsim.verdicts.VERDICT_TABLE`
(``refuted`` with a twice-verified counterexample, ``proved for this instance``, ``no
counterexample in M instances of <family> (seed s)``, or ``undecided`` with the reason).
:func:`run_claims` runs a selection (``netsim claims``),
first the counterexample searches and long runs the claims read, in worker processes;
:mod:`netsim.claims.search` is the seeded search and shrinking engine (and the LCSYS2022
Theorem 1 search), :mod:`netsim.claims.searches` the searches of the other claims
stated over a class of systems; :mod:`netsim.bench.claims` holds the same claims'
checks on a ``netsim bench delay-tolerance`` report (the papers' printed numbers are in
:mod:`netsim.papers`); :mod:`netsim.claims.findings`
generates the documentation's findings (``docs/findings.rst``) from a report.
"""

from __future__ import annotations

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
from netsim.claims.registry import CLAIM_IDS, REGISTRY, get_claim, select
from netsim.claims.report import ClaimResult, ClaimsReport, run_claims

__all__ = ["REFUTED", "PROVED", "NO_COUNTEREXAMPLE", "UNDECIDED", "VERDICTS", "Claim",
           "Context", "Evidence", "Outcome",
           "CLAIM_IDS", "REGISTRY", "get_claim", "select", "ClaimResult", "ClaimsReport",
           "run_claims"]
