"""The event kernel against independent recursions and the delay semantics."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import lcsys, lockstep_compensated, with_delays
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from netsim.models.seeding import child_sequence

from netsim.runner import run_trial, scenario_gains

STEPS = 60


@pytest.fixture(scope="module")
def scenario():
    return lcsys()


@pytest.fixture(scope="module")
def gains(scenario):
    return scenario_gains(scenario)


def test_zero_delays_every_consensus_variant_is_the_delay_free_recursion(scenario, gains):
    zero = with_delays(scenario, model="homogeneous", tau=0)
    seed = child_sequence(7, "trial", 0)
    runs = {
        f: run_trial(zero, f, gains, seed, STEPS)
        for f in ("compensated", "uncompensated", "block")
    }
    # identical arithmetic in all three variants when every delay is zero
    np.testing.assert_array_equal(runs["compensated"].estimates, runs["uncompensated"].estimates)
    np.testing.assert_array_equal(runs["compensated"].estimates, runs["block"].estimates)
    # and the delay-free recursion of LCSYS2022 eq. (12) in stacked form
    plant = zero.plant
    run = runs["compensated"]
    N, n = zero.n_agents, plant.n_states
    PA = np.kron(zero.weights, plant.A)
    KD = np.zeros((N * n, N * n))
    for i in range(N):
        KD[i * n:(i + 1) * n, i * n:(i + 1) * n] = gains.L[i] @ plant.C[i]
    KDy = np.zeros((STEPS + 1, N * n))
    for i in range(N):
        KDy[:, i * n:(i + 1) * n] = run.measurements[i] @ gains.L[i].T
    x = np.tile(plant.x0_mean, N)
    x = x - KD @ x + KDy[0]
    stacked = [x]
    for k in range(1, STEPS + 1):
        prior = PA @ stacked[-1]
        stacked.append(prior - KD @ prior + KDy[k])
    expected = np.array(stacked).reshape(STEPS + 1, N, n)
    np.testing.assert_allclose(run.estimates, expected, rtol=1e-12, atol=1e-12)
    assert run.diverged_at is None


def test_compensating_estimator_matches_lockstep_recursion_of_eqs_4_5(scenario, gains):
    links = scenario.links
    delays = {link: d for link, d in zip(links, [0, 3, 1, 5], strict=True)}
    fixed = with_delays(
        scenario, model="fixed", links={k: float(v) for k, v in delays.items()}
    )
    run = run_trial(fixed, "compensated", gains, child_sequence(11, "trial", 0), 120)
    plant = fixed.plant
    expected = lockstep_compensated(
        fixed.weights, plant.A, plant.C, gains.L, plant.x0_mean, run.measurements, delays, 120
    )
    err_sim = run.estimates - run.states[:, None, :]
    err_ref = expected - run.states[:, None, :]
    np.testing.assert_allclose(err_sim, err_ref, rtol=0, atol=1e-9)


def test_message_sent_at_s_is_used_at_s_plus_1_plus_d(scenario, gains):
    links = scenario.links
    delays = {link: d for link, d in zip(links, [2, 0, 4, 1], strict=True)}
    fixed = with_delays(scenario, model="fixed", links={k: float(v) for k, v in delays.items()})
    run = run_trial(fixed, "compensated", gains, 3, 30, record_messages=True)
    r = run.effective_delays
    for (j, i), d in delays.items():
        # nothing from j before step 1 + d: agent i substitutes its own estimate
        assert np.all(r[1:1 + d, i, j] == -1)
        # from step 1 + d on, the message of step k - 1 - d is used: r_ij[k] = d
        assert np.all(r[1 + d:, i, j] == d)
    for message in run.messages:
        d = delays[(message.sender, message.receiver)]
        assert message.arrival_time == message.sent_step + 1 + d
        assert message.delay_steps == d


@pytest.mark.parametrize(
    ("latency", "expected_d"), [(0.0, 0), (0.4, 0), (1.0, 0), (1.5, 1), (2.0, 1), (2.01, 2)]
)
def test_continuous_latency_maps_to_ceil_minus_one(scenario, gains, latency, expected_d):
    link = scenario.links[0]
    lat = with_delays(scenario, model="latency", links={link: latency}, default=0.0)
    run = run_trial(lat, "compensated", gains, 5, 12)
    j, i = link
    # a message arriving exactly at k * Ts counts as arrived for step k
    assert np.all(run.effective_delays[1 + expected_d:, i, j] == expected_d)
    assert np.all(run.effective_delays[1:1 + expected_d, i, j] == -1)


def _freshest_reference(messages, i, j, steps, by_timestamp):
    """s_j(k) from the delivered messages alone: largest stamp or last arrival."""
    used = np.full(steps + 1, -1)
    current = None
    arrivals = [m for m in messages if (m.sender, m.receiver) == (j, i)]
    idx = 0
    for k in range(1, steps + 1):
        while idx < len(arrivals) and arrivals[idx].arrival_time <= k:
            s = arrivals[idx].sent_step
            if current is None or not by_timestamp or s > current:
                current = s
            idx += 1
        used[k] = -1 if current is None else k - 1 - current
    return used


@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
def test_reordered_messages_obey_the_freshest_rule(scenario, gains, family):
    tv = with_delays(scenario, model="asynchronous", tau=6)
    steps = 80
    run = run_trial(tv, family, gains, 9, steps, record_messages=True)
    reordered = 0
    for j, i in tv.links:
        arrivals = [m.sent_step for m in run.messages if (m.sender, m.receiver) == (j, i)]
        reordered += sum(b < a for a, b in zip(arrivals, arrivals[1:], strict=False))
        expected = _freshest_reference(
            run.messages, i, j, steps, by_timestamp=(family == "compensated")
        )
        np.testing.assert_array_equal(run.effective_delays[1:, i, j], expected[1:])
    assert reordered > 0, "the scenario must actually reorder messages"
    if family == "compensated":
        # with time-stamps the used stamp never goes backwards
        for j, i in tv.links:
            stamps = np.arange(steps + 1) - 1 - run.effective_delays[:, i, j]
            valid = run.effective_delays[:, i, j] >= 0
            assert np.all(np.diff(stamps[valid]) >= 0)
        assert run.messages_discarded > 0


def test_same_seed_same_numbers_bit_for_bit(scenario, gains):
    tv = with_delays(scenario, model="asynchronous", tau=4)
    a = run_trial(tv, "compensated", gains, child_sequence(5, "trial", 2), 50)
    b = run_trial(tv, "compensated", gains, child_sequence(5, "trial", 2), 50)
    c = run_trial(tv, "compensated", gains, child_sequence(6, "trial", 2), 50)
    assert a.estimates.tobytes() == b.estimates.tobytes()
    assert np.array_equal(a.effective_delays, b.effective_delays)
    assert a.estimates.tobytes() != c.estimates.tobytes()


def test_divergence_is_reported_with_its_step(scenario):
    from dataclasses import replace

    from netsim.estimators.gains import gains_from_matrices

    zero_gain = gains_from_matrices(
        [np.zeros((6, 6))] * 4, scenario.weights, scenario.plant.A, scenario.plant.C
    )
    tight = replace(scenario, divergence_threshold=50.0)
    run = run_trial(tight, "compensated", zero_gain, 1, 400)
    assert run.diverged_at is not None
    k = run.diverged_at
    # the error at the reported step is the first above the threshold
    norms = np.sqrt(run.squared_errors[:k])
    assert np.all(norms <= 50.0)
    assert np.sqrt(run.squared_errors[k]).max() > 50.0
    assert np.all(np.isnan(run.squared_errors[k + 1:]))


# --- the plant drawn up front, the monitor's divergence test --------------------------


class _Scripted:
    """Hosted estimator whose estimates are the true state plus a scripted error."""

    def __init__(self, errors: dict[int, np.ndarray], states: np.ndarray) -> None:
        self.errors = errors
        self.states = states
        self._estimate = np.zeros(states.shape[1])

    def message_arrived(self, sender, sent_step, payload) -> bool:
        return True

    def step(self, k, y):
        self._estimate = self.states[k] + self.errors.get(k, 0.0)
        return self._estimate

    @property
    def estimate(self):
        return self._estimate


def _scripted_run(scenario, errors_by_agent, threshold, steps=12):
    """Run the kernel with scripted errors; the states come from a first run."""
    from operator import itemgetter

    from netsim.models.delays import FixedDelays
    from netsim.models.seeding import stream

    from netsim.kernel import AgentSpec, Simulation

    plant = scenario.plant

    def simulation(estimators):
        agents = [AgentSpec(e, itemgetter(i)) for i, e in enumerate(estimators)]
        return Simulation(plant, agents, FixedDelays(), stream(3, "plant"),
                          divergence_threshold=threshold)

    n_agents = len(errors_by_agent)
    truth = simulation([_Scripted({}, np.zeros((steps + 1, plant.n_states)))
                        for _ in range(n_agents)]).run(steps).states
    estimators = [_Scripted(errors, truth) for errors in errors_by_agent]
    return simulation(estimators).run(steps)


def test_kernel_plant_is_the_step_by_step_recursion_of_its_stream(scenario):
    """x_k = A x_{k-1} + nu_k and y^i_k from stream(seed, 'plant'), drawn step by step."""
    from netsim.models.seeding import stream

    seed = child_sequence(9, "trial", 0)
    run = run_trial(scenario, "compensated", scenario_gains(scenario), seed, STEPS)
    plant = scenario.plant
    rng = stream(seed, "plant")
    x = plant.sample_initial(rng)
    for k in range(STEPS + 1):
        if k:
            x = plant.step(x, rng)
        ys = plant.measure(x, rng)
        np.testing.assert_allclose(run.states[k], x, rtol=1e-12, atol=1e-12)
        for i, y in enumerate(ys):
            np.testing.assert_allclose(run.measurements[i][k], y, rtol=1e-12, atol=1e-12)


def test_steps_after_a_divergence_are_not_reported(scenario):
    """The trajectory is simulated up front, but steps after the stop are NaN."""
    n = scenario.plant.n_states
    run = _scripted_run(scenario, [{5: np.full(n, 100.0)}, {}], threshold=50.0)
    assert run.diverged_at == 5
    assert np.all(np.isfinite(run.states[:6])) and np.all(np.isnan(run.states[6:]))
    assert all(np.all(np.isnan(m[6:])) and np.all(np.isfinite(m[:6]))
               for m in run.measurements)
    assert np.all(np.isnan(run.squared_errors[6:]))
    np.testing.assert_allclose(run.squared_errors[5], [100.0**2 * n, 0.0], rtol=1e-9)


def test_errors_whose_sum_exceeds_the_threshold_are_not_a_divergence(scenario):
    """Each agent's error within the threshold: no divergence, however many agents."""
    n = scenario.plant.n_states
    error = np.zeros(n)
    error[0] = 49.0  # each squared error 2401 <= 2500, the sum over 4 agents is 9604
    run = _scripted_run(scenario, [{k: error for k in range(13)}] * 4, threshold=50.0)
    assert run.diverged_at is None
    np.testing.assert_allclose(run.squared_errors, 49.0**2)


