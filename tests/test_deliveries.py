"""The delivery calendar delivers exactly as one URGENT SimPy event per message would.

:class:`netsim.deliveries.DeliveryCalendar` schedules one URGENT event per arrival
instant and hands the messages of that instant over in scheduling order. The
reference here, :class:`PerMessageCalendar`, is the plain design it replaces: one
URGENT ``simpy.events.Event`` per message, scheduled with ``env.schedule``. Random
programs of sends (several links, integer and fractional send times, waits including
zero, equal arrival instants reached from different links and send times, sends made
from inside deliveries) interleaved with NORMAL-priority events must give the same
log -- deliveries (time, link, value), the NORMAL events and the number of pending
messages they see -- under both; and so must the kernel's whole simulation.
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import simpy
from hypothesis import given, settings
from hypothesis import strategies as st
from netsim.models.scenario import parse_scenario
from netsim.models.seeding import child_sequence
from simpy.core import NORMAL, URGENT
from simpy.events import Event

import netsim.kernel
from netsim.deliveries import DeliveryCalendar
from netsim.runner import run_trial


class PerMessageCalendar:
    """Reference: one URGENT SimPy event per message, scheduled at send time.

    Same interface as DeliveryCalendar: ``schedule(wait, arrive, value)``, ``events``
    (events scheduled), ``env`` and ``len()`` (messages pending).
    """

    #: instances built (the end-to-end test checks the kernel used this class)
    built: list[PerMessageCalendar] = []

    def __init__(self, env: simpy.Environment) -> None:
        self.env = env
        self.events = 0
        self._pending = 0
        PerMessageCalendar.built.append(self)

    def schedule(self, wait: float, arrive: Callable[[Any], None], value: Any) -> None:
        event = Event(self.env)
        event._ok = True
        event._value = None

        def hand_over(_event: Event, arrive=arrive, value=value) -> None:
            self._pending -= 1
            arrive(value)

        event.callbacks.append(hand_over)
        self.env.schedule(event, URGENT, wait)
        self.events += 1
        self._pending += 1

    def __len__(self) -> int:
        return self._pending


# -- random programs of sends ---------------------------------------------------------

#: waits: zero, exact binary fractions (so that different send times and waits meet at
#: equal arrival instants) and inexact decimals
WAITS = [0, 0.0, 0.0, 0.25, 0.5, 0.75, 1, 1.0, 1.5, 2.0, 3, 0.1, 0.2, 0.3]

send_times = st.one_of(
    st.integers(0, 6).map(float),
    st.integers(0, 24).map(lambda q: q / 4),
    st.integers(0, 60).map(lambda q: q / 10),
)


@st.composite
def programs(draw):
    """A program: links, sends (time, link, wait, pause-before, reaction), ticks."""
    n_links = draw(st.integers(1, 4))
    link = st.integers(0, n_links - 1)
    wait = st.sampled_from(WAITS)
    reaction = st.none() | st.tuples(link, wait)
    # a wait is drawn, or aimed at an integer arrival instant (so that many sends
    # from different times and links meet there; zero if that instant has passed)
    aim = st.none() | st.integers(0, 8).map(float)
    drawn = draw(st.lists(st.tuples(send_times, link, wait, aim, st.booleans(), reaction),
                          min_size=1, max_size=40))
    sends = [(time, link, wait if target is None else max(0.0, target - time), pause,
              reaction) for time, link, wait, target, pause, reaction in drawn]
    sends.sort(key=lambda send: send[0])  # stable: equal times keep the drawn order
    tick_period = draw(st.sampled_from([1.0, 0.5, 0.25]))
    tick_offset = draw(st.sampled_from([0.0, 0.25, 0.5]))
    return n_links, sends, tick_period, tick_offset


def run_program(program, calendar_class) -> tuple[list[tuple], Any]:
    """Run a program on a fresh environment with the given calendar; return the log."""
    n_links, sends, tick_period, tick_offset = program
    env = simpy.Environment()
    calendar = calendar_class(env)
    log: list[tuple] = []

    def arrive(delivery: tuple) -> None:
        link, value, reaction = delivery
        log.append(("deliver", env.now, link, value))
        if reaction is not None:  # a send made from inside a delivery (URGENT context)
            to_link, wait = reaction
            log.append(("react", env.now, to_link, value))
            calendar.schedule(wait, arrive, (to_link, f"{value}'", None))

    def driver():
        for index, (time, link, wait, pause, reaction) in enumerate(sends):
            if time > env.now:
                yield env.timeout(time - env.now)
            elif pause:
                yield env.timeout(0)  # a NORMAL event at the same instant
            log.append(("send", env.now, link, index, len(calendar)))
            calendar.schedule(wait, arrive, (link, index, reaction))

    def ticker():
        yield env.timeout(tick_offset)
        for k in range(int(12 / tick_period)):
            log.append(("tick", env.now, k, len(calendar)))
            yield env.timeout(tick_period)

    env.process(ticker())
    env.process(driver())
    env.run()
    assert len(calendar) == 0
    return log, calendar


@settings(max_examples=200, deadline=None)
@given(programs())
def test_calendar_delivers_as_one_urgent_event_per_message(program):
    expected, reference = run_program(program, PerMessageCalendar)
    got, calendar = run_program(program, DeliveryCalendar)
    assert got == expected
    # one event per distinct arrival instant at most, one per message in the reference
    assert calendar.events <= reference.events


@settings(max_examples=100, deadline=None)
@given(st.lists(st.sampled_from(WAITS) | st.none(), min_size=1, max_size=40),
       st.sampled_from([0, 1.0, 2.5]))
def test_events_count_distinct_pending_instants_and_len_counts_messages(operations, start):
    """Sends (a wait) and steps (None): a new event exactly when a send's arrival
    instant has no pending batch; ``len`` is the number of undelivered messages."""
    env = simpy.Environment(initial_time=start)
    calendar = DeliveryCalendar(env)
    delivered: list[int] = []
    pending: dict[float, list[int]] = {}  # model: instant -> messages, in sending order
    events = 0
    for index, wait in enumerate(operations):
        if wait is None:
            if not pending:
                continue
            instant = min(pending)
            env.step()
            assert env.now == instant
            assert delivered[-len(pending[instant]):] == pending.pop(instant)
        else:
            at = env.now + wait
            events += at not in pending
            pending.setdefault(at, []).append(index)
            calendar.schedule(wait, delivered.append, index)
        assert calendar.events == events
        assert len(calendar) == sum(map(len, pending.values()))
    env.run()
    assert len(calendar) == 0 and calendar.events == events
    assert sorted(delivered) == [i for i, wait in enumerate(operations) if wait is not None]


# -- zero wait at an instant whose calendar event has been processed -----------------


def _zero_wait_log(calendar_class) -> tuple[list[tuple], Any]:
    env = simpy.Environment()
    calendar = calendar_class(env)
    log: list[tuple] = []

    def record(value: str) -> None:
        log.append((env.now, value))
        if value == "a":  # from inside the delivery: after b and c, before any NORMAL
            calendar.schedule(0, record, "a0")
            calendar.schedule(1, record, "a1")

    def normal(name: str, sends: tuple[str, ...]):
        log.append((env.now, name, len(calendar)))
        for value in sends:
            calendar.schedule(0, record, value)
        yield env.timeout(0)
        log.append((env.now, name + " again", len(calendar)))

    def start():
        calendar.schedule(2, record, "a")
        calendar.schedule(2, record, "b")
        yield env.timeout(1)
        calendar.schedule(1, record, "c")  # the same instant from a later send time
        yield env.timeout(1)
        # at t = 2: a, b, c, a0 were delivered (URGENT) before this NORMAL event
        env.process(normal("n1", ("d", "e")))
        env.process(normal("n2", ("f",)))

    env.process(start())
    env.run()
    return log, calendar


def test_zero_wait_sends_after_the_instants_event_come_after_it():
    expected = [
        (2, "a"), (2, "b"), (2, "c"), (2, "a0"),
        # the processes start (URGENT Initialize events, scheduled before d, e, f)
        (2, "n1", 1), (2, "n2", 3),
        # d, e, f: URGENT, so before the NORMAL timeouts of n1 and n2 at the same instant
        (2, "d"), (2, "e"), (2, "f"),
        (2, "n1 again", 1), (2, "n2 again", 1),
        (3, "a1"),
    ]
    log, reference = _zero_wait_log(PerMessageCalendar)
    assert log == expected and reference.events == 8
    log, calendar = _zero_wait_log(DeliveryCalendar)
    assert log == expected
    # events at t = 2 for a, b, c; for a0 (sent while a, b, c were handed over); for
    # d, e, f (sent after that); at t = 3 for a1
    assert calendar.events == 4


# -- the kernel end to end -------------------------------------------------------------


def _lossy_buffered_scenario():
    """Random topology; step delays 0..4 (arrivals at sampling instants, out of order),
    per-link latencies (zero, fractional, exactly one period), Bernoulli and
    Gilbert-Elliott loss, buffers of every policy, and one plain link."""
    rng = np.random.default_rng(7)
    n, agents = 3, 5
    A = rng.normal(size=(n, n))
    A *= 1.02 / np.max(np.abs(np.linalg.eigvals(A)))
    data = {
        "name": "calendar-e2e",
        "run": {"steps": 150, "trials": 1, "seed": 5, "divergence_threshold": 1e300},
        "plant": {"A": A.tolist(), "C": [rng.normal(size=(1, n)).tolist()
                                         for _ in range(agents)],
                  "Q": 0.01, "R": 0.01},
        "network": {"topology": "random", "agents": agents, "edge_probability": 0.8,
                    "seed": 3, "weights": "random"},
        "delays": {"model": "asynchronous", "tau": 3, "seed": 11},
        "gains": {"method": "lmi"},
        "links": {
            "seed": 13,
            "delay": {"distribution": "uniform", "low": 0, "high": 4, "mode": "asynchronous"},
            "loss": {"model": "bernoulli", "p": 0.2},
        },
    }
    scenario = parse_scenario(data, "calendar-e2e")
    links = scenario.links
    per_link = [
        {"from": links[0][0], "to": links[0][1], "loss": {"model": "none"}},  # plain link
        {"from": links[1][0], "to": links[1][1],
         "delay": {"distribution": "constant", "value": 0.0, "unit": "time"}},
        {"from": links[2][0], "to": links[2][1],
         "delay": {"distribution": "uniform", "low": 0.0, "high": 2.5, "unit": "time"},
         "buffer": {"policy": "drop-oldest", "capacity": 1}},
        {"from": links[3][0], "to": links[3][1],
         "delay": {"distribution": "constant", "value": 1.0, "unit": "time"},
         "loss": {"model": "gilbert-elliott", "p": 0.2, "r": 0.5}},
        {"from": links[4][0], "to": links[4][1], "buffer": {"policy": "drop-tail",
                                                            "capacity": 1}},
        {"from": links[5][0], "to": links[5][1], "buffer": {"policy": "keep-latest"}},
        {"from": links[6][0], "to": links[6][1], "buffer": {"policy": "drop-oldest",
                                                            "capacity": 3}},
    ]
    data["links"]["per_link"] = per_link
    scenario = parse_scenario(data, "calendar-e2e")
    gains = SimpleNamespace(L=[rng.normal(scale=0.3, size=(n, 1)) for _ in range(agents)])
    return scenario, gains


@pytest.mark.parametrize("family", ["compensated", "uncompensated", "block"])
@pytest.mark.parametrize("record_messages", [False, True])
def test_kernel_is_bit_identical_with_one_event_per_message(monkeypatch, family,
                                                            record_messages):
    scenario, gains = _lossy_buffered_scenario()
    seed = child_sequence(5, "trial", 0)
    counted: list[DeliveryCalendar] = []

    class CountedCalendar(DeliveryCalendar):
        def __init__(self, env):
            super().__init__(env)
            counted.append(self)

    monkeypatch.setattr(netsim.kernel, "DeliveryCalendar", CountedCalendar)
    shared = run_trial(scenario, family, gains, seed, record_messages=record_messages)
    PerMessageCalendar.built.clear()
    monkeypatch.setattr(netsim.kernel, "DeliveryCalendar", PerMessageCalendar)
    reference = run_trial(scenario, family, gains, seed, record_messages=record_messages)
    assert len(PerMessageCalendar.built) == 1 and len(counted) == 1
    # the scenario has shared arrival instants (fewer events than messages), losses
    # and drops, and stale arrivals (discarded by the freshest rule)
    assert counted[0].events < PerMessageCalendar.built[0].events
    assert reference.messages_dropped > 0
    assert reference.messages_discarded > 0 or family != "compensated"
    assert shared.diverged_at is None and np.all(np.isfinite(shared.estimates))

    assert shared.estimates.tobytes() == reference.estimates.tobytes()
    assert shared.states.tobytes() == reference.states.tobytes()
    assert np.array_equal(shared.effective_delays, reference.effective_delays)
    for name in ("messages_sent", "messages_delivered", "messages_discarded",
                 "messages_dropped", "drop_reasons"):
        assert getattr(shared, name) == getattr(reference, name), name
    order = [(m.sender, m.receiver, m.sequence, m.arrival_time) for m in shared.messages]
    assert order == [(m.sender, m.receiver, m.sequence, m.arrival_time)
                     for m in reference.messages]
    assert len(order) == (shared.messages_delivered if record_messages else 0)


def test_reference_is_what_its_docstring_says():
    """The reference's events are URGENT and per message (guards the guard)."""
    env = simpy.Environment()
    calendar = PerMessageCalendar(env)
    calendar.schedule(1, lambda value: None, 0)
    calendar.schedule(1, lambda value: None, 1)
    assert calendar.events == 2 and len(calendar) == 2
    assert [entry[:2] for entry in env._queue] == [(1, URGENT), (1, URGENT)]
    assert URGENT < NORMAL
