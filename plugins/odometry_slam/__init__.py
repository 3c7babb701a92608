"""``odometry`` SLAM backend: dead reckoning on VIO, the world frame is the odometry frame.

It is the baseline every SLAM backend is measured against (what the robot knows without loop
closure), and the backend to use when objects are irrelevant. Key poses are kept every
``keypose_distance`` metres so the run's ``slam.tum`` has the same shape as a real backend's.
Detections are placed into the world with the VIO pose and merged by nearest neighbour per class,
so the semantic map still exists (without any correction).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

import amslam
from amslam.geometry import wrap_angle, yaw_of
from amslam.interfaces import BackendParams, RunContext, Slam
from amslam.types import Detection, KeyPose, Landmark, Odometry


class OdometrySlam(Slam):
    """World = odometry: no correction, landmarks placed with the VIO pose."""

    class Params(BackendParams):
        keypose_distance: float = Field(0.5, gt=0, le=100, description="a key pose every this many metres")
        keypose_yaw: float = Field(0.5, gt=0, le=math.pi, description="or every this much yaw change, rad")
        association_gate: float = Field(1.0, gt=0, le=100, description="max distance to merge a detection, m")

    def __init__(self) -> None:
        self._keyposes: list[KeyPose] = []
        self._distance = 0.0
        self._last: np.ndarray | None = None
        self._sums: list[np.ndarray] = []
        self._counts: list[int] = []
        self._classes: list[str] = []
        self._first: list[int] = []

    def configure(self, params: Params, context: RunContext) -> None:
        self.params = params

    def add_odometry(self, odom: Odometry) -> bool:
        T = odom.T_odom_body
        if self._last is not None:
            self._distance += float(np.linalg.norm(T[:3, 3] - self._last[:3, 3]))
        self._last = T
        if self._keyposes:
            ref = self._keyposes[-1]
            moved = self._distance - ref.distance
            turned = abs(wrap_angle(yaw_of(T) - yaw_of(ref.T_world_body)))
            if moved < self.params.keypose_distance and turned < self.params.keypose_yaw:
                return False
        self._keyposes.append(KeyPose(len(self._keyposes), odom.stamp, T.copy(), self._distance))
        return True

    def add_detections(self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]) -> None:
        T_world_cam = odom.T_odom_body @ T_body_cam
        for det in detections:
            p = T_world_cam[:3, :3] @ det.centroid_cam + T_world_cam[:3, 3]
            best, best_d = -1, self.params.association_gate
            for i, cls in enumerate(self._classes):
                if cls != det.class_name:
                    continue
                d = float(np.linalg.norm(self._sums[i] / self._counts[i] - p))
                if d < best_d:
                    best, best_d = i, d
            if best < 0:
                self._sums.append(p.copy())
                self._counts.append(1)
                self._classes.append(det.class_name)
                self._first.append(len(self._keyposes) - 1)
            else:
                self._sums[best] += p
                self._counts[best] += 1

    def T_world_odom(self) -> np.ndarray:
        return np.eye(4)

    def keyposes(self) -> list[KeyPose]:
        return list(self._keyposes)

    def landmarks(self) -> list[Landmark]:
        return [
            Landmark(i, c, s / n, np.full((3, 3), np.nan), n, f)
            for i, (c, s, n, f) in enumerate(
                zip(self._classes, self._sums, self._counts, self._first, strict=True)
            )
        ]


@amslam.hookimpl
def amslam_slam_backends():
    return {"odometry": OdometrySlam}
