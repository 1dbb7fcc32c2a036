"""The SimPy event kernel: plant process, agents hosting estimators, delayed links.

One run of one estimator family over one realisation of the plant and the links.
Event order within a sampling instant k (simulation time k, in units of Ts):

1. deliveries arriving at k, in sending order (one URGENT event per arrival instant
   on the shared :class:`netsim.deliveries.DeliveryCalendar`);
2. the plant process publishes x_k and every sensor's y^i_k, then fires the step's
   tick (the plant does not depend on the estimators, so its trajectory is drawn from
   its stream and simulated up front, :meth:`netsim.models.plant.LinearPlant.simulate`);
3. every agent process, in agent order, runs its estimator's update for step k;
   then, in the same order, sends its new estimate on its out-links;
4. the monitor (a callback of the tick, after the agents') records every agent's
   estimate and checks for divergence.

Deliveries scheduled during step 3 for time k (zero latency) are processed after
all updates of step k, so a message is never used at the step it was sent.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, cast

import numpy as np
import simpy

from netsim import interrupt
from netsim.deliveries import DeliveryCalendar
from netsim.estimators.contract import EstimatorFailure
from netsim.links import ConfiguredLink, Link, Message, resolve_link, sender_function
from netsim.models.delays import DelayModel
from netsim.models.plant import LinearPlant
from netsim.trialresult import (  # re-exported: they lived here before (issue 34)
    DEFAULT_DIVERGENCE_THRESHOLD,
    NOT_USED,
    ROUNDOFF_RELATIVE_ERROR,
    TrialResult,
    squared_threshold,
)

__all__ = [
    "KernelObserver",
    "HostedEstimator",
    "AgentSpec",
    "TrialResult",
    "Simulation",
    "NOT_USED",
    "DEFAULT_DIVERGENCE_THRESHOLD",
    "ROUNDOFF_RELATIVE_ERROR",
    "squared_threshold",
]



class HostedEstimator(Protocol):
    """What the kernel needs from an estimator object.

    Optional, used when present: ``outgoing(k)`` (the payload to send after step k,
    None for nothing; default: the estimate), ``last_delays`` (dict j -> r_ij[k]
    of the last update), and an ``out`` parameter of ``step``: ``step(k, y, out)``
    may put the estimate into ``out`` (the kernel's row of estimates for this agent
    and step, shape (n,), float64) and return it, saving the kernel a copy (see
    :meth:`netsim.estimators.consensus.CompensatingEstimator.step`).
    """

    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool: ...

    def step(self, k: int, y: np.ndarray) -> np.ndarray: ...

    @property
    def estimate(self) -> np.ndarray: ...


def _takes_out(estimator: Any) -> bool:
    """Whether the estimator's ``step`` has an ``out`` parameter (HostedEstimator)."""
    try:
        return "out" in inspect.signature(estimator.step).parameters
    except (TypeError, ValueError):  # no signature to read
        return False


class KernelObserver(Protocol):
    """Hooks called by the kernel (e.g. a trace recorder); all optional."""

    def on_plant(self, k: int, state: np.ndarray, measurements: Sequence[np.ndarray]) -> None: ...
    def on_sent(self, message: Message) -> None: ...
    def on_delivered(self, message: Message, accepted: bool) -> None: ...
    def on_dropped(self, message: Message, reason: str = "", drop_time: float | None = None
                   ) -> None: ...
    def on_update(
        self, agent: int, k: int, estimate: np.ndarray, delays: dict[int, int]
    ) -> None: ...


@dataclass
class AgentSpec:
    """An agent of the simulation.

    Parameters
    ----------
    estimator : HostedEstimator
        The update rule (knows nothing of SimPy).
    measure : callable(list of y^i_k) -> numpy.ndarray or None
        Selects this agent's measurement from all sensors' (e.g. ``lambda ys: ys[i]``);
        None for an agent that measures nothing (a fusion centre).
    out_neighbours : sequence of int
        Agents this one sends its estimate to.
    """

    estimator: Any
    measure: Callable[[Sequence[np.ndarray]], np.ndarray | None]
    out_neighbours: Sequence[int] = ()


