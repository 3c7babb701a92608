"""Small SE(3) helpers on 4×4 numpy arrays (the interface representation of poses)."""

from __future__ import annotations

import numpy as np


def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle (or an array of angles) to (-π, π]; a float for a scalar, an array for an array.

    The one angle-wrapping helper of the project: every module imports this one.
    """
    w = np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)
    return float(w) if np.ndim(w) == 0 else w


def yaw_matrix(yaw: float) -> np.ndarray:
    """The 3×3 rotation about the vertical axis by ``yaw`` (rad)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def skew(v: np.ndarray) -> np.ndarray:
    """The 3×3 cross-product matrix ``[v]×`` (``[v]× u = v × u``)."""
    x, y, z = np.asarray(v, float).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def yaw_of(T: np.ndarray) -> float:
    """Heading of a pose: the angle of its x axis projected on the horizontal plane."""
    return float(np.arctan2(T[1, 0], T[0, 0]))


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
    from scipy.spatial.transform import Rotation  # scipy.spatial costs 0.2 s: imported when a run writes

    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x, y, z, w
    x, y, z = T[:3, 3]
    return f"{stamp:.6f} {x:.6f} {y:.6f} {z:.6f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n"
