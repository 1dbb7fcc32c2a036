"""The printed-number claims on the calibrated instances, and LCSYS2022 Fig. 1 on
``lcsys2022-calibrated-rho-tau`` (issue 31; netsim/papers/_calibrated.py).

Independent: every number is recomputed here from the bundled scenario files, read with
tomllib (not netsim's scenario loader): A, C_i, P and K_i give L_i = K_i C_i^T, the
delay-free matrix A-hat = (I - blockdiag(L_i C_i))(P kron A) and Theorem 1's
M(tau) = (I - blockdiag(L_i C_i))(P kron A^(tau+1)) by numpy kron and dense eigenvalues;
the exact radii of the delayed loops (9) and (11) from tests/helpers.augmented_by_hand.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import augmented_by_hand, rho

from netsim.claims import REGISTRY
from netsim.claims.core import PROVED, UNDECIDED, Context

SCENARIOS = Path(__file__).resolve().parents[1] / "models" / "scenarios"
RHO_TAU, CLOSEST = "lcsys2022-calibrated-rho-tau", "lcsys2022-calibrated"
TOLERANT = "delay-tolerant-calibrated"
EQ26 = {3: 0.74, 8: 0.94, 19: 1.45}


def _matrices(name):
    data = tomllib.loads((SCENARIOS / f"{name}.toml").read_text())
    A = np.array(data["plant"]["A"], float)
    C = [np.array(c, float) for c in data["plant"]["C"]]
    P = np.array(data["network"]["P"], float)
    K = [np.array(k, float) for k in data["gains"]["K"]]
    L = [Ki @ Ci.T for Ki, Ci in zip(K, C, strict=True)]
    return P, A, C, L


def _gain(P, A, C, L):
    n = A.shape[0]
    G = np.eye(P.shape[0] * n)
    for i, (Li, Ci) in enumerate(zip(L, C, strict=True)):
        G[i * n:(i + 1) * n, i * n:(i + 1) * n] -= Li @ Ci
    return G


def _theorem1(P, A, C, L, tau):
    """rho(M(tau)), M(tau) = (I - blockdiag(L_i C_i))(P kron A^(tau+1))."""
    return rho(_gain(P, A, C, L) @ np.kron(P, np.linalg.matrix_power(A, tau + 1)))


def _homogeneous(P, tau):
    return np.where((P != 0) & ~np.eye(P.shape[0], dtype=bool), tau, 0)


def _by_hand(name):
    P, A, C, L = _matrices(name)
    values = [_theorem1(P, A, C, L, t) for t in range(31)]
    passing = [t for t, v in enumerate(values) if v < 1]
    star = -1
    while star + 1 < len(values) and values[star + 1] < 1:
        star += 1
    return {"rho": values[0], "star": star, "isolated": [t for t in passing if t > star],
            "no_root": {t: values[t] for t in EQ26},
            "with_root": {t: values[t] ** (1 / (t + 1)) for t in EQ26},
            "hom19": rho(augmented_by_hand(P, A, C, L, _homogeneous(P, 19)))}


@pytest.fixture(scope="module")
def hand():
    return {name: _by_hand(name) for name in (RHO_TAU, CLOSEST)}


@pytest.fixture(scope="module")
def ctx():
    return Context()


def test_lcsys_rho_and_tau_star_attained_on_the_rho_tau_instance(hand, ctx):
    h = hand[RHO_TAU]
    assert abs(h["rho"] - 0.64) <= 0.005 and h["star"] == 10 and not h["isolated"]
    out = REGISTRY["L-rho"].run(ctx)
    assert out.verdict == PROVED and "attainable" in out.summary and RHO_TAU in out.summary
    assert "not that the paper's own instance had it" in out.summary
    assert out.numbers["calibrated"][RHO_TAU] == pytest.approx(h["rho"], abs=1e-4)
    assert out.numbers["calibrated"][CLOSEST] == pytest.approx(hand[CLOSEST]["rho"], abs=1e-4)
    star = REGISTRY["L-tau-star"].run(ctx)
    assert star.verdict == PROVED
    assert star.numbers["calibrated"] == {RHO_TAU: h["star"], CLOSEST: hand[CLOSEST]["star"]}


def test_lcsys_eq26_values_and_which_are_reached(hand, ctx):
    out = REGISTRY["L-eq26"].run(ctx)
    reached = {t: [] for t in EQ26}
    for name in (RHO_TAU, CLOSEST):
        cal = out.numbers["calibrated"][name]
        for t, printed in EQ26.items():
            assert cal["as_printed"][str(t)] == pytest.approx(hand[name]["with_root"][t],
                                                              abs=1e-4)
            assert cal["no_root"][str(t)] == pytest.approx(hand[name]["no_root"][t], abs=1e-4)
            for reading, key in (("with the root", "with_root"),
                                 ("without the root", "no_root")):
                if abs(hand[name][key][t] - printed) <= 0.005:
                    reached[t].append(f"{name} {reading}")
    assert out.numbers["reached"] == {str(t): v for t, v in reached.items()}
    missed = [t for t in EQ26 if not reached[t]]
    assert out.verdict == (UNDECIDED if missed else PROVED)
    if missed:
        assert all(f"{EQ26[t]:g} at tau = {t}" in out.reason for t in missed)


def test_lcsys_hom19_not_reached(hand, ctx):
    out = REGISTRY["L-hom-19"].run(ctx)
    for name in (RHO_TAU, CLOSEST):
        assert out.numbers["calibrated"][name]["homogeneous"] == pytest.approx(
            hand[name]["hom19"], abs=1e-4)
    near = [n for n in (RHO_TAU, CLOSEST) if abs(hand[n]["hom19"] - 1.0) <= 0.005]
    assert out.verdict == (PROVED if near else UNDECIDED)
    if all(hand[n]["hom19"] > 1 for n in (RHO_TAU, CLOSEST)):
        assert "a little above 1" in out.reason


def test_a_missed_number_is_undecided_not_proved():
    ctx = Context()
    for name in (RHO_TAU, CLOSEST):  # the cache the check reads, with rho(A-hat) moved
        from netsim.papers._calibrated import calibrated_numbers

        m = dict(calibrated_numbers(ctx, name))
        m["rho_delay_free"] = 0.70
        ctx.cache[f"calibrated:{name}"] = m
    out = REGISTRY["L-rho"].run(ctx)
    assert out.verdict == UNDECIDED and "no calibrated instance reaches" in out.reason


def test_tolerant_rho_and_bounds(ctx):
    P, A, C, L = _matrices(TOLERANT)
    r = rho(_gain(P, A, C, L) @ np.kron(P, A))
    rho_out, bounds_out = REGISTRY["T-rho"].run(ctx), REGISTRY["T-bounds"].run(ctx)
    assert rho_out.numbers["calibrated"][TOLERANT] == pytest.approx(r, abs=1e-4)
    assert rho_out.verdict == (PROVED if abs(r - 0.64) <= 0.005 else UNDECIDED)
    cal = bounds_out.numbers["calibrated"][TOLERANT]
    ok = True
    for t, printed in ((10, 0.96), (25, 0.983)):
        assert cal[str(t)]["bound"] == pytest.approx(r ** (1 / (t + 1)), abs=1e-4)
        hom = rho(augmented_by_hand(P, A, C, L, _homogeneous(P, t), compensated=False))
        assert cal[str(t)]["exact_homogeneous"] == pytest.approx(hom, abs=1e-4)
        assert hom <= r ** (1 / (t + 1))
        ok = ok and abs(r ** (1 / (t + 1)) - printed) <= 0.5 * 10.0 ** -len(
            str(printed).split(".")[1])
    assert bounds_out.verdict == (PROVED if ok else UNDECIDED)


def test_half_unit():
    from netsim.papers._calibrated import half_unit

    assert half_unit(0.64) == pytest.approx(0.005)
    assert half_unit(0.983) == pytest.approx(0.0005)
    assert half_unit(1.0) == pytest.approx(0.005)


def test_fig1_calibrated_builds_quickly_with_the_hand_radii(tmp_path, hand):
    from netsim.papers._calibrated import fig1_contrast
    from netsim.reproduce import ITEMS
    from netsim.reproduce.items import BuildContext

    item = next(it for it in ITEMS if it.id == "lcsys2022-fig1-calibrated")
    res = item.build(BuildContext(out=tmp_path, trials=2, workers=1))
    res.figure.savefig(tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 1000
    data = json.loads((tmp_path / "lcsys2022-fig1-calibrated.json").read_text())
    cal = data["reports"][RHO_TAU]
    assert cal["steps"] == 100 and cal["trials"] == 2  # the quick rule
    P, A, C, L = _matrices(RHO_TAU)
    for c in cal["cells"]:
        if c["setting"] == "homogeneous" and c["tau"] in (3, 8, 19):
            hand_rho = rho(augmented_by_hand(P, A, C, L, _homogeneous(P, c["tau"])))
            assert c["analytics"]["exact"] == pytest.approx(hand_rho, abs=1e-6)
            assert (c["measured"]["verdict"] == "stable") == (hand_rho < 1)
    # the caption's contrast follows the cells' verdicts (a homogeneous 19 above 1)
    contrast = fig1_contrast(cal)
    assert res.numbers["contrast_calibrated"] == contrast["contrast"]
    assert contrast["contrast"] == (hand[RHO_TAU]["hom19"] > 1
                                    and contrast["verdicts"]["heterogeneous 19"] == "stable"
                                    and contrast["stable_038"])
    assert any("caption's contrast" in line for line in res.ours)
    rows = (tmp_path / "lcsys2022-fig1-calibrated.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * 2 * 4 * 101  # two instances, two settings, four taus
