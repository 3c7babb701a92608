"""Re-centring the local window forgets exactly the voxels that left it (by slabs, not by a scan)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from amslam.lib.voxel_grid import LogOddsModel
from amslam.plugins.voxel_open3d.backend import HashGrid, _left_behind


def _cells(lo, hi) -> set[tuple[int, int, int]]:
    axes = [range(int(a), int(b)) for a, b in zip(lo, hi, strict=True)]
    return {(x, y, z) for x in axes[0] for y in axes[1] for z in axes[2]}


def test_the_slabs_cover_the_old_window_minus_the_new_once():
    rng = np.random.default_rng(0)
    shape = np.array([6, 5, 4])
    for _ in range(300):
        old = rng.integers(-5, 5, 3)
        new = old + rng.integers(-8, 9, 3)
        slabs = _left_behind(old, new, shape)
        covered = [_cells(a, b) for a, b in slabs]
        union = set().union(*covered) if covered else set()
        assert union == _cells(old, old + shape) - _cells(new, new + shape), (old, new)
        assert sum(len(c) for c in covered) == len(union)  # disjoint


@pytest.mark.parametrize("jump", [(3, 0, 0), (-2, 4, 1), (40, 0, 0), (0, 0, 0)])
def test_a_shift_keeps_what_is_inside_and_forgets_what_left(jump):
    grid = HashGrid(
        0.1, np.zeros(3, np.int64), (20, 20, 10), LogOddsModel(0.7, 0.4, 0.8, 0.12, 0.97), True, 4096
    )
    rng = np.random.default_rng(1)
    index = np.unique(rng.integers(0, [20, 20, 10], (900, 3)), axis=0)
    grid.map.insert(grid._keys(index), o3d.core.Tensor(np.ones((len(index), 1), np.float32)))
    new = np.array(jump, np.int64)
    grid.shift_to(new)
    kept, _ = grid._active()
    inside = np.all((index >= new) & (index < new + [20, 20, 10]), axis=1)
    assert {tuple(k) for k in kept.tolist()} == {tuple(k) for k in index[inside].tolist()}
