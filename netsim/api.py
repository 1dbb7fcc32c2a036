"""The Python API: load a scenario, run Monte Carlo or one trial, design, analyse, read.

Everything here is re-exported by ``import netsim`` (lazily, so that importing a
submodule such as ``netsim.models`` stays light). The command line is built on the
same functions.

Example
-------
>>> import netsim
>>> scenario = netsim.load_scenario("lcsys2022-heterogeneous")
>>> run = netsim.run(scenario, steps=50, trials=2, estimators=["compensated"])
>>> run["compensated"].squared_errors.shape        # (trials, K+1, N)
(2, 51, 4)
>>> run.summary["compensated"].verdict in ("stable", "diverging", "unbounded", "undecided",
...                                           "diverged")
True
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from netsim.estimators.contract import Estimator
from netsim.estimators.gains import GainDesign
from netsim.estimators.registry import (
    AgentPlan,
    AgentSetup,
    EstimatorFamily,
    FamilyContext,
    FamilyError,
    family_from_object,
    family_names,
    get_family,
    register,
    resolve_families,
)
from netsim.models.scenario import Scenario, ScenarioError, parse_scenario, resolve_scenario
from netsim.models.seeding import child_sequence

__all__ = [
    "Estimator",
    "EstimatorFamily",
    "AgentSetup",
    "AgentPlan",
    "FamilyContext",
    "FamilyError",
    "ScenarioError",
    "Scenario",
    "load_scenario",
    "estimator_names",
    "register_estimator",
    "design_gains",
    "run",
    "run_one",
    "analyze",
    "read_trace",
    "FamilyRun",
    "RunResult",
]


def load_scenario(source: str | os.PathLike[str] | Mapping[str, Any]) -> Scenario:
    """Load and validate a scenario, checking that its estimators resolve.

    Parameters
    ----------
    source : str, path or mapping
        A built-in name (``netsim scenarios``), a TOML file, or a dict with the TOML's
        structure (as ``tomllib.load`` returns it).

    Raises
    ------
    ScenarioError
        Naming the first offending key (an estimator that does not resolve is
        ``run.estimators[i]``).
    """
    if isinstance(source, Mapping):
        scenario = parse_scenario(dict(source), source="")
    else:
        scenario = resolve_scenario(os.fspath(source))
    from netsim.runner import scenario_folder

    try:
        resolve_families(scenario.estimators, "run.estimators", scenario_folder(scenario))
    except FamilyError as error:
        raise ScenarioError(error.key, str(error).split(": ", 1)[1]) from None
    return scenario


def estimator_names() -> list[str]:
    """Names of the registered estimator families (built-ins, then the others)."""
    return family_names()


def register_estimator(estimator: Any, name: str | None = None, *,
                       replace_existing: bool = False, **traits: Any) -> EstimatorFamily:
    """Register a user's estimator under ``name`` and return its family.

    Parameters
    ----------
    estimator : class, factory or EstimatorFamily
        A class implementing the per-agent contract (built as ``cls(setup)`` with each
        agent's :class:`AgentSetup`), a factory ``(FamilyContext) -> list of
        AgentPlan``, or a ready :class:`EstimatorFamily`.
    name : str, optional
        The family's name (default: the class's ``name`` attribute or its name).
    replace_existing : bool
        Replace a registered family of the same name.
    **traits
        Overrides of :class:`EstimatorFamily` fields (``needs_gains``, ``batched``,
        ``description``, ...).

    Example
    -------
    >>> import numpy as np, netsim
    >>> class Hold:          # keeps its prior: the worst sensible estimator
    ...     def __init__(self, setup):
    ...         self.estimate = np.array(setup.prior_mean, dtype=float)
    ...     def message_arrived(self, sender, sent_step, payload):
    ...         return False
    ...     def step(self, k, y):
    ...         return self.estimate
    >>> family = netsim.register_estimator(Hold, "hold", replace_existing=True)
    >>> family.name, family.vectorised
    ('hold', False)
    """
    key = "register_estimator"
    if name is None:
        name = getattr(estimator, "name", None) or getattr(estimator, "__name__", None)
    if not isinstance(name, str) or not name:
        raise FamilyError(key, "give the estimator a name")
    family = family_from_object(estimator, name, key, source="python")
    family = replace(family, name=name, source="python", **traits)
    return register(family, replace_existing=replace_existing)


def design_gains(scenario: Scenario) -> GainDesign:
    """The innovation gains the scenario's consensus estimators use (its ``[gains]``)."""
    from netsim.runner import scenario_gains

    return scenario_gains(scenario)


