"""The planning service: tours from perception snapshots, the SLC schedule and goal bookkeeping.

The service's state (visited and unreachable goals, the viewpoints of the last plan, the SLC
offers and attempts) belongs to the control thread: the behaviour tree reads and writes it there.
A plan is made from a :class:`PlanInputs`, frozen copies taken on the control thread when the
plan is asked for (:meth:`PlanningService.plan_async`); the planner thread reads only those, the
planner, and the SLAM and mapping backends through their :class:`amslam.sharing.Shared` locks.
What a plan decided (its viewpoints, the SLC candidates it offered) comes back inside the
:class:`Plan` and is adopted on the control thread when the tree takes the tour
(:meth:`PlanJob.result`). With a simulated platform the plan is made at once on the control
thread, so simulated time does not pass while it computes and runs stay deterministic.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from amslam.boundary import BackendError, BackendOutputError, Boundary
from amslam.errors import AmslamError
from amslam.interfaces import Mapping as MappingBackend
from amslam.interfaces import Planner, Slam
from amslam.mission import ExplorationSection
from amslam.perception import Snapshot
from amslam.sharing import finished
from amslam.types import (
    CameraModel,
    LoopClosureResult,
    PlanRequest,
    SlcCandidate,
    TourItem,
    TourItemKind,
    Viewpoint,
)

#: a viewpoint or loop-closure place this near (m) to where a goal was given up is not offered again
UNREACHABLE_RADIUS = 0.75


@dataclass(frozen=True)
class SlcSchedule:
    """When a cluster of landmarks may be offered for a loop closure (a pure function of travel).

    A cluster is offered only after ``min_travel`` metres since the last SLC attempt anywhere,
    and not the same landmarks again until as much travel again: revisits trade exploration time
    for accuracy, and pay only once drift has built up.
    """

    distance: float  # travelled now
    last_attempt: float  # travelled at the last attempt anywhere (0 before any)
    tried_at: Mapping[int, float]  # landmark id → travelled when last tried
    min_travel: float

    def due(self, candidate: SlcCandidate) -> bool:
        if self.distance - self.last_attempt < self.min_travel:
            return False
        return all(
            self.distance - self.tried_at.get(i, -np.inf) >= self.min_travel for i in candidate.landmark_ids
        )


@dataclass(frozen=True)
class PlanInputs:
    """Everything a plan is made from besides the backends: copies, fixed when it was asked for."""

    snapshot: Snapshot
    viewpoints: tuple[Viewpoint, ...]  # the candidates: gain enough, not visited, not unreachable
    slc: SlcSchedule | None  # None: SLC off
    cruise_z: float  # the height SLC viewpoints are lifted to at least
    unreachable: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # goals given up there
    goal: np.ndarray | None = None  # the exploration goal flown to and not reached (PlanRequest.goal)


@dataclass(frozen=True)
class Plan:
    """A tour and what it was planned over."""

    tour: list[TourItem]
    viewpoints: tuple[np.ndarray, ...]
    slc_offered: Mapping[int, SlcCandidate]


class PlanJob:
    """A plan being made; :meth:`result` hands over the tour and adopts the plan's bookkeeping."""

    def __init__(self, future: Future, service: PlanningService, requested_at: float):
        self._future = future
        self._service = service
        self.requested_at = requested_at  # the time of the snapshot it plans from

    def done(self) -> bool:
        return self._future.done()

    def cancel(self) -> bool:
        return self._future.cancel()

    def result(self) -> list[TourItem]:
        """The tour (or the planner's exception); call on the control thread.

        The service counts failures in a row (:attr:`PlanningService.failures`) and keeps a
        broken contract (:attr:`PlanningService.fault`): the runner ends the run on either.
        """
        service = self._service
        try:
            plan: Plan = self._future.result()
        except BackendOutputError as exc:
            service.fault = exc
            raise
        except Exception as exc:
            service.failures += 1
            label = service.boundary.label("planner")
            if isinstance(exc, BackendError):
                service.last_error = str(exc)
            elif isinstance(exc, AmslamError):
                service.last_error = f"{label}: {exc}"
            else:
                service.last_error = f"{label}: {type(exc).__name__}: {exc}"
            raise
        service.failures = 0
        service._adopt(plan)
        if service.clock is not None:
            service.plan_latency.append(service.clock() - self.requested_at)
        return plan.tour


