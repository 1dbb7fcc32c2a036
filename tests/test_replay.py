"""Replay, analytics and plots recomputed from MCAP traces (traces.replay/analysis/plot).

Traces are recorded with the real event kernel (``run_trial`` + ``TraceRecorder``) and
read back; everything below is computed from the files alone and checked against the
scenario.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest
from netsim.models.augmented import (
    augmented_closed_loop,
    closed_loop_sequence_growth,
    delay_bound_lcsys,
    spectral_radius,
    tau_star,
)
from netsim.models.scenario import resolve_scenario
from netsim.traces.analysis import DECAY_TOLERANCE, analyze_trace, growth_rates
from netsim.traces.plot import plot_traces
from netsim.traces.reader import read_trace
from netsim.traces.recorder import TraceRecorder
from netsim.traces.replay import replay_trace, trace_system

from netsim.runner import fixed_delay_matrix, run_trial, scenario_gains

STEPS = 120
SEED = 5
ROOT = Path(__file__).resolve().parents[1]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def design():
    """The heterogeneous scenario (tau 3) and its gains, designed once.

    The built-in LCSYS2022 scenarios share plant, weights and gain method, so the same
    gains serve the time-varying and delay-free variants (checked in ``_scenario``).
    """
    scenario = resolve_scenario("lcsys2022-heterogeneous").with_tau(3)
    return scenario, scenario_gains(scenario)


def _scenario(design, name, tau):
    base, gains = design
    scenario = resolve_scenario(name).with_tau(tau)
    same = (np.array_equal(scenario.weights, base.weights)
            and np.array_equal(scenario.plant.A, base.plant.A)
            and all(np.array_equal(a, b) for a, b in zip(scenario.plant.C, base.plant.C,
                                                          strict=True))
            and scenario.gains.method == base.gains.method)
    return scenario, (gains if same else scenario_gains(scenario))


@pytest.fixture(scope="module")
def record(design, tmp_path_factory):
    folder = tmp_path_factory.mktemp("replay")
    cache = {}

    def _record(name, tau, family, steps=STEPS):
        key = (name, tau, family, steps)
        if key not in cache:
            scenario, gains = _scenario(design, name, tau)
            path = folder / f"{name}.tau{tau}.{family}.{steps}.mcap"
            with TraceRecorder.for_run(path, scenario, gains, family, 0, seed=SEED,
                                       steps=steps) as recorder:
                run_trial(scenario, family, gains, SEED, steps, observer=recorder)
            cache[key] = read_trace(path)
        return cache[key]

    return _record


HET = "lcsys2022-heterogeneous"
TV = "lcsys2022-time-varying"
DELAYED = [(HET, 3), (TV, 4)]


# -- replay ---------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "tau"), DELAYED)
def test_compensated_exact_eta_reproduces_recorded_errors(record, name, tau):
    trace = record(name, tau, "compensated")
    report = replay_trace(trace)
    assert report.defined and report.compensated is True
    assert report.steps_replayed == STEPS
    assert report.tau >= 1 and report.nonzero_delay_steps > 0
    assert report.substitutions > 0  # start-up: nothing arrived yet, own estimate used
    assert report.exact.max_rel < 1e-9
    assert report.exact.reproduces and report.exact.cause == ""
    # the agent-by-agent recursion is the same computation without the big matrices
    other = replay_trace(trace, method="agents" if report.method == "dense" else "dense")
    np.testing.assert_allclose(other.exact.errors, report.exact.errors, rtol=0, atol=1e-10)
    np.testing.assert_allclose(other.paper.errors, report.paper.errors, rtol=0, atol=1e-10)


@pytest.mark.parametrize(("name", "tau"), DELAYED)
def test_compensated_paper_eta_deviates_with_delays(record, name, tau):
    report = replay_trace(record(name, tau, "compensated"))
    paper = report.paper
    assert paper.max_rel > 1e-6
    assert not paper.reproduces
    assert paper.first_step_above is not None and paper.first_step_above >= 1
    assert "omits the accumulated process noise" in paper.cause
    assert report.eta_gap > 0
    text = report.format_text()
    assert "DEVIATES" in text and "reproduces the recorded errors" in text


@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
def test_paper_eta_matches_without_delays(record, family):
    report = replay_trace(record(HET, 0, family))
    assert report.tau == 0 and report.nonzero_delay_steps == 0
    assert report.exact.max_rel < 1e-9
    assert report.paper.max_rel < 1e-9
    assert report.paper.reproduces


@pytest.mark.parametrize(("name", "tau"), DELAYED)
def test_uncompensated_exact_eta_reproduces_and_cause_is_stated(record, name, tau):
    report = replay_trace(record(name, tau, "uncompensated"))
    assert report.defined and report.compensated is False
    assert report.exact.max_rel < 1e-9
    assert not report.paper.reproduces and report.paper.max_rel > 1e-6
    assert "proportional to the state" in report.paper.cause
    assert report.state_term is not None and report.state_term > 0
    assert "state-proportional" in report.verdict


@pytest.mark.parametrize("family", ["block", "centralized-kf"])
def test_replay_not_defined_for_other_families(record, family):
    report = replay_trace(record(HET, 3, family, steps=40))
    assert not report.defined
    assert report.reason
    assert "not defined" in report.format_text()
    json.dumps(report.to_dict())


@pytest.mark.parametrize("family, kind", [("compensated", True), ("uncompensated", False),
                                          ("block", None), ("centralized-kf", None)])
def test_recursion_kind_is_the_one_family_decision(record, family, kind):
    """Which recursion a trace's family has is decided in one place (_recursion_kind)."""
    from netsim.traces.replay import _recursion_kind

    trace = record(HET, 3, family, steps=40)
    assert _recursion_kind(trace) is kind
    assert replay_trace(trace).compensated is kind


