"""Tests for models.augmented against independent facts.

LCSYS2022 eqs. 2-3, 9-14, 26, Theorem 1, Lemmas 2-4 (Lemma 5 only where it holds);
delay-tolerant paper eqs. 11, 17, Theorem 1 (and a counterexample to its bound)."""

from __future__ import annotations

import contextlib
import warnings

import netsim.models.augmented as aug
import numpy as np
import pytest
from helpers import N_AGENTS, N_STATES, example  # noqa: E402,F401
from netsim.models.augmented import (
    TauStar,
    augmented_closed_loop,
    augmented_consensus,
    augmented_spectral_radius,
    closed_loop_sequence_growth,
    convergence_time_augmented,
    convergence_time_delay_free,
    convergence_time_order,
    decay_rate,
    decay_rate_lcsys,
    decay_rate_tolerant,
    delay_bound_lcsys,
    delay_bound_tolerant,
    delay_free_closed_loop,
    delay_free_spectral_radius,
    delay_split,
    gain_product,
    output_gain_matrix,
    spectral_radius,
    tau_star,
    tau_star_report,
)
from scipy.linalg import block_diag


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


# ---------------------------------------------------------------------------
# random instances for the structured analytics
# ---------------------------------------------------------------------------


def random_instance(
    seed, N, n, tau, *, dense_P=False, homogeneous=False, cycle=False, bipartite=False
):
    """Random (P, A, C, L, delays): row-stochastic P (self-loops unless ``homogeneous``,
    ``cycle`` or ``bipartite``), unstable A (rho in 1.0..1.15), 1-2 outputs per agent,
    small gains, heterogeneous delays in 0..tau with tau attained (all links at tau
    if ``homogeneous``; even delays if ``bipartite``)."""
    rng = np.random.default_rng(seed)
    if cycle:  # pure directed cycle, no self-loops: spectrum invariant under rotations
        mask = np.roll(np.eye(N, dtype=bool), 1, axis=1)
    elif bipartite:  # links only between agents of different parity, even delays:
        # every cycle of the block graph has even length, spectrum symmetric under -1
        parity = np.arange(N) % 2
        mask = (parity[:, None] != parity[None, :]) & (rng.random((N, N)) < 0.5)
        mask |= np.roll(np.eye(N, dtype=bool), 1, axis=1)
    elif dense_P:
        mask = np.ones((N, N), dtype=bool)
    else:
        mask = (rng.random((N, N)) < 2.5 / N) | np.roll(np.eye(N, dtype=bool), 1, axis=1)
        mask |= np.eye(N, dtype=bool)
    if homogeneous:
        np.fill_diagonal(mask, False)
        mask |= np.roll(np.eye(N, dtype=bool), 1, axis=1)
    P = stoch(rng, mask.astype(float))
    A = rng.standard_normal((n, n))
    A *= rng.uniform(1.0, 1.15) / np.max(np.abs(np.linalg.eigvals(A)))
    C = [rng.standard_normal((int(rng.integers(1, 3)), n)) for _ in range(N)]
    L = [rng.uniform(0.1, 0.6) * Ci.T / np.sum(Ci**2) for Ci in C]
    if homogeneous:
        delays = np.full((N, N), tau)
    else:
        delays = rng.integers(0, tau + 1, (N, N))
        if bipartite:
            delays -= delays % 2
        edge_i, edge_j = np.nonzero(mask & ~np.eye(N, dtype=bool))
        delays[edge_i[0], edge_j[0]] = tau  # tau is attained on some link
    np.fill_diagonal(delays, 0)
    return P, A, C, L, delays


# ---------------------------------------------------------------------------
# P-bar and LCSYS2022 Lemma 4
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_Pbar_first_rows_sum_like_P(seed):
    """Rows 1..N of P-bar sum to the row sums of P (any weights, stochastic or not);
    the identity rows below sum to 1."""
    rng = np.random.default_rng(100 + seed)
    N, tau = int(rng.integers(3, 8)), int(rng.integers(1, 6))
    P = rng.standard_normal((N, N)) * (rng.random((N, N)) < 0.6)
    np.fill_diagonal(P, rng.uniform(0.1, 1.0, N))
    delays = rng.integers(0, tau + 1, (N, N))
    np.fill_diagonal(delays, 0)
    Pbar = augmented_consensus(delay_split(P, delays, tau))
    np.testing.assert_allclose(Pbar[:N].sum(axis=1), P.sum(axis=1), atol=1e-13)
    np.testing.assert_allclose(Pbar[N:].sum(axis=1), np.ones(N * tau), atol=0)


