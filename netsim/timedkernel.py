"""The event kernel on true time: agent clocks, asynchronous sampling, triggers.

Runs a scenario with a ``[time]`` table (:mod:`netsim.models.timing`). The plant is
continuous-time and moves between events by its exact discretisation
(:class:`netsim.models.continuous.ContinuousModel`); agent i samples when its own clock
reads phi_i + m T_i (:mod:`netsim.models.clocks`); what it sends carries its local
time-stamp; a trigger in its estimator decides whether it sends
(:mod:`netsim.models.triggers`). Links, delivery calendar, drops and observers are the
step kernel's (:class:`netsim.kernel.Simulation`, whose environment clock counts base
periods T = ``run.sample_period``): a step delay d is a wait of (1 + d) T, a latency l a
wait of l.

Time bookkeeping keeps "the time the data refers to" apart from "the time it arrived":
a message's ``sent_step`` (on the link, in the trace) is the sender's sample index m;
the stamp handed to the receiver's estimator is the sender's local clock reading at
that sample (looked up by (sender, m)); the arrival is the link's event time.

Events at one true instant, in order: deliveries due then (URGENT, as in the step
kernel); the plant's state and every sensor's measurement at that instant; every agent
that samples then, in agent order: its update, then its sends; at a report instant
t = k T, every agent's estimate is recorded -- its latest estimate predicted to the
instant by its own model over its own clock's elapsed time, Phi(c_i(t) - c_i(t_i))
x-hat^i (the estimate itself when it sampled at t) -- and tested for divergence.

With neutral clocks (no offset, drift or jitter), every period T and phase 0, the
events are the step kernel's, the plant noise is drawn in the same order, and a timed
estimator (:mod:`netsim.estimators.timed`) computes the same products: the run is the
step kernel's bit for bit (tests/test_timed.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from netsim import interrupt
from netsim.deliveries import DeliveryCalendar
from netsim.estimators.contract import EstimatorFailure
from netsim.kernel import (
    NOT_USED,
    ROUNDOFF_RELATIVE_ERROR,
    AgentSpec,
    Simulation,
    TrialResult,
    squared_threshold,
)
from netsim.links import Message
from netsim.models.clocks import Clock, sample_times
from netsim.models.continuous import ContinuousModel
from netsim.models.plant import LinearPlant

__all__ = ["TimedSimulation", "SampleRecord", "run_timed_trial", "cannot_run_timed",
           "MAX_EVENTS"]

#: Most sampling events one timed trial may hold (the timeline is built up front).
MAX_EVENTS = 2e7
#: Env times within this many base periods of a whole number are that number.
_SNAP = 1e-9


def cannot_run_timed(family: str) -> str:
    """The one line refusing a family without a timed form under ``[time]``."""
    return (f"estimator family {family!r} cannot run asynchronously: it has no timed form "
            "(step_at(t, y, elapsed, transition), netsim.estimators.timed); the [time] "
            "table supports compensated and uncompensated (or a family whose estimators "
            "define step_at)")


@dataclass
class SampleRecord:
    """Every sample of one run: who sampled when, on which clock reading.

    Attributes
    ----------
    agent, index : numpy.ndarray, shape (S,), int
        The sampling agent and its sample index m (0, 1, ...).
    true_time, local_time : numpy.ndarray, shape (S,)
        True time of the sample and the agent's clock reading (jitter included),
        which is the stamp on what it sends.
    sent : numpy.ndarray, shape (S,), bool
        Whether the agent's trigger let the new estimate out.
    """

    agent: np.ndarray
    index: np.ndarray
    true_time: np.ndarray
    local_time: np.ndarray
    sent: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready columns."""
        return {"agent": self.agent.tolist(), "index": self.index.tolist(),
                "true_time": self.true_time.tolist(), "local_time": self.local_time.tolist(),
                "sent": self.sent.astype(int).tolist()}


