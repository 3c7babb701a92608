"""Floor changes and slabs (issue #19): paths never cross a slab through unseen space.

Synthetic global maps (0.25 m voxels) of a 6 × 6 m two-storey box, loaded through the public
``load``: a floor, a 0.25 m slab at z 2.75–3.0 and a ceiling, with the air of both storeys known
free. Demo flights crashed where the SLAM-posed global map had carved a small hole into the slab
whose rim was never seen (unknown): with only occupied voxels keeping paths away, the planner
routed the floor change through it.
"""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib.free_space import obstacles, samples_clear, unseen_ceiling
from amslam.lib.voxel_grid import OCCUPIED, UNKNOWN, to_index
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.testing.mapping import make_context
from amslam.types import BoundingBox

from .global_maps import _save_global, load_states, replace_states

V = 0.25
N = (24, 24, 24)  # 6 × 6 × 6 m
SLAB = 11  # z layer 2.75–3.0 m
AREA = BoundingBox(np.array([0.0, 0.0, 0.0]), np.array([6.0, 6.0, 5.5]))
BELOW, ABOVE = np.array([1.0, 1.0, 1.5]), np.array([1.0, 1.0, 4.2])


def building() -> np.ndarray:
    """int8 states: floor (z layer 0), slab (layer 11), ceiling (layer 21), free air between."""
    s = np.full(N, UNKNOWN, dtype=np.int8)
    s[:, :, 1:21] = 0  # FREE
    s[:, :, [0, SLAB, 21]] = OCCUPIED
    return s


def load(mapping_cls, tmp_path, states: np.ndarray, **params):
    return load_states(mapping_cls, tmp_path, states, AREA, V, **params)


def carved_hole(states: np.ndarray) -> np.ndarray:
    """A 0.5 × 0.5 m hole carved free in the slab at x, y 2.5–3.0, its one-voxel rim never seen."""
    s = states.copy()
    s[9:13, 9:13, SLAB] = UNKNOWN
    s[10:12, 10:12, SLAB] = 0
    return s


BACKENDS = [NumpyVoxelMap, Open3dVoxelMap]
#: the rules before issue #19: only occupied voxels keep paths off, vertical moves anywhere
OLD_RULES = {"unseen_surface_reach": 0.0, "observed_floor_changes": False, "floor_change_opening": 0.0}


@pytest.mark.parametrize("cls", BACKENDS)
def test_no_floor_change_through_a_carved_hole_with_an_unseen_rim(cls, tmp_path) -> None:
    states = carved_hole(building())
    # The old rules (only occupied voxels keep paths off; vertical moves anywhere) fly through it:
    # the occupied slab is 0.375 m from the hole's centre line, more than the 0.325 m planning radius.
    old = load(cls, tmp_path, states, **OLD_RULES)
    path = old.plan_path(BELOW, ABOVE)
    assert path is not None, "the scene must expose the defect"
    crossing = path[np.argmax(path[:, 2] > 3.0)]
    assert 2.4 < crossing[0] < 3.1 and 2.4 < crossing[1] < 3.1
    # Each rule alone refuses the hole: the unknown rim next to the seen slab is an obstacle; a
    # vertical move near a slab needs the robot's whole ball observed; a floor change needs an
    # opening wider than 1 m.
    for params in (
        {**OLD_RULES, "unseen_surface_reach": 0.25},
        {**OLD_RULES, "observed_floor_changes": True},
        {**OLD_RULES, "floor_change_opening": 0.75},
        {},  # the defaults: all three
    ):
        m = load(cls, tmp_path, states, **params)
        assert m.plan_path(BELOW, ABOVE) is None, params
        assert np.isinf(m.path_costs(BELOW[None], ABOVE[None])[0, 0]), params


