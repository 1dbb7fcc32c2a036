"""Plant, network, delays, seeding and the built-in LCSYS2022 scenario."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
import scipy.linalg
import scipy.stats
from helpers import lcsys
from hypothesis import given, settings
from hypothesis import strategies as st
from netsim.estimators.kalman import CentralizedKalmanFilter
from netsim.models.delays import (
    BATCH_SIZE,
    AsynchronousRandomDelays,
    BatchedDraws,
    SynchronousRandomDelays,
    heterogeneous_delays,
    latency_to_steps,
)
from netsim.models.network import (
    check_consensus_matrix,
    directed_cycle,
    geometric,
    lazy_metropolis_weights,
    random_strongly_connected,
    random_weights,
    uniform_weights,
)
from netsim.models.plant import LinearPlant
from netsim.models.seeding import child_sequence, stream

from netsim.runner import run_trial


def _obs_rank(A, C):
    n = A.shape[0]
    blocks, M = [], C
    for _ in range(n):
        blocks.append(M)
        M = M @ A
    return np.linalg.matrix_rank(np.vstack(blocks), tol=1e-9)


# -- the built-in LCSYS2022 scenario: every property the paper states -----------


def test_lcsys2022_plant_has_the_papers_properties():
    s = lcsys()
    A, C = s.plant.A, s.plant.C
    assert A.shape == (6, 6) and s.n_agents == 4
    assert abs(np.max(np.abs(np.linalg.eigvals(A))) - 1.04) < 1e-12  # unstable, rho = 1.04
    assert abs(np.linalg.det(A)) > 1e-6  # full rank
    # structurally cyclic: the sparsity pattern has a perfect matching (cycle cover)
    pattern = nx.Graph()
    rows = [("r", i) for i in range(6)]
    pattern.add_nodes_from(rows)
    pattern.add_edges_from((("r", i), ("c", j)) for i, j in zip(*np.nonzero(A), strict=True))
    matching = nx.bipartite.maximum_matching(pattern, top_nodes=rows)
    assert len(matching) // 2 == 6
    assert np.all(np.diag(A) != 0)  # self-damped
    # 4 irreducible blocks = strongly connected components of the system digraph
    system = nx.DiGraph()
    system.add_nodes_from(range(6))
    system.add_edges_from((j, i) for i, j in zip(*np.nonzero(A), strict=True) if i != j)
    blocks = list(nx.strongly_connected_components(system))
    assert len(blocks) == 4
    # one scalar output per sensor, each from a different irreducible block
    measured = []
    for Ci in C:
        assert Ci.shape == (1, 6)
        (state,) = np.flatnonzero(Ci[0])
        measured.append(next(k for k, b in enumerate(blocks) if state in b))
    assert sorted(measured) == [0, 1, 2, 3]
    # noise variance 0.004
    np.testing.assert_array_equal(s.plant.Q, 0.004 * np.eye(6))
    for Ri in s.plant.R:
        np.testing.assert_array_equal(Ri, [[0.004]])


def test_lcsys2022_network_and_observability():
    s = lcsys()
    A, C, P = s.plant.A, s.plant.C, s.weights
    # directed self-looped cycle 0 -> 1 -> 2 -> 3 -> 0 with row-stochastic weights
    assert sorted(s.graph.edges) == [(0, 1), (1, 2), (2, 3), (3, 0)]
    check_consensus_matrix(P)
    assert np.all(np.diag(P) > 0)
    # globally observable ...
    assert _obs_rank(A, np.vstack(C)) == 6
    # ... but not in the neighbourhood of any sensor (LCSYS2022 Remark 1)
    for i in range(4):
        hood = [i, *s.graph.predecessors(i)]
        assert _obs_rank(A, np.vstack([C[j] for j in hood])) < 6
        assert _obs_rank(A, C[i]) < 6
    # distributed observability of (P kron A, D_C-bar) (Lemma 1)
    DC = scipy.linalg.block_diag(*[Ci.T @ Ci for Ci in C])
    assert _obs_rank(np.kron(P, A), DC) == 24


# -- networks and weights -------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_generators_are_strongly_connected_and_weights_valid(seed):
    for graph in (
        directed_cycle(7),
        random_strongly_connected(12, 0.05, seed),
        geometric(15, seed=seed),
    ):
        assert nx.is_strongly_connected(graph)
        for P in (random_weights(graph, seed), uniform_weights(graph)):
            check_consensus_matrix(P)
            # support of P = self-loops + edges of the graph
            support = {(int(j), int(i)) for i, j in zip(*np.nonzero(P), strict=True) if i != j}
            assert support == set(graph.edges)


def test_uniform_and_lazy_metropolis_formulas():
    graph = random_strongly_connected(8, 0.2, 3)
    U = uniform_weights(graph)
    for i in range(8):
        deg = len(list(graph.predecessors(i)))
        assert U[i, i] == pytest.approx(1.0 / (deg + 1))
    M = lazy_metropolis_weights(graph)
    np.testing.assert_allclose(M, M.T)
    np.testing.assert_allclose(M.sum(axis=0), 1.0)
    np.testing.assert_allclose(M.sum(axis=1), 1.0)
    und = graph.to_undirected()
    for i, j in und.edges:
        assert M[i, j] == pytest.approx(1 / (2 * max(und.degree(i), und.degree(j))))
    assert np.all(np.diag(M) >= 0.5 - 1e-12)  # lazy: at least half on the self-loop


# -- seeding and delay samplers -------------------------------------------------


def test_named_streams_are_reproducible_and_independent():
    a = stream(1, "trial", 0, "plant").standard_normal(5)
    b = stream(1, "trial", 0, "plant").standard_normal(5)
    c = stream(1, "trial", 0, "delays/synchronous").standard_normal(5)
    d = stream(1, "trial", 1, "plant").standard_normal(5)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c) and not np.allclose(a, d)
    # a child sequence is the same whether built in one go or by nesting
    nested = child_sequence(child_sequence(1, "trial", 0), "plant")
    assert np.array_equal(
        np.random.default_rng(nested).standard_normal(5), a
    )


def test_synchronous_delays_are_shared_by_all_links_in_a_step():
    model = SynchronousRandomDelays(5, 3)
    for s in range(200):
        draws = {model.draw(j, i, s) for j, i in [(0, 1), (1, 2), (2, 0)]}
        assert len(draws) == 1
        assert 0 <= draws.pop() <= 5


def test_asynchronous_delays_uniform_and_independent_per_link():
    tau = 4
    model = AsynchronousRandomDelays(tau, 11)
    draws = np.array([model.draw(0, 1, s) for s in range(5000)])
    assert draws.min() == 0 and draws.max() == tau
    counts = np.bincount(draws, minlength=tau + 1)
    assert scipy.stats.chisquare(counts).pvalue > 1e-4
    # a link's stream does not depend on the draws of other links
    other = AsynchronousRandomDelays(tau, 11)
    for s in range(100):
        other.draw(2, 3, s)
    np.testing.assert_array_equal([other.draw(0, 1, s) for s in range(300)], draws[:300])
    # consecutive draws of one link are not correlated
    assert abs(np.corrcoef(draws[:-1], draws[1:])[0, 1]) < 0.06


def test_heterogeneous_delay_realisation_is_fixed_by_its_seed():
    links = [(0, 1), (1, 2), (2, 3), (3, 0)]
    a = heterogeneous_delays(links, 8, 1)
    b = heterogeneous_delays(links, 8, 1)
    assert dict(a.delays) == dict(b.delays)
    assert all(0 <= d <= 8 for d in a.delays.values())
    assert a.time_invariant


def test_heterogeneous_delays_attain_their_bound():
    """A realisation for the bound tau has tau on some link, for every tau and seed."""
    links = [(0, 1), (1, 2), (2, 3), (3, 0)]
    for tau in range(0, 26):
        for seed in (0, 1, 2022):
            d = heterogeneous_delays(links, tau, seed).delays
            assert max(d.values()) == tau and min(d.values()) >= 0


@pytest.mark.parametrize(
    ("latency", "period", "d"), [(0, 1, 0), (0.2, 1, 0), (1, 1, 0), (1.2, 1, 1), (3, 0.5, 5)]
)
def test_latency_to_steps_rule(latency, period, d):
    assert latency_to_steps(latency, period) == d


# -- the centralised Kalman filter reference ------------------------------------


def test_kalman_filter_covariance_converges_to_the_riccati_solution():
    s = lcsys()
    p = s.plant
    C, R = p.C_stacked, p.R_stacked
    kf = CentralizedKalmanFilter(p.A, C, p.Q, R, p.x0_mean, p.x0_cov)
    for k in range(400):
        kf.step(k, np.zeros(C.shape[0]))
    prior = scipy.linalg.solve_discrete_are(p.A.T, C.T, p.Q, R)
    post = prior - prior @ C.T @ np.linalg.solve(C @ prior @ C.T + R, C @ prior)
    np.testing.assert_allclose(kf.covariance, post, rtol=1e-8, atol=1e-12)


def test_kalman_filter_error_matches_its_covariance_monte_carlo():
    s = lcsys()
    p = s.plant
    trials, steps = 400, 30
    sq = np.empty(trials)
    for t in range(trials):
        run = run_trial(s, "centralized-kf", None, child_sequence(99, "trial", t), steps)
        sq[t] = run.squared_errors[steps, 0]
    kf = CentralizedKalmanFilter(p.A, p.C_stacked, p.Q, p.R_stacked, p.x0_mean, p.x0_cov)
    for k in range(steps + 1):
        kf.step(k, np.zeros(4))
    expected = np.trace(kf.covariance)
    stderr = np.sqrt(2 * np.trace(kf.covariance @ kf.covariance) / trials)
    assert abs(sq.mean() - expected) < 4 * stderr


# --- batched draws: every way of asking gives the same sequence -------------------------

_asks = st.lists(st.one_of(st.just(("next", 1)), st.just(("sampler", 1)),
                           st.tuples(st.just("take"), st.integers(0, 3 * BATCH_SIZE + 7))),
                 max_size=12)


@settings(max_examples=150, deadline=None)
@given(_asks, st.sampled_from(["integers", "uniform"]), st.integers(0, 2**32 - 1))
def test_batched_draws_give_one_sequence_however_they_are_asked(asks, kind, seed):
    """next, sampler and take, interleaved, hand out the numbers of one stream drawn
    BATCH_SIZE at a time, in order (the event kernel asks one at a time, the vectorised
    engine many at once)."""
    def fn(g, size):
        return g.integers(0, 5, size=size) if kind == "integers" else g.uniform(size=size)

    draws = BatchedDraws(np.random.default_rng(seed), fn)
    got = []
    for how, count in asks:
        if how == "next":
            got.append(draws.next())
        elif how == "sampler":
            got.append(draws.sampler(17))
        else:
            taken = draws.take(count)
            assert taken.shape == (count,)
            got.extend(taken.tolist())
    # the reference: the same stream, drawn in batches by hand
    rng = np.random.default_rng(seed)
    batches = -(-len(got) // BATCH_SIZE) if got else 0
    expected = np.concatenate([fn(rng, BATCH_SIZE) for _ in range(batches)] or [[]])
    assert got == expected[:len(got)].tolist()
    if got:
        assert all(type(v) is type(expected[:1].tolist()[0]) for v in got)


# --- the plant simulated in one go ------------------------------------------------------


@pytest.mark.parametrize("outputs", [(1, 1, 1), (2, 1, 3), (0, 2)])
def test_plant_simulate_is_the_step_by_step_recursion(outputs):
    """LinearPlant.simulate on T streams equals sample_initial / step / measure called
    step by step on each stream: sensors with one, several (correlated noise) and no
    outputs."""
    rng = np.random.default_rng(11)
    n = 3
    A = rng.normal(size=(n, n)) / 2
    C = tuple(rng.normal(size=(m, n)) for m in outputs)

    def covariance(m):
        F = rng.normal(size=(m, m))
        return F @ F.T + 0.1 * np.eye(m)

    plant = LinearPlant(A=A, C=C, Q=covariance(n), R=tuple(covariance(m) for m in outputs),
                        x0_mean=rng.normal(size=n), x0_cov=covariance(n))
    steps, seeds = 25, [3, 4, 5]
    noise = np.stack([plant.standard_noise(np.random.default_rng(s), steps) for s in seeds],
                     axis=1)
    trajectory = plant.simulate(noise)
    assert trajectory.states.shape == (steps + 1, len(seeds), n)
    assert trajectory.measurements.shape == (steps + 1, len(seeds), sum(outputs))
    for t, seed in enumerate(seeds):
        g = np.random.default_rng(seed)
        x = plant.sample_initial(g)
        for k in range(steps + 1):
            if k:
                x = plant.step(x, g)
            y = plant.measure(x, g)
            np.testing.assert_allclose(trajectory.states[k, t], x, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(trajectory.measurements[k, t],
                                       np.concatenate([*y, np.zeros(0)]),
                                       rtol=1e-12, atol=1e-12)
