"""Shared fixtures: random registration instances and a driven synthetic loop."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.interfaces import RunContext
from amslam.plugins.gtsam_slam.backend import GtsamSlam
from amslam.plugins.gtsam_slam.synthetic import LoopWorld, camera_mount, make_instance  # noqa: F401


def configured(**params: object) -> GtsamSlam:
    slam = GtsamSlam()
    slam.configure(GtsamSlam.Params(**params), RunContext(rng=np.random.default_rng(7), run_dir=Path(".")))
    return slam


def drive_loop(seed: int = 0, slam: GtsamSlam | None = None, **world: float) -> tuple[GtsamSlam, LoopWorld]:
    """Panorama at the start, one drifting loop with detections every metre; back at the start.

    The yaw bias makes VIO end about 1.4 m (3.5 %) off after the 40 m loop: beyond the front end's
    association gate, inside semantic loop closure's drift bound (0.4 m + 3 % of the travel).
    """
    w = LoopWorld.rectangle(np.random.default_rng(seed), **({"yaw_bias_per_m": 0.005} | world))
    slam = slam or configured()
    Tc = camera_mount()
    slam.add_odometry(w.odometry())
    for T in w.panorama():
        w.move_to(T)
        slam.add_odometry(w.odometry())
        slam.add_detections(w.odometry(), Tc, w.detect())
    for k, T in enumerate(w.loop_path()):
        w.move_to(T)
        slam.add_odometry(w.odometry())
        if k % 5 == 4:
            slam.add_detections(w.odometry(), Tc, w.detect())
    return slam, w


@pytest.fixture(scope="module")
def looped() -> tuple[GtsamSlam, LoopWorld]:
    return drive_loop(0)