@pytest.mark.parametrize("cls", BACKENDS)
def test_an_observed_shaft_is_still_a_way_between_floors(cls, tmp_path) -> None:
    states = carved_hole(building())
    states[13:23, 13:23, SLAB] = 0  # a 2.5 × 2.5 m shaft at x, y 3.25–5.75 (the demo's is 2.6 m)
    m = load(cls, tmp_path, states)
    path = m.plan_path(BELOW, ABOVE)
    assert path is not None
    # every leg at slab height runs inside the shaft's footprint, none through the carved hole
    for a, b in zip(path[:-1], path[1:], strict=True):
        pts = a + np.linspace(0, 1, 50)[:, None] * (b - a)
        at_slab = (pts[:, 2] > 2.75 - 0.3) & (pts[:, 2] < 3.0 + 0.3)
        assert np.all((pts[at_slab, :2] > 3.25) & (pts[at_slab, :2] < 5.75)), (a, b)
        assert m.segment_free(a, b)


@pytest.mark.parametrize("cls", BACKENDS)
def test_a_carved_hole_seen_all_round_is_too_narrow_for_a_floor_change(cls, tmp_path) -> None:
    # A 1 × 1 m patch of the slab carved free with its rim seen occupied and the air above and
    # below it observed: by clearance alone the robot fits (0.375 m from the rim > 0.325 m).
    states = building()
    states[8:12, 8:12, SLAB] = 0
    old = load(cls, tmp_path, states, **OLD_RULES)
    assert old.plan_path(BELOW, ABOVE) is not None, "the scene must expose the defect"
    m = load(cls, tmp_path, states)
    assert m.plan_path(BELOW, ABOVE) is None
    # ... while flying level through the same layer's air elsewhere is untouched
    assert m.plan_path(BELOW, BELOW + [3.5, 3.5, 0.0]) is not None
    # Nor may a path hover under the patch, 0.125 m below where the slab really is: the patch is an
    # obstacle, not a skylight (snap radius 0: the very voxel must be a graph node).
    under = np.array([[2.375, 2.375, 2.625]])
    exact = {"snap_radius": 0.0}
    assert np.isfinite(load(cls, tmp_path, states, **OLD_RULES, **exact).path_costs(BELOW[None], under)[0, 0])
    assert np.isinf(load(cls, tmp_path, states, **exact).path_costs(BELOW[None], under)[0, 0])
    # A goal there (a viewpoint the height band let float up under the patch) is reached only as
    # far as the graph goes: the path ends on the node it snapped to, not in the danger zone.
    assert np.allclose(load(cls, tmp_path, states, **OLD_RULES).plan_path(BELOW, under[0])[-1], under[0])
    end = m.plan_path(BELOW, under[0])[-1]
    assert np.linalg.norm(end - under[0]) <= 0.6 and end[2] <= 2.75 - 0.325 - 1e-9
    # a wide shaft is no such patch: its air in the slab's layer stays a way up
    shaft = building()
    shaft[13:23, 13:23, SLAB] = 0
    assert np.isfinite(
        load(cls, tmp_path, shaft, **exact).path_costs(BELOW[None], [[4.375, 4.375, 2.875]])[0, 0]
    )


@pytest.mark.parametrize("cls", BACKENDS)
def test_a_slab_the_map_carved_after_a_plan_stays_an_obstacle(cls, tmp_path) -> None:
    # Later in a flight the global map holds a 2 m strip of the slab free, its rim seen occupied
    # and the air round it observed (a slab seen from below and from above by poses whose heights
    # disagree, each side's rays carving the other's voxels): on the map alone it is an opening
    # wide enough for a floor change.
    carved = building()
    carved[6:14, :, SLAB] = 0  # x 1.5–3.5 m, the whole width
    assert load(cls, tmp_path, carved).plan_path(BELOW, ABOVE) is not None, "the scene must expose the defect"
    # A flight whose plans saw the slab whole keeps it as an obstacle, whatever the map says now ...
    m = load(cls, tmp_path, building())
    assert m.plan_path(BELOW, ABOVE) is None
    assert len(m.slab_history()) == N[0] * N[1] * 3  # floor, slab and ceiling, every voxel
    replace_states(m, tmp_path, carved)
    assert m.plan_path(BELOW, ABOVE) is None
    assert np.isinf(m.path_costs(BELOW[None], ABOVE[None])[0, 0])
    # ... and so does the map it saves, loaded by a later mission
    m.save(tmp_path / "saved.npz")
    later = load(cls, tmp_path, building())
    later.load(tmp_path / "saved.npz")
    assert later.plan_path(BELOW, ABOVE) is None
    # A shaft its plans saw open from the start stays a way up.
    shaft = building()
    shaft[13:23, 13:23, SLAB] = 0
    m = load(cls, tmp_path, shaft)
    assert m.plan_path(BELOW, ABOVE) is not None
    replace_states(m, tmp_path, np.where(carved == 0, carved, shaft))
    assert m.plan_path(BELOW, ABOVE) is not None


