"""Training data, cell assignment and the held-out evaluation (torch is not needed for these, but
for the one test that trains), and the command lines' answers to bad input."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from amslam.apps.detector_training.dataset import (
    CLASSES,
    CLUTTER,
    Dataset,
    DatasetError,
    building,
    label_frame,
    random_look,
    render_dataset,
    sample_poses,
)
from amslam.apps.detector_training.evaluate import choose_threshold, evaluate, points_on_instance, predict
from amslam.apps.detector_training.evaluate import main as evaluate_main
from amslam.apps.detector_training.train import (
    P2_STRIDES,
    STRIDES,
    anchors,
    assign,
    lr_factor,
    make_batch,
    train,
)
from amslam.apps.detector_training.train import main as train_main
from amslam.errors import AmslamError
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


def test_points_are_counted_on_the_instance_their_pixels_show() -> None:
    K = np.array([[100.0, 0.0, 19.5], [0.0, 100.0, 14.5], [0.0, 0.0, 1.0]])
    instance = np.zeros((30, 40), np.int32)
    instance[:, :20] = 7  # the object fills the image's left half, the wall (0) the right
    v, u = np.mgrid[0:30, 10:30]  # a mask over ten columns of each
    z = np.full(v.size, 3.0)
    pts = np.column_stack([(u.ravel() - 19.5) / 100.0 * z, (v.ravel() - 14.5) / 100.0 * z, z])
    assert points_on_instance(pts, K, instance, 7) == pytest.approx(0.5)
    assert points_on_instance(pts[:0], K, instance, 7) == 0.0


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


def _refused(main, argv: list[str], capsys) -> str:
    """What ``main(argv)`` says on stderr when it stops with exit status 2 (never a traceback)."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize(
    "content",
    [b"not an archive", b"", b"PK\x03\x04 a torn zip"],
    ids=["text", "empty", "torn zip"],
)
def test_a_cache_that_is_no_training_set_is_named(content: bytes, tmp_path: Path) -> None:
    path = tmp_path / "cache.npz"
    path.write_bytes(content)
    with pytest.raises(DatasetError, match=re.escape(str(path))):
        Dataset.load(path)


def test_a_cache_of_other_arrays_or_a_folder_is_named(tiny_set: Dataset, tmp_path: Path) -> None:
    np.save(tmp_path / "one.npy", tiny_set.seeds)
    with pytest.raises(DatasetError, match="one array"):
        Dataset.load(tmp_path / "one.npy")
    np.savez_compressed(tmp_path / "part.npz", images=tiny_set.images, seeds=tiny_set.seeds)
    with pytest.raises(DatasetError, match="no instance, inst_class, names"):
        Dataset.load(tmp_path / "part.npz")
    tiny_set.save(tmp_path / "whole.npz")
    data = (tmp_path / "whole.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="cut.npz"):
        Dataset.load(tmp_path / "cut.npz")
    with pytest.raises(DatasetError, match="IsADirectoryError"):
        Dataset.load(tmp_path)


def test_a_cache_is_saved_under_the_name_given(tiny_set: Dataset, tmp_path: Path) -> None:
    tiny_set.save(tmp_path / "train.cache")  # numpy alone would write train.cache.npz
    assert [f.name for f in tmp_path.iterdir()] == ["train.cache"]
    np.testing.assert_array_equal(Dataset.load(tmp_path / "train.cache").images, tiny_set.images)


def test_training_on_an_unreadable_cache_says_so_in_one_line(tmp_path: Path, capsys) -> None:
    cache = tmp_path / "train.npz"
    cache.write_text("not a training set")
    err = _refused(
        train_main, ["--data", str(cache), "--seeds", "1", "--out", str(tmp_path / "m.onnx")], capsys
    )
    assert err == f"error: {cache}: not an .npz file (a training set written by Dataset.save)\n"


def test_rendering_no_frame_is_refused() -> None:
    with pytest.raises(ValueError, match="no frames to render: 0 buildings"):
        render_dataset([], 3)
    with pytest.raises(ValueError, match="no frames to render: 1 buildings × 0 frames"):
        render_dataset([100], 0)
    with pytest.raises(ValueError, match="a negative frame count"):
        render_dataset([100], -1)


def test_a_mesh_world_with_a_broken_objects_file_is_named(little_mesh_world: Path, capsys) -> None:
    objects = little_mesh_world / "objects.json"
    objects.write_text('{"objects": [1, 2')
    argv = ["--seeds", "", "--world", str(little_mesh_world), "--sizes", "160x120", "--frames", "2"]
    err = _refused(evaluate_main, argv, capsys)
    assert err.startswith("error: not a JSON objects file") and str(objects) in err
    with pytest.raises(AmslamError, match="not a JSON objects file"):
        render_dataset([], 0, mesh_worlds=(little_mesh_world,), mesh_frames=2)


def test_a_mesh_world_without_room_to_fly_is_named(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "crawlspace"
    folder.mkdir()
    _write_mesh(folder / "world.ply", *boxes_mesh(room_shell((6.0, 4.0, 0.8))))
    argv = ["--seeds", "", "--world", str(folder), "--sizes", "160x120", "--frames", "2"]
    err = _refused(evaluate_main, argv, capsys)
    assert err == "error: world crawlspace: no reachable point at flight height\n"


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--model", "NOWHERE"], "NOWHERE: model file not found"),
        (["--model", "COCO"], "the model's classes (['person', 'car', 'dog']) are not the frames'"),
        (["--sizes", "320x"], "argument --sizes: WxH,... such as 320x240,640x480, got '320x'"),
        (["--sizes", "320x240,"], "argument --sizes"),
        (["--frames", "0"], "argument --frames: 0 is not at least 1"),
        (["--seeds", ""], "nothing to evaluate: --seeds '' and no --world"),
        (["--conf", "1.5"], "--conf 1.5: a class score threshold, between 0 and 1"),
        (["--choose-threshold", "--sizes", "640x480"], "--choose-threshold scores the 320×240 frames"),
        (["--centroids", "--seeds", "", "--world", "WORLD"], "--centroids renders procedural buildings"),
    ],
)
def test_evaluation_refuses_bad_arguments_before_rendering(
    argv: list[str], said: str, little_mesh_world: Path, tmp_path: Path, capsys
) -> None:
    coco = constant_model(
        tmp_path / "coco.onnx",
        candidates([((120.0, 160.0, 80.0, 80.0), [0.9, 0.0, 0.1], [1.0])]),
        np.zeros((1, 32, 80, 80), np.float32),
        metadata={"names": "{0: 'person', 1: 'car', 2: 'dog'}"},
    )
    places = {"NOWHERE": str(tmp_path / "none.onnx"), "COCO": str(coco), "WORLD": str(little_mesh_world)}
    said = said.replace("NOWHERE", places["NOWHERE"])
    assert said in _refused(evaluate_main, [places.get(a, a) for a in argv], capsys)


