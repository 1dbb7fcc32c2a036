"""Each claim's check against an independent computation (issue 18).

The references here are written from the papers' equations in this file: augmented
matrices built with numpy kron from eqs. (9) and (11) (``augmented_by_hand`` in
tests/helpers.py, shared with tests/test_unchecked_claims.py), closed forms for scalar
plants, a second implementation of the aoi freshness-index rules (eqs. 8-14), the
steady-state Kalman filter from scipy's Riccati solver, and the dkfe conditions computed
from the paper's printed matrices. Instances are tiny; the whole file takes a few seconds.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.linalg
from helpers import augmented_by_hand, rho

from netsim.claims import REGISTRY, Context
from netsim.claims.search import Found, ScalarInstance
from netsim.claims.searches import clean_delays as _clean
from netsim.claims.searches import simulate_error_growth
from netsim.papers.delay_tolerant import _lemma5_judge, _t1_judge
from netsim.papers.dkfe import DkfeInstance, _dkfe_judge, dkfe_numbers
from netsim.papers.lcsys2022 import _eq26_judge, search_eq26


def scalar_parts(a, P, c, k):
    P = np.asarray(P, float)
    g = np.array([1 - ki * ci * ci for ki, ci in zip(k, c, strict=True)])
    return P, g, rho(np.diag(g) @ P) * abs(a)


def delayed(a, P, c, k, d):
    return _clean(ScalarInstance(a, tuple(map(tuple, P)), tuple(c), tuple(k)), np.array(d))


# -- LCSYS2022 eq. (26) and the delay-tolerant Lemma 5, Theorem 1 ---------------------


def test_eq26_judge_against_hand_matrix_and_closed_form_bound():
    a, P, c, k, d = 0.7, [[0.8, 0.2], [0.6, 0.4]], (0.0, 1.0), (0.0, -1.0), [[0, 0], [1, 0]]
    x = delayed(a, P, c, k, d)
    Pm, g, rho_hat = scalar_parts(a, P, c, k)
    hand = rho(augmented_by_hand(*x.matrices(), compensated=True))
    bound = (abs(a) ** 2 * rho(np.diag(g) @ Pm)) ** 0.5  # eq. (26) at tau = 1, n = 1
    res = _eq26_judge(x)
    assert res is not None and rho_hat < 1
    assert res["exact_rho"] == pytest.approx(hand, rel=1e-10)
    assert res["bound"] == pytest.approx(bound, rel=1e-10) and hand > bound + 0.01
    assert simulate_error_growth(x, True) == pytest.approx(hand, rel=1e-3)


def test_every_bound_judge_catches_a_planted_counterexample_at_tau_star():
    """A counterexample placed exactly at tau = tau* (the edge a judge could skip): the
    eq. (26) and Theorem 1 judges must report it there, by hand-built matrices and the
    closed-form tau* (|a|^(tau+1) rho(G P) < 1)."""
    from netsim.papers.lcsys2022 import _theorem1_judge

    a, P, c, k = 1.144, [[0.34, 0.66], [0.56, 0.44]], (1.0, 1.0), (-0.52, 1.86)
    Pm, g, rho_hat = scalar_parts(a, P, c, k)
    star = max(t for t in range(21) if abs(a) ** (t + 1) * rho(np.diag(g) @ Pm) < 1)
    assert star == 3 and rho_hat < 1
    x = delayed(a, P, c, k, [[0, star], [star, 0]])
    hand = rho(augmented_by_hand(*x.matrices(), compensated=True))
    bound = (abs(a) ** (star + 1) * rho(np.diag(g) @ Pm)) ** (1 / (star + 1))
    assert hand > bound + 0.05 and hand > 1.05
    got = _eq26_judge(x)
    assert got is not None and got["tau"] == star == got["tau_star"]
    assert got["exact_rho"] == pytest.approx(hand, rel=1e-10)
    assert got["bound"] == pytest.approx(bound, rel=1e-10)
    # Theorem 1: the smallest violating tau (here 2) is reported, and tau* itself counts
    inst = x.inst
    smallest = min(t for t in range(1, star + 1) if rho(augmented_by_hand(
        *delayed(a, P, c, k, [[0, t], [t, 0]]).matrices())) >= 1.01)
    t1 = _theorem1_judge(inst)
    assert t1 is not None and t1["tau"] == smallest and t1["tau_star"] == star


def test_eq26_search_hits_satisfy_the_hypotheses_by_hand():
    found = search_eq26(np.random.SeedSequence(5), instances=40)
    assert found.hits >= 1 and found.instance is not None
    x = found.instance
    Pm, g, rho_hat = scalar_parts(x.inst.a, x.inst.P, x.inst.c, x.inst.k)
    assert np.allclose(Pm.sum(axis=1), 1) and np.all(np.diag(Pm) > 0) and rho_hat < 1
    tau = x.tau
    # Theorem 1's condition by hand at every tau' <= tau: |a|^(tau'+1) rho(G P) < 1
    assert all(abs(x.inst.a) ** (t + 1) * rho(np.diag(g) @ Pm) < 1 for t in range(tau + 1))
    hand = rho(augmented_by_hand(*x.matrices(), compensated=True))
    bound = (abs(x.inst.a) ** (tau + 1) * rho(np.diag(g) @ Pm)) ** (1 / (tau + 1))
    assert hand >= bound + 0.01


def test_lemma5_judge_against_hand_matrix():
    a, P, c, k, d = 1.0, [[0.7, 0.3], [0.8, 0.2]], (1.0, 0.0), (2.0, 0.0), [[0, 0], [1, 0]]
    x = delayed(a, P, c, k, d)
    _, _, rho_hat = scalar_parts(a, P, c, k)
    hand = rho(augmented_by_hand(*x.matrices(), compensated=False))
    res = _lemma5_judge(x)
    assert res["exact_rho"] == pytest.approx(hand, rel=1e-10)
    assert res["bound"] == pytest.approx(rho_hat ** 0.5, rel=1e-10) and hand > rho_hat ** 0.5
    assert simulate_error_growth(x, False) == pytest.approx(hand, rel=1e-3)


def test_tolerant_theorem1_counterexample_by_hand_and_by_netsim(tmp_path, capsys):
    """|a| = 1 (bounded state), rho(A-hat) < 1, homogeneous tau = 3: eq. (11) rho > 1."""
    from netsim.cli import main

    a, P, c, k = -1.0, [[0.5, 0.5], [0.7, 0.3]], (1.0, 0.0), (2.5, 0.0)
    x = delayed(a, P, c, k, [[0, 3], [3, 0]])
    _, _, rho_hat = scalar_parts(a, P, c, k)
    hand = rho(augmented_by_hand(*x.matrices(), compensated=False))
    assert rho_hat < 0.99 and hand > 1.01
    assert _t1_judge(x)["exact_rho"] == pytest.approx(hand, rel=1e-10)
    ctx = Context(seed=0, out=tmp_path)
    ctx.cache["search:T-theorem1"] = Found("T-theorem1", 1, 1, 0.0, x, _t1_judge(x))
    out = REGISTRY["T-theorem1"].run(ctx)
    assert out.verdict == "refuted"
    # verified twice: the exact rho and an independent simulation of the recursion
    check = out.counterexample["verification"]
    assert check["confirmed"] and check["simulated_error_growth"] > 1
    assert check["simulated_error_growth"] == pytest.approx(hand, rel=5e-3)
    # the unstable-plant part: uncompensated MSE grows like |x|^2, i.e. rho(A)^2 per step
    rho_a = out.numbers["rho_A_squared"]
    assert out.numbers["mse_growth_per_step"] == pytest.approx(rho_a, rel=0.03)
    path = out.counterexample["scenario"]
    assert main(["analyze", path, "--tau-max", "3", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["homogeneous"][3]["rho_uncompensated"] == pytest.approx(hand, rel=1e-9)
    assert out.counterexample["verification"]["netsim_run"]["measured"] == "diverging"


# -- LCSYS2022 Lemmas 2 and 4, eq. (14), printed numbers on our instance -----------------


def test_convergence_time_closed_form():
    from netsim.claims.checks import convergence_time, lemma2_on

    for q in (0.5, -0.9, 0.97):
        assert convergence_time(np.array([[q]])) == math.ceil(math.log(1e3) / -math.log(abs(q)))
    rows = lemma2_on(np.array([[1.0]]), np.array([[1.2]]), [np.array([[1.0]])],
                     [np.array([[0.5]])], [0])
    q = 1.2 * 0.5
    assert rows[0]["rho"] == pytest.approx(q)
    assert rows[0]["time"] == math.ceil(math.log(1e3) / -math.log(q))


def test_lemma4_closed_form_for_a_scalar_agent():
    from netsim.papers.lcsys2022 import lemma4_on

    a, L = 1.3, 0.4
    for tau in (1, 3, 8):
        r = lemma4_on(np.array([[1.0]]), np.array([[a]]), [np.array([[1.0]])],
                      [np.array([[L]])], tau)
        # the eigenvalues solve lambda^(tau+1) = (1 - L) a^(tau+1)
        closed = abs((1 - L) * a ** (tau + 1)) ** (1 / (tau + 1))
        assert r["exact"] == pytest.approx(closed, rel=1e-10)
        assert r["bound"] == pytest.approx(closed, rel=1e-10)


def test_lcsys_instance_numbers_against_hand_matrices():
    from netsim.claims.checks import homogeneous_delays
    from netsim.papers.lcsys2022 import lcsys_instance

    ctx = Context()
    inst = lcsys_instance(ctx)
    P, A, C, L = inst["P"], inst["A"], inst["C"], inst["L"]
    eq14 = REGISTRY["L-decay"].run(ctx).numbers["exact_rho"]
    lemma2 = REGISTRY["L-lemma2"].run(ctx).numbers["rows"]
    tdecay = REGISTRY["T-decay"].run(ctx).numbers["exact_rho_eq11"]
    for tau in (1, 2, 3):
        d = homogeneous_delays(P, tau)
        comp = rho(augmented_by_hand(P, A, C, L, d, True))
        assert eq14[str(tau)] == pytest.approx(comp, abs=1e-4)
        assert lemma2[str(tau)]["rho"] == pytest.approx(comp, abs=1e-4)
        assert tdecay[str(tau)] == pytest.approx(rho(augmented_by_hand(P, A, C, L, d, False)),
                                                 abs=1e-4)
    hom19 = REGISTRY["L-hom-19"].run(ctx).numbers["exact_rho_19"]
    assert hom19 == pytest.approx(rho(augmented_by_hand(P, A, C, L, homogeneous_delays(P, 19))),
                                  abs=1e-4)
    # eq. (26) at tau = 3 by hand: rho((I - K D)(P kron A^4))^(1/4)
    G = np.eye(P.shape[0] * A.shape[0]) - scipy.linalg.block_diag(
        *[Li @ Ci for Li, Ci in zip(L, C, strict=True)])
    b3 = rho(G @ np.kron(P, np.linalg.matrix_power(A, 4))) ** 0.25
    assert REGISTRY["L-eq26"].run(ctx).numbers["3"] == pytest.approx(b3, abs=1e-4)
    # tau* (Theorem 1's definition) by hand: the largest tau with
    # rho((I - K D)(P kron A^(t+1))) < 1 for every t <= tau
    star = -1
    while star < 30 and rho(G @ np.kron(P, np.linalg.matrix_power(A, star + 2))) < 1:
        star += 1
    assert REGISTRY["L-tau-star"].run(ctx).numbers["tau_star"] == star


# -- figure statements (small bench runs) ---------------------------------------------


def test_figure_checks_follow_the_bench_cells(monkeypatch):
    import netsim.claims.searches as searches
    import netsim.papers.lcsys2022 as checks

    monkeypatch.setattr(searches, "BENCH_TRIALS", 2)
    ctx = Context()
    out = REGISTRY["T-fig2-stable"].run(ctx)
    # a figure of the paper's unprinted system cannot be refuted on another system: the
    # difference is stated as the reason of an undecided verdict
    assert out.verdict == "undecided" and "unprinted" in out.reason
    # independent: the uncompensated error carries (A^(r+1) - A) x, so its MSE grows like
    # |x_k|^2, rho(A)^2 per step (rho(A) of the plant)
    data = ctx.cache["bench:delay-tolerant-fig2"]
    A = np.array(data["scenario"]["plant"]["A"]) if "plant" in data["scenario"] else \
        checks.lcsys_instance(ctx)["A"]
    r2 = rho(A) ** 2
    for cell in data["cells"]:
        assert cell["measured"]["verdict"] != "stable"
        assert cell["measured"]["growth_rate"] == pytest.approx(r2, rel=0.01)
    # LCSYS2022 Fig. 1 on our instance: stable cells, each with an exact rho below 1 that
    # the hand-built eq. (9) matrix reproduces for the homogeneous delays
    from netsim.claims.checks import homogeneous_delays
    from netsim.papers.lcsys2022 import lcsys_instance

    stable = REGISTRY["L-stable-0-3-8"].run(ctx)
    assert stable.verdict == "no counterexample" and stable.evidence.instances == 2
    inst = lcsys_instance(ctx)
    for cell in ctx.cache["bench:lcsys2022-fig1"]["cells"]:
        if cell["setting"] == "homogeneous" and cell["tau"] in (3, 8):
            hand = rho(augmented_by_hand(inst["P"], inst["A"], inst["C"], inst["L"],
                                         homogeneous_delays(inst["P"], cell["tau"])))
            assert cell["analytics"]["exact"] == pytest.approx(hand, abs=1e-6) and hand < 1
            assert cell["measured"]["verdict"] == "stable"


# -- aoi: a second implementation of the freshness-index rules -----------------------------


def freshness_by_hand(N, source, graphs, steps):
    """Eqs. (8), (9), (14): tau_source = 0; an untriggered node takes 1 + the least finite
    index among its neighbours; a triggered one takes 1 + the least strictly smaller one,
    else its own + 1. ``graphs[k]``: the (from, to) edges at step k."""
    omega = None
    tau = [0 if i == source else omega for i in range(N)]
    hist = [list(tau)]
    for k in range(steps):
        edges = graphs[k % len(graphs)]
        new = list(tau)
        for i in range(N):
            if i == source:
                continue
            nb = [tau[s] for (s, j) in edges if j == i and tau[s] is not omega]
            if tau[i] is omega:
                new[i] = min(nb) + 1 if nb else omega
            else:
                better = [t for t in nb if t < tau[i]]
                new[i] = min(better) + 1 if better else tau[i] + 1
        tau = new
        hist.append(list(tau))
    return hist


def test_aoi_lemmas_and_corollary_on_the_section_3_example_by_hand():
    from netsim.aoi import EXAMPLE_GRAPH_A, EXAMPLE_GRAPH_B
    from netsim.papers.aoi import aoi_numbers_example

    N, T, n = 3, 1, 1
    hist = freshness_by_hand(N, 0, [EXAMPLE_GRAPH_A, EXAMPLE_GRAPH_B], 40)
    trig = next(k for k, t in enumerate(hist) if all(v is not None for v in t))
    start = (N - 1) * T
    fresh_max = max(max(t) for t in hist[start:])
    # Corollary 1 by hand: the source's deadbeat error is 0 from step n on; node i's error
    # is a^tau e_0[k - tau], zero once it is triggered and k - tau_i[k] >= n
    conv = next(k for k in range(len(hist)) if all(
        t is not None and k - t >= n for t in hist[k][1:]) and all(
        all(t is not None and kk - t >= n for t in hist[kk][1:]) for kk in range(k, 40)))
    got = aoi_numbers_example()
    assert got["triggered_by"] == trig == 2 and got["lemma_3"] == (N - 1) * T
    assert got["max_index"] == fresh_max and fresh_max <= got["lemma_5"] == 2 * (N - 1) * T
    assert got["converged_at"] == conv and conv <= got["corollary_1"] == n + 2 * N * (N - 1) * T


def test_aoi_rate_is_the_designs_slowest_source_rate():
    from netsim.aoi import random_aoi_scenario
    from netsim.papers.aoi import aoi_rate
    from netsim.runner import run_monte_carlo

    r = aoi_rate(0, 0.6)
    sc = random_aoi_scenario(4, 3, 2, seed=0, steps=150, spectral_radius=1.0)
    design = run_monte_carlo(sc.with_options("aoi", gains="rate", rho=0.6), families=["aoi"],
                             keep_trials=False).analytics["aoi"]["design"]["gains"]
    # closed loop of each source block: A_jj - L_j C_jj has spectral radius rho_j < rho;
    # the slowest one sets the decay of every node (the others inherit delayed copies)
    assert max(design["rhos"]) < 0.6
    assert r["measured_rate"] == pytest.approx(max(design["rhos"]), abs=0.03)


# -- dkfe: from the paper's printed matrices -----------------------------------------------


def kalman_phi(A, C, Q, R):
    """Steady Kalman filter (eqs. 5-7) from scipy's DARE: G = I - K C, Phi = G A."""
    Pp = scipy.linalg.solve_discrete_are(A.T, C.T, Q, R)  # a-priori covariance
    K = Pp @ C.T @ np.linalg.inv(C @ Pp @ C.T + R)
    G = np.eye(A.shape[0]) - K @ C
    return G, G @ A


