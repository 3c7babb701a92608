"""The ``onnx`` detector: model validation, the 3-D step, and the shipped model on a rendered frame."""

from __future__ import annotations

import functools
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from amslam.errors import AmslamError, MissionError
from amslam.interfaces import RunContext
from amslam.mission import load_mission
from amslam.plugins.onnx_detector.decoder import Instance
from amslam.plugins.onnx_detector.detector import (
    OnnxDetector,
    largest_depth_cluster,
    largest_surface,
    relief,
    shipped_model,
)
from amslam.plugins.sim.camera import viewing_pose
from amslam.plugins.sim.platform import SimPlatform
from amslam.testing.detector import DetectorContract
from amslam.types import Frame
from tests.plugins.onnx_detector.graphs import candidates, constant_model


@functools.cache
def chair_frame() -> tuple[Frame, list[tuple[str, np.ndarray]]]:
    """A 320×240 frame (the demo camera) of a chair of the seed-7 building, and its mask centroid."""
    plat = SimPlatform()
    plat.configure(
        SimPlatform.Params(camera={"width": 320, "height": 240}),
        RunContext(rng=np.random.default_rng(7), run_dir=Path(".")),
    )
    plat.start()
    world = plat.world
    chair = next(o for o in world.objects if o.class_name == "chair")
    T_wc = viewing_pose(world, chair.centroid, plat.camera.T_body_cam, distance=2.0)
    r = plat._renderer.render(world, T_wc, np.random.default_rng(0))
    cam = plat.camera
    frame = Frame(1.0, r.depth, cam.K.copy(), T_wc, r.rgb, r.instance, r.class_id, world.class_names, T_wc)
    mask = (r.instance == chair.instance_id) & (r.depth > 0)
    v, u = np.nonzero(mask)
    z = r.depth[v, u]
    pts = np.stack([(u - cam.K[0, 2]) / cam.K[0, 0] * z, (v - cam.K[1, 2]) / cam.K[1, 1] * z, z], 1)
    return frame, [("chair", np.median(pts, axis=0))]


class TestOnnxDetectorContract(DetectorContract):
    def make_backend(self) -> OnnxDetector:
        return OnnxDetector()

    def scene(self):
        return chair_frame()


def test_registered_as_onnx(registry) -> None:
    assert registry.backend_class("detector", "onnx") is OnnxDetector


def test_shipped_model_finds_the_chair(tmp_path: Path) -> None:
    det = OnnxDetector()
    det.configure(OnnxDetector.Params(), RunContext(rng=np.random.default_rng(0), run_dir=tmp_path))
    assert det.names == ("chair", "table", "shelf", "sofa")
    frame, [(_, centroid)] = chair_frame()
    chairs = [d for d in det.detect(frame) if d.class_name == "chair"]
    best = min(chairs, key=lambda d: np.linalg.norm(d.centroid_cam - centroid))
    assert np.linalg.norm(best.centroid_cam - centroid) < 0.15
    assert best.confidence >= 0.4 and 50 <= len(best.points_cam) <= 400


# ------------------------------------------------------------------------- validation of the model


def _write_mission(tmp_path: Path, detector: str) -> Path:
    path = tmp_path / "mission.yaml"
    path.write_text(f"name: m\ndetector:\n{textwrap.indent(textwrap.dedent(detector), '  ')}")
    return path


def test_default_params_point_at_the_shipped_model() -> None:
    assert shipped_model().is_file()
    assert OnnxDetector.Params().model is None


def test_missing_model_fails_mission_validation_with_its_location(tmp_path: Path, registry) -> None:
    missing = tmp_path / "nowhere" / "model.onnx"
    path = _write_mission(tmp_path, f"plugin: onnx\nmodel: {missing}\n")
    with pytest.raises(MissionError) as info:
        load_mission(path, registry)
    (problem,) = info.value.problems
    assert problem.startswith(f"{path}:4: detector.model:"), problem
    assert "model file not found" in problem and str(missing) in problem


def test_missing_relative_model_fails_mission_validation(tmp_path: Path, registry) -> None:
    # A relative path is looked up beside the mission file, already when the mission is validated.
    path = _write_mission(tmp_path, "plugin: onnx\nmodel: models/absent.onnx\n")
    with pytest.raises(MissionError) as info:
        load_mission(path, registry)
    (problem,) = info.value.problems
    assert problem.startswith(f"{path}:4: detector.model:"), problem
    assert str(tmp_path / "models" / "absent.onnx") in problem


