"""The ROS 2 messages of ``amslam export``: frames, landmark shapes, ellipsoids, tours, tree status."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from amslam.apps.export import ros_messages as ros
from amslam.apps.export.mcap_file import gather
from amslam.apps.export.runfolder import (
    CameraMount,
    ExportError,
    RunFolder,
    Trajectory,
    map_ply_cloud,
    read_run_folder,
)
from amslam.errors import RunFileError
from amslam.measurements import MeasurementLog, read_measurements_header
from amslam.types import CameraModel


def trajectory(stamps, xyz, yaws) -> Trajectory:
    quats = Rotation.from_euler("z", np.asarray(yaws, float).reshape(-1, 1)).as_quat()
    return Trajectory(np.asarray(stamps, float), np.hstack([np.asarray(xyz, float), quats]))


def run_folder(**fields) -> RunFolder:
    base = dict(
        path=Path("run"),
        mission_name="unit",
        trajectories={},
        events=[],
        tree_structure=None,
        tree_records=[],
        landmarks=None,
        global_map=None,
        local_map=None,
        camera=CameraMount(np.eye(4), "test"),
        metrics=None,
        warnings=[],
    )
    base.update(fields)
    return RunFolder(**base)


def matrix(translation, rotation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([rotation[k] for k in "xyzw"]).as_matrix()
    T[:3, 3] = [translation[k] for k in "xyz"]
    return T


def test_world_odom_base_chain_puts_the_body_where_slam_does():
    stamps = np.arange(0.0, 5.01, 0.5)
    vio = trajectory(stamps, np.c_[stamps, 0.1 * stamps, np.ones_like(stamps)], 0.2 * stamps)
    # SLAM: the VIO path turned by 0.1 rad and shifted (a drift it corrected), known at key poses only
    T_fix = np.eye(4)
    T_fix[:3, :3] = Rotation.from_euler("z", 0.1).as_matrix()
    T_fix[:3, 3] = [0.3, -0.2, 0.0]
    keys = stamps[::4]
    T_slam = [T_fix @ m for m in ros._matrices(ros.interpolate(vio, keys))]
    slam = Trajectory(keys, np.array([ros.pose7(T) for T in T_slam]))
    run = run_folder(trajectories={"vio": vio, "slam": slam})
    tf = [(t, m["transforms"]) for t, _, topic, _, m in gather(run).items if topic == "/tf"]
    assert len(tf) == len(stamps)
    for t, (world_odom, odom_base) in tf:
        assert (world_odom["header"]["frame_id"], world_odom["child_frame_id"]) == ("world", "odom")
        assert (odom_base["header"]["frame_id"], odom_base["child_frame_id"]) == ("odom", "base_link")
        T_world_odom = matrix(world_odom["transform"]["translation"], world_odom["transform"]["rotation"])
        assert np.allclose(T_world_odom, T_fix, atol=1e-9), t  # a constant correction at every time
        if t / 1e9 in keys:
            T_odom_base = matrix(odom_base["transform"]["translation"], odom_base["transform"]["rotation"])
            k = int(np.flatnonzero(np.isclose(keys, t / 1e9))[0])
            assert np.allclose(T_world_odom @ T_odom_base, T_slam[k], atol=1e-9)


def test_odometry_twist_is_in_the_body_frame():
    stamps = np.arange(0.0, 2.01, 0.1)
    # flying sideways: heading +y (yaw 90°) while moving along world +x at 1 m/s, turning at 0.5 rad/s
    track = trajectory(stamps, np.c_[stamps, 0 * stamps, 0 * stamps], np.pi / 2 + 0.5 * stamps)
    linear, angular = ros.velocities(track)
    assert np.allclose(angular, [0, 0, 0.5], atol=1e-9)
    assert np.allclose(np.linalg.norm(linear, axis=1), 1.0)
    assert linear[0, 1] == pytest.approx(-1.0, abs=0.03)  # world +x is body -y at yaw 90°


def test_landmark_shapes_and_covariance_ellipsoids():
    box_rotation = Rotation.from_euler("z", 0.4).as_matrix().tolist()
    landmarks = [
        {
            "id": 3,
            "class": "car",
            "position": [5.0, 1.0, 0.8],
            "covariance": [[0.04, 0, 0], [0, 0.01, 0], [0, 0, 0.0025]],
            "shape": {
                "model": "cuboid",
                "center": [5, 1, 0.8],
                "yaw": 0.4,
                "dims": [4.6, 1.8, 1.6],
                "rotation": box_rotation,
            },
        },
        {
            "id": 7,
            "class": "hydrant",
            "position": [2.0, 2.0, 0.4],
            "shape": {
                "model": "cylinder",
                "root": [2, 2, 0],
                "axis": [0, 0, 1],
                "radius": 0.15,
                "height": 0.8,
            },
        },
        {"id": 9, "class": "chair", "position": [0.0, 0.0, 0.5], "covariance": None},
    ]
    markers = ros.landmark_markers(landmarks, 1.0)["markers"]
    assert markers[0]["action"] == ros.DELETEALL  # a new array replaces the old one
    by_key = {(m["ns"], m["id"]): m for m in markers[1:]}
    car = by_key["car", 3]
    assert car["type"] == ros.CUBE
    assert [car["scale"][k] for k in "xyz"] == [4.6, 1.8, 1.6]
    q = car["pose"]["orientation"]
    assert Rotation.from_quat([q[k] for k in "xyzw"]).as_euler("xyz")[2] == pytest.approx(0.4)
    hydrant = by_key["hydrant", 7]
    assert hydrant["type"] == ros.CYLINDER
    assert hydrant["pose"]["position"]["z"] == pytest.approx(0.4)  # centred half-way up from the root
    assert [hydrant["scale"][k] for k in "xyz"] == pytest.approx([0.3, 0.3, 0.8])
    assert by_key["chair", 9]["type"] == ros.SPHERE
    ellipsoid = by_key["car/covariance", 3]
    assert ellipsoid["type"] == ros.SPHERE and ellipsoid["color"]["a"] < 1
    # diameters: 2 × 2σ along the principal axes (σ = 0.2, 0.1, 0.05 m)
    assert sorted(ellipsoid["scale"][k] for k in "xyz") == pytest.approx([0.2, 0.4, 0.8])
    assert ("hydrant/covariance", 7) not in by_key and ("chair/covariance", 9) not in by_key
    assert by_key["car", 3]["color"] != by_key["chair", 9]["color"]  # colours by class
    assert by_key["labels", 9]["text"] == "chair 9"


def test_tour_line_slc_pins_and_cumulative_slc_viewpoints():
    events = [
        {"t": 1.0, "event": "replan", "tour": [["explore", 1, 0, 1], ["slc", 2, 0, 1], ["explore", 3, 0, 1]]},
        {"t": 2.0, "event": "replan", "tour": [["slc", 2, 0, 1]]},
        {"t": 3.0, "event": "replan", "tour": [["slc", 4, 4, 1], ["explore", 3, 0, 1]]},
        {"t": 4.0, "event": "replan", "tour": []},
    ]
    stamps = np.arange(0.0, 5.0, 0.5)
    slam = trajectory(stamps, np.zeros((len(stamps), 3)), np.zeros(len(stamps)))
    items = gather(run_folder(events=events, trajectories={"slam": slam})).items
    tours = [m["markers"] for _, _, topic, _, m in items if topic == "/planner/tour"]
    assert len(tours) == 4
    line = next(m for m in tours[0] if m["ns"] == "tour")
    assert line["type"] == ros.LINE_STRIP
    assert [(p["x"], p["y"]) for p in line["points"]] == [(0, 0), (1, 0), (2, 0), (3, 0)]  # from the robot
    (pin,) = [m for m in tours[0] if m["ns"] == "tour_slc"]
    assert pin["type"] == ros.ARROW and pin["points"][1] == {"x": 2.0, "y": 0.0, "z": 1.0}
    assert [m["action"] for m in tours[3]] == [ros.DELETEALL]  # an empty tour clears the last one
    slc = [(t, m["markers"]) for t, _, topic, _, m in items if topic == "/planner/slc_viewpoints"]
    assert [t for t, _ in slc] == [1_000_000_000, 3_000_000_000]  # published when a new one appears
    assert len(slc[-1][1]) == 2


def test_tree_status_is_the_whole_tree_at_each_record():
    structure = [
        {"id": 0, "name": "Mission", "type": "Sequence", "parent": None},
        {"id": 1, "name": "TakeOff", "type": "TakeOff", "parent": 0},
        {"id": 2, "name": "Explore", "type": "GoTo", "parent": 0},
    ]
    records = [
        {
            "t": 0.1,
            "tick": 1,
            "nodes": {"0": ["RUNNING", ""], "1": ["RUNNING", "climbing"]},
            "blackboard": {"/goal": None},
        },
        {"t": 2.0, "tick": 20, "nodes": {"1": ["SUCCESS", "at 1.2 m"], "2": ["RUNNING", "waypoint 1/3"]}},
    ]
    items = gather(run_folder(tree_structure=structure, tree_records=records)).items
    status = [m for _, _, topic, _, m in items if topic == "/tree/status"]
    assert status[0]["running"] == "Mission/TakeOff"
    last = status[1]
    assert last["running"] == "Mission/Explore" and last["tick"] == 20
    assert [(n["name"], n["status"]) for n in last["nodes"]] == [
        ("Mission", "RUNNING"),
        ("TakeOff", "SUCCESS"),
        ("Explore", "RUNNING"),
    ]
    assert last["blackboard"] == {"/goal": None}  # kept from the first record


def test_reading_a_run_folder_locates_problems(tmp_path):
    (tmp_path / "events.jsonl").write_text(
        '{"t": 0.0, "event": "run_start"}\n{"t": 1.0, "event": "replan", "tour": 3}\n'
    )
    with pytest.raises(ExportError, match=r"events.jsonl:2: a replan event's 'tour'"):
        read_run_folder(tmp_path)
    (tmp_path / "events.jsonl").write_text(
        '{"t": 0.0, "event": "run_start"}\n{"t": 1.0, "ev'
    )  # cut mid-write
    (tmp_path / "vio.tum").write_text("0.1 0 0 0 0 0 0 1\n0.2 0 0 0 0 0 0 1\n")
    run = read_run_folder(tmp_path)
    assert len(run.events) == 1 and any("events.jsonl:2: not JSON" in w for w in run.warnings)
    assert any("camera mount" in w and "assumed" in w for w in run.warnings)  # no measurements, no mission
    (tmp_path / "vio.tum").write_text("0.2 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\n0.3 0 0 0 0 0 0 1\n")
    with pytest.raises(ExportError, match=r"vio.tum:2: time 0.1 goes back"):
        read_run_folder(tmp_path)
    (tmp_path / "vio.tum").write_text("0.1 0 0 0 0 0 0 1\n")
    (tmp_path / "landmarks.json").write_text('[{"class": "chair"}]')
    with pytest.raises(
        ExportError, match=r"landmarks.json: landmark 0: needs a 'class' string and a 'position'"
    ):
        read_run_folder(tmp_path)
    (tmp_path / "landmarks.json").unlink()
    (tmp_path / "map.npz").write_bytes(b"not a zip")
    with pytest.raises(ExportError, match=r"map.npz: not a readable .npz"):
        read_run_folder(tmp_path)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ExportError, match="not a run folder"):
        read_run_folder(tmp_path / "empty")


def test_the_command_line_does_not_load_the_interop_libraries():
    # `amslam --help` builds every command's parser: mcap and rosbags must wait for `export` to run
    code = (
        "import sys; from amslam.cli import build_parser; from amslam.registry import build_plugin_manager; "
        "build_parser(build_plugin_manager()); "
        "print(sorted(m for m in ('mcap', 'mcap_ros2', 'rosbags') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_an_export_that_fails_midway_leaves_no_file(tmp_path, monkeypatch):
    pytest.importorskip("mcap_ros2", reason="the interop extra (pip install amslam[interop])")
    from amslam.apps.export import mcap_file

    stamps = np.arange(0.0, 2.0, 0.1)
    run = run_folder(
        trajectories={"vio": trajectory(stamps, np.zeros((len(stamps), 3)), np.zeros(len(stamps)))}
    )
    summary = mcap_file.write_mcap(run, tmp_path / "ok.mcap")
    assert summary.counts["/vio/odometry"] == len(stamps) and (tmp_path / "ok.mcap").is_file()

    written = []

    def full_disk(self, *args):
        if len(written) == 5:
            raise OSError(28, "No space left on device")
        written.append(args)

    monkeypatch.setattr(mcap_file._Channels, "write", full_disk)
    with pytest.raises(OSError):
        mcap_file.write_mcap(run, tmp_path / "out.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.mcap"]


def test_a_binary_ply_map_keeps_its_extra_vertex_values(tmp_path):
    # the map of a run without map.npz: x, y, z and whatever else each vertex carries
    vertices = np.zeros(
        3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("probability", "<f4"), ("class", "u1")]
    )
    vertices["x"], vertices["probability"], vertices["class"] = [1, 2, 3], [0.9, 0.95, 0.99], [1, 2, 3]
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
    header += "".join(
        f"property {t} {n}\n"
        for t, n in [("float", c) for c in "xyz"] + [("float", "probability"), ("uchar", "class")]
    )
    (tmp_path / "map.ply").write_bytes((header + "end_header\n").encode() + vertices.tobytes())
    cloud = map_ply_cloud(tmp_path / "map.ply")
    assert cloud.points[:, 0].tolist() == [1, 2, 3]
    assert set(cloud.values) == {"probability", "class"} and cloud.values["class"].tolist() == [1, 2, 3]
    message = ros.point_cloud(cloud, "world", 0.0)
    assert [f["name"] for f in message["fields"]] == ["x", "y", "z", "probability", "class"]
    assert message["point_step"] == 20 and len(message["data"]) == 60


def test_the_camera_mount_comes_from_the_measurement_logs_header(tmp_path):
    (tmp_path / "vio.tum").write_text("0.1 0 0 0 0 0 0 1\n")
    mount = CameraModel.forward_mount(20.0, (0.1, 0.0, 0.05))
    MeasurementLog(tmp_path / "measurements.jsonl", "r1", mount).close()
    run = read_run_folder(tmp_path)
    assert run.camera.source == "measurements.jsonl header"
    np.testing.assert_allclose(run.camera.T_body_cam, mount, atol=1e-9)
    (tmp_path / "measurements.jsonl").write_text('{"type": "keypose"}\n')  # not a header
    run = read_run_folder(tmp_path)
    assert run.camera.source.startswith("assumed")
    assert any("measurements.jsonl:1: no T_body_cam in the header" in w for w in run.warnings)
    with pytest.raises(RunFileError, match=r"measurements.jsonl:1: not an amslam measurement log"):
        read_measurements_header(tmp_path)
