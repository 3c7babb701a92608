"""The ``octomap`` mapping backend: amslam's :class:`~amslam.interfaces.Mapping` on two OctoMap octrees.

* **Occupancy** lives in OctoMap (see :mod:`.store`): a global tree in the world frame at
  ``global_voxel`` limited to the exploration area plus ``area_margin``, and a local tree in the
  odometry frame at ``local_voxel`` limited to a ``local_size`` window that follows the camera
  (voxels left outside the window are deleted). The occupancy model is OctoMap's own, with its
  defaults (hit 0.7, miss 0.4, threshold 0.5, clamping 0.1192–0.971).
* **Frontiers, viewpoints and paths** reuse amslam's backend-independent helpers as a library:
  :class:`amslam.lib.frontiers.FrontierTracker` (incremental frontier clustering and
  ray-fan viewpoint sampling, paper 1 §VI-A) reads the tree through ``dense_states``, and
  :mod:`amslam.lib.free_space` (robot-radius inflation, 26-connected Dijkstra, line-of-sight
  smoothing) works on a dense state block read from the tree. Both only need voxel states on
  amslam's lattice, which OctoMap's keys share.
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field, model_validator

from amslam.interfaces import BackendParams, Mapping, RunContext
from amslam.lib.free_space import (
    FreeSpaceGraph,
    known_along,
    samples_clear,
    segment_samples,
    smooth_path,
    traversable,
)
from amslam.lib.frontiers import FrontierConfig, FrontierTracker
from amslam.types import BoundingBox, Viewpoint
from amslam_octomap.store import OCCUPIED, OctreeStore, SensorModel

Vec3 = tuple[float, float, float]


class FrontierParams(BackendParams):
    """Frontier clustering and viewpoint sampling (amslam's shared frontier tracker)."""

    min_cluster_size: int = Field(
        4, ge=1, description="Frontier clusters smaller than this (voxels) are ignored."
    )
    max_cluster_extent: float = Field(
        2.5, gt=0, description="Clusters longer than this along their principal axis (m) are split in two."
    )
    viewpoint_radii: tuple[float, ...] = Field(
        (1.0, 1.75, 2.5), description="Distances (m) of candidate viewpoints from a cluster centroid."
    )
    viewpoint_angles: int = Field(12, ge=1, description="Candidate directions around a cluster centroid.")
    viewpoint_heights: tuple[float, ...] = Field(
        (-0.5, 0.0, 0.5), description="Candidate heights (m) relative to the cluster centroid."
    )
    viewpoint_yaws: int = Field(24, ge=1, description="Candidate yaws evaluated at each candidate position.")
    gain_rays_azimuth: int = Field(72, ge=4, description="Azimuths of the ray fan counting information gain.")
    gain_rays_elevation: int = Field(8, ge=1, description="Elevations (over the vertical fov) of that fan.")
    sensing_range: float | None = Field(
        None, gt=0, description="Range (m) of the gain rays; default min(camera max range, max_range) - 0.5."
    )
    min_gain: float = Field(
        0.5, ge=0, description="Viewpoints expecting to see less unknown volume (m³) than this are dropped."
    )
    resample_ratio: float = Field(
        0.5,
        ge=0,
        le=1,
        description="A kept viewpoint whose gain fell below this share of its first is resampled.",
    )


class OctomapParams(BackendParams):
    """Parameters of the ``octomap`` backend."""

    global_voxel: float = Field(0.25, gt=0, description="Resolution of the global (world-frame) octree, m.")
    local_voxel: float = Field(0.1, gt=0, description="Resolution of the local (odometry-frame) octree, m.")
    local_size: Vec3 = Field(
        (10.0, 10.0, 5.0), description="Size (x, y, z) of the local window around the camera, m."
    )
    local_recentre: float = Field(
        1.0, ge=0, description="The local window moves to the camera once it is this far off-centre, m."
    )
    prob_hit: float = Field(
        0.7, gt=0.5, lt=1, description="OctoMap: occupancy probability of a ray's end voxel."
    )
    prob_miss: float = Field(
        0.4, gt=0, lt=0.5, description="OctoMap: occupancy probability of a crossed voxel."
    )
    occupancy_threshold: float = Field(
        0.5, gt=0, lt=1, description="OctoMap: a voxel at or above this probability is OCCUPIED."
    )
    clamping_min: float = Field(0.1192, gt=0, lt=0.5, description="OctoMap: lower clamp of the probability.")
    clamping_max: float = Field(0.971, gt=0.5, lt=1, description="OctoMap: upper clamp of the probability.")
    max_range: float = Field(
        5.0, gt=0, description="Max ray length, m; no-return and farther pixels clear free space up to it."
    )
    stride: int | None = Field(
        None,
        ge=1,
        description="Insert every n-th pixel (both axes); None: the largest stride whose rays are at most "
        "half a voxel apart at max_range, per map.",
    )
    area_margin: float = Field(1.0, ge=0, description="The global tree extends this far beyond the area, m.")
    default_area: tuple[Vec3, Vec3] = Field(
        ((-25.0, -25.0, -1.0), (25.0, 25.0, 6.0)),
        description="Exploration area (lo, hi corners, m) when the run context gives none.",
    )
    tight_penalty: float = Field(
        3.0,
        ge=1.0,
        description="Cost multiplier of path stretches closer to obstacles than radius + clearance.",
    )
    snap_radius: float = Field(
        0.6,
        ge=0,
        description="Path ends off the free graph connect to the nearest free voxel within this, m.",
    )
    frontiers: FrontierParams = Field(
        default_factory=FrontierParams, description="Frontier clustering and viewpoint sampling."
    )

    @model_validator(mode="after")
    def _ordered_probabilities(self) -> OctomapParams:
        if not self.clamping_min < self.occupancy_threshold < self.clamping_max:
            raise ValueError("expected clamping_min < occupancy_threshold < clamping_max")
        return self


def pixel_stride(K: np.ndarray, voxel: float, max_range: float) -> int:
    """Largest pixel stride whose neighbouring rays are at most half a voxel apart at ``max_range``."""
    return max(1, int(0.5 * voxel * float(max(K[0, 0], K[1, 1])) / max_range))


class OctomapMapping(Mapping):
    """Mapping backend on OctoMap octrees (see the module docstring)."""

    Params: ClassVar[type[BackendParams]] = OctomapParams

    def __init__(self) -> None:  # nothing heavy: the trees are built in configure()
        self.params = OctomapParams()
        self.global_map: OctreeStore | None = None
        self.local_map: OctreeStore | None = None
        self.frontiers: FrontierTracker | None = None
        self.area = BoundingBox.nothing()
        self.robot_radius = 0.25
        self.segment_radius = 0.25
        self._local_centre: np.ndarray | None = None
        self._pending = BoundingBox.nothing()
        self._version = 0
        self._graph: tuple[int, FreeSpaceGraph] | None = None

    # ------------------------------------------------------------------ lifecycle
    def configure(self, params: BackendParams, context: RunContext) -> None:
        """Build both octrees and the frontier tracker."""
        if not isinstance(params, OctomapParams):
            raise TypeError(f"expected OctomapParams, got {type(params).__name__}")
        p = self.params = params
        if context.area is not None:
            self.area = context.area
        elif context.world is not None:
            self.area = BoundingBox(np.asarray(context.world.bounds_lo), np.asarray(context.world.bounds_hi))
        else:
            self.area = BoundingBox(np.array(p.default_area[0]), np.array(p.default_area[1]))
        # the same clearance rule as amslam's voxel backends: a hard radius of the robot plus half the
        # tracking margin, and the full planning radius for straight shortcuts
        self.robot_radius = float(context.robot.radius + 0.5 * context.robot.clearance)
        self.segment_radius = float(context.robot.planning_radius)
        sensor = SensorModel(p.prob_hit, p.prob_miss, p.occupancy_threshold, p.clamping_min, p.clamping_max)
        margin = np.full(3, p.area_margin)
        self.global_map = OctreeStore(
            p.global_voxel, sensor, BoundingBox(self.area.lo - margin, self.area.hi + margin)
        )
        self.local_map = OctreeStore(p.local_voxel, sensor, self._window(np.zeros(3)))
        self._local_centre = None
        cam = context.camera
        hfov, vfov = (cam.hfov, cam.vfov) if cam else (np.radians(87.0), np.radians(58.0))
        cam_range = min(cam.max_range if cam else p.max_range, p.max_range)
        f = p.frontiers
        self.frontiers = FrontierTracker(
            FrontierConfig(
                voxel=p.global_voxel,
                area=self.area,
                robot_radius=self.robot_radius,
                hfov=hfov,
                vfov=vfov,
                sensing_range=f.sensing_range or max(cam_range - 0.5, p.global_voxel),
                min_cluster_size=f.min_cluster_size,
                max_extent=f.max_cluster_extent,
                radii=tuple(f.viewpoint_radii),
                n_angles=f.viewpoint_angles,
                heights=tuple(f.viewpoint_heights),
                n_yaws=f.viewpoint_yaws,
                n_rays_azimuth=f.gain_rays_azimuth,
                n_rays_elevation=f.gain_rays_elevation,
                min_gain=f.min_gain,
                resample_ratio=f.resample_ratio,
            )
        )
        self._pending = BoundingBox.nothing()
        self._version = 0
        self._graph = None

    def close(self) -> None:
        """Drop both trees (safe to call twice)."""
        self.global_map = None
        self.local_map = None
        self._graph = None

    def _maps(self) -> tuple[OctreeStore, OctreeStore]:
        if self.global_map is None or self.local_map is None:
            raise RuntimeError("OctomapMapping is not configured (or already closed)")
        return self.global_map, self.local_map

    def _window(self, centre: np.ndarray) -> BoundingBox:
        half = 0.5 * np.asarray(self.params.local_size, dtype=float)
        return BoundingBox(centre - half, centre + half)

    # ------------------------------------------------------------------ updates
    def integrate_global(self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> BoundingBox:
        """Insert a depth image into the global tree (SLAM pose); return the box it touched."""
        g, _ = self._maps()
        p = self.params
        stride = p.stride or pixel_stride(K, p.global_voxel, p.max_range)
        box = g.integrate_depth(depth, K, T_world_cam, stride, p.max_range)
        if not box.empty:
            self._pending = _union(self._pending, box)
            self._version += 1
        return box

    def integrate_local(self, depth: np.ndarray, K: np.ndarray, T_odom_cam: np.ndarray) -> BoundingBox:
        """Insert a depth image into the local tree (VIO pose), moving its window to the camera first."""
        _, loc = self._maps()
        p = self.params
        cam = np.asarray(T_odom_cam, dtype=float)[:3, 3]
        if self._local_centre is None or np.linalg.norm(cam - self._local_centre) > p.local_recentre:
            loc.forget_outside(self._window(cam))
            self._local_centre = cam.copy()
        stride = p.stride or pixel_stride(K, p.local_voxel, p.max_range)
        return loc.integrate_depth(depth, K, T_odom_cam, stride, p.max_range)

    # ------------------------------------------------------------------ queries
    def states(self, points: np.ndarray, *, local: bool = False) -> np.ndarray:
        """int8 VoxelState of the voxels holding ``points`` (N×3); UNKNOWN outside the map."""
        g, loc = self._maps()
        store = loc if local else g
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        return store.states_at_index(np.floor(pts / store.voxel).astype(np.int64))

    def viewpoints(self) -> list[Viewpoint]:
        """Frontier viewpoints after folding in every global update since the last call."""
        g, _ = self._maps()
        if not self._pending.empty:
            self.frontiers.update(g, self._pending)
            self._pending = BoundingBox.nothing()
        return self.frontiers.viewpoints()

    def _free_graph(self) -> FreeSpaceGraph:
        """The free-space graph of the global tree, rebuilt only when the tree changed."""
        if self._graph is not None and self._graph[0] == self._version:
            return self._graph[1]
        g, _ = self._maps()
        lo, hi = g.extent()
        lo, hi = lo - 1, hi + 1
        states = g.dense_states(lo, tuple(int(s) for s in hi - lo))
        passable = traversable(states, self.robot_radius, g.voxel)
        roomy = traversable(states, self.segment_radius, g.voxel)
        graph = FreeSpaceGraph(
            passable,
            lo,
            g.voxel,
            self.params.snap_radius,
            states,
            penalty=np.where(roomy, 1.0, self.params.tight_penalty),
        )
        self._graph = (self._version, graph)
        return graph

    def path_costs(self, sources: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """S×T path lengths (m) through known free space with robot clearance; inf if unreachable."""
        return self._free_graph().costs(sources, targets)

    def plan_path(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Shortest 26-connected path over clear known-free voxels, shortcut-smoothed; or None."""
        g, _ = self._maps()
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        raw = self._free_graph().shortest_path(start, goal)
        if raw is None:
            return None
        ends = np.floor(np.array([start, goal]) / g.voxel).astype(np.int64)

        def line_of_sight(a: np.ndarray, b: np.ndarray) -> bool:
            samples = segment_samples(a, b, 0.5 * g.voxel)
            idx = np.floor(samples / g.voxel).astype(np.int64)
            at_end = np.all(idx == ends[0], axis=1) | np.all(idx == ends[1], axis=1)
            known = known_along(samples, g.voxel, g.states_at_index)
            return bool(np.all(known | at_end)) and self.segment_free(a, b)

        return smooth_path(raw, line_of_sight)

    def segment_free(self, a: np.ndarray, b: np.ndarray, *, local: bool = False) -> bool:
        """No occupied voxel within the robot radius of the segment (unknown counts as free)."""
        g, loc = self._maps()
        store = loc if local else g
        samples = segment_samples(a, b, 0.5 * store.voxel)
        radius = self.robot_radius if local else self.segment_radius
        return samples_clear(samples, radius, store.voxel, store.states_at_index)

    def explored_volume(self) -> float:
        """Known (free or occupied) volume of the global tree in m³ (pruned leaves count whole)."""
        g, _ = self._maps()
        return g.known_volume()

    def _index_box(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Voxel index range ``[a, b)`` of the global voxels whose centres lie inside the box."""
        v = self.params.global_voxel
        a = np.ceil(np.asarray(lo, float) / v - 0.5).astype(np.int64)
        b = np.floor(np.asarray(hi, float) / v - 0.5).astype(np.int64) + 1
        return a, np.maximum(a, b)

    def explored_volume_in(self, lo: np.ndarray, hi: np.ndarray) -> float:
        """Known volume (m³) of global voxels whose centres lie inside the box."""
        g, _ = self._maps()
        return g.known_volume(*self._index_box(lo, hi))

    def free_volume_in(self, lo: np.ndarray, hi: np.ndarray) -> float:
        """Known free volume (m³) of global voxels whose centres lie inside the box."""
        g, _ = self._maps()
        return g.known_volume(*self._index_box(lo, hi), free=True)

    def occupied_points(self) -> np.ndarray:
        """Centres of occupied global voxels (N×3)."""
        g, _ = self._maps()
        idx, st = g.voxels()
        return (idx[st == OCCUPIED] + 0.5) * g.voxel

    def voxel_size(self) -> float:
        """Edge of a global voxel in metres."""
        return float(self.params.global_voxel)

    # ------------------------------------------------------------------ persistence
    def save(self, path: Path) -> None:
        """Write both trees (OctoMap ``.ot`` with log-odds) and the local window to one ``.npz``."""
        g, loc = self._maps()
        centre = self._local_centre if self._local_centre is not None else np.full(3, np.nan)
        np.savez_compressed(
            Path(path),
            format=np.array("amslam-octomap-1"),
            global_ot=np.frombuffer(g.to_bytes(), dtype=np.uint8),
            local_ot=np.frombuffer(loc.to_bytes(), dtype=np.uint8),
            local_centre=centre,
        )

    def load(self, path: Path) -> None:
        """Load trees written by :meth:`save` (same resolutions) and recompute the frontiers."""
        g, loc = self._maps()
        with np.load(Path(path)) as f:
            if str(f["format"]) != "amslam-octomap-1":
                raise ValueError(f"{path}: not a map written by the octomap backend")
            g.from_bytes(f["global_ot"].tobytes())
            loc.from_bytes(f["local_ot"].tobytes())
            centre = f["local_centre"]
        if np.all(np.isfinite(centre)):
            self._local_centre = centre.copy()
            loc.set_limit(self._window(centre))
        self._version += 1
        self._graph = None
        self.frontiers.recompute(g)
        self._pending = BoundingBox.nothing()


def _union(a: BoundingBox, b: BoundingBox) -> BoundingBox:
    if a.empty:
        return b
    if b.empty:
        return a
    return BoundingBox(np.minimum(a.lo, b.lo), np.maximum(a.hi, b.hi))
