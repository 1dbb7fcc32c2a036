"""The papers' figures and tables: the item type, how a builder writes its data.

Every paper module (:mod:`netsim.papers`) declares its items (``Paper.items``): one
figure or table of a paper that has data each (the papers' diagrams are left out). An
item's builder computes the data with the functions that already exist (``netsim bench
delay-tolerance``'s :func:`netsim.bench.delay_tolerance.run_delay_tolerance` through
:func:`bench_data`, the models' own analyses), writes the data (CSV and JSON, with
:func:`write_csv` and :func:`write_json`) and returns a ``matplotlib.figure.Figure`` (no
pyplot, :func:`figure`) drawn with the paper's axes. The report
(:mod:`netsim.reproduce.report`) puts each beside the paper's text. :data:`ITEMS`,
:data:`PAPERS` and :data:`PAPER_TITLES` are computed on access from the registry.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from netsim.models.jsonsafe import json_tree

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["PAPERS", "PAPER_TITLES", "Item", "ItemResult", "BuildContext",  # noqa: F822
           "ITEMS", "items", "items_for", "write_csv", "write_json", "fmt", "figure",
           "positive", "bench_data", "bench_curves", "bench_files", "mse_axes",
           "REPRODUCE_TRIALS"]

#: Key of the run's ``--trials`` in the claims context's cache while ``netsim reproduce``
#: checks its items' claims (absent under ``netsim claims``): a check whose computation is
#: shared with an item reads it to compute what the item computes (the same quick share).
REPRODUCE_TRIALS = "reproduce:trials"


def __getattr__(name: str) -> Any:
    from netsim.papers import papers

    if name == "PAPERS":  # paper keys in report order
        return tuple(p.key for p in papers())
    if name == "PAPER_TITLES":
        return {p.key: p.title for p in papers()}
    if name == "ITEMS":
        return items()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass
class ItemResult:
    """What a builder made: the figure, the data files, numbers for the report."""

    figure: Figure
    data_files: list[str]
    ours: list[str]
    differs: list[str] = field(default_factory=list)
    bench_claims: list[dict[str, Any]] = field(default_factory=list)
    numbers: dict[str, Any] = field(default_factory=dict)


@dataclass
class BuildContext:
    """Settings and shared results of one ``netsim reproduce`` run."""

    out: Path
    trials: int
    seed: int = 0
    workers: int = 2
    cache: dict[str, Any] = field(default_factory=dict)

    def cached(self, key: str, make: Callable[[], Any]) -> Any:
        """``cache[key]``, computed by ``make()`` the first time."""
        if key not in self.cache:
            self.cache[key] = make()
        return self.cache[key]


@dataclass(frozen=True)
class Item:
    """One figure or table of a paper.

    Attributes
    ----------
    id : str
        File stem (``<paper>-fig1``).
    paper : str
        The key of the paper that declares it.
    label : str
        As the paper names it (``Fig. 1``, ``Table I``).
    caption : str
        The paper's caption.
    paper_says : str
        What the paper's text states about it.
    differs : tuple of str
        Where our system differs from the paper's (fixed facts; builders add numbers).
    claims : tuple of str
        Claim registry ids it bears on (missing ids are skipped).
    build : callable(BuildContext) -> ItemResult
    seeded : bool
        Its data depends on ``--seed`` (``BuildContext.seed``).
    """

    id: str
    paper: str
    label: str
    caption: str
    paper_says: str
    differs: tuple[str, ...]
    claims: tuple[str, ...]
    build: Callable[[BuildContext], ItemResult]
    seeded: bool = False


# -- helpers ---------------------------------------------------------------------------------


def write_csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Write a CSV file safely (non-finite floats as empty cells); return its name."""
    from netsim.outfiles import safe_output

    with safe_output(path, "--out") as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in rows:
            w.writerow(["" if (isinstance(v, float) and not math.isfinite(v)) else v
                        for v in row])
    return path.name


def write_json(path: Path, data: Any) -> str:
    """Write JSON (non-finite numbers as null) safely; return the file's name."""
    from netsim.outfiles import write_text_safely

    write_text_safely(path, json.dumps(json_tree(data), indent=1, allow_nan=False) + "\n",
                      "--out")
    return path.name