@pytest.mark.parametrize("cls", BACKENDS)
def test_segment_free_keeps_clear_of_the_unseen_edge_of_a_slab(cls, tmp_path) -> None:
    states = building()
    states[12:, :, SLAB] = UNKNOWN  # the slab seen only for x < 3.0: its edge beyond is unseen
    a, b = np.array([3.2, 2.0, 2.4]), np.array([3.2, 2.5, 2.4])  # 0.35 m under the unseen part
    old = load(cls, tmp_path, states, unseen_surface_reach=0.0)
    assert old.segment_free(a, b)  # 0.40 m from the seen edge's box: clear by the old rule
    m = load(cls, tmp_path, states)
    assert not m.segment_free(a, b)
    # further along, under unknown space two voxels from the seen slab, nothing is assumed
    assert m.segment_free(a + [0.6, 0, 0], b + [0.6, 0, 0])
    # the same rule point-wise, for clearance checks outside the planner
    # slab, its unseen edge, unknown two voxels on, free below, free above
    pts = np.array([[2.9, 2.1, 2.85], [3.1, 2.1, 2.85], [3.6, 2.1, 2.85], [3.1, 2.1, 2.4], [3.1, 2.1, 3.1]])
    np.testing.assert_array_equal(m.blocked(pts), [True, True, False, False, False])
    np.testing.assert_array_equal(old.blocked(pts), [True, False, False, False, False])


def test_samples_clear_unknown_next_to_a_slab_in_a_fine_map() -> None:
    # 0.1 m voxels (the local map): a slab bottom seen at z 2.8 for x < 1, unknown beyond.
    v = 0.1
    s = np.full((40, 20, 40), UNKNOWN, dtype=np.int8)
    s[:, :, :28] = 0
    s[:10, :, 28] = OCCUPIED

    def states_at(index: np.ndarray) -> np.ndarray:
        out = np.full(len(index), UNKNOWN, dtype=np.int8)
        ok = np.all((index >= 0) & (index < np.array(s.shape)), axis=1)
        out[ok] = s[tuple(index[ok].T)]
        return out

    seg = np.array([[1.12, 0.5, 2.62], [1.12, 1.5, 2.62]])  # 0.18 m under the unseen edge
    assert samples_clear(seg, 0.2, v, states_at)  # 0.18 m below, 0.12 m beside the seen part: 0.216
    assert not samples_clear(seg, 0.2, v, states_at, unseen_reach=0.25)
    # wall-like surfaces are not extended: an unknown voxel beside a vertical wall stays free
    w = np.full((40, 20, 40), UNKNOWN, dtype=np.int8)
    w[:20, :, :] = 0
    w[20, :, :] = OCCUPIED  # a wall at x 2.0–2.1, unknown behind it
    w[21:, :10, :] = 0

    def wall_at(index: np.ndarray) -> np.ndarray:
        out = np.full(len(index), UNKNOWN, dtype=np.int8)
        ok = np.all((index >= 0) & (index < np.array(w.shape)), axis=1)
        out[ok] = w[tuple(index[ok].T)]
        return out

    beside = np.array([[2.35, 1.05, 2.0], [2.35, 1.05, 2.5]])  # behind the wall, next to the unknown
    assert samples_clear(beside, 0.2, v, wall_at, unseen_reach=0.25)
    assert to_index(beside, v)[0, 0] == 23


