"""Paths keep away from walls where there is room, and still pass narrow gaps."""

from __future__ import annotations

import numpy as np

from amslam.lib.free_space import FreeSpaceGraph
from amslam.lib.voxel_grid import FREE


def graph(penalty=None):
    # A 9 × 3 × 1 slab of free voxels; row y = 0 hugs a wall (penalised), y = 2 is roomy.
    passable = np.ones((9, 3, 1), dtype=bool)
    states = np.full(passable.shape, FREE, dtype=np.int8)
    return FreeSpaceGraph(passable, np.zeros(3, dtype=np.int64), 1.0, 0.5, states, penalty=penalty)


def test_penalty_scales_costs_along_tight_voxels():
    a, b = np.array([[0.5, 0.5, 0.5]]), np.array([[8.5, 0.5, 0.5]])
    plain = graph().costs(a, b)[0, 0]
    penalty = np.ones((9, 3, 1))
    penalty[:, 0, 0] = 3.0
    assert plain == 8.0
    # With the wall row penalised the cheapest route leaves it for the middle row and comes back.
    weighted = graph(penalty).costs(a, b)[0, 0]
    assert 8.0 < weighted < 3.0 * 8.0


def test_a_gap_that_is_only_tight_stays_passable():
    penalty = np.full((9, 3, 1), 3.0)
    cost = graph(penalty).costs(np.array([[0.5, 1.5, 0.5]]), np.array([[8.5, 1.5, 0.5]]))[0, 0]
    assert np.isclose(cost, 24.0)
