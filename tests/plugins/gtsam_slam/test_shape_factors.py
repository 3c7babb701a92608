"""Cuboid (eq. 1) and cylinder (eq. 2) factors: analytic vs numerical Jacobians, and solving."""

from __future__ import annotations

from collections.abc import Callable

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from amslam.lib.shape_factors import (
    cuboid_centre_tie,
    cuboid_error,
    cuboid_factor,
    cuboid_keys,
    cylinder_error,
    cylinder_factor,
    cylinder_keys,
)


def _random_pose(rng: np.random.Generator, spread: float = 3.0) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.8, 3)), rng.normal(0, spread, 3))


def _retract(value: object, delta: np.ndarray) -> object:
    if isinstance(value, gtsam.Pose3 | gtsam.Unit3):
        return value.retract(delta)
    return np.asarray(value, float) + delta


def _dim(value: object) -> int:
    if isinstance(value, gtsam.Pose3):
        return 6
    if isinstance(value, gtsam.Unit3):
        return 2
    return int(np.size(value))


def numerical_jacobians(
    f: Callable[..., np.ndarray], args: list[object], eps: float = 1e-6
) -> list[np.ndarray]:
    """Central differences of ``f(*args)`` along each argument's retraction."""
    out = []
    for i, a in enumerate(args):
        n = _dim(a)
        cols = []
        for k in range(n):
            d = np.zeros(n)
            d[k] = eps
            plus = list(args)
            minus = list(args)
            plus[i] = _retract(a, d)
            minus[i] = _retract(a, -d)
            cols.append((f(*plus) - f(*minus)) / (2 * eps))
        out.append(np.column_stack(cols))
    return out


