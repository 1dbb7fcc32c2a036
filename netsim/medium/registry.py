"""The registry of MAC models: each model module declares itself with :func:`register_mac`.

:func:`netsim.medium.catalog.mac_model` looks a model up after loading the built-in ones.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from netsim.medium.core import Medium

__all__ = ["MAC_MODELS", "register_mac"]

#: name (``network.medium.model``) -> Medium subclass.
MAC_MODELS: dict[str, type[Medium]] = {}


def register_mac(cls: type[Medium]) -> type[Medium]:
    """Class decorator: register a :class:`netsim.medium.core.Medium` under its ``name``."""
    MAC_MODELS[cls.name] = cls
    return cls
