"""GtsamSlam with shape landmarks: overlap association, windowed fits, eq. 1/2 factors, outputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.interfaces import RunContext
from amslam.lib import shapes as S  # noqa: N812
from amslam.plugins.gtsam_slam.backend import GtsamSlam
from amslam.types import CameraModel, Detection, Odometry

from .test_shapes import box_points, cylinder_points, rz

CAR_C, CAR_YAW, CAR_DIMS = np.array([6.0, 2.0, 0.75]), 0.5, np.array([4.5, 1.8, 1.5])
POLE_ROOT, POLE_R, POLE_H = np.array([3.0, -3.0, 0.0]), 0.12, 5.0


def _pose(p: np.ndarray, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rz(yaw)
    T[:3, 3] = p
    return T


def _fly(slam: GtsamSlam, rng: np.random.Generator, noise: float = 0.02) -> None:
    """Circle the car and the pole at 3.5 m, exact odometry, detections every step."""
    T_body_cam = CameraModel.forward_mount(35.0)
    for k in range(40):
        a = 2 * np.pi * k / 40
        p = np.array([6.0 + 7.0 * np.cos(a), 2.0 + 7.0 * np.sin(a), 3.5])
        T_wb = _pose(p, a + np.pi)  # facing the car
        odom = Odometry(float(k), T_wb)
        slam.add_odometry(odom)
        T_cw = np.linalg.inv(T_wb @ T_body_cam)
        cam_pos = (T_wb @ T_body_cam)[:3, 3]
        dets = []
        car = box_points(rz(CAR_YAW), CAR_C, CAR_DIMS, cam_pos, rng, n=400, noise=noise)
        pole = cylinder_points(POLE_ROOT, POLE_R, POLE_H, cam_pos, rng, n=200, noise=noise)
        ground = np.column_stack(
            [rng.uniform(-4, 14, 400), rng.uniform(-8, 10, 400), rng.normal(0, 0.01, 400)]
        )
        for cls, pts in (("car", car), ("pole", pole), ("ground", ground)):
            pc = pts @ T_cw[:3, :3].T + T_cw[:3, 3]
            dets.append(Detection(cls, 0.9, np.median(pc, axis=0), pc))
        slam.add_detections(odom, T_body_cam, dets)


def _circled(landmark_models: dict[str, str]) -> GtsamSlam:
    """A backend that circled the car and the pole (:func:`_fly`) with these landmark models."""
    slam = GtsamSlam()
    params = GtsamSlam.Params(landmark_models=landmark_models, association={"max_range": 12.0})
    slam.configure(params, RunContext(rng=np.random.default_rng(1), run_dir=Path(".")))
    _fly(slam, np.random.default_rng(2))
    return slam


@pytest.fixture(scope="module")
def mapped() -> GtsamSlam:
    return _circled({"car": "cuboid", "pole": "cylinder", "ground": "plane"})


def test_one_landmark_per_object_with_its_shape(mapped: GtsamSlam) -> None:
    lms = mapped.landmarks()
    assert sorted(lm.class_name for lm in lms) == ["car", "pole"]  # the ground makes no landmark
    car = next(lm for lm in lms if lm.class_name == "car")
    pole = next(lm for lm in lms if lm.class_name == "pole")
    assert car.shape is not None and car.shape["model"] == "cuboid"
    assert pole.shape is not None and pole.shape["model"] == "cylinder"
    err = S.shape_errors(car.shape, S.cuboid_shape(rz(CAR_YAW), CAR_C, CAR_DIMS))
    assert err["dims"] < 0.1 and err["position"] < 0.1 and err["yaw"] < np.radians(2.0)
    # the point landmark is the shape's reference point
    assert np.linalg.norm(car.position - CAR_C) < 0.15
    perr = S.shape_errors(pole.shape, S.cylinder_shape(POLE_ROOT, [0, 0, 1], POLE_R, POLE_H))
    assert perr["position"] < 0.08 and perr["dims"] < 0.05


def test_shape_factors_are_in_the_graph(mapped: GtsamSlam) -> None:
    import gtsam

    graph, _ = mapped.graph()
    custom = [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), gtsam.CustomFactor)]
    # one factor per measurement of each object (most of the 40 frames yield one of each)
    assert len(custom) > 50


def test_information_gain_over_shape_variables_equals_brute_force(mapped: GtsamSlam) -> None:
    """Eq. 10 over a graph with a box (Pose3 + Point3 dims) and a cylinder (Unit3 axis, 1-vector
    radius): every variable's tangent size, not only the key poses' (the planner asked this of
    a graph with cuboid landmarks and failed on the box pose)."""
    from amslam.plugins.gtsam_slam.information import brute_force_information_gain

    graph, values = mapped.graph()
    ids = [k.id for k in mapped.keyposes()][:30:10]
    dists = [20.0, 10.0, 5.0][: len(ids)]
    fast = mapped.information_gain(ids, dists)
    over = [int(k) for k in values.keys()]  # noqa: SIM118 — gtsam's KeyVector
    brute = [
        brute_force_information_gain(graph, values, mapped.virtual_factor(i, d), over)
        for i, d in zip(ids, dists, strict=True)
    ]
    np.testing.assert_allclose(fast, brute, rtol=1e-6)


def _last_frame(slam: GtsamSlam, classes: tuple[str, ...]) -> int:
    """How many factors one more detection frame of ``classes`` adds, seen from the last pose of
    :func:`_fly` (no new key pose: the robot has not moved)."""
    rng = np.random.default_rng(5)
    T_body_cam = CameraModel.forward_mount(35.0)
    a = 2 * np.pi * 39 / 40
    T_wb = _pose(np.array([6.0 + 7.0 * np.cos(a), 2.0 + 7.0 * np.sin(a), 3.5]), a + np.pi)
    T_cw = np.linalg.inv(T_wb @ T_body_cam)
    cam_pos = (T_wb @ T_body_cam)[:3, 3]
    points = {
        "car": box_points(rz(CAR_YAW), CAR_C, CAR_DIMS, cam_pos, rng, n=400, noise=0.02),
        "pole": cylinder_points(POLE_ROOT, POLE_R, POLE_H, cam_pos, rng, n=200, noise=0.02),
    }
    dets = []
    for cls in classes:
        pc = points[cls] @ T_cw[:3, :3].T + T_cw[:3, 3]
        dets.append(Detection(cls, 0.9, np.median(pc, axis=0), pc))
    before = slam.graph()[0].size()
    keyposes = slam.num_keyposes
    slam.add_detections(Odometry(39.5, T_wb), T_body_cam, dets)
    assert slam.num_keyposes == keyposes  # no odometry factor in the count
    return slam.graph()[0].size() - before


@pytest.mark.parametrize("factors", [True, False])
def test_a_shape_detection_is_measured_once(factors: bool) -> None:
    """Paper 2 §IV-B: a shape detection is one factor, its eq. 1 / eq. 2 factor (with ``factors``
    off, one range-bearing factor on the shape's reference variable), never also a point landmark
    measured from the same fit; the graph has no point-landmark variables for shape classes."""
    import gtsam

    slam = GtsamSlam()
    params = GtsamSlam.Params(
        landmark_models={"car": "cuboid", "pole": "cylinder", "ground": "plane"},
        association={"max_range": 12.0},
        shapes={"factors": factors},
    )
    slam.configure(params, RunContext(rng=np.random.default_rng(1), run_dir=Path(".")))
    _fly(slam, np.random.default_rng(2))
    assert _last_frame(slam, ("car",)) == 1
    assert _last_frame(slam, ("pole",)) == 1
    assert _last_frame(slam, ("car", "pole")) == 2
    graph, values = slam.graph()
    assert not any(gtsam.Symbol(k).chr() == ord("l") for k in values.keys())  # noqa: SIM118
    ranged = [graph.at(i) for i in range(graph.size()) if "BearingRange" in type(graph.at(i)).__name__]
    assert bool(ranged) == (not factors)
    # the reported position and covariance are the shape's reference point's
    car = next(lm for lm in slam.landmarks() if lm.class_name == "car")
    assert np.linalg.norm(car.position - CAR_C) < 0.3
    assert np.all(np.isfinite(car.covariance)) and np.all(np.linalg.eigvalsh(car.covariance) > 0)


def test_centroid_is_the_default_model() -> None:
    slam = GtsamSlam()
    slam.configure(GtsamSlam.Params(), RunContext(rng=np.random.default_rng(1), run_dir=Path(".")))
    _fly(slam, np.random.default_rng(2))
    assert all(lm.shape is None for lm in slam.landmarks())


def test_unknown_model_is_rejected() -> None:
    with pytest.raises(ValueError):
        GtsamSlam.Params(landmark_models={"car": "sphere"})


def test_star_gives_every_class_not_named_its_model() -> None:
    """``"*"`` covers the classes a mission does not list (a mesh world has dozens)."""
    slam = _circled({"*": "cuboid", "pole": "cylinder", "ground": "plane"})
    by_class = {lm.class_name: lm for lm in slam.landmarks()}
    assert sorted(by_class) == ["car", "pole"]  # the named plane still makes no landmark
    assert by_class["car"].shape is not None and by_class["car"].shape["model"] == "cuboid"
    assert by_class["pole"].shape is not None and by_class["pole"].shape["model"] == "cylinder"


def test_star_cannot_be_the_ground() -> None:
    slam = GtsamSlam()
    params = GtsamSlam.Params(landmark_models={"*": "plane"})
    with pytest.raises(ValueError, match="every other class"):
        slam.configure(params, RunContext(rng=np.random.default_rng(1), run_dir=Path(".")))


def _detect(slam: GtsamSlam, odom: Odometry, T_body_cam: np.ndarray, points: dict[str, np.ndarray]) -> None:
    """One detection per class of its world-frame ``points``, seen from ``odom``'s pose."""
    T_cw = np.linalg.inv(odom.T_odom_body @ T_body_cam)
    dets = []
    for cls, pts in points.items():
        pc = pts @ T_cw[:3, :3].T + T_cw[:3, 3]
        dets.append(Detection(cls, 0.9, np.median(pc, axis=0), pc))
    slam.add_detections(odom, T_body_cam, dets)


def _two_end_passes(params: GtsamSlam.Params, ends: tuple[float, ...] = (1.0, -1.0)) -> GtsamSlam:
    """A car seen at its front end, then, after its points left the window, at its rear end.

    Each pass is a sideways flight 4 m beyond one end, 3.5 m up, looking at the car; only the
    near 2 m of the car are in view (the rest cut by the image). Exact odometry.
    """
    slam = GtsamSlam()
    slam.configure(params, RunContext(rng=np.random.default_rng(1), run_dir=Path(".")))
    rng = np.random.default_rng(3)
    T_body_cam = CameraModel.forward_mount(35.0)
    R = rz(CAR_YAW)
    t = 0.0
    for end in ends:
        for k in range(12):
            lateral = -1.5 + 3.0 * k / 11
            p = CAR_C + R @ np.array([end * 6.3, lateral, 2.75])
            T_wb = _pose(p, CAR_YAW + (np.pi if end > 0 else 0.0))  # facing the car
            odom = Odometry(t, T_wb)
            slam.add_odometry(odom)
            cam = (T_wb @ T_body_cam)[:3, 3]
            car = box_points(R, CAR_C, CAR_DIMS, cam, rng, n=600)
            car = car[end * ((car - CAR_C) @ R[:, 0]) >= 0.25]
            ground = np.column_stack(
                [rng.uniform(0, 12, 400), rng.uniform(-4, 8, 400), rng.normal(0, 0.01, 400)]
            )
            _detect(slam, odom, T_body_cam, {"car": car, "ground": ground})
            t += 1.0
        t += 30.0  # the first pass's points leave the window
    return slam


def test_a_car_seen_at_both_ends_is_one_landmark_placed_on_the_car() -> None:
    models = {"car": "cuboid", "ground": "plane"}
    prior = {"car": {"dims": [4.6, 1.85, 1.5]}}
    shape = {"window": 5.0, "size_prior": prior}
    done = _two_end_passes(
        GtsamSlam.Params(landmark_models=models, association={"max_range": 12.0}, shapes=shape)
    )
    cars = [lm for lm in done.landmarks() if lm.class_name == "car"]
    assert len(cars) == 1
    assert np.linalg.norm(cars[0].position[:2] - CAR_C[:2]) < 0.25
    # without the completion each end is a landmark of its own, ~1.2 m off the car's centre
    shape["complete"] = False
    raw = _two_end_passes(
        GtsamSlam.Params(landmark_models=models, association={"max_range": 12.0}, shapes=shape)
    )
    cars = [lm for lm in raw.landmarks() if lm.class_name == "car"]
    assert len(cars) == 2
    assert all(np.linalg.norm(lm.position[:2] - CAR_C[:2]) > 0.8 for lm in cars)


def test_twins_are_boxes_holding_each_others_centre_not_neighbours() -> None:
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    sh = ShapeLandmarks({"car": "cuboid"}, ShapeParams(), np.random.default_rng(0))
    R = rz(0.3)
    boxes = {
        0: S.cuboid_shape(R, R @ [0.5, 0, 0] + [0, 0, 0.75], [4.4, 1.8, 1.5]),  # front-heavy view
        1: S.cuboid_shape(R, R @ [-0.6, 0.1, 0] + [0, 0, 0.75], [4.6, 1.8, 1.5]),  # rear-heavy view
        2: S.cuboid_shape(R, R @ [0.0, 2.5, 0] + [0, 0, 0.75], [4.6, 1.8, 1.5]),  # the next stall
        3: S.cuboid_shape(R, R @ [1.8, 0, 0] + [0, 0, 0.75], [1.2, 1.8, 1.5]),  # the front 1.2 m only
    }
    for i, b in boxes.items():
        sh.measure(i, "car", 0.0, np.zeros((1, 3)), np.eye(4))  # creates the record (too few points)
        sh.set_world(i, b)
    live = dict.fromkeys(boxes, "car")
    assert sh.twins(0, live) == [1]
    assert sh.twins(2, live) == []
    assert 3 not in sh.twins(0, live)  # its centre is in the big box, not the other way round


def test_all_twins_finds_one_chair_mapped_twice_but_not_its_neighbours_in_a_row() -> None:
    """After the estimates moved (a loop closure), every pair is checked, not only the measured."""
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    sh = ShapeLandmarks({"chair": "cuboid"}, ShapeParams(), np.random.default_rng(0))
    chair = [0.55, 0.5, 0.9]
    boxes = {  # a row of chairs 0.75 m apart; 3 is chair 1 mapped again 0.2 m off; 4 another class
        0: S.cuboid_shape(rz(0.0), [0.0, 0.0, 0.45], chair),
        1: S.cuboid_shape(rz(0.0), [0.75, 0.0, 0.45], chair),
        2: S.cuboid_shape(rz(0.0), [1.5, 0.0, 0.45], chair),
        3: S.cuboid_shape(rz(0.1), [0.9, 0.12, 0.45], chair),
        4: S.cuboid_shape(rz(0.0), [0.75, 0.0, 0.45], chair),
    }
    for i, b in boxes.items():
        sh.measure(i, "chair", 0.0, np.zeros((1, 3)), np.eye(4))  # creates the record (too few points)
        sh.set_world(i, b)
    live = {0: "chair", 1: "chair", 2: "chair", 3: "chair", 4: "table"}
    assert sh.all_twins(live) == [(1, 3)]
    assert sh.all_twins({0: "chair", 2: "chair"}) == []


def test_a_chair_whose_near_half_overlaps_its_neighbour_is_not_the_neighbour() -> None:
    """Chairs in a row, 0.75 m apart: the smeared points of one reach into the other's margin."""
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    rng = np.random.default_rng(3)
    sh = ShapeLandmarks({"chair": "cuboid"}, ShapeParams(association_margin=0.2), rng)
    a_points = rng.uniform([-0.45, -0.25, 0.0], [0.45, 0.25, 0.9], (400, 3))  # chair A, smeared
    sh.measure(0, "chair", 0.0, a_points, np.eye(4))
    sh.set_world(0, S.cuboid_shape(rz(0.0), [0.0, 0.0, 0.45], [0.9, 0.5, 0.9]))
    near = rng.uniform([0.45, -0.25, 0.0], [0.6, 0.25, 0.9], (45, 3))  # chair B: its near side ...
    far = rng.uniform([0.85, -0.25, 0.0], [1.05, 0.25, 0.9], (55, 3))  # ... and the rest of it
    b_points = np.vstack([near, far])
    assert sh.associate("chair", b_points, b_points, {0: "chair"}, 1.0) == -1
    a_again = rng.uniform([-0.3, -0.2, 0.0], [0.3, 0.2, 0.9], (100, 3))
    assert sh.associate("chair", a_again, a_again, {0: "chair"}, 1.0) == 0


def test_a_stale_window_fit_that_left_its_estimate_does_not_take_the_next_car() -> None:
    # A window that saw one end of car 0 was completed the wrong way, 3.7 m into the next stall
    # (lot_team seed 1: car_1 took van_2's detections): once its window is empty, a detection
    # of the car parked there must start its own landmark, not join car 0.
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    sh = ShapeLandmarks({"car": "cuboid"}, ShapeParams(), np.random.default_rng(0))
    estimate = S.cuboid_shape(np.eye(3), [0.0, 0.0, 0.75], [4.4, 1.8, 1.5])
    stray = S.cuboid_shape(np.eye(3), [3.7, 0.0, 0.75], [4.4, 1.8, 1.5])  # over the next stall
    sh.measure(0, "car", 0.0, np.zeros((1, 3)), np.eye(4))
    sh.set_world(0, stray)
    sh.recs[0].est_world = estimate
    viewer = np.array([2.5, -6.0, 3.0])
    neighbour = box_points(
        np.eye(3), [5.0, 0.0, 0.75], [4.4, 1.8, 1.5], viewer, np.random.default_rng(1), n=200
    )
    later = 100.0  # the window is long empty
    assert sh.associate("car", neighbour, neighbour, {0: "car"}, later) == -1
    own = box_points(np.eye(3), [0.0, 0.0, 0.75], [4.4, 1.8, 1.5], viewer, np.random.default_rng(2), n=200)
    assert sh.associate("car", own, own, {0: "car"}, later) == 0  # the car itself still joins


def test_view_noise_grows_with_range_and_towards_head_on_views() -> None:
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    models = {"car": "cuboid", "pole": "cylinder", "tree_trunk": "cylinder"}
    sh = ShapeLandmarks(models, ShapeParams(), None)
    car = S.cuboid_shape(np.eye(3), [0.0, 0.0, 0.75], [4.4, 1.8, 1.5])  # length along x
    pole = {
        "model": "cylinder",
        "root": [0.0, 0.0, 0.0],
        "axis": [0.0, 0.0, 1.0],
        "radius": 0.1,
        "height": 5.0,
    }

    def at(r: float, angle_deg: float) -> np.ndarray:
        a = np.radians(angle_deg)
        return np.array([[r * np.cos(a), r * np.sin(a), 2.5]])

    oblique, head_on = sh.view_scale("car", car, at(5.0, 45.0)), sh.view_scale("car", car, at(5.0, 0.0))
    assert 1.0 <= oblique < 2.0 and head_on > 3 * oblique  # paper 2 Fig. 7a: oblique views are best
    # a window holding one oblique view among head-on ones is nearly as good as the oblique one
    assert sh.view_scale("car", car, np.vstack([at(5.0, 0.0), at(5.0, 0.0), at(5.0, 45.0)])) < head_on / 1.5
    near, far = sh.view_scale("pole", pole, at(3.0, 0.0)), sh.view_scale("pole", pole, at(8.0, 0.0))
    assert near < 1.5 and far > 2 * near
    # a trunk (not characterised) is measured with the one cylinder class's model
    assert sh.view_scale("tree_trunk", pole, at(8.0, 0.0)) == pytest.approx(far)
    off = ShapeLandmarks(models, ShapeParams(view_noise=False), None)
    assert off.view_scale("car", car, at(5.0, 0.0)) == 1.0


def test_model_sigmas_measure_a_characterised_class_with_its_best_look() -> None:
    """With ``model_sigmas`` a chair's box is measured with the packaged chair model's best-look std
    (paper 2: Σ = f^g), not the 0.3 m default; a class without a model keeps the configured sigmas."""
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    models = {"*": "cuboid"}
    plain = ShapeLandmarks(models, ShapeParams(), None)
    assert plain.base_sigmas("chair", "cuboid") == (0.3, 0.3)
    own = ShapeLandmarks(models, ShapeParams(model_sigmas=True), None)
    translation, dims = own.base_sigmas("chair", "cuboid")
    assert 0.005 < translation < 0.1 and 0.005 < dims < 0.2  # a chair is measured to centimetres
    assert own.base_sigmas("table", "cuboid") != (translation, dims)  # each class its own
    # several cuboid classes are characterised: a bed has no model of its own nor a stand-in
    assert own.base_sigmas("bed", "cuboid") == (0.3, 0.3)
    sigmas = own.noise("cuboid", scale=2.0, base=(translation, dims)).sigmas()
    np.testing.assert_allclose(sigmas[3:6], 2.0 * translation)
    np.testing.assert_allclose(sigmas[6:9], 2.0 * dims)
    # a window of far views of a chair is noisier than one of near views (the chair model's range trend)
    chair = S.cuboid_shape(np.eye(3), [0.0, 0.0, 0.45], [0.5, 0.46, 0.9])
    near = own.view_scale("chair", chair, np.array([[1.5, 1.5, 1.4]]))
    far = own.view_scale("chair", chair, np.array([[4.0, 3.5, 1.4]]))
    assert far > near >= 1.0


def test_the_ground_buffer_keeps_one_point_per_voxel_across_frames() -> None:
    from amslam.plugins.gtsam_slam.shape_landmarks import GroundBuffer

    rng = np.random.default_rng(3)
    buffer = GroundBuffer(voxel=0.1, window=10.0)
    patch = lambda n: np.column_stack([rng.uniform(0, 2, (n, 2)), np.zeros(n)])  # noqa: E731
    for t in range(20):  # the same 2 x 2 m patch in 20 frames: 400 voxels, not 20 copies of them
        buffer.add(float(t), patch(3000))
    assert len(buffer) == 400
    assert np.all(buffer.stamps >= 15.0)  # each voxel's newest point (all seen in the last frames)
    # a voxel not seen again within the window is forgotten; one seen again stays
    buffer.add(30.0, np.array([[0.05, 0.05, 0.0]]))
    assert len(buffer) == 1 and buffer.stamps[0] == 30.0
    # far off (or hostile) coordinates do not overflow the packed voxel index
    buffer.add(31.0, np.array([[1e9, -1e9, 5.0], [1e9, -1e9, 5.0]]))
    assert len(buffer) == 2


def _circled_in_parts(extent: bool) -> GtsamSlam:
    """The car circled as in :func:`_fly`, one detection per measurement (a short window), where
    three views in four see only the car's near 2 m (the rest cut by the image) and every fourth
    sees it whole. No size prior (one car): nothing completes the partial views. The fit's
    percentiles are extrapolated to the edges (noise-free sensor): a whole view measures the car."""
    slam = GtsamSlam()
    params = GtsamSlam.Params(
        landmark_models={"car": "cuboid", "ground": "plane"},
        association={"max_range": 12.0},
        shapes={"window": 0.5, "extent": extent, "extrapolate": True},
    )
    slam.configure(params, RunContext(rng=np.random.default_rng(1), run_dir=Path(".")))
    rng = np.random.default_rng(4)
    T_body_cam = CameraModel.forward_mount(35.0)
    R = rz(CAR_YAW)
    for k in range(48):
        a = 2 * np.pi * k / 48
        p = np.array([6.0 + 7.0 * np.cos(a), 2.0 + 7.0 * np.sin(a), 3.5])
        T_wb = _pose(p, a + np.pi)
        odom = Odometry(float(k), T_wb)
        slam.add_odometry(odom)
        cam = (T_wb @ T_body_cam)[:3, 3]
        car = box_points(R, CAR_C, CAR_DIMS, cam, rng, n=600)
        if k % 4:
            along = (car - CAR_C) @ R[:, 0]
            near = np.sign((cam - CAR_C) @ R[:, 0])
            car = car[near * along >= CAR_DIMS[0] / 2 - 2.0]
        ground = np.column_stack(
            [rng.uniform(-4, 14, 400), rng.uniform(-8, 10, 400), rng.normal(0, 0.01, 400)]
        )
        _detect(slam, odom, T_body_cam, {"car": car, "ground": ground})
    return slam


def _length_width(slam: GtsamSlam) -> np.ndarray:
    (car,) = [lm for lm in slam.landmarks() if lm.class_name == "car"]
    return np.sort(np.asarray(car.shape["dims"][:2]))[::-1]


def test_a_car_seen_mostly_in_parts_is_mapped_at_the_extent_its_whole_views_reach() -> None:
    import gtsam

    slam = _circled_in_parts(extent=True)
    np.testing.assert_allclose(_length_width(slam), CAR_DIMS[:2], atol=0.15)
    # one dims measurement per landmark, replaced as the views came in; iSAM2 agrees with a
    # batch solve of the history that holds it
    graph, values = slam.graph()
    dims_priors = [
        graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), gtsam.PriorFactorPoint3)
    ]
    assert len(dims_priors) == 1
    batch = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    key = dims_priors[0].keys()[0]
    np.testing.assert_allclose(batch.atPoint3(key), values.atPoint3(key), atol=0.01)
    # eq. 1's own dims residual averages the partial views: the car comes out short
    averaged = _length_width(_circled_in_parts(extent=False))
    assert averaged[0] < CAR_DIMS[0] - 0.25