def test_replay_report_is_json_ready(record):
    report = replay_trace(record(HET, 3, "compensated"))
    data = json.loads(json.dumps(report.to_dict()))
    assert data["exact"]["reproduces"] is True
    assert data["paper"]["reproduces"] is False


# -- analysis -------------------------------------------------------------------------


def _system(scenario, gains):
    return scenario.weights, scenario.plant.A, scenario.plant.C, gains.L


@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
def test_analysis_exact_rho_of_fixed_pattern_matches_scenario(design, record, family):
    scenario, gains = design
    analysis = analyze_trace(record(HET, 3, family))
    assert analysis.rho_delay_free == pytest.approx(gains.rho, abs=1e-10)  # scenario_gains
    P, A, C, L = _system(scenario, gains)
    delays = fixed_delay_matrix(scenario)
    expected = spectral_radius(augmented_closed_loop(
        P, A, C, L, delays, int(delays.max()), compensated=(family == "compensated")))
    assert analysis.rho_exact_final == pytest.approx(expected, abs=1e-10)
    assert analysis.rho_exact_max == pytest.approx(expected, abs=1e-10)
    assert analysis.tau_obs == int(delays.max())
    assert analysis.tau_star == tau_star(P, A, C, L)
    assert analysis.bound_lcsys_eq26 == pytest.approx(
        delay_bound_lcsys(P, A, C, L, analysis.tau_obs), abs=1e-12)
    assert analysis.bound_delay_tolerant == pytest.approx(
        gains.rho ** (1.0 / (analysis.tau_obs + 1)), abs=1e-12)
    # one pattern for all steps after the start-up (substitution) steps
    steady = [p for p in analysis.patterns if not p.substituted]
    assert len(steady) == 1 and steady[0].count == STEPS - analysis.startup_steps
    assert analysis.startup_steps >= 1
    assert set(analysis.verdicts) >= {"stability", "eq26", "delay_tolerant", "theorem1",
                                      "growth", "decay"}
    json.dumps(analysis.to_dict())


def test_analysis_verdicts_for_compensated_fixed_delays(record):
    analysis = analyze_trace(record(HET, 3, "compensated"))
    v = analysis.verdicts
    assert v["stability"].startswith("exact max rho") and "< 1: stable" in v["stability"]
    assert v["eq26"].startswith("respected")
    decay = analysis.decay
    assert decay.transient and decay.factor < 1
    # one trial's transient is noisy: near the spectral rate, not equal to it
    assert decay.factor == pytest.approx(analysis.rho_exact_max, abs=0.05)
    consistent = decay.factor <= analysis.spectral_prediction + DECAY_TOLERANCE
    assert ("INCONSISTENT" not in v["decay"]) == consistent
    text = analysis.format_text()
    assert "tau*" in text and "eq. (26)" in text and "verdicts" in text


