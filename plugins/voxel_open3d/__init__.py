"""``open3d`` mapping backend: the fast default (projective updates into block and window storage)."""

import amslam
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap, Open3dVoxelMapParams, WindowGrid

# blocks.BlockGrid (the global map's storage) is not imported here: it imports numba
__all__ = ["Open3dVoxelMap", "Open3dVoxelMapParams", "WindowGrid"]


@amslam.hookimpl
def amslam_mapping_backends():
    """The ``open3d`` mapping backend."""
    return {"open3d": Open3dVoxelMap}
