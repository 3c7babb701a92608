"""Training data, cell assignment and the held-out evaluation (torch is not needed for these)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from amslam.apps.detector_training.dataset import (
    CLASSES,
    CLUTTER,
    Dataset,
    building,
    label_frame,
    random_look,
    render_dataset,
    sample_poses,
)
from amslam.apps.detector_training.evaluate import choose_threshold, evaluate, predict
from amslam.apps.detector_training.evaluate import main as evaluate_main
from amslam.apps.detector_training.train import P2_STRIDES, STRIDES, anchors, assign, make_batch
from amslam.apps.detector_training.train import main as train_main
from amslam.plugins.onnx_detector.decoder import SegmentationModel
from amslam.plugins.sim.camera import CameraParams, Renderer, viewing_pose
from amslam.plugins.sim.world import boxes_mesh, room_shell
from tests.plugins.onnx_detector.graphs import candidates, constant_model
from tests.plugins.sim.test_meshworld import _write_mesh


@pytest.fixture(scope="module")
def tiny_set() -> Dataset:
    return render_dataset([100], 6, width=160, height=120)


def test_rendered_frames_are_labelled_by_instance_masks(tiny_set: Dataset, tmp_path: Path) -> None:
    assert tiny_set.images.shape == (6, 120, 160, 3) and tiny_set.images.dtype == np.uint8
    assert tiny_set.names == CLASSES and set(tiny_set.seeds.tolist()) == {100}
    labelled = 0
    for i in range(len(tiny_set)):
        ids = set(np.unique(tiny_set.instance[i]).tolist()) - {0}
        # every id in the image has a class, every class row entry beyond them is unused
        assert all(0 <= tiny_set.inst_class[i, k] < len(CLASSES) for k in ids)
        for c, m in tiny_set.objects(i):
            assert 0 <= c < len(CLASSES) and m.sum() >= 12
            labelled += 1
    assert labelled > 0, "most poses look at furniture: some frame must show an object"
    tiny_set.save(tmp_path / "d.npz")
    back = Dataset.load(tmp_path / "d.npz")
    np.testing.assert_array_equal(back.instance, tiny_set.instance)
    assert back.names == tiny_set.names


def test_batches_letterbox_images_boxes_and_masks(tiny_set: Dataset) -> None:
    imgs, targets = make_batch(tiny_set, np.arange(len(tiny_set)), 160, None)
    assert imgs.shape == (6, 3, 160, 160) and imgs.min() >= 0.0 and imgs.max() <= 1.0
    for i, t in enumerate(targets):
        objs = tiny_set.objects(i)
        assert len(t["boxes"]) == len(objs)
        for (c, m), box, cls in zip(objs, t["boxes"], t["classes"], strict=True):
            ys, xs = np.nonzero(m)
            # centred letterbox: 160×120 into 160×160 puts the image 20 rows down
            np.testing.assert_array_equal(box, [xs.min(), ys.min() + 20, xs.max() + 1, ys.max() + 21])
            assert cls == c
        assert t["masks"].shape == (len(objs), 40, 40)


def test_assignment_by_size_centre_and_smallest_box() -> None:
    a_xy, strides = anchors(320)
    assert len(a_xy) == sum((320 // s) ** 2 for s in STRIDES)
    boxes = np.array(
        [
            [100.0, 100.0, 120.0, 130.0],  # 30 px tall: stride 8 only
            [0.0, 0.0, 300.0, 300.0],  # 300 px: stride 32, and holds the first box
            [10.0, 200.0, 13.0, 204.0],  # 4 px: no cell centre inside, gets the nearest one
        ]
    )
    which = assign(boxes, a_xy, strides)
    small = np.flatnonzero(which == 0)
    assert len(small) > 0 and set(strides[small].tolist()) == {8.0}
    inside = (a_xy[small] > boxes[0, :2]) & (a_xy[small] < boxes[0, 2:])
    assert inside.all()
    big = np.flatnonzero(which == 1)
    assert set(strides[big].tolist()) == {32.0}
    assert np.count_nonzero(which == 2) == 1


def test_stride_4_level_takes_the_small_boxes() -> None:
    a_xy, strides = anchors(320, P2_STRIDES)
    assert len(a_xy) == sum((320 // s) ** 2 for s in P2_STRIDES)
    boxes = np.array(
        [
            [100.0, 100.0, 110.0, 112.0],  # 12 px: stride 4 only
            [200.0, 200.0, 230.0, 230.0],  # 30 px: strides 4 and 8
            [0.0, 0.0, 300.0, 300.0],  # 300 px: stride 32
        ]
    )
    which = assign(boxes, a_xy, strides)
    small = np.flatnonzero(which == 0)
    assert len(small) >= 4 and set(strides[small].tolist()) == {4.0}
    assert set(strides[which == 1].tolist()) == {4.0, 8.0}
    assert set(strides[which == 2].tolist()) == {32.0}


def test_evaluation_counts_on_a_known_model(tmp_path: Path) -> None:
    """One 160×120 frame with one chair; a model predicting exactly it, plus one false table."""
    inst = np.zeros((1, 120, 160), np.int16)
    inst[0, 40:80, 40:80] = 1
    data = Dataset(
        np.zeros((1, 120, 160, 3), np.uint8),
        inst,
        np.array([[-1, 0]], np.int16),
        np.array([0]),
        ("chair", "table"),
    )
    # 160×120 → 320×320 input: scale 2, 40-pixel borders above and below
    out0 = candidates(
        [((120.0, 160.0, 80.0, 80.0), [0.9, 0.0], [1.0]), ((260.0, 100.0, 40.0, 40.0), [0.0, 0.8], [1.0])]
    )
    protos = np.zeros((1, 32, 80, 80), np.float32)
    protos[0, 0] = 20.0
    model = SegmentationModel(constant_model(tmp_path / "m.onnx", out0, protos))
    for match in ("mask", "box"):
        res = evaluate(model, data, conf=0.25, match=match)
        assert (res["chair"].tp, res["chair"].fp, res["chair"].fn) == (1, 0, 0)
        assert res["chair"].mask_iou == pytest.approx(1.0)
        assert (res["table"].tp, res["table"].fp) == (0, 1)
        assert res["all"].precision == pytest.approx(0.5) and res["all"].recall == pytest.approx(1.0)
    # the false table scores 0.8: a threshold above it keeps only the chair (F1 1 instead of 2/3)
    best, rows = choose_threshold([predict(model, data, conf=0.25)], [data], (0.5, 0.85))
    assert best == 0.85 and [c.fp for _, c in rows] == [1, 0]


def test_a_cached_training_set_of_other_buildings_is_refused(tiny_set: Dataset, tmp_path: Path) -> None:
    cache = tmp_path / "train.npz"
    tiny_set.save(cache)  # seed 100, 6 frames
    out = tmp_path / "m.onnx"
    with pytest.raises(SystemExit, match="other buildings or frames"):
        train_main(["--data", str(cache), "--seeds", "2", "--frames", "6", "--out", str(out)])
    with pytest.raises(SystemExit, match="other buildings or frames"):
        train_main(["--data", str(cache), "--seeds", "1", "--frames", "4", "--out", str(out)])
    assert not out.exists()


def test_randomised_looks_change_the_images_not_the_labels() -> None:
    world = building(100)
    cp = CameraParams(width=160, height=120)
    renderer = Renderer(cp.model(), cp)
    T = sample_poses(world, 1, np.random.default_rng(1))[0]
    plain = renderer.render(world, T, np.random.default_rng(2))
    for k in range(3):
        look = random_look(world, np.random.default_rng(k))
        looked = renderer.render(world, T, np.random.default_rng(2), look)
        np.testing.assert_array_equal(looked.instance, plain.instance)
        assert np.abs(looked.rgb.astype(int) - plain.rgb.astype(int)).mean() > 10


def test_randomised_buildings_vary_and_their_clutter_is_background() -> None:
    plain, varied = building(101), building(101, randomise=True)
    assert building(101, randomise=True).n_triangles == varied.n_triangles  # a seed is one building
    clutter = [o for o in varied.objects if o.class_name == CLUTTER]
    assert len(clutter) >= 3 and not any(o.class_name == CLUTTER for o in plain.objects)
    heights = {round(float(o.hi[2] - o.lo[2]), 3) for o in varied.objects if o.class_name == "chair"}
    assert len(heights) > 3, "each chair is stretched on its own"
    cp = CameraParams(width=160, height=120)
    renderer = Renderer(cp.model(), cp)
    seen = 0
    for o in clutter:
        T = viewing_pose(varied, o.centroid, cp.model().T_body_cam, distance=2.0, height=o.centroid[2])
        r = renderer.render(varied, T, np.random.default_rng(0))
        instance, labels = label_frame(varied, r.instance, CLASSES, 12)
        shown = r.instance == o.instance_id
        if shown.sum() >= 12:
            seen += 1
            assert np.all(instance[shown] == 0)
        for new_id in np.unique(instance[instance > 0]).tolist():  # what stays labelled keeps its class
            (old_id,) = np.unique(r.instance[instance == new_id])
            assert CLASSES[labels[new_id]] == varied.class_names[varied.instance_class[old_id]]
    assert seen > 0


@pytest.fixture
def little_mesh_world(tmp_path: Path) -> Path:
    """A 6×4×3 m room in one PLY, a chair and a table box in it, the objects file in Gazebo's classes."""
    room = [
        *room_shell((6.0, 4.0, 3.0)),
        ([4.0, 1.0, 0.0], [4.5, 1.5, 0.9]),
        ([1.0, 2.5, 0.0], [2.2, 3.3, 0.75]),
        ([5.4, 3.4, 0.0], [5.9, 3.9, 1.2]),
    ]
    folder = tmp_path / "little"
    folder.mkdir()
    _write_mesh(folder / "world.ply", *boxes_mesh([(np.array(a), np.array(b)) for a, b in room]))
    objs = [
        {"name": "c1", "class": "ChairB", "bounds": [[3.99, 0.99, -0.01], [4.51, 1.51, 0.91]]},
        {"name": "t1", "class": "KitchenTable", "bounds": [[0.99, 2.49, -0.01], [2.21, 3.31, 0.76]]},
        {"name": "n1", "class": "NightStand", "bounds": [[5.39, 3.39, -0.01], [5.91, 3.91, 1.21]]},
    ]
    (folder / "objects.json").write_text(json.dumps({"objects": objs}))
    return folder


