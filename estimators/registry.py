"""The estimator-family registry: every family, built-in or plugged in, in one place.

A *family* is a kind of estimator run on a scenario: its name, a factory that builds
one trial's agents from a scenario, what it needs and what it supports. Each built-in
family is declared by its own module (:data:`BUILTIN_MODULES`, each calling
:func:`register` at import); nothing else names it. Everything that runs, traces or
analyses estimators (the runner, the command line, ``inspect``, ``plot``, ``replay``,
``bench``) asks this registry instead of comparing names.

Three ways in for a user's estimator:

- by name in a scenario, ``run.estimators = ["compensated", "mypkg.filters:MyFilter"]``:
  ``module:attribute`` is imported; the attribute is an :class:`EstimatorFamily`, a
  factory ``(FamilyContext) -> list of AgentPlan``, or a class implementing the
  per-agent contract (:mod:`netsim.estimators.contract`), built once per agent as
  ``cls(setup)`` from that agent's :class:`AgentSetup` (see :func:`family_from_object`);
- from Python: :func:`register`;
- from an installed package: the entry-point group ``netsim.estimators`` (the entry
  point's name is the family name, its value ``module:attribute`` as above).

Names. A family from an entry point runs, and its results are reported, under the
entry point's name, the name the user asked for (a class's own ``name`` attribute is
ignored there); one named as ``module:attribute`` runs under its class's ``name``
attribute if it declares one (so ``--estimators`` and the results can use the short
name), else under the reference itself. Resolving a name again in the same process
(a second ``netsim.run``, a re-run notebook cell) returns the family resolved first.

What the resolved object is gets checked before anything calls it
(:func:`family_from_object`): a builtin or standard-library function, a module, a
constant, a class without the contract's methods or whose constructor cannot take
``cls(setup)``, or a factory that cannot be called as ``factory(context)`` is refused.
A name that does not import (the module raising anything, ``sys.exit()`` included),
an object that is not an estimator family, or a user's factory or constructor that
fails on the host's arguments is one :class:`FamilyError` (a ``ValueError``) naming
the scenario key and the object, on one line.
"""

from __future__ import annotations

import importlib
import inspect
import os
import sys
import types
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from netsim.estimators.contract import ContractError, check_estimator
from netsim.models.lazy import issparse

__all__ = [
    "BUILTIN_MODULES",
    "RECURSION_COMPENSATED",
    "RECURSION_UNCOMPENSATED",
    "RECURSION_BLOCK",
    "ENTRY_POINT_GROUP",
    "FamilyError",
    "PROTOCOL",
    "FamilyContext",
    "ObserverTap",
    "AgentSetup",
    "AgentPlan",
    "EstimatorFamily",
    "register",
    "unregister",
    "get_family",
    "resolve_families",
    "family_names",
    "families",
    "family_listing",
    "family_from_object",
    "resolve_reference",
]

#: Modules that declare the built-in families (imported on first use of the registry).
BUILTIN_MODULES = (
    "netsim.estimators.consensus",
    "netsim.estimators.kalman",
    "netsim.estimators.aoi",
    "netsim.estimators.fusion",
    "netsim.estimators.baselines",
)
#: The augmented error recursions a family may declare (``error_recursion``): with
#: A^(r+1) compensation, LCSYS2022 eq. (9); with A, the delay-tolerant paper's eq. (11);
#: the block update of LCSYS2022 eqs. (15)-(16). Replay and the trace analytics exist
#: for these.
RECURSION_COMPENSATED = "lcsys2022-eq9"
RECURSION_UNCOMPENSATED = "delay-tolerant-eq11"
RECURSION_BLOCK = "lcsys2022-eq15"
#: Entry-point group through which installed packages add families.
ENTRY_POINT_GROUP = "netsim.estimators"


class FamilyError(ValueError):
    """A family name that cannot be resolved, or an object that is not a family.

    Parameters
    ----------
    key : str
        The scenario key or argument that named the family (``run.estimators``).
    message : str
    """

    def __init__(self, key: str, message: str) -> None:
        self.key = key
        self.detail = _one_line(message)
        super().__init__(f"{key}: {self.detail}")

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        # raised in a worker process, it must unpickle with both arguments
        return (type(self), (self.key, self.detail))


#: What an estimator family may be, as the one-line errors say it.
PROTOCOL = ("expected a class with message_arrived() and step(), built once per agent as "
            "cls(setup); a factory (FamilyContext) -> list of AgentPlan; or an "
            "EstimatorFamily")