def test_corrupt_model_fails_mission_validation(tmp_path: Path, registry) -> None:
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"this is not an ONNX file")
    path = _write_mission(tmp_path, f"plugin: onnx\nmodel: {bad}\n")
    with pytest.raises(MissionError) as info:
        load_mission(path, registry)
    assert "detector.model:" in info.value.problems[0]
    assert "not a readable onnx model" in info.value.problems[0].lower()


def test_relative_model_is_resolved_against_the_mission_directory(tmp_path: Path) -> None:
    (tmp_path / "models").mkdir()
    out0 = candidates([((10.0, 10.0, 4.0, 4.0), [0.5], [1.0])])
    protos = np.zeros((1, 32, 80, 80), np.float32)
    constant_model(tmp_path / "models" / "m.onnx", out0, protos, metadata={"names": "{0: 'chair'}"})
    ok = OnnxDetector.Params.model_validate({"model": "models/m.onnx"}, context={"mission_dir": tmp_path})
    assert ok.model == "models/m.onnx"
    with pytest.raises(ValidationError, match="model file not found"):
        OnnxDetector.Params.model_validate({"model": "models/x.onnx"}, context={"mission_dir": tmp_path})
    # configure resolves against the run context's mission_dir, and fails before the flight
    det = OnnxDetector()
    ctx = RunContext(rng=np.random.default_rng(0), run_dir=tmp_path, mission_dir=tmp_path)
    det.configure(ok, ctx)
    assert det.names == ("chair",)
    with pytest.raises(AmslamError, match="model file not found"):
        OnnxDetector().configure(OnnxDetector.Params(model="models/x.onnx"), ctx)


def test_class_names_must_match_the_model(tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match="class_names lists 1 classes, the model has 4"):
        OnnxDetector.Params(model=str(shipped_model()), class_names=["chair"])


# ------------------------------------------------------------------------------------ 3-D step


def test_largest_depth_cluster_drops_the_wall_behind() -> None:
    depth = np.full((10, 10), 4.0, np.float32)  # wall
    depth[2:8, 2:8] = 2.0 + np.linspace(0, 0.4, 6)[None]  # a slanted object face, 36 pixels
    mask = np.zeros((10, 10), bool)
    mask[1:9, 1:9] = True  # the mask bleeds one pixel around the object: 28 wall pixels
    kept = largest_depth_cluster(mask, depth, gap=0.3)
    expected = np.zeros_like(mask)
    expected[2:8, 2:8] = True
    np.testing.assert_array_equal(kept, expected)
    np.testing.assert_array_equal(largest_depth_cluster(mask, depth, gap=5.0), mask)


def _two_chairs_in_a_row() -> tuple[np.ndarray, np.ndarray]:
    """Depth of two chair faces at 2.0–2.1 m before a wall at 2.35 m, and a mask over both and the gap."""
    depth = np.full((40, 60), 2.35, np.float32)  # the wall 0.25 m behind: within the depth gap
    depth[5:35, 5:25] = 2.0 + np.linspace(0, 0.1, 20)[None]  # the larger chair, 600 pixels
    depth[10:35, 35:55] = 2.1  # its neighbour, 500 pixels
    mask = np.zeros((40, 60), bool)
    mask[5:35, 5:55] = True  # one mask over both chairs and the wall between them
    return depth, mask


def test_largest_surface_keeps_one_of_two_chairs_the_depth_gap_cannot_split() -> None:
    depth, mask = _two_chairs_in_a_row()
    by_depth = largest_depth_cluster(mask, depth, gap=0.3)
    np.testing.assert_array_equal(by_depth, mask)  # chairs and wall: one depth cluster
    kept = largest_surface(by_depth, depth, step=0.05, slope=0.03)
    expected = np.zeros_like(mask)
    expected[5:35, 5:25] = True
    np.testing.assert_array_equal(kept, expected)


def test_largest_surface_keeps_a_slanted_face_and_a_noisy_one_whole() -> None:
    # a floor-like face seen at a grazing angle: 0.06 m deeper every row, from 1.5 to 5.0 m
    slanted = np.repeat((1.5 + 0.06 * np.arange(60))[:, None], 30, axis=1).astype(np.float32)
    mask = np.ones_like(slanted, dtype=bool)
    np.testing.assert_array_equal(largest_surface(mask, slanted, step=0.05, slope=0.03), mask)
    # a face at 4 m with the simulated camera's depth noise (σ = 0.005·z², 8 cm)
    rng = np.random.default_rng(3)
    noisy = (4.0 + rng.normal(0.0, 0.005 * 16, (40, 30))).astype(np.float32)
    mask = np.ones_like(noisy, dtype=bool)
    assert largest_surface(mask, noisy, step=0.05, slope=0.03).mean() > 0.9


