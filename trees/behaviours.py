"""The stock behaviour-tree leaves of an exploration mission.

Each leaf is thin: its constructor takes configuration only; ``setup(**services)`` hands it the
runtime services it names in ``uses`` (narrow protocols, see :mod:`amslam.robot`: ``flight``,
``navigation``, ``planning``, ``events``); ``initialise`` starts work, ``update`` polls and
returns quickly, ``terminate`` cancels. Retries, stalls and limits are decorators around the
leaves, not counters inside them: ``Retry`` around :class:`Replan`, the :class:`WithinLimits`
eternal guard around the exploration loop, :class:`amslam.trees.decorators.GiveUpGoal` (no
progress, the way blocked) around :class:`GoTo`, :class:`amslam.trees.decorators.SkipUnreachable`
around the next stop. Blackboard keys are registered with their access so each leaf's inputs and
outputs are explicit:

==================  ========================================================================
key                 meaning
==================  ========================================================================
``/tour``           list[TourItem] — the refined tour of the latest plan (world frame)
``/goal``           TourItem | None — the stop being flown to (None: nothing left to explore)
``/tour_time``      float — when ``/tour`` was planned
``/cruise_z``       float — world height the take-off settled at; the return-home height
``/exploration``    str — "exploring", or why exploration ended
``/slc``            dict — the latest loop-closure attempt
==================  ========================================================================
"""

from __future__ import annotations

import dataclasses

import numpy as np
import py_trees
from py_trees.common import Access, Status
from py_trees.composites import Sequence
from py_trees.decorators import EternalGuard, FailureIsSuccess

from amslam.geometry import wrap_angle
from amslam.mission import ExplorationSection
from amslam.robot import Events, Exploring, Flight, Navigation, PathHandle, PlanHandle
from amslam.trees.decorators import PathProgress
from amslam.trees.services import require_services
from amslam.types import TourItem, TourItemKind

#: the exploration section's defaults, for leaves built without a mission (tests, other trees)
DEFAULTS = ExplorationSection()


class RobotBehaviour(py_trees.behaviour.Behaviour):
    """Base: receives the services named in ``uses`` in ``setup`` and refuses to run without them."""

    #: the runtime services this leaf calls (keys of ``setup``)
    uses: tuple[str, ...] = ("flight", "events")
    flight: Flight
    navigation: Navigation
    planning: Exploring
    events: Events

    def __init__(self, name: str):
        super().__init__(name)
        self.bb = self.attach_blackboard_client(name=name)

    def setup(self, **kwargs) -> None:
        require_services(self, self.uses, kwargs)


def cruise_height(bb: py_trees.blackboard.Client, flight: Flight) -> float:
    """The height take-off settled at, or the planned one before (or without) a take-off."""
    return (
        bb.get("/cruise_z") if bb.exists("/cruise_z") else float(flight.home_world[2] + flight.spec.altitude)
    )


class TakeOff(RobotBehaviour):
    """Arm and climb to the mission altitude (idempotent); SUCCESS once the climb has settled."""

    uses = ("flight",)

    def __init__(self, name: str = "TakeOff"):
        super().__init__(name)
        self.bb.register_key("/cruise_z", access=Access.WRITE)

    def initialise(self) -> None:
        self.flight.takeoff()
        self.last_z = self.flight.odometry().T_odom_body[2, 3]
        self.feedback_message = "climbing"

    def update(self) -> Status:
        z = self.flight.odometry().T_odom_body[2, 3]
        rising, self.last_z = z - self.last_z, z
        climbed = z - self.flight.home_world[2]
        # The platform owns the meaning of "altitude" (PX4: above home); settle on its answer.
        # "Settled": rising less than 1 cm per tick — a real hover is never still to the millimetre.
        if self.flight.airborne() and climbed > 0.5 * self.flight.spec.altitude and abs(rising) < 0.01:
            self.bb.set("/cruise_z", float(z))
            self.feedback_message = f"at {z:.2f} m"
            return Status.SUCCESS
        return Status.RUNNING


