"""The built-in MAC models, loaded, and the lookup by name."""

from __future__ import annotations

from netsim.medium import aloha, can, csma, p2p, switched, tdma  # noqa: F401  (register)
from netsim.medium.core import Medium
from netsim.medium.registry import MAC_MODELS

__all__ = ["mac_model"]


def mac_model(name: str) -> type[Medium]:
    """The MAC model registered as ``name`` (ValueError naming the known ones)."""
    try:
        return MAC_MODELS[name]
    except KeyError:
        raise ValueError(f"unknown medium model {name!r}; known: "
                         f"{', '.join(sorted(MAC_MODELS))}") from None
