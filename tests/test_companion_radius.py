"""The structured radius of the augmented closed loop with its tuned ARPACK settings.

Issue 34: ``augmented_spectral_radius`` runs ARPACK on ``M^48`` with 40 Krylov vectors
(``AUGMENTED_ARPACK_POWER``, ``AUGMENTED_ARPACK_NCV``) above 120 rows. Each value is
checked against ``numpy.linalg.eigvals`` of the whole block companion matrix built here
from scratch (a second implementation), to 1e-10 relative, on random instances and on
the shipped scenario, across tau, with complex dominant eigenvalues, clustered top
moduli, and radii far from 1 (where the high power would over- or underflow).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from netsim.models import augmented as aug


def _companion(P, A, C, L, delays, compensated):
    """The augmented closed loop, LCSYS2022 eq. (10), from its definition."""
    N, n = P.shape[0], A.shape[0]
    tau = int(delays[P != 0].max())
    G = np.zeros((N * n, N * n))
    for i in range(N):
        G[i * n:(i + 1) * n, i * n:(i + 1) * n] = np.eye(n) - L[i] @ C[i]
    D = N * n * (tau + 1)
    M = np.zeros((D, D))
    for r in range(tau + 1):
        Pr = np.where((P != 0) & (delays == r), P, 0.0)
        B = np.linalg.matrix_power(A, r + 1) if compensated else A
        M[:N * n, r * N * n:(r + 1) * N * n] = G @ np.kron(Pr, B)
    M[N * n:, :-N * n] = np.eye(tau * N * n)
    return M


def _instance(seed, N=3, n=3):
    rng = np.random.default_rng(seed)
    P = rng.uniform(0.1, 1.0, (N, N)) * (rng.uniform(size=(N, N)) < 0.7)
    np.fill_diagonal(P, rng.uniform(0.2, 1.0, N))
    P /= P.sum(axis=1, keepdims=True)
    A = rng.standard_normal((n, n)) / np.sqrt(n)
    C = [rng.standard_normal((1, n)) for _ in range(N)]
    L = [0.3 * rng.standard_normal((n, 1)) for _ in range(N)]
    return P, A, C, L


def _check(P, A, C, L, delays, compensated):
    """Structured equals dense to 1e-10; returns the dense eigenvalues."""
    eig = np.linalg.eigvals(_companion(P, A, C, L, delays, compensated))
    dense = float(np.max(np.abs(eig)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ARPACK failure, no dense fallback
        value, how = aug.augmented_radius_and_method(P, A, C, L, delays,
                                                     compensated=compensated)
    assert how == ("ARPACK" if len(eig) > aug.AUGMENTED_DENSE_SIZE_THRESHOLD
                   else "dense eigenvalues")
    assert value == pytest.approx(dense, rel=1e-10)
    return eig


def _top(eig):
    order = np.argsort(-np.abs(eig))
    return eig[order]


def test_random_instances_across_tau():
    tops = []
    for seed in range(6):
        P, A, C, L = _instance(seed)
        N = P.shape[0]
        off = (P != 0) & ~np.eye(N, dtype=bool)
        for tau in (2, 4, 9, 15):  # 27 .. 144 rows: both sides of the dense threshold
            for compensated in (True, False):
                tops.append(_top(_check(P, A, C, L, np.where(off, tau, 0), compensated))[0])
        # heterogeneous delays too (LCSYS2022 eq. 3: each link its own)
        rng = np.random.default_rng(100 + seed)
        delays = np.where(off, rng.integers(0, 16, (N, N)), 0)
        delays[0, 1], P[0, 1] = 16, max(P[0, 1], 0.1)
        for compensated in (True, False):
            tops.append(_top(_check(P, A, C, L, delays, compensated))[0])
    complex_top = sum(abs(z.imag) > 1e-8 for z in tops)
    assert 0 < complex_top < len(tops)  # complex and real dominant eigenvalues


@pytest.mark.parametrize("scale", [1e-7, 1e-3, 1e3, 1e7])
def test_radii_far_from_one_are_exact(scale):
    """Companions whose roots lie far from the unit circle (135 rows). Compensated with
    G = I, the radius for ``scale * A`` is exactly ``scale`` times the one for ``A``
    (block similarity by ``diag(scale^-s)``); before the root scaling
    (``_root_scale``) ARPACK returned values off by 1 % to 80x here, unflagged."""
    P, A, C, L = _instance(3)
    delays = np.where((P != 0) & ~np.eye(3, dtype=bool), 14, 0)
    zero = [Li * 0 for Li in L]
    _check(P, A, C, zero, delays, True)
    base = aug.augmented_spectral_radius(P, A, C, zero, delays, compensated=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        value = aug.augmented_spectral_radius(P, scale * A, C, zero, delays, compensated=True)
    assert value == pytest.approx(scale * base, rel=1e-10)
    if 1e-3 <= scale <= 1e3:  # the dense reference is well conditioned here
        _check(P, scale * A, C, L, delays, True)
        _check(P, scale * A, C, L, delays, False)


@pytest.mark.parametrize("scale", [1e-5, 1e5])
def test_a_power_that_would_over_or_underflow_is_replaced(scale, monkeypatch):
    """Unscaled (``ROOT_SCALE_FREE`` raised), rho^48 of about 1e-240 or 1e240 (tau = 0,
    147 rows: no shift, ARPACK is exact at any scale): the first run takes
    ``M^ARPACK_POWER`` instead and no run fails."""
    powers = []
    real = aug._FirstRow.companion_power

    def spy(self, X, q=1):
        powers.append(q)
        return real(self, X, q)

    P, A, C, L = _instance(4, N=21, n=7)
    delays = np.zeros(P.shape, dtype=int)
    monkeypatch.setattr(aug, "ROOT_SCALE_FREE", 10**6)
    monkeypatch.setattr(aug._FirstRow, "companion_power", spy)
    _check(P, scale * A, C, L, delays, True)
    assert powers[0] == aug.AUGMENTED_ARPACK_POWER and aug.ARPACK_POWER in powers


def test_the_scenarios_clustered_top_moduli():
    """The LCSYS2022 scenario, uncompensated, tau = 14 (360 rows): top moduli within
    1e-3 of each other, the dominant ones complex."""
    from helpers import lcsys

    from netsim.runner import scenario_gains

    scenario = lcsys()
    gains = scenario_gains(scenario)
    P, A, C, L = scenario.weights, scenario.plant.A, scenario.plant.C, gains.L
    delays = np.where((P > 0) & ~np.eye(4, dtype=bool), 14, 0)
    top = _top(_check(P, A, C, L, delays, False))
    assert abs(top[0].imag) > 1e-8
    assert abs(top[5]) > abs(top[0]) * (1 - 1e-3)  # clustered
    _check(P, A, C, L, delays, True)


def test_a_spurious_ritz_value_is_rejected():
    """A strongly non-normal companion (n = 1, A = -0.398, compensated, tau = 24: the
    last first-row block is of size 0.4^25 beside identity blocks): ARPACK on M^48 with
    40 vectors returned 0.39808, no eigenvalue, with a residual within its operator-norm
    check. The eigenvector check against M itself rejects it; the value returned is a
    root modulus: T(z) = I - sum_r z^-(r+1) M_r is singular at z = -rho, and not at
    z = -0.39808 (scanned by hand: the smallest singular value on that circle, 0.09, is
    at the negative axis)."""
    P = np.array([
        [0.12631751967716823, 0.17315931308474516, 0.09993278559356283, 0.22109249829858058,
         0.37949788334594314],
        [0.25776065278565247, 0.0, 0.44653068473299246, 0.2957086624813549, 0.0],
        [0.20665747162087675, 0.0, 0.4376279343243122, 0.10556227986157449,
         0.25015231419323675],
        [0.46013871415519714, 0.13612083587414098, 0.4037404499706619, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0, 0.0]])
    A = np.array([[-0.398105405432532]])
    C = [np.array([[c]]) for c in (1.5321064660580506, -0.41508220216800257,
                                   1.540961415332024, 0.3534616216663202,
                                   -0.2355253706657324)]
    L = [np.array([[g]]) for g in (0.00826312490901077, -0.18125513728461645,
                                   0.32197698300234584, -0.41435618386821693,
                                   0.028574544312562348)]
    delays = np.where((P != 0) & ~np.eye(5, dtype=bool), 24, 0)
    M = _companion(P, A, C, L, delays, True)
    blocks = [M[:5, 5 * r:5 * (r + 1)] for r in range(25)]

    def smallest_singular_value(z):
        T = np.eye(5, dtype=complex) - sum(z ** -(r + 1) * B for r, B in enumerate(blocks))
        return np.linalg.svd(T, compute_uv=False)[-1]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # may end in the dense fallback
        rho = aug.augmented_spectral_radius(P, A, C, L, delays, compensated=True)
    assert smallest_singular_value(-rho) < 1e-9
    assert smallest_singular_value(-0.39808070906571935) > 1e-2
    assert rho == pytest.approx(np.max(np.abs(np.linalg.eigvals(M))), rel=1e-9)  # dense too
