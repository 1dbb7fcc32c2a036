"""The paper registry: each paper netsim reproduces declares itself in one module.

A paper module (``netsim/papers/lcsys2022.py``, ``delay_tolerant.py``, ``aoi.py``,
``dkfe.py``, or a module of your own) builds one :class:`Paper` and calls
:func:`register_paper` at import. The paper's scenarios, claims (``netsim claims``),
reproduce items (``netsim reproduce``), bench presets and claim rows (``netsim bench``),
counterexample searches and delay bounds are all fields of that :class:`Paper`; the
claims, reproduce and bench packages only iterate :func:`papers` and never name a paper
(``tests/test_paper_layout.py`` holds this). The built-in paper modules are listed in
:data:`BUILTIN_PAPERS` only, imported on the first call of :func:`papers` (so ``netsim
run`` never imports them).

This module imports nothing of :mod:`netsim.claims`, :mod:`netsim.reproduce` or
:mod:`netsim.bench`: a paper module imports their data types (``Claim``, ``Item``,
``Preset``), they import this registry.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["BUILTIN_PAPERS", "Paper", "Search", "BenchRow", "DelayBound", "register_paper",
           "unregister_paper", "papers", "get_paper", "paper_keys", "delay_bounds",
           "PaperError"]

#: Modules that declare the built-in papers, in report order (imported on first use).
BUILTIN_PAPERS = (
    "netsim.papers.lcsys2022",
    "netsim.papers.delay_tolerant",
    "netsim.papers.aoi",
    "netsim.papers.dkfe",
)


class PaperError(ValueError):
    """A paper declared twice, or a paper key that is not registered."""


@dataclass(frozen=True)
class Search:
    """A counted counterexample search (or another long computation) a claim reads.

    Attributes
    ----------
    name : str
        What a claim's ``searches`` names it by (e.g. the claim id it serves).
    run : callable(seed, instances, deadline) -> Found
        The search: ``seed`` a ``numpy.random.SeedSequence`` (its own stream of the run's
        seed) or, with ``own_seed``, the run's int seed itself; ``instances`` the count of
        random instances; ``deadline`` a ``time.monotonic()`` value (inf: none).
    own_seed : bool
        Seed the search with the run's seed itself instead of its own stream.
    cache_key : str or None
        The :class:`netsim.claims.Context` cache key its result is stored under (None:
        ``search:NAME``).
    """

    name: str
    run: Callable[[Any, int, float], Any]
    own_seed: bool = False
    cache_key: str | None = None

    @property
    def key(self) -> str:
        """The cache key of its result."""
        return self.cache_key or f"search:{self.name}"


@dataclass(frozen=True)
class BenchRow:
    """A paper statement checked on a ``netsim bench delay-tolerance`` report.

    Attributes
    ----------
    claim : str
        The claim id (as in the claim registry).
    check : callable(dict) -> dict
        ``check(report)``: the bench row (``id, paper, kind, claim, ours, agrees,
        status``).
    default_rank : int or None
        Not None: the row is checked on every report without a preset, in increasing
        rank (None: only for the presets that list it).
    """

    claim: str
    check: Callable[[dict[str, Any]], dict[str, Any]]
    default_rank: int | None = None


@dataclass(frozen=True)
class DelayBound:
    """A paper's bound on the spectral radius of a delayed error recursion at bound tau,
    as ``netsim bench`` reports it beside the exact value.

    Attributes
    ----------
    key : str
        Its key in a bench cell's analytics, in the homogeneous scan's rows, and the
        attribute of :class:`netsim.analysis` rows holding it (e.g. ``bound_eq26``).
    run_key : str
        Its key in ``netsim run``'s analytics (a sweep's columns).
    name : str
        The bound's name in a cell (``bound_name``).
    compute : callable(P, A, C, L, tau) -> float
    recursions : tuple of str
        The error recursions (``netsim.estimators.registry.RECURSION_*``) it is the bound
        of; a family declaring one of them gets this bound and its prediction.
    prediction : str
        ``"tau_star"`` (stable for tau up to the scan's tau*) or ``"any"`` (any bounded
        delay when rho(A-hat) < 1).
    predicted_by : str
        Why, in a tolerance row.
    exact_kinds : mapping
        Recursion -> what a cell's exact value is for it.
    help : str
        The bound in ``netsim bench delay-tolerance --help``.
    legend : str
        The bound in the report's column legend.
    prediction_legend : str
        The prediction in the report's tolerance legend.
    tau_star_label : str
        How the report's header names tau* ("" unless ``prediction`` is ``tau_star``).
    """

    key: str
    run_key: str
    name: str
    compute: Callable[..., float]
    recursions: tuple[str, ...]
    prediction: str
    predicted_by: str
    exact_kinds: Mapping[str, str] = field(default_factory=dict)
    help: str = ""
    legend: str = ""
    prediction_legend: str = ""
    tau_star_label: str = ""


@dataclass(frozen=True)
class Paper:
    """One paper: what netsim reproduces and checks of it.

    Attributes
    ----------
    key : str
        Short name (``LCSYS2022``): the claims' and items' ``paper``, what ``netsim claims
        PAPER`` and ``netsim reproduce PAPER`` accept (case-insensitive).
    title : str
        As the reproduce report heads it.
    text_file : str
        The paper's plain text (in the project's shared papers folder).
    scenarios : tuple of str
        The built-in scenarios (``netsim/models/scenarios/*.toml``) of the paper.
    claims : tuple of netsim.claims.Claim
        Its statements as executable checks, in report order.
    items : tuple of netsim.reproduce.items.Item
        Its figures and tables (``netsim reproduce``).
    presets : tuple of netsim.bench.presets.Preset
        Its bench presets (``netsim bench delay-tolerance PRESET``).
    sweeps : tuple of netsim.bench.presets.SweepPreset
        Its sweep presets (``netsim bench sweep PRESET``).
    bench_rows : tuple of BenchRow
        Its statements checked on a bench report.
    searches : tuple of Search
        The counterexample searches its claims read (``Claim.searches``).
    jobs : mapping
        Prefix -> ``job(argument, seed)``: other long computations its claims read, named
        ``PREFIX:ARGUMENT`` in ``Claim.searches`` (run first, in worker processes).
    delay_bounds : tuple of DelayBound
        Its delay bounds (the bench's ``bound`` columns).
    delay_settings : mapping
        Bench delay setting -> the figure that uses it (``Fig. 1``), cited in the
        setting's description.
    printed : mapping
        The paper's printed numbers by name.
    mc_trials : int or None
        Monte Carlo trials of the paper's own figures, if it says.
    """

    key: str
    title: str
    text_file: str
    scenarios: tuple[str, ...] = ()
    claims: tuple[Any, ...] = ()
    items: tuple[Any, ...] = ()
    presets: tuple[Any, ...] = ()
    sweeps: tuple[Any, ...] = ()
    bench_rows: tuple[BenchRow, ...] = ()
    searches: tuple[Search, ...] = ()
    jobs: Mapping[str, Callable[[str, int], Any]] = field(default_factory=dict)
    delay_bounds: tuple[DelayBound, ...] = ()
    delay_settings: Mapping[str, str] = field(default_factory=dict)
    printed: Mapping[str, Any] = field(default_factory=dict)
    mc_trials: int | None = None


_PAPERS: dict[str, Paper] = {}
_LOADED = False


def register_paper(paper: Paper, *, replace: bool = False) -> Paper:
    """Add ``paper`` to the registry (PaperError if its key is taken, unless
    ``replace``); returns it."""
    taken = _PAPERS.get(paper.key)
    if taken is not None and not replace and taken is not paper:
        raise PaperError(f"paper {paper.key!r} is already registered")
    _PAPERS[paper.key] = paper
    return paper


def unregister_paper(key: str) -> None:
    """Remove the paper ``key`` (nothing if it is not registered)."""
    _PAPERS.pop(key, None)


def _load_builtin() -> None:
    global _LOADED
    if not _LOADED:
        _LOADED = True
        for module in BUILTIN_PAPERS:
            importlib.import_module(module)


def papers() -> tuple[Paper, ...]:
    """Every registered paper: the built-in ones in :data:`BUILTIN_PAPERS` order, then
    those registered from Python."""
    _load_builtin()
    return tuple(_PAPERS.values())


def paper_keys() -> tuple[str, ...]:
    """The keys of :func:`papers`."""
    return tuple(p.key for p in papers())


def get_paper(key: str) -> Paper:
    """The paper ``key`` (case-insensitive); PaperError names the known ones."""
    for p in papers():
        if p.key.lower() == str(key).lower():
            return p
    raise PaperError(f"unknown paper {key!r}; known: {', '.join(paper_keys())}")


def delay_bounds() -> tuple[DelayBound, ...]:
    """Every paper's delay bounds, in registry order."""
    return tuple(b for p in papers() for b in p.delay_bounds)