@pytest.mark.parametrize("seed", range(5))
def test_cuboid_jacobians_match_numerical(seed: int) -> None:
    rng = np.random.default_rng(seed)
    Xp, O = _random_pose(rng), _random_pose(rng)
    D = rng.uniform(0.5, 5.0, 3)
    # a measurement near the prediction (small error) and one far from it (large rotation error)
    near = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.1, 3)), rng.normal(0, 0.2, 3))
    for Z in (Xp.between(O).compose(near), _random_pose(rng)):
        dz = D + rng.normal(0, 0.3, 3)
        _, J = cuboid_error(Xp, O, D, Z, dz, jacobians=True)
        Jn = numerical_jacobians(lambda x, o, d, Z=Z, dz=dz: cuboid_error(x, o, d, Z, dz)[0], [Xp, O, D])
        for a, n in zip(J, Jn, strict=True):
            np.testing.assert_allclose(a, n, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("seed", range(5))
def test_cylinder_jacobians_match_numerical(seed: int) -> None:
    rng = np.random.default_rng(seed)
    Xp = _random_pose(rng)
    b = rng.normal(0, 3, 3)
    n = gtsam.Unit3(rng.normal(0, 1, 3))
    r = np.array([rng.uniform(0.05, 0.5)])
    b_meas, n_meas = rng.normal(0, 3, 3), rng.normal(0, 1, 3)
    n_meas /= np.linalg.norm(n_meas)
    _, J = cylinder_error(Xp, b, n, float(r[0]), b_meas, n_meas, 0.2, jacobians=True)
    Jn = numerical_jacobians(
        lambda x, bb, nn, rr: cylinder_error(x, bb, nn, float(rr[0]), b_meas, n_meas, 0.2)[0], [Xp, b, n, r]
    )
    for a, num in zip(J, Jn, strict=True):
        np.testing.assert_allclose(a, num, atol=1e-6, rtol=1e-5)


def test_cuboid_error_is_zero_at_the_true_measurement() -> None:
    rng = np.random.default_rng(3)
    Xp, O, D = _random_pose(rng), _random_pose(rng), np.array([4.5, 1.8, 1.5])
    e, _ = cuboid_error(Xp, O, D, Xp.between(O), D)
    np.testing.assert_allclose(e, 0.0, atol=1e-9)
    e, _ = cuboid_error(Xp, O, D, Xp.between(O), D + [0.1, 0.0, -0.2])
    np.testing.assert_allclose(e[6:], [-0.1, 0.0, 0.2], atol=1e-12)


def test_custom_factors_linearize_with_the_analytic_jacobians() -> None:
    """The CustomFactor wrappers hand GTSAM the same Jacobians (whitened by the noise)."""
    rng = np.random.default_rng(4)
    Xp, O, D = _random_pose(rng), _random_pose(rng), np.array([4.0, 2.0, 1.4])
    Z = _random_pose(rng, 1.0)
    o, d = cuboid_keys(0)
    v = gtsam.Values()
    v.insert(X(0), Xp)
    v.insert(o, O)
    v.insert(d, D)
    f = cuboid_factor(X(0), o, d, Z.matrix(), [4.2, 1.9, 1.5], gtsam.noiseModel.Unit.Create(9))
    A, bvec = f.linearize(v).jacobian()
    _, J = cuboid_error(Xp, O, D, Z, np.array([4.2, 1.9, 1.5]), jacobians=True)
    np.testing.assert_allclose(A, np.hstack(J), atol=1e-9)
    np.testing.assert_allclose(bvec, -cuboid_error(Xp, O, D, Z, np.array([4.2, 1.9, 1.5]))[0], atol=1e-9)

    bk, nk, rk = cylinder_keys(0)
    v.insert(bk, np.array([1.0, 2.0, 0.0]))
    v.insert(nk, gtsam.Unit3(np.array([0.1, 0.0, 1.0])))
    v.insert(rk, np.array([0.2]))
    g = cylinder_factor(X(0), bk, nk, rk, [0.5, 0.5, -1.0], [0, 0, 1], 0.25, gtsam.noiseModel.Unit.Create(7))
    A, _ = g.linearize(v).jacobian()
    _, J = cylinder_error(
        Xp, np.array([1.0, 2.0, 0.0]), gtsam.Unit3(np.array([0.1, 0.0, 1.0])), 0.2,
        np.array([0.5, 0.5, -1.0]), np.array([0.0, 0.0, 1.0]), 0.25, jacobians=True,
    )  # fmt: skip
    np.testing.assert_allclose(A, np.hstack(J), atol=1e-9)


def test_cuboid_centre_tie_jacobians_match_numerical() -> None:
    """The tie of two boxes' centres: its error is the centres' difference, its Jacobians GTSAM's."""
    rng = np.random.default_rng(6)
    Oa, Ob = _random_pose(rng), _random_pose(rng)
    a, b = cuboid_keys(0)[0], cuboid_keys(1)[0]
    v = gtsam.Values()
    v.insert(a, Oa)
    v.insert(b, Ob)
    A, rhs = cuboid_centre_tie(a, b, gtsam.noiseModel.Unit.Create(3)).linearize(v).jacobian()
    np.testing.assert_allclose(-rhs, Oa.translation() - Ob.translation(), atol=1e-12)
    Jn = numerical_jacobians(lambda p, q: p.translation() - q.translation(), [Oa, Ob])
    np.testing.assert_allclose(A, np.hstack(Jn), atol=1e-6)


def test_factors_recover_objects_from_noisy_measurements() -> None:
    """Known key poses, noisy body-frame measurements: Levenberg–Marquardt finds the objects."""
    rng = np.random.default_rng(5)
    O_true = gtsam.Pose3(gtsam.Rot3.Rz(0.7), [5.0, 3.0, 0.75])
    D_true = np.array([4.5, 1.8, 1.5])
    b_true, n_true, r_true = np.array([2.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 0.15
    o, d = cuboid_keys(1)
    bk, nk, rk = cylinder_keys(2)
    graph, init = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pose_noise = gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)
    cub_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.03] * 3 + [0.1] * 3 + [0.1] * 3))
    cyl_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05] * 3 + [0.03] * 3 + [0.02]))
    for i in range(30):
        Xi = gtsam.Pose3(gtsam.Rot3.Rz(0.2 * i), [np.cos(0.2 * i) * 8, np.sin(0.2 * i) * 8, 3.0])
        graph.add(gtsam.PriorFactorPose3(X(i), Xi, pose_noise))
        init.insert(X(i), Xi)
        Z = Xi.between(O_true).compose(
            gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.03, 3)), rng.normal(0, 0.1, 3))
        )
        graph.add(cuboid_factor(X(i), o, d, Z, D_true + rng.normal(0, 0.1, 3), cub_noise))
        b_meas = Xi.transformTo(b_true) + rng.normal(0, 0.05, 3)
        n_meas = Xi.rotation().unrotate(n_true) + rng.normal(0, 0.03, 3)
        graph.add(cylinder_factor(X(i), bk, nk, rk, b_meas, n_meas, r_true + rng.normal(0, 0.02), cyl_noise))
    init.insert(o, gtsam.Pose3(gtsam.Rot3.Rz(0.4), [4.0, 3.5, 1.0]))
    init.insert(d, np.array([3.0, 2.5, 1.0]))
    init.insert(bk, np.array([2.5, -0.5, 0.3]))
    init.insert(nk, gtsam.Unit3(np.array([0.2, 0.1, 1.0])))
    init.insert(rk, np.array([0.4]))
    est = gtsam.LevenbergMarquardtOptimizer(graph, init).optimize()
    assert est.atPose3(o).translation() == pytest.approx(O_true.translation(), abs=0.06)
    assert est.atPose3(o).rotation().yaw() == pytest.approx(0.7, abs=0.02)
    assert est.atPoint3(d) == pytest.approx(D_true, abs=0.05)
    assert est.atPoint3(bk) == pytest.approx(b_true, abs=0.03)
    assert est.atUnit3(nk).point3() == pytest.approx(n_true, abs=0.02)
    assert est.atVector(rk)[0] == pytest.approx(r_true, abs=0.01)