def test_a_mesh_world_renders_frames_labelled_through_the_class_map(little_mesh_world: Path) -> None:
    data = render_dataset([], 0, width=160, height=120, mesh_worlds=(little_mesh_world,), mesh_frames=12)
    assert len(data) == 12 and set(data.seeds.tolist()) == {-1} and set(data.sources.tolist()) == {"little"}
    classes = {data.names[c] for i in range(len(data)) for c, _ in data.objects(i)}
    # KitchenTable is a table by the packaged class map; the night stand (a cabinet) is background
    assert classes == {"chair", "table"}
    both = Dataset.concatenate([render_dataset([100], 2, width=160, height=120), data])
    assert len(both) == 14 and both.sources[0] == "seed 100" and both.sources[-1] == "little"


def test_evaluating_on_a_missing_mesh_world_names_it(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        evaluate_main(["--world", str(tmp_path / "nowhere"), "--seeds", ""])
    assert f"--world {tmp_path / 'nowhere'}: no world.ply" in capsys.readouterr().err


def test_plain_buildings_on_top_need_randomised_ones(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        train_main(["--with-plain", "--no-randomise", "--out", str(tmp_path / "m.onnx")])
    assert "--with-plain adds unrandomised buildings to randomised ones" in capsys.readouterr().err


def test_a_cache_written_before_sources_were_kept_still_loads(tiny_set: Dataset, tmp_path: Path) -> None:
    np.savez_compressed(
        tmp_path / "old.npz",
        images=tiny_set.images,
        instance=tiny_set.instance,
        inst_class=tiny_set.inst_class,
        seeds=tiny_set.seeds,
        names=np.array(tiny_set.names),
    )
    old = Dataset.load(tmp_path / "old.npz")
    assert old.sources.tolist() == ["seed 100"] * len(tiny_set)
