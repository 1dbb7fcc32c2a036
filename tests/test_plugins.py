"""A user's estimator as a plugin: the contract, the registry and the commands.

The example plugin (examples/consensus_on_information.py) lives outside the installed
package; these tests run it from its TOML through ``netsim run``, ``--trace`` +
``inspect`` + ``plot``, check it against an independent Kalman filter, and check the
one-line errors for plugins that do not import or do not satisfy the contract.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from helpers import mse_level
from netsim.estimators.contract import Estimator, check_estimator, missing_methods
from netsim.estimators.registry import (
    AgentSetup,
    EstimatorFamily,
    FamilyError,
    get_family,
    register,
    unregister,
)

from netsim.cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "consensus-on-information.toml"
SMALL = ("--steps", "60", "--trials", "2", "--no-progress")


def run_cli(capsys, *args):
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_line_error(code, out, err, *fragments):
    assert "Traceback" not in err, err
    assert code == 2, err
    assert out == ""
    assert err.count("\n") == 1 and err.endswith("\n"), err
    for fragment in fragments:
        assert fragment in err, (fragment, err)


# -- the example plugin against an independent filter ---------------------------


def _example_class():
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        import consensus_on_information
    finally:
        sys.path.remove(str(ROOT / "examples"))
    return consensus_on_information.ConsensusOnInformation


def test_example_plugin_alone_is_the_kalman_filter():
    # One agent with no neighbours: consensus on information is the information-form
    # Kalman filter, so it must equal the centralised (covariance-form) filter.
    from netsim.estimators.kalman import CentralizedKalmanFilter

    rng = np.random.default_rng(7)
    n, m = 3, 2
    A = rng.standard_normal((n, n)) * 0.5
    C = rng.standard_normal((m, n))
    Q, R = 0.1 * np.eye(n), np.diag([0.2, 0.3])
    mean, cov = rng.standard_normal(n), 2.0 * np.eye(n)
    setup = AgentSetup(agent=0, n_agents=1, in_neighbours=(), out_neighbours=(),
                       weights=np.ones(1), A=A, C=C, Q=Q, R=R, prior_mean=mean,
                       prior_cov=cov, L=None, rng=rng, delay_bound=0, sample_period=1.0)
    ci = _example_class()(setup)
    kf = CentralizedKalmanFilter(A, C, Q, R, mean, cov)
    check_estimator(ci, "test")
    for k in range(40):
        y = rng.standard_normal(m)
        np.testing.assert_allclose(ci.step(k, y), kf.step(k, y), rtol=1e-9, atol=1e-10)


def test_example_plugin_predicts_a_neighbours_estimate_from_its_time_stamp():
    # Agent 0 with weight 1/2 on neighbour 1 and no measurement: its estimate is the
    # information-weighted mean of its own prior and neighbour 1's message predicted
    # by A^(k - s) with the covariance grown by Q at each step (computed here by hand).
    n = 2
    A = np.array([[1.0, 0.1], [0.0, 0.9]])
    Q = 0.01 * np.eye(n)
    setup = AgentSetup(agent=0, n_agents=2, in_neighbours=(1,), out_neighbours=(),
                       weights=np.array([0.5, 0.5]), A=A, C=np.zeros((0, n)), Q=Q,
                       R=np.zeros((0, 0)), prior_mean=np.zeros(n), prior_cov=np.eye(n),
                       L=None, rng=np.random.default_rng(0), delay_bound=3, sample_period=1.0)
    ci = _example_class()(setup)
    ci.step(0, np.zeros(0))
    x1, P1 = np.array([1.0, -2.0]), np.diag([0.5, 0.25])
    assert ci.message_arrived(1, 0, np.concatenate([x1, P1.ravel()]))
    assert not ci.message_arrived(1, 0, np.concatenate([x1, P1.ravel()]))  # not fresher
    estimate = ci.step(3, np.zeros(0))
    # own prior at step 3 after steps 0 (no info) and the predictions in between:
    # the test re-derives it: step 0 gives x = 0, P = I; then predicted once to step 1
    # is what ci holds as prior for its next step (it skipped steps 1, 2: the host
    # calls every step, so emulate the one call it got)
    P_own = A @ np.eye(n) @ A.T + Q
    x_j, P_j = x1, P1
    for _ in range(3):
        x_j, P_j = A @ x_j, A @ P_j @ A.T + Q
    Om = 0.5 * np.linalg.inv(P_own) + 0.5 * np.linalg.inv(P_j)
    q = 0.5 * np.linalg.inv(P_own) @ np.zeros(n) + 0.5 * np.linalg.inv(P_j) @ x_j
    np.testing.assert_allclose(estimate, np.linalg.solve(Om, q), rtol=1e-12)
    assert ci.last_delays == {1: 2}


# -- the commands ---------------------------------------------------------------


def test_example_runs_beside_the_builtins(capsys):
    code, out, err = run_cli(capsys, "run", str(EXAMPLE), *SMALL, "--json")
    assert code == 0, err
    data = json.loads(out)
    assert list(data["estimators"]) == ["compensated", "ci-filter", "local-kf",
                                        "centralized-kf"]
    assert data["engine"] == "mixed"
    assert data["engines"] == {"compensated": "vectorised", "ci-filter": "events",
                               "local-kf": "events", "centralized-kf": "vectorised"}
    assert "ci-filter, local-kf have no batched form" in err
    # steady MSE of a stable run, else the mean trusted MSE over the second half
    mse = {name: mse_level(e) for name, e in data["estimators"].items()}
    # no agent observes the unstable plant alone: local filters lose it (MSE grows like
    # rho(A)^(2k)), the networked ones track it within a small multiple of the optimum
    assert mse["local-kf"] > 100 * mse["ci-filter"]
    assert mse["centralized-kf"] <= mse["ci-filter"] < 10 * mse["centralized-kf"]


def test_example_plugin_matches_its_python_api_run():
    # the same trials through the Python API, one trial in the kernel (run_one)
    import netsim

    scenario = netsim.load_scenario(EXAMPLE)
    result = netsim.run(scenario, steps=40, trials=2, estimators=["ci-filter"])
    one = netsim.run_one(scenario, "ci-filter", trial=1, steps=40)
    np.testing.assert_array_equal(result["ci-filter"].squared_errors[1], one.squared_errors)


def test_example_traced_inspected_and_plotted(capsys, tmp_path):
    base = tmp_path / "ci.mcap"
    code, out, err = run_cli(capsys, "run", str(EXAMPLE), "--steps", "40", "--trials", "1",
                             "--estimators", "ci-filter,compensated", "--trace", str(base),
                             "--json", "--no-progress")
    assert code == 0, err
    traces = json.loads(out)["traces"]
    plugin = tmp_path / "ci.ci-filter.trial0.mcap"
    assert str(plugin) in traces
    code, out, err = run_cli(capsys, "inspect", str(plugin), "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["family"] == "ci-filter"
    assert set(report["links"]) == {"0->1", "1->2", "2->3", "3->0"}
    # the trace's errors are the kernel's: compare with an in-memory run of trial 0
    import netsim

    one = netsim.run_one(netsim.load_scenario(EXAMPLE), "ci-filter", trial=0, steps=40)
    trace = netsim.read_trace(plugin)
    np.testing.assert_allclose(trace.estimates(), one.estimates, rtol=0, atol=0)
    assert trace.error_recursion is None  # the plugin declares none
    png = tmp_path / "ci.png"
    code, out, err = run_cli(capsys, "plot", str(plugin), str(tmp_path / "ci.compensated"
                             ".trial0.mcap"), "-o", str(png))
    assert code == 0, err
    assert png.stat().st_size > 10_000
    code, out, err = run_cli(capsys, "replay", str(plugin), "--json")
    assert code == 0 and json.loads(out)["defined"] is False


def test_vectorised_engine_refuses_a_plugin_without_a_batched_form(capsys):
    code, out, err = run_cli(capsys, "run", str(EXAMPLE), *SMALL, "--engine", "vectorised")
    one_line_error(code, out, err, "--engine vectorised", "ci-filter", "batched form")


# -- errors ---------------------------------------------------------------------


def _scenario_with(tmp_path, estimator: str, module_source: str | None = None) -> Path:
    # each test writes its own module (imported modules are cached by name)
    module = f"user_filters_{tmp_path.name.replace('-', '_')}"
    estimator = estimator.replace("user_filters", module)
    text = EXAMPLE.read_text()
    text = text.replace(
        'estimators = ["compensated", "consensus_on_information:ConsensusOnInformation", '
        '"local-kf", "centralized-kf"]', f'estimators = ["compensated", "{estimator}"]')
    path = tmp_path / "plugin.toml"
    path.write_text(text)
    if module_source is not None:
        (tmp_path / f"{module}.py").write_text(textwrap.dedent(module_source))
    return path


def test_plugin_module_that_does_not_import(capsys, tmp_path):
    path = _scenario_with(tmp_path, "no_such_module_xyz:Filter")
    code, out, err = run_cli(capsys, "run", str(path), *SMALL)
    one_line_error(code, out, err, "run.estimators[1]", "no_such_module_xyz")


def test_plugin_attribute_missing(capsys, tmp_path):
    path = _scenario_with(tmp_path, "user_filters:Missing", "class Present:\n    pass\n")
    code, out, err = run_cli(capsys, "run", str(path), *SMALL)
    one_line_error(code, out, err, "run.estimators[1]", "no attribute 'Missing'")


def test_plugin_class_without_step(capsys, tmp_path):
    source = """
        class NoStep:
            def __init__(self, setup):
                pass
            def message_arrived(self, sender, sent_step, payload):
                return True
    """
    path = _scenario_with(tmp_path, "user_filters:NoStep", source)
    code, out, err = run_cli(capsys, "run", str(path), *SMALL)
    one_line_error(code, out, err, "run.estimators[1]", "NoStep", "no method step()")


def test_plugin_factory_building_non_estimators(capsys, tmp_path):
    source = """
        def build(context):
            return [object() for _ in range(context.scenario.n_agents)]
    """
    path = _scenario_with(tmp_path, "user_filters:build", source)
    code, out, err = run_cli(capsys, "run", str(path), *SMALL)
    one_line_error(code, out, err, "run.estimators", "agent 0", "no method message_arrived()")


def test_plugin_that_raises_while_importing(capsys, tmp_path):
    path = _scenario_with(tmp_path, "user_filters:X", "raise RuntimeError('boom')\n")
    code, out, err = run_cli(capsys, "run", str(path), *SMALL)
    one_line_error(code, out, err, "run.estimators[1]", "RuntimeError: boom")


def test_contract_check_names_what_is_missing():
    class Half:
        def step(self, k):
            return None

    problems = missing_methods(Half())
    assert "no method message_arrived()" in problems
    assert "step() does not take 2 arguments" in problems
    assert not isinstance(Half(), Estimator)


# -- Python registration and entry points ---------------------------------------


def test_registered_family_with_the_lockstep_rule_runs_on_both_engines():
    # a user's family reusing the vectorised engine's consensus lockstep: both engines
    # must agree (the differential contract of a batched form)
    import netsim

    builtin = get_family("compensated")
    mine = register(EstimatorFamily(
        name="my-compensated", build=builtin.build, needs_gains=True,
        batched=builtin.batched, batched_options=dict(builtin.batched_options)),
        replace_existing=True)
    try:
        scenario = netsim.load_scenario("lcsys2022-time-varying")
        fast = netsim.run(scenario, steps=40, trials=3, estimators=[mine.name],
                          engine="vectorised")
        slow = netsim.run(scenario, steps=40, trials=3, estimators=[mine.name],
                          engine="events")
        np.testing.assert_allclose(fast[mine.name].estimates, slow[mine.name].estimates,
                                   rtol=1e-9, atol=1e-9)
        ref = netsim.run(scenario, steps=40, trials=3, estimators=["compensated"],
                         engine="events")
        np.testing.assert_array_equal(ref["compensated"].estimates,
                                      slow[mine.name].estimates)
    finally:
        unregister(mine.name)


def test_register_refuses_a_taken_name():
    with pytest.raises(ValueError, match="registered already"):
        register(EstimatorFamily("compensated", lambda context: []))


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(FamilyError, match="run.estimators.*local-kf"):
        get_family("no-such-family", "run.estimators")


def test_entry_point_family(tmp_path):
    # an installed package declaring the entry point group netsim.estimators
    site = tmp_path / "site"
    dist = site / "userpkg-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: userpkg\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[netsim.estimators]\nhold-prior = userpkg_filters:HoldPrior\n")
    (site / "userpkg_filters.py").write_text(textwrap.dedent("""
        import numpy as np

        class HoldPrior:
            def __init__(self, setup):
                self.estimate = np.array(setup.prior_mean, dtype=float)
            def message_arrived(self, sender, sent_step, payload):
                return False
            def step(self, k, y):
                return self.estimate
    """))
    code = ("import json, netsim; "
            "print('hold-prior' in netsim.estimator_names()); "
            "r = netsim.run('lcsys2022-heterogeneous', steps=30, trials=2, "
            "estimators=['hold-prior']); "
            "import numpy as np; s = r['hold-prior']; "
            "print(np.allclose(s.estimates, 0.0), "
            "np.allclose(s.squared_errors, (s.states ** 2).sum(axis=-1)[..., None]))")
    env = {**os.environ, "PYTHONPATH": str(site)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", "True", "True"]


def test_example_takes_part_in_bench_delay_tolerance_and_sweep(capsys, tmp_path):
    code, out, err = run_cli(capsys, "bench", "delay-tolerance", str(EXAMPLE), "--taus", "0,2",
                             "--delays", "homogeneous", "--trials", "2", "--steps", "60",
                             "--json", "--no-progress")
    assert code == 0, err
    assert "ci-filter, local-kf have no batched form" in err
    data = json.loads(out)
    assert data["families"] == ["compensated", "ci-filter", "local-kf", "centralized-kf"]
    cells = {(c["tau"], c["family"]): c for c in data["cells"]}
    for tau in (0, 2):
        plugin = cells[(tau, "ci-filter")]
        # no recursion declared: no bound, no prediction, the measurement decides
        assert plugin["analytics"]["bound"] is None
        assert plugin["verdict"] == plugin["measured"]["verdict"]
    # its cell runs the same trials as netsim run with the same seed: the same MSE
    import netsim
    from netsim.bench.variants import delay_variant

    variant = delay_variant(netsim.load_scenario(EXAMPLE), "homogeneous", 2)
    same = netsim.run(variant, steps=60, trials=2, seed=data["seed"],
                      estimators=["ci-filter"])
    assert cells[(2, "ci-filter")]["measured"]["last_trusted_mse"] == pytest.approx(
        same.summary["ci-filter"].last_trusted_mse, rel=1e-12)
    assert cells[(2, "ci-filter")]["measured"]["verdict"] == same.summary["ci-filter"].verdict
    if same.summary["ci-filter"].verdict == "stable":
        assert cells[(2, "ci-filter")]["measured"]["steady_state_mse"] == pytest.approx(
            same.summary["ci-filter"].steady_state_mse, rel=1e-12)
    tolerance = {(t["family"], t["setting"]): t for t in data["tolerance"]}
    assert tolerance[("ci-filter", "homogeneous")]["predicted"] is None
    assert ("local-kf", "homogeneous") not in tolerance  # no communication: no tolerance
    code, out, err = run_cli(capsys, "bench", "sweep", str(EXAMPLE), "--estimators",
                             "compensated,ci-filter", "--taus", "0,2", "--delays",
                             "homogeneous", "--trials", "2", "--steps", "40", "--out",
                             str(tmp_path / "rows.jsonl"), "--json", "--no-progress")
    assert code == 0, err
    rows = json.loads(out)["rows"]
    assert len(rows) == 2
    assert all(set(r["result"]["estimators"]) == {"compensated", "ci-filter"} for r in rows)


class _Hold:
    """Keeps the prior: x-hat_k = x0_mean (a user's estimator with a batched form)."""

    def __init__(self, setup):
        self.estimate = np.array(setup.prior_mean, dtype=float)

    def message_arrived(self, sender, sent_step, payload):
        return False

    def step(self, k, y):
        return self.estimate


def _hold_batched(scenario, family, gains, trial_seeds, steps, *, record_delays=False,
                  record_estimates=True, progress=None):
    # the batched contract: one TrialResult per trial, the per-agent form's numbers
    from netsim.kernel import TrialResult
    from netsim.vectorised import simulate_plant

    K = scenario.steps if steps is None else int(steps)
    batch = simulate_plant(scenario, trial_seeds, K)
    N, prior = scenario.n_agents, scenario.plant.x0_mean
    out = []
    for t in range(len(trial_seeds)):
        x = batch.states[:, t]
        sq = np.repeat(((x - prior) ** 2).sum(axis=1)[:, None], N, axis=1)
        out.append(TrialResult(
            states=x.copy(), measurements=[], estimates=np.broadcast_to(
                prior, (K + 1, N, len(prior))).copy(), squared_errors=sq,
            effective_delays=None, diverged_at=None, messages_sent=0,
            messages_delivered=0, messages_discarded=0))
    if progress is not None:
        progress(len(trial_seeds))
    return out


def test_a_plugin_with_its_own_batched_form_gets_the_vectorised_engine():
    import netsim

    _Hold.batched = staticmethod(_hold_batched)
    family = netsim.register_estimator(_Hold, "hold-batched", replace_existing=True)
    try:
        assert family.vectorised
        scenario = netsim.load_scenario("lcsys2022-heterogeneous")
        fast = netsim.run(scenario, steps=30, trials=3, estimators=["hold-batched"],
                          engine="vectorised")
        slow = netsim.run(scenario, steps=30, trials=3, estimators=["hold-batched"],
                          engine="events")
        assert fast.monte_carlo.engine == "vectorised" and slow.monte_carlo.engine == "events"
        np.testing.assert_allclose(fast["hold-batched"].squared_errors,
                                   slow["hold-batched"].squared_errors, rtol=1e-12)
    finally:
        unregister("hold-batched")
        del _Hold.batched