@pytest.mark.parametrize(("N", "n_blocks", "i"), [(2, 3, 1), (3, 4, 2), (2, 5, 5), (4, 3, 3)])
def test_lemma4_characteristic_polynomial(N, n_blocks, i):
    """LCSYS2022 Lemma 4: the block matrix with A_i as the only block of the first block
    row (block position i, 1-based) and identities below has characteristic polynomial
    q(lam) = lam^(N(n-i)) p(lam^i), p that of A_i. Checked at random complex points
    and through the eigenvalues (n = number of blocks)."""
    rng = np.random.default_rng(N * 100 + n_blocks * 10 + i)
    Ai = rng.standard_normal((N, N))
    blocks = [np.zeros((N, N)) for _ in range(n_blocks)]
    blocks[i - 1] = Ai
    Abar = augmented_consensus(blocks)
    assert Abar.shape == (N * n_blocks,) * 2
    for lam in rng.standard_normal(5) + 1j * rng.standard_normal(5):
        q = np.linalg.det(lam * np.eye(N * n_blocks) - Abar)
        expected = lam ** (N * (n_blocks - i)) * np.linalg.det(lam**i * np.eye(N) - Ai)
        assert q == pytest.approx(expected, rel=1e-9, abs=1e-12)
    # coefficients: q = x^(N(n-i)) p(x^i)
    p = np.poly(Ai)
    q_expected = np.zeros(N * n_blocks + 1)
    q_expected[::i][: N + 1] = p
    np.testing.assert_allclose(np.poly(Abar).real, q_expected, atol=1e-6)


def test_lemma3_kronecker_eigenvalues():
    """LCSYS2022 Lemma 3: eig(P kron A) = {lambda_i mu_j}; so rho(P kron A) = rho(A) for
    row-stochastic P (Remark 2)."""
    rng = np.random.default_rng(7)
    P, A = rng.standard_normal((4, 4)), rng.standard_normal((3, 3))
    products = np.outer(np.linalg.eigvals(P), np.linalg.eigvals(A)).ravel()
    eig = np.linalg.eigvals(np.kron(P, A))
    dist = np.abs(eig[:, None] - products[None, :])
    assert np.max(np.min(dist, axis=1)) < 1e-9 and np.max(np.min(dist, axis=0)) < 1e-9
    S = stoch(rng, np.ones((4, 4)))
    assert spectral_radius(np.kron(S, A)) == pytest.approx(spectral_radius(A), rel=1e-12)


# ---------------------------------------------------------------------------
# structured spectral radius
# ---------------------------------------------------------------------------

STRUCTURED_CASES = [
    # (seed, N, n, tau, kwargs)
    (0, 5, 3, 1, {}),
    (1, 6, 4, 3, {}),
    (2, 8, 3, 6, {}),
    (3, 4, 5, 10, {}),
    (4, 7, 2, 10, {}),
    (5, 12, 3, 4, {"dense_P": True}),  # factored operator
    (6, 6, 3, 8, {"dense_P": True}),
    (7, 5, 3, 4, {"homogeneous": True}),  # (tau+1)-fold equal moduli (Lemma 4)
    (8, 9, 2, 3, {"cycle": True}),  # rotational symmetry of the block graph
    (9, 16, 2, 2, {"cycle": True}),
    (10, 10, 3, 4, {"bipartite": True}),  # cyclic index 2, ARPACK on one colour class
]


@pytest.mark.parametrize("compensated", [True, False])
@pytest.mark.parametrize(("seed", "N", "n", "tau", "kw"), STRUCTURED_CASES)
def test_structured_spectral_radius_matches_dense(seed, N, n, tau, kw, compensated):
    P, A, C, L, delays = random_instance(seed, N, n, tau, **kw)
    dense = augmented_spectral_radius(P, A, C, L, delays, tau, compensated, method="dense")
    expected = spectral_radius(augmented_closed_loop(P, A, C, L, delays, tau, compensated))
    assert dense == expected
    structured = augmented_spectral_radius(
        P, A, C, L, delays, tau, compensated, method="structured"
    )
    assert abs(structured - dense) <= 1e-8
    # below the threshold, auto is the dense computation; above it, the structured one
    auto = augmented_spectral_radius(P, A, C, L, delays, tau, compensated)
    small = N * n * (tau + 1) <= aug.AUGMENTED_DENSE_SIZE_THRESHOLD
    assert auto == (dense if small else structured)
    # padding with unused delay slots changes nothing
    padded = augmented_spectral_radius(
        P, A, C, L, delays, tau + 2, compensated, method="structured"
    )
    assert abs(padded - dense) <= 1e-8


