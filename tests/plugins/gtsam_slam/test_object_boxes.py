"""The reported object map: each object at the box fitted to all its points (issue #23)."""

from __future__ import annotations

from types import SimpleNamespace

import gtsam
import numpy as np
import pytest

from amslam.geometry import invert, pose_from
from amslam.plugins.gtsam_slam.object_boxes import fitted_boxes
from amslam.plugins.gtsam_slam.synthetic import camera_mount

CHAIR = np.array([0.5, 0.5, 0.9])


def face(lo: np.ndarray, y: float, rng: np.random.Generator, n: int = 80) -> np.ndarray:
    """Points on the face of the box at ``lo`` (size CHAIR) at height-wise plane ``y``."""
    pts = lo + rng.uniform(0, 1, (n, 3)) * CHAIR
    pts[:, 1] = y + rng.normal(0.0, 0.01, n)  # a depth camera's noise
    return pts


def view(key: int, body: np.ndarray, **more) -> SimpleNamespace:  # noqa: ANN003
    """One detection of a landmark from key pose ``key``: its body-frame points, and its centroid
    at their median (the ``sim`` detector's)."""
    return SimpleNamespace(pose_key=key, points=body, p_body=np.median(body, axis=0), **more)


def report(landmarks: list, observations: dict[int, list]) -> list:
    """The landmarks with their observations, as the graph holds them."""
    return [SimpleNamespace(**vars(lm), observations=observations.get(lm.id, [])) for lm in landmarks]


def test_chairs_all_seen_from_the_front_stay_as_deep_as_they_look() -> None:
    rng = np.random.default_rng(3)
    chairs = [np.array([2.0 * i, 0.0, 0.0]) for i in range(4)]
    values = gtsam.Values()
    landmarks, observations = [], {}
    key = 0
    for j, lo in enumerate(chairs):
        obs = []
        for dx in (-1.0, 0.0, 1.0):  # three views from the front, one metre apart
            T = pose_from(lo + np.array([0.25 + dx, -2.5, 1.2]), np.pi / 2)
            values.insert(key, gtsam.Pose3(T))
            body = (invert(T) @ np.c_[face(lo, lo[1], rng), np.ones(80)].T).T[:, :3]
            obs.append(view(key, body))
            key += 1
        landmarks.append(SimpleNamespace(id=j, class_name="chair"))
        observations[j] = obs
    landmarks.append(SimpleNamespace(id=9, class_name="chair"))  # a landmark without points
    boxes = fitted_boxes(report(landmarks, observations), values, camera_mount(), twin_margin=0.2).boxes
    assert set(boxes) == {0, 1, 2, 3}
    for j, lo in enumerate(chairs):
        centre = lo + CHAIR / 2
        box = boxes[j]
        # across the view and in height the box is the chair's; its depth is what the front face
        # shows, and with every chair of the class seen from the front alone there is no whole
        # one to complete it from: a class's boxes complete each other's partial views
        assert np.linalg.norm(np.asarray(box["center"])[[0, 2]] - centre[[0, 2]]) < 0.05
        assert abs(box["center"][1] - lo[1]) < 0.05


def test_a_class_seen_whole_completes_its_partial_views() -> None:
    rng = np.random.default_rng(4)
    values = gtsam.Values()
    landmarks, observations = [], {}
    key = 0
    for j in range(4):
        lo = np.array([2.0 * j, 0.0, 0.0])
        obs = []
        # three chairs seen from the front and the back (whole), the fourth from the front only
        sides = ((-2.5, np.pi / 2), (3.0, -np.pi / 2)) if j < 3 else ((-2.5, np.pi / 2),)
        for y, yaw in sides:
            T = pose_from(lo + np.array([0.25, y, 1.2]), yaw)
            values.insert(key, gtsam.Pose3(T))
            pts = face(lo, lo[1] if y < 0 else lo[1] + CHAIR[1], rng)
            body = (invert(T) @ np.c_[pts, np.ones(len(pts))].T).T[:, :3]
            obs.append(view(key, body))
            key += 1
        landmarks.append(SimpleNamespace(id=j, class_name="chair"))
        observations[j] = obs
    boxes = fitted_boxes(report(landmarks, observations), values, camera_mount(), twin_margin=0.2).boxes
    centre = np.array([6.0, 0.0, 0.0]) + CHAIR / 2
    # the fourth chair's box is put behind its front face at the class's depth: its centre is the
    # chair's, where the middle of what the camera saw is half a chair towards the camera
    visible = np.median(np.vstack([o.points for o in observations[3]]), axis=0)
    values_T = values.atPose3(key - 1).matrix()
    visible_world = values_T[:3, :3] @ visible + values_T[:3, 3]
    assert np.linalg.norm(np.asarray(boxes[3]["center"]) - centre) < 0.08
    assert np.linalg.norm(visible_world - centre) > 0.2
    np.testing.assert_allclose(sorted(boxes[3]["dims"][:2]), sorted(CHAIR[:2]), atol=0.1)