class WithinLimits(EternalGuard):
    """Tick the child while mission time and distance remain; FAILURE (with the reason) once not.

    An eternal guard: the limits are checked before every tick of the child, and a child cut
    short is stopped (a flight leaf's ``terminate`` holds position).
    """

    uses = ("flight", "events")
    flight: Flight
    events: Events

    def __init__(self, name: str = "WithinLimits", child: py_trees.behaviour.Behaviour | None = None):
        if child is None:
            raise ValueError(f"{name}: WithinLimits guards a child: WithinLimits(name, child)")
        super().__init__(name=name, child=child, condition=self._within_limits)
        self.blackboard.register_key("/exploration", access=Access.WRITE)

    def setup(self, **kwargs) -> None:
        require_services(self, self.uses, kwargs)

    def _within_limits(self) -> bool:
        reason = self.flight.limit_reached()
        if reason:
            self.feedback_message = reason
            self.blackboard.set("/exploration", f"stopped: {reason}")
            # the run's log says when and why the mission was cut short (the guard fires once:
            # its parent moves on to the return home)
            self.events.emit("limit_reached", reason=reason, behaviour=self.decorated.name)
            return False
        return True


class Replan(RobotBehaviour):
    """Keep following the refined tour, or ask the planner for a new one (paper 1 §VI-B).

    Each loop iteration first drops the stop just handled from ``/tour``. The planner is asked
    again when the tour is used up, when ``replan_fraction`` of it has been executed (receding
    horizon), when ``frontier_change`` of the viewpoints changed since it was planned, or when it
    is older than ``replan_period``; otherwise the next stop becomes ``/goal`` at once. Planning
    runs off the control loop on a real vehicle (:meth:`PlanningService.plan_async`); the robot
    holds until the tour is ready. A planner exception is FAILURE (the ``Retry`` decorator around
    this leaf asks again, up to ``max_replan_failures`` times in a row). When nothing reachable is
    left to explore, ``/goal`` becomes None and ``/exploration`` says so.
    """

    uses = ("flight", "planning", "events")

    def __init__(
        self,
        name: str = "Replan",
        replan_fraction: float = DEFAULTS.replan_fraction,
        replan_period: float = DEFAULTS.replan_period,
        frontier_change: float = DEFAULTS.frontier_change,
    ):
        super().__init__(name)
        self.replan_fraction = replan_fraction
        self.replan_period = replan_period
        self.frontier_change = frontier_change
        for key in ("/tour", "/goal", "/tour_time", "/tour_planned", "/exploration"):
            self.bb.register_key(key, access=Access.WRITE)
        self.bb.register_key("/cruise_z", access=Access.READ)
        self.job: PlanHandle | None = None

    def setup(self, **kwargs) -> None:
        super().setup(**kwargs)
        self.bb.set("/exploration", "exploring")
        self.bb.set("/tour", [])
        self.bb.set("/goal", None)
        self.bb.set("/tour_time", -np.inf)
        self.bb.set("/tour_planned", 0)

    def _replan_reason(self, tour: list[TourItem]) -> str | None:
        if not tour:
            return "tour done" if self.bb.get("/tour_planned") else "no tour yet"
        planned = max(self.bb.get("/tour_planned"), 1)
        if (planned - len(tour)) / planned >= self.replan_fraction:
            return "receding horizon"
        if self.flight.time() - self.bb.get("/tour_time") > self.replan_period:
            return "tour stale"
        # A planner of views of known objects (PAMS) does not care how the frontiers moved.
        if self.planning.plans_frontiers and self.planning.frontier_change() >= self.frontier_change:
            return "frontiers changed"
        return None

    def initialise(self) -> None:
        tour: list[TourItem] = list(self.bb.get("/tour"))
        goal = self.bb.get("/goal")
        if tour and goal is not None and tour[0] is goal:
            tour = tour[1:]  # the stop the last iteration handled
            self.bb.set("/tour", tour)
        self.reason = self._replan_reason(tour)
        if self.reason:
            cruise = cruise_height(self.bb, self.flight)
            # The exploration goal the robot was flying to; the planning service, which GoTo told
            # of arrivals (mark_visited) and give-ups, hands it on only if neither happened.
            explore = goal is not None and goal.kind == TourItemKind.EXPLORE
            self.job = self.planning.plan_async(cruise, goal=goal.position if explore else None)
        else:
            self.job = None

    def update(self) -> Status:
        if self.job is None:
            tour = self.bb.get("/tour")
            self.bb.set("/goal", tour[0])
            self.feedback_message = f"following the tour: {len(tour)} stops left"
            return Status.SUCCESS
        if not self.job.done():
            self.flight.hold()
            self.feedback_message = f"planning ({self.reason})"
            return Status.RUNNING
        try:
            tour = self.job.result()
        except Exception as exc:  # the Retry decorator around this leaf asks again
            self.events.emit("planner_error", error=f"{type(exc).__name__}: {exc}")
            self.flight.hold()
            self.bb.set("/exploration", f"stopped: the planner failed ({type(exc).__name__}: {exc})")
            self.feedback_message = f"planner failed: {exc}"
            return Status.FAILURE
        self.bb.set("/exploration", "exploring")
        reachable = [item for item in tour if np.all(np.isfinite(item.position))]
        if not reachable:
            self.bb.set("/exploration", "complete: no reachable frontier left")
            self.bb.set("/tour", [])
            self.bb.set("/goal", None)
            self.feedback_message = "nothing left to explore"
            return Status.SUCCESS
        return self._adopt(reachable)

    def _adopt(self, tour: list[TourItem]) -> Status:
        self.bb.set("/tour", tour)
        self.bb.set("/goal", tour[0])
        self.bb.set("/tour_time", self.flight.time())
        self.bb.set("/tour_planned", len(tour))
        self.events.emit(
            "replan",
            reason=self.reason,
            tour=[[item.kind.value, *np.round(item.position, 2).tolist()] for item in tour],
            viewpoints=self.planning.viewpoint_count,
        )
        self.events.plugin_hook("amslam_replan", t=self.flight.time(), tour=tour, reason=self.reason)
        self.feedback_message = f"{len(tour)} stops, next {tour[0].kind.value}"
        return Status.SUCCESS

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and self.job is not None:
            self.job.cancel()