@dataclass
class FamilyRun:
    """Every trial of one estimator family, as stacked arrays.

    Attributes
    ----------
    family : str
    states : numpy.ndarray, shape (M, K+1, n)
        True states per trial (NaN after a divergence).
    estimates : numpy.ndarray, shape (M, K+1, N, n)
        Each agent's estimate x-hat^i_{k|k} (N = 1 for a centralised filter).
    squared_errors : numpy.ndarray, shape (M, K+1, N)
        ||x_k - x-hat^i_k||^2 (NaN after divergence).
    effective_delays : numpy.ndarray or None, shape (M, K+1, N, N)
        r_ij[k] used by agent i's update at step k (-1: own estimate substituted,
        -2: not used), when the family reports them.
    diverged_at : list of int or None
        Per trial, the step it diverged at.
    summary : netsim.runner.EstimatorSummary
        Network MSE, verdict, growth, and the steady-state MSE (stable runs only; NaN
        otherwise: see its last trusted MSE).
    """

    family: str
    states: np.ndarray
    estimates: np.ndarray
    squared_errors: np.ndarray
    effective_delays: np.ndarray | None
    diverged_at: list[int | None]
    summary: Any

    @property
    def mse(self) -> np.ndarray:
        """Network MSE (1/N) sum_i ||x_k - x-hat^i_k||^2 over non-diverged trials, (K+1,)."""
        return self.summary.mse


