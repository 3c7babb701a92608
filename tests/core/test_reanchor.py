"""exploration.reanchor_map: the corrections a rebuild of the global map uses, and kept frames."""

from __future__ import annotations

import numpy as np

from amslam.perception import KeptFrame, keypose_corrections
from amslam.types import Frame, KeyPose


def _pose(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_each_frame_takes_the_correction_of_the_latest_key_pose_before_it() -> None:
    # VIO drifted +0.1 m per key pose; SLAM's optimised key poses put them back on the truth
    odometry = {0.0: _pose(0.0), 10.0: _pose(1.1), 20.0: _pose(2.2)}
    keyposes = [KeyPose(i, t, _pose(float(i)), 0.0) for i, t in enumerate((0.0, 10.0, 20.0))]
    corr = keypose_corrections(np.array([-1.0, 0.0, 5.0, 10.0, 19.9, 25.0]), keyposes, odometry, np.eye(4))
    shifts = [round(float(C[0, 3]), 6) for C in corr]
    assert shifts == [0.0, 0.0, 0.0, -0.1, -0.1, -0.2]
    # a key pose whose odometry was not recorded is skipped; none at all: the fallback
    assert keypose_corrections(np.array([1.0]), keyposes, {}, _pose(7.0))[0][0, 3] == 7.0


def test_a_kept_frame_is_the_frames_every_fth_pixel_with_matching_intrinsics() -> None:
    K = np.array([[160.0, 0, 159.5], [0, 160.0, 119.5], [0, 0, 1]])
    depth = np.random.default_rng(0).uniform(0.5, 5.0, (240, 320)).astype(np.float32)
    kept = KeptFrame.of(Frame(1.0, depth, K, np.eye(4)))
    assert kept.depth.shape == (60, 80) and kept.depth.dtype == np.float16
    # the ray of kept pixel (u', v') is the ray of frame pixel (4u', 4v')
    u, v = 13, 7
    ray_kept = np.linalg.solve(kept.K, [u, v, 1.0])
    ray_frame = np.linalg.solve(K, [4 * u, 4 * v, 1.0])
    np.testing.assert_allclose(ray_kept, ray_frame)
    assert abs(float(kept.depth[v, u]) - depth[4 * v, 4 * u]) < 5e-3


class _Recorder:
    def __init__(self):
        self.rebuilt, self.events = [], []

    def rebuild_global(self, frames):
        self.rebuilt.append(list(frames))
        return True

    def event(self, t, name, **fields):
        self.events.append((name, fields))


def _perception(keyposes):
    from types import SimpleNamespace

    from amslam.boundary import Boundary
    from amslam.mission import ExplorationSection
    from amslam.perception import Perception

    rec = _Recorder()
    frames = [
        KeptFrame.of(Frame(float(t), np.full((12, 16), 2.0, np.float32), np.eye(3), _pose(0.0)))
        for t in range(10)
    ]
    fake = SimpleNamespace(
        exploration=ExplorationSection(reanchor_map=True, reanchor_min_shift=0.2),
        boundary=Boundary(),
        slam=SimpleNamespace(keyposes=lambda: keyposes),
        mapping=rec,
        rundir=rec,
        _kept=frames,
        _kept_at=[np.eye(4)] * len(frames),
        _keypose_odometry={0.0: _pose(0.0), 5.0: _pose(0.5)},
        _anchored=np.eye(4),
        _refresh_after_rebuild=False,
        _event=rec.event,
    )
    return fake, rec, Perception._reanchor_if_moved


def test_growing_drift_alone_rebuilds_nothing_and_a_loop_closure_rebuilds_at_the_corrected_poses():
    # SLAM follows the current drift (the correction moved 0.5 m) but left the key poses where the
    # frames were integrated: no frame belongs elsewhere, nothing to rebuild
    still = [KeyPose(0, 0.0, _pose(0.0), 0.0), KeyPose(1, 5.0, _pose(0.5), 0.0)]
    fake, rec, reanchor = _perception(still)
    reanchor(fake, 10.0, _pose(-0.5))
    assert rec.rebuilt == [] and not fake._refresh_after_rebuild
    # a loop closure moved the second key pose back 0.4 m: frames 5..9 belong 0.4 m off
    closed = [KeyPose(0, 0.0, _pose(0.0), 0.0), KeyPose(1, 5.0, _pose(0.1), 0.0)]
    fake, rec, reanchor = _perception(closed)
    reanchor(fake, 10.0, _pose(-0.5))
    (frames,) = rec.rebuilt
    shifts = [round(float(T[0, 3]), 6) for _, _, T in frames]
    assert shifts == [0.0] * 5 + [-0.4] * 5
    assert rec.events == [("map_reanchored", {"frames": 10, "moved": 5, "max_move_m": 0.4})]
    assert fake._refresh_after_rebuild and [round(float(C[0, 3]), 6) for C in fake._kept_at] == shifts