class HasGoal(py_trees.behaviour.Behaviour):
    """SUCCESS while ``/goal`` holds a stop; FAILURE once the planner left none (exploration done)."""

    def __init__(self, name: str = "HasGoal"):
        super().__init__(name)
        self.bb = self.attach_blackboard_client(name=name)
        self.bb.register_key("/goal", access=Access.READ)

    def update(self) -> Status:
        if self.bb.get("/goal") is None:
            self.feedback_message = "nothing left to explore"
            return Status.FAILURE
        return Status.SUCCESS


class IsGoalKind(py_trees.behaviour.Behaviour):
    """SUCCESS when the current goal is of the given kind (explore or SLC)."""

    def __init__(self, name: str, kind: TourItemKind):
        super().__init__(name)
        self.kind = kind
        self.bb = self.attach_blackboard_client(name=name)
        self.bb.register_key("/goal", access=Access.READ)

    def update(self) -> Status:
        goal: TourItem | None = self.bb.get("/goal")
        return Status.SUCCESS if goal is not None and goal.kind == self.kind else Status.FAILURE


class GoTo(RobotBehaviour):
    """Fly to the goal along a path through known free space, facing the direction of travel.

    SUCCESS on arrival (heading turned to the goal's yaw), or, with ``early_exit``, early when an
    exploration goal's frontier was seen on the way or the tour is older than ``replan_period``;
    FAILURE when no path exists (the goal is marked unreachable); with ``follow_trail`` (the way
    home) a goal the map has no path to is flown to along the robot's own trail where the map's
    rules leave no way. When the local map shows the way
    blocked, or the guards hold the robot where it is, it takes a detour on the local map or plans
    a new path and flies on. When to give the goal up (no progress, blocked too
    often) is the :class:`amslam.trees.decorators.GiveUpGoal` decorator's decision: the leaf
    reports its :meth:`progress` and gives up on request (:meth:`give_up`). Trees build it with
    :func:`go_to`, which puts it under that decorator.
    """

    uses = ("flight", "navigation", "planning", "events")

    def __init__(
        self,
        name: str,
        goal_key: str = "/goal",
        early_exit: bool = True,
        goal_tolerance: float = DEFAULTS.goal_tolerance,
        yaw_tolerance: float = DEFAULTS.yaw_tolerance,
        replan_period: float = DEFAULTS.replan_period,
        follow_trail: bool = False,
    ):
        super().__init__(name)
        self.goal_key = goal_key
        self.early_exit = early_exit
        self.follow_trail = follow_trail
        self.goal_tolerance = goal_tolerance
        self.yaw_tolerance = yaw_tolerance
        self.replan_period = replan_period
        self.bb.register_key(goal_key, access=Access.READ)
        self.bb.register_key("/tour_time", access=Access.READ)
        self.path: np.ndarray | None = None
        self.index = 0
        self.arrived = False

    def initialise(self) -> None:
        self.goal: TourItem = self.bb.get(self.goal_key)
        self.arrived = False
        self.replanned = 0
        self._path_job: PathHandle | None = None
        self._plan()
        self.sent: tuple[int, np.ndarray | None] = (-1, None)  # (waypoint, where the guards sent it)
        self.held_since: float | None = None  # when the guards began to hold the robot where it is

    def _plan(self, along_trail: bool = False) -> None:
        """Ask for a path to the goal (``along_trail``: one along the flown trail). On a real
        vehicle it is planned beside the control loop and the robot holds meanwhile; in the
        simulator it is there at once."""
        self.path = None
        self._along_trail = along_trail
        self._path_job = self.navigation.request_path(self.goal.position, along_trail=along_trail)
        self._take_path()

    def _take_path(self) -> bool:
        """Adopt the requested path once it is planned; False while it is still being planned."""
        job = self._path_job
        if job is None:
            return True
        if not job.done():
            return False
        self._path_job = None
        self.path = job.result()
        if self.path is None and self.follow_trail and not self._along_trail:
            # no way through the map: the way the robot came (the second request, at once in
            # the simulator; on a real vehicle the robot holds while it is planned)
            self._plan(along_trail=True)
            return self._path_job is None
        if self.path is not None and self._along_trail:
            self.events.emit(
                "path_along_trail",
                goal=np.round(self.goal.position, 2).tolist(),
                waypoints=len(self.path),
                behaviour=self.name,
            )
        self.index = self.first_index = 1 if self.path is not None and len(self.path) > 1 else 0
        return True

    def progress(self, here: np.ndarray) -> PathProgress:
        """How far it got (for :class:`GiveUpGoal`): paths replanned, waypoints passed, distance left
        to the current waypoint from ``here``."""
        if self.path is None:
            return PathProgress(self.replanned, 0, np.inf)
        distance = float(np.linalg.norm(self.path[self.index] - here))
        return PathProgress(self.replanned, self.index - self.first_index, distance)

    def give_up(self, why: str) -> None:
        """The goal is unreachable: tell the planning service and the run, hold position."""
        self.planning.mark_unreachable(self.goal.position)
        self.events.emit(
            "unreachable", goal=np.round(self.goal.position, 2).tolist(), why=why, behaviour=self.name
        )
        self.flight.hold()
        self.feedback_message = why

    #: how far ahead along the path the fresh local map is checked, m
    LOOKAHEAD = 1.5
    WAYPOINT_TOLERANCE = 0.15
    SKIP_NEAR = 0.3
    #: a viewpoint this close to the goal (m) means the goal's frontier is still there
    SAME_GOAL = 1.0

    def _done(self, why: str) -> Status:
        self.feedback_message = why
        self.events.emit(
            "goal_done", goal=np.round(self.goal.position, 2).tolist(), why=why, behaviour=self.name
        )
        return Status.SUCCESS

    def _fail(self, why: str) -> Status:
        self.give_up(why)
        return Status.FAILURE

    #: how far the guards may hold the robot off a waypoint for it still to count as reached, m
    HELD_OFF = 0.6

    def _held_off(self, here: np.ndarray) -> bool:
        """At the setpoint the guards made of the current waypoint, which they keep away from it.

        The height guard keeps the robot below a ceiling or above a floor that the local map shows
        nearer than the global map did, and the clearance guard off walls: that setpoint is as close
        as the robot may come, so waiting for the waypoint itself would stall the goal.
        """
        index, sent = self.sent
        if index != self.index or sent is None:
            return False
        moved = float(np.linalg.norm(sent - self.path[self.index]))
        return self.WAYPOINT_TOLERANCE <= moved <= self.HELD_OFF and (
            float(np.linalg.norm(sent - here)) < self.WAYPOINT_TOLERANCE
        )

    def _frontier_gone_or_stale(self) -> str | None:
        """Why an exploration goal is not worth finishing (early exit), or None."""
        if not (self.early_exit and self.goal.kind == TourItemKind.EXPLORE and self.planning.plans_frontiers):
            return None
        # Clusters are re-made as the map grows, so their ids change; the goal is still
        # worth reaching while some viewpoint remains near it.
        if not self.planning.wants_view_near(self.goal.position, self.SAME_GOAL):
            return "frontier seen on the way"
        if self.flight.time() - self.bb.get("/tour_time") > self.replan_period:
            return "tour stale: replan"
        return None

    def update(self) -> Status:
        if not self._take_path():
            self.flight.hold()
            self.feedback_message = "planning a path"
            return Status.RUNNING
        if self.path is None:
            return self._fail("no path through known free space")
        here = self.flight.position_world()
        if why := self._frontier_gone_or_stale():
            return self._done(why)
        # Intermediate waypoints are passed tightly: cutting a corner near a door frame is how
        # a drone hits it.
        while self.index < len(self.path) - 1 and (
            np.linalg.norm(self.path[self.index] - here) < self.WAYPOINT_TOLERANCE or self._held_off(here)
        ):
            self.index += 1
        target = self.path[self.index]
        if self.index == len(self.path) - 1 and (
            np.linalg.norm(target - here) < self.goal_tolerance or self._held_off(here)
        ):
            return self._arrive(target)
        return self._fly(here, target)

    def _arrive(self, target: np.ndarray) -> Status:
        """At the goal: turn to its heading, then SUCCESS."""
        err = abs(wrap_angle(self.goal.yaw - self.flight.yaw_world()))
        self.flight.send_setpoint_world(target, self.goal.yaw)
        if err < self.yaw_tolerance:
            if self.goal.kind == TourItemKind.EXPLORE:
                self.planning.mark_visited(self.goal.position)
            self.arrived = True
            return self._done("arrived")
        self.feedback_message = "turning to the viewpoint heading"
        return Status.RUNNING

    def _fly(self, here: np.ndarray, target: np.ndarray) -> Status:
        """Towards the current waypoint, facing it, while the local map shows the way clear."""
        to_target = target - here
        length = max(float(np.linalg.norm(to_target)), 1e-9)
        ahead = here + to_target * min(1.0, self.LOOKAHEAD / length)
        # Skip the first stretch: what is already within it cannot be avoided by stopping, and a
        # robot hovering near furniture must still be able to fly away from it.
        near = here + to_target * min(1.0, self.SKIP_NEAR / length)
        if length > self.SKIP_NEAR and not self.navigation.segment_clear_local(near, ahead):
            return self._blocked(here, f"blocked near {np.round(ahead, 2).tolist()}")
        horizontal = np.linalg.norm(to_target[:2])
        heading = float(np.arctan2(to_target[1], to_target[0])) if horizontal > 0.3 else self.goal.yaw
        yaw_err = abs(wrap_angle(heading - self.flight.yaw_world()))
        # Turn before moving when the way ahead is outside the camera's view: never fly blind.
        if yaw_err > self.flight.camera.hfov / 3:
            self.flight.send_setpoint_world(here, heading)
            self.feedback_message = "turning towards the path"
        else:
            sent = self.flight.send_setpoint_world(target, heading)
            self.sent = (self.index, sent)
            self.feedback_message = f"waypoint {self.index}/{len(self.path) - 1}"
            if self._held_in_place(here, sent, length):
                return self._blocked(here, "held in place by the clearance guards")
        return Status.RUNNING

    #: the guards hold the robot in place when what they send is this close to it (m) while the
    #: waypoint is farther than SKIP_NEAR, for HOLD_PATIENCE seconds of the run's clock
    HELD_STILL = 0.05
    HOLD_PATIENCE = 1.0

    def _held_in_place(self, here: np.ndarray, sent: np.ndarray | None, length: float) -> bool:
        """The guards send the robot where it already is, and have for ``HOLD_PATIENCE`` s.

        The clearance guard projects the step into the corridor the local map leaves around the
        robot; near a slab edge and a wall (the top of the demo's shaft) the long straight step
        towards a far waypoint projects to nothing, and the robot hovered until the goal was given
        up for lack of progress, goal after goal on the same first leg (demo seed 1 with box
        landmarks: 300 s). Held like that, the way is blocked as surely as when the local map
        shows it: the leaf takes a detour on the fine local map, which goes round (up, then on).
        """
        if sent is None or length <= self.SKIP_NEAR or float(np.linalg.norm(sent - here)) > self.HELD_STILL:
            self.held_since = None
            return False
        now = self.flight.time()
        if self.held_since is None:
            self.held_since = now
        if now - self.held_since < self.HOLD_PATIENCE:
            return False
        self.held_since = None
        return True

    def _blocked(self, here: np.ndarray, why: str) -> Status:
        """The way on is blocked: a detour on the local map, else a new path (counted as a replan,
        which :class:`GiveUpGoal` limits)."""
        self.replanned += 1
        if self._detour(here):
            self.feedback_message = f"{why}: detour on the local map"
            return Status.RUNNING
        self._plan()
        self.feedback_message = f"{why}: new path"
        if self.path is None and self._path_job is None:
            return self._fail(f"{why}, no other path")
        if self._path_job is not None:
            self.flight.hold()  # the old path runs into what blocks it
        return Status.RUNNING

    #: how far along the path a detour rejoins it, m: past what blocks the way, inside the local map
    DETOUR_REJOIN = 2.5

    def _detour(self, here: np.ndarray) -> bool:
        """Replace the path's next stretch by a way round what blocks it, planned on the fine local
        map from here to the point ``DETOUR_REJOIN`` metres on along the path (paper 1 plans
        trajectories on the local map; the global map, 0.25 m voxels carrying old pose errors,
        misses table legs, chair backs and shelf edges that the local map shows). False when the
        local map has no such way: the caller plans a new global path."""
        ahead = np.vstack([here[None], self.path[self.index :]])
        legs = np.linalg.norm(np.diff(ahead, axis=0), axis=1)
        along = np.concatenate([[0.0], np.cumsum(legs)])
        if along[-1] <= self.SKIP_NEAR:
            return False
        k = int(np.searchsorted(along, min(self.DETOUR_REJOIN, along[-1]), side="left"))
        k = max(k, 1)
        t = (min(self.DETOUR_REJOIN, along[-1]) - along[k - 1]) / max(legs[k - 1], 1e-9)
        rejoin = ahead[k - 1] + np.clip(t, 0.0, 1.0) * (ahead[k] - ahead[k - 1])
        local = self.navigation.plan_local_path(here, rejoin)
        if local is None or len(local) < 2:
            return False
        rest = ahead[k + 1 :] if np.linalg.norm(rejoin - ahead[k]) < 1e-6 else ahead[k:]
        self.path = np.vstack([local, rest])
        self.index = self.first_index = 1
        self.events.emit(
            "detour",
            at=np.round(here, 2).tolist(),
            rejoin=np.round(rejoin, 2).tolist(),
            waypoints=len(local),
            behaviour=self.name,
        )
        return True

    def terminate(self, new_status: Status) -> None:
        if getattr(self, "_path_job", None) is not None:  # a path no one will fly
            self._path_job.cancel()
            self._path_job = None
        if new_status == Status.INVALID and getattr(self, "flight", None) is not None:
            self.flight.hold()


