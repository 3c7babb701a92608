"""PAMS: entropy and information gain, path enumeration, viewpoints in the good region, stopping;
and the prior-visit baseline."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from amslam.errors import PlanningError
from amslam.interfaces import RunContext
from amslam.plugins.pams import planner as pams_planner
from amslam.plugins.pams.planner import (
    PamsPlanner,
    PriorVisitPlanner,
    count_paths,
    entropy,
    fuse,
    information_gain,
    target_order,
)
from amslam.testing.contract import CAMERA
from amslam.types import BoundingBox, Landmark, PlanRequest, TourItemKind


def _request(start=(0.0, 0.0, 2.0), landmarks=()) -> PlanRequest:
    return PlanRequest(
        np.asarray(start, float), 0.0, (), np.zeros((1, 1)), CAMERA, landmarks=tuple(landmarks)
    )


def _prior(tmp_path, objects) -> str:
    data = [
        {
            "id": i,
            "class": c,
            "position": list(p),
            "covariance": np.eye(3).tolist(),
            "observations": 5,
            **({"shape": s} if s else {}),
        }
        for i, (c, p, s) in enumerate(objects)
    ]
    (tmp_path / "landmarks.json").write_text(json.dumps(data))
    return "landmarks.json"


CAR = {"model": "cuboid", "center": [10.0, 0.0, 0.75], "dims": [4.6, 1.9, 1.5], "yaw": 0.0}


def _pams(tmp_path, models_path, events=None, **params) -> PamsPlanner:
    planner = PamsPlanner()
    ctx = RunContext(
        rng=np.random.default_rng(0),
        run_dir=tmp_path,
        mission_dir=tmp_path,
        emit=(lambda name, **f: events.append((name, f))) if events is not None else (lambda *a, **k: None),
    )
    planner.configure(PamsPlanner.Params(models=str(models_path), **params), ctx)
    return planner


# -- entropy and information gain --------------------------------------------------------------


def test_entropy_and_information_gain_by_hand():
    prior = np.diag([0.25, 0.25])
    R1, R2 = np.diag([0.01, 0.04]), np.diag([0.04, 0.01])
    assert entropy(prior) == pytest.approx(0.5 * math.log(0.0625))
    # Σ⁻¹ = diag(4, 4) + diag(100, 25) + diag(25, 100) = diag(129, 129)
    fused = fuse(prior, [R1, R2])
    np.testing.assert_allclose(fused, np.diag([1 / 129, 1 / 129]))
    assert information_gain(prior, [R1, R2]) == pytest.approx(
        0.5 * math.log(0.0625) - 0.5 * math.log(1 / 129**2)
    )
    # one look after the other equals both at once (the recursion of paper 2 §IV-D)
    np.testing.assert_allclose(fuse(fuse(prior, [R1]), [R2]), fused)
    # a correlated prior: ½ ln det by hand
    S = np.array([[0.5, 0.2], [0.2, 0.3]])
    assert entropy(S) == pytest.approx(0.5 * math.log(0.5 * 0.3 - 0.04))
    with pytest.raises(ValueError):
        entropy(np.diag([1.0, -1.0]))


def test_number_of_candidate_paths_is_a_permutation_count(tmp_path, models_path):
    # every order is evaluated (tests/plugins/pams/test_best_path.py: the same choice as each of
    # the P(a, T) orders one by one); here the count a plan reports
    assert count_paths(8, 3) == 336 and count_paths(5, 5) == 120 and count_paths(2, 3) == 0
    events: list = []
    planner = _pams(
        tmp_path,
        models_path,
        events,
        prior_objects=_prior(tmp_path, [("car", CAR["center"], CAR)]),
        sampling="uniform",
        samples=7,
        horizon=3,
        target_std=1e-4,
        max_position_error=0.6,
        max_dimension_error=1.0,
    )
    tour = planner.plan(_request())
    (path,) = [f for name, f in events if name == "pams_path"]
    assert path["free"] == 7 and path["candidates"] == count_paths(7, 3) == 210 and path["chosen"] == 3
    assert len(tour) == 3


# -- viewpoints --------------------------------------------------------------------------------


def test_viewpoints_lie_in_the_predicted_good_region_and_face_the_object(tmp_path, models_path, models):
    planner = _pams(
        tmp_path,
        models_path,
        prior_objects=_prior(tmp_path, [("car", CAR["center"], CAR)]),
        min_confidence=0.8,
        max_position_error=0.2,  # the test's synthetic models reach ~0.085 m, not the paper's 0.051
        max_dimension_error=0.4,
    )
    tour = planner.plan(_request())
    assert tour and all(item.kind == TourItemKind.EXPLORE for item in tour)
    car = models["car"]
    centre = np.array(CAR["center"])
    st = planner.states[0]
    assert len(st.samples) >= 2
    for p in [*st.samples, *(item.position for item in tour)]:
        rng = float(np.linalg.norm(p - centre))
        angle = abs(math.atan2(p[1] - centre[1], p[0] - centre[0]))
        assert car.confidence(rng, angle)[0] >= 0.8
        # errors within their limits with 95 % (error_confidence): stds within limit / 1.96
        assert np.all(np.sqrt(car.variances(rng, angle)[0]) <= np.array([0.2, 0.2, 0.4, 0.4]) / 1.959964)
        assert p[2] == pytest.approx(2.0)  # the robot's height
        # outside the car's footprint plus clearance
        assert np.linalg.norm(p[:2] - centre[:2]) >= 0.5 * math.hypot(4.6, 1.9) + 1.0 - 1e-9
    for item in tour:
        d = centre[:2] - item.position[:2]
        assert abs(math.remainder(item.yaw - math.atan2(d[1], d[0]), 2 * math.pi)) < 1e-9
        assert item.ref == 0
    # synthetic truth: oblique views are best, so centroid sampling finds the four oblique regions
    bearings = sorted(round(math.degrees(math.atan2(p[1], p[0] - 10.0))) % 360 for p in st.samples)
    assert len(bearings) == 4
    for b, expected in zip(bearings, (45, 135, 225, 315), strict=True):
        assert abs(b - expected) <= 20


def test_viewpoints_avoid_other_objects_and_leave_the_area_alone(tmp_path, models_path):
    # a pole right where the best oblique views of the car would be
    objects = [("car", CAR["center"], CAR), ("pole", [13.5, 3.5, 0.0], None)]
    area = BoundingBox(np.array([-5.0, -20.0, 0.0]), np.array([40.0, 3.0, 6.0]))
    planner = PamsPlanner()
    ctx = RunContext(rng=np.random.default_rng(0), run_dir=tmp_path, mission_dir=tmp_path, area=area)
    planner.configure(
        PamsPlanner.Params(
            models=str(models_path),
            prior_objects=_prior(tmp_path, objects),
            sampling="uniform",
            samples=30,
            target_classes=["car"],
            max_position_error=0.6,
            max_dimension_error=1.0,
        ),
        ctx,
    )
    planner.plan(_request())
    st = planner.states[0]
    assert len(st.samples) > 5
    assert np.all(np.linalg.norm(st.samples[:, :2] - [13.5, 3.5], axis=1) > 0.5 + 1.0)
    assert np.all(st.samples[:, 1] <= 2.5)


def test_neighbours_block_viewpoints_unless_low_enough_to_overfly(tmp_path, models_path):
    # a car between two neighbours 2.6 m away (a parking row), and a tall pole off its rear
    left, right = dict(CAR, center=[10.0, 2.6, 0.75]), dict(CAR, center=[10.0, -2.6, 0.75])
    pole = {"model": "cylinder", "root": [4.0, 0.0, 0.0], "radius": 0.1, "height": 6.0}
    objects = [("car", CAR["center"], CAR), ("car", left["center"], left), ("car", right["center"], right)]
    objects.append(("pole", [4.0, 0.0, 3.0], pole))

    def samples(**params) -> np.ndarray:
        planner = _pams(
            tmp_path,
            models_path,
            prior_objects=_prior(tmp_path, objects),
            sampling="uniform",
            samples=120,
            target_classes=["car"],
            max_position_error=0.6,
            max_dimension_error=1.0,
            **params,
        )
        planner.plan(_request(start=(0.0, 0.0, 3.4)))
        return planner.state(0, 3.4).samples

    def clear_of(xy: np.ndarray, centre, radius: float) -> bool:
        return bool(np.all(np.linalg.norm(xy[:, :2] - centre, axis=1) > radius))

    car_r = 0.5 * math.hypot(4.6, 1.9) + 1.0
    blocked = samples()
    assert clear_of(blocked, [10.0, 2.6], car_r) and clear_of(blocked, [10.0, -2.6], car_r)
    assert clear_of(blocked, [4.0, 0.0], 1.1)  # the pole is not a target, but an obstacle
    over = samples(overfly=0.8)  # the cars' tops (1.5 m) are 1.9 m below the 3.4 m viewpoints
    assert not clear_of(over, [10.0, 2.6], car_r) and not clear_of(over, [10.0, -2.6], car_r)
    assert clear_of(over, [4.0, 0.0], 1.1)  # the 6 m pole still blocks
    assert len(over) > len(blocked)
    # too small a gap to overfly: the neighbours block again
    assert clear_of(samples(overfly=2.5), [10.0, 2.6], car_r)


# -- stopping and bookkeeping ------------------------------------------------------------------------


def test_stops_when_entropy_falls_below_the_threshold(tmp_path, models_path):
    events = []
    planner = _pams(
        tmp_path,
        models_path,
        events,
        prior_objects=_prior(tmp_path, [("car", CAR["center"], CAR)]),
        sampling="uniform",
        samples=8,
        horizon=2,
        target_std=0.12,
    )
    here = np.array([0.0, 0.0, 2.0])
    flown = 0
    for _ in range(10):
        tour = planner.plan(_request(here))
        if not tour:
            break
        here = tour[-1].position  # the robot flew the whole path
        flown += len(tour)
    assert tour == []
    st = planner.states[0]
    assert st.done and st.looks == flown
    assert entropy(st.cov) <= planner.threshold(st.model)
    before_last = st.history[-2] if len(st.history) > 1 else entropy(np.eye(4) * 0.5**2)
    assert before_last > planner.threshold(st.model)  # it did not look more than needed
    assert (~st.used).sum() > 0  # samples were left: the entropy, not the samples, ended it
    done = [f for name, f in events if name == "pams_target_done"]
    assert done and done[0]["reason"] == "entropy below threshold"


def test_stops_when_samples_run_out_then_moves_to_the_next_target(tmp_path, models_path):
    car2 = dict(CAR, center=[30.0, 0.0, 0.75])
    planner = _pams(
        tmp_path,
        models_path,
        prior_objects=_prior(tmp_path, [("car", CAR["center"], CAR), ("car", car2["center"], car2)]),
        sampling="centroid",
        horizon=3,
        target_std=1e-6,
    )
    here = np.array([0.0, 0.0, 2.0])
    refs = []
    for _ in range(12):
        tour = planner.plan(_request(here))
        if not tour:
            break
        refs.append(tour[0].ref)
        here = tour[-1].position
    assert refs[0] == 0 and refs[-1] == 1 and sorted(set(refs)) == [0, 1]
    assert all(st.done and st.used.all() for st in planner.states.values())
    # the TSP visited the nearer car first
    assert target_order(np.zeros(3), np.array([[30.0, 0, 0], [10.0, 0, 0]])) == [1, 0]


def test_unreached_viewpoints_return_to_the_pool_then_get_dropped(tmp_path, models_path):
    planner = _pams(
        tmp_path,
        models_path,
        prior_objects=_prior(tmp_path, [("car", CAR["center"], CAR)]),
        sampling="uniform",
        samples=6,
        horizon=2,
        target_std=1e-6,
        max_attempts=2,
    )
    start = _request()
    first = planner.plan(start)
    # the robot did not get anywhere: nothing was taken, the samples are free again; only the
    # stop it was flying to (the first) counts an attempt
    second = planner.plan(start)
    st = planner.states[0]
    assert st.looks == 0 and len(second) == 2
    assert sorted(st.attempts[st.attempts > 0].tolist()) == [1]
    # it reached the first stop of the second path: exactly that one is taken
    planner.plan(_request(second[0].position))
    assert st.looks == 1 and len(st.history) == 1
    # a stop given up max_attempts times is dropped, without information
    before = int(st.used.sum())
    here = _request(second[0].position + np.array([0.0, 3.0, 0.0]))
    tried = planner.plan(here)[0].position
    planner.plan(here)
    again = planner.plan(here)
    assert st.looks == 1 and int(st.used.sum()) > before
    assert first and not any(np.allclose(item.position, tried) for item in again)


def test_settle_takes_the_first_reached_stop_and_blames_only_the_one_flown_to(tmp_path):
    objects = [("car", [10.0 * i, 0.0, 0.75], None) for i in range(1, 8)]
    planner = PriorVisitPlanner()
    planner.configure(
        PriorVisitPlanner.Params(prior_objects=_prior(tmp_path, objects), standoff=3.0, max_attempts=2),
        RunContext(rng=np.random.default_rng(0), run_dir=tmp_path, mission_dir=tmp_path),
    )
    tour = planner.plan(_request())
    assert len(tour) == 7
    # a long tour flown one stop per replan: the far stops, never tried, are never dropped
    for k in range(7):
        tour = planner.plan(_request(tour[0].position))
        assert len(tour) == 6 - k
    assert planner.done == set(range(7))
    # a stop near the robot late in the tour does not count the stops before it as seen
    objects = [("car", [10.0 * i, 0.0, 0.75], None) for i in range(1, 4)]
    planner.configure(
        PriorVisitPlanner.Params(prior_objects=_prior(tmp_path, objects), standoff=3.0),
        RunContext(rng=np.random.default_rng(0), run_dir=tmp_path, mission_dir=tmp_path),
    )
    planner.plan(_request())
    here = np.array([0.0, 5.0, 2.0])
    planner.pending = [
        pams_planner._Pending(0, 0, here.copy()),
        pams_planner._Pending(1, 0, np.array([20.0, 5.0, 2.0])),
        pams_planner._Pending(2, 0, here + [0.5, 0.0, 0.0]),
    ]
    assert [t.ref for t in planner.plan(_request(here))] == [1, 2]
    assert planner.done == {0}


def test_targets_from_slam_landmarks_and_errors(tmp_path, models_path):
    planner = _pams(tmp_path, models_path)
    lm = Landmark(7, "car", np.array(CAR["center"]), np.eye(3) * 0.01, 5, shape=CAR)
    chair = Landmark(8, "sofa", np.array([3.0, 3.0, 0.5]), np.eye(3) * 0.01, 5)  # not modelled
    tour = planner.plan(_request(landmarks=[lm, chair]))
    assert tour and {item.ref for item in tour} == {7}
    assert planner.plan(_request()) == []  # the objects are gone from the map: nothing to do
    with pytest.raises(PlanningError, match="cannot load"):
        PamsPlanner().configure(
            PamsPlanner.Params(models="missing.npz"),
            RunContext(rng=np.random.default_rng(0), run_dir=tmp_path),
        )
    bad = _pams(tmp_path, models_path, prior_objects="nope.json")
    with pytest.raises(PlanningError, match=r"prior_objects: .*nope.json: cannot be read \(No such file"):
        bad.plan(_request())


# -- the baseline ----------------------------------------------------------------------------------


def test_prior_visit_looks_once_at_each_object_in_tsp_order(tmp_path):
    objects = [
        ("car", [20.0, 0.0, 0.75], None),
        ("car", [10.0, 0.0, 0.75], CAR),
        ("pole", [30.0, 5.0, 0.0], None),
    ]
    planner = PriorVisitPlanner()
    planner.configure(
        PriorVisitPlanner.Params(prior_objects=_prior(tmp_path, objects), standoff=3.0),
        RunContext(rng=np.random.default_rng(0), run_dir=tmp_path, mission_dir=tmp_path),
    )
    assert planner.needs_frontiers is False
    tour = planner.plan(_request())
    assert [t.ref for t in tour] == [1, 0, 2]
    # the first stop: 3 m beyond the car's edge, on the robot's side, facing it
    assert np.linalg.norm(tour[0].position[:2] - [10.0, 0.0]) == pytest.approx(
        0.5 * math.hypot(4.6, 1.9) + 3.0
    )
    assert tour[0].position[0] < 10.0 and tour[0].yaw == pytest.approx(0.0)
    # after the first two looks only the third object is left; after it, nothing
    assert [t.ref for t in planner.plan(_request(tour[1].position))] == [2]
    assert planner.plan(_request(tour[2].position)) == []


def test_the_low_uncertainty_region_is_the_papers_95_percent_within_the_error_limits():
    from amslam.plugins.pams.planner import PamsParams, region_std_limits

    limits = region_std_limits(PamsParams(), ["x", "y", "length", "width"])
    np.testing.assert_allclose(
        limits, [0.1 / 1.959964, 0.1 / 1.959964, 0.2 / 1.959964, 0.2 / 1.959964], rtol=1e-6
    )
    # a Gaussian error with that std is within the limit 95 % of the time
    from scipy.stats import norm

    assert norm.cdf(0.1, scale=limits[0]) - norm.cdf(-0.1, scale=limits[0]) == pytest.approx(0.95)
    looser = region_std_limits(PamsParams(error_confidence=0.68), ["x"])
    assert looser[0] > limits[0]


# -- localisation constraint (paper 2 §IV-D) ----------------------------------------------------


def _pose(std: float, translation: float = 0.05):
    from amslam.types import OdometryNoise, PoseUncertainty

    noise = OdometryNoise(translation, 0.01, 0.005, 0.001, 0.01, 0.001, 0.001)
    return PoseUncertainty(np.diag([std**2, (0.5 * std) ** 2, 0.01]), noise)


def test_pose_uncertainty_grows_with_the_distance_flown_and_bounds_the_reach():
    pose = _pose(0.6)
    assert pose.position_std == pytest.approx(0.6)  # the worst direction
    assert pose.reach(math.sqrt(0.36 + 0.0025 * 100)) == pytest.approx(100.0)
    assert pose.reach(1.0) == pytest.approx((1.0 - 0.36) / 0.0025)  # 256 m
    assert math.sqrt(0.36 + 0.0025 * pose.reach(1.0)) == pytest.approx(1.0)
    assert pose.reach(0.5) == 0.0
    with pytest.raises(ValueError, match="expected \\(3, 3\\)"):
        type(pose)(np.eye(2), pose.odometry)


def _flown(start: np.ndarray, tour) -> float:
    stops = [start, *(item.position for item in tour)]
    return float(sum(np.linalg.norm(b - a) for a, b in zip(stops, stops[1:], strict=False)))


def test_paths_keep_the_robot_within_its_localisation_bound(tmp_path, models_path):
    events: list = []

    def planner():
        return _pams(
            tmp_path,
            models_path,
            events,
            prior_objects=_prior(tmp_path, [("car", CAR["center"], CAR)]),
            target_std=1e-4,
            max_position_error=0.6,
            max_dimension_error=1.0,
            sampling="uniform",
            samples=12,
            max_position_std=1.0,
        )

    request = _request()
    free_planner = planner()
    free = free_planner.plan(request)  # no covariance from the backend: no constraint
    nearest = min(np.linalg.norm(p - request.start) for p in free_planner.states[0].samples)
    reach = max(nearest + 0.5, 0.7 * _flown(request.start, free))
    assert reach < _flown(request.start, free)  # the unconstrained path would break the bound
    pose = _pose(math.sqrt(1.0 - 0.0025 * reach))
    assert pose.reach(1.0) == pytest.approx(reach)
    tour = planner().plan(dataclasses.replace(request, pose_uncertainty=pose))
    assert tour and all(item.ref == 0 for item in tour)
    assert _flown(request.start, tour) <= reach + 1e-6
    assert not [e for e, _ in events if e.startswith("pams_relocal") or e == "pams_localisation_unmet"]


def test_a_robot_too_uncertain_relocalises_at_a_known_landmark_first(tmp_path, models_path):
    events: list = []
    planner = _pams(
        tmp_path,
        models_path,
        events,
        prior_objects=_prior(tmp_path, [("car", CAR["center"], CAR)]),
        max_position_error=0.6,
        max_dimension_error=1.0,
        max_position_std=0.5,
        relocalise_range=3.0,
    )
    known = Landmark(7, "pole", np.array([-4.0, 0.0, 1.0]), np.eye(3) * 0.1**2, 9)
    # nearer and below the bound, but known too poorly to bring a sample of the car within reach
    vague = Landmark(8, "pole", np.array([-1.0, 0.0, 1.0]), np.eye(3) * 0.49**2, 2)
    request = dataclasses.replace(_request(landmarks=[known, vague]), pose_uncertainty=_pose(0.8))
    (stop,) = planner.plan(request)
    assert stop.ref == 7 and stop.gain == 0.0
    np.testing.assert_allclose(stop.position, [-1.0, 0.0, 2.0], atol=1e-9)  # 3 m from it, on our side
    assert abs(math.remainder(stop.yaw - math.pi, 2 * math.pi)) < 1e-9  # facing it
    (relocalise,) = [f for e, f in events if e == "pams_relocalise"]
    assert relocalise["landmark"] == 7 and relocalise["position_std"] == 0.8
    # still too uncertain and no other known landmark: the target is planned all the same
    tour = planner.plan(request)
    assert tour and all(item.ref == 0 for item in tour)
    assert [e for e, _ in events].count("pams_localisation_unmet") == 1
