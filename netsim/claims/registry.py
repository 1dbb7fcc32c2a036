"""The registry: every checkable statement of the registered papers, one :class:`Claim`
each.

The claims are declared by the paper modules (``Paper.claims``, :mod:`netsim.papers`);
this module collects them in registry order. :data:`REGISTRY` and :data:`CLAIM_IDS` are
computed on access (module ``__getattr__``), so a paper registered later shows up.
"""

from __future__ import annotations

from typing import Any

from netsim.claims.core import Claim

__all__ = ["REGISTRY", "CLAIM_IDS", "all_claims", "get_claim", "select"]  # noqa: F822


def all_claims() -> list[Claim]:
    """Every registered paper's claims, in registry order."""
    from netsim.papers import papers

    return [c for p in papers() for c in p.claims]


def _registry() -> dict[str, Claim]:
    return {c.id: c for c in all_claims()}


def __getattr__(name: str) -> Any:
    if name == "REGISTRY":
        return _registry()  # every claim by id, in registry order
    if name == "CLAIM_IDS":
        return tuple(_registry())  # the ids in order
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def get_claim(claim_id: str) -> Claim:
    """Return the claim ``claim_id`` (KeyError with the known ids otherwise)."""
    registry = _registry()
    try:
        return registry[claim_id]
    except KeyError:
        raise KeyError(f"unknown claim {claim_id!r}; known: {', '.join(registry)}") from None


def select(names: list[str] | tuple[str, ...] | None) -> list[Claim]:
    """Claims named by id or by paper key (case-insensitive); all for an empty
    selection. ValueError names an unknown one."""
    claims = all_claims()
    if not names:
        return claims
    registry = {c.id: c for c in claims}
    papers = {c.paper.lower() for c in claims}
    out: list[Claim] = []
    for name in names:
        if name.lower() in papers:
            picked = [c for c in claims if c.paper.lower() == name.lower()]
        elif name in registry:
            picked = [registry[name]]
        else:
            raise ValueError(f"unknown paper or claim {name!r} (papers: "
                             f"{', '.join(sorted(papers))}; claims: {', '.join(registry)})")
        out += [c for c in picked if c not in out]
    return out
