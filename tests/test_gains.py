"""Tests for estimators.gains: LMI and CCL gain design (LCSYS2022 eq. 13), delay-bound
design (Discussion 5), direct refinement, method selection."""

from __future__ import annotations

import netsim.estimators.gains as gains_module
import netsim.models.observability as observability_module
import numpy as np
import pytest
from helpers import N_AGENTS, N_STATES, example  # noqa: E402,F401
from netsim.estimators.gains import (
    GainDesign,
    GainDesignError,
    design_gains,
    gains_from_matrices,
    refine_gains,
    select_method,
)
from netsim.models.augmented import augmented_closed_loop, spectral_radius
from netsim.models.observability import distributed_observability
from scipy.linalg import block_diag


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
    assert distributed_observability(P, A, C)


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
    assert not distributed_observability(P, A, C2)
    with pytest.raises(GainDesignError, match="not observable") as err:
        design_gains(P, A, C2)
    assert "PBH" in str(err.value) and f"{abs(A[5, 5]):.4g}" in str(err.value)


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


# ---------------------------------------------------------------------------
# CCL (full Lyapunov matrix), method selection, delay-bound design, refinement
# ---------------------------------------------------------------------------

CCL_STEPS = 20


def rho_with_power(P, A, C, L, power):
    """rho((I - blockdiag(L_i C_i)) (P kron A^power)), computed independently."""
    return rho_from_L(P, np.linalg.matrix_power(A, power), C, L)


def homogeneous_delays(P, tau):
    d = np.where(P != 0, tau, 0)
    np.fill_diagonal(d, 0)  # an agent's own estimate is never delayed
    return d


@pytest.fixture(scope="module")
def ccl(system):
    return design_gains(*system, method="ccl", max_iter=CCL_STEPS)


def test_ccl_is_stable_certified_and_no_worse_than_the_lmi(system, design, ccl):
    P, A, C = system
    rho = rho_from_L(P, A, C, ccl.L)
    assert rho < 1
    assert rho == pytest.approx(ccl.rho, abs=1e-9)
    assert ccl.method == "ccl-full-lyapunov-rate-search"
    assert ccl.certified and ccl.status == "optimal"
    assert rho < ccl.certified_rate < 1
    assert 1 <= ccl.iterations <= CCL_STEPS
    assert "CCL" in ccl.message and "SDP solves" in ccl.message
    # a full Lyapunov matrix is less conservative than a block-diagonal one
    assert ccl.certified_rate <= design.certified_rate + 1e-3
    # K realises L and stays block diagonal (one K_i per agent)
    for Ki, Li, Ci in zip(ccl.K, ccl.L, C, strict=True):
        np.testing.assert_allclose(Ki @ Ci.T, Li, atol=1e-10)


def test_ccl_certificate_is_a_full_lyapunov_matrix(system, ccl):
    from scipy.linalg import solve_discrete_lyapunov

    P, A, C = system
    M = np.kron(P, A)
    KD = block_diag(*[Li @ Ci for Li, Ci in zip(ccl.L, C, strict=True)])
    F = (M - KD @ M) / ccl.certified_rate
    X = solve_discrete_lyapunov(F.T, np.eye(F.shape[0]))
    assert np.linalg.eigvalsh((X + X.T) / 2)[0] > 0
    assert np.linalg.eigvalsh(X - F.T @ X @ F)[0] > 0.5


def test_ccl_at_a_given_rate(system):
    d = design_gains(*system, method="ccl", rate=0.95, max_iter=CCL_STEPS)
    assert d.method == "ccl-full-lyapunov"
    assert d.certified_rate == 0.95 and d.certified
    assert rho_from_L(*system, d.L) < 0.95


def test_ccl_failures_are_gain_design_errors(system, monkeypatch):
    with pytest.raises(GainDesignError, match=r"CCL.*alpha=0\.001") as info:
        design_gains(*system, method="ccl", rate=1e-3, max_iter=3)
    assert info.value.__cause__ is None
    P, A, C = system
    with pytest.raises(GainDesignError, match="not observable"):
        design_gains(P, A, [np.zeros((1, 6)) for _ in C], method="ccl")

    import cvxpy as cp

    def boom(self, *args, **kwargs):
        raise cp.error.SolverError("boom")

    monkeypatch.setattr(cp.Problem, "solve", boom)
    with pytest.raises(GainDesignError, match="boom") as info:
        design_gains(*system, method="ccl", max_iter=2)
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_optimal_inaccurate_is_not_certified(system, monkeypatch):
    import cvxpy as cp

    real_solve = cp.Problem.solve

    def inaccurate(self, *args, **kwargs):
        real_solve(self, *args, **kwargs)
        self._status = "optimal_inaccurate"

    monkeypatch.setattr(cp.Problem, "solve", inaccurate)
    d = design_gains(*system, bisect=False)
    assert d.status == "optimal_inaccurate"
    assert not d.certified and d.certified_rate is None
    assert "NOT certified" in d.message
    with pytest.raises(GainDesignError, match="CCL"):
        design_gains(*system, method="ccl", max_iter=2)


def test_select_method_by_size():
    method, reason = select_method(4, 6)
    assert method == "ccl" and "24" in reason
    assert select_method(10, 6)[0] == "ccl"  # N n = 60 is the threshold
    method, reason = select_method(11, 6)
    assert method == "lmi" and "66" in reason
    assert select_method(200, 6)[0] == "lmi"
    assert select_method(200, 6, threshold=10**6)[0] == "ccl"


