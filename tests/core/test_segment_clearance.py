"""samples_clear: a segment's samples keep ``radius`` from every occupied voxel, by the box distance."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from amslam.lib.free_space import samples_clear, segment_samples
from amslam.lib.voxel_grid import FREE, OCCUPIED

VOXEL = 0.1
SHAPE = (30, 30, 20)


def _states(occupied: np.ndarray):
    grid = np.full(SHAPE, FREE, dtype=np.int8)
    grid[tuple(occupied.T)] = OCCUPIED

    def states_at(index: np.ndarray) -> np.ndarray:
        out = np.full(len(index), FREE, dtype=np.int8)
        inside = np.all((index >= 0) & (index < np.array(SHAPE)), axis=1)
        out[inside] = grid[tuple(index[inside].T)]
        return out

    return states_at


def _clear_by_every_voxel(samples: np.ndarray, occupied: np.ndarray, radius: float) -> bool:
    """The definition, over every occupied voxel of the map: no box nearer than ``radius``."""
    lo = occupied * VOXEL
    gap = np.maximum(np.maximum(lo[None] - samples[:, None], samples[:, None] - (lo + VOXEL)[None]), 0.0)
    return bool(np.all(np.sqrt((gap**2).sum(-1)) >= radius))


points = st.tuples(*(st.floats(0.3, (n - 3) * VOXEL) for n in SHAPE))


@settings(max_examples=150, deadline=None)
@given(
    a=points,
    b=points,
    radius=st.sampled_from([0.05, 0.2, 0.25, 0.33]),
    seed=st.integers(0, 2**16),
    count=st.integers(1, 60),
)
def test_samples_clear_is_the_distance_to_the_nearest_occupied_box(a, b, radius, seed, count) -> None:
    occupied = np.random.default_rng(seed).integers(0, SHAPE, size=(count, 3))
    samples = segment_samples(np.array(a), np.array(b), 0.5 * VOXEL)
    expected = _clear_by_every_voxel(samples, occupied, radius)
    assert samples_clear(samples, radius, VOXEL, _states(occupied)) == expected


def test_a_voxel_just_inside_and_just_outside_the_radius() -> None:
    samples = segment_samples(np.array([0.5, 1.0, 1.0]), np.array([2.5, 1.0, 1.0]), 0.05)
    wall = np.array([[15, 13, 10]])  # its box starts at y 1.3: 0.3 m beside the segment
    assert samples_clear(samples, 0.29, VOXEL, _states(wall))
    assert not samples_clear(samples, 0.31, VOXEL, _states(wall))