def test_a_car_seen_at_one_end_only_has_the_class_prior_s_length() -> None:
    # no view saw the far end: every measurement completed the length with the size prior, so the
    # extent along it is the prior's, not the 2 m in view
    shape = {"window": 5.0, "size_prior": {"car": {"dims": [4.6, 1.85, 1.5]}}}
    params = GtsamSlam.Params(
        landmark_models={"car": "cuboid", "ground": "plane"}, association={"max_range": 12.0}, shapes=shape
    )
    (car,) = [lm for lm in _two_end_passes(params, ends=(1.0,)).landmarks() if lm.class_name == "car"]
    assert max(car.shape["dims"][:2]) == pytest.approx(4.6, abs=0.15)


def test_seat_faces_puts_a_car_seen_from_one_corner_where_it_is_not_toward_the_camera() -> None:
    """``shapes.seat_faces``: the window's fit with the seen faces seated (depth noise along the rays)."""
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    from .test_shapes import _ray_noise

    centre, dims = np.array([0.0, 0.0, 0.775]), np.array([4.5, 1.85, 1.55])
    camera = np.array([-6.0, -4.0, 3.5])  # beyond the rear and the right side
    los = -camera[:2] / np.linalg.norm(camera[:2])
    toward = {}
    for seat in (False, True):
        rng = np.random.default_rng(5)
        sh = ShapeLandmarks({"car": "cuboid"}, ShapeParams(seat_faces=seat, complete=False), rng)
        faces = box_points(np.eye(3), centre, dims, camera, rng, n=5000, noise=0.0)
        pts = _ray_noise(faces, camera, 0.005, rng)
        s = sh.measure(0, "car", 0.0, pts, np.eye(4), camera_odom=camera)
        toward[seat] = -float((np.asarray(s["center"])[:2] - centre[:2]) @ los)
    assert toward[False] > 0.08  # (0.08-0.13 m over seeds 5-9)
    assert abs(toward[True]) < 0.05  # (0.00-0.03 m)


