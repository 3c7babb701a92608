"""Viewpoints and their alternatives are moved into the band between floor and ceiling."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from amslam.mission import ExplorationSection
from amslam.perception import Perception
from amslam.types import Viewpoint, VoxelState


class Room:
    """Occupied below z 0.25 m (floor) and from z 2.75 m up (ceiling), except a low gap at x > 9."""

    def voxel_size(self) -> float:
        return 0.25

    def states(self, points):
        p = np.atleast_2d(points)
        ceiling = np.where(p[:, 0] > 9.0, 1.0, 2.75)
        occupied = (p[:, 2] < 0.25) | (p[:, 2] >= ceiling)
        return np.where(occupied, VoxelState.OCCUPIED, VoxelState.FREE)


def vp(x: float, z: float, alternatives=()) -> Viewpoint:
    return Viewpoint(1, np.array([x, 0.0, z]), 0.0, 5.0, np.zeros(3), 10, tuple(alternatives))


def test_each_option_is_moved_into_the_band_and_a_low_gap_is_left_alone() -> None:
    ex = ExplorationSection()
    fake = SimpleNamespace(mapping=Room(), exploration=ex)
    low, high, fine, gap = vp(1.0, 0.4), vp(2.0, 2.6), vp(3.0, 1.5), vp(9.5, 0.6)
    (out,) = Perception._within_band(fake, [vp(0.0, 0.3, (high, fine, gap))])
    floor_top, ceiling = 0.25, 2.75
    assert out.position[2] >= floor_top + ex.min_height - 0.25  # the floor is found to a voxel
    assert out.position[2] > 0.3
    moved_high, kept, kept_gap = out.alternatives
    assert moved_high.position[2] < 2.6 and moved_high.position[2] <= ceiling - ex.min_headroom + 0.25
    assert kept is fine  # inside the band: the same object
    assert kept_gap is gap  # floor and ceiling closer than the band: left to the path planner
    assert np.allclose(moved_high.position[:2], high.position[:2])
    assert Perception._within_band(fake, []) == ()
    assert Perception._within_band(fake, [low])[0].alternatives == ()
