"""A ceiling seen at grazing angles stays in the map (both backends).

A level camera sees a slab's underside (2.8 m) only at grazing angles; its rays cross the bottom
5 cm of the slab's 0.25 m voxel layer (2.75–3.0 m) for half a metre before they end. Freeing every
voxel a ray crosses (plain exact traversal, as OctoMap does) carved that layer down to scattered
voxels and a demo flight with the ``numpy`` backend climbed into the slab beside the shaft.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.lib.voxel_grid import FREE, OCCUPIED
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.testing.mapping import camera_pose, make_context, render_depth
from amslam.types import BoundingBox, CameraModel

CAMERA = CameraModel.from_fov(320, 240, 87.0, 58.0, min_range=0.3, max_range=5.0)
AREA = BoundingBox(np.array([0.0, 0.0, 0.0]), np.array([12.0, 6.0, 3.5]))
SLAB_LAYER = 11  # 0.25 m voxels: z 2.75–3.0 holds the slab's 2.8–3.0


def slab_scene():
    """A 12 × 6 m floor and a 0.2 m slab over it, underside at 2.8 m."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    for lo, hi in [((0, 0, -0.2), (12, 6, 0.0)), ((0, 0, 2.8), (12, 6, 3.0))]:
        box = o3d.geometry.TriangleMesh.create_box(*(np.subtract(hi, lo)))
        box.translate(lo)
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(box))
    return scene


@pytest.mark.parametrize("backend", [NumpyVoxelMap, Open3dVoxelMap])
def test_slab_seen_from_below_at_grazing_angles_is_not_carved(backend, tmp_path: Path) -> None:
    m = backend()
    m.configure(backend.Params(global_voxel=0.25), make_context(tmp_path, camera=CAMERA, area=AREA))
    scene = slab_scene()
    for x in np.arange(0.5, 6.0, 0.5):  # flying along the room, level, at two heights
        for z in (1.2, 1.6):
            T = camera_pose((x, 3.0, z), 0.0)
            m.integrate_global(render_depth(scene, CAMERA, T), CAMERA.K, T)
    index, states = m.global_map.voxels()
    layer = index[:, 2] == SLAB_LAYER
    assert np.sum(layer & (states == OCCUPIED)) > 100  # the underside was seen
    assert not np.any(layer & (states == FREE)), "voxels of the slab's layer carved free"
    # the air under it is free
    assert np.sum((index[:, 2] == SLAB_LAYER - 1) & (states == FREE)) > 100