EX1_A = np.array([[1.25, 0.0], [1.0, 1.1]])


def test_dkfe_example1_numbers_from_the_printed_system():
    ctx = Context()
    G, Phi = kalman_phi(EX1_A, np.array([[0.0, 1.0]]), 20 * np.eye(2), np.array([[2.5]]))
    printed = np.array([[0.4760, -0.8573], [0.0314, 0.0376]])  # eq. (83)
    out = REGISTRY["D-eq83"].run(ctx)
    assert out.numbers["diff_G"] == pytest.approx(np.abs(G - printed).max(), abs=1e-4)
    assert out.numbers["diff_Phi"] == pytest.approx(np.abs(Phi - printed).max(), abs=1e-4)
    IH = np.diag([0.5, 0.5])  # I - H_1 at gamma_11 = 0.5 (eq. 84)
    lam = max(np.linalg.eigvalsh(EX1_A.T @ IH @ EX1_A))
    S = np.sqrt(IH) @ EX1_A
    xi = np.linalg.norm(S, 1) * np.linalg.norm(S, np.inf)
    n = REGISTRY["D-ex1-numbers"].run(ctx).numbers
    assert n["lambda_max"] == pytest.approx(lam, abs=1e-4) and abs(lam - 1.5887) < 1e-4
    assert n["xi_inf"] == pytest.approx(xi, abs=1e-4) and abs(xi - 2.3625) < 1e-4


