"""The YOLOv8-seg decoder on hand-built ONNX graphs whose constant outputs encode known instances."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.plugins.onnx_detector.decoder import (
    Letterbox,
    ModelError,
    SegmentationModel,
    inspect_model,
    letterbox,
    parse_names,
)
from tests.plugins.onnx_detector.graphs import candidates, constant_model

NAMES = "{0: 'chair', 1: 'table'}"


def _protos(size: int = 320) -> np.ndarray:
    """Prototypes at input/4: channel 0 is +20 everywhere, channel 1 is +20 on columns < 20 else −20."""
    p = np.zeros((1, 32, size // 4, size // 4), np.float32)
    p[0, 0] = 20.0
    p[0, 1] = -20.0
    p[0, 1, :, :20] = 20.0
    return p


def _scene_model(tmp_path: Path) -> Path:
    """640×480 image → 320×320 input: scale ½, 40-pixel borders above and below.

    A: chair, original box [100, 80, 300, 400] → input [50, 80, 150, 240], mask = whole box.
    B: chair, a near-duplicate of A with a lower score → removed by NMS.
    C: table over A (other class: NMS keeps it), original [120, 100, 280, 380]; its mask is the
       prototype-1 half plane: input x < 80, i.e. original u < 160.
    D: chair below the confidence threshold.
    """
    out0 = candidates(
        [
            ((100.0, 160.0, 100.0, 160.0), [0.9, 0.05], [1.0]),
            ((102.0, 161.0, 100.0, 160.0), [0.8, 0.05], [1.0]),
            ((100.0, 160.0, 80.0, 140.0), [0.1, 0.7], [0.0, 1.0]),
            ((250.0, 200.0, 40.0, 40.0), [0.2, 0.1], [1.0]),
        ]
    )
    return constant_model(tmp_path / "scene.onnx", out0, _protos(), metadata={"names": NAMES})


def test_inspect_reads_layout_and_names(tmp_path: Path) -> None:
    info = inspect_model(_scene_model(tmp_path))
    assert info.input_hw == (320, 320)
    assert (info.num_classes, info.num_masks) == (2, 32)
    assert info.names == ("chair", "table")


def test_letterbox_of_a_640x480_image() -> None:
    img = np.zeros((480, 640, 3), np.uint8)
    img[:, :, 0] = 255
    blob, lb = letterbox(img, (320, 320))
    assert blob.shape == (1, 3, 320, 320) and blob.dtype == np.float32
    assert lb == Letterbox((480, 640), (240, 320), (0, 40), (320, 320))
    np.testing.assert_allclose(blob[0, :, :40], 114 / 255, rtol=1e-6)  # grey border above
    np.testing.assert_allclose(blob[0, 0, 40:280], 1.0)  # the red image in the middle
    np.testing.assert_allclose(blob[0, :, 280:], 114 / 255, rtol=1e-6)


def test_boxes_classes_nms_and_letterbox_undo(tmp_path: Path) -> None:
    model = SegmentationModel(_scene_model(tmp_path))
    found = model(np.zeros((480, 640, 3), np.uint8), conf=0.25, iou=0.5)
    assert [(i.class_id, round(i.score, 6)) for i in found] == [(0, 0.9), (1, 0.7)]
    np.testing.assert_allclose(found[0].box, [100, 80, 300, 400], atol=1e-4)
    np.testing.assert_allclose(found[1].box, [120, 100, 280, 380], atol=1e-4)


def test_masks_are_cropped_to_the_box_in_original_pixels(tmp_path: Path) -> None:
    model = SegmentationModel(_scene_model(tmp_path))
    chair, table = model(np.zeros((480, 640, 3), np.uint8), conf=0.25, iou=0.5)
    expected = np.zeros((480, 640), bool)
    expected[80:400, 100:300] = True
    np.testing.assert_array_equal(chair.mask, expected)
    # the half plane ends at input x = 80 = original u 160; cropped to the table's box
    expected = np.zeros((480, 640), bool)
    expected[100:380, 120:160] = True
    np.testing.assert_array_equal(table.mask, expected)


def test_nms_threshold_and_max_det(tmp_path: Path) -> None:
    model = SegmentationModel(_scene_model(tmp_path))
    img = np.zeros((480, 640, 3), np.uint8)
    # the duplicate overlaps A with IoU ≈ 0.96: kept only when NMS allows more overlap than that
    assert len(model(img, conf=0.25, iou=0.99)) == 3
    assert len(model(img, conf=0.15, iou=0.5)) == 3  # D passes a lower threshold
    assert [i.score for i in model(img, conf=0.15, iou=0.5, max_det=1)] == [pytest.approx(0.9)]
    assert model(img, conf=0.95) == []


def test_non_square_input_and_pillarbox(tmp_path: Path) -> None:
    """A 480×640 portrait image into a 256×320 (h×w) input: scale 0.4, 64-pixel side borders."""
    # original box [50, 100, 250, 400] → input x = 0.4 u + 64, y = 0.4 v: [84, 40, 164, 160]
    out0 = candidates([((124.0, 100.0, 80.0, 120.0), [0.8], [1.0])])
    protos = np.full((1, 32, 64, 80), 0.0, np.float32)
    protos[0, 0] = 20.0
    path = constant_model(tmp_path / "wide.onnx", out0, protos, input_hw=(256, 320))
    model = SegmentationModel(path)
    assert model.info.input_hw == (256, 320) and model.info.names == ()
    (inst,) = model(np.zeros((640, 480, 3), np.uint8))
    np.testing.assert_allclose(inst.box, [50, 100, 250, 400], atol=1e-4)
    expected = np.zeros((640, 480), bool)
    expected[100:400, 50:250] = True
    np.testing.assert_array_equal(inst.mask, expected)


def test_dynamic_input_size_comes_from_imgsz_metadata(tmp_path: Path) -> None:
    out0 = candidates([((100.0, 100.0, 20.0, 20.0), [0.8], [1.0])])
    path = constant_model(
        tmp_path / "dyn.onnx",
        out0,
        _protos(),
        input_hw=("height", "width"),
        metadata={"imgsz": "[320, 320]", "names": "{0: 'chair'}"},
    )
    assert inspect_model(path).input_hw == (320, 320)


def test_parse_names() -> None:
    assert parse_names("{0: 'person', 1: 'bicycle'}") == ("person", "bicycle")
    assert parse_names("['a', 'b']") == ("a", "b")
    with pytest.raises(ValueError):
        parse_names("{1: 'a'}")


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("missing", "not found"),
        ("garbage", "not a readable ONNX model"),
        ("one_output", "expected 2 outputs"),
        ("names", "'names' metadata lists 3 classes"),
    ],
)
def test_malformed_models_are_rejected(tmp_path: Path, case: str, message: str) -> None:
    path = tmp_path / f"{case}.onnx"
    if case == "garbage":
        path.write_bytes(b"\x08\x07not a protobuf" * 10)
    elif case == "one_output":
        import onnx
        from onnx import TensorProto, helper

        graph = helper.make_graph(
            [helper.make_node("Identity", ["images"], ["output0"])],
            "det",
            [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 32, 32])],
            [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 3, 32, 32])],
        )
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
        model.ir_version = 8
        onnx.save(model, str(path))
    elif case == "names":
        out0 = candidates([((10.0, 10.0, 4.0, 4.0), [0.5, 0.5], [1.0])])
        constant_model(path, out0, _protos(), metadata={"names": "{0: 'a', 1: 'b', 2: 'c'}"})
    with pytest.raises(ModelError, match=message):
        inspect_model(path)
