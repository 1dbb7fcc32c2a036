"""The ``[time]`` table of a scenario: clocks, asynchronous sampling and triggers.

Keys (all optional; every one at its neutral value gives the step kernel's run)::

    [time]
    Ac = [[...]]          # continuous-time plant (then plant.A, plant.Q may be left out)
    Qc = 0.01             # its noise intensity (a number is a multiple of I)
    periods = 1.0         # each agent's sampling period T_i, local time (number or list)
    phases = 0.0          # each agent's phase phi_i, local time (number or list)
    offset = 0.0          # clock offsets o_i: number, list, or a distribution table
    drift_ppm = 0.0       # clock drifts delta_i in ppm: number, list, or a distribution
    jitter = 0.0          # read-jitter standard deviation(s): number or list
    seed = 0              # stream of the clock draws (with the trial seed)

    [time.trigger]
    kind = "send-on-delta"   # always | send-on-delta | periodic
    threshold = 0.05
    every = 1                # periodic: check every this many updates

A distribution table is ``{distribution = "uniform", low = .., high = ..}`` or
``{distribution = "normal", mean = 0, std = ..}``; it is drawn per agent and per trial
from the trial's stream ``("clocks", seed)``.

Without ``Ac``, the plant's ``A`` and ``Q`` are its discretisation at
``run.sample_period`` (T), and the continuous model is recovered from them
(:func:`netsim.models.continuous.continuous_from_discrete`). Every bad value raises a
:class:`TimeError` (a ``ValueError``) naming its key.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from netsim.models.clocks import Clock
from netsim.models.continuous import ContinuousModel
from netsim.models.triggers import TRIGGER_KINDS, TriggerSpec

__all__ = ["TIME_KEYS", "TRIGGER_KEYS", "SYNC_KEYS", "TimeError", "ClockDistribution",
           "SyncSpec", "TimeSpec",
           "parse_time", "plant_table_with_continuous", "MIN_PERIOD_FRACTION", "MAX_OFFSET",
           "MAX_DRIFT_PPM"]

TIME_KEYS = {"Ac", "Qc", "periods", "phases", "offset", "drift_ppm", "jitter", "seed",
             "trigger", "sync"}
SYNC_KEYS = {"period", "reference"}
TRIGGER_KEYS = {"kind", "threshold", "every"}
_DISTRIBUTIONS = {"uniform": ({"low", "high"}, set()), "normal": ({"std"}, {"mean"})}
#: Shortest sampling period accepted, as a fraction of run.sample_period.
MIN_PERIOD_FRACTION = 1e-3
#: Largest |offset| (time units) and |drift| (ppm) accepted.
MAX_OFFSET = 1e9
MAX_DRIFT_PPM = 1e5


class TimeError(ValueError):
    """A bad ``[time]`` setting; ``key`` names it (``time.offset``, ...)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