def test_a_car_seen_again_takes_its_own_view_not_the_next_car_s_down_the_row() -> None:
    """``shapes.return_gate``: a returning view's box must hold the landmark's centre or lie in it."""
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    rng = np.random.default_rng(2)
    sh = ShapeLandmarks({"car": "cuboid"}, ShapeParams(), rng)
    car_a = S.cuboid_shape(rz(np.pi / 2), [0.0, 0.0, 0.775], [4.5, 1.85, 1.55])  # length along y
    camera = np.array([0.0, 9.0, 3.5])
    own = box_points(rz(np.pi / 2), np.array([0.0, 0.0, 0.775]), np.array([4.5, 1.85, 1.55]), camera, rng)
    assert sh.measure(0, "car", 0.0, own, np.eye(4), camera_odom=camera) is not None
    sh.set_world(0, car_a)
    assert not sh.returning(0, 5.0)  # its window still holds its points
    assert sh.returning(0, 100.0)
    # seen again 1 m off (drift): one object
    assert sh.agrees(0, S.cuboid_shape(rz(np.pi / 2), [0.6, 0.8, 0.775], [4.5, 1.85, 1.55]))
    # the next car down the row, 5.1 m on and placed 1 m back by the drift: its near end lies
    # against car A's box, its box centred 4.1 m away, holding neither centre
    car_b = S.cuboid_shape(rz(np.pi / 2), [0.0, 4.1, 0.775], [4.5, 1.85, 1.55])
    assert not sh.agrees(0, car_b)
    sh.forget_latest(0)
    assert sh.recs[0].points == [] and sh.recs[0].fits == []


