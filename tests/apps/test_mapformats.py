"""The map in other tools' formats: the binary map.ply, OctoMap .bt out and back in as a prior."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from amslam.apps.mapformats import (
    MapCloud,
    landmark_classes,
    probabilities_from_saved_map,
    read_map_ply,
    write_map_ply,
)
from amslam.lib.octomap_files import OctomapFileError, read_bt, write_bt
from amslam.lib.voxel_grid import OCCUPIED, logit
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.testing.mapping import AREA, CAMERA, box_depth, camera_pose, make_context
from amslam.types import Landmark

VOXEL = 0.25


def _cloud() -> MapCloud:
    points = (np.array([[0, 0, 0], [1, 0, 0], [4, 2, 1], [-3, 5, 7]]) + 0.5) * VOXEL
    return MapCloud(
        points=points,
        classes=np.array([0, 2, 1, 0], np.uint8),
        probability=np.array([0.81, 0.97, 0.9, np.nan], np.float32),
        voxel_size=VOXEL,
        class_names=("none", "chair", "table"),
    )


def test_map_ply_is_binary_with_class_probability_and_voxel_size(tmp_path):
    from plyfile import PlyData

    path = write_map_ply(tmp_path / "map.ply", _cloud())
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    data = PlyData.read(str(path))  # a reader that is not ours
    assert "voxel_size 0.25" in data.obj_info
    assert {"class 0 none", "class 1 chair", "class 2 table"} <= set(data.obj_info)
    vertex = data["vertex"].data
    assert vertex.dtype.names == ("x", "y", "z", "class", "probability")
    np.testing.assert_array_equal(vertex["class"], [0, 2, 1, 0])
    again = read_map_ply(path)
    np.testing.assert_allclose(again.points, _cloud().points)
    np.testing.assert_array_equal(again.classes, _cloud().classes)
    np.testing.assert_allclose(again.probability, _cloud().probability)  # NaN stays NaN
    assert again.voxel_size == VOXEL and again.class_names == ("none", "chair", "table")


def test_open3d_reads_class_and_probability_as_attributes(tmp_path):
    import open3d as o3d

    path = write_map_ply(tmp_path / "map.ply", _cloud())
    cloud = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_allclose(cloud.point.positions.numpy(), _cloud().points, atol=1e-6)
    np.testing.assert_array_equal(cloud.point["class"].numpy().reshape(-1), [0, 2, 1, 0])
    np.testing.assert_allclose(cloud.point["probability"].numpy().reshape(-1)[:3], [0.81, 0.97, 0.9], 1e-6)


def test_an_older_ascii_map_ply_still_reads(tmp_path):
    path = tmp_path / "map.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n0.125 0.125 0.125\n1.375 0.125 2.625\n"
    )
    cloud = read_map_ply(path)
    assert len(cloud) == 2 and cloud.voxel_size is None and cloud.class_names == ("none",)
    np.testing.assert_array_equal(cloud.classes, [0, 0])
    assert np.isnan(cloud.probability).all()
    path.write_text("solid not a ply\n")
    with pytest.raises(ValueError, match="not a PLY"):
        read_map_ply(path)


def test_voxels_take_the_class_of_the_landmark_holding_them():
    points = np.array([[0.0, 0.0, 0.5], [0.3, 0.0, 0.5], [3.0, 0.0, 0.5], [3.9, 0.0, 0.5], [9.0, 9.0, 0.5]])
    box = {"model": "cuboid", "center": [3.5, 0.0, 0.5], "yaw": 0.0, "dims": [2.0, 1.0, 1.0]}
    landmarks = [
        Landmark(0, "chair", np.array([0.1, 0.0, 0.5]), np.eye(3) * 0.01, 5),  # no shape: a radius
        Landmark(1, "table", np.array(box["center"]), np.eye(3) * 0.01, 5, shape=box),
    ]
    classes, names = landmark_classes(points, landmarks, VOXEL)
    assert names == ("none", "chair", "table")
    assert [names[c] for c in classes] == ["chair", "chair", "table", "table", "none"]


def test_probability_comes_from_the_saved_log_odds(tmp_path):
    saved = tmp_path / "map.npz"
    np.savez(
        saved,
        global_index=np.array([[0, 0, 0], [4, 2, 1]]),
        global_logodds=np.array([logit(0.9), logit(0.85)], np.float32),
        global_voxel=np.array(VOXEL),
    )
    points = (np.array([[4, 2, 1], [0, 0, 0], [7, 7, 7]]) + 0.5) * VOXEL
    p = probabilities_from_saved_map(points, saved, VOXEL)
    np.testing.assert_allclose(p[:2], [0.85, 0.9], rtol=1e-6)
    assert np.isnan(p[2])  # not in the saved map
    assert np.isnan(probabilities_from_saved_map(points, tmp_path / "missing.npz", VOXEL)).all()


# ------------------------------------------------------------------ OctoMap .bt
pytest.importorskip("pyoctomap", reason="OctoMap files need pyoctomap (amslam[interop])")


def _as_set(index: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(int(v) for v in row) for row in index}


def test_bt_round_trip_keeps_every_voxel_and_its_state(tmp_path):
    rng = np.random.default_rng(1)
    index = np.unique(rng.integers(-40, 40, size=(3000, 3)), axis=0)
    occupied = rng.random(len(index)) < 0.3
    block = np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3) + 100
    index = np.vstack([index, block])  # a whole 8³ block: OctoMap prunes it into one leaf
    occupied = np.concatenate([occupied, np.ones(len(block), bool)])
    path = write_bt(tmp_path / "map.bt", index, occupied, VOXEL)
    assert path.read_bytes().startswith(b"# Octomap OcTree binary file")
    back, back_occupied = read_bt(path, VOXEL)
    assert _as_set(back) == _as_set(index)
    assert _as_set(back[back_occupied]) == _as_set(index[occupied])


def test_bt_of_another_resolution_is_resampled_and_occupied_wins(tmp_path):
    # a coarse 0.5 m occupied voxel covers eight 0.25 m ones
    coarse = write_bt(tmp_path / "coarse.bt", np.array([[0, 0, 0]]), np.array([True]), 0.5)
    index, occupied = read_bt(coarse, VOXEL)
    assert _as_set(index) == _as_set(np.stack(np.meshgrid(*[[0, 1]] * 3, indexing="ij"), -1).reshape(-1, 3))
    assert occupied.all()
    # eight 0.125 m voxels in one 0.25 m voxel, one occupied: it is occupied
    fine_index = np.stack(np.meshgrid(*[[0, 1]] * 3, indexing="ij"), -1).reshape(-1, 3)
    fine = write_bt(tmp_path / "fine.bt", fine_index, np.arange(8) == 3, 0.125)
    index, occupied = read_bt(fine, VOXEL)
    assert _as_set(index) == {(0, 0, 0)} and occupied.tolist() == [True]


def test_a_file_that_is_not_an_octree_is_one_clear_error(tmp_path):
    bad = tmp_path / "map.bt"
    bad.write_bytes(b"PK\x03\x04 a zip file")
    with pytest.raises(OctomapFileError, match=r"map\.bt: not an OctoMap binary tree"):
        read_bt(bad, VOXEL)
    truncated = tmp_path / "cut.bt"
    write_bt(truncated, np.zeros((1, 3), int), np.ones(1, bool), VOXEL)
    truncated.write_bytes(truncated.read_bytes()[:60])
    with pytest.raises(OctomapFileError, match="could not read"):
        read_bt(truncated, VOXEL)


def test_without_pyoctomap_the_error_says_what_to_install(tmp_path, monkeypatch):
    path = write_bt(tmp_path / "map.bt", np.zeros((1, 3), int), np.ones(1, bool), VOXEL)
    monkeypatch.setitem(sys.modules, "pyoctomap", None)  # import pyoctomap now raises ImportError
    with pytest.raises(OctomapFileError, match=r"needs pyoctomap: pip install 'amslam\[interop\]'"):
        read_bt(path, VOXEL)


@pytest.mark.parametrize("backend", [NumpyVoxelMap, Open3dVoxelMap])
def test_a_bt_loads_as_the_global_map(backend, tmp_path):
    seen = backend()
    seen.configure(backend.Params(), make_context(tmp_path))
    seen.integrate_global(box_depth(), CAMERA.K, camera_pose())
    index, states = seen.global_map.voxels()
    occupied = states == OCCUPIED
    assert occupied.sum() > 10 and (~occupied).sum() > 100
    path = write_bt(tmp_path / "seen.bt", index, occupied, seen.voxel_size())

    prior = backend()
    prior.configure(backend.Params(), make_context(tmp_path))
    prior.load(path)
    np.testing.assert_allclose(
        np.sort(prior.occupied_points(), axis=0), np.sort(seen.occupied_points(), axis=0)
    )
    grid = np.stack(
        np.meshgrid(*[np.arange(lo, hi, VOXEL) + 0.1 for lo, hi in zip(AREA.lo, AREA.hi, strict=True)]), -1
    ).reshape(-1, 3)
    np.testing.assert_array_equal(prior.states(grid), seen.states(grid))  # free space too
    assert len(prior.viewpoints()) > 0  # frontiers recomputed from the loaded map


def test_amslam_map_refuses_bad_input_in_one_line(tmp_path, capsys):
    from amslam.cli import main

    run = tmp_path / "run"
    run.mkdir()
    cases = [
        (["map", str(tmp_path / "nope"), "--bt", "x.bt"], f"error: {tmp_path}/nope: no such run folder"),
        (["map", str(run), "--bt", "x.ot"], "error: --bt x.ot: the file name must end in .bt"),
        (["map", str(run), "--bt", "x.bt"], f"error: {run}: no map.ply (is it a finished run folder?)"),
    ]
    for argv, line in cases:
        assert main(argv) == 2
        assert capsys.readouterr().err.splitlines() == [line]


def test_amslam_map_writes_the_runs_map_as_a_bt(tmp_path, capsys):
    from amslam.cli import main

    run = tmp_path / "run"
    run.mkdir()
    write_map_ply(run / "map.ply", _cloud())
    np.savez(
        run / "map.npz",
        global_index=np.vstack([np.floor(_cloud().points / VOXEL).astype(int), [[9, 9, 9], [9, 9, 8]]]),
        global_logodds=np.zeros(6, np.float32),
        global_voxel=np.array(VOXEL),
    )
    assert main(["map", str(run), "--bt", str(tmp_path / "map.bt")]) == 0
    assert capsys.readouterr().out.startswith(f"{tmp_path}/map.bt: 4 occupied and 2 free voxels")
    index, occupied = read_bt(tmp_path / "map.bt", VOXEL)
    assert _as_set(index[occupied]) == _as_set(np.floor(_cloud().points / VOXEL).astype(int))
    assert _as_set(index[~occupied]) == {(9, 9, 9), (9, 9, 8)}
    # a folder of runs, as `amslam view` and `amslam export` take it: its newest
    (run / "events.jsonl").write_text("")
    assert main(["map", str(tmp_path), "--bt", str(tmp_path / "newest.bt")]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"newest run in {tmp_path}: {run}\n{tmp_path}/newest.bt: 4 occupied")
