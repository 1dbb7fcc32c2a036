"""Differential tests: the vectorised engine's compiled step against its numpy step.

The numpy step (:func:`netsim.vectorised._consensus_run`) is the reference. For the
same seeds the compiled step (:mod:`netsim.lockstep_numba`, ``kernel="numba"``) must
give the same divergence steps, effective delays, message counts and drop records,
and the same estimates and squared errors to round-off (1e-10 relative to the
magnitudes in play): it groups the additions differently (the terms of one lag are
summed before A^lag is applied). Skipped when numba is not installed.

Also: the choice of the step (``NETSIM_NUMBA``), and that importing
:mod:`netsim.vectorised` loads neither numba, scipy.sparse nor simpy.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from netsim.models.scenario import parse_scenario
from netsim.models.seeding import child_sequence

from netsim import vectorised
from netsim.vectorised import choose_kernel, run_vectorised
from tests.helpers import lcsys, with_delays
from tests.test_vectorised import random_case

TOLERANCE = 1e-10

needs_numba = pytest.mark.skipif(not vectorised.numba_available(),
                                 reason="numba is not installed (netsim[numba])")


def assert_steps_agree(scenario, family, gains, seeds, steps, **kwargs):
    """Run both steps on the same seeds and compare everything they report."""
    ref = run_vectorised(scenario, family, gains, seeds, steps, record_delays=True,
                         kernel="numpy", **kwargs)
    got = run_vectorised(scenario, family, gains, seeds, steps, record_delays=True,
                         kernel="numba", **kwargs)
    for t, (a, b) in enumerate(zip(ref, got, strict=True)):
        where = f"{family}, trial {t}"
        assert a.diverged_at == b.diverged_at, where
        end = steps if a.diverged_at is None else a.diverged_at
        assert np.array_equal(a.states, b.states, equal_nan=True), where
        if a.estimates.size:
            ea, eb = a.estimates[: end + 1], b.estimates[: end + 1]
            finite = np.isfinite(ea)
            np.testing.assert_array_equal(finite, np.isfinite(eb), err_msg=where)
            scale = 1.0 + np.maximum(
                np.nanmax(np.abs(a.states[: end + 1]), axis=1),
                np.nanmax(np.abs(np.where(finite, ea, 0.0)), axis=(1, 2)))[:, None, None]
            diff = np.abs(ea - eb)[finite] / np.broadcast_to(scale, ea.shape)[finite]
            assert diff.size == 0 or diff.max() <= TOLERANCE, (where, diff.max())
            assert np.all(np.isnan(b.estimates[end + 1:])), where
        sa, sb = a.squared_errors, b.squared_errors
        np.testing.assert_array_equal(np.isnan(sa), np.isnan(sb), err_msg=where)
        ok = np.isfinite(sa) & np.isfinite(sb)
        np.testing.assert_array_equal(np.isfinite(sa), np.isfinite(sb), err_msg=where)
        np.testing.assert_allclose(np.sqrt(sb[ok]), np.sqrt(sa[ok]), rtol=1e-8, atol=1e-10,
                                   err_msg=where)
        np.testing.assert_array_equal(a.effective_delays, b.effective_delays, err_msg=where)
        for name in ("messages_sent", "messages_delivered", "messages_discarded",
                     "messages_dropped", "drop_reasons", "drops"):
            assert getattr(a, name) == getattr(b, name), (where, name)


def _random_scenario(N: int, n: int, sizes: list[int], delays: dict, seed: int):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A *= 0.98 / np.max(np.abs(np.linalg.eigvals(A)))
    data = {
        "name": "numba-differential",
        "run": {"steps": 80, "trials": 3, "seed": seed, "divergence_threshold": 1e8},
        "plant": {"A": A.tolist(), "C": [rng.normal(size=(m, n)).tolist() for m in sizes],
                  "Q": 0.01, "R": 0.01},
        "network": {"topology": "random", "agents": N, "seed": seed, "weights": "random",
                    "edge_probability": 0.4},
        "delays": delays,
        "gains": {"method": "lmi"},
    }
    scenario = parse_scenario(data, "test")
    gains = SimpleNamespace(L=[0.2 * np.linalg.pinv(C) for C in scenario.plant.C])
    return scenario, gains


@needs_numba
@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
@pytest.mark.parametrize("delays", [
    {"model": "homogeneous", "tau": 3},
    {"model": "heterogeneous", "tau": 6, "seed": 5},
    {"model": "asynchronous", "tau": 4},
    {"model": "synchronous", "tau": 3},
    {"model": "none"},
])
def test_numba_step_agrees_with_numpy_step(family, delays):
    """Several outputs per agent (padded), every delay model, both consensus rules."""
    scenario, gains = _random_scenario(7, 3, [1, 2, 1, 3, 1, 2, 1], delays, seed=4)
    seeds = [child_sequence(scenario.seed, "trial", t) for t in range(3)]
    assert_steps_agree(scenario, family, gains, seeds, 80)
    assert_steps_agree(scenario, family, gains, seeds, 80, record_estimates=False)


def lcsys_gains() -> SimpleNamespace:
    """Fixed gains L_i = 0.3 C_i^T (no design: the engines' arithmetic is the point)."""
    return SimpleNamespace(L=[0.3 * C.T for C in lcsys().plant.C])


@needs_numba
def test_numba_step_agrees_on_lcsys2022_and_reports_divergence_at_the_same_step():
    scenario = with_delays(lcsys(), model="asynchronous", tau=5)
    seeds = [child_sequence(11, "trial", t) for t in range(4)]
    assert_steps_agree(scenario, "compensated", lcsys_gains(), seeds, 200)
    # the uncompensated estimator on the unstable plant blows up (LCSYS2022's plant)
    unstable = replace(with_delays(lcsys(), model="homogeneous", tau=3),
                       divergence_threshold=50.0)
    results = run_vectorised(unstable, "uncompensated", lcsys_gains(), seeds, 300,
                             kernel="numba")
    assert all(r.diverged_at is not None for r in results)
    assert_steps_agree(unstable, "uncompensated", lcsys_gains(), seeds, 300)


@needs_numba
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_case())
def test_numba_step_agrees_on_random_scenarios(case):
    """Random plants, graphs, delay models, losses, outages, buffers and unstable gains
    (test_vectorised's cases); the block rule always runs the numpy step."""
    scenario, family, gains, steps = case
    seeds = [child_sequence(scenario.seed, "trial", t) for t in range(3)]
    assert_steps_agree(scenario, family, gains, seeds, steps)


