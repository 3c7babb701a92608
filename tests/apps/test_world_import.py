"""``amslam world import`` on small hand-written Gazebo worlds, COLLADA and OBJ files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from amslam.apps.worlds.classmap import load_class_map, words
from amslam.apps.worlds.importer import ImportOptions, import_world
from amslam.apps.worlds.sdf import WorldImportError
from amslam.cli import main
from amslam.errors import AmslamError

# -- files written by the tests -------------------------------------------------------------------


def sdf_world(body: str, version: str = "1.7") -> str:
    head = f'<?xml version="1.0"?>\n<sdf version="{version}">\n<world name="test_world">\n'
    return head + f"{body}\n</world>\n</sdf>\n"


def box_link(size: str, link_pose: str = "0 0 0 0 0 0", visual_pose: str = "0 0 0 0 0 0", name="link") -> str:
    return (
        f'<link name="{name}"><pose>{link_pose}</pose>'
        f'<visual name="v"><pose>{visual_pose}</pose>'
        f"<geometry><box><size>{size}</size></box></geometry></visual>"
        f'<collision name="c"><geometry><box><size>9 9 9</size></box></geometry></collision></link>'
    )


def write_model(root: Path, name: str, sdf_body: str, extra_files: dict[str, str] | None = None) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    (folder / "model.config").write_text(
        f'<?xml version="1.0"?><model><name>{name}</name><sdf version="1.5">old.sdf</sdf>'
        f'<sdf version="1.7">model.sdf</sdf></model>'
    )
    (folder / "model.sdf").write_text(f'<?xml version="1.0"?><sdf version="1.7">{sdf_body}</sdf>')
    for rel, text in (extra_files or {}).items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(text)
    return folder


def collada_box(size: float, unit_metres: float, up_axis: str = "Z_UP", node_name: str = "box") -> str:
    """A COLLADA file holding one axis-aligned cube of ``size`` units, with corner at the origin."""
    corners = [(x, y, z) for x in (0, size) for y in (0, size) for z in (0, size)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    triangles = [i for a, b, c, d in quads for i in (a, b, c, a, c, d)]
    positions = " ".join(f"{v}" for corner in corners for v in corner)
    return f"""<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="custom" meter="{unit_metres}"/><up_axis>{up_axis}</up_axis></asset>
  <library_geometries>
    <geometry id="cube" name="cube"><mesh>
      <source id="cube-pos"><float_array id="cube-pos-array" count="24">{positions}</float_array>
        <technique_common><accessor source="#cube-pos-array" count="8" stride="3">
          <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
        </accessor></technique_common></source>
      <vertices id="cube-vtx"><input semantic="POSITION" source="#cube-pos"/></vertices>
      <triangles count="12"><input semantic="VERTEX" source="#cube-vtx" offset="0"/>
        <p>{" ".join(map(str, triangles))}</p></triangles>
    </mesh></geometry>
  </library_geometries>
  <library_visual_scenes><visual_scene id="scene">
    <node id="{node_name}" name="{node_name}"><instance_geometry url="#cube"/></node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#scene"/></scene>