def _env_times(true_times: np.ndarray, period: float) -> np.ndarray:
    """True times in base periods, snapped to whole numbers within _SNAP."""
    env = true_times / period
    nearest = np.rint(env)
    return np.where(np.abs(env - nearest) <= _SNAP, nearest, env)


class _TolerantCalendar(DeliveryCalendar):
    """The delivery calendar with arrivals within _SNAP after a sampling instant
    handed over before it (:meth:`due`).

    On true time an arrival and a sample of another agent meet at the same instant
    only up to the rounding of their sums (a send at 4.7 plus a wait of 1.0 against a
    sample computed as 5.7); DESIGN.md counts a message arriving exactly at an update
    as arrived, so rounding must not decide. An instant taken early is skipped when its
    own event fires.
    """

    __slots__ = ()

    def due(self, now: float) -> None:
        """Hand over every pending delivery due in (now, now + _SNAP], in time order."""
        limit = now + _SNAP * max(1.0, abs(now))
        for at in sorted(a for a in self._pending if now < a <= limit):
            entries = iter(self._pending.pop(at))
            for arrive, value in zip(entries, entries, strict=False):
                arrive(value)

    def _hand_over(self, event: Any) -> None:
        entries = self._pending.pop(event._value, None)
        if entries is None:  # taken early by due()
            return
        pairs = iter(entries)
        for arrive, value in zip(pairs, pairs, strict=False):
            arrive(value)


class TimedSimulation(Simulation):
    """One run on true time (see the module docstring).

    Parameters
    ----------
    plant : LinearPlant
        The plant at the base period (A, C_i, Q, R_i, prior).
    model : ContinuousModel
        Its continuous-time model (transitions over any interval).
    clocks : sequence of Clock
        One per agent.
    agents : sequence of AgentSpec
        Estimators implementing the timed contract (``step_at``).
    clock_rng : numpy.random.Generator
        Stream of the read jitter.
    **options
        As :class:`netsim.kernel.Simulation` (delay_model, plant_rng, sample_period,
        divergence_threshold, record_delays, record_messages, observer, availability,
        link_models).
    """

    def __init__(self, plant: LinearPlant, model: ContinuousModel, clocks: Sequence[Clock],
                 agents: Sequence[AgentSpec], delay_model: Any, plant_rng: np.random.Generator,
                 clock_rng: np.random.Generator, *, sync: Any = None,
                 sync_graph: Any = None, **options: Any) -> None:
        keep_messages = bool(options.pop("record_messages", False))
        link_models = options.get("link_models")
        # Message objects always (no lean path): the stamp is looked up per delivery
        super().__init__(plant, agents, delay_model, plant_rng, record_messages=True,
                         **options)
        self.record_messages = keep_messages
        # every link on the tolerant calendar (nothing is scheduled yet)
        calendar = _TolerantCalendar(self.env)
        self.calendar = calendar
        for link in self.links.values():
            link.calendar = calendar
            link._schedule = calendar.schedule
        self.model = model
        self.clocks = list(clocks)
        self.clock_rng = clock_rng
        #: stamps[j][m]: agent j's clock reading at its sample m.
        self.stamps: list[list[float]] = [[] for _ in self.agents]
        for i, spec in enumerate(self.agents):
            if not callable(getattr(spec.estimator, "step_at", None)):
                kind = type(spec.estimator)
                raise ValueError(f"agent {i}'s estimator {kind.__module__}.{kind.__qualname__}"
                                 " has no step_at(t, y, elapsed, transition): it cannot run "
                                 "asynchronously")
        #: Each agent's clock correction (added to its readings; clock synchronisation).
        self.corrections = [0.0] * len(self.agents)
        self.sync = None if sync is None else _ClockSync(self, sync, sync_graph, delay_model,
                                                          link_models,
                                                          options.get("availability"))

    def read(self, i: int, t_true: float) -> float:
        """Agent i's clock reading at true time t (jitter and its correction included)."""
        return self.clocks[i].read(t_true, self.clock_rng) + self.corrections[i]

    def local(self, i: int, t_true: float) -> float:
        """Agent i's jitter-free corrected clock at true time t."""
        return self.clocks[i].local(t_true) + self.corrections[i]

    def _deliver(self, message: Message) -> None:
        estimator = self.agents[message.receiver].estimator
        stamp = self.stamps[message.sender][message.sent_step]
        accepted = estimator.message_arrived(message.sender, stamp, message.payload)
        if not accepted:
            self._discarded += 1
        if self.record_messages:
            self._messages.append(message)
        if self.observer is not None:
            self.observer.on_delivered(message, accepted)

    def run(self, steps: int) -> TrialResult:
        """Simulate true time 0 .. ``steps`` T and return the record on the report grid."""
        run = _TimedRun(self, steps)
        self.env.process(run.process())
        if self.sync is not None:
            self.sync.start(steps * self.sample_period)
        with np.errstate(over="ignore", invalid="ignore"):
            self.env.run(until=run.done)
            result = run.result()
        return result


