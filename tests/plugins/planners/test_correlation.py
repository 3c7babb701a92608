"""Field-of-view overlap correlation w(u, v)."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.plugins.planners.correlation import camera_poses, fov_correlation, frustum_samples


def inside_frustum(points_cam: np.ndarray, camera) -> np.ndarray:
    z = points_cam[:, 2]
    return (
        (z >= camera.min_range)
        & (z <= camera.max_range)
        & (np.abs(points_cam[:, 0]) <= z * np.tan(camera.hfov / 2))
        & (np.abs(points_cam[:, 1]) <= z * np.tan(camera.vfov / 2))
    )


def monte_carlo_overlap(p_u, yaw_u, p_v, yaw_v, camera, n=200_000) -> float:
    """Independent estimate: rejection-sample u's frustum, count the share inside v's."""
    rng = np.random.default_rng(1)
    r = camera.max_range
    half = np.array([r * np.tan(camera.hfov / 2), r * np.tan(camera.vfov / 2)])
    box = np.column_stack([rng.uniform(-half, half, (n, 2)), rng.uniform(0, r, n)])
    pts = box[inside_frustum(box, camera)]
    R, t = camera_poses(np.array([p_u, p_v], float), np.array([yaw_u, yaw_v]), camera)
    world = pts @ R[0].T + t[0]
    in_v = inside_frustum((world - t[1]) @ R[1], camera)
    return float(in_v.mean())


def test_samples_fill_the_frustum(camera):
    pts = frustum_samples(camera, 500)
    assert pts.shape == (500, 3)
    assert inside_frustum(pts, camera).all()
    # uniform by volume: half the volume lies beyond the depth where z³ splits [near³, far³] in two
    z_half = np.cbrt((camera.min_range**3 + camera.max_range**3) / 2)
    assert abs((pts[:, 2] > z_half).mean() - 0.5) < 0.02


def test_identical_viewpoints_correlate_fully(camera):
    w = fov_correlation(np.array([[1.0, 2.0, 1.0], [1.0, 2.0, 1.0]]), np.array([0.7, 0.7]), camera)
    np.testing.assert_allclose(w, np.ones((2, 2)))


def test_disjoint_viewpoints_do_not_correlate(camera):
    positions = np.array([[0.0, 0.0, 1.0], [30.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    yaws = np.array([0.0, 0.0, np.pi])  # far apart; back to back at the same place
    w = fov_correlation(positions, yaws, camera)
    np.testing.assert_array_equal(w, np.eye(3))


def test_symmetric_in_unit_interval_and_decreasing_with_distance(camera):
    rng = np.random.default_rng(3)
    positions = rng.uniform(0, 8, (25, 3))
    w = fov_correlation(positions, rng.uniform(-np.pi, np.pi, 25), camera)
    np.testing.assert_array_equal(w, w.T)
    assert np.all((w >= 0) & (w <= 1))
    np.testing.assert_array_equal(np.diag(w), 1.0)
    shifts = [0.5, 1.5, 3.0, 6.0]
    lateral = [
        fov_correlation(np.array([[0, 0, 1.0], [0, s, 1.0]]), np.zeros(2), camera)[0, 1] for s in shifts
    ]
    assert all(a > b for a, b in zip(lateral, lateral[1:], strict=False))


@pytest.mark.parametrize(
    ("p_v", "yaw_v"),
    [((0.0, 1.0, 1.0), 0.0), ((1.5, 0.0, 1.0), 0.0), ((0.0, 0.0, 1.0), 0.8), ((2, 2, 1.0), -1.0)],
)
def test_matches_an_independent_monte_carlo_estimate(camera, p_v, yaw_v):
    p_u = (0.0, 0.0, 1.0)
    w = fov_correlation(np.array([p_u, p_v]), np.array([0.0, yaw_v]), camera, samples=1024)[0, 1]
    ref_uv = monte_carlo_overlap(p_u, 0.0, p_v, yaw_v, camera)
    ref_vu = monte_carlo_overlap(p_v, yaw_v, p_u, 0.0, camera)
    assert w == pytest.approx((ref_uv + ref_vu) / 2, abs=0.03)
    assert ref_uv == pytest.approx(ref_vu, abs=0.02)  # same camera, same volume: the overlap is symmetric