@needs_numba
def test_same_seed_same_numbers_with_the_numba_step():
    scenario = with_delays(lcsys(), model="asynchronous", tau=4)
    seeds = [child_sequence(9, "trial", t) for t in range(3)]
    a = run_vectorised(scenario, "compensated", lcsys_gains(), seeds, 100, kernel="numba")
    b = run_vectorised(scenario, "compensated", lcsys_gains(), seeds, 100, kernel="numba")
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.estimates, y.estimates)
        assert np.array_equal(x.squared_errors, y.squared_errors)


def test_the_step_is_chosen_by_argument_then_environment(monkeypatch):
    monkeypatch.delenv(vectorised.KERNEL_ENV, raising=False)
    assert choose_kernel() == "numpy"
    assert choose_kernel("numpy") == "numpy"
    monkeypatch.setenv(vectorised.KERNEL_ENV, "0")
    assert choose_kernel() == "numpy"
    with pytest.raises(ValueError, match="kernel must be"):
        choose_kernel("fortran")
    monkeypatch.setattr(vectorised, "numba_available", lambda: False)
    monkeypatch.setenv(vectorised.KERNEL_ENV, "1")
    with pytest.warns(RuntimeWarning, match=r"netsim\[numba\]"):
        assert choose_kernel() == "numpy"
    from netsim.models.extras import MissingExtra

    with pytest.raises(MissingExtra, match=r"netsim\[numba\]"):
        choose_kernel("numba")
    monkeypatch.setattr(vectorised, "numba_available", lambda: True)
    assert choose_kernel() == "numba"
    assert choose_kernel("numpy") == "numpy"


def test_importing_the_engine_loads_no_heavy_module():
    code = ("import sys, json, netsim.vectorised\n"
            "print(json.dumps([m for m in ('numba', 'scipy.sparse', 'simpy', "
            "'netsim.kernel', 'netsim.lockstep_numba') if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
