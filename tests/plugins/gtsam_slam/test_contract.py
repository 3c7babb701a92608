"""The GTSAM SLAM backend passes the SLAM contract kit."""

from amslam.plugins.gtsam_slam import GtsamSlam
from amslam.testing.slam import SlamContract


class TestGtsamSlamContract(SlamContract):
    def make_backend(self) -> GtsamSlam:
        return GtsamSlam()
