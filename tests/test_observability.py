"""Tests for models.observability: numerical, local, distributed and structural tests."""

from __future__ import annotations

import json

import networkx as nx
import numpy as np
import pytest
import scipy.linalg
from netsim.models.network import directed_cycle, random_strongly_connected, random_weights
from netsim.models.observability import (
    ObservabilityReport,
    distributed_observability,
    distributed_output_matrix,
    irreducible_blocks,
    is_full_rank,
    is_irreducible,
    is_observable,
    is_output_connected,
    is_self_damped,
    is_self_damped_network,
    is_structurally_distributed_observable,
    is_structurally_full_rank,
    is_structurally_observable,
    kronecker_pattern,
    lemma1_conditions,
    local_observability,
    observability_matrix,
    observability_rank,
    observability_report,
    output_unreachable_states,
    satisfies_lemma1,
    structural_rank,
    unobservable_modes,
)
from netsim.models.scenario import resolve_scenario
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import structural_rank as scipy_structural_rank


def kalman_rank(A, C, tol=1e-9):
    """Independent Kalman rank test (small n only)."""
    n = A.shape[0]
    obs = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(n)])
    return np.linalg.matrix_rank(obs, tol=tol * max(1.0, np.linalg.norm(obs, 2)))


def random_orthogonal(rng, n):
    q, r = np.linalg.qr(rng.standard_normal((n, n)))
    return q * np.sign(np.diag(r))


# -- the built-in LCSYS2022 scenario -------------------------------------------------


@pytest.fixture(scope="module")
def lcsys():
    s = resolve_scenario("lcsys2022-heterogeneous")
    return s.weights, s.plant.A, list(s.plant.C), s.graph


def test_lcsys2022_scenario_properties(lcsys):
    P, A, C, graph = lcsys
    C_all = np.vstack(C)
    # Assumption 1: globally observable, but no single sensor observes the system
    assert is_observable(A, C_all)
    assert not any(is_observable(A, Ci) for Ci in C)
    # Remark 1: not observable in any closed in-neighbourhood, from P or from the graph
    assert local_observability(A, C, P) == [False] * 4
    assert local_observability(A, C, graph) == [False] * 4
    # Lemma 1: distributed observability, numerically and structurally
    assert distributed_observability(P, A, C)
    assert is_structurally_distributed_observable(P, A, C)
    assert satisfies_lemma1(P, A, C)
    assert is_structurally_observable(A, C_all)
    # full-rank, structurally cyclic, self-damped system; self-damped irreducible network
    assert is_full_rank(A) and is_structurally_full_rank(A) and is_self_damped(A)
    assert is_self_damped_network(P) and is_irreducible(P)
    assert irreducible_blocks(A) == [[0, 1], [2, 3], [4], [5]]


def test_lcsys2022_report(lcsys):
    P, A, C, _ = lcsys
    report = observability_report(P, A, C)
    assert isinstance(report, ObservabilityReport)
    assert (report.n_states, report.n_agents, report.n_outputs) == (6, 4, 4)
    assert report.spectral_radius == pytest.approx(1.04)
    assert report.observable and report.kalman_rank == 6 and report.unobservable_modes == ()
    assert report.sensor_observable == (False,) * 4
    assert report.locally_observable == (False,) * 4
    assert report.distributed_observable and report.structurally_distributed_observable
    assert report.structurally_observable and report.structural_rank_AC == 6
    assert report.full_rank and report.structurally_full_rank and report.self_damped
    assert report.network_self_damped and report.network_irreducible
    assert report.lemma1_satisfied
    assert len(report.irreducible_blocks) == 4
    assert report.output_unreachable_states == ()
    with pytest.raises(AttributeError):
        report.observable = False  # frozen
    data = json.loads(json.dumps(report.to_dict()))
    assert data["irreducible_blocks"] == [[0, 1], [2, 3], [4], [5]]
    assert data["locally_observable"] == [False] * 4


def test_report_serialises_unobservable_modes():
    A = np.diag([0.5, 2.0])
    report = observability_report(np.eye(1), A, [np.array([[1.0, 0.0]])])
    assert not report.observable and report.kalman_rank == 1
    assert report.unobservable_modes == pytest.approx((2.0 + 0j,))
    assert report.output_unreachable_states == (1,)
    assert json.loads(json.dumps(report.to_dict()))["unobservable_modes"] == [[2.0, 0.0]]