def test_structured_operator_matches_dense_matrix():
    """Both first-row representations (block-sparse and factored) apply exactly the
    companion matrix of augmented_closed_loop, and M^q by the buffered recursion."""
    rng = np.random.default_rng(11)
    kinds = set()
    for dense_P in (False, True):
        P, A, C, L, delays = random_instance(11, 8, 3, 4, dense_P=dense_P)
        for comp in (True, False):
            M = augmented_closed_loop(P, A, C, L, delays, 4, comp)
            G = aug._gain_blocks(L, aug._as_outputs(C))
            B = aug._delay_blocks(A, 5, comp)
            X = rng.standard_normal((M.shape[0], 3))
            for kind in ("bsr", "factored", "auto"):
                row = aug._FirstRow(G, P, np.where(P != 0, delays, 0), B, kind=kind)
                kinds.add(row.kind)
                np.testing.assert_allclose(row.companion_apply(X), M @ X, atol=1e-12)
                np.testing.assert_allclose(row.companion_apply(X[:, 0]), M @ X[:, 0], atol=1e-12)
                np.testing.assert_allclose(
                    row.companion_power(X, 7), np.linalg.matrix_power(M, 7) @ X, rtol=1e-10
                )
    assert kinds == {"bsr", "factored"}
    # the automatic choice: block-sparse for sparse P, factored for dense P
    for dense_P, kind in ((False, "bsr"), (True, "factored")):
        P, A, C, L, delays = random_instance(12, 60, 3, 4, dense_P=dense_P)
        G = aug._gain_blocks(L, aug._as_outputs(C))
        row = aug._FirstRow(G, P, np.where(P != 0, delays, 0), aug._delay_blocks(A, 5, True))
        assert row.kind == kind


def test_cyclic_index_of_block_graph():
    """A directed ring without self-loops, all delays 0: block graph is one cycle of
    length N, so p = N; with delays, p = sum over the ring of (r + 1)."""
    P, A, C, L, _ = random_instance(8, 5, 2, 0, cycle=True)
    G = aug._gain_blocks(L, aug._as_outputs(C))
    zero = np.zeros((5, 5), dtype=int)
    row = aug._FirstRow(G, P, zero, aug._delay_blocks(A, 1, True))
    assert aug._cyclic_class(row)[0] == 5
    d = np.where(P != 0, np.array([0, 1, 2, 0, 1])[:, None], 0)
    row = aug._FirstRow(G, P, d, aug._delay_blocks(A, 3, True))
    assert aug._cyclic_class(row)[0] == 5 + 4
    # a self-loop (delay 0) gives p = 1
    P2 = stoch(np.random.default_rng(0), (P != 0) + np.eye(5))
    row = aug._FirstRow(G, P2, np.zeros((5, 5), dtype=int), aug._delay_blocks(A, 1, True))
    assert aug._cyclic_class(row)[0] == 1


def test_structured_nilpotent_and_overflow():
    rng = np.random.default_rng(3)
    N, n = 5, 4
    P = stoch(rng, np.ones((N, N)))
    delays = rng.integers(0, 3, (N, N))
    np.fill_diagonal(delays, 0)
    C = [np.eye(n)[[0]] for _ in range(N)]
    L = [0.5 * Ci.T for Ci in C]
    # nilpotent A: every M_r is strictly upper triangular in the state index, the
    # augmented matrix is nilpotent with long Jordan chains; eigenvalue 0 is then only
    # determined to about eps^(1/m), by dense eigvals and ARPACK alike
    shift = np.diag(np.ones(n - 1), 1)
    for comp in (True, False):
        assert augmented_spectral_radius(P, shift, C, L, delays, 2, comp, "structured") < 1e-2
        assert augmented_spectral_radius(P, shift, C, L, delays, 2, comp, "dense") < 1e-2
    # all gains I - L_i C_i = 0: the first block row vanishes, rho = 0 exactly
    eye = [np.eye(n) for _ in range(N)]
    A1 = shift + np.eye(n)
    assert augmented_spectral_radius(P, A1, eye, eye, delays, 2, True, "structured") == 0
    huge = 1e200 * np.eye(n)
    assert augmented_spectral_radius(P, huge, C, L, delays, 2, method="structured") == np.inf
    assert augmented_spectral_radius(P, huge, C, L, delays, 2, method="dense") == np.inf


