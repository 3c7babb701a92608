"""Contract tests for mapping backends: known geometry in, expected states, frontiers and paths out.

A plugin author subclasses :class:`MappingContract` in a test module and overrides
:meth:`MappingContract.make_backend` (and :meth:`MappingContract.make_params` to tune parameters)::

    from amslam.testing.mapping import MappingContract

    class TestMyMap(MappingContract):
        def make_backend(self):
            return MyMap()

pytest then runs every ``test_*`` method below against the backend. The scenes are synthetic depth
frames from a small 160×120 camera at the world origin looking along +x (a wall, a box in front of
far background, an empty view), so the expected answers are known exactly; points are placed in
the middle of voxels for both 0.25 m and 0.1 m lattices so no boundary rounding is involved.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.geometry import yaw_matrix
from amslam.interfaces import BackendParams, Mapping, RunContext
from amslam.types import R_BODY_CAM, BoundingBox, CameraModel, RobotSpec, VoxelState

UNKNOWN, FREE, OCCUPIED = VoxelState.UNKNOWN.value, VoxelState.FREE.value, VoxelState.OCCUPIED.value

#: The small camera used by the contract scenes.
CAMERA = CameraModel.from_fov(160, 120, 87.0, 58.0, min_range=0.3, max_range=5.0)
#: Exploration area of the contract scenes (world frame).
AREA = BoundingBox(np.array([-1.0, -4.0, -1.5]), np.array([7.0, 4.0, 2.0]))
WALL_X = 3.15


def camera_pose(position: tuple[float, float, float] = (0.0, 0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    """``T_world_cam`` of a camera at ``position`` looking horizontally at heading ``yaw``."""
    T = np.eye(4)
    T[:3, :3] = yaw_matrix(yaw) @ R_BODY_CAM
    T[:3, 3] = position
    return T


def wall_depth(camera: CameraModel = CAMERA, distance: float = WALL_X) -> np.ndarray:
    """Depth image of a plane facing the camera at ``distance`` (depth is along the optical axis)."""
    return np.full((camera.height, camera.width), distance, dtype=np.float32)


def box_depth(camera: CameraModel = CAMERA, box: float = 2.1, background: float = 5.0) -> np.ndarray:
    """A box face at ``box`` metres covering the central quarter of the image, far background behind."""
    d = np.full((camera.height, camera.width), background, dtype=np.float32)
    h, w = camera.height, camera.width
    d[3 * h // 8 : 5 * h // 8, 3 * w // 8 : 5 * w // 8] = box
    return d


def make_context(tmp_path: Path, camera: CameraModel = CAMERA, area: BoundingBox = AREA) -> RunContext:
    """A run context for the contract scenes."""
    return RunContext(
        rng=np.random.default_rng(0),
        run_dir=Path(tmp_path),
        camera=camera,
        robot=RobotSpec(radius=0.25),
        area=area,
    )


class MappingContract:
    """Mix-in of contract tests; override :meth:`make_backend`."""

    def make_backend(self) -> Mapping:
        """A fresh, unconfigured backend."""
        raise NotImplementedError("override make_backend() to return your Mapping backend")

    def make_params(self, backend: Mapping) -> BackendParams:
        """Parameters for the backend under test (defaults unless overridden)."""
        return type(backend).Params()

    def configured(self, tmp_path: Path) -> Mapping:
        """A backend configured for the contract scenes."""
        backend = self.make_backend()
        backend.configure(self.make_params(backend), make_context(tmp_path))
        return backend

    @pytest.fixture
    def mapping(self, tmp_path: Path):
        backend = self.configured(tmp_path)
        yield backend
        backend.close()

    @pytest.fixture
    def wall_map(self, mapping: Mapping) -> Mapping:
        mapping.integrate_global(wall_depth(), CAMERA.K, camera_pose())
        mapping.integrate_local(wall_depth(), CAMERA.K, camera_pose())
        return mapping

    # ------------------------------------------------------------------ parameters and lifecycle
    def test_params_are_documented(self) -> None:
        params_cls = type(self.make_backend()).Params
        assert issubclass(params_cls, BackendParams)
        undocumented = [n for n, f in params_cls.model_fields.items() if not f.description]
        assert not undocumented, f"parameters without a description: {undocumented}"

    def test_close_twice(self, tmp_path: Path) -> None:
        backend = self.configured(tmp_path)
        backend.close()
        backend.close()

    # ------------------------------------------------------------------ occupancy
    def test_empty_map_is_unknown(self, mapping: Mapping) -> None:
        pts = np.array([[1.0, 0.0, 0.0], [1e4, 0.0, 0.0], [-1e4, 5.0, 3.0]])
        for local in (False, True):
            st = mapping.states(pts, local=local)
            assert st.dtype == np.int8 and st.shape == (3,)
            assert np.all(st == UNKNOWN)
        assert mapping.explored_volume() == 0.0

    @pytest.mark.parametrize("local", [False, True])
    def test_wall_free_occupied_unknown(self, wall_map: Mapping, local: bool) -> None:
        pts = np.array(
            [
                [1.55, 0.05, 0.05],  # in front of the wall: free
                [2.55, 0.55, -0.45],  # in front, off-axis: free
                [WALL_X, 0.05, 0.05],  # on the wall: occupied
                [WALL_X, -0.55, 0.45],
                [4.55, 0.05, 0.05],  # behind the wall: unknown
                [1.05, -3.55, 0.05],  # outside the field of view: unknown
                [-0.95, 0.05, 0.05],  # behind the camera: unknown
            ]
        )
        expected = [FREE, FREE, OCCUPIED, OCCUPIED, UNKNOWN, UNKNOWN, UNKNOWN]
        np.testing.assert_array_equal(wall_map.states(pts, local=local), expected)

    def test_outside_map_is_unknown(self, wall_map: Mapping) -> None:
        far = np.array([[1e4, 0.0, 0.0], [0.0, -1e4, 0.0]])
        assert np.all(wall_map.states(far) == UNKNOWN)
        assert np.all(wall_map.states(far, local=True) == UNKNOWN)

    def test_no_return_carves_free_to_max_range(self, mapping: Mapping) -> None:
        depth = np.zeros((CAMERA.height, CAMERA.width), dtype=np.float32)
        mapping.integrate_global(depth, CAMERA.K, camera_pose())
        st = mapping.states(np.array([[4.55, 0.05, 0.05], [5.55, 0.05, 0.05]]))
        np.testing.assert_array_equal(st, [FREE, UNKNOWN])
        assert len(mapping.occupied_points()) == 0

    def test_box_casts_shadow(self, mapping: Mapping) -> None:
        mapping.integrate_global(box_depth(), CAMERA.K, camera_pose())
        pts = np.array([[2.15, 0.05, 0.05], [3.05, 0.05, 0.05], [3.05, 1.55, 0.05], [1.05, 0.05, 0.05]])
        np.testing.assert_array_equal(mapping.states(pts), [OCCUPIED, UNKNOWN, FREE, FREE])

    def test_a_rebuild_at_corrected_poses_moves_what_was_drawn_off(self, mapping: Mapping) -> None:
        """Optional (``rebuild_global``): a wall integrated from a pose 0.5 m off (a drifted
        estimate) stands 0.5 m off; rebuilt from the same frame at the corrected pose, it stands
        where it is and nothing is left where it was drawn."""
        drifted, true = camera_pose((0.5, 0.0, 0.0)), camera_pose()
        mapping.integrate_global(wall_depth(), CAMERA.K, drifted)
        phantom, wall = np.array([[WALL_X + 0.55, 0.05, 0.05]]), np.array([[WALL_X + 0.05, 0.05, 0.05]])
        assert mapping.states(phantom)[0] == OCCUPIED
        if not mapping.rebuild_global([(wall_depth(), CAMERA.K, true)]):
            pytest.skip("rebuild_global is optional: this backend keeps its map as it is")
        assert mapping.states(wall)[0] == OCCUPIED
        assert mapping.states(phantom)[0] == UNKNOWN  # behind the wall: never seen
        assert len(mapping.viewpoints()) > 0  # frontiers follow the rebuilt map

    def test_repeated_misses_clear_an_obstacle(self, mapping: Mapping) -> None:
        mapping.integrate_global(wall_depth(), CAMERA.K, camera_pose())
        p = np.array([[WALL_X, 0.05, 0.05]])
        assert mapping.states(p)[0] == OCCUPIED
        for _ in range(8):  # the wall is gone: rays now pass through to the max range
            mapping.integrate_global(np.zeros_like(wall_depth()), CAMERA.K, camera_pose())
        assert mapping.states(p)[0] == FREE

    def test_integrate_returns_touched_box(self, mapping: Mapping) -> None:
        box = mapping.integrate_global(wall_depth(), CAMERA.K, camera_pose())
        assert isinstance(box, BoundingBox) and not box.empty
        assert np.all(box.lo <= [0.5, -0.5, -0.5]) and np.all(box.hi >= [WALL_X, 0.5, 0.5])
        assert box.hi[0] < WALL_X + 1.0  # nothing behind the wall was touched
        # every occupied voxel lies inside the touched box
        occ = mapping.occupied_points()
        assert len(occ) > 0 and np.all((occ >= box.lo) & (occ <= box.hi))
        local_box = mapping.integrate_local(wall_depth(), CAMERA.K, camera_pose())
        assert not local_box.empty and local_box.hi[0] < WALL_X + 1.0

    def test_volumes_and_occupied_points(self, wall_map: Mapping) -> None:
        v = wall_map.voxel_size()
        total = wall_map.explored_volume()
        # the frustum up to the wall is 1/3 · (2·3.15·tan 43.5°)(2·3.15·tan 29°)·3.15 ≈ 12.7 m³, plus
        # the 0.25 m-thick wall slab (≈ 5.3 m³) and the voxels the frustum's faces cut (≈ 5-10 m³)
        assert 12.0 < total < 12.7 + 5.3 + 15.0
        inside = wall_map.explored_volume_in(AREA.lo, AREA.hi)
        free = wall_map.free_volume_in(AREA.lo, AREA.hi)
        assert 0 < free < inside <= total + 1e-9
        occ = wall_map.occupied_points()
        assert occ.shape[1] == 3
        assert np.all(wall_map.states(occ) == OCCUPIED)
        assert np.allclose(np.abs(occ[:, 0] - WALL_X), np.abs(occ[:, 0] - WALL_X).min())  # one slab
        assert 0 < inside - free <= len(occ) * v**3 + 1e-9

    # ------------------------------------------------------------------ frontiers and viewpoints
    def test_frontier_viewpoints_at_the_boundary(self, wall_map: Mapping) -> None:
        vps = wall_map.viewpoints()
        assert len(vps) > 0
        ids = [vp.id for vp in vps]
        assert len(set(ids)) == len(ids)
        for vp in vps:
            assert vp.gain > 0 and vp.cluster_size > 0
            assert -np.pi <= vp.yaw <= np.pi
            assert np.all(vp.position >= AREA.lo) and np.all(vp.position <= AREA.hi)
            assert wall_map.states(vp.position[None])[0] == FREE
            # the cluster borders the observed frustum: in front of the wall, not behind it
            assert vp.cluster_centroid[0] < WALL_X + 0.5
        # no new data: same viewpoints, same ids
        assert [vp.id for vp in wall_map.viewpoints()] == ids

    def test_viewpoint_ids_stable_for_untouched_clusters(self, wall_map: Mapping) -> None:
        before = {vp.id: vp for vp in wall_map.viewpoints()}
        # look at the far side of the area: clusters near the first frustum are left alone
        far = camera_pose((6.0, 3.0, 0.0), np.pi / 2)
        wall_map.integrate_global(np.full_like(wall_depth(), 0.8), CAMERA.K, far)
        after = {vp.id: vp for vp in wall_map.viewpoints()}
        kept = set(before) & set(after)
        assert kept, "updates far away must not renumber every cluster"
        for i in kept:
            np.testing.assert_allclose(before[i].cluster_centroid, after[i].cluster_centroid)

    def test_exploring_everything_leaves_no_viewpoints(self, tmp_path: Path) -> None:
        # a small area seen from its centre in every direction (walls ~2 m away): nothing left
        small = BoundingBox(np.array([-1.5, -1.5, -0.5]), np.array([1.5, 1.5, 0.5]))
        mapping = self.make_backend()
        mapping.configure(self.make_params(mapping), make_context(tmp_path, area=small))
        depth = np.full_like(wall_depth(), 2.0)
        for pitch in (-np.pi / 2, -np.pi / 4, 0.0, np.pi / 4, np.pi / 2):
            for yaw in np.linspace(-np.pi, np.pi, 12, endpoint=False):
                c, s = np.cos(pitch), np.sin(pitch)
                tilt = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # raises body x by pitch
                T = camera_pose((0.0, 0.0, 0.0), yaw)
                T[:3, :3] = T[:3, :3] @ R_BODY_CAM.T @ tilt @ R_BODY_CAM
                mapping.integrate_global(depth, CAMERA.K, T)
        assert mapping.explored_volume_in(small.lo, small.hi) == pytest.approx(3.0 * 3.0 * 1.0, rel=0.05)
        assert mapping.viewpoints() == []
        mapping.close()

    # ------------------------------------------------------------------ paths and collisions
    def test_segment_free(self, wall_map: Mapping) -> None:
        assert wall_map.segment_free(np.array([0.5, 0.0, 0.0]), np.array([2.5, 0.3, 0.0]))
        assert not wall_map.segment_free(np.array([0.5, 0.0, 0.0]), np.array([4.5, 0.0, 0.0]))
        # grazing the wall within the robot radius (0.25 m) is a collision
        assert not wall_map.segment_free(np.array([2.95, -0.5, 0.0]), np.array([2.95, 0.5, 0.0]))
        # unknown space counts as free
        assert wall_map.segment_free(np.array([0.5, -3.5, 0.0]), np.array([1.5, -3.5, 0.0]))
        assert not wall_map.segment_free(np.array([2.0, 0.0, 0.0]), np.array([4.0, 0.0, 0.0]), local=True)
        assert wall_map.segment_free(np.array([0.5, 0.0, 0.0]), np.array([2.0, 0.0, 0.0]), local=True)

    def test_path_costs(self, wall_map: Mapping) -> None:
        pts = np.array([[0.55, 0.05, 0.05], [2.3, 0.8, 0.3], [1.8, -0.6, -0.3]])
        behind = np.array([[4.55, 0.05, 0.05]])
        costs = wall_map.path_costs(pts, np.vstack([pts, behind]))
        assert costs.shape == (3, 4)
        sym = costs[:, :3]
        np.testing.assert_allclose(sym, sym.T, atol=2 * wall_map.voxel_size())
        assert np.allclose(np.diag(sym), 0.0, atol=wall_map.voxel_size())
        euclid = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
        assert np.all(sym >= euclid - 1e-6)
        assert np.all(sym[~np.eye(3, dtype=bool)] < 3.0 * euclid[~np.eye(3, dtype=bool)])
        assert np.all(np.isinf(costs[:, 3]))

    def test_plan_path(self, wall_map: Mapping) -> None:
        start, goal = np.array([0.05, 0.05, 0.05]), np.array([2.3, 0.8, 0.3])
        path = wall_map.plan_path(start, goal)
        assert path is not None and path.ndim == 2 and path.shape[1] == 3
        np.testing.assert_allclose(path[0], start)
        np.testing.assert_allclose(path[-1], goal)
        for a, b in zip(path[:-1], path[1:], strict=True):
            assert wall_map.segment_free(a, b)
        length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
        assert length <= 1.2 * np.linalg.norm(goal - start) + wall_map.voxel_size()
        assert wall_map.plan_path(start, np.array([4.55, 0.05, 0.05])) is None
        assert wall_map.plan_path(start, np.array([WALL_X, 0.05, 0.05])) is None

    # ------------------------------------------------------------------ persistence
    def test_save_load_round_trip(self, wall_map: Mapping, tmp_path: Path) -> None:
        path = tmp_path / "map.npz"
        wall_map.save(path)
        other = self.configured(tmp_path)
        other.load(path)
        g = np.stack(
            np.meshgrid(*[np.arange(lo, hi, 0.25) + 0.05 for lo, hi in zip(AREA.lo, AREA.hi, strict=True)]),
            -1,
        )
        pts = g.reshape(-1, 3)
        np.testing.assert_array_equal(other.states(pts), wall_map.states(pts))
        assert other.explored_volume() == pytest.approx(wall_map.explored_volume())
        assert len(other.viewpoints()) == len(wall_map.viewpoints())
        other.close()


# ---------------------------------------------------------------------- a furnished room, rendered
def room_scene():
    """An Open3D ``RaycastingScene`` of a furnished 8×6×3 m room with a doorway onto a long corridor.

    Geometry in metres, floor at z = 0: walls 0.2 m thick, a doorway (1 m wide) in the wall at
    x = 8 leading to a 12 m corridor (so some rays get no return within 5 m), a table, two pillars,
    a cabinet and a chair-sized box. Used by the cross-backend agreement tests and the benchmark.
    """
    import open3d as o3d

    boxes = [  # (lo, hi)
        ((-0.2, -0.2, -0.2), (8.2, 6.2, 0.0)),  # floor
        ((-0.2, -0.2, 3.0), (8.2, 6.2, 3.2)),  # ceiling
        ((-0.2, -0.2, 0.0), (0.0, 6.2, 3.0)),  # wall x = 0
        ((-0.2, -0.2, 0.0), (8.2, 0.0, 3.0)),  # wall y = 0
        ((-0.2, 6.0, 0.0), (8.2, 6.2, 3.0)),  # wall y = 6
        ((8.0, -0.2, 0.0), (8.2, 2.5, 3.0)),  # wall x = 8, left of the doorway
        ((8.0, 3.5, 0.0), (8.2, 6.2, 3.0)),  # wall x = 8, right of the doorway
        ((8.0, 2.5, 2.1), (8.2, 3.5, 3.0)),  # lintel
        ((8.2, 2.3, 0.0), (20.2, 2.5, 3.0)),  # corridor walls
        ((8.2, 3.5, 0.0), (20.2, 3.7, 3.0)),
        ((3.0, 1.0, 0.0), (4.6, 1.9, 0.75)),  # table
        ((5.5, 4.2, 0.0), (5.8, 4.5, 3.0)),  # pillars
        ((2.2, 4.6, 0.0), (2.5, 4.9, 3.0)),
        ((6.8, 0.3, 0.0), (7.8, 0.8, 1.8)),  # cabinet
        ((4.2, 3.0, 0.0), (4.7, 3.5, 0.9)),  # chair
    ]
    scene = o3d.t.geometry.RaycastingScene()
    offset = np.array([0.013, 0.031, 0.017])  # keeps surfaces off voxel boundaries (real rooms do)
    for lo, hi in boxes:
        size = np.subtract(hi, lo)
        mesh = o3d.geometry.TriangleMesh.create_box(*size).translate(np.add(lo, offset))
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def render_depth(scene, camera: CameraModel, T_world_cam: np.ndarray) -> np.ndarray:
    """H×W float32 depth (along the optical axis, 0 = no return within the camera's max range)."""
    import open3d as o3d

    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    K = camera.K
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1).reshape(-1, 3)
    d_world = d_cam @ np.asarray(T_world_cam)[:3, :3].T  # unnormalised: t_hit is the optical depth
    origins = np.broadcast_to(np.asarray(T_world_cam)[:3, 3], d_world.shape)
    rays = o3d.core.Tensor(np.hstack([origins, d_world]).astype(np.float32))
    t = scene.cast_rays(rays)["t_hit"].numpy().reshape(camera.height, camera.width)
    rng = t * np.linalg.norm(d_cam, axis=1).reshape(t.shape)
    return np.where(np.isfinite(t) & (rng <= camera.max_range), t, 0.0).astype(np.float32)


#: A pose in :func:`room_scene`: camera 1.3 m high in the room, looking at the far wall and
#: through the doorway down the corridor.
ROOM_POSE = camera_pose((4.0, 1.8, 1.3), np.radians(15.0))
