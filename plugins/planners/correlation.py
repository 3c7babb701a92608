"""Reward correlation between viewpoints: the overlap of their field-of-view frusta (paper 1 §VI-B).

``w(u, v)`` is the share of the volume seen from viewpoint ``u`` that viewpoint ``v`` also sees.
Both frusta come from the same camera, so they have the same volume and the exact overlap share is
symmetric; the estimate below samples each frustum with the same fixed low-discrepancy point set,
counts the share of ``u``'s samples that fall inside ``v``'s frustum and vice versa, and averages
the two shares so that ``w(u, v) == w(v, u)`` holds exactly. Identical poses give 1, frusta that do
not intersect give 0. Occlusion is ignored: the planner has no map (the gains already account for
what is hidden).

A viewpoint's body has zero roll and pitch; its camera sits at ``camera.T_body_cam``.
"""

from __future__ import annotations

import numpy as np

from amslam.types import CameraModel

#: Pairs of viewpoints processed per vectorised batch (bounds memory to ~batch × samples × 3 floats).
_BATCH = 1024


def frustum_samples(camera: CameraModel, count: int, far: float | None = None) -> np.ndarray:
    """``count`` points spread uniformly (by volume) in the camera frustum, camera optical frame.

    A Halton sequence (unscrambled, so deterministic) fills the unit cube; depth is mapped through
    the inverse CDF of the frustum's volume, which grows as ``z²``, and the lateral coordinates
    scale with depth. Points lie strictly inside the frustum.
    """
    from scipy.stats import qmc  # 0.3-0.6 s of scipy.stats: imported when a planner samples, not at load

    near = camera.min_range
    far = camera.max_range if far is None else far
    if far <= near:
        raise ValueError(f"frustum far range {far} must exceed the near range {near}")
    u = qmc.Halton(d=3, scramble=False).random(count + 1)[1:]  # the first Halton point is the origin
    z = np.cbrt(near**3 + u[:, 2] * (far**3 - near**3))
    x = (2.0 * u[:, 0] - 1.0) * z * np.tan(camera.hfov / 2.0)
    y = (2.0 * u[:, 1] - 1.0) * z * np.tan(camera.vfov / 2.0)
    return np.column_stack([x, y, z])


def camera_poses(
    positions: np.ndarray, yaws: np.ndarray, camera: CameraModel
) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (N×3×3) and positions (N×3) of the camera at each body position and yaw."""
    c, s = np.cos(yaws), np.sin(yaws)
    R_world_body = np.zeros((len(yaws), 3, 3))
    R_world_body[:, 0, 0], R_world_body[:, 0, 1] = c, -s
    R_world_body[:, 1, 0], R_world_body[:, 1, 1] = s, c
    R_world_body[:, 2, 2] = 1.0
    T_body_cam = np.asarray(camera.T_body_cam, dtype=float)
    R = R_world_body @ T_body_cam[:3, :3]
    t = np.asarray(positions, dtype=float) + R_world_body @ T_body_cam[:3, 3]
    return R, t


def _share_inside(
    samples: np.ndarray, R_rel: np.ndarray, t_rel: np.ndarray, near: float, far: float, tx: float, ty: float
) -> np.ndarray:
    """For each pair, the share of ``samples`` (one camera's frame) inside the other frustum."""
    # One (P·3)×3 by 3×M product (coordinate-major result) is several times faster than a batched
    # einsum over pairs.
    p = (R_rel.reshape(-1, 3) @ samples.T).reshape(len(R_rel), 3, len(samples)) + t_rel[:, :, None]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    tol = 1e-9 * far
    inside = (z >= near - tol) & (z <= far + tol) & (np.abs(x) <= z * tx + tol) & (np.abs(y) <= z * ty + tol)
    return inside.mean(axis=1)


def fov_correlation(
    positions: np.ndarray,
    yaws: np.ndarray,
    camera: CameraModel,
    *,
    samples: int = 256,
    far: float | None = None,
) -> np.ndarray:
    """The N×N correlation matrix ``w(u, v)`` ∈ [0, 1] of viewpoints by frustum overlap.

    Args:
        positions: N×3 body positions (world frame).
        yaws: N headings in radians.
        camera: the depth camera (field of view, near range, mounting).
        samples: points sampled per frustum; the estimate's resolution is ``1 / samples``.
        far: far range of the frustum in metres; defaults to ``camera.max_range``.

    Returns:
        A symmetric matrix with ones on the diagonal.
    """
    from scipy.spatial import cKDTree  # 0.2 s: imported when a planner first plans, not when it is listed

    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    yaws = np.asarray(yaws, dtype=float).reshape(-1)
    n = len(positions)
    w = np.eye(n)
    if n < 2:
        return w
    far = camera.max_range if far is None else far
    near = camera.min_range
    tx, ty = np.tan(camera.hfov / 2.0), np.tan(camera.vfov / 2.0)
    pts = frustum_samples(camera, samples, far)
    R, t = camera_poses(positions, yaws, camera)
    # Frusta can only meet if their bounding spheres do. The sphere is centred on the optical axis
    # at depth d (the point equidistant from the apex and the far corners, capped at the far plane)
    # and reaches the farthest of the 8 frustum corners.
    d = min(far * (1.0 + tx**2 + ty**2) / 2.0, far)
    corners = np.array(
        [[sx * r * tx, sy * r * ty, r] for r in (near, far) for sx in (-1, 1) for sy in (-1, 1)]
    )
    radius = float(np.linalg.norm(corners - [0.0, 0.0, d], axis=1).max())
    centres = t + R[:, :, 2] * d
    pairs = np.array(sorted(cKDTree(centres).query_pairs(2.0 * radius)), dtype=int).reshape(-1, 2)
    for start in range(0, len(pairs), _BATCH):
        a, b = pairs[start : start + _BATCH].T
        # Points of a's camera frame expressed in b's camera frame, and the reverse.
        R_ba = np.einsum("pji,pjk->pik", R[b], R[a])
        t_ba = np.einsum("pji,pj->pi", R[b], t[a] - t[b])
        R_ab = np.transpose(R_ba, (0, 2, 1))
        t_ab = -np.einsum("pij,pj->pi", R_ab, t_ba)
        share = 0.5 * (
            _share_inside(pts, R_ba, t_ba, near, far, tx, ty)
            + _share_inside(pts, R_ab, t_ab, near, far, tx, ty)
        )
        w[a, b] = w[b, a] = share
    return w