@pytest.mark.parametrize("cls", BACKENDS)
def test_local_path_on_the_fine_map(cls, tmp_path) -> None:
    # The contract's wall scene on the local map (0.1 m): a wall at x 3.15 seen from the origin.
    from amslam.testing.mapping import CAMERA, camera_pose, wall_depth

    m = cls()
    m.configure(cls.Params(), make_context(tmp_path))
    m.integrate_local(wall_depth(), CAMERA.K, camera_pose())
    a, b = np.array([0.5, 0.0, 0.0]), np.array([2.5, 0.0, 0.0])
    path = m.plan_local_path(a, b)
    assert path is not None and np.allclose(path[0], a) and np.allclose(path[-1], b)
    assert len(path) == 2  # a clear straight line stays one leg
    assert m.plan_local_path(a, np.array([4.0, 0.0, 0.0])) is None  # behind the wall: unknown
    # a goal in the wall's clearance band: the path ends on the graph, out of the band
    end = m.plan_local_path(a, np.array([2.95, 0.0, 0.0]))[-1]
    assert end[0] <= 3.1 - m.local_radius + 1e-9 and np.linalg.norm(end - [2.95, 0.0, 0.0]) <= 0.3 + 1e-9
    for s, e in zip(path[:-1], path[1:], strict=True):
        assert m.segment_free(s, e, local=True)


def _ceiling_seen_on_one_side() -> np.ndarray:
    """0.1 m voxels, 6 × 2 × 4 m: air known free under z 2.8; a ceiling (z 2.8–2.9) seen from below
    for x < 1 m; above z 2.8 for x ≥ 1 m only what a level camera saw: nothing, except a shaft at
    x ≥ 4 m seen free all the way up."""
    s = np.full((60, 20, 40), UNKNOWN, dtype=np.int8)
    s[:, :, :28] = 0  # FREE
    s[:10, :, 28] = OCCUPIED
    s[40:, :, 28:] = 0
    return s


def test_the_unseen_rest_of_a_ceiling_is_an_obstacle_in_its_layer() -> None:
    # Three-floor seed 2 climbed "the shaft" 1.2 m off where it thought, 0.9 m from a ceiling it
    # had seen, into the unseen part of the same slab. The unknown voxels of the ceiling's layer
    # within the reach count as ceiling; the seen shaft, the layers above and below, and unknown
    # beyond the reach do not.
    s, v = _ceiling_seen_on_one_side(), 0.1
    rest = unseen_ceiling(s, v, 1.5)
    assert rest[10:25, :, 28].all()  # 0–1.5 m from the seen edge
    assert not rest[26:40, :, 28].any()  # beyond the reach
    assert not rest[40:].any()  # the shaft, seen free
    assert not rest[:, :, 29:].any() and not rest[:, :, :28].any()  # only the ceiling's own layer
    np.testing.assert_array_equal(obstacles(s, v, ceiling_reach=1.5), (s == OCCUPIED) | rest)
    # a door's lintel (a 0.2 m deep underside over a 1.2 m door) is no ceiling to continue
    lintel = np.full((60, 20, 40), UNKNOWN, dtype=np.int8)
    lintel[:, :, :21] = 0
    lintel[20:32, 9:11, 21] = OCCUPIED
    assert not unseen_ceiling(lintel, v, 1.5).any()
    # a floor seen from above is no ceiling: unknown beside it stays unknown
    floor = np.full((60, 20, 40), UNKNOWN, dtype=np.int8)
    floor[:, :, 10:] = 0
    floor[:10, :, 9] = OCCUPIED
    assert not unseen_ceiling(floor, v, 1.5).any()


@pytest.mark.parametrize("cls", BACKENDS)
def test_setpoints_stop_a_climb_under_the_unseen_rest_of_a_ceiling(cls, tmp_path) -> None:
    # The same scene in a backend's local map (moved 3, 1, 2 m down so that the window, centred on
    # the origin, holds it): the guards keep the vehicle below the unseen ceiling 0.9 m from the
    # seen edge, and let it climb the seen shaft (both backends: the rule lives in the shared map
    # code).
    from amslam.setpoints import SetpointFilter

    shift = np.array([3.0, 1.0, 2.0])
    scene, origin = _ceiling_seen_on_one_side(), (-30, -10, -20)
    m = load(cls, tmp_path, np.full(N, UNKNOWN, np.int8), local=scene, local_origin=origin)
    assert m.states(np.array([0.55, 1.05, 2.85]) - shift, local=True)[0] == OCCUPIED
    here, up = np.array([1.95, 1.05, 1.85]) - shift, np.array([0.0, 0.0, 1.65])
    top = _fly(SetpointFilter(m, 0.25, 0.0, 0.6), here, here + up)[:, 2].max()
    assert here[2] + 0.1 < top <= 2.8 - 0.25 - 0.1 - shift[2] + 1e-9  # radius and margin below it
    shaft = np.array([5.05, 1.05, 1.85]) - shift
    np.testing.assert_allclose(_fly(SetpointFilter(m, 0.25, 0.0, 0.6), shaft, shaft + up)[-1], shaft + up)
    # with the rule off only the seen part is a ceiling: the climb goes on into the unseen one
    old = load(
        cls, tmp_path, np.full(N, UNKNOWN, np.int8), local=scene, local_origin=origin, local_ceiling_reach=0
    )
    np.testing.assert_allclose(_fly(SetpointFilter(old, 0.25, 0.0, 0.6), here, here + up)[-1], here + up)