class Simulation:
    """One run: a plant, agents and links in a SimPy environment.

    Parameters
    ----------
    plant : LinearPlant
    agents : sequence of AgentSpec
    delay_model : DelayModel
        Delay of every link (j, i) for j in agent i's in-neighbours. A model with a
        ``link(sender, receiver)`` method (:class:`netsim.models.linkmodels.NetworkLinks`, what
        a scenario with a ``[links]`` table builds) also gives each link its
        :class:`netsim.models.linkmodels.LinkModel` (own delays, loss, outages, buffer).
    plant_rng : numpy.random.Generator
        Stream for x_0, process and measurement noise.
    sample_period : float
        Ts.
    divergence_threshold : float
        Error norm that counts as divergence.
    record_delays : bool
        Keep the (K+1, N, N) array of effective delays.
    record_messages : bool
        Keep every delivered message.
    observer : KernelObserver, optional
        Receives every event (trace recording).
    availability : callable(sender, receiver, step) -> bool, optional
        Whether link (sender -> receiver) is up at a sending step (time-varying
        topologies, link schedules). A message sent on a down link is dropped, counted
        and reported to the observer.
    link_models : mapping (sender, receiver) -> LinkModel, optional
        Per-link models, taking precedence over the delay model's ``link()``. A link
        whose model has no loss, outage or buffer is a plain :class:`Link` (with the
        model's delays), so it costs nothing extra per message.
    """

    def __init__(
        self,
        plant: LinearPlant,
        agents: Sequence[AgentSpec],
        delay_model: DelayModel,
        plant_rng: np.random.Generator,
        *,
        sample_period: float = 1.0,
        divergence_threshold: float = DEFAULT_DIVERGENCE_THRESHOLD,
        record_delays: bool = True,
        record_messages: bool = False,
        observer: KernelObserver | None = None,
        availability: Callable[[int, int, int], bool] | None = None,
        link_models: Any = None,
    ) -> None:
        self.env = simpy.Environment()
        self.plant = plant
        self.agents = list(agents)
        self.delay_model = delay_model
        self.plant_rng = plant_rng
        self.sample_period = float(sample_period)
        self.divergence_threshold = float(divergence_threshold)
        self.record_delays = record_delays
        self.record_messages = record_messages
        self.observer = observer
        self.links: dict[tuple[int, int], Link] = {}
        #: Pending deliveries of every link (one event per arrival instant).
        self.calendar = DeliveryCalendar(self.env)
        self._out_links: list[list[Link]] = []
        for i, spec in enumerate(self.agents):
            links: list[Link] = []
            for r in spec.out_neighbours:
                delays, model = resolve_link(delay_model, i, int(r), link_models)
                link: Link
                if model is not None:
                    link = ConfiguredLink(self.env, i, int(r), delays, self._deliver,
                                          self.sample_period, self.calendar)
                    link.configure(model)
                else:
                    link = Link(self.env, i, int(r), delays, self._deliver,
                                self.sample_period, self.calendar)
                link.availability = availability
                link.on_drop = self._dropped
                if observer is not None:
                    link.on_send = observer.on_sent
                self.links[(i, int(r))] = link
                links.append(link)
            self._out_links.append(links)
        self._messages: list[Message] = []
        self._discarded = 0
        self._drop_reasons: dict[str, int] = {}
        self._drops: list[tuple[int, int, int, float, str]] = []
        if observer is None and not record_messages:
            # Nothing needs Message objects: plain links hand deliveries straight to
            # the receiver's estimator (Link's lean path, same events and times).
            for (_, r), link in self.links.items():
                if type(link) is Link:
                    link.receive = self.agents[r].estimator.message_arrived

    def _dropped(self, message: Message, reason: str) -> None:
        self._drop_reasons[reason] = self._drop_reasons.get(reason, 0) + 1
        if self.record_delays:
            self._drops.append((message.sender, message.receiver, message.sent_step,
                                float(self.env.now), reason))
        if self.observer is not None and hasattr(self.observer, "on_dropped"):
            self.observer.on_dropped(message, reason, self.env.now * self.sample_period)

    def _deliver(self, message: Message) -> None:
        estimator = self.agents[message.receiver].estimator
        accepted = estimator.message_arrived(message.sender, message.sent_step, message.payload)
        if not accepted:
            self._discarded += 1
        if self.record_messages:
            self._messages.append(message)
        if self.observer is not None:
            self.observer.on_delivered(message, accepted)

    def run(self, steps: int) -> TrialResult:
        """Simulate steps 0..``steps`` and return the recorded result."""
        run = _Run(self, steps)
        # The agents start (and wait on the first tick) before the plant fires it;
        # their order is the order their updates run in at every step.
        for i, spec in enumerate(self.agents):
            self.env.process(run.agent_process(i, spec))
        self.env.process(run.plant_process())
        with np.errstate(over="ignore", invalid="ignore"):
            self.env.run(until=run.done)
            run.blank_unreached_steps()
            squared_errors = run.squared_errors()
        return self._result(run, squared_errors)

    def _result(self, run: _Run, squared_errors: np.ndarray) -> TrialResult:
        """The record of ``run`` and the links' counts."""
        links = self.links.values()
        return TrialResult(
            states=run.states,
            measurements=[run.all_measurements[:, rows].copy()
                          for rows in self.plant.sensor_slices],
            estimates=run.estimates,
            squared_errors=squared_errors,
            effective_delays=run.delays,
            diverged_at=run.diverged_at,
            messages_sent=sum(link.sent for link in links),
            messages_delivered=sum(link.delivered for link in links),
            messages_dropped=sum(link.dropped for link in links),
            messages_discarded=self._discarded + sum(link.discarded for link in links),
            messages=self._messages,
            drop_reasons=dict(self._drop_reasons),
            drops=list(self._drops) if self.record_delays else None,
        )


