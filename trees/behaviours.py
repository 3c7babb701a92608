"""The stock behaviour-tree leaves of an exploration mission.

Each leaf is thin: its constructor takes configuration only, ``setup(robot=...)`` receives the
:class:`amslam.robot.Robot` facade, ``initialise`` starts work, ``update`` polls and returns quickly,
``terminate`` cancels. Blackboard keys are registered with their access so each leaf's inputs and
outputs are explicit:

==================  ========================================================================
key                 meaning
==================  ========================================================================
``/tour``           list[TourItem] — the refined tour of the latest plan (world frame)
``/goal``           TourItem | None — the stop being flown to
``/tour_time``      float — when ``/tour`` was planned
``/exploration``    str — "exploring", or why exploration ended
``/replan_failures`` int — consecutive planner failures
``/unreachable``    int — consecutive unreachable goals
``/slc``            dict — the latest loop-closure attempt
==================  ========================================================================
"""

from __future__ import annotations

import dataclasses

import numpy as np
import py_trees
from py_trees.common import Access, Status

import amslam
from amslam.geometry import wrap_angle
from amslam.types import TourItem, TourItemKind


class RobotBehaviour(py_trees.behaviour.Behaviour):
    """Base: receives the robot in ``setup`` and refuses to run without it."""

    def __init__(self, name: str):
        super().__init__(name)
        self.robot = None
        self.bb = self.attach_blackboard_client(name=name)

    def setup(self, **kwargs) -> None:
        robot = kwargs.get("robot")
        if robot is None:
            raise KeyError(f"behaviour {self.name!r} needs setup(robot=...): the runner's Robot facade")
        self.robot = robot


class TakeOff(RobotBehaviour):
    """Arm and climb to the mission altitude (idempotent); SUCCESS once the climb has settled."""

    def initialise(self) -> None:
        self.robot.takeoff()
        self.last_z = self.robot.odometry().T_odom_body[2, 3]
        self.feedback_message = "climbing"

    def update(self) -> Status:
        z = self.robot.odometry().T_odom_body[2, 3]
        rising, self.last_z = z - self.last_z, z
        climbed = z - self.robot.home_world[2]
        # The platform owns the meaning of "altitude" (PX4: above home); settle on its answer.
        # "Settled": rising less than 1 cm per tick — a real hover is never still to the millimetre.
        if self.robot.airborne() and climbed > 0.5 * self.robot.spec.altitude and abs(rising) < 0.01:
            self.robot.cruise_z = z
            self.feedback_message = f"at {z:.2f} m"
            return Status.SUCCESS
        return Status.RUNNING


class WithinLimits(RobotBehaviour):
    """SUCCESS while mission time and distance remain; FAILURE (with the reason) when exhausted."""

    def __init__(self, name: str = "WithinLimits"):
        super().__init__(name)
        self.bb.register_key("/exploration", access=Access.WRITE)

    def update(self) -> Status:
        reason = self.robot.limit_reached()
        if reason:
            self.feedback_message = reason
            self.bb.set("/exploration", f"stopped: {reason}")
            return Status.FAILURE
        return Status.SUCCESS


