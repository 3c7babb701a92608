"""The platform on its own against the emulator: idempotent actions, frames over the wire, camera."""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from amslam.errors import PlatformError
from amslam.geometry import yaw_of
from amslam.interfaces import RunContext
from amslam.plugins.mavsdk_platform.camera_sources import CameraSourceParams, make_camera_source
from amslam.plugins.mavsdk_platform.platform import MavsdkPlatform
from amslam.types import RobotSpec


def _platform(url: str, tmp_path: Path, **params) -> tuple[MavsdkPlatform, list]:
    log: list = []
    platform = MavsdkPlatform()
    context = RunContext(
        rng=np.random.default_rng(0),
        run_dir=tmp_path,
        emit=lambda name, **f: log.append((name, f)),
        robot=RobotSpec(altitude=1.0),
        mission_dir=tmp_path,
    )
    platform.configure(MavsdkPlatform.Params(url=url, land_timeout=5.0, **params), context)
    return platform, log


def _until(platform: MavsdkPlatform, condition: Callable[[], bool], limit: float = 20.0) -> None:
    """Tick the platform until the condition holds (fails after ``limit`` seconds of ticks)."""
    start = platform.time()
    while not condition():
        assert platform.time() - start < limit, "condition not reached"
        platform.advance(0.05)


def test_actions_are_idempotent_and_setpoints_land_in_enu(make_peer, tmp_path):
    peer, url = make_peer()
    platform, log = _platform(url, tmp_path)
    platform.start()
    try:
        assert not platform.status().armed and not platform.status().airborne
        platform.arm_and_takeoff(1.0)
        platform.arm_and_takeoff(1.0)  # while the first is under way
        _until(platform, lambda: platform.status().airborne and platform.odometry().T_odom_body[2, 3] > 0.95)
        platform.arm_and_takeoff(1.0)  # already flying
        assert [name for _, name, _ in peer.commands].count("arm") == 1
        assert [name for _, name, _ in peer.commands].count("takeoff") == 1

        platform.set_setpoint(np.array([1.0, -0.5, 1.2]), 0.0)  # 1 m east, 0.5 m south, facing east
        _until(
            platform, lambda: np.linalg.norm(platform.odometry().T_odom_body[:3, 3] - [1.0, -0.5, 1.2]) < 0.05
        )
        _until(platform, lambda: abs(yaw_of(platform.odometry().T_odom_body)) < 0.02)
        truth = peer.trace[-1]
        assert np.allclose(truth.position, [-0.5, 1.0, -1.2], atol=0.06)  # NED: north, east, down
        assert math.isclose(truth.yaw, math.pi / 2, abs_tol=0.03)  # east is 90° in NED

        platform.land()
        platform.land()
        _until(platform, lambda: not platform.status().airborne)
        _until(platform, lambda: not platform.status().armed)
        platform.land()  # on the ground: nothing to do
        assert [name for _, name, _ in peer.commands].count("land") == 1
        assert platform.failsafe() is None
        names = [name for name, _ in log]
        assert names.index("command_accepted") < names.index("touchdown")
    finally:
        platform.close()
        platform.close()
    assert peer.trace[-1].landed and not peer.trace[-1].armed


def test_start_refuses_with_the_reason(make_peer, tmp_path):
    _, url = make_peer(battery=0.2)
    platform, log = _platform(url, tmp_path)
    try:
        with pytest.raises(
            PlatformError, match=r"pre-flight check refused the flight: battery: 20 % \(< 50 %\)"
        ):
            platform.start()
    finally:
        platform.close()
    assert ("preflight", {"check": "battery", "ok": False, "detail": "20 % (< 50 %)"}) in log


@pytest.mark.parametrize(
    ("params", "field", "match"),
    [
        ({"battery_return": 0.6}, "battery_return", r"0.6 must not be above battery_min_start \(0.5\)"),
        ({"battery_land": 0.4}, "battery_land", r"0.4 must not be above battery_return \(0.3\)"),
    ],
)
def test_battery_thresholds_must_be_ordered_when_validated(params, field, match):
    with pytest.raises(ValidationError, match=match) as caught:
        MavsdkPlatform.Params(**params)
    assert caught.value.errors()[0]["ctx"]["error"].field == field


def test_replay_camera_source(tmp_path):
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    for i in range(2):
        np.savez(tmp_path / f"{i:03d}.npz", depth=np.full((48, 64), 1.0 + i, np.float32), K=K)
    params = CameraSourceParams(source="replay", folder=".", rate_hz=1000.0, mount_pitch_deg=10.0)
    source = make_camera_source(params, tmp_path)
    model = source.open()
    assert (model.width, model.height) == (64, 48) and np.allclose(model.K, K)
    optical_axis = model.T_body_cam[:3, 2]  # camera z in the body: forward, tilted down
    assert np.allclose(optical_axis, [math.cos(math.radians(10)), 0.0, -math.sin(math.radians(10))])
    first = source.read()
    time.sleep(0.005)  # past the 1 ms frame period
    second = source.read()
    time.sleep(0.005)
    assert first.depth[0, 0] == 1.0 and second.depth[0, 0] == 2.0 and first.stamp < second.stamp
    assert source.read() is None  # played out


def test_realsense_without_its_sdk_says_what_to_install(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # not installed
    source = make_camera_source(CameraSourceParams(source="realsense"), tmp_path)
    with pytest.raises(PlatformError, match=re.escape("pip install 'amslam[realsense]'")):
        source.open()


@pytest.mark.parametrize(
    ("position", "yaw"),
    [([1.0, float("nan"), 1.2], 0.0), ([1.0, 0.0, 1.2], float("nan"))],
    ids=["nan_position", "nan_yaw"],
)
def test_a_setpoint_that_is_not_finite_is_refused_and_lands(make_peer, tmp_path, position, yaw):
    """No geofence configured: the NaN is still refused at the platform, which raises a landing
    failsafe (the mission tree's failsafe guard answers it, as here)."""
    peer, url = make_peer()
    platform, log = _platform(url, tmp_path)
    platform.start()
    try:
        platform.arm_and_takeoff(1.0)
        _until(platform, lambda: platform.status().airborne and platform.odometry().T_odom_body[2, 3] > 0.95)
        platform.set_setpoint(np.array(position), yaw)
        failsafe = platform.failsafe()
        assert failsafe is not None and failsafe.kind == "bad_setpoint" and failsafe.action == "land"
        assert "is not finite: not sent" in failsafe.reason
        platform.land()
        _until(platform, lambda: not platform.status().armed)
        assert all(np.all(np.isfinite(p.position)) for p in peer.trace)
    finally:
        platform.close()
    assert peer.trace[-1].landed and not peer.trace[-1].armed
    assert [name for name, _ in log].count("failsafe") == 1
