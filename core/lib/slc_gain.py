"""Eq. (10) of paper 1 for one virtual factor or a chain of them (Algorithm 1, line 6).

A virtual odometry factor between two poses adds the rank-6 term ``JᵀJ`` to the information
matrix, ``J`` its whitened Jacobian. ``m`` such factors touching only the poses ``S`` stack into
``J`` (6m × |S|), and by Woodbury

    IG = tr(Σ_V) − tr(Σ⁺_V) = tr( W⁻¹ J G Jᵀ ),   W = I + J Σ_SS Jᵀ,   G = Σ_{S,V} Σ_{V,S},

so a whole chain is scored from ``Σ_SS`` and ``G`` alone: the SLAM backend computes those once
per plan (:class:`amslam.types.SlcGainModel`) and the planner scores every chain it considers.
The paper's "for a long-horizon path, we can sequentially perform such operations to evaluate the
IG for a sequence of actions with multiple SLCs" is this, done at once rather than one factor at
a time (the same result: the factors' information adds).

Written here rather than with gtsam because the planner has no graph: it holds two small dense
matrices, and each chain is a 6m × 6m solve.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from amslam.geometry import skew, wrap_angle, yaw_of
from amslam.types import SlcGainModel

__all__ = ["Leg", "between_jacobians", "chain_gain", "trace_reduction"]

#: One virtual odometry factor of a chain: (from key pose id, to key pose id, metres travelled).
Leg = tuple[int, int, float]


def trace_reduction(covariance: np.ndarray, gram: np.ndarray, J: np.ndarray) -> float:
    """``tr(W⁻¹ J G Jᵀ)``, ``W = I + J Σ Jᵀ``: the trace reduction of adding whitened rows ``J``.

    Args:
        covariance: Σ_SS over the columns ``J`` acts on.
        gram: Σ_{S,V} Σ_{V,S} for the variables V whose trace is measured.
        J: whitened Jacobian rows (k × |S|).
    """
    if J.shape[0] == 0:
        return 0.0
    W = np.eye(J.shape[0]) + J @ covariance @ J.T
    return float(np.trace(np.linalg.solve(W, J @ gram @ J.T)))


def _adjoint(T: np.ndarray) -> np.ndarray:
    """gtsam's ``Pose3.AdjointMap`` in its (rotation, translation) tangent order."""
    R, t = T[:3, :3], T[:3, 3]
    out = np.zeros((6, 6))
    out[:3, :3] = R
    out[3:, 3:] = R
    out[3:, :3] = skew(t) @ R
    return out


def between_jacobians(T_a: np.ndarray, T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of gtsam's ``BetweenFactorPose3(a, b)`` at zero error, on ``a`` and on ``b``.

    At zero error the log map's Jacobian is the identity, so ``H_a = −Ad((T_a⁻¹ T_b)⁻¹)`` and
    ``H_b = I`` (tested against gtsam's own linearisation).
    """
    rel_inv = np.linalg.inv(np.linalg.inv(T_a) @ T_b)
    return -_adjoint(rel_inv), np.eye(6)


def chain_gain(model: SlcGainModel, legs: Sequence[Leg]) -> float:
    """Eq. (10) for the virtual odometry factors ``legs`` added together.

    Each leg ``(a, b, d)`` is the robot travelling ``d`` metres from key pose ``a`` to key pose
    ``b`` and closing a loop there (paper 1 §VI-C: the loop-closure viewpoint is the old key pose
    itself, so the expected odometry factor joins the two key poses), its noise the odometry
    model over ``d`` metres and the yaw turned.

    Raises:
        KeyError: a leg names a key pose the model does not hold.
    """
    if not legs:
        return 0.0
    col = {k: i for i, k in enumerate(model.keypose_ids)}
    n = len(model.keypose_ids)
    J = np.zeros((6 * len(legs), 6 * n))
    for row, (a, b, distance) in enumerate(legs):
        ia, ib = col[a], col[b]
        T_a, T_b = model.poses[ia], model.poses[ib]
        sigmas = model.odometry.sigmas(distance, wrap_angle(yaw_of(T_b) - yaw_of(T_a)))
        H_a, H_b = between_jacobians(T_a, T_b)
        rows = slice(6 * row, 6 * row + 6)
        J[rows, 6 * ia : 6 * ia + 6] += H_a / sigmas[:, None]
        J[rows, 6 * ib : 6 * ib + 6] += H_b / sigmas[:, None]
    return trace_reduction(model.covariance, model.gram, J)
