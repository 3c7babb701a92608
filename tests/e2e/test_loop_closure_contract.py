"""Every detection reaches SLAM exactly once, at the pose of the frame it was made in.

``Slam.try_loop_closure(odom, T_body_cam, detections)`` takes detections seen *now*, at ``odom``;
the panorama's earlier detections were already fed through ``add_detections`` at their own
poses. Handing them over again at the current pose would add each a second time, displaced by
however far the robot moved or turned since it was made.
"""

from __future__ import annotations

import numpy as np

import amslam
from amslam.mission import load_mission
from amslam.plugins.odometry_slam import OdometrySlam
from amslam.plugins.sim.detector import SimDetector
from amslam.registry import build_plugin_manager
from amslam.runner import Runner

from .missions import small_mission


class RecordingDetector(SimDetector):
    """Remembers the camera pose of the frame each detection was made in."""

    made: dict[int, np.ndarray] = {}
    kept: list = []  # the detections themselves, so their ids stay unique

    def detect(self, frame):
        detections = super().detect(frame)
        for d in detections:
            RecordingDetector.made[id(d)] = frame.T_odom_cam.copy()
            RecordingDetector.kept.append(d)
        return detections


class RecordingSlam(OdometrySlam):
    """Remembers every detection it is handed and the camera pose it is handed with."""

    fed: list[tuple[int, np.ndarray]] = []
    loop_closures = 0

    def add_detections(self, odom, T_body_cam, detections):
        RecordingSlam.fed += [(id(d), odom.T_odom_body @ T_body_cam) for d in detections]
        super().add_detections(odom, T_body_cam, detections)

    def try_loop_closure(self, odom, T_body_cam, detections):
        RecordingSlam.loop_closures += 1
        RecordingSlam.fed += [(id(d), odom.T_odom_body @ T_body_cam) for d in detections]
        return super().try_loop_closure(odom, T_body_cam, detections)


class Plugin:
    @amslam.hookimpl
    def amslam_slam_backends(self):
        return {"recording": RecordingSlam}

    @amslam.hookimpl
    def amslam_detector_backends(self):
        return {"recording": RecordingDetector}


def test_each_detection_reaches_slam_once_at_its_own_pose(tmp_path):
    registry = build_plugin_manager(extra_plugins=[Plugin()])
    path = small_mission(tmp_path, max_time=45)
    text = path.read_text().replace("slam: {plugin: odometry}", "slam: {plugin: recording}")
    path.write_text(text.replace("detector: {plugin: sim}", "detector: {plugin: recording}"))
    # SLC on: the flight ends with a panorama at home and a loop-closure attempt after it
    mission = load_mission(path, registry, overrides=["exploration.slc=true"])
    result = Runner(mission, registry, tmp_path / "runs").run()
    assert result.verdict == "completed", result.verdict
    assert RecordingSlam.loop_closures >= 1 and RecordingDetector.made
    ids = [i for i, _ in RecordingSlam.fed]
    assert sorted(ids) == sorted(RecordingDetector.made), "a detection was fed twice, or never"
    for i, T_odom_cam in RecordingSlam.fed:
        np.testing.assert_allclose(T_odom_cam, RecordingDetector.made[i], atol=1e-9)