def fmt(v: Any, digits: int = 4) -> str:
    """A number for the report (``-`` for None)."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    v = float(v)
    if not math.isfinite(v):
        return str(v)
    if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
        return f"{v:.3e}"
    return f"{v:.{digits}f}"


def figure(**kwargs: Any) -> Figure:
    """A ``matplotlib.figure.Figure`` (matplotlib imported here, on first use)."""
    from matplotlib.figure import Figure

    return Figure(dpi=110, layout="constrained", **kwargs)


def positive(values: Sequence[float]) -> np.ndarray:
    """``values`` with the non-finite and non-positive ones as NaN (for a log axis)."""
    a = np.asarray(values, dtype=float)
    return np.where(np.isfinite(a) & (a > 0), a, np.nan)


# -- the delay benchmarks ----------------------------------------------------------------------


def bench_data(ctx: BuildContext, preset_name: str) -> dict[str, Any]:
    """The report of the bench preset ``preset_name`` with the run's trials (cached)."""
    def make() -> dict[str, Any]:
        from netsim.bench.delay_tolerance import run_delay_tolerance
        from netsim.bench.presets import presets
        from netsim.models.scenario import resolve_scenario

        preset = presets()[preset_name]
        scenario = resolve_scenario(preset.scenario)
        extra: dict[str, Any] = ({"families": list(preset.families)} if preset.families
                                 else {})
        return run_delay_tolerance(
            scenario, taus=preset.taus, delays=preset.delays, trials=ctx.trials,
            steps=preset.steps, seed=scenario.seed, preset=preset, workers=ctx.workers,
            executor="serial" if ctx.workers == 1 else "local", progress=False, **extra)

    return ctx.cached(f"bench:{preset_name}", make)


def bench_curves(data: dict[str, Any], family: str) -> list[tuple[str, int, list[int],
                                                                   list[float], str]]:
    """(setting, tau, steps, mse, verdict) of ``family``'s cells (tau = 0 once)."""
    out = []
    for c in data["cells"]:
        if c["family"] != family:
            continue
        curve = (c.get("measured") or {}).get("curve")
        if not curve:
            continue
        mse = [math.nan if v is None else float(v) for v in curve["mse"]]
        out.append((c["setting"], int(c["tau"]), list(curve["steps"]), mse,
                    c["measured"]["verdict"]))
    return out


def bench_files(ctx: BuildContext, item_id: str, data: dict[str, Any], family: str
                ) -> list[str]:
    """Write ``family``'s MSE curves (CSV) and the report (JSON); return the names."""
    rows = []
    for setting, tau, steps, mse, _ in bench_curves(data, family):
        rows += [(family, setting, tau, k, v) for k, v in zip(steps, mse, strict=True)]
    files = [write_csv(ctx.out / f"{item_id}.csv",
                        ("family", "delay_setting", "tau_bar", "step", "mse"), rows)]
    files.append(write_json(ctx.out / f"{item_id}.json", data))
    return files


def mse_axes(ax: Any, title: str) -> None:
    """A log MSE axis over the time step, titled, with a legend."""
    ax.set_yscale("log")
    ax.set_xlabel("time step k")
    ax.set_ylabel("MSE")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)


def items() -> tuple[Item, ...]:
    """Every registered paper's items, in registry order."""
    from netsim.papers import papers

    return tuple(it for p in papers() for it in p.items)


def items_for(papers: Sequence[str] | None) -> list[Item]:
    """The items of the given papers (case-insensitive keys); all for none. ValueError
    names an unknown paper."""
    from netsim.papers import paper_keys

    every = items()
    if not papers:
        return list(every)
    known = paper_keys()
    keys = {p.lower(): p for p in known}
    chosen = []
    for name in papers:
        key = keys.get(str(name).lower())
        if key is None:
            raise ValueError(f"unknown paper {name!r}; choose from {', '.join(known)}")
        if key not in chosen:
            chosen.append(key)
    return [it for it in every if it.paper in chosen]
