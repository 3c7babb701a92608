"""ENU/FLU ↔ NED/FRD conversions: the one place the plugin converts frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from amslam.geometry import yaw_of
from amslam.plugins.mavsdk_platform.frames import (
    enu_to_ned,
    ned_to_enu,
    pose_enu_from_ned,
    yaw_enu_to_ned,
    yaw_ned_to_enu,
)


def test_positions_swap_axes_and_flip_up():
    assert ned_to_enu(np.array([1.0, 2.0, -3.0])).tolist() == [2.0, 1.0, 3.0]
    rng = np.random.default_rng(0)
    for p in rng.normal(size=(20, 3)):
        assert np.allclose(enu_to_ned(ned_to_enu(p)), p)


@pytest.mark.parametrize(
    ("yaw_ned", "yaw_enu"),
    [(0.0, math.pi / 2), (math.pi / 2, 0.0), (math.pi, -math.pi / 2), (-math.pi / 2, math.pi)],
)
def test_headings(yaw_ned, yaw_enu):
    """North is yaw_ned 0 and yaw_enu π/2; east is yaw_ned π/2 and yaw_enu 0."""
    assert math.isclose(yaw_ned_to_enu(yaw_ned), yaw_enu, abs_tol=1e-12)
    assert math.isclose(math.remainder(yaw_enu_to_ned(yaw_enu) - yaw_ned, 2 * math.pi), 0.0, abs_tol=1e-12)


def test_pose_axes():
    """Facing east, pitched nose-up: body x points east and up, body z (up) tilts west, in ENU."""
    T = pose_enu_from_ned(np.array([1.0, 2.0, -3.0]), 0.0, 0.2, math.pi / 2)
    R = T[:3, :3]
    assert np.allclose(T[:3, 3], [2.0, 1.0, 3.0])
    assert np.allclose(R @ R.T, np.eye(3)) and math.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R[:, 0], [math.cos(0.2), 0.0, math.sin(0.2)])  # forward: east and up
    assert R[0, 2] < 0 and R[2, 2] > 0.9  # up: mostly up, leaning back (west)
    assert math.isclose(yaw_of(T), 0.0, abs_tol=1e-12)


def test_roll_right_wing_down():
    """PX4 roll > 0 drops the right wing: the FLU left axis (y) points up."""
    T = pose_enu_from_ned(np.zeros(3), 0.3, 0.0, 0.0)  # facing north
    left = T[:3, 1]
    assert left[2] > 0 and math.isclose(left[2], math.sin(0.3))
