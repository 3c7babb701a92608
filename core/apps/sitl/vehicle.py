"""The SITL vehicle: the MAVLink emulator's protocol flying the simulator's vehicle in its world.

:class:`SitlVehicle` is :class:`~amslam.plugins.mavsdk_platform.emulator.MavlinkVehiclePeer`
(heartbeat, PX4 modes, command acks, offboard-loss landing, auto-disarm, battery) with its vehicle
model swapped: instead of the peer's point mass, a configured and started
:class:`~amslam.plugins.sim.platform.SimPlatform` moves — its kinematic multicopter with speed,
acceleration and yaw-rate limits, its VIO drift model and its collision check against the world.
As PX4 fed by a VIO does, the vehicle reports the **drifting estimate** as ``LOCAL_POSITION_NED``
and ``ATTITUDE`` and flies its setpoints on that estimate, so the true path carries the drift;
the truth stays here, in the :class:`~amslam.apps.sitl.record.TruthRecord`.

Frames: the autopilot's local frame is the world's axes (x east, y north, z up) with its origin at
the vehicle's landed start position, as PX4 SITL's local origin is its spawn point. So
``p_local = p_world − start`` and the simulator's odometry frame (the world frame, equal to the
truth at the start) maps to the local frame by the same translation.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from amslam.geometry import yaw_of
from amslam.plugins.mavsdk_platform.emulator import MavlinkVehiclePeer
from amslam.plugins.mavsdk_platform.frames import enu_to_ned, ned_to_enu, yaw_enu_to_ned, yaw_ned_to_enu
from amslam.plugins.sim.platform import SimPlatform


class SitlVehicle(MavlinkVehiclePeer):
    """A PX4-like vehicle over MAVLink whose motion, estimate and contacts are the simulator's.

    Args:
        sim: a started simulator platform (its world built, the vehicle landed at its start).
        record: where the truth goes (``truth(t, T_world_body, T_local_estimate)``, ``contact``).
        **peer: the emulator's own arguments (``connect_to``, ``rate_hz``, ``battery``, …).
    """

    def __init__(self, sim: SimPlatform, record: Any, **peer: Any):
        self.sim = sim
        self.record = record
        T = sim.ground_truth()
        self.origin = T[:3, 3].copy()  # world position of the local origin
        self.crashed = False
        super().__init__(yaw=yaw_enu_to_ned(yaw_of(T)), **peer)
        self._read_estimate()

    # -- frames --------------------------------------------------------------------------------

    def world_of_local_ned(self, p_ned: np.ndarray) -> np.ndarray:
        return self.origin + ned_to_enu(p_ned)

    def _read_estimate(self) -> np.ndarray:
        """Set the reported position and yaw from the simulator's VIO estimate; its local pose."""
        T_odom = self.sim.odometry().T_odom_body
        T_local = T_odom.copy()
        T_local[:3, 3] -= self.origin
        self.position = enu_to_ned(T_local[:3, 3])
        self.yaw = yaw_enu_to_ned(yaw_of(T_odom))
        return T_local

    # -- the vehicle model (see MavlinkVehiclePeer._move) --------------------------------------

    def _move(self, target: np.ndarray, yaw_target: float, vz_max: float, dt: float) -> bool:
        sim = self.sim
        if self.crashed:
            return True
        status = sim.status()
        if self.mode == "LAND":
            sim.land()  # the simulator descends onto what is below it and disarms (idempotent)
        elif not status.airborne:
            if target[2] < -0.05:  # asked up (take-off, or offboard from the ground)
                sim.arm_and_takeoff(float(-target[2]))
                sim.set_setpoint(self.world_of_local_ned(target), yaw_ned_to_enu(yaw_target))
        else:
            sim.set_setpoint(self.world_of_local_ned(target), yaw_ned_to_enu(yaw_target))
        before = self.position[2]
        sim.advance(dt)
        T_local = self._read_estimate()
        now = self.now()
        self.record.truth(now, sim.ground_truth(), T_local)
        status = sim.status()
        if status.crashed:
            self._contact(now, status.crash_reason)
        return bool(self.position[2] >= before - 1e-9)

    def _contact(self, now: float, reason: str) -> None:
        """Touching the world ends the flight: the motors stop (disarmed), as after a crash."""
        self.crashed = True
        self.record.contact(now, reason)
        self._note(f"contact: {reason}")
        self._mav.statustext_send(mavlink.MAV_SEVERITY_CRITICAL, f"contact: {reason}"[:50].encode())
        self.armed = False
        self._set_mode("LOITER")

    def _on_ground(self) -> bool:
        return self.crashed or not self.sim.status().airborne

    def _resting(self) -> bool:
        return self._on_ground()

    def true_pose(self) -> tuple[float, np.ndarray]:
        """(monotonic time, ``T_world_body``) now; taken under the vehicle's lock (camera thread)."""
        import time

        with self._lock:
            return time.monotonic(), self.sim.ground_truth()

    def truth(self) -> tuple[Any, np.ndarray]:
        """The simulator's status (contact, closest approach) and ``T_world_body``, under the lock
        (the vehicle's thread steps the simulator; the status names the closest surface lazily)."""
        with self._lock:
            return self.sim.status(), self.sim.ground_truth()

    def state(self) -> dict[str, Any]:
        """What the vehicle is doing, for the record and the console."""
        with self._lock:
            return {
                "mode": self.mode,
                "armed": self.armed,
                "landed": self.landed,
                "crashed": self.crashed,
                "battery": round(self.battery, 3),
                "estimate_local_enu": [round(float(x), 3) for x in ned_to_enu(self.position)],
                "yaw_enu": round(math.remainder(yaw_ned_to_enu(self.yaw), 2 * math.pi), 4),
            }
