"""What behaviours may use, as narrow protocols, and the runtime's implementation of the flight one.

A behaviour receives in ``setup(**services)`` only the services it names (see
:class:`amslam.trees.behaviours.RobotBehaviour`):

==============  ======================  =======================================================
key             protocol                provided by
==============  ======================  =======================================================
``flight``      :class:`Flight`         :class:`Robot`: pose, motion, clock, limits, failsafes
``navigation``  :class:`Navigation`     :class:`Robot`: paths through the maps
``planning``    :class:`Exploring`      :class:`amslam.planning.PlanningService`
``events``      :class:`Events`         :class:`EventSink`: events.jsonl and observer hooks
==============  ======================  =======================================================

All of them are called on the control thread.

:class:`Robot` converts between frames (drift compensation, paper 1 §VI-E): goals live in the
world (SLAM) frame, setpoints in the odometry (VIO) frame, and ``T_world_odom`` from the SLAM
backend maps one into the other at the moment a setpoint is sent; every setpoint passes the
:class:`amslam.setpoints.SetpointFilter` guards on its way to the platform.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from amslam.errors import AmslamError
from amslam.geometry import invert, transform_points, yaw_of
from amslam.interfaces import Mapping, Platform
from amslam.mission import LimitsSection
from amslam.setpoints import SetpointFilter
from amslam.sharing import finished
from amslam.types import CameraModel, Failsafe, LoopClosureResult, Odometry, RobotSpec, TourItem, Viewpoint


class Flight(Protocol):
    """Where the robot is and how to move it."""

    home_world: np.ndarray
    spec: RobotSpec

    @property
    def camera(self) -> CameraModel: ...
    def time(self) -> float: ...
    def odometry(self) -> Odometry: ...
    def position_world(self) -> np.ndarray: ...
    def yaw_world(self) -> float: ...
    def airborne(self) -> bool: ...
    def distance(self) -> float: ...
    def limit_reached(self) -> str | None: ...
    def failsafe(self) -> Failsafe | None: ...
    def send_setpoint_world(self, position: np.ndarray, yaw: float) -> np.ndarray: ...
    def hold(self) -> None: ...
    def takeoff(self) -> None: ...
    def land(self) -> None: ...
    def landing_spot_world(self) -> np.ndarray | None: ...
    def seen_free_below(self) -> float: ...
    def landing_surface_seen(self) -> bool: ...


class PathHandle(Protocol):
    """A path being planned (:meth:`Robot.request_path`); its result is the path or None."""

    def done(self) -> bool: ...
    def cancel(self) -> bool: ...
    def result(self) -> np.ndarray | None: ...


class Navigation(Protocol):
    """Paths through the maps."""

    def request_path(self, goal_world: np.ndarray, *, along_trail: bool = False) -> PathHandle: ...
    def segment_clear_local(self, a_world: np.ndarray, b_world: np.ndarray) -> bool: ...
    def plan_local_path(self, start_world: np.ndarray, goal_world: np.ndarray) -> np.ndarray | None: ...
    def reachable_near(self, goal_world: np.ndarray, within: float = 1.0) -> np.ndarray | None: ...


class PlanHandle(Protocol):
    def done(self) -> bool: ...
    def cancel(self) -> bool: ...
    def result(self) -> list[TourItem]: ...


class LoopClosureHandle(Protocol):
    def done(self) -> bool: ...
    def result(self) -> LoopClosureResult: ...


class Exploring(Protocol):
    """Tours, goal bookkeeping and loop closures (:class:`amslam.planning.PlanningService`)."""

    @property
    def plans_frontiers(self) -> bool: ...
    @property
    def viewpoint_count(self) -> int: ...
    def candidate_viewpoints(self) -> list[Viewpoint]: ...
    def wants_view_near(self, position: np.ndarray, within: float) -> bool: ...
    def frontier_change(self) -> float: ...
    def plan_async(self, cruise_z: float, goal: np.ndarray | None = None) -> PlanHandle: ...
    def mark_visited(self, position: np.ndarray) -> None: ...
    def mark_unreachable(self, position: np.ndarray) -> None: ...
    def request_loop_closure(self, goal: TourItem | None = None) -> LoopClosureHandle: ...


class Events(Protocol):
    """The run's event stream and the plugins' observer hooks."""

    def emit(self, name: str, **fields: Any) -> None: ...
    def plugin_hook(self, name: str, **kwargs: Any) -> None: ...


@dataclass
class EventSink:
    """``emit`` → events.jsonl; ``plugin_hook`` → every plugin's observer (errors contained)."""

    emit_event: Callable[..., None]
    hooks: Callable[..., None] = lambda name, **kwargs: None

    def emit(self, name: str, **fields: Any) -> None:
        self.emit_event(name, **fields)

    def plugin_hook(self, name: str, **kwargs: Any) -> None:
        """Call an observer hook of every plugin (see :mod:`amslam.hookspecs`)."""
        self.hooks(name, **kwargs)