class _Run:
    """The state of one :meth:`Simulation.run`, shared by its processes and its monitor.

    The plant process publishes step k (``measurements``, then fires ``tick`` with
    value k); every agent process updates its estimator and writes x-hat^i_{k|k} into
    the record (``estimates``, ``delays``); the monitor, a callback of the tick after
    the agents, tests the step for divergence and fires ``done`` after the last step
    or a divergence.

    Parameters
    ----------
    sim : Simulation
    steps : int
        The run simulates steps 0..``steps``.
    """

    def __init__(self, sim: Simulation, steps: int) -> None:
        plant = sim.plant
        n, n_agents = plant.n_states, len(sim.agents)
        self.env = sim.env
        self.observer = sim.observer
        self.out_links = sim._out_links
        self.steps = steps
        # The plant does not depend on the estimators: its whole trajectory is drawn
        # and simulated up front, from the same stream in the same order as step by
        # step; the plant process publishes it one step at a time. Steps after a
        # divergence are not reached and are set to NaN at the end.
        trajectory = plant.simulate(plant.standard_noise(sim.plant_rng, steps)[:, None, :])
        self.states = trajectory.states[:, 0]
        self.all_measurements = trajectory.measurements[:, 0]
        # every step's y^i_k (views of the trajectory), as the agents' ``measure`` takes them
        self.measurements_by_step = list(zip(
            *(self.all_measurements[:, rows] for rows in plant.sensor_slices), strict=True))
        # the record: each agent's estimate and effective delays r_ij[k] at every step
        self.estimates = np.full((steps + 1, n_agents, n), np.nan)
        self.delays = (
            np.full((steps + 1, n_agents, n_agents), NOT_USED, dtype=np.int32)
            if sim.record_delays
            else None
        )
        # each agent's estimate of the current step, recorded by the monitor, unless
        # every estimator writes its estimate into its row of ``estimates`` itself
        self.in_place = all(_takes_out(spec.estimator) for spec in sim.agents)
        self.current: list[Any] = [None] * n_agents
        # the step being simulated: its tick (the agents wait on it) and measurements,
        # both set by the plant
        self.tick = self.env.event()
        self.measurements: Sequence[np.ndarray] = ()
        self.done = self.env.event()
        self.diverged_at: int | None = None
        self.failure: EstimatorFailure | None = None  # set when an estimator raised
        # The divergence test (see ``monitor`` and ``diverged``).
        self.threshold_sq = squared_threshold(sim.divergence_threshold)
        self.state_norms = np.sqrt(np.einsum("ki,ki->k", self.states, self.states)).tolist()
        # below this, sqrt(sum_i ||x-hat^i||^2) + ||x|| bounds every agent's error
        # within the threshold (the margin covers round-off in the bound)
        self.norm_bound = math.sqrt(self.threshold_sq) * (1.0 - 1e-6)
        # every step's row of ``estimates`` flattened, in step order (views made as needed)
        self.flat_rows = iter(self.estimates.reshape(steps + 1, -1))
        self.difference = np.empty((n_agents, n))

    def plant_process(self):
        """Publish x_k and every y^i_k, then fire step k's tick; one step per Ts."""
        env = self.env
        observer = self.observer
        states = self.states
        monitor = self.monitor
        check_interrupt = interrupt.check
        for k, ys in enumerate(self.measurements_by_step):
            check_interrupt()  # a requested Ctrl-C stops here, between steps
            if observer is not None:
                observer.on_plant(k, states[k], ys)
            self.measurements = ys
            tick, self.tick = self.tick, env.event()
            # the agents wait on the tick already: the monitor runs after them
            tick.callbacks.append(monitor)
            tick.succeed(k)
            yield env.timeout(1.0)

    def agent_process(self, i: int, spec: AgentSpec):
        """At every tick, agent i's update x-hat^i_{k|k}, then its sends."""
        # resolved once: the update, the payload hook, the sends, the reporting
        estimator = spec.estimator
        update = estimator.step
        measure = spec.measure
        links = self.out_links[i]
        send = sender_function(links) if links else None
        outgoing = getattr(estimator, "outgoing", None)
        has_delays = hasattr(estimator, "last_delays")
        reports = self.observer is not None or (has_delays and self.delays is not None)
        # this agent's row of every step, in step order (views made as needed)
        own_rows = iter(self.estimates[:, i]) if self.in_place else None
        current = self.current
        while True:
            k = yield self.tick
            try:
                if own_rows is not None:
                    row = next(own_rows)
                    estimate = update(k, measure(self.measurements), row)
                    if estimate is not row:
                        row[...] = estimate
                else:
                    estimate = update(k, measure(self.measurements))
                    current[i] = estimate
            except Exception as exc:  # the estimator's own failure: say whose, and where
                kind = type(estimator)
                failure = EstimatorFailure(
                    f"estimator {kind.__module__}.{kind.__qualname__} of agent {i} failed "
                    f"in step() at step {k}: {type(exc).__name__}: {exc}")
                if self.failure is None:  # the first agent's error is the one reported
                    self.failure = failure
                raise failure from exc
            if reports:
                self.report_update(i, k, estimate,
                                   estimator.last_delays if has_delays else None)
            if send is not None:
                payload = estimate if outgoing is None else outgoing(k)
                if payload is not None:
                    send(k, payload)

    def report_update(self, i: int, k: int, estimate: np.ndarray,
                      used: dict[int, int] | None) -> None:
        """Record agent i's effective delays r_ij[k] (``used``: j -> r), tell the observer."""
        if self.delays is not None and used:
            row = self.delays[k, i]
            for j, r in used.items():
                row[j] = r
        if self.observer is not None:
            self.observer.on_update(i, k, estimate, used or {})

    def monitor(self, tick: simpy.Event) -> None:
        """Record step k and test it for divergence (a callback of the tick, after the agents)."""
        k = cast(int, tick.value)  # the tick's value is its step
        if self.failure is not None:  # an agent's step raised: stop with its error
            raise self.failure
        if not self.in_place:
            self.estimates[k] = self.current
        # Within the norm bound every agent's error is within the threshold; beyond it
        # (or NaN) the exact test decides.
        row = next(self.flat_rows)  # step k's: the monitor runs once per step, in order
        bounded = math.sqrt(row.dot(row)) + self.state_norms[k] < self.norm_bound
        if not bounded and self.diverged(k):
            self.diverged_at = k
            self.done.succeed()
        elif k == self.steps:
            self.done.succeed()

    def diverged(self, k: int) -> bool:
        """Whether some agent's error at step k is not finite or above the threshold.

        Above the threshold means above max(threshold, the round-off floor
        ROUNDOFF_RELATIVE_ERROR * ||x_k||). One sum of squares over all agents first:
        every agent's squared error is at most the sum, so a sum within the threshold
        clears the step; otherwise (inf, NaN, or no threshold and an infinite sum) the
        test agent by agent.
        """
        difference = self.difference
        np.subtract(self.estimates[k], self.states[k], out=difference)
        flat = difference.reshape(-1)
        if flat.dot(flat) < self.threshold_sq:
            return False
        # max propagates NaN and NaN <= t is False; the floor (x @ x) is only computed
        # when the threshold is exceeded
        worst = np.einsum("ij,ij->i", difference, difference).max(initial=0.0)
        x = self.states[k]
        return worst == math.inf or not (
            worst <= self.threshold_sq or worst <= ROUNDOFF_RELATIVE_ERROR**2 * float(x @ x))

    @property
    def last_step(self) -> int:
        """The last step reached: ``steps``, or the step that diverged."""
        return self.steps if self.diverged_at is None else self.diverged_at

    def blank_unreached_steps(self) -> None:
        """Set the states and measurements after the last step reached to NaN."""
        last = self.last_step
        self.states[last + 1:] = np.nan
        self.all_measurements[last + 1:] = np.nan

    def squared_errors(self) -> np.ndarray:
        """||x_k - x-hat^i_{k|k}||^2 up to the last step reached, NaN after it.

        At a divergence, an agent's squared error that is not finite is reported as inf.
        """
        last = self.last_step
        err = self.estimates[: last + 1] - self.states[: last + 1, None, :]
        sq_errors = np.full(self.estimates.shape[:2], np.nan)
        np.einsum("kij,kij->ki", err, err, out=sq_errors[: last + 1])
        if self.diverged_at is not None:
            sq_errors[last] = np.where(np.isfinite(sq_errors[last]), sq_errors[last], np.inf)
        return sq_errors