def test_a_model_of_other_classes_is_not_scored(tmp_path: Path) -> None:
    data = Dataset(
        np.zeros((1, 120, 160, 3), np.uint8),
        np.zeros((1, 120, 160), np.int16),
        np.full((1, 1), -1, np.int16),
        np.array([0]),
        ("chair", "table"),
    )
    out0 = candidates([((120.0, 160.0, 80.0, 80.0), [0.9, 0.0, 0.1], [1.0])])
    model = SegmentationModel(
        constant_model(tmp_path / "m.onnx", out0, np.zeros((1, 32, 80, 80), np.float32))
    )
    with pytest.raises(ValueError, match="3 unnamed classes"):
        predict(model, data)


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--seeds", "801"], "--seeds 801: at most 800; the seeds from 900 on are held out"),
        (["--seeds", "-1"], "argument --seeds: -1 is not at least 0"),
        (["--seeds", "0"], "--seeds 0 and no --mesh-worlds: nothing to train on"),
        (["--seeds", "0", "--with-plain", "--mesh-worlds", "WORLD"], "--with-plain renders the --seeds"),
        (["--frames", "0"], "argument --frames: 0 is not at least 1"),
        (["--epochs", "0"], "argument --epochs: 0 is not at least 1"),
        (["--batch", "0"], "argument --batch: 0 is not at least 1"),
        (["--threads", "0"], "argument --threads: 0 is not at least 1"),
        (["--mesh-frames", "0"], "argument --mesh-frames: 0 is not at least 1"),
        (["--size", "100"], "--size 100: not a multiple of 32"),
        (["--lr", "0"], "--lr 0.0: not positive"),
        (["--out", "FILE/m.onnx"], "--out FILE/m.onnx: cannot be written, FILE is a file, not a folder"),
        (["--data", "FILE/d.npz"], "--data FILE/d.npz: cannot be written, FILE is a file, not a folder"),
    ],
)
def test_training_refuses_bad_arguments_before_rendering(
    argv: list[str], said: str, little_mesh_world: Path, tmp_path: Path, capsys
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("")
    before = sorted(tmp_path.rglob("*"))

    def place(a: str) -> str:
        return a.replace("WORLD", str(little_mesh_world)).replace("FILE", str(afile))

    argv = ["--out", str(tmp_path / "out" / "m.onnx"), "--data", str(tmp_path / "d.npz"), *argv]
    assert place(said) in _refused(train_main, [place(a) for a in argv], capsys)
    assert sorted(tmp_path.rglob("*")) == before, "nothing is written"


def test_the_learning_rate_warms_up_then_falls_along_a_cosine() -> None:
    assert [lr_factor(k, 4, 20) for k in range(4)] == [0.25, 0.5, 0.75, 1.0]
    assert lr_factor(4, 4, 20) == pytest.approx(1.0)
    assert lr_factor(12, 4, 20) == pytest.approx(0.51)
    assert lr_factor(20, 4, 20) == pytest.approx(0.02)
    assert lr_factor(0, 0, 5) == pytest.approx(1.0)  # train() gives runs under 10 steps no warm-up


def test_training_writes_into_a_new_folder_and_names_foreign_weights(
    tiny_set: Dataset, tmp_path: Path
) -> None:
    pytest.importorskip("torch")
    pytest.importorskip("onnx")
    out = tmp_path / "new" / "m.onnx"  # the weights (.pt) are saved there before the export
    assert train(tiny_set, out, size=64, epochs=1, batch=6, threads=1) == out
    assert out.is_file() and out.with_suffix(".pt").is_file()
    foreign = tmp_path / "foreign.pt"
    foreign.write_text("not weights")
    with pytest.raises(
        AmslamError, match=re.escape(f"initial weights {foreign}: not weights saved by train.py")
    ):
        train(tiny_set, tmp_path / "m2.onnx", size=64, epochs=1, batch=6, threads=1, init=foreign)
    with pytest.raises(AmslamError, match="not this network's"):  # the weights of a network without --p2
        train(
            tiny_set,
            tmp_path / "m3.onnx",
            size=64,
            batch=6,
            threads=1,
            init=out.with_suffix(".pt"),
            levels=P2_STRIDES,
        )
