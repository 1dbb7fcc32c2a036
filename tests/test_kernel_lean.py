"""The kernel's lean path (no Message objects when nothing observes) changes nothing."""

import numpy as np
import pytest
import simpy
from helpers import lcsys, with_delays
from netsim.estimators.consensus import NO_MESSAGE, CompensatingEstimator, ConsensusParameters
from netsim.models.delays import AsynchronousRandomDelays
from netsim.models.seeding import child_sequence

from netsim.links import Link
from netsim.runner import run_trial, scenario_gains

STEPS = 120


@pytest.fixture(scope="module")
def scenario():
    return with_delays(lcsys(), model="asynchronous", tau=3)


@pytest.fixture(scope="module")
def gains(scenario):
    return scenario_gains(scenario)


class _Updates:
    """Observer that only records the effective delays it is given."""

    def __init__(self):
        self.delays = {}

    def on_plant(self, k, state, measurements):
        pass

    def on_sent(self, message):
        pass

    def on_delivered(self, message, accepted):
        pass

    def on_update(self, agent, k, estimate, delays):
        self.delays[(agent, k)] = dict(delays)


@pytest.mark.parametrize("family", ["compensated", "uncompensated", "block"])
def test_lean_and_full_paths_are_bit_identical(scenario, gains, family):
    seed = child_sequence(11, "trial", 0)
    lean = run_trial(scenario, family, gains, seed, STEPS)
    full = run_trial(scenario, family, gains, seed, STEPS, record_messages=True)
    observer = _Updates()
    observed = run_trial(scenario, family, gains, seed, STEPS, observer=observer)
    for other in (full, observed):
        assert lean.estimates.tobytes() == other.estimates.tobytes()
        assert lean.states.tobytes() == other.states.tobytes()
        assert np.array_equal(lean.effective_delays, other.effective_delays)
        for a, b in zip(lean.measurements, other.measurements, strict=True):
            assert a.tobytes() == b.tobytes()
        assert (lean.messages_sent, lean.messages_delivered, lean.messages_discarded) == (
            other.messages_sent, other.messages_delivered, other.messages_discarded)
    assert len(full.messages) == full.messages_delivered and not lean.messages
    # the delays handed to the observer are the recorded r_ij[k]
    for (i, k), delays in observer.delays.items():
        for j, r in delays.items():
            assert observed.effective_delays[k, i, j] == r


def test_send_function_is_lean_only_without_hooks():
    env = simpy.Environment()
    received = []
    link = Link(env, 0, 1, AsynchronousRandomDelays(2, seed=0), received.append)
    assert not link.lean and link.send_function() == link.send
    link.receive = lambda sender, step, payload: True
    assert link.lean and link.send_function() != link.send
    link.on_send = lambda message: None
    assert not link.lean
    link.on_send = None
    link.availability = lambda sender, receiver, step: True
    assert not link.lean


def test_lean_link_delivers_at_the_same_time_as_the_full_link():
    times = {}
    for lean in (False, True):
        env = simpy.Environment()
        arrivals = []
        link = Link(env, 0, 1, AsynchronousRandomDelays(3, seed=4),
                    lambda m, a=arrivals, e=env: a.append((e.now, m.sent_step)))
        if lean:
            link.receive = lambda sender, step, payload, a=arrivals, e=env: \
                a.append((e.now, step)) or step % 2 == 0
        send = link.send_function()

        def sender(env=env, send=send):
            for k in range(50):
                send(k, np.zeros(1))
                yield env.timeout(1)

        env.process(sender())
        env.run()
        times[lean] = arrivals
        assert link.sent == link.delivered == 50
        assert link.discarded == (25 if lean else 0)
    assert times[True] == times[False]


