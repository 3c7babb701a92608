"""The mask-based sim detector."""

from __future__ import annotations

import numpy as np

from amslam.interfaces import RunContext
from amslam.plugins.sim import SimDetector
from amslam.plugins.sim.camera import viewing_pose
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