class Replan(RobotBehaviour):
    """Keep following the refined tour, or ask the planner for a new one (paper 1 §VI-B).

    Each loop iteration first drops the stop just handled from ``/tour``. The planner is asked
    again when the tour is used up, when ``replan_fraction`` of it has been executed (receding
    horizon), when ``frontier_change`` of the viewpoints changed since it was planned, or when it
    is older than ``replan_period``; otherwise the next stop becomes ``/goal`` at once. Planning
    runs off the control loop (see :meth:`Robot.plan_async`); the robot holds until the tour is
    ready. A planner exception is counted, not raised: after ``max_replan_failures`` consecutive
    failures exploration gives up, so a broken planner cannot livelock the robot. FAILURE also when
    nothing reachable is left to explore.
    """

    def __init__(self, name: str = "Replan"):
        super().__init__(name)
        for key in ("/tour", "/goal", "/tour_time", "/tour_planned", "/exploration", "/replan_failures"):
            self.bb.register_key(key, access=Access.WRITE)
        self.future = None

    def setup(self, **kwargs) -> None:
        super().setup(**kwargs)
        self.bb.set("/replan_failures", 0)
        self.bb.set("/exploration", "exploring")
        self.bb.set("/tour", [])
        self.bb.set("/goal", None)
        self.bb.set("/tour_time", -np.inf)
        self.bb.set("/tour_planned", 0)

    def _replan_reason(self, tour: list[TourItem]) -> str | None:
        ex = self.robot.exploration
        if not tour:
            return "tour done" if self.bb.get("/tour_planned") else "no tour yet"
        planned = max(self.bb.get("/tour_planned"), 1)
        if (planned - len(tour)) / planned >= ex.replan_fraction:
            return "receding horizon"
        if self.robot.time() - self.bb.get("/tour_time") > ex.replan_period:
            return "tour stale"
        # A planner of views of known objects (PAMS) does not care how the frontiers moved.
        if self.robot.plans_frontiers and self.robot.frontier_change() >= ex.frontier_change:
            return "frontiers changed"
        return None

    def initialise(self) -> None:
        tour: list[TourItem] = list(self.bb.get("/tour"))
        goal = self.bb.get("/goal")
        if tour and goal is not None and tour[0] is goal:
            tour = tour[1:]  # the stop the last iteration handled
            self.bb.set("/tour", tour)
        self.reason = self._replan_reason(tour)
        self.future = self.robot.plan_async() if self.reason else None

    def update(self) -> Status:
        if self.future is None:
            tour = self.bb.get("/tour")
            self.bb.set("/goal", tour[0])
            self.feedback_message = f"following the tour: {len(tour)} stops left"
            return Status.SUCCESS
        if not self.future.done():
            self.robot.hold()
            self.feedback_message = f"planning ({self.reason})"
            return Status.RUNNING
        try:
            tour = self.future.result()
        except Exception as exc:  # recovery: count, report, hold position, retry
            failures = self.bb.get("/replan_failures") + 1
            self.bb.set("/replan_failures", failures)
            self.robot.emit("planner_error", error=f"{type(exc).__name__}: {exc}", failures=failures)
            self.robot.hold()
            if failures >= self.robot.exploration.max_replan_failures:
                self.bb.set("/exploration", f"stopped: planner failed {failures} times ({exc})")
                self.feedback_message = "planner keeps failing"
                return Status.FAILURE
            self.feedback_message = f"planner failed ({failures})"
            self.future = self.robot.plan_async()
            return Status.RUNNING
        self.bb.set("/replan_failures", 0)
        reachable = [item for item in tour if np.all(np.isfinite(item.position))]
        if not reachable:
            self.bb.set("/exploration", "complete: no reachable frontier left")
            self.bb.set("/tour", [])
            self.bb.set("/goal", None)
            self.feedback_message = "nothing left to explore"
            return Status.FAILURE
        self.bb.set("/tour", reachable)
        self.bb.set("/goal", reachable[0])
        self.bb.set("/tour_time", self.robot.time())
        self.bb.set("/tour_planned", len(reachable))
        self.robot.emit(
            "replan",
            reason=self.reason,
            tour=[[item.kind.value, *np.round(item.position, 2).tolist()] for item in reachable],
            viewpoints=len(self.robot.viewpoints),
        )
        self.robot.plugin_hook("amslam_replan", t=self.robot.time(), tour=reachable, reason=self.reason)
        self.feedback_message = f"{len(reachable)} stops, next {reachable[0].kind.value}"
        return Status.SUCCESS

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and self.future is not None:
            self.future.cancel()


class IsGoalKind(RobotBehaviour):
    """SUCCESS when the current goal is of the given kind (explore or SLC)."""

    def __init__(self, name: str, kind: TourItemKind):
        super().__init__(name)
        self.kind = kind
        self.bb.register_key("/goal", access=Access.READ)

    def update(self) -> Status:
        goal: TourItem | None = self.bb.get("/goal")
        return Status.SUCCESS if goal is not None and goal.kind == self.kind else Status.FAILURE