class _TimedRun:
    """The state of one :meth:`TimedSimulation.run`."""

    def __init__(self, sim: TimedSimulation, steps: int) -> None:
        self.sim = sim
        self.env = sim.env
        self.steps = steps
        period = sim.sample_period
        self.period = period
        n_agents = len(sim.agents)
        n = sim.plant.n_states
        horizon = steps * period
        # each agent's sampling instants (env time = base periods) and scheduled readings
        sampling: list[np.ndarray] = []
        for clock in sim.clocks:
            true, _ = sample_times(clock, horizon)
            sampling.append(_env_times(true, period))
        report = np.arange(steps + 1, dtype=float)
        timeline = np.unique(np.concatenate([report, *sampling]))
        timeline = timeline[(timeline >= 0) & (timeline <= steps)]
        self.timeline = timeline
        # which agents sample at each instant (in agent order)
        at: dict[float, list[int]] = {}
        for i, times in enumerate(sampling):
            for tau in times.tolist():
                at.setdefault(tau, []).append(i)
        self.sampling_at = at
        self.report_rows = np.searchsorted(timeline, report)
        trajectory = self._simulate_plant(sim, timeline)
        self.states_all = trajectory[0]
        self.measurements_all = trajectory[1]
        self.states = self.states_all[self.report_rows].copy()
        self.all_measurements = self.measurements_all[self.report_rows].copy()
        self.estimates = np.full((steps + 1, n_agents, n), np.nan)
        self.delays = (np.full((steps + 1, n_agents, n_agents), NOT_USED, dtype=np.int32)
                       if sim.record_delays else None)
        self.done = self.env.event()
        self.diverged_at: int | None = None
        self.threshold_sq = squared_threshold(sim.divergence_threshold)
        # per agent: last clock reading, last update's true time, samples so far
        self.last_local: list[float | None] = [None] * n_agents
        self.sampled_now: list[bool] = [False] * n_agents
        self.samples: list[tuple[int, int, float, float, bool]] = []
        self.broadcasts = 0

    @staticmethod
    def _simulate_plant(sim: TimedSimulation, timeline: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
        """States (E, n) and stacked measurements (E, M) at the timeline's instants.

        One row of standard normals per instant, laid out as the step kernel's
        (:meth:`netsim.models.plant.LinearPlant.standard_noise`); on the base grid the
        plant's own :meth:`simulate` (the step kernel's numbers bit for bit), else the
        exact discretisation over each interval.
        """
        plant, model = sim.plant, sim.model
        E = len(timeline)
        noise = plant.standard_noise(sim.plant_rng, E - 1)
        intervals = np.diff(timeline)
        if E == 1 or (np.all(intervals == 1.0) and timeline[0] == 0.0):
            trajectory = plant.simulate(noise[:, None, :])
            return trajectory.states[:, 0], trajectory.measurements[:, 0]
        from netsim.models.plant import _factor

        n = plant.n_states
        states = np.empty((E, n))
        states[0] = plant.x0_mean + _factor(plant.x0_cov) @ noise[0, :n]
        factors: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        for e in range(1, E):
            h = float(intervals[e - 1]) * sim.sample_period
            pair = factors.get(h)
            if pair is None:
                pair = factors[h] = (model.transition(h), _factor(model.noise(h)))
            states[e] = pair[0] @ states[e - 1] + pair[1] @ noise[e, :n]
        C = plant.C_stacked
        _, factor, diagonal, _ = plant._stacked_measurement
        z = noise[:, n:]
        measurements = states @ C.T + (z * factor if diagonal else z @ factor.T)
        return states, measurements

    def process(self):
        """Walk the timeline: deliveries (URGENT, before), plant, samples, report."""
        sim = self.sim
        env = self.env
        observer = sim.observer
        slices = sim.plant.sensor_slices
        period = self.period
        report_of = {float(k): k for k in range(self.steps + 1)}
        for e, tau in enumerate(self.timeline.tolist()):
            interrupt.check()
            if tau > env.now:
                yield env.timeout(tau - env.now)
            y_all = self.measurements_all[e]
            ys = [y_all[rows] for rows in slices]
            k = report_of.get(tau)
            if k is not None and observer is not None:
                observer.on_plant(k, self.states_all[e], ys)
            self.sampled_now = [False] * len(sim.agents)
            if tau in self.sampling_at:
                calendar = sim.calendar
                if isinstance(calendar, _TolerantCalendar):
                    calendar.due(env.now)
            for i in self.sampling_at.get(tau, ()):
                self._sample(i, tau * period, ys)
            if k is not None:
                self._report(k, tau * period)
                if self.diverged_at is not None or k == self.steps:
                    self.done.succeed()
                    return

    def _sample(self, i: int, t_true: float, ys: Sequence[np.ndarray]) -> None:
        """Agent i's update at true time t_true, then its sends."""
        sim = self.sim
        spec = sim.agents[i]
        estimator = spec.estimator
        local = sim.read(i, t_true)
        previous = self.last_local[i]
        elapsed = 0.0 if previous is None else local - previous
        transition = sim.model.transition(elapsed)
        m = len(sim.stamps[i])
        try:
            estimator.step_at(local, spec.measure(ys), elapsed, transition)
        except Exception as exc:
            kind = type(estimator)
            raise EstimatorFailure(
                f"estimator {kind.__module__}.{kind.__qualname__} of agent {i} failed in "
                f"step_at() at true time {t_true:g} (local {local:g}): "
                f"{type(exc).__name__}: {exc}") from exc
        self.last_local[i] = local
        self.sampled_now[i] = True
        sim.stamps[i].append(local)
        outgoing = getattr(estimator, "outgoing", None)
        payload = estimator.estimate if outgoing is None else outgoing(local)
        sent = payload is not None
        if sent:
            self.broadcasts += 1
            for link in sim._out_links[i]:
                link.send(m, payload)
        self.samples.append((i, m, t_true, local, sent))
        observer = sim.observer
        if observer is not None and hasattr(observer, "on_clock"):
            observer.on_clock(i, m, t_true, local, sent)

    def _report(self, k: int, t_true: float) -> None:
        """Record every agent's estimate at report instant k (predicted by its own clock)."""
        sim = self.sim
        observer = sim.observer
        for i, spec in enumerate(sim.agents):
            estimator = spec.estimator
            estimate = np.asarray(estimator.estimate, dtype=float)
            previous = self.last_local[i]
            if not self.sampled_now[i] and previous is not None:
                ahead = sim.local(i, t_true) - previous
                estimate = sim.model.transition(ahead) @ estimate
            self.estimates[k, i] = estimate
            used: dict[int, int] = {}
            if self.sampled_now[i]:
                used = dict(getattr(estimator, "last_delays", {}) or {})
                if self.delays is not None:
                    row = self.delays[k, i]
                    for j, r in used.items():
                        row[j] = r
            if observer is not None:
                observer.on_update(i, k, self.estimates[k, i], used)
        if self._diverged(k):
            self.diverged_at = k

    def _diverged(self, k: int) -> bool:
        """The step kernel's test (:meth:`netsim.kernel._Run.diverged`) at report k."""
        difference = self.estimates[k] - self.states[k]
        flat = difference.reshape(-1)
        if flat.dot(flat) < self.threshold_sq:
            return False
        worst = np.einsum("ij,ij->i", difference, difference).max(initial=0.0)
        x = self.states[k]
        return worst == math.inf or not (
            worst <= self.threshold_sq or worst <= ROUNDOFF_RELATIVE_ERROR**2 * float(x @ x))

    def result(self) -> TrialResult:
        """The run's record on the report grid."""
        sim = self.sim
        last = self.steps if self.diverged_at is None else self.diverged_at
        self.states[last + 1:] = np.nan
        self.all_measurements[last + 1:] = np.nan
        err = self.estimates[: last + 1] - self.states[: last + 1, None, :]
        sq = np.full(self.estimates.shape[:2], np.nan)
        np.einsum("kij,kij->ki", err, err, out=sq[: last + 1])
        if self.diverged_at is not None:
            sq[last] = np.where(np.isfinite(sq[last]), sq[last], np.inf)
        links = sim.links.values()
        sent = sum(link.sent for link in links)
        columns = list(zip(*self.samples, strict=True)) if self.samples else [()] * 5
        record = SampleRecord(np.array(columns[0], dtype=int), np.array(columns[1], dtype=int),
                              np.array(columns[2], dtype=float),
                              np.array(columns[3], dtype=float),
                              np.array(columns[4], dtype=bool))
        duration = last * self.period
        n_agents = len(sim.agents)
        timing = {
            "samples": len(self.samples),
            "broadcasts": self.broadcasts,
            "messages_sent": sent,
            "duration": duration,
            # broadcasts (estimates let out by the triggers) per agent and time unit
            "message_rate": (self.broadcasts / (n_agents * duration) if duration > 0
                             else math.nan),
            "send_fraction": (self.broadcasts / len(self.samples) if self.samples
                              else math.nan),
            "clocks": [{"offset": c.offset, "drift_ppm": c.drift_ppm, "jitter": c.jitter,
                        "period": c.period, "phase": c.phase} for c in sim.clocks],
            "sample_record": record,
            **({"sync": sim.sync.summary(last * self.period)} if sim.sync is not None else {}),
        }
        return TrialResult(
            states=self.states,
            measurements=[self.all_measurements[:, rows].copy()
                          for rows in sim.plant.sensor_slices],
            estimates=self.estimates,
            squared_errors=sq,
            effective_delays=self.delays,
            diverged_at=self.diverged_at,
            messages_sent=sent,
            messages_delivered=sum(link.delivered for link in links),
            messages_dropped=sum(link.dropped for link in links),
            messages_discarded=sim._discarded + sum(link.discarded for link in links),
            messages=sim._messages,
            drop_reasons=dict(sim._drop_reasons),
            drops=list(sim._drops) if sim.record_delays else None,
            extras={"timing": timing},
        )


class _SyncPacket:
    """One leg of a two-way exchange travelling hop by hop (see :class:`_ClockSync`)."""

    __slots__ = ("kind", "origin", "path", "hop", "t1", "t2", "t3", "c1")

    def __init__(self, kind: str, origin: int, path: list[int], t1: float,
                 t2: float = math.nan, t3: float = math.nan, c1: float = 0.0) -> None:
        self.kind, self.origin, self.path, self.hop = kind, origin, path, 0
        self.t1, self.t2, self.t3 = t1, t2, t3
        #: the origin's correction when it stamped t1 (exchanges may overlap)
        self.c1 = c1


class _ClockSync:
    """Periodic two-way clock synchronisation over the scenario's links.

    Every agent but the reference has a parent: its in-neighbour on a shortest-path
    tree from the reference. Every ``period`` of its own clock it sends a request to
    its parent (stamp t1, its corrected clock), along the shortest path of links; the
    parent stamps its arrival t2 and replies at once (t3 = t2) on the link parent ->
    agent; on the reply's arrival (t4) the agent adds
    theta = ((t2 - t1) - (t4 - t3)) / 2 to its correction (t1 taken into the frame of
    its current correction, since exchanges may overlap). With path delays d_req and
    d_rep the corrected clock then trails its parent's by (d_req - d_rep) / 2 (the
    residual offset of an asymmetric exchange), plus what drift adds until the next one.
    Sync messages use links of their own with each link's delay model and losses (not
    its buffer), are counted apart from the estimates and are not traced.
    """

    def __init__(self, sim: TimedSimulation, spec: Any, graph: Any, delay_model: Any,
                 link_models: Any, availability: Any) -> None:
        import networkx as nx

        from netsim.links import ConfiguredLink, Link, resolve_link

        self.sim = sim
        self.spec = spec
        self.links: dict[tuple[int, int], Link] = {}
        for j, i in graph.edges:
            delays, model = resolve_link(delay_model, int(j), int(i), link_models)
            link: Link
            if model is not None:
                link = ConfiguredLink(sim.env, int(j), int(i), delays, self._arrive,
                                      sim.sample_period, sim.calendar)
                link.configure(model)
            else:
                link = Link(sim.env, int(j), int(i), delays, self._arrive, sim.sample_period,
                            sim.calendar)
            link.availability = availability
            self.links[(int(j), int(i))] = link
        ref = spec.reference
        tree = nx.bfs_tree(graph, ref)
        self.parent = {int(i): int(next(iter(tree.predecessors(i)))) for i in tree.nodes
                       if i != ref}
        self.request_path = {i: [int(v) for v in nx.shortest_path(graph, i, p)]
                             for i, p in self.parent.items()}
        self.exchanges = 0

    def start(self, horizon: float) -> None:
        """Start every non-reference agent's request process (before the run)."""
        for i in self.parent:
            self.sim.env.process(self._requests(i, horizon))

    def _requests(self, i: int, horizon: float):
        sim = self.sim
        clock = sim.clocks[i]
        schedule = Clock(clock.offset, clock.drift_ppm, 0.0, self.spec.period, 0.0)
        for t in sample_times(schedule, horizon)[0].tolist():
            if t <= 0:
                continue
            when = t / sim.sample_period
            if when > sim.env.now:
                yield sim.env.timeout(when - sim.env.now)
            self._send(_SyncPacket("req", i, self.request_path[i], sim.read(i, t),
                                   c1=sim.corrections[i]))

    def _send(self, packet: _SyncPacket) -> None:
        here, there = packet.path[packet.hop], packet.path[packet.hop + 1]
        self.links[(here, there)].send(len(self.sim.stamps[here]), packet)  # type: ignore[arg-type]

    def _arrive(self, message: Message) -> None:
        packet = message.payload
        assert isinstance(packet, _SyncPacket)
        packet.hop += 1
        if packet.hop < len(packet.path) - 1:  # forward along the path
            self._send(packet)
            return
        sim = self.sim
        now = sim.env.now * sim.sample_period
        here = packet.path[-1]
        if packet.kind == "req":
            t2 = sim.read(here, now)
            reply = _SyncPacket("rep", packet.origin, [here, packet.origin], packet.t1, t2, t2,
                                packet.c1)
            self._send(reply)
            return
        t4 = sim.read(here, now)
        # t1 in the frame of the current correction (a reply of an earlier exchange may
        # have moved it since)
        t1 = packet.t1 + (sim.corrections[here] - packet.c1)
        theta = ((packet.t2 - t1) - (t4 - packet.t3)) / 2.0
        sim.corrections[here] += theta
        self.exchanges += 1

    def summary(self, t_end: float) -> dict[str, Any]:
        """Exchanges, sync messages, final corrections and residual offsets at t_end
        (each agent's corrected clock minus the reference's)."""
        sim = self.sim
        ref = sim.local(self.spec.reference, t_end)
        return {
            "exchanges": self.exchanges,
            "messages_sent": sum(link.sent for link in self.links.values()),
            "messages_dropped": sum(link.dropped for link in self.links.values()),
            "corrections": list(sim.corrections),
            "residual_offsets": [sim.local(i, t_end) - ref for i in range(len(sim.agents))],
            "parent": {str(i): p for i, p in self.parent.items()},
        }


def _measure(sensors: tuple[int, ...], n_sensors: int) -> Any:
    """The selector of an agent's measurement from all sensors' y^j (as the runner's)."""
    if len(sensors) == 1:
        index = sensors[0]
        return lambda ys: ys[index]
    if not sensors:
        empty = np.zeros(0)
        return lambda ys: empty
    return lambda ys: np.concatenate([ys[j] for j in sensors])


def run_timed_trial(scenario: Any, family: Any, gains: Any, trial_seed: Any,
                    steps: int, *, record_delays: bool = True, record_messages: bool = False,
                    observer: Any = None) -> TrialResult:
    """One trial of a scenario with a ``[time]`` table (see :func:`netsim.runner.run_trial`).

    The family's timed form (:data:`netsim.estimators.timed.TIMED_FORMS`) builds the
    agents; a family without one runs only if its estimators define ``step_at``, else
    ValueError (:func:`cannot_run_timed`).
    """
    from netsim.estimators.registry import FamilyContext
    from netsim.estimators.timed import TIMED_FORMS, takes_time
    from netsim.models.seeding import stream

    timing = scenario.timing
    # samples of all agents over the run (drift at most 10 %, MAX_DRIFT_PPM)
    events = (steps + 1) + sum(1.1 * steps * scenario.sample_period / p + 1
                               for p in timing.periods)
    if events > MAX_EVENTS:
        raise ValueError(f"time.periods: {events:.3g} sampling events over {steps} steps "
                         f"exceed {MAX_EVENTS:.0e} (longer periods or fewer steps)")
    context = FamilyContext(scenario, gains, trial_seed, family.name)
    form = TIMED_FORMS.get(family.name) if family.source == "builtin" else None
    plans = form(context) if form is not None else family.agents(context)
    if not all(takes_time(plan.estimator) for plan in plans):
        raise ValueError(cannot_run_timed(family.name))
    n_sensors = scenario.plant.n_sensors
    agents = [AgentSpec(plan.estimator, _measure(tuple(plan.sensors), n_sensors),
                        list(plan.out_neighbours)) for plan in plans]
    model = timing.model
    plant = scenario.plant
    if not (np.array_equal(model.A, plant.A) and np.array_equal(model.Q, plant.Q)):
        # the plant was changed after parsing (Scenario.with_noise): its own model
        model = ContinuousModel.from_discrete(plant.A, plant.Q, scenario.sample_period)
    topology = scenario.topology
    simulation = TimedSimulation(
        scenario.plant, model, timing.clocks(trial_seed), agents,
        scenario.delay_model(trial_seed), stream(trial_seed, "plant"),
        stream(trial_seed, "clocks", timing.seed, "jitter"),
        sample_period=scenario.sample_period,
        divergence_threshold=scenario.divergence_threshold,
        record_delays=record_delays, record_messages=record_messages, observer=observer,
        availability=None if topology is None else topology.is_up,
        sync=timing.sync, sync_graph=scenario.graph if timing.sync is not None else None,
    )
    return simulation.run(steps)
