"""The state-major step of the vectorised engine (one delay on every link), forced on.

Large runs with one delay on every link take :func:`netsim.vectorised._state_major_run`
(estimates held (n, N, T)); small ones the agent-major step
(:data:`netsim.vectorised.STATE_MAJOR_MIN_WORK`). The differential tests of
``tests/test_vectorised.py`` run small batches, so here the state-major step is forced
for every size and held to the same references:

* the SimPy event kernel (``assert_engines_agree``: estimates to 1e-9 of the
  magnitudes in play, the same divergence step, effective delays and message counts),
  on random scenarios and on LCSYS2022 with one delay, divergence included;
* the agent-major step on the same batch (a second implementation of the same
  recursion: estimates to round-off, the same divergence steps and NaN pattern);
* itself with scipy's or numpy's sparse products (the same bits), and with or without
  recording the estimates (the same squared errors).
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from netsim.models.seeding import child_sequence

from netsim import vectorised
from tests.helpers import lcsys, with_delays
from tests.test_vectorised import assert_engines_agree, random_case


@lru_cache(maxsize=1)
def lcsys_gains():
    """Gains L_i = 0.3 C_i^T (any gains do to compare two computations of one
    recursion; the LMI design would take seconds)."""
    from netsim.estimators.gains import GainDesign

    C = lcsys().plant.C
    L = tuple(0.3 * np.asarray(Ci, dtype=float).T for Ci in C)
    return GainDesign(L=L, K=tuple(Li @ np.asarray(Ci) for Li, Ci in zip(L, C, strict=True)),
                      rho=0.5, certified_rate=None, certified=False, method="given",
                      solver="none", status="given", message="")


def _force(monkeypatch, state_major: bool) -> list[int]:
    """Force the step (or the agent-major one); returns the state-major step's calls."""
    monkeypatch.setattr(vectorised, "STATE_MAJOR_MIN_WORK", -1 if state_major else 10**18)
    calls: list[int] = []
    real = vectorised._state_major_run

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(vectorised, "_state_major_run", counted)
    return calls


def _run(scenario, family, seeds, steps, **kwargs):
    return vectorised.run_vectorised(scenario, family, lcsys_gains(), seeds, steps,
                                     kernel="numpy", **kwargs)


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(case=random_case())
def test_state_major_agrees_with_the_event_kernel_on_random_scenarios(case, monkeypatch):
    scenario, family, gains, steps = case
    _force(monkeypatch, True)
    seeds = [child_sequence(scenario.seed, "trial", t) for t in range(3)]
    assert_engines_agree(scenario, family, gains, seeds, steps)


@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
@pytest.mark.parametrize("tau", [0, 3, 8])
def test_state_major_agrees_with_the_event_kernel_on_lcsys2022(family, tau, monkeypatch):
    calls = _force(monkeypatch, True)
    scenario = with_delays(lcsys(), model="homogeneous", tau=tau)
    seeds = [child_sequence(11, "trial", t) for t in range(3)]
    assert_engines_agree(scenario, family, lcsys_gains(), seeds, 120)
    assert calls  # the state-major step ran


def test_state_major_reports_divergence_as_the_event_kernel(monkeypatch):
    _force(monkeypatch, True)
    scenario = replace(with_delays(lcsys(), model="homogeneous", tau=3),
                       divergence_threshold=50.0)
    seeds = [child_sequence(3, "trial", t) for t in range(4)]
    assert all(r.diverged_at is not None for r in _run(scenario, "uncompensated", seeds, 400))
    assert_engines_agree(scenario, "uncompensated", lcsys_gains(), seeds, 400)


@pytest.mark.parametrize(("family", "tau", "threshold"), [
    ("compensated", 2, 1e150), ("uncompensated", 5, 1e150), ("uncompensated", 3, 50.0)])
def test_state_major_and_agent_major_steps_agree(family, tau, threshold, monkeypatch):
    scenario = replace(with_delays(lcsys(), model="homogeneous", tau=tau),
                       divergence_threshold=threshold)
    seeds = [child_sequence(5, "trial", t) for t in range(7)]
    calls = _force(monkeypatch, False)
    agent = _run(scenario, family, seeds, 300)
    assert not calls
    calls = _force(monkeypatch, True)
    state = _run(scenario, family, seeds, 300)
    assert calls
    for a, b in zip(agent, state, strict=True):
        assert a.diverged_at == b.diverged_at
        np.testing.assert_array_equal(np.isnan(a.estimates), np.isnan(b.estimates))
        np.testing.assert_array_equal(np.isnan(a.squared_errors), np.isnan(b.squared_errors))
        ok = np.isfinite(a.estimates) & np.isfinite(b.estimates)
        scale = 1.0 + np.abs(a.estimates[ok])
        assert np.max(np.abs(a.estimates[ok] - b.estimates[ok]) / scale, initial=0) < 1e-12


@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
def test_state_major_gives_the_same_bits_with_numpy_or_scipy_products(family, monkeypatch):
    _force(monkeypatch, True)
    scenario = with_delays(lcsys(), model="homogeneous", tau=2)
    seeds = [child_sequence(6, "trial", t) for t in range(3)]
    runs = []
    for numpy_products in (True, False):
        monkeypatch.setattr(vectorised, "NUMPY_PRODUCT_MAX_WORK",
                            10**18 if numpy_products else -1)
        runs.append(_run(scenario, family, seeds, 60))
    for a, b in zip(*runs, strict=True):
        assert a.estimates.tobytes() == b.estimates.tobytes()
        assert a.squared_errors.tobytes() == b.squared_errors.tobytes()


def test_state_major_errors_do_not_depend_on_recording_the_estimates(monkeypatch):
    _force(monkeypatch, True)
    scenario = with_delays(lcsys(), model="homogeneous", tau=3)
    seeds = [child_sequence(8, "trial", t) for t in range(3)]
    kept = _run(scenario, "compensated", seeds, 80)
    lean = _run(scenario, "compensated", seeds, 80, record_estimates=False)
    for a, b in zip(kept, lean, strict=True):
        assert a.squared_errors.tobytes() == b.squared_errors.tobytes()
        assert b.estimates.shape == (0, *a.estimates.shape[1:])


def test_large_runs_with_one_delay_take_the_state_major_step():
    scenario = with_delays(lcsys(), model="homogeneous", tau=3)
    assert not vectorised._state_major(scenario, 3, 40)
    assert vectorised._state_major(scenario, 10_000, 500)


def test_sparse_weights_keep_the_agent_major_step():
    """At 100,000 agents the state-major step cost 1.4x the time and 2x the memory."""
    from scipy import sparse

    scenario = with_delays(lcsys(), model="homogeneous", tau=3)
    sparse_scenario = dataclasses.replace(scenario, weights=sparse.csr_matrix(scenario.weights))
    assert vectorised._state_major(scenario, 10_000, 500)
    assert not vectorised._state_major(sparse_scenario, 10_000, 500)