def _one_line(text: str) -> str:
    """``text`` with its line breaks (an exception's multi-line message) made spaces."""
    return " ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _failure(error: BaseException) -> str:
    """One line saying how a user's code failed (``SystemExit`` included)."""
    if isinstance(error, SystemExit):
        return f"it called sys.exit({error.code!r})"
    text = _one_line(str(error))
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


@dataclass(frozen=True)
class FamilyContext:
    """What a family's factory receives to build the agents of one trial.

    Attributes
    ----------
    scenario : netsim.models.scenario.Scenario
        The scenario (plant ``scenario.plant``: A, C_i, Q, R_i, prior; consensus
        weights ``scenario.weights``, shape (N, N); graph ``scenario.graph``).
    gains : netsim.estimators.gains.GainDesign or None
        The scenario's innovation gains (None unless the family needs gains).
    trial_seed : numpy.random.SeedSequence or int
        The trial's seed; :meth:`stream` derives an agent's own random stream.
    family : str
        The name the family runs under.
    """

    scenario: Any
    gains: Any
    trial_seed: Any
    family: str = ""

    def stream(self, *names: Any) -> np.random.Generator:
        """An independent random stream of this trial, ``(family, *names)``."""
        from netsim.models.seeding import stream

        return stream(self.trial_seed, "estimator", self.family, *names)

    def agent_setup(self, agent: int) -> AgentSetup:
        """What agent ``agent`` may know (DESIGN.md: the factory's inputs)."""
        scenario = self.scenario
        plant = scenario.plant
        gain = None if self.gains is None else self.gains.L[agent]
        return AgentSetup(
            agent=agent,
            n_agents=scenario.n_agents,
            in_neighbours=tuple(self.in_neighbours(agent)),
            out_neighbours=tuple(self.out_neighbours(agent)),
            weights=(scenario.weights_sparse[[agent], :].toarray()[0]
                     if issparse(scenario.weights)
                     else np.asarray(scenario.weights[agent], dtype=float).copy()),
            A=plant.A, C=plant.C[agent], Q=plant.Q, R=plant.R[agent],
            prior_mean=plant.x0_mean, prior_cov=plant.x0_cov, L=gain,
            rng=self.stream("agent", agent),
            delay_bound=int(scenario.delay_bound),
            sample_period=float(scenario.sample_period),
        )

    def in_neighbours(self, agent: int) -> list[int]:
        """Agents that agent ``agent`` receives from (self excluded)."""
        return sorted(j for j in self.scenario.graph.predecessors(agent) if j != agent)

    def out_neighbours(self, agent: int) -> list[int]:
        """Agents that agent ``agent`` sends to (self excluded)."""
        return sorted(j for j in self.scenario.graph.successors(agent) if j != agent)


class ObserverTap:
    """Base of a family's own observer (``EstimatorFamily.observer``).

    It receives every kernel hook and forwards it to ``inner`` (a trace recorder, or
    None); a subclass overrides the hooks it needs (calling ``super()``) and
    :meth:`collect`. Hooks the inner observer has beyond these (``on_freshness``) are
    reached through attribute access.
    """

    def __init__(self, inner: Any = None) -> None:
        self.inner = inner

    def __getattr__(self, name: str) -> Any:
        inner = self.__dict__.get("inner")
        if inner is None or name.startswith("_"):
            raise AttributeError(name)
        return getattr(inner, name)

    def on_plant(self, k: int, state: np.ndarray, measurements: Sequence[np.ndarray]) -> None:
        if self.inner is not None:
            self.inner.on_plant(k, state, measurements)

    def on_sent(self, message: Any) -> None:
        if self.inner is not None:
            self.inner.on_sent(message)

    def on_delivered(self, message: Any, accepted: bool) -> None:
        if self.inner is not None:
            self.inner.on_delivered(message, accepted)

    def on_update(self, agent: int, k: int, estimate: np.ndarray,
                  delays: dict[int, int]) -> None:
        if self.inner is not None:
            self.inner.on_update(agent, k, estimate, delays)

    def collect(self) -> dict[str, Any]:
        """What the run's ``TrialResult.extras`` keeps (default: nothing)."""
        return {}