def _finite(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TimeError(key, f"expected a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise TimeError(key, f"must be finite, got {value!r}")
    return x


def _per_agent(value: Any, key: str, n_agents: int) -> tuple[float, ...]:
    if isinstance(value, list):
        if len(value) != n_agents:
            raise TimeError(key, f"has {len(value)} entries, expected one per agent "
                                 f"({n_agents})")
        return tuple(_finite(v, f"{key}[{i}]") for i, v in enumerate(value))
    return (_finite(value, key),) * n_agents


@dataclass(frozen=True)
class ClockDistribution:
    """Per-agent values of a clock parameter: fixed, or drawn per trial.

    Parameters
    ----------
    kind : str
        ``fixed``, ``uniform`` or ``normal``.
    values : tuple of float
        The fixed values (one per agent) for ``fixed``.
    a, b : float
        (low, high) for ``uniform``; (mean, std) for ``normal``.
    """

    kind: str = "fixed"
    values: tuple[float, ...] = ()
    a: float = 0.0
    b: float = 0.0

    def draw(self, rng: np.random.Generator, n_agents: int) -> np.ndarray:
        """The agents' values, shape (N,)."""
        if self.kind == "fixed":
            return np.array(self.values, dtype=float)
        if self.kind == "uniform":
            return rng.uniform(self.a, self.b, n_agents)
        return self.a + self.b * rng.standard_normal(n_agents)

    @property
    def zero(self) -> bool:
        """Whether every value is 0."""
        return self.kind == "fixed" and not any(self.values)

    def describe(self) -> Any:
        """JSON-ready form."""
        if self.kind == "fixed":
            return list(self.values)
        keys = ("low", "high") if self.kind == "uniform" else ("mean", "std")
        return {"distribution": self.kind, keys[0]: self.a, keys[1]: self.b}


def _distribution(value: Any, key: str, n_agents: int, limit: float) -> ClockDistribution:
    if isinstance(value, dict):
        kind = value.get("distribution")
        if kind not in _DISTRIBUTIONS:
            raise TimeError(f"{key}.distribution", f"unknown distribution {kind!r}; expected "
                                                   "uniform or normal")
        required, optional = _DISTRIBUTIONS[kind]
        for k in value:
            if k != "distribution" and k not in required | optional:
                raise TimeError(f"{key}.{k}", f"unknown key; {kind} takes "
                                              f"{', '.join(sorted(required | optional))}")
        for k in required:
            if k not in value:
                raise TimeError(f"{key}.{k}", "is missing")
        if kind == "uniform":
            low, high = _finite(value["low"], f"{key}.low"), _finite(value["high"], f"{key}.high")
            if high < low:
                raise TimeError(f"{key}.high", f"must be >= low ({low:g}), got {high:g}")
            if max(abs(low), abs(high)) > limit:
                raise TimeError(key, f"values beyond +-{limit:g} are not supported")
            return ClockDistribution("uniform", (), low, high)
        mean = _finite(value.get("mean", 0.0), f"{key}.mean")
        std = _finite(value["std"], f"{key}.std")
        if std < 0:
            raise TimeError(f"{key}.std", f"must be >= 0, got {std:g}")
        if abs(mean) + 10 * std > limit:
            raise TimeError(key, f"values beyond +-{limit:g} are not supported")
        return ClockDistribution("normal", (), mean, std)
    values = _per_agent(value, key, n_agents)
    for i, v in enumerate(values):
        if abs(v) > limit:
            raise TimeError(key if not isinstance(value, list) else f"{key}[{i}]",
                            f"|{v:g}| is beyond the supported {limit:g}")
    return ClockDistribution("fixed", values)


def _square(value: Any, key: str, n: int | None) -> np.ndarray:
    if isinstance(value, int | float) and not isinstance(value, bool):
        if n is None:
            raise TimeError(key, "a number needs time.Ac to fix the size")
        return float(value) * np.eye(n)
    try:
        matrix = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise TimeError(key, f"expected a matrix (list of rows), got {value!r}") from None
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1] or matrix.size == 0:
        raise TimeError(key, f"expected a square matrix, got shape {matrix.shape}")
    if n is not None and matrix.shape[0] != n:
        raise TimeError(key, f"has shape {matrix.shape}, expected ({n}, {n})")
    if not np.all(np.isfinite(matrix)):
        raise TimeError(key, "has entries that are not finite")
    return matrix


def plant_table_with_continuous(data: dict[str, Any], period: float) -> dict[str, Any]:
    """The ``[plant]`` table, with ``A`` and ``Q`` filled in from ``time.Ac``/``time.Qc``
    (their discretisation at ``period``) when the time table gives them.

    Raises :class:`TimeError` if both plant.A and time.Ac are given.
    """
    plant = data.get("plant")
    time = data.get("time")
    if not isinstance(plant, dict) or not isinstance(time, dict) or "Ac" not in time:
        return plant if isinstance(plant, dict) else {}
    for key in ("A", "Q"):
        if key in plant:
            raise TimeError(f"plant.{key}", f"give either plant.{key} (the discretisation at "
                                            f"run.sample_period) or time.{key}c, not both")
    if "Qc" not in time:
        raise TimeError("time.Qc", "is missing (time.Ac is given)")
    Ac = _square(time["Ac"], "time.Ac", None)
    Qc = _square(time["Qc"], "time.Qc", Ac.shape[0])
    _check_psd(Qc, "time.Qc")
    model = ContinuousModel.from_continuous(Ac, Qc, period)
    return {**plant, "A": model.A.tolist(), "Q": model.Q.tolist()}


def _check_psd(Q: np.ndarray, key: str) -> None:
    if not np.allclose(Q, Q.T, atol=1e-12):
        raise TimeError(key, "must be symmetric")
    if np.linalg.eigvalsh(0.5 * (Q + Q.T)).min(initial=0.0) < -1e-12 * max(
            1.0, float(np.abs(Q).max())):
        raise TimeError(key, "must be positive semi-definite")


@dataclass(frozen=True)
class SyncSpec:
    """A validated ``[time.sync]`` table: a periodic two-way exchange with the parent on
    a shortest-path tree from the reference agent (:mod:`netsim.timedkernel`).

    Parameters
    ----------
    period : float
        Local time between an agent's exchanges.
    reference : int
        The agent whose clock the others follow.
    """

    period: float
    reference: int = 0

    def describe(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"period": self.period, "reference": self.reference}


@dataclass(frozen=True)
class TimeSpec:
    """A validated ``[time]`` table (see the module docstring).

    Attributes
    ----------
    model : ContinuousModel
        The continuous plant and its discretisation at the base period T.
    periods, phases : tuple of float, each (N,)
        Sampling period T_i and phase phi_i of each agent (local time).
    offset, drift_ppm : ClockDistribution
        Clock offsets o_i and drifts (ppm).
    jitter : tuple of float, (N,)
        Read-jitter standard deviations.
    seed : int
        Clock stream (with the trial seed).
    trigger : TriggerSpec
    """

    model: ContinuousModel
    periods: tuple[float, ...]
    phases: tuple[float, ...]
    offset: ClockDistribution = field(default_factory=ClockDistribution)
    drift_ppm: ClockDistribution = field(default_factory=ClockDistribution)
    jitter: tuple[float, ...] = ()
    seed: int = 0
    trigger: TriggerSpec = field(default_factory=TriggerSpec)
    sync: SyncSpec | None = None

    @property
    def n_agents(self) -> int:
        """N."""
        return len(self.periods)

    def clocks(self, trial_seed: Any) -> list[Clock]:
        """Each agent's clock in one trial (distributions drawn from the trial's stream)."""
        from netsim.models.seeding import stream

        rng = stream(trial_seed, "clocks", self.seed)
        n = self.n_agents
        offsets = self.offset.draw(rng, n)
        drifts = self.drift_ppm.draw(rng, n)
        return [Clock(float(offsets[i]), float(drifts[i]), self.jitter[i], self.periods[i],
                      self.phases[i]) for i in range(n)]

    @property
    def synchronous_grid(self) -> bool:
        """Whether every agent samples on the base grid k T with a neutral clock."""
        T = self.model.period
        return (self.offset.zero and self.drift_ppm.zero and not any(self.jitter)
                and all(p == T for p in self.periods) and not any(self.phases))

    @property
    def neutral(self) -> bool:
        """Whether the table changes nothing: the base grid, neutral clocks, every update
        sent, no synchronisation (the step kernel's run and its analytics apply)."""
        return self.synchronous_grid and self.trigger.neutral and self.sync is None

    def analytics_note(self) -> str:
        """Why the step model's exact analyses do not decide a run under this table."""
        what = [w for w, on in (
            ("clock offsets", not self.offset.zero), ("clock drifts", not self.drift_ppm.zero),
            ("read jitter", any(self.jitter)),
            ("asynchronous sampling", any(p != self.model.period for p in self.periods)
             or any(self.phases)),
            (f"a {self.trigger.kind} trigger", not self.trigger.neutral),
            ("clock synchronisation", self.sync is not None)) if on]
        return (f"[time] with {', '.join(what) or 'no change'}: the exact analyses (eqs. 9, "
                "11, the joint system) are the step model's (one clock, one grid, every "
                "update sent) and do not decide these runs; the verdicts are measured "
                "(docs/time.rst)")

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "continuous_plant": self.model.describe(),
            "periods": list(self.periods), "phases": list(self.phases),
            "offset": self.offset.describe(), "drift_ppm": self.drift_ppm.describe(),
            "jitter": list(self.jitter), "seed": self.seed,
            "trigger": {"kind": self.trigger.kind, "threshold": self.trigger.threshold,
                        "every": self.trigger.every},
            **({"sync": self.sync.describe()} if self.sync is not None else {}),
        }


