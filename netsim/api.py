"""The Python API: load a scenario, run Monte Carlo or one trial, design, analyse, read.

Everything here is re-exported by ``import netsim`` (lazily, so that importing a
submodule such as ``netsim.models`` stays light). The command line is built on the
same functions.

Examples
--------
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

import math
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

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
from netsim.threads import single_threaded_blas

if TYPE_CHECKING:  # (imported where used: pandas is optional, the others load on demand)
    import pandas as pd

    from netsim.analysis import AnalysisReport
    from netsim.kernel import TrialResult
    from netsim.traces.analysis import TraceAnalysis
    from netsim.traces.reader import Trace

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

    Examples
    --------
    >>> import netsim
    >>> scenario = netsim.load_scenario("lcsys2022-heterogeneous")
    >>> scenario.name, scenario.n_agents
    ('lcsys2022-heterogeneous', 4)
    >>> scenario.with_tau(8).delay_bound      # a copy with another delay bound
    8

    A dict with the TOML's structure works too; a wrong key is named (``key``), with
    the closest allowed key when there is one:

    >>> try:
    ...     netsim.load_scenario({"name": "x", "plant": {"A": [[1.0]], "C": [[[1.0]]]},
    ...                           "network": {"P": [[1.0]]}, "run": {"stepz": 3}})
    ... except netsim.ScenarioError as error:
    ...     print(error.key)
    ...     print(str(error).split(";")[0])
    run.stepz
    run.stepz: unknown key (did you mean 'steps'?)
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

    Examples
    --------
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
    """The innovation gains the scenario's consensus estimators use (its ``[gains]``).

    The design is cached on disk (``$NETSIM_CACHE_DIR``, default
    ``~/.cache/netsim/gains``); ``netsim design`` prints the same.

    Examples
    --------
    >>> import netsim
    >>> gains = netsim.design_gains(netsim.load_scenario("lcsys2022-heterogeneous"))
    >>> gains.method, round(gains.rho, 4), len(gains.L)
    ('block-diagonal-lmi-bisection', 0.8276, 4)"""
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
    drops : list of list of (int, int, int, float, str), or None
        Per trial, every message the links dropped, as (sender j, receiver i, sent step
        s, drop time in sampling periods, reason) (``TrialResult.drops``); None when
        not recorded (with ``effective_delays``).
    """

    family: str
    states: np.ndarray
    estimates: np.ndarray
    squared_errors: np.ndarray
    effective_delays: np.ndarray | None
    diverged_at: list[int | None]
    summary: Any
    drops: list[list[tuple[int, int, int, float, str]]] | None = None

    @property
    def mse(self) -> np.ndarray:
        """Network MSE (1/N) sum_i ||x_k - x-hat^i_k||^2 over non-diverged trials, (K+1,)."""
        return self.summary.mse

    def __repr__(self) -> str:
        shapes = ", ".join(f"{name} {getattr(self, name).shape}" for name in
                           ("states", "estimates", "squared_errors"))
        return (f"<FamilyRun {self.family}: {self.summary.verdict}, "
                f"{len(self.diverged_at)} trial(s); {shapes}>")


#: What :meth:`RunResult.to_dataframe` can tabulate.
TABLES = ("errors", "estimates", "states", "delays", "drops")

#: The columns of each table of :meth:`RunResult.to_dataframe`.
TABLE_COLUMNS: dict[str, tuple[str, ...]] = {
    "errors": ("family", "trial", "step", "time", "agent", "squared_error"),
    "estimates": ("family", "trial", "step", "time", "agent", "component", "estimate"),
    "states": ("family", "trial", "step", "time", "component", "state"),
    "delays": ("family", "trial", "step", "time", "agent", "sender", "delay"),
    "drops": ("family", "trial", "sent_step", "sender", "receiver", "time", "reason"),
}

#: Estimators listed one per line in ``repr`` (the others are counted).
_REPR_FAMILIES = 12


