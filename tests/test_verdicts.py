"""The verdict rule (netsim.verdicts): statistics, exact rho, precision horizon.

Expected verdicts come from independent facts: exact spectral radii of the augmented
closed loop (netsim.models.augmented), closed-form growth of synthetic MSE curves with a
known slope, Monte Carlo false-alarm rates, and the unstable plant's rho(A).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from netsim.models.augmented import augmented_closed_loop, spectral_radius
from netsim.models.delays import heterogeneous_delays
from netsim.models.scenario import resolve_scenario

from netsim.bench.cells import _verdict
from netsim.bench.variants import delay_variant
from netsim.runner import fixed_delay_matrix, run_monte_carlo, scenario_gains
from netsim.verdicts import (
    BEYOND_HORIZON,
    DIVERGING,
    GROWTH_TOLERANCE,
    MIN_WINDOW,
    STABLE,
    UNDECIDED,
    estimate_growth,
    judge,
    precision_horizon,
)

SEEDS = range(6)


# -- the statistics on synthetic curves (known slope) ----------------------------------


def _curves(rng, trials, steps, slope, phi=0.8, sd=0.5):
    """MSE curves exp(slope k + AR(1) noise): log-linear with a known slope."""
    noise = np.zeros((trials, steps))
    for k in range(1, steps):
        noise[:, k] = phi * noise[:, k - 1] + sd * rng.standard_normal(trials)
    return np.exp(slope * np.arange(steps) + noise)


def test_no_growth_is_rarely_called_diverging():
    """Slope 0: the false-alarm rate of "diverging" at 50 steps x 2 trials is small."""
    rng = np.random.default_rng(1)
    calls = [judge(_curves(rng, 2, 51, 0.0)).verdict for _ in range(400)]
    assert calls.count(DIVERGING) <= 4  # <= 1 %
    # and with many steps and trials the evidence bounds the growth: stable
    assert judge(_curves(rng, 20, 1001, 0.0)).verdict == STABLE


def test_growth_is_called_diverging_and_estimated():
    rng = np.random.default_rng(2)
    slope = math.log(1.05)
    M = _curves(rng, 10, 401, slope)
    g = estimate_growth(M)
    assert g.window == (200, 401)
    # the estimate lies within its band of the true slope
    assert abs(g.log_slope - slope) < 3 * g.stderr + 1e-12
    assert g.rate == pytest.approx(1.05, rel=0.01)
    assert judge(M).verdict == DIVERGING


def test_too_few_steps_are_undecided():
    rng = np.random.default_rng(3)
    short = _curves(rng, 20, 2 * MIN_WINDOW - 2, 0.0)
    v = judge(short)
    assert v.verdict == UNDECIDED and "too few steps" in v.reason
    # a huge-uncertainty fit (one trial, strong noise) is undecided too
    assert judge(_curves(rng, 1, 41, 0.0, sd=3.0)).verdict == UNDECIDED


def test_exact_rho_decides_where_given():
    rng = np.random.default_rng(4)
    M = _curves(rng, 2, 51, 0.0)
    assert judge(M, rho_exact=1.01).verdict == DIVERGING
    assert judge(M, rho_exact=0.95).verdict == STABLE
    v = judge(M, diverged_at=[30, None])
    assert v.verdict == "diverged" and v.label == "diverged at step 30"


# -- runs ------------------------------------------------------------------------------


@pytest.mark.parametrize("scenario", ["lcsys2022-homogeneous", "dkfe-example2"])
def test_kalman_filter_is_never_diverging_at_50_steps(scenario):
    for seed in SEEDS:
        result = run_monte_carlo(resolve_scenario(scenario), steps=50, trials=2, seed=seed,
                                 families=["centralized-kf"])
        s = result.estimators["centralized-kf"]
        assert s.verdict in (STABLE, UNDECIDED), (seed, s.verdict, s.judgement.reason)


def test_exact_rho_below_one_is_never_diverging_at_50_steps():
    scenario = resolve_scenario("lcsys2022-homogeneous")
    gains = scenario_gains(scenario)
    rho = run_monte_carlo(scenario, steps=2, trials=1, gains=gains,
                          families=["compensated"]).analytics["rho_exact_compensated"]
    assert rho < 1
    for seed in SEEDS:
        result = run_monte_carlo(scenario, steps=50, trials=2, seed=seed, gains=gains,
                                 families=["compensated"])
        s = result.estimators["compensated"]
        assert s.verdict == STABLE and s.judgement.basis == "exact analysis"
        assert s.judgement.analysis.rho_error_recursion == pytest.approx(rho, rel=1e-9)
        # the measurement alone does not call it diverging either
        assert s.judgement.measured != DIVERGING, (seed, s.judgement.reason)


def test_exact_rho_above_one_is_diverging():
    scenario = resolve_scenario("lcsys2022-homogeneous")
    gains = scenario_gains(scenario)
    bad = dataclasses.replace(gains, L=[2.5 * L for L in gains.L])
    N = scenario.n_agents
    free = augmented_closed_loop(scenario.weights, scenario.plant.A, scenario.plant.C, bad.L,
                                 np.zeros((N, N), dtype=int), 0)
    assert spectral_radius(free) > 1  # the delay-free closed loop is unstable
    result = run_monte_carlo(scenario, steps=150, trials=3, gains=bad,
                             families=["compensated"])
    assert result.analytics["rho_exact_compensated"] > 1
    s = result.estimators["compensated"]
    assert s.verdict == DIVERGING
    # the measured growth on its own agrees, and it is about rho^2 per step
    assert s.judgement.measured == DIVERGING
    rho = result.analytics["rho_exact_compensated"]
    assert s.growth_rate == pytest.approx(rho ** 2, rel=0.05)


def test_few_steps_give_undecided():
    result = run_monte_carlo(resolve_scenario("lcsys2022-homogeneous"), steps=10, trials=2,
                             families=["centralized-kf", "uncompensated"])
    for s in result.estimators.values():
        assert s.judgement.measured == UNDECIDED, (s.family, s.judgement.reason)
    # the measurement alone decides the Kalman filter: undecided
    assert result.estimators["centralized-kf"].verdict == UNDECIDED
    # the uncompensated estimator's error is forced by the growing state (rho(A) > 1): the
    # exact analysis of the joint system says diverging from the first step
    s = result.estimators["uncompensated"]
    assert s.verdict == DIVERGING and s.judgement.basis == "exact analysis"


def test_unstable_plant_reports_the_precision_horizon_not_a_divergence(capsys):
    from netsim.cli import main

    scenario = resolve_scenario("lcsys2022-heterogeneous")
    rho_A = spectral_radius(scenario.plant.A)
    assert rho_A > 1
    assert main(["run", "lcsys2022-heterogeneous", "--steps", "20000", "--trials", "1",
                 "--estimators", "compensated", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "beyond the float64 precision horizon at step" in out
    assert "diverged at step" not in out and "diverging" not in out.split("\n\nMSE:")[0]
    result = run_monte_carlo(scenario, steps=20000, trials=1, families=["compensated"],
                             keep_trials=True)
    s = result.estimators["compensated"]
    assert s.diverged == [] and s.verdict == STABLE
    k = s.precision_horizon
    # independent: the state grows like rho(A)^k from its start, so 100 eps |x_k| reaches
    # an error RMS e at about k = log(e / (100 eps |x_0|)) / log rho(A)
    run = result.runs["compensated"][0]
    rms = math.sqrt(float(np.nanmean(run.squared_errors[k // 4: k // 2])))
    x0 = float(np.max(np.abs(run.states[:50])))
    predicted = math.log(rms / (100 * np.finfo(float).eps * x0)) / math.log(rho_A)
    assert abs(k - predicted) < 0.1 * predicted
    assert precision_horizon([run.states[:k // 2]],
                             [run.squared_errors[:k // 2].mean(axis=1)]) is None
    assert math.isfinite(s.steady_state_mse) and s.steady_state_mse < 10
    # the MSE@ columns from the horizon on are not printed, and marked in the JSON
    d = s.to_dict()
    beyond = [m for m in d["mse_at"] if int(m) >= k]
    assert beyond and d["mse_at_beyond_horizon"] == beyond
    assert all(d["mse_at_trusted"][m] is None for m in beyond)
    assert all(d["mse_at_trusted"][m] == d["mse_at"][m] for m in d["mse_at"] if int(m) < k)
    row = next(ln for ln in out.splitlines() if ln.startswith("compensated "))
    assert row.count(BEYOND_HORIZON) == len(beyond)
    assert f"precision horizon at step {k}" in out


# -- heterogeneous delays reach the bound ---------------------------------------------


def test_heterogeneous_delays_reach_tau():
    links = [(0, 1), (1, 2), (2, 3), (3, 0)]
    for tau in range(0, 26):
        for seed in (0, 1, 2022):
            d = heterogeneous_delays(links, tau, seed).delays
            assert max(d.values()) == tau and min(d.values()) >= 0
    scenario = resolve_scenario("lcsys2022-heterogeneous")
    for tau in (3, 8, 19):
        assert int(fixed_delay_matrix(delay_variant(scenario, "heterogeneous", tau)).max()) \
            == tau


# -- one meaning of "bound violated" ---------------------------------------------------


def test_bound_violated_means_exact_above_bound():
    predicted = {"predicted_stable": True, "exact_violates_bound": False}
    assert _verdict(None, {"verdict": DIVERGING}, predicted) == "prediction contradicted"
    assert _verdict(None, {"verdict": "diverged"}, predicted) == "prediction contradicted"
    assert _verdict(None, {"verdict": UNDECIDED}, predicted) == UNDECIDED
    assert _verdict(None, {"verdict": STABLE}, predicted) == STABLE
    violated = {"predicted_stable": True, "exact_violates_bound": True}
    assert _verdict(None, {"verdict": STABLE}, violated) == "bound violated"
    unpredicted = {"predicted_stable": False, "exact_violates_bound": False}
    assert _verdict(None, {"verdict": STABLE}, unpredicted) == "bound conservative"
    assert GROWTH_TOLERANCE == 2.0
