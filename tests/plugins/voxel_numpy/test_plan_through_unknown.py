"""``plan_through_unknown``: open outdoor areas are crossed before they are mapped, inside the area only."""

from __future__ import annotations

import numpy as np

from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.testing.mapping import AREA, make_context


def _mapping(tmp_path, **params) -> NumpyVoxelMap:
    m = NumpyVoxelMap()
    m.configure(NumpyVoxelMap.Params(**params), make_context(tmp_path))
    return m


def test_unknown_space_inside_the_area_is_crossed_only_when_asked(tmp_path) -> None:
    a = AREA.lo + 0.25 * (AREA.hi - AREA.lo)
    b = AREA.lo + 0.75 * (AREA.hi - AREA.lo)
    pts = np.array([a, b])
    # Nothing is mapped: no known free space, no path.
    assert np.isinf(_mapping(tmp_path).path_costs(pts, pts)[0, 1])
    optimistic = _mapping(tmp_path, plan_through_unknown=True)
    cost = optimistic.path_costs(pts, pts)[0, 1]
    straight = float(np.linalg.norm(b - a))
    assert straight - 0.5 <= cost <= 1.2 * straight
    path = optimistic.plan_path(a, b)
    assert path is not None and np.allclose(path[0], a, atol=0.3) and np.allclose(path[-1], b, atol=0.3)
    # Below the area (under the ground, say) stays out of reach.
    below = a - np.array([0.0, 0.0, (AREA.hi - AREA.lo)[2] + 3.0])
    assert np.isinf(optimistic.path_costs(np.array([a, below]), np.array([a, below]))[0, 1])
