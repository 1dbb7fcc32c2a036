"""netsim design on the LCSYS2022 scenario: rho < 1, block-diagonal K, tau*, tau1 design."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import lcsys
from netsim.models.augmented import augmented_closed_loop, spectral_radius

from netsim.cli import main


def _closed_loop_rho(P, A, C, K):
    N, n = P.shape[0], A.shape[0]
    KD = np.zeros((N * n, N * n))
    for i in range(N):
        KD[i * n:(i + 1) * n, i * n:(i + 1) * n] = K[i] @ C[i].T @ C[i]
    return max(abs(np.linalg.eigvals((np.eye(N * n) - KD) @ np.kron(P, A))))


@pytest.mark.parametrize("method", ["lmi", "auto"])
def test_design_reaches_rho_below_one_with_block_diagonal_gain(capsys, method):
    assert main(["design", "lcsys2022-heterogeneous", "--method", method, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    d = data["design"]
    s = lcsys()
    K = [np.array(k) for k in d["K"]]
    assert len(K) == s.n_agents and all(k.shape == (6, 6) for k in K)  # one block per agent
    rho = _closed_loop_rho(s.weights, s.plant.A, s.plant.C, K)
    assert rho < 1
    assert rho == pytest.approx(d["rho_delay_free"], abs=1e-8)
    assert d["method"] and d["solver"]
    if d["certified"]:
        assert rho <= d["certified_rate"] + 1e-6
    assert isinstance(data["tau_star"], int)


def test_delay_bound_design_tolerates_its_tau1(capsys):
    code = main(["design", "lcsys2022-heterogeneous", "--method", "lmi", "--tau1", "3",
                 "--json"])
    out = capsys.readouterr()
    if code != 0:  # allowed: it must then say plainly that it is infeasible
        assert "infeasible" in out.err
        return
    d = json.loads(out.out)["design"]
    s = lcsys()
    L = [np.array(x) for x in d["L"]]
    N = s.n_agents
    edges = (s.weights > 0) & ~np.eye(N, dtype=bool)
    for tau in range(4):
        delays = np.where(edges, tau, 0)
        M = augmented_closed_loop(s.weights, s.plant.A, s.plant.C, L, delays, tau)
        assert spectral_radius(M) < 1, f"tau = {tau}"


# -- netsim design shows what netsim run uses: the scenario's [gains] table ------------


def _json_main(capsys, argv):
    code = main(argv)
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


#: Runs only long enough to report the gains (they do not depend on steps or trials).
_SHORT_RUN = ["--json", "--no-progress", "--trials", "1", "--steps", "3",
              "--estimators", "compensated"]


def test_design_defaults_to_the_gains_netsim_run_uses(capsys):
    run = _json_main(capsys, ["run", "lcsys2022-heterogeneous", *_SHORT_RUN])
    design = _json_main(capsys, ["design", "lcsys2022-heterogeneous", "--json"])
    np.testing.assert_allclose(np.array(design["design"]["L"]), np.array(run["gains"]["L"]),
                               rtol=0, atol=1e-12)
    assert design["design"]["rho_delay_free"] == pytest.approx(
        run["gains"]["rho_delay_free"], abs=1e-12)
    assert design["design"]["method"] == run["gains"]["method"]
    g = design["gains"]
    assert (g["method"], g["tau1"], g["refine_from"]) == ("lmi", 0, None)
    assert g["scenario_gains"] is True and g["overridden"] == []


def test_design_text_says_the_gains_are_the_scenarios(capsys):
    assert main(["design", "lcsys2022-heterogeneous"]) == 0
    assert "gains: lmi: the scenario's [gains]" in capsys.readouterr().out


def _builtin_toml(name: str = "lcsys2022-heterogeneous") -> str:
    from pathlib import Path

    import netsim.models.scenario as scenario_module

    return (Path(scenario_module.__file__).parent / "scenarios" / f"{name}.toml").read_text()


def _with_gains(tmp_path, gains: str, name: str = "variant"):
    """The heterogeneous built-in with its [gains] table replaced by ``gains``."""
    text = _builtin_toml()
    head, _, _ = text.partition("[gains]")
    path = tmp_path / f"{name}.toml"
    path.write_text(head + "[gains]\n" + gains + "\n")
    return str(path)


def _system(path):
    from netsim.models.scenario import resolve_scenario

    s = resolve_scenario(path)
    return s.weights, s.plant.A, s.plant.C


# A small unstable plant (n = 2, N = 2) so that CCL takes a second, not twenty.
_SMALL = """
[run]
steps = 20
trials = 2
estimators = ["compensated", "centralized-kf"]