class GoTo(RobotBehaviour):
    """Fly to the goal along a path through known free space, facing the direction of travel.

    SUCCESS on arrival (heading turned to the goal's yaw), or early when an exploration goal's
    frontier was seen on the way or the tour is older than the replan period; FAILURE when no
    path exists or the local map shows the way blocked twice (the goal is marked unreachable).
    """

    def __init__(self, name: str, goal_key: str = "/goal", early_exit: bool = True):
        super().__init__(name)
        self.goal_key = goal_key
        self.early_exit = early_exit
        self.bb.register_key(goal_key, access=Access.READ)
        self.bb.register_key("/tour_time", access=Access.READ)
        self.bb.register_key("/unreachable", access=Access.WRITE)
        self.path: np.ndarray | None = None
        self.index = 0
        self.blocked = 0

    def setup(self, **kwargs) -> None:
        super().setup(**kwargs)
        self.bb.set("/unreachable", 0)

    def initialise(self) -> None:
        self.goal: TourItem = self.bb.get(self.goal_key)
        self.path = self.robot.plan_path(self.goal.position)
        self.index = 1 if self.path is not None and len(self.path) > 1 else 0
        self.blocked = 0
        self.sent: tuple[int, np.ndarray | None] = (-1, None)  # (waypoint, where the guards sent it)
        self.progress = (self.index, np.inf, self.robot.time())  # (waypoint, distance, since)

    #: how far ahead along the path the fresh local map is checked, m
    LOOKAHEAD = 1.5
    WAYPOINT_TOLERANCE = 0.15
    #: seconds without progress after which the goal is given up as unreachable
    NO_PROGRESS = 20.0
    SKIP_NEAR = 0.3
    #: a viewpoint this close to the goal (m) means the goal's frontier is still there
    SAME_GOAL = 1.0

    def _done(self, why: str) -> Status:
        self.bb.set("/unreachable", 0)
        self.feedback_message = why
        self.robot.emit(
            "goal_done", goal=np.round(self.goal.position, 2).tolist(), why=why, behaviour=self.name
        )
        return Status.SUCCESS

    def _fail(self, why: str) -> Status:
        self.robot.mark_unreachable(self.goal.position)
        count = self.bb.get("/unreachable") + 1
        self.bb.set("/unreachable", count)
        self.robot.emit(
            "unreachable", goal=np.round(self.goal.position, 2).tolist(), why=why, behaviour=self.name
        )
        self.robot.hold()
        self.feedback_message = why
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

    def _stalled(self, here: np.ndarray) -> bool:
        """No waypoint passed and no 0.1 m gained on the current one for NO_PROGRESS seconds."""
        now = self.robot.time()
        dist = float(np.linalg.norm(self.path[self.index] - here))
        if self.index > self.progress[0] or dist < self.progress[1] - 0.1:
            self.progress = (self.index, dist, now)
        return now - self.progress[2] > self.NO_PROGRESS

    def update(self) -> Status:
        if self.path is None:
            return self._fail("no path through known free space")
        here = self.robot.position_world()
        exploration = self.robot.exploration
        if self.goal_key != "/home" and (reason := self.robot.limit_reached()):
            self.robot.hold()
            self.feedback_message = f"stopped: {reason}"
            return Status.FAILURE
        if self._stalled(here):
            # A goal the guards or the controller cannot reach must not hold the robot forever.
            return self._fail(f"no progress for {self.NO_PROGRESS:.0f} s")
        if self.early_exit and self.goal.kind == TourItemKind.EXPLORE and self.robot.plans_frontiers:
            # Clusters are re-made as the map grows, so their ids change; the goal is still
            # worth reaching while some viewpoint remains near it.
            remaining = self.robot.candidate_viewpoints()
            if not any(np.linalg.norm(vp.position - self.goal.position) < self.SAME_GOAL for vp in remaining):
                return self._done("frontier seen on the way")
            if self.robot.time() - self.bb.get("/tour_time") > exploration.replan_period:
                return self._done("tour stale: replan")
        # Intermediate waypoints are passed tightly: cutting a corner near a door frame is how
        # a drone hits it.
        while self.index < len(self.path) - 1 and (
            np.linalg.norm(self.path[self.index] - here) < self.WAYPOINT_TOLERANCE or self._held_off(here)
        ):
            self.index += 1
        target = self.path[self.index]
        to_target = target - here
        last_leg = self.index == len(self.path) - 1
        arrived = last_leg and (
            np.linalg.norm(to_target) < exploration.goal_tolerance or self._held_off(here)
        )
        if arrived:
            err = abs(wrap_angle(self.goal.yaw - self.robot.yaw_world()))
            self.robot.send_setpoint_world(target, self.goal.yaw)
            if err < exploration.yaw_tolerance:
                if self.goal.kind == TourItemKind.EXPLORE:
                    self.robot.mark_visited(self.goal.position)
                return self._done("arrived")
            self.feedback_message = "turning to the viewpoint heading"
            return Status.RUNNING
        length = max(float(np.linalg.norm(to_target)), 1e-9)
        ahead = here + to_target * min(1.0, self.LOOKAHEAD / length)
        # Skip the first stretch: what is already within it cannot be avoided by stopping, and a
        # robot hovering near furniture must still be able to fly away from it.
        near = here + to_target * min(1.0, self.SKIP_NEAR / length)
        if length > self.SKIP_NEAR and not self.robot.segment_clear_local(near, ahead):
            self.blocked += 1
            if self.blocked > 2:
                return self._fail(f"the local map shows the way blocked near {np.round(ahead, 2).tolist()}")
            self.path = self.robot.plan_path(self.goal.position)
            self.index = 1 if self.path is not None and len(self.path) > 1 else 0
            self.progress = (self.index, np.inf, self.robot.time())
            self.feedback_message = "blocked: new path"
            return Status.RUNNING if self.path is not None else self._fail("blocked, no other path")
        horizontal = np.linalg.norm(to_target[:2])
        heading = float(np.arctan2(to_target[1], to_target[0])) if horizontal > 0.3 else self.goal.yaw
        yaw_err = abs(wrap_angle(heading - self.robot.yaw_world()))
        # Turn before moving when the way ahead is outside the camera's view: never fly blind.
        if yaw_err > self.robot.platform.camera.hfov / 3:
            self.robot.send_setpoint_world(here, heading)
            self.feedback_message = "turning towards the path"
        else:
            self.sent = (self.index, self.robot.send_setpoint_world(target, heading))
            self.feedback_message = f"waypoint {self.index}/{len(self.path) - 1}"
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and self.robot is not None:
            self.robot.hold()


