"""The gain cache: a hit is the same design, bit for bit; a bad entry is never trusted."""

from __future__ import annotations

import json

import numpy as np
import pytest
from netsim.estimators.gains import design_for_scenario, design_request
from netsim.models.scenario import resolve_scenario

from netsim import gaincache
from netsim.cli import main
from netsim.runner import scenario_gains

NAME = "lcsys2022-homogeneous"


@pytest.fixture(scope="module")
def fresh():
    """The scenario's design, solved without the cache (one LMI solve per module)."""
    return design_for_scenario(resolve_scenario(NAME))


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """(entry bytes, gains) of a cache filled by one real ``scenario_gains`` call: solved
    and stored by the real path, once per module."""
    folder = tmp_path_factory.mktemp("stored")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NETSIM_CACHE_DIR", str(folder))
        gains = scenario_gains(resolve_scenario(NAME))
    (path,) = folder.glob("*.npz")
    return path.name, path.read_bytes(), gains


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NETSIM_CACHE_DIR", str(tmp_path / "gains"))
    return tmp_path / "gains"


def _seed(cache, stored):
    """Put the module's real entry into this test's (empty) cache."""
    name, data, _ = stored
    cache.mkdir(parents=True, exist_ok=True)
    (cache / name).write_bytes(data)


def _same(a, b):
    assert len(a.K) == len(b.K)
    for x, y in zip(a.K + a.L, b.K + b.L, strict=True):
        assert np.array_equal(x, y)
    for name in gaincache._SCALARS:
        assert getattr(a, name) == getattr(b, name), name


def test_a_hit_is_the_fresh_design_bit_for_bit(cache, fresh, stored, monkeypatch):
    scenario = resolve_scenario(NAME)
    # fresh: solved, not cached; stored: solved and stored by scenario_gains in an empty
    # cache, which then held exactly one entry (the fixture unpacks exactly one)
    name, _, first = stored
    _seed(cache, stored)
    assert gaincache.fingerprint(scenario, design_request(scenario)) + ".npz" == name
    calls = []
    monkeypatch.setattr("netsim.runner.design_for_scenario",
                        lambda s: calls.append(s) or fresh)
    second = scenario_gains(scenario)              # read back: no solve
    assert calls == []
    _same(first, fresh)
    _same(second, fresh)


def test_the_fingerprint_follows_what_the_design_depends_on():
    base = resolve_scenario("lcsys2022-heterogeneous")
    key = gaincache.fingerprint(base, design_request(base))
    # the delays do not enter the design; the weights and the method do
    assert gaincache.fingerprint(base.with_tau(7), design_request(base)) == key
    other = resolve_scenario("lcsys2022-homogeneous")
    assert gaincache.fingerprint(other, design_request(other)) == key  # same P, A, C
    assert gaincache.fingerprint(base, design_request(base, method="ccl")) != key
    from dataclasses import replace

    moved = replace(base, weights=base.weights * 1.0 + 0.0)
    moved.weights[0, 0] += 1e-15
    assert gaincache.fingerprint(moved, design_request(moved)) != key


@pytest.mark.parametrize("damage", ["garbage", "foreign", "shapes", "empty"])
def test_a_bad_entry_is_ignored_and_rewritten(cache, fresh, stored, monkeypatch, damage):
    scenario = resolve_scenario(NAME)
    _seed(cache, stored)
    good = stored[2]                                # the real entry's gains
    (path,) = cache.glob("*.npz")
    if damage == "garbage":
        path.write_bytes(b"\x00not an npz at all")
    elif damage == "empty":
        path.write_bytes(b"")
    else:
        data = dict(np.load(path, allow_pickle=False))
        meta = json.loads(str(data["meta"][()]))
        if damage == "foreign":
            meta["fingerprint"] = "0" * 64  # an entry made for something else
            meta["rho"] = 0.0
        else:
            data["K"] = np.zeros((2, 2))    # the layout's K, of the wrong shape
        data["meta"] = np.array(json.dumps(meta))
        with open(path, "wb") as out:
            np.savez(out, **data)
    calls = []  # the solve is the module's (the design is deterministic: the test above)
    monkeypatch.setattr("netsim.runner.design_for_scenario",
                        lambda s: calls.append(s) or fresh)
    with pytest.warns(gaincache.GainCacheWarning, match=path.name):
        again = scenario_gains(scenario)
    assert calls == [scenario]                      # solved afresh, not trusted
    _same(again, good)
    assert gaincache.load(path, gaincache.fingerprint(scenario, design_request(scenario)),
                          scenario) is not None     # and rewritten


def test_no_cache_option_solves_afresh(cache, fresh, stored, capsys, monkeypatch):
    _seed(cache, stored)                             # the entry a cold run stores
    calls = []
    monkeypatch.setattr("netsim.runner.design_for_scenario",
                        lambda s: calls.append(1) or fresh)
    assert main(["run", "lcsys2022-homogeneous", "--steps", "10", "--trials", "1",
                 "--no-progress", "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert calls == []                               # warm: read from the cache
    assert main(["run", "lcsys2022-homogeneous", "--steps", "10", "--trials", "1",
                 "--no-progress", "--json", "--no-cache"]) == 0
    assert calls == [1]                              # --no-cache: solved
    third = json.loads(capsys.readouterr().out.split("\n}\n")[-2] + "\n}")
    assert third["gains"]["L"] == first["gains"]["L"]


def test_cache_off(monkeypatch, tmp_path):
    monkeypatch.setenv("NETSIM_CACHE_DIR", "off")
    assert gaincache.cache_dir() is None
    with gaincache.disabled():
        assert gaincache.cache_dir() is None