def test_dkfe_table1_against_the_closed_form_radius():
    """Example 1, d = 0: the error chain's second-moment radius is
    max((1 - g) 1.25^2, g 1.1^2, rho(Phi)^2) (block triangular chain)."""
    from netsim.models.dkfe import table1_rows

    _, Phi = kalman_phi(EX1_A, np.array([[0.0, 1.0]]), 20 * np.eye(2), np.array([[2.5]]))
    feasible = []
    for row in table1_rows():
        g = row["gamma11"]
        radius = max((1 - g) * 1.5625, 1.21 * g, rho(Phi) ** 2)
        assert row["second_moment_radius"] == pytest.approx(radius, rel=1e-8)
        assert row["c75"] == (radius < 1)
        if radius < 1:
            feasible.append(g)
    assert feasible == [0.4, 0.5, 0.6, 0.7, 0.8]  # Table I's (75) column
    assert REGISTRY["D-table1"].run(Context()).verdict == "proved for this instance"


def test_dkfe_search_judge_against_the_closed_form_radius():
    g = 0.3
    x = DkfeInstance(tuple(map(tuple, EX1_A)), (0.0, 1.0), 1, (g, 1 - g), 0)
    _, Phi = kalman_phi(EX1_A, np.array([[0.0, 1.0]]), np.eye(2), np.eye(1))
    v = dkfe_numbers(x)
    assert v["radius"] == pytest.approx(max((1 - g) * 1.5625, 1.21 * g, rho(Phi) ** 2),
                                        rel=1e-8)
    assert v["c75"] == (v["radius"] < 1) and _dkfe_judge(x) is None