@dataclass(frozen=True)
class AgentSetup:
    """Everything one agent may know, as a family's per-agent class receives it.

    Attributes
    ----------
    agent : int
        Its index i (agents are numbered 0..N-1).
    n_agents : int
        N.
    in_neighbours, out_neighbours : tuple of int
        Agents it receives from / sends to (itself excluded).
    weights : numpy.ndarray, shape (N,)
        Row i of the consensus matrix P (p_ij > 0 for j in-neighbours and j = i).
    A : numpy.ndarray, shape (n, n)
    C : numpy.ndarray, shape (m_i, n)
        Its output matrix (m_i may be 0).
    Q : numpy.ndarray, shape (n, n)
        Process noise covariance.
    R : numpy.ndarray, shape (m_i, m_i)
        Its measurement noise covariance.
    prior_mean : numpy.ndarray, shape (n,)
    prior_cov : numpy.ndarray, shape (n, n)
        The prior x-hat_{0|-1} and its covariance.
    L : numpy.ndarray, shape (n, m_i), or None
        Its innovation gain L_i = K_i C_i^T from the scenario's gain design (None
        unless the family declares ``needs_gains``).
    rng : numpy.random.Generator
        Its own random stream (independent of every other component).
    delay_bound : int
        The delay bound tau-bar the agents are told (steps).
    sample_period : float
        Ts.
    """

    agent: int
    n_agents: int
    in_neighbours: tuple[int, ...]
    out_neighbours: tuple[int, ...]
    weights: np.ndarray
    A: np.ndarray
    C: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    L: np.ndarray | None
    rng: np.random.Generator
    delay_bound: int
    sample_period: float

    @property
    def n_states(self) -> int:
        """n."""
        return int(self.A.shape[0])


@dataclass(frozen=True)
class AgentPlan:
    """One agent a family hosts in a run.

    Attributes
    ----------
    estimator : object
        Implements the per-agent contract (:class:`netsim.estimators.contract.Estimator`).
    sensors : tuple of int
        The sensors whose measurements the agent's ``step`` receives, concatenated in
        this order (one agent, one sensor: ``(i,)``; a centralised filter: all; none: ``()``).
    out_neighbours : tuple of int
        The agents it sends to.
    """

    estimator: Any
    sensors: tuple[int, ...]
    out_neighbours: tuple[int, ...] = ()


def _name_of(obj: Any) -> str:
    return getattr(obj, "__qualname__", None) or type(obj).__name__


