"""Values that validate but would fail or hang a run: each is one ``amslam validate`` error naming
file, line and field (exit 2, no traceback), from the mission file and from ``--set`` alike.

In-process through :func:`amslam.cli.main`; no flight. ``M`` in an expected line stands for the
mission's path; ``M:7`` is its line 7 (see :func:`tests.e2e.missions.small_mission`: line 2 seed,
3 robot, 4 limits, 5 platform, 7 platform.world, 8 platform.camera, 9 mapping, 10 slam,
11 detector, 12 planner). Keys the file does not have are named without a line.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from amslam.cli import main
from amslam.mission import resolve_mission_path
from tests.e2e.missions import small_mission

FINITE = "input should be a finite number"

CASES = [
    # the world: sizes NaN, negative, zero, huge; rooms of width 0; layouts that make no building
    ("platform.world.size=[.nan, 8]", f"M:7: platform.world.size.0: {FINITE} (got nan)"),
    ("platform.world.size=[.inf, 8]", f"M:7: platform.world.size.0: {FINITE} (got inf)"),
    ("platform.world.size=[-1, 8]", "M:7: platform.world.size.0: input should be greater than 0 (got -1)"),
    ("platform.world.size=[0, 8]", "M:7: platform.world.size.0: input should be greater than 0 (got 0)"),
    (
        "platform.world.size=[1e9, 8]",
        "M:7: platform.world.size.0: input should be less than or equal to 500 (got '1e9')",
    ),
    (
        "platform.world.size=[6, 6]",
        "M:7: platform.world.size: building 6x6 m is too small for a corridor (2 m), rooms (2.5 m deep) "
        "and a lobby (4.5 m)",
    ),
    (
        "platform.world.room_width=[5, 2]",
        "M:7: platform.world.room_width: [5, 2]: the narrowest room must not be wider than the widest",
    ),
    (
        "platform.world.room_width=[0, 5]",
        "M:7: platform.world.room_width.0: input should be greater than or equal to 1.5 (got 0)",
    ),
    (
        "platform.world.floors=0",
        "M:7: platform.world.floors: input should be greater than or equal to 1 (got 0)",
    ),
    (
        "platform.world.floors=99",
        "M:7: platform.world.floors: input should be less than or equal to 4 (got 99)",
    ),
    ("platform.world.floor_height=.nan", f"M:7: platform.world.floor_height: {FINITE} (got nan)"),
    (
        "platform.world.door_height=2.9",
        "M:7: platform.world.door_height: 2.9 m: a door must be lower than the ceiling (2.8 m)",
    ),
    (
        "platform.world.shaft_size=5",
        "M:7: platform.world.shaft_size: 5 m: the shaft must be smaller than lobby_width (4.5 m)",
    ),
    (
        "platform.world.seed_offset=1e30",
        "M:7: platform.world.seed_offset: input should be a valid integer, unable to parse string as an "
        "integer (got '1e30')",
    ),
    (
        "platform.world.furniture=1e6",
        "M:7: platform.world.furniture: input should be less than or equal to 10 (got '1e6')",
    ),
    ("platform.world.bogus=1", None),  # unknown key: message lists the keys (checked by prefix below)
    # the start: inside the world, finite
    (
        "platform.start=[100, 3]",
        "M:5: platform.start: (100, 3) is outside the procedural world, which spans [0, 10] x [0, 8] m",
    ),
    ("platform.start=[.nan, 3]", f"M:5: platform.start.0: {FINITE} (got nan)"),
    ("platform.start_yaw=.inf", f"M:5: platform.start_yaw: {FINITE} (got inf)"),
    # the camera: bounded size (a 1e8-pixel-wide image is a 74 GiB allocation), rates, ranges
    (
        "platform.camera.width=100000000",
        "M:8: platform.camera.width: input should be less than or equal to 4096 (got 100000000)",
    ),
    (
        "platform.camera.height=0",
        "M:8: platform.camera.height: input should be greater than or equal to 8 (got 0)",
    ),
    ("platform.camera.rate_hz=.inf", f"M:8: platform.camera.rate_hz: {FINITE} (got inf)"),
    ("platform.camera.rate_hz=0", "M:8: platform.camera.rate_hz: input should be greater than 0 (got 0)"),
    ("platform.camera.min_range=9", "M:8: platform.camera.min_range: 9 m must be below max_range (5 m)"),
    ("platform.camera.hfov_deg=.nan", f"M:8: platform.camera.hfov_deg: {FINITE} (got nan)"),
    (
        "platform.physics_hz=1e12",
        "M:5: platform.physics_hz: input should be less than or equal to 1000 (got '1e12')",
    ),
    (
        "platform.reachable_cell=1e-9",
        "M:5: platform.reachable_cell: input should be greater than or equal to 0.05 (got '1e-9')",
    ),
    (
        "platform.vio.smoothing_distance=1e-12",
        "M:5: platform.vio.smoothing_distance: input should be greater than or equal to 0.01 (got '1e-12')",
    ),
    ("platform.vio.sigma_xy=.inf", f"M:5: platform.vio.sigma_xy: {FINITE} (got inf)"),
    # other worlds and the files they name
    (
        "platform.world={kind: mesh, mesh: nope.ply}",
        "M:7: platform.world.mesh: no such file: D/nope.ply"
        " (nor in AMSLAM_WORLDS: not set; shipped worlds: small_house)",
    ),
    ("platform.world={kind: mesh}", "M:7: platform.world.mesh: required, but missing"),
    (
        "platform.world={kind: mesh, mesh: small.yaml, objects: gone.json}",
        "M:7: platform.world.objects: no such file: D/gone.json (nor in AMSLAM_WORLDS: not set; shipped "
        "worlds: small_house)",
    ),
    ("platform.world={kind: mesh, mesh: .}", "M:7: platform.world.mesh: not a regular file: D"),
    (
        "platform.world={kind: outdoor, size: [5, 30]}",
        "M:7: platform.world.size.0: input should be greater than or equal to 12 (got 5)",
    ),
    (
        "platform.world={kind: outdoor, pole_height: [7, 5]}",
        "M:7: platform.world.pole_height: [7, 5]: the lower end must not be above the upper",
    ),
    # rates of the runtime: inf would be dt = 0, 1e-9 a tick of 30 years
    ("exploration.control_rate_hz=.inf", f"M: exploration.control_rate_hz: {FINITE} (got inf)"),
    ("exploration.control_rate_hz=-.inf", f"M: exploration.control_rate_hz: {FINITE} (got -inf)"),
    (
        "exploration.control_rate_hz=1e-9",
        "M: exploration.control_rate_hz: input should be greater than or equal to 1 (got '1e-9')",
    ),
    (
        "exploration.control_rate_hz=0",
        "M: exploration.control_rate_hz: input should be greater than or equal to 1 (got 0)",
    ),
    ("exploration.replan_period=.nan", f"M: exploration.replan_period: {FINITE} (got nan)"),
    (
        "exploration.max_replan_failures=0",
        "M: exploration.max_replan_failures: input should be greater than or equal to 1 (got 0)",
    ),
    (
        "exploration.panorama_steps=1000000",
        "M: exploration.panorama_steps: input should be less than or equal to 360 (got 1000000)",
    ),
    (
        "exploration.trajectory_rate_hz=1e9",
        "M: exploration.trajectory_rate_hz: input should be less than or equal to 1000 (got '1e9')",
    ),
    # seeds
    ("seed=-1", "M:2: seed: input should be greater than or equal to 0 (got -1)"),
    ("seed=.nan", f"M:2: seed: {FINITE} (got nan)"),
    (
        "seed=abc",
        "M:2: seed: input should be a valid integer, unable to parse string as an integer (got 'abc')",
    ),
    ("seed=1.5", "M:2: seed: input should be a valid integer, got a number with a fractional part (got 1.5)"),
    # the robot and the limits
    ("robot.radius=.inf", f"M:3: robot.radius: {FINITE} (got inf)"),
    ("robot.radius=0", "M:3: robot.radius: input should be greater than 0 (got 0)"),
    ("robot.radius=-1", "M:3: robot.radius: input should be greater than 0 (got -1)"),
    ("robot.max_speed=.inf", f"M:3: robot.max_speed: {FINITE} (got inf)"),
    ("robot.max_speed=1e9", "M:3: robot.max_speed: input should be less than or equal to 30 (got '1e9')"),
    ("robot.altitude=.nan", f"M:3: robot.altitude: {FINITE} (got nan)"),
    ("robot.base=[0, 0, 0, .nan]", f"M:3: robot.base.3: {FINITE} (got nan)"),
    ("limits.max_time=.inf", f"M:4: limits.max_time: {FINITE} (got inf)"),
    ("limits.max_time=-1", "M:4: limits.max_time: input should be greater than 0 (got -1)"),
    ("limits.max_distance=.nan", f"M:4: limits.max_distance: {FINITE} (got nan)"),
    # the area: finite, bounded, lo below hi
    (
        "area={lo: [0, 0, 0], hi: [-1, 5, 5]}",
        "M: area.hi: [-1.0, 5.0, 5.0] must be above lo [0.0, 0.0, 0.0] on every axis; it is not on x",
    ),
    (
        "area={lo: [0, 0, 1], hi: [4, 5, 1]}",
        "M: area.hi: [4.0, 5.0, 1.0] must be above lo [0.0, 0.0, 1.0] on every axis; it is not on z",
    ),
    ("area={lo: [0, 0, .nan], hi: [1, 5, 5]}", f"M: area.lo.2: {FINITE} (got nan)"),
    (
        "area={lo: [0, 0, 0], hi: [1e9, 5, 5]}",
        "M: area.hi.0: input should be less than or equal to 10000 (got '1e9')",
    ),
    ("area={lo: [0, 0, 0]}", "M: area.hi: required, but missing"),
    # files the mission names
    ("prior_map=nope.npz", "M: prior_map: no such file: D/nope.npz"),
    ("prior_map=/etc", "M: prior_map: not a regular file: /etc"),
    # waypoints
    ("tree=waypoints", "M: waypoints.points: tree: waypoints needs at least one point here"),
    ("waypoints.points=[[0, 0, .nan]]", f"M: waypoints.points.0.2: {FINITE} (got nan)"),
    ("waypoints.points=[[0, 0]]", "M: waypoints.points.0.2: required, but missing"),
    (
        "waypoints.points=[[1e9, 0, 1]]",
        "M: waypoints.points.0.0: input should be less than or equal to 10000 (got '1e9')",
    ),
    # backends' own parameters
    (
        "mapping.global_voxel=0",
        "M:9: mapping.global_voxel: input should be greater than or equal to 0.02 (got 0)",
    ),
    (
        "mapping.global_voxel=1e-9",
        "M:9: mapping.global_voxel: input should be greater than or equal to 0.02 (got '1e-9')",
    ),
    ("mapping.local_voxel=.nan", f"M:9: mapping.local_voxel: {FINITE} (got nan)"),
    ("mapping.p_hit=.nan", f"M:9: mapping.p_hit: {FINITE} (got nan)"),
    ("detector.rate_hz=.inf", f"M:11: detector.rate_hz: {FINITE} (got inf)"),
    ("detector.max_range=.nan", f"M:11: detector.max_range: {FINITE} (got nan)"),
    ("planner.epsilon=.nan", f"M:12: planner.epsilon: {FINITE} (got nan)"),
    ("planner.items=0", "M:12: planner.items: input should be greater than or equal to 1 (got 0)"),
    ("slam.keypose_distance=.inf", f"M:10: slam.keypose_distance: {FINITE} (got inf)"),
    # ... and their upper bounds, a case per kind of bound: a noise std (1e300 was an OverflowError
    # mid-run), an angle, a gate, a count, a time window, an object size, a budget, a gain, a grid
    # step, a Poisson rate, a window allocated at once
    (
        "slam={plugin: gtsam, graph: {odometry_sigma_translation: 1e300}}",
        "M:10: slam.graph.odometry_sigma_translation: input should be less than or equal to 10 (got '1e300')",
    ),
    (
        "slam={plugin: gtsam, graph: {bearing_sigma: 10}}",
        "M:10: slam.graph.bearing_sigma: input should be less than or equal to 3.141592653589793 (got 10)",
    ),
    (
        "slam.keypose_yaw=100",
        "M:10: slam.keypose_yaw: input should be less than or equal to 3.141592653589793 (got 100)",
    ),
    (
        "slam={plugin: gtsam, association: {chi2: 1e9}}",
        "M:10: slam.association.chi2: input should be less than or equal to 1000 (got '1e9')",
    ),
    (
        "slam={plugin: gtsam, association: {tentative_timeout: 10000000000}}",
        "M:10: slam.association.tentative_timeout: input should be less than or equal to 1000000 "
        "(got 10000000000)",
    ),
    (
        "slam={plugin: gtsam, loop_closure: {window: 1e9}}",
        "M:10: slam.loop_closure.window: input should be less than or equal to 3600 (got '1e9')",
    ),
    (
        "slam={plugin: gtsam, shapes: {size_prior: {car: {dims: [4, 2, 1e9]}}}}",
        "M:10: slam.shapes.size_prior.car.dims.2: input should be less than or equal to 100 (got '1e9')",
    ),
    (
        "planner={plugin: cop, budget_factor: 1e9}",
        "M:12: planner.budget_factor: input should be less than or equal to 1000 (got '1e9')",
    ),
    (
        "planner.min_gain=1e300",
        "M:12: planner.min_gain: input should be less than or equal to 1000000 (got '1e300')",
    ),
    (
        "planner={plugin: pams, range_step: 1e-9}",
        "M:12: planner.range_step: input should be greater than or equal to 0.05 (got '1e-9')",
    ),
    (
        "detector.false_positive_rate=1e9",
        "M:11: detector.false_positive_rate: input should be less than or equal to 100 (got '1e9')",
    ),
    (
        "mapping.local_size=[1e4, 10, 5]",
        "M:9: mapping.local_size.0: input should be less than or equal to 100 (got '1e4')",
    ),
    (
        "mapping={plugin: open3d, local_size: [100, 100, 100], local_voxel: 0.02}",
        "M:9: mapping.local_size: 100 x 100 x 100 m at local_voxel 0.02 m is 1.25e+11 voxels, more than "
        "5e+07 (a smaller window or a coarser local_voxel)",
    ),
]


def validate(capsys, *argv: str) -> tuple[int, list[str]]:
    try:
        status = main(["validate", *argv])
    except SystemExit as exc:  # argparse
        status = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return status, [line for line in err.splitlines() if line.strip()]


@pytest.mark.parametrize(("override", "expected"), CASES, ids=[c[0] for c in CASES])
def test_a_value_a_run_would_trip_on_is_one_located_error(tmp_path, capsys, override, expected):
    mission = small_mission(tmp_path)
    status, lines = validate(capsys, str(mission), "--set", override)
    assert status == 2
    assert len(lines) == 1, lines
    if expected is None:
        assert lines[0].startswith(
            f"error: {mission}:7: platform.world.bogus: unknown key 'bogus'; expected one of:"
        )
        return
    where = (
        expected.replace("M", str(mission), 1).replace("D/", f"{tmp_path}/").replace(": D", f": {tmp_path}")
    )
    assert lines[0] == f"error: {where}"


FILE_CASES = [  # (YAML appended to the mission file, the line it lands on, the error after path:line)
    ("exploration: {control_rate_hz: .inf}", f"exploration.control_rate_hz: {FINITE} (got inf)"),
    ("area: {lo: [0, 0, 0], hi: [-1, 5, 5]}", "area.hi: [-1.0, 5.0, 5.0] must be above lo [0.0, 0.0, 0.0] on "
     "every axis; it is not on x"),
    ("prior_map: nope.npz", "prior_map: no such file: D/nope.npz"),
    ("waypoints: {points: [[0, .nan, 1]]}", f"waypoints.points.0.1: {FINITE} (got nan)"),
    ("exploration: {control_rate_hz: 1e-9}",
     "exploration.control_rate_hz: input should be greater than or equal to 1 (got '1e-9')"),
    ("exploration: {max_unreachable: -1}",
     "exploration.max_unreachable: input should be greater than or equal to 1 (got -1)"),
    ("exploration: {panorama_steps: 1000000}",
     "exploration.panorama_steps: input should be less than or equal to 360 (got 1000000)"),
    ("area: {lo: [0, 0, .nan], hi: [1, 1, 1]}", f"area.lo.2: {FINITE} (got nan)"),
    ("prior_map: /etc", "prior_map: not a regular file: /etc"),
    ("waypoints: {points: [[0, 0, 1]], tolerance: .inf}", f"waypoints.tolerance: {FINITE} (got inf)"),
]  # fmt: skip


@pytest.mark.parametrize(("text", "expected"), FILE_CASES, ids=[c[0] for c in FILE_CASES])
def test_the_file_and_set_are_treated_alike(tmp_path, capsys, text, expected):
    mission = small_mission(tmp_path)
    key, value = text.split(": ", 1)
    status, from_set = validate(capsys, str(mission), "--set", f"{key}={value}")
    assert status == 2
    lines = mission.read_text().splitlines()
    mission.write_text("\n".join([*lines, text]) + "\n")
    status, from_file = validate(capsys, str(mission))
    assert status == 2
    message = expected.replace("D/", f"{tmp_path}/")
    assert from_set == [f"error: {mission}: {message}"]
    assert from_file == [f"error: {mission}:{len(lines) + 1}: {message}"]


BACKEND_FILE_CASES = [  # (line of the small mission replaced, its new text, the error after path:line)
    (10, "slam: {plugin: gtsam, graph: {odometry_sigma_translation: 11}}",
     "slam.graph.odometry_sigma_translation: input should be less than or equal to 10 (got 11)"),
    (12, "planner: {plugin: greedy, items: 100000}",
     "planner.items: input should be less than or equal to 10000 (got 100000)"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("line", "text", "expected"), BACKEND_FILE_CASES, ids=[c[1] for c in BACKEND_FILE_CASES]
)
def test_a_backend_bound_from_the_file_and_set_alike(tmp_path, capsys, line, text, expected):
    mission = small_mission(tmp_path)
    key, value = text.split(": ", 1)
    status, from_set = validate(capsys, str(mission), "--set", f"{key}={value}")
    assert status == 2
    lines = mission.read_text().splitlines()
    assert lines[line - 1].startswith(f"{key}:")
    lines[line - 1] = text
    mission.write_text("\n".join(lines) + "\n")
    status, from_file = validate(capsys, str(mission))
    assert status == 2
    assert from_set == from_file == [f"error: {mission}:{line}: {expected}"]


def _box_ply(path: Path, hi: tuple[float, float, float]) -> Path:
    """An ASCII PLY of the closed box [0, hi] (12 triangles): the smallest mesh world."""
    v = [(x, y, z) for x in (0, hi[0]) for y in (0, hi[1]) for z in (0, hi[2])]
    f = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
         (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]  # fmt: skip
    head = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
            "property float z", f"element face {len(f)}", "property list uchar int vertex_indices",
            "end_header"]  # fmt: skip
    body = [" ".join(map(str, p)) for p in v] + ["3 " + " ".join(map(str, t)) for t in f]
    path.write_text("\n".join(head + body) + "\n")
    return path


MESH_START_CASES = [  # (the mesh file, platform.start, the error after M:line; None: valid)
    ("box.ply", "[10, 1]",
     "5: platform.start: (10, 1) is outside the mesh world, which spans [0.00, 4.00] x [0.00, 3.00] m"),
    ("box.ply", "[2, -0.5]",
     "5: platform.start: (2, -0.5) is outside the mesh world, which spans [0.00, 4.00] x [0.00, 3.00] m"),
    ("box.ply", "[2, 1.5]", None),
    ("small.yaml", "[2, 1.5]", "7: platform.world.mesh: no triangles in D/small.yaml: not a mesh file"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("mesh", "start", "expected"), MESH_START_CASES, ids=[f"{c[0]}-{c[1]}" for c in MESH_START_CASES]
)
def test_a_mesh_worlds_start_is_checked_against_its_mesh(tmp_path, capfd, mesh, start, expected):
    # a generated world's start was checked against its size; a mesh world's only when it was built
    mission = small_mission(tmp_path)
    _box_ply(tmp_path / "box.ply", (4, 3, 2.5))
    world = f"platform.world={{kind: mesh, mesh: {mesh}}}"
    status = main(["validate", str(mission), "--set", world, "--set", f"platform.start={start}"])
    out, err = capfd.readouterr()  # at the descriptors: open3d's C++ warnings would show here
    if expected is None:
        assert (status, err) == (0, "") and out.startswith(f"{mission}: valid")
        return
    assert status == 2 and out == ""
    assert err == f"error: {mission}:{expected.replace('D/', f'{tmp_path}/')}\n"


def test_an_unreadable_referenced_file_is_named(tmp_path, capsys):
    locked = tmp_path / "map.npz"
    locked.write_bytes(b"x")
    locked.chmod(0)
    try:
        import os

        if os.access(locked, os.R_OK):
            pytest.skip("running as a user who reads any file (root)")
        status, lines = validate(capsys, str(small_mission(tmp_path)), "--set", f"prior_map={locked}")
    finally:
        locked.chmod(0o600)
    assert status == 2
    assert lines == [f"error: {tmp_path}/small.yaml: prior_map: cannot read {locked}: permission denied"]


def test_waypoints_must_fit_inside_the_geofence(capsys):
    status, lines = validate(capsys, "px4_square", "--set", "waypoints.points=[[0, 0, 1], [500, 0, 1]]")
    assert status == 2 and len(lines) == 1
    assert lines[0].endswith(
        ": waypoints.points: the pattern spans 500 m in x, more than the geofence's 10 m "
        "(platform.geofence): it cannot lie inside the fence"
    )


BATTERY_CASES = [  # (key, value, its line in px4_square.yaml, the error after path:line)
    ("battery_land", "0.4", 36,
     "platform.battery_land: 0.4 must not be above battery_return (0.3): the vehicle returns before it must "
     "land"),
    ("battery_return", "0.9", 35,
     "platform.battery_return: 0.9 must not be above battery_min_start (0.5): a flight would start already "
     "returning"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("key", "value", "line", "expected"), BATTERY_CASES, ids=[c[0] for c in BATTERY_CASES]
)
def test_battery_thresholds_out_of_order_are_refused_before_the_run(
    tmp_path, capsys, key, value, line, expected
):
    # checked when the platform configured, i.e. after take-off preparations; now amslam validate
    shipped = resolve_mission_path("px4_square")
    status, from_set = validate(capsys, str(shipped), "--set", f"platform.{key}={value}")
    assert status == 2
    lines = shipped.read_text().splitlines()
    assert lines[line - 1].startswith(f"  {key}: ")
    lines[line - 1] = f"  {key}: {value}"
    copy = tmp_path / "px4_square.yaml"
    copy.write_text("\n".join(lines) + "\n")
    status, from_file = validate(capsys, str(copy))
    assert status == 2
    assert from_set == [f"error: {shipped}:{line}: {expected}"]
    assert from_file == [f"error: {copy}:{line}: {expected}"]


def test_an_inverted_geofence_is_refused(capsys):
    status, lines = validate(
        capsys, "px4_square", "--set", "platform.geofence={lo: [0, 0, 0], hi: [0, 5, 5]}"
    )
    assert status == 2 and len(lines) == 1
    assert lines[0].endswith(
        ": platform.geofence.hi: [0.0, 5.0, 5.0] must be above lo [0.0, 0.0, 0.0] on every axis; "
        "it is not on x"
    )


@pytest.mark.parametrize("name", ["demo", "demo_onnx", "lot_team", "one_floor", "pams_lot_a", "pams_lot_b",
                                  "pams_street", "parking_lot", "px4_square", "small_house", "three_floors",
                                  "warehouse"])  # fmt: skip
def test_the_shipped_missions_stay_valid(capsys, name):
    status, lines = validate(capsys, name)
    assert status == 0 and lines == [], lines


@pytest.fixture
def broken_models(tmp_path):
    from amslam.plugins.pams.uncertainty import DEFAULT_MODELS_PATH

    files = {
        "empty.npz": b"",
        "truncated.npz": DEFAULT_MODELS_PATH.read_bytes()[:3000],
        "text.npz": b"models\n",
        "empty.onnx": b"",
        "garbage.onnx": b"\x08\x07garbage",
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    return tmp_path


MODEL_CASES = [
    ("pams_lot_a", "planner.models", "empty.npz",
     "not readable uncertainty models (EOFError: No data left in file)"),
    ("pams_lot_a", "planner.models", "truncated.npz",
     "not readable uncertainty models (BadZipFile: File is not a zip file)"),
    ("pams_lot_a", "planner.models", "text.npz",
     "not readable uncertainty models (ValueError: This file contains pickled (object) data."),
    ("pams_lot_a", "planner.models", "gone.npz", "no such file"),
    ("pams_lot_a", "planner.prior_objects", "gone.json", "no such file"),
    ("demo_onnx", "detector.model", "empty.onnx", "not a readable ONNX model"),
    ("demo_onnx", "detector.model", "garbage.onnx", "not a readable ONNX model"),
]  # fmt: skip


@pytest.mark.parametrize(("mission", "key", "name", "expected"), MODEL_CASES, ids=[c[2] for c in MODEL_CASES])
def test_a_broken_model_file_is_named_before_the_run(broken_models, capsys, mission, key, name, expected):
    path = broken_models / name
    status, lines = validate(capsys, mission, "--set", f"{key}={path}")
    assert status == 2 and len(lines) == 1, lines
    assert f": {key}: {expected}" in lines[0] and str(path) in lines[0], lines[0]
