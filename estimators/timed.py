"""Consensus estimators on local clocks and asynchronous sampling (the timed contract).

The timed contract extends the per-agent contract (:mod:`netsim.estimators.contract`)
for scenarios with a ``[time]`` table (:mod:`netsim.models.timing`). At each of its own
sampling instants the host (:mod:`netsim.timedkernel`):

1. hands over every message that has arrived, ``message_arrived(sender, stamp,
   payload)``, where ``stamp`` is now the *sender's local time* (a float) at which the
   payload x-hat^j was computed -- the time the data refers to, read on another clock;
2. calls ``step_at(t, y, elapsed, transition, out=None)``: ``t`` is the agent's own
   local time of the sample (its clock, with jitter), ``elapsed`` the local time since
   its previous update, ``transition`` Phi(elapsed) = expm(A_c elapsed), the plant's
   transition over that interval as the agent's clock measures it;
3. sends what ``outgoing(t)`` returns (None: nothing; a trigger decides,
   :mod:`netsim.models.triggers`).

An estimator without ``step_at`` cannot run under a ``[time]`` table (the host says so
in one line). Step-synchronous estimators keep running, unchanged, on scenarios
without one.

Rules (agent i at local time t, neighbour j's freshest stamp s_j, own interval h_i):

* :class:`TimedCompensatingEstimator` -- LCSYS2022 eq. (4) with A^(k - s_j) read as
  the transition over the stamp difference measured across two clocks:
  x-hat^i_{t|t-} = p_ii Phi(h_i) x-hat^i + sum_j p_ij Phi(t - s_j) x-hat^j_{s_j},
  then the innovation (5). On one clock and one grid t - s_j = (k - s_j) T and
  Phi((k - s_j) T) = A^(k - s_j): the step rule exactly.
* :class:`TimedUncompensatedEstimator` -- delay-tolerant paper eq. (6) with A read as
  the transition over the agent's own interval: p_ij Phi(h_i) x-hat^j (most recently
  arrived), never using the stamps.

See ``docs/time.rst`` for what these become when the clocks disagree.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from netsim.estimators.consensus import NO_MESSAGE, ConsensusParameters, _ConsensusBase
from netsim.models.continuous import ContinuousModel
from netsim.models.triggers import Trigger, TriggerSpec

__all__ = ["TimedCompensatingEstimator", "TimedUncompensatedEstimator", "TIMED_FORMS",
           "TIMED_CLASSES",
           "timed_agents", "takes_time"]

#: Update operators cached per estimator (keys of lags seen); beyond, built afresh.
_OPERATOR_CACHE = 512


def takes_time(estimator: Any) -> bool:
    """Whether an estimator implements the timed contract (has ``step_at``)."""
    return callable(getattr(estimator, "step_at", None))


class _TimedConsensus(_ConsensusBase):
    """Shared timed update (eqs. (4)-(5) with transitions over local time intervals)."""

    def __init__(self, params: ConsensusParameters, model: ContinuousModel,
                 trigger: TriggerSpec | None = None) -> None:
        super().__init__(params)
        self.model = model
        self.trigger: Trigger | None = None if trigger is None else trigger.make()
        #: Lags t - s_j (local time) of the last update per neighbour (None: silent).
        self.last_lags: dict[int, float | None] = {}
        self._timed_ops: dict[tuple[Any, ...], np.ndarray] = {}
        self._blocks: dict[float, np.ndarray] = {}

    def _block(self, lag: float) -> np.ndarray:
        """(I - L_i C_i) Phi(lag), cached by lag (whole periods: A^r, as the step rule)."""
        block = self._blocks.get(lag)
        if block is None:
            block = self._closed_loop.dot(self.model.transition(lag))
            if len(self._blocks) < 4 * _OPERATOR_CACHE:
                self._blocks[lag] = block
        return block

    def step_at(self, t: float, y: np.ndarray, elapsed: float, transition: np.ndarray,
                out: np.ndarray | None = None) -> np.ndarray:
        """Run the update at local time ``t`` with the measurement y (shape (m_i,)).

        Parameters
        ----------
        t : float
            The agent's local time of this sample.
        y : numpy.ndarray, shape (m_i,)
            The measurement.
        elapsed : float
            Local time since the previous update (0 at the first).
        transition : numpy.ndarray, shape (n, n)
            Phi(elapsed), the plant's transition over that interval.
        out : numpy.ndarray, shape (n,), optional
            Where to write the estimate (see :meth:`_ConsensusBase.step`).

        Returns
        -------
        numpy.ndarray, shape (n,)
            x-hat^i at local time t.
        """
        if not self._started:
            self._started = True
            self.last_delays = {j: NO_MESSAGE for j in self.neighbours}
            self.last_lags = {j: None for j in self.neighbours}
            self._estimate = self._written(self._innovate(self._estimate, y), out)
            self.last_step = 0
            return self._estimate
        lags = self._neighbour_lags(t, elapsed)
        key = (elapsed, *lags)
        operator = self._timed_ops.get(key)
        if operator is None:
            operator = self._timed_operator(lags, transition)
            if len(self._timed_ops) < _OPERATOR_CACHE:
                self._timed_ops[key] = operator
        period = self.model.period
        self.last_lags = dict(zip(self.neighbours, lags, strict=True))
        stamps = self._stamps
        self.last_delays = {
            j: NO_MESSAGE if s is None else round((t - s) / period) - 1
            for j, s in zip(self.neighbours, stamps, strict=True)}
        vector = np.concatenate([self._estimate, *(v for v in self._payloads if v is not None),
                                 y])
        if out is not None and vector.dtype == np.float64 and operator.dtype == np.float64:
            self._estimate = operator.dot(vector, out)
        else:
            self._estimate = operator.dot(vector)
        self.last_step = (self.last_step or 0) + 1
        return self._estimate

    def own_block(self, silent: tuple[bool, ...], transition: np.ndarray) -> np.ndarray:
        """G_i = (I - L_i C_i)(p_ii + sum of the silent p_ij) Phi(h_i), shape (n, n).

        ``silent[p]``: whether neighbour ``neighbours[p]`` has not been heard from (its
        weight goes to the own term, DESIGN.md); ``transition`` is Phi(h_i).
        """
        own_weight = self._own_weight + sum(
            w for (_, w), quiet in zip(self._neighbour_weights, silent, strict=True) if quiet)
        return self._closed_loop.dot(own_weight * transition)

    def neighbour_block(self, position: int, lag: float) -> np.ndarray:
        """G_j = p_ij (I - L_i C_i) Phi(lag), shape (n, n), for neighbour
        ``neighbours[position]`` at the lag the rule gives (:meth:`neighbour_lag`)."""
        return self._neighbour_weights[position][1] * self._block(lag)

    def neighbour_lag(self, t: Any, elapsed: float, stamp: Any) -> Any:
        """The interval a neighbour's estimate stamped ``stamp`` is propagated over at
        local time ``t`` (floats, or arrays of them elementwise)."""
        raise NotImplementedError

    def _neighbour_lags(self, t: float, elapsed: float) -> tuple[float | None, ...]:
        return tuple(None if s is None else self.neighbour_lag(t, elapsed, s)
                     for s in self._stamps)

    def _timed_operator(self, lags: tuple[float | None, ...], transition: np.ndarray
                        ) -> np.ndarray:
        """[G_i, G_j..., L_i]: G_i = (I - L C)(p_ii + silent p_ij) Phi(h_i), G_j = p_ij
        (I - L C) Phi(lag_j) (the same products, in the same order, as the step rule's
        operator, so one clock on one grid gives its numbers bit for bit)."""
        own = self.own_block(tuple(lag is None for lag in lags), transition)
        blocks = [self.neighbour_block(p, lag) for p, lag in enumerate(lags)
                  if lag is not None]
        return np.concatenate([own, *blocks, self._L], axis=1)

    def step(self, k: int, y: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The step contract on the base grid: ``step_at(k T, y, T, A)``."""
        period = self.model.period
        return self.step_at(k * period, y, period if self._started else 0.0,
                            self.model.A, out)

    def outgoing(self, step: Any) -> np.ndarray | None:
        """The estimate, if the trigger lets it through (no trigger: always)."""
        if self.trigger is None or self.trigger.should_send(self._estimate):
            return self._estimate
        return None