def _pandas(what: str) -> Any:
    """Import pandas, or raise :class:`netsim.models.extras.MissingExtra` (an ImportError)
    naming it and the extra that installs it."""
    from netsim.models.extras import MissingExtra

    try:
        import pandas
    except ImportError:
        raise MissingExtra(f"{what} needs pandas: pip install 'netsim[notebook]'",
                           name="pandas") from None
    return pandas


def _number(value: Any) -> str:
    """A float for a table cell: 4 significant digits, ``-`` for NaN or None."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.4g}"


def _write_table(frame: Any, path: str | os.PathLike[str], option: str, force: bool,
                 write: Callable[[Any, Path], None]) -> Path:
    """Write ``frame`` by the output-file rule (:mod:`netsim.outfiles`): never through a
    link, an existing file only with ``force``, atomically."""
    from netsim.outfiles import OutputFileError, atomic_output, check_output

    try:
        target = check_output(path, option, force=force)
    except OutputFileError as error:  # the API's word for --force
        raise OutputFileError(str(error).replace("--force", "force=True")) from None
    with atomic_output(target) as tmp:
        write(frame, tmp)
    return target


@dataclass(repr=False)
class RunResult:
    """Result of :func:`run`: per-family trial arrays and the Monte Carlo summary.

    Index by family name (``result["compensated"]``) for a :class:`FamilyRun`;
    ``summary`` maps names to summaries; ``monte_carlo`` is the full
    :class:`netsim.runner.MonteCarloResult` (what ``netsim run --json`` prints).

    In a notebook the result shows its summary table (``repr`` of a few lines, or
    HTML); :meth:`plot` draws the network MSE of every family, :meth:`to_dataframe`
    gives the errors, estimates, states, effective delays or drops as a tidy pandas
    table, and :meth:`to_csv` / :meth:`to_parquet` write them.

    Examples
    --------
    >>> import netsim
    >>> result = netsim.run("lcsys2022-heterogeneous", steps=50, trials=2,
    ...                     estimators=["compensated", "centralized-kf"])
    >>> print(repr(result).splitlines()[0])                 # doctest: +ELLIPSIS
    <RunResult lcsys2022-heterogeneous: 2 estimator(s), 2 trial(s), steps 0..50, ...>
    >>> frame = result.to_dataframe(what="estimates")       # doctest: +SKIP
    >>> list(frame.columns)                                 # doctest: +SKIP
    ['family', 'trial', 'step', 'time', 'agent', 'component', 'estimate']
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

    # -- notebook display ---------------------------------------------------------

    def _header(self) -> str:
        mc = self.monte_carlo
        return (f"{self.scenario.name}: {len(self.families) or len(self.summary)} "
                f"estimator(s), {mc.trials} trial(s), steps 0..{mc.steps}, "
                f"Ts = {self.scenario.sample_period:g}, seed {mc.seed}, engine {mc.engine}")

    def summary_rows(self) -> list[dict[str, Any]]:
        """The summary table: one dict per family (what ``repr`` and HTML show).

        Keys: ``estimator``, ``engine``, ``verdict``, ``steady_state_mse`` (NaN unless
        stable), ``last_trusted_mse``, ``last_trusted_step``, ``growth_rate`` (MSE
        growth factor per step), ``diverged`` (trials that blew up), ``trials``,
        ``sent``, ``delivered``, ``dropped`` and ``discarded`` (messages, all trials);
        under a ``[time]`` table also ``message_rate`` (estimates sent per agent and
        time unit, :mod:`netsim.timedkernel`).
        """
        mc = self.monte_carlo
        rows = []
        for name, s in self.summary.items():
            runs = mc.runs.get(name, [])
            rows.append({
                "estimator": name, "engine": mc.engines.get(name, mc.engine),
                "verdict": s.verdict, "steady_state_mse": s.steady_state_mse,
                "last_trusted_mse": s.last_trusted_mse,
                "last_trusted_step": s.last_trusted_step, "growth_rate": s.growth_rate,
                "diverged": len(s.diverged), "trials": s.trials_finished or mc.trials,
                "sent": s.messages_sent, "delivered": s.messages_delivered,
                "dropped": sum(r.messages_dropped for r in runs),
                "discarded": s.messages_discarded,
                # [time] scenarios: estimates sent per agent and time unit (triggers)
                **({"message_rate": s.message_rate} if s.message_rate is not None else {}),
            })
        return rows

    def __repr__(self) -> str:
        rows = self.summary_rows()
        width = max([len("estimator"), *(len(r["estimator"]) for r in rows[:_REPR_FAMILIES])])
        lines = [f"<RunResult {self._header()}>",
                 f"  {'estimator':<{width}}  {'verdict':<10} {'steady MSE':>10} "
                 f"{'last MSE':>10} {'at k':>5} {'growth':>7} {'diverged':>8}"]
        for r in rows[:_REPR_FAMILIES]:
            step = "-" if r["last_trusted_step"] is None else r["last_trusted_step"]
            lines.append(f"  {r['estimator']:<{width}}  {r['verdict']:<10} "
                         f"{_number(r['steady_state_mse']):>10} "
                         f"{_number(r['last_trusted_mse']):>10} {step:>5} "
                         f"{_number(r['growth_rate']):>7} "
                         f"{str(r['diverged']) + '/' + str(r['trials']):>8}")
        if len(rows) > _REPR_FAMILIES:
            lines.append(f"  ... and {len(rows) - _REPR_FAMILIES} more (result.summary)")
        lines.append('  arrays: result["<estimator>"].states / .estimates / .squared_errors; '
                     ".plot(); .to_dataframe(what=...)")
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        """The summary table as HTML (Jupyter's rich display); every value escaped."""
        import html

        heads = ("estimator", "engine", "verdict", "steady-state MSE", "last trusted MSE",
                 "at step", "growth / step", "diverged", "messages sent", "delivered",
                 "dropped", "discarded stale")
        body = []
        for r in self.summary_rows():
            cells = (r["estimator"], r["engine"], r["verdict"],
                     _number(r["steady_state_mse"]), _number(r["last_trusted_mse"]),
                     "-" if r["last_trusted_step"] is None else r["last_trusted_step"],
                     _number(r["growth_rate"]), f"{r['diverged']} / {r['trials']}",
                     r["sent"], r["delivered"], r["dropped"], r["discarded"])
            body.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells)
                        + "</tr>")
        head = "".join(f"<th>{html.escape(h)}</th>" for h in heads)
        return (f"<div><p><b>RunResult</b> {html.escape(self._header())}</p>"
                f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody>"
                "</table></div>")

    def plot(self, ax: Any = None, *, log: bool | None = None) -> Any:
        """Plot the network MSE over time of every family, one line each (matplotlib).

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Where to draw (default: a new figure).
        log : bool, optional
            Logarithmic MSE axis; by default when every finite MSE is positive and
            they span more than a factor of 10.

        Returns
        -------
        matplotlib.axes.Axes
            The axes (its figure is ``ax.figure``). The line of family ``f`` has the
            label ``f`` and the data ``summary[f].mse`` (NaN where no trial counts).

        Examples
        --------
        >>> ax = result.plot()                       # doctest: +SKIP
        >>> ax.figure.savefig("mse.png")             # doctest: +SKIP
        """
        if ax is None:
            from netsim.models.extras import require

            plt = require("matplotlib.pyplot", "notebook", "RunResult.plot()")
            _, ax = plt.subplots(figsize=(7, 4))
        finite = []
        for name, s in self.summary.items():
            mse = np.asarray(s.mse, dtype=float)
            ax.plot(np.arange(len(mse)), mse, label=name)
            finite.append(mse[np.isfinite(mse)])
        values = np.concatenate(finite) if finite else np.zeros(0)
        if log is None:
            log = bool(values.size) and bool(np.all(values > 0)) and (
                values.max() > 10 * values.min())
        if log:
            ax.set_yscale("log")
        ax.set_xlabel("step k")
        ax.set_ylabel("network MSE")
        ax.set_title(f"{self.scenario.name}: {self.monte_carlo.trials} trial(s)")
        ax.legend()
        return ax

    # -- tables -------------------------------------------------------------------

    def to_dataframe(self, what: str = "errors") -> pd.DataFrame:
        """One tidy (long) pandas table of the run's arrays.

        Parameters
        ----------
        what : str
            Which table (:data:`TABLES`); the columns are :data:`TABLE_COLUMNS`.
            ``family`` is the estimator family, ``trial`` the Monte Carlo trial
            (0..M-1), ``step`` k (0..K), ``time`` the simulation time in seconds
            (k Ts), ``agent`` i, ``component`` the index into the state vector.

            - ``"errors"`` (default): one row per (family, trial, step, agent),
              ``squared_error`` = ||x_k - x-hat^i_k||^2 (NaN after a divergence), the
              numbers the summary's MSE averages;
            - ``"estimates"``: per (family, trial, step, agent, component), the
              estimate x-hat^i_{k|k} (N = 1 agent for a centralised filter);
            - ``"states"``: per (family, trial, step, component), the true state x_k
              of that family's run (every family sees the same plant trials; NaN
              after a divergence);
            - ``"delays"``: the effective delays r_ij[k] agent i's update at step k
              used: one row per (family, trial, step, agent i, sender j) where
              j's estimate entered the update, ``delay`` = k - 1 - s_j (-1: nothing
              had arrived, i's own prediction stood in); the (k, i, j) entries marked
              not used are left out;
            - ``"drops"``: one row per message a link dropped, ``sent_step`` s,
              ``sender`` j, ``receiver`` i, ``time`` of the drop in seconds and its
              ``reason`` (see :mod:`netsim.links`), ordered by trial and time.

        Returns
        -------
        pandas.DataFrame

        Raises
        ------
        ImportError
            When pandas is not installed (``pip install 'netsim[notebook]'``).
        ValueError
            For an unknown ``what``; for ``delays`` or ``drops`` of a run that did
            not record them (a traced :func:`run` keeps neither: read the trace).

        Examples
        --------
        >>> frame = result.to_dataframe(what="estimates")       # doctest: +SKIP
        >>> frame.groupby(["family", "step"]).estimate.mean()   # doctest: +SKIP
        """
        if what not in TABLES:
            raise ValueError(f"what={what!r}: expected one of {', '.join(TABLES)}")
        pd = _pandas("to_dataframe")
        names = list(TABLE_COLUMNS[what])
        parts: dict[str, list[np.ndarray]] = {c: [] for c in names}
        ts = float(self.scenario.sample_period)
        for name, fam in self.families.items():
            if what in ("delays", "drops") and (fam.effective_delays is None
                                                or fam.drops is None):
                raise ValueError(f"to_dataframe(what={what!r}): family {name!r} did not "
                                 "record its effective delays and drops (a traced run "
                                 "keeps neither; read them from the trace)")
            columns = _table(what, fam, ts)
            count = len(next(iter(columns.values())))
            parts["family"].append(np.full(count, name, dtype=object))
            for column, values in columns.items():
                parts[column].append(values)
        data = {c: (np.concatenate(v) if v else np.zeros(0, dtype=object if c in (
            "family", "reason") else float)) for c, v in parts.items()}
        return pd.DataFrame(data, columns=names)

    def to_csv(self, path: str | os.PathLike[str], what: str = "errors", *,
               force: bool = False) -> Path:
        """Write :meth:`to_dataframe` (``what``) to a CSV file, without the index.

        The file is written by netsim's output-file rule (:mod:`netsim.outfiles`):
        never through a symbolic link, never over an existing file unless
        ``force=True``, atomically (a failed write leaves the old file). Returns the
        path written.
        """
        frame = self.to_dataframe(what)
        return _write_table(frame, path, "to_csv", force,
                            lambda f, tmp: f.to_csv(tmp, index=False))

    def to_parquet(self, path: str | os.PathLike[str], what: str = "errors", *,
                   force: bool = False) -> Path:
        """Write :meth:`to_dataframe` (``what``) to a Parquet file (needs pyarrow).

        Same file rule as :meth:`to_csv`. Returns the path written.
        """
        frame = self.to_dataframe(what)
        from netsim.models.extras import MissingExtra

        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise MissingExtra("to_parquet needs pyarrow: pip install 'netsim[notebook]'",
                               name="pyarrow") from None
        return _write_table(frame, path, "to_parquet", force,
                            lambda f, tmp: f.to_parquet(tmp, index=False))


