"""``amslam export RUN --mcap FILE`` on a flown run, read back with the ``mcap`` and ``rosbags`` readers."""

from __future__ import annotations

import json
import shutil
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from amslam.cli import main

pytest.importorskip("mcap_ros2", reason="the interop extra (pip install amslam[interop])")
from mcap.reader import make_reader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402


def tum_lines(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.strip() and not line.startswith("#"))


def ply_vertices(path: Path) -> int:
    # map.ply is binary since the class and probability columns: only its header is text
    header = path.read_bytes().partition(b"end_header")[0].decode("ascii")
    return next(int(line.split()[2]) for line in header.splitlines() if line.startswith("element vertex"))


def read_mcap(path: Path) -> tuple[Counter, dict[str, list], dict[str, tuple[str, str, str]]]:
    """Messages per topic, every decoded message per topic, and (schema name, schema encoding,
    message encoding) per topic."""
    counts: Counter = Counter()
    messages: dict[str, list] = {}
    kinds: dict[str, tuple[str, str, str]] = {}
    decoders = DecoderFactory()
    with open(path, "rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True):
            counts[channel.topic] += 1
            kinds[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                decoded = decoders.decoder_for(channel.message_encoding, schema)(message.data)
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
    return counts, messages, kinds


@pytest.fixture(scope="module")
def exported(small_run, tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    full, ros_only = folder / "run.mcap", folder / "run_ros.mcap"
    assert main(["export", str(small_run.run_dir), "--mcap", str(full)]) == 0
    assert main(["export", str(small_run.run_dir), "--mcap", str(ros_only), "--ros-only"]) == 0
    return small_run.run_dir, full, ros_only


def test_topics_carry_every_record_of_the_run_folder(exported):
    run, full, _ = exported
    counts, messages, kinds = read_mcap(full)
    for name in ("ground_truth", "vio", "slam"):
        lines = tum_lines(run / f"{name}.tum")
        assert counts[f"/{name}/odometry"] == lines, name
        assert counts[f"/{name}/path"] == 1 and len(messages[f"/{name}/path"][0][1].poses) == lines
        assert kinds[f"/{name}/odometry"][:2] == ("nav_msgs/msg/Odometry", "ros2msg")
    # one TF message per VIO pose (world → odom → base_link) and per true pose
    assert counts["/tf"] == tum_lines(run / "vio.tum") + tum_lines(run / "ground_truth.tum")
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert [m for _, m in messages["/events"]] == events
    assert kinds["/events"] == ("amslam/Event", "jsonschema", "json")
    tree_records = len((run / "tree.jsonl").read_text().splitlines()) - 1  # the first is the structure
    assert counts["/tree/status"] == tree_records
    assert counts["/planner/tour"] == sum(e["event"] == "replan" for e in events)
    # the odometry follows the TUM file: first VIO pose, stamped with the run's own clock
    first = np.array((run / "vio.tum").read_text().split()[:8], float)
    t, odometry = messages["/vio/odometry"][0]
    assert t == round(first[0] * 1e9) and odometry.header.frame_id == "odom"
    p = odometry.pose.pose.position
    assert np.allclose([p.x, p.y, p.z], first[1:4])


def test_map_cloud_and_landmark_markers(exported):
    run, full, _ = exported
    _, messages, _ = read_mcap(full)
    cloud = messages["/map/global"][0][1]
    assert cloud.width * cloud.height == ply_vertices(run / "map.ply")
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "probability"]
    points = np.frombuffer(bytes(cloud.data), dtype=[(f.name, "<f4") for f in cloud.fields])
    assert np.all(points["probability"] > 0.8)  # occupied: above the mission's p_occ
    landmarks = json.loads((run / "landmarks.json").read_text())
    assert landmarks, "the small mission maps some furniture"
    (markers,) = [m for _, m in messages["/landmarks"]]
    namespaces = Counter(m.ns for m in markers.markers if m.action == 0)
    for cls, n in Counter(lm["class"] for lm in landmarks).items():
        assert namespaces[cls] == n, cls  # one body per landmark, in its class's namespace
    assert namespaces["labels"] == len(landmarks)
    # the camera mount the run recorded
    header = json.loads((run / "measurements.jsonl").read_text().splitlines()[0])
    (static,) = [m for _, m in messages["/tf_static"]]
    (camera,) = static.transforms
    assert (camera.header.frame_id, camera.child_frame_id) == ("base_link", "camera_optical")
    q = camera.transform.rotation
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    assert np.allclose(R, np.asarray(header["T_body_cam"])[:3, :3], atol=1e-9)


def test_rosbags_reads_every_ros_type(exported):
    from rosbags.highlevel import AnyReader

    run, _, ros_only = exported
    decoded = {}
    with AnyReader([ros_only]) as reader:
        by_topic = {c.topic: c for c in reader.connections}
        assert not any(topic.startswith(("/events", "/tree", "/run")) for topic in by_topic)
        static_qos = by_topic["/tf_static"].ext.offered_qos_profiles
        assert static_qos and static_qos[0].durability.name == "TRANSIENT_LOCAL"
        for connection, _, raw in reader.messages():
            if connection.msgtype not in decoded:
                decoded[connection.msgtype] = reader.deserialize(raw, connection.msgtype)
    assert set(decoded) == {
        "tf2_msgs/msg/TFMessage",
        "nav_msgs/msg/Path",
        "nav_msgs/msg/Odometry",
        "sensor_msgs/msg/PointCloud2",
        "visualization_msgs/msg/MarkerArray",
    }
    assert decoded["sensor_msgs/msg/PointCloud2"].width == ply_vertices(run / "map.ply")
    assert decoded["nav_msgs/msg/Path"].header.frame_id == "world"


def test_a_corrupt_file_is_one_line_naming_it(small_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(small_run.run_dir, run)
    lines = (run / "vio.tum").read_text().splitlines()
    lines[4] = "0.5 1.0 nope"
    (run / "vio.tum").write_text("\n".join(lines) + "\n")
    assert main(["export", str(run), "--mcap", str(tmp_path / "out.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{run / 'vio.tum'}:5:" in err and "Traceback" not in err
    assert not (tmp_path / "out.mcap").exists() and not list(tmp_path.glob("*.part"))

    assert main(["export", str(tmp_path / "nowhere"), "--mcap", str(tmp_path / "out.mcap")]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert main(["export", str(run), "--mcap", str(tmp_path / "out.bag")]) == 2
    assert "must end in .mcap" in capsys.readouterr().err


def test_a_missing_file_leaves_its_topic_out_with_a_warning(small_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(small_run.run_dir, run)
    (run / "landmarks.json").unlink()
    (run / "map.npz").unlink()
    assert main(["export", str(run), "--mcap", str(tmp_path / "out.mcap")]) == 0
    captured = capsys.readouterr()
    assert f"warning: {run / 'landmarks.json'} missing: the landmarks left out" in captured.err
    assert f"warning: {run / 'map.npz'} missing: the final local map" in captured.err
    counts, messages, _ = read_mcap(tmp_path / "out.mcap")
    assert "/landmarks" not in counts and counts["/vio/odometry"] == tum_lines(run / "vio.tum")
    # the map from map.ply instead: the same points, with its class and probability columns
    cloud = messages["/map/global"][0][1]
    names = [f.name for f in cloud.fields]
    assert cloud.width == ply_vertices(run / "map.ply")
    assert names[:3] == ["x", "y", "z"] and {"class", "probability"} <= set(names)
    assert "/map/local" not in counts


def test_without_the_interop_extra_the_error_names_it(small_run, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mcap_ros2", None)  # not installed
    assert main(["export", str(small_run.run_dir), "--mcap", str(tmp_path / "out.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "pip install amslam[interop]" in err
