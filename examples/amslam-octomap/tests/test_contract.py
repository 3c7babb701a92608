"""The octomap backend passes amslam's mapping contract (run with ``pytest`` in this folder)."""

from amslam_octomap import OctomapMapping

from amslam.testing.mapping import MappingContract


class TestOctomapContract(MappingContract):
    def make_backend(self) -> OctomapMapping:
        return OctomapMapping()