def _check_table(value: Any, key: str, allowed: Collection[str]) -> None:
    """TimeError unless ``value`` is a table (the one named ``key``) whose keys are all in
    ``allowed`` (naming the first other key)."""
    if not isinstance(value, dict):
        raise TimeError(key, f"expected a table, got {value!r}")
    for k in value:
        if k not in allowed:
            raise TimeError(f"{key}.{k}", f"unknown key; allowed: {', '.join(sorted(allowed))}")


def _parse_trigger(value: Any) -> TriggerSpec:
    _check_table(value, "time.trigger", TRIGGER_KEYS)
    kind = value.get("kind", "always")
    if kind not in TRIGGER_KINDS:
        raise TimeError("time.trigger.kind", f"unknown kind {kind!r}; expected one of "
                                             f"{', '.join(TRIGGER_KINDS)}")
    threshold = _finite(value.get("threshold", 0.0), "time.trigger.threshold")
    if threshold < 0:
        raise TimeError("time.trigger.threshold", f"must be >= 0, got {threshold:g}")
    every = value.get("every", 1)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise TimeError("time.trigger.every", f"must be an integer >= 1, got {every!r}")
    if kind == "always" and ("threshold" in value or "every" in value):
        raise TimeError("time.trigger.kind", "is 'always' (send every update): threshold "
                                             "and every need send-on-delta or periodic")
    if kind == "send-on-delta" and "every" in value:
        raise TimeError("time.trigger.every", "only the periodic trigger takes it")
    return TriggerSpec(kind, threshold, every)


