"""Sparse end to end (issue 19): graphs, weights, checks, link tables, per-link delays
and the large-N gain design, each against an independent dense construction at small N."""

from __future__ import annotations

import math
from dataclasses import replace

import networkx as nx
import numpy as np
import pytest
import scipy.sparse as sp
from netsim.estimators.gains import design_gains, design_local
from netsim.models import network as nw
from netsim.models import scenario as scn
from netsim.models.seeding import stream

from netsim.runner import fixed_delay_matrix, run_trial
from netsim.vectorised import (
    _consensus_terms,
    effective_delays_per_link,
    run_batch,
    run_vectorised,
)

A6 = [[0.90, 0.30, 0, 0, 0, 0], [-0.30, 0.90, 0, 0, 0, 0], [0, 0.20, 0.95, 0.20, 0, 0],
      [0, 0, -0.20, 0.95, 0, 0], [0, 0, 0, 0, 1.01, 0], [0, 0, 0, 0, 0, 1.04]]


def _brute_geometric(n_agents: int, radius: float | None, seed: int) -> list[tuple[int, int]]:
    """The historic O(N^2) construction: all pairs within r, grown by 10% until the
    graph is strongly connected (networkx)."""
    positions = stream(seed, "network/geometric").random((n_agents, 2))
    r = radius if radius is not None else math.sqrt(2.0 * math.log(n_agents) / n_agents)
    dist = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=-1)
    while True:
        g = nx.DiGraph()
        g.add_nodes_from(range(n_agents))
        g.add_edges_from((j, i) for i in range(n_agents) for j in range(n_agents)
                         if i != j and dist[i, j] <= r)
        if nx.is_strongly_connected(g):
            return sorted(g.edges)
        r *= 1.1


@pytest.mark.parametrize("seed,radius", [(0, None), (1, 0.05), (7, 0.02)])
def test_kdtree_geometric_equals_brute_force(seed, radius):
    src, dst, positions = nw.geometric_links(200, radius, seed)
    assert list(zip(src.tolist(), dst.tolist(), strict=True)) == _brute_geometric(
        200, radius, seed)
    np.testing.assert_array_equal(positions, stream(seed, "network/geometric").random((200, 2)))


@pytest.mark.parametrize("seed", [0, 3])
def test_sparse_weights_equal_dense(seed):
    graph = nw.random_strongly_connected(40, 0.15, seed)
    N, src, dst = nw.links_of_graph(graph)
    pairs = [
        (nw.random_weights(graph, seed), nw.sparse_random_weights(N, src, dst, seed)),
        (nw.uniform_weights(graph), nw.sparse_uniform_weights(N, src, dst)),
        (nw.lazy_metropolis_weights(graph), nw.sparse_lazy_metropolis_weights(N, src, dst)),
    ]
    for dense, sparse in pairs:
        assert sp.issparse(sparse)
        S = sparse.toarray()
        np.testing.assert_allclose(S, dense, rtol=0, atol=1e-15)
        assert np.array_equal(S != 0, dense != 0)
        np.testing.assert_allclose(S.sum(axis=1), 1.0, atol=1e-12)
        nw.check_sparse_consensus_matrix(sparse)


def test_strong_connectivity_agrees_with_networkx():
    rng = np.random.default_rng(5)
    seen = set()
    for _ in range(60):
        N = int(rng.integers(2, 25))
        mask = rng.random((N, N)) < rng.uniform(0.03, 0.3)
        np.fill_diagonal(mask, False)
        src, dst = np.nonzero(mask)
        g = nx.DiGraph()
        g.add_nodes_from(range(N))
        g.add_edges_from(zip(src.tolist(), dst.tolist(), strict=True))
        ok, count = nw.strongly_connected(N, src, dst)
        assert ok == nx.is_strongly_connected(g)
        W = sp.csr_array(np.eye(N) + mask.T)  # P[i, j] != 0 iff j -> i
        assert sorted(nw.graph_from_weights(W).edges) == sorted(g.edges)
        assert count == nx.number_strongly_connected_components(g)
        seen.add(ok)
        if not ok:  # the sparse consensus check refuses it, as the dense one does
            P = nw.sparse_uniform_weights(N, *nw.links_of_graph(g)[1:])
            with pytest.raises(nw.NetworkError, match="not strongly connected"):
                nw.check_sparse_consensus_matrix(P)
            with pytest.raises(nw.NetworkError, match="not strongly connected"):
                nw.check_consensus_matrix(P.toarray())
    assert seen == {True, False}