@dataclass(frozen=True)
class EstimatorFamily:
    """A declared estimator family.

    Attributes
    ----------
    name : str
        What scenarios and commands call it.
    build : callable(FamilyContext) -> sequence of AgentPlan
        Builds one trial's agents.
    description : str
        One line for listings.
    paper : str
        The paper and equations it implements ("" for a user's family).
    needs_gains : bool
        Whether it uses the scenario's innovation gains L_i (designed once per run).
    timestamps : bool
        Whether it reads messages' time-stamps (False: it is told nothing about them).
    needs_graph_sequence : bool
        Whether it needs a time-varying graph sequence.
    error_recursion : str or None
        The augmented error recursion it declares (:data:`RECURSION_COMPENSATED`,
        LCSYS2022 eq. 9; :data:`RECURSION_UNCOMPENSATED`, delay-tolerant eq. 11;
        :data:`RECURSION_BLOCK`, LCSYS2022 eqs. 15-16), which enables replay and the
        augmented-matrix analytics; None: none.
    centralised : bool
        One agent on every sensor (the reference filter); has no network.
    delay_free : bool
        Its agents exchange no messages (a centralised or local filter), so its results
        do not depend on the links: a delay sweep computes it once.
    batched : str or callable or None
        The batched (vectorised) form, ``module:attribute`` resolved on use: a callable
        ``(scenario, family, gains, trial_seeds, steps, **options) -> batch`` with the
        contract of :func:`netsim.vectorised.run_batch`. None: event kernel only.
    batched_options : dict
        Keyword arguments passed to ``batched``.
    source : str
        ``builtin``, ``python`` (registered from Python), ``scenario`` (named as
        module:attribute) or ``entry-point``.
    observer : callable or None
        ``(context, plans, steps, inner) -> observer``: wraps the kernel observer of
        each run of this family (``inner``: a trace recorder or None), to record what
        only the family knows (the AoI observer's freshness indices). The returned
        object receives every kernel hook, forwards it to ``inner``, and its
        ``collect()`` is kept in ``TrialResult.extras``.
    report : callable or None
        ``(context, trials) -> dict``: family-specific numbers over the trials (a list
        of ``TrialResult``), added to the run's summary as ``report``; a ``verdict``
        key replaces the generic verdict (the AoI observer's "converged at step k").
    analytics : callable or None
        ``(scenario, gains) -> dict``: scenario-level analytics of the family (its
        paper's bounds), shown once per ``analytics_key`` in a run's ``analytics``.
    analytics_key : str
        The key of ``analytics`` (families sharing one analysis share the key).
    reported : callable or None
        ``(scenario) -> sequence of int``: the agents whose estimates the run's MSE and
        verdict are about (a fusion centre, not its sinks); None: every agent.
    reference : str
        What resolves the family in a fresh process (``module:attribute`` or the entry
        point's name; "" for built-ins and families registered from Python), so the
        worker processes of a sweep find a plugin: :attr:`key`.
    """

    name: str
    build: Callable[[FamilyContext], Sequence[AgentPlan]]
    description: str = ""
    paper: str = ""
    needs_gains: bool = False
    timestamps: bool = True
    needs_graph_sequence: bool = False
    error_recursion: str | None = None
    centralised: bool = False
    delay_free: bool = False
    batched: str | Callable[..., Any] | None = None
    batched_options: dict[str, Any] = field(default_factory=dict)
    source: str = "python"
    observer: Callable[..., Any] | None = None
    report: Callable[..., dict[str, Any]] | None = None
    analytics: Callable[..., dict[str, Any]] | None = None
    analytics_key: str = ""
    reported: Callable[..., Sequence[int]] | None = None
    reference: str = ""

    @property
    def key(self) -> str:
        """The name to resolve it by elsewhere: its reference, else its name."""
        return self.reference or self.name

    @property
    def vectorised(self) -> bool:
        """Whether it has a batched form for the vectorised engine."""
        return self.batched is not None

    def batched_form(self) -> Callable[..., Any]:
        """The batched form, imported if it was given as ``module:attribute``."""
        if self.batched is None:
            raise FamilyError(self.name, "has no batched form (event kernel only)")
        if callable(self.batched):
            return self.batched
        return resolve_reference(self.batched, f"family {self.name!r} batched form")

    @property
    def label(self) -> str:
        """How errors name it: its name, and the reference it was resolved by."""
        if self.reference and self.reference != self.name:
            return f"{self.name!r} ({self.reference})"
        return repr(self.name)

    def agents(self, context: FamilyContext, key: str = "run.estimators"
               ) -> list[AgentPlan]:
        """Build one trial's agents and check each against the contract.

        Raises
        ------
        FamilyError
            Naming ``key`` and the family: an agent that breaks the contract, or (for
            a family not shipped with netsim) a factory or constructor that failed on
            the host's arguments, ``SystemExit`` included.
        """
        context = replace(context, family=self.name)
        if self.source == "builtin":  # netsim's own: a failure is a bug, keep its traceback
            built = self.build(context)
        else:
            try:
                built = self.build(context)
            except _AgentBuildError as error:  # the constructor's own error is the cause
                raise FamilyError(key, f"family {self.label}, {error}") from error.__cause__
            except (Exception, SystemExit) as error:
                raise FamilyError(key, f"family {self.label}: its factory "
                                  f"{_name_of(self.build)}(context) failed: "
                                  f"{_failure(error)}") from error
        if isinstance(built, str | bytes) or not isinstance(built, Iterable):
            raise FamilyError(key, f"family {self.label}: its factory "
                              f"{_name_of(self.build)}(context) returned "
                              f"{_describe(built)}, not a list of AgentPlan")
        plans = list(built)
        if not plans:
            raise FamilyError(key, f"family {self.label} built no agents")
        for index, plan in enumerate(plans):
            if not isinstance(plan, AgentPlan):
                plan = AgentPlan(plan, (index,), ())
                plans[index] = plan
            try:
                check_estimator(plan.estimator, key)
            except ContractError as error:
                raise FamilyError(key, f"family {self.label}, agent {index}: "
                                  f"{str(error).split(': ', 1)[1]}") from None
        return plans

    def traits(self) -> dict[str, Any]:
        """What the family declares, as plain values (recorded in traces)."""
        return {
            "name": self.name,
            "paper": self.paper,
            "needs_gains": self.needs_gains,
            "timestamps": self.timestamps,
            "needs_graph_sequence": self.needs_graph_sequence,
            "error_recursion": self.error_recursion,
            "centralised": self.centralised,
            "delay_free": self.delay_free,
            "vectorised": self.vectorised,
            "source": self.source,
        }


