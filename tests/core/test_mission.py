"""Mission files: validation errors name the file, line, field path and expectation."""

from __future__ import annotations

import textwrap

import pytest
import yaml

from amslam.errors import MissionError
from amslam.mission import load_mission, packaged_missions


def write(tmp_path, text: str):
    path = tmp_path / "mission.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def test_packaged_demo_validates(registry):
    assert "demo" in packaged_missions()
    mission = load_mission("demo", registry)
    assert mission.name == "demo"
    assert set(mission.backends) == {"platform", "mapping", "slam", "detector", "planner"}


def test_three_problems_reported_together_with_locations(tmp_path, registry):
    path = write(
        tmp_path,
        """\
        name: broken
        seed: 3
        robot:
          radius: fat
        exploration:
          replan_perod: 4
        planner:
          plugin: nosuchplanner
        """,
    )
    with pytest.raises(MissionError) as info:
        load_mission(path, registry)
    problems = info.value.problems
    assert len(problems) == 3, problems
    typo, wrong_type, unknown = sorted(problems, key=lambda p: ("replan" not in p, "radius" not in p))
    assert f"{path}:6: exploration.replan_perod: unknown key 'replan_perod'" in typo
    assert "replan_period" in typo  # the expected keys are listed
    assert f"{path}:4: robot.radius:" in wrong_type and "'fat'" in wrong_type
    assert f"{path}:8: planner.plugin: no planner backend named 'nosuchplanner'; installed:" in unknown
    assert "greedy" in unknown


def test_backend_parameters_validated_by_the_backend(tmp_path, registry):
    path = write(
        tmp_path,
        """\
        name: p
        planner:
          plugin: greedy
          no_such_param: 1
        """,
    )
    with pytest.raises(MissionError) as info:
        load_mission(path, registry)
    assert "planner.no_such_param: unknown key" in info.value.problems[0]


def test_unknown_keys_are_named_and_can_be_left_out(tmp_path, registry):
    # A run folder's mission written by an older version names a parameter since renamed.
    path = write(
        tmp_path,
        """\
        name: old
        exploration:
          replan_perod: 4
        planner:
          plugin: greedy
          no_such_param: 1
        """,
    )
    with pytest.raises(MissionError) as info:
        load_mission(path, registry)
    assert sorted(info.value.unknown_keys) == ["exploration.replan_perod", "planner.no_such_param"]
    mission = load_mission(path, registry, unset=info.value.unknown_keys)
    assert mission.model.name == "old"
    assert "no_such_param" not in mission.raw["planner"]
    # a wrong value is no unknown key: nothing to leave out
    bad = write(tmp_path, "name: b\nrobot:\n  radius: fat\n")
    with pytest.raises(MissionError) as info:
        load_mission(bad, registry)
    assert info.value.unknown_keys == []


def test_overrides_apply_before_validation(tmp_path, registry):
    path = write(tmp_path, "name: o\nseed: 1\n")
    mission = load_mission(path, registry, ["seed=42", "exploration.slc=true"])
    assert mission.model.seed == 42 and mission.model.exploration.slc is True
    with pytest.raises(MissionError, match="expected key.path=value"):
        load_mission(path, registry, ["seed"])


def test_invalid_yaml_names_the_line(tmp_path, registry):
    path = write(tmp_path, "name: x\nrobot: [1, 2\n")
    with pytest.raises(MissionError, match=r"mission.yaml:\d+: not valid YAML"):
        load_mission(path, registry)


def test_resolved_mission_fills_every_default(registry):
    resolved = load_mission("demo", registry).resolved()
    assert resolved["robot"]["radius"] > 0
    assert resolved["planner"]["plugin"]
    assert "replan_period" in resolved["exploration"]


def test_the_run_folders_mission_names_its_files_absolutely(tmp_path, registry):
    # a mesh world's files are relative to the mission file; the run folder's copy (mission.yaml,
    # written from resolved()) is read from elsewhere (--reuse, a team's world): it must stand alone
    source = tmp_path / "site"
    (source / "meshes").mkdir(parents=True)
    for name in ("objects.json", "map.npz"):
        (source / "meshes" / name).write_text("[]")
    # validation reads the world mesh (a file without triangles is refused): one triangle
    (source / "meshes" / "world.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    mission = write(
        source,
        """\
        name: mesh
        prior_map: meshes/map.npz
        platform: {plugin: sim, world: {kind: mesh, mesh: meshes/world.ply, objects: ./meshes/objects.json}}
        """,
    )
    resolved = load_mission(mission, registry).resolved()
    world = resolved["platform"]["world"]
    assert world["mesh"] == str(source / "meshes" / "world.ply")
    assert world["objects"] == str(source / "meshes" / "objects.json")
    assert resolved["prior_map"] == str(source / "meshes" / "map.npz")
    run = tmp_path / "runs" / "mesh_1"
    run.mkdir(parents=True)
    (run / "mission.yaml").write_text(yaml.safe_dump(resolved))
    again = load_mission(run / "mission.yaml", registry)
    assert again.backends["platform"].params.world.mesh == str(source / "meshes" / "world.ply")
    assert again.resolved() == resolved


def test_robot_base_is_for_real_vehicles_only(registry):
    real = load_mission("px4_square", registry, overrides=["robot.base=[1.0, 2.0, 0.0, 90]"])
    assert real.model.robot.base == (1.0, 2.0, 0.0, 90.0)
    assert "base" not in vars(real.model.robot.spec())
    with pytest.raises(MissionError) as err:
        load_mission("demo", registry, overrides=["robot.base=[1.0, 2.0, 0.0, 90]"])
    assert "robot.base" in str(err.value) and "platform.start" in str(err.value)
    with pytest.raises(MissionError, match="robot.base"):
        load_mission("px4_square", registry, overrides=["robot.base=[1.0, 2.0]"])