class TimedCompensatingEstimator(_TimedConsensus):
    """LCSYS2022 eqs. (4)-(5) on local clocks: Phi(t - s_j) compensation (see module)."""

    family = "compensated"
    uses_timestamps = True
    compensates = True

    def neighbour_lag(self, t: Any, elapsed: float, stamp: Any) -> Any:
        """t - s_j: the stamp difference across the two clocks."""
        return t - stamp


class TimedUncompensatedEstimator(_TimedConsensus):
    """Delay-tolerant eqs. (6)-(7) on local clocks: Phi(h_i) on every neighbour."""

    family = "uncompensated"
    uses_timestamps = False
    compensates = False

    def neighbour_lag(self, t: Any, elapsed: float, stamp: Any) -> Any:
        """h_i, the agent's own interval, whatever the stamp."""
        return elapsed


def timed_agents(context: Any, compensate: bool) -> list[Any]:
    """The agents (AgentPlan) of the timed consensus family of a scenario with ``[time]``.

    Parameters
    ----------
    context : netsim.estimators.registry.FamilyContext
    compensate : bool
        Phi(t - s_j) compensation (True) or Phi(h_i) (False).
    """
    from netsim.estimators.registry import AgentPlan

    scenario, gains = context.scenario, context.gains
    if gains is None:
        raise ValueError(f"estimator family {context.family!r} needs gains")
    timing = scenario.timing
    plant, P, graph = scenario.plant, scenario.weights, scenario.graph
    trigger = None if timing.trigger.neutral else timing.trigger
    make = TimedCompensatingEstimator if compensate else TimedUncompensatedEstimator
    plans = []
    for i in range(scenario.n_agents):
        params = ConsensusParameters(agent=i, weights=P[i], A=plant.A, C=plant.C[i],
                                     L=gains.L[i], prior=plant.x0_mean)
        plans.append(AgentPlan(make(params, timing.model, trigger), (i,),
                               tuple(sorted(graph.successors(i)))))
    return plans


#: Families with a timed form: name -> the timed estimator class.
TIMED_CLASSES: dict[str, type[_TimedConsensus]] = {
    cls.family: cls for cls in (TimedCompensatingEstimator, TimedUncompensatedEstimator)}

#: Families with a timed form: name -> factory(context) of its agents.
TIMED_FORMS = {
    "compensated": lambda context: timed_agents(context, True),
    "uncompensated": lambda context: timed_agents(context, False),
}