def test_sparse_check_messages_match_dense():
    P = nw.uniform_weights(nw.directed_cycle(5))
    for bad in (P * 1.1, np.where(np.eye(5, dtype=bool), 0.0, P) + np.eye(5) * 0,
                P - 0.3 * np.eye(5)):
        with pytest.raises(nw.NetworkError) as dense:
            nw.check_consensus_matrix(bad)
        with pytest.raises(nw.NetworkError) as sparse:
            nw.check_sparse_consensus_matrix(sp.csr_array(bad))
        assert str(sparse.value) == str(dense.value)


def test_sparse_random_links_statistics(monkeypatch):
    """Above the dense threshold the extra edges come from geometric skips: each
    ordered pair with probability p (Monte Carlo over the pairs), plus the cycle."""
    monkeypatch.setattr(nw, "DENSE_RANDOM_MAX_AGENTS", 10)
    N, p = 300, 0.02
    src, dst = nw.random_links(N, p, 4)
    assert nw.strongly_connected(N, src, dst)[0]
    assert np.all(src != dst)
    assert len(np.unique(src * N + dst)) == len(src)
    pairs = N * (N - 1)
    expected = pairs * p + N  # about N cycle edges on top
    assert abs(len(src) - expected) < 5 * math.sqrt(pairs * p)


def _toml(n_agents: int, topology: str, weights: str, delays: str) -> dict:
    extra = {"radius": 0.25} if topology == "geometric" else (
        {"edge_probability": 0.1} if topology == "random" else {})
    return {
        "name": "sparse-test",
        "run": {"steps": 30, "trials": 2, "seed": 3, "estimators": ["compensated"]},
        "plant": {"A": A6, "C": [[[1.0, 0, 0, 0, 0, 0]], [[0, 0, 1.0, 0, 0, 0]],
                                 [[0, 0, 0, 0, 1.0, 0]], [[0, 0, 0, 0, 0, 1.0]]],
                  "sensors": n_agents, "Q": 0.004, "R": 0.004},
        "network": {"topology": topology, "agents": n_agents, "weights": weights,
                    "seed": 2, **extra},
        "delays": {"model": delays, "tau": 3, "seed": 1},
        "gains": {"method": "local"},
    }


@pytest.mark.parametrize("topology,weights,delays", [
    ("geometric", "random", "homogeneous"),
    ("random", "lazy-metropolis", "heterogeneous"),
    ("cycle", "uniform", "homogeneous"),
])
def test_sparse_scenario_path_equals_dense(monkeypatch, topology, weights, delays):
    """The sparse parse (no N x N array, no networkx) gives the dense parse's weights,
    links and delays, and the same runs on the vectorised engine."""
    data = _toml(24, topology, weights, delays)
    dense = scn.parse_scenario(data)
    monkeypatch.setattr(scn, "SPARSE_MIN_AGENTS", 2)
    sparse = scn.parse_scenario(data)
    assert sp.issparse(sparse.weights) and not sp.issparse(dense.weights)
    np.testing.assert_allclose(sparse.dense_weights(), dense.weights, rtol=0, atol=1e-15)
    assert sparse.links == dense.links
    table = sparse.link_table
    np.testing.assert_allclose(table.weight, dense.weights[table.dst, table.src], atol=1e-15)
    np.testing.assert_array_equal(fixed_delay_matrix(sparse), fixed_delay_matrix(dense))
    gains = design_local(dense.weights, dense.plant.A, dense.plant.C, gamma=0.6)
    seeds = [11, 12]
    a = run_vectorised(dense, "compensated", gains, seeds, record_estimates=False)
    b = run_vectorised(sparse, "compensated", gains, seeds, record_estimates=False)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(y.squared_errors, x.squared_errors, rtol=1e-12, atol=0)