_REGISTRY: dict[str, EstimatorFamily] = {}
_LOADED = False


#: The module of each built-in family (tests/test_registry.py checks it against what
#: :data:`BUILTIN_MODULES` register): a run of built-in families imports only their
#: modules, not the AoI or fusion estimators it does not use (start-up latency).
BUILTIN_FAMILIES: dict[str, str] = {
    **dict.fromkeys(("compensated", "uncompensated", "block"), "netsim.estimators.consensus"),
    **dict.fromkeys(("centralized-kf", "local-kf"), "netsim.estimators.kalman"),
    **dict.fromkeys(("aoi", "naive-uniform", "naive-tree"), "netsim.estimators.aoi"),
    **dict.fromkeys(("dkfe", "sdkfe", "odkfe"), "netsim.estimators.fusion"),
    **dict.fromkeys(("kcf", "ci", "diffkf"), "netsim.estimators.baselines"),
}


def _load_builtins(name: str | None = None) -> None:
    """Import the built-in modules: only the one that declares ``name`` if that is a
    built-in family's name, else all of them (listings, other names)."""
    global _LOADED
    if _LOADED:
        return
    module = BUILTIN_FAMILIES.get(name) if name is not None else None
    if module is not None:
        importlib.import_module(module)
        return
    _LOADED = True
    for module in BUILTIN_MODULES:
        importlib.import_module(module)


def register(family: EstimatorFamily, *, replace_existing: bool = False) -> EstimatorFamily:
    """Add a family to the registry and return it.

    Parameters
    ----------
    family : EstimatorFamily
    replace_existing : bool
        Allow replacing a family of the same name (otherwise an error).

    Example
    -------
    >>> from netsim.estimators.registry import EstimatorFamily, register, unregister
    >>> fam = register(EstimatorFamily("doc-hold", lambda ctx: []))
    >>> unregister("doc-hold")
    """
    if not isinstance(family, EstimatorFamily):
        raise TypeError(f"register() takes an EstimatorFamily, not {type(family).__name__}")
    if not family.name or "," in family.name or family.name != family.name.strip():
        raise ValueError(f"family name {family.name!r}: give a non-empty name without ',' "
                         "or surrounding spaces")
    old = _REGISTRY.get(family.name)
    if old is not None and old is not family and not replace_existing:
        raise ValueError(f"an estimator family {family.name!r} is registered already "
                         f"({old.source}); pass replace_existing=True to replace it")
    _REGISTRY[family.name] = family
    return family


def unregister(name: str) -> None:
    """Remove a family and every reference to it (a no-op for an unknown name)."""
    family = _REGISTRY.pop(name, None)
    if family is not None:
        for other in [n for n, f in _REGISTRY.items() if f is family]:
            del _REGISTRY[other]


def _entry_points() -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _add_search_path(base: str | os.PathLike[str] | None) -> None:
    if base is None:
        return
    folder = os.path.abspath(os.fspath(base))
    if os.path.isdir(folder) and folder not in sys.path:
        sys.path.append(folder)


def _search_folders(base: str | os.PathLike[str] | None) -> list[str]:
    """The folders a ``module:attribute`` is looked for in besides the import path: the
    scenario's folder (``base``), then the current directory."""
    folders = [] if base is None else [os.path.abspath(os.fspath(base))]
    cwd = os.getcwd()
    return folders + ([cwd] if cwd not in folders else [])


def resolve_reference(reference: str, key: str,
                      base: str | os.PathLike[str] | None = None) -> Any:
    """Import ``module:attribute`` (dots allowed in both) or raise FamilyError.

    The module is looked for on the import path, in ``base`` (a scenario file's folder,
    so a scenario can name a module that sits beside it) and in the current directory
    (so ``--estimators mymodule:MyFilter`` works beside a built-in scenario without
    PYTHONPATH); the folders are appended to ``sys.path``, after the installed packages.
    The error of a module found nowhere names the folders looked in.
    """
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise FamilyError(key, f"{reference!r} is not module:attribute")
    folders = _search_folders(base)
    for folder in folders:
        _add_search_path(folder)
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        where = ""
        if isinstance(error, ModuleNotFoundError) and error.name is not None and \
                module_name.split(".")[0] == error.name.split(".")[0]:
            named = [f"the scenario's folder {folders[0]}"] if base is not None else []
            named += [f"the current directory {folders[-1]}"] if (
                base is None or len(folders) > 1) else []
            where = f" (looked in {', '.join(named)} and the Python path)"
        raise FamilyError(key, f"cannot import module {module_name!r} for {reference!r}: "
                          f"{error}{where}") from None
    except (Exception, SystemExit) as error:  # the user's module failed while importing
        raise FamilyError(key, f"importing {module_name!r} for {reference!r} failed: "
                          f"{_failure(error)}") from error
    obj: Any = module
    for part in attribute.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise FamilyError(key, f"module {module_name!r} has no attribute {attribute!r}"
                              ) from None
        except (Exception, SystemExit) as error:  # a module __getattr__ of its own
            raise FamilyError(key, f"reading {attribute!r} of module {module_name!r} "
                              f"failed: {_failure(error)}") from error
    return obj


