"""On a real vehicle the detector runs beside the control loop; its detections still reach SLAM."""

from __future__ import annotations

import threading

import numpy as np

import amslam
from amslam.measurements import read_measurements
from amslam.mission import load_mission
from amslam.plugins.sim.detector import SimDetector
from amslam.plugins.sim.platform import SimPlatform
from amslam.registry import build_plugin_manager
from amslam.runner import Runner

from .missions import small_mission


class ThreadRecordingDetector(SimDetector):
    threads: set[str] = set()

    def detect(self, frame):
        ThreadRecordingDetector.threads.add(threading.current_thread().name)
        return super().detect(frame)


class UnsimulatedSim(SimPlatform):
    """The simulator, flagged as a real vehicle: the runner treats it as one (no failsafes raised)."""

    simulated = False


class Plugin:
    @amslam.hookimpl
    def amslam_platform_backends(self):
        return {"unsimulated": UnsimulatedSim}

    @amslam.hookimpl
    def amslam_detector_backends(self):
        return {"recording": ThreadRecordingDetector}


def test_a_real_vehicle_detects_off_the_control_thread(tmp_path):
    registry = build_plugin_manager(extra_plugins=[Plugin()])
    path = small_mission(tmp_path, max_time=40)
    text = path.read_text().replace("plugin: sim\n", "plugin: unsimulated\n", 1)
    path.write_text(text.replace("detector: {plugin: sim}", "detector: {plugin: recording}"))
    # a real vehicle of a team names its base: the measurement log's T_world_odom
    mission = load_mission(path, registry, overrides=["robot.base=[2.0, -1.0, 0.5, 90]"])
    result = Runner(mission, registry, tmp_path / "runs").run()
    assert result.verdict == "completed", result.verdict
    assert ThreadRecordingDetector.threads and all(
        name.startswith("amslam-detector") for name in ThreadRecordingDetector.threads
    )
    assert result.metrics["landmarks"]["count"] > 0
    np.testing.assert_allclose(
        read_measurements(result.run_dir).T_world_odom,
        [[0, -1, 0, 2.0], [1, 0, 0, -1.0], [0, 0, 1, 0.5], [0, 0, 0, 1]],
        atol=1e-9,
    )
