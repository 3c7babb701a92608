"""Re-centring the local window keeps exactly the voxels still inside it (the hash-map window it
replaced forgot what left by slabs; the dense window copies the overlap)."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib.voxel_grid import LogOddsModel
from amslam.plugins.voxel_open3d.backend import WindowGrid


@pytest.mark.parametrize("jump", [(3, 0, 0), (-2, 4, 1), (40, 0, 0), (0, 0, 0), (-7, -19, 9)])
def test_a_shift_keeps_what_is_inside_and_forgets_what_left(jump):
    shape = (20, 20, 10)
    grid = WindowGrid(0.1, np.zeros(3, np.int64), shape, LogOddsModel(0.7, 0.4, 0.8, 0.12, 0.97))
    rng = np.random.default_rng(1)
    index = np.unique(rng.integers(0, shape, (900, 3)), axis=0)
    values = rng.uniform(-2, 3, len(index)).astype(np.float32)
    grid.from_arrays({"index": index, "logodds": values})
    new = np.array(jump, np.int64)
    grid.shift_to(new)
    kept = grid.to_arrays()
    inside = np.all((index >= new) & (index < new + shape), axis=1)
    assert {tuple(k) for k in kept["index"].tolist()} == {tuple(k) for k in index[inside].tolist()}
    by_index = dict(zip(map(tuple, index.tolist()), values.tolist(), strict=True))
    assert [by_index[tuple(k)] for k in kept["index"].tolist()] == kept["logodds"].tolist()
    np.testing.assert_array_equal(grid.lo, new)
    # what enters the window is unknown until seen
    assert grid.known.sum() == inside.sum()


@pytest.mark.parametrize("window", ["dense", "projective"])
def test_the_window_forgets_free_space_no_recent_frame_updated(window):
    """Free space seen once and then not again for ``frames`` frames is unknown again, free space
    seen in every frame stays, and an obstacle stays however old (the window keeps voxels for as
    long as they are inside it, in the odometry frame of when they were seen: stale free space can
    stand where something now is, a stale obstacle only keeps the vehicle away)."""
    from amslam.lib.voxel_grid import DenseGrid

    model = LogOddsModel(0.7, 0.4, 0.8, 0.12, 0.97)
    grid = (DenseGrid if window == "dense" else WindowGrid)(0.1, np.zeros(3, np.int64), (40, 40, 20), model)
    K = np.array([[20.0, 0.0, 10.0], [0.0, 20.0, 10.0], [0.0, 0.0, 1.0]])

    def camera(z_axis: list[float], x_axis: list[float]) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x_axis, [0.0, 0.0, -1.0], z_axis])  # image rows downwards
        T[:3, 3] = [0.5, 2.0, 1.0]
        return T

    towards_wall, away = camera([1.0, 0.0, 0.0], [0.0, -1.0, 0.0]), camera([0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    wall, near = np.full((20, 20), 2.0, np.float32), np.full((20, 20), 0.5, np.float32)
    # 1 m and 2 m ahead of the camera at x = 0.5 m: air, then the wall
    air_and_wall = np.array([[15, 20, 10], [25, 20, 10]])

    def look(T: np.ndarray, depth: np.ndarray, frames: int) -> list[int]:
        for _ in range(frames):
            grid.integrate_depth(depth, K, T, 1, 5.0)
            grid.forget(10)
        return grid.states_at_index(air_and_wall).tolist()

    assert look(towards_wall, wall, 1) == [0, 1]  # FREE, OCCUPIED
    assert look(away, near, 8) == [0, 1]  # 8 frames without them: kept
    assert look(away, near, 2) == [-1, 1]  # 10: the air is unknown again, the wall stays
    assert look(towards_wall, wall, 15) == [0, 1]  # seen in every frame: kept