class _AgentBuildError(Exception):
    """A per-agent class's constructor failed (reworded by :meth:`EstimatorFamily.agents`)."""


def _describe(obj: Any) -> str:
    """What ``obj`` is, for a one-line error ("a builtin function (posix.system)")."""
    if obj is None:
        return "None"
    if isinstance(obj, types.ModuleType):
        return f"a module ({obj.__name__})"
    if isinstance(obj, _BUILTIN_CALLABLES):
        return f"a builtin function ({_where(obj)})"
    if isinstance(obj, type):
        return f"a class ({_where(obj)})"
    if inspect.isfunction(obj) or inspect.ismethod(obj):
        return f"a function ({_where(obj)})"
    if not _missing_methods_of_class(type(obj)):
        return f"an instance of {type(obj).__qualname__} (name the class: netsim builds " \
            "one per agent)"
    return f"a {type(obj).__qualname__} object"


def _where(obj: Any) -> str:
    """``module.qualname`` of a function or class."""
    return f"{getattr(obj, '__module__', None) or '?'}.{_name_of(obj)}"


def _missing_methods_of_class(cls: type) -> list[str]:
    """The contract's methods (``message_arrived``, ``step``) that ``cls`` lacks."""
    return [m for m in ("message_arrived", "step") if not callable(getattr(cls, m, None))]


#: Callables implemented in C (``os.system``, ``print``, ``str.join``): none is a family.
_BUILTIN_CALLABLES = (types.BuiltinFunctionType, types.BuiltinMethodType,
                      types.WrapperDescriptorType, types.MethodWrapperType,
                      types.MethodDescriptorType, types.ClassMethodDescriptorType)


def _from_standard_library(obj: Any) -> bool:
    """Whether ``obj`` (a function) is defined in Python's standard library."""
    module = getattr(obj, "__module__", None)
    return isinstance(module, str) and module.split(".")[0] in sys.stdlib_module_names


def _cannot_call_with_one(obj: Any) -> str | None:
    """Why ``obj(x)`` with one positional argument is refused by its signature (None:
    it is accepted, or there is no signature to read)."""
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):  # no signature to read: trust it
        return None
    try:
        signature.bind(None)
    except TypeError as error:
        return f"takes {signature}, not one argument ({error})"
    return None


def _per_agent_factory(cls: Any, name: str) -> Callable[[FamilyContext], list[AgentPlan]]:
    def build(context: FamilyContext) -> list[AgentPlan]:
        plans = []
        for i in range(context.scenario.n_agents):
            setup = context.agent_setup(i)
            try:
                estimator = cls(setup)
            except (Exception, SystemExit) as error:
                raise _AgentBuildError(f"agent {i}: {cls.__qualname__}(setup) failed: "
                                       f"{_failure(error)}") from error
            plans.append(AgentPlan(estimator, (i,), tuple(context.out_neighbours(i))))
        return plans

    build.__qualname__ = f"per-agent {name}"
    return build


