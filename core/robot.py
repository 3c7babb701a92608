"""The robot as the behaviour tree sees it: a thin facade over the configured backends.

Behaviours receive one :class:`Robot` in ``setup(robot=...)`` and call it; it owns no algorithm.
It converts between frames (drift compensation, paper 1 §VI-E): goals live in the world (SLAM)
frame, setpoints in the odometry (VIO) frame, and ``T_world_odom`` from the SLAM backend maps one
into the other at the moment a setpoint is sent.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from amslam.errors import AmslamError
from amslam.geometry import invert, transform_points, yaw_of
from amslam.interfaces import Detector, Mapping, Planner, Platform, Slam
from amslam.mission import ExplorationSection, LimitsSection
from amslam.types import (
    LoopClosureResult,
    Odometry,
    PlanRequest,
    RobotSpec,
    SlcCandidate,
    TourItem,
    TourItemKind,
    Viewpoint,
    VoxelState,
)


@dataclass
class Robot:
    """Backends plus the little state the tree needs to query them."""

    platform: Platform
    mapping: Mapping
    slam: Slam
    detector: Detector
    planner: Planner
    spec: RobotSpec
    limits: LimitsSection
    exploration: ExplorationSection
    emit: Callable[..., None]  # emit(event, **fields) → events.jsonl
    hooks: Callable[..., None] = lambda name, **kwargs: None  # observer hooks, errors contained
    distance: float = 0.0
    home_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cruise_z: float = 1.0  # world z the take-off settled at; the return-home height
    viewpoints: list[Viewpoint] = field(default_factory=list)
    unreachable: list[np.ndarray] = field(default_factory=list)
    visited: list[np.ndarray] = field(default_factory=list)
    viewpoints_stale: bool = False  # ask the runner to refresh viewpoints at the next frame
    planned_viewpoints: list[np.ndarray] = field(default_factory=list)
    _executor: ThreadPoolExecutor | None = None
    _guard_grid: np.ndarray | None = None
    slc_log: list[tuple[float, float, LoopClosureResult]] = field(
        default_factory=list
    )  # (t, distance, result)
    slc_offered: dict[int, SlcCandidate] = field(default_factory=dict)  # key pose id → last offer
    slc_tried_at: dict[int, float] = field(default_factory=dict)  # landmark id → distance tried

    def plugin_hook(self, name: str, **kwargs) -> None:
        """Call an observer hook of every plugin (see :mod:`amslam.hookspecs`)."""
        self.hooks(name, **kwargs)

    # -- state ---------------------------------------------------------------------------------

    def time(self) -> float:
        return self.platform.time()

    def odometry(self) -> Odometry:
        return self.platform.odometry()

    def pose_world(self) -> np.ndarray:
        """Best estimate of ``T_world_body``: the SLAM correction applied to the VIO pose."""
        return self.slam.T_world_odom() @ self.platform.odometry().T_odom_body

    def position_world(self) -> np.ndarray:
        return self.pose_world()[:3, 3]

    def yaw_world(self) -> float:
        return yaw_of(self.pose_world())

    def airborne(self) -> bool:
        return self.platform.status().airborne

    def limit_reached(self) -> str | None:
        """Which mission limit is exhausted, if any."""
        if self.time() >= self.limits.max_time:
            return f"time limit {self.limits.max_time:.0f} s"
        if self.distance >= self.limits.max_distance:
            return f"distance limit {self.limits.max_distance:.0f} m"
        return None

    # -- motion --------------------------------------------------------------------------------

    def send_setpoint_world(self, position: np.ndarray, yaw: float) -> np.ndarray:
        """Fly towards a world-frame goal, mapped into the odometry frame now (drift compensation).

        Returns the world-frame position actually sent: the guards below may have moved it, and a
        behaviour waiting to reach the goal must know when it is as close as they allow.
        """
        T_world_odom = self.slam.T_world_odom()
        if not (np.all(np.isfinite(T_world_odom)) and np.all(np.isfinite(position)) and np.isfinite(yaw)):
            # A NaN setpoint would fly the vehicle nowhere the log can say (a simulated run once
            # ended in an SVD error three modules later): hold, and fail the run by name.
            self.hold()
            culprit = (
                f"the SLAM backend {type(self.slam).__name__} returned T_world_odom {T_world_odom.tolist()}"
                if not np.all(np.isfinite(T_world_odom))
                else f"a behaviour asked for setpoint {np.asarray(position).tolist()}, yaw {yaw}"
            )
            raise AmslamError(f"non-finite setpoint: {culprit}; holding position")
        T_odom_world = invert(T_world_odom)
        p_odom = transform_points(T_odom_world, np.asarray(position, float)[None])[0]
        yaw_odom = yaw + float(np.arctan2(T_odom_world[1, 0], T_odom_world[0, 0]))
        sent = self._clearance_guard(self._height_guard(p_odom))
        self.platform.set_setpoint(sent, yaw_odom)
        return transform_points(T_world_odom, sent[None])[0]

    def _height_guard(self, p_odom: np.ndarray) -> np.ndarray:
        """Keep a setpoint inside the floor/ceiling band of the fresh local (odometry-frame) map.

        Goals come from the world-frame map, whose floors and ceilings carry the height error the
        estimate had when they were seen; the local map was built moments ago in the frame the
        vehicle flies in. This is the last line of defence against flying into a slab.
        """
        ex = self.exploration
        offsets = np.arange(0.1, 2.05, 0.1)
        up = np.array([0.0, 0.0, 1.0])
        column = np.concatenate([p_odom - np.outer(offsets, up), p_odom + np.outer(offsets, up)])
        occupied = self.mapping.states(column, local=True) == VoxelState.OCCUPIED
        below, above = occupied[: len(offsets)], occupied[len(offsets) :]
        if not below.any() and not above.any():
            return p_odom
        z = p_odom[2]
        floor = z - offsets[np.argmax(below)] if below.any() else -np.inf
        ceiling = z + offsets[np.argmax(above)] if above.any() else np.inf
        lo, hi = floor + ex.min_height, ceiling - ex.min_headroom
        new_z = 0.5 * (floor + ceiling) if lo > hi else float(np.clip(z, lo, hi))
        return p_odom if new_z == z else np.array([p_odom[0], p_odom[1], new_z])

    #: grid step of the clearance guard's look into the local map: paper 1's local voxel, m
    GUARD_STEP = 0.1
    #: distance kept from occupied local voxels beyond the robot radius, m: the local map's VIO
    #: drift since a surface was seen eats into it (demo seed 1 lost 0.055 m over a slab with 0.05)
    GUARD_MARGIN = 0.1
    #: how far around the vehicle the clearance guard looks, m: the largest kept distance (radius,
    #: margin, one voxel) plus a braking distance (1 m/s at 1.5 m/s² stops in 0.33 m), so that a
    #: surface enters the look before the vehicle can reach it
    GUARD_LOOK = 0.8

    def _clearance_guard(self, setpoint: np.ndarray) -> np.ndarray:
        """Move a setpoint so that the straight flight to it keeps clear of the fresh local map.

        Paths are laid on the coarse world map: 0.25 m voxels carrying the pose error of when each
        wall was seen, so a door can be 0.1–0.2 m narrower or offset from what the vehicle meets,
        and a path checked against it can graze the frame. The local map was built moments ago in
        the frame the vehicle flies in. Each occupied local voxel near the vehicle bounds a
        half-space: its tangent plane towards the vehicle, pushed out by the safe distance. The
        setpoint is projected into their intersection (a few rounds of projection onto the most
        violated one); the vehicle is inside it too (or the constraint moves the setpoint away),
        so the straight flight between them stays inside: a convex safe flight corridor (Liu et
        al., RA-L 2017), rebuilt every tick. Opposite door jambs give opposite half-spaces, which
        centre the vehicle in the opening. No maintained library filters a position setpoint
        against a voxel map, hence by hand.
        """
        here = self.platform.odometry().T_odom_body[:3, 3]
        samples = here + self._guard_offsets()
        occupied = samples[self.mapping.states(samples, local=True) == VoxelState.OCCUPIED]
        if not len(occupied):
            return setpoint
        away = here - occupied
        dist = np.maximum(np.linalg.norm(away, axis=1), 1e-6)
        normals = away / dist[:, None]
        # A sample can lie up to one voxel deeper than the face of the voxel it fell in.
        need = self.spec.radius + self.GUARD_MARGIN + self.GUARD_STEP - dist  # normals · step ≥ need
        step = np.asarray(setpoint, float) - here
        for _ in range(12):
            slack = normals @ step - need
            worst = int(np.argmin(slack))
            if slack[worst] >= -1e-3:
                break
            step = step - slack[worst] * normals[worst]
        return here + step

    def _guard_offsets(self) -> np.ndarray:
        if self._guard_grid is None:
            k = int(np.ceil(self.GUARD_LOOK / self.GUARD_STEP))
            axis = np.arange(-k, k + 1) * self.GUARD_STEP
            grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
            radius = np.linalg.norm(grid, axis=1)
            self._guard_grid = grid[(radius > 0) & (radius <= self.GUARD_LOOK)]
        return self._guard_grid

    def hold(self) -> None:
        """Keep the current VIO position and heading."""
        T = self.platform.odometry().T_odom_body
        self.platform.set_setpoint(T[:3, 3].copy(), yaw_of(T))

    def takeoff(self) -> None:
        self.platform.arm_and_takeoff(self.spec.altitude)

    def land(self) -> None:
        self.platform.land()

    def plan_path(self, goal_world: np.ndarray) -> np.ndarray | None:
        """Waypoints from here to the goal through known free space, or None."""
        return self.mapping.plan_path(self.position_world(), np.asarray(goal_world, float))

    def segment_clear_local(self, a_world: np.ndarray, b_world: np.ndarray) -> bool:
        """Check a world-frame segment against the fresh local (odometry-frame) map."""
        T_odom_world = invert(self.slam.T_world_odom())
        a, b = transform_points(T_odom_world, np.stack([a_world, b_world]))
        return self.mapping.segment_free(a, b, local=True)

    # -- planning ------------------------------------------------------------------------------

    def mark_unreachable(self, position: np.ndarray) -> None:
        self.unreachable.append(np.asarray(position, float))
        self.viewpoints_stale = True

    def mark_visited(self, position: np.ndarray) -> None:
        """We looked from here: a viewpoint resampled to the same place cannot show more."""
        self.visited.append(np.asarray(position, float))
        self.viewpoints_stale = True

    def set_viewpoints(self, viewpoints: list[Viewpoint]) -> None:
        """Take the mapping backend's fresh viewpoints, each moved into the safe height band."""
        self.viewpoints = [self._within_band(vp) for vp in viewpoints]

    def _within_band(self, vp: Viewpoint) -> Viewpoint:
        """Move a viewpoint vertically into the band between floor and ceiling the tree flies in.

        The coarse map allows any height with a robot radius of clearance, but odometry drifts
        most in z: a goal a radius above the floor or below the ceiling is a crash waiting for
        a few centimetres of drift. Floor and ceiling are the nearest occupied voxels below and
        above in the global map.
        """
        ex = self.exploration
        step = self.mapping.voxel_size()
        offsets = np.arange(step, 3.0 + step, step)
        column = np.concatenate(
            [vp.position + np.outer(-offsets, [0, 0, 1]), vp.position + np.outer(offsets, [0, 0, 1])]
        )
        occupied = self.mapping.states(column) == VoxelState.OCCUPIED
        below, above = occupied[: len(offsets)], occupied[len(offsets) :]
        z = vp.position[2]
        floor = z - offsets[np.argmax(below)] if below.any() else -np.inf
        ceiling = z + offsets[np.argmax(above)] if above.any() else np.inf
        lo, hi = floor + ex.min_height, ceiling - ex.min_headroom
        if lo > hi:
            return vp  # a low gap: leave it to the path planner's clearance
        new_z = float(np.clip(z, lo, hi))
        if new_z == z:
            return vp
        return dataclasses.replace(vp, position=np.array([vp.position[0], vp.position[1], new_z]))

    def candidate_viewpoints(self) -> list[Viewpoint]:
        """Viewpoints worth visiting: enough gain, not known to be unreachable, at a safe height."""
        out = []
        for vp in self.viewpoints:
            if vp.gain < self.exploration.min_viewpoint_gain:
                continue
            if any(np.linalg.norm(vp.position - u) < 0.75 for u in self.unreachable):
                continue
            if any(np.linalg.norm(vp.position - u) < 0.5 for u in self.visited):
                continue
            out.append(vp)
        return out

    @property
    def plans_frontiers(self) -> bool:
        """Whether the planner tours frontier viewpoints (False: views of known objects, PAMS)."""
        return self.planner.needs_frontiers

    def frontier_change(self) -> float:
        """Share of viewpoints that appeared or vanished (by position) since the last plan."""
        now = [vp.position for vp in self.candidate_viewpoints()]
        then = self.planned_viewpoints
        if not now and not then:
            return 0.0
        if not now or not then:
            return 1.0
        d = np.linalg.norm(np.asarray(now)[:, None] - np.asarray(then)[None], axis=2)
        kept = min(int((d.min(axis=1) < 1.0).sum()), int((d.min(axis=0) < 1.0).sum()))
        return 1.0 - kept / max(len(now), len(then))

    def plan_async(self) -> Future:
        """Plan off the control loop; the future holds the tour (or the planner's exception).

        With a simulated platform the plan is made at once, so simulated time does not pass while
        it computes and runs stay deterministic; on a real vehicle a worker thread computes it
        while the tree keeps ticking.
        """
        if self.platform.simulated:
            future: Future = Future()
            try:
                future.set_result(self.plan())
            except Exception as exc:  # delivered through the future, like the threaded path
                future.set_exception(exc)
            return future
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="amslam-planner")
        return self._executor.submit(self.plan)

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)

    def plan(self) -> list[TourItem]:
        """Ask the planner for a tour over the current viewpoints (and SLC candidates)."""
        # A planner of views of known objects (PAMS) never reads the frontier viewpoints; their
        # all-pairs path costs (one Dijkstra per viewpoint over the whole free-space graph, which
        # with plan_through_unknown spans the mission area) were 90 % of such a run's time.
        vps = self.candidate_viewpoints() if self.planner.needs_frontiers else []
        self.planned_viewpoints = [vp.position for vp in vps]
        if not vps and self.planner.needs_frontiers:
            return []
        start = self.position_world()
        nodes = np.vstack([start[None], np.array([v.position for v in vps]).reshape(-1, 3)])
        costs = self.mapping.path_costs(nodes, nodes) if vps else np.zeros((1, 1))
        slc_candidates: tuple = ()
        slc_costs = np.zeros((0, len(nodes)))
        if self.exploration.slc:
            cands = [
                # A key pose from the take-off climb is still a fine place to look from, in the air.
                dataclasses.replace(
                    c, position=np.array([*c.position[:2], max(c.position[2], self.cruise_z)])
                )
                for c in self.slam.slc_candidates(self.exploration.slc_sensing_range)
                if self._slc_due(c)
            ]
            self.slc_offered = {c.keypose_id: c for c in cands}
            if cands:
                slc_candidates = tuple(cands)
                slc_costs = self.mapping.path_costs(np.array([c.position for c in cands]), nodes)
        request = PlanRequest(
            start=start,
            start_yaw=self.yaw_world(),
            viewpoints=tuple(vps),
            costs=costs,
            camera=self.platform.camera,
            slc_candidates=slc_candidates,
            slc_costs=slc_costs,
            landmarks=tuple(self.slam.landmarks()),
        )
        return self.planner.plan(request)

    # -- semantic loop closure -----------------------------------------------------------------

    def _slc_due(self, candidate: SlcCandidate) -> bool:
        """Offer a cluster only after enough travel since the last SLC attempt anywhere, and not
        the same landmarks again until as much travel again: revisits trade exploration time for
        accuracy, and pay only once drift has built up."""
        wait = self.exploration.slc_min_travel
        last = max((d for _, d, _ in self.slc_log), default=0.0)
        if self.distance - last < wait:
            return False
        return all(self.distance - self.slc_tried_at.get(i, -np.inf) >= wait for i in candidate.landmark_ids)

    def attempt_loop_closure(self, goal: TourItem | None = None) -> LoopClosureResult:
        """Try an SLC with what the detector saw most recently (e.g. during a panorama).

        The runner fed every detection to SLAM at the pose of its own frame as it came in, so
        nothing is seen *now* that SLAM does not have: the call hands over no detections and the
        backend registers the panorama from what it was fed (see :meth:`Slam.try_loop_closure`).
        """
        is_slc = goal is not None and goal.kind == TourItemKind.SLC
        candidate = self.slc_offered.get(goal.ref) if is_slc else None
        if candidate is not None:
            for i in candidate.landmark_ids:
                self.slc_tried_at[i] = self.distance
        odom = self.platform.odometry()
        result = self.slam.try_loop_closure(odom, self.platform.camera.T_body_cam, [])
        self.slc_log.append((self.time(), self.distance, result))
        return result