[plant]
A = [[1.02, 0.2], [0.0, 0.95]]
C = [[[1.0, 0.0]], [[0.0, 1.0]]]
Q = 0.01
R = 0.01

[network]
topology = "cycle"
agents = 2
weights = "random"
seed = 3

[delays]
model = "homogeneous"
tau = 1

[gains]
"""


def test_a_ccl_scenario_runs_with_ccl_gains(capsys, tmp_path):
    from netsim.estimators.gains import design_gains

    path = tmp_path / "small-ccl.toml"
    path.write_text(_SMALL + 'method = "ccl"\n')
    independent = design_gains(*_system(str(path)), method="ccl")
    run = _json_main(capsys, ["run", str(path), *_SHORT_RUN])
    assert run["gains"]["method"].startswith("ccl")
    np.testing.assert_allclose(np.array(run["gains"]["L"]), np.array(independent.L),
                               rtol=0, atol=1e-10)
    design = _json_main(capsys, ["design", str(path), "--json"])
    assert design["gains"]["method"] == "ccl" and design["gains"]["scenario_gains"] is True
    np.testing.assert_allclose(np.array(design["design"]["L"]), np.array(independent.L),
                               rtol=0, atol=1e-10)
    # --method overrides the scenario and says so
    lmi = _json_main(capsys, ["design", str(path), "--method", "lmi", "--json"])
    assert lmi["gains"]["scenario_gains"] is False and lmi["gains"]["overridden"] == ["--method"]
    assert lmi["gains"]["scenario"]["method"] == "ccl"
    assert lmi["design"]["method"].startswith("block-diagonal-lmi")


def test_refined_and_tau1_scenarios_match_the_direct_calls(tmp_path):
    from netsim.estimators.gains import design_gains, refine_gains
    from netsim.models.scenario import resolve_scenario

    from netsim.runner import scenario_gains

    path = tmp_path / "small-refined.toml"
    path.write_text(_SMALL + 'method = "refined"\nrefine_from = "lmi"\ntau1 = 1\n')
    P, A, C = _system(str(path))
    want = refine_gains(design_gains(P, A, C, method="lmi", tau1=1), P, A, C, tau1=1)
    got = scenario_gains(resolve_scenario(str(path)))
    assert got.method == "refined" and got.design_tau == 1
    np.testing.assert_allclose(np.array(got.L), np.array(want.L), rtol=0, atol=1e-10)
    # the delay-free rho, recomputed here from K
    assert _closed_loop_rho(P, A, C, got.K) == pytest.approx(got.rho, abs=1e-9)


def test_given_gains_and_their_refinement(capsys, tmp_path):
    P, A, C = _system(_with_gains(tmp_path, 'method = "lmi"', "probe"))
    K = [0.5 * np.linalg.pinv(c) @ c for c in C]  # half of the own-output projector
    K_toml = "K = " + repr([k.tolist() for k in K])
    given = _with_gains(tmp_path, 'method = "given"\n' + K_toml, "given")
    data = _json_main(capsys, ["design", given, "--json"])
    assert data["gains"]["method"] == "given" and data["design"]["method"] == "given"
    np.testing.assert_allclose(np.array(data["design"]["K"]), np.array(K), atol=1e-12)
    assert data["design"]["rho_delay_free"] == pytest.approx(
        _closed_loop_rho(P, A, C, K), abs=1e-9)
    # --tau1 means nothing for fixed matrices unless they are refined: bad input
    assert main(["design", given, "--tau1", "2"]) == 2
    assert "given" in capsys.readouterr().err


@pytest.mark.parametrize("gains, key", [
    ('method = "lmii"', "gains.method"),
    ('method = 3', "gains.method"),
    ('method = "ccl"\nrefine_from = "lmi"', "gains.refine_from"),
    ('method = "refined"\nrefine_from = "bfgs"', "gains.refine_from"),
    ('method = "auto"\ntau1 = -1', "gains.tau1"),
    ('method = "lmi"\ntau1 = 1.5', "gains.tau1"),
    ('method = "given"\ntau1 = 1\nK = []', "gains.tau1"),
    ('method = "ccl"\nK = []', "gains.K"),
    ('method = "refined"\nrefine_from = "given"', "gains.K"),
    ('method = "lmi"\nrate = 0.5', "gains.rate"),
])
def test_bad_gains_tables_are_exit_2_naming_the_key(capsys, tmp_path, gains, key):
    path = _with_gains(tmp_path, gains)
    for command in ("run", "design"):
        assert main([command, path, "--no-progress"] if command == "run"
                    else [command, path]) == 2
        err = capsys.readouterr().err
        assert key in err and len(err.strip().splitlines()) == 1, err
