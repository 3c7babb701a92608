"""Procedural buildings: floors, the shaft between them, furniture arrangements."""

from __future__ import annotations

import numpy as np

from amslam.plugins.sim.procedural import ProceduralWorldParams, generate_building
from amslam.plugins.sim.world import World

from .conftest import fly_to, make_platform


def test_robot_changes_floor_through_the_shaft(tmp_path):
    plat = make_platform(tmp_path, seed=11, world={"floors": 3})
    spec = plat.world.spec
    s = plat.world_summary()
    assert len(s.reachable_free_volume_per_floor) == 3
    assert all(v > 300 for v in s.reachable_free_volume_per_floor)  # every floor is reachable
    plat.arm_and_takeoff(1.4)
    plat.advance(4.0)
    y = spec.places["shaft"][1]
    for p in (spec.places["corridor_east"], spec.places["lobby_entrance"], spec.places["shaft"]):
        fly_to(plat, np.array([p[0], y, 1.4]))
    for floor in (1, 2):
        fly_to(plat, np.array([spec.places["shaft"][0], y, floor * 3.0 + 1.4]))
        assert not plat.status().crashed, plat.status().crash_reason
        assert plat.world.floor_index(plat.ground_truth()[2, 3]) == floor
    # the ceiling of the top floor is closed
    fly_to(plat, np.array([spec.places["shaft"][0], y, 3 * 3.0 + 1.0]))
    assert plat.status().crashed and "roof" in plat.status().crash_reason


def test_buildings_have_clusters_rows_and_several_classes():
    classes, chairs_near_table, rows = set(), 0, 0
    for seed in range(4):
        spec = generate_building(ProceduralWorldParams(floors=2), np.random.default_rng(seed))
        w = World(spec)
        classes |= {o.class_name for o in w.objects}
        chairs = np.array([o.centroid for o in w.objects if o.class_name == "chair"])
        for t in (o for o in w.objects if o.class_name == "table"):
            chairs_near_table += int(np.sum(np.linalg.norm(chairs[:, :2] - t.centroid[:2], axis=1) < 1.3))
        # repeated rows: chairs with the same x (or y) at a regular pitch
        for c in chairs:
            same_row = np.abs(chairs[:, 0] - c[0]) < 0.15
            if np.sum(same_row & (np.abs(chairs[:, 2] - c[2]) < 0.5)) >= 3:
                rows += 1
        # furniture never blocks the way from the corridor: the start and shaft are connected
        assert all(v > 0 for v in w.summary(np.array([1.2, 7.0, 1.2])).reachable_free_volume_per_floor)
    assert {"chair", "table", "shelf", "sofa"} <= classes
    assert chairs_near_table >= 8  # tight clusters around tables
    assert rows >= 6  # symmetric repeated rows


def test_procedural_objects_do_not_intersect_walls_or_each_other():
    spec = generate_building(ProceduralWorldParams(), np.random.default_rng(2))
    w = World(spec)
    boxes = [(o.lo, o.hi) for o in w.objects]
    for i, (a_lo, a_hi) in enumerate(boxes):
        for b_lo, b_hi in boxes[i + 1 :]:
            overlap = np.minimum(a_hi, b_hi) - np.maximum(a_lo, b_lo)
            assert np.any(overlap <= 0.02), "two pieces of furniture overlap"
    # object centres sit inside free space at their own height, not in walls
    for o in w.objects:
        probe = np.array([o.centroid[0], o.centroid[1], 2.5])  # above the furniture, below the ceiling
        assert w.distance(probe)[0] > 0.05