def family_from_object(obj: Any, name: str, key: str, source: str = "scenario", *,
                       own_name: bool = True) -> EstimatorFamily:
    """Make a family of an imported object, after checking what the object is.

    ``obj`` may be an :class:`EstimatorFamily` (renamed to ``name`` if it has none), a
    class (each agent i gets ``cls(setup)`` with its :class:`AgentSetup`: weights, plant
    model, gain, neighbours and own random stream; the class's optional attributes
    ``name``, ``needs_gains``, ``timestamps``, ``description``, ``paper`` and ``batched``
    declare the rest), or a factory function ``(FamilyContext) -> list of AgentPlan``.

    Parameters
    ----------
    obj : object
        What the name resolved to.
    name : str
        The name it was asked for by (the family's name unless a class declares its own).
    key : str
        The scenario key or option that named it (``run.estimators[1]``,
        ``--estimators[0]``), for the error.
    source : str
        The family's ``source``.
    own_name : bool
        Whether a class's ``name`` attribute names the family (False for entry points:
        they run under the entry point's name).

    Raises
    ------
    FamilyError
        ``obj`` is none of these: a module, a constant, a builtin or standard-library
        function, a class without ``message_arrived()`` and ``step()`` or whose
        constructor cannot be called as ``cls(setup)``, an abstract class or protocol,
        or a callable that cannot be called as ``factory(context)``.
    """
    if isinstance(obj, EstimatorFamily):
        return obj if obj.name else replace(obj, name=name)
    if isinstance(obj, type):
        where = f"class {obj.__qualname__}"
        for method in _missing_methods_of_class(obj)[:1]:
            raise FamilyError(key, f"{name!r}: {where} is not an "
                              f"estimator: no method {method}() (the contract: "
                              "message_arrived(sender, sent_step, payload) -> bool, "
                              "step(k, y) -> estimate)")
        if getattr(obj, "_is_protocol", False) or inspect.isabstract(obj):
            raise FamilyError(key, f"{name!r}: {where} is abstract (a protocol or an "
                              "abstract base class), not an estimator one can build; name "
                              "a class implementing it")
        why = _cannot_call_with_one(obj)
        if why is not None:
            raise FamilyError(key, f"{name!r}: {where} cannot be built as "
                              f"{obj.__qualname__}(setup), one AgentSetup per agent: its "
                              f"constructor {why}")
        short = getattr(obj, "name", None)
        if (own_name and isinstance(short, str) and short and ":" not in short
                and "," not in short and short == short.strip()):
            name = short
        return EstimatorFamily(
            name=name,
            build=_per_agent_factory(obj, name),
            description=str(getattr(obj, "description", "") or
                            (obj.__doc__ or "").strip().split("\n")[0]),
            paper=str(getattr(obj, "paper", "")),
            needs_gains=bool(getattr(obj, "needs_gains", False)),
            timestamps=bool(getattr(obj, "timestamps", True)),
            batched=getattr(obj, "batched", None),
            source=source,
        )
    if isinstance(obj, _BUILTIN_CALLABLES):
        raise FamilyError(key, f"{name!r} is {_describe(obj)}, not an estimator family "
                          f"({PROTOCOL})")
    if callable(obj) and (inspect.isfunction(obj) or inspect.ismethod(obj)) \
            and _from_standard_library(obj):
        raise FamilyError(key, f"{name!r} is a function of the standard library "
                          f"({_where(obj)}), not an estimator family ({PROTOCOL})")
    if callable(obj):
        why = _cannot_call_with_one(obj)
        if why is not None:
            raise FamilyError(key, f"{name!r} is {_describe(obj)} that cannot be called as "
                              f"a factory, factory(context): it {why} ({PROTOCOL})")
        return EstimatorFamily(name=name, build=obj, description=_name_of(obj),
                               source=source,
                               needs_gains=bool(getattr(obj, "needs_gains", False)))
    raise FamilyError(key, f"{name!r} is {_describe(obj)}, not an estimator family "
                      f"({PROTOCOL})")


def get_family(name: str, key: str = "run.estimators",
               base: str | os.PathLike[str] | None = None) -> EstimatorFamily:
    """Return the family called ``name``: registered, ``module:attribute`` or an entry point.

    A family imported as ``module:attribute`` is registered under that reference and
    under its own name (a class's ``name`` attribute, else the reference), so results
    and traces can use the short name; ``base`` is a folder searched for the module
    (the scenario's, see :func:`resolve_reference`). A family from an entry point is
    registered under the entry point's name, whatever its class calls itself, and its
    results are reported under that name. Either is resolved once per process: asking
    again returns the same family.

    Raises
    ------
    FamilyError
        Naming ``key`` and what is wrong (unknown name, import failure, not an estimator).
    """
    _load_builtins(name if isinstance(name, str) else None)
    if not isinstance(name, str) or not name:
        raise FamilyError(key, f"expected an estimator name, got {name!r}")
    family = _REGISTRY.get(name)
    if family is not None:
        return family
    if ":" in name:
        obj = resolve_reference(name, key, base)
        family = replace(family_from_object(obj, name, key, source="scenario"),
                         reference=name)
        if family.name != name:
            other = _REGISTRY.get(family.name)
            if other is not None and other is not family and other.source == "builtin":
                raise FamilyError(key, f"{name!r} calls itself {family.name!r}, the name of "
                                  "a built-in family; give it another name")
            _REGISTRY[name] = family
        return register(family, replace_existing=True)
    points = _entry_points()
    if name in points:
        try:
            obj = points[name].load()
        except (Exception, SystemExit) as error:
            raise FamilyError(key, f"entry point {name!r} ({points[name].value}) failed to "
                              f"load: {_failure(error)}") from error
        family = family_from_object(obj, name, key, source="entry-point", own_name=False)
        return register(replace(family, name=name, reference=name, source="entry-point"))
    known = ", ".join(family_names())
    raise FamilyError(key, f"unknown estimator {name!r}; expected one of {known}, or "
                      "module:attribute of your own estimator")