def test_per_link_effective_delays_equal_kernel_record():
    """The vectorised engine's per-link (K+1, E) record, and the (K+1, N, N) one built
    from it, equal the event kernel's record (heterogeneous and asynchronous delays)."""
    for model in ("heterogeneous", "asynchronous"):
        scenario = scn.parse_scenario(_toml(8, "random", "random", model))
        gains = design_local(scenario.weights, scenario.plant.A, scenario.plant.C, gamma=0.5)
        batch = run_batch(scenario, "compensated", gains, [5], 20, record_delays=True)
        kernel = run_trial(scenario, "compensated", gains, 5, 20, record_delays=True)
        np.testing.assert_array_equal(batch.results[0].effective_delays,
                                      kernel.effective_delays)
        term_i, term_j, _, term_link, _ = _consensus_terms(scenario, batch.schedule)
        per_link = effective_delays_per_link(batch.selection, batch.schedule, term_link,
                                             batch.updated, 0, 20)
        assert per_link.shape == (21, len(term_i))
        np.testing.assert_array_equal(per_link, kernel.effective_delays[:, term_i, term_j])


@pytest.mark.parametrize("gamma", [None, 0.5])
def test_local_design_structured_rho_equals_dense_eigvals(gamma):
    data = _toml(60, "geometric", "random", "homogeneous")
    scenario = scn.parse_scenario(data)
    P_sparse = sp.csr_array(scenario.weights)
    C = scenario.plant.C
    design = design_local(P_sparse, scenario.plant.A, C, gamma=gamma)
    assert design.status == "structured-arpack"
    assert "structured" in design.message and "Lemma 1 conditions hold" in design.message
    # independent: the dense closed loop (I - blockdiag(L_i C_i)) (P kron A), eigvals
    G = sp.block_diag([np.eye(6) - L @ Ci for L, Ci in zip(design.L, C, strict=True)]).toarray()
    M = G @ np.kron(scenario.weights, np.asarray(A6))
    rho_dense = float(np.max(np.abs(np.linalg.eigvals(M))))
    assert design.rho == pytest.approx(rho_dense, rel=1e-9, abs=1e-12)
    assert design.certified == (rho_dense < 1)
    # the same design from the dense P: dense eigenvalues up to the size cut-off
    from netsim.models.augmented import DENSE_SIZE_THRESHOLD

    dense = design_local(scenario.weights, scenario.plant.A, C, gamma=gamma)
    small = scenario.weights.shape[0] * 6 <= DENSE_SIZE_THRESHOLD
    assert dense.status == ("dense-eigvals" if small else "structured-arpack")
    assert dense.rho == pytest.approx(rho_dense, rel=1e-10, abs=1e-14)


def test_auto_picks_local_for_sparse_and_dense_refuses(monkeypatch):
    monkeypatch.setattr(scn, "SPARSE_MIN_AGENTS", 2)
    scenario = scn.parse_scenario(_toml(30, "geometric", "random", "homogeneous"))
    design = design_gains(scenario.weights, scenario.plant.A, scenario.plant.C, method="auto")
    assert design.method == "local-scaled-projection"
    assert design.message.startswith("auto:")
    monkeypatch.setattr(scn, "DENSE_WEIGHTS_MAX_AGENTS", 10)
    with pytest.raises(scn.ScenarioError) as exc:
        scenario.dense_weights()
    assert "\n" not in str(exc.value) and "GiB" in str(exc.value)
    # the dense-only designs say what to use instead, in one line
    with pytest.raises(Exception, match="method = 'local'"):
        design_gains(scenario.weights, scenario.plant.A, scenario.plant.C, method="lmi")


