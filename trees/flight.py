"""Trees for real flights: the failsafe guard and the waypoint mission.

A real vehicle can end a mission in ways a simulator does not: the radio link drops, the battery
runs low, the vehicle leaves its geofence, refuses a command or is taken over by its pilot. A
platform reports them through ``Platform.failsafe() -> Failsafe | None`` (the ``mavsdk``
platform does; the simulator does not), and the mission tree is put under a guard that answers
them, built from py_trees composites only::

    Guarded (sequence, reactive)
    ├── FailsafeGuard (selector, reactive)
    │   ├── NoFailsafe (inverter)
    │   │   └── FailsafeTriggered    SUCCESS once the platform reports a failsafe (latched)
    │   └── Failsafe (sequence)
    │       ├── FailsafeReturn       return_and_land: straight back over the take-off point
    │       ├── FailsafeLand         land (hand_over: wait); FAILURE if no touchdown is seen in time
    │       └── FailsafeEnd          FAILURE naming the failsafe: the run's verdict
    └── Mission                      the exploration tree, or the waypoint flight:
        ├── TakeOff
        ├── FlyWaypointsInTime (selector)
        │   ├── WithinLimits         the mission's time and distance limits (event limit_reached)
        │   │   └── FlyWaypointsOrSkip  SkipStalledWaypoint: a waypoint come no nearer to is skipped
        │   │       └── FlyWaypoints     straight lines through ``waypoints.points`` (from take-off)
        │   └── ReturnHome           once a limit cut the waypoints short, as exploration does
        └── Land

The guard is ticked first at every tick, so a failsafe pre-empts whatever the mission was doing
(the pre-empted leaf's ``terminate`` holds position) and the mission is never resumed: the run
ends with the verdict ``failed: FailsafeEnd: <kind>: <reason>; landed`` (or ``FailsafeLand: ...``
when no touchdown was seen) and a complete run folder.

========================  ====================================================================
key                       meaning
========================  ====================================================================
``/failsafe``             Failsafe | None — the failsafe being answered
``/waypoint``             int — index of the waypoint being flown to
========================  ====================================================================
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import py_trees
from py_trees.common import Access, Status
from py_trees.composites import Selector, Sequence
from py_trees.decorators import Inverter

from amslam.geometry import wrap_angle
from amslam.mission import MissionModel, WaypointsSection
from amslam.trees.behaviours import RobotBehaviour, go_to, return_home
from amslam.trees.decorators import WaypointProgress
from amslam.types import Failsafe, TourItem, TourItemKind


class FailsafeTriggered(RobotBehaviour):
    """SUCCESS once the platform reports a failsafe; it stays SUCCESS from then on."""

    uses = ("flight", "events")

    def __init__(self, name: str = "FailsafeTriggered"):
        super().__init__(name)
        self.bb.register_key("/failsafe", access=Access.WRITE)
        self.latched: Failsafe | None = None

    def setup(self, **kwargs) -> None:
        super().setup(**kwargs)
        self.bb.set("/failsafe", None)

    def update(self) -> Status:
        current = self.flight.failsafe()
        if current is not None and (self.latched is None or current.action != self.latched.action):
            self.latched = current  # escalation (e.g. low → critical battery) replaces the answer
            self.bb.set("/failsafe", current)
            self.events.emit(
                "failsafe_answered", kind=current.kind, reason=current.reason, action=current.action
            )
        if self.latched is None:
            self.feedback_message = "no failsafe"
            return Status.FAILURE
        self.feedback_message = f"{self.latched.kind}: {self.latched.action}"
        return Status.SUCCESS


class FailsafeReturn(RobotBehaviour):
    """For ``return_and_land``: fly straight back over the take-off point at the current height.

    SUCCESS at once for other actions, on arrival, or when the failsafe escalates to another
    action (a battery turning critical on the way lands where the vehicle is).
    """

    uses = ("flight",)

    def __init__(self, name: str = "FailsafeReturn", tolerance: float = 0.3):
        super().__init__(name)
        self.tolerance = tolerance
        self.bb.register_key("/failsafe", access=Access.READ)

    def initialise(self) -> None:
        here = self.flight.position_world()
        self.target = np.array([*self.flight.home_world[:2], here[2]])
        self.yaw = self.flight.yaw_world()

    def update(self) -> Status:
        failsafe: Failsafe | None = self.bb.get("/failsafe")
        if failsafe is None or failsafe.action != "return_and_land":
            self.feedback_message = "no return needed"
            return Status.SUCCESS
        if not self.flight.airborne():
            self.feedback_message = "on the ground"
            return Status.SUCCESS
        if np.linalg.norm(self.flight.position_world() - self.target) < self.tolerance:
            self.feedback_message = "over the take-off point"
            return Status.SUCCESS
        self.flight.send_setpoint_world(self.target, self.yaw)
        self.feedback_message = "returning"
        return Status.RUNNING


class FailsafeLand(RobotBehaviour):
    """Land (``hand_over``: only wait); SUCCESS on touchdown, FAILURE after ``timeout`` seconds.

    On a lost link the platform cannot confirm a touchdown: the vehicle's own failsafe lands it
    and this leaf gives up after the timeout, saying so.
    """

    uses = ("flight",)

    def __init__(self, name: str = "FailsafeLand", timeout: float = 60.0):
        super().__init__(name)
        self.timeout = timeout
        self.bb.register_key("/failsafe", access=Access.READ)

    def initialise(self) -> None:
        self.failsafe: Failsafe | None = self.bb.get("/failsafe")
        self.started = self.flight.time()
        if self.failsafe is None or self.failsafe.action != "hand_over":
            self.flight.land()

    def update(self) -> Status:
        if not self.flight.airborne():
            self.feedback_message = "landed"
            return Status.SUCCESS
        if self.flight.time() - self.started > self.timeout:
            self.feedback_message = f"no touchdown seen within {self.timeout:g} s"
            if self.failsafe is not None and self.failsafe.kind == "link_lost":
                self.feedback_message += " (link lost: the vehicle's own failsafe is landing it)"
            return Status.FAILURE
        self.feedback_message = (
            "waiting for the vehicle" if self.failsafe.action == "hand_over" else "descending"
        )
        return Status.RUNNING


class FailsafeEnd(RobotBehaviour):
    """FAILURE naming the failsafe, so the run's verdict says why the mission ended."""

    uses = ()

    def __init__(self, name: str = "FailsafeEnd"):
        super().__init__(name)
        self.bb.register_key("/failsafe", access=Access.READ)

    def update(self) -> Status:
        failsafe: Failsafe | None = self.bb.get("/failsafe")
        what = f"{failsafe.kind}: {failsafe.reason}" if failsafe else "failsafe"
        self.feedback_message = f"{what}; landed"
        return Status.FAILURE


