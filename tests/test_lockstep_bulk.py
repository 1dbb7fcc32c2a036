"""The vectorised engine's bulk paths against their plain references (issue 34).

* :func:`netsim.linkschedule._select_bounded` (one-byte passes, no masked copies)
  against :func:`netsim.linkschedule._select_bounded_wide` (the previous int32 passes)
  and the general selection (suffix minima and counts), element for element;
* the message counts and discarded counts of lossless step delays (only the D rows
  before each trial's end compared) against the whole (T, L, S) comparisons;
* the preallocated sparse product of the step loop against ``matrix @ x``, bit for bit.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from netsim.linkschedule import (
    LinkSchedule,
    _select_bounded,
    _select_bounded_wide,
    select_messages,
)
from netsim.vectorised import _sparse_product_into


def _schedule(delays_slt: np.ndarray) -> LinkSchedule:
    """A lossless step-delay schedule stored (S, L, T), as build_schedule stores it."""
    S, L, T = delays_slt.shape
    latency = delays_slt.transpose(2, 1, 0)
    shape = (T, L, S)
    return LinkSchedule(
        [(j, j + 1) for j in range(L)], np.arange(S), None, latency, latency,
        fate=np.broadcast_to(np.zeros((1, 1, 1), dtype=np.int16), shape),
        drop_time=np.broadcast_to(np.full((1, 1, 1), np.nan), shape),
        reasons=[], lossless_steps=True)


CASES = [(0, 1, 1, 1), (3, 60, 5, 4), (7, 45, 3, 6), (2, 1, 4, 3), (4, 3, 2, 2),
         (30, 80, 2, 3), (126, 200, 2, 2), (140, 300, 2, 2), (5, 700, 40, 9)]


@pytest.mark.parametrize(("tau", "steps", "links", "trials"), CASES)
def test_bounded_selection_bulk_equals_wide_and_general(tau, steps, links, trials):
    rng = np.random.default_rng([tau, steps, links, trials])
    d = rng.integers(0, tau + 1, size=(steps + 1, links, trials), dtype=np.int32)
    schedule = _schedule(d)
    bulk = _select_bounded(schedule, steps)
    wide = _select_bounded_wide(schedule, steps)
    general = select_messages(dataclasses.replace(schedule, lossless_steps=False), steps,
                              timestamps=True)
    for other in (wide, general):
        assert bulk.chosen.dtype == other.chosen.dtype
        assert np.array_equal(bulk.chosen, other.chosen)
        assert np.array_equal(bulk.discarded, other.discarded)
        assert bulk.max_lag == other.max_lag


@pytest.mark.parametrize(("tau", "steps", "links", "trials"), CASES)
def test_lossless_counts_equal_the_whole_comparison(tau, steps, links, trials):
    rng = np.random.default_rng([1, tau, steps, links, trials])
    d = rng.integers(0, tau + 1, size=(steps + 1, links, trials), dtype=np.int32)
    schedule = _schedule(d)
    selection = select_messages(schedule, steps, timestamps=True)
    general = dataclasses.replace(schedule, lossless_steps=False)
    # every trial's own end (divergence steps), equal ends, ends beyond the delays
    for ends in (rng.integers(0, steps + 1, size=trials), np.full(trials, steps),
                 np.zeros(trials, dtype=np.int64), np.minimum(np.arange(trials), steps)):
        limit = ends[:, None, None] - 1 - schedule.send_steps
        arrived = schedule.delay_steps <= limit
        delivered = np.count_nonzero(arrived, axis=(1, 2))
        assert [c["delivered"] for c in schedule.counts(ends)] == delivered.tolist()
        assert schedule.counts(ends) == general.counts(ends)
        expect = np.count_nonzero(selection.discarded & arrived, axis=(1, 2))
        assert np.array_equal(selection.discarded_by(schedule, ends), expect)
        assert np.array_equal(selection.discarded_by(general, ends), expect)


@pytest.mark.parametrize("shape", [(5, 9, 12), (32, 64, 600), (1, 1, 1), (7, 3, 0)])
def test_sparse_product_into_is_bit_identical(shape):
    rows, cols, vectors = shape
    rng = np.random.default_rng(list(shape))
    matrix = sp.random(rows, cols, density=0.3, format="csr", random_state=rng)
    matrix.sort_indices()
    x = rng.normal(size=(cols, vectors))
    out = np.full((rows, vectors), np.nan)
    product = _sparse_product_into(matrix, out)
    for _ in range(2):  # the output is cleared on every call
        assert product(x) is out
        assert np.array_equal(out, matrix @ x)
        x = rng.normal(size=(cols, vectors))