def test_structured_failure_is_never_silent(monkeypatch):
    """ARPACK not converging, or returning a Ritz pair that is not an eigenpair, gives
    the dense value with a RuntimeWarning (small sizes) or a RuntimeError."""
    from scipy.sparse.linalg import ArpackNoConvergence, eigs

    P, A, C, L, delays = random_instance(2, 8, 3, 6)
    dense = augmented_spectral_radius(P, A, C, L, delays, method="dense")

    def no_convergence(*args, **kwargs):
        raise ArpackNoConvergence("ARPACK error -1: No convergence", np.array([]), None)

    def garbage(*args, **kwargs):
        vals, vecs = eigs(*args, **kwargs)
        return 1.5 * vals, vecs

    for fake in (no_convergence, garbage):
        monkeypatch.setattr(aug, "eigs", fake)
        with pytest.warns(RuntimeWarning, match="ARPACK failed.*falling back to dense"):
            value = augmented_spectral_radius(P, A, C, L, delays, method="structured")
        assert value == pytest.approx(dense, abs=1e-10)
        with monkeypatch.context() as m:
            m.setattr(aug, "DENSE_FALLBACK_MAX", 10)
            with pytest.raises(RuntimeError, match="ARPACK could not compute"):
                augmented_spectral_radius(P, A, C, L, delays, method="structured")


def test_structured_above_threshold_uses_arpack(monkeypatch):
    """``auto`` switches to the structured method above DENSE_SIZE_THRESHOLD (the
    augmented closed loop: above AUGMENTED_DENSE_SIZE_THRESHOLD)."""
    P, A, C, L, delays = random_instance(1, 6, 4, 3)
    dense = augmented_spectral_radius(P, A, C, L, delays, method="dense")
    calls = []
    original = aug._companion_rho
    monkeypatch.setattr(aug, "_companion_rho",
                        lambda *a, **k: calls.append(1) or original(*a, **k))
    monkeypatch.setattr(aug, "DENSE_SIZE_THRESHOLD", 10)
    monkeypatch.setattr(aug, "AUGMENTED_DENSE_SIZE_THRESHOLD", 10)
    assert augmented_spectral_radius(P, A, C, L, delays) == pytest.approx(dense, abs=1e-8)
    assert delay_free_spectral_radius(P, A, C, L) == pytest.approx(
        spectral_radius(delay_free_closed_loop(P, A, C, L)), abs=1e-8
    )
    assert delay_bound_lcsys(P, A, C, L, 3) == pytest.approx(_bound_rho(P, A, C, L, 3) ** 0.25)
    assert len(calls) == 3


def test_method_validation():
    P, A, C = example()
    L = random_gains(np.random.default_rng(0), C)
    zero = np.zeros((4, 4), dtype=int)
    with pytest.raises(ValueError, match="method"):
        augmented_spectral_radius(P, A, C, L, zero, method="arpack")
    with pytest.raises(ValueError, match="outside"):
        augmented_spectral_radius(P, A, C, L, np.full((4, 4), 3) - 3 * np.eye(4, dtype=int), 1)


# ---------------------------------------------------------------------------
# tau = 0 reduces to the delay-free quantities
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tau_zero_reduces_to_delay_free(seed):
    P, A, C, L, _ = random_instance(20 + seed, 5, 3, 0)
    Ahat = delay_free_closed_loop(P, A, C, L)
    rho = spectral_radius(Ahat)
    zero = np.zeros(P.shape, dtype=int)
    for comp in (True, False):
        np.testing.assert_allclose(
            augmented_closed_loop(P, A, C, L, zero, 0, comp), Ahat, atol=1e-14
        )
        for method in ("dense", "structured", "auto"):
            assert augmented_spectral_radius(P, A, C, L, zero, 0, comp, method) == pytest.approx(
                rho, abs=1e-10
            )
    assert delay_free_spectral_radius(P, A, C, L) == pytest.approx(rho, rel=1e-13)
    assert delay_bound_lcsys(P, A, C, L, 0) == pytest.approx(rho, rel=1e-12)
    assert delay_bound_tolerant(P, A, C, L, 0) == pytest.approx(rho, rel=1e-12)
    report = tau_star_report(P, A, C, L, tau_max=0)
    assert report.values == (pytest.approx(rho, rel=1e-12),)
    assert report.values[0] == pytest.approx(
        spectral_radius((np.eye(15) - gain_product(L, C)) @ np.kron(P, A)), rel=1e-12
    )
    assert report.contiguous == (0 if rho < 1 else None)
    assert report.isolated == ()
    for rate in (decay_rate_lcsys(P, A, C, L, 0), decay_rate_tolerant(P, A, C, L, 0)):
        if rho < 1:
            assert rate == pytest.approx(1 - rho, rel=1e-12)
        else:
            assert rate is None
    assert convergence_time_augmented(P, A, C, L, zero) == pytest.approx(
        convergence_time_delay_free(P, A, C, L)
    )
    # the growth of one step is log ||A-hat||_2
    g = closed_loop_sequence_growth(P, A, C, L, [zero], 0)
    assert g == pytest.approx(np.log(np.linalg.norm(Ahat, 2)), rel=1e-12)