@dataclass
class RunResult:
    """Result of :func:`run`: per-family trial arrays and the Monte Carlo summary.

    Index by family name (``result["compensated"]``) for a :class:`FamilyRun`;
    ``summary`` maps names to summaries; ``monte_carlo`` is the full
    :class:`netsim.runner.MonteCarloResult` (what ``netsim run --json`` prints).
    """

    scenario: Scenario
    monte_carlo: Any
    families: dict[str, FamilyRun] = field(default_factory=dict)

    def __getitem__(self, family: str) -> FamilyRun:
        return self.families[family]

    def __iter__(self) -> Iterator[str]:
        return iter(self.families)

    @property
    def summary(self) -> dict[str, Any]:
        """Per family: :class:`netsim.runner.EstimatorSummary`."""
        return self.monte_carlo.estimators

    @property
    def seed_layout(self) -> int:
        """Layout of the random streams (:data:`netsim.models.seeding.SEED_LAYOUT`)."""
        return self.monte_carlo.seed_layout

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready summary (the same as ``netsim run --json``)."""
        return self.monte_carlo.to_dict()

    def to_dataframe(self) -> Any:
        """One row per (family, trial, step, agent) with the squared error (pandas).

        Columns: ``family``, ``trial``, ``step``, ``agent``, ``squared_error``.
        Raises ImportError with a clear message when pandas is not installed.
        """
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("RunResult.to_dataframe() needs pandas: pip install pandas"
                              ) from None
        frames = []
        for name, fam in self.families.items():
            M, K1, N = fam.squared_errors.shape
            trial, step, agent = np.meshgrid(np.arange(M), np.arange(K1), np.arange(N),
                                             indexing="ij")
            frames.append(pd.DataFrame({
                "family": name, "trial": trial.ravel(), "step": step.ravel(),
                "agent": agent.ravel(), "squared_error": fam.squared_errors.ravel()}))
        return pd.concat(frames, ignore_index=True)


def _stack(name: str, trials: list[Any], summary: Any) -> FamilyRun:
    delays = [t.effective_delays for t in trials]
    return FamilyRun(
        family=name,
        states=np.stack([t.states for t in trials]),
        estimates=np.stack([t.estimates for t in trials]),
        squared_errors=np.stack([t.squared_errors for t in trials]),
        effective_delays=(np.stack(delays) if delays and all(d is not None for d in delays)
                          else None),
        diverged_at=[t.diverged_at for t in trials],
        summary=summary,
    )


def run(scenario: Scenario | str | os.PathLike[str] | Mapping[str, Any], *,
        steps: int | None = None, trials: int | None = None, seed: int | None = None,
        estimators: Sequence[str | EstimatorFamily] | None = None, engine: str = "auto",
        trace: str | os.PathLike[str] | None = None,
        trace_format: int | None = None, trace_compression: str | None = None,
        progress: Callable[[int], None] | None = None) -> RunResult:
    """Run Monte Carlo trials of the scenario's estimators (or ``estimators``).

    Parameters
    ----------
    scenario : Scenario, or what :func:`load_scenario` takes
    steps, trials, seed : int, optional
        Override the scenario's ``[run]`` settings.
    estimators : sequence of str or EstimatorFamily, optional
        Families to run (registered names, ``module:attribute``, entry points).
    engine : str
        ``auto`` (vectorised where a family has a batched form), ``vectorised`` or
        ``events``.
    trace : path, optional
        Record MCAP traces (see ``netsim run --trace``).
    trace_format : int, optional
        3 (the default, :data:`netsim.traces.recorder.DEFAULT_TRACE_FORMAT`: a message
        per step and kind) or 2 (a message per agent and per link event).
    trace_compression : str, optional
        ``none`` or ``zstd`` (default: none for format 3, zstd for format 2).
    progress : callable(int), optional
        Called with the number of trials finished.

    Returns
    -------
    RunResult
    """
    from netsim.runner import run_monte_carlo

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    options: dict[str, Any] = {}
    if trace_format is not None:
        options["trace_format"] = int(trace_format)
    if trace_compression is not None:
        options["compression"] = str(trace_compression)
    result = run_monte_carlo(scenario, steps=steps, trials=trials, seed=seed,
                             families=estimators, engine=engine, progress=progress,
                             trace=None if trace is None else os.fspath(trace),
                             keep_trials=True, trace_options=options or None)
    out = RunResult(scenario, result)
    for name, runs in result.runs.items():
        out.families[name] = _stack(name, runs, result.estimators[name])
    return out


def run_one(scenario: Scenario | str | os.PathLike[str] | Mapping[str, Any],
            estimator: str | EstimatorFamily, *, trial: int = 0, seed: int | None = None,
            steps: int | None = None, observer: Any = None) -> Any:
    """Run one trial of one estimator family in the SimPy event kernel.

    The trial's randomness is the same as trial ``trial`` of :func:`run` with the same
    seed. Returns a :class:`netsim.kernel.TrialResult` (states (K+1, n), estimates
    (K+1, N, n), squared_errors (K+1, N), effective_delays (K+1, N, N), counts).
    """
    from netsim.runner import family_of, run_trial, scenario_gains

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    family = family_of(estimator, scenario, "estimator")
    gains = scenario_gains(scenario) if family.needs_gains else None
    root = scenario.seed if seed is None else int(seed)
    return run_trial(scenario, family, gains, child_sequence(root, "trial", int(trial)),
                     steps, observer=observer)


def analyze(scenario: Scenario | str | os.PathLike[str], tau_max: int = 30) -> Any:
    """Exact spectral radii of the augmented closed loop beside the papers' bounds.

    ``scenario``: a Scenario or what :func:`load_scenario` takes; a path ending in
    ``.mcap`` analyses a trace instead (:func:`netsim.traces.analysis.analyze_trace`).
    Returns the report object (``to_dict()``, ``format_text()`` where available).
    """
    if isinstance(scenario, str | os.PathLike) and Path(scenario).suffix == ".mcap":
        from netsim.traces.analysis import analyze_trace

        return analyze_trace(read_trace(scenario), tau_max=tau_max)
    from netsim.analysis import analyze as analyze_scenario

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    return analyze_scenario(scenario, design_gains(scenario), tau_max)


def read_trace(path: str | os.PathLike[str]) -> Any:
    """Read an MCAP trace written by netsim (:class:`netsim.traces.reader.Trace`)."""
    from netsim.traces.reader import read_trace as read

    return read(os.fspath(path))


# keep the registry's lookup at hand for users who want it
get_estimator = get_family
__all__.append("get_estimator")
