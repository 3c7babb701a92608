"""The open3d backend passes the mapping contract."""

from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.testing.mapping import MappingContract


class TestOpen3dContract(MappingContract):
    def make_backend(self) -> Open3dVoxelMap:
        return Open3dVoxelMap()
