"""Custom GTSAM factors for cuboid and cylinder object landmarks (paper 2, §IV-B3, eqs. 1–2).

Both factors connect a robot key pose ``X`` (``gtsam.Pose3``, world ← body, the same variable as
the rest of :mod:`.backend`) to the variables of one object, and both compute their Jacobians in
closed form (GTSAM's convention: the derivative of the error with respect to the tangent-space
perturbation of each variable's ``retract``).

**Cuboid** (eq. 1). Variables: the object pose ``O`` (``Pose3``, world ← cuboid, the cuboid
frame centred in the box with axes ``b1, b2, b3``) and its dimensions ``D`` (``Point3`` used as a
3-vector ``[l, w, h]``). Measurement: the cuboid pose in the body frame ``Z = H_cub^s(z)`` and its
dimensions ``d(z)``. With ``H_w^s = X⁻¹``::

    e_cub = [ Log( Z⁻¹ · X⁻¹ · O ) ;  D − d(z) ]                       (9 × 1)

    ∂e/∂X = [ J_log · (−Ad((X⁻¹O)⁻¹)) ; 0 ]
    ∂e/∂O = [ J_log ; 0 ]                 J_log = Pose3.LogmapDerivative(Z⁻¹X⁻¹O)
    ∂e/∂D = [ 0 ; I₃ ]

(``between`` has Jacobians −Ad(h⁻¹) and I; left-composing with the constant ``Z⁻¹`` leaves a
right perturbation unchanged.)

**Cylinder** (eq. 2). Variables: the root ``B`` (``Point3``, where the axis meets the ground),
the axis ``N`` (``Unit3``) and the radius ``R`` (a 1-vector). Measurement: root, axis and radius
in the body frame. With ``X = (R_X, t_X)`` and ``q = R_Xᵀ(b − t_X)``, ``m = R_Xᵀ n``::

    e_cyl = [ q − b(z) ;  m − n(z) ;  r − r(z) ]                       (7 × 1)

    ∂e/∂X = [ [q]× , −I₃ ; [m]× , 0 ; 0 , 0 ]   (rotation columns first, as Pose3's tangent)
    ∂e/∂B = [ R_Xᵀ ; 0 ; 0 ]
    ∂e/∂N = [ 0 ; R_Xᵀ · basis(n) ; 0 ]       (Unit3's retract moves along its 3×2 basis)
    ∂e/∂R = [ 0 ; 0 ; 1 ]

(under ``X·Exp([ω; v])``: ``R_X`` becomes ``R_X Exp(ω)`` and ``t_X`` becomes ``t_X + R_X v``,
so ``q`` becomes ``q + q × ω − v`` and ``m`` becomes ``m + m × ω`` to first order).

Keys: :func:`cuboid_keys` and :func:`cylinder_keys` give the symbols the SLAM backend uses for
landmark ``j`` (characters ``o``, ``d`` for cuboids; ``b``, ``n``, ``r`` for cylinders), next to
``X(i)`` key poses and ``L(j)`` centroid landmarks.
"""

from __future__ import annotations

import gtsam
import numpy as np

from amslam.geometry import skew

__all__ = [
    "cuboid_centre_tie",
    "cuboid_error",
    "cuboid_factor",
    "cuboid_keys",
    "cylinder_error",
    "cylinder_factor",
    "cylinder_keys",
]


def cuboid_keys(j: int) -> tuple[int, int]:
    """Keys of cuboid landmark ``j``: its pose ``o_j`` and its dimensions ``d_j``."""
    return gtsam.symbol("o", j), gtsam.symbol("d", j)


def cylinder_keys(j: int) -> tuple[int, int, int]:
    """Keys of cylinder landmark ``j``: root ``b_j``, axis ``n_j`` and radius ``r_j``."""
    return gtsam.symbol("b", j), gtsam.symbol("n", j), gtsam.symbol("r", j)


