"""The compiled projective kernel decides every voxel as the vectorised numpy kernel it replaced."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib.voxel_grid import to_index
from amslam.plugins.voxel_open3d.projective import HIT, frustum_update
from amslam.testing.mapping import ROOM_POSE, camera_pose, render_depth, room_scene
from amslam.types import CameraModel

CAMERA = CameraModel.from_fov(320, 240, 87.0, 58.0)


def numpy_frustum_update(depth, K, T_world_cam, stride, max_range, voxel):
    """The former kernel (commit 4ccada0), vectorised with numpy: unique touched voxel indices
    (sorted) and their hit flags."""
    depth = np.asarray(depth, dtype=np.float32)
    H, W = depth.shape
    T = np.asarray(T_world_cam, dtype=np.float64)
    R, o = T[:3, :3], T[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    v_pix, u_pix = np.mgrid[0:H, 0:W]
    ray_norm = np.sqrt(((u_pix - cx) / fx) ** 2 + ((v_pix - cy) / fy) ** 2 + 1.0).astype(np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    meas = np.where(valid, depth * ray_norm, np.inf)
    meas = np.where(meas <= max_range, meas, np.inf)
    bu = np.array([0, W / 2, W - 1, 0, W - 1, 0, W / 2, W - 1, W / 2])
    bv = np.array([0, 0, 0, H / 2, H / 2, H - 1, H - 1, H - 1, H / 2])
    rays = np.stack([(bu - cx) / fx, (bv - cy) / fy, np.ones_like(bu)], 1)
    far = o + (rays / np.linalg.norm(rays, axis=1, keepdims=True) * max_range) @ R.T
    pts = np.vstack([o, far])
    lo = np.floor(pts.min(0) / voxel).astype(np.int64) - 1
    hi = np.floor(pts.max(0) / voxel).astype(np.int64) + 2
    shape = tuple(int(s) for s in hi - lo)
    axes = [((np.arange(lo[i], hi[i]) + 0.5) * voxel - o[i]).astype(np.float32) for i in range(3)]
    Rt = R.T.astype(np.float32)
    pc = [
        Rt[r, 0] * axes[0][:, None, None]
        + Rt[r, 1] * axes[1][None, :, None]
        + Rt[r, 2] * axes[2][None, None, :]
        for r in range(3)
    ]
    z = pc[2]
    rng = np.sqrt(pc[0] ** 2 + pc[1] ** 2 + z**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.rint(fx * pc[0] / z + cx)
        v = np.rint(fy * pc[1] / z + cy)
    in_view = (z > 0) & (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1) & (rng <= max_range)
    flat = np.nonzero(in_view.reshape(-1))[0]
    pix = v.reshape(-1)[flat].astype(np.int64) * W + u.reshape(-1)[flat].astype(np.int64)
    free_flat = flat[rng.reshape(-1)[flat] < meas.reshape(-1)[pix]]
    status = np.zeros(int(np.prod(shape)), dtype=np.uint8)
    status[free_flat] = 1
    ds, ms = depth[::stride, ::stride], meas[::stride, ::stride]
    vv, uu = np.nonzero(np.isfinite(ms))
    d = ds[vv, uu].astype(np.float64)
    cam = np.stack([(uu * stride - cx) / fx * d, (vv * stride - cy) / fy * d, d], 1)
    hidx = to_index(cam @ R.T + o, voxel) - lo
    ok = np.all((hidx >= 0) & (hidx < np.array(shape)), axis=1)
    status[np.ravel_multi_index(tuple(hidx[ok].T), shape)] = 2
    touched = np.nonzero(status)[0]
    return np.stack(np.unravel_index(touched, shape), 1).astype(np.int64) + lo, status[touched] == 2


def poses():
    rng = np.random.default_rng(3)
    out = [ROOM_POSE, camera_pose((2.0, 4.0, 1.0), np.radians(-60.0))]
    for _ in range(3):  # tilted and rolled too
        T = camera_pose(tuple(rng.uniform([1, 1, 0.5], [9, 5, 2.5])), rng.uniform(-np.pi, np.pi))
        a, b = rng.uniform(-0.4, 0.4, 2)
        tilt = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        roll = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]])
        T[:3, :3] = T[:3, :3] @ tilt @ roll
        out.append(T)
    return out


@pytest.fixture(scope="module")
def frames():
    scene = room_scene()
    out = []
    for T in poses():
        depth = render_depth(scene, CAMERA, T)
        depth[::7, ::5] = np.nan  # no-return pixels of every kind
        depth[3::11, ::3] = np.inf
        out.append((depth, T))
    return out


@pytest.mark.parametrize(("voxel", "stride"), [(0.1, 1), (0.1, 3), (0.25, 1), (0.25, 4), (0.05, 2)])
def test_the_compiled_kernel_equals_the_numpy_one(frames, voxel, stride):
    for depth, T in frames:
        index, hit = numpy_frustum_update(depth, CAMERA.K, T, stride, 4.0, voxel)
        frame = frustum_update(depth, CAMERA.K, T, stride, 4.0, voxel)
        order = np.argsort(frame.touched)  # the numpy kernel lists them in flat order
        np.testing.assert_array_equal(frame.indices()[order], index)
        np.testing.assert_array_equal(frame.hits()[order], hit)
        assert np.count_nonzero(frame.status) == len(frame.touched) == len(np.unique(frame.touched))


def test_hits_win_and_no_return_pixels_carve_to_max_range():
    depth = np.zeros((CAMERA.height, CAMERA.width), np.float32)  # nothing returns
    frame = frustum_update(depth, CAMERA.K, np.eye(4), 1, 2.0, 0.1)
    assert not frame.hits().any()
    centres = (frame.indices() + 0.5) * 0.1
    assert np.linalg.norm(centres, axis=1).max() == pytest.approx(2.0, abs=0.1)
    depth[:] = 1.0  # a wall 1 m ahead: hits on it, nothing behind it
    frame = frustum_update(depth, CAMERA.K, np.eye(4), 1, 2.0, 0.1)
    z = (frame.indices()[:, 2] + 0.5) * 0.1
    assert set(np.unique(frame.indices()[frame.hits(), 2])) == {10}
    assert z.max() < 1.1 and (frame.status == HIT).sum() == frame.hits().sum()
