"""Seed layout 2: one stream per trial for a link set's per-message draws."""

from __future__ import annotations

import numpy as np
import pytest
from netsim.models.delays import (
    BATCH_SIZE,
    BLOCK_ELEMENTS,
    AsynchronousRandomDelays,
    LinkBlockDraws,
)
from netsim.models.seeding import SEED_LAYOUT, child_sequence, stream

LINKS = [(j, i) for j in range(5) for i in range(5) if i != j]


def test_table_is_rows_of_one_stream():
    """Entry (q, c) is draw q * L + c of the trial's one stream, in blocks of R rows
    (computed here from numpy directly, not through the class)."""
    tau, seed, steps = 4, 7, 3 * min(BATCH_SIZE, BLOCK_ELEMENTS // len(LINKS)) + 5
    model = AsynchronousRandomDelays(tau, seed, LINKS)
    got = model.draw_block(LINKS, np.arange(steps))
    rng = np.random.Generator(np.random.PCG64(child_sequence(seed, "delays/asynchronous")))
    rows = min(BATCH_SIZE, BLOCK_ELEMENTS // len(LINKS))
    blocks = [rng.integers(0, tau + 1, size=rows * len(LINKS), dtype=np.int32).reshape(
        rows, len(LINKS))
              for _ in range(-(-steps // rows))]
    assert np.array_equal(got, np.concatenate(blocks)[:steps])


@pytest.mark.parametrize("order", ["kernel", "reversed", "mixed"])
def test_any_read_order_gives_the_same_numbers(order):
    """The event kernel reads one value per link per step, the vectorised engine whole
    columns; any interleaving gives each link the same sequence."""
    steps = 40
    ref = AsynchronousRandomDelays(3, 11, LINKS).draw_block(LINKS, np.arange(steps))
    model = AsynchronousRandomDelays(3, 11, LINKS)
    if order == "kernel":
        samplers = [model.sampler(j, i) for j, i in LINKS]
        out = np.array([[sample(s) for sample in samplers] for s in range(steps)])
        assert np.array_equal(out, ref)
    elif order == "reversed":
        for c in reversed(range(len(LINKS))):
            assert np.array_equal(model.draw_many(*LINKS[c], np.arange(steps)), ref[:, c])
    else:
        # even columns read 5 values one at a time first, then a block of every column
        for j, i in LINKS[::2]:
            [model.draw(j, i, s) for s in range(5)]
        block = model.draw_block(LINKS, np.arange(20))
        assert np.array_equal(block[:, ::2], ref[5:25, ::2])
        assert np.array_equal(block[:, 1::2], ref[:20, 1::2])
        rest = model.draw_block(LINKS, np.arange(10))
        assert np.array_equal(rest[:, 1::2], ref[20:30, 1::2])


def test_delays_are_uniform_and_independent_across_links():
    """Monte Carlo: each value of {0..tau} about 1/(tau+1) of the draws; links and
    successive messages uncorrelated (|r| within 5 standard errors)."""
    tau, steps = 3, 4000
    d = AsynchronousRandomDelays(tau, 5, LINKS).draw_block(LINKS, np.arange(steps))
    freq = np.bincount(d.ravel(), minlength=tau + 1) / d.size
    assert np.allclose(freq, 1 / (tau + 1), atol=5 * np.sqrt(0.25 / d.size))
    corr = np.corrcoef(d.T)
    off = corr[~np.eye(len(LINKS), dtype=bool)]
    assert np.max(np.abs(off)) < 5 / np.sqrt(steps)
    lag1 = np.corrcoef(d[:-1].ravel(), d[1:].ravel())[0, 1]
    assert abs(lag1) < 5 / np.sqrt(d.size)


def test_links_outside_the_set_use_their_own_stream():
    model = AsynchronousRandomDelays(5, 3, LINKS[:3])
    own = np.random.Generator(np.random.PCG64(child_sequence(3, "delays/link/9-8")))
    assert [model.draw(9, 8, s) for s in range(4)] == own.integers(0, 6, size=256)[:4].tolist()


def test_block_stream_refuses_duplicate_links():
    with pytest.raises(ValueError, match="distinct"):
        LinkBlockDraws(stream(0, "x"), lambda g, n: g.random(n), [(0, 1), (0, 1)])


def test_seed_layout_in_results_and_traces(tmp_path):
    from netsim.models.scenario import resolve_scenario
    from netsim.traces.reader import read_trace

    from netsim.api import run

    assert SEED_LAYOUT == 2
    scenario = resolve_scenario("lcsys2022-homogeneous")
    path = tmp_path / "t.mcap"
    result = run(scenario, steps=5, trials=1, estimators=["compensated"], engine="events",
                 trace=path)
    assert result.seed_layout == SEED_LAYOUT
    assert result.to_dict()["seed_layout"] == SEED_LAYOUT
    traces = sorted(tmp_path.glob("*.mcap"))
    assert traces, "no trace written"
    assert read_trace(traces[0]).run["seed_layout"] == str(SEED_LAYOUT)


@pytest.mark.parametrize(("tau", "steps", "trials"), [(3, 60, 4), (0, 10, 2), (7, 30, 3),
                                                      (5, 3, 2), (2, 0, 2)])
def test_bounded_selection_equals_the_general_one(tau, steps, trials):
    """The freshest-message selection for lossless step delays (D + 1 passes) against
    the general one (suffix minima and counts) on the same schedule."""
    import dataclasses

    from netsim.linkschedule import build_schedule, select_messages

    models = [AsynchronousRandomDelays(tau, s, LINKS) for s in range(trials)]
    schedule = build_schedule(models, LINKS, np.arange(steps + 1))
    assert schedule.lossless_steps
    fast = select_messages(schedule, steps, timestamps=True)
    general = select_messages(dataclasses.replace(schedule, lossless_steps=False), steps,
                              timestamps=True)
    assert np.array_equal(fast.chosen, general.chosen)
    assert np.array_equal(fast.discarded, general.discarded)
    assert fast.max_lag == general.max_lag
    ends = np.full(trials, steps)
    assert np.array_equal(fast.discarded_by(schedule, ends),
                          general.discarded_by(dataclasses.replace(
                              schedule, lossless_steps=False), ends))