def _indices(shape: tuple[int, ...]) -> list[np.ndarray]:
    """Row-major index columns of an array of ``shape`` (one per axis, all its cells)."""
    return [np.asarray(a).ravel() for a in np.indices(shape, dtype=np.int64)]


def _table(what: str, fam: FamilyRun, ts: float) -> dict[str, np.ndarray]:
    """The columns (but ``family``) of one family's part of a :data:`TABLES` table."""
    if what == "errors":
        t, k, i = _indices(fam.squared_errors.shape)
        return {"trial": t, "step": k, "time": k * ts, "agent": i,
                "squared_error": fam.squared_errors.ravel()}
    if what == "estimates":
        t, k, i, c = _indices(fam.estimates.shape)
        return {"trial": t, "step": k, "time": k * ts, "agent": i, "component": c,
                "estimate": fam.estimates.ravel()}
    if what == "states":
        t, k, c = _indices(fam.states.shape)
        return {"trial": t, "step": k, "time": k * ts, "component": c,
                "state": fam.states.ravel()}
    if what == "delays":
        from netsim.kernel import NOT_USED

        delays = np.asarray(fam.effective_delays)
        t, k, i, j = (a.astype(np.int64) for a in np.nonzero(delays != NOT_USED))
        return {"trial": t, "step": k, "time": k * ts, "agent": i, "sender": j,
                "delay": delays[t, k, i, j].astype(np.int64)}
    rows = sorted((trial, when, sender, receiver, sent, reason)
                  for trial, records in enumerate(fam.drops or [])
                  for sender, receiver, sent, when, reason in records)
    return {
        "trial": np.array([r[0] for r in rows], dtype=np.int64),
        "sent_step": np.array([r[4] for r in rows], dtype=np.int64),
        "sender": np.array([r[2] for r in rows], dtype=np.int64),
        "receiver": np.array([r[3] for r in rows], dtype=np.int64),
        "time": np.array([r[1] * ts for r in rows], dtype=float),
        "reason": np.array([r[5] for r in rows], dtype=object),
    }


