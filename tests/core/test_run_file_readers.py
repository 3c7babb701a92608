"""Each run-folder format read by the module that writes it: what it gives back, what it forgives
(a torn last line of a stream) and the one located error of a bad file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from amslam.errors import RunFileError
from amslam.geometry import pose_from, tum_line
from amslam.lib.voxel_map import read_saved_map
from amslam.measurements import MeasurementLog, read_measurements
from amslam.rundir import (
    RunDir,
    RunFiles,
    read_jsonl,
    read_landmarks,
    read_metrics,
    read_run_mission,
    read_tum,
    tum_values,
    write_landmarks,
)
from amslam.types import Landmark


def test_a_trajectory_written_by_the_run_folder_reads_back(tmp_path: Path):
    run = RunDir(tmp_path, "m")
    poses = [pose_from(np.array([1.0, 2.0, 3.0]), 0.5), pose_from(np.array([4.0, 5.0, 6.0]), -2.0)]
    run.write_trajectory("slam", [0.5, 1.5], poses)
    trajectory = read_tum(run.path / "slam.tum")
    assert trajectory.stamps.tolist() == [0.5, 1.5]
    np.testing.assert_allclose(trajectory.matrices(), poses, atol=1e-6)


def test_a_torn_last_line_is_dropped_with_a_warning_and_a_bad_line_before_it_is_located(tmp_path: Path):
    tum = tmp_path / "vio.tum"
    whole = tum_line(0.1, np.eye(4)) + tum_line(0.2, np.eye(4))
    tum.write_text(whole + "0.3 1.0 2.")  # a run killed mid-write
    warnings: list[str] = []
    assert len(read_tum(tum, warnings)) == 2
    assert warnings == [f"{tum}:3: not 8 numbers (a run stopped mid-write?): line dropped"]
    tum.write_text("# t x y z qx qy qz qw\n0.1 0 0 0 0 0 0 1\n0.2 0 0 oops 0 0 0 1\n0.3 0 0 0 0 0 0 1\n")
    with pytest.raises(RunFileError, match=r"vio.tum:3: expected 8 numbers"):
        read_tum(tum)
    tum.write_text("0.1 0 0 0 0 0 0 0\n")
    with pytest.raises(RunFileError, match=r"vio.tum:1: quaternion is zero"):
        read_tum(tum)
    with pytest.raises(RunFileError, match=r"missing.tum: cannot be read"):
        read_tum(tmp_path / "missing.tum")


def test_a_stream_read_line_by_line_skips_what_is_not_a_pose():
    assert tum_values("1.5 1 2 3 0 0 0 1") == [1.5, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]
    for line in ("# comment", "", "1 2 3", "1 2 3 4 5 6 7 nan", "1 2 3 4 5 6 7 x"):
        assert tum_values(line) is None


def test_landmarks_written_by_the_run_folder_read_back(tmp_path: Path):
    chair = Landmark(
        3,
        "chair",
        np.array([1.0, 2.0, 0.5]),
        np.eye(3) * 0.01,
        7,
        shape={"model": "cuboid"},
        class_probabilities={"chair": 0.9, "table": 0.1},
    )
    unknown = Landmark(4, "table", np.array([0.0, 1.0, 0.7]), np.full((3, 3), np.nan), 2)  # no uncertainty
    path = write_landmarks(tmp_path / "landmarks.json", [chair, unknown])
    first, second = read_landmarks(path)
    assert first == {
        "id": 3,
        "class": "chair",
        "position": [1.0, 2.0, 0.5],
        "covariance": (np.eye(3) * 0.01).tolist(),
        "observations": 7,
        "shape": {"model": "cuboid"},
        "class_probabilities": {"chair": 0.9, "table": 0.1},
    }
    assert second["class"] == "table" and second["covariance"] is None and "shape" not in second
    assert "class_probabilities" not in second


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('[{"class": "chair", "position": [1, 2', r"landmarks.json:1: not JSON"),
        ('{"class": "chair"}', r"landmarks.json: expected a JSON list of landmarks"),
        ('[{"class": "chair", "position": [1, 2]}]', r"landmarks.json: landmark 0: needs a 'class' string"),
        (
            '[{"class": "chair", "position": [1, 2, 3], "covariance": [[1]]}]',
            r"landmarks.json: landmark 0: 'covariance' must be a 3×3 list",
        ),
        ('[{"class": "chair", "position": [1, 2, 3], "shape": 5}]', r"landmark 0: 'shape' must be an object"),
        (
            '[{"class": "chair", "position": [1, 2, 3], "class_probabilities": {"chair": 1.5}}]',
            r"landmark 0: 'class_probabilities' must map class names to numbers in \[0, 1\]",
        ),
    ],
)
def test_a_bad_landmarks_file_is_one_error_naming_it(tmp_path: Path, text: str, expected: str):
    (tmp_path / "landmarks.json").write_text(text)
    with pytest.raises(RunFileError, match=expected):
        read_landmarks(tmp_path / "landmarks.json")


def test_a_saved_map_reads_back_with_its_occupied_voxels(tmp_path: Path):
    np.savez_compressed(
        tmp_path / "map.npz",
        format=np.array("amslam-voxels-1"),
        global_index=np.array([[0, 0, 0], [1, 2, 3]]),
        global_logodds=np.array([3.0, 1.38], np.float32),  # logit(0.8) = 1.386: the second is not occupied
        global_voxel=np.array(0.5),
    )
    saved = read_saved_map(tmp_path / "map.npz")
    assert saved.local_map is None and saved.global_map.voxel == 0.5
    assert saved.global_map.centres()[saved.global_map.occupied()].tolist() == [[0.25, 0.25, 0.25]]
    assert saved.global_map.occupied(p_occ=0.75).tolist() == [True, True]
    assert saved.slab_history.shape == (0, 3)  # a map saved without one


@pytest.mark.parametrize(
    ("arrays", "expected"),
    [
        (None, r"map.npz: not a readable .npz"),
        ({"format": np.array("other-1")}, r"map.npz: not an amslam voxel map"),
        ({"global_index": np.zeros((2, 3))}, r"map.npz: the global map is incomplete"),
        (
            {"global_index": np.zeros((2, 3)), "global_logodds": np.zeros(3), "global_voxel": np.array(0.1)},
            r"map.npz: the global map's index, log-odds and voxel size do not agree",
        ),
        (
            {
                "global_index": np.zeros((2, 3)),
                "global_logodds": np.zeros(2),
                "global_voxel": np.array(0.1),
                "global_slab_history": np.full((2, 3), 0.5),
            },
            r"map.npz: the global map's slab history is not N×3 voxel indices",
        ),
    ],
)
def test_a_bad_saved_map_is_one_error_naming_it(tmp_path: Path, arrays, expected: str):
    path = tmp_path / "map.npz"
    if arrays is None:
        path.write_bytes(b"PK\x03\x04 cut short")
    else:
        np.savez(path, **arrays)
    with pytest.raises(RunFileError, match=expected):
        read_saved_map(path)


def test_a_run_mission_reads_as_plain_data_and_a_bad_one_is_named(tmp_path: Path):
    RunFiles(tmp_path).write_yaml("mission.yaml", {"name": "x", "planner": {"plugin": "not_installed_here"}})
    assert read_run_mission(tmp_path) == read_run_mission(tmp_path / "mission.yaml")
    assert read_run_mission(tmp_path)["planner"] == {"plugin": "not_installed_here"}
    for text, expected in (
        ("- a\n- b\n", "not a mission"),
        ("a: [\n", "not readable YAML"),
        ("", "not a mission"),
    ):
        (tmp_path / "mission.yaml").write_text(text)
        with pytest.raises(RunFileError, match=rf"mission.yaml: {expected}"):
            read_run_mission(tmp_path)
    with pytest.raises(RunFileError, match=r"missing: cannot be read"):
        read_run_mission(tmp_path / "missing")


def test_metrics_read_from_the_folder_or_the_file_and_a_bad_one_is_named(tmp_path: Path):
    RunFiles(tmp_path).write_json("metrics.json", {"verdict": "completed", "distance_m": np.float64(2.5)})
    assert (
        read_metrics(tmp_path)
        == read_metrics(tmp_path / "metrics.json")
        == {
            "verdict": "completed",
            "distance_m": 2.5,
        }
    )
    (tmp_path / "metrics.json").write_text("[1, 2]")
    with pytest.raises(RunFileError, match=r"metrics.json: not a JSON object"):
        read_metrics(tmp_path)


def test_a_json_lines_stream_forgives_only_a_torn_last_line(tmp_path: Path):
    events = tmp_path / "events.jsonl"
    events.write_text('{"t": 0.0, "event": "run_start"}\n\n{"t": 1.0, "event": "replan"}\n{"t": 2.0, "ev')
    warnings: list[str] = []
    assert [n for n, _ in read_jsonl(events, warnings)] == [1, 3]
    assert warnings == [f"{events}:4: not JSON (a run stopped mid-write?): line dropped"]
    events.write_text('{"t": 0.0}\n[1, 2]\n{"t": 1.0}\n')
    with pytest.raises(RunFileError, match=r"events.jsonl:2: not a JSON object"):
        read_jsonl(events)
    events.write_text('{"t": 0.0}\n{"t": 1.\n{"t": 1.0}\n')
    with pytest.raises(RunFileError, match=r"events.jsonl:2: not JSON"):
        read_jsonl(events)


def test_a_measurement_log_cut_mid_write_reads_and_a_garbled_one_is_named(tmp_path: Path):
    log = MeasurementLog(tmp_path / "measurements.jsonl", "r1", np.eye(4))
    log.close()
    with open(tmp_path / "measurements.jsonl", "a") as f:
        f.write('{"type": "keyp')  # killed mid-write
    assert read_measurements(tmp_path).robot == "r1"
    (tmp_path / "measurements.jsonl").write_text((tmp_path / "measurements.jsonl").read_text() + '"x"\n{}\n')
    with pytest.raises(RunFileError, match=r"measurements.jsonl:2: not JSON"):
        read_measurements(tmp_path)
    with pytest.raises(RunFileError, match=r"missing: cannot be read"):
        read_measurements(tmp_path / "missing")


def test_a_measurement_record_missing_a_field_or_garbled_is_named_by_line(tmp_path: Path):
    log = MeasurementLog(tmp_path / "measurements.jsonl", "r1", np.eye(4))
    log.close()
    header = (tmp_path / "measurements.jsonl").read_text()
    keypose = {"type": "keypose", "id": 0, "t": 0.5, "T_odom_body": [0, 0, 1, 0, 0, 0, 1]}  # no "rel"
    (tmp_path / "measurements.jsonl").write_text(header + json.dumps(keypose) + "\n")
    with pytest.raises(RunFileError, match=r"measurements.jsonl:2: keypose record has no 'rel'"):
        read_measurements(tmp_path)
    keypose["rel"] = [0, 0, 0, 0, 0, 0, 1]
    detection = {"type": "detections", "keypose": 0, "objects": [{"class": "chair", "confidence": "high"}]}
    (tmp_path / "measurements.jsonl").write_text(
        header + json.dumps(keypose) + "\n" + json.dumps(detection) + "\n"
    )
    with pytest.raises(RunFileError, match=r"measurements.jsonl:3: malformed detections record"):
        read_measurements(tmp_path)
