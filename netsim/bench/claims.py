"""The papers' statements checked against a delay-tolerance report.

The statements and the paper numbers live in the claim registry (:mod:`netsim.claims`);
``CLAIMS[id](data)`` is the bench form of registry claim ``id``, and
:func:`disagreements` lists the statements and cells where they disagree.
"""

from __future__ import annotations

from netsim.claims.bench_checks import disagreements
from netsim.claims.registry import REGISTRY

__all__ = ["CLAIMS", "disagreements"]

#: The bench checks by registry id (a preset lists the ids it checks).
CLAIMS = {cid: c.bench for cid, c in REGISTRY.items() if c.bench is not None}
