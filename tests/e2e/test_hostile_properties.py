"""Property-based hostile input (hypothesis): any mission made by mutating a valid one, any
``--set``, any argument list ends with exit 0, 1 or 2, one ``error:`` line per problem and no
traceback. In-process through :func:`amslam.cli.main`; nothing flies (commands that would fly,
serve or connect are given a mission that cannot load)."""

from __future__ import annotations

import contextlib
import copy
import io
import math
import os
import tempfile
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from amslam.cli import main
from amslam.errors import MissionError
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from tests.e2e.missions import small_mission

SETTINGS = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True
)

with tempfile.TemporaryDirectory() as folder:
    VALID = yaml.safe_load(small_mission(Path(folder)).read_text())

#: key paths of the small mission and of sections it leaves to defaults
PATHS = [
    ("name",), ("seed",), ("robot", "radius"), ("robot", "max_speed"), ("robot", "altitude"),
    ("robot", "base"),
    ("limits", "max_time"), ("limits", "max_distance"), ("area",), ("area", "lo"), ("prior_map",), ("tree",),
    ("waypoints", "points"), ("exploration", "control_rate_hz"), ("exploration", "replan_period"),
    ("exploration", "max_replan_failures"), ("exploration", "panorama_steps"), ("plugins", "disable"),
    ("platform",), ("platform", "plugin"), ("platform", "world"), ("platform", "world", "size"),
    ("platform", "world", "room_width"), ("platform", "world", "floors"), ("platform", "world", "kind"),
    ("platform", "world", "mesh"), ("platform", "start"), ("platform", "camera", "width"),
    ("platform", "camera", "rate_hz"), ("platform", "camera", "min_range"), ("platform", "vio", "rate_hz"),
    ("mapping", "plugin"), ("mapping", "global_voxel"), ("mapping", "local_size"), ("slam", "plugin"),
    ("detector", "rate_hz"), ("planner", "plugin"), ("planner", "items"), ("bogus",),
]  # fmt: skip

REGISTRY = build_plugin_manager()

NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e9, -1e9, 1e308, 1e-12, -1.0]),
    st.integers(min_value=-(2**70), max_value=2**70),
)
SCALARS = st.one_of(NUMBERS, st.booleans(), st.none(), st.text(max_size=12))
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)


def cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(list(argv))
        except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
            status = exc.code
    return status, out.getvalue(), err.getvalue()


def assert_clean(status: int, out: str, err: str, allowed=(0, 1, 2)) -> None:
    assert status in allowed, (status, err)
    assert "Traceback" not in out + err, err


def mutate(data: dict, path: tuple, value, delete: bool) -> dict:
    raw = copy.deepcopy(data)
    node = raw
    for key in path[:-1]:
        if not isinstance(node.get(key), dict):
            node[key] = {}
        node = node[key]
    if delete:
        node.pop(path[-1], None)
    else:
        node[path[-1]] = value
    return raw


@SETTINGS
@given(mutations=st.lists(st.tuples(st.sampled_from(PATHS), VALUES, st.booleans()), min_size=1, max_size=4))
def test_any_mutated_mission_validates_or_is_refused_in_one_line_per_problem(mutations):
    raw = VALID
    for path, value, delete in mutations:
        raw = mutate(raw, path, value, delete)
    with tempfile.TemporaryDirectory() as folder:
        mission = Path(folder) / "m.yaml"
        mission.write_text(yaml.safe_dump(raw, allow_unicode=True))
        status, out, err = cli("validate", str(mission))
        if status == 0:  # what validates is what a run can use: every number in it finite
            loaded = load_mission(mission, REGISTRY)
            for dump in [
                loaded.model.model_dump(),
                *(c.params.model_dump() for c in loaded.backends.values()),
            ]:
                assert not list(_non_finite(dump)), list(_non_finite(dump))
    assert_clean(status, out, err, allowed=(0, 2))
    if status == 2:
        lines = [line for line in err.splitlines() if line.strip()]
        assert lines and all(line.startswith("error: ") for line in lines), err


def _non_finite(value, path=()):
    if isinstance(value, float) and not math.isfinite(value):
        yield path, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _non_finite(item, (*path, key))
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            yield from _non_finite(item, (*path, i))


