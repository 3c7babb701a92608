"""Report metrics computed from a run's outputs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from amslam.apps.report import in_amslam_classes, landmark_accuracy, object_accuracy
from amslam.lib import shapes
from amslam.types import Landmark
from tests.world_summaries import objects_world


def _lm(i: int, cls: str, p: list[float]) -> Landmark:
    return Landmark(i, cls, np.array(p, float), np.eye(3) * 0.01, 5)


def test_landmark_accuracy_tells_the_maps_shift_from_the_landmarks_own_error() -> None:
    world = objects_world({f"c{i}": ("chair", [2.0 * i, 0, 0]) for i in range(4)})
    shift = np.array([0.3, -0.1, 0.0])
    own = [[0.05, 0, 0], [-0.05, 0, 0], [0, 0.05, 0], [0, -0.05, 0]]  # about the shift, mean zero
    lms = [_lm(i, "chair", list(np.array([2.0 * i, 0, 0]) + shift + own[i])) for i in range(4)]
    acc = landmark_accuracy(lms, world)
    assert np.allclose(acc["common_offset_m"], shift, atol=1e-4)
    assert np.isclose(acc["error_about_offset_m"], 0.05, atol=1e-4)
    assert acc["mean_error_m"] > 0.3  # the plain error holds both
    assert "common_offset_m" not in landmark_accuracy([], world)


def test_landmark_accuracy_pairs_by_class_and_counts_duplicates_and_spurious() -> None:
    world = objects_world(
        {"a": ("chair", [0, 0, 0]), "b": ("chair", [0.75, 0, 0]), "c": ("table", [5, 5, 0])}
    )
    lms = [
        _lm(0, "chair", [0.1, 0, 0]),  # chair a, 0.1 m off
        _lm(1, "chair", [0.75, 0.6, 0]),  # chair b, 0.6 m off
        _lm(2, "chair", [0.05, 0.05, 0]),  # a second landmark on chair a
        _lm(3, "table", [0.0, 0.2, 0]),  # a table where there is only a chair
        _lm(4, "table", [5, 5.2, 0]),  # table c
    ]
    acc = landmark_accuracy(lms, world)
    assert acc["objects"] == 3 and acc["matched"] == 3
    assert acc["duplicates"] == 1 and acc["spurious"] == 1
    assert acc["off_by_more_than_0_5_m"] == 1
    # one-to-one: the duplicate at 0.07 m takes chair a, landmark 0 is left as the duplicate
    assert np.isclose(acc["mean_error_m"], (np.hypot(0.05, 0.05) + 0.6 + 0.2) / 3, atol=1e-3)
    chair, table = acc["by_class"]["chair"], acc["by_class"]["table"]
    assert (
        chair["objects"],
        chair["landmarks"],
        chair["matched"],
        chair["duplicates"],
        chair["spurious"],
    ) == (
        2,
        3,
        2,
        1,
        0,
    )
    assert (
        table["objects"],
        table["landmarks"],
        table["matched"],
        table["duplicates"],
        table["spurious"],
    ) == (
        1,
        2,
        1,
        0,
        1,
    )
    assert np.isclose(table["mean_error_m"], 0.2, atol=1e-6) and chair["off_by_more_than_0_5_m"] == 1


def test_a_mesh_worlds_own_class_names_are_scored_in_amslams_classes_too() -> None:
    # The shared house names its tables after its models; an image detector says "table".
    world = objects_world(
        {
            "k": ("kitchen_table", [0, 0, 0]),
            "r": ("reading_desk", [4, 0, 0]),
            "s": ("shoe_rack", [8, 0, 0]),
            "c": ("chair", [0, 4, 0]),
            "p": ("desk_portrait", [4, 4, 0]),  # a picture: building structure to the class map
            "w": ("room_window", [8, 4, 0]),  # no rule names it: it keeps its own class
        }
    )
    image_detector = [
        _lm(0, "table", [0.1, 0, 0]),
        _lm(1, "table", [4, 0.1, 0]),
        _lm(2, "shelf", [8, 0, 0.1]),
        _lm(3, "chair", [0, 4.1, 0]),
    ]
    assert landmark_accuracy(image_detector, world)["matched"] == 1  # by the world's names: the chair
    lms, objects = in_amslam_classes(image_detector, world)
    acc = landmark_accuracy(lms, objects)
    assert acc["objects"] == 5 and acc["matched"] == 4 and acc["spurious"] == 0
    assert acc["by_class"]["table"]["objects"] == 2 and acc["by_class"]["table"]["matched"] == 2
    assert acc["by_class"]["shelf"]["matched"] == 1 and acc["by_class"]["room_window"]["matched"] == 0
    # the simulator's detector reports the world's names: the same objects, now in amslam's classes
    sim_detector = [
        _lm(i, world.object_classes[k], world.object_positions[k]) for i, k in enumerate("krscpw")
    ]
    lms, objects = in_amslam_classes(sim_detector, world)
    assert sorted(lm.class_name for lm in lms) == ["chair", "room_window", "shelf", "table", "table"]
    assert landmark_accuracy(lms, objects)["matched"] == 5
    # a world already in amslam's classes (procedural buildings, car parks) gets no second score
    assert (
        in_amslam_classes(image_detector, objects_world({"a": ("chair", [0, 0, 0]), "b": ("car", [5, 0, 0])}))
        is None
    )


def test_object_accuracy_fig9_error_is_length_and_width_of_vehicles_only() -> None:
    """Paper 2 Fig. 9 scores vehicles by length and width; height and cylinders stay out of it."""
    yaw = 0.4
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    car_a = shapes.cuboid_shape(R, [0, 0, 0.75], [4.6, 1.8, 1.5])
    car_b = shapes.cuboid_shape(R, [0, 5, 0.75], [4.2, 1.7, 1.4])
    pole = shapes.cylinder_shape(np.array([8.0, 0, 0]), np.array([0, 0, 1.0]), 0.15, 6.0)
    world = objects_world({"a": ("car", [0, 0, 0.75]), "b": ("car", [0, 5, 0.75]), "p": ("pole", [8, 0, 0])})
    world = dataclasses.replace(world, object_shapes={"a": car_a, "b": car_b, "p": pole})
    # car a: length 0.2 m short, height 0.5 m too tall; seen a quarter turn off (l and w swapped)
    est_a = shapes.cuboid_shape(
        R @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]), [0.3, 0, 0.75], [1.8, 4.4, 2.0]
    )
    est_b = shapes.cuboid_shape(R, [0, 5.1, 0.7], [4.2, 1.9, 1.4])  # width 0.2 m off
    dup_b = shapes.cuboid_shape(R, [0, 6.8, 0.7], [2.0, 1.7, 1.4])  # a second landmark on car b
    est_p = shapes.cylinder_shape(np.array([8.0, 0.1, 0]), np.array([0, 0, 1.0]), 0.2, 6.0)
    lms = [
        Landmark(i, c, np.asarray(shapes.shape_center(s)), np.eye(3), 5, 0, s)
        for i, (c, s) in enumerate([("car", est_a), ("car", est_b), ("car", dup_b), ("pole", est_p)])
    ]
    acc = object_accuracy(lms, world)
    car = acc["car"]
    assert car["mapped"] == 2 and car["duplicates"] == 1 and car["spurious"] == 0
    # per car: mean(|dl|, |dw|) = 0.1 and 0.1; with the height: (0.2 + 0.5) / 3 and 0.2 / 3
    assert car["fig9_error_mean_m"] == pytest.approx(0.1) and car["fig9_error_std_m"] == pytest.approx(0.0)
    assert car["dims_error_mean_m"] == pytest.approx((0.7 / 3 + 0.2 / 3) / 2, abs=1e-4)
    assert "fig9_error_mean_m" not in acc["pole"] and acc["pole"]["dims_error_mean_m"] == pytest.approx(0.1)
    overall = acc["overall"]
    assert overall["fig9_objects"] == 2 and overall["fig9_mapped"] == 2
    assert overall["fig9_error_mean_m"] == pytest.approx(0.1)
    assert overall["mapped"] == 3


def test_objects_discovered_count_a_drifted_map_once_its_drift_is_taken_out() -> None:
    """An overhead survey's map sits ~1 m off the world (its odometry's drift): ``mapped`` pairs
    in place, ``discovered`` after one rigid 2-D alignment — a missing car stays missing and a
    spurious landmark stays unpaired."""
    R = np.eye(3)
    cars = {
        f"c{k}": shapes.cuboid_shape(R, [3.0 * k, 2.5 * (k % 3), 0.75], [4.5, 1.8, 1.5]) for k in range(8)
    }
    world = objects_world({k: ("car", s["center"]) for k, s in cars.items()})
    world = dataclasses.replace(world, object_shapes=cars)
    turn = np.radians(3.0)
    Rz = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    drift = np.array([1.3, -0.9, 0.0])
    est = [
        shapes.cuboid_shape(Rz, Rz @ np.asarray(cars[f"c{k}"]["center"]) + drift, [4.4, 1.9, 1.5])
        for k in range(7)
    ]
    est.append(shapes.cuboid_shape(R, [40.0, 40.0, 0.75], [4.5, 1.8, 1.5]))  # spurious, far away
    lms = [
        Landmark(i, "car", np.asarray(shapes.shape_center(s)), np.eye(3), 5, 0, s) for i, s in enumerate(est)
    ]
    car = object_accuracy(lms, world)["car"]
    assert car["mapped"] < 7 and car["discovered"] == 7  # c7 was never mapped
    assert object_accuracy(lms, world)["overall"]["fig9_discovered"] == 7
    # a map in place: discovered is mapped
    in_place = [
        Landmark(i, "car", np.asarray(s["center"]), np.eye(3), 5, 0, s) for i, s in enumerate(cars.values())
    ]
    acc = object_accuracy(in_place[:5], world)["car"]
    assert acc["mapped"] == acc["discovered"] == 5


class _Map:
    """What the top view reads of a mapping backend."""

    def __init__(self, points: np.ndarray):
        self.points = points

    def occupied_points(self) -> np.ndarray:
        return self.points

    def voxel_size(self) -> float:
        return 0.25


def _pose(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def test_top_view_shows_slam_classes_and_floors_sized_to_the_building(tmp_path):
    from types import SimpleNamespace

    from amslam.apps.report import top_view_figure
    from amslam.types import KeyPose, RunSummary

    world = dataclasses.replace(
        objects_world({}), bounds_hi=np.array([14.0, 10.0, 6.0]), floor_heights=(0.0, 3.0)
    )
    # a short flight: a few metres along the first floor, nothing seen upstairs but one wall
    path = [(1.0 + 0.1 * i, 5.0, 1.2) for i in range(40)]
    wall = np.array([[x, 4.0, 1.0] for x in np.arange(0.125, 5, 0.25)] + [[13.0, 9.0, 4.0]])
    summary = RunSummary(
        mission=SimpleNamespace(name="short"),
        run_dir=tmp_path,
        verdict="completed",
        truth=tuple((0.1 * i, _pose(*p)) for i, p in enumerate(path)),
        vio=tuple((0.1 * i, _pose(p[0], p[1] + 0.1, p[2])) for i, p in enumerate(path)),
        keyposes=tuple(
            KeyPose(i, 0.5 * i, _pose(p[0], p[1] - 0.05, p[2]), 0.5 * i) for i, p in enumerate(path[::5])
        ),
        landmarks=(_lm(0, "chair", [2, 6, 0.4]), _lm(1, "table", [4, 6, 0.5]), _lm(2, "table", [3, 3, 3.5])),
        world=world,
        mapping=_Map(wall),
    )
    fig = top_view_figure(summary)
    floor0, floor1 = fig.axes
    slam = [line for line in floor0.get_lines() if line.get_label() == "SLAM"]
    assert len(slam) == 1 and np.isfinite(slam[0].get_xydata()).all(axis=1).sum() == 8  # every key pose
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend == ["occupied voxels", "ground truth", "VIO", "SLAM", "chair ×1", "table ×2"]
    # one colour per class, the same on every floor
    colours = {
        line.get_markerfacecolor() for ax in fig.axes for line in ax.get_lines() if line.get_marker() == "o"
    }
    assert len(colours) == 2
    # both floors show the whole building, though only a corridor of the first was flown
    for ax in (floor0, floor1):
        assert ax.get_xlim()[0] < 0 and ax.get_xlim()[1] > 14
        assert ax.get_ylim()[0] < 0 and ax.get_ylim()[1] > 10
    assert floor0.get_position().bounds[2:] == pytest.approx(floor1.get_position().bounds[2:])
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_the_reports_file_list_names_only_files_the_run_wrote(tmp_path):
    # a run that failed before take-off has no trajectories, landmarks or map: its report.md
    # linked to them all the same
    from amslam.apps.report import files_section

    for name in ("mission.yaml", "metrics.json", "events.jsonl", "vio.tum"):
        (tmp_path / name).write_text("")
    text = "\n".join(files_section(tmp_path))
    for name in ("mission.yaml", "metrics.json", "events.jsonl", "[vio.tum](vio.tum)"):
        assert name in text
    for name in ("tree.jsonl", "ground_truth.tum)", "slam.tum)", "landmarks.json", "map.ply", "map.npz"):
        assert name not in text


def test_a_real_time_runs_late_control_ticks_are_a_row_of_the_report() -> None:
    from amslam.apps.report import _figure_rows

    m = {
        "control_ticks": 788,
        "control_period_ms": 100.0,
        "control_tick_overruns": 79,
        "control_tick_overrun_percent": 10.03,
        "control_tick_interval_ms": {"median": 100.0, "p95": 186.0, "p99": 295.0, "max": 1950.0},
        "host_load": {"start": [8.4, 7.0, 6.0], "end": [9.0, 7.5, 6.2], "cpus": 2},
    }
    (line,) = [r for r in _figure_rows(m) if r.startswith("| control ticks")]
    assert line == (
        "| control ticks late (interval > 1.25 × 100.0 ms) | 79 of 788 (10.03 %); interval median 100.0,"
        " p95 186.0, max 1950.0 ms; host load 8.4 → 9.0 (1-min average) on 2 CPUs |"
    )
    # a simulated run has no such figures
    assert not [r for r in _figure_rows({"control_ticks": 3}) if r.startswith("| control ticks")]
    pipeline = {
        "frames": 50,
        "mapped": 40,
        "skipped_by_mapper": 10,
        "detected": 12,
        "latency_ms": {"frame_to_global_map": {"median": 200.0, "p95": 290.0, "max": 300.0, "n": 3}},
    }
    rows = [r for r in _figure_rows({**m, "pipeline": pipeline}) if r.startswith(("| camera", "| latency"))]
    assert rows == [
        "| camera frames (received / in the global map / skipped by the busy mapper / detected)"
        " | 50 / 40 / 10 / 12 |",
        "| latency frame to global map (ms) | median 200.0, p95 290.0, max 300.0 (3 samples) |",
    ]


def test_trajectory_error_is_over_the_whole_flight_at_the_key_poses(tmp_path):
    from types import SimpleNamespace

    from amslam.apps.report import _trajectory_error
    from amslam.types import KeyPose, RunSummary

    # truth along x at 1 m/s sampled at 10 Hz; VIO drifts 0.1 m per second in y; SLAM's key poses,
    # one per second, are 0.05 m off in z except the last, 0.5 m off (a bad end, a good flight)
    truth = tuple((0.1 * i, _pose(0.1 * i, 0.0, 1.0)) for i in range(101))
    vio = tuple((t, _pose(T[0, 3], 0.1 * t, 1.0)) for t, T in truth)
    keyposes = tuple(
        KeyPose(k, float(k), _pose(float(k), 0.0, 1.05 if k < 10 else 1.5), float(k)) for k in range(11)
    )
    summary = RunSummary(
        mission=SimpleNamespace(name="line"),
        run_dir=tmp_path,
        verdict="completed",
        truth=truth,
        vio=vio,
        keyposes=keyposes,
        slam_optimises=True,
    )
    track = _trajectory_error(summary)["trajectory_error"]
    assert track["at"] == "key poses" and track["samples"] == 11
    vio_err = 0.1 * np.arange(11.0)
    assert track["vio_rms_m"] == pytest.approx(np.sqrt(np.mean(vio_err**2)), abs=1e-4)
    assert track["vio_max_m"] == pytest.approx(1.0, abs=1e-4)
    slam_err = np.array([0.05] * 10 + [0.5])
    assert track["slam_rms_m"] == pytest.approx(np.sqrt(np.mean(slam_err**2)), abs=1e-4)
    assert track["slam_mean_m"] == pytest.approx(slam_err.mean(), abs=1e-4)
    # the odometry baseline keeps no key poses: VIO alone, at its own samples
    odometry = dataclasses.replace(summary, keyposes=(), slam_optimises=False)
    track = _trajectory_error(odometry)["trajectory_error"]
    assert track["at"] == "VIO samples" and track["samples"] == 101 and "slam_rms_m" not in track
    # no true trajectory (a real vehicle): nothing
    assert _trajectory_error(dataclasses.replace(summary, truth=())) == {}