# -------------------------------------------------------------------------------------------
# cuboid (eq. 1)
# -------------------------------------------------------------------------------------------
def cuboid_error(
    X: gtsam.Pose3,
    O: gtsam.Pose3,  # noqa: E741 — the paper's name for the object pose
    D: np.ndarray,
    Z: gtsam.Pose3,
    d_meas: np.ndarray,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Eq. 1 error and (optionally) its Jacobians with respect to ``X``, ``O`` and ``D``.

    Args:
        X: robot key pose, world ← body.
        O: object pose, world ← cuboid.
        D: object dimensions ``[l, w, h]``.
        Z: measured cuboid pose in the body frame (body ← cuboid).
        d_meas: measured dimensions.
        jacobians: also return ``[∂e/∂X (9×6), ∂e/∂O (9×6), ∂e/∂D (9×3)]``.

    Returns:
        The 9-vector error and the Jacobians (or ``None``).
    """
    h = X.between(O)  # X⁻¹ O: the predicted cuboid pose in the body frame
    E = Z.between(h)  # Z⁻¹ X⁻¹ O
    xi = gtsam.Pose3.Logmap(E)
    err = np.concatenate([xi, np.asarray(D, float).reshape(3) - np.asarray(d_meas, float).reshape(3)])
    if not jacobians:
        return err, None
    J_log = gtsam.Pose3.LogmapDerivative(E)
    J_X = np.zeros((9, 6))
    J_X[:6] = J_log @ (-h.inverse().AdjointMap())
    J_O = np.zeros((9, 6))
    J_O[:6] = J_log
    J_D = np.zeros((9, 3))
    J_D[6:] = np.eye(3)
    return err, [J_X, J_O, J_D]


def cuboid_factor(
    pose_key: int,
    object_key: int,
    dims_key: int,
    T_body_cuboid: np.ndarray | gtsam.Pose3,
    dims: np.ndarray,
    noise: gtsam.noiseModel.Base,
) -> gtsam.CustomFactor:
    """Eq. 1 as a ``gtsam.CustomFactor`` on (``Pose3`` key pose, ``Pose3`` object, ``Point3`` dims).

    Args:
        pose_key: key of the robot key pose (world ← body).
        object_key: key of the object pose (world ← cuboid).
        dims_key: key of the object dimensions.
        T_body_cuboid: measured cuboid pose in the body frame (4×4 or ``Pose3``).
        dims: measured dimensions ``[l, w, h]``.
        noise: 9-dimensional noise model (rotation, translation, dimensions).
    """
    Z = T_body_cuboid if isinstance(T_body_cuboid, gtsam.Pose3) else gtsam.Pose3(np.asarray(T_body_cuboid))
    d_meas = np.asarray(dims, float).reshape(3).copy()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        k = this.keys()
        e, J = cuboid_error(
            values.atPose3(k[0]), values.atPose3(k[1]), values.atPoint3(k[2]), Z, d_meas, H is not None
        )
        if H is not None:
            assert J is not None
            H[0], H[1], H[2] = J
        return e

    return gtsam.CustomFactor(noise, [pose_key, object_key, dims_key], error)


# -------------------------------------------------------------------------------------------
# cylinder (eq. 2)
# -------------------------------------------------------------------------------------------
def cylinder_error(
    X: gtsam.Pose3,
    b: np.ndarray,
    n: gtsam.Unit3,
    r: float,
    b_meas: np.ndarray,
    n_meas: np.ndarray,
    r_meas: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Eq. 2 error and (optionally) its Jacobians with respect to ``X``, ``b``, ``n`` and ``r``.

    Args:
        X: robot key pose, world ← body.
        b: cylinder root in the world frame.
        n: cylinder axis in the world frame.
        r: radius.
        b_meas, n_meas, r_meas: the measured root, axis (unit vector) and radius, body frame.
        jacobians: also return ``[∂e/∂X (7×6), ∂e/∂b (7×3), ∂e/∂n (7×2), ∂e/∂r (7×1)]``.

    Returns:
        The 7-vector error and the Jacobians (or ``None``).
    """
    Rt = X.rotation().matrix().T
    q = Rt @ (np.asarray(b, float).reshape(3) - X.translation())
    nv = n.point3()
    m = Rt @ nv
    err = np.concatenate([q - np.asarray(b_meas, float), m - np.asarray(n_meas, float), [r - r_meas]])
    if not jacobians:
        return err, None
    J_X = np.zeros((7, 6))
    J_X[0:3, 0:3] = skew(q)
    J_X[0:3, 3:6] = -np.eye(3)
    J_X[3:6, 0:3] = skew(m)
    J_b = np.zeros((7, 3))
    J_b[0:3] = Rt
    J_n = np.zeros((7, 2))
    J_n[3:6] = Rt @ n.basis()
    J_r = np.zeros((7, 1))
    J_r[6, 0] = 1.0
    return err, [J_X, J_b, J_n, J_r]


def cylinder_factor(
    pose_key: int,
    root_key: int,
    axis_key: int,
    radius_key: int,
    root: np.ndarray,
    axis: np.ndarray,
    radius: float,
    noise: gtsam.noiseModel.Base,
) -> gtsam.CustomFactor:
    """Eq. 2 as a ``gtsam.CustomFactor`` on (``Pose3``, ``Point3`` root, ``Unit3`` axis, 1-vector radius).

    Args:
        pose_key: key of the robot key pose (world ← body).
        root_key: key of the root (``Point3``).
        axis_key: key of the axis (``Unit3``).
        radius_key: key of the radius (a ``Vector`` of size 1).
        root: measured root in the body frame.
        axis: measured axis direction in the body frame (normalised here).
        radius: measured radius.
        noise: 7-dimensional noise model (root, axis, radius).
    """
    b_meas = np.asarray(root, float).reshape(3).copy()
    n_meas = np.asarray(axis, float).reshape(3)
    n_meas = n_meas / np.linalg.norm(n_meas)
    r_meas = float(radius)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        k = this.keys()
        e, J = cylinder_error(
            values.atPose3(k[0]),
            values.atPoint3(k[1]),
            values.atUnit3(k[2]),
            float(values.atVector(k[3])[0]),
            b_meas,
            n_meas,
            r_meas,
            H is not None,
        )
        if H is not None:
            assert J is not None
            H[0], H[1], H[2], H[3] = J
        return e

    return gtsam.CustomFactor(noise, [pose_key, root_key, axis_key, radius_key], error)


# -------------------------------------------------------------------------------------------
# two cuboid landmarks of one object
# -------------------------------------------------------------------------------------------
def cuboid_centre_tie(
    object_key_a: int, object_key_b: int, noise: gtsam.noiseModel.Base
) -> gtsam.CustomFactor:
    """A zero-offset tie of two cuboids' centres (two landmarks found to be one object).

    ``e = t(O_a) − t(O_b)`` (3 × 1, world frame). Under ``O·Exp([ω; v])`` a pose's translation
    moves by ``R v``, so ``∂e/∂O_a = [0, R_a]`` and ``∂e/∂O_b = [0, −R_b]``. Only the centres are
    tied, as a point landmark's fusion ties its point: the boxes' rotations and dimensions keep
    their own measurements.
    """

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        k = this.keys()
        Oa, Ob = values.atPose3(k[0]), values.atPose3(k[1])
        if H is not None:
            H[0] = np.hstack([np.zeros((3, 3)), Oa.rotation().matrix()])
            H[1] = np.hstack([np.zeros((3, 3)), -Ob.rotation().matrix()])
        return np.asarray(Oa.translation() - Ob.translation(), float)

    return gtsam.CustomFactor(noise, [object_key_a, object_key_b], error)