@SETTINGS
@given(path=st.sampled_from(PATHS), text=st.text(max_size=30))
def test_any_set_is_taken_like_the_file_or_refused(path, text):
    with tempfile.TemporaryDirectory() as folder:
        mission = small_mission(Path(folder))
        status, out, err = cli("validate", str(mission), "--set", f"{'.'.join(path)}={text}")
    assert_clean(status, out, err, allowed=(0, 2))


@SETTINGS
@given(text=st.one_of(st.text(max_size=200), st.binary(max_size=200).map(lambda b: b.decode("latin-1"))))
def test_any_text_as_a_mission_file_is_loaded_or_refused(text):
    registry = REGISTRY
    with tempfile.TemporaryDirectory() as folder:
        mission = Path(folder) / "m.yaml"
        mission.write_text(text, encoding="utf-8", errors="surrogateescape")
        try:
            load_mission(mission, registry)
        except MissionError as exc:
            assert exc.problems and all(p.strip() for p in exc.problems)


COMMANDS = ["validate", "plugins", "dump-config", "tree", "view", "world", "run", "experiment", "fly",
            "characterise", "nonsense", ""]  # fmt: skip
WORDS = ["demo", "--set", "seed=[1", "seed=-1", "--out", "/proc/x", "--seeds", "0", "abc", "-3", "--robots",
         "1,x", "--port", "99999", "--format", "png", "dot", "--help", "-h", "mapping", "open3d", "planner",
         "import", "slc-ablation", "planners", "--at", "nan", "--first-seed", "1e400", "--", "-", "..",
         "/"]  # fmt: skip
FLIES = {"run", "fly", "experiment", "characterise"}


@SETTINGS
@given(
    command=st.sampled_from(COMMANDS),
    words=st.lists(st.one_of(st.sampled_from(WORDS), st.text(max_size=10)), max_size=6),
)
def test_any_argument_list_ends_with_0_1_or_2_and_no_traceback(command, words):
    argv = [command, *words] if command else words
    if command in FLIES:
        # nothing may fly, connect or serve here: the mission these commands get cannot load
        argv = [command, "no-such-mission.yaml", *[w for w in words if w != "demo"]]
    if "--serve" in argv or "--screenshot" in argv:
        return
    with tempfile.TemporaryDirectory() as folder:
        cwd = os.getcwd()
        os.chdir(folder)  # anything a command writes lands here
        try:
            status, out, err = cli(*argv)
        finally:
            os.chdir(cwd)
    assert_clean(status, out, err)


NUMERIC_PATHS = [
    ("seed",),
    ("robot", "radius"),
    ("robot", "max_speed"),
    ("robot", "altitude"),
    ("robot", "clearance"),
    ("limits", "max_time"),
    ("limits", "max_distance"),
    ("exploration", "control_rate_hz"),
    ("exploration", "replan_period"),
    ("exploration", "goal_tolerance"),
    ("exploration", "viewpoint_period"),
    ("exploration", "trajectory_rate_hz"),
    ("platform", "world", "floor_height"),
    ("platform", "world", "furniture"),
    ("platform", "camera", "width"),
    ("platform", "camera", "rate_hz"),
    ("platform", "camera", "max_range"),
    ("platform", "vio", "rate_hz"),
    ("platform", "vio", "sigma_xy"),
    ("platform", "physics_hz"),
    ("mapping", "global_voxel"),
    ("mapping", "local_voxel"),
    ("mapping", "max_range"),
    ("detector", "rate_hz"),
    ("detector", "max_range"),
    ("planner", "epsilon"),
    ("slam", "keypose_distance"),
]


@SETTINGS
@given(path=st.sampled_from(NUMERIC_PATHS), value=NUMBERS)
def test_a_number_that_is_not_finite_is_refused_where_it_is(path, value):
    raw = mutate(VALID, path, value, delete=False)
    with tempfile.TemporaryDirectory() as folder:
        mission = Path(folder) / "m.yaml"
        mission.write_text(yaml.safe_dump(raw))
        status, out, err = cli("validate", str(mission))
    assert_clean(status, out, err, allowed=(0, 2))
    if isinstance(value, float) and not math.isfinite(value):
        assert status == 2
        (line,) = [line for line in err.splitlines() if line.strip()]
        assert f": {'.'.join(path)}: input should be a finite number" in line, line