# ---------------------------------------------------------------------------
# bounds, tau* report and convergence orders
# ---------------------------------------------------------------------------


def test_delay_bound_tolerant_and_decay_rates():
    P, A, C = example()
    L = [0.9 * Ci.T for Ci in C]
    rho = spectral_radius(delay_free_closed_loop(P, A, C, L))
    assert rho < 1
    for tau in (1, 4, 9):
        assert delay_bound_tolerant(P, A, C, L, tau) == pytest.approx(rho ** (1 / (tau + 1)))
        assert decay_rate_tolerant(P, A, C, L, tau) == pytest.approx(1 - rho ** (1 / (tau + 1)))
        lc = delay_bound_lcsys(P, A, C, L, tau)
        rate = decay_rate_lcsys(P, A, C, L, tau)
        assert (rate is None) == (lc >= 1)
        if rate is not None:
            assert rate == pytest.approx(1 - lc, rel=1e-12)
    # longer delays decay more slowly (eq. 17)
    rates = [decay_rate_tolerant(P, A, C, L, t) for t in range(6)]
    assert all(a > b for a, b in zip(rates, rates[1:], strict=False))
    # beyond tau*, eq. (14) has no decay rate
    ts = tau_star(P, A, C, L, tau_max=60)
    assert decay_rate_lcsys(P, A, C, L, ts) is not None
    assert decay_rate_lcsys(P, A, C, L, ts + 1) is None


def test_convergence_time_order():
    assert convergence_time_order(0.0) == 1.0
    assert convergence_time_order(0.9) == pytest.approx(10.0)
    assert convergence_time_order(1.0) == np.inf
    assert convergence_time_order(1.3) == np.inf
    assert decay_rate(0.81, 1) == pytest.approx(0.1)
    assert decay_rate(0.0, 3) == 1.0
    assert decay_rate(1.0, 3) is None
    assert decay_rate(np.inf, 0) is None
    for bad in (-0.1, np.nan):
        with pytest.raises(ValueError):
            convergence_time_order(bad)
        with pytest.raises(ValueError):
            decay_rate(bad, 1)
    with pytest.raises(ValueError, match="tau"):
        decay_rate(0.5, -1)


def test_tau_star_report_matches_tau_star():
    P, A, C = example()
    L = [0.9 * Ci.T for Ci in C]
    report = tau_star_report(P, A, C, L, tau_max=40)
    assert isinstance(report, TauStar)
    assert report.tau_max == 40 and len(report.values) == 41
    assert report.contiguous == tau_star(P, A, C, L, tau_max=40)
    for t in (0, 5, 17):
        assert report.values[t] == pytest.approx(_bound_rho(P, A, C, L, t), rel=1e-12)
    assert report.passing[: report.contiguous + 1] == tuple(range(report.contiguous + 1))
    with pytest.raises(AttributeError):
        report.contiguous = 3  # frozen
    # a Schur-stable A never fails; an unstable open loop fails at tau = 0
    A_stable = 0.5 * A / np.max(np.abs(np.linalg.eigvals(A)))
    assert tau_star_report(P, A_stable, C, L, tau_max=12).contiguous == 12
    zero = [np.zeros((6, 1)) for _ in C]
    rep = tau_star_report(P, A, C, zero, tau_max=5)
    assert rep.contiguous is None and rep.isolated == () and rep.passing == ()


