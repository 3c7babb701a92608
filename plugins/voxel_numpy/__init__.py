"""``numpy`` mapping backend: the simple, obviously correct reference voxel map.

Also home of the pieces every voxel backend shares (one copy of each concept): the lattice and
log-odds model (:mod:`.grid`), frontier clustering and viewpoint sampling (:mod:`.frontiers`), and
collision checks and graph search (:mod:`.search`), and the Mapping base class (:mod:`.backend`).
"""

import amslam
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap, VoxelMapBase, VoxelMapParams

__all__ = ["NumpyVoxelMap", "VoxelMapBase", "VoxelMapParams"]


@amslam.hookimpl
def amslam_mapping_backends():
    """The ``numpy`` reference mapping backend."""
    return {"numpy": NumpyVoxelMap}
