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