def go_to(behaviours: dict, name: str, **options) -> py_trees.behaviour.Behaviour:
    """The registered ``GoTo`` leaf named ``name`` (``options`` to its constructor) under the
    registered ``GiveUpGoal`` decorator: how every stock tree flies to a goal."""
    return behaviours["GiveUpGoal"](f"{name}OrGiveUp", behaviours["GoTo"](name, **options))


def return_home(
    behaviours: dict, ex: ExplorationSection = DEFAULTS, then: tuple[py_trees.behaviour.Behaviour, ...] = ()
) -> py_trees.behaviour.Behaviour:
    """``ReturnHome`` (failure is success): SetHomeGoal → GoHome [→ ``then``], how every stock tree
    comes back before it lands; a home out of reach lands the robot where it is."""
    b = behaviours
    home = go_to(
        b,
        "GoHome",
        goal_key="/home",
        early_exit=False,
        goal_tolerance=ex.goal_tolerance,
        yaw_tolerance=ex.yaw_tolerance,
        replan_period=ex.replan_period,
        follow_trail=True,
    )
    steps = Sequence("GoHomeSteps", memory=True, children=[b["SetHomeGoal"]("SetHomeGoal"), home, *then])
    return FailureIsSuccess("ReturnHome", steps)


class Panorama(RobotBehaviour):
    """Yaw a full circle in place in ``steps`` headings; the detector sees around meanwhile."""

    uses = ("flight",)

    def __init__(self, name: str = "Panorama", steps: int = 8, yaw_tolerance: float = DEFAULTS.yaw_tolerance):
        super().__init__(name)
        self.steps = steps
        self.yaw_tolerance = yaw_tolerance

    def initialise(self) -> None:
        self.center = self.flight.position_world().copy()
        self.start_yaw = self.flight.yaw_world()
        self.step = 1

    def update(self) -> Status:
        target = wrap_angle(self.start_yaw + 2 * np.pi * self.step / self.steps)
        self.flight.send_setpoint_world(self.center, target)
        if abs(wrap_angle(target - self.flight.yaw_world())) < self.yaw_tolerance:
            self.step += 1
            if self.step > self.steps:
                self.feedback_message = "full circle"
                return Status.SUCCESS
        self.feedback_message = f"heading {self.step}/{self.steps}"
        return Status.RUNNING