EX2_A = np.array([[1.0156, 0.0139, 0.0457, 0.0971], [-0.0353, 0.9997, -0.0008, -0.0017],
                  [-0.0526, -0.0448, 0.9625, -0.0797], [-0.008, -0.0505, -0.0903, 0.9011]])
EX2_H = (np.diag([0.6, 0.5, 0.5, 0.4]), np.diag([0.5, 0.6, 0.3, 0.6]))  # eq. (92)


def test_dkfe_example2_conditions_from_the_printed_matrices():
    ctx = Context()
    I4 = np.eye(4)
    c77 = [rho(EX2_A @ (I4 - EX2_H[0]) @ EX2_A),
           rho(np.linalg.matrix_power(EX2_A, 2) @ (I4 - EX2_H[1]) @ EX2_A)]
    out = REGISTRY["D-eq93"].run(ctx)
    assert out.numbers["ours"] == pytest.approx(c77, abs=1e-4)
    assert out.verdict == ("proved for this instance" if abs(c77[1] - 0.6631) < 5e-5
                           else "refuted")
    assert REGISTRY["D-cond77"].run(ctx).numbers["c77"] == pytest.approx(c77, abs=1e-4)
    zeta = []
    for d, H in ((1, EX2_H[0]), (2, EX2_H[1])):
        Ad, S = np.linalg.matrix_power(EX2_A, d), np.sqrt(I4 - H) @ EX2_A
        zeta.append(np.linalg.norm(Ad, 1) * np.linalg.norm(S, 1) * np.linalg.norm(Ad, np.inf)
                    * np.linalg.norm(S, np.inf))
    assert REGISTRY["D-eq95"].run(ctx).numbers["ours"] == pytest.approx(zeta, abs=1e-4)
    # (88): the steady local filters from the printed C_i, R_i (eq. 87), Q_w (86)
    from netsim.models.dkfe import PAPER_EX2_PHI_K, example2

    setup = example2()
    diffs = [np.abs(kalman_phi(EX2_A, C, setup.Q, R)[1] - printed).max()
             for C, R, printed in zip(setup.C, setup.R, PAPER_EX2_PHI_K, strict=True)]
    assert REGISTRY["D-eq88"].run(ctx).numbers["max_abs_diff"] == pytest.approx(diffs,
                                                                               abs=1e-4)
    # (94) and Fig. 6: the weights sum to I; an optimal fusion is no worse than each CSE
    d94 = REGISTRY["D-eq94"].run(ctx).numbers
    W = [np.array(w) for w in d94["ours"]]
    assert np.allclose(W[0] + W[1], I4)
    printed = [np.array(w) for w in d94["printed"]]
    assert d94["max_abs_diff"][0] == pytest.approx(np.abs(W[0] - printed[0]).max(), abs=1e-4)
    # Fig. 6's exact traces (a 300-step recursion from x(0) ~ N(0, I)) end at the steady
    # state that netsim fusion example2 iterates to convergence on its own
    f6 = REGISTRY["D-fig6"].run(ctx).numbers["exact_trace"]
    steady = REGISTRY["D-eq94"].run(ctx)
    from netsim.fusion import example2 as ex2

    ss = ex2(json=True)[0]["steady_state"]
    assert f6["DKFE"][-1] == pytest.approx(ss["trace_P"], rel=1e-6)
    assert f6["DKFE"][-1] <= min(f6["CSE 1 (d=1)"][-1], f6["CSE 2 (d=2)"][-1])
    assert steady.verdict == "refuted"


