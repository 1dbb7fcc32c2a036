"""The per-agent estimator contract every family implements, built-in or plugged in.

An estimator is agent i's update rule: a plain object that knows nothing of SimPy, so
the same object runs in the event kernel, in tests and in a host of the user's own.
At step k the host (``../shared/DESIGN.md``, "What every estimator may rely on"):

1. hands over every message whose arrival time is <= k Ts, in arrival order:
   ``message_arrived(sender, sent_step, payload) -> bool`` (True: kept, False:
   discarded; ``sent_step`` is the sender's time-stamp, the time the data refers to,
   kept apart from the time it arrived, which is the order of the calls);
2. calls ``step(k, y)`` once with the agent's own measurement y^i_k (shape (m_i,),
   possibly (0,)) and takes the returned x-hat^i_{k|k}, shape (n,);
3. sends what ``outgoing(k)`` returns on every out-link (optional; default: the
   estimate; None: nothing this step).

Every estimator also has ``estimate``, its current estimate x-hat^i (shape (n,); a
property or an attribute). Optional attributes the host reads when present:
``last_delays`` (dict j -> r_ij[k], the effective delay of each neighbour's estimate
used by the last update; -1 when the agent substituted its own),
and an ``out`` parameter of ``step`` (``step(k, y, out)`` may write the estimate into
the host's row ``out``, shape (n,), float64, and return it).

Examples
--------
>>> import numpy as np
>>> from netsim.estimators.contract import check_estimator
>>> class Hold:
...     def __init__(self, n):
...         self.estimate = np.zeros(n)
...     def message_arrived(self, sender, sent_step, payload):
...         return False
...     def step(self, k, y):
...         return self.estimate
>>> check_estimator(Hold(2), "run.estimators[0]")
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["Estimator", "ContractError", "EstimatorFailure", "missing_methods",
           "check_estimator"]


class EstimatorFailure(RuntimeError):
    """An estimator raised while a simulation ran it (one line: which estimator, which
    agent, which step, and what it raised; the original exception is its cause)."""


@runtime_checkable
class Estimator(Protocol):
    """One agent's update rule (see the module docstring for the call order)."""

    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool:
        """Take a delivered message; return whether it was kept."""
        ...

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Run step k with the agent's measurement y^i_k; return x-hat^i_{k|k}, (n,)."""
        ...

    @property
    def estimate(self) -> np.ndarray:
        """The current estimate x-hat^i, shape (n,)."""
        ...


class ContractError(TypeError):
    """An object does not implement the estimator contract.

    Parameters
    ----------
    key : str
        What named the object (a scenario key such as ``run.estimators[1]``).
    message : str
        What is missing.
    """

    def __init__(self, key: str, message: str) -> None:
        self.key = key
        super().__init__(f"{key}: {message}")


#: Methods every estimator has, with the number of positional arguments each takes.
_REQUIRED = {"message_arrived": 3, "step": 2}
#: Methods an estimator may have (called when present).
_OPTIONAL = {"outgoing": 1}


def _accepts(function: Any, count: int) -> bool:
    import inspect

    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):  # a builtin without a signature: trust it
        return True
    try:
        signature.bind(*([None] * count))
    except TypeError:
        return False
    return True


def missing_methods(obj: Any) -> list[str]:
    """Return what ``obj`` lacks of the contract (empty when it satisfies it).

    Each entry names a method and what is wrong with it (absent, not callable, or a
    signature that does not take the contract's arguments).
    """
    problems = []
    for name, count in _REQUIRED.items():
        method = getattr(obj, name, None)
        if method is None:
            problems.append(f"no method {name}()")
        elif not callable(method):
            problems.append(f"{name} is not callable")
        elif not _accepts(method, count):
            problems.append(f"{name}() does not take {count} arguments")
    if not hasattr(obj, "estimate"):
        problems.append("no attribute estimate")
    for name, count in _OPTIONAL.items():
        method = getattr(obj, name, None)
        if method is not None and not (callable(method) and _accepts(method, count)):
            problems.append(f"{name} must be a method taking {count} argument")
    return problems


def check_estimator(obj: Any, key: str) -> None:
    """Raise :class:`ContractError` naming ``key`` if ``obj`` is not an estimator."""
    problems = missing_methods(obj)
    if problems:
        raise ContractError(
            key, f"{type(obj).__name__} is not an estimator: {'; '.join(problems)} "
            "(the contract: message_arrived(sender, sent_step, payload) -> bool, "
            "step(k, y) -> estimate, an estimate attribute; see "
            "netsim.estimators.contract)")