class AttemptLoopClosure(RobotBehaviour):
    """Ask SLAM for a semantic loop closure with what the panorama saw; SUCCESS once it answered.

    On a real vehicle the attempt waits on the SLAM thread behind the detections handed over
    before it: the vehicle holds meanwhile (RUNNING), the control loop ticking on time.
    """

    uses = ("flight", "planning", "events")

    def __init__(self, name: str = "AttemptSLC"):
        super().__init__(name)
        self.bb.register_key("/slc", access=Access.WRITE)
        self.bb.register_key("/goal", access=Access.READ)
        self._job = None

    def initialise(self) -> None:
        self._job = None

    def update(self) -> Status:
        if self._job is None:
            self._job = self.planning.request_loop_closure(self.bb.get("/goal"))
        if not self._job.done():
            self.flight.hold()
            self.feedback_message = "waiting for SLAM"
            return Status.RUNNING
        job, self._job = self._job, None
        result = job.result()
        self.bb.set("/slc", {"accepted": result.accepted, "reason": result.reason, "matched": result.matched})
        self.events.emit("loop_closure", **dataclasses.asdict(result), distance=self.flight.distance())
        self.events.plugin_hook("amslam_loop_closure", t=self.flight.time(), result=result)
        self.feedback_message = ("accepted: " if result.accepted else "rejected: ") + result.reason
        return Status.SUCCESS


