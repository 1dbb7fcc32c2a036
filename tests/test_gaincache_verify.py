"""Gain-cache entries are verified on load (issue 29), and the cache key follows every
input that changes the gains.

Every entry here is written by the real store from a real design; the tampered ones are
then ignored with one warning, rewritten, and the gains are those of a fresh design. A
"re-signed" entry has its digest recomputed after the tampering: it stands for a writer
that wrote wrong gains consistently, so only the recomputed certificate can catch it.
"""

from __future__ import annotations

import copy
import json
import re
import warnings
from dataclasses import replace

import numpy as np
import pytest
from netsim.estimators.gains import design_for_scenario, design_request
from netsim.models.scenario import (
    builtin_scenarios,
    parse_scenario,
    read_scenario_data,
    resolve_scenario,
)

from netsim import gaincache
from netsim.cli import main
from netsim.runner import scenario_gains

NAME = "lcsys2022-homogeneous"


@pytest.fixture(scope="module")
def scenario():
    return resolve_scenario(NAME)


@pytest.fixture(scope="module")
def fresh(scenario):
    """The LMI design, solved without the cache (what --no-cache gives)."""
    return design_for_scenario(scenario)


@pytest.fixture(scope="module")
def entries(scenario, fresh, tmp_path_factory):
    """The bytes of real cache entries: the scenario's own (LMI) and, under another
    key, its local design."""
    folder = tmp_path_factory.mktemp("entries")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NETSIM_CACHE_DIR", str(folder))
        gaincache.cached_design(scenario, design_request(scenario), lambda: fresh)
        local = design_request(scenario, method="local")
        gaincache.cached_design(scenario, local,
                                lambda: design_for_scenario(scenario, method="local"))
    own = folder / f"{gaincache.fingerprint(scenario, design_request(scenario))}.npz"
    other = folder / f"{gaincache.fingerprint(scenario, local)}.npz"
    return own.read_bytes(), other.read_bytes()


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NETSIM_CACHE_DIR", str(tmp_path / "gains"))
    (tmp_path / "gains").mkdir()
    return tmp_path / "gains"


def _same(a, b):
    assert len(a.K) == len(b.K) and len(a.L) == len(b.L)
    for x, y in zip(a.K + a.L, b.K + b.L, strict=True):
        assert np.array_equal(x, y)
    for name in gaincache._SCALARS:
        assert getattr(a, name) == getattr(b, name), name


def _tamper(path, *, K=None, L=None, resign=False, **fields):
    """Change a stored entry in place: the arrays through K(...)/L(...), meta fields;
    with ``resign`` the digest is recomputed over the changed contents."""
    data = dict(np.load(path, allow_pickle=False))
    meta = json.loads(str(data["meta"][()]))
    if K is not None:
        data["K"] = K(data["K"])
    if L is not None:
        data["L"] = L(data["L"])
    meta.update(fields)
    if resign:
        scalars = {name: meta[name] for name in gaincache._SCALARS}
        meta["digest"] = gaincache.entry_digest(meta["fingerprint"], data["K"], data["L"],
                                                scalars)
    data["meta"] = np.array(json.dumps(meta))
    with open(path, "wb") as out:
        np.savez(out, **data)


def _nan(a):
    a = a.copy()
    a.flat[0] = np.nan
    return a


# damage -> (what is done to the stored entry, a word the warning's reason contains)
DAMAGES = {
    "L=0": ({"L": np.zeros_like}, "digest"),
    "L=1e6": ({"L": lambda a: np.full_like(a, 1e6)}, "digest"),
    "NaN": ({"L": _nan}, "non-finite"),
    "K and L = 0, re-signed": ({"K": np.zeros_like, "L": np.zeros_like, "resign": True},
                               "rho"),
    "K and L x 1e6, re-signed": ({"K": lambda a: a * 1e6, "L": lambda a: a * 1e6,
                                  "resign": True}, "rho"),
    "L x 1e6 alone, re-signed": ({"L": lambda a: a * 1e6, "resign": True}, "K_i C_i^T"),
    "rho 0.5, re-signed": ({"rho": 0.5, "rho_design": 0.5, "resign": True}, "rho"),
    # open-loop gains whose stored rho is right (rho(P) rho(A) = 1.04) but claimed certified
    "uncertified claim, re-signed": ({"K": np.zeros_like, "L": np.zeros_like, "rho": 1.04,
                                      "rho_design": 1.04, "resign": True}, "certified"),
    "certified flag flipped": ({"certified": False}, "digest"),
    "NaN rho, re-signed": ({"rho": float("nan"), "resign": True}, "rho"),
}


