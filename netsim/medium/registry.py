"""The registry of MAC models: each model module declares itself with :func:`register_mac`."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from netsim.medium.core import Medium

__all__ = ["MAC_MODELS", "register_mac", "mac_model"]

#: name (``network.medium.model``) -> Medium subclass.
MAC_MODELS: dict[str, type[Medium]] = {}


def register_mac(cls: type[Medium]) -> type[Medium]:
    """Class decorator: register a :class:`netsim.medium.core.Medium` under its ``name``."""
    MAC_MODELS[cls.name] = cls
    return cls


def mac_model(name: str) -> type[Medium]:
    """The MAC model registered as ``name`` (ValueError naming the known ones)."""
    import netsim.medium  # noqa: F401  (registers the built-in models)

    try:
        return MAC_MODELS[name]
    except KeyError:
        raise ValueError(f"unknown medium model {name!r}; known: "
                         f"{', '.join(sorted(MAC_MODELS))}") from None