class SetHome(RobotBehaviour):
    """Write the return-home goal: the take-off point at the height the take-off settled at, or
    the nearest point to it the map has a path to (``Navigation.reachable_near``: the map may
    hold the take-off point's own voxel occupied by the end of a flight)."""

    uses = ("flight", "navigation", "events")

    def __init__(self, name: str = "SetHomeGoal"):
        super().__init__(name)
        self.bb.register_key("/home", access=Access.WRITE)
        self.bb.register_key("/cruise_z", access=Access.READ)

    def update(self) -> Status:
        home = np.array([*self.flight.home_world[:2], cruise_height(self.bb, self.flight)])
        near = self.navigation.reachable_near(home)
        if near is not None and np.linalg.norm(near - home) > 1e-6:
            self.events.emit(
                "home_moved",
                home=np.round(home, 2).tolist(),
                to=np.round(near, 2).tolist(),
                behaviour=self.name,
            )
            home = near
        self.bb.set("/home", TourItem(TourItemKind.EXPLORE, home, self.flight.yaw_world(), 0.0, -1))
        return Status.SUCCESS


class Land(RobotBehaviour):
    """Descend and disarm, first moving to a spot whose descent is clear (idempotent).

    Platforms land straight down. Where the fresh local map shows something near the column
    below (a table edge, a window sill), the robot first flies to the nearest point at its height
    whose column is clear (``Flight.landing_spot_world``): a turtlebot3 house flight that could
    not find its way home landed in place beside a piece of furniture and touched it at 0.72 m.
    When the maps do not reach the surface below (a PAMS survey ends 6 m over the lot and maps 5 m
    deep: every survey's landing went unchecked, one onto clutter), the robot first steps down
    through the part of its column it has seen free (``Flight.seen_free_below``), turns half round
    there so the camera sees all of the column, and judges again. A column judged on the global
    map alone (its surface out of the local map's reach) is stepped down through the same way
    before the vehicle lands, so that the last judgement is the local map's, in the frame it flies
    in now (``Flight.landing_surface_seen``). When nothing within reach is clear it lands where
    it is and says so.
    """

    uses = ("flight", "events")
    #: close enough to the landing spot (or a step's end) to go on, m
    ARRIVED = 0.1
    #: the move to the landing spot or a step down gives up (and goes on) after this long, s
    MOVE_TIMEOUT = 20.0
    #: a step down ends this far above the part of the column not seen free, m (the guard's
    #: radius-sized look plus a voxel: the unseen part may begin with a surface)
    STEP_MARGIN = 0.6
    #: the least step down worth taking, m
    STEP_MIN = 0.8
    #: the hover after a step, turning half round, before the column is judged again, s: a camera
    #: pitched down sees only the half of the column ahead of it (after a survey's step to 1.9 m,
    #: 6 of the 9 cells around the column behind it were unknown and the landing went unchecked)
    LOOK = 4.0
    #: steps down before landing unchecked
    MAX_STEPS = 4

    def __init__(self, name: str = "Land"):
        super().__init__(name)
        self.spot: np.ndarray | None = None
        self.phase: str | None = None  # "move" to a spot, "step" down, "look" round after a step
        self.started = 0.0
        self.yaw = 0.0  # the heading a look starts from
        self.steps = 0

    def initialise(self) -> None:
        self.spot, self.phase, self.steps = None, None, 0
        if self.flight.airborne():
            self._judge()

    def _judge(self) -> None:
        """Where to go from here: to a clear spot, a step down, or straight down (``land``)."""
        spot = self.flight.landing_spot_world()
        here = self.flight.position_world()
        if spot is None:
            if self._step_down("no clear descent column judged from here"):
                return
            self.events.emit(
                "landing_unchecked", why="no clear descent column within reach", behaviour=self.name
            )
        elif np.linalg.norm(spot - here) > self.ARRIVED:
            self.spot, self.phase, self.started = spot, "move", self.flight.time()
            self.events.emit(
                "landing_spot",
                spot=np.round(spot, 2).tolist(),
                moved=round(float(np.linalg.norm(spot - here)), 2),
            )
            return
        elif self._step_down_to_see():
            return
        self.spot, self.phase = None, None
        self.flight.land()

    def _step_down_to_see(self) -> bool:
        """Step down when the local map does not show the surface close below (its window does
        not reach under it): the column was judged on the global map, built in the estimate's
        frame of minutes ago, which may place it off by more than the footprint (a survey landed
        half off the lot's ground slab whose edge its global map put 0.3 m further out), or at
        the local window's bottom, where a void past an edge is out of sight."""
        if self.flight.landing_surface_seen():
            return False
        return self._step_down("the surface below not seen close in the local map")

    def _step_down(self, why: str) -> bool:
        """Descend through the part of the column seen free, less ``STEP_MARGIN``, if that is
        ``STEP_MIN`` or more and fewer than ``MAX_STEPS`` steps were taken; whether it does."""
        depth = self.flight.seen_free_below()
        if self.steps >= self.MAX_STEPS or depth - self.STEP_MARGIN < self.STEP_MIN:
            return False
        self.steps += 1
        here = self.flight.position_world()
        target = here - np.array([0.0, 0.0, depth - self.STEP_MARGIN])
        self.spot, self.phase, self.started = target, "step", self.flight.time()
        self.events.emit(
            "landing_step_down",
            height=round(float(here[2]), 2),
            to=round(float(target[2]), 2),
            why=f"{why}; the column seen free {depth:.1f} m down",
        )
        return True

    def update(self) -> Status:
        if self.phase == "look":
            turned = (self.flight.time() - self.started) / self.LOOK
            if turned < 1.0:
                self.flight.send_setpoint_world(self.spot, self.yaw + np.pi * turned)
                self.feedback_message = "looking round below before landing"
                return Status.RUNNING
            self._judge()
            if self.phase is not None:
                return Status.RUNNING
        if self.phase in ("move", "step"):
            arrived = np.linalg.norm(self.flight.position_world() - self.spot) <= self.ARRIVED
            if not arrived and self.flight.time() - self.started < self.MOVE_TIMEOUT:
                self.flight.send_setpoint_world(self.spot, self.flight.yaw_world())
                self.feedback_message = (
                    "moving to a clear landing spot"
                    if self.phase == "move"
                    else "stepping down through seen-free space"
                )
                return Status.RUNNING
            if self.phase == "step":
                self.spot, self.yaw = self.flight.position_world(), self.flight.yaw_world()
                self.phase, self.started = "look", self.flight.time()
                return Status.RUNNING
            if self._step_down_to_see():
                return Status.RUNNING
            self.spot, self.phase = None, None
            self.flight.land()
        if self.flight.airborne():
            self.feedback_message = "descending"
            return Status.RUNNING
        self.feedback_message = "landed"
        return Status.SUCCESS
