"""The radius cache (netsim.radiuscache): what ``netsim analyze`` reuses, and when not.

Properties against a second computation: a cached radius is the recomputed one bit for
bit; a corrupt, tampered or foreign entry is reported in one warning and recomputed;
``--no-cache`` (``gaincache.disabled``) and ``NETSIM_RADIUS_CACHE=off`` bypass it; the
key changes with every input; the folder is bounded.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from helpers import lcsys
from netsim.models import augmented as aug

from netsim import gaincache, radiuscache
from netsim.analysis import analyze, radii_line
from netsim.runner import scenario_gains

#: tau = 0..5 with dense eigenvalues up to 100 rows: tau = 0..3 dense, 4 and 5 (D = 120,
#: 144) by ARPACK
TAU_MAX = 5


@pytest.fixture(scope="module")
def scenario():
    return lcsys()


@pytest.fixture(scope="module")
def gains(scenario):
    return scenario_gains(scenario)


@pytest.fixture()
def folder(tmp_path, monkeypatch):
    path = tmp_path / "radii"
    monkeypatch.setenv("NETSIM_RADIUS_CACHE", str(path))
    return path


def _numbers(report):
    rows = [(r.rho_compensated, r.rho_uncompensated, r.bound_eq26, r.verdict_eq26,
             r.verdict_tolerant) for r in report.rows]
    realised = report.realised
    own = None if realised is None else (realised["rho_compensated"],
                                         realised["rho_uncompensated"])
    return rows, own, report.violations, report.contradictions


def _radii(report):
    """Radii the report needs: two per homogeneous row, two for the scenario's own
    (heterogeneous, so not one of the rows') delays."""
    own = report.realised is not None and len(set(report.realised["delays"].values())) > 1
    return 2 * (len(report.rows) + own)


def _sources(report):
    return {s for r in report.rows for s in (r.source_compensated, r.source_uncompensated)}


def test_cached_radii_are_the_recomputed_ones_bit_for_bit(scenario, gains, folder,
                                                          monkeypatch):
    monkeypatch.setattr(aug, "AUGMENTED_DENSE_SIZE_THRESHOLD", 100)
    cold = analyze(scenario, gains, TAU_MAX)
    assert _sources(cold) == {"dense eigenvalues", "ARPACK"}
    assert cold.radii["cached"] == {} and cold.radii["cache"] == str(folder)
    assert sum(cold.radii["computed"].values()) == _radii(cold) == 2 * (TAU_MAX + 2)
    warm = analyze(scenario, gains, TAU_MAX)
    assert _sources(warm) == {"cache (dense eigenvalues)", "cache (ARPACK)"}
    assert warm.radii["computed"] == {}
    assert warm.radii["cached"] == cold.radii["computed"]
    fresh = analyze(scenario, gains, TAU_MAX, cache=False)
    assert fresh.radii["cache"] is None and fresh.radii["cached"] == {}
    # == on floats: the same bits (the cache stores float.hex)
    assert _numbers(cold) == _numbers(warm) == _numbers(fresh)
    for r in warm.rows[3:]:  # and the independent second implementation agrees
        delays = np.where((scenario.weights > 0) & ~np.eye(4, dtype=bool), r.tau, 0)
        dense = aug.augmented_spectral_radius(scenario.weights, scenario.plant.A,
                                              scenario.plant.C, gains.L, delays, r.tau,
                                              False, method="dense")
        assert r.rho_uncompensated == pytest.approx(dense, rel=1e-10)
    assert "read from the cache" in radii_line(warm.radii)
    assert "computed now" in radii_line(cold.radii)


def test_a_larger_tau_range_reuses_the_smaller_ones_radii(scenario, gains, folder):
    analyze(scenario, gains, 3)
    report = analyze(scenario, gains, 5)
    assert sum(report.radii["cached"].values()) == 2 * 4 + 2  # and the own delays'
    assert sum(report.radii["computed"].values()) == 2 * 2


@pytest.mark.parametrize("damage", ["garbage", "tampered", "foreign", "negative"])
def test_a_bad_entry_is_reported_and_recomputed(scenario, gains, folder, damage):
    want = _numbers(analyze(scenario, gains, 3, cache=False))
    analyze(scenario, gains, 3)
    files = sorted(folder.glob("*.json"))
    assert len(files) == 2 * 5
    victim = files[0]
    data = json.loads(victim.read_text())
    if damage == "garbage":
        victim.write_bytes(b"\x00\xffnot json")
    elif damage == "tampered":  # another radius, the old digest
        data["rho"] = (float.fromhex(data["rho"]) * 0.5).hex()
        victim.write_text(json.dumps(data))
    elif damage == "foreign":  # a valid entry of another key under this name
        victim.write_text(files[1].read_text())
    else:
        data["rho"] = (-1.0).hex()
        victim.write_text(json.dumps(data))
    with pytest.warns(radiuscache.RadiusCacheWarning, match=victim.name):
        report = analyze(scenario, gains, 3)
    assert _numbers(report) == want
    assert sum(report.radii["computed"].values()) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = analyze(scenario, gains, 3)  # rewritten: read back, no warning
    assert again.radii["computed"] == {} and _numbers(again) == want


def test_no_cache_and_off_bypass_the_cache(scenario, gains, folder, monkeypatch):
    analyze(scenario, gains, 2)
    with gaincache.disabled():  # what --no-cache does
        assert radiuscache.radius_dir() is None
        report = analyze(scenario, gains, 2)
    assert report.radii["cached"] == {} and report.radii["cache"] is None
    monkeypatch.setenv("NETSIM_RADIUS_CACHE", "off")
    assert radiuscache.radius_dir() is None
    assert analyze(scenario, gains, 2).radii["cached"] == {}
    monkeypatch.delenv("NETSIM_RADIUS_CACHE")
    monkeypatch.setenv("NETSIM_CACHE_DIR", "off")
    assert radiuscache.radius_dir() is None
    monkeypatch.setenv("NETSIM_CACHE_DIR", str(folder.parent / "gains"))
    assert radiuscache.radius_dir() == folder.parent / "gains" / "radii"


def test_the_key_changes_when_any_input_changes(scenario, gains, monkeypatch):
    P, A, C, L = scenario.weights, scenario.plant.A, scenario.plant.C, gains.L
    delays = np.where((P > 0) & ~np.eye(4, dtype=bool), 2, 0)
    base = (P, A, C, L, delays, 2, True)
    key = radiuscache.radius_key(*base)
    assert radiuscache.radius_key(*base) == key
    assert radiuscache.radius_key(P.copy(), A.copy(), list(C), list(L), delays.astype(float),
                                  2, True) == key  # the values, not the objects

    def ulp(x):
        x = np.array(x, dtype=float)
        x.flat[0] = np.nextafter(x.flat[0], np.inf)
        return x

    variants = [
        (ulp(P), A, C, L, delays, 2, True),
        (P, ulp(A), C, L, delays, 2, True),
        (P, A, [ulp(C[0]), *C[1:]], L, delays, 2, True),
        (P, A, C, [*L[:3], ulp(L[3])], delays, 2, True),
        (P, A, C, L, np.where(delays == 2, 1, 0), 2, True),
        (P, A, C, L, delays, 3, True),
        (P, A, C, L, delays, 2, False),
    ]
    keys = {radiuscache.radius_key(*v) for v in variants}
    assert len(keys) == len(variants) and key not in keys
    monkeypatch.setattr(radiuscache, "METHOD_VERSION", radiuscache.METHOD_VERSION + 1)
    assert radiuscache.radius_key(*base) != key
    monkeypatch.undo()
    monkeypatch.setattr(aug, "ARPACK_NCV", aug.ARPACK_NCV + 1)
    assert radiuscache.radius_key(*base) != key
    monkeypatch.undo()
    monkeypatch.setattr(radiuscache, "_VERSIONS", ["netsim=0;numpy=0;scipy=0;"])
    assert radiuscache.radius_key(*base) != key


def test_the_folder_is_bounded(tmp_path):
    import os

    entries = {f"{i:064x}": (0.5 + i / 1000, "ARPACK") for i in range(20)}
    radiuscache.store(tmp_path, entries)
    for age, path in enumerate(sorted(tmp_path.glob("*.json"))):
        os.utime(path, (1e9 + age, 1e9 + age))  # the name order is the age order
    radiuscache._prune(tmp_path, limit=10)
    left = sorted(p.stem for p in tmp_path.glob("*.json"))
    assert left == sorted(entries)[-7:]  # the newest three quarters of the limit
    assert radiuscache.load(tmp_path, left) == {k: entries[k] for k in left}
    assert not list(tmp_path.glob(".tmp-*"))  # no temporary file left behind


def test_an_unwritable_folder_is_no_error(scenario, gains, tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("NETSIM_RADIUS_CACHE", str(blocker / "radii"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report = analyze(scenario, gains, 1)
    assert sum(report.radii["computed"].values()) == _radii(report) == 6


def test_the_command_says_where_the_radii_came_from(folder, capsys):
    from netsim.cli import main

    # tau = 0..3; the scenario's own delays are tau = 3's
    argv = ["analyze", "lcsys2022-homogeneous", "--tau-max", "3", "--no-progress"]
    assert main(argv) == 0
    assert "exact radii: 8 computed now (dense eigenvalues 8)" in capsys.readouterr().out
    assert main([*argv, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["radii"] == {"computed": {}, "cached": {"dense eigenvalues": 8},
                             "cache": str(folder)}
    assert {r["source_compensated"] for r in data["homogeneous"]} == {
        "cache (dense eigenvalues)"}


def test_workers_with_some_radii_cached_give_the_serial_report(scenario, gains, folder):
    """Two worker processes computing only the radii the cache lacks (tau 4..9; 0..3 and
    the scenario's own delays cached) give the numbers of a serial run without cache."""
    analyze(scenario, gains, 3)
    ticks = []
    mixed = analyze(scenario, gains, 9, workers=2, progress=ticks.append)
    assert sum(mixed.radii["cached"].values()) == 2 * 4 + 2
    assert ticks == [1] * 11
    assert _numbers(mixed) == _numbers(analyze(scenario, gains, 9, cache=False))
