"""benchmarks/slam_offline.py: flights re-solved offline, with the true odometry or object surfaces."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.lib.shapes import cuboid_pose, points_inside
from amslam.measurements import LoggedDetection, RobotMeasurements, read_measurements
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from tests.apps.benchmark_script import load_benchmark
from tests.tiny_mission import tiny_mission_file
from tests.world_summaries import objects_world


@pytest.fixture(scope="module")
def registry():  # noqa: ANN201
    return build_plugin_manager(())


@pytest.fixture(scope="module")
def flight(registry, tmp_path_factory) -> Path:  # noqa: ANN001
    folder = tmp_path_factory.mktemp("offline")
    spec = str(tiny_mission_file(folder, max_time=40, seed=3))
    mission = load_mission(spec, registry, ["exploration.look_around=true"])
    return Runner(mission, registry, folder / "runs").run().run_dir


def test_true_odometry_leaves_the_landmarks_little_to_correct(flight, registry) -> None:  # noqa: ANN001
    b = load_benchmark("slam_offline")
    logged = b.resolve(flight, "centroid", "logged", "logged", [], registry)
    true = b.resolve(flight, "centroid", "true", "logged", [], registry)
    assert logged["vio"] == true["vio"]  # VIO is scored as flown in every variant
    assert logged["objects"] > 0 and logged["mapped"] > 0
    # the true key poses as odometry: the solve stays within centimetres of them
    assert true["slam"]["rms_m"] < 0.05
    assert true["slam"]["rms_m"] <= logged["slam"]["rms_m"] + 1e-9 or logged["slam"]["rms_m"] < 0.05


def test_a_cuboid_variant_and_a_setting_reach_the_solve(flight, registry) -> None:  # noqa: ANN001
    b = load_benchmark("slam_offline")
    row = b.resolve(
        flight, "cuboid", "logged", "true-surface", ["slam.shapes.window=6"], registry, depth_noise="0.004"
    )
    assert row["variant"] == {
        "models": "cuboid",
        "odometry": "logged",
        "points": "true-surface",
        "depth_noise": "0.004",
        "set": ["slam.shapes.window=6"],
    }
    assert "cuboid, points true-surface, depth noise 0.004, slam.shapes.window=6" in b.table([row])
    with pytest.raises(b.OfflineError, match="--depth-noise 'loud'"):
        b._depth_noises("loud")
    with pytest.raises(b.OfflineError, match="no_such_key"):
        b.resolve(flight, "cuboid", "logged", "logged", ["slam.shapes.no_such_key=1"], registry)
    with pytest.raises(b.OfflineError, match="--models 'cuboid=box'"):
        b.resolve(flight, "cuboid=box", "logged", "logged", [], registry)


def test_a_flight_of_an_older_version_is_re_solved_only_when_asked(flight, registry, tmp_path: Path) -> None:  # noqa: ANN001
    b = load_benchmark("slam_offline")
    old = tmp_path / "old"
    old.mkdir()
    text = (flight / "mission.yaml").read_text()
    assert "\nslam:\n" in text
    (old / "mission.yaml").write_text(text.replace("\nslam:\n", "\nslam:\n  renamed_since: 1\n", 1))
    (old / "measurements.jsonl").write_text((flight / "measurements.jsonl").read_text())
    with pytest.raises(b.OfflineError, match=r"slam.renamed_since: unknown key.*--drop-unknown-keys"):
        b.resolve(old, "centroid", "logged", "logged", [], registry)
    row = b.resolve(old, "centroid", "logged", "logged", [], registry, drop_unknown_keys=True)
    assert row == {**b.resolve(flight, "centroid", "logged", "logged", [], registry), "run_dir": str(old)}


def _log_with_one_detection(points_body: np.ndarray) -> RobotMeasurements:
    truth = np.eye(4)[None].repeat(2, axis=0)
    truth[1, :3, 3] = [1.0, 0.0, 0.0]
    vio = truth.copy()
    vio[1, :3, 3] = [1.1, 0.05, 0.0]
    det = LoggedDetection(0, "chair", 0.9, points_body.mean(axis=0), points_body)
    return RobotMeasurements(
        robot="r",
        T_world_odom=np.eye(4),
        T_body_cam=np.eye(4),
        stamps=np.array([0.0, 1.0]),
        T_odom_body=vio,
        rel=np.array([np.eye(4), np.linalg.inv(vio[0]) @ vio[1]]),
        truth=truth,
        detections=[det],
    )


def test_points_move_onto_the_true_box_and_odometry_becomes_the_truth() -> None:
    b = load_benchmark("slam_offline")
    box = {"model": "cuboid", "center": [3.0, 0.0, 0.5], "yaw": 0.3, "dims": [0.5, 0.4, 1.0]}
    world = objects_world({"chair_1": ("chair", box["center"])}, {"chair_1": box})
    rng = np.random.default_rng(0)
    noisy = np.array(box["center"]) + rng.normal(0, 0.3, (50, 3))
    log = _log_with_one_detection(noisy)
    moved = b.with_true_surface_points(log, world).detections[0].points
    assert points_inside(box, moved, 1e-9).all()  # inside the box ...
    local = np.abs((moved - np.array(box["center"])) @ cuboid_pose(box)[:3, :3])
    on_face = np.isclose(local, np.array(box["dims"]) / 2).any(axis=1)
    assert on_face.all()  # ... and on its surface
    true = b.with_true_odometry(log)
    np.testing.assert_allclose(true.T_odom_body, log.truth)
    np.testing.assert_allclose(true.rel[1][:3, 3], [1.0, 0.0, 0.0])


def test_bad_input_is_named(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    b = load_benchmark("slam_offline")
    assert b.main([str(tmp_path)]) == 2
    assert f"{tmp_path}: no run folder (measurements.jsonl) there" in capsys.readouterr().err
    assert b.main([str(tmp_path), "--odometry", "vio"]) == 2
    assert "--odometry 'vio': choose among logged, true" in capsys.readouterr().err
    assert b.main([str(tmp_path), "--models", "chair="]) == 2
    assert "'chair=' is not CLASS=MODEL" in capsys.readouterr().err
    assert b.parse_models("chair=cuboid, *=centroid") == {"chair": "cuboid", "*": "centroid"}


def test_a_log_without_truth_is_refused(flight, registry, tmp_path: Path) -> None:  # noqa: ANN001
    b = load_benchmark("slam_offline")
    real = tmp_path / "real"
    real.mkdir()
    (real / "mission.yaml").write_text((flight / "mission.yaml").read_text())
    lines = (flight / "measurements.jsonl").read_text().splitlines()
    import json

    out = []
    for line in lines:
        rec = json.loads(line)
        rec.pop("truth", None)
        out.append(json.dumps(rec))
    (real / "measurements.jsonl").write_text("\n".join(out) + "\n")
    assert read_measurements(real).truth is None
    with pytest.raises(b.OfflineError, match="no true key poses"):
        b.resolve(real, "centroid", "logged", "logged", [], registry)