def test_links_cached_and_gain_cache_fingerprints_sparse(monkeypatch):
    from netsim.gaincache import fingerprint

    monkeypatch.setattr(scn, "SPARSE_MIN_AGENTS", 2)
    scenario = scn.parse_scenario(_toml(20, "geometric", "random", "homogeneous"))
    assert scenario.links is scenario.links  # built once
    request = {"method": "local", "tau1": 0, "refine_from": None}
    key = fingerprint(scenario, request)
    moved = replace(scenario, weights=sp.csr_array(scenario.weights * 0.5))
    assert fingerprint(moved, request) != key
    assert fingerprint(replace(scenario), request) == key


def test_densified_and_plant_sensors(monkeypatch):
    monkeypatch.setattr(scn, "SPARSE_MIN_AGENTS", 2)
    scenario = scn.parse_scenario(_toml(12, "geometric", "random", "homogeneous"))
    C = scenario.plant.C
    assert len(C) == 12 and all(C[i] is C[i % 4] for i in range(12))  # shared, cycling
    assert [int(np.argmax(Ci)) for Ci in C] == [0, 2, 4, 5] * 3
    dense = scenario.densified("netsim analyze")
    assert not sp.issparse(dense.weights)
    np.testing.assert_array_equal(dense.weights, scenario.weights.toarray())
    assert dense.links == scenario.links
    monkeypatch.setattr(scn, "DENSE_WEIGHTS_MAX_AGENTS", 8)
    with pytest.raises(scn.ScenarioError) as exc:
        scenario.densified("netsim analyze")
    assert "\n" not in str(exc.value) and "netsim analyze" in str(exc.value)
    monkeypatch.setattr(scn, "SUMMARY_MAX_LINKS", 3)
    summary = scenario.summary()
    assert "links" not in summary and summary["n_links"] == len(scenario.links)


def test_huge_sparse_requests_refused_in_one_line(monkeypatch):
    monkeypatch.setattr(scn, "SPARSE_MIN_AGENTS", 2)
    monkeypatch.setattr(scn, "MAX_SPARSE_LINKS", 100)
    for topology, key in (("geometric", "network.radius"),
                          ("random", "network.edge_probability")):
        with pytest.raises(scn.ScenarioError) as exc:
            scn.parse_scenario(_toml(60, topology, "random", "homogeneous"))
        assert exc.value.key == key and "\n" not in str(exc.value)
    monkeypatch.setattr(scn, "MAX_AGENTS", 50)
    with pytest.raises(scn.ScenarioError) as exc:
        scn.parse_scenario(_toml(60, "cycle", "random", "homogeneous"))
    assert exc.value.key == "plant.sensors"


def test_default_gain_method_by_size():
    data = _toml(300, "geometric", "random", "homogeneous")  # N n = 1800
    del data["gains"]
    assert scn.parse_scenario(data).gains.method == "local"
    small = _toml(40, "geometric", "random", "homogeneous")  # N n = 240
    del small["gains"]
    assert scn.parse_scenario(small).gains.method == "lmi"


