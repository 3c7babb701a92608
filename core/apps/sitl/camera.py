"""The SITL's depth camera: frames rendered at the vehicle's true pose, sent over TCP.

A thread listens on ``host:port`` (the mission's ``platform.camera.host``/``port``) for amslam's
``stream`` camera source; while one is connected, it renders a frame at the camera rate with the
simulator's renderer (depth with the sensor's noise model, RGB, instance and class masks) at the
**true** camera pose and sends it with the intrinsics and the monotonic time the pose was sampled
at (:mod:`amslam.plugins.mavsdk_platform.camera_sources.stream`). amslam pairs it with the
*estimated* pose it heard nearest that time: exactly what a real camera and a VIO-fed autopilot
give it.

Thread rule: this thread takes the vehicle's pose under the vehicle's lock (a copy) and renders
outside it, so a render never holds up the vehicle's physics and telemetry. The world's Open3D
ray-casting scene is only read, by this thread and the vehicle's contact check: it is built and
committed (its first queries, choosing the start) before the threads start, and Open3D ≥ 0.18
commits with ``rtcJoinCommitScene``, so queries from several threads are supported (Open3D
issue #6050, PR #6051).
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time

import numpy as np

from amslam.plugins.mavsdk_platform.camera_sources.base import RgbdImage
from amslam.plugins.mavsdk_platform.camera_sources.stream import send_frame
from amslam.plugins.sim.camera import CameraParams, Renderer
from amslam.plugins.sim.world import World
from amslam.types import CameraModel


class CameraStreamer:
    """Renders and sends frames to one client at a time (see the module docstring)."""

    def __init__(
        self,
        world: World,
        camera: CameraModel,
        noise: CameraParams,
        true_pose,
        host: str,
        port: int,
        seed: int = 0,
    ):
        self.world = world
        self.camera = camera
        self.renderer = Renderer(camera, noise)
        self.true_pose = true_pose  # () -> (monotonic time, T_world_body)
        self.rng = np.random.default_rng(seed)
        self.server = socket.create_server((host, port))
        self.server.settimeout(0.2)
        self.address = f"{host}:{self.server.getsockname()[1]}"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames_sent = 0
        self.clients = 0
        self.render_seconds: list[float] = []

    def start(self) -> CameraStreamer:
        self._thread = threading.Thread(target=self._serve, name="sitl-camera", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.server.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.clients += 1
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._stream_to(conn)

    def _stream_to(self, conn: socket.socket) -> None:
        period = 1.0 / self.camera.rate_hz
        next_frame = time.monotonic()
        while not self._stop.is_set():
            delay = next_frame - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            next_frame = max(next_frame + period, time.monotonic() - period)  # late: no burst after
            stamp, T_world_body = self.true_pose()
            began = time.perf_counter()
            frame = self.renderer.render(self.world, T_world_body @ self.camera.T_body_cam, self.rng)
            self.render_seconds.append(time.perf_counter() - began)
            message = RgbdImage(
                stamp,
                frame.depth,
                self.camera.K,
                frame.rgb,
                frame.instance,
                frame.class_id,
                self.world.class_names,
            )
            try:
                send_frame(conn, message)
            except OSError:  # amslam went away: wait for the next one
                with contextlib.suppress(OSError):
                    conn.shutdown(socket.SHUT_RDWR)
                return
            self.frames_sent += 1

    def stats(self) -> dict:
        r = np.array(self.render_seconds or [np.nan])
        return {
            "address": self.address,
            "clients": self.clients,
            "frames_sent": self.frames_sent,
            "render_ms_mean": round(1000 * float(np.nanmean(r)), 1) if self.render_seconds else None,
            "render_ms_max": round(1000 * float(np.nanmax(r)), 1) if self.render_seconds else None,
        }