@pytest.mark.parametrize("bad", [np.inf, np.nan])
def test_non_finite_errors_diverge_even_without_a_threshold(scenario, bad):
    n = scenario.plant.n_states
    run = _scripted_run(scenario, [{}, {7: np.full(n, bad)}], threshold=np.inf)
    assert run.diverged_at == 7
    assert run.squared_errors[7, 1] == np.inf and run.squared_errors[7, 0] == 0.0


def test_no_threshold_and_finite_squared_errors_is_no_divergence(scenario):
    """Each agent's squared error is finite; only their sum overflows."""
    n = scenario.plant.n_states
    error = np.full(n, np.sqrt(1.5e308 / n))
    run = _scripted_run(scenario, [{3: error}, {3: error}], threshold=np.inf)
    assert run.diverged_at is None
    assert np.all(np.isfinite(run.squared_errors))


class _Drawn:
    """Hosted estimator reporting drawn estimates: a * x_k + e_k (a in {0, 1})."""

    def __init__(self, estimates: np.ndarray) -> None:
        self.estimates = estimates
        self._estimate = estimates[0]

    def message_arrived(self, sender, sent_step, payload) -> bool:
        return True

    def step(self, k, y):
        self._estimate = self.estimates[k]
        return self._estimate

    @property
    def estimate(self):
        return self._estimate