def non_monotone_instance():
    """A has eigenvalue -1.05 (the sign of A^(tau+1) alternates with tau) and the stable
    complex pair 0.95 exp(+-0.33 i); N = 2 agents, one output each."""
    c, s = 0.95 * np.cos(0.33), 0.95 * np.sin(0.33)
    A = np.array([[-1.05, 0.4, 0.4], [0.0, c, -s], [0.0, s, c]])
    P = np.array([[0.38, 0.62], [0.71, 0.29]])
    C = [np.array([[0.9, -0.4, -0.4]]), np.array([[-0.3, -0.9, -0.9]])]
    L = [np.array([[0.3], [-0.9], [0.1]]), np.array([[0.9], [-0.6], [-0.8]])]
    return P, A, C, L


def test_tau_star_report_non_monotone():
    P, A, C, L = non_monotone_instance()
    eig = np.linalg.eigvals(A)
    assert np.min(eig.real) == pytest.approx(-1.05) and np.sum(np.abs(eig.imag) > 0) == 2
    report = tau_star_report(P, A, C, L, tau_max=12)
    v = np.array(report.values)
    for t in range(13):
        assert v[t] == pytest.approx(_bound_rho(P, A, C, L, t), rel=1e-12)
    assert not report.monotone
    # pass (0), fail (1), pass (2), fail (3), pass (4), fail (5), pass (6), fail from 7
    assert report.contiguous == 0 == tau_star(P, A, C, L, tau_max=12)
    assert report.isolated == (2, 4, 6)
    assert report.passing == (0, 2, 4, 6)
    assert np.all(v[[0, 2, 4, 6]] < 0.92) and np.all(v[[1, 3, 5]] > 1.3)
    # Lemma 4: with every link (self-loops included) delayed by tau the exact
    # augmented spectral radius is values[tau]^(1/(tau+1)), so tau = 2 really is stable
    # although tau = 1 is not
    G = np.eye(6) - gain_product(L, C)
    for tau in (1, 2, 3, 4):
        Ahom = augmented_consensus(
            [np.zeros((6, 6))] * tau + [G @ np.kron(P, np.linalg.matrix_power(A, tau + 1))]
        )
        rho_hom = spectral_radius(Ahom)
        assert rho_hom == pytest.approx(v[tau] ** (1 / (tau + 1)), rel=1e-9)
        assert (rho_hom < 1) == (v[tau] < 1)


def test_paper_bounds_fail_for_heterogeneous_delays():
    """Scalar counterexample (N = 2, n = 1) to LCSYS2022 eq. (26) and to the
    delay-tolerant paper's rho(A-hat)^(1/(tau+1)) as bounds for heterogeneous delays:
    only the link 1 -> 0 is delayed (by 1). Checked against the roots of
    det(lam^2 I - lam M_0 - M_1) formed by hand."""
    a = -1.5
    P = np.array([[0.7, 0.3], [0.7, 0.3]])
    A = np.array([[a]])
    C = [np.eye(1), np.eye(1)]
    L = [np.array([[1.8]]), np.array([[-1.0]])]
    G = np.diag([1 - 1.8, 1 + 1.0])
    delays = np.array([[0, 1], [0, 0]])
    P0, P1 = np.array([[0.7, 0.0], [0.7, 0.3]]), np.array([[0.0, 0.3], [0.0, 0.0]])

    def rho_by_hand(M0, M1):
        # det of the 2x2 polynomial matrix lam^2 I - lam M0 - M1 (coefficients, high first)
        Q = [
            [np.array([1.0 if i == j else 0.0, -M0[i, j], -M1[i, j]]) for j in range(2)]
            for i in range(2)
        ]
        det = np.polysub(np.polymul(Q[0][0], Q[1][1]), np.polymul(Q[0][1], Q[1][0]))
        return np.max(np.abs(np.roots(det)))

    rho0 = spectral_radius(delay_free_closed_loop(P, A, C, L))
    assert rho0 == pytest.approx(0.06)  # rank one: a (0.7 (-0.8) + 0.3 (2.0))
    assert delay_bound_lcsys(P, A, C, L, 1) == pytest.approx(0.3)  # sqrt(a^2 0.04)
    assert delay_bound_tolerant(P, A, C, L, 1) == pytest.approx(0.06**0.5)
    comp = augmented_spectral_radius(P, A, C, L, delays, compensated=True)
    unc = augmented_spectral_radius(P, A, C, L, delays, compensated=False)
    assert comp == pytest.approx(rho_by_hand(G @ P0 * a, G @ P1 * a**2), rel=1e-12)
    assert unc == pytest.approx(rho_by_hand(G @ P0 * a, G @ P1 * a), rel=1e-12)
    assert comp > 1.25 and unc > 1.2  # unstable although both "bounds" are < 1


