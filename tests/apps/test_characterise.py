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


def test_furniture_specimens_are_the_buildings_pieces_scored_against_their_bounding_box():
    from amslam.apps.characterisation import SPECIMENS, specimen_world

    world, summary, truth = specimen_world(SPECIMENS["shelf"], 6.0, np.random.default_rng(3))
    # made of its parts (two sides, a back, five boards), not one solid box of twelve triangles
    part = next(p for p in world.spec.parts if p.name == "shelf_1")
    assert len(part.triangles) == 8 * 12
    length, width, height = truth["dims"]
    assert 0.3 < length < 0.5 and 0.8 <= width <= 1.2 and 1.6 <= height <= 2.0
    assert truth["center"] == pytest.approx([0.0, 0.0, height / 2])
    # the mesh stands on the ground inside its true box, centred on the origin
    v = part.vertices @ np.array([[np.cos(0.3), -np.sin(0.3), 0], [np.sin(0.3), np.cos(0.3), 0], [0, 0, 1]])
    assert v.min(axis=0) == pytest.approx([-length / 2, -width / 2, 0.0], abs=1e-9)
    assert v.max(axis=0) == pytest.approx([length / 2, width / 2, height], abs=1e-9)


def test_furniture_angles_and_errors_are_taken_from_the_longer_axis():
    """A sofa's length is across its own x: viewed along its length is angle 0, and the x error
    is along the length, as the SLAM backend reads a fitted box."""
    from amslam.apps.characterisation import SPECIMENS

    cfg = _config().model_copy(
        update={
            "targets": [SPECIMENS["sofa"].model_copy(update={"yaw": 0.0})],
            "range_min": 2.0,
            "range_max": 4.0,
            "heights": [1.5],
            "poses_per_spiral": 24,
        }
    )
    s = collect(cfg)
    assert s.models == {"sofa": "cuboid"} and len(s) >= 12
    # the spiral starts on the +x side (bearing 0): beside the sofa's length, angle ≈ 90°
    assert s.angle[0] == pytest.approx(np.pi / 2, abs=0.3)
    det = s.detected & np.isfinite(s.errors[:, 2])
    assert det.sum() >= 6
    # length error (the longer side: about 1.6-2.2 m) stays within a metre of the truth
    assert np.all(np.abs(s.errors[det, 2]) < 1.0)


def test_characterise_rejects_a_class_without_specimen(tmp_path):
    from amslam.apps.characterisation import characterise
    from amslam.errors import AmslamError

    with pytest.raises(AmslamError, match="no specimen for bicycle; known: car, pole, chair"):
        characterise(tmp_path / "m.npz", classes=["chair", "bicycle"], log=lambda s: None)


def test_keep_carries_the_other_classes_and_a_bad_file_fails_before_flying(tmp_path):
    from amslam.apps.characterisation import SPECIMENS, characterise
    from amslam.errors import AmslamError
    from amslam.lib.uncertainty import DEFAULT_MODELS_PATH, UncertaintyModels

    cfg = _config().model_copy(
        update={
            "targets": [SPECIMENS["chair"]],
            "range_min": 1.0,
            "range_max": 5.0,
            "heights": [0.9, 1.5],
            "poses_per_spiral": 60,
        }
    )
    samples = tmp_path / "chair-samples.npz"
    collect(cfg).save(samples)
    out = tmp_path / "models.npz"
    models = characterise(out, samples_in=samples, keep=DEFAULT_MODELS_PATH, log=lambda s: None)
    packaged = UncertaintyModels.load(DEFAULT_MODELS_PATH)
    back = UncertaintyModels.load(out)
    assert set(back.classes) == set(packaged.classes) == set(models.classes)
    assert back.meta["kept"]["classes"] == [c for c in packaged.classes if c != "chair"]
    # the chair is the new fit, the car the packaged one
    assert back["chair"].samples == len(Samples.load(samples)) != packaged["chair"].samples
    assert back["car"].samples == packaged["car"].samples
    # a file that is not a models file is refused before anything is flown or read
    with pytest.raises(AmslamError, match="--keep .*not a models file"):
        characterise(out, samples_in=tmp_path / "missing.npz", keep=samples, log=lambda s: None)
