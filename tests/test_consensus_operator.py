"""The one-product update of the consensus estimators is the papers' two-stage update.

:mod:`netsim.estimators.consensus` computes the update of step k >= 1 as one product with a
stacked operator [G_own, G_j..., L] cached per pattern of lags. :class:`Reference`
below is written directly from the equations instead -- first the prior, then the
innovation, one A^r product per neighbour:

* compensated (LCSYS2022 eqs. 4-5): x_{k|k-1} = p_ii A x_{k-1} + sum_j p_ij A^(k - s_j)
  x_j(s_j), with s_j the largest time-stamp received from j;
* uncompensated (delay-tolerant paper eqs. 6-7): A in place of A^(k - s_j), with the
  most recently *arrived* message from j (no time-stamp check);
* block (LCSYS2022 eqs. 15-16): updates only at k % (tau + 1) == 0, own term
  A^(tau+1) x_block, neighbours A^(k - s_j); between block steps A^(k - k_m) x_block;

a neighbour from which nothing has arrived is replaced by agent i's own term; step 0
is the innovation from the prior; then x_{k|k} = x_{k|k-1} + L (y_k - C x_{k|k-1}).
Both are fed the same random arrivals (random senders, out-of-order and stale
time-stamps, neighbours silent early on or for long stretches, so that lags keep
exceeding any seen before) and measurements, with the operator cache at its default
size, disabled, and tiny.
"""

from __future__ import annotations

import netsim.estimators.consensus
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from netsim.estimators.consensus import (
    NO_MESSAGE,
    BlockUpdateEstimator,
    CompensatingEstimator,
    ConsensusParameters,
    UncompensatedEstimator,
)

STEPS = 60
RTOL = 1e-10
FAMILIES = ("compensated", "uncompensated", "block")


def _norm(a: np.ndarray) -> float:
    return float(np.linalg.norm(a, 2)) if a.ndim == 2 else float(np.linalg.norm(a))


