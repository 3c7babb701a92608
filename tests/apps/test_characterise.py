"""Characterisation samples from spirals around a specimen object (paper 2 §IV-C1)."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.apps.characterisation import (
    COMPONENTS,
    CharacteriseConfig,
    Samples,
    TargetSpec,
    collect,
    spiral_poses,
)
from amslam.plugins.sim.camera import CameraParams


def _config(**kw) -> CharacteriseConfig:
    return CharacteriseConfig(
        targets=[TargetSpec(class_name="car", size=(4.6, 1.9, 1.5), yaw=0.3)],
        heights=[2.0],
        poses_per_spiral=16,
        range_min=3.0,
        range_max=12.0,
        turns=2.0,
        camera=CameraParams(width=160, height=120, max_range=20.0, rgb=False, pitch_deg=15.0),
        **kw,
    )


def test_spiral_poses_face_the_object_and_widen():
    cfg = _config()
    centre = np.array([0.0, 0.0, 0.75])
    poses = spiral_poses(centre, cfg)
    assert len(poses) == 16
    radii = [np.linalg.norm(T[:2, 3]) for T in poses]
    assert radii[0] == pytest.approx(3.0) and radii[-1] == pytest.approx(12.0)
    assert np.all(np.diff(radii) > 0)
    for T in poses:
        to_obj = centre[:2] - T[:2, 3]
        assert np.dot(T[:2, 0], to_obj / np.linalg.norm(to_obj)) == pytest.approx(1.0)  # body x at it
        assert T[2, 3] == 2.0


def test_collect_records_range_angle_confidence_and_errors(tmp_path):
    s = collect(_config())
    assert 8 <= len(s) <= 16 and s.models == {"car": "cuboid"}
    assert np.all((s.angle >= 0) & (s.angle <= np.pi))
    assert np.all((s.range > 2.5) & (s.range < 13.0))
    assert np.all(s.confidence[~s.detected] == 0.0)
    assert np.all((s.confidence[s.detected] > 0.3) & (s.confidence[s.detected] < 1.0))
    assert s.errors.shape == (len(s), len(COMPONENTS))
    det = s.detected
    assert det.sum() >= 4
    assert np.all(np.isnan(s.errors[~det]))
    assert np.any(np.isfinite(s.errors[det, 0]))
    # far looks are less confident than near ones (the detector's range model)
    near, far = s.range < 6.0, s.range > 9.0
    assert s.confidence[near & det].mean() > s.confidence[far].mean()
    path = tmp_path / "s.npz"
    s.save(path)
    back = Samples.load(path)
    np.testing.assert_array_equal(back.range, s.range)
    np.testing.assert_array_equal(back.errors, s.errors)
    assert back.models == s.models and list(back.class_name) == list(s.class_name)