def test_trace_of_a_sparse_network_equals_the_dense_ones(monkeypatch, tmp_path):
    """A network with sparse weights traces as its dense twin: the same messages on
    the same topics, P stored dense; no trace needs more channels than the bound the
    command line checks (netsim.budget.trace_channels)."""
    from mcap.reader import make_reader
    from netsim.traces.reader import read_trace

    from netsim.budget import trace_channels
    from netsim.runner import run_monte_carlo
    from netsim.vectrace import _neighbours

    data = _toml(24, "geometric", "random", "heterogeneous")
    data["run"]["trials"] = 1
    dense = scn.parse_scenario(data)
    monkeypatch.setattr(scn, "SPARSE_MIN_AGENTS", 2)
    sparse = scn.parse_scenario(data)
    assert sp.issparse(sparse.weights)
    assert _neighbours(sparse.weights) == _neighbours(dense.weights)
    gains = design_local(dense.weights, dense.plant.A, dense.plant.C, gamma=0.6)
    traces = {}
    for name, scenario in (("dense", dense), ("sparse", sparse)):
        path = tmp_path / f"{name}.mcap"
        run_monte_carlo(scenario, steps=12, gains=gains, trace=str(path),
                        engine="vectorised")
        [written] = sorted(tmp_path.glob(f"{name}*.mcap"))
        traces[name] = read_trace(written)
        with open(written, "rb") as f:
            channels = len(make_reader(f).get_summary().channels)
        assert channels <= trace_channels(scenario)
    a, b = traces["dense"], traces["sparse"]
    np.testing.assert_array_equal(b.matrices["P"], sparse.dense_weights())
    assert a.counts == b.counts
    for topic, records in a.records.items():  # (weights equal to round-off)
        other = b.records[topic]
        if topic.endswith("/estimate"):
            np.testing.assert_allclose([list(r.message.estimate) for r in other],
                                       [list(r.message.estimate) for r in records],
                                       rtol=1e-12, atol=1e-12)
        elif "/link_" in topic:  # every field but the payload (an estimate) exactly
            def fields(message):
                return {f.name: v for f, v in message.ListFields() if f.name != "payload"}
            assert ([fields(r.message) for r in other]
                    == [fields(r.message) for r in records])


def test_trace_with_more_topics_than_mcap_channels_is_refused_in_one_line(
        monkeypatch, tmp_path, capsys):
    import json

    from netsim import budget
    from netsim.cli import main

    data = _toml(24, "cycle", "uniform", "homogeneous")
    path = tmp_path / "s.toml"
    # (JSON scalars and arrays of numbers are TOML too)
    path.write_text("\n".join(
        f"{k} = {json.dumps(v)}" for k, v in data.items() if not isinstance(v, dict))
        + "\n" + "\n".join(f"[{table}]\n" + "\n".join(f"{k} = {json.dumps(v)}"
                                                     for k, v in body.items())
                            for table, body in data.items() if isinstance(body, dict)))
    bound = budget.trace_channels(scn.load_scenario(path))
    assert bound == 1 + 24 + 3 * 24 + 3 * 24  # sensors, agents, cycle links
    monkeypatch.setattr(budget, "MCAP_MAX_CHANNELS", bound - 1)
    trace = tmp_path / "t.mcap"
    assert main(["run", str(path), "--trace", str(trace), "--trace-format", "2",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--trace" in err[0] and f"{bound:,} topics" in err[0]
    assert "--trace-format 3" in err[0]
    assert not list(tmp_path.glob("t*.mcap"))
    # format 3 (the default) has its eight topics at any size
    assert budget.trace_channels(scn.load_scenario(path), 3) == 8
    budget.check_trace_size(scn.load_scenario(path), trace)


def test_trace_of_a_network_too_large_for_a_dense_P_is_refused_up_front(monkeypatch):
    from netsim import budget

    monkeypatch.setattr(scn, "SPARSE_MIN_AGENTS", 2)
    scenario = scn.parse_scenario(_toml(24, "cycle", "uniform", "homogeneous"))
    budget.guard_run(scenario, 5, 1, ["vectorised"], trace="t.mcap")
    monkeypatch.setattr(scn, "DENSE_WEIGHTS_MAX_AGENTS", 23)
    with pytest.raises(budget.ResourceError) as exc:
        budget.guard_run(scenario, 5, 1, ["vectorised"], trace="t.mcap")
    assert "--trace t.mcap" in str(exc.value) and "\n" not in str(exc.value)
    assert "N = 24" in str(exc.value)
    from netsim.runner import run_monte_carlo  # the Python API: refused before the run

    with pytest.raises(budget.ResourceError):
        run_monte_carlo(scenario, steps=5, trace="t.mcap", progress=_never_called)


def _never_called(*_):
    raise AssertionError("the run started")
