"""netsim calibrate (issue 31): the LCSYS2022 instance search."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from netsim.models import augmented as aug

from netsim import calibrate as cal

SMALL = {"evaluations": 60, "starts": 1, "seed": 7}


@pytest.fixture(scope="module")
def small() -> cal.CalibrationResult:
    return cal.search("no-root", **SMALL)


def _homogeneous(P: np.ndarray, tau: int) -> np.ndarray:
    off = (P != 0) & ~np.eye(P.shape[0], dtype=bool)
    return np.where(off, tau, 0)


def test_reported_numbers_are_the_analytics_recomputed(small: cal.CalibrationResult) -> None:
    inst = small.instance
    assert inst is not None
    P, A, C, L = inst.P, inst.A, list(inst.C), list(inst.L)
    n = small.numbers
    assert n["rho_delay_free"] == aug.delay_free_spectral_radius(P, A, C, L)
    assert math.isclose(n["rho_delay_free"],
                        aug.spectral_radius(aug.delay_free_closed_loop(P, A, C, L)),
                        rel_tol=1e-12)
    for t in (3, 8, 19):
        assert n[f"eq26_tau{t}"] == aug.delay_bound_lcsys(P, A, C, L, t)
        # Theorem 1's value is the bound's (tau+1)-th power
        assert math.isclose(n[f"theorem1_tau{t}"], n[f"eq26_tau{t}"] ** (t + 1), rel_tol=1e-9)
    star = aug.tau_star(P, A, C, L, tau_max=cal.TAU_MAX)
    assert n["tau_star"] == star
    hom = aug.augmented_spectral_radius(P, A, C, L, _homogeneous(P, 19), 19, method="dense")
    assert math.isclose(n["homogeneous_tau19"], hom, rel_tol=1e-8)
    d = np.array(n["heterogeneous_delays"])
    het = aug.augmented_spectral_radius(P, A, C, L, d, 19, method="dense")
    assert math.isclose(n["heterogeneous_tau19"], het, rel_tol=1e-8)
    # the target rows repeat those numbers
    rows = {r["name"]: r for r in small.targets}
    assert rows["rho(A-hat)"]["achieved"] == n["rho_delay_free"]
    assert rows["eq. (26) at tau = 8"]["achieved"] == n["theorem1_tau8"]  # no-root reading
    assert all(r["matched"] == (abs(r["gap"]) <= cal.TOLERANCE)
               for r in small.targets if isinstance(r["printed"], float))


def test_instance_has_the_stated_properties(small: cal.CalibrationResult) -> None:
    inst = small.instance
    assert inst is not None
    props = small.properties
    assert all(p["holds"] for p in props.values()), props
    assert math.isclose(max(abs(np.linalg.eigvals(inst.A))), 1.04, rel_tol=1e-12)
    for i, (Ki, Ci, Li) in enumerate(zip(inst.K, inst.C, inst.L, strict=True)):
        assert Ki.shape == (6, 6)
        np.testing.assert_array_equal(Ki @ Ci.T, Li)
        lo, hi = cal.BLOCKS[i]
        assert np.count_nonzero(Ci) >= 1 and not np.any(np.delete(Ci[0], range(lo, hi)))


def test_scenario_file_round_trips(small: cal.CalibrationResult, tmp_path) -> None:
    from netsim.api import load_scenario
    from netsim.runner import fixed_delay_matrix, scenario_gains

    inst = small.instance
    assert inst is not None
    path = tmp_path / "cal.toml"
    path.write_text(cal.scenario_toml(small), encoding="utf-8")
    sc = load_scenario(path)
    np.testing.assert_array_equal(sc.plant.A, inst.A)
    np.testing.assert_array_equal(sc.weights, inst.P)
    for a, b in zip(sc.plant.C, inst.C, strict=True):
        np.testing.assert_array_equal(a, b)
    gains = scenario_gains(sc)
    for a, b in zip(gains.L, inst.L, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(fixed_delay_matrix(sc.with_tau(19)),
                                  inst.heterogeneous_delays(19))


def test_search_is_deterministic_for_a_seed(small: cal.CalibrationResult) -> None:
    again = cal.search("no-root", **SMALL)
    assert again.parameters == small.parameters
    assert again.numbers == small.numbers
    assert again.evaluations == small.evaluations
    other = cal.search("no-root", evaluations=60, starts=1, seed=8)
    assert other.parameters != small.parameters


@pytest.mark.parametrize("reading", cal.READINGS)
def test_tiny_budget_never_matches(reading: str) -> None:
    res = cal.search(reading, evaluations=5, starts=1, seed=1)
    assert res.verdict == "undecided"
    assert 1 <= res.evaluations <= 5
    res = cal.search(reading, evaluations=40, starts=2, seed=1)
    assert res.verdict in ("undecided", "not matched")


def test_contradiction_closed_forms(small: cal.CalibrationResult) -> None:
    inst = small.instance
    assert inst is not None
    notes = cal.contradictions(inst)
    lemma4 = notes[0]["evidence"]
    # Lemma 4: companion with first block row [0 .. 0 M] has the (tau+1)-th roots of M's
    # eigenvalues as its eigenvalues, so its rho is rho(M)^(1/(tau+1)) = eq. (26)
    m = inst.P.shape[0] * inst.A.shape[0]
    M = (np.eye(m) - aug.gain_product(list(inst.L), list(inst.C))) @ np.kron(
        inst.P, np.linalg.matrix_power(inst.A, 20))
    closed = max(abs(np.linalg.eigvals(M))) ** (1 / 20)
    assert math.isclose(lemma4["exact_all_delayed"], closed, rel_tol=1e-8)
    assert lemma4["difference"] < 1e-8
    assert notes[0]["contradiction"] is True
    ev = notes[1]["evidence"]
    assert math.isclose(ev["rho_M8"], 0.94 ** 9) and math.isclose(ev["rho_M19"], 1.45 ** 20)
    assert math.isclose(ev["amplification_needed"], 1.45 ** 20 / 0.94 ** 9 / 1.04 ** 11)
    ev = notes[2]["evidence"]
    lo, hi = ev["tau_star_range"]
    assert lo <= 10 <= hi
    assert math.isclose(ev["root_of_1.45_at_19"], 1.45 ** 0.05)


def test_cli_writes_the_scenario_and_refuses_to_overwrite(tmp_path, capsys) -> None:
    from netsim.cli import main

    out = tmp_path / "c.toml"
    args = ["calibrate", "lcsys2022", "--evaluations", "30", "--starts", "1",
            "--reading", "no-root", "--no-progress", "--out", str(out)]
    assert main([*args, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["results"][0]["verdict"] in ("undecided", "not matched")
    assert data["written"] == str(out) and out.exists()
    assert main(args) != 0
    assert "--force" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0
    assert "reading no-root" in capsys.readouterr().out