class _StubModel:
    """Stands in for the network: returns fixed instances (the 3-D step and mask NMS are under test)."""

    def __init__(self, instances: list[Instance]) -> None:
        self.instances = instances

    def __call__(self, rgb: np.ndarray, **kwargs) -> list[Instance]:  # noqa: ANN003
        return list(self.instances)


def _instance(
    class_id: int, score: float, box: tuple[int, int, int, int], rows: slice | None = None
) -> Instance:
    """An instance on a 320×240 image whose mask fills its box (or only the box's ``rows``)."""
    mask = np.zeros((240, 320), bool)
    u0, v0, u1, v1 = box
    mask[v0:v1, u0:u1] = True
    if rows is not None:
        keep = np.zeros_like(mask)
        keep[rows, u0:u1] = True
        mask &= keep
    return Instance(class_id, score, np.array(box, float), mask)


def _stub_detector(tmp_path: Path, instances: list[Instance], **params) -> tuple[OnnxDetector, Frame]:  # noqa: ANN003
    det = OnnxDetector()
    det.configure(OnnxDetector.Params(**params), RunContext(rng=np.random.default_rng(0), run_dir=tmp_path))
    det._model = _StubModel(instances)
    K = np.array([[160.0, 0.0, 159.5], [0.0, 160.0, 119.5], [0.0, 0.0, 1.0]])
    depth = np.full((240, 320), 4.5, np.float32)  # the room behind
    for inst in instances:
        depth[inst.mask] = 3.0  # each object 1.5 m before it
    frame = Frame(0.0, depth, K, np.eye(4), np.zeros((240, 320, 3), np.uint8))
    return det, frame


def test_mask_nms_drops_parts_and_merges_of_stronger_detections(tmp_path: Path) -> None:
    chair_a = _instance(0, 0.9, (100, 60, 160, 200))
    chair_b = _instance(0, 0.8, (170, 60, 230, 200))
    back_of_a = _instance(0, 0.7, (100, 60, 160, 110))  # box IoU with A 0.36: box NMS keeps it
    a_and_b = _instance(0, 0.5, (100, 60, 230, 200))  # both chairs in one box: IoU 0.46 with each
    table_on_a = _instance(1, 0.6, (100, 60, 160, 200))  # another class: not a duplicate
    instances = [chair_a, chair_b, back_of_a, table_on_a, a_and_b]
    det, frame = _stub_detector(tmp_path, instances)
    found = det.detect(frame)
    assert [(d.class_name, d.confidence) for d in found] == [("chair", 0.9), ("chair", 0.8), ("table", 0.6)]
    det, frame = _stub_detector(tmp_path, instances, duplicate_overlap=1.0)
    assert len(det.detect(frame)) == 5


def test_a_mask_over_two_chairs_lifts_the_larger_one_only(tmp_path: Path) -> None:
    both = _instance(0, 0.9, (100, 60, 150, 90))
    det, frame = _stub_detector(tmp_path, [both])
    depth, mask = _two_chairs_in_a_row()
    frame.depth[55:95, 95:155] = depth  # the instance's box is the mask's rows 5–35, columns 5–55
    both.mask[:] = False
    both.mask[55:95, 95:155] = mask
    (d,) = det.detect(frame)
    assert d.points_cam[:, 2].max() < 2.11  # the larger chair's face: no wall, no neighbour
    assert d.points_cam[:, 0].max() < (120 - 159.5) / 160.0 * 2.1  # nothing right of its columns
    det, frame2 = _stub_detector(tmp_path, [both], surface_step=0.0)
    frame2.depth[55:95, 95:155] = depth
    (d,) = det.detect(frame2)
    assert d.points_cam[:, 2].max() == pytest.approx(2.35)  # without: the wall between them too


