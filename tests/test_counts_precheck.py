"""A scenario too large for the machine is refused from its counts, before its network
is built (issue 29: a 1,000,000-agent scenario was refused only after 12 minutes and
2.4 GB, by a guard that built the network first)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from netsim.models import network
from netsim.models import scenario as scn
from scipy.spatial import cKDTree

from netsim.cli import main

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def _geometric_reference(n_agents: int, radius: float, seed: int) -> tuple[np.ndarray, ...]:
    """geometric_links as first written: query every radius of the 10% growth."""
    rng = network.stream(seed, "network/geometric")
    positions = rng.random((n_agents, 2))
    tree = cKDTree(positions)
    r = radius
    while True:
        pairs = tree.query_pairs(r, output_type="ndarray")
        src = np.concatenate([pairs[:, 0], pairs[:, 1]])
        dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
        if len(src) and network.strongly_connected(n_agents, src, dst)[0]:
            return network._sorted_links(src, dst)
        r *= 1.1


@pytest.mark.parametrize("n_agents, degree, seed", [(50, 1.0, 0), (300, 2.0, 1),
                                                   (3000, 4.0, 2), (3000, 10.0, 3)])
def test_skipping_the_radii_with_an_isolated_agent_builds_the_same_graph(n_agents, degree,
                                                                         seed):
    radius = math.sqrt(degree / (math.pi * n_agents))
    src, dst, _ = network.geometric_links(n_agents, radius, seed)
    ref_src, ref_dst = _geometric_reference(n_agents, radius, seed)
    assert np.array_equal(src, ref_src) and np.array_equal(dst, ref_dst)


@pytest.mark.parametrize("n_agents, degree", [(5000, 10.0), (20000, 10.0), (20000, 3.0)])
def test_the_geometric_link_estimate_is_close_to_the_built_count(n_agents, degree):
    radius = math.sqrt(degree / (math.pi * n_agents))
    estimate, _ = network.geometric_link_estimate(n_agents, radius, 7)
    built = len(network.geometric_links(n_agents, radius, 7)[0])
    # the expected count at the built radius: off by its sampling spread (about
    # 1/sqrt(L)), or by one 10% growth (21% more links) in the rare case where the
    # graph without isolated agents is still not connected
    assert abs(estimate - built) <= 0.03 * built or estimate < built <= 1.25 * estimate, (
        estimate, built)


def _million(tmp_path):
    text = (ROOT / "examples" / "geometric-100k.toml").read_text()
    text = (text.replace("sensors = 100000", "sensors = 1000000")
            .replace("agents = 100000", "agents = 1000000")
            .replace("radius = 0.005641895835477563", "radius = 0.0017841241161527712"))
    path = tmp_path / "million.toml"
    path.write_text(text)
    return path


def test_a_million_agents_are_refused_before_the_network_is_built(tmp_path, monkeypatch,
                                                                   capsys):
    monkeypatch.setenv("NETSIM_MEMORY_LIMIT", "8G")

    def never(*args, **kwargs):
        raise AssertionError("the network was built before the budget refused it")

    monkeypatch.setattr(scn, "geometric_links", never)
    monkeypatch.setattr(scn, "sparse_random_weights", never)
    assert main(["run", str(_million(tmp_path)), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    line = err[0]
    assert line.startswith("netsim run: error: run.steps = 100: one trial")
    assert "N = 1,000,000 agents" in line and "before building the network" in line
    assert "NETSIM_MEMORY_LIMIT" in line and "lower run.steps" in line


def test_the_precheck_never_refuses_what_the_built_check_accepts(tmp_path, monkeypatch):
    """A lower bound: with a memory limit just above the exact estimate of the built
    scenario, the counts alone do not refuse it."""
    from netsim import budget

    path = ROOT / "examples" / "geometric-100k.toml"
    scenario = scn.load_scenario(path)
    total, _ = budget.run_bytes(scenario, scenario.steps, scenario.trials, "vectorised")
    seen = []
    monkeypatch.setenv("NETSIM_MEMORY_LIMIT", str(int(total * 1.05)))
    scn.load_scenario(path, lambda counts: (
        seen.append(counts), budget.check_counts(counts, None, None, ["vectorised"])))
    (counts,) = seen
    assert counts.n_agents == 100_000 and counts.max_delay == 3
    assert abs(counts.links - len(scenario.links)) <= 0.03 * len(scenario.links)
