"""Heavy modules loaded on first use, and checks that do not load them (start-up
latency, issue 34).

``nx = lazy_module("networkx")`` binds a stand-in that imports networkx the first time
one of its attributes is read: a module that only builds graphs on some paths imports
networkx only on those paths. :func:`issparse` and :func:`is_digraph` answer without
importing scipy.sparse or networkx: an object of theirs can exist only once they are
imported.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

__all__ = ["lazy_module", "issparse", "is_digraph"]


class _LazyModule:
    """Stand-in for a module, imported when an attribute is first read."""

    __slots__ = ("_name",)

    def __init__(self, name: str) -> None:
        self._name = name

    def __getattr__(self, attribute: str) -> Any:
        module = sys.modules.get(self._name)
        if module is None:
            module = importlib.import_module(self._name)
        return getattr(module, attribute)

    def __repr__(self) -> str:
        return f"<lazy module {self._name!r}>"


def lazy_module(name: str) -> Any:
    """A stand-in for module ``name`` that imports it when an attribute is first read."""
    return _LazyModule(name)


def issparse(x: Any) -> bool:
    """``scipy.sparse.issparse(x)``, without importing scipy.sparse."""
    sp = sys.modules.get("scipy.sparse")
    return sp is not None and bool(sp.issparse(x))


def is_digraph(x: Any) -> bool:
    """``isinstance(x, networkx.DiGraph)``, without importing networkx."""
    nx = sys.modules.get("networkx")
    return nx is not None and isinstance(x, nx.DiGraph)