class Reference:
    """Agent i's update rule, two-stage, straight from the equations.

    Besides the estimate it keeps ``scale``, the size of the round-off the estimate
    may carry: the norms of the terms that made it (``local``), plus those of the
    previous own estimate times the norm of the map it went through, (I - L C) p A^e
    (one step back only, so the scale does not compound over the run). Two correct
    implementations differ by a few ulps of it, even where the estimate cancels to
    near zero or is predicted from a block estimate that did.
    """

    def __init__(self, family: str, agent: int, weights, A, C, L, prior, tau: int = 0):
        self.family = family
        self.agent = agent
        self.weights = weights
        self.A, self.C, self.L = A, C, L
        self.period = tau + 1
        self.neighbours = [j for j in range(len(weights)) if j != agent and weights[j] != 0]
        self.stored: dict[int, tuple[int, np.ndarray]] = {}
        self.estimate = np.array(prior, dtype=float)
        self.block_estimate = self.estimate
        self.block_step = 0
        self.last_delays: dict[int, int] = {}
        self.local = self.block_local = self.scale = _norm(self.estimate)
        self._closed = np.eye(A.shape[0]) - L @ C

    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool:
        if sender not in self.neighbours:
            return True  # p_ij = 0: accepted, no effect (the estimator's convention)
        if self.family != "uncompensated":
            current = self.stored.get(sender)
            if current is not None and sent_step <= current[0]:
                return False  # freshest rule: not newer than the stored one
        self.stored[sender] = (sent_step, payload)
        return True

    def innovate(self, prior: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Eq. (5): x_{k|k} = x_{k|k-1} + L (y - C x_{k|k-1})."""
        return prior + self.L @ (y - self.C @ prior)

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        A, w, i = self.A, self.weights, self.agent
        if k == 0:
            self.estimate = self.innovate(self.estimate, y)
            self.block_estimate, self.block_step = self.estimate, 0
            self.local = self.block_local = self.scale = self._innovation_scale(
                self.local, y)
            self.last_delays = {j: NO_MESSAGE for j in self.neighbours}
            return self.estimate
        if self.family == "block" and k % self.period != 0:
            # between block steps: the open-loop prediction A^(k - k_m) x_block
            power = np.linalg.matrix_power(A, k - self.block_step)
            self.estimate = power @ self.block_estimate
            self.scale = _norm(power) * max(self.block_local, _norm(self.block_estimate))
            self.last_delays = {}
            return self.estimate
        # eq. (4) / (6) / (15): the prior
        if self.family == "block":
            own_power = np.linalg.matrix_power(A, self.period)
            own_vector, own_local = self.block_estimate, self.block_local
        else:
            own_power, own_vector, own_local = A, self.estimate, self.local
        own = own_power @ own_vector
        prior = w[i] * own
        own_weight = w[i]  # p_ii plus the weights of silent neighbours
        terms = 0.0
        delays = {}
        for j in self.neighbours:
            if j not in self.stored:  # nothing arrived: i's own term instead
                prior = prior + w[j] * own
                own_weight += w[j]
                delays[j] = NO_MESSAGE
                continue
            s, x_j = self.stored[j]
            assert s < k
            power = A if self.family == "uncompensated" else np.linalg.matrix_power(A, k - s)
            prior = prior + w[j] * (power @ x_j)
            terms += w[j] * _norm(power) * _norm(x_j)
            delays[j] = k - 1 - s
        # eq. (5): the innovation
        self.estimate = self.innovate(prior, y)
        terms += own_weight * _norm(own_power) * _norm(own_vector)
        self.local = self._innovation_scale(terms, y)
        self.scale = self.local + _norm(self._closed @ (own_weight * own_power)) * max(
            own_local, _norm(own_vector))
        if self.family == "block":
            self.block_estimate, self.block_step = self.estimate, k
            self.block_local = self.local
        self.last_delays = delays
        return self.estimate

    def _innovation_scale(self, prior_scale: float, y: np.ndarray) -> float:
        return (1.0 + _norm(self.L @ self.C)) * prior_scale + _norm(self.L) * _norm(y)


def build(family: str, params: ConsensusParameters, tau: int):
    if family == "compensated":
        return CompensatingEstimator(params)
    if family == "uncompensated":
        return UncompensatedEstimator(params)
    return BlockUpdateEstimator(params, tau)


# -- random cases ----------------------------------------------------------------------


def random_system(rng: np.random.Generator, n: int, m: int, n_agents: int, radius: float):
    A = rng.normal(size=(n, n))
    A *= radius / max(np.max(np.abs(np.linalg.eigvals(A))), 1e-12)
    C = rng.normal(size=(m, n))
    L = rng.normal(scale=rng.uniform(0.05, 1.0), size=(n, m))
    weights = rng.uniform(0.05, 1.0, n_agents) * (rng.random(n_agents) < 0.75)
    agent = int(rng.integers(n_agents))
    weights[agent] = rng.uniform(0.05, 1.0)  # p_ii > 0
    weights /= weights.sum()
    prior = rng.normal(size=n)
    return agent, weights, A, C, L, prior


def random_arrivals(rng: np.random.Generator, agent: int, n_agents: int, steps: int):
    """Per step k >= 1, the messages (sender, s < k) delivered before step k's update.

    Each sender has a start step (silent until then), silent stretches, and a mode:
    a fixed delay (a repeating lag pattern, reused operators), random delays (out of
    order, stale), or rare bursts of old messages. Zero-weight agents send too.
    """
    senders = [j for j in range(n_agents) if j != agent]
    plan = {}
    for j in senders:
        start = int(rng.integers(0, steps // 2))
        silent = set()
        for _ in range(int(rng.integers(0, 3))):
            begin = int(rng.integers(start, steps))
            silent.update(range(begin, begin + int(rng.integers(1, 25))))
        plan[j] = (start, silent, rng.choice(["fixed", "random", "bursts"]),
                   int(rng.integers(0, 4)))
    arrivals: list[list[tuple[int, int]]] = [[] for _ in range(steps + 1)]
    for k in range(1, steps + 1):
        for j in senders:
            start, silent, mode, delay = plan[j]
            if k <= start or k in silent:
                continue
            if mode == "fixed":
                if k - 1 - delay >= 0:
                    arrivals[k].append((j, k - 1 - delay))
            elif mode == "random":
                for _ in range(int(rng.integers(0, 3))):
                    lag = int(rng.geometric(0.4)) - 1
                    arrivals[k].append((j, max(0, k - 1 - lag)))
            elif rng.random() < 0.3:
                for _ in range(int(rng.integers(1, 4))):
                    arrivals[k].append((j, int(rng.integers(0, k))))
        order = rng.permutation(len(arrivals[k]))
        arrivals[k] = [arrivals[k][index] for index in order]
    return arrivals


def check_agreement(seed: int, family: str, n: int, m: int, n_agents: int, tau: int,
                    radius: float, steps: int = STEPS) -> float:
    """Run the estimator and the reference side by side; return the worst error ratio."""
    rng = np.random.default_rng(seed)
    agent, weights, A, C, L, prior = random_system(rng, n, m, n_agents, radius)
    params = ConsensusParameters(agent=agent, weights=weights, A=A, C=C, L=L, prior=prior)
    estimator = build(family, params, tau)
    reference = Reference(family, agent, weights, A, C, L, prior, tau)
    arrivals = random_arrivals(rng, agent, n_agents, steps)
    worst = 0.0
    for k in range(steps + 1):
        for sender, sent_step in arrivals[k]:
            payload = rng.normal(size=n) * rng.choice([1.0, 10.0])
            assert estimator.message_arrived(sender, sent_step, payload.copy()) == \
                reference.message_arrived(sender, sent_step, payload.copy()), (k, sender)
        y = rng.normal(size=m)
        got = estimator.step(k, y.copy())
        want = reference.step(k, y)
        scale = max(float(np.linalg.norm(want)), reference.scale, 1e-300)
        error = float(np.linalg.norm(got - want)) / scale
        assert error <= RTOL, (k, error, got, want)
        assert np.array_equal(estimator.estimate, got)
        assert estimator.last_delays == reference.last_delays, k
        worst = max(worst, error)
    return worst


cases = st.tuples(
    st.integers(0, 2**32 - 1),                      # seed of the rest
    st.sampled_from(FAMILIES),
    st.integers(1, 4),                              # n
    st.integers(1, 3),                              # m_i
    st.integers(1, 5),                              # N (agent i and up to 4 others)
    st.integers(0, 4),                              # tau (block)
    st.sampled_from([0.3, 0.9, 1.0, 1.1, 1.3]),     # rho(A): stable and unstable
)

#: operator cache budgets: the default, none, tiny (a few small operators), small
BUDGETS = [None, 0, 200, 2000]


@pytest.mark.parametrize("budget", BUDGETS)
@settings(max_examples=100, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=cases)
def test_operator_update_equals_the_two_stage_equations(monkeypatch, budget, case):
    if budget is not None:
        monkeypatch.setattr(netsim.estimators.consensus, "OPERATOR_CACHE_BYTES", budget)
    check_agreement(*case)


@pytest.mark.parametrize("budget", BUDGETS)
def test_cache_budget_is_respected_and_both_paths_run(monkeypatch, budget):
    """The budget decides the path: with none, every operator is assembled afresh."""
    if budget is not None:
        monkeypatch.setattr(netsim.estimators.consensus, "OPERATOR_CACHE_BYTES", budget)
    rng = np.random.default_rng(3)
    agent, weights, A, C, L, prior = random_system(rng, 3, 2, 4, 1.1)
    weights = np.full(4, 0.25)
    params = ConsensusParameters(agent=agent, weights=weights, A=A, C=C, L=L, prior=prior)
    estimator = CompensatingEstimator(params)
    reference = Reference("compensated", agent, weights, A, C, L, prior)
    for k in range(40):
        for j in params.neighbours:
            if k >= 1 + j:
                stamp = max(0, k - 1 - (k + j) % 3)  # a repeating lag pattern
                payload = rng.normal(size=3)
                estimator.message_arrived(j, stamp, payload)
                reference.message_arrived(j, stamp, payload)
        y = rng.normal(size=2)
        np.testing.assert_allclose(estimator.step(k, y), reference.step(k, y),
                                   rtol=RTOL, atol=RTOL * reference.scale)
    cached = estimator._operators  # a white-box look: which path ran
    used = sum(operator.nbytes for operator in cached.values())
    if budget is None:
        # all three neighbours heard from: three lag patterns (lags 1, 2, 3 in turn)
        assert len([key for key in cached if NO_MESSAGE not in key]) == 3
        assert used <= netsim.estimators.consensus.OPERATOR_CACHE_BYTES
    elif budget == 0:
        assert not cached
    else:
        assert 0 < used <= budget


def test_reference_follows_the_papers_on_a_hand_computed_case():
    """Guard for the guard: the reference on a scalar case computed by hand."""
    weights = np.array([0.5, 0.3, 0.2])
    A, C, L = np.array([[2.0]]), np.array([[1.0]]), np.array([[0.5]])
    ref = Reference("compensated", 0, weights, A, C, L, np.array([1.0]))
    assert ref.step(0, np.array([3.0])) == pytest.approx([2.0])  # 1 + 0.5 (3 - 1)
    assert ref.last_delays == {1: -1, 2: -1}
    ref.message_arrived(1, 0, np.array([1.0]))
    ref.message_arrived(1, 0, np.array([5.0]))  # as old as the stored one: discarded
    # prior = 0.5 * 2 * 2 + 0.3 * 2^(2 - 0) * 1 + 0.2 * 2 * 2 (silent: own term)
    prior = 2.0 + 1.2 + 0.8
    assert ref.step(2, np.array([0.0])) == pytest.approx([prior - 0.5 * prior])
    assert ref.last_delays == {1: 1, 2: -1}
    unc = Reference("uncompensated", 0, weights, A, C, L, np.array([1.0]))
    unc.step(0, np.array([1.0]))
    unc.message_arrived(1, 3, np.array([1.0]))
    unc.message_arrived(1, 0, np.array([5.0]))  # arrived last: used, stamp ignored
    prior = 0.5 * 2 + 0.3 * 2 * 5 + 0.2 * 2
    assert unc.step(5, np.array([0.0])) == pytest.approx([0.5 * prior])
    assert unc.last_delays == {1: 4, 2: -1}
    block = Reference("block", 0, weights, A, C, L, np.array([1.0]), tau=1)
    block.step(0, np.array([1.0]))  # x_block = 1
    assert block.step(1, np.array([9.0])) == pytest.approx([2.0]) and block.last_delays == {}
    block.message_arrived(2, 0, np.array([1.0]))
    # own 2^2 * 1, neighbour 1 silent (own term), neighbour 2 2^(2 - 0) * 1
    prior = 0.5 * 4 + 0.3 * 4 + 0.2 * 4
    assert block.step(2, np.array([0.0])) == pytest.approx([0.5 * prior])
    assert block.last_delays == {1: -1, 2: 1}


@pytest.mark.parametrize("family", ["compensated", "uncompensated", "block"])
def test_a_message_used_at_its_own_step_is_an_error(family):
    # a host that delivers a message stamped k before the update of step k is broken;
    # the estimator says so instead of using a lag of 0 (also when its operator for
    # the same lags is cached)
    params = netsim.estimators.consensus.ConsensusParameters(
        0, np.array([0.5, 0.5]), np.eye(2), np.ones((1, 2)), np.zeros((2, 1)), np.zeros(2))
    cls = {"compensated": netsim.estimators.consensus.CompensatingEstimator,
           "uncompensated": netsim.estimators.consensus.UncompensatedEstimator}.get(family)
    est = cls(params) if cls else netsim.estimators.consensus.BlockUpdateEstimator(params, tau=0)
    est.step(0, np.zeros(1))
    est.message_arrived(1, 0, np.ones(2))
    est.step(1, np.zeros(1))  # lag 1: fine, and its operator is now cached
    est.message_arrived(1, 2, np.ones(2))
    with pytest.raises(RuntimeError, match="stamped 2 used at step 2"):
        est.step(2, np.zeros(1))


# -- the input vector: float64 bytes, or numpy.concatenate for anything else -----------


def _program(seed: int, family: str):
    """A random run with integer-valued payloads and measurements (exact in any dtype)."""
    rng = np.random.default_rng(seed)
    agent, weights, A, C, L, prior = random_system(rng, 3, 2, 4, 1.1)
    params = ConsensusParameters(agent=agent, weights=weights, A=A, C=C, L=L, prior=prior)
    arrivals = random_arrivals(rng, agent, 4, 40)
    payloads = [[rng.integers(-9, 10, size=3) for _ in step] for step in arrivals]
    ys = [rng.integers(-9, 10, size=2) for _ in arrivals]
    return params, arrivals, payloads, ys


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("layout", ["int64", "float32", "list", "strided", "big-endian"])
def test_inputs_of_any_real_dtype_and_layout_give_the_same_estimates(family, layout):
    """The update reads float64 payloads and measurements as raw bytes; anything else
    (other dtypes, lists, non-contiguous views) must give the same numbers, bit for bit,
    as float64 arrays holding the same values. An int64 read as float64 bytes would
    not."""

    def convert(values: np.ndarray):
        if layout == "list":
            return values.tolist()
        if layout == "strided":  # every other element of a longer float64 array
            wide = np.zeros(2 * len(values))
            wide[::2] = values
            return wide[::2]
        dtype = {"int64": np.int64, "float32": np.float32, "big-endian": ">f8"}[layout]
        return values.astype(dtype)

    for seed in range(5):
        params, arrivals, payloads, ys = _program(seed, family)
        plain, other = build(family, params, 2), build(family, params, 2)
        for k, (step_arrivals, step_payloads, y) in enumerate(
                zip(arrivals, payloads, ys, strict=True)):
            for (sender, stamp), payload in zip(step_arrivals, step_payloads, strict=True):
                plain.message_arrived(sender, stamp, payload.astype(float))
                other.message_arrived(sender, stamp, convert(payload))
            want = plain.step(k, y.astype(float))
            got = other.step(k, convert(y))
            assert got.dtype == np.float64 and np.array_equal(got, want), (seed, k)


def test_a_complex_payload_is_not_read_as_float64_bytes():
    """A complex payload keeps its imaginary part (numpy.concatenate), as the equations
    say, instead of being cut to float64."""
    weights = np.array([0.5, 0.5])
    A, C, L = np.array([[2.0]]), np.array([[1.0]]), np.array([[0.5]])
    params = ConsensusParameters(0, weights, A, C, L, np.array([1.0]))
    estimator = CompensatingEstimator(params)
    reference = Reference("compensated", 0, weights, A, C, L, np.array([1.0]))
    for k in range(4):
        if k:
            payload = np.array([1.0 + 2.0j * k])
            estimator.message_arrived(1, k - 1, payload)
            reference.message_arrived(1, k - 1, payload)
        y = np.array([float(k)])
        np.testing.assert_allclose(estimator.step(k, y), reference.step(k, y), rtol=1e-12)
    assert np.iscomplexobj(estimator.estimate) and estimator.estimate.imag[0] != 0.0


@pytest.mark.parametrize("family", FAMILIES)
def test_an_estimate_written_into_out_is_the_same_estimate(family):
    """step(k, y, out) puts the estimate into out, bit for bit the one step(k, y)
    returns, keeps out as its estimate, and never writes to an earlier row again."""
    for seed in range(5):
        params, arrivals, payloads, ys = _program(seed, family)
        plain, writing = build(family, params, 2), build(family, params, 2)
        rows = np.full((len(arrivals), params.A.shape[0]), np.nan)
        wanted = []
        for k, (step_arrivals, step_payloads, y) in enumerate(
                zip(arrivals, payloads, ys, strict=True)):
            for (sender, stamp), payload in zip(step_arrivals, step_payloads, strict=True):
                plain.message_arrived(sender, stamp, payload.astype(float))
                writing.message_arrived(sender, stamp, payload.astype(float))
            wanted.append(plain.step(k, y.astype(float)).copy())
            out = rows[k]
            got = writing.step(k, y.astype(float), out)
            assert got is out and writing.estimate is out, (seed, k)
            assert np.array_equal(out, wanted[-1]), (seed, k)
        assert np.array_equal(rows, np.array(wanted)), seed


def test_a_complex_estimate_leaves_out_alone():
    weights = np.array([0.5, 0.5])
    params = ConsensusParameters(0, weights, np.array([[2.0]]), np.array([[1.0]]),
                                 np.array([[0.5]]), np.array([1.0]))
    estimator = CompensatingEstimator(params)
    estimator.step(0, np.array([0.0]), np.zeros(1))
    estimator.message_arrived(1, 0, np.array([1.0 + 1.0j]))
    out = np.zeros(1)
    got = estimator.step(1, np.array([0.0]), out)
    assert np.iscomplexobj(got) and got is not out and out[0] == 0.0
