"""The kernels are compiled when the backend is configured, before take-off, and a flight's frames
and queries use those compiled versions: none is compiled again in flight."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from amslam.plugins.voxel_open3d import blocks, projective
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.testing.mapping import ROOM_POSE, make_context, render_depth, room_scene
from amslam.types import BoundingBox, CameraModel

KERNELS = (
    projective._frustum_kernel,
    projective._fold_dense,
    projective._fold_blocks,
    projective._flag_blocks,
    blocks._blocks_into_box,
    blocks._known_extent,
)


def test_configure_compiles_every_kernel_once_for_the_types_a_flight_uses(tmp_path: Path):
    camera = CameraModel.from_fov(160, 120, 87.0, 58.0)
    m = Open3dVoxelMap()
    area = BoundingBox(np.array([0.0, 0.0, 0.0]), np.array([20.0, 6.0, 3.0]))
    m.configure(Open3dVoxelMap.Params(), make_context(tmp_path, camera=camera, area=area))
    compiled = {k.py_func.__name__: len(k.signatures) for k in KERNELS}
    assert all(n >= 1 for n in compiled.values()), compiled
    depth = render_depth(room_scene(), camera, ROOM_POSE)
    m.integrate_local(depth, camera.K, ROOM_POSE)
    m.integrate_global(depth.astype(np.float64), camera.K, ROOM_POSE)  # any depth dtype
    m.viewpoints()
    m.path_costs(np.array([[4.6, 1.9, 1.3]]), np.array([[6.0, 2.2, 1.3]]))
    m.segment_free(np.array([4.6, 1.9, 1.3]), np.array([6.0, 2.2, 1.3]), local=True)
    m.states(np.array([[5, 2, 1]]))  # int points: the map's calls convert them
    m.blocked(np.array([[5.0, 2.0, 1.0]]))
    m.explored_volume()
    m.save(tmp_path / "map.npz")
    m.load(tmp_path / "map.npz")
    assert {k.py_func.__name__: len(k.signatures) for k in KERNELS} == compiled