def _stack(name: str, trials: list[Any], summary: Any) -> FamilyRun:
    delays = [t.effective_delays for t in trials]
    drops = [getattr(t, "drops", None) for t in trials]
    recorded = [d for d in drops if d is not None]
    return FamilyRun(
        family=name,
        states=np.stack([t.states for t in trials]),
        estimates=np.stack([t.estimates for t in trials]),
        squared_errors=np.stack([t.squared_errors for t in trials]),
        effective_delays=(np.stack(delays) if delays and all(d is not None for d in delays)
                          else None),
        diverged_at=[t.diverged_at for t in trials],
        summary=summary,
        drops=(recorded if drops and len(recorded) == len(drops) else None),
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

    Examples
    --------
    >>> import netsim
    >>> result = netsim.run("lcsys2022-heterogeneous", steps=50, trials=2,
    ...                     estimators=["compensated", "centralized-kf"])
    >>> list(result)
    ['compensated', 'centralized-kf']
    >>> result["compensated"].squared_errors.shape      # (trials, K+1, N)
    (2, 51, 4)
    >>> result.summary["compensated"].verdict
    'stable'
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


@single_threaded_blas()
def run_one(scenario: Scenario | str | os.PathLike[str] | Mapping[str, Any],
            estimator: str | EstimatorFamily, *, trial: int = 0, seed: int | None = None,
            steps: int | None = None, observer: Any = None) -> TrialResult:
    """Run one trial of one estimator family in the SimPy event kernel.

    The trial's randomness is the same as trial ``trial`` of :func:`run` with the same
    seed. Returns a :class:`netsim.kernel.TrialResult` (states (K+1, n), estimates
    (K+1, N, n), squared_errors (K+1, N), effective_delays (K+1, N, N), counts).

    Examples
    --------
    >>> import numpy as np, netsim
    >>> one = netsim.run_one("lcsys2022-heterogeneous", "compensated", trial=1, steps=50)
    >>> one.squared_errors.shape                        # (K+1, N)
    (51, 4)
    >>> batch = netsim.run("lcsys2022-heterogeneous", steps=50, trials=2,
    ...                    estimators=["compensated"])  # the vectorised engine
    >>> np.allclose(one.squared_errors, batch["compensated"].squared_errors[1],
    ...             rtol=1e-9, atol=1e-12)
    True
    """
    from netsim.runner import family_of, run_trial, scenario_gains

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    family = family_of(estimator, scenario, "estimator")
    gains = scenario_gains(scenario) if family.needs_gains else None
    root = scenario.seed if seed is None else int(seed)
    return run_trial(scenario, family, gains, child_sequence(root, "trial", int(trial)),
                     steps, observer=observer)


@single_threaded_blas()
def analyze(scenario: Scenario | str | os.PathLike[str], tau_max: int = 30
            ) -> AnalysisReport | TraceAnalysis:
    """Exact spectral radii of the augmented closed loop beside the papers' bounds.

    ``scenario``: a Scenario or what :func:`load_scenario` takes; a path ending in
    ``.mcap`` analyses a trace instead (:func:`netsim.traces.analysis.analyze_trace`).
    Returns the report: a :class:`netsim.analysis.AnalysisReport`, or for a trace a
    :class:`netsim.traces.analysis.TraceAnalysis` (``to_dict()``, ``format_text()``
    where available).

    Examples
    --------
    >>> import netsim
    >>> report = netsim.analyze("lcsys2022-homogeneous", tau_max=8)
    >>> report.tau_star, round(report.rho_delay_free, 4)
    (8, 0.8276)
    """
    if isinstance(scenario, str | os.PathLike) and Path(scenario).suffix == ".mcap":
        from netsim.traces.analysis import analyze_trace

        return analyze_trace(read_trace(scenario), tau_max=tau_max)
    from netsim.analysis import analyze as analyze_scenario

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    return analyze_scenario(scenario, design_gains(scenario), tau_max)


def read_trace(path: str | os.PathLike[str]) -> Trace:
    """Read an MCAP trace written by netsim (:class:`netsim.traces.reader.Trace`).

    Formats 1, 2 and 3 are read alike (a format-3 file is shown as its format-2 view;
    ``Trace.file_topics`` lists the file's own topics).

    Examples
    --------
    >>> import netsim
    >>> _ = netsim.run("lcsys2022-heterogeneous", steps=20, trials=1,
    ...                estimators=["compensated"], trace="run.mcap")
    >>> trace = netsim.read_trace("run.mcap")
    >>> trace.estimates().shape                         # (K+1, N, n)
    (21, 4, 6)
    >>> "/agents/estimate" in trace.file_topics
    True"""
    from netsim.traces.reader import read_trace as read

    return read(os.fspath(path))


# keep the registry's lookup at hand for users who want it
get_estimator = get_family
__all__.append("get_estimator")
