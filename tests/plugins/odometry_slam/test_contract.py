"""The odometry SLAM backend passes the SLAM contract kit."""

from amslam.plugins.odometry_slam import OdometrySlam
from amslam.testing.slam import SlamContract


class TestOdometrySlamContract(SlamContract):
    def make_backend(self) -> OdometrySlam:
        return OdometrySlam()