# -- numerical observability ----------------------------------------------------------


def test_observability_matrix_layout():
    rng = np.random.default_rng(0)
    A, C = rng.standard_normal((3, 3)), rng.standard_normal((2, 3))
    obs = observability_matrix(A, C)
    assert obs.shape == (6, 3)
    np.testing.assert_allclose(obs[4:], C @ A @ A)
    assert observability_matrix(A, C[0]).shape == (3, 3)  # 1-D C is one row


def test_pbh_and_kalman_agree_on_random_systems():
    """Generic random pairs are observable; pairs built with an unobservable subspace
    (Kalman decomposition in a random orthogonal basis) are not. Both tests agree."""
    rng = np.random.default_rng(42)
    verdicts = {True: 0, False: 0}
    for trial in range(300):
        n = int(rng.integers(2, 6))
        m = int(rng.integers(1, 3))
        A = rng.standard_normal((n, n))
        C = rng.standard_normal((m, n))
        if trial % 2:
            r = int(rng.integers(1, n))  # dimension of the observable part
            A[:r, r:] = 0.0  # unobservable states do not drive observable ones
            C[:, r:] = 0.0
            T = random_orthogonal(rng, n)
            A, C = T.T @ A @ T, C @ T
        pbh = is_observable(A, C)
        assert pbh == (kalman_rank(A, C) == n) == (observability_rank(A, C) == n)
        assert pbh == (not trial % 2)
        verdicts[pbh] += 1
    assert verdicts[True] == verdicts[False] == 150


def test_block_with_unmeasured_block_is_unobservable():
    rng = np.random.default_rng(1)
    A1, A2 = rng.standard_normal((3, 3)), rng.standard_normal((2, 2))
    A = scipy.linalg.block_diag(A1, A2)
    C = np.hstack([rng.standard_normal((1, 3)), np.zeros((1, 2))])
    assert not is_observable(A, C)
    modes = sorted(unobservable_modes(A, C), key=lambda z: (z.real, z.imag))
    expected = sorted(np.linalg.eigvals(A2), key=lambda z: (z.real, z.imag))
    np.testing.assert_allclose(modes, expected, atol=1e-10)
    # measuring the second block too restores observability
    C2 = np.vstack([C, np.hstack([np.zeros((1, 3)), rng.standard_normal((1, 2))])])
    assert is_observable(A, C2)
    # hidden in a rotated basis it is still detected
    T = random_orthogonal(rng, 5)
    assert not is_observable(T.T @ A @ T, C @ T)


def test_repeated_and_defective_eigenvalues():
    # geometric multiplicity 2 with one output: never observable
    assert not is_observable(np.eye(2), [[1.0, 1.0]])
    assert is_observable(np.eye(2), np.eye(2))
    # Jordan block x1+ = x1 + x2, x2+ = x2: measuring x1 sees x2, measuring x2 does not
    J = np.array([[1.0, 1.0], [0.0, 1.0]])
    assert is_observable(J, [[1.0, 0.0]])
    assert not is_observable(J, [[0.0, 1.0]])
    # a 4 x 4 Jordan block measured at its head, in a rotated basis
    J4 = np.eye(4) * 0.7 + np.eye(4, k=1)
    T = random_orthogonal(np.random.default_rng(2), 4)
    assert is_observable(T.T @ J4 @ T, np.eye(4)[[0]] @ T)
    assert not is_observable(T.T @ J4 @ T, np.eye(4)[[3]] @ T)


def test_scale_invariance():
    rng = np.random.default_rng(3)
    A, C = rng.standard_normal((4, 4)), rng.standard_normal((1, 4))
    assert is_observable(A, C)
    for a, c in [(1e6, 1e-6), (1e-6, 1e6), (1e-9, 1.0)]:
        assert is_observable(a * A, c * C)
    A[:2, 2:] = 0.0
    C[:, 2:] = 0.0
    for a, c in [(1.0, 1.0), (1e6, 1e-6), (1e-6, 1e6)]:
        assert not is_observable(a * A, c * C)


