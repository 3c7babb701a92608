"""The world search path (amslam.plugins.sim.worldpath): beside the mission, AMSLAM_WORLDS, shipped worlds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from amslam.cli import main
from amslam.errors import MissionError
from amslam.mission import load_mission
from amslam.plugins.sim.worldpath import WORLDS_ENV, packaged_worlds, unpacked_world

from .test_meshworld import _write_mesh


def box_world(folder: Path) -> Path:
    """``folder/world.ply``: a closed 4 x 4 x 3 m box, and ``folder/objects.json`` with no objects."""
    import numpy as np

    folder.mkdir(parents=True)
    v = np.array([[x, y, z] for x in (0, 4) for y in (0, 4) for z in (0, 3)], float)
    t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])  # fmt: skip
    _write_mesh(folder / "world.ply", v, t)
    (folder / "objects.json").write_text("[]")
    return folder


def mission_file(folder: Path, mesh: str, objects: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    world = {"kind": "mesh", "mesh": mesh, **({"objects": objects} if objects else {})}
    path = folder / "m.yaml"
    path.write_text(json.dumps({"name": "m", "platform": {"plugin": "sim", "world": world}}))
    return path


def world_of(mission) -> dict:
    return mission.resolved()["platform"]["world"]


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv(WORLDS_ENV, raising=False)
    return tmp_path / "cache" / "amslam" / "worlds"


def test_small_house_is_shipped_and_unpacked_once(cache):
    assert "small_house" in packaged_worlds()
    folder = unpacked_world("small_house")
    assert folder.parent.parent == cache and folder.name == "small_house"
    assert {"world.ply", "objects.json", "LICENSE", "SOURCE.md"} <= {p.name for p in folder.iterdir()}
    entries = json.loads((folder / "objects.json").read_text())
    assert all((folder / e["mesh"]).is_file() for e in entries if "mesh" in e)
    stamp = (folder / "world.ply").stat().st_mtime_ns
    assert unpacked_world("small_house") == folder
    assert (folder / "world.ply").stat().st_mtime_ns == stamp  # not unpacked again
    assert [p.name for p in folder.parent.parent.iterdir()] == [folder.parent.name]  # no staging left


def test_a_shipped_world_is_found_from_a_mission_anywhere(cache, tmp_path, registry):
    path = mission_file(tmp_path / "anywhere", "small_house/world.ply", "small_house/objects.json")
    world = world_of(load_mission(path, registry))
    assert world["mesh"] == str(cache.resolve() / world["mesh"].split("/")[-3] / "small_house" / "world.ply")
    assert world["objects"] == str(Path(world["mesh"]).parent / "objects.json")


def test_a_world_beside_the_mission_comes_before_amslam_worlds_and_the_shipped_one(
    cache, tmp_path, registry, monkeypatch
):
    mine = box_world(tmp_path / "mine" / "small_house")
    listed = box_world(tmp_path / "listed" / "small_house")
    monkeypatch.setenv(WORLDS_ENV, f"{tmp_path / 'empty'}:{tmp_path / 'listed'}")
    path = mission_file(tmp_path / "elsewhere", "small_house/world.ply")
    assert world_of(load_mission(path, registry))["mesh"] == str(listed / "world.ply")
    assert not cache.exists()  # the shipped world is not unpacked when a folder of AMSLAM_WORLDS has it
    path = mission_file(tmp_path / "mine", "small_house/world.ply")
    assert world_of(load_mission(path, registry))["mesh"] == str(mine / "world.ply")


def test_a_world_found_nowhere_names_every_place_looked_in(cache, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(WORLDS_ENV, str(tmp_path / "worlds"))
    path = mission_file(tmp_path, "castle/world.ply")
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"error: {path}:1: platform.world.mesh: no such file: {tmp_path}/castle/world.ply (nor in "
        f"{WORLDS_ENV}: {tmp_path}/worlds; shipped worlds: small_house)"
    ]


def test_validate_names_a_missing_object_mesh_of_the_objects_file(cache, tmp_path, capsys, registry):
    folder = box_world(tmp_path / "w")
    (folder / "objects.json").write_text(
        json.dumps(
            [
                {"name": "chair_1", "class": "chair", "bounds": [[1, 1, 0], [2, 2, 1]]},
                {"name": "chair_2", "class": "chair", "mesh": "objects/chair_2.ply"},
                {"name": "chair_3", "class": "chair", "mesh": "objects/chair_3.ply"},
            ]
        )
    )
    path = mission_file(tmp_path, "w/world.ply", "w/objects.json")
    assert main(["validate", str(path)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"error: {path}:1: platform.world.objects: object #1 'chair_2': no such mesh file: "
        f"{folder}/objects/chair_2.ply (2 object meshes missing)"
    ]
    (folder / "objects.json").write_text("[{")
    with pytest.raises(MissionError, match=r"platform.world.objects: not a JSON objects file"):
        load_mission(path, registry)


def test_validate_names_a_missing_replay_camera_folder(tmp_path, capsys):
    path = tmp_path / "m.yaml"
    path.write_text(
        "name: m\ntree: waypoints\nwaypoints: {points: [[0, 0, 1]]}\n"
        "platform: {plugin: mavsdk, camera: {source: replay, folder: frames}}\n"
    )
    assert main(["validate", str(path)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"error: {path}:4: platform.camera.folder: no such folder: {tmp_path}/frames"
    ]
    (tmp_path / "frames").mkdir()
    assert main(["validate", str(path)]) == 2
    assert capsys.readouterr().err.splitlines()[0].endswith(f"no .npz frames in {tmp_path}/frames")
    (tmp_path / "frames" / "000.npz").write_bytes(b"")
    assert main(["validate", str(path)]) == 0


def test_a_mesh_file_without_triangles_is_one_error_line(tmp_path, capfd):
    (tmp_path / "empty.ply").write_bytes(b"")
    path = mission_file(tmp_path, "empty.ply")
    assert main(["validate", str(path)]) == 2
    out, err = capfd.readouterr()  # at the descriptors: open3d's and its PLY reader's messages would show
    assert out == ""
    expected = f"platform.world.mesh: no triangles in {tmp_path}/empty.ply: not a mesh file"
    assert err == f"error: {path}:1: {expected}\n"
