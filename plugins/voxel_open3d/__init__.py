"""``open3d`` mapping backend: the fast default (Open3D hash-map voxels, projective updates)."""

import amslam
from amslam.plugins.voxel_open3d.backend import HashGrid, Open3dVoxelMap, Open3dVoxelMapParams

__all__ = ["HashGrid", "Open3dVoxelMap", "Open3dVoxelMapParams"]


@amslam.hookimpl
def amslam_mapping_backends():
    """The ``open3d`` mapping backend."""
    return {"open3d": Open3dVoxelMap}
