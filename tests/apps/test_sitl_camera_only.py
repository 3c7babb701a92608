"""``amslam sitl --camera-only``: a depth camera for PX4 SITL, rendered at the pose it reports.

PX4 SITL flies a vehicle amslam has no camera for. The camera-only process listens to the
autopilot's ground-station MAVLink stream, takes its local pose into the world by
``platform.world_from_local`` and serves frames rendered there to ``amslam fly``'s ``stream``
source. The emulated PX4 of the platform tests stands in for PX4 SITL here (the same MAVLink).
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from amslam.apps.sitl.reported_pose import ReportedPose
from amslam.geometry import pose_from, yaw_of
from amslam.plugins.mavsdk_platform.camera_sources.stream import receive_frame
from amslam.plugins.mavsdk_platform.emulator import MavlinkVehiclePeer, free_udp_port

AMSLAM = Path(sys.executable).with_name("amslam")
BOUND = 60.0  # s; a bound on waits, never a measured time


def _until(condition, bound: float = BOUND) -> bool:
    deadline = time.monotonic() + bound
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return False


def test_the_reported_pose_is_the_autopilots_local_pose_taken_into_the_world():
    port = free_udp_port()
    T_world_local = pose_from(np.array([1.0, 2.0, 0.0]), np.pi / 2)  # local x (east) is world y
    reported = ReportedPose(f"udpin://127.0.0.1:{port}", T_world_local).start()
    peer = MavlinkVehiclePeer(also_to=(("127.0.0.1", port),), yaw=0.0)  # heading north (NED yaw 0)
    try:
        with peer:
            peer.position = np.array([1.0, 0.0, 0.0])  # 1 m north of the local origin, on the ground
            assert _until(lambda: np.allclose(reported.pose()[1][:3, 3], [0.0, 2.0, 0.0], atol=1e-6))
            stamp, T = reported.pose()
            assert yaw_of(T) == pytest.approx(np.pi)  # north in the local frame is world −x
            assert abs(time.monotonic() - stamp) < BOUND
            assert not reported.armed and not reported.was_armed
            peer.armed = True
            assert _until(lambda: reported.armed and reported.was_armed)
            peer.armed = False
            assert _until(lambda: not reported.armed) and reported.was_armed
    finally:
        reported.stop()


def test_camera_only_serves_frames_rendered_at_the_reported_pose(tmp_path):
    from amslam.apps.commands import load_with_registry
    from amslam.apps.sitl.camera import CameraStreamer
    from amslam.apps.sitl.run import _started_simulator

    mavlink_port = free_udp_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        camera_port = s.getsockname()[1]
    overrides = ["--set", f"platform.camera.port={camera_port}"]
    proc = subprocess.Popen(
        [AMSLAM, "sitl", "sitl_small", "--camera-only", f"udpin://127.0.0.1:{mavlink_port}", *overrides],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
    peer = MavlinkVehiclePeer(also_to=(("127.0.0.1", mavlink_port),), yaw=0.0)
    try:
        assert _until(lambda: any("frames on tcp" in line for line in lines)), "".join(lines)
        with peer, socket.create_connection(("127.0.0.1", camera_port), timeout=BOUND) as conn:
            peer.position = np.array([1.5, -0.5, 0.0])  # NED: 1.5 m north, 0.5 m west
            assert _until(lambda: any("hearing the vehicle" in line for line in lines)), "".join(lines)
            time.sleep(0.5)  # frames rendered before the move are in flight
            for _ in range(5):
                frame = receive_frame(conn)
            assert frame is not None
        # the same world, rendered here at the pose the vehicle reported
        args = SimpleNamespace(mission="sitl_small", set=[f"platform.camera.port={camera_port}"])
        mission, _ = load_with_registry(args)
        p = mission.backends["platform"].params
        sim, sim_params = _started_simulator(mission, p, tmp_path)
        start = sim.ground_truth()[:3, 3]
        T_world_body = pose_from(start + np.array([-0.5, 1.5, 0.0]), np.pi / 2)  # ENU: west, north
        here = CameraStreamer(sim.world, p.camera.nominal_model(), sim_params.camera, None, "127.0.0.1", 0)
        expected = here.renderer.render(
            sim.world, T_world_body @ here.camera.T_body_cam, np.random.default_rng(0)
        )
        here.server.close()
        sim.close()
        both = (frame.depth > 0) & (expected.depth > 0)
        assert both.mean() > 0.5
        assert np.median(np.abs(frame.depth[both] - expected.depth[both])) < 0.05  # sensor noise only
        assert np.array_equal(frame.instance > 0, expected.instance > 0) or (
            np.mean((frame.instance > 0) == (expected.instance > 0)) > 0.98
        )
    finally:
        proc.terminate()
        proc.wait(timeout=BOUND)
    assert any("frames sent" in line for line in lines), "".join(lines)
