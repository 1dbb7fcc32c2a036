"""The papers' statements checked against a delay-tolerance report (its claim rows).

Each paper module declares its rows (:class:`netsim.papers.BenchRow`: a claim id and a
check putting the paper's statement next to a bench report's numbers, made with
:func:`claim_row`); :func:`bench_rows` maps every claim id to its check
(``bench_rows()[id](data)``, a bench row; a preset lists the ids it checks,
:func:`default_rows` are checked on a report without a preset) and
:func:`disagreements` lists the statements and cells where they disagree. The claim
registry (:mod:`netsim.claims`) names the same functions as its claims' ``bench`` form;
this module never imports :mod:`netsim.claims`, so the bench sits below the claims in the
layering.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from netsim.bench.fmt import describe_cell as _describe
from netsim.bench.fmt import fmt_value as _f

__all__ = ["CLAIMS", "bench_rows", "default_rows", "claim_row", "disagreements"]  # noqa: F822


def claim_row(cid: str, paper: str, text: str, ours: str, agrees: bool | None,
              kind: str = "claim") -> dict[str, Any]:
    """A paper's statement next to ours. ``kind``: ``claim`` (a qualitative result that
    should hold for any instance satisfying the paper's assumptions) or ``instance`` (a
    number of the paper's own, unprinted system; ours differs by construction)."""
    status = {True: "agrees", False: "DISAGREES" if kind == "claim" else "differs",
              None: "not checked"}[agrees]
    return {"id": cid, "paper": paper, "kind": kind, "claim": text, "ours": ours,
            "agrees": agrees, "status": status}


def bench_rows() -> dict[str, Callable[[dict[str, Any]], dict[str, Any]]]:
    """Every paper's bench checks by claim id: ``bench_rows()[id](report) -> dict``."""
    from netsim.papers import papers

    return {r.claim: r.check for p in papers() for r in p.bench_rows}


def default_rows() -> tuple[str, ...]:
    """The claim ids checked on a report without a preset, in their declared rank."""
    from netsim.papers import papers

    rows = [r for p in papers() for r in p.bench_rows if r.default_rank is not None]
    return tuple(r.claim for r in sorted(rows, key=lambda r: r.default_rank or 0))


def __getattr__(name: str) -> Any:
    if name == "CLAIMS":
        return bench_rows()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def disagreements(data: dict[str, Any]) -> list[str]:
    """The report's disagreements: failed ``claim`` checks and ``bound violated`` cells."""
    out = [f"{c['paper']}: \"{c['claim']}\" -- ours: {c['ours']}"
           for c in data["claims"] if c["agrees"] is False and c["kind"] == "claim"]
    for c in data["cells"]:
        if c["verdict"] == "bound violated" and not c.get("computed_as"):
            a = c["analytics"]
            why = []
            if a["predicted_stable"] and c["measured"]["verdict"] != "stable":
                why.append(f"{a['bound_name']} = {_f(a['bound'])} < 1 predicts stability, "
                           f"measured {_describe(c)}")
            if a.get("exact_violates_bound"):
                why.append(f"{a['exact_kind']} {_f(a['exact'], 6)} > {a['bound_name']} "
                           f"{_f(a['bound'], 6)}")
            out.append(f"{c['family']}, {c['setting']}, tau {c['tau']}: " + "; ".join(why))
    return out