def test_uncompensated_error_growth_is_flagged(record):
    analysis = analyze_trace(record(HET, 3, "uncompensated"))
    assert analysis.rho_exact_max < 1  # its A-hat is stable ...
    assert "GROWS" in analysis.verdicts["decay"]  # ... but the error grows with the state


def test_growth_rate_of_fixed_delays_is_log_rho(design, record):
    scenario, gains = design
    analysis = analyze_trace(record(HET, 3, "compensated", steps=400))
    rho = analysis.rho_exact_final
    assert analysis.rho_exact_final == pytest.approx(analysis.rho_exact_max)
    assert analysis.tail_growth_rate == pytest.approx(math.log(rho), abs=2e-3)
    assert analysis.growth_rate == pytest.approx(math.log(rho), abs=1e-2)
    assert analysis.growth_factor == pytest.approx(math.exp(analysis.growth_rate))


@pytest.mark.parametrize("family", ["compensated", "uncompensated"])
def test_growth_matches_models_sequence_growth(record, family):
    trace = record(TV, 4, family)
    system, _ = trace_system(trace)
    edge = (system.P != 0) & ~np.eye(system.n_agents, dtype=bool)
    D = trace.effective_delays()
    # from the first step without substitutions (models' helper has a fixed P)
    start = next(k for k in range(1, D.shape[0]) if np.all(D[k][edge] >= 0))
    seq = [np.where(edge, D[k], 0) for k in range(start, min(start + 60, D.shape[0]))]
    tau = int(max(d.max() for d in seq))
    compensated = family == "compensated"
    full, late = growth_rates(system, seq, tau, compensated)
    expected = closed_loop_sequence_growth(system.P, system.A, system.C, system.L, seq, tau,
                                           compensated)
    assert full == pytest.approx(expected, abs=1e-9)
    assert math.isfinite(late)


def test_analysis_of_time_varying_delays(record):
    analysis = analyze_trace(record(TV, 4, "compensated"))
    assert analysis.n_patterns > 5
    assert sum(p.count for p in analysis.patterns) == STEPS
    assert analysis.tau_obs <= 4
    assert analysis.rho_exact_max >= analysis.rho_exact_weighted
    assert analysis.growth_rate is not None and math.isfinite(analysis.growth_rate)
    assert "growth" in analysis.verdicts


def test_analysis_of_block_and_centralized(design, record):
    scenario, gains = design
    block = analyze_trace(record(HET, 3, "block", steps=40))
    assert block.block_period == 4
    P, A, C, L = _system(scenario, gains)
    assert block.spectral_prediction == pytest.approx(delay_bound_lcsys(P, A, C, L, 3))
    assert not block.patterns
    kf = analyze_trace(record(HET, 3, "centralized-kf", steps=40))
    assert kf.decay is not None and "decay" in kf.verdicts
    json.dumps(block.to_dict())
    json.dumps(kf.to_dict())


# -- plot -----------------------------------------------------------------------------


def test_plot_writes_a_png(record, tmp_path):
    traces = [record(HET, 3, f) for f in ("compensated", "uncompensated")]
    traces.append(record(HET, 3, "block", steps=40))
    out = plot_traces(traces, tmp_path / "summary.png")
    data = out.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > 10_000
    image = mpimg.imread(out)
    assert image.ndim == 3 and image.shape[0] > 300 and image.shape[1] > 600


def test_plot_needs_a_trace(tmp_path):
    with pytest.raises(ValueError):
        plot_traces([], tmp_path / "empty.png")


# -- layering -------------------------------------------------------------------------


def test_traces_modules_do_not_import_netsim_or_simpy():
    code = ("import sys, netsim.traces.replay, netsim.traces.analysis, netsim.traces.plot; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'simpy' or "
            "(m.startswith('netsim.') and "
            "m.split('.')[1] not in ('models', 'traces', 'estimators'))); "
            "print(bad); sys.exit(1 if bad else 0)")
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
