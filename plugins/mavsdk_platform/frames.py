"""The one place where PX4's NED/FRD conventions meet amslam's ENU/FLU ones.

PX4 (and MAVLink's ``LOCAL_POSITION_NED``, ``ATTITUDE``, ``SET_POSITION_TARGET_LOCAL_NED``)
uses a local **NED** frame (x north, y east, z down) and an **FRD** body (x forward, y right,
z down); yaw is measured from north, clockwise seen from above. amslam's odometry frame is
**ENU** (x east, y north, z up) with an **FLU** body (x forward, y left, z up); yaw is measured
from east, counter-clockwise (see :mod:`amslam.types`).

The odometry frame of the ``mavsdk`` platform *is* PX4's local frame, re-expressed in ENU: same
origin (the autopilot's local origin, e.g. where its estimator started), axes swapped. So

* position: ``p_enu = (e, n, -d)``, ``p_ned = (y, x, -z)``;
* yaw: ``yaw_enu = π/2 − yaw_ned`` (north-facing is yaw_ned 0, yaw_enu π/2);
* rotation: ``R_enu_flu = R_ENU_NED · R_ned_frd · R_FRD_FLU``.

Nothing else in the plugin converts frames: everything goes through these functions.
"""

from __future__ import annotations

import math

import numpy as np

from amslam.geometry import wrap_angle

#: Rotation taking NED vectors to ENU (a swap of x and y and a flip of z; its own inverse).
R_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Rotation taking FLU body vectors to FRD (flip y and z; its own inverse).
R_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def ned_to_enu(p_ned: np.ndarray) -> np.ndarray:
    """A position or velocity from NED to ENU."""
    p = np.asarray(p_ned, float)
    return np.array([p[1], p[0], -p[2]])


def enu_to_ned(p_enu: np.ndarray) -> np.ndarray:
    """A position or velocity from ENU to NED."""
    p = np.asarray(p_enu, float)
    return np.array([p[1], p[0], -p[2]])


def yaw_ned_to_enu(yaw_ned: float) -> float:
    """Heading from north-clockwise (PX4) to east-counter-clockwise (amslam), radians."""
    return wrap_angle(math.pi / 2.0 - yaw_ned)


def yaw_enu_to_ned(yaw_enu: float) -> float:
    """Heading from east-counter-clockwise (amslam) to north-clockwise (PX4), radians."""
    return wrap_angle(math.pi / 2.0 - yaw_enu)


def rotation_ned_frd(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``R_ned_frd`` of PX4 Euler angles (3-2-1 intrinsic Tait-Bryan: yaw, then pitch, then roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return Rz @ Ry @ Rx


def pose_enu_from_ned(position_ned: np.ndarray, roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``T_odom_body`` (ENU/FLU, 4×4) of a PX4 local position and attitude (NED/FRD, radians)."""
    T = np.eye(4)
    T[:3, :3] = R_ENU_NED @ rotation_ned_frd(roll, pitch, yaw) @ R_FRD_FLU
    T[:3, 3] = ned_to_enu(position_ned)
    return T
