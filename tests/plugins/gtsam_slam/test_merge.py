"""Multi-robot merging: two drifting robots observing overlapping objects from nearby bases."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from amslam.geometry import pose_from
from amslam.measurements import MeasurementLog, read_measurements
from amslam.plugins.gtsam_slam.merge import (
    MergeParams,
    MergeResult,
    chain_from_base,
    merge_measurements,
    merge_runs,
    position_errors,
    write_landmarks,
)
from amslam.plugins.gtsam_slam.shape_landmarks import ShapeParams, SizePrior
from amslam.plugins.gtsam_slam.synthetic import LoopWorld, camera_mount
from amslam.types import Detection, Odometry

WIDTH, HEIGHT = 12.0, 8.0


def loop(start: np.ndarray, clockwise: bool, step: float = 0.2) -> Iterator[np.ndarray]:
    """True poses around the WIDTH×HEIGHT rectangle from ``start``, turning in place at corners."""
    corners = np.array([[0, 0], [WIDTH, 0], [WIDTH, HEIGHT], [0, HEIGHT], [0, 0]], float)
    if clockwise:
        corners = corners[::-1]
    corners[0] = corners[-1] = start[:2]
    z, yaw = start[2], None
    for a, b in zip(corners[:-1], corners[1:], strict=True):
        target = float(np.arctan2(b[1] - a[1], b[0] - a[0]))
        if yaw is not None:
            d = float(np.angle(np.exp(1j * (target - yaw))))
            for k in range(1, int(np.ceil(abs(d) / 0.25)) + 1):
                yield pose_from(np.array([a[0], a[1], z]), yaw + d * k / int(np.ceil(abs(d) / 0.25)))
        yaw = target
        n = int(np.ceil(np.linalg.norm(b - a) / step))
        for i in range(1, n + 1):
            xy = a + (b - a) * i / n
            yield pose_from(np.array([xy[0], xy[1], z]), yaw)


def fly(objects: LoopWorld, base: np.ndarray, clockwise: bool, seed: int, path: Path, bias: float) -> Path:
    """One robot: drifting VIO around the loop from ``base``, detections every metre, logged."""
    rng = np.random.default_rng(seed)
    w = LoopWorld(objects.objects, objects.classes, rng, yaw_bias_per_m=bias)
    first = next(loop(base, clockwise))
    w.T_true = pose_from(base, float(np.arctan2(first[1, 0], first[0, 0])))
    w.T_vio = w.T_true.copy()
    log = MeasurementLog(path, f"robot-{seed}", camera_mount())
    log.keypose(w.odometry(), w.T_true)
    for k, T in enumerate(loop(base, clockwise)):
        w.move_to(T)
        if k % 5 == 4:
            # a blob of surface points around each centroid, for the shape fitter
            dets = [replace(d, points_cam=d.centroid_cam + rng.normal(0, 0.1, (40, 3))) for d in w.detect()]
            log.detections(w.odometry(), dets, w.T_true)
    log.close()
    return path


@pytest.fixture(scope="module")
def two_robots(tmp_path_factory: pytest.TempPathFactory) -> tuple[LoopWorld, Path, Path]:
    tmp = tmp_path_factory.mktemp("merge")
    world = LoopWorld.rectangle(np.random.default_rng(3), width=WIDTH, height=HEIGHT)
    a = fly(world, np.array([0.0, 0.0, 1.2]), False, 11, tmp / "a.jsonl", bias=0.006)
    b = fly(world, np.array([0.6, -0.5, 1.2]), True, 12, tmp / "b.jsonl", bias=-0.006)
    return world, a, b


def truth_of(world: LoopWorld) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    ids = [str(i) for i in range(len(world.objects))]
    return dict(zip(ids, world.objects, strict=True)), dict(zip(ids, world.classes, strict=True))


def test_log_round_trip(two_robots: tuple[LoopWorld, Path, Path]) -> None:
    _, a, _ = two_robots
    log = read_measurements(a)
    assert log.robot == "robot-11"
    assert len(log.stamps) > 30 and log.truth is not None
    # the relative motions chain up to the logged VIO poses
    T = log.T_odom_body[0]
    for rel in log.rel[1:]:
        T = T @ rel
    np.testing.assert_allclose(T, log.T_odom_body[-1], atol=1e-4)
    assert {d.class_name for d in log.detections} <= {"chair", "table", "plant"}
    # VIO drifted: its end is far from the truth
    assert np.linalg.norm(log.T_odom_body[-1][:3, 3] - log.truth[-1][:3, 3]) > 0.3


def test_merged_map_has_one_landmark_per_object_and_lower_error(
    two_robots: tuple[LoopWorld, Path, Path],
) -> None:
    world, a, b = two_robots
    truth, classes = truth_of(world)
    logs = [read_measurements(a), read_measurements(b)]
    # LoopWorld's detections are the objects' centres plus noise, their points a blob about them:
    # no visible-part bias for graph.spread_slack to allow for (it would only blur them)
    unbiased = MergeParams(graph=MergeParams().graph.model_copy(update={"spread_slack": 0.0}))
    alone = [merge_measurements([log], unbiased) for log in logs]
    merged = merge_measurements(logs, unbiased)
    err_alone = [position_errors(r.landmarks, truth, classes)[0] for r in alone]
    err, pairs = position_errors(merged.landmarks, truth, classes)
    # one landmark per object: every landmark matches a distinct object (a duplicate would be left
    # unmatched), and nearly every object is mapped (a couple are never in view of a camera)
    assert len(pairs) == len(merged.landmarks) >= len(world.objects) - 2
    assert len(merged.landmarks) > max(len(position_errors(r.landmarks, truth, classes)[1]) for r in alone)
    assert merged.shared() == len(merged.landmarks)  # both robots contributed to every object
    assert err.mean() < min(e.mean() for e in err_alone)
    # the robots' chains were corrected: the merged trajectories beat dead reckoning
    for r, log in enumerate(logs):
        vio = np.linalg.norm(chain_from_base(log)[:, :3, 3] - log.truth[:, :3, 3], axis=1).mean()
        est = np.linalg.norm(merged.trajectories[r][:, :3, 3] - log.truth[:, :3, 3], axis=1).mean()
        assert est < vio


def test_gate_too_tight_makes_duplicates_that_fusion_removes(
    two_robots: tuple[LoopWorld, Path, Path],
) -> None:
    world, a, b = two_robots
    logs = [read_measurements(a), read_measurements(b)]
    # a tiny association gate: the second robot's drifted detections start new landmarks
    loose = merge_measurements(logs, MergeParams(association={"gate": 0.15}, fuse_gate=0.0))
    fused = merge_measurements(logs, MergeParams(association={"gate": 0.15}, fuse_gate=0.8))
    truth, classes = truth_of(world)
    # duplicates: landmarks left over by the one-to-one matching to the objects
    assert len(loose.landmarks) > len(position_errors(loose.landmarks, truth, classes)[1])
    assert fused.fused > 0
    assert len(fused.landmarks) < len(loose.landmarks)


def test_merge_runs_writes_landmarks_json(two_robots: tuple[LoopWorld, Path, Path], tmp_path: Path) -> None:
    world, a, b = two_robots

    def fit(class_name: str, points: np.ndarray) -> dict:
        return {"model": "blob", "center": points.mean(axis=0), "n": len(points)}

    # object_map "landmarks": the fitter's shapes for every class (with "boxes", centroid classes
    # are reported at their fitted boxes, as onboard)
    result = merge_runs([a, b], MergeParams(object_map="landmarks"), shape_fitter=fit)
    out = write_landmarks(tmp_path / "landmarks.json", result.landmarks)
    import json

    records = json.loads(out.read_text())
    assert len(records) == len(result.landmarks)
    assert {"id", "class", "position", "covariance", "observations"} <= set(records[0])
    cov = np.array(records[0]["covariance"], float)
    assert cov.shape == (3, 3) and np.all(np.linalg.eigvalsh(cov) > 0)
    # the fitter got every detection's logged points (all 40 of each), moved into the world frame
    for rec, lm in zip(records, result.landmarks, strict=True):
        assert rec["shape"]["model"] == "blob" and rec["shape"]["n"] == 40 * lm.observations
        assert np.linalg.norm(np.array(rec["shape"]["center"]) - lm.position) < 0.1


def test_merged_objects_are_reported_as_onboard(two_robots: tuple[LoopWorld, Path, Path]) -> None:
    """``object_map: boxes`` (the default, onboard's rule): each centroid-class object at the box
    fitted to all its detections' points, every robot's; ``landmarks``: the graph's points."""
    world, a, b = two_robots
    boxes = merge_runs([a, b])
    points = merge_runs([a, b], MergeParams(object_map="landmarks"))
    assert all(lm.shape is None for lm in points.landmarks)
    assert all(lm.shape["model"] == "cuboid" for lm in boxes.landmarks)
    for lm in boxes.landmarks:
        np.testing.assert_allclose(lm.position, lm.shape["center"])
    assert len(boxes.landmarks) <= len(points.landmarks)
    assert set(boxes.contributors) == {lm.id for lm in boxes.landmarks}
    assert boxes.shared() > 0  # both robots' detections went into the shared objects' boxes
    truth, classes = truth_of(world)
    err_boxes, _ = position_errors(boxes.landmarks, truth, classes)
    err_points, _ = position_errors(points.landmarks, truth, classes)
    assert np.mean(err_boxes) < np.mean(err_points) + 0.05


def test_known_base_places_the_chain(two_robots: tuple[LoopWorld, Path, Path]) -> None:
    _, a, _ = two_robots
    shift = np.eye(4)
    shift[:3, 3] = [100.0, -50.0, 0.0]
    result = merge_runs([a], bases=[shift], params=MergeParams())
    start = result.trajectories[0][0][:3, 3]
    np.testing.assert_allclose(start, [100.0, -50.0, 1.2], atol=0.05)


# -- shape classes: cars seen from opposite sides --------------------------------------------------

CAR = np.array([1.8, 4.5, 1.5])  # x (width), y (length), z (height): nose-in stalls along x


def car_points(lo: np.ndarray, viewer: np.ndarray, rng: np.random.Generator, n: int = 60) -> np.ndarray:
    """Surface points of the box faces at ``lo`` (size CAR) that face the viewer."""
    hi = lo + CAR
    out = []
    for axis in range(3):
        for side, plane in ((-1, lo[axis]), (1, hi[axis])):
            if (viewer[axis] - plane) * side <= 0 or (axis == 2 and side < 0):
                continue  # the face is turned away (or is the bottom)
            p = rng.uniform(lo, hi, (n, 3))
            p[:, axis] = plane
            out.append(p)
    return np.vstack(out)


def fly_past_cars(
    cars: np.ndarray,
    y: float,
    direction: int,
    seed: int,
    path: Path,
    seen_length: float = CAR[1],
    seen_from: float = 0.0,
    depth_noise: float = 0.0,
) -> Path:
    """A robot flying along x at height 3.5 m, ``y`` m off the row, detecting cars within 6 m
    (only the part of each car from ``seen_from`` to ``seen_length`` m of its y = lo end: the rest
    hidden), its camera's depth σ ``depth_noise``·z² (logged in the header)."""
    rng = np.random.default_rng(seed)
    log = MeasurementLog(path, f"robot-{seed}", camera_mount(), depth_noise=depth_noise)
    xs = np.arange(-6.0, cars[:, 0].max() + 8.0, 0.25)[::direction]
    for k, x in enumerate(xs):
        T = pose_from(np.array([x, y, 3.5]), 0.0 if direction > 0 else np.pi)
        odom = Odometry(float(k) * 0.25, T)
        log.keypose(odom, T)
        if k % 2:
            continue
        T_wc = T @ camera_mount()
        dets = []
        for lo in cars:
            if np.linalg.norm(lo + CAR / 2 - T[:3, 3]) > 6.0:
                continue
            pw = car_points(lo, T[:3, 3], rng)
            pw = pw[(pw[:, 1] <= lo[1] + seen_length) & (pw[:, 1] >= lo[1] + seen_from)]
            pc = (pw - T_wc[:3, 3]) @ T_wc[:3, :3]
            # along each ray, σ = k·z²: the point moves by (p / z) per metre of depth
            pc = pc + depth_noise * pc[:, 2:3] * pc * rng.normal(0.0, 1.0, (len(pc), 1))
            dets.append(Detection("car", 0.9, np.median(pc, axis=0), rng.permutation(pc)))
        log.detections(odom, dets, T)
    log.close()
    return path


def test_shape_classes_merge_by_shape_one_landmark_per_car(tmp_path: Path) -> None:
    # four cars side by side, 2.6 m stalls (0.8 m gaps), as in the simulated lot; robot a flies
    # past their fronts, robot b past their backs: the visible-surface centroids of one car seen
    # from the two sides are ~2 m apart, far beyond the centroid gate
    cars = np.array([[2.6 * i, 0.0, 0.0] for i in range(4)])
    truth = {str(i): lo + CAR / 2 for i, lo in enumerate(cars)}
    classes = dict.fromkeys(truth, "car")
    a = fly_past_cars(cars, -3.0, 1, 1, tmp_path / "a.jsonl")
    b = fly_past_cars(cars, CAR[1] + 3.0, -1, 2, tmp_path / "b.jsonl")
    logs = [read_measurements(a), read_measurements(b)]
    by_centroid = merge_measurements(logs, MergeParams(object_map="landmarks"))
    by_shape = merge_measurements(logs, MergeParams(landmark_models={"car": "cuboid"}))
    assert len(by_centroid.landmarks) >= 2 * len(cars)  # each side its own landmark in the graph
    # (the reported map folds the two sides' boxes into one car, as onboard: boxes after the fact)
    reported = merge_measurements(logs)
    assert len(reported.landmarks) == len(cars)
    assert len(by_shape.landmarks) == len(cars)  # one per car, neighbours not fused
    assert by_shape.shared() == len(cars)  # both robots' sides in each
    err, pairs = position_errors(by_shape.landmarks, truth, classes, gate=0.5)
    assert len(pairs) == len(cars) and err.max() < 0.3  # the position is the fitted box centre
    for lm in by_shape.landmarks:
        assert lm.shape is not None and lm.shape["model"] == "cuboid"
        np.testing.assert_allclose(sorted(lm.shape["dims"][:2]), sorted(CAR[:2]), atol=0.35)


def cuboid_centres(result: MergeResult) -> list[np.ndarray]:
    """The optimised centres of the merged graph's cuboid pose variables (eq. 1's ``o_j``)."""
    import gtsam

    keys = [k for k in result.values.keys() if chr(gtsam.Symbol(k).chr()) == "o"]  # noqa: SIM118
    return [np.asarray(result.values.atPose3(k).translation()) for k in keys]


def shape_factor_counts(result: MergeResult) -> tuple[int, int, int]:
    """Of the merged graph's factors on the cars' variables: eq. 1 factors (on a pose ``o`` and
    dims ``d``), range-bearing factors (to a box centre, any point landmark ``L(j)`` included) and
    landmark ties (a centre tie of two boxes, a Point3 between-factor of two points)."""
    import gtsam

    eq1 = range_bearing = ties = 0
    for i in range(result.graph.size()):
        f = result.graph.at(i)
        chars = [chr(gtsam.Symbol(k).chr()) for k in f.keys()]  # noqa: SIM118
        eq1 += {"o", "d"} <= set(chars)
        range_bearing += type(f).__name__.startswith("BearingRange")
        ties += chars.count("o") == 2 or (type(f).__name__ == "BetweenFactorPoint3" and chars.count("l") == 2)
    return eq1, range_bearing, ties


def point_landmarks(result: MergeResult) -> int:
    """How many point landmark variables ``L(j)`` the merged graph has."""
    import gtsam

    return sum(chr(gtsam.Symbol(k).chr()) == "l" for k in result.values.keys())  # noqa: SIM118


def test_one_car_seen_from_two_sides_is_one_cuboid_better_than_either_robots(tmp_path: Path) -> None:
    # robot a sees the first 3.2 m of the car from its y = lo side, robot b the last 3.2 m from its
    # y = hi side: each alone measures a box 3.2 m long, its centre 0.65 m towards its viewer; the
    # merged graph holds both robots' eq. 1 factors on one pose + dims variable, which sits between
    car = np.array([[0.0, 0.0, 0.0]])
    truth = car[0] + CAR / 2
    a = read_measurements(fly_past_cars(car, -3.0, 1, 1, tmp_path / "a.jsonl", seen_length=3.2))
    b = read_measurements(fly_past_cars(car, CAR[1] + 3.0, -1, 2, tmp_path / "b.jsonl", seen_from=1.3))
    params = MergeParams(landmark_models={"car": "cuboid"})
    alone = [merge_measurements([log], params) for log in (a, b)]
    merged = merge_measurements([a, b], params)
    errors_alone = []
    for result in alone:
        (centre,) = cuboid_centres(result)
        errors_alone.append(np.linalg.norm(centre - truth))
    (centre,) = cuboid_centres(merged)  # one cuboid variable for the car
    assert len(merged.landmarks) == 1 and merged.shared() == 1
    assert min(errors_alone) > 0.5
    assert np.linalg.norm(centre - truth) < 0.6 * min(errors_alone)


def test_adjacent_cars_half_a_metre_apart_stay_two(tmp_path: Path) -> None:
    cars = np.array([[0.0, 0.0, 0.0], [CAR[0] + 0.5, 0.0, 0.0]])
    truth = {str(i): lo + CAR / 2 for i, lo in enumerate(cars)}
    a = read_measurements(fly_past_cars(cars, -3.0, 1, 3, tmp_path / "a.jsonl"))
    b = read_measurements(fly_past_cars(cars, CAR[1] + 3.0, -1, 4, tmp_path / "b.jsonl"))
    merged = merge_measurements([a, b], MergeParams(landmark_models={"car": "cuboid"}))
    assert len(merged.landmarks) == 2 and len(cuboid_centres(merged)) == 2
    err, pairs = position_errors(merged.landmarks, truth, dict.fromkeys(truth, "car"), gate=0.5)
    assert len(pairs) == 2 and err.max() < 0.3


def test_the_merged_graph_has_one_shape_factor_per_measurement(tmp_path: Path) -> None:
    # robot b's first view of the car starts a landmark of its own, found a twin of robot a's and
    # fused into it before it entered the graph: its measurement is on the survivor's variables
    # too, and no tie joins two variables of one car. Each detection is measured once: its eq. 1
    # factor alone, no range-bearing factor to a point landmark of the same fit (issue #21)
    car = np.array([[0.0, 0.0, 0.0]])
    a = read_measurements(fly_past_cars(car, -3.0, 1, 1, tmp_path / "a.jsonl", seen_length=3.2))
    b = read_measurements(fly_past_cars(car, CAR[1] + 3.0, -1, 2, tmp_path / "b.jsonl", seen_from=1.3))
    detections = sum(1 for log in (a, b) for d in log.detections if d.class_name == "car")
    merged = merge_measurements([a, b], MergeParams(landmark_models={"car": "cuboid"}))
    eq1, range_bearing, ties = shape_factor_counts(merged)
    observations = sum(lm.observations for lm in merged.landmarks)
    assert observations == detections  # every detection is a shape measurement here
    assert eq1 == observations and range_bearing == ties == 0
    assert len(cuboid_centres(merged)) == len(merged.landmarks) == 1 and point_landmarks(merged) == 0


def test_slam_odometry_replaces_the_vio_chain(
    two_robots: tuple[LoopWorld, Path, Path], tmp_path: Path
) -> None:
    from amslam.geometry import tum_line
    from amslam.plugins.gtsam_slam.merge import with_slam_odometry

    _, a, _ = two_robots
    log = read_measurements(a)
    # the run folder's trajectories: VIO at every key pose, the onboard SLAM estimate at every
    # other one (here: the truth, as a perfect SLAM would have it)
    (tmp_path / "vio.tum").write_text(
        "".join(tum_line(t, T) + "\n" for t, T in zip(log.stamps, log.T_odom_body, strict=True))
    )
    (tmp_path / "slam.tum").write_text(
        "".join(tum_line(t, T) + "\n" for t, T in list(zip(log.stamps, log.truth, strict=True))[::2])
    )
    vio_err = np.linalg.norm(log.T_odom_body[:, :3, 3] - log.truth[:, :3, 3], axis=1)
    fixed = with_slam_odometry(read_measurements(a), tmp_path)
    err = np.linalg.norm(fixed.T_odom_body[:, :3, 3] - log.truth[:, :3, 3], axis=1)
    assert vio_err.max() > 0.5 and err.max() < 0.05  # between SLAM poses: one step of VIO
    np.testing.assert_allclose(fixed.T_odom_body[::2], log.truth[::2], atol=1e-5)
    chained = fixed.T_odom_body[0].copy()
    for rel in fixed.rel[1:]:
        chained = chained @ rel
    np.testing.assert_allclose(chained, fixed.T_odom_body[-1], atol=1e-6)


def test_the_merge_is_the_onboard_graph_with_its_noise_and_shape_factors(tmp_path: Path) -> None:
    import gtsam

    from amslam.plugins.gtsam_slam.graph import NoiseModels
    from amslam.plugins.gtsam_slam.merge import ROBOT_CHARS

    cars = np.array([[2.6 * i, 0.0, 0.0] for i in range(2)])
    logs = [read_measurements(fly_past_cars(cars, -3.0, 1, 1, tmp_path / "a.jsonl"))]
    params = MergeParams(landmark_models={"car": "cuboid"})
    result = merge_measurements(logs, params)
    factors = [result.graph.at(i) for i in range(result.graph.size())]
    # eq. 1: every car landmark has its pose and dimension variables, tied to the robot's key poses
    chars = [[chr(gtsam.Symbol(k).chr()) for k in f.keys()] for f in factors]  # noqa: SIM118 — a KeyVector
    eq1 = [c for c in chars if "o" in c and "d" in c]
    keys = [k for f in factors for k in f.keys()]  # noqa: SIM118 — a KeyVector
    cars_in_graph = {gtsam.Symbol(k).index() for k in keys if chr(gtsam.Symbol(k).chr()) == "o"}
    assert len(cars_in_graph) == len(result.landmarks) == len(cars)
    assert eq1 and all(ROBOT_CHARS[0] in c for c in eq1)
    # the odometry noise is the onboard model's: std ∝ √distance (a 4× longer step, 2× the std)
    noise = NoiseModels(params.graph)
    short, long = (noise.odometry(s, 0.0).sigmas()[3] for s in (1.0, 4.0))
    assert long == pytest.approx(2 * short)
    between = [f for f in factors if type(f).__name__ == "BetweenFactorPose3"]
    step = float(np.linalg.norm(logs[0].rel[1][:3, 3]))
    np.testing.assert_allclose(between[0].noiseModel().sigmas(), noise.odometry(step, 0.0).sigmas())


def test_a_car_seen_at_one_end_only_is_completed_behind_it(tmp_path: Path) -> None:
    # one robot sees the first 1.5 m of each car's 4.5 m (the rest hidden behind the row in front):
    # a box fitted to those points is 1.5 m long, its centre 1.5 m short of the car's; completed
    # behind its visible faces with the class's size prior (as onboard windows are), it is the car
    # (cars 8 m apart: two neighbours' ends 1.8 + 0.8 + 1.8 m wide together fit one car lying
    # across, and the fusion, which cannot tell, joins them)
    cars = np.array([[8.0 * i, 0.0, 0.0] for i in range(3)])
    truth = {str(i): lo + CAR / 2 for i, lo in enumerate(cars)}
    log = read_measurements(fly_past_cars(cars, -3.0, 1, 3, tmp_path / "a.jsonl", seen_length=1.5))
    prior = {"car": SizePrior(dims=(CAR[1], CAR[0], CAR[2]))}

    def merged(complete: bool) -> np.ndarray:
        shapes = ShapeParams(
            min_points=20, percentile=1.0, extrapolate=True, size_prior=prior, complete=complete
        )
        res = merge_measurements([log], MergeParams(landmark_models={"car": "cuboid"}, shapes=shapes))
        err, pairs = position_errors(res.landmarks, truth, dict.fromkeys(truth, "car"), gate=2.5)
        assert len(pairs) == len(cars)
        return err

    assert merged(complete=False).min() > 1.0
    assert merged(complete=True).max() < 0.35


def test_frames_logged_at_one_key_pose_are_associated_frame_by_frame(tmp_path: Path) -> None:
    # A hovering robot: its pose does not change between camera frames, so the log writes no new
    # key pose and several frames' detections share one. Replayed as one frame, the views of an
    # object competed for its landmark (one-to-one association): here every view became a
    # tentative landmark of its own and none reached the graph (0 landmarks); on seed 2's
    # overhead robot, stalled at a waypoint with 109 frames sharing key poses, such duplicates
    # reached the graph and stayed apart as "seen from one key pose" (13 spurious, 6 now).
    world = LoopWorld.rectangle(np.random.default_rng(3), width=WIDTH, height=HEIGHT)
    w = LoopWorld(world.objects, world.classes, np.random.default_rng(5))
    w.T_true = w.T_vio = pose_from(np.array([WIDTH / 2, -1.0, 1.2]), np.pi / 2)
    log = MeasurementLog(tmp_path / "hover.jsonl", "hover", camera_mount())
    for k in range(6):  # six key poses 5 mm apart ...
        w.move_to(pose_from(np.array([WIDTH / 2 + 0.005 * k, -1.0, 1.2]), np.pi / 2))
        for _ in range(3):  # ... three camera frames at each, the pose unchanged
            log.detections(w.odometry(), w.detect(), w.T_true)
            w.move_to(w.T_true)
    log.close()
    hover = read_measurements(tmp_path / "hover.jsonl")
    assert len(hover.stamps) == 6 and len({d.stamp for d in hover.detections}) == 18
    in_view = len(w.detect())
    assert in_view >= 2

    merged = merge_measurements([hover])

    truth, classes = truth_of(world)
    _, pairs = position_errors(merged.landmarks, truth, classes)
    assert len(merged.landmarks) == len(pairs) == in_view  # one landmark per object in view


def test_overlapping_shape_landmarks_fuse_within_the_chi2_gate_of_their_factors_noise(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # robot b's known base is 2.5 m off along the car's length: its box of the car lies beyond
    # half a car from robot a's, so the replay keeps two landmarks. Taken as overlapping, they are
    # fused or not on the χ² of their centres under the joint marginal covariance, i.e. on the
    # eq. 1 factors' noise: the onboard noise (a window fit's translation std 0.3 m, times the
    # views' and the window's scales: a centre σ of about 1 m here) accepts 2.5 m; a 0.05 m std
    # does not
    from amslam.plugins.gtsam_slam import merge

    car = np.array([[0.0, 0.0, 0.0]])
    logs = []
    for k, (y, direction) in enumerate(((-3.0, 1), (CAR[1] + 3.0, -1))):
        log = read_measurements(fly_past_cars(car, y, direction, k + 1, tmp_path / f"{k}.jsonl"))
        log.T_world_odom = pose_from(np.array([0.0, 2.5 * k, 0.0]), 0.0)
        logs.append(log)
    monkeypatch.setattr(merge._Merger, "overlap", lambda *_: True)

    def merged(sigma_translation: float) -> MergeResult:
        shapes = MergeParams().shapes.model_copy(update={"sigma_translation": sigma_translation})
        return merge_measurements(logs, MergeParams(landmark_models={"car": "cuboid"}, shapes=shapes))

    onboard, stiff = merged(0.3), merged(0.05)
    assert len(onboard.landmarks) == 1 and onboard.fused == 1
    assert len(stiff.landmarks) == 2 and stiff.fused == 0
    eq1, range_bearing, ties = shape_factor_counts(onboard)
    assert eq1 == sum(lm.observations for lm in onboard.landmarks) and range_bearing == ties == 0


def test_shapes_reported_not_optimised_are_measured_once_by_range_bearing_factors(tmp_path: Path) -> None:
    # shapes.factors off, as onboard: each detection is one range-bearing factor on its box's
    # centre (the pose variable's translation), the box's rotation and dims held by priors at
    # their fit; no eq. 1 factor, no point landmark, and the map still has its boxes
    cars = np.array([[2.6 * i, 0.0, 0.0] for i in range(2)])
    logs = [read_measurements(fly_past_cars(cars, -3.0, 1, 1, tmp_path / "a.jsonl"))]
    shapes = MergeParams().shapes.model_copy(update={"factors": False})
    merged = merge_measurements(logs, MergeParams(landmark_models={"car": "cuboid"}, shapes=shapes))
    eq1, range_bearing, ties = shape_factor_counts(merged)
    assert eq1 == ties == point_landmarks(merged) == 0
    assert range_bearing == sum(lm.observations for lm in merged.landmarks) > 0
    assert len(cuboid_centres(merged)) == len(merged.landmarks) == 2
    assert all(lm.shape["model"] == "cuboid" for lm in merged.landmarks)


def test_cars_are_fitted_past_the_depth_noise_their_robots_logged(tmp_path: Path) -> None:
    # a noisy stereo camera (σ = 0.04·z², 0.1 m at the points' median depth) on both robots: the
    # 1st percentiles of every car's points are the noise's tails, a box too long, unless the
    # merge fits past the noise each log's header gives
    cars = np.array([[2.6 * i, 0.0, 0.0] for i in range(3)])
    a = fly_past_cars(cars, -3.0, 1, 1, tmp_path / "a.jsonl", depth_noise=0.04)
    b = fly_past_cars(cars, CAR[1] + 3.0, -1, 2, tmp_path / "b.jsonl", depth_noise=0.04)
    logs = [read_measurements(a), read_measurements(b)]
    assert [log.depth_noise for log in logs] == [0.04, 0.04]
    unlogged = [dataclasses.replace(log, depth_noise=0.0) for log in logs]
    params = MergeParams(landmark_models={"car": "cuboid"})

    def dims_errors(result: MergeResult) -> np.ndarray:  # per car: length, width, height
        assert len(result.landmarks) == len(cars)
        return np.array(
            [np.r_[np.sort(lm.shape["dims"][:2])[::-1], lm.shape["dims"][2]] for lm in result.landmarks]
        ) - [CAR[1], CAR[0], CAR[2]]

    assert dims_errors(merge_measurements(unlogged, params))[:, 0].min() > 0.25
    assert np.abs(dims_errors(merge_measurements(logs, params))).max() < 0.15