class Panorama(RobotBehaviour):
    """Yaw a full circle in place in ``steps`` headings, collecting detections on the way."""

    def __init__(self, name: str = "Panorama", steps: int = 8):
        super().__init__(name)
        self.steps = steps

    def initialise(self) -> None:
        self.center = self.robot.position_world().copy()
        self.start_yaw = self.robot.yaw_world()
        self.step = 1

    def update(self) -> Status:
        target = wrap_angle(self.start_yaw + 2 * np.pi * self.step / self.steps)
        self.robot.send_setpoint_world(self.center, target)
        if abs(wrap_angle(target - self.robot.yaw_world())) < self.robot.exploration.yaw_tolerance:
            self.step += 1
            if self.step > self.steps:
                self.feedback_message = "full circle"
                return Status.SUCCESS
        self.feedback_message = f"heading {self.step}/{self.steps}"
        return Status.RUNNING


class AttemptLoopClosure(RobotBehaviour):
    """Ask SLAM for a semantic loop closure with what the panorama saw; always SUCCESS."""

    def __init__(self, name: str = "AttemptSLC"):
        super().__init__(name)
        self.bb.register_key("/slc", access=Access.WRITE)
        self.bb.register_key("/goal", access=Access.READ)

    def update(self) -> Status:
        result = self.robot.attempt_loop_closure(self.bb.get("/goal"))
        self.bb.set("/slc", {"accepted": result.accepted, "reason": result.reason, "matched": result.matched})
        self.robot.emit("loop_closure", **dataclasses.asdict(result), distance=self.robot.distance)
        self.robot.plugin_hook("amslam_loop_closure", t=self.robot.time(), result=result)
        self.feedback_message = ("accepted: " if result.accepted else "rejected: ") + result.reason
        return Status.SUCCESS


class ForgetGoal(RobotBehaviour):
    """Recovery after an unreachable goal: SUCCESS (so the loop replans) until too many in a row."""

    def __init__(self, name: str = "SkipUnreachable"):
        super().__init__(name)
        self.bb.register_key("/unreachable", access=Access.READ)
        self.bb.register_key("/exploration", access=Access.WRITE)

    def update(self) -> Status:
        count = self.bb.get("/unreachable")
        if count >= self.robot.exploration.max_unreachable:
            self.bb.set("/exploration", f"stopped: {count} goals in a row unreachable")
            self.feedback_message = "too many unreachable goals"
            return Status.FAILURE
        self.feedback_message = f"skipped ({count} in a row)"
        return Status.SUCCESS


class SetHome(RobotBehaviour):
    """Write the return-home goal: the take-off point at the mission altitude."""

    def __init__(self, name: str = "SetHomeGoal"):
        super().__init__(name)
        self.bb.register_key("/home", access=Access.WRITE)

    def update(self) -> Status:
        home = np.array([*self.robot.home_world[:2], self.robot.cruise_z])
        self.bb.set("/home", TourItem(TourItemKind.EXPLORE, home, self.robot.yaw_world(), 0.0, -1))
        return Status.SUCCESS


class Land(RobotBehaviour):
    """Descend and disarm where the robot is (idempotent)."""

    def initialise(self) -> None:
        self.robot.land()

    def update(self) -> Status:
        if self.robot.airborne():
            self.feedback_message = "descending"
            return Status.RUNNING
        self.feedback_message = "landed"
        return Status.SUCCESS


@amslam.hookimpl
def amslam_behaviours():
    return {
        "TakeOff": TakeOff,
        "WithinLimits": WithinLimits,
        "Replan": Replan,
        "GoTo": GoTo,
        "Panorama": Panorama,
        "AttemptSLC": AttemptLoopClosure,
        "SkipUnreachable": ForgetGoal,
        "SetHomeGoal": SetHome,
        "Land": Land,
    }
