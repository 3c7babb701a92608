"""The odometry model's drift along a path agrees with the random walks it is made of."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.types import OdometryNoise

NOISE = OdometryNoise(
    translation=0.05,
    vertical=0.012,
    translation_min=0.005,
    yaw=0.004,
    yaw_per_rad=0.01,
    yaw_min=0.002,
    roll_pitch=0.002,
)


def _square_twice(side: float = 8.0, step: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Key poses every ``step`` round a square flown twice (turning 90° in place at each corner)."""
    positions, yaws = [], []
    corners = np.array([[0, 0], [side, 0], [side, side], [0, side]], float)
    for lap in range(2):
        for c in range(4):
            a, b = corners[c], corners[(c + 1) % 4]
            yaw = np.pi / 2 * (c + 4 * lap)  # unwrapped: every corner turns +90°
            n = round(side / step)
            for i in range(n):
                positions.append([*(a + (b - a) * i / n), 1.5])
                yaws.append(yaw)
    positions.append([0.0, 0.0, 1.5])
    yaws.append(yaws[-1])
    P = np.array(positions)
    return P, np.array(yaws), np.append(0.0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1)))


def _sampled_drift(
    P: np.ndarray, Y: np.ndarray, D: np.ndarray, start: int, n: int = 4000
) -> tuple[float, float]:
    """Monte Carlo: chain the noisy steps from pose ``start``; the end's mean squared error and yaw's."""
    rng = np.random.default_rng(3)
    sig = NOISE.sigmas_of_steps(np.diff(D), np.diff(Y))
    pos = np.tile(P[start], (n, 1))
    yaw = np.full(n, Y[start])
    for k in range(start, len(P) - 1):
        # The true step in pose k's frame, composed with noise in pose k+1's frame (gtsam's between factor).
        c, s = np.cos(Y[k]), np.sin(Y[k])
        d = P[k + 1] - P[k]
        local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]])
        dyaw = Y[k + 1] - Y[k]
        pos[:, 0] += np.cos(yaw) * local[0] - np.sin(yaw) * local[1]
        pos[:, 1] += np.sin(yaw) * local[0] + np.cos(yaw) * local[1]
        pos[:, 2] += local[2]
        yaw = yaw + dyaw + rng.normal(0, sig[k, 2], n)
        e = rng.normal(0, 1, (n, 3)) * sig[k, 3:]
        pos[:, 0] += np.cos(yaw) * e[:, 0] - np.sin(yaw) * e[:, 1]
        pos[:, 1] += np.sin(yaw) * e[:, 0] + np.cos(yaw) * e[:, 1]
        pos[:, 2] += e[:, 2]
    return float(np.mean(np.sum((pos - P[-1]) ** 2, axis=1))), float(np.mean((yaw - Y[-1]) ** 2))


@pytest.mark.parametrize("start", [0, 40, 100])
def test_drift_to_end_matches_the_sampled_random_walks(start: int) -> None:
    P, Y, D = _square_twice()
    position_var, yaw_var = NOISE.drift_to_end(P, Y, D)
    sampled_position, sampled_yaw = _sampled_drift(P, Y, D, start)
    assert position_var[start] == pytest.approx(sampled_position, rel=0.1)
    assert yaw_var[start] == pytest.approx(sampled_yaw, rel=0.1)
    assert position_var[-1] == 0.0 and yaw_var[-1] == 0.0


def test_drift_grows_like_a_random_walk_not_like_the_travel() -> None:
    # Two laps of the square: 64 m; from the start the yaw walk's sweep is bounded by the square's size,
    # so the end's std grows about like √travel: twice the travel, well under twice the std.
    P, Y, D = _square_twice()
    position_var, _ = NOISE.drift_to_end(P, Y, D)
    half = len(P) // 2
    assert np.sqrt(position_var[0]) < 1.6 * np.sqrt(position_var[half])
    assert np.all(np.diff(position_var) <= 1e-12)  # less drift the later the pose it is relative to


def test_sigmas_of_steps_is_sigmas_per_step() -> None:
    d, y = np.array([0.0, 0.1, 0.5, 3.0]), np.array([0.0, -0.3, 0.2, 1.0])
    np.testing.assert_array_equal(
        NOISE.sigmas_of_steps(d, y), [NOISE.sigmas(a, b) for a, b in zip(d, y, strict=True)]
    )
