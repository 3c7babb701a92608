"""Mission tooling: ``amslam missions``, ``amslam init``, ``amslam schema`` (amslam.apps.missions)."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
import yaml

from amslam.cli import main
from amslam.mission import packaged_missions, resolve_mission_path

SHIPPED = packaged_missions()


def run(capsys, *argv: str) -> tuple[int, str, list[str]]:
    try:
        status = main(list(argv))
    except SystemExit as exc:  # argparse
        status = exc.code
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return status, out, [line for line in err.splitlines() if line.strip()]


def test_missions_lists_each_packaged_mission_with_its_own_description(capsys):
    status, out, err = run(capsys, "missions")
    assert status == 0 and err == []
    listed = {line.split()[0]: line.split(None, 1)[1] for line in out.splitlines()[: len(SHIPPED)]}
    assert sorted(listed) == SHIPPED
    for name, description in listed.items():
        assert description == yaml.safe_load(resolve_mission_path(name).read_text())["description"]


@pytest.mark.parametrize("name", SHIPPED)
def test_an_init_copy_validates_where_it_is_written(tmp_path, capsys, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    status, out, err = run(capsys, "init", "mine", "--from", name)
    assert status == 0 and err == [], err
    copy = tmp_path / "mine.yaml"
    assert f"wrote {copy.name}" in out
    text = copy.read_text()
    assert yaml.safe_load(text)["name"] == "mine"
    original = resolve_mission_path(name).read_text()
    # the comments and every other line are the packaged mission's, for the user to edit
    assert [line for line in text.splitlines() if not line.startswith("name:")] == [
        line for line in original.splitlines() if not line.startswith("name:")
    ]
    status, out, err = run(capsys, "validate", str(copy))
    assert status == 0 and err == [], err  # its files (a world, models) are found from where the copy is


def test_init_refuses_to_overwrite(tmp_path, capsys):
    target = tmp_path / "mine.yaml"
    target.write_text("mine, edited\n")
    status, out, err = run(capsys, "init", str(tmp_path / "mine"), "--from", "demo")
    assert status == 2 and out == ""
    assert err == [f"error: {target}: already exists; not overwritten (choose another NAME or remove it)"]
    assert target.read_text() == "mine, edited\n"


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["init", "x", "--from", "nope"], "error: --from nope: no packaged mission of that name (demo, "),
        (["init", "two words"], "error: two words: 'two words' cannot be a mission name"),
        (["init", "no/such/dir/x"], "error: no/such/dir/x.yaml: no folder no/such/dir to write it in"),
    ],
)
def test_init_refuses_bad_input_in_one_line(tmp_path, capsys, monkeypatch, argv, expected):
    monkeypatch.chdir(tmp_path)
    status, out, err = run(capsys, *argv)
    assert status == 2 and len(err) == 1 and err[0].startswith(expected), err
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def schema(registry):
    from amslam.apps.missions import mission_schema

    return mission_schema(registry)


def test_schema_is_json_schema_printed_as_json(capsys, schema):
    status, out, err = run(capsys, "schema")
    assert status == 0 and err == []
    assert json.loads(out) == schema
    jsonschema.Draft7Validator.check_schema(schema)
    # draft-07, which yaml-language-server validates fully: none of 2020-12's keywords pydantic writes
    assert schema["$schema"] == "http://json-schema.org/draft-07/schema#"
    assert "$defs" not in out and "prefixItems" not in out and '"#/definitions/' in out


@pytest.mark.parametrize("name", SHIPPED)
def test_schema_accepts_every_packaged_mission(schema, name):
    mission = yaml.safe_load(resolve_mission_path(name).read_text())
    errors = [e.message for e in jsonschema.Draft7Validator(schema).iter_errors(mission)]
    assert errors == []


@pytest.mark.parametrize(
    "change",
    [
        {"mapping": {"plugin": "open3d", "global_voxl": 0.2}},  # a typo in a backend's parameter
        {"mapping": {"plugin": "open3d", "global_voxel": "fine"}},
        {"planner": {"plugin": "no_such_planner"}},
        {"platform": {"world": {"kind": "mesh"}}},  # the default plugin (sim): its world needs a mesh
        {"robot": {"radius": -1}},
        {"area": {"lo": [0, 0, "low"], "hi": [1, 1, 1]}},  # a tuple's item, in draft-07's list form
        {"colour": "red"},
    ],
)
def test_schema_refuses_what_validate_refuses(schema, change, tmp_path, capsys):
    mission = {**yaml.safe_load(resolve_mission_path("demo").read_text()), **change}
    assert list(jsonschema.Draft7Validator(schema).iter_errors(mission)) != []
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(mission))
    status, _, err = run(capsys, "validate", str(path))
    assert status == 2 and err


def test_schema_knows_each_backends_parameters(schema, registry):
    for kind in ("platform", "mapping", "slam", "detector", "planner"):
        refs = {ref["$ref"].split("/")[-1] for ref in schema["properties"][kind]["anyOf"]}
        assert refs == {f"{kind}_{plugin}" for plugin in registry.backends[kind]}
    assert "global_voxel" in schema["definitions"]["mapping_open3d"]["properties"]


def test_a_folder_named_like_a_packaged_mission_does_not_hide_it(tmp_path, monkeypatch):
    # `amslam run demo --out demo` makes a folder `demo`; the next `amslam run demo` there
    # failed with "demo: a directory; a mission is a YAML file"
    monkeypatch.chdir(tmp_path)
    (tmp_path / "demo").mkdir()
    path = resolve_mission_path("demo")
    assert path.is_file() and path.name == "demo.yaml"
    (tmp_path / "mine").mkdir()  # a folder no packaged mission is named after stays an error
    assert resolve_mission_path("mine") == Path("mine")
