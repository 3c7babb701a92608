"""The VIO drift model against its own analytic covariance (paper 1, Table I calibration)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from amslam.geometry import wrap_angle
from amslam.plugins.sim.vio import VioParams, VioState, drift_covariance

from .conftest import fly_to, make_platform


def square_loop(side: float, step: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """A closed square loop (positions, yaws) sampled every ``step`` metres, turning at corners."""
    corners = np.array([[0, 0], [side, 0], [side, side], [0, side], [0, 0]], dtype=float)
    pts, yaws = [], []
    for a, b in zip(corners[:-1], corners[1:], strict=True):
        n = int(round(np.linalg.norm(b - a) / step))
        s = np.linspace(0, 1, n, endpoint=False)
        pts.append(a + s[:, None] * (b - a))
        yaws.append(np.full(n, np.arctan2(*(b - a)[::-1])))
    P = np.concatenate(pts + [corners[-1:]])
    P = np.column_stack([P, np.full(len(P), 1.5)])
    return P, np.concatenate(yaws + [yaws[0][:1]])


def fly_vio(P: np.ndarray, yaws: np.ndarray, p: VioParams, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    vio = VioState(position=P[0].copy(), yaw=float(yaws[0]))
    for i in range(1, len(P)):
        vio.step(P[i] - P[i - 1], float(wrap_angle(yaws[i] - yaws[i - 1])), float(yaws[i]), p, rng)
    return vio.position - P[-1]


def test_zero_noise_vio_is_exact():
    P, Y = square_loop(10.0)
    p = VioParams(sigma_xy=0, sigma_z=0, sigma_yaw=0, sigma_yaw_rotation=0)
    np.testing.assert_allclose(fly_vio(P, Y, p, 0), 0.0, atol=1e-9)


def test_200m_closed_loop_error_lies_in_the_95_percent_band():
    P, Y = square_loop(50.0)  # 200 m
    p = VioParams()
    cov = drift_covariance(P, Y, p)
    info = np.linalg.inv(cov)
    gate = chi2.ppf(0.95, df=3)
    d2 = []
    errors = []
    for seed in range(40):
        e = fly_vio(P, Y, p, seed)
        d2.append(float(e @ info @ e))
        errors.append(np.linalg.norm(e))
    d2 = np.array(d2)
    # ≥ 95 % inside in expectation: allow the binomial spread of 40 draws (P(≤ 34 inside) < 3 %)
    assert np.count_nonzero(d2 <= gate) >= 35
    # and the band is not loose: the squared Mahalanobis distance averages 3 (its dof)
    assert 2.0 < d2.mean() < 4.0
    # defaults as in paper 1 Table I: about 1–1.5 % of the distance travelled on such a loop
    assert 0.006 < np.sqrt(np.trace(cov)) / 200.0 < 0.016
    assert 0.004 < np.mean(errors) / 200.0 < 0.016


@pytest.mark.slow
def test_200m_closed_loop_flown_by_the_platform(tmp_path):
    """The same band, with the whole vehicle flying a 4 × 50 m loop in an empty hall."""
    from amslam.plugins.sim.world import box_room

    gate = chi2.ppf(0.95, df=3)
    inside = 0
    for seed in range(6):
        plat = make_platform(tmp_path, seed=seed, spec=box_room((60.0, 60.0, 4.0), start_xy=(5.0, 5.0)))
        plat.arm_and_takeoff(1.5)
        plat.advance(4.0)
        truth = [plat.ground_truth()[:3, 3].copy()]
        yaws = [0.0]
        start = truth[0].copy()
        for corner in ([55, 5], [55, 55], [5, 55], [5, 5]):
            goal = np.array([*corner, start[2]], float)
            plat.set_setpoint(goal, 0.0)
            for _ in range(1200):
                plat.advance(0.1)
                T = plat.ground_truth()
                truth.append(T[:3, 3].copy())
                yaws.append(np.arctan2(T[1, 0], T[0, 0]))
                if np.linalg.norm(plat.odometry().T_odom_body[:3, 3] - goal) < 0.02:
                    break
        fly_to(plat, start)
        e = plat.ground_truth()[:3, 3] - start  # VIO says we are back at the start
        cov = drift_covariance(np.array(truth), np.array(yaws), VioParams())
        inside += int(e @ np.linalg.inv(cov) @ e <= gate)
    assert inside >= 5
