"""``numpy`` mapping backend: the simple, obviously correct reference voxel map.

The pieces every voxel backend shares live in the library: the lattice and log-odds model
(:mod:`amslam.lib.voxel_grid`), frontier clustering and viewpoint sampling
(:mod:`amslam.lib.frontiers`), collision checks and graph search (:mod:`amslam.lib.free_space`),
and the Mapping base class (:mod:`amslam.lib.voxel_map`).
"""

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_mapping_backends():
    """The ``numpy`` reference mapping backend."""
    return {"numpy": Deferred("amslam.plugins.voxel_numpy.backend:NumpyVoxelMap")}