def parse_time(table: Any, A: np.ndarray, Q: np.ndarray, period: float,
               n_agents: int) -> TimeSpec:
    """Validate the ``[time]`` table of a scenario whose plant is (A, Q) at ``period``.

    Raises
    ------
    TimeError
        Naming the first bad key.
    """
    _check_table(table, "time", TIME_KEYS)
    if "Ac" in table:
        Ac = _square(table["Ac"], "time.Ac", A.shape[0])
        Qc = _square(table.get("Qc"), "time.Qc", A.shape[0])
        model = ContinuousModel(Ac, Qc, np.asarray(A, float), np.asarray(Q, float), period)
    else:
        if "Qc" in table:
            raise TimeError("time.Qc", "needs time.Ac (without it the continuous model is "
                                       "recovered from plant.A and plant.Q)")
        try:
            model = ContinuousModel.from_discrete(A, Q, period)
        except ValueError as exc:
            raise TimeError("plant.A", str(exc).removeprefix("plant.A ")) from None
    periods = _per_agent(table.get("periods", period), "time.periods", n_agents)
    for i, p in enumerate(periods):
        if not p > 0:
            raise TimeError("time.periods", f"agent {i}'s period must be > 0, got {p:g}")
        if p < MIN_PERIOD_FRACTION * period:
            raise TimeError("time.periods", f"agent {i}'s period {p:g} is below "
                                            f"{MIN_PERIOD_FRACTION:g} run.sample_period "
                                            "(too many events)")
    phases = _per_agent(table.get("phases", 0.0), "time.phases", n_agents)
    offset = _distribution(table.get("offset", 0.0), "time.offset", n_agents, MAX_OFFSET)
    drift = _distribution(table.get("drift_ppm", 0.0), "time.drift_ppm", n_agents,
                          MAX_DRIFT_PPM)
    jitter = _per_agent(table.get("jitter", 0.0), "time.jitter", n_agents)
    for i, s in enumerate(jitter):
        if s < 0:
            raise TimeError("time.jitter", f"agent {i}'s jitter must be >= 0, got {s:g}")
    seed = table.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise TimeError("time.seed", f"must be an integer >= 0, got {seed!r}")
    trigger = _parse_trigger(table.get("trigger", {}))
    sync = _parse_sync(table["sync"], n_agents, period) if "sync" in table else None
    return TimeSpec(model, periods, phases, offset, drift, jitter, int(seed), trigger, sync)


def _parse_sync(value: Any, n_agents: int, base: float) -> SyncSpec:
    _check_table(value, "time.sync", SYNC_KEYS)
    if "period" not in value:
        raise TimeError("time.sync.period", "is missing")
    period = _finite(value["period"], "time.sync.period")
    if period < MIN_PERIOD_FRACTION * base:
        raise TimeError("time.sync.period", f"must be >= {MIN_PERIOD_FRACTION:g} "
                                            f"run.sample_period, got {period:g}")
    reference = value.get("reference", 0)
    if isinstance(reference, bool) or not isinstance(reference, int) or not (
            0 <= reference < n_agents):
        raise TimeError("time.sync.reference", f"must be an agent 0..{n_agents - 1}, got "
                                               f"{reference!r}")
    return SyncSpec(period, int(reference))