def waypoints_ended(count: int, skipped: int) -> str:
    """How a waypoint flight ended (``/exploration``: metrics' ``exploration_end``, the report),
    the same for straight legs and paths."""
    return f"complete: {count} waypoints" + (f", {skipped} skipped" if skipped else "")


class FlyWaypoints(RobotBehaviour):
    """Fly straight to each waypoint in turn (positions relative to the take-off point).

    SUCCESS after the last one. No obstacle checks beyond the setpoint guards every flight has:
    waypoint missions are for open spaces the operator has looked at (see docs/flight.md). When
    to give a waypoint up is the :class:`~amslam.trees.decorators.SkipStalledWaypoint`
    decorator's decision (:meth:`progress`, :meth:`skip`).
    """

    uses = ("flight", "events")

    def __init__(self, name: str = "FlyWaypoints", section: WaypointsSection | None = None):
        super().__init__(name)
        self.section = section or WaypointsSection()
        self.bb.register_key("/waypoint", access=Access.WRITE)
        self.bb.register_key("/exploration", access=Access.WRITE)  # how the flight ended: metrics, report

    def initialise(self) -> None:
        self.index = 0
        self.yaw = self.flight.yaw_world()
        self.bb.set("/waypoint", 0)
        self.skipped = 0

    def _next(self, event: str, **fields: object) -> None:
        self.events.emit(event, index=self.index, **fields)
        self.index += 1
        self.bb.set("/waypoint", self.index)

    def progress(self, here: np.ndarray) -> WaypointProgress:
        """The waypoint flown to and the distance left to it (for ``SkipStalledWaypoint``)."""
        if self.index >= len(self.section.points):
            return WaypointProgress(self.index, 0.0)
        return WaypointProgress(self.index, float(np.linalg.norm(self._target(self.index) - here)))

    def skip(self, why: str) -> None:
        """Give the current waypoint up (event ``waypoint_skipped``); the next tick flies on."""
        if self.index >= len(self.section.points):
            return
        here = self.flight.position_world()
        self.skipped += 1
        self._next(
            "waypoint_skipped",
            position=np.round(self._target(self.index), 3).tolist(),
            at=np.round(here, 3).tolist(),
            reason=why,
        )

    def _target(self, i: int) -> np.ndarray:
        return self.flight.home_world + np.asarray(self.section.points[i], float)

    def update(self) -> Status:
        points = self.section.points
        while self.index < len(points):
            target = self._target(self.index)
            here = self.flight.position_world()
            if np.linalg.norm(target - here) >= self.section.tolerance:
                break
            self._next("waypoint_reached", position=np.round(target, 3).tolist())
        if self.index >= len(points):
            self.feedback_message = waypoints_ended(len(points), self.skipped)
            self.bb.set("/exploration", self.feedback_message)
            return Status.SUCCESS
        yaw = self.yaw
        if self.section.heading == "travel":
            d = target - here
            if np.linalg.norm(d[:2]) > self.section.tolerance:
                yaw = float(np.arctan2(d[1], d[0]))
            if abs(wrap_angle(yaw - self.flight.yaw_world())) > 0.5:
                target = here  # turn first, then go
        self.flight.send_setpoint_world(target, yaw)
        self.feedback_message = f"waypoint {self.index + 1}/{len(points)}"
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and getattr(self, "flight", None) is not None:
            self.flight.hold()


