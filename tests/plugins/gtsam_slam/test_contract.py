"""The GTSAM SLAM backend passes the SLAM contract kit."""

from amslam.backend_process import SlamProcess
from amslam.plugins.gtsam_slam.backend import GtsamSlam
from amslam.testing.slam import SlamContract


class TestGtsamSlamContract(SlamContract):
    def make_backend(self) -> GtsamSlam:
        return GtsamSlam()


class TestGtsamSlamInItsOwnProcess(SlamContract):
    """The same promises kept by the graph in a process of its own, as on a real vehicle."""

    def make_backend(self) -> SlamProcess:
        return SlamProcess(GtsamSlam)
