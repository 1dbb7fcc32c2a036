"""Tests for estimators.gains: block-diagonal LMI gain design (LCSYS2022 eq. 13)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag

from estimators.gains import (
    GainDesign,
    GainDesignError,
    design_gains,
    gains_from_matrices,
    is_observable,
)

N_AGENTS, N_STATES = 4, 6


def example(seed: int = 0):
    """n=6 unstable structurally-cyclic A (4 irreducible blocks), N=4 sensors on
    a directed self-looped cycle 1->2->3->4->1, one output per sensor."""
    rng = np.random.default_rng(seed)
    n, N = N_STATES, N_AGENTS
    sizes = [2, 2, 1, 1]
    starts = np.cumsum([0, *sizes])
    A = np.zeros((n, n))
    for b, (s, e) in enumerate(zip(starts[:-1], starts[1:], strict=True)):
        A[s:e, s:e] = rng.uniform(0.5, 1.0, (e - s, e - s))
        if b:
            A[s:e, :s] = rng.uniform(-0.3, 0.3, (e - s, s)) * (rng.random((e - s, s)) < 0.5)
    A *= 1.04 / np.max(np.abs(np.linalg.eigvals(A)))
    C = [np.eye(n)[[s]] for s in starts[:-1]]
    W = (np.eye(N) + np.roll(np.eye(N), -1, axis=1)) * rng.uniform(0.2, 1.0, (N, N))
    P = W / W.sum(axis=1, keepdims=True)
    return P, A, C


def rho_from_L(P, A, C, L):
    """rho((I - blockdiag(L_i C_i)) (P kron A)), computed independently."""
    M = np.kron(P, A)
    KD = block_diag(*[Li @ Ci for Li, Ci in zip(L, C, strict=True)])
    return float(np.max(np.abs(np.linalg.eigvals(M - KD @ M))))


@pytest.fixture(scope="module")
def system():
    return example(0)


@pytest.fixture(scope="module")
def design(system):
    return design_gains(*system)


def test_example_is_a_genuinely_distributed_problem(system):
    P, A, C = system
    assert np.max(np.abs(np.linalg.eigvals(A))) > 1  # unstable plant
    assert np.allclose(P.sum(axis=1), 1) and np.all(np.diag(P) > 0)
    # no sensor observes A on its own
    for Ci in C:
        obs = np.vstack([Ci @ np.linalg.matrix_power(A, k) for k in range(6)])
        assert np.linalg.matrix_rank(obs) < 6
    assert is_observable(P, A, C) == (True, "")


def test_design_is_stable_and_certified(system, design):
    P, A, C = system
    assert isinstance(design, GainDesign)
    rho = rho_from_L(P, A, C, design.L)
    assert rho < 1
    assert rho == pytest.approx(design.rho, abs=1e-9)
    assert design.certified is True
    assert design.certified_rate is not None
    assert rho <= design.certified_rate + 1e-6
    assert 0 < design.certified_rate < 1
    assert design.method == "block-diagonal-lmi-bisection"
    assert design.status == "optimal"
    assert design.solver in ("CLARABEL", "SCS")
    assert "certified" in design.message


def test_K_realises_L_and_is_block_diagonal(system, design):
    P, A, C = system
    n = A.shape[0]
    assert len(design.K) == len(design.L) == len(C)
    for Ki, Li, Ci in zip(design.K, design.L, C, strict=True):
        assert Ki.shape == (n, n)
        assert Li.shape == (n, Ci.shape[0])
        np.testing.assert_allclose(Ki @ Ci.T, Li, atol=1e-10)
    # K D_C-bar is block diagonal: agent i's correction uses only its own output
    D = block_diag(*[Ci.T @ Ci for Ci in C])
    KD = block_diag(*design.K) @ D
    for i in range(len(C)):
        for j in range(len(C)):
            blk = KD[i * n : (i + 1) * n, j * n : (j + 1) * n]
            if i != j:
                assert np.all(blk == 0)
            else:
                np.testing.assert_allclose(blk, design.L[i] @ C[i], atol=1e-10)
    # and the resulting closed loop is the one the design reports
    M = np.kron(P, A)
    assert np.max(np.abs(np.linalg.eigvals(M - KD @ M))) == pytest.approx(design.rho, abs=1e-9)


def test_bisection_beats_plain_feasibility(system, design):
    single = design_gains(*system, bisect=False)
    assert single.method == "block-diagonal-lmi"
    assert single.certified_rate == 1.0
    assert single.certified
    assert rho_from_L(*system, single.L) < 1
    assert design.certified_rate < single.certified_rate


def test_given_rate_is_certified(system, design):
    rate = min(0.95, design.certified_rate + 0.1)
    d = design_gains(*system, rate=rate)
    assert d.certified_rate == rate
    assert rho_from_L(*system, d.L) < rate
    assert d.method == "block-diagonal-lmi"


def test_infeasible_rate_raises(system):
    with pytest.raises(GainDesignError, match=r"alpha=0\.001"):
        design_gains(*system, rate=1e-3)


def test_unobservable_raises():
    P, A, C = example(0)
    with pytest.raises(GainDesignError, match="not observable"):
        design_gains(P, A, [np.zeros((1, 6)) for _ in C])
    # nobody measures the sink state 5 (column 5 of A is zero off the diagonal)
    assert np.all(A[:5, 5] == 0)
    C2 = list(C[:3]) + [np.zeros((1, 6))]
    ok, reason = is_observable(P, A, C2)
    assert not ok and "PBH" in reason and f"{abs(A[5, 5]):.4g}" in reason
    with pytest.raises(GainDesignError, match="not observable"):
        design_gains(P, A, C2)


def test_solver_failures_become_gain_design_errors(system, monkeypatch):
    import cvxpy as cp

    with pytest.raises(GainDesignError, match="not installed"):
        design_gains(*system, solver="NO_SUCH_SOLVER")

    def boom(self, *args, **kwargs):
        raise cp.error.SolverError("boom")

    monkeypatch.setattr(cp.Problem, "solve", boom)
    with pytest.raises(GainDesignError, match="boom") as info:
        design_gains(*system)
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_gains_from_matrices(system, design):
    P, A, C = system
    given = gains_from_matrices(design.K, P, A, C)
    assert given.method == "given"
    assert given.certified_rate is None
    assert given.certified
    assert given.rho == pytest.approx(design.rho, abs=1e-10)
    for Lg, Ld in zip(given.L, design.L, strict=True):
        np.testing.assert_allclose(Lg, Ld, atol=1e-10)

    zero = gains_from_matrices([np.zeros((6, 6))] * 4, P, A, C)
    assert zero.rho == pytest.approx(1.04, abs=1e-9)  # rho(P kron A) = rho(A)
    assert not zero.certified

    bad = list(design.K)
    bad[2] = np.zeros((6, 5))
    with pytest.raises(ValueError, match=r"K\[2\] \(agent 2\)"):
        gains_from_matrices(bad, P, A, C)
    with pytest.raises(ValueError, match="3 gains"):
        gains_from_matrices(design.K[:3], P, A, C)


def test_invalid_parameters(system):
    with pytest.raises(ValueError, match="rate"):
        design_gains(*system, rate=-1.0)
    with pytest.raises(ValueError, match=r"C\[1\]"):
        P, A, C = system
        design_gains(P, A, [C[0], np.zeros((1, 5)), C[2], C[3]])