def failsafe_branch(
    behaviours: dict[str, Callable[..., py_trees.behaviour.Behaviour]], land_timeout: float = 60.0
) -> py_trees.behaviour.Behaviour:
    """SUCCESS while no failsafe is active, then the answer to it (see the module docstring)."""
    b = behaviours
    answer = Sequence(
        "Failsafe",
        memory=True,
        children=[
            b["FailsafeReturn"]("FailsafeReturn"),
            b["FailsafeLand"]("FailsafeLand", timeout=land_timeout),
            b["FailsafeEnd"]("FailsafeEnd"),
        ],
    )
    no_failsafe = Inverter("NoFailsafe", b["FailsafeTriggered"]("FailsafeTriggered"))
    return Selector("FailsafeGuard", memory=False, children=[no_failsafe, answer])


class SetWaypointGoal(RobotBehaviour):
    """Write waypoint ``index`` (relative to the take-off point) as ``/waypoint_goal`` for the
    ``GoTo`` after it (``waypoints.follow: paths``), its heading on arrival the way there
    (``heading: travel``) or the heading the vehicle has now (``keep``; in between, ``GoTo``
    faces the way it flies)."""

    uses = ("flight",)

    def __init__(self, name: str, index: int, section: WaypointsSection):
        super().__init__(name)
        self.index, self.section = index, section
        self.bb.register_key("/waypoint", access=Access.WRITE)
        self.bb.register_key("/waypoint_goal", access=Access.WRITE)
        self.bb.register_key("/waypoints_skipped", access=Access.WRITE)

    def update(self) -> Status:
        target = self.flight.home_world + np.asarray(self.section.points[self.index], float)
        if self.index == 0:
            self.bb.set("/waypoints_skipped", 0)
        yaw = self.flight.yaw_world()
        way = target - self.flight.position_world()
        if self.section.heading == "travel" and np.linalg.norm(way[:2]) > self.section.tolerance:
            yaw = float(np.arctan2(way[1], way[0]))
        self.bb.set("/waypoint", self.index)
        self.bb.set("/waypoint_goal", TourItem(TourItemKind.EXPLORE, target, yaw, 0.0, -1))
        return Status.SUCCESS


class WaypointOutcome(RobotBehaviour):
    """Log waypoint ``index`` reached, or skipped (its ``GoTo`` found no path or gave it up)."""

    uses = ("flight", "events")

    def __init__(self, name: str, index: int, reached: bool):
        super().__init__(name)
        self.index, self.reached = index, reached
        self.bb.register_key("/waypoint_goal", access=Access.READ)
        self.bb.register_key("/waypoints_skipped", access=Access.WRITE)

    def update(self) -> Status:
        position = np.round(self.bb.get("/waypoint_goal").position, 3).tolist()
        if self.reached:
            self.events.emit("waypoint_reached", index=self.index, position=position)
        else:
            self.bb.set("/waypoints_skipped", self.bb.get("/waypoints_skipped") + 1)
            at = np.round(self.flight.position_world(), 3).tolist()
            self.events.emit(
                "waypoint_skipped", index=self.index, position=position, at=at, reason="no way there"
            )
        return Status.SUCCESS


class WaypointsFlown(RobotBehaviour):
    """SUCCESS, saying how the waypoint flight ended (``/exploration``: metrics, report)."""

    def __init__(self, name: str, count: int):
        super().__init__(name)
        self.count = count
        self.bb.register_key("/waypoints_skipped", access=Access.READ)
        self.bb.register_key("/exploration", access=Access.WRITE)

    def update(self) -> Status:
        self.feedback_message = waypoints_ended(self.count, self.bb.get("/waypoints_skipped"))
        self.bb.set("/exploration", self.feedback_message)
        return Status.SUCCESS