@dataclass
class Robot:
    """The vehicle as the tree flies it: pose in the world frame, guarded setpoints, paths."""

    platform: Platform
    mapping: Mapping
    #: SLAM's correction ``T_world_odom`` now (:meth:`amslam.perception.Perception.T_world_odom`:
    #: on a real vehicle the SLAM thread's latest, never a wait for the graph)
    correction: Callable[[], np.ndarray]
    slam_name: str  # the SLAM backend's, for errors
    spec: RobotSpec
    limits: LimitsSection
    setpoints: SetpointFilter
    odometer: Callable[[], float] = lambda: 0.0  # distance travelled so far (perception's), m
    home_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: the path thread on a real vehicle (the runtime's, which closes it); None: paths at once
    path_thread: Executor | None = None

    # -- state ---------------------------------------------------------------------------------

    @property
    def camera(self) -> CameraModel:
        return self.platform.camera

    def time(self) -> float:
        return self.platform.time()

    def odometry(self) -> Odometry:
        return self.platform.odometry()

    def pose_world(self) -> np.ndarray:
        """Best estimate of ``T_world_body``: the SLAM correction applied to the VIO pose."""
        return self.correction() @ self.platform.odometry().T_odom_body

    def position_world(self) -> np.ndarray:
        return self.pose_world()[:3, 3]

    def yaw_world(self) -> float:
        return yaw_of(self.pose_world())

    def airborne(self) -> bool:
        return self.platform.status().airborne

    def distance(self) -> float:
        """Distance travelled since the start (VIO), m."""
        return self.odometer()

    def failsafe(self) -> Failsafe | None:
        """The platform's failsafe, if any (:meth:`amslam.interfaces.Platform.failsafe`)."""
        return self.platform.failsafe()

    def limit_reached(self) -> str | None:
        """Which mission limit is exhausted, if any."""
        if self.time() >= self.limits.max_time:
            return f"time limit {self.limits.max_time:.0f} s"
        if self.distance() >= self.limits.max_distance:
            return f"distance limit {self.limits.max_distance:.0f} m"
        return None

    # -- motion --------------------------------------------------------------------------------

    def send_setpoint_world(self, position: np.ndarray, yaw: float) -> np.ndarray:
        """Fly towards a world-frame goal, mapped into the odometry frame now (drift compensation).

        Returns the world-frame position actually sent: the guards may have moved it, and a
        behaviour waiting to reach the goal must know when it is as close as they allow.
        """
        T_world_odom = self.correction()
        if not (np.all(np.isfinite(T_world_odom)) and np.all(np.isfinite(position)) and np.isfinite(yaw)):
            # A NaN setpoint would fly the vehicle nowhere the log can say (a simulated run once
            # ended in an SVD error three modules later): hold, and fail the run by name.
            self.hold()
            culprit = (
                f"the SLAM backend {self.slam_name} returned T_world_odom {T_world_odom.tolist()}"
                if not np.all(np.isfinite(T_world_odom))
                else f"a behaviour asked for setpoint {np.asarray(position).tolist()}, yaw {yaw}"
            )
            raise AmslamError(f"non-finite setpoint: {culprit}; holding position")
        T_odom_world = invert(T_world_odom)
        p_odom = transform_points(T_odom_world, np.asarray(position, float)[None])[0]
        yaw_odom = yaw + float(np.arctan2(T_odom_world[1, 0], T_odom_world[0, 0]))
        sent = self.setpoints.apply(
            p_odom, self.platform.odometry().T_odom_body[:3, 3], odom_z=float(T_world_odom[2, 3])
        )
        self.platform.set_setpoint(sent, yaw_odom)
        return transform_points(T_world_odom, sent[None])[0]

    def hold(self) -> None:
        """Keep the current VIO position and heading."""
        T = self.platform.odometry().T_odom_body
        self.platform.set_setpoint(T[:3, 3].copy(), yaw_of(T))

    def takeoff(self) -> None:
        self.platform.arm_and_takeoff(self.spec.altitude)

    def land(self) -> None:
        self.platform.land()

    def landing_spot_world(self) -> np.ndarray | None:
        """Where to land: the nearest point at this height whose straight-down descent the fresh
        local map shows clear, the global map filling in below the local map's reach
        (:meth:`amslam.setpoints.SetpointFilter.landing_spot`), world frame; here when here is
        clear, None when nothing within reach is."""
        here = self.platform.odometry().T_odom_body[:3, 3]
        T_world_odom = self.correction()
        spot = self.setpoints.landing_spot(here, T_world_odom)
        if spot is None:
            return None
        return transform_points(T_world_odom, spot[None])[0]

    def seen_free_below(self) -> float:
        """How far below the robot its descent column has been seen free, m
        (:meth:`amslam.setpoints.SetpointFilter.seen_free_below`)."""
        here = self.platform.odometry().T_odom_body[:3, 3]
        return self.setpoints.seen_free_below(here, self.correction())

    def landing_surface_seen(self) -> bool:
        """Whether the fresh local map shows the surface below the robot, so that a landing is
        judged in the frame it flies in (:meth:`amslam.setpoints.SetpointFilter.surface_seen_locally`)."""
        here = self.platform.odometry().T_odom_body[:3, 3]
        return self.setpoints.surface_seen_locally(here)

    # -- navigation ----------------------------------------------------------------------------

    def request_path(self, goal_world: np.ndarray, *, along_trail: bool = False) -> Future:
        """Waypoints from here to the goal through known free space, or None, as a future;
        ``along_trail``: a path that follows the robot's flown trail where the map has none
        (``Mapping.plan_path_along_trail``, the way home when the map's rules leave no way back).

        On a real vehicle the path is planned on the path thread: a path through the global map
        rebuilds its search graph whenever the map changed (every frame), 0.1-0.4 s that a
        control tick cannot wait (docs/flight.md, late ticks). In the simulator it is planned at
        once and the future is done when returned.
        """
        start, goal = self.position_world(), np.asarray(goal_world, float)
        plan = self.mapping.plan_path_along_trail if along_trail else self.mapping.plan_path
        if self.path_thread is not None:
            return self.path_thread.submit(plan, start, goal)
        return finished(lambda: plan(start, goal))

    def reachable_near(self, goal_world: np.ndarray, within: float = 1.0) -> np.ndarray | None:
        """``goal_world`` if the global map has a path to it from here, else the nearest point
        within ``within`` metres of it that has one, else None.

        A goal whose own voxel the map holds occupied is off the planning graph, and the flight
        map collects such voxels where nothing stands (a demo flight, seed 14, found its take-off
        point's voxel occupied at the end and could not return home).
        """
        here = self.position_world()
        goal = np.asarray(goal_world, float)
        step = 0.25
        axis = np.arange(-within, within + 1e-9, step)
        grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        grid = grid[np.linalg.norm(grid, axis=1) <= within]
        grid = grid[np.argsort(np.linalg.norm(grid, axis=1), kind="stable")]  # the goal itself first
        candidates = goal + grid
        costs = self.mapping.path_costs(here[None], candidates)[0]
        ok = np.flatnonzero(np.isfinite(costs))
        return candidates[ok[0]] if len(ok) else None

    def segment_clear_local(self, a_world: np.ndarray, b_world: np.ndarray) -> bool:
        """Check a world-frame segment against the fresh local (odometry-frame) map."""
        T_odom_world = invert(self.correction())
        a, b = transform_points(T_odom_world, np.stack([a_world, b_world]))
        return self.mapping.segment_free(a, b, local=True)

    #: room around a local path's two ends that it may use, m (a detour round a table or a shelf)
    LOCAL_MARGIN = 1.5

    def plan_local_path(self, start_world: np.ndarray, goal_world: np.ndarray) -> np.ndarray | None:
        """Waypoints (world frame) from ``start_world`` to ``goal_world`` on the fine local map,
        planned in the odometry frame it was built in, or None (see ``Mapping.plan_local_path``)."""
        T_world_odom = self.correction()
        ends = transform_points(invert(T_world_odom), np.stack([start_world, goal_world]))
        path = self.mapping.plan_local_path(ends[0], ends[1], margin=self.LOCAL_MARGIN)
        return None if path is None else transform_points(T_world_odom, np.asarray(path, float))
