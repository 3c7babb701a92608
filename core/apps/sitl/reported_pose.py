"""The pose an autopilot reports over MAVLink, in the world frame: what a camera for PX4 SITL renders at.

PX4 SITL (``make px4_sitl …``) flies a vehicle with no depth camera for amslam. ``amslam sitl
MISSION --camera-only URL`` gives it one: it listens to the vehicle's MAVLink on ``URL`` (PX4 SITL
sends its ground-station stream to UDP 14550), reads ``LOCAL_POSITION_NED`` and ``ATTITUDE``, and
renders the mission's world at that pose, taken into the world by ``platform.world_from_local``
(where the autopilot's local origin stands in the world, and its heading). The reported pose is
the autopilot's estimate; in SITL, with simulated GPS or vision, it is close to the truth, which
is all a camera stand-in needs (``amslam sitl``'s own vehicle renders at its true pose instead).

Written by hand on pymavlink, not MAVSDK: MAVSDK's telemetry is one client per vehicle, and amslam
fly is that client; this is a second listener on the ground-station stream, which pymavlink reads
as it comes.
"""

from __future__ import annotations

import threading
import time
from urllib.parse import urlsplit

import numpy as np

from amslam.errors import AmslamError
from amslam.plugins.mavsdk_platform.frames import pose_enu_from_ned

#: HEARTBEAT base_mode bit of an armed vehicle (MAV_MODE_FLAG_SAFETY_ARMED)
ARMED_FLAG = 128
#: MAV_TYPE_GCS: heartbeats of ground stations (and of amslam's MAVSDK) are not the vehicle's
MAV_TYPE_GCS = 6


def pymavlink_address(url: str) -> str:
    """``udpin://HOST:PORT`` (as in missions) → pymavlink's ``udpin:HOST:PORT``."""
    parts = urlsplit(url)
    if parts.scheme not in ("udpin", "udp") or parts.port is None:
        raise AmslamError(
            f"--camera-only {url!r}: give the UDP port the autopilot sends its MAVLink to as"
            " udpin://HOST:PORT (PX4 SITL's ground-station stream: udpin://0.0.0.0:14550)"
        )
    return f"udpin:{parts.hostname or '0.0.0.0'}:{parts.port}"


class ReportedPose:
    """A thread listening to a vehicle's MAVLink; :meth:`pose` is its latest pose in the world.

    Args:
        url: ``udpin://HOST:PORT`` the autopilot sends to.
        T_world_local: the autopilot's local frame (ENU) in the world.
    """

    def __init__(self, url: str, T_world_local: np.ndarray):
        from pymavlink import mavutil

        self.T_world_local = np.asarray(T_world_local, float)
        try:
            self._link = mavutil.mavlink_connection(pymavlink_address(url), source_system=250)
        except OSError as exc:
            raise AmslamError(f"--camera-only {url}: cannot listen there ({exc.strerror or exc})") from None
        self._lock = threading.Lock()
        self._position: np.ndarray | None = None  # NED, m
        self._attitude = (0.0, 0.0, 0.0)  # roll, pitch, yaw (NED/FRD), rad
        self._stamp = 0.0  # time.monotonic() of the latest position
        self.armed = False
        self.was_armed = False
        self.positions = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._listen, name="sitl-reported-pose", daemon=True)

    def start(self) -> ReportedPose:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._link.close()

    def pose(self) -> tuple[float, np.ndarray]:
        """(monotonic time it was heard, ``T_world_body``) of the latest reported pose."""
        with self._lock:
            position, attitude, stamp = self._position, self._attitude, self._stamp
        if position is None:
            return time.monotonic(), self.T_world_local.copy()
        return stamp, self.T_world_local @ pose_enu_from_ned(position, *attitude)

    def _listen(self) -> None:
        while not self._stop.is_set():
            msg = self._link.recv_match(
                type=["LOCAL_POSITION_NED", "ATTITUDE", "HEARTBEAT"], blocking=True, timeout=0.2
            )
            if msg is None:
                continue
            kind = msg.get_type()
            with self._lock:
                if kind == "LOCAL_POSITION_NED":
                    self._position = np.array([msg.x, msg.y, msg.z], float)
                    self._stamp = time.monotonic()
                    self.positions += 1
                elif kind == "ATTITUDE":
                    self._attitude = (float(msg.roll), float(msg.pitch), float(msg.yaw))
                elif msg.type != MAV_TYPE_GCS and msg.get_srcComponent() == 1:
                    self.armed = bool(msg.base_mode & ARMED_FLAG)
                    self.was_armed = self.was_armed or self.armed
