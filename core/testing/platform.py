"""Contract tests for platforms: clock, take-off, setpoints, frames, landing — on a simulated vehicle.

    from amslam.testing.platform import PlatformContract

    class TestMyPlatform(PlatformContract):
        def make_backend(self):
            return MyPlatform()

        def make_params(self, backend):
            return MyPlatform.Params(...)   # a small world / a SITL connection

The tests fly for a few tens of seconds of platform time, so run them against a simulated platform
(or a real vehicle's software-in-the-loop simulator): on a real one ``advance`` waits in wall-clock
time. Every manoeuvre stays within 0.5 m of the take-off point, above it, so any world with room
to take off is safe.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.geometry import wrap_angle, yaw_of
from amslam.interfaces import Platform, RunContext
from amslam.testing.contract import BackendContract
from amslam.testing.slam import is_rigid
from amslam.types import CameraModel, Frame, Odometry, RobotSpec, VehicleStatus

ALTITUDE = 1.0
DT = 0.1


def advance_until(platform: Platform, done, t_max: float) -> bool:
    """Advance in ``DT`` steps until ``done()`` is true or ``t_max`` seconds of platform time passed."""
    t0 = platform.time()
    while platform.time() - t0 < t_max:
        platform.advance(DT)
        if done():
            return True
    return bool(done())


class PlatformContract(BackendContract):
    """Mix-in of platform contract tests; override :meth:`make_backend` (and :meth:`make_params`)."""

    kind = Platform
    #: Position error accepted after a manoeuvre settles (m), and heading error (rad).
    position_tolerance: float = 0.15
    yaw_tolerance: float = 0.1

    def make_context(self, tmp_path: Path, *, seed: int = 0) -> RunContext:
        """Platforms are configured before any camera exists: ``context.camera`` is None."""
        return RunContext(rng=np.random.default_rng(seed), run_dir=Path(tmp_path), robot=RobotSpec())

    @pytest.fixture
    def started(self, backend: Platform) -> Platform:
        backend.start()
        return backend

    @pytest.fixture
    def airborne(self, started: Platform) -> tuple[Platform, np.ndarray]:
        """Taken off to ``ALTITUDE`` and hovering; also the odometry position before take-off.

        "Above the start" may be read from the ground or from the landed body (a landed body sits
        a radius above the ground), so the climb must end between ALTITUDE - 0.5 m and ALTITUDE.
        """
        before = started.odometry().T_odom_body[:3, 3].copy()
        started.arm_and_takeoff(ALTITUDE)
        climb = lambda: started.odometry().T_odom_body[2, 3] - before[2]  # noqa: E731
        assert advance_until(started, lambda: climb() > ALTITUDE - 0.5, 20.0), "no take-off within 20 s"
        advance_until(started, lambda: False, 5.0)  # let it settle
        assert ALTITUDE - 0.5 < climb() <= ALTITUDE + self.position_tolerance, f"climbed {climb():.2f} m"
        status = started.status()
        assert status.armed and status.airborne and not status.crashed
        return started, before

    def _settle(self, platform: Platform, goal: np.ndarray, yaw: float, t_max: float = 20.0) -> bool:
        def there() -> bool:
            T = platform.odometry().T_odom_body
            return (
                np.linalg.norm(T[:3, 3] - goal) < self.position_tolerance
                and abs(wrap_angle(yaw_of(T) - yaw)) < self.yaw_tolerance
            )

        return advance_until(platform, there, t_max)

    def test_camera_after_configure(self, backend: Platform) -> None:
        cam = backend.camera
        assert isinstance(cam, CameraModel)
        assert cam.width > 0 and cam.height > 0 and cam.K.shape == (3, 3) and cam.rate_hz > 0
        assert is_rigid(cam.T_body_cam) and 0 < cam.min_range < cam.max_range

    def test_landed_at_start(self, started: Platform) -> None:
        status = started.status()
        assert isinstance(status, VehicleStatus)
        assert not status.armed and not status.airborne and not status.crashed
        odom = started.odometry()
        assert isinstance(odom, Odometry) and is_rigid(odom.T_odom_body)

    def test_clock_advances(self, started: Platform) -> None:
        t0 = started.time()
        started.advance(0.5)
        t1 = started.time()
        assert t1 - t0 >= 0.5 - 1e-9
        if started.simulated:
            assert t1 - t0 == pytest.approx(0.5)

    def test_takeoff_is_idempotent(self, airborne) -> None:
        platform, _ = airborne
        hover = platform.odometry().T_odom_body.copy()
        platform.arm_and_takeoff(ALTITUDE)  # already up: nothing changes
        assert self._settle(platform, hover[:3, 3], yaw_of(hover))
        advance_until(platform, lambda: False, 2.0)
        assert np.linalg.norm(platform.odometry().T_odom_body[:3, 3] - hover[:3, 3]) < self.position_tolerance
        assert not platform.status().crashed

    def test_setpoints_are_tracked(self, airborne) -> None:
        platform, _ = airborne
        yaw = wrap_angle(yaw_of(platform.odometry().T_odom_body) + 0.6)
        goal = platform.odometry().T_odom_body[:3, 3] + np.array([0.0, 0.0, 0.3])
        platform.set_setpoint(goal, yaw)
        assert self._settle(platform, goal, yaw), "setpoint (0.3 m up, 0.6 rad left) not reached in 20 s"
        assert not platform.status().crashed

    def test_frames_arrive_at_the_camera_rate(self, airborne) -> None:
        platform, _ = airborne
        cam = platform.camera
        frames: list[tuple[Frame, Odometry]] = []
        t0 = platform.time()
        while platform.time() - t0 < 2.0:
            platform.advance(DT)
            frame = platform.capture()
            if frame is not None:
                frames.append((frame, platform.odometry()))
        expected = 2.0 * cam.rate_hz
        assert 0.5 * expected <= len(frames) <= 1.5 * expected + 1
        stamps = [f.stamp for f, _ in frames]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
        for frame, odom in frames:
            assert frame.depth.shape == (cam.height, cam.width) and frame.depth.dtype == np.float32
            assert np.all(np.isfinite(frame.depth)) and np.all(frame.depth >= 0)
            np.testing.assert_allclose(frame.K, cam.K)
            assert is_rigid(frame.T_odom_cam)
            # the camera pose is the body pose (at most one step of motion earlier) times the mount
            expected_T = odom.T_odom_body @ cam.T_body_cam
            assert np.linalg.norm(frame.T_odom_cam[:3, 3] - expected_T[:3, 3]) < 0.2
            assert frame.stamp <= odom.stamp + 1e-9

    def test_land_is_idempotent(self, airborne) -> None:
        platform, before = airborne
        platform.land()
        platform.land()
        assert advance_until(platform, lambda: not platform.status().airborne, 30.0), (
            "still airborne after 30 s"
        )
        status = platform.status()
        assert not status.crashed
        assert abs(platform.odometry().T_odom_body[2, 3] - before[2]) < 0.2
        platform.land()  # landed already: nothing happens
        assert not platform.status().airborne

    def test_same_seed_same_flight(self, tmp_path: Path) -> None:
        trajectories = []
        for _ in range(2):
            platform = self.configured(tmp_path, seed=11)
            if not platform.simulated:
                pytest.skip("only a simulated platform repeats itself")
            platform.start()
            platform.arm_and_takeoff(ALTITUDE)
            poses = []
            for _ in range(30):
                platform.advance(DT)
                poses.append(platform.odometry().T_odom_body.copy())
            trajectories.append(np.array(poses))
            platform.close()
        np.testing.assert_allclose(trajectories[0], trajectories[1], atol=1e-12)
