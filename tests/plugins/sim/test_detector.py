"""The mask-based sim detector."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.interfaces import RunContext
from amslam.plugins.sim.camera import viewing_pose
from amslam.plugins.sim.detector import SimDetector
from amslam.types import Frame

from .conftest import make_platform


def _detector(tmp_path, seed=0, **params) -> SimDetector:
    det = SimDetector()
    det.configure(SimDetector.Params(**params), RunContext(rng=np.random.default_rng(seed), run_dir=tmp_path))
    return det


def _frame_facing_chair(tmp_path, room_with_chair):
    plat = make_platform(tmp_path, spec=room_with_chair)
    plat.arm_and_takeoff(1.2)
    plat.advance(4.0)
    plat.capture()  # discard the frame from the ground
    plat.advance(0.1)
    return plat, plat.capture()


def test_detects_a_chair_in_view_close_to_truth(tmp_path, room_with_chair):
    plat, frame = _frame_facing_chair(tmp_path, room_with_chair)
    det = _detector(tmp_path, miss_probability=0.0, false_positive_rate=0.0, centroid_noise=0.0)
    assert det.rate_hz == 2.0
    dets = det.detect(frame)
    assert [d.class_name for d in dets] == ["chair"]
    d = dets[0]
    truth_world = plat.world_summary().object_positions["chair_1"]
    T_cw = np.linalg.inv(frame.T_world_cam_truth)
    truth_cam = T_cw[:3, :3] @ truth_world + T_cw[:3, 3]
    # the median of the visible surface sits on the near face: biased by at most half the depth
    assert np.linalg.norm(d.centroid_cam - truth_cam) < 0.3
    assert abs(d.centroid_cam[0] - truth_cam[0]) < 0.05 and abs(d.centroid_cam[1] - truth_cam[1]) < 0.1
    assert d.centroid_cam[2] < truth_cam[2]  # seen from the front
    assert d.points_cam.shape[1] == 3 and 0 < len(d.points_cam) <= 400
    assert 0.5 < d.confidence <= 1.0


def test_class_filter_range_and_misses(tmp_path, room_with_chair):
    _, frame = _frame_facing_chair(tmp_path, room_with_chair)
    assert _detector(tmp_path, classes=["table"], false_positive_rate=0.0).detect(frame) == []
    assert _detector(tmp_path, max_range=2.0, false_positive_rate=0.0).detect(frame) == []  # chair ~2.75 m
    det = _detector(tmp_path, miss_probability=0.5, false_positive_rate=0.0)
    hits = sum(len(det.detect(frame)) for _ in range(200))
    assert 70 < hits < 130


def test_false_positives_are_seeded(tmp_path, room_with_chair):
    _, frame = _frame_facing_chair(tmp_path, room_with_chair)
    runs = []
    for _ in range(2):
        det = _detector(tmp_path, seed=5, false_positive_rate=1.0, miss_probability=0.0)
        runs.append([det.detect(frame) for _ in range(20)])
    n = [len(x) - 1 for x in runs[0]]
    assert 10 < sum(n) < 35  # Poisson(1) per frame
    flat = [d for frame_dets in runs[0] for d in frame_dets]
    assert all(d.centroid_cam[2] > 0 for d in flat)
    for a, b in zip(runs[0], runs[1], strict=True):
        assert [d.class_name for d in a] == [d.class_name for d in b]
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x.centroid_cam, y.centroid_cam)


def test_detections_in_a_procedural_building_land_on_their_objects(tmp_path):
    """Across a spin in a furnished room, every true detection lifts to near its object."""
    plat = make_platform(tmp_path, seed=7, camera={"width": 320, "height": 240})
    w = plat.world
    det = _detector(tmp_path, miss_probability=0.0, false_positive_rate=0.0, centroid_noise=0.0)
    # hover 2.5 m from the most crowded object and look at it
    obj = max(w.objects, key=lambda o: sum(np.linalg.norm(o.centroid - p.centroid) < 3 for p in w.objects))
    T_wc = viewing_pose(w, obj.centroid, plat.camera.T_body_cam)
    rendered = plat._renderer.render(w, T_wc, np.random.default_rng(0))
    frame = Frame(
        0.0,
        rendered.depth,
        plat.camera.K,
        T_wc,
        rendered.rgb,
        rendered.instance,
        rendered.class_id,
        w.class_names,
        T_wc,
    )
    dets = det.detect(frame)
    assert len(dets) >= 2
    truth = {o.name: o for o in w.objects}
    for d in dets:
        p_world = T_wc[:3, :3] @ d.centroid_cam + T_wc[:3, 3]
        near = [o for o in truth.values() if o.class_name == d.class_name]
        # the median surface point lies on (or within a few cm of) one object's bounding box
        gap = min(np.linalg.norm(np.maximum(np.maximum(o.lo - p_world, p_world - o.hi), 0)) for o in near)
        assert gap < 0.1, (d.class_name, p_world)


# -- perception model: confidence and noise against range and viewing angle ------------------


def _car_world():
    from amslam.plugins.sim.world import box_room

    car = ("car_1", "car", np.array([13.75, 14.1, 0.0]), np.array([18.25, 15.9, 1.5]))
    return box_room((32.0, 30.0, 6.0), [car], start_xy=(3.0, 3.0))


def _look_at(target: np.ndarray, bearing: float, distance: float, height: float, T_body_cam) -> np.ndarray:
    """``T_world_cam`` of a level body ``distance`` from ``target`` in direction ``bearing``, facing it."""
    pos = np.array([target[0] + distance * np.cos(bearing), target[1] + distance * np.sin(bearing), height])
    yaw = bearing + np.pi
    T = np.eye(4)
    T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = pos
    return T @ T_body_cam


def _car_frames(tmp_path, views):
    cam = {"width": 160, "height": 120, "max_range": 20.0, "depth_noise": 0.0, "dropout": 0.0}
    plat = make_platform(tmp_path, spec=_car_world(), camera=cam)
    w = plat.world
    centre = w.objects[0].centroid
    frames = []
    for bearing, dist in views:
        T_wc = _look_at(centre, bearing, dist, 1.5, plat.camera.T_body_cam)
        r = plat._renderer.render(w, T_wc, np.random.default_rng(0))
        frames.append(
            Frame(0.0, r.depth, plat.camera.K, T_wc, r.rgb, r.instance, r.class_id, w.class_names, T_wc)
        )
    return plat, frames


def _world_detector(tmp_path, plat, seed=0, **params) -> SimDetector:
    det = SimDetector()
    ctx = RunContext(rng=np.random.default_rng(seed), run_dir=tmp_path, world=plat.world_summary())
    det.configure(SimDetector.Params(max_range=20.0, false_positive_rate=0.0, **params), ctx)
    return det


def test_confidence_falls_with_range_and_end_on_views(tmp_path):
    # side (bearing π/2), front (bearing 0: the car's +x), back (π); near and far
    views = [(np.pi / 2, 5.0), (0.0, 5.0), (np.pi, 5.0), (np.pi / 2, 13.0)]
    plat, frames = _car_frames(tmp_path, views)
    det = _world_detector(
        tmp_path, plat, miss_probability=0.0, miss_floor=0.0, miss_ceiling=0.0, confidence_noise=0.0
    )
    conf = []
    for f in frames:
        d = det.detect(f)
        assert [x.class_name for x in d] == ["car"]
        conf.append(d[0].confidence)
    side, front, back, far = conf
    assert front < back < side  # paper 2 Fig. 6: side best, back better than front
    assert far < side
    m = det.model("car")
    assert side == pytest.approx(det.expected_confidence("car", 4.1, np.pi / 2), abs=0.05)
    assert front == pytest.approx(side * (1 - m.front_penalty), abs=0.05)


def test_misses_follow_low_confidence(tmp_path):
    SimDetector.Params()  # defaults validate
    det = _detector(tmp_path)
    assert det.detection_probability(0.9) == pytest.approx(0.95)
    assert det.detection_probability(0.2) == 0.0
    assert 0.0 < det.detection_probability(0.45) < det.detection_probability(0.5) < 0.95
    # a far car (weak confidence) is missed more often than a near one
    plat, frames = _car_frames(tmp_path, [(np.pi / 2, 5.0), (0.0, 13.0)])
    det = _world_detector(tmp_path, plat, seed=3)
    near = sum(len(det.detect(frames[0])) for _ in range(100))
    far = sum(len(det.detect(frames[1])) for _ in range(100))
    assert near > 85 and 0 < far < near - 20


def test_localisation_noise_grows_with_range(tmp_path):
    plat, frames = _car_frames(tmp_path, [(np.pi / 2, 4.0), (np.pi / 2, 13.0)])
    det = _world_detector(tmp_path, plat, seed=1, miss_probability=0.0, miss_floor=0.0, miss_ceiling=0.0)
    spread = []
    for f in frames:
        c = np.array([det.detect(f)[0].centroid_cam for _ in range(150)])
        spread.append(float(c.std(axis=0).mean()))
    r_near, r_far = 4.0 - 0.9, 13.0 - 0.9
    assert spread[0] == pytest.approx(det.localisation_sigma("car", r_near), rel=0.25)
    assert spread[1] == pytest.approx(det.localisation_sigma("car", r_far), rel=0.25)
    assert spread[1] > 2 * spread[0]
    # the points move with their centroid: a shape fit sees the same localisation error
    d = det.detect(frames[1])[0]
    assert np.linalg.norm(np.median(d.points_cam, axis=0) - d.centroid_cam) < 0.3


def test_viewing_angle_and_object_yaw():
    from amslam.lib.viewing import object_yaw, viewing_angle

    assert viewing_angle(np.zeros(3), 0.0, np.array([5.0, 0.0, 1.0])) == pytest.approx(0.0)
    assert viewing_angle(np.zeros(3), 0.0, np.array([0.0, -5.0, 1.0])) == pytest.approx(np.pi / 2)
    assert viewing_angle(np.zeros(3), np.pi / 2, np.array([0.0, -5.0, 1.0])) == pytest.approx(np.pi)
    assert object_yaw({"yaw": 0.3}) == pytest.approx(0.3)
    assert object_yaw({"rotvec": [0.0, 0.0, 0.4]}) == pytest.approx(0.4)
    c, s = np.cos(-1.0), np.sin(-1.0)
    assert object_yaw({"rotation": [[c, -s, 0], [s, c, 0], [0, 0, 1]]}) == pytest.approx(-1.0)
    assert object_yaw(None) == 0.0
