"""The flyable volume is bounded by the area (issue #19): an open-topped building is explored
inside, not over its walls.

A 6 × 6 m room without a ceiling, split by a 2.0 m wall with a door at its far end; the air above
the walls is known free (a camera sees the sky over a wall as free space). The area is the
building's box, 2.0 m high: paths go through the door, never over the wall.
"""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib.voxel_grid import OCCUPIED, UNKNOWN
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.types import BoundingBox

from .global_maps import load_states

V = 0.25
N = (24, 24, 16)  # 6 × 6 × 4 m
WALL_TOP = 8  # the walls end at z 2.0 m
A, B = np.array([1.5, 1.0, 1.2]), np.array([4.5, 1.0, 1.2])  # either side of the middle wall


def open_topped() -> np.ndarray:
    s = np.full(N, UNKNOWN, dtype=np.int8)
    s[:, :, 1:] = 0  # air, up to 4 m: seen free over the walls
    s[:, :, 0] = OCCUPIED  # floor
    t = WALL_TOP
    walls = np.s_[0, :, 1:t], np.s_[-1, :, 1:t], np.s_[:, 0, 1:t], np.s_[:, -1, 1:t]
    for wall in walls:
        s[wall] = OCCUPIED
    s[12, :, 1:WALL_TOP] = OCCUPIED  # the middle wall, x 3.0–3.25 m ...
    s[12, 18:22, 1:WALL_TOP] = 0  # ... with a 1 m door at y 4.5–5.5 m
    return s


def load(cls, tmp_path, states: np.ndarray, top: float):
    return load_states(
        cls, tmp_path, states, BoundingBox(np.array([0.0, 0.0, 0.0]), np.array([6.0, 6.0, top])), V
    )


@pytest.mark.parametrize("cls", [NumpyVoxelMap, Open3dVoxelMap])
def test_paths_stay_inside_an_open_topped_building(cls, tmp_path) -> None:
    # An area reaching above the walls lets the shortest path hop over the middle wall: the
    # scene exposes the defect the bound removes.
    loose = load(cls, tmp_path, open_topped(), top=4.0)
    over = loose.plan_path(A, B)
    assert over is not None and over[:, 2].max() > 2.0

    bounded = load(cls, tmp_path, open_topped(), top=2.0)
    path = bounded.plan_path(A, B)
    assert path is not None
    assert path[:, 2].max() <= 2.0 - bounded.robot_radius + 1e-6
    # it goes round through the door (y 4.5–5.5 m) instead
    crossing = path[np.argmin(np.abs(path[:, 0] - 3.1))]
    assert crossing[1] > 4.0
    costs = bounded.path_costs(A[None], B[None])
    assert np.isfinite(costs).all() and costs[0, 0] > 6.0


@pytest.mark.parametrize("cls", [NumpyVoxelMap, Open3dVoxelMap])
def test_no_path_leaves_the_area_even_where_space_is_known_free(cls, tmp_path) -> None:
    s = open_topped()
    s[12, 18:22, 1:WALL_TOP] = OCCUPIED  # no door: over the wall is the only way
    assert load(cls, tmp_path, s, top=4.0).plan_path(A, B) is not None
    assert load(cls, tmp_path, s, top=2.0).plan_path(A, B) is None