# ---------------------------------------------------------------------------
# time-varying delays: growth rate of the product
# ---------------------------------------------------------------------------


def test_sequence_growth_exact_for_short_products():
    rng = np.random.default_rng(30)
    P, A, C, L, _ = random_instance(30, 4, 3, 2)
    tau = 2
    pats = []
    for _ in range(3):
        d = rng.integers(0, tau + 1, P.shape)
        np.fill_diagonal(d, 0)
        pats.append(d)
    for comp in (True, False):
        Ms = [augmented_closed_loop(P, A, C, L, d, tau, comp) for d in pats]
        prod = Ms[2] @ Ms[1] @ Ms[0]
        g = closed_loop_sequence_growth(P, A, C, L, pats, tau, comp)
        assert g == pytest.approx(np.log(np.linalg.norm(prod, 2)) / 3, rel=1e-10)
    with pytest.raises(ValueError, match="at least one"):
        closed_loop_sequence_growth(P, A, C, L, [], tau)
    bad = pats[0].copy()
    bad[P != 0] = tau + 1
    np.fill_diagonal(bad, 0)
    with pytest.raises(ValueError, match=r"delay_patterns\[1\].*outside"):
        closed_loop_sequence_growth(P, A, C, L, [pats[0], bad], tau)


@pytest.mark.parametrize("compensated", [True, False])
def test_sequence_growth_constant_pattern_tends_to_log_rho(compensated):
    P, A, C, L, delays = random_instance(31, 4, 3, 3)
    tau = 3
    rho = augmented_spectral_radius(P, A, C, L, delays, tau, compensated, method="dense")
    errors = []
    for k in (25, 100, 400, 1600):
        g = closed_loop_sequence_growth(P, A, C, L, [delays] * k, tau, compensated)
        errors.append(abs(g - np.log(rho)))
    assert errors[-1] < 5e-3
    assert errors[-1] < errors[0] / 10
    # Gelfand: (1/k) log ||M^k|| >= log rho for every k
    g = closed_loop_sequence_growth(P, A, C, L, [delays] * 50, tau, compensated)
    assert g >= np.log(rho) - 1e-12


def test_sequence_growth_block_mode_tracks_full_mode():
    """Above full_max the product is applied to random orthonormal vectors: a lower
    bound that is within O(1/k) of the full value."""
    rng = np.random.default_rng(32)
    P, A, C, L, _ = random_instance(32, 5, 3, 3)
    tau, k = 3, 300
    pats = []
    for _ in range(k):
        d = rng.integers(0, tau + 1, P.shape)
        np.fill_diagonal(d, 0)
        pats.append(d)
    full = closed_loop_sequence_growth(P, A, C, L, pats, tau)
    block = closed_loop_sequence_growth(P, A, C, L, pats, tau, full_max=0, block=8, seed=1)
    assert block <= full + 1e-12
    assert full - block < 10 / k
    one = closed_loop_sequence_growth(P, A, C, L, pats, tau, full_max=0, block=1, seed=2)
    assert one <= full + 1e-12 and full - one < 20 / k


# ---------------------------------------------------------------------------
# ARPACK robustness: clustered top moduli, ill-conditioning, retries
# ---------------------------------------------------------------------------


def _clustered_instance(tau):
    """Homogeneous delays on a ring with self-loops (delay 0), the shape of
    lcsys2022-homogeneous: the companion spectrum has many eigenvalues of nearly the
    same modulus (the case tests/test_analysis.py checks on the scenario itself, where
    ARPACK with 40 Krylov vectors did not converge)."""
    rng = np.random.default_rng(7)
    N, n = 4, 6
    mask = np.eye(N, dtype=bool) | np.roll(np.eye(N, dtype=bool), 1, axis=1)
    mask[0, 2] = True
    P = stoch(rng, mask.astype(float))
    A = rng.standard_normal((n, n))
    A *= 1.05 / np.max(np.abs(np.linalg.eigvals(A)))
    C = [np.eye(n)[[i % n, (i + 3) % n]] for i in range(N)]
    L = [0.3 * Ci.T for Ci in C]
    delays = np.full((N, N), tau)
    np.fill_diagonal(delays, 0)
    return P, A, C, L, delays