def _fly(guard, start: np.ndarray, goal: np.ndarray, ticks: int = 40) -> np.ndarray:
    """Positions of a point vehicle flying 0.1 m a tick towards what the guards send."""
    p, track = start.copy(), []
    for _ in range(ticks):
        step = guard.apply(goal, p) - p
        p = p + step * min(1.0, 0.1 / max(float(np.linalg.norm(step)), 1e-9))
        track.append(p)
    return np.array(track)


# ---------------------------------------------------------------------------------------------
# Floors are changed through air the camera saw through. A slab seen from above and from below by
# poses whose heights disagree sits in two z layers in two places, and each side's rays carve the
# other's layer: a three-floor flight's map had a free strip 2 m wide through both layers, farther
# than the opening rule's 0.75 m from either, its plans climbed into it (session 46). Rays cross a
# real opening: the camera below sees the ceiling above through it, the camera above the floor
# below. The rays that carved the strip ended on the slab.

SHAFT = (3.25, 5.75)  # x and y of the shaft of the scene below (voxels 13–22)


def true_building_scene(shaft: bool = True):
    """The building of :func:`building` as surfaces for ray casting: floor, a slab with the shaft,
    ceiling (kept a few centimetres inside their voxel layers, as real surfaces are; reaching
    beyond the rays' range, so that the shaft is the one way through)."""
    o3d = pytest.importorskip("open3d")
    lo, hi, z = -6.0, 12.0, (2.78, 2.97)
    boxes = [((lo, lo, 0.03), (hi, hi, 0.22)), ((lo, lo, 5.28), (hi, hi, 5.47))]
    if shaft:
        a, b = SHAFT
        boxes += [
            ((lo, lo, z[0]), (a, hi, z[1])),
            ((b, lo, z[0]), (hi, hi, z[1])),
            ((a, lo, z[0]), (b, a, z[1])),
            ((a, b, z[0]), (b, hi, z[1])),
        ]
    else:
        boxes.append(((lo, lo, z[0]), (hi, hi, z[1])))
    scene = o3d.t.geometry.RaycastingScene()
    for lo, hi in boxes:
        mesh = o3d.geometry.TriangleMesh.create_box(*np.subtract(hi, lo)).translate(lo)
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def pitched_pose(position, yaw: float, pitch: float) -> np.ndarray:
    """``T_world_cam`` of a camera at ``position``, heading ``yaw``, looking ``pitch`` up (rad)."""
    from amslam.geometry import yaw_matrix
    from amslam.types import R_BODY_CAM

    c, s = np.cos(-pitch), np.sin(-pitch)
    T = np.eye(4)
    T[:3, :3] = yaw_matrix(yaw) @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ R_BODY_CAM
    T[:3, 3] = position
    return T


#: a camera under the slab looking up at the shaft, one over it looking down into it; two looking
#: at the slab by the strip :func:`strip_map` carves, from over it and from under it (both floors
#: visited)
VIEWS = [
    ((1.5, 4.5, 1.5), 0.0, np.radians(35)),
    ((1.5, 4.5, 4.2), 0.0, np.radians(-40)),
    ((5.0, 1.5, 4.2), np.pi, np.radians(-30)),
    ((5.0, 1.5, 1.5), np.pi, np.radians(30)),
]


