"""The radius past isolation of a geometric network (models.network, issue 34): the
grid pre-filter gives exactly the radius an all-pairs nearest-neighbour search gives."""

from __future__ import annotations

import math

import numpy as np
import pytest
from netsim.models import network
from scipy.spatial import cKDTree


def _all_pairs(r: float, positions: np.ndarray) -> float:
    """The 10% growth from r past the largest nearest-neighbour distance, by all pairs."""
    d2 = np.sum((positions[:, None, :] - positions[None, :, :]) ** 2, axis=2)
    np.fill_diagonal(d2, np.inf)
    needed = math.sqrt(float(d2.min(axis=1).max()))
    while r < needed:
        r *= 1.1
    return r


@pytest.mark.parametrize("seed", range(6))
def test_the_grid_gives_the_radius_of_an_all_pairs_search(seed):
    rng = np.random.default_rng(seed)
    for case in range(40):
        n = int(rng.integers(2, 400))
        positions = rng.random((n, 2))
        if case % 5 == 0:
            positions[: n // 2] = positions[0]  # coincident points
        if case % 7 == 0:
            positions = np.round(positions, 1)  # ties on a lattice: distances equal to r
        r = float(10 ** rng.uniform(-4, 0.3))
        if case % 3 == 0:  # exactly at a nearest-neighbour distance
            d2 = np.sum((positions[:, None] - positions[None]) ** 2, axis=2)
            np.fill_diagonal(d2, np.inf)
            r = math.sqrt(float(d2.min(axis=1).max())) or r
        expected = _all_pairs(r, positions)
        assert network._grown_past_isolation(r, positions) == expected
        assert network._grown_past_isolation(r, positions, cKDTree(positions)) == expected


def test_only_points_alone_in_their_cell_are_suspects():
    rng = np.random.default_rng(3)
    positions = rng.random((2000, 2))
    r = 0.08  # cells of side <= 0.057: about 6 points a cell
    suspects = set(network._lonely_points(r, positions).tolist())
    d2 = np.sum((positions[:, None] - positions[None]) ** 2, axis=2)
    np.fill_diagonal(d2, np.inf)
    isolated = set(np.flatnonzero(d2.min(axis=1) > r * r).tolist())
    assert isolated <= suspects  # no isolated point is missed
    assert len(suspects) < len(positions) // 10  # and the filter does filter


def test_a_radius_too_small_for_a_grid_falls_back_to_every_point():
    positions = np.random.default_rng(0).random((50, 2))
    assert len(network._lonely_points(1e-300, positions)) == 50
    assert network._grown_past_isolation(1e-300, positions) == _all_pairs(1e-300, positions)