@pytest.mark.parametrize("tau,compensated", [(30, False), (30, True), (17, False)])
def test_structured_agrees_with_dense_on_clustered_spectra(tau, compensated):
    """Structured equals dense eigvals to 1e-10 without the dense fallback (no warning),
    where the top moduli are clustered (checked here from the dense spectrum)."""
    P, A, C, L, delays = _clustered_instance(tau)
    M = augmented_closed_loop(P, A, C, L, delays, tau, compensated)
    moduli = np.sort(np.abs(np.linalg.eigvals(M)))[::-1]
    dense = moduli[0]
    assert moduli[0] - moduli[7] < 2e-2 * moduli[0]  # a genuinely clustered top
    with warnings_as_errors():
        value = augmented_spectral_radius(P, A, C, L, delays, tau, compensated, "structured")
    assert value == pytest.approx(dense, abs=1e-10)


@pytest.mark.parametrize("seed", range(4))
def test_structured_agrees_with_dense_when_ill_conditioned(seed):
    """A non-normal A (a Jordan-like block with large off-diagonal, in a badly scaled
    basis, condition number ~1e3-1e6): structured equals dense to 1e-10 (relative)."""
    rng = np.random.default_rng(200 + seed)
    N, n, tau = 5, 4, 9
    P, _, C, L, delays = random_instance(300 + seed, N, n, tau, homogeneous=seed % 2 == 0)
    J = 0.99 * np.eye(n) + np.diag(np.full(n - 1, 10.0 ** (seed % 3)), 1)
    S = rng.standard_normal((n, n))
    S[:, 0] *= 1e-3
    A = S @ J @ np.linalg.inv(S)
    assert np.linalg.cond(S) > 1e3
    for comp in (True, False):
        dense = augmented_spectral_radius(P, A, C, L, delays, tau, comp, "dense")
        with warnings_as_errors():
            value = augmented_spectral_radius(P, A, C, L, delays, tau, comp, "structured")
        assert value == pytest.approx(dense, rel=1e-10, abs=1e-12)


def test_arpack_retries_with_a_larger_krylov_space(monkeypatch):
    """A run that does not converge is retried with twice the power and twice the Krylov
    space (another start vector) before any dense fallback: the answer comes from ARPACK,
    with no warning."""
    from scipy.sparse.linalg import ArpackNoConvergence, eigs

    P, A, C, L, delays = random_instance(5, 16, 4, 9)  # 640 rows: room for a retry
    dense = augmented_spectral_radius(P, A, C, L, delays, method="dense")
    calls = []

    def flaky(op, **kwargs):
        calls.append(kwargs["ncv"])
        if len(calls) == 1:
            raise ArpackNoConvergence("ARPACK error -1: No convergence", np.array([]), None)
        return eigs(op, **kwargs)

    monkeypatch.setattr(aug, "eigs", flaky)
    monkeypatch.setattr(aug, "_dense_operator_rho", lambda *a: pytest.fail("dense fallback"))
    with warnings_as_errors():
        value = augmented_spectral_radius(P, A, C, L, delays, method="structured")
    assert value == pytest.approx(dense, abs=1e-10)
    assert len(calls) == 2 and calls[1] >= calls[0]
    attempts = aug._arpack_attempts(8, 10_000, aug.ARPACK_K)
    assert [j for j, _, _ in attempts] == [8 * 2**s for s in range(aug.ARPACK_RETRIES + 1)]
    assert [c for _, c, _ in attempts] == sorted(c for _, c, _ in attempts)
    assert [m for _, _, m in attempts] == sorted((m for _, _, m in attempts), reverse=True)
    # no retry whose Krylov space is a quarter of the dimension: dense is cheaper
    assert all(c <= 744 // 4 for _, c, _ in aug._arpack_attempts(8, 744, aug.ARPACK_K)[1:])
    # the Krylov basis stays within ARPACK_BASIS_BYTES at large sizes
    big = 10**7
    assert all(8 * big * c <= max(aug.ARPACK_BASIS_BYTES, 8 * big * (2 * aug.ARPACK_K + 1))
               for _, c, _ in aug._arpack_attempts(8, big, aug.ARPACK_K))


@contextlib.contextmanager
def warnings_as_errors():
    """A RuntimeWarning (the structured method's dense fallback) fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        yield