def test_a_flight_reports_its_objects_at_their_boxes(tmp_path) -> None:  # noqa: ANN001
    import json

    from amslam.mission import load_mission
    from amslam.registry import build_plugin_manager
    from amslam.runner import Runner
    from tests.tiny_mission import tiny_mission_file

    spec = str(tiny_mission_file(tmp_path, max_time=30, seed=3))
    registry = build_plugin_manager(())
    maps = {}
    for choice in ("boxes", "landmarks"):
        m = load_mission(spec, registry, ["exploration.look_around=true", f"slam.object_map={choice}"])
        run = Runner(m, registry, tmp_path / choice).run().run_dir
        maps[choice] = json.loads((run / "landmarks.json").read_text())
    boxes, points = maps["boxes"], maps["landmarks"]
    assert [lm["id"] for lm in boxes] == [lm["id"] for lm in points]  # the same flight, the same map
    shaped = [lm for lm in boxes if lm.get("shape")]
    assert shaped and not any(lm.get("shape") for lm in points)
    for lm in shaped:
        assert lm["shape"]["model"] == "cuboid"
        np.testing.assert_allclose(lm["position"], lm["shape"]["center"])


def test_one_chair_mapped_twice_is_reported_once_and_neighbours_stay_apart() -> None:
    rng = np.random.default_rng(5)
    values = gtsam.Values()
    observations: dict[int, list] = {}
    key = 0

    def seen(j: int, lo: np.ndarray, y: float, yaw: float, shared_key: int | None = None) -> int:
        nonlocal key
        k = shared_key
        if k is None:
            k = key
            values.insert(k, gtsam.Pose3(pose_from(lo + np.array([0.25, y, 1.2]), yaw)))
            key += 1
        T = values.atPose3(k).matrix()
        pts = face(lo, lo[1] if y < 0 else lo[1] + CHAIR[1], rng)
        body = (invert(T) @ np.c_[pts, np.ones(len(pts))].T).T[:, :3]
        observations.setdefault(j, []).append(view(k, body))
        return k

    row = [np.array([0.75 * i, 0.0, 0.0]) for i in range(3)]  # a row of chairs 0.75 m apart
    for j, lo in enumerate(row):
        seen(j, lo, -2.5, np.pi / 2)
        seen(j, lo, 3.0, -np.pi / 2)
    # chair 1 mapped a second time (landmark 7) from views of its own ...
    seen(7, row[1], -2.5, np.pi / 2)
    seen(7, row[1], -2.5, np.pi / 2)
    # ... and an object of another class where chair 2 stands
    seen(8, row[2], -2.5, np.pi / 2)
    landmarks = [SimpleNamespace(id=j, class_name="chair") for j in (0, 1, 2, 7)]
    landmarks.append(SimpleNamespace(id=8, class_name="table"))
    for share in (None, 0.6):  # a neighbour's points are not inside a chair's box either
        reported = fitted_boxes(
            report(landmarks, observations), values, camera_mount(), twin_margin=0.2, twin_share=share
        )
        assert reported.folded == {7: 1}  # the twin joins the chair seen more, not the row
    assert set(reported.boxes) == {0, 1, 2, 8}
    # two landmarks seen from one key pose are two objects, however their boxes overlap
    k = seen(9, row[0], -2.5, np.pi / 2)
    seen(10, row[0], -2.5, np.pi / 2, shared_key=k)
    apart = [SimpleNamespace(id=j, class_name="chair") for j in (9, 10)]
    assert fitted_boxes(report(apart, observations), values, camera_mount(), twin_margin=0.2).folded == {}


