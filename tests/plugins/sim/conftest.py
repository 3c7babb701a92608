"""Helpers for the simulator tests: small worlds and configured platforms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.interfaces import RunContext
from amslam.plugins.sim.platform import SimPlatform
from amslam.plugins.sim.world import WorldSpec, box_room
from amslam.types import RobotSpec

EXACT_CAMERA = {"width": 160, "height": 120, "depth_noise": 0.0, "dropout": 0.0, "grazing_dropout": 0.0}


def make_platform(
    tmp_path: Path,
    *,
    seed: int = 0,
    spec: WorldSpec | None = None,
    robot: RobotSpec | None = None,
    events: list | None = None,
    mission_dir: Path | None = None,
    **params,
) -> SimPlatform:
    """A configured and started SimPlatform (optionally in a custom world)."""
    plat = SimPlatform()
    ctx = RunContext(
        rng=np.random.default_rng(seed),
        run_dir=tmp_path,
        robot=robot or RobotSpec(),
        emit=(lambda name, **f: events.append((name, f))) if events is not None else (lambda *a, **k: None),
        mission_dir=mission_dir or tmp_path,
    )
    params.setdefault("camera", EXACT_CAMERA)
    plat.configure(SimPlatform.Params(**params), ctx)
    if spec is not None:
        plat.use_world(spec)
    plat.start()
    return plat


@pytest.fixture
def room_with_chair() -> WorldSpec:
    """A 10×8×3 m room with one chair-sized box 3 m in front of the start."""
    chair = ("chair_1", "chair", np.array([4.75, 3.75, 0.0]), np.array([5.25, 4.25, 0.9]))
    return box_room((10.0, 8.0, 3.0), [chair], start_xy=(2.0, 4.0))


def fly_to(
    plat: SimPlatform, goal: np.ndarray, yaw: float = 0.0, t_max: float = 60.0, dt: float = 0.1
) -> None:
    """Command a setpoint and advance until the VIO estimate reaches it (or t_max passes)."""
    plat.set_setpoint(np.asarray(goal, float), yaw)
    t0 = plat.time()
    while plat.time() - t0 < t_max:
        plat.advance(dt)
        if np.linalg.norm(plat.odometry().T_odom_body[:3, 3] - goal) < 0.02 or plat.status().crashed:
            break
