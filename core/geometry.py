"""Small SE(3) helpers on 4×4 numpy arrays (the interface representation of poses)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-π, π]."""
    return float(np.pi - (np.pi - a) % (2.0 * np.pi))


def yaw_of(T: np.ndarray) -> float:
    """Heading of a pose: the angle of its x axis projected on the horizontal plane."""
    return float(np.arctan2(T[1, 0], T[0, 0]))


def yaw_matrix(yaw: float) -> np.ndarray:
    """The 3×3 rotation by ``yaw`` about the vertical axis, ``R(ψ) = exp([ψ e3]×)``."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_from(position: np.ndarray, yaw: float = 0.0) -> np.ndarray:
    """A level pose at ``position`` with heading ``yaw``."""
    T = np.eye(4)
    T[:3, :3] = yaw_matrix(yaw)
    T[:3, 3] = position
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a rigid transform to N×3 points."""
    return points @ T[:3, :3].T + T[:3, 3]


def tum_line(stamp: float, T: np.ndarray) -> str:
    """One line of a TUM trajectory file: ``t tx ty tz qx qy qz qw``."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x, y, z, w
    x, y, z = T[:3, 3]
    return f"{stamp:.6f} {x:.6f} {y:.6f} {z:.6f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n"
