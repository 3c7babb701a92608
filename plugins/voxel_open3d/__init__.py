"""``open3d`` mapping backend: the fast default (projective updates into Open3D-indexed 8³ blocks and a
dense window)."""

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_mapping_backends():
    """The ``open3d`` mapping backend."""
    return {"open3d": Deferred("amslam.plugins.voxel_open3d.backend:Open3dVoxelMap")}