def test_a_weaker_detection_on_the_surface_a_stronger_one_left_out_is_still_its_duplicate(
    tmp_path: Path,
) -> None:
    whole = _instance(0, 0.9, (100, 60, 150, 90))  # one object whose mask holds two surfaces
    right_part = _instance(0, 0.6, (130, 60, 150, 90))  # a second box on the smaller surface
    det, frame = _stub_detector(tmp_path, [whole, right_part])
    depth, mask = _two_chairs_in_a_row()
    frame.depth[55:95, 95:155] = depth
    whole.mask[:] = False
    whole.mask[55:95, 95:155] = mask
    right_part.mask[:] = False
    right_part.mask[60:90, 130:150] = True
    (d,) = det.detect(frame)  # the second lies within the first's mask: one object, seen once
    assert d.confidence == 0.9


def test_centroid_height_from_the_box_when_the_mask_misses_the_legs(tmp_path: Path) -> None:
    seat_and_back = _instance(0, 0.9, (100, 60, 160, 200), rows=slice(60, 120))
    det, frame = _stub_detector(tmp_path, [seat_and_back])
    (d,) = det.detect(frame)
    fy, cy = frame.K[1, 1], frame.K[1, 2]
    assert d.centroid_cam[1] == pytest.approx((130.0 - 0.5 - cy) / fy * 3.0)  # the box's middle row
    assert d.centroid_cam[2] == pytest.approx(3.0)
    det, frame = _stub_detector(tmp_path, [seat_and_back], centroid_height="mask")
    (d,) = det.detect(frame)
    assert d.centroid_cam[1] == pytest.approx((89.5 - cy) / fy * 3.0)  # the median of rows 60–119
    # a box cut by the image's bottom edge does not show the object's height: the mask's median
    cut = _instance(0, 0.9, (100, 160, 160, 240), rows=slice(160, 200))
    det, frame = _stub_detector(tmp_path, [cut])
    (d,) = det.detect(frame)
    assert d.centroid_cam[1] == pytest.approx((179.5 - cy) / fy * 3.0)


def test_relief_tells_furniture_from_a_picture_on_the_wall() -> None:
    wall = np.full((60, 80), 4.0, np.float32)
    picture = np.zeros_like(wall, dtype=bool)
    picture[20:40, 30:50] = True
    assert relief(picture, wall, step=0.05, slope=0.03, width=2) == 0.0  # level all round
    chair = wall.copy()
    chair[20:40, 30:50] = 3.0  # a metre before the wall
    chair[40:, :] = 3.0  # standing on the floor, level with its bottom row (and lower rows)
    share = relief(picture, chair, step=0.05, slope=0.03, width=2)
    assert share is not None and 0.6 < share < 0.9  # behind on three sides, level on the fourth
    dropped = wall.copy()
    dropped[np.random.default_rng(0).random(wall.shape) < 0.1] = 0.0  # lone pixels without a depth
    dropped[picture] = 4.0
    assert relief(picture, dropped, step=0.05, slope=0.03, width=2) < 0.02  # they say nothing
    no_return = np.zeros_like(wall)  # nothing within the camera's range around it: room behind
    no_return[20:40, 30:50] = 3.0
    assert relief(picture, no_return, step=0.05, slope=0.03, width=2) == 1.0
    hidden = wall.copy()
    hidden[picture] = 3.0
    hidden[15:45, 25:55] = np.where(picture[15:45, 25:55], 3.0, 1.0)  # something nearer all round
    assert relief(picture, hidden, step=0.05, slope=0.03, width=2) is None  # cannot tell


def test_a_detection_flush_with_the_wall_is_dropped(tmp_path: Path) -> None:
    picture = _instance(3, 0.9, (100, 60, 160, 110))
    det, frame = _stub_detector(tmp_path, [picture])
    frame.depth[:] = 3.0  # the picture is level with the wall around it
    assert det.detect(frame) == []
    det, frame = _stub_detector(tmp_path, [picture], min_relief=0.0)
    frame.depth[:] = 3.0
    assert len(det.detect(frame)) == 1
    det, frame = _stub_detector(tmp_path, [picture], flush_classes=["sofa"])  # a class that may be flush
    frame.depth[:] = 3.0
    assert len(det.detect(frame)) == 1
    det, frame = _stub_detector(tmp_path, [picture])  # a sofa before the wall
    assert len(det.detect(frame)) == 1


def test_a_flush_class_the_model_has_not_is_named(tmp_path: Path) -> None:
    with pytest.raises(AmslamError, match=r"detector.flush_classes: \['tv'\] not among the model's classes"):
        _stub_detector(tmp_path, [], flush_classes=["tv"])