def waypoint_paths(
    model: MissionModel, behaviours: dict[str, Callable[..., py_trees.behaviour.Behaviour]]
) -> py_trees.behaviour.Behaviour:
    """``waypoints.follow: paths``: each waypoint a goal flown to along a path through the map
    (``GoTo`` under ``GiveUpGoal``, as exploration flies), skipped when there is none."""
    b, section, ex = behaviours, model.waypoints, model.exploration
    legs = []
    for i in range(len(section.points)):
        go = go_to(
            b,
            f"GoToWaypoint{i}",
            goal_key="/waypoint_goal",
            early_exit=False,
            goal_tolerance=section.tolerance,
            yaw_tolerance=ex.yaw_tolerance,
            replan_period=ex.replan_period,
        )
        flown = Sequence(
            f"Waypoint{i}",
            memory=True,
            children=[
                SetWaypointGoal(f"SetWaypoint{i}", i, section),
                go,
                WaypointOutcome(f"Reached{i}", i, True),
            ],
        )
        legs.append(
            Selector(
                f"Waypoint{i}OrSkip", memory=True, children=[flown, WaypointOutcome(f"Skip{i}", i, False)]
            )
        )
    return Sequence(
        "FlyWaypointPaths", memory=True, children=[*legs, WaypointsFlown("WaypointsFlown", len(legs))]
    )


def build_waypoint_tree(
    model: MissionModel, behaviours: dict[str, Callable[..., py_trees.behaviour.Behaviour]]
) -> py_trees.behaviour.Behaviour:
    """Take off, fly the waypoints within the mission's limits (else return home), land."""
    b = behaviours
    # The mission's time and distance limits bound the waypoints as they bound exploration (the
    # same WithinLimits guard and return home): a waypoint the vehicle cannot reach (a drifting
    # estimate, a wind it cannot beat) otherwise held it hovering until the battery or the
    # operator ended the flight (a lot_team overhead robot hovered 110 s past its 240 s budget).
    if model.waypoints.follow == "paths":
        waypoints = waypoint_paths(model, b)
    else:
        waypoints = b["FlyWaypoints"]("FlyWaypoints", section=model.waypoints)
    if model.waypoints.follow == "straight" and model.waypoints.skip_after > 0:
        after = model.waypoints.skip_after
        waypoints = b["SkipStalledWaypoint"]("FlyWaypointsOrSkip", waypoints, after=after)
    within = b["WithinLimits"]("WithinLimits", waypoints)
    fly = Selector("FlyWaypointsInTime", memory=True, children=[within, return_home(b, model.exploration)])
    return Sequence("Mission", memory=True, children=[b["TakeOff"]("TakeOff"), fly, b["Land"]("Land")])


def with_failsafe_guard(
    mission: py_trees.behaviour.Behaviour,
    model: MissionModel,
    behaviours: dict[str, Callable[..., py_trees.behaviour.Behaviour]],
    failsafe: bool,
) -> py_trees.behaviour.Behaviour:
    """The mission under the failsafe guard when ``failsafe`` (a real vehicle), else as it is."""
    if not failsafe:
        return mission
    guard = failsafe_branch(behaviours, model.waypoints.land_timeout)
    return Sequence("Guarded", memory=False, children=[guard, mission])


def waypoints_tree(
    model: MissionModel,
    behaviours: dict[str, Callable[..., py_trees.behaviour.Behaviour]],
    failsafe: bool = False,
) -> py_trees.behaviour.Behaviour:
    """The ``waypoints`` mission tree (``amslam_mission_trees``)."""
    return with_failsafe_guard(build_waypoint_tree(model, behaviours), model, behaviours, failsafe)


def build_mission_tree(
    model: MissionModel,
    behaviours: dict[str, Callable[..., py_trees.behaviour.Behaviour]],
    failsafe: bool = False,
) -> py_trees.behaviour.Behaviour:
    """The built-in tree the mission's ``tree`` field names, under the failsafe guard when asked.

    The runner looks trees up in the registry (``Registry.tree``), where plugins add theirs;
    this covers the two built-in ones for callers without a registry.
    """
    from amslam.trees.exploration import exploration_tree

    builders = {"exploration": exploration_tree, "waypoints": waypoints_tree}
    if model.tree not in builders:
        raise KeyError(f"{model.tree!r} is not a built-in tree ({', '.join(builders)}); use Registry.tree")
    return builders[model.tree](model, behaviours, failsafe=failsafe)
