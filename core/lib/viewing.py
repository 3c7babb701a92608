"""Where a sensor sees an object from: an object's yaw from its shape parameters, and the viewing
angle between the object's forward axis and the sensor (paper 2's uncertainty models depend on the
range and this angle, §IV-C).
"""

from __future__ import annotations

import math

import numpy as np

from amslam.geometry import wrap_angle


def viewing_angle(object_position: np.ndarray, object_yaw_rad: float, sensor: np.ndarray) -> float:
    """Horizontal angle in [0, π] between the object's forward axis and the direction to the sensor.

    0 = the sensor is in front of the object, π/2 = beside it, π = behind it.
    """
    d = np.asarray(sensor, float)[:2] - np.asarray(object_position, float)[:2]
    return abs(wrap_angle(math.atan2(d[1], d[0]) - object_yaw_rad))


def object_yaw(shape: dict | None) -> float:
    """Yaw of an object's frame from its shape parameters (0 = world axes, e.g. procedural boxes).

    Understands ``yaw``, a 3×3 ``rotation``/``R`` matrix and a ``rotvec``/``r`` rotation vector.
    A cylinder has no forward axis: its yaw is 0 and its models should not depend on the angle.
    """
    if not shape:
        return 0.0
    if "yaw" in shape:
        return float(shape["yaw"])
    for key in ("rotation", "R"):
        if key in shape:
            R = np.asarray(shape[key], float).reshape(3, 3)
            return math.atan2(R[1, 0], R[0, 0])
    for key in ("rotvec", "r"):
        if key in shape:
            from scipy.spatial.transform import Rotation

            R = Rotation.from_rotvec(np.asarray(shape[key], float).reshape(3)).as_matrix()
            return math.atan2(R[1, 0], R[0, 0])
    return 0.0