def test_a_part_of_a_table_mapped_again_alone_joins_the_table() -> None:
    rng = np.random.default_rng(6)
    table = np.array([1.6, 0.9, 0.74])
    values = gtsam.Values()
    observations: dict[int, list] = {}
    key = 0

    def seen(j: int, pts: np.ndarray, camera: np.ndarray, yaw: float) -> None:
        nonlocal key
        T = pose_from(camera, yaw)
        values.insert(key, gtsam.Pose3(T))
        key += 1
        body = (invert(T) @ np.c_[pts, np.ones(len(pts))].T).T[:, :3]
        observations.setdefault(j, []).append(view(key - 1, body))

    def side(y: float) -> np.ndarray:
        pts = rng.uniform(0, 1, (150, 3)) * table
        pts[:, 1] = y + rng.normal(0.0, 0.01, 150)
        return pts

    top = rng.uniform(0, 1, (150, 3)) * np.array([1.6, 0.45, 0.0])  # the near half of the top alone
    top[:, 2] = table[2] + rng.normal(0.0, 0.01, 150)
    for _ in range(3):  # landmark 0: the table from both long sides
        seen(0, side(0.0), np.array([0.8, -2.5, 1.2]), np.pi / 2)
        seen(0, side(table[1]), np.array([0.8, 3.4, 1.2]), -np.pi / 2)
    seen(1, top, np.array([0.8, -1.5, 2.0]), np.pi / 2)  # landmark 1: its top, seen once from above
    landmarks = [SimpleNamespace(id=j, class_name="table") for j in (0, 1)]
    for share, folded in ((None, {}), (0.6, {1: 0})):  # the top's box holds no other centre
        reported = fitted_boxes(
            report(landmarks, observations), values, camera_mount(), twin_margin=0.2, twin_share=share
        )
        assert reported.folded == folded
    assert set(reported.boxes) == {0}
    centre = np.asarray(reported.boxes[0]["center"])
    np.testing.assert_allclose(centre[:2], table[:2] / 2, atol=0.1)


def test_a_neighbours_detection_given_to_a_chair_is_left_out_of_its_box() -> None:
    rng = np.random.default_rng(7)
    values = gtsam.Values()
    observations: dict[int, list] = {}
    row = [np.array([0.75 * i, 0.0, 0.0]) for i in range(2)]  # two chairs 0.75 m apart
    for key in range(8):
        chair = row[1] if key == 7 else row[0]  # the last view of landmark 0 is the neighbour's
        camera = np.array([0.25 + 0.3 * (key % 3), -2.5, 1.2])
        T = pose_from(camera, np.pi / 2)
        values.insert(key, gtsam.Pose3(T))
        pts = face(chair, chair[1], rng)
        body = (invert(T) @ np.c_[pts, np.ones(len(pts))].T).T[:, :3]
        xy = pts[:, :2] - pts[:, :2].mean(axis=0)
        spread = float(np.sqrt(np.mean(np.sum(xy**2, axis=1))))
        observations.setdefault(0, []).append(view(key, body, spread=spread))
    landmarks = [SimpleNamespace(id=0, class_name="chair")]
    centre = row[0] + CHAIR / 2
    errors = {}
    for trim in (None, 2.5):
        box = fitted_boxes(
            report(landmarks, observations), values, camera_mount(), twin_margin=0.2, trim_spreads=trim
        ).boxes[0]
        errors[trim] = abs(box["center"][0] - centre[0])
    assert errors[2.5] < 0.05 < errors[None]  # the neighbour's points widened the box towards it


def test_a_chair_whose_masks_miss_its_legs_reaches_down_to_where_its_detections_say() -> None:
    rng = np.random.default_rng(5)
    lo = np.array([0.0, 0.0, 0.0])
    values = gtsam.Values()
    observations: dict[int, list] = {0: [], 1: [], 2: []}
    for key, dx in enumerate((-1.0, 0.0, 1.0)):
        T = pose_from(lo + np.array([0.25 + dx, -2.5, 1.2]), np.pi / 2)
        values.insert(key, gtsam.Pose3(T))
        pts = face(lo, lo[1], rng)
        seat_and_back = pts[pts[:, 2] > 0.45]  # a network's mask: no legs
        body = (invert(T) @ np.c_[seat_and_back, np.ones(len(seat_and_back))].T).T[:, :3]
        # the detector's centroid at the middle of the object's image box: the chair's middle
        box_middle = invert(T) @ np.r_[np.median(seat_and_back, axis=0)[:2], 0.45, 1.0]
        observations[0].append(SimpleNamespace(pose_key=key, points=body, p_body=box_middle[:3]))
        observations[1].append(view(key, body))  # the points' median: says nothing lower
        far_below = invert(T) @ np.r_[np.median(seat_and_back, axis=0)[:2], -1.0, 1.0]
        observations[2].append(SimpleNamespace(pose_key=key, points=body, p_body=far_below[:3]))
    chairs = [SimpleNamespace(id=j, class_name="chair") for j in (0, 1, 2)]
    boxes = fitted_boxes(report(chairs, observations), values, camera_mount(), twin_margin=0.0).boxes
    assert boxes[0]["center"][2] == pytest.approx(0.45, abs=0.03)  # down to the floor
    assert boxes[0]["dims"][2] == pytest.approx(0.9, abs=0.05)
    assert boxes[1]["center"][2] == pytest.approx(0.675, abs=0.03)  # seat to top, as the points are
    assert boxes[2]["dims"][2] == pytest.approx(0.45 + 0.6, abs=0.05)  # stretched by 0.6 m at most
