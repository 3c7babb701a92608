"""rerun: a small mission flown with ``amslam run --rerun --rrd`` (the live view) and the same run
folder replayed into rerun's in-memory recording (``amslam view --rerun``), both decoded with
rerun's own reader and checked against the run folder's files."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from tests.e2e.missions import small_mission

rr = pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install amslam[interop])")
from rerun.chunk import RrdReader  # noqa: E402

from amslam.apps.rerun_view import replay_run  # noqa: E402
from amslam.apps.rerun_view.replay import read_map  # noqa: E402

AMSLAM = Path(sys.executable).with_name("amslam")


def decode(rrd: Path) -> dict[str, dict[str, list]]:
    """Per entity path: ``timed`` and ``static`` rows, each row a dict of its components."""
    rows: dict[str, dict[str, list]] = defaultdict(lambda: {"timed": [], "static": []})
    for chunk in RrdReader(rrd).stream().to_chunks():
        kind = "static" if chunk.is_static else "timed"
        rows[chunk.entity_path.lstrip("/")][kind] += chunk.to_record_batch().to_pylist()
    return rows


def tum_lines(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.strip() and not line.startswith("#"))


def ply_vertices(path: Path) -> int:
    header = path.read_bytes().partition(b"end_header")[0].decode()  # the body is binary
    return next(int(line.split()[2]) for line in header.splitlines() if line.startswith("element vertex"))


def events(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]


def strip_points(rows: list[dict]) -> int:
    """Points of the (one) line strip of the last row."""
    return len(rows[-1]["LineStrips3D:strips"][0])


@pytest.fixture(scope="module")
def live_flight(tmp_path_factory):
    """``amslam run small.yaml --rerun --rrd``: the run folder and what the command printed."""
    folder = tmp_path_factory.mktemp("rerun-live")
    done = subprocess.run(
        [AMSLAM, "run", str(small_mission(folder)), "--out", str(folder / "runs"), "--rerun", "--rrd"],
        capture_output=True,
        text=True,
        check=False,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr
    (run,) = (folder / "runs").iterdir()
    return run, done.stdout


def test_live_view_of_a_flight_is_saved_in_the_run_folder_and_decodes(live_flight):
    run, stdout = live_flight
    rrd = run / "recording.rrd"
    assert f"rerun recording: {rrd}" in stdout
    assert not [e for e in events(run) if e["event"] == "observer_failed"]
    rows = decode(rrd)
    for source in ("ground_truth", "vio"):
        lines = tum_lines(run / f"{source}.tum")
        assert len(rows[f"world/robot/{source}"]["timed"]) == lines  # every pose, at its stamp
        assert strip_points(rows[f"world/trajectory/{source}"]["static"]) == lines
        assert rows[f"world/trajectory/{source}"]["timed"]  # the path as it grew
    replans = [e for e in events(run) if e["event"] == "replan"]
    assert len(rows["world/tour"]["timed"]) == len(replans) > 0  # amslam_replan
    assert rows["world/keyposes"]["timed"]  # amslam_keyframe
    assert rows["tree"]["timed"]
    maps = [len(m["Points3D:positions"]) for m in rows["world/map"]["timed"]]  # amslam_tick's mapping
    assert len(maps) >= 3 and maps[0] < maps[-1] == ply_vertices(run / "map.ply")  # grows to the final map
    (marks,) = rows["world/landmarks/points"]["static"]
    assert len(marks["Points3D:positions"]) == len(json.loads((run / "landmarks.json").read_text()))


def test_replay_of_a_run_folder_into_the_in_memory_recording(live_flight, tmp_path):
    run, _ = live_flight
    rec = rr.RecordingStream("amslam-test")
    memory = rr.memory_recording(rec)
    counts = replay_run(run, rec)
    rec.flush()
    rrd = tmp_path / "replay.rrd"
    rrd.write_bytes(memory.drain_as_bytes())
    rows = decode(rrd)

    for source in ("ground_truth", "vio", "slam"):
        lines = tum_lines(run / f"{source}.tum")
        assert counts[source] == lines
        assert len(rows[f"world/robot/{source}"]["timed"]) == lines
        assert strip_points(rows[f"world/trajectory/{source}"]["static"]) == lines
    records = events(run)
    assert len(rows["events"]["timed"]) == len(records)
    assert rows["events"]["timed"][-1]["TextLog:text"] == ["run_end verdict=completed"]
    replans = [e for e in records if e["event"] == "replan"]
    tours = rows["world/tour/viewpoints"]["timed"]
    assert [len(t["Points3D:positions"]) for t in tours] == [len(e["tour"]) for e in replans]
    tree = [json.loads(line) for line in (run / "tree.jsonl").read_text().splitlines()]
    changed = [r for r in tree if any(s != "INVALID" for s, _ in (r.get("nodes") or {}).values())]
    assert len(rows["tree"]["timed"]) == len(changed) == counts["tree"]
    (cloud,) = rows["world/map"]["static"]
    assert len(cloud["Points3D:positions"]) == ply_vertices(run / "map.ply") == counts["map"]
    landmarks = json.loads((run / "landmarks.json").read_text())
    (marks,) = rows["world/landmarks/points"]["static"]
    assert marks["Points3D:labels"] == [f"{lm['class']} #{lm['id']}" for lm in landmarks]
    # one class id per landmark class, labelled; the last context logged holds them all
    context = [r for r in rows["world"]["static"] if r.get("AnnotationContext:context")][-1]
    labels = {c["class_description"]["info"]["label"] for c in context["AnnotationContext:context"][0]}
    _, _, voxel_classes = read_map(run)  # map voxels carry their landmark's class, or none
    assert labels == {lm["class"] for lm in landmarks} | set(voxel_classes or ())


def test_shaped_landmarks_are_boxes_with_their_yaw_and_cylinders(live_flight, tmp_path):
    """Cuboids become one box each (half their dims, turned by their yaw about z), cylinders stand
    on their root; the others stay points."""
    run, _ = live_flight
    copy = tmp_path / "run"
    shutil.copytree(run, copy, ignore=shutil.ignore_patterns("*.rrd"))
    landmarks = json.loads((copy / "landmarks.json").read_text())
    assert len(landmarks) >= 3
    landmarks[0]["shape"] = {
        "model": "cuboid",
        "center": [1.0, 2.0, 0.4],
        "yaw": 0.5,
        "dims": [2.0, 1.0, 0.8],
    }
    landmarks[1]["shape"] = {"model": "cuboid", "center": [3.0, 2.0, 0.5], "yaw": -1.0, "dims": [1, 1, 1]}
    landmarks[2]["shape"] = {
        "model": "cylinder",
        "root": [5.0, 1.0, 0.0],
        "axis": [0.0, 0.0, 1.0],
        "radius": 0.3,
        "height": 1.2,
    }
    (copy / "landmarks.json").write_text(json.dumps(landmarks))
    rrd = tmp_path / "shapes.rrd"
    rec = rr.RecordingStream("amslam-test")
    rec.save(rrd)
    replay_run(copy, rec)
    rec.flush()
    del rec
    rows = decode(rrd)

    (boxes,) = rows["world/landmarks/cuboids"]["static"]
    assert boxes["Boxes3D:centers"] == [pytest.approx([1.0, 2.0, 0.4]), pytest.approx([3.0, 2.0, 0.5])]
    assert boxes["Boxes3D:half_sizes"] == [pytest.approx([1.0, 0.5, 0.4]), pytest.approx([0.5, 0.5, 0.5])]
    angles = [r["angle"] for r in boxes["Boxes3D:rotation_axis_angles"]]
    assert angles == pytest.approx([0.5, -1.0])
    assert [r["axis"] for r in boxes["Boxes3D:rotation_axis_angles"]] == [[0.0, 0.0, 1.0]] * 2
    (cylinders,) = rows["world/landmarks/cylinders"]["static"]
    assert cylinders["Cylinders3D:centers"] == [pytest.approx([5.0, 1.0, 0.6])]
    assert cylinders["Cylinders3D:lengths"] == pytest.approx([1.2])
    (points,) = rows["world/landmarks/points"]["static"]
    assert len(points["Points3D:positions"]) == len(landmarks) - 3
