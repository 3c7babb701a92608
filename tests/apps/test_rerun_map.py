"""The map a rerun replay shows: ``map.ply`` in either PLY encoding, else the voxels of ``map.npz``."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.apps.rerun_view.replay import read_map


def test_without_map_ply_the_occupied_voxels_of_map_npz_are_shown(tmp_path):
    index = np.array([[0, 0, 0], [1, 2, 3], [4, 0, 1]])
    np.savez_compressed(
        tmp_path / "map.npz",
        format=np.array("amslam-voxels-1"),
        global_index=index,
        global_logodds=np.array([3.47, -1.99, 1.38], np.float32),  # occupied from logit(0.8) = 1.386
        global_voxel=np.array(0.25),
    )
    points, voxel, classes = read_map(tmp_path)
    assert voxel == 0.25 and classes is None
    assert points.tolist() == [[0.125, 0.125, 0.125]]  # 1.38 < logit(0.8): not occupied


def test_a_binary_ply_with_a_class_per_voxel_gives_the_classes(tmp_path):
    vertices = np.array(
        [(0.125, 0.125, 0.125, 2), (0.375, 0.125, 0.125, 2), (1.125, 0.625, 0.375, 5)],
        dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("class", "u1")],
    )
    header = (
        "ply\nformat binary_little_endian 1.0\nobj_info class 0 none\nobj_info class 2 chair\n"
        "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar class\nend_header\n"
    )
    (tmp_path / "map.ply").write_bytes(header.encode() + vertices.tobytes())
    points, voxel, classes = read_map(tmp_path)
    assert points == pytest.approx(
        np.array([[0.125, 0.125, 0.125], [0.375, 0.125, 0.125], [1.125, 0.625, 0.375]])
    )
    assert voxel == 0.25
    assert classes == ["chair", "chair", "class 5"]  # a class the file does not name


def test_no_map_file_is_an_empty_map(tmp_path):
    points, voxel, classes = read_map(tmp_path)
    assert points.shape == (0, 3) and voxel is None and classes is None