def _damage(path, name, entries):
    """Apply a damage: one of DAMAGES, or a whole-file one."""
    own, other = entries
    if name == "truncated":
        path.write_bytes(own[: len(own) // 2])
        return "cannot be read"
    if name == "swapped key":  # another key's entry under this key's name
        path.write_bytes(other)
        return "another key"
    if name == "swapped key, relabelled and re-signed":
        key = path.stem
        path.write_bytes(other)
        _tamper(path, fingerprint=key, resign=True)
        return "method"
    path.write_bytes(own)
    changes, word = DAMAGES[name]
    _tamper(path, **changes)
    return word


@pytest.mark.parametrize("damage", [*DAMAGES, "truncated", "swapped key",
                                    "swapped key, relabelled and re-signed"])
def test_a_tampered_entry_is_ignored_reported_once_and_rewritten(
        damage, scenario, fresh, entries, cache, monkeypatch):
    key = gaincache.fingerprint(scenario, design_request(scenario))
    path = cache / f"{key}.npz"
    word = _damage(path, damage, entries)
    bad = path.read_bytes()
    calls = []
    monkeypatch.setattr("netsim.runner.design_for_scenario",
                        lambda s: calls.append(s) or fresh)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = scenario_gains(scenario)
    ours = [w for w in caught if issubclass(w.category, gaincache.GainCacheWarning)]
    assert len(ours) == 1, [str(w.message) for w in caught]
    text = str(ours[0].message)
    assert "\n" not in text and path.name in text and word in text, text
    assert len(calls) == 1                         # designed afresh ...
    _same(got, fresh)                              # ... and the stored gains not used
    assert path.read_bytes() != bad                # rewritten, with a good entry:
    _same(gaincache.read_entry(path, key, scenario, design_request(scenario)), fresh)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = scenario_gains(scenario)
    assert len(calls) == 1 and not [w for w in caught
                                    if issubclass(w.category, gaincache.GainCacheWarning)]
    _same(again, fresh)


def test_a_good_entry_is_read_without_a_warning_or_a_solve(scenario, fresh, entries,
                                                          cache, monkeypatch):
    key = gaincache.fingerprint(scenario, design_request(scenario))
    (cache / f"{key}.npz").write_bytes(entries[0])
    monkeypatch.setattr("netsim.runner.design_for_scenario",
                        lambda s: pytest.fail("solved although the entry is good"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", gaincache.GainCacheWarning)
        _same(scenario_gains(scenario), fresh)


def test_run_with_a_nan_entry_warns_once_and_runs_with_the_fresh_gains(
        scenario, fresh, entries, cache, capsys, monkeypatch):
    """The reported failure: a NaN entry blocked every run until --no-cache."""
    key = gaincache.fingerprint(scenario, design_request(scenario))
    path = cache / f"{key}.npz"
    _damage(path, "NaN", entries)
    calls = []  # the solves: the module's fresh design, counted
    monkeypatch.setattr("netsim.runner.design_for_scenario",
                        lambda s: calls.append(s) or fresh)
    argv = ["run", NAME, "--steps", "10", "--trials", "1", "--no-progress", "--json"]
    assert main(argv) == 0
    assert len(calls) == 1                         # the entry not trusted: solved
    out, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if "gain cache" in line]
    assert len(lines) == 1 and lines[0].startswith("netsim run: warning: gain cache: ")
    assert "non-finite" in lines[0]
    cached = json.loads(out)["gains"]
    assert main([*argv, "--no-cache"]) == 0
    out, err = capsys.readouterr()
    assert "gain cache" not in err and len(calls) == 2
    assert cached == json.loads(out)["gains"]      # the fresh design's gains
    assert main(argv) == 0                         # rewritten: no second warning
    assert "gain cache" not in capsys.readouterr().err and len(calls) == 2


def test_design_with_wrong_gains_does_not_claim_their_certificate(
        scenario, fresh, entries, cache, capsys, monkeypatch):
    """The reported failure: L = 1e6 was used as is and reported 'certified, rho 0.8276'."""
    key = gaincache.fingerprint(scenario, design_request(scenario))
    path = cache / f"{key}.npz"
    _damage(path, "K and L x 1e6, re-signed", entries)
    calls = []  # the solves (no option given): the module's fresh design, counted
    monkeypatch.setattr("netsim.estimators.gains.design_for_scenario",
                        lambda s, **options: calls.append(options) or fresh)
    assert main(["design", NAME, "--json"]) == 0
    assert len(calls) == 1 and not any(calls[0].values())  # not trusted: solved
    out, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if "gain cache" in line]
    assert len(lines) == 1 and lines[0].startswith("netsim design: warning: gain cache: ")
    cached = json.loads(out)["design"]
    assert main(["design", NAME, "--json", "--no-cache"]) == 0
    fresh = json.loads(capsys.readouterr().out)["design"]
    assert cached == fresh and len(calls) == 2
    # independent of the stored numbers: the reported rho is that of the reported gains
    P, A, C = scenario.weights, scenario.plant.A, scenario.plant.C
    blocks = [np.eye(A.shape[0]) - np.asarray(L) @ Ci for L, Ci in zip(cached["L"], C,
                                                                          strict=True)]
    closed = np.zeros((len(C) * A.shape[0],) * 2)
    n = A.shape[0]
    for i, G in enumerate(blocks):
        closed[i * n:(i + 1) * n] = G @ np.kron(P[i], A)
    rho = max(abs(np.linalg.eigvals(closed)))
    assert cached["certified"] and rho < 1
    assert cached["rho_delay_free"] == pytest.approx(rho, rel=1e-9)


def test_above_the_threshold_no_eigenproblem_and_the_digest_still_holds(
        scenario, fresh, entries, cache, monkeypatch):
    monkeypatch.setattr(gaincache, "VERIFY_RHO_MAX_STATES", 0)

    def no_eigenproblem(*args, **kwargs):
        raise AssertionError("a spectral radius was computed above VERIFY_RHO_MAX_STATES")

    monkeypatch.setattr(gaincache, "_closed_loop_rho", no_eigenproblem)
    key = gaincache.fingerprint(scenario, design_request(scenario))
    path = cache / f"{key}.npz"
    request = design_request(scenario)
    path.write_bytes(entries[0])
    _same(gaincache.read_entry(path, key, scenario, request), fresh)
    for damage, word in (("L=0", "digest"), ("NaN", "non-finite"),
                         ("L x 1e6 alone, re-signed", "K_i C_i^T"),
                         ("truncated", "cannot be read"), ("swapped key", "another key")):
        _damage(path, damage, entries)
        with pytest.raises(gaincache.EntryError, match=re.escape(word)):
            gaincache.read_entry(path, key, scenario, request)


def _ring(method, agents=60):
    """A dense ring of ``agents`` agents (N n = 360 > DENSE_SIZE_THRESHOLD): the
    LCSYS2022 plant, sensor i mod 4."""
    data = copy.deepcopy(read_scenario_data(builtin_scenarios()[NAME]))
    data["plant"]["sensors"] = agents
    data["network"] = {"topology": "cycle", "agents": agents, "weights": "uniform"}
    gains = {"method": method}
    if method == "given":
        C = [np.asarray(data["plant"]["C"][i % 4], dtype=float) for i in range(agents)]
        gains["K"] = [(0.5 * Ci.T @ Ci).tolist() for Ci in C]
    data["gains"] = gains
    return parse_scenario(data)


@pytest.mark.parametrize("method, kinds", [
    # the given gains' rho is a dense eigenproblem: screened by ARPACK, dense only on doubt
    ("given", (["structured"], ["structured", "closed-loop"])),
    # the local design's own rho is the structured one
    ("local", (["structured"], ["structured"])),
])
def test_larger_entries_are_recomputed_by_the_cheap_path(method, kinds, cache, monkeypatch):
    scenario = _ring(method)
    assert len(scenario.plant.C) * scenario.plant.n_states == 360
    request = design_request(scenario)
    design = gaincache.cached_design(scenario, request, lambda: design_for_scenario(scenario))
    key = gaincache.fingerprint(scenario, request)
    path = cache / f"{key}.npz"
    seen = []
    real = gaincache._closed_loop_rho
    monkeypatch.setattr(gaincache, "_closed_loop_rho",
                        lambda kind, *a: seen.append(kind) or real(kind, *a))
    _same(gaincache.read_entry(path, key, scenario, request), design)
    assert seen == kinds[0]
    seen.clear()
    _tamper(path, rho=design.rho * (1 + 1e-4), rho_design=design.rho * (1 + 1e-4),
            resign=True)
    with pytest.raises(gaincache.EntryError, match="rho"):
        gaincache.read_entry(path, key, scenario, request)
    assert seen == kinds[1]


# ---------------------------------------------------------------------------
# the key
# ---------------------------------------------------------------------------


def _nudged(a, index):
    """A copy of ``a`` with one entry moved to the next float."""
    b = np.array(a, dtype=float, copy=True)
    b[index] = np.nextafter(b[index], np.inf)
    return b


def _with_C(scenario, i, Ci):
    C = list(scenario.plant.C)
    C[i] = Ci
    return replace(scenario, plant=replace(scenario.plant, C=tuple(C)))


def test_the_key_changes_with_every_input_of_the_design(scenario, monkeypatch):
    request = design_request(scenario)
    key = gaincache.fingerprint(scenario, request)
    # the same values in new arrays and a reordered request: the same key
    copied = replace(scenario, weights=np.array(scenario.weights),
                     plant=replace(scenario.plant, A=np.array(scenario.plant.A),
                                   C=tuple(np.array(Ci) for Ci in scenario.plant.C)))
    assert gaincache.fingerprint(copied, dict(reversed(list(request.items())))) == key

    keys = {"base": key}
    keys["P"] = gaincache.fingerprint(
        replace(scenario, weights=_nudged(scenario.weights, (0, 0))), request)
    keys["A"] = gaincache.fingerprint(
        replace(scenario, plant=replace(scenario.plant, A=_nudged(scenario.plant.A, (5, 5)))),
        request)
    for i, Ci in enumerate(scenario.plant.C):
        keys[f"C_{i}"] = gaincache.fingerprint(_with_C(scenario, i, _nudged(Ci, (0, 0))),
                                               request)
    for method in ("ccl", "auto", "local"):
        keys[f"method={method}"] = gaincache.fingerprint(
            scenario, design_request(scenario, method=method))
    keys["refined"] = gaincache.fingerprint(scenario, design_request(scenario, refine=True))
    keys["refined from ccl"] = gaincache.fingerprint(
        scenario, design_request(scenario, method="ccl", refine=True))
    for tau1 in (1, 2):
        keys[f"tau1={tau1}"] = gaincache.fingerprint(scenario,
                                                     design_request(scenario, tau1=tau1))
    # given gains: the K_i are an input of the design
    n = scenario.plant.n_states
    K = tuple(0.5 * Ci.T @ Ci for Ci in scenario.plant.C)
    given = replace(scenario, gains=replace(scenario.gains, method="given", K=K))
    keys["given"] = gaincache.fingerprint(given, design_request(given))
    other_K = (_nudged(K[0], (0, 0)), *K[1:])
    other = replace(given, gains=replace(given.gains, K=other_K))
    keys["given, K_0 moved"] = gaincache.fingerprint(other, design_request(other))
    assert all(k.shape == (n, n) for k in other_K)
    # the solver stack: each library's version
    from importlib import metadata

    real = metadata.version
    for name in ("netsim", "numpy", "scipy", "cvxpy", "clarabel"):
        monkeypatch.setattr(metadata, "version",
                            lambda dist, name=name: "0.0.0-other" if dist == name
                            else real(dist))
        keys[f"{name} version"] = gaincache.fingerprint(scenario, request)
        monkeypatch.setattr(metadata, "version", real)
    assert gaincache.fingerprint(scenario, request) == key
    clashes = {k: [name for name, v in keys.items() if v == k] for k in set(keys.values())}
    assert len(set(keys.values())) == len(keys), [v for v in clashes.values() if len(v) > 1]


def _sensor_variant():
    """The scenario with sensor 1 measuring x3 instead of x2 (still observable)."""
    data = copy.deepcopy(read_scenario_data(builtin_scenarios()[NAME]))
    assert data["plant"]["C"][1] == [[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]]
    data["plant"]["C"][1] = [[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]]
    return parse_scenario(data)


def test_a_scenario_differing_in_one_sensor_gets_its_own_gains(scenario, fresh, entries,
                                                              cache, monkeypatch):
    variant = _sensor_variant()
    assert np.array_equal(variant.weights, scenario.weights)
    assert np.array_equal(variant.plant.A, scenario.plant.A)
    assert [np.array_equal(a, b) for a, b in zip(variant.plant.C, scenario.plant.C,
                                                 strict=True)] == [True, False, True, True]
    own = design_for_scenario(variant)             # solved, not cached
    assert not np.array_equal(own.L[1], fresh.L[1])
    key = gaincache.fingerprint(scenario, design_request(scenario))
    (cache / f"{key}.npz").write_bytes(entries[0])  # the first scenario's (real) entry
    _same(scenario_gains(scenario), fresh)
    calls = []  # the variant's solve: its design above, counted
    monkeypatch.setattr("netsim.runner.design_for_scenario",
                        lambda s: calls.append(s) or own)
    with warnings.catch_warnings():
        warnings.simplefilter("error", gaincache.GainCacheWarning)
        got = scenario_gains(variant)              # not a hit on the other's entry
    assert calls == [variant]
    _same(got, own)
    assert len(list(cache.glob("*.npz"))) == 2


def test_agents_with_different_numbers_of_outputs(cache):
    """Agent 0 measures two states, the others one: the stored L_i side by side have
    different widths, and a change to agent 2's columns alone is found at agent 2."""
    data = copy.deepcopy(read_scenario_data(builtin_scenarios()[NAME]))
    data["plant"]["C"][0] = [[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]]
    data["gains"] = {"method": "local"}
    scenario = parse_scenario(data)
    assert [Ci.shape[0] for Ci in scenario.plant.C] == [2, 1, 1, 1]
    request = design_request(scenario)
    design = gaincache.cached_design(scenario, request, lambda: design_for_scenario(scenario))
    key = gaincache.fingerprint(scenario, request)
    path = cache / f"{key}.npz"
    _same(gaincache.read_entry(path, key, scenario, request), design)

    def agent2(L):  # columns 0-1 are agent 0's, 2 agent 1's, 3 agent 2's
        L = L.copy()
        L[:, 3] *= 2.0
        return L

    _tamper(path, L=agent2, resign=True)
    with pytest.raises(gaincache.EntryError, match=r"1 agent\(s\) \(agent 2"):
        gaincache.read_entry(path, key, scenario, request)


def test_a_delay_bound_designs_rho_design_is_recomputed_too(scenario, cache):
    """tau1 > 0: rho_design is the radius with A^(tau1+1); its stored value is checked."""
    request = design_request(scenario, method="local", tau1=2)
    design = gaincache.cached_design(
        scenario, request, lambda: design_for_scenario(scenario, method="local", tau1=2))
    assert design.design_tau == 2 and design.rho_design != design.rho
    key = gaincache.fingerprint(scenario, request)
    path = cache / f"{key}.npz"
    _same(gaincache.read_entry(path, key, scenario, request), design)
    _tamper(path, rho_design=design.rho, resign=True)     # the delay-free value instead
    with pytest.raises(gaincache.EntryError, match="stored rho_design"):
        gaincache.read_entry(path, key, scenario, request)
    # the same entry looked up for another tau1 is not what that request asks for
    _tamper(path, rho_design=design.rho_design, resign=True)
    with pytest.raises(gaincache.EntryError, match="design_tau"):
        gaincache.read_entry(path, key, scenario, {**request, "tau1": 1})