def test_a_returning_view_of_the_next_car_goes_to_a_new_landmark_with_the_gate_only() -> None:
    """``ShapeLandmarks.measure_view``: the gate's wiring (``return_gate``)."""
    from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams

    R, dims = rz(np.pi / 2), np.array([4.5, 1.85, 1.55])
    drift = np.eye(4)
    drift[1, 3] = -1.0  # world ← odometry: the key poses placed 1 m back along the row
    for gate, expected in ((False, 0), (True, 7)):
        rng = np.random.default_rng(2)
        sh = ShapeLandmarks({"car": "cuboid"}, ShapeParams(return_gate=gate), rng)
        camera = np.array([0.0, 9.0, 3.5])
        own = box_points(R, np.array([0.0, 0.0, 0.775]), dims, camera, rng)
        sh.measure(0, "car", 0.0, own, np.eye(4), camera_odom=camera)
        sh.set_world(0, S.cuboid_shape(R, [0.0, 0.0, 0.775], dims))
        camera = np.array([0.0, 12.0, 3.5])  # 100 s later, the next car down the row, 5.1 m on
        next_car = box_points(R, np.array([0.0, 5.1, 0.775]), dims, camera, rng)
        lm, shape = sh.measure_view(
            0, True, lambda: 7, drift, "car", 100.0, next_car, np.eye(4), camera, drift
        )  # fmt: skip
        assert lm == expected and shape is not None
    assert sh.recs[0].points == []  # the first car's landmark kept nothing of the view