</COLLADA>
"""


def objects_of(out: Path) -> dict[str, dict]:
    return {e["name"]: e for e in json.loads((out / "objects.json").read_text())}


def assert_bounds(entry: dict, lo, hi, tol: float = 1e-4) -> None:
    assert np.allclose(entry["bounds"][0], lo, atol=tol), entry["bounds"]
    assert np.allclose(entry["bounds"][1], hi, atol=tol), entry["bounds"]


# -- includes, nesting, poses ---------------------------------------------------------------------


def test_include_is_resolved_along_the_model_path_and_its_pose_replaces_the_models(tmp_path):
    models = tmp_path / "elsewhere" / "models"
    # the model's own pose (10 m away) is replaced by the include's; the link and visual poses compose
    write_model(
        models,
        "cafe_table",
        '<model name="cafe_table"><pose>10 10 0 0 0 0</pose>'
        + box_link("1 2 1", link_pose="0 0 0.5 0 0 0", visual_pose="0.5 0 0 0 0 0")
        + "</model>",
    )
    world = tmp_path / "worlds" / "room.world"
    world.parent.mkdir()
    world.write_text(
        sdf_world(
            "<include><uri>model://cafe_table</uri><name>dining_table</name>"
            f"<pose>3 4 0 0 0 {math.pi / 2}</pose></include>"
        )
    )
    out = tmp_path / "out"
    import_world(world, out, ImportOptions(model_path=[models]))
    table = objects_of(out)["dining_table"]
    assert table["class"] == "table"
    # box 1 × 2 × 1 centred at (0.5, 0, 0.5) in the model; turned 90°: x extent 2, y extent 1 at (3, 4.5)
    assert_bounds(table, [2.0, 4.0, 0.0], [4.0, 5.0, 1.0])
    assert (out / table["mesh"]).is_file()


def test_include_found_through_gazebo_model_path_variable(tmp_path, monkeypatch):
    models = tmp_path / "gz_models"
    write_model(models, "office_chair", '<model name="office_chair">' + box_link("0.5 0.5 1") + "</model>")
    monkeypatch.setenv("GAZEBO_MODEL_PATH", str(models))
    world = tmp_path / "w.world"
    world.write_text(
        sdf_world("<include><uri>model://office_chair</uri><pose>1 0 0.5 0 0 0</pose></include>")
    )
    import_world(world, tmp_path / "out")
    assert_bounds(objects_of(tmp_path / "out")["office_chair"], [0.75, -0.25, 0.0], [1.25, 0.25, 1.0])


def test_nested_models_compose_poses_and_each_class_is_its_own_object(tmp_path):
    # an unmapped "dining_set" turned 90° holds a table and two chairs, one chair itself nested twice
    body = f"""
    <model name="dining_set"><pose>10 0 0 0 0 {math.pi / 2}</pose>
      <model name="table"><pose>0 0 0 0 0 0</pose>{box_link("2 1 0.8", link_pose="0 0 0.4 0 0 0")}</model>
      <model name="chair_1"><pose>1.5 0 0 0 0 0</pose>{box_link("0.4 0.4 1", link_pose="0 0 0.5 0 0 0")}
        <model name="chair_cushion"><pose>0 0 0.5 0 0 0</pose>{box_link("0.4 0.4 0.1")}</model>
      </model>
      <model name="chair_2"><pose>-1.5 0 0 0 0 0</pose>
        {box_link("0.4 0.4 1", link_pose="0 0 0.5 0 0 0")}</model>
    </model>
    """
    world = tmp_path / "w.sdf"
    world.write_text(sdf_world(body))
    result = import_world(world, tmp_path / "out")
    objects = objects_of(tmp_path / "out")
    assert sorted(objects) == ["dining_set::chair_1", "dining_set::chair_2", "dining_set::table"]
    assert {e["class"] for e in objects.values()} == {"table", "chair"}
    # the table 2 × 1 turned 90° at (10, 0): 1 wide in x, 2 long in y
    assert_bounds(objects["dining_set::table"], [9.5, -1.0, 0.0], [10.5, 1.0, 0.8])
    # chair_1 at model x 1.5 → world y 1.5; its cushion (a nested chair part) belongs to it
    assert_bounds(objects["dining_set::chair_1"], [9.8, 1.3, 0.0], [10.2, 1.7, 1.0])
    assert_bounds(objects["dining_set::chair_2"], [9.8, -1.7, 0.0], [10.2, -1.3, 1.0])
    assert result.triangles == 4 * 12


def test_relative_to_frames_and_degrees(tmp_path):
    # SDF 1.7 frames: the link is placed relative to a <frame>, the visual relative to another link
    body = """
    <model name="shelf_unit">
      <frame name="corner"><pose>2 0 0 0 0 90</pose></frame>
      <link name="base"><pose relative_to="corner" degrees="true">1 0 0 0 0 0</pose></link>
      <link name="top"><pose>0 0 5 0 0 0</pose>
        <visual name="v"><pose relative_to="base">0 0 1 0 0 0</pose>
          <geometry><box><size>1 1 1</size></box></geometry></visual></link>
    </model>
    """
    world = tmp_path / "w.sdf"
    # the <frame> pose is in degrees too
    world.write_text(
        sdf_world(body.replace("<pose>2 0 0 0 0 90</pose>", '<pose degrees="true">2 0 0 0 0 90</pose>'))
    )
    import_world(world, tmp_path / "out")
    # corner at (2, 0) turned 90°; base 1 m along the corner's x → (2, 1); visual 1 m above base
    assert_bounds(objects_of(tmp_path / "out")["shelf_unit"], [1.5, 0.5, 0.5], [2.5, 1.5, 1.5])


def test_collision_geometry_on_request(tmp_path):
    world = tmp_path / "w.sdf"
    world.write_text(sdf_world('<model name="bed">' + box_link("1 1 1") + "</model>"))
    import_world(world, tmp_path / "out", ImportOptions(geometry="collision"))
    assert_bounds(objects_of(tmp_path / "out")["bed"], [-4.5] * 3, [4.5] * 3)


# -- meshes: scale, COLLADA units ----------------------------------------------------------------


def test_collada_unit_and_mesh_scale(tmp_path):
    models = tmp_path / "models"
    # a 100-unit cube in centimetres is 1 m; the visual scales it by 2 along x, then the link's
    # pose lifts it 1 m. Gazebo keeps the file's axes for meshes an SDF names (the up axis is
    # not applied), so the Y_UP declaration changes nothing here.
    write_model(
        models,
        "bookshelf",
        '<model name="bookshelf"><link name="l"><pose>0 0 1 0 0 0</pose><visual name="v"><geometry><mesh>'
        "<uri>model://bookshelf/meshes/shelf.DAE</uri><scale>2 1 1</scale>"
        "</mesh></geometry></visual></link></model>",
        {"meshes/shelf.DAE": collada_box(100, 0.01, up_axis="Y_UP")},
    )
    world = tmp_path / "w.world"
    world.write_text(sdf_world("<include><uri>model://bookshelf</uri><pose>5 0 0 0 0 0</pose></include>"))
    import_world(world, tmp_path / "out", ImportOptions(model_path=[models]))
    shelf = objects_of(tmp_path / "out")["bookshelf"]
    assert shelf["class"] == "shelf"
    assert_bounds(shelf, [5.0, 0.0, 1.0], [7.0, 1.0, 2.0])


def test_mirroring_scale_keeps_triangles_facing_out(tmp_path):
    import trimesh

    mesh_file = tmp_path / "cube.dae"
    mesh_file.write_text(collada_box(1, 1.0))
    world = tmp_path / "w.sdf"
    world.write_text(
        sdf_world(
            '<model name="cabinet"><link name="l"><visual name="v"><geometry>'
            f"<mesh><uri>{mesh_file.name}</uri>"
            "<scale>-1 1 1</scale></mesh></geometry></visual></link></model>"
        )
    )
    import_world(world, tmp_path / "out")
    mesh = trimesh.load(tmp_path / "out" / "world.ply", process=False)
    assert mesh.volume == pytest.approx(1.0)  # positive: normals face outwards
    assert np.allclose(mesh.bounds, [[-1, 0, 0], [0, 1, 1]])


# -- primitives -----------------------------------------------------------------------------------


def test_primitives_and_the_ground_plane_cut_to_the_building(tmp_path):
    body = """
    <model name="ground_plane"><static>true</static><link name="link"><visual name="v"><geometry>
      <plane><normal>0 0 1</normal><size>100 100</size></plane></geometry></visual></link></model>
    <model name="pillar"><pose>2 3 1.5 0 0 0</pose><link name="l"><visual name="v"><geometry>
      <cylinder><radius>0.5</radius><length>3</length></cylinder></geometry></visual></link></model>
    <model name="potted_plant"><pose>-2 -1 0.3 0 0 0</pose><link name="l"><visual name="v"><geometry>
      <sphere><radius>0.3</radius></sphere></geometry></visual></link></model>
    <model name="wall"><pose>0 0 1 0 0 0</pose><link name="l"><visual name="v"><geometry>
      <box><size>4 0.2 2</size></box></geometry></visual></link></model>
    <model name="handrail"><link name="l"><visual name="v"><geometry><heightmap><uri>x.png</uri></heightmap>
      </geometry></visual></link></model>
    """
    world = tmp_path / "w.sdf"
    world.write_text(sdf_world(body))
    result = import_world(world, tmp_path / "out", ImportOptions(plane_margin=1.0))
    # everything but the plane spans x -2.3 … 2.5, y -1.3 … 3.5; the plane is cut to that + 1 m
    assert np.allclose(result.lo, [-3.3, -2.3, -0.05], atol=1e-3)
    assert np.allclose(result.hi, [3.5, 4.5, 3.0], atol=1e-3)
    plant = objects_of(tmp_path / "out")["potted_plant"]
    assert plant["class"] == "plant"
    assert_bounds(plant, [-2.3, -1.3, 0.0], [-1.7, -0.7, 0.6], tol=0.02)
    assert "pillar" not in objects_of(tmp_path / "out")  # no class: structure
    assert any("heightmap" in s.reason for s in result.skipped)
    assert any("100 × 100 m cut to 6.8 × 6.8 m" in n for n in result.notes)


def test_stock_ground_plane_and_sun_need_no_gazebo(tmp_path, monkeypatch):
    for variable in ("GAZEBO_MODEL_PATH", "GZ_SIM_RESOURCE_PATH", "IGN_GAZEBO_RESOURCE_PATH", "SDF_PATH"):
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    world = tmp_path / "w.world"
    world.write_text(
        sdf_world(
            "<include><uri>model://sun</uri></include><include><uri>model://ground_plane</uri></include>"
            '<model name="sofa"><pose>0 0 0.4 0 0 0</pose>' + box_link("2 1 0.8") + "</model>"
        )
    )
    result = import_world(world, tmp_path / "out")
    assert [o.name for o in result.objects] == ["sofa"]
    assert np.allclose(result.lo[:2], [-2.0, -1.5]) and np.allclose(result.hi[:2], [2.0, 1.5])
    assert any("sun" in s.what and "no geometry" in s.reason for s in result.skipped)


def test_fuel_urls_of_the_stock_models_need_no_network(tmp_path, monkeypatch):
    # ROS 2 worlds (turtlebot3_house.world) include the sun and the ground plane from Gazebo Fuel
    monkeypatch.setenv("HOME", str(tmp_path))
    fuel = "https://fuel.gazebosim.org/1.0/OpenRobotics/models"
    world = tmp_path / "w.world"
    world.write_text(
        sdf_world(
            f"<include><uri>{fuel}/Sun</uri></include><include><uri>{fuel}/Ground Plane/1</uri></include>"
            '<model name="sofa"><pose>0 0 0.4 0 0 0</pose>' + box_link("2 1 0.8") + "</model>"
        )
    )
    result = import_world(world, tmp_path / "out")
    assert [o.name for o in result.objects] == ["sofa"]
    assert any("100 × 100 m cut to" in n for n in result.notes)  # the ground plane, cut to size
    # any other Fuel model still names itself and says it was not fetched
    world.write_text(sdf_world(f"<include><uri>{fuel}/Cafe table</uri></include>"))
    with pytest.raises(WorldImportError, match=r"model 'Cafe table' \(https://fuel.*not fetched"):
        import_world(world, tmp_path / "out2")


# -- the class map --------------------------------------------------------------------------------


def test_words_split_names_as_the_class_map_sees_them():
    assert words("OfficeChairBlack") == "office_chair_black"
    assert words("TVCabinet") == "tv_cabinet"
    assert words("aws_robomaker_residential_ChairA_01") == "aws_robomaker_residential_chair_a_01"
    assert words("BookshelfB_01_003") == "bookshelf_b_01_003"


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("aws_robomaker_residential_ChairA_01", "chair"),
        ("OfficeChairBlack", "chair"),
        ("TVCabinet_01_001", "cabinet"),
        ("TV_01_001", "tv"),
        ("Bed_01_001", "bed"),
        ("BedTable", "table"),
        ("bedside_lamp", None),
        ("DeskPortraitA_01_001", "structure"),
        ("ReadingDesk", "table"),
        ("SofaC_01_001", "sofa"),
        ("couch", "sofa"),
        ("aws_robomaker_retail_BookshelfB_01", "shelf"),
        ("StorageRack", "shelf"),
        ("PatientWheelChair", "person"),
        ("PottedPlant", "plant"),
        ("person_standing", "person"),
        ("HouseWallB", None),
        ("ground_plane", None),
    ],
)
def test_default_class_map(name, expected):
    match = load_class_map().classify(name)
    assert (match[0] if match else None) == expected


def test_user_class_map_globs_regexes_skip_and_extends(tmp_path):
    class_map = tmp_path / "map.yaml"
    class_map.write_text(
        "extends: default\n"
        "classes:\n"
        "  '*fridge*': refrigerator\n"
        "  're:^Crate[A-Z]$': box\n"
        "  curtain: skip\n"
        "  chair: seat\n"
    )
    body = (
        '<model name="big_fridge_2">' + box_link("1 1 2") + "</model>"
        '<model name="CrateB"><pose>3 0 0 0 0 0</pose>' + box_link("1 1 1") + "</model>"
        '<model name="CrateB_02"><pose>5 0 0 0 0 0</pose>' + box_link("1 1 1") + "</model>"
        '<model name="shower_curtain"><pose>7 0 0 0 0 0</pose>' + box_link("1 1 1") + "</model>"
        '<model name="chair_1"><pose>9 0 0 0 0 0</pose>' + box_link("1 1 1") + "</model>"
        '<model name="sofa_1"><pose>11 0 0 0 0 0</pose>' + box_link("1 1 1") + "</model>"
    )
    world = tmp_path / "w.sdf"
    world.write_text(sdf_world(body))
    result = import_world(world, tmp_path / "out", ImportOptions(class_map=class_map))
    classes = {e["name"]: e["class"] for e in objects_of(tmp_path / "out").values()}
    # the user's rules come first, the default's after them (sofa); CrateB_02 does not match the regex
    assert classes == {"big_fridge_2": "refrigerator", "CrateB": "box", "chair_1": "seat", "sofa_1": "sofa"}
    assert result.hi[0] == pytest.approx(11.5)  # CrateB_02 is structure, the curtain is gone
    assert any(s.what == "shower_curtain" and "skip" in s.reason for s in result.skipped)


def test_class_map_errors_are_clear(tmp_path):
    bad = tmp_path / "map.yaml"
    bad.write_text("classes:\n  chair: [1, 2]\n")
    with pytest.raises(AmslamError, match="pattern 'chair' needs a class name"):
        load_class_map(bad)
    bad.write_text("classes:\n  're:(': chair\n")
    with pytest.raises(AmslamError, match="not a valid regular expression"):
        load_class_map(bad)
    bad.write_text("classes: {chair: chair\n")
    with pytest.raises(AmslamError, match=r"map.yaml:\d+: not valid YAML"):
        load_class_map(bad)


# -- plain meshes ---------------------------------------------------------------------------------


def test_plain_obj_objects_come_from_its_named_parts(tmp_path):
    def cube(x0: float, offset: int) -> str:
        v = [(x0 + x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
        quads = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
        lines = [f"v {a} {b} {c}" for a, b, c in v]
        lines += [f"f {a + offset} {b + offset} {c + offset} {d + offset}" for a, b, c, d in quads]
        return "\n".join(lines)

    obj = tmp_path / "flat.obj"
    obj.write_text(f"o Walls\n{cube(0, 0)}\no ArmChair_3\n{cube(4, 8)}\no table.001\n{cube(8, 16)}\n")
    result = import_world(obj, tmp_path / "out")
    classes = {e["name"]: e["class"] for e in objects_of(tmp_path / "out").values()}
    assert classes == {"ArmChair_3": "chair", "table.001": "table"}
    assert result.triangles == 36
    assert_bounds(objects_of(tmp_path / "out")["ArmChair_3"], [4, 0, 0], [5, 1, 1])


def test_plain_collada_honours_its_unit_and_up_axis(tmp_path):
    dae = tmp_path / "shop.dae"
    dae.write_text(collada_box(200, 0.01, up_axis="Y_UP", node_name="display_rack"))
    result = import_world(dae, tmp_path / "out")
    # 2 m cube, y-up: (x, y, z) → (x, -z, y)
    assert np.allclose(result.lo, [0, -2, 0]) and np.allclose(result.hi, [2, 0, 2])
    assert objects_of(tmp_path / "out")["display_rack"]["class"] == "shelf"


# -- the output flies -----------------------------------------------------------------------------


def test_output_loads_as_a_mesh_world_with_every_object_labelled(tmp_path):
    from amslam.plugins.sim.meshworld import MeshWorldParams, load_mesh_world

    body = (
        '<model name="floor"><pose>0 0 -0.1 0 0 0</pose>' + box_link("10 8 0.2") + "</model>"
        '<model name="chair_1"><pose>1 1 0.5 0 0 0</pose>' + box_link("0.5 0.5 1") + "</model>"
        '<model name="chair_2"><pose>2 1 0.5 0 0 0</pose>' + box_link("0.5 0.5 1") + "</model>"
        '<model name="KitchenTable"><pose>1.5 2 0.4 0 0 0</pose>' + box_link("1.5 0.8 0.8") + "</model>"
    )
    world = tmp_path / "w.sdf"
    world.write_text(sdf_world(body))
    out = tmp_path / "out"
    import_world(world, out)
    spec = load_mesh_world(MeshWorldParams(mesh="world.ply", objects="objects.json"), out)
    assert sorted((o.name, o.class_name) for o in spec.objects) == [
        ("KitchenTable", "table"),
        ("chair_1", "chair"),
        ("chair_2", "chair"),
    ]
    assert len(spec.parts) == 1  # every object found inside world.ply, none added beside it
    instances = spec.parts[0].instance
    assert (instances == 0).sum() == 12 and len(np.unique(instances[instances > 0])) == 3
    assert spec.floor_heights[0] == pytest.approx(0.0, abs=1e-3)


def test_cli_writes_a_mission_that_validates(tmp_path, capsys):
    world = tmp_path / "w.sdf"
    world.write_text(
        sdf_world(
            '<model name="room">' + box_link("6 6 0.2") + '</model><model name="tv_1">' + box_link("1 1 1")
        ).replace("</world>", "</model></world>")
    )
    out = tmp_path / "imported"
    assert main(["world", "import", str(world), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert (
        "objects: 1 — tv 1" in printed and "24 triangles" in printed and "structure (no class): 1" in printed
    )
    assert (out / "summary.txt").read_text().strip() == printed.strip()
    assert main(["validate", str(out / "mission.yaml")]) == 0


# -- errors ---------------------------------------------------------------------------------------


def run_cli_error(capsys, *argv: str) -> str:
    assert main(["world", "import", *argv]) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    return lines[0]


def test_missing_include_names_the_model_and_the_paths_searched(tmp_path, capsys):
    models = tmp_path / "my_models"
    models.mkdir()
    world = tmp_path / "w.world"
    world.write_text(
        sdf_world('<model name="x_1">\n<include>\n<uri>model://no_such_desk</uri></include></model>')
    )
    message = run_cli_error(capsys, str(world), "--out", str(tmp_path / "o"), "--model-path", str(models))
    assert f"{world}:5" in message and "include" in message
    assert "'no_such_desk'" in message and str(models) in message
    # with --skip-missing it is reported and skipped instead
    assert main(["world", "import", str(world), "--out", str(tmp_path / "o"), "--skip-missing"]) == 2
    assert "no geometry to import" in capsys.readouterr().err


def test_missing_mesh_names_the_visual(tmp_path, capsys):
    world = tmp_path / "w.world"
    world.write_text(
        sdf_world(
            '<model name="m"><link name="l"><visual name="v"><geometry><mesh><uri>meshes/gone.dae</uri>'
            "</mesh></geometry></visual></link></model>"
        )
    )
    message = run_cli_error(capsys, str(world), "--out", str(tmp_path / "o"))
    assert "model[m]/link[l]/visual[v]" in message and "'meshes/gone.dae' not found" in message


def test_malformed_xml_names_file_and_line(tmp_path, capsys):
    world = tmp_path / "broken.world"
    world.write_text(
        '<?xml version="1.0"?>\n<sdf version="1.6">\n<world name="w">\n<model name="a">\n</world>\n</sdf>\n'
    )
    message = run_cli_error(capsys, str(world), "--out", str(tmp_path / "o"))
    assert f"{world}:5:" in message and "malformed XML" in message and "mismatched tag" in message


def test_bad_pose_names_the_element(tmp_path, capsys):
    world = tmp_path / "w.world"
    world.write_text(
        sdf_world('<model name="a">\n<link name="l"><pose>1 2 three 0 0 0</pose></link></model>')
    )
    message = run_cli_error(capsys, str(world), "--out", str(tmp_path / "o"))
    assert f"{world}:5" in message and "link[l]" in message and "pose" in message


def test_unknown_relative_to_frame_is_reported(tmp_path):
    world = tmp_path / "w.world"
    world.write_text(
        sdf_world(
            '<model name="a"><link name="l"><pose relative_to="nowhere">0 0 0 0 0 0</pose></link></model>'
        )
    )
    with pytest.raises(WorldImportError, match="frame 'nowhere' not found"):
        import_world(world, tmp_path / "o")


def test_not_an_sdf_file(tmp_path):
    world = tmp_path / "w.world"
    world.write_text("<robot name='r'/>")
    with pytest.raises(WorldImportError, match=r"w.world:1: not an SDF file"):
        import_world(world, tmp_path / "o")


def test_a_model_far_outside_the_building_is_left_out(tmp_path):
    # saved worlds keep what physics threw away (the AWS bookstore has a book 343 km up)
    body = "".join(
        f'<model name="book_{i}"><pose>{i} 0 0.5 0 0 0</pose>' + box_link("0.2 0.3 0.05") + "</model>"
        for i in range(6)
    )
    body += '<model name="book_lost"><pose>1 1 343582.7 0 0 0</pose>' + box_link("0.2 0.3 0.05") + "</model>"
    world = tmp_path / "w.sdf"
    world.write_text(sdf_world(body))
    result = import_world(world, tmp_path / "out")
    assert result.hi[2] == pytest.approx(0.525)
    assert [s.what for s in result.skipped] == ["model book_lost"]
    assert "far outside the rest of the world (at 1, 1, 343583 m)" in result.skipped[0].reason


def test_with_skip_missing_a_missing_visual_mesh_falls_back_to_the_collision_shapes(tmp_path):
    world = tmp_path / "w.sdf"
    world.write_text(
        sdf_world(
            '<model name="bookshelf_1"><link name="l"><visual name="v"><geometry><mesh><uri>gone.dae</uri>'
            '</mesh></geometry></visual><collision name="c"><geometry><box><size>2 0.5 2</size></box>'
            "</geometry></collision></link></model>"
        )
    )
    result = import_world(world, tmp_path / "out", ImportOptions(skip_missing=True))
    assert_bounds(objects_of(tmp_path / "out")["bookshelf_1"], [-1, -0.25, -1], [1, 0.25, 1])
    assert any("'gone.dae' not found" in s.reason or "gone.dae" in s.reason for s in result.skipped)
    assert any("imported its <collision> geometry instead" in n for n in result.notes)


def test_what_gazebo_tolerates_imports_too(tmp_path):
    # a bare & in a model.config (AWS hospital) and a comment before the XML declaration (cafe.world)
    models = tmp_path / "models"
    folder = write_model(models, "portal", '<model name="portal">' + box_link("1 1 1") + "</model>")
    (folder / "model.config").write_text(
        '<?xml version="1.0"?>\n<model><name>portal</name><sdf version="1.6">model.sdf</sdf>\n'
        "<description>portal, door & car</description></model>\n"
    )
    world = tmp_path / "w.world"
    world.write_text("<!-- usage notes -->\n" + sdf_world("<include><uri>model://portal</uri></include>"))
    result = import_world(world, tmp_path / "out", ImportOptions(model_path=[models]))
    assert result.triangles == 12


def test_skip_missing_lists_each_missing_model(tmp_path):
    world = tmp_path / "w.world"
    body = "".join(f"<include><uri>model://{m}</uri><name>n{i}</name></include>" for i, m in enumerate("aab"))
    world.write_text(sdf_world(body + '<model name="floor">' + box_link("5 5 0.1") + "</model>"))
    result = import_world(world, tmp_path / "out", ImportOptions(skip_missing=True))
    reasons = sorted(s.reason for s in result.skipped)
    assert reasons == ["model 'a' not found on the model path"] * 2 + [
        "model 'b' not found on the model path"
    ]


def test_relative_file_uri_is_found_beside_the_models_folder(tmp_path):
    # ROS world packages write file://models/NAME/meshes/x.dae, relative to the package folder
    package = tmp_path / "shop_world"
    models = package / "models"
    write_model(
        models,
        "rack_1",
        '<model name="rack_1"><link name="l"><visual name="v"><geometry><mesh>'
        "<uri>file://models/rack_1/meshes/rack.dae</uri></mesh></geometry></visual></link></model>",
        {"meshes/rack.dae": collada_box(1, 1.0)},
    )
    world = package / "worlds" / "shop.world"
    world.parent.mkdir()
    world.write_text(sdf_world("<include><uri>model://rack_1</uri></include>"))
    import_world(world, tmp_path / "out")  # models/ one folder up from the world: found without a path
    assert_bounds(objects_of(tmp_path / "out")["rack_1"], [0, 0, 0], [1, 1, 1])


def test_submesh_selects_and_centres_one_part_of_a_mesh(tmp_path):
    (tmp_path / "parts.obj").write_text(
        "o top\nv 0 0 1\nv 2 0 1\nv 0 2 1\nf 1 2 3\no leg\nv 10 10 0\nv 11 10 0\nv 10 11 0\nf 4 5 6\n"
    )
    world = tmp_path / "w.sdf"
    world.write_text(
        sdf_world(
            '<model name="desk"><link name="l"><visual name="v"><geometry><mesh><uri>parts.obj</uri>'
            "<submesh><name>leg</name><center>true</center></submesh></mesh></geometry></visual></link></model>"
        )
    )
    result = import_world(world, tmp_path / "out")
    assert result.triangles == 1
    assert_bounds(objects_of(tmp_path / "out")["desk"], [-0.5, -0.5, 0], [0.5, 0.5, 0])


def test_class_map_command_prints_the_default_which_loads_back(tmp_path, capsys):
    assert main(["world", "class-map"]) == 0
    printed = capsys.readouterr().out
    (tmp_path / "mine.yaml").write_text(printed)
    assert load_class_map(tmp_path / "mine.yaml").rules == load_class_map().rules


def test_plain_glb_is_turned_from_y_up(tmp_path):
    import trimesh

    scene = trimesh.Scene()
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))  # 1 m tall along glTF's up axis, y
    box.apply_translation((0.0, 0.5, 0.25))
    scene.add_geometry(box, node_name="sofa_1", geom_name="sofa_mesh")
    glb = tmp_path / "lounge.glb"
    glb.write_bytes(scene.export(file_type="glb"))
    result = import_world(glb, tmp_path / "out")
    # y-up (x, y, z) → z-up (x, -z, y): 1 m tall, the 0.5 m depth now along -y
    assert np.allclose(result.lo, [-1.0, -0.5, 0.0]) and np.allclose(result.hi, [1.0, 0.0, 1.0])
    assert objects_of(tmp_path / "out")["sofa_1"]["class"] == "sofa"
