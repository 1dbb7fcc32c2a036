"""Tests for models.augmented against independent facts (LCSYS2022 eqs. 2-12, Lemma 4)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag

from models.augmented import (
    augmented_closed_loop,
    augmented_consensus,
    delay_bound_lcsys,
    delay_free_closed_loop,
    delay_split,
    gain_product,
    output_gain_matrix,
    spectral_radius,
    tau_star,
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


def random_gains(rng, C, scale=0.5):
    return [scale * rng.standard_normal((Ci.shape[1], Ci.shape[0])) for Ci in C]


def stoch(rng, mask):
    W = mask * rng.uniform(0.2, 1.0, mask.shape)
    return W / W.sum(axis=1, keepdims=True)


# ---------------------------------------------------------------------------
# delay-free blocks
# ---------------------------------------------------------------------------


def test_output_gain_matrix_is_DcT_Dc():
    rng = np.random.default_rng(1)
    C = [rng.standard_normal((m, 5)) for m in (1, 2, 1)]
    Dc = block_diag(*C)  # D_C = blockdiag(C_i), shape (sum m_i, N n)
    D = output_gain_matrix(C)
    assert D.shape == (15, 15)
    np.testing.assert_allclose(D, Dc.T @ Dc, atol=1e-14)


def test_gain_product_equals_K_times_Dbar():
    rng = np.random.default_rng(2)
    n = 4
    C = [rng.standard_normal((m, n)) for m in (1, 2, 1)]
    K = [rng.standard_normal((n, n)) for _ in C]
    L = [Ki @ Ci.T for Ki, Ci in zip(K, C, strict=True)]
    expected = block_diag(*K) @ output_gain_matrix(C)
    np.testing.assert_allclose(gain_product(L, C), expected, atol=1e-12)


def test_delay_free_closed_loop_formula():
    P, A, C = example()
    rng = np.random.default_rng(3)
    L = random_gains(rng, C)
    M = np.kron(P, A)
    KD = block_diag(*[Li @ Ci for Li, Ci in zip(L, C, strict=True)])
    np.testing.assert_allclose(delay_free_closed_loop(P, A, C, L), M - KD @ M, atol=1e-13)


def test_shape_errors():
    P, A, C = example()
    L = random_gains(np.random.default_rng(0), C)
    with pytest.raises(ValueError, match="C has 3"):
        delay_free_closed_loop(P, A, C[:3], L[:3])
    with pytest.raises(ValueError, match=r"L\[1\]"):
        delay_free_closed_loop(P, A, C, [L[0], np.zeros((5, 1)), L[2], L[3]])
    with pytest.raises(ValueError, match="square"):
        delay_free_closed_loop(P[:3], A, C, L)


# ---------------------------------------------------------------------------
# P_r split and P-bar
# ---------------------------------------------------------------------------


def test_delay_split_partitions_P_and_ignores_non_edges():
    P, _, _ = example()
    rng = np.random.default_rng(4)
    delays = rng.integers(0, 4, P.shape)
    np.fill_diagonal(delays, 0)
    delays[P == 0] = 99  # non-edges are ignored
    parts = delay_split(P, delays, 3)
    assert len(parts) == 4
    np.testing.assert_array_equal(sum(parts), P)
    for r, Pr in enumerate(parts):
        edge = P != 0
        np.testing.assert_array_equal(Pr[edge & (delays == r)], P[edge & (delays == r)])
        assert np.all(Pr[delays != r] == 0)
    # each edge appears in exactly one P_r
    assert np.all(sum((Pr != 0).astype(int) for Pr in parts) == (P != 0))


def test_delay_split_rejects_bad_delays():
    P, _, _ = example()
    d = np.zeros((4, 4), dtype=int)
    d[0, 3] = 5  # edge 3 -> 0 (the cycle closes 4 -> 1)
    assert P[0, 3] != 0
    with pytest.raises(ValueError, match=r"edge 3->0.*outside the allowed range 0\.\.2"):
        delay_split(P, d, 2)
    d[0, 3] = -1
    with pytest.raises(ValueError, match="outside"):
        delay_split(P, d, 2)
    d = np.zeros((4, 4), dtype=int)
    d[1, 1] = 1
    with pytest.raises(ValueError, match="self-loop"):
        delay_split(P, d, 2)
    with pytest.raises(ValueError, match="shape"):
        delay_split(P, np.zeros((3, 3), dtype=int), 2)


def test_augmented_consensus_is_row_stochastic():
    P, _, _ = example()
    rng = np.random.default_rng(5)
    delays = rng.integers(0, 4, P.shape)
    np.fill_diagonal(delays, 0)
    Pbar = augmented_consensus(delay_split(P, delays, 3))
    assert Pbar.shape == (16, 16)
    assert np.all(Pbar >= 0)
    np.testing.assert_allclose(Pbar.sum(axis=1), np.ones(16), atol=1e-14)
    # rho(P-bar) = 1 for a row-stochastic P-bar
    assert spectral_radius(Pbar) == pytest.approx(1.0, abs=1e-9)
    # identity shift blocks below the first block row
    np.testing.assert_array_equal(Pbar[4:, :12], np.eye(12))
    np.testing.assert_array_equal(Pbar[4:, 12:], 0)


# ---------------------------------------------------------------------------
# augmented closed loop
# ---------------------------------------------------------------------------


def test_zero_delays_reduce_to_delay_free():
    P, A, C = example()
    L = random_gains(np.random.default_rng(6), C)
    Ahat = delay_free_closed_loop(P, A, C, L)
    zero = np.zeros((4, 4), dtype=int)
    for comp in (True, False):
        np.testing.assert_allclose(
            augmented_closed_loop(P, A, C, L, zero, compensated=comp), Ahat, atol=1e-14
        )
    # padding with unused delay slots only adds zero eigenvalues
    padded = augmented_closed_loop(P, A, C, L, zero, tau=2)
    assert padded.shape == (72, 72)
    assert spectral_radius(padded) == pytest.approx(spectral_radius(Ahat), rel=1e-10)


@pytest.mark.parametrize("tau", [1, 2, 4])
def test_homogeneous_delay_lemma4(tau):
    """All links delayed by tau: q(lam) = p(lam^(tau+1)) (LCSYS2022 Lemma 4)."""
    rng = np.random.default_rng(10 + tau)
    N = 4
    # zero diagonal so that *every* link (there are no self-loops) has delay tau
    mask = np.ones((N, N)) - np.eye(N)
    P = stoch(rng, mask)
    A = rng.standard_normal((3, 3)) * 0.6
    C = [rng.standard_normal((1, 3)) for _ in range(N)]
    L = random_gains(rng, C, 0.3)
    delays = np.full((N, N), tau)
    aug = augmented_closed_loop(P, A, C, L, delays)
    assert aug.shape == (N * 3 * (tau + 1),) * 2
    B = (np.eye(N * 3) - block_diag(*[Li @ Ci for Li, Ci in zip(L, C, strict=True)])) @ np.kron(
        P, np.linalg.matrix_power(A, tau + 1)
    )
    rho_B = np.max(np.abs(np.linalg.eigvals(B)))
    rho_aug = spectral_radius(aug)
    assert rho_aug == pytest.approx(rho_B ** (1 / (tau + 1)), abs=1e-8)
    assert delay_bound_lcsys(P, A, C, L, tau) == pytest.approx(rho_aug, abs=1e-8)
    # every eigenvalue of the augmented matrix is a (tau+1)-th root of one of B's
    eb = np.linalg.eigvals(B)
    lam_pow = np.linalg.eigvals(aug) ** (tau + 1)
    dist = np.min(np.abs(lam_pow[:, None] - eb[None, :]), axis=1)
    assert np.max(dist) < 1e-6 * max(1.0, rho_B)


def _simulate_agents(P, A, C, L, delays, tau, steps, rng, compensated):
    """Per-agent estimator (4)-(5), written out agent by agent.

    a-priori:  xp_i(k) = sum_j p_ij A^(r_ij+1) xh_j(k-1-r_ij)   (A instead of
               A^(r+1) when not compensated; r_ii = 0)
    update:    xh_i(k) = xp_i(k) + L_i (y_i(k) - C_i xp_i(k)),  y_i(k) = C_i x(k)

    Noise free. For compensated=True the true state moves, x(k) = A x(k-1); for
    compensated=False it is zero (the homogeneous estimate recursion).
    Returns the errors e(k) = (x(k) - xh_i(k))_i for k = -tau..steps.
    """
    N, n = P.shape[0], A.shape[0]
    x = {-tau: rng.standard_normal(n) if compensated else np.zeros(n)}
    for k in range(-tau + 1, steps + 1):
        x[k] = A @ x[k - 1] if compensated else np.zeros(n)
    xh = {k: [rng.standard_normal(n) for _ in range(N)] for k in range(-tau, 1)}
    for k in range(1, steps + 1):
        xh[k] = []
        for i in range(N):
            xp = np.zeros(n)
            for j in range(N):
                if P[i, j] == 0:
                    continue
                r = int(delays[i, j])
                Ar = np.linalg.matrix_power(A, r + 1) if compensated else A
                xp += P[i, j] * Ar @ xh[k - 1 - r][j]
            y = C[i] @ x[k]
            xh[k].append(xp + L[i] @ (y - C[i] @ xp))
    return {k: np.concatenate([x[k] - xh[k][i] for i in range(N)]) for k in xh}


@pytest.mark.parametrize("compensated", [True, False])
def test_error_recursion_matches_per_agent_simulation(compensated):
    rng = np.random.default_rng(20)
    P, A, C = example(1)
    # add a few chords so heterogeneous delays act on several in-links
    mask = (P != 0).astype(float)
    mask[0, 2] = mask[2, 0] = mask[3, 1] = 1.0
    P = stoch(rng, mask)
    tau = 3
    delays = rng.integers(0, tau + 1, P.shape)
    np.fill_diagonal(delays, 0)
    delays[0, 3] = tau  # make sure the maximum delay occurs
    L = random_gains(rng, C, 0.4)
    steps = 25
    e = _simulate_agents(P, A, C, L, delays, tau, steps, rng, compensated)
    Abar = augmented_closed_loop(P, A, C, L, delays, compensated=compensated)
    assert Abar.shape == (4 * 6 * (tau + 1),) * 2
    z = np.concatenate([e[-r] for r in range(tau + 1)])  # (e_0; e_-1; ...; e_-tau)
    for k in range(1, steps + 1):
        z = Abar @ z
        scale = max(1.0, np.linalg.norm(e[k]))
        np.testing.assert_allclose(z[: 4 * 6], e[k], atol=1e-10 * scale)
        np.testing.assert_allclose(z[4 * 6 : 2 * 4 * 6], e[k - 1], atol=1e-10 * scale)


def test_uncompensated_differs_from_compensated_with_delays():
    P, A, C = example()
    L = random_gains(np.random.default_rng(7), C)
    d = np.ones((4, 4), dtype=int)
    np.fill_diagonal(d, 0)
    comp = augmented_closed_loop(P, A, C, L, d, compensated=True)
    unc = augmented_closed_loop(P, A, C, L, d, compensated=False)
    G = np.eye(24) - gain_product(L, C)
    P0, P1 = delay_split(P, d, 1)
    np.testing.assert_allclose(comp[:24, 24:], G @ np.kron(P1, A @ A), atol=1e-13)
    np.testing.assert_allclose(unc[:24, 24:], G @ np.kron(P1, A), atol=1e-13)
    np.testing.assert_allclose(comp[:24, :24], unc[:24, :24], atol=0)


# ---------------------------------------------------------------------------
# spectral radius and the paper's bounds
# ---------------------------------------------------------------------------


def test_spectral_radius_basic():
    th = 0.3
    R = 0.9 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    assert spectral_radius(R) == pytest.approx(0.9, abs=1e-14)
    assert spectral_radius(np.diag([-2.0, 1.0])) == pytest.approx(2.0)
    assert spectral_radius(np.zeros((0, 0))) == 0.0


def _bound_rho(P, A, C, L, tau):
    G = np.eye(P.shape[0] * A.shape[0]) - block_diag(
        *[Li @ Ci for Li, Ci in zip(L, C, strict=True)]
    )
    return np.max(np.abs(np.linalg.eigvals(G @ np.kron(P, np.linalg.matrix_power(A, tau + 1)))))


def test_tau_star_matches_independent_scan():
    P, A, C = example()
    # L_i = 0.9 C_i^T damps each measured state; stable delay-free, finite tau*
    L = [0.9 * Ci.T for Ci in C]
    assert _bound_rho(P, A, C, L, 0) < 1
    ts = tau_star(P, A, C, L, tau_max=60)
    assert ts is not None and ts < 60
    for t in range(ts + 1):
        assert _bound_rho(P, A, C, L, t) < 1
    assert _bound_rho(P, A, C, L, ts + 1) >= 1
    for t in (0, 3, 7):
        expected = _bound_rho(P, A, C, L, t) ** (1 / (t + 1))
        assert delay_bound_lcsys(P, A, C, L, t) == pytest.approx(expected, rel=1e-12)


def test_tau_star_scalar_closed_form():
    # N = n = 1: condition |1 - l| a^(tau+1) < 1  <=>  tau + 1 < ln(1/|1-l|) / ln(a)
    a, l_gain = 1.1, 0.5
    expected = int(np.ceil(np.log(1 / abs(1 - l_gain)) / np.log(a))) - 2
    assert expected == 6
    P, A, C, L = np.eye(1), np.array([[a]]), [np.eye(1)], [np.array([[l_gain]])]
    assert tau_star(P, A, C, L) == expected
    assert delay_bound_lcsys(P, A, C, L, 6) == pytest.approx(0.5 ** (1 / 7) * a, rel=1e-12)


def test_tau_star_edge_cases():
    P, A, C = example()
    zero = [np.zeros((6, 1)) for _ in C]
    assert tau_star(P, A, C, zero) is None  # unstable open loop fails at tau=0
    A_stable = 0.5 * A / np.max(np.abs(np.linalg.eigvals(A)))
    assert tau_star(P, A_stable, C, zero, tau_max=15) == 15  # never fails
