"""``netsim reproduce``: every figure and table of the registered papers, with a report.

Each paper module (:mod:`netsim.papers`) declares the figures and tables that have data
(``Paper.items``; :data:`~netsim.reproduce.items.ITEMS` collects them);
:func:`~netsim.reproduce.report.reproduce` writes each as a PNG with its data (CSV /
JSON) and a Markdown report that puts our figure beside the paper's caption and text,
where our system differs, and the claim registry's verdicts.
"""

from __future__ import annotations

from typing import Any

from netsim.reproduce.command import add_reproduce_parser, cmd_reproduce
from netsim.reproduce.items import Item, items_for
from netsim.reproduce.report import DEFAULT_TRIALS, ReproduceResult, reproduce

__all__ = ["ITEMS", "PAPERS", "Item", "items_for", "reproduce",  # noqa: F822
           "ReproduceResult", "DEFAULT_TRIALS", "add_reproduce_parser", "cmd_reproduce"]


def __getattr__(name: str) -> Any:
    # ITEMS and PAPERS come from the paper modules: computed on access
    if name in ("ITEMS", "PAPERS"):
        import importlib

        return getattr(importlib.import_module("netsim.reproduce.items"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