class LoopClosureJob:
    """A loop-closure attempt queued behind what perception handed SLAM; :meth:`result` logs it
    (``PlanningService.slc_log``) the first time it is read, on the control thread."""

    def __init__(self, future: Future, service: PlanningService, t: float, distance: float):
        self._future, self._service = future, service
        self._t, self._distance = t, distance
        self._logged = False

    def done(self) -> bool:
        return self._future.done()

    def result(self) -> LoopClosureResult:
        """The backend's answer (waiting for it if need be), or its exception."""
        result = self._future.result()
        if not self._logged:
            self._logged = True
            self._service.slc_log.append((self._t, self._distance, result))
        return result


@dataclass
class PlanningService:
    """Plans tours from snapshots; owns the goal bookkeeping and the SLC schedule."""

    planner: Planner
    slam: Slam  # shared with the control thread: pass a Shared wrapper when threaded
    mapping: MappingBackend  # likewise
    exploration: ExplorationSection
    camera: CameraModel
    threaded: bool  # plan on the planner thread (a real vehicle) rather than at once
    refresh_viewpoints: Callable[[], None] = lambda: None  # ask perception for fresh viewpoints
    #: queues SLAM calls behind everything perception handed SLAM (perception's SLAM thread): a
    #: future of the call's result
    slam_jobs: Callable[[Callable[[], Any]], Future] = finished
    snapshot: Snapshot | None = None  # the latest, published by the runner each tick
    unreachable: list[np.ndarray] = field(default_factory=list)
    visited: list[np.ndarray] = field(default_factory=list)
    planned_viewpoints: tuple[np.ndarray, ...] = ()
    slc_offered: Mapping[int, SlcCandidate] = field(default_factory=dict)  # key pose id → last offer
    slc_tried_at: dict[int, float] = field(default_factory=dict)  # landmark id → distance tried
    slc_log: list[tuple[float, float, LoopClosureResult]] = field(
        default_factory=list
    )  # (t, distance, result)
    boundary: Boundary = field(default_factory=Boundary)  # checks the planner's tours, names it
    failures: int = 0  # plans that failed in a row
    last_error: str = ""  # why the last one failed
    fault: BackendOutputError | None = None  # the planner broke its contract: the run ends
    #: the platform's clock when threaded: each adopted plan's latency (s from the snapshot it was
    #: planned from to its adoption) goes to ``plan_latency``
    clock: Callable[[], float] | None = None
    plan_latency: list[float] = field(default_factory=list)
    _executor: ThreadPoolExecutor | None = None
    _loop_closures: list[LoopClosureJob] = field(default_factory=list)  # not yet logged

    def observe(self, snapshot: Snapshot) -> None:
        self.snapshot = snapshot
        if self._loop_closures:  # attempts whose behaviour stopped waiting still reach the log
            for job in [j for j in self._loop_closures if j.done()]:
                self._loop_closures.remove(job)
                with contextlib.suppress(Exception):  # the behaviour that waited reports errors
                    job.result()

    # -- goal bookkeeping (control thread) -----------------------------------------------------

    @property
    def plans_frontiers(self) -> bool:
        """Whether the planner tours frontier viewpoints (False: views of known objects, PAMS)."""
        return self.planner.needs_frontiers

    @property
    def viewpoint_count(self) -> int:
        return len(self.snapshot.viewpoints) if self.snapshot else 0

    def mark_unreachable(self, position: np.ndarray) -> None:
        self.unreachable.append(np.asarray(position, float).copy())
        self.refresh_viewpoints()

    def mark_visited(self, position: np.ndarray) -> None:
        """We looked from here: a viewpoint resampled to the same place cannot show more."""
        self.visited.append(np.asarray(position, float).copy())
        self.refresh_viewpoints()

    def candidate_viewpoints(self) -> list[Viewpoint]:
        """Viewpoints worth visiting: enough gain, not known to be unreachable, not visited.

        Each cluster's viewpoint and its alternatives are judged alike; the first that passes
        stands for the cluster, carrying the others that pass as its alternatives.
        """
        vps = self.snapshot.viewpoints if self.snapshot else ()
        options = [vp.options() for vp in vps]
        flat = [o for opts in options for o in opts]
        if not flat:
            return []
        ok = self._worth_visiting(flat)  # every option at once: this runs at every tick of a GoTo
        out, k = [], 0
        for opts in options:
            kept = [o for o, good in zip(opts, ok[k : k + len(opts)], strict=True) if good]
            k += len(opts)
            if kept:
                out.append(dataclasses.replace(kept[0], alternatives=tuple(kept[1:])))
        return out

    def _worth_visiting(self, vps: list[Viewpoint]) -> np.ndarray:
        """Which viewpoints have enough gain and are not :meth:`_done_with`."""
        ok = np.array([vp.gain >= self.exploration.min_viewpoint_gain for vp in vps])
        return ok & ~self._done_with(np.array([vp.position for vp in vps]))

    def _done_with(self, positions: np.ndarray) -> np.ndarray:
        """Which positions (N×3) are near a goal found unreachable (``UNREACHABLE_RADIUS``) or
        one visited (0.5 m)."""
        done = np.zeros(len(positions), bool)
        for near, within in ((self.unreachable, UNREACHABLE_RADIUS), (self.visited, 0.5)):
            if near:
                d = np.linalg.norm(positions[:, None] - np.asarray(near)[None], axis=2)
                done |= np.any(d < within, axis=1)
        return done

    def wants_view_near(self, position: np.ndarray, within: float) -> bool:
        """Whether some candidate viewpoint, or an alternative of one, lies within ``within`` m."""
        pos = [o.position for vp in self.candidate_viewpoints() for o in vp.options()]
        return bool(pos) and bool(np.any(np.linalg.norm(np.asarray(pos) - position, axis=1) < within))

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

    # -- planning ------------------------------------------------------------------------------

    def inputs(self, cruise_z: float, goal: np.ndarray | None = None) -> PlanInputs:
        """The frozen inputs of a plan asked for now. ``goal``, the exploration goal the robot was
        flying to, becomes :attr:`PlanRequest.goal` unless the robot arrived there (visited) or
        gave it up (unreachable)."""
        ex = self.exploration
        slc = None
        if ex.slc:
            last = max((d for _, d, _ in self.slc_log), default=0.0)
            tried = MappingProxyType(dict(self.slc_tried_at))
            slc = SlcSchedule(self.snapshot.distance, last, tried, ex.slc_min_travel)
        # A planner of views of known objects (PAMS) never reads the frontier viewpoints; their
        # all-pairs path costs (one Dijkstra per viewpoint over the whole free-space graph, which
        # with plan_through_unknown spans the mission area) were 90 % of such a run's time.
        viewpoints = tuple(self.candidate_viewpoints()) if self.plans_frontiers else ()
        unreachable = np.array(self.unreachable, float).reshape(-1, 3)
        if goal is not None:
            goal = np.asarray(goal, float).copy()
            goal = None if self._done_with(goal[None])[0] else goal
        return PlanInputs(self.snapshot, viewpoints, slc, cruise_z, unreachable, goal)

    def plan_async(self, cruise_z: float, goal: np.ndarray | None = None) -> PlanJob:
        """Plan from the latest snapshot; the job holds the tour (or the planner's exception).
        ``goal``: the exploration goal the robot was flying to (:meth:`inputs`)."""
        inputs = self.inputs(cruise_z, goal)
        if not self.threaded:
            return PlanJob(finished(lambda: self.plan(inputs)), self, inputs.snapshot.t)
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="amslam-planner")
        return PlanJob(self._executor.submit(self.plan, inputs), self, inputs.snapshot.t)

    def plan(self, inputs: PlanInputs) -> Plan:
        """Ask the planner for a tour over the inputs' viewpoints (and SLC candidates).

        Runs on the planner thread when threaded: it reads ``inputs``, the planner, and the SLAM
        and mapping backends (through their locks), and writes nothing of the service.
        """
        vps = inputs.viewpoints
        planned = tuple(vp.position for vp in vps)
        if not vps and self.plans_frontiers:
            return Plan([], planned, MappingProxyType({}))
        start = inputs.snapshot.position_world
        offered = self._slc_candidates(inputs) if inputs.slc is not None else ()
        vps, costs, slc_costs = self._tour_costs(start, vps, offered)
        slc_gain = self.slam.slc_gain_model([c.keypose_id for c in offered]) if offered else None
        request = PlanRequest(
            start=start,
            start_yaw=inputs.snapshot.yaw_world,
            viewpoints=vps,
            costs=costs,
            camera=self.camera,
            slc_candidates=offered,
            slc_costs=slc_costs,
            slc_gain=slc_gain,
            landmarks=tuple(self.slam.landmarks()),
            pose_uncertainty=self.slam.pose_uncertainty() if self.planner.needs_pose_uncertainty else None,
            goal=inputs.goal,
        )
        with self.boundary.calling("planner", "plan()"):
            tour = self.boundary.tour(self.planner.plan(request), request, self.plans_frontiers)
        return Plan(tour, planned, MappingProxyType({c.keypose_id: c for c in offered}))

    def _tour_costs(
        self, start: np.ndarray, vps: tuple[Viewpoint, ...], offered: tuple[SlcCandidate, ...]
    ) -> tuple[tuple[Viewpoint, ...], np.ndarray, np.ndarray]:
        """The viewpoints to plan over (each, or its best alternative with a path from ``start``
        when it has none) and the request's path-cost matrices.

        The robot's row and column both come from one search out of the robot, to every option and
        candidate. Asked as a target, the robot's own position is no node when the map shows it
        inside an occupied voxel (a surface SLAM moved after it was integrated); only a path that
        starts there may leave it (:meth:`Mapping.path_costs`). The tour closure keeps the larger
        of a pair's two directions, so an all-pairs query with the robot among the targets made
        every viewpoint unreachable: demo seed 3 found such a phantom wall at home after a loop
        closure and ended "no reachable frontier left" at 56 % explored.
        """
        options = [vp.options() for vp in vps]
        flat = [o.position for opts in options for o in opts] + [c.position for c in offered]
        from_robot = (
            self.mapping.path_costs(start[None], np.array(flat).reshape(-1, 3))[0] if flat else np.zeros(0)
        )
        chosen, row, k = [], [], 0
        for opts in options:
            reach = from_robot[k : k + len(opts)]
            k += len(opts)
            i = int(np.argmax(np.isfinite(reach)))  # the first reachable option; else the viewpoint
            chosen.append(opts[i])  # a cluster none of whose options is reachable stays out of the tour
            row.append(reach[i])
        to_candidates = from_robot[k:]
        vps = tuple(chosen)
        n = len(vps)
        costs = np.zeros((n + 1, n + 1))
        if n:
            positions = np.array([v.position for v in vps])
            costs[1:, 1:] = self.mapping.path_costs(positions, positions)
            costs[0, 1:] = costs[1:, 0] = row
        slc_costs = np.zeros((len(offered), n + 1))
        if offered:
            slc_costs[:, 0] = to_candidates
            if n:
                slc_costs[:, 1:] = self.mapping.path_costs(np.array([c.position for c in offered]), positions)
        return vps, costs, slc_costs

    def _slc_candidates(self, inputs: PlanInputs) -> tuple[SlcCandidate, ...]:
        """The SLAM backend's loop-closure candidates the schedule allows now, lifted to the
        cruise height (a key pose from the take-off climb is still a fine place to look from, in
        the air), minus those at a place a goal was found unreachable (as viewpoints are):
        offered again, an unreachable one came back at every replan — one-floor seed 10 gave it
        up eight times in 0.7 s and exploration stopped at 77 % ("8 goals in a row
        unreachable")."""
        lifted = (
            dataclasses.replace(c, position=np.array([*c.position[:2], max(c.position[2], inputs.cruise_z)]))
            for c in self.slam.slc_candidates(self.exploration.slc_sensing_range)
            if inputs.slc.due(c)
        )
        return tuple(
            c
            for c in lifted
            if not np.any(np.linalg.norm(inputs.unreachable - c.position, axis=1) < UNREACHABLE_RADIUS)
        )

    def _adopt(self, plan: Plan) -> None:
        self.planned_viewpoints = plan.viewpoints
        if self.exploration.slc:
            self.slc_offered = plan.slc_offered

    # -- semantic loop closure (control thread) ------------------------------------------------

    def request_loop_closure(self, goal: TourItem | None = None) -> LoopClosureJob:
        """Try an SLC with what the detector saw most recently (e.g. during a panorama).

        Perception fed every detection to SLAM at the pose of its own frame as it came in, so
        nothing is seen *now* that SLAM does not have: the call hands over no detections and the
        backend registers the panorama from what it was fed (see :meth:`Slam.try_loop_closure`).
        On a real vehicle the attempt waits on the SLAM thread behind those detections (and an
        uncertainty sample's marginals, a quarter of a second late in a long flight) while the
        control thread ticks on; in the simulator the job is done when returned.
        """
        now = self.snapshot
        candidate = (
            self.slc_offered.get(goal.ref) if goal is not None and goal.kind == TourItemKind.SLC else None
        )
        if candidate is not None:
            for i in candidate.landmark_ids:
                self.slc_tried_at[i] = now.distance
        future = self.slam_jobs(lambda: self.slam.try_loop_closure(now.odometry, self.camera.T_body_cam, []))
        job = LoopClosureJob(future, self, now.t, now.distance)
        self._loop_closures.append(job)
        return job

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