@settings(max_examples=120, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), log_threshold=st.floats(-12.0, 3.0))
def test_divergence_step_is_the_first_step_an_agent_fails_the_test(
        scenario, seed, log_threshold):
    """The monitor's fast paths (a norm bound, a sum of squares) against the test as
    defined, agent by agent: an error that is not finite, or above both the threshold
    and the round-off floor ROUNDOFF_RELATIVE_ERROR * |x_k|. Estimates are drawn around
    the threshold, some near the state, some far from it, some not finite."""
    from operator import itemgetter

    from netsim.models.delays import FixedDelays
    from netsim.models.seeding import stream

    from netsim.kernel import ROUNDOFF_RELATIVE_ERROR, AgentSpec, Simulation

    plant, steps, n_agents = scenario.plant, 12, 3
    threshold = 10.0**log_threshold
    rng = np.random.default_rng(seed)

    def simulation(estimators):
        agents = [AgentSpec(e, itemgetter(i)) for i, e in enumerate(estimators)]
        return Simulation(plant, agents, FixedDelays(), stream(seed, "plant"),
                          divergence_threshold=threshold)

    n = plant.n_states
    states = simulation([_Drawn(np.zeros((steps + 1, n)))] * n_agents).run(steps).states
    sizes = threshold * 10.0 ** rng.uniform(-3.0, 0.5, (steps + 1, n_agents, 1))
    errors = sizes * rng.normal(size=(steps + 1, n_agents, n)) / np.sqrt(n)
    near = rng.random((steps + 1, n_agents, 1)) < 0.7
    estimates = np.where(near, states[:, None, :], 0.0) + errors
    estimates[rng.random((steps + 1, n_agents)) < 0.02] = rng.choice([np.inf, np.nan])
    run = simulation([_Drawn(estimates[:, i]) for i in range(n_agents)]).run(steps)

    last = steps if run.diverged_at is None else run.diverged_at
    for k in range(last + 1):
        x = run.states[k]
        sq = np.sum((run.estimates[k] - x) ** 2, axis=1)
        fails = ~np.isfinite(sq) | ((sq > threshold**2)
                                    & (sq > ROUNDOFF_RELATIVE_ERROR**2 * (x @ x)))
        assert fails.any() == (k == run.diverged_at), (k, sq, threshold**2)