def cycle_example(N, seed=1):
    """n=6 plant of `example`, N sensors on a self-looped cycle, sensor i measures block i%4."""
    _, A, _ = example(seed)
    rng = np.random.default_rng(seed)
    W = (np.eye(N) + np.roll(np.eye(N), -1, axis=1)) * rng.uniform(0.2, 1.0, (N, N))
    starts = [0, 2, 4, 5]
    C = [np.eye(6)[[starts[i % 4]]] for i in range(N)]
    return W / W.sum(axis=1, keepdims=True), A, C


def test_auto_dispatches_by_size_without_solving(system, monkeypatch):
    calls = []

    def fake(kind):
        def run(*args, **kwargs):
            calls.append(kind)
            raise GainDesignError(f"{kind} called")

        return run

    monkeypatch.setattr(gains_module, "_design_ccl", fake("ccl"))
    monkeypatch.setattr(gains_module, "_design_lmi", fake("lmi"))
    with pytest.raises(GainDesignError, match=r"auto: N n = 24 <= 60.*ccl called"):
        design_gains(*system, method="auto")
    with pytest.raises(GainDesignError, match=r"auto: N n = 72 > 60.*lmi called"):
        design_gains(*cycle_example(12), method="auto")
    assert calls == ["ccl", "lmi"]
    with pytest.raises(ValueError, match="method"):
        design_gains(*system, method="newton")


def test_auto_reports_what_ran(system, ccl):
    d = design_gains(*system, method="auto", max_iter=CCL_STEPS)
    assert d.method == ccl.method
    assert d.message.startswith("auto: N n = 24 <= 60")
    assert d.rho == pytest.approx(ccl.rho, abs=1e-6)


@pytest.fixture(scope="module")
def delay_design(system):
    return design_gains(*system, tau1=3)


def test_delay_bound_design_reports_both_radii(system, delay_design):
    P, A, C = system
    d = delay_design
    assert d.design_tau == 3
    assert d.rho == pytest.approx(rho_from_L(P, A, C, d.L), abs=1e-9)  # delay-free
    assert d.rho_design == pytest.approx(rho_with_power(P, A, C, d.L, 4), abs=1e-9)
    assert d.rho_design < d.certified_rate <= 1
    assert d.certified and d.rho < 1
    assert "tau1=3" in d.message
    assert design_gains(*system, bisect=False).design_tau == 0


def test_delay_bound_design_is_stable_for_homogeneous_delays_up_to_tau1(system, delay_design):
    P, A, C = system
    for tau in range(4):
        Abar = augmented_closed_loop(P, A, C, delay_design.L, homogeneous_delays(P, tau), tau=tau)
        assert spectral_radius(Abar) < 1, tau


def test_delay_bound_design_infeasible_is_reported_plainly(system):
    with pytest.raises(GainDesignError, match=r"^delay-bound design for tau1=2 is infeasible"):
        design_gains(*system, tau1=2, rate=1e-3)
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="tau1"):
            design_gains(*system, tau1=bad)


def test_refinement_never_worsens_and_is_recomputable(system, design):
    P, A, C = system
    r = refine_gains(design, P, A, C, max_iter=50)
    assert r.method == "refined"
    rho = rho_from_L(P, A, C, r.L)
    assert rho == pytest.approx(r.rho, abs=1e-9)
    assert rho <= design.rho + 1e-12
    assert f"{design.rho:.6g}" in r.message
    if r.certified:
        assert rho < r.certified_rate < 1
    else:
        assert r.certified_rate is None
    for Ki, Li, Ci in zip(r.K, r.L, C, strict=True):
        np.testing.assert_allclose(Ki @ Ci.T, Li, atol=1e-10)


def test_refinement_of_a_delay_bound_design(system, delay_design):
    P, A, C = system
    r = refine_gains(delay_design, P, A, C, tau1=3, max_iter=50)
    assert r.design_tau == 3
    assert r.rho_design <= delay_design.rho_design + 1e-12
    assert r.rho_design == pytest.approx(rho_with_power(P, A, C, r.L, 4), abs=1e-9)
    assert r.rho == pytest.approx(rho_from_L(P, A, C, r.L), abs=1e-9)


def test_observability_fast_path_agrees_with_svd_test(system, monkeypatch):
    P, A, C = system
    C2 = list(C[:3]) + [np.zeros((1, 6))]
    exact = [distributed_observability(P, A, C), distributed_observability(P, A, C2)]
    assert exact == [True, False]
    monkeypatch.setattr(observability_module, "_PBH_SVD_MAX_STATES", 0)
    assert [distributed_observability(P, A, C), distributed_observability(P, A, C2)] == exact


def test_gain_design_stays_backward_compatible(design):
    g = GainDesign(design.L, design.K, 0.5, None, True, "given", "none", "given", "")
    assert g.rho_design == 0.5 and g.design_tau == 0 and g.iterations == 0
    assert design.rho_design == design.rho and design.design_tau == 0
    assert design.iterations == 11


def test_ccl_rate_search_never_aims_at_zero():
    """n = 2, N = 2: the best CCL rate (about 0.17) falls below the search step, and the
    target best_rho - delta used to reach alpha = 0 (ZeroDivisionError in the SDP)."""
    A = np.array([[1.02, 0.2], [0.0, 0.95]])
    C = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])]
    P = np.array([[0.6, 0.4], [0.3, 0.7]])
    d = design_gains(P, A, C, method="ccl")
    rho = rho_from_L(P, A, C, d.L)
    assert rho == pytest.approx(d.rho, abs=1e-9)
    assert d.certified and rho < d.certified_rate < 0.5