def views(scene):
    """(depth, K, T_world_cam) of :data:`VIEWS` in ``scene``."""
    from amslam.testing.mapping import CAMERA, render_depth

    frames = []
    for position, yaw, pitch in VIEWS:
        T = pitched_pose(position, yaw, pitch)
        frames.append((render_depth(scene, CAMERA, T), CAMERA.K, T))
    return frames


def through_record(frames) -> np.ndarray:
    from amslam.lib.voxel_grid import decode, depth_rays, seen_through
    from amslam.testing.mapping import CAMERA

    keys = [seen_through(depth_rays(d, K, T, 1, CAMERA.max_range), V, 1.0) for d, K, T in frames]
    return decode(np.unique(np.concatenate(keys)))


def sides_record(frames) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the surfaces ``frames`` hit from above and from below."""
    from amslam.lib.voxel_grid import decode, depth_rays, surfaces_seen_from
    from amslam.testing.mapping import CAMERA

    sides = [surfaces_seen_from(depth_rays(d, K, T, 1, CAMERA.max_range), V) for d, K, T in frames]
    return tuple(decode(np.unique(np.concatenate(side))) for side in zip(*sides, strict=True))


def views_record(frames) -> dict[str, np.ndarray]:
    """The seen-through records of ``frames`` as a saved map holds them."""
    above, below = sides_record(frames)
    return {
        "global_seen_through": through_record(frames),
        "global_seen_from_above": above,
        "global_seen_from_below": below,
    }


def test_rays_see_through_a_shaft_and_not_through_a_slab() -> None:
    record = through_record(views(true_building_scene()))
    layer = record[record[:, 2] == SLAB]
    assert len(layer) >= 20  # the shaft, seen through from below and from above
    # in the shaft (voxels 13–22) or its rim: a ray through the shaft's edge crosses the rim voxel
    # in the few centimetres of its layer over or under the slab
    inside = ((layer[:, :2] >= 12) & (layer[:, :2] <= 23)).all(axis=1)
    assert inside.all(), layer[~inside]
    assert ((layer[:, :2] >= 13) & (layer[:, :2] <= 22)).all(axis=1).sum() >= 20
    # a slab without an opening: rays end on it, none is seen through in its layer or next to it
    whole = through_record(views(true_building_scene(shaft=False)))
    assert not np.isin(whole[:, 2], [SLAB - 1, SLAB, SLAB + 1]).any()


def strip_map() -> np.ndarray:
    """The building with the shaft, and a 2 m square of the slab carved free at x, y 0.5–2.5 m,
    its rim occupied and the air round it observed: on the map alone, a way up 1 m from the slab."""
    s = building()
    s[13:23, 13:23, SLAB] = 0
    s[2:10, 2:10, SLAB] = 0
    return s


def band_crossings(path: np.ndarray) -> np.ndarray:
    """x, y of the points of a path (sampled every 5 cm) in the slab's layer or next to it."""
    from amslam.lib.free_space import segment_samples

    pts = np.concatenate([segment_samples(a, b, 0.05) for a, b in zip(path[:-1], path[1:], strict=True)])
    return pts[(pts[:, 2] >= (SLAB - 1) * V) & (pts[:, 2] < (SLAB + 2) * V), :2]