def test_last_delays_reflect_the_update_not_later_arrivals():
    params = ConsensusParameters(agent=0, weights=np.array([0.5, 0.25, 0.25]),
                                 A=np.eye(2), C=np.ones((1, 2)), L=np.zeros((2, 1)),
                                 prior=np.zeros(2))
    est = CompensatingEstimator(params)
    est.step(0, np.zeros(1))
    assert est.last_delays == {1: NO_MESSAGE, 2: NO_MESSAGE}
    est.message_arrived(1, 0, np.ones(2))
    est.step(3, np.zeros(1))
    est.message_arrived(2, 2, np.ones(2))  # after the update: not in its delays
    assert est.last_delays == {1: 2, 2: NO_MESSAGE}
    est.step(4, np.zeros(1))
    assert est.last_delays == {1: 3, 2: 1}


def _send_program(build_send, kinds):
    """Send 30 steps on links 0 -> r with the given kinds; return what arrived when."""
    from netsim.models.delays import FixedDelays

    from netsim.deliveries import DeliveryCalendar

    env = simpy.Environment()
    calendar = DeliveryCalendar(env)
    arrivals = []
    links = []
    for r, kind in enumerate(kinds, start=1):
        model = AsynchronousRandomDelays(3, seed=r) if kind != "fixed" else FixedDelays(default=2)
        link = Link(env, 0, r, model, lambda m, r=r: arrivals.append((env.now, r, m.sent_step)),
                    calendar=calendar)
        if kind != "full":  # lean: the receiver's message_arrived
            link.receive = lambda sender, step, payload, r=r: \
                arrivals.append((env.now, r, step)) or True
        links.append(link)
    send = build_send(links)

    def sender():
        for k in range(30):
            send(k, np.full(2, float(k)))
            yield env.timeout(1)

    env.process(sender())
    env.run()
    return arrivals, [(link.sent, link.delivered) for link in links]


@pytest.mark.parametrize("kinds", [("random", "random", "fixed"), ("random", "full", "fixed"),
                                   ("full",), ()])
def test_sender_function_is_each_links_send_in_turn(kinds):
    """One send for all out-links delivers what the links' own sends deliver, in order."""
    from netsim.links import sender_function

    def each(links):
        sends = [link.send_function() for link in links]
        return lambda k, payload: [send(k, payload) for send in sends]

    together, counts = _send_program(sender_function, kinds)
    separately, expected_counts = _send_program(each, kinds)
    assert together == separately
    assert counts == expected_counts
    assert len(together) == 30 * len(kinds) and all(c == (30, 30) for c in counts)


def test_sender_function_refuses_lean_links_of_different_senders():
    from netsim.links import sender_function

    env = simpy.Environment()
    links = [Link(env, s, 2, AsynchronousRandomDelays(1, seed=0), lambda m: None)
             for s in (0, 1)]
    for link in links:
        link.receive = lambda sender, step, payload: True
    with pytest.raises(ValueError, match="share a sender"):
        sender_function(links)


@pytest.mark.parametrize("family", ["compensated", "uncompensated", "block"])
def test_estimates_written_in_place_are_the_copied_ones(scenario, gains, family,
                                                         monkeypatch):
    """The consensus estimators write into the kernel's rows of estimates (step's out);
    a kernel that copies every returned estimate instead gives the same run, bit for
    bit, with or without an observer."""
    import netsim.kernel

    seed = child_sequence(12, "trial", 0)
    assert netsim.kernel._takes_out(CompensatingEstimator(ConsensusParameters(
        0, np.ones(1), np.eye(1), np.eye(1), np.eye(1), np.zeros(1))))
    in_place = run_trial(scenario, family, gains, seed, STEPS)
    observed = run_trial(scenario, family, gains, seed, STEPS, observer=_Updates())
    monkeypatch.setattr(netsim.kernel, "_takes_out", lambda estimator: False)
    copied = run_trial(scenario, family, gains, seed, STEPS)
    for other in (copied, observed):
        assert in_place.estimates.tobytes() == other.estimates.tobytes()
        assert np.array_equal(in_place.squared_errors, other.squared_errors, equal_nan=True)
        assert np.array_equal(in_place.effective_delays, other.effective_delays)
        assert (in_place.messages_sent, in_place.messages_delivered,
                in_place.messages_discarded, in_place.diverged_at) == (
            other.messages_sent, other.messages_delivered, other.messages_discarded,
            other.diverged_at)
    assert np.all(np.isfinite(in_place.estimates))
