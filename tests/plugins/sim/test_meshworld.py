"""Mesh worlds: loading, labelling objects, and the real small_house world."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from amslam.errors import PlatformError
from amslam.plugins.sim.meshworld import MeshWorldParams, load_mesh_world, normalize_class
from amslam.plugins.sim.world import World, box_mesh, boxes_mesh, room_shell
from amslam.plugins.sim.worldpath import unpacked_world

from .conftest import make_platform


def _write_mesh(path: Path, v: np.ndarray, t: np.ndarray) -> None:
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t.astype(np.int32))
    )
    m.compute_triangle_normals()  # the STL writer needs them
    assert o3d.io.write_triangle_mesh(str(path), m)


@pytest.fixture
def tiny_world(tmp_path) -> Path:
    """A 6×4×3 room (walls 0.2 m) with a chair-box and a table-box merged in one PLY file."""
    room = room_shell((6.0, 4.0, 3.0))
    chair = box_mesh(np.array([4.0, 1.0, 0.0]), np.array([4.5, 1.5, 0.9]))
    table = box_mesh(np.array([1.0, 2.5, 0.0]), np.array([2.2, 3.3, 0.75]))
    v, t = boxes_mesh([(np.array(a), np.array(b)) for a, b in room])
    allv = np.concatenate([v, chair[0], table[0]])
    allt = np.concatenate([t, chair[1] + len(v), table[1] + len(v) + 8])
    (tmp_path / "objects").mkdir()
    _write_mesh(tmp_path / "world.ply", allv, allt)
    _write_mesh(tmp_path / "objects" / "chair.obj", *chair)
    shelf = box_mesh(np.array([0.3, 0.3, 0.0]), np.array([1.0, 0.7, 1.8]))  # not in world.ply
    _write_mesh(tmp_path / "objects" / "shelf.stl", *shelf)
    objs = [
        {"name": "c1", "class": "ChairB", "mesh": "objects/chair.obj"},
        {"name": "t1", "class": "DiningTable", "bounds": [[0.99, 2.49, -0.01], [2.21, 3.31, 0.76]]},
        {"name": "s1", "class": "Shelf", "mesh": "objects/shelf.stl"},
        {"name": "w", "class": "RoomWall", "bounds": [[-0.2, -0.2, 0.0], [0.0, 4.2, 3.0]]},
    ]
    (tmp_path / "objects.json").write_text(json.dumps({"objects": objs}))
    return tmp_path


def test_normalize_class_names():
    assert normalize_class("ChairA") == "chair"
    assert normalize_class("KitchenTable") == "kitchen_table"
    assert normalize_class("TVCabinet") == "tv_cabinet"
    assert normalize_class("HouseWallB") == "house_wall"
    assert normalize_class("sofa") == "sofa"


def test_mesh_world_labels_objects_by_mesh_and_bounds(tiny_world):
    p = MeshWorldParams(mesh="world.ply", objects="objects.json", class_map={"dining_table": "table"})
    spec = load_mesh_world(p, tiny_world)
    w = World(spec)
    by_name = {o.name: o for o in w.objects}
    assert set(by_name) == {"c1", "t1", "s1"}  # the wall is structure
    assert by_name["c1"].class_name == "chair" and by_name["t1"].class_name == "table"
    np.testing.assert_allclose(by_name["c1"].centroid, [4.25, 1.25, 0.45], atol=1e-6)
    np.testing.assert_allclose(by_name["t1"].centroid, [1.6, 2.9, 0.375], atol=1e-6)
    # 12 triangles each; the shelf was not in world.ply, so it was added as its own geometry
    assert np.count_nonzero(spec.parts[0].instance == by_name["c1"].instance_id) == 12
    assert np.count_nonzero(spec.parts[0].instance == by_name["t1"].instance_id) == 12
    assert len(spec.parts) == 2
    # rays into each object report its instance
    for o in w.objects:
        ray = np.array([[o.centroid[0], o.centroid[1], 2.9, 0.0, 0.0, -1.0]])
        ans = w.cast_rays(ray)
        tri = w.triangle_index(ans["geometry_ids"], ans["primitive_ids"])
        assert w.tri_instance[tri[0]] == o.instance_id
    s = w.summary(np.array([3.0, 2.0, 1.2]))
    assert s.objects_by_class == {"chair": 1, "table": 1, "shelf": 1}
    assert 0.7 * 6 * 4 * 3 < s.reachable_free_volume < 6 * 4 * 3


def test_mesh_world_y_up_and_scale(tiny_world):
    m = o3d.io.read_triangle_mesh(str(tiny_world / "world.ply"))
    v = np.asarray(m.vertices) * 100.0  # centimetres, y up
    _write_mesh(
        tiny_world / "world_yup.obj", np.stack([v[:, 0], v[:, 2], -v[:, 1]], 1), np.asarray(m.triangles)
    )
    spec = load_mesh_world(MeshWorldParams(mesh="world_yup.obj", up_axis="y", scale=0.01), tiny_world)
    np.testing.assert_allclose(spec.bounds_lo, [-0.2, -0.2, -0.2], atol=1e-5)
    np.testing.assert_allclose(spec.bounds_hi, [6.2, 4.2, 3.2], atol=1e-5)


def test_missing_files_are_clear_errors(tiny_world):
    with pytest.raises(PlatformError, match="not found"):
        load_mesh_world(MeshWorldParams(mesh="nope.ply"), tiny_world)


def test_platform_flies_in_a_mesh_world_from_the_mission_folder(tmp_path, tiny_world):
    plat = make_platform(
        tmp_path,
        world={"kind": "mesh", "mesh": "world.ply", "objects": "objects.json"},
        mission_dir=tiny_world,
    )
    start = plat.ground_truth()[:3, 3]
    assert 0 < start[0] < 6 and 0 < start[1] < 4
    plat.arm_and_takeoff(1.2)
    plat.advance(4.0)
    assert not plat.status().crashed
    f = plat.capture()
    assert f is not None and f.depth.shape == (120, 160)


def test_small_house_loads_with_its_chairs(tmp_path):
    plat = make_platform(
        tmp_path,
        world={"kind": "mesh", "mesh": "world.ply", "objects": "objects.json"},
        mission_dir=unpacked_world("small_house"),
    )
    s = plat.world_summary()
    assert s.objects_by_class["chair"] == 8
    assert "house_wall" not in s.objects_by_class and "floor" not in s.objects_by_class
    assert 250 < s.reachable_free_volume < 19 * 11.4 * 2.6
    np.testing.assert_allclose(s.bounds_hi - s.bounds_lo, [19.0, 11.4, 3.0], atol=0.01)