@pytest.mark.parametrize("cls", BACKENDS)
def test_floors_are_changed_through_air_seen_through(cls, tmp_path) -> None:
    carved = strip_map()
    record = views_record(views(true_building_scene()))
    # Without the record (a map saved without it: the rule is off) the plan climbs the strip.
    m = load(cls, tmp_path, carved)
    path = m.plan_path(BELOW, ABOVE)
    assert path is not None and (band_crossings(path) < SHAFT[0]).all(axis=1).any(), "the defect"
    # a map saved with the air seen through but not the surfaces' sides (before they were kept):
    # the rule is off too
    _save_global(tmp_path / "older.npz", carved, V, global_seen_through=record["global_seen_through"])
    m.load(tmp_path / "older.npz")
    assert (band_crossings(m.plan_path(BELOW, ABOVE)) < SHAFT[0]).all(axis=1).any()
    # With the record the floor change goes through the shaft, the air the camera saw through.
    _save_global(tmp_path / "seen.npz", carved, V, **record)
    m.load(tmp_path / "seen.npz")
    path = m.plan_path(BELOW, ABOVE)
    assert path is not None
    crossing = band_crossings(path)
    assert len(crossing) and ((crossing > SHAFT[0] - V) & (crossing < SHAFT[1] + V)).all()
    # the record goes with a saved map
    m.save(tmp_path / "saved.npz")
    later = load(cls, tmp_path, building())
    later.load(tmp_path / "saved.npz")
    np.testing.assert_array_equal(later.seen_through(), m.seen_through())
    for got, want in zip(later.surfaces_seen_from(), m.surfaces_seen_from(), strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(later.plan_path(BELOW, ABOVE), path)
    # seen_through_rise 0: no record, no rule
    off = load(cls, tmp_path, carved, seen_through_rise=0.0)
    off.load(tmp_path / "seen.npz")
    assert (band_crossings(off.plan_path(BELOW, ABOVE)) < SHAFT[0]).all(axis=1).any()


@pytest.mark.parametrize("cls", BACKENDS)
def test_the_record_is_kept_by_integration_and_rebuilt_with_the_map(cls, tmp_path) -> None:
    from amslam.testing.mapping import CAMERA

    m = cls()
    m.configure(cls.Params(global_stride=1), make_context(tmp_path, camera=CAMERA, area=AREA))
    frames = views(true_building_scene())
    for depth, K, T in frames:
        m.integrate_global(depth, K, T)
    np.testing.assert_array_equal(m.seen_through(), through_record(frames))
    above, below = m.surfaces_seen_from()
    # the cameras over the slab hit its top, those under it its underside; nothing else
    assert set(above[:, 2]) == {SLAB} and set(below[:, 2]) == {SLAB}
    for got, want in zip((above, below), sides_record(frames), strict=True):
        np.testing.assert_array_equal(got, want)
    # SLAM moved the poses: the record is the frames' at the new poses, not the old ones'
    shifted = []
    for depth, K, T in frames:
        moved = T.copy()
        moved[:3, 3] += [0.5, 0.0, 0.0]
        shifted.append((depth, K, moved))
    m.rebuild_global(shifted)
    np.testing.assert_array_equal(m.seen_through(), through_record(shifted))
    assert not np.array_equal(through_record(shifted), through_record(frames))
    for got, want in zip(m.surfaces_seen_from(), sides_record(shifted), strict=True):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("cls", BACKENDS)
def test_a_floor_not_yet_visited_is_reached_without_the_proof(cls, tmp_path) -> None:
    # From below, the level camera sees through a shaft only with rays that end within its 5 m
    # range less than a metre above the slab: no proof. Before the floor above was visited, its
    # air over the slab is unknown; the slab was seen from below only and could not be carved by
    # the two sides' rays, so the first climb keeps the other rules.
    shaft = (slice(10, 18), slice(10, 18))  # 2 m, in the middle: every voxel of it within 1.5 m of the slab
    first_visit = building()
    first_visit[(*shaft, SLAB)] = 0
    first_visit[:, :, SLAB + 1 : 21] = UNKNOWN
    first_visit[(*shaft, slice(SLAB + 1, SLAB + 5))] = 0  # seen through the shaft from below
    up = np.array([3.5, 3.5, 3.6])
    nothing = np.array([[0, 0, 0]])  # a record that holds no voxel of the shaft: the rule is on
    slab = np.argwhere(building()[:, :, SLAB] == OCCUPIED)
    slab = np.column_stack([slab, np.full(len(slab), SLAB)])
    from_below = {
        "global_seen_through": nothing,
        "global_seen_from_above": nothing,
        "global_seen_from_below": slab,
    }
    _save_global(tmp_path / "first.npz", first_visit, V, **from_below)
    m = load(cls, tmp_path, building())
    m.load(tmp_path / "first.npz")
    assert m.plan_path(BELOW, up) is not None
    # The air over the slab seen from below, through the shaft (rays up through it reach the air
    # beyond its rim): the slab's top was never seen, no pose was over it to carve it, the climb
    # keeps the other rules (the demo's first climb waited 400 s for a proof it could not get).
    visited = building()
    visited[(*shaft, SLAB)] = 0
    _save_global(tmp_path / "air.npz", visited, V, **from_below)
    m.load(tmp_path / "air.npz")
    assert m.plan_path(BELOW, up) is not None
    # The same shaft once the floor above was visited: the slab's top seen from above, the slab
    # seen from both floors, and a climb needs the proof.
    _save_global(
        tmp_path / "visited.npz", visited, V, **{**from_below, "global_seen_from_above": slab + [0, 0, 1]}
    )
    m.load(tmp_path / "visited.npz")
    assert m.plan_path(BELOW, up) is None


def fly_trail(mapping, points: np.ndarray) -> None:
    """The body's poses along ``points`` (level, heading +x) as frames whose images hold no pixel:
    the trail without carving anything into the loaded map."""
    from amslam.testing.mapping import CAMERA

    for p in points:
        T_world_body = np.eye(4)
        T_world_body[:3, 3] = p
        mapping.integrate_global(np.zeros((0, 0), np.float32), CAMERA.K, T_world_body @ CAMERA.T_body_cam)


def polyline(*corners, step: float = 0.1) -> np.ndarray:
    return np.concatenate(
        [segment_points(a, b, step) for a, b in zip(corners[:-1], corners[1:], strict=True)]
    )


def segment_points(a, b, step: float) -> np.ndarray:
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
    return a + (b - a) * np.linspace(0.0, 1.0, n + 1)[:, None]


@pytest.mark.parametrize("cls", BACKENDS)
def test_the_way_back_follows_the_flown_trail_where_the_rules_leave_none(cls, tmp_path) -> None:
    from amslam.testing.mapping import CAMERA

    # Both floors visited, the slab seen from both, the shaft never seen through (the level camera
    # climbed it blind): the rule refuses every vertical move in it, no way down through the map.
    slab = np.argwhere(building()[:, :, SLAB] == OCCUPIED)
    slab = np.column_stack([slab, np.full(len(slab), SLAB)])
    nothing = np.array([[0, 0, 0]])
    shaft = building()
    shaft[10:18, 10:18, SLAB] = 0  # 2 m, in the middle: every voxel of it within 1.5 m of the slab
    _save_global(
        tmp_path / "m.npz",
        shaft,
        V,
        global_seen_through=nothing,
        global_seen_from_above=slab + [0, 0, 1],
        global_seen_from_below=slab,
    )
    m = cls()
    m.configure(cls.Params(), make_context(tmp_path, camera=CAMERA, area=AREA))
    m.load(tmp_path / "m.npz")
    top, bottom = np.array([1.0, 5.0, 4.2]), np.array([1.0, 1.0, 1.5])
    assert m.plan_path(top, bottom) is None
    assert m.plan_path_along_trail(top, bottom) is None  # no trail yet
    # the way it came: from the ground floor's corner to the shaft, up it, and on over the slab
    flown = polyline(bottom, (3.5, 3.5, 1.5), (3.5, 3.5, 4.2), (2.0, 3.5, 4.2), (1.0, 4.5, 4.2))
    fly_trail(m, flown)
    assert len(m.trail()) >= 20 and np.allclose(m.trail()[0], bottom)
    path = m.plan_path_along_trail(top, bottom)
    assert path is not None
    np.testing.assert_allclose(path[0], top)
    np.testing.assert_allclose(path[-1], bottom)
    # down the shaft as it came up, where it came up: every point in the slab's layer on the trail
    from amslam.lib.free_space import segment_samples

    pts = np.concatenate([segment_samples(a, b, 0.05) for a, b in zip(path[:-1], path[1:], strict=True)])
    crossing = pts[(pts[:, 2] >= SLAB * V) & (pts[:, 2] < (SLAB + 1) * V), :2]
    assert len(crossing) and np.abs(crossing - 3.5).max() < 0.15
    # the map's part of the way: to the trail over the slab and from it on the ground floor, not
    # the whole trail back to its start (the trail joined where the map reaches it)
    assert len(path) < len(flown)
    # a rebuild moves the trail with the frames' poses
    m.rebuild_global([(np.zeros((0, 0), np.float32), CAMERA.K, np.eye(4) @ CAMERA.T_body_cam)])
    np.testing.assert_allclose(m.trail(), [[0.0, 0.0, 0.0]], atol=1e-9)
