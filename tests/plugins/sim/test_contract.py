"""The simulator platform and the sim detector pass their contract kits."""

from amslam.plugins.sim.detector import SimDetector
from amslam.plugins.sim.platform import SimPlatform
from amslam.testing.detector import DetectorContract
from amslam.testing.platform import PlatformContract


class TestSimPlatformContract(PlatformContract):
    def make_backend(self) -> SimPlatform:
        return SimPlatform()

    def make_params(self, backend: SimPlatform) -> SimPlatform.Params:
        # a small one-floor building and a small camera keep the flights fast
        return SimPlatform.Params(
            world={"size": [10, 8], "floors": 1}, camera={"width": 80, "height": 60, "rate_hz": 5}
        )


class TestSimDetectorContract(DetectorContract):
    def make_backend(self) -> SimDetector:
        return SimDetector()
