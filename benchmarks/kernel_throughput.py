#!/usr/bin/env python
"""Throughput of the SimPy event kernel (netsim.kernel.Simulation).

For each network size N the script builds one scenario -- a random strongly
connected digraph with about ``--in-degree`` in-neighbours per agent, random
row-stochastic weights, a stable 2-state plant with one scalar output per agent,
constant gains L_i = 0.1 C_i^T, asynchronous random delays in {0..tau} -- and runs
``Simulation(...).run(steps)`` with ``record_delays=False``. It measures, in one
process:

* **kernel**: wall time of ``run(steps)`` (``time.perf_counter``, best of
  ``--repeat``), simulated steps/s, delivered messages/s, and the number of
  simulation events it handled. **Simulation events** are the events a kernel with
  one SimPy event per message pops: one per delivered message, plus the plant's
  timeout and the tick of every step and the processes' starts. They are counted
  exactly in an untimed run of the one-event-per-message variant below (same seeds,
  so the same events) whose ``env.step`` is wrapped to classify each popped event by
  type; the benchmark checks that this equals the kernel's delivered messages plus
  its other popped events. The kernel itself pops fewer SimPy events: its delivery
  calendar (:mod:`netsim.deliveries`) schedules one event per arrival instant, not
  per message; those counts are reported too. The timed runs are not instrumented.
* **event per message**: the same kernel with a calendar that schedules one URGENT
  SimPy event per message (the kernel's design before the delivery calendar).
* **bare SimPy**: the same number of bare events, timed the same way.
  ``bare-timeout`` processes that many ``env.timeout(d)`` events (d in
  1..tau+1), each with a no-op callback; a driver timeout creates them step by
  step, as many per step as the kernel processes, so the event queue stays the
  size of the kernel's (creation is inside the timed region, as the kernel's
  event creation is). Pre-scheduling all of them at once was tried and rejected:
  the huge live set (GC passes, deep heap) made it several times slower per event than
  SimPy's real per-event cost. ``bare-process`` is one process yielding that
  many ``env.timeout(1)`` (one generator resume per event).
* **ratio**: kernel cost per simulation event / bare cost per event.
* **null estimator**: the same kernel run with an estimator that does no
  arithmetic (``step`` returns a constant), to separate the kernel's own
  machinery from the estimators' numpy work. It does not take ``step``'s ``out``,
  so the kernel's monitor copies its estimates into the record (one numpy
  assignment per step), where the compensating estimator writes its estimate into
  the kernel's row itself: the difference slightly understates the estimators' work.
* **process per message**: the same scenario with links that start one SimPy
  process per message (``env.process(gen)``, the generator yields
  ``env.timeout(wait)`` then delivers) instead of the delivery calendar. Its
  estimates, like the event-per-message variant's, are checked to be bit-identical
  to the kernel's, and the ratios of wall times are reported.

* **profile** (``--profile``): one extra, untimed run per size and estimator under
  cProfile, its time split by where it is spent: SimPy's own machinery, the kernel
  (``netsim/kernel.py``), the links, the delivery calendar, the estimator, the delay
  model, the plant, the benchmark's glue. Time in C functions (numpy, heapq, dict
  methods, ...) is charged to the Python function that called them. cProfile slows
  Python-level calls more than C work, so the shares are indicative, not wall-time
  fractions.

The headline is the first table: at each N, the kernel's cost per simulation event
over bare SimPy's cost per event (``bare-timeout``), for the real estimator, the
event-per-message variant and the null estimator, all measured in the same run.
The issue's goal is <= 3x.

Usage::

    python benchmarks/kernel_throughput.py                # default sizes 4,32,128
    python benchmarks/kernel_throughput.py --profile      # plus the profile breakdown
    python benchmarks/kernel_throughput.py --sizes 8,64 --steps 500 --repeat 5
    python benchmarks/kernel_throughput.py --json > kernel.json

Progress goes to stderr; stdout holds the table (or, with ``--json``, exactly one
JSON object and no table).
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import json
import platform
import pstats
import sys
import time
from collections import Counter
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from operator import itemgetter
from typing import Any
from unittest import mock

import networkx as nx
import numpy as np
import simpy
from netsim.estimators.consensus import CompensatingEstimator, ConsensusParameters
from netsim.models.delays import AsynchronousRandomDelays, DelayModel
from netsim.models.network import random_strongly_connected, random_weights
from netsim.models.plant import LinearPlant
from netsim.models.seeding import stream
from tables import format_table, si

import netsim.kernel
from netsim.deliveries import DeliveryCalendar
from netsim.kernel import AgentSpec, Simulation, TrialResult
from netsim.links import Link, Message

DEFAULT_SIZES = (4, 32, 128)
#: Default steps: about 51200 / N, clamped to [200, 2000] (2000, 1600, 400 for the
#: default sizes), which keeps the default run well under two minutes on 2 cores.
STEPS_BUDGET = 51200
STEPS_MIN, STEPS_MAX = 200, 2000

EVENT_COUNT_EXPLANATION = (
    "events = simulation events: every event a kernel with one SimPy event per message "
    "pops, counted by type with env.step wrapped in an untimed run of the "
    "event-per-message variant with the same seeds: MessageDelivery = one per delivered "
    "message (URGENT, scheduled at send time); Timeout = the plant process's one timeout "
    "per step; Event = the per-step tick (one event, resuming all N agent processes, "
    "then the monitor callback) plus the final 'done' event; Initialize = start of the "
    "N+1 processes (agents and plant). "
    "The kernel's delivery calendar pops one Delivery event per arrival instant instead "
    "of one per message (its counts: 'SimPy events popped'); the benchmark checks that "
    "its delivered messages plus its other popped events equal the simulation events. "
    "Process-per-message links add one Initialize, one Timeout and one Process "
    "(termination) event per message instead of a delivery event."
)


def progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- scenario


@dataclass
class Scenario:
    n_agents: int
    graph: nx.DiGraph
    weights: np.ndarray
    plant: LinearPlant
    tau: int
    seed: int

    @property
    def n_links(self) -> int:
        return self.graph.number_of_edges()

    @property
    def mean_in_degree(self) -> float:
        return self.n_links / self.n_agents


def build_scenario(n_agents: int, in_degree: float, tau: int, seed: int) -> Scenario:
    """Random strongly-connected digraph, random weights and a stable 2-state plant."""
    # The Hamiltonian cycle gives every agent one in-neighbour; each other ordered
    # pair is added with probability p, so E[in-degree] = 1 + p (N - 1).
    p = min(1.0, max(0.0, (in_degree - 1.0) / (n_agents - 1)))
    graph = random_strongly_connected(n_agents, p, seed=seed)
    weights = random_weights(graph, seed=seed)
    A = np.array([[0.95, 0.1], [0.0, 0.9]])
    angles = stream(seed, "benchmark/outputs").uniform(0.0, np.pi, n_agents)
    C = tuple(np.array([[np.cos(a), np.sin(a)]]) for a in angles)
    plant = LinearPlant(
        A=A,
        C=C,
        Q=0.01 * np.eye(2),
        R=tuple(0.1 * np.eye(1) for _ in C),
        x0_mean=np.zeros(2),
        x0_cov=np.eye(2),
    )
    return Scenario(n_agents, graph, weights, plant, tau, seed)


class NullEstimator:
    """Hosts in the kernel like an estimator but does no arithmetic."""

    __slots__ = ("_estimate", "last_delays")

    def __init__(self, n_states: int) -> None:
        self._estimate = np.zeros(n_states)
        self.last_delays: dict[int, int] = {}

    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool:
        return True

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        return self._estimate

    def outgoing(self, step: int) -> np.ndarray:
        return self._estimate

    @property
    def estimate(self) -> np.ndarray:
        return self._estimate


def build_agents(scn: Scenario, estimator: str) -> list[AgentSpec]:
    plant = scn.plant
    agents = []
    for i in range(scn.n_agents):
        if estimator == "compensated":
            params = ConsensusParameters(
                agent=i,
                weights=scn.weights[i],
                A=plant.A,
                C=plant.C[i],
                L=0.1 * plant.C[i].T,
                prior=plant.x0_mean,
            )
            est: Any = CompensatingEstimator(params)
        elif estimator == "null":
            est = NullEstimator(plant.n_states)
        else:
            raise ValueError(estimator)
        agents.append(AgentSpec(est, itemgetter(i), sorted(scn.graph.successors(i))))
    return agents


def delay_model(scn: Scenario) -> DelayModel:
    # seed layout 2: the link set's delays from one stream, as netsim's scenarios build it
    return AsynchronousRandomDelays(scn.tau, seed=scn.seed, links=sorted(scn.graph.edges))


# ------------------------------------------------------------ process-per-message link


class ProcessPerMessageLink(Link):
    """A link that starts one SimPy process per message (the alternative design).

    ``send`` is :meth:`netsim.links.Link.send` (same delay draw, same Message),
    but instead of scheduling one URGENT ``Delivery`` event it starts
    ``env.process(gen)`` where ``gen`` yields ``env.timeout(wait)`` and then
    delivers. Deliveries still precede the updates of their arrival step (their
    timeouts were scheduled before the step's tick), so the run is bit-identical;
    the benchmark checks this.
    """

    __slots__ = ()

    def send(self, step: int, payload: np.ndarray) -> Message:
        # the link's own delay draw and Message (Link._stamp), then a process
        message, wait, up = self._stamp(step, payload)
        if up:
            self.env.process(self._carry(wait, message))
        return message

    def _carry(self, wait: float, message: Message):
        yield self.env.timeout(wait)
        self.delivered += 1
        self._deliver(message)


# ----------------------------------------------------- one scheduled event per message


class MessageDelivery(simpy.events.Event):
    """One message's URGENT delivery event (the event-per-message calendar)."""

    __slots__ = ()


_new_message_delivery = simpy.events.Event.__new__


class PerMessageCalendar(DeliveryCalendar):
    """A delivery calendar that schedules one URGENT SimPy event per message.

    The kernel's design before the shared calendar: the same arrival times and the
    same delivery order (SimPy pops equal-time URGENT events in scheduling order),
    one heap push and pop per message.
    """

    __slots__ = ()

    def schedule(self, wait: float, arrive: Callable[[Any], None], value: Any) -> None:
        event = _new_message_delivery(MessageDelivery)
        event.env = self.env
        event.callbacks = [self._hand_over]
        event._value = (arrive, value)
        event._ok = True
        self.env.schedule(event, simpy.core.URGENT, wait)
        self.events += 1

    def _hand_over(self, event: simpy.events.Event) -> None:
        arrive, value = event._value
        arrive(value)


#: variant -> (link class, calendar class) the kernel is built with.
VARIANTS = {
    "calendar": (Link, DeliveryCalendar),
    "event": (Link, PerMessageCalendar),
    "process": (ProcessPerMessageLink, DeliveryCalendar),
}


@contextmanager
def kernel_parts(variant: str):
    """Make ``Simulation.__init__`` build the links and the calendar of a variant."""
    link_cls, calendar_cls = VARIANTS[variant]
    with mock.patch.object(netsim.kernel, "Link", link_cls), \
            mock.patch.object(netsim.kernel, "DeliveryCalendar", calendar_cls):
        yield link_cls, calendar_cls


def make_simulation(scn: Scenario, estimator: str, variant: str) -> Simulation:
    agents = build_agents(scn, estimator)
    with kernel_parts(variant) as (link_cls, calendar_cls):
        sim = Simulation(
            scn.plant,
            agents,
            delay_model(scn),
            stream(scn.seed, "plant"),
            record_delays=False,
        )
    if type(sim.calendar) is not calendar_cls or not all(
        type(link) is link_cls and link.calendar is sim.calendar
        for link in sim.links.values()
    ):
        raise RuntimeError(
            f"kernel variant {variant!r} was not applied (netsim.kernel no longer builds "
            "links and the calendar through its module-level names 'Link' and "
            "'DeliveryCalendar'); update the benchmark"
        )
    return sim


# ------------------------------------------------------------------------- measuring


def _time_simulation(factory: Callable[[], Simulation], steps: int) -> tuple[float, TrialResult]:
    sim = factory()
    gc.collect()
    t0 = time.perf_counter()
    result = sim.run(steps)
    return time.perf_counter() - t0, result


def interleaved_best(
    cases: dict[str, Callable[[], tuple[float, Any]]], repeat: int
) -> dict[str, tuple[float, Any]]:
    """Best wall time of each case over ``repeat`` rounds, with the cases interleaved.

    Each round runs every case once, so a burst of load from other processes hits
    all cases alike instead of one case's repeats. Returns (best wall, last output).
    """
    best: dict[str, tuple[float, Any]] = {}
    for r in range(repeat):
        for label, case in cases.items():
            dt, out = case()
            progress(f"  round {r + 1}/{repeat}  {label:<20} {dt:.3f} s")
            if label not in best or dt < best[label][0]:
                best[label] = (dt, out)
            else:
                best[label] = (best[label][0], out)
    return best


def count_events(sim: Simulation, steps: int) -> tuple[Counter, TrialResult]:
    """Run once with ``env.step`` wrapped; count every processed event by type."""
    env = sim.env
    counts: Counter = Counter()
    original = env.step  # bound method; env.run looks up self.step each iteration
    queue = env._queue

    def counting_step() -> None:
        if queue:
            counts[type(queue[0][3]).__name__] += 1
        original()

    env.step = counting_step  # type: ignore[method-assign]
    result = sim.run(steps)
    return counts, result


def _noop(event: simpy.events.Event) -> None:
    pass


def bare_timeouts(n_events: int, per_step: int, spread: int) -> float:
    """Process ``n_events`` bare timeouts with no-op callbacks, shaped like the kernel's.

    A driver timeout fires once per unit of time and creates ``per_step - 1``
    timeouts with delays ``1 + i % spread`` and a no-op callback (so the queue holds
    about as many events as the kernel's, not all ``n_events`` at once), then the
    next driver timeout. Every created event is processed; the driver events are
    included in ``n_events``.
    """
    gc.collect()
    t0 = time.perf_counter()
    env = simpy.Environment()
    timeout = env.timeout
    remaining = n_events - 1  # the first driver

    def driver(event: simpy.events.Event) -> None:
        nonlocal remaining
        k = min(per_step - 1, remaining)
        for i in range(k):
            timeout(1 + i % spread).callbacks.append(_noop)
        remaining -= k
        if remaining > 0:
            remaining -= 1
            timeout(1).callbacks.append(driver)

    timeout(0).callbacks.append(driver)
    env.run()
    return time.perf_counter() - t0


def bare_process(n_events: int) -> float:
    """One process yielding ``n_events`` timeouts of delay 1."""

    def proc(env: simpy.Environment, n: int):
        timeout = env.timeout
        for _ in range(n):
            yield timeout(1)

    gc.collect()
    t0 = time.perf_counter()
    env = simpy.Environment()
    env.process(proc(env, n_events))
    env.run()
    return time.perf_counter() - t0


#: (label, path fragment) of the profile's components, first match wins.
PROFILE_COMPONENTS = (
    ("simpy", "/simpy/"),
    ("kernel", "netsim/kernel.py"),
    ("links", "netsim/links.py"),
    ("calendar", "netsim/deliveries.py"),
    ("estimator", "estimators/"),
    ("delay model", "models/delays.py"),
    ("plant", "models/plant.py"),
    ("benchmark glue", "kernel_throughput.py"),
)


def _component(func: tuple[str, int, str]) -> str | None:
    filename = func[0].replace("\\", "/")
    for label, fragment in PROFILE_COMPONENTS:
        if fragment in filename:
            return label
    return None


def profile_breakdown(sim: Simulation, steps: int) -> dict[str, float]:
    """Profiled run; seconds of own time per component (C calls charged to the caller).

    Own time of a Python function goes to its component; own time of a C function
    (``~`` entries: numpy, heapq, dict methods, ...) is split over its callers by what
    each caller spent in it, so ``ndarray.dot`` called by the estimator counts as
    estimator time. Whatever matches nothing is reported as ``other``.
    """
    profiler = cProfile.Profile()
    profiler.enable()
    sim.run(steps)
    profiler.disable()
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    out: dict[str, float] = {label: 0.0 for label, _ in PROFILE_COMPONENTS}
    out["other"] = 0.0
    for func, (_, _, tottime, _, callers) in stats.items():
        label = _component(func)
        if label is not None or func[0] != "~" or not callers:
            out[label or "other"] += tottime
            continue
        for caller, caller_stats in callers.items():
            out[_component(caller) or "other"] += caller_stats[2]
    return out


def default_steps(n_agents: int) -> int:
    return int(min(STEPS_MAX, max(STEPS_MIN, STEPS_BUDGET // n_agents)))


def benchmark_size(
    n_agents: int, steps: int, repeat: int, tau: int, in_degree: float, seed: int,
    profile: bool = False,
) -> dict[str, Any]:
    scn = build_scenario(n_agents, in_degree, tau, seed)
    progress(
        f"N={n_agents}: {scn.n_links} links (mean in-degree {scn.mean_in_degree:.2f}), "
        f"{steps} steps, tau={tau}"
    )

    # exact event counts (untimed, instrumented runs with the same seeds)
    event_counts, counted = count_events(make_simulation(scn, "compensated", "event"), steps)
    kernel_counts, kernel_counted = count_events(
        make_simulation(scn, "compensated", "calendar"), steps)
    pp_counts, _ = count_events(make_simulation(scn, "compensated", "process"), steps)
    null_counts, null_counted = count_events(make_simulation(scn, "null", "calendar"), steps)

    def simulation_events(popped: Counter, result: TrialResult) -> int:
        # a calendar kernel's popped events with its Delivery events replaced by messages
        return sum(popped.values()) - popped.get("Delivery", 0) + result.messages_delivered

    kernel_events = sum(event_counts.values())  # simulation events
    kernel_popped = sum(kernel_counts.values())
    pp_events = sum(pp_counts.values())
    null_events = simulation_events(null_counts, null_counted)
    if simulation_events(kernel_counts, kernel_counted) != kernel_events:
        raise RuntimeError("the calendar kernel's events (Delivery events counted per "
                           "message) differ from the event-per-message kernel's")
    if event_counts.get("MessageDelivery", 0) != counted.messages_delivered:
        raise RuntimeError("MessageDelivery events counted != messages delivered")

    per_step = -(-kernel_events // (steps + 1))  # ceil: the kernel's events per step
    best = interleaved_best(
        {
            "kernel": lambda: _time_simulation(
                lambda: make_simulation(scn, "compensated", "calendar"), steps
            ),
            "event-per-message": lambda: _time_simulation(
                lambda: make_simulation(scn, "compensated", "event"), steps
            ),
            "process-per-message": lambda: _time_simulation(
                lambda: make_simulation(scn, "compensated", "process"), steps
            ),
            "null estimator": lambda: _time_simulation(
                lambda: make_simulation(scn, "null", "calendar"), steps
            ),
            "bare-timeout": lambda: (bare_timeouts(kernel_events, per_step, tau + 1), None),
            "bare-process": lambda: (bare_process(kernel_events), None),
        },
        repeat,
    )
    kernel_wall, kernel_res = best["kernel"]
    pp_wall, pp_res = best["process-per-message"]
    ev_wall, ev_res = best["event-per-message"]
    null_wall, null_res = best["null estimator"]
    bare_t_wall = best["bare-timeout"][0]
    bare_p_wall = best["bare-process"][0]

    if kernel_res.diverged_at is not None:
        raise RuntimeError(f"N={n_agents}: run diverged at step {kernel_res.diverged_at}")
    if kernel_res.messages_delivered != counted.messages_delivered:
        raise RuntimeError("instrumented and timed runs delivered different message counts")

    def same_run(other: TrialResult) -> bool:
        return bool(
            np.array_equal(other.estimates, kernel_res.estimates)
            and other.messages_delivered == kernel_res.messages_delivered
            and other.messages_discarded == kernel_res.messages_discarded
        )

    identical = same_run(pp_res)
    if not identical:
        progress("  WARNING: process-per-message run differs from the kernel run")
    ev_identical = same_run(ev_res)
    if not ev_identical:
        progress("  WARNING: event-per-message run differs from the kernel run")

    def per_event(wall: float, events: int) -> float:
        return wall / events * 1e6

    kernel_us = per_event(kernel_wall, kernel_events)
    bare_t_us = per_event(bare_t_wall, kernel_events)
    bare_p_us = per_event(bare_p_wall, kernel_events)
    null_us = per_event(null_wall, null_events)
    pp_us = per_event(pp_wall, pp_events)
    ev_us = per_event(ev_wall, kernel_events)
    simulated = steps + 1  # steps 0..steps
    profiles = {}
    if profile:
        for estimator in ("compensated", "null"):
            progress(f"  profiling {estimator}")
            profiles[estimator] = profile_breakdown(
                make_simulation(scn, estimator, "calendar"), steps
            )
    return {
        "profile_s": profiles,
        "n_agents": n_agents,
        "steps": steps,
        "simulated_steps": simulated,
        "links": scn.n_links,
        "mean_in_degree": scn.mean_in_degree,
        "tau": tau,
        "messages_sent": kernel_res.messages_sent,
        "messages_delivered": kernel_res.messages_delivered,
        "messages_discarded_stale": kernel_res.messages_discarded,
        "kernel": {
            "wall_s": kernel_wall,
            "steps_per_s": simulated / kernel_wall,
            "messages_per_s": kernel_res.messages_delivered / kernel_wall,
            "events": kernel_events,
            "events_by_type": dict(sorted(event_counts.items())),
            "simpy_events_popped": kernel_popped,
            "simpy_events_popped_by_type": dict(sorted(kernel_counts.items())),
            "events_per_s": kernel_events / kernel_wall,
            "us_per_event": kernel_us,
        },
        "event_per_message": {
            "wall_s": ev_wall,
            "events": kernel_events,
            "events_per_s": kernel_events / ev_wall,
            "us_per_event": ev_us,
            "over_bare_timeout": ev_us / bare_t_us,
            "wall_over_kernel": ev_wall / kernel_wall,
            "identical_estimates": ev_identical,
        },
        "bare_timeout": {
            "events": kernel_events,
            "wall_s": bare_t_wall,
            "us_per_event": bare_t_us,
        },
        "bare_process": {
            "events": kernel_events,
            "wall_s": bare_p_wall,
            "us_per_event": bare_p_us,
        },
        "kernel_over_bare_timeout": kernel_us / bare_t_us,
        "bare_timeout_events_per_s": kernel_events / bare_t_wall,
        "kernel_over_bare_process": kernel_us / bare_p_us,
        "null_estimator": {
            "wall_s": null_wall,
            "steps_per_s": simulated / null_wall,
            "messages_per_s": null_res.messages_delivered / null_wall,
            "events": null_events,
            "us_per_event": null_us,
            "events_per_s": null_events / null_wall,
            "over_bare_timeout": null_us / bare_t_us,
            "share_of_kernel_wall": null_wall / kernel_wall,
        },
        # what the estimators' arithmetic adds per simulation event (kernel minus null
        # estimator), in bare SimPy timeouts: a floor under the kernel's ratio that no
        # kernel work removes
        "estimator_over_bare_timeout": (kernel_us - null_us) / bare_t_us,
        "process_per_message": {
            "wall_s": pp_wall,
            "steps_per_s": simulated / pp_wall,
            "messages_per_s": pp_res.messages_delivered / pp_wall,
            "events": pp_events,
            "events_by_type": dict(sorted(pp_counts.items())),
            "us_per_event": pp_us,
            "wall_over_kernel": pp_wall / kernel_wall,
            "extra_us_per_message": (pp_wall - kernel_wall)
            / max(1, kernel_res.messages_delivered)
            * 1e6,
            "identical_estimates": identical,
        },
    }


# -------------------------------------------------------------------------- output


def render(report: dict[str, Any]) -> str:
    results = report["results"]
    out = [
        f"netsim kernel throughput  (python {report['python']}, simpy {report['simpy']}, "
        f"numpy {report['numpy']}; best of {report['repeat']} interleaved rounds, "
        "wall = perf_counter around Simulation.run)",
        "scenario: random strongly-connected digraph, random row-stochastic weights, "
        "n=2 plant, 1 output/agent, L_i = 0.1 C_i^T, "
        f"asynchronous random delays tau={results[0]['tau'] if results else '?'}, "
        "CompensatingEstimator, record_delays=False",
        "",
        "Headline: kernel cost per simulation event / bare SimPy timeout cost per event "
        "(goal <= 3x)",
        format_table(
            [
                "N",
                "kernel events/s",
                "bare-timeout events/s",
                "ratio (kernel)",
                "ratio (event per message)",
                "ratio (null estimator)",
                "estimator work / bare",
            ],
            [
                [
                    str(r["n_agents"]),
                    si(r["kernel"]["events_per_s"]),
                    si(r["bare_timeout_events_per_s"]),
                    f"{r['kernel_over_bare_timeout']:.2f}x",
                    f"{r['event_per_message']['over_bare_timeout']:.2f}x",
                    f"{r['null_estimator']['over_bare_timeout']:.2f}x",
                    f"{r['estimator_over_bare_timeout']:.2f}x",
                ]
                for r in results
            ],
        ),
        "",
        "Kernel throughput",
        format_table(
            [
                "N",
                "links",
                "in-deg",
                "steps",
                "msgs",
                "wall s",
                "steps/s",
                "msgs/s",
                "events",
                "events/s",
                "us/event",
            ],
            [
                [
                    str(r["n_agents"]),
                    str(r["links"]),
                    f"{r['mean_in_degree']:.2f}",
                    str(r["steps"]),
                    str(r["messages_delivered"]),
                    f"{r['kernel']['wall_s']:.3f}",
                    si(r["kernel"]["steps_per_s"]),
                    si(r["kernel"]["messages_per_s"]),
                    str(r["kernel"]["events"]),
                    si(r["kernel"]["events_per_s"]),
                    f"{r['kernel']['us_per_event']:.2f}",
                ]
                for r in results
            ],
        ),
        "",
        "Cost per event vs bare SimPy (same event count)",
        format_table(
            [
                "N",
                "kernel us/ev",
                "bare-timeout us/ev",
                "ratio",
                "bare-process us/ev",
                "ratio",
                "null-est us/ev",
                "null/bare-timeout",
                "null wall share",
            ],
            [
                [
                    str(r["n_agents"]),
                    f"{r['kernel']['us_per_event']:.2f}",
                    f"{r['bare_timeout']['us_per_event']:.3f}",
                    f"{r['kernel_over_bare_timeout']:.1f}x",
                    f"{r['bare_process']['us_per_event']:.3f}",
                    f"{r['kernel_over_bare_process']:.1f}x",
                    f"{r['null_estimator']['us_per_event']:.2f}",
                    f"{r['null_estimator']['over_bare_timeout']:.1f}x",
                    f"{100 * r['null_estimator']['share_of_kernel_wall']:.0f}%",
                ]
                for r in results
            ],
        ),
        "",
        "Delivery designs (same scenario): the kernel's calendar (one event per arrival "
        "instant) vs one event per message vs one process per message",
        format_table(
            [
                "N",
                "kernel wall s",
                "event/msg wall s",
                "event/msg ÷ kernel",
                "proc/msg wall s",
                "proc/msg ÷ kernel",
                "SimPy events popped (kernel / event/msg / proc/msg)",
                "identical",
            ],
            [
                [
                    str(r["n_agents"]),
                    f"{r['kernel']['wall_s']:.3f}",
                    f"{r['event_per_message']['wall_s']:.3f}",
                    f"{r['event_per_message']['wall_over_kernel']:.2f}x",
                    f"{r['process_per_message']['wall_s']:.3f}",
                    f"{r['process_per_message']['wall_over_kernel']:.2f}x",
                    f"{r['kernel']['simpy_events_popped']} / {r['kernel']['events']} / "
                    f"{r['process_per_message']['events']}",
                    "yes" if r["process_per_message"]["identical_estimates"]
                    and r["event_per_message"]["identical_estimates"] else "NO",
                ]
                for r in results
            ],
        ),
        "",
        "Simulation events by type (event-per-message run) and the kernel's popped events",
        format_table(
            ["N", *report["event_types"], "kernel: Delivery", "kernel: all popped"],
            [
                [str(r["n_agents"])]
                + [str(r["kernel"]["events_by_type"].get(t, 0)) for t in report["event_types"]]
                + [str(r["kernel"]["simpy_events_popped_by_type"].get("Delivery", 0)),
                   str(r["kernel"]["simpy_events_popped"])]
                for r in results
            ],
        ),
        *_render_profiles(results),
        "",
        "Notes:",
        "- " + EVENT_COUNT_EXPLANATION,
        "- bare-timeout: the same number of env.timeout(1 + i % (tau+1)) events with a no-op "
        "callback, created per unit of time by a driver timeout (as many per step as the "
        "kernel processes, so the queue stays kernel-sized; creation is timed); "
        "bare-process: one process yielding that many env.timeout(1). "
        "ratio = kernel us/event / bare us/event.",
        "- null-est: the same kernel run with an estimator doing no arithmetic (kernel "
        "machinery + plant + monitor; it does not take step's out, so the monitor copies "
        "its estimates, one numpy assignment per step, where the compensating estimator "
        "writes into the kernel's row itself); 'null wall share' = its wall time / the "
        "kernel's. "
        "'estimator work / bare' = (kernel - null-est us/event) / bare-timeout us/event: "
        "what the estimators' arithmetic adds, a floor under the kernel's ratio that no "
        "kernel work removes (ratio (kernel) = ratio (null estimator) + this).",
        "- event/msg: the kernel with one URGENT SimPy event per message instead of the "
        "delivery calendar. proc/msg: links starting env.process(gen) per message (gen "
        "yields env.timeout(wait), then delivers). 'identical' = both give bit-identical "
        "estimates and message counts to the kernel run.",
        "- steps/s counts simulated steps 0..steps (steps + 1 per run).",
    ]
    return "\n".join(out)


def _render_profiles(results: list[dict[str, Any]]) -> list[str]:
    rows = []
    labels = [label for label, _ in PROFILE_COMPONENTS] + ["other"]
    for r in results:
        for estimator, parts in r["profile_s"].items():
            total = sum(parts.values())
            rows.append(
                [str(r["n_agents"]), estimator, f"{total:.2f}"]
                + [f"{100 * parts[label] / total:.0f}%" for label in labels]
            )
    if not rows:
        return []
    return [
        "",
        "Profile (--profile): share of cProfile time by component "
        "(C calls charged to their caller)",
        format_table(["N", "estimator", "prof. s", *labels], rows),
    ]


def parse_int_list(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}"
        ) from exc
    if not values:
        raise argparse.ArgumentTypeError("empty list")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="kernel_throughput.py",
        description=(
            "Throughput of the netsim SimPy kernel (steps/s, messages/s, events/s) "
            "against bare SimPy events and a process-per-message link design."
        ),
        epilog=(
            f"Default steps per size: {STEPS_BUDGET}/N clamped to [{STEPS_MIN}, {STEPS_MAX}] "
            "(2000, 1600, 400 for N = 4, 32, 128). Progress is printed on stderr."
        ),
    )
    parser.add_argument(
        "--sizes",
        type=parse_int_list,
        default=list(DEFAULT_SIZES),
        help="comma-separated numbers of agents (default: 4,32,128)",
    )
    parser.add_argument(
        "--steps",
        type=parse_int_list,
        default=None,
        help="steps per run: one value for every size, or one per size "
        "(default: 51200/N clamped to [200, 2000])",
    )
    parser.add_argument(
        "--repeat", type=int, default=3, help="timed runs per measurement; best is kept (3)"
    )
    parser.add_argument("--tau", type=int, default=3, help="delay bound of the random delays (3)")
    parser.add_argument(
        "--in-degree", type=float, default=3.0, help="target mean in-degree per agent (3)"
    )
    parser.add_argument("--seed", type=int, default=0, help="root seed (0)")
    parser.add_argument(
        "--profile",
        action="store_true",
        help="also profile one untimed run per size and estimator (cProfile) and "
        "report where the time goes",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object on stdout instead of the table",
    )
    args = parser.parse_args(argv)

    sizes = args.sizes
    if any(n < 2 for n in sizes):
        parser.error("--sizes: every size must be >= 2")
    if args.steps is None:
        steps = [default_steps(n) for n in sizes]
    elif len(args.steps) == 1:
        steps = args.steps * len(sizes)
    elif len(args.steps) == len(sizes):
        steps = args.steps
    else:
        parser.error("--steps: give one value or one per size")
    if any(s < 1 for s in steps):
        parser.error("--steps: must be >= 1")
    if args.repeat < 1:
        parser.error("--repeat: must be >= 1")

    t0 = time.perf_counter()
    results = [
        benchmark_size(n, s, args.repeat, args.tau, args.in_degree, args.seed, args.profile)
        for n, s in zip(sizes, steps, strict=True)
    ]
    types = sorted({t for r in results for t in r["kernel"]["events_by_type"]})
    report = {
        "benchmark": "kernel_throughput",
        "command": " ".join([sys.argv[0], *(sys.argv[1:] if argv is None else argv)]),
        "python": platform.python_version(),
        "simpy": simpy.__version__,
        "numpy": np.__version__,
        "machine": platform.machine(),
        "repeat": args.repeat,
        "seed": args.seed,
        "event_count_definition": EVENT_COUNT_EXPLANATION,
        "event_types": types,
        "results": results,
        "total_wall_s": time.perf_counter() - t0,
    }
    progress(f"total {report['total_wall_s']:.1f} s")
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(render(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
