"""``netsim reproduce``: every figure and table of the four papers, with a report.

:data:`~netsim.reproduce.items.ITEMS` lists the figures and tables that have data
(LCSYS2022 Fig. 1; delay-tolerant Figs. 1-2; aoi Fig. 2; dkfe Table I and Figs. 3-8);
:func:`~netsim.reproduce.report.reproduce` writes each as a PNG with its data (CSV /
JSON) and a Markdown report that puts our figure beside the paper's caption and text,
where our system differs, and the claim registry's verdicts.
"""

from __future__ import annotations

from netsim.reproduce.command import add_reproduce_parser, cmd_reproduce
from netsim.reproduce.items import ITEMS, PAPERS, Item, items_for
from netsim.reproduce.report import DEFAULT_TRIALS, ReproduceResult, reproduce

__all__ = ["ITEMS", "PAPERS", "Item", "items_for", "reproduce", "ReproduceResult",
           "DEFAULT_TRIALS", "add_reproduce_parser", "cmd_reproduce"]