def resolve_families(names: Iterable[str], key: str = "run.estimators",
                     base: str | os.PathLike[str] | None = None) -> list[EstimatorFamily]:
    """Resolve several names (:func:`get_family`), refusing duplicates."""
    out: list[EstimatorFamily] = []
    seen: dict[str, str] = {}
    for index, name in enumerate(names):
        family = get_family(name, f"{key}[{index}]", base)
        if family.name in seen:
            first = seen[family.name]
            also = "" if first == name else f" (as {first!r}, both run as {family.name!r})"
            raise FamilyError(f"{key}[{index}]", f"estimator {name!r} is listed twice{also}")
        seen[family.name] = name
        out.append(family)
    return out


def _ordered() -> list[EstimatorFamily]:
    """Registered families: built-ins in the order of :data:`BUILTIN_MODULES`, then the
    others in the order they were registered."""
    _load_builtins()
    unique = [f for n, f in _REGISTRY.items() if n == f.name]

    def rank(item: tuple[int, EstimatorFamily]) -> tuple[int, int]:
        index, family = item
        module = getattr(family.build, "__module__", "")
        if family.source == "builtin" and module in BUILTIN_MODULES:
            return (BUILTIN_MODULES.index(module), index)
        return (len(BUILTIN_MODULES), index)

    return [f for _, f in sorted(enumerate(unique), key=rank)]


def family_names(include_entry_points: bool = True) -> list[str]:
    """Names of the registered families (built-ins first) and of installed entry points."""
    names = [f.name for f in _ordered()]
    if include_entry_points:
        names += [n for n in _entry_points() if n not in _REGISTRY]
    return names


def families() -> list[EstimatorFamily]:
    """The registered families (built-ins and those resolved so far)."""
    return _ordered()


def _origin(family: EstimatorFamily) -> str:
    """Where a family comes from, in words: its module, reference or entry point."""
    module = getattr(family.build, "__module__", None) or "?"
    if family.source == "builtin":
        return f"built-in ({module})"
    if family.source == "entry-point":
        point = _entry_points().get(family.name)
        value = f" = {point.value}" if point is not None else ""
        return f"entry point {ENTRY_POINT_GROUP}: {family.name}{value}"
    if family.source == "scenario":
        return f"module {family.reference or family.name}"
    return f"registered from Python ({module})"


def family_listing(load_entry_points: bool = True) -> list[dict[str, Any]]:
    """Every registered family and installed entry point, as plain values (``netsim
    estimators``): ``name``, ``source`` (built-in, entry-point, module, python),
    ``origin`` (the module, reference or entry point it comes from), ``description``,
    ``traits`` (:meth:`EstimatorFamily.traits`) and, for an entry point that fails to
    load, ``error`` (one line) instead of traits.

    Parameters
    ----------
    load_entry_points : bool
        Load installed entry points to read their traits (False: list them by name).
    """
    out = []
    for family in families():
        traits = family.traits()
        out.append({"name": family.name,
                    "source": {"builtin": "built-in", "scenario": "module"}.get(
                        family.source, family.source),
                    "origin": _origin(family), "description": family.description,
                    "traits": traits})
    listed = {item["name"] for item in out}
    for name, point in _entry_points().items():
        if name in listed:
            continue
        item: dict[str, Any] = {"name": name, "source": "entry-point",
                                "origin": f"entry point {ENTRY_POINT_GROUP}: {name} = "
                                f"{point.value}", "description": "", "traits": None}
        if load_entry_points:
            try:
                family = get_family(name, "entry point")
            except FamilyError as error:
                item["error"] = error.detail
            else:
                item.update(description=family.description, traits=family.traits())
        out.append(item)
    return out
