"""The numpy reference backend passes the mapping contract."""

from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.testing.mapping import MappingContract


class TestNumpyContract(MappingContract):
    def make_backend(self) -> NumpyVoxelMap:
        return NumpyVoxelMap()
