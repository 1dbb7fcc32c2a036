"""Benchmark presets: the estimator families, the delay settings, the papers' studies.

The presets themselves are declared by the paper modules (:mod:`netsim.papers`,
``Paper.presets``); :func:`presets` collects them. :data:`PRESETS` and
:data:`DELAY_SETTINGS` are computed on first access (module ``__getattr__``), so that
importing the bench does not import the papers.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["DELAY_SETTINGS", "DELAY_MODELS", "FAMILIES", "NO_DELAY", "PRESETS",  # noqa: F822
           "Preset", "SweepPreset", "presets", "sweep_presets", "delay_settings"]


#: Estimator families benchmarked, in table order (the last one is the reference).
FAMILIES = ("compensated", "uncompensated", "block", "centralized-kf")


#: Delay settings: name -> (``delays.model``, description, notes). The papers' figures
#: that use a setting (``Paper.delay_settings``) are added to its notes.
_SETTINGS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "homogeneous": ("homogeneous", "fixed, tau on every link", ()),
    "heterogeneous": ("heterogeneous", "fixed, uniform in 0..tau per link, drawn once",
                      ("delays.seed",)),
    "asynchronous-fixed": ("heterogeneous", "asynchronous time-invariant: fixed, uniform "
                           "in 0..tau per link, drawn once", ()),
    "time-varying": ("asynchronous", "asynchronous time-varying: a uniform draw in 0..tau "
                     "per link per message, reordering", ()),
    "synchronous": ("synchronous", "synchronous time-varying: one uniform draw in 0..tau "
                    "per step, common to all links", ()),
}

#: Delay settings: name -> ``delays.model`` (no paper imported).
DELAY_MODELS: dict[str, str] = {name: s[0] for name, s in _SETTINGS.items()}


#: Cells with tau = 0 are the same whatever the setting; they are computed once.
NO_DELAY = "none"


@dataclass(frozen=True)
class Preset:
    """A built-in benchmark: a paper's simulation study (declared by its paper module).

    Attributes
    ----------
    name, scenario : str
        The preset's name and its scenario (built-in name or file).
    taus : tuple of int
        Delay bounds of the grid.
    delays : tuple of str
        Delay settings (:data:`DELAY_MODELS`).
    trials, steps : int
    focus : str
        The family the study is about (the one a claim check runs).
    description : str
    claims : tuple of str
        Claim ids whose bench rows are checked on the report.
    families : tuple of str
        The families to run (empty: the scenario's ``run.estimators``).
    """

    name: str
    scenario: str
    taus: tuple[int, ...]
    delays: tuple[str, ...]
    trials: int
    steps: int
    focus: str
    description: str
    claims: tuple[str, ...]
    families: tuple[str, ...] = ()


@dataclass(frozen=True)
class SweepPreset:
    """A built-in ``netsim bench sweep``: a grid a paper module declares
    (``Paper.sweeps``); the command line's axes, estimators, trials and steps override
    the preset's.

    Attributes
    ----------
    name, scenario : str
        The preset's name and its base scenario (built-in name or file).
    axes : mapping
        Axis -> values (``delays``, ``tau``, ``topology``, ``agents``, ``seed``, ``loss``,
        ``offset``, ``drift_ppm``, ``threshold``; :func:`netsim.bench.variants.sweep_variant`).
    families : tuple of str
        The families each cell runs.
    trials, steps : int
    description : str
    """

    name: str
    scenario: str
    axes: Mapping[str, tuple[Any, ...]]
    families: tuple[str, ...]
    trials: int
    steps: int
    description: str


def sweep_presets() -> dict[str, SweepPreset]:
    """Every paper's sweep presets by name, in registry order."""
    from netsim.papers import papers

    return {p.name: p for paper in papers() for p in paper.sweeps}


def delay_settings() -> dict[str, tuple[str, str]]:
    """Delay settings: name -> (``delays.model``, description citing the papers' figures
    that use it)."""
    from netsim.papers import papers

    notes = {name: list(s[2]) for name, s in _SETTINGS.items()}
    for paper in papers():
        for name, where in paper.delay_settings.items():
            notes[name].append(f"{paper.key} {where}")
    return {name: (s[0], s[1] + (f" ({'; '.join(notes[name])})" if notes[name] else ""))
            for name, s in _SETTINGS.items()}


def presets() -> dict[str, Preset]:
    """Every paper's presets by name, in registry order."""
    from netsim.papers import papers

    return {p.name: p for paper in papers() for p in paper.presets}


def __getattr__(name: str) -> Any:
    if name == "PRESETS":
        return presets()
    if name == "DELAY_SETTINGS":
        return delay_settings()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