def test_pbh_is_robust_where_the_kalman_matrix_is_ill_conditioned():
    """Distinct eigenvalues, all measured: observable. The observability matrix is a
    20 x 20 Vandermonde matrix whose numerical rank collapses; PBH is unaffected."""
    n = 20
    A = np.diag(np.linspace(0.1, 0.9, n))
    C = np.ones((1, n))
    T = random_orthogonal(np.random.default_rng(4), n)
    assert is_observable(A, C) and is_observable(T.T @ A @ T, C @ T)
    assert observability_rank(A, C) < n  # why the Kalman rank is not the decision
    C[0, 7] = 0.0
    assert unobservable_modes(A, C) == pytest.approx([A[7, 7]])


def test_local_observability_from_graph_and_weights_agree():
    """Decoupled states with distinct eigenvalues, sensor i measures state i: an agent
    is locally observable iff its closed in-neighbourhood covers every state."""
    rng = np.random.default_rng(5)
    N = 4
    A = np.diag(rng.uniform(0.5, 1.5, N))
    C = [np.eye(N)[[i]] for i in range(N)]
    graph = directed_cycle(N)
    P = random_weights(graph, seed=5)
    assert local_observability(A, C, graph) == local_observability(A, C, P) == [False] * N
    star = nx.DiGraph([(j, 0) for j in range(1, N)])  # agent 0 hears everyone
    P_star = np.eye(N)
    P_star[0] = 1.0 / N
    assert local_observability(A, C, star) == [True, False, False, False]
    assert local_observability(A, C, P_star) == [True, False, False, False]
    # a generic dense A is observable from any single output
    assert local_observability(rng.standard_normal((N, N)), C, graph) == [True] * N


def test_distributed_output_matrix():
    C = [np.array([[1.0, 2.0]]), np.array([[0.0, 1.0], [3.0, 0.0]])]
    D = distributed_output_matrix(C)
    assert D.shape == (4, 4)
    np.testing.assert_array_equal(D[:2, :2], C[0].T @ C[0])
    np.testing.assert_array_equal(D[2:, 2:], C[1].T @ C[1])
    np.testing.assert_array_equal(D[:2, 2:], 0.0)


