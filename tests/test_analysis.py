"""Scenario analytics (netsim analyze / design) against independent computations."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import lcsys, with_delays

from netsim.analysis import analyze
from netsim.cli import main
from netsim.runner import scenario_gains


@pytest.fixture(scope="module")
def scenario():
    return lcsys()


@pytest.fixture(scope="module")
def gains(scenario):
    return scenario_gains(scenario)


def _dense_exact(P, A, C, L, tau, compensated):
    """The augmented closed loop of LCSYS2022 eq. (9)-(10) built here from scratch."""
    N, n = P.shape[0], A.shape[0]
    KD = np.zeros((N * n, N * n))
    for i in range(N):
        KD[i * n:(i + 1) * n, i * n:(i + 1) * n] = L[i] @ C[i]
    G = np.eye(N * n) - KD
    P0 = np.diag(np.diag(P))
    Ptau = P - P0
    size = N * n * (tau + 1)
    M = np.zeros((size, size))
    if tau == 0:
        M[:N * n, :N * n] = G @ np.kron(P, A)
    else:
        M[:N * n, :N * n] = G @ np.kron(P0, A)
        Ar = np.linalg.matrix_power(A, tau + 1) if compensated else A
        M[:N * n, tau * N * n:] = G @ np.kron(Ptau, Ar)
        M[N * n:, :-N * n] = np.eye(tau * N * n)
    return max(abs(np.linalg.eigvals(M)))


def test_homogeneous_table_matches_independent_matrices(scenario, gains):
    report = analyze(scenario, gains, tau_max=12)
    P, A, C, L = scenario.weights, scenario.plant.A, scenario.plant.C, gains.L
    assert [row.tau for row in report.rows] == list(range(13))
    for row in report.rows:
        comp = _dense_exact(P, A, C, L, row.tau, True)
        uncomp = _dense_exact(P, A, C, L, row.tau, False)
        assert row.rho_compensated == pytest.approx(comp, abs=1e-8)
        assert row.rho_uncompensated == pytest.approx(uncomp, abs=1e-8)
        # eq. (26): rho((I-KD)(P kron A^(tau+1)))^(1/(tau+1)), computed here
        G = np.eye(24) - np.kron(np.eye(4), np.eye(6)) @ _kd(L, C)
        b = max(abs(np.linalg.eigvals(G @ np.kron(P, np.linalg.matrix_power(A, row.tau + 1)))))
        assert row.bound_eq26 == pytest.approx(b ** (1 / (row.tau + 1)), rel=1e-10)
        # a bound is flagged violated exactly when the exact value exceeds it
        assert (row.verdict_eq26 == "violated") == (comp > row.bound_eq26 + 1e-9)
        assert (row.verdict_tolerant == "violated") == (uncomp > row.bound_tolerant + 1e-9)
    # tau = 0: every augmented quantity is the delay-free one
    first = report.rows[0]
    for value in (first.rho_compensated, first.rho_uncompensated, first.bound_eq26,
                  first.bound_tolerant):
        assert value == pytest.approx(gains.rho, abs=1e-10)
    # Theorem 1's tau* is where the eq. (26) quantity crosses 1
    star = report.tau_star
    assert report.rows[star].bound_eq26 < 1 <= report.rows[star + 1].bound_eq26
    # violations are listed with both numbers
    for row in report.rows:
        if row.verdict_eq26 == "violated":
            assert any(f"tau = {row.tau}:" in v and f"{row.bound_eq26:.6f}" in v
                       for v in report.violations)


def _kd(L, C):
    N, n = len(C), C[0].shape[1]
    KD = np.zeros((N * n, N * n))
    for i in range(N):
        KD[i * n:(i + 1) * n, i * n:(i + 1) * n] = L[i] @ C[i]
    return KD


def test_realised_fixed_delays_are_analysed(scenario, gains):
    fixed = with_delays(scenario, model="fixed",
                        links={(0, 1): 2.0, (1, 2): 0.0, (2, 3): 4.0, (3, 0): 1.0})
    report = analyze(fixed, gains, tau_max=2)
    assert report.realised["delays"] == {"0->1": 2, "1->2": 0, "2->3": 4, "3->0": 1}
    assert report.realised["max_delay"] == 4


def test_analyze_command_reports_homogeneous_0_to_30(capsys):
    assert main(["analyze", "lcsys2022-homogeneous", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    rows = data["homogeneous"]
    assert [r["tau"] for r in rows] == list(range(31))
    for r in rows:
        for key in ("rho_compensated", "bound_eq26", "verdict_eq26", "rho_uncompensated",
                    "bound_tolerant", "verdict_tolerant"):
            assert key in r
    assert data["tau_star"] is not None
    flagged = [r["tau"] for r in rows if r["verdict_eq26"] == "violated"]
    assert all(any(f"tau = {t}:" in v for v in data["violations"]) for t in flagged)


def test_structured_matches_dense_on_the_scenario_at_tau_30(scenario, gains):
    """The uncompensated loop of lcsys2022-homogeneous at tau = 30 (744 rows; its top
    ten moduli lie within 2e-4 of each other) is where ARPACK with 40 Krylov vectors
    failed and fell back to dense (10 s and a RuntimeWarning): the structured method now
    converges, with no warning, to the dense eigvals value within 1e-10."""
    import warnings

    from netsim.models.augmented import augmented_spectral_radius

    P, A, C, L = scenario.weights, scenario.plant.A, scenario.plant.C, gains.L
    for tau, comp in ((30, False), (30, True), (12, False)):
        delays = np.where((P > 0) & ~np.eye(4, dtype=bool), tau, 0)
        dense = _dense_exact(P, A, C, L, tau, comp)
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            value = augmented_spectral_radius(P, A, C, L, delays, tau, comp, "structured")
        assert value == pytest.approx(dense, abs=1e-10)


def test_parallel_report_is_the_serial_report(scenario, gains):
    """Two worker processes give the same report, in the same order, as one; the
    progress callback ticks once per delay pattern either way."""
    fixed = with_delays(scenario, model="fixed",
                        links={(0, 1): 2.0, (1, 2): 0.0, (2, 3): 4.0, (3, 0): 1.0})
    ticks = {1: [], 2: []}
    reports = {w: analyze(fixed, gains, tau_max=14, workers=w, progress=ticks[w].append,
                          cache=False)
               for w in (1, 2)}
    assert reports[1].to_dict() == reports[2].to_dict()
    assert ticks[1] == ticks[2] == [1] * 16