def test_lemma1_observability_closed_forms():
    from netsim.claims.checks import kron_observable

    one = [np.array([[1.0]]), np.zeros((0, 1))]
    # reducible P (no link into agent 1): agent 1's estimate never sees a measurement
    assert not kron_observable(np.eye(2), np.array([[1.5]]), one)
    # irreducible, self-looped: [D; D F] = [[1, 0], [0, 0], [a/2, a/2], [0, 0]] has rank 2
    assert kron_observable(np.full((2, 2), 0.5), np.array([[1.5]]), one)
    lemma1 = REGISTRY["L-lemma1"].run(Context())
    assert lemma1.verdict == "no counterexample" and lemma1.evidence.instances > 200


def test_corollary1_against_the_hand_built_delay_free_loop():
    from netsim.papers.lcsys2022 import lcsys_instance

    ctx = Context()
    inst = lcsys_instance(ctx)
    P = np.asarray(inst["P"])
    hand = rho(augmented_by_hand(P, inst["A"], inst["C"], inst["L"], np.zeros(P.shape, int)))
    out = REGISTRY["L-corollary1"].run(ctx)
    assert out.numbers["rho_delay_free"] == pytest.approx(hand, abs=1e-4) and hand < 1


def test_dkfe_eq94_weights_minimise_the_fused_covariance_independently():
    """D-eq94's computed weights, recomputed here from the steady stacked covariance Xi
    (cross blocks included; Xi itself is checked against Monte Carlo in test_fusion) as
    the minimiser of tr(Omega Xi Omega^T) subject to Omega_1 + Omega_2 = I, written as
    its own KKT solve; and no feasible perturbation lowers that trace."""
    from netsim.models import dkfe as dk

    from netsim.fusion import covariances_for

    setup = dk.example2()
    Xi = covariances_for(setup)[0].steady_state().Xi
    n, L = setup.n, 2
    Xi = 0.5 * (Xi + Xi.T)
    # minimise sum_r w_r^T Xi w_r over the rows w_r of Omega, subject to sum_i Omega_i = I:
    # Lagrangian stationarity 2 Xi W^T + E Lambda = 0 with E = [I; I]
    E = np.vstack([np.eye(n)] * L)
    kkt = np.block([[2 * Xi, E], [E.T, np.zeros((n, n))]])
    sol = np.linalg.solve(kkt, np.vstack([np.zeros((L * n, n)), np.eye(n)]))
    Omega = sol[: L * n].T  # (n, L n)
    ours = np.hstack([np.array(w) for w in REGISTRY["D-eq94"].run(Context()).numbers["ours"]])
    np.testing.assert_allclose(ours, Omega, atol=1e-4)  # the registry rounds to 4 places
    best = np.trace(Omega @ Xi @ Omega.T)
    rng = np.random.default_rng(0)
    for _ in range(20):
        D = rng.standard_normal((n, n))
        delta = np.hstack([D, -D]) * 1e-2
        assert np.trace((Omega + delta) @ Xi @ (Omega + delta).T) >= best - 1e-12