def test_bad_shapes_raise():
    A = np.eye(3)
    with pytest.raises(ValueError, match="shape"):
        is_observable(A, np.ones((1, 2)))
    with pytest.raises(ValueError, match="square"):
        is_observable(np.ones((2, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="C_list"):
        distributed_observability(np.eye(2), A, [np.ones((1, 3))])
    with pytest.raises(ValueError, match="non-finite"):
        is_observable(A, [[np.nan, 0.0, 0.0]])


# -- structural observability ---------------------------------------------------------


def test_structural_rank_is_generic_numerical_rank():
    rng = np.random.default_rng(6)
    for _ in range(300):
        p, q = (int(k) for k in rng.integers(1, 9, size=2))
        pattern = rng.random((p, q)) < rng.uniform(0.05, 0.7)
        values = pattern * rng.standard_normal((p, q))
        srank = structural_rank(pattern)
        assert srank == np.linalg.matrix_rank(values)
        assert srank == scipy_structural_rank(csr_matrix(pattern.astype(float)))
        assert srank == structural_rank(values)  # numerical input uses its pattern


def test_structural_rank_known_patterns():
    assert structural_rank(np.eye(4, dtype=bool)) == 4
    assert structural_rank(np.zeros((3, 5), dtype=bool)) == 0
    # full row 0 plus column 0: only two independent entries can be matched
    pat = np.zeros((4, 4), dtype=bool)
    pat[0, :] = pat[:, 0] = True
    assert structural_rank(pat) == 2


def test_structural_says_yes_where_numerical_observability_holds():
    # chain 2 -> 1 -> 0 with self-loops, extra link 0 -> 2; state 0 measured
    pattern = np.array([[1, 1, 0], [0, 1, 1], [1, 0, 1]], dtype=bool)
    C = np.array([[1.0, 0.0, 0.0]])
    assert is_structurally_observable(pattern, C)
    rng = np.random.default_rng(7)
    for _ in range(20):
        A = pattern * rng.standard_normal((3, 3))
        assert is_observable(A, C)
        assert is_structurally_observable(A, C)


def test_structural_catches_a_state_that_reaches_no_output():
    # state 2 only drives itself; outputs see states 0 and 1 (which feed each other)
    pattern = np.array([[1, 1, 0], [1, 1, 0], [0, 0, 1]], dtype=bool)
    C = np.array([[1.0, 0.0, 0.0]])
    assert not is_output_connected(pattern, C)
    assert output_unreachable_states(pattern, C) == [2]
    assert structural_rank(np.vstack([pattern, C != 0])) == 3  # no contraction
    assert not is_structurally_observable(pattern, C)
    A = pattern * np.random.default_rng(8).standard_normal((3, 3))
    assert not is_observable(A, C)


def test_structural_catches_a_contraction():
    # states 1 and 2 both feed the measured state 0 and nothing else
    pattern = np.array([[0, 1, 1], [0, 0, 0], [0, 0, 0]], dtype=bool)
    C = np.array([[1.0, 0.0, 0.0]])
    assert is_output_connected(pattern, C)
    assert structural_rank(np.vstack([pattern, C != 0])) == 2
    assert not is_structurally_observable(pattern, C)
    rng = np.random.default_rng(9)
    for _ in range(10):
        assert not is_observable(pattern * rng.standard_normal((3, 3)), C)
    # measuring state 1 as well removes the contraction
    assert is_structurally_observable(pattern, np.eye(3)[:2])


def test_structural_and_generic_numerical_observability_agree():
    """With independent random values, numerical observability holds iff the pattern
    pair is structurally observable (with probability one)."""
    rng = np.random.default_rng(10)
    verdicts = {True: 0, False: 0}
    for _ in range(400):
        n, m = int(rng.integers(1, 7)), int(rng.integers(1, 3))
        A_pat = rng.random((n, n)) < rng.uniform(0.05, 0.6)
        C_pat = rng.random((m, n)) < rng.uniform(0.05, 0.5)
        A = A_pat * rng.standard_normal((n, n))
        C = C_pat * rng.standard_normal((m, n))
        verdict = is_structurally_observable(A_pat, C_pat)
        assert verdict == is_observable(A, C)
        verdicts[verdict] += 1
    assert min(verdicts.values()) > 50


def test_full_rank_self_damped_and_blocks():
    assert is_full_rank(np.array([[0.0, 1.0], [1.0, 0.0]]))
    assert not is_full_rank(np.array([[1.0, 2.0], [2.0, 4.0]]))
    # structurally full rank (a cycle cover) but not self-damped
    perm = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=bool)
    assert is_structurally_full_rank(perm) and not is_self_damped(perm)
    assert not is_structurally_full_rank(np.array([[1, 1], [0, 0]], dtype=bool))
    assert is_self_damped(np.diag([0.1, -2.0, 3.0]))
    assert not is_self_damped_network(np.array([[0.0, 1.0], [1.0, 0.0]]))
    assert irreducible_blocks(perm) == [[0, 1, 2]]
    # block {2} drives {0, 1}; {3} is isolated: topological order then smallest index
    A = np.array([[1, 1, 1, 0], [1, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    assert irreducible_blocks(A) == [[2], [0, 1], [3]]
    assert not is_irreducible(A) and is_irreducible(perm)


def test_kronecker_pattern():
    P = np.array([[0.5, 0.5], [0.0, 1.0]])
    A = np.array([[1.0, 0.0], [2.0, 3.0]])
    np.testing.assert_array_equal(kronecker_pattern(P, A), np.kron(P, A) != 0)


def test_lemma1_sufficient_conditions_give_distributed_observability():
    """Random instances satisfying Lemma 1 (structurally full-rank A, (A, C)
    structurally observable, irreducible self-damped P) are distributed observable,
    structurally and for random values (LCSYS2022 footnote 3)."""
    rng = np.random.default_rng(11)
    checked = 0
    for trial in range(60):
        n, N = int(rng.integers(2, 6)), int(rng.integers(2, 6))
        A_pat = rng.random((n, n)) < 0.3
        A_pat[np.arange(n), rng.permutation(n)] = True  # cycle cover: structurally cyclic
        A = A_pat * rng.uniform(0.2, 1.0, (n, n)) * rng.choice([-1.0, 1.0], (n, n))
        C = []
        for block in irreducible_blocks(A):  # one output in every irreducible block
            C.append(np.eye(n)[[int(rng.choice(block))]])
        while len(C) < N:
            C.append(np.eye(n)[[int(rng.integers(n))]])
        C = C[:N]  # may drop blocks: then Lemma 1 may fail, which is checked below
        P = random_weights(random_strongly_connected(N, 0.2, seed=trial), seed=trial)
        conditions = lemma1_conditions(P, A, C)
        assert conditions["A_structurally_full_rank"]
        assert conditions["P_irreducible"] and conditions["P_self_damped"]
        assert conditions["AC_structurally_observable"] == is_observable(A, np.vstack(C))
        if not all(conditions.values()):
            continue
        checked += 1
        assert is_structurally_distributed_observable(P, A, C)
        assert distributed_observability(P, A, C)
    assert checked > 20


def test_structural_distributed_is_necessary():
    """A False structural verdict on the Kronecker pattern means no values work: the
    numerical test never says yes when the structural one says no."""
    rng = np.random.default_rng(12)
    for _ in range(300):
        n, N = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        A = (rng.random((n, n)) < 0.4) * rng.standard_normal((n, n))
        W = (rng.random((N, N)) < 0.4) * rng.uniform(0.1, 1.0, (N, N))
        W[np.arange(N), np.arange(N)] += rng.random(N) < 0.5
        P = W / np.where(W.sum(axis=1, keepdims=True) > 0, W.sum(axis=1, keepdims=True), 1)
        C = [(rng.random((1, n)) < 0.4) * rng.standard_normal((1, n)) for _ in range(N)]
        if distributed_observability(P, A, C):
            assert is_structurally_distributed_observable(P, A, C)


def test_network_without_self_loops_breaks_lemma1():
    """Why P must be self-damped: two 2-cycles (P without self-links, A a swap) give a
    Kronecker product of two disjoint 2-cycles; the sensors' outputs sit in one of
    them, so the other is unobservable although (A, C) is observable and P is
    irreducible."""
    P = np.array([[0.0, 1.0], [1.0, 0.0]])
    A = np.array([[0.0, 1.0], [1.0, 0.0]])
    C = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])]
    assert is_observable(A, np.vstack(C)) and is_full_rank(A) and is_irreducible(P)
    assert not lemma1_conditions(P, A, C)["P_self_damped"]
    assert not is_structurally_distributed_observable(P, A, C)
    assert not distributed_observability(P, A, C)
    # adding self-loops (a lazy version of P) restores distributed observability
    P_lazy = 0.5 * (np.eye(2) + P)
    assert satisfies_lemma1(P_lazy, A, C)
    assert is_structurally_distributed_observable(P_lazy, A, C)
    assert distributed_observability(P_lazy, A, C)


def test_distributed_uses_output_pattern_not_gram_pattern():
    """C_i^T C_i of a single dense row has a full pattern but rank one; the structural
    test must not count it as n independent outputs."""
    P = np.array([[1.0]])
    A = np.zeros((2, 2))
    C = [np.array([[1.0, 1.0]])]
    assert not distributed_observability(P, A, C)
    assert not is_structurally_distributed_observable(P, A, C)
    assert structural_rank(distributed_output_matrix(C)) == 2  # the over-count avoided


# -- the screened PBH test above 60 states (moved here from estimators.gains) --------


def test_screened_pbh_above_60_states_agrees_with_the_exact_test(monkeypatch):
    """A 72-state diagonal pair with known unobservable modes: the eigenvalue screening
    used above 60 states finds exactly the modes the per-eigenvalue SVD test finds."""
    import netsim.models.observability as obs

    rng = np.random.default_rng(7)
    n = 72
    lams = np.linspace(0.05, 1.5, n)
    lams[[10, 11]] = 0.3  # a repeated eigenvalue: a cluster with a 2-D eigenspace
    lams[[20, 21]] = 0.9  # another one
    hidden = [3, 40, 71]  # states nobody measures
    C = rng.standard_normal((4, n))
    C[:, hidden] = 0.0
    C[:, 11] = 0.0  # only state 10 of the 0.3-eigenspace is seen: 0.3 is unobservable
    T = random_orthogonal(rng, n)
    A, CT = T.T @ np.diag(lams) @ T, C @ T
    want = sorted([*lams[hidden], 0.3])  # 0.9 is seen in both directions: observable
    screened = unobservable_modes(A, CT, distinct=True)
    assert sorted(z.real for z in screened) == pytest.approx(want, abs=1e-9)
    monkeypatch.setattr(obs, "_PBH_SVD_MAX_STATES", 10**6)  # force the exact test
    exact = unobservable_modes(A, CT, distinct=True)
    assert sorted(z.real for z in exact) == pytest.approx(want, abs=1e-9)
    assert is_observable(A, np.vstack([CT, np.eye(n)[[*hidden, 11]] @ T]))
