"""Time-varying topologies: sequences, link schedules, Assumption 1 / Remark 1 checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from netsim.models.delays import homogeneous_delays
from netsim.models.plant import LinearPlant
from netsim.models.topology import (
    GraphSequence,
    LinkSchedule,
    TopologyError,
    alternating_sequence,
    bfs_parents,
    connectivity_report,
    is_strongly_connected,
    random_jointly_connected,
    random_jointly_rooted,
    reaches_all,
    satisfies_joint_connectivity,
    satisfies_jointly_rooted,
    smallest_joint_period,
    smallest_rooted_period,
    static_sequence,
    window_unions,
)

from netsim.kernel import AgentSpec, Simulation

CYCLE3 = [(0, 1), (1, 2), (2, 0)]


# -- sequences ----------------------------------------------------------------------


def test_periodic_indexing_and_prefix():
    seq = GraphSequence(3, [[(0, 1)], [(1, 2)], [(2, 0)], [(0, 2)]], period=2)
    assert seq.prefix == 2
    assert [seq.index(k) for k in range(8)] == [0, 1, 2, 3, 2, 3, 2, 3]
    assert seq.edges(5) == frozenset({(0, 2)})
    assert seq.is_up(2, 0, 4) and not seq.is_up(2, 0, 1)
    assert seq.in_neighbours(2, 1) == (1,)
    assert seq.out_neighbours(0, 7) == (2,)
    assert seq.links() == frozenset({(0, 1), (1, 2), (2, 0), (0, 2)})
    assert seq.union(0, 2) == frozenset({(0, 1), (1, 2)})
    assert GraphSequence.from_dict(seq.to_dict()) == seq


@pytest.mark.parametrize("graphs, period, match", [
    ([], None, "at least one graph"),
    ([[(0, 0)]], None, "self-loop"),
    ([[(0, 3)]], None, "outside agents"),
    ([[(0, 1, 2)]], None, "pair"),
    ([[(0, 1)]], 2, "period"),
])
def test_bad_sequences_raise(graphs, period, match):
    with pytest.raises(TopologyError, match=match):
        GraphSequence(3, graphs, period)


def test_negative_step_is_an_error():
    with pytest.raises(ValueError):
        static_sequence(2, [(0, 1)]).edges(-1)


def test_predicates():
    assert is_strongly_connected(3, CYCLE3)
    assert not is_strongly_connected(3, CYCLE3[:2])
    assert is_strongly_connected(1, [])
    assert reaches_all(3, CYCLE3[:2], 0) and not reaches_all(3, CYCLE3[:2], 1)
    # BFS tree: lowest-numbered parent among equally close ones
    assert bfs_parents(4, [(0, 1), (0, 2), (1, 3), (2, 3)], 0) == {1: 0, 2: 0, 3: 1}
    assert bfs_parents(3, [(1, 2)], 0) == {}


# -- Assumption 1 and Remark 1 ----------------------------------------------------------


def test_paper_example_is_rooted_but_not_jointly_strongly_connected():
    # aoi paper Figure 1 (0-based): nothing ever enters node 0
    seq = alternating_sequence(3, [(0, 1), (1, 2)], [(0, 2), (2, 1)])
    assert smallest_joint_period(seq) is None
    assert smallest_rooted_period(seq, [0]) == 1  # each graph is a tree rooted at 0
    assert smallest_rooted_period(seq, [1]) is None
    report = connectivity_report(seq, [0])
    assert report.joint_T is None and report.rooted_all_T == 1
    assert report.graphs_strongly_connected == 0


def test_split_cycle_needs_the_whole_window():
    # one edge of a 3-cycle per step, in the order that is worst for propagation
    seq = GraphSequence(3, [[(2, 0)], [(1, 2)], [(0, 1)]])
    assert smallest_joint_period(seq) == 3
    assert not satisfies_joint_connectivity(seq, 2)
    assert satisfies_joint_connectivity(seq, 3)
    assert satisfies_joint_connectivity(seq, 6)


def test_smallest_T_is_not_monotone():
    full = [(0, 1), (1, 0)]
    seq = GraphSequence(2, [[], [], full, full, [], []])
    assert smallest_joint_period(seq) == 3
    assert not satisfies_joint_connectivity(seq, 4)  # window [4, 8) sees no edge
    assert satisfies_joint_connectivity(seq, 5)


def test_transient_prefix_counts():
    # the first window never connects; afterwards every graph is strongly connected
    seq = GraphSequence(2, [[], [], [(0, 1), (1, 0)]], period=1)
    assert smallest_joint_period(seq) == 3
    assert window_unions(seq, 3)[0] == (0, frozenset({(0, 1), (1, 0)}))
    assert satisfies_joint_connectivity(seq, 3) and not satisfies_joint_connectivity(seq, 2)


def _brute_force_ok(seq: GraphSequence, T: int, test) -> bool:
    horizon = seq.prefix + 3 * math.lcm(seq.period, T) + T
    return all(test(seq.union(m * T, (m + 1) * T)) for m in range(horizon // T + 1))


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 4), st.lists(st.sets(st.tuples(st.integers(0, 3), st.integers(0, 3)),
                                           max_size=4), min_size=1, max_size=6),
       st.integers(0, 5), st.data())
def test_checker_matches_brute_force(n, raw, prefix_cut, data):
    graphs = [[(j, i) for j, i in g if j < n and i < n and j != i] for g in raw]
    period = max(1, len(graphs) - min(prefix_cut, len(graphs) - 1))
    seq = GraphSequence(n, graphs, period)
    sc = lambda e: is_strongly_connected(n, e)  # noqa: E731
    expected = next((T for T in range(1, 3 * (seq.prefix + seq.period) + 1)
                     if _brute_force_ok(seq, T, sc)), None)
    assert smallest_joint_period(seq) == expected
    root = data.draw(st.integers(0, n - 1))
    rooted = lambda e: reaches_all(n, e, root)  # noqa: E731
    expected_r = next((T for T in range(1, 3 * (seq.prefix + seq.period) + 1)
                       if _brute_force_ok(seq, T, rooted)), None)
    assert smallest_rooted_period(seq, [root]) == expected_r


# -- random sequences ----------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 4), st.integers(1, 4), st.integers(0, 10**6),
       st.floats(0, 0.5), st.floats(0, 0.3))
def test_random_sequences_satisfy_assumption_1(n, T, windows, seed, extra, repeat):
    seq = random_jointly_connected(n, T, windows=windows, seed=seed,
                                   extra_edge_probability=extra, repeat_probability=repeat)
    assert seq.period == windows * T
    assert satisfies_joint_connectivity(seq, T)
    smallest = smallest_joint_period(seq)
    assert smallest is not None and smallest <= T


def test_random_sequence_single_graphs_are_not_connected():
    seq = random_jointly_connected(5, 3, windows=4, seed=7)
    assert smallest_joint_period(seq) == 3
    assert sum(is_strongly_connected(5, g) for g in seq.graphs) == 0
    # reproducible from the seed, different for another seed
    assert random_jointly_connected(5, 3, windows=4, seed=7) == seq
    assert random_jointly_connected(5, 3, windows=4, seed=8) != seq


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 6), st.integers(1, 3), st.integers(0, 10**6), st.data())
def test_random_rooted_sequences_satisfy_remark_1(n, T, seed, data):
    roots = data.draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=2, unique=True))
    seq = random_jointly_rooted(n, T, roots, windows=3, seed=seed)
    assert satisfies_jointly_rooted(seq, T, roots)
    assert smallest_rooted_period(seq, roots) <= T


def test_rooted_sequence_need_not_be_strongly_connected():
    seq = random_jointly_rooted(4, 2, [0], windows=2, seed=1)
    assert smallest_rooted_period(seq, [0]) is not None
    assert smallest_joint_period(seq) is None  # a tree out of 0: nothing enters 0


# -- link schedules -------------------------------------------------------------------------


def test_link_schedule_intervals_and_duty_cycles():
    sched = LinkSchedule(CYCLE3, n_agents=3, down={(0, 1): [(2, 4), (10, None)]},
                         duty={(1, 2): (3, 1, 1)})
    up01 = [sched.is_up(0, 1, k) for k in range(12)]
    assert up01 == [True, True, False, False, True, True, True, True, True, True,
                    False, False]
    assert [sched.is_up(1, 2, k) for k in range(6)] == [False, True, False, False, True, False]
    assert all(sched.is_up(2, 0, k) for k in range(12))
    assert not sched.is_up(1, 0, 0)  # not a link at all
    assert sched.links() == frozenset(CYCLE3)
    seq = sched.to_sequence()
    for k in range(40):
        assert seq.edges(k) == sched.edges(k)
    # (0,1) is down for good after step 10: never strongly connected again
    assert smallest_joint_period(sched) is None


def test_link_schedule_over_a_sequence_and_errors():
    base = alternating_sequence(2, [(0, 1)], [(1, 0)])
    sched = LinkSchedule(base, duty={(0, 1): (4, 2)})
    assert [sched.is_up(0, 1, k) for k in range(8)] == [True, False, False, False,
                                                        True, False, False, False]
    assert smallest_joint_period(sched) == 4
    with pytest.raises(TopologyError):
        LinkSchedule(CYCLE3)  # edge set without n_agents
    with pytest.raises(TopologyError):
        LinkSchedule(CYCLE3, n_agents=3, down={(0, 1): [(5, 2)]})
    with pytest.raises(TopologyError):
        LinkSchedule(CYCLE3, n_agents=3, duty={(0, 1): (2, 3)})


# -- the kernel's availability hook ---------------------------------------------------------


class _Recorder:
    """Minimal estimator: remembers which (sender, sent step) it received."""

    def __init__(self) -> None:
        self.received: list[tuple[int, int]] = []
        self.estimate = np.zeros(1)

    def message_arrived(self, sender, sent_step, payload):
        self.received.append((int(sender), int(sent_step)))
        return True

    def step(self, k, y):
        return self.estimate


def test_kernel_delivers_exactly_the_edges_that_are_up():
    seq = random_jointly_connected(4, 3, windows=2, seed=3)
    plant = LinearPlant(np.eye(1), tuple(np.zeros((0, 1)) for _ in range(4)), np.zeros((1, 1)),
                        tuple(np.zeros((0, 0)) for _ in range(4)), np.zeros(1), np.eye(1))
    ests = [_Recorder() for _ in range(4)]
    links = sorted(seq.links())
    agents = [AgentSpec(ests[i], lambda ys, i=i: ys[i], [r for s, r in links if s == i])
              for i in range(4)]
    steps = 20
    sim = Simulation(plant, agents, homogeneous_delays(links, 0), np.random.default_rng(0),
                     availability=seq.is_up)
    result = sim.run(steps)
    for i in range(4):
        expected = sorted((j, s) for s in range(steps) for (j, r) in seq.edges(s) if r == i)
        assert sorted(ests[i].received) == expected
    sent = (steps + 1) * len(links)
    up = sum(len(seq.edges(s)) for s in range(steps + 1))
    assert result.messages_sent == sent
    assert result.messages_dropped == sent - up
