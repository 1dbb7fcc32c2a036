"""Verdicts from the joint system of plant state and estimation error (issue 28).

Independent computations, written here from the estimators' equations (LCSYS2022 eqs.
4-5; delay-tolerant eqs. 6-7) and not from netsim.models.jointsystem:

* the full linear system of (x_k, ..., x_{k-D}, x-hat_k, ..., x-hat_{k-D}), agents'
  estimates as the state (not their errors), with the start-up rule of DESIGN.md (a
  neighbour not heard from yet is replaced by the agent's own estimate);
* its error-visible spectrum by the PBH rank tests (observable from the errors
  x_k - x-hat^i_k, reachable from the noise and the prior);
* its exact mean and covariance recursion, hence the exact expected MSE at every step,
  against which the Monte Carlo mean of the simulator is checked;
* synthetic MSE series with a known law (geometric, linear, bounded) for the measured
  rule.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from netsim.models.augmented import augmented_spectral_radius
from netsim.models.jointsystem import (
    BOUNDED,
    GEOMETRIC,
    POLYNOMIAL,
    block_joint_analysis,
    joint_analysis,
)
from netsim.models.scenario import resolve_scenario

from netsim.cli import build_parser, main
from netsim.runner import fixed_delay_matrix, run_monte_carlo, scenario_gains
from netsim.verdicts import (
    DIVERGING,
    GROWTH_TOLERANCE,
    STABLE,
    UNBOUNDED,
    UNDECIDED,
    VERDICT_TABLE,
    judge,
)

ROOT = Path(__file__).resolve().parents[1]
ROTATION = ROOT / "examples" / "rotation-uncompensated.toml"


# -- the independent model: (x history, x-hat history) from the estimator equations ----


def full_system(P, A, C, L, d, compensated, k=None):
    """Update matrix J_k and noise input G of z = (x_k..x_{k-D}, xhat_k..xhat_{k-D}).

    x_k = A x_{k-1} + nu_k; x-hat^i_k = (I - L_i C_i)[p_ii A x-hat^i_{k-1}
    + sum_j p_ij B_ij x-hat^j_{k-1-r_ij}] + L_i (C_i x_k + zeta^i_k), B_ij = A^(r+1)
    (compensated) or A. At step k (given), a neighbour whose first message is not there
    yet (k - 1 - r_ij < 0) is replaced by i's own A x-hat^i_{k-1}; k=None: after
    start-up. Noise vector: (nu, zeta^0, ..., zeta^{N-1}).
    """
    N, n = len(C), A.shape[0]
    D = int(max([d[i, j] for i in range(N) for j in range(N) if P[i, j] and i != j] + [0]))
    nx = n * (D + 1)
    dim = nx + N * n * (D + 1)
    m = [Ci.shape[0] for Ci in C]
    J = np.zeros((dim, dim))
    G = np.zeros((dim, n + sum(m)))

    def x(lag):
        return slice(lag * n, (lag + 1) * n)

    def h(lag, i):
        start = nx + lag * N * n + i * n
        return slice(start, start + n)

    J[x(0), x(0)] = A
    G[x(0), :n] = np.eye(n)
    for lag in range(1, D + 1):
        J[x(lag), x(lag - 1)] = np.eye(n)
        for i in range(N):
            J[h(lag, i), h(lag - 1, i)] = np.eye(n)
    offset = n
    for i in range(N):
        Gi = np.eye(n) - L[i] @ C[i]
        own = P[i, i]
        for j in range(N):
            if j == i or P[i, j] == 0:
                continue
            r = int(d[i, j])
            if k is not None and k - 1 - r < 0:
                own += P[i, j]
                continue
            B = np.linalg.matrix_power(A, r + 1) if compensated else A
            J[h(0, i), h(r, j)] += P[i, j] * Gi @ B
        J[h(0, i), h(0, i)] += own * Gi @ A
        J[h(0, i), x(0)] += L[i] @ C[i] @ A
        G[h(0, i), :n] = L[i] @ C[i]
        G[h(0, i), offset:offset + m[i]] = L[i]
        offset += m[i]
    E = np.zeros((N * n, dim))  # errors x_k - x-hat^i_k
    for i in range(N):
        E[i * n:(i + 1) * n, x(0)] = np.eye(n)
        E[i * n:(i + 1) * n, h(0, i)] = -np.eye(n)
    return J, G, E, D


def exact_mse(P, A, C, L, d, compensated, Q, R, x0_mean, x0_cov, steps):
    """The exact expected network MSE (1/N) sum_i E||x_k - x-hat^i_k||^2, k = 0..steps,
    by the mean and covariance recursion of the full system (start-up included)."""
    N, n = len(C), A.shape[0]
    J, G, E, D = full_system(P, A, C, L, d, compensated)
    W = np.zeros((G.shape[1], G.shape[1]))
    W[:n, :n] = Q
    o = n
    for Ri in R:
        W[o:o + Ri.shape[0], o:o + Ri.shape[0]] = Ri
        o += Ri.shape[0]
    dim = J.shape[0]
    # step 0: x_0 ~ (x0_mean, x0_cov); x-hat^i_0 = prior + L_i (C_i x_0 + zeta - C_i prior)
    M0 = np.zeros((dim, n))
    c0 = np.zeros(dim)
    nx = n * (D + 1)
    M0[:n] = np.eye(n)
    G0 = G.copy()
    G0[:, :n] = 0  # no process noise at step 0
    for i in range(N):
        rows = slice(nx + i * n, nx + (i + 1) * n)
        M0[rows] = L[i] @ C[i]
        c0[rows] = (np.eye(n) - L[i] @ C[i]) @ x0_mean
    mu = M0 @ x0_mean + c0
    S = M0 @ x0_cov @ M0.T + G0 @ W @ G0.T
    GWG = G @ W @ G.T
    out = np.zeros(steps + 1)
    out[0] = (np.sum((E @ mu) ** 2) + np.trace(E @ S @ E.T)) / N
    for k in range(1, steps + 1):
        Jk = full_system(P, A, C, L, d, compensated, k)[0] if k <= D else J
        mu = Jk @ mu
        S = Jk @ S @ Jk.T + GWG
        out[k] = (np.sum((E @ mu) ** 2) + np.trace(E @ S @ E.T)) / N
    return out


def visible_rho(P, A, C, L, d, compensated, Q, R, S0):
    """max |lambda| over the eigenvalues of the full system that are observable from the
    errors and reachable from the noise or the prior (PBH rank tests)."""
    J, G, E, _ = full_system(P, A, C, L, d, compensated)
    n = A.shape[0]
    W = np.zeros((G.shape[1], G.shape[1]))
    W[:n, :n] = Q
    o = n
    for Ri in R:
        W[o:o + Ri.shape[0], o:o + Ri.shape[0]] = Ri
        o += Ri.shape[0]
    M0 = np.zeros((J.shape[0], n))
    M0[:n] = np.eye(n)
    B = np.hstack([G @ _sqrtm(W), M0 @ _sqrtm(S0)])
    scale = max(1.0, float(np.linalg.norm(J, 2)))
    best = 0.0
    for lam in np.linalg.eigvals(J):
        if abs(lam) < 1e-6:
            continue
        shifted = J - lam * np.eye(len(J))
        observable = np.linalg.svd(np.vstack([shifted, E]), compute_uv=False)[-1] > 1e-7 * scale
        reachable = np.linalg.svd(np.hstack([shifted, B]), compute_uv=False)[-1] > 1e-7 * scale
        if observable and reachable:
            best = max(best, abs(lam))
    return best


def _sqrtm(S):
    w, V = np.linalg.eigh((S + S.T) / 2)
    return V @ np.diag(np.sqrt(np.clip(w, 0, None))) @ V.T


def _random_case(rng, n=2, N=3, radius=1.1, tau=2):
    A = rng.standard_normal((n, n))
    A *= radius / max(abs(np.linalg.eigvals(A)))
    P = np.eye(N) * 0.5
    for i in range(N):
        P[i, (i - 1) % N] = 0.5 * rng.uniform(0.2, 1.0)
        P[i, (i + 1) % N] = 0.5 - P[i, (i - 1) % N]
    d = rng.integers(0, tau + 1, size=(N, N))
    np.fill_diagonal(d, 0)
    C = [rng.standard_normal((1, n)) for _ in range(N)]
    L = [0.3 * rng.standard_normal((n, 1)) for _ in range(N)]
    return P, A, C, L, d


# -- 1. the analysis against the independent full system -----------------------------


@pytest.mark.parametrize("compensated", [True, False])
def test_growth_rate_equals_the_error_visible_spectrum_of_the_full_system(compensated):
    rng = np.random.default_rng(28)
    n = 2
    Q, S0 = 0.01 * np.eye(n), np.eye(n)
    kinds = set()
    for radius in np.linspace(0.6, 1.2, 16):
        P, A, C, L, d = _random_case(rng, radius=radius)
        R = [0.01 * np.eye(1)] * len(C)
        a = joint_analysis(P, A, C, L, d, compensated=compensated, Q=Q,
                           x0_mean=np.zeros(n), x0_cov=S0)
        ref = visible_rho(P, A, C, L, d, compensated, Q, R, S0)
        assert a.rho == pytest.approx(ref, rel=1e-7, abs=1e-9), (A, d)
        full = max(abs(np.linalg.eigvals(full_system(P, A, C, L, d, compensated)[0])))
        if compensated:
            # the plant's modes are invisible in the compensated error
            assert a.rho_forcing == 0 and a.rho == pytest.approx(a.rho_error_recursion)
        elif np.any(d[(P != 0) & ~np.eye(3, dtype=bool)] > 0):
            # the moving state forces the uncompensated error: rho >= rho(A)
            assert a.rho_forcing == pytest.approx(radius) and a.rho >= radius - 1e-12
        kinds.add((a.growth, a.rho < full - 1e-6, a.rho_forcing > a.rho_error_recursion))
    # the sample holds bounded and geometric cases, ones where the full system's largest
    # eigenvalue is invisible, and (uncompensated) ones decided by the forcing
    assert {BOUNDED, GEOMETRIC} <= {k[0] for k in kinds}
    if compensated:
        assert any(k[1] for k in kinds)
    else:
        assert any(k[2] for k in kinds) and any(not k[2] for k in kinds)


def test_a_mode_the_forcing_cancels_is_invisible_in_both_models():
    """lambda = 1 (a random walk) and lambda = -1 with delay 2: x_{k-1} - x_{k-1-r} has no
    component on them, so the uncompensated error does not see them."""
    P = np.array([[0.6, 0.4, 0.0], [0.0, 0.7, 0.3], [0.5, 0.0, 0.5]])
    C = [np.array([[1.0, 0.3]]), np.array([[0.2, 1.0]]), np.array([[1.0, -1.0]])]
    L = [0.4 * Ci.T for Ci in C]
    d = np.array([[0, 2, 0], [0, 0, 2], [2, 0, 0]])
    A = np.diag([1.0, -1.0])
    Q, S0 = 0.01 * np.eye(2), np.eye(2)
    R = [0.01 * np.eye(1)] * 3
    a = joint_analysis(P, A, C, L, d, compensated=False, Q=Q, x0_mean=np.zeros(2), x0_cov=S0)
    assert not any(m.forced for m in a.modes)
    assert a.growth == BOUNDED and a.rho == pytest.approx(a.rho_error_recursion)
    assert visible_rho(P, A, C, L, d, False, Q, R, S0) == pytest.approx(a.rho, rel=1e-7)
    # delay 1 instead: lambda = -1 is no longer cancelled (x_{k-1} - x_{k-2} = 2 x_{k-1})
    d1 = np.minimum(d, 1)
    b = joint_analysis(P, A, C, L, d1, compensated=False, Q=Q, x0_mean=np.zeros(2),
                       x0_cov=S0)
    assert [m.eigenvalue for m in b.modes if m.forced] == [-1.0]
    assert b.growth == POLYNOMIAL
    assert visible_rho(P, A, C, L, d1, False, Q, R, S0) == pytest.approx(1.0, abs=1e-9)


def test_noise_free_modes_and_jordan_blocks():
    P = np.array([[0.5, 0.5], [0.5, 0.5]])
    C = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])]
    L = [0.5 * C[0].T, 0.5 * C[1].T]
    d = np.array([[0, 1], [1, 0]])
    A = np.diag([1.2, 0.5])
    # the unstable mode gets neither noise nor prior: nothing grows
    Q = np.diag([0.0, 0.01])
    a = joint_analysis(P, A, C, L, d, compensated=False, Q=Q, x0_mean=np.zeros(2),
                       x0_cov=np.diag([0.0, 1.0]))
    top = a.modes[0]
    assert top.eigenvalue == pytest.approx(1.2) and top.forced and not top.excited
    assert a.growth == BOUNDED
    # the prior alone excites it: geometric growth at 1.2
    b = joint_analysis(P, A, C, L, d, compensated=False, Q=Q, x0_mean=np.array([1.0, 0.0]),
                       x0_cov=np.diag([0.0, 1.0]))
    assert b.growth == GEOMETRIC and b.mse_growth_factor == pytest.approx(1.44)
    # a double integrator (Jordan block at 1): the velocity random walk forces the error
    # through (A^2 - A) x = velocity terms; the exact MSE grows linearly
    J = np.array([[1.0, 1.0], [0.0, 1.0]])
    R = [0.01 * np.eye(1)] * 2
    c = joint_analysis(P, J, C, L, d, compensated=False, Q=0.01 * np.eye(2),
                       x0_mean=np.zeros(2), x0_cov=np.eye(2))
    assert c.growth == POLYNOMIAL and c.modes[0].defective
    mse = exact_mse(P, J, C, L, d, False, 0.01 * np.eye(2), R, np.zeros(2), np.eye(2), 4000)
    slope = np.diff(mse)
    assert slope[-1] > 0 and abs(slope[-1] / slope[-1000] - 1) < 0.01  # linear
    # ... and the compensating estimator cancels the motion: bounded
    e = joint_analysis(P, J, C, L, d, compensated=True, Q=0.01 * np.eye(2),
                       x0_mean=np.zeros(2), x0_cov=np.eye(2))
    assert e.growth == (BOUNDED if e.rho_error_recursion < 1 else GEOMETRIC)


def test_block_analysis_is_the_compensated_one_on_the_block_time_scale():
    scenario = resolve_scenario("lcsys2022-heterogeneous")
    gains = scenario_gains(scenario)
    plant, tau = scenario.plant, scenario.delay_bound
    b = block_joint_analysis(scenario.weights, plant.A, plant.C, gains.L, tau, Q=plant.Q,
                             x0_mean=plant.x0_mean, x0_cov=plant.x0_cov)
    # independent: rho of (I - L C)(P kron A^(tau+1)) written out, to the power 1/(tau+1)
    N, n = scenario.n_agents, plant.n_states
    G = np.zeros((N * n, N * n))
    for i in range(N):
        G[i * n:(i + 1) * n, i * n:(i + 1) * n] = np.eye(n) - gains.L[i] @ plant.C[i]
    M = G @ np.kron(scenario.weights, np.linalg.matrix_power(plant.A, tau + 1))
    rho = max(abs(np.linalg.eigvals(M))) ** (1 / (tau + 1))
    assert b.rho == pytest.approx(rho, rel=1e-9) and b.growth == BOUNDED and b.period == tau + 1


# -- 2. the LCSYS2022 demo: diverging from the first step ------------------------------


def test_uncompensated_on_the_growing_plant_is_diverging_at_50_steps(capsys):
    assert main(["run", "lcsys2022-heterogeneous", "--steps", "50", "--trials", "2",
                 "--estimators", "uncompensated", "--no-progress", "--json"]) == 0
    e = json.loads(capsys.readouterr().out)["estimators"]["uncompensated"]
    rho_A = max(abs(np.linalg.eigvals(resolve_scenario("lcsys2022-heterogeneous").plant.A)))
    assert rho_A == pytest.approx(1.04)
    assert e["verdict"] == DIVERGING and "steady_state_mse" not in e
    detail = e["verdict_detail"]
    assert detail["basis"] == "exact analysis"
    assert detail["analysis"]["mse_growth_factor"] == pytest.approx(rho_A ** 2, rel=1e-9)
    assert "rho(A)^2 = 1.0816" in detail["reason"]
    # the measurement alone (a decaying transient over 50 steps) would not say so
    assert detail["measured"] != DIVERGING
    assert e["last_trusted_mse"] == e["mse_at"]["50"]
    # the text says why eq. (11)'s radius is not the error's growth here
    assert main(["run", "lcsys2022-heterogeneous", "--steps", "50", "--trials", "2",
                 "--estimators", "uncompensated", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "eq. (11) does not apply here" in out and "valid only for a still state" not in out
    assert "uncompensated: rho = 1.0400 = max(error recursion 0.8898" in out
    row = next(line for line in out.splitlines() if line.startswith("uncompensated "))
    assert row.split()[1] == "diverging" and row.split()[2] == "-"  # no steady MSE


# -- 3. the rotation: unbounded, linearly growing MSE ------------------------------------


@pytest.fixture(scope="module")
def rotation():
    scenario = resolve_scenario(str(ROTATION))
    return scenario, scenario_gains(scenario)


def test_rotation_example_is_unbounded_with_no_steady_mse(rotation, capsys):
    scenario, gains = rotation
    A = scenario.plant.A
    lam = np.linalg.eigvals(A)
    assert np.allclose(abs(lam), 1.0) and not np.any(np.isclose(lam, 1.0))
    d = fixed_delay_matrix(scenario)
    assert set(d[scenario.weights != 0].tolist()) - {0} == {2}  # homogeneous tau = 2
    rho11 = augmented_spectral_radius(scenario.weights, A, scenario.plant.C, gains.L, d, None,
                                      compensated=False)
    assert rho11 < 1  # eq. (11) alone would promise a bounded error
    assert main(["run", str(ROTATION), "--steps", "3000", "--no-progress", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    e = data["estimators"]["uncompensated"]
    assert e["verdict"] == UNBOUNDED and "steady_state_mse" not in e
    assert e["verdict_detail"]["basis"] == "exact analysis"
    assert e["verdict_detail"]["analysis"]["growth"] == POLYNOMIAL
    comp = data["estimators"]["compensated"]
    assert comp["verdict"] == STABLE and "steady_state_mse" in comp
    # the MSE grows, roughly in proportion to k (linear growth) from step 1500 on
    at = {int(k): v for k, v in e["mse_at"].items()}
    assert at[3000] > 1.5 * at[1500] > 2 * at[750]


def test_rotation_monte_carlo_follows_the_exact_covariance_recursion(rotation):
    """The simulator's Monte Carlo mean MSE over 200 trials against the exact expected
    MSE of the full system (mean and covariance recursion), at five steps, within 4
    standard errors; the exact MSE grows linearly (constant increments)."""
    scenario, gains = rotation
    p = scenario.plant
    d = fixed_delay_matrix(scenario)
    steps, trials = 3000, 200
    exact = exact_mse(np.asarray(scenario.weights), p.A, list(p.C), gains.L, d, False, p.Q,
                      list(p.R), p.x0_mean, p.x0_cov, steps)
    result = run_monte_carlo(scenario, steps=steps, trials=trials, gains=gains,
                             families=["uncompensated"], keep_trials=True)
    per_trial = np.array([r.squared_errors.mean(axis=1)
                          for r in result.runs["uncompensated"]])
    mean = per_trial.mean(axis=0)
    se = per_trial.std(axis=0, ddof=1) / math.sqrt(trials)
    for k in (10, 300, 1000, 2000, 3000):
        assert abs(mean[k] - exact[k]) < 4 * se[k], (k, mean[k], exact[k], se[k])
    # linear growth: the exact increments settle to a positive constant
    inc = np.diff(exact)
    assert inc[-1] > 0 and abs(inc[2999] / inc[1499] - 1) < 1e-3
    assert exact[3000] / exact[300] > 8  # about 10 for a line through the origin
    # and the Monte Carlo slope over the second half matches it, within 4 standard errors
    # of the mean of the trials' own least-squares slopes (independent trials)
    k = np.arange(1500, 3001)
    slopes = np.polyfit(k, per_trial[:, 1500:].T, 1)[0]
    exact_slope = np.polyfit(k, exact[1500:], 1)[0]
    assert abs(slopes.mean() - exact_slope) < 4 * slopes.std(ddof=1) / math.sqrt(trials)


# -- 4. the measured rule on synthetic series -----------------------------------------


def _noisy(rng, trials, steps, law, sd, phi=0.8):
    noise = np.zeros((trials, steps + 1))
    for k in range(1, steps + 1):
        noise[:, k] = phi * noise[:, k - 1] + sd * rng.standard_normal(trials)
    return law(np.arange(steps + 1))[None, :] * np.exp(noise)


def test_measured_rule_tells_geometric_linear_and_bounded_apart():
    rng = np.random.default_rng(5)
    geometric = _noisy(rng, 4, 400, lambda k: 1.03 ** k, 0.1)
    linear = _noisy(rng, 4, 3000, lambda k: 1.0 + 0.05 * k, 0.1)
    bounded = _noisy(rng, 4, 3000, lambda k: np.ones_like(k, dtype=float), 0.1)
    assert judge(geometric).verdict == DIVERGING
    v = judge(linear)
    assert v.verdict == UNBOUNDED and v.basis == "measured growth"
    assert v.growth.power == pytest.approx(1.0, abs=0.1)  # MSE ~ k^1
    assert judge(bounded).verdict == STABLE


def test_a_slow_geometric_growth_is_not_stable_at_50_steps_2_trials():
    """1.018 per step over 50 steps x 2 trials, smooth MSE: the old rule (upper band below
    x2) called it stable; now a visibly growing trend is at best undecided."""
    rng = np.random.default_rng(7)
    for _ in range(50):
        series = _noisy(rng, 2, 50, lambda k: 1.018 ** k, 0.03)
        v = judge(series)
        low, est, high = v.growth.window_growth
        assert est > 1.4  # 1.018^25 = 1.56 over the window
        assert v.verdict != STABLE, v.reason
        assert v.verdict in (UNDECIDED, UNBOUNDED, DIVERGING)
    assert high < GROWTH_TOLERANCE  # the old rule's stable condition held


def test_verdict_table_defines_every_word_and_is_run_help():
    for word in ("stable", "diverging", "unbounded", "undecided", "diverged at step k",
                 "refuted", "proved for this instance",
                 "no counterexample in M instances of <family> (seed s)"):
        assert word in VERDICT_TABLE
    assert len(VERDICT_TABLE.splitlines()) <= 24
    run = next(a for a in build_parser("run")._actions
               if a.__class__.__name__ == "_SubParsersAction").choices["run"]
    assert VERDICT_TABLE in run.format_help()  # the table keeps its layout


def test_bench_cell_names_the_eq11_radius_and_gives_the_joint_verdict():
    from netsim.bench import delay_tolerance_cell
    from netsim.bench.fmt import describe_cell

    scenario = resolve_scenario("lcsys2022-heterogeneous")
    gains = scenario_gains(scenario)
    cell = delay_tolerance_cell(
        {"kind": "mc", "setting": "heterogeneous", "tau": 3, "family": "uncompensated",
         "trials": 2, "steps": 40, "seed": 1}, None, {"scenario": scenario, "gains": gains})
    a, m = cell["analytics"], cell["measured"]
    assert "error recursion alone" in a["exact_kind"] and a["exact"] < 1
    assert a["joint"]["verdict"] == DIVERGING and a["joint"]["rho"] == pytest.approx(1.04)
    assert m["verdict"] == DIVERGING and m["verdict_basis"] == "exact analysis"
    assert "steady_state_mse" not in m and m["last_trusted_step"] == 40
    assert cell["verdict"] == "prediction contradicted"  # the paper's bound predicts decay
    text = describe_cell({**cell, "setting": "heterogeneous", "tau": 3})
    assert "eq. (11) error-recursion rho (moving-state forcing ignored)" in text
    assert "joint system of state and error: diverging" in text and "steady MSE" not in text


def test_recursion_identifiers_are_the_registrys():
    from netsim.estimators import registry
    from netsim.models import jointsystem

    for name in ("RECURSION_COMPENSATED", "RECURSION_UNCOMPENSATED", "RECURSION_BLOCK"):
        assert getattr(jointsystem, name) == getattr(registry, name)
