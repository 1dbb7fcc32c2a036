"""netsim: discrete-event simulation of distributed estimation over delayed networks.

The public Python API (:mod:`netsim.api`), loaded on first use so that importing a
submodule (``netsim.models``, ``netsim.traces``) stays light:

- :func:`load_scenario` (a built-in name, a TOML file or a dict), :func:`run` (Monte
  Carlo, a :class:`RunResult` with per-trial arrays and a summary), :func:`run_one`
  (one trial in the SimPy event kernel);
- the estimator contract :class:`Estimator` (a ``typing.Protocol``),
  :func:`register_estimator`, :func:`estimator_names`, :class:`EstimatorFamily`,
  :class:`AgentSetup`;
- :func:`design_gains`, :func:`analyze`, :func:`read_trace`; ``__version__``.
"""

# Importing netsim changes nothing process-wide (no environment variables): the work
# that wants one BLAS thread limits it while it runs (netsim.threads).
from netsim.models.delaysources import (
    register_delay_source as _register_delay_source,
)
from netsim.models.medium import register_medium_simulator as _register_medium_simulator


def _trace_replay(path):
    """The ``"trace"`` delay source: imports :mod:`netsim.traces` only when a scenario
    names a trace, so ``netsim.models`` never loads ``netsim.traces`` by itself."""
    from netsim.traces.linkdelays import load_trace_replay

    return load_trace_replay(path)


# Before any netsim.models module runs (netsim/__init__ always loads first), give the
# scenario loader its reader of trace-driven delays ([links] delay.distribution = "trace").
_register_delay_source("trace", _trace_replay)


def _medium(spec, links, sample_period, seed):
    """The ``[network.medium]`` simulator: imports simpy and :mod:`netsim.medium` only
    when a scenario names a medium (``netsim.models`` never imports simpy)."""
    from netsim.medium.schedule import simulate_medium

    return simulate_medium(spec, links, sample_period, seed)


_register_medium_simulator(_medium)



def _version() -> str:
    """The installed distribution's version (importlib.metadata costs 20-50 ms to
    import, so ``__version__`` is looked up on first access)."""
    from importlib import metadata

    try:
        return metadata.version("netsim")
    except metadata.PackageNotFoundError:  # pragma: no cover - run from a source tree
        return "0+unknown"

_API = (
    "Estimator", "EstimatorFamily", "AgentSetup", "AgentPlan", "FamilyContext",
    "FamilyError", "ScenarioError", "Scenario", "load_scenario", "estimator_names",
    "register_estimator", "get_estimator", "design_gains", "run", "run_one", "analyze",
    "read_trace", "FamilyRun", "RunResult",
)

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name == "__version__":
        globals()["__version__"] = version = _version()
        return version
    if name in _API:
        from netsim import api

        return getattr(api, name)
    raise AttributeError(f"module 'netsim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API) | {"__version__"})
