"""dkfe paper, issue 31: readings of (94), (71)-(72) against the delay, the r_i sweep,
Theorem 4 and Remark 1.

Independent computations used here:

- a Monte Carlo simulation of the estimator itself, written from the paper's equations
  (1), (2), (5) with steady-state gains and (15), with the selection drawn by a sampler
  (any law, or a deterministic schedule). The second moments of the compensating errors
  at a late step are compared entry by entry with the steady state of
  :func:`netsim.models.dkfe.stationary_fusion`: the standard error of each entry is
  estimated from the same samples (their fourth moments) and every entry must lie within
  Z_MAX = 5 standard errors (a few dozen entries: a false alarm for a correct covariance
  has probability below 1e-4; the seeds are fixed);
- :class:`netsim.estimators.fusion.FusionCovariance` (time-varying gains from x(0),
  another recursion) for the categorical reading;
- closed forms (subset laws, Example 1's radius at d = 0, the CSE covariance when every
  component is sent), and the power iteration of the paper's own f of Lemma 7 (69).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from netsim.estimators.fusion import FusionCovariance
from netsim.models import dkfe as dk

from netsim import fusion as nf

Z_MAX = 5.0


def _z(errors: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """Entry-wise z-scores of the empirical second moment of errors (M, p)."""
    M = errors.shape[0]
    prod = errors[:, :, None] * errors[:, None, :]
    se = prod.std(axis=0, ddof=1) / np.sqrt(M)
    return (prod.mean(axis=0) - exact) / np.where(se > 0, se, np.inf)


def _simulate(setup, sampler, steps: int, trials: int, seed: int, *, send="posterior",
              compensation="paper") -> np.ndarray:
    """CSE errors x(T) - x-hat^c_i(T), shape (trials, L n), from the paper's equations.

    x(t+1) = A x(t) + w(t), y_i = C_i x + v_i, x-hat_i(t) = A x-hat_i(t-1)
    + K_i (y_i(t) - C_i A x-hat_i(t-1)) (steady gains), and (15):
    x-hat^c_i(t) = A^d [H x-hat_i(t-d) + (I - H) A x-hat^c_i(t-d-1)], H the pattern
    ``sampler(i, t - d, rng, trials)`` (B, n). Everything is zero up to t = 0.
    """
    rng = np.random.default_rng(seed)
    A, n, L = setup.A, setup.n, setup.n_sinks
    K = [dk.steady_state_local_filter(A, setup.C[i], setup.Q, setup.R[i]).K for i in range(L)]
    FQ = np.linalg.cholesky(setup.Q + 1e-12 * np.eye(n))
    FR = [np.linalg.cholesky(R) for R in setup.R]
    x = np.zeros((trials, n))
    xs = {0: x.copy()}
    loc = {i: {0: np.zeros((trials, n))} for i in range(L)}
    pred = {i: {0: np.zeros((trials, n))} for i in range(L)}  # A x-hat_i(t-1)
    cse = {i: {0: np.zeros((trials, n))} for i in range(L)}
    zero = np.zeros((trials, n))
    for t in range(1, steps + 1):
        x = x @ A.T + rng.standard_normal((trials, n)) @ FQ.T
        xs[t] = x
        for i in range(L):
            p = loc[i][t - 1] @ A.T
            y = x @ setup.C[i].T + rng.standard_normal((trials, setup.C[i].shape[0])) @ FR[i].T
            pred[i][t] = p
            loc[i][t] = p + (y - p @ setup.C[i].T) @ K[i].T
            d = setup.delays[i]
            sent = loc[i].get(t - d, zero) if send == "posterior" else pred[i].get(t - d, zero)
            if compensation == "paper":
                other = cse[i].get(t - d - 1, zero) @ A.T
            else:
                other = cse[i].get(t - d, zero)
            h = sampler(i, t - d, rng, trials)
            inner = h * sent + (1.0 - h) * other
            cse[i][t] = inner @ np.linalg.matrix_power(A, d).T
    return np.hstack([x - cse[i][steps] for i in range(L)])


def _categorical(setup):
    def draw(i, s, rng, B):
        sel = setup.selections[i]
        return sel.patterns[rng.choice(len(sel.probabilities), size=B, p=sel.probabilities)]
    return draw


def _bernoulli(setup):
    def draw(i, s, rng, B):
        g = setup.selections[i].mean
        return (rng.random((B, len(g))) < g).astype(float)
    return draw


# ---------------------------------------------------------------------------
# the engine
# ---------------------------------------------------------------------------


def test_categorical_steady_state_equals_the_time_varying_recursion():
    setup = dk.example2()
    ours = dk.stationary_fusion(setup)
    theirs = FusionCovariance(setup).steady_state()
    assert ours.converged and theirs.converged
    np.testing.assert_allclose(ours.Xi, theirs.Xi, atol=1e-8, rtol=0)
    for a, b in zip(ours.weights, theirs.weights, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-8)


def test_independent_bernoulli_reading_matches_monte_carlo():
    setup = dk.example2()
    moments = [dk._bernoulli_moments(s.mean) for s in setup.selections]
    st = dk.stationary_fusion(setup, moments)
    errors = _simulate(setup, _bernoulli(setup), 150, 3000, 1)
    assert np.max(np.abs(_z(errors, st.Xi))) < Z_MAX
    # power: the Xi of the expected selection (H_i(t) replaced by its mean) is rejected
    mean = [(s.mean, np.outer(s.mean, s.mean)) for s in setup.selections]
    assert np.max(np.abs(_z(errors, dk.stationary_fusion(setup, mean).Xi))) > Z_MAX


def test_prediction_sent_and_same_time_compensation_match_monte_carlo():
    setup = dk.example2()
    st = dk.stationary_fusion(setup, send="prior", compensation="same-time")
    errors = _simulate(setup, _categorical(setup), 150, 3000, 2, send="prior",
                       compensation="same-time")
    assert np.max(np.abs(_z(errors, st.Xi))) < Z_MAX


def test_round_robin_schedule_matches_monte_carlo_at_its_phase():
    setup = dk.example2()
    # period 5, prime to d_i + 1 = 2, 3: each interleaved CSE chain sees every pattern
    scheds = [s.patterns[[0, 5, 1, 4, 2]] for s in setup.selections]
    st = dk.stationary_fusion(setup, schedules=scheds)
    assert st.converged and len(st.phases) == 5

    def draw(i, s, rng, B):
        return np.broadcast_to(scheds[i][s % 5], (B, setup.n))

    for T in (150, 152):
        errors = _simulate(setup, draw, T, 2000, 3 + T)
        assert np.max(np.abs(_z(errors, st.phases[T % 5][0]))) < Z_MAX
    # power: another phase's covariance is rejected
    assert np.max(np.abs(_z(errors, st.phases[(T + 1) % 5][0]))) > Z_MAX


def test_stein_solution_equals_the_iteration():
    setup = dk.example2()
    moments = [(s.mean, np.outer(s.mean, s.mean)) for s in setup.selections]
    exact = dk.stationary_fusion(setup, moments)
    iterated = dk.stationary_fusion(setup, moments, method="iterate", tol=1e-13)
    assert exact.converged and iterated.converged
    np.testing.assert_allclose(exact.Xi, iterated.Xi, atol=1e-8)


def test_subset_laws_closed_forms():
    n, r = 4, 2
    pats, p = dk.conditional_bernoulli([0.5] * n, r)
    np.testing.assert_allclose(p, np.full(6, 1 / 6))
    pats2, p2 = dk.sequential_without_replacement([0.3] * n, r)
    np.testing.assert_allclose(p2, np.full(6, 1 / 6))
    m, second = dk._subset_law_moments(pats, p)
    off = second[~np.eye(n, dtype=bool)]
    np.testing.assert_allclose(off, r * (r - 1) / (n * (n - 1)))
    np.testing.assert_allclose(m, r / n)
    # sequential draws: P(first = 0) = g_0 / sum g, by hand for g = (1, 2, 3, 4)
    g = np.array([1.0, 2.0, 3.0, 4.0])
    pats3, p3 = dk.sequential_without_replacement(g, 2)
    by_hand = {}
    for a, b in itertools.permutations(range(4), 2):
        pr = g[a] / g.sum() * g[b] / (g.sum() - g[a])
        key = frozenset((a, b))
        by_hand[key] = by_hand.get(key, 0.0) + pr
    for h, q in zip(pats3, p3, strict=True):
        assert q == pytest.approx(by_hand[frozenset(np.flatnonzero(h).tolist())])
    # independent indicators: P(l sent) = 1 - prod over patterns containing l of (1 - pi)
    sel = dk.example2().selections[0]
    m4, _ = dk.independent_indicators(sel)
    for l_ in range(n):
        prod = math.prod(1 - q for h, q in zip(sel.patterns, sel.probabilities, strict=True)
                         if h[l_])
        assert m4[l_] == pytest.approx(1 - prod)


# ---------------------------------------------------------------------------
# (94)
# ---------------------------------------------------------------------------


def test_eq94_readings_distances_are_those_of_independent_weights():
    res = dk.eq94_readings(("categorical", "independent-bernoulli"), (), delay_readings=(),
                           marginal_search=False)
    weights = FusionCovariance(dk.example2()).steady_state().weights
    dist = max(float(np.max(np.abs(w - p))) for w, p in zip(weights, dk.PAPER_EX2_OMEGA,
                                                            strict=True))
    cat = res.row("categorical")
    assert cat.distance == pytest.approx(dist, abs=1e-7)
    assert cat.best_distance <= cat.distance
    assert not cat.matches and res.matching == []
    assert res.closest.name in ("categorical", "independent-bernoulli")
    assert res.row("independent-bernoulli").distance > cat.distance
    data = res.to_dict()
    assert data["matching"] == [] and len(data["rows"]) == 2


def test_eq94_score_recognises_a_match_and_a_relabelling():
    printed = dk.PAPER_EX2_OMEGA
    dist, label, best, exact = dk._score(list(printed), printed)
    assert (dist, label, best, exact) == (0.0, "as printed", 0.0, 16)
    dist, label, best, exact = dk._score([w.T for w in printed], printed)
    assert label == "transposed" and best == 0.0 and dist > 0.1


# ---------------------------------------------------------------------------
# (71)-(72) against the delay
# ---------------------------------------------------------------------------


def _growth_of_f(A, Phi, sel, d, steps=400):
    """Per-step growth of tr f^k(I) with f of Lemma 7 as printed (69)."""
    B = np.eye(2 * A.shape[0])
    logs = []
    for _ in range(steps):
        B = dk.lemma7_f(B, A, Phi, sel, d)
        tr = float(np.trace(B))
        logs.append(math.log(tr))
        B = B / tr
    return math.exp(np.mean(logs[steps // 2:]))


def test_gamma_delay_table_lmis_radius_closed_form_and_lemma7():
    table = dk.gamma_delay_table((0.3, 0.6), (0, 1), resolution=50, lmis=False)
    # real cvxpy solves where it is delicate: d = 1, inside and just outside the interval
    lmi = dk.gamma_delay_table((0.6, 0.7), (1,), resolution=10, lmi75=False)
    assert lmi.lmi_agrees_with_radius
    assert lmi.cell(0.6, 1).lmi71_72 is True and lmi.cell(0.7, 1).lmi71_72 is False
    assert 1 < lmi.cell(0.7, 1).radius < 1.03
    setup = dk.example1(0.5)
    Phi = dk.steady_state_local_filter(setup.A, setup.C[0], setup.Q, setup.R[0]).Phi
    rho_phi2 = max(abs(np.linalg.eigvals(Phi))) ** 2
    for g in (0.3, 0.6):
        closed = max((1 - g) * 1.25 ** 2, 1.1 ** 2 * g, rho_phi2)
        assert table.cell(g, 0).radius == pytest.approx(closed, rel=1e-9)
        for d in (0, 1):
            growth = _growth_of_f(setup.A, Phi, dk.example1(g, d).selections[0], d)
            assert growth == pytest.approx(table.cell(g, d).radius, rel=1e-3)
    # d = 0: (1 - g) 1.5625 < 1 and 1.21 g < 1
    [(lo, hi)] = table.intervals[0]
    assert lo == pytest.approx(1 - 1 / 1.5625, abs=1e-7)
    assert hi == pytest.approx(1 / 1.21, abs=1e-7)
    [(lo1, hi1)] = table.intervals[1]
    assert lo < lo1 < 0.6 < hi1 < hi
    for g in (lo1 - 1e-4, hi1 + 1e-4):
        assert _growth_of_f(setup.A, Phi, dk.example1(g, 1).selections[0], 1) > 1


def test_sink_delay_table_boundary_of_example2():
    t = dk.sink_delay_table(delays=(12, 13), lmis=True)
    by = {(r["sink"], r["d"]): r for r in t.rows}
    assert by[(1, 13)]["lmi71_72"] is True and by[(2, 13)]["lmi71_72"] is False
    assert by[(2, 12)]["lmi71_72"] is True
    for r in t.rows:
        assert r["lmi71_72"] == (r["radius"] < 1)
    assert t.largest_delay == [13, 12]


# ---------------------------------------------------------------------------
# the transmitted dimension
# ---------------------------------------------------------------------------


def test_dimension_sweep_full_dimension_closed_form_and_printed_row():
    setup = dk.example2()
    sweep = dk.dimension_sweep(r_values=(4,), same_r=True)
    full, printed = sweep.rows
    n = setup.n
    for i, d in enumerate(setup.delays):
        f = dk.steady_state_local_filter(setup.A, setup.C[i], setup.Q, setup.R[i])
        Ad = np.linalg.matrix_power(setup.A, d)
        xi = Ad @ f.P @ Ad.T + sum(np.linalg.matrix_power(setup.A, k) @ setup.Q
                                   @ np.linalg.matrix_power(setup.A, k).T for k in range(d))
        assert full["trace_Xi"][i] == pytest.approx(np.trace(xi), rel=1e-8)
    ref = FusionCovariance(setup).steady_state()
    assert printed["trace_P"] == pytest.approx(np.trace(ref.P), rel=1e-8)
    assert full["trace_P"] < printed["trace_P"]
    assert full["r"] == [n, n] and printed["law"] == "printed"


# ---------------------------------------------------------------------------
# Theorem 4 and Remark 1
# ---------------------------------------------------------------------------


def test_theorem4_on_a_two_sink_instance():
    check = nf.theorem4_check(steps=60, c1=nf.two_sink_example1((0.5, 0.2)),
                              c2=nf.two_sink_example1((0.5, 0.6)),
                              control=nf.two_sink_example1((0.2, 0.3)))
    c1, c2, ctl = (check.case(k) for k in ("C.1", "C.2", "control"))
    assert c1.lmi71_72 == [True, False] and c2.lmi71_72 == [True, True]
    assert ctl.lmi71_72 == [False, False]
    assert check.c1_holds and check.c2_holds
    assert c1.trace_Xi[1][-1] > 1e3 * c1.trace_Xi[1][10]  # the other CSE diverges
    assert not ctl.bounded and ctl.growth > 2
    # the limit of C.2 by the estimators' own recursion from x(0) ~ N(0, I)
    ref = FusionCovariance(nf.two_sink_example1((0.5, 0.6))).steady_state()
    assert c2.trace_P[-1] == pytest.approx(np.trace(ref.P), rel=1e-4)


def test_remark1_buffered_delays_equal_the_constant_bound():
    res = nf.remark1_check(delays=(3, 2), steps=25, trials=2, seed=5)
    assert res.identical and res.buffered > 0 and res.messages > 0
    assert res.to_dict()["identical"] is True


def test_readings_report_quick_builds_text_and_json():
    data, text = nf.readings_report(quick=True)
    assert "(94)" in text and "Theorem 4" in text and "Remark 1" in text
    assert data["theorem4"]["c1_holds"] and data["remark1"]["identical"]
    assert data["eq94_readings"]["matching"] == []


# ---------------------------------------------------------------------------
# the claims and reproduce items (netsim.papers.dkfe)
# ---------------------------------------------------------------------------


def _context(**cache):
    from netsim.claims.core import Context

    ctx = Context(seed=0)
    ctx.cache.update({f"dkfe-issue31:{k}": v for k, v in cache.items()})
    return ctx


def test_new_claims_and_items_are_registered_with_their_jobs():
    from netsim.claims import REGISTRY
    from netsim.reproduce.items import items

    for cid in ("D-eq94-readings", "D-thm2-delays", "D-theorem4", "D-remark1"):
        claim = REGISTRY[cid]
        assert claim.paper == "dkfe" and all(s.startswith("dkfe-issue31:")
                                             for s in claim.searches)
    ids = {i.id for i in items()}
    assert {"dkfe-eq94-readings", "dkfe-gamma-delay", "dkfe-dimension", "dkfe-theorem4",
            "dkfe-remark1"} <= ids


def test_eq94_claim_verdict_follows_the_enumeration():
    from netsim.claims.core import PROVED, REFUTED
    from netsim.papers._dkfe_readings import check_eq94_readings

    data = dk.eq94_readings(("categorical", "uniform-r-of-n"), (), delay_readings=(),
                            marginal_search=False).to_dict()
    out = check_eq94_readings(_context(eq94=data))
    assert out.verdict == REFUTED and "uniform-r-of-n at 0.1261" in out.summary
    # a reading that gives the printed weights turns the verdict
    hit = dict(data, matching=["uniform-r-of-n"])
    assert check_eq94_readings(_context(eq94=hit)).verdict == PROVED


def test_theorem2_delays_claim_refutes_a_feasible_lmi_with_a_diverging_chain():
    from netsim.claims.core import PROVED, REFUTED
    from netsim.papers._dkfe_readings import check_theorem2_delays

    g = dk.gamma_delay_table((0.6,), (0, 1), resolution=20, lmis=False).to_dict()
    for c in g["cells"]:
        c["lmi71_72"] = c["radius"] < 1  # as cvxpy found (tested above)
    s = dk.sink_delay_table(delays=(0, 1), lmis=False).to_dict()
    for r in s["rows"]:
        r["lmi71_72"] = r["radius"] < 1
    assert check_theorem2_delays(_context(gamma=g, sinks=s)).verdict == PROVED
    bad = {**g, "cells": [dict(c, radius=1.5) if c["d"] == 0 else c for c in g["cells"]]}
    assert check_theorem2_delays(_context(gamma=bad, sinks=s)).verdict == REFUTED


def test_theorem4_and_remark1_claims_on_small_runs():
    from netsim.claims.core import PROVED, REFUTED
    from netsim.papers._dkfe_readings import check_remark1, check_theorem4

    t = nf.theorem4_check(steps=60, c1=nf.two_sink_example1((0.5, 0.2)),
                          c2=nf.two_sink_example1((0.5, 0.6)), with_control=False).to_dict()
    assert check_theorem4(_context(theorem4=t)).verdict == PROVED
    assert check_theorem4(_context(theorem4=dict(t, c1_holds=False))).verdict == REFUTED
    r = nf.remark1_check(steps=15, trials=1).to_dict()
    assert check_remark1(_context(remark1=r)).verdict == PROVED
    assert check_remark1(_context(remark1=dict(r, identical=False))).verdict == REFUTED
