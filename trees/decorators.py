"""Decorators of the stock trees for what py_trees' own cannot express: when to give a goal up.

py_trees' decorators count within one run of themselves on the wall clock: ``Retry`` ticks the
same child again after a failure and forgets its count when it starts, ``Timeout`` measures
``time.monotonic()`` from the child's start. A goal's give-up needs neither:

* :class:`SkipUnreachable` counts unreachable goals *across* its runs (one run per iteration of
  the exploration loop, with a new plan in between, so a new goal each time) and only a goal
  reached resets the count;
* :class:`GiveUpGoal` measures the child's *progress along its path* on the run's clock (the
  simulator's in a simulation), which no status and no wall clock shows;
* :class:`SkipStalledWaypoint` measures a waypoint flight's progress the same way and skips the
  waypoint it comes no nearer to.

The leaves under them keep no counters and no timers: a follower only says how far it got
(:class:`PathProgress`, :class:`WaypointProgress`) and what giving its goal up means
(:meth:`FollowsPath.give_up`, :meth:`FliesWaypoints.skip`).
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np
import py_trees
from py_trees.common import Access, Status
from py_trees.decorators import Decorator

from amslam.mission import ExplorationSection
from amslam.robot import Flight
from amslam.trees.services import require_services


class PathProgress(NamedTuple):
    """How far a path follower has got towards its goal.

    ``(replanned, passed)`` only grows while it follows one goal: paths planned anew after the
    way was blocked, then waypoints passed on the current path; ``to_waypoint`` is the distance
    left to the current waypoint, m. Every follower starts at ``(0, 0)``.
    """

    replanned: int
    passed: int
    to_waypoint: float

    @property
    def stage(self) -> tuple[int, int]:
        return (self.replanned, self.passed)


class FollowsPath(Protocol):
    """What :class:`GiveUpGoal` needs of its child (the ``GoTo`` leaf)."""

    #: whether its last run ended at its goal (False: early, e.g. on a stale tour, or not yet)
    arrived: bool

    def progress(self, here) -> PathProgress: ...

    def give_up(self, why: str) -> None:
        """Mark the goal unreachable, say why, hold position."""


class GiveUpGoal(Decorator):
    """Give the child's goal up when it makes no progress for ``no_progress`` seconds of the
    run's clock, or once the way was blocked ``max_blocked`` times within ``block_radius`` metres
    (its path replanned as often there).

    Blocks count where they happen: a way blocked three times in one place is blocked, but a long
    way with three obstacles, each flown round, is progress (a bookstore flight gave up going home
    after detours 2.5 and 3.5 m apart, and landed on furniture 1.2 m high, 6 m from home). A block more than
    ``block_radius`` from the first of the blocks counted starts the count again there.

    Progress is a waypoint passed, a path replanned, or ``min_gain`` metres gained on the current
    waypoint. The no-progress check runs before the child's tick, against where the robot is now
    (a goal the guards or the controller cannot reach must not hold the robot forever); the
    blocked check after it, once the child has seen the local map. Giving up is the child's
    :meth:`FollowsPath.give_up`, then FAILURE, in the same tick. (The path the child planned on
    the last block is thrown away unflown: the leaf always replans when blocked, since only the
    decorator knows when to stop. Before the decorator, the leaf counted and skipped that plan.)
    """

    uses = ("flight",)
    flight: Flight

    def __init__(
        self,
        name: str,
        child: py_trees.behaviour.Behaviour,
        no_progress: float = 20.0,
        max_blocked: int = 3,
        min_gain: float = 0.1,
        block_radius: float = 1.0,
    ):
        super().__init__(name=name, child=child)
        self.no_progress = no_progress
        self.max_blocked = max_blocked
        self.min_gain = min_gain
        self.block_radius = block_radius
        #: the child's blocks seen so far, and the count of those near where the count began
        self.blocks_seen = 0
        self.blocks_here: tuple[np.ndarray, int] | None = None
        #: the best progress so far and since when: ((replanned, passed), distance, time)
        self.best: tuple[tuple[int, int], float, float] | None = None
        #: where the robot was when the child last made progress, and when; kept across runs
        #: while the child keeps ending early (see :meth:`terminate`)
        self.last_progress: tuple[np.ndarray, float] | None = None

    def setup(self, **kwargs) -> None:
        require_services(self, self.uses, kwargs)

    def initialise(self) -> None:
        self.best = None
        self.blocks_seen, self.blocks_here = 0, None

    def terminate(self, new_status: Status) -> None:
        # A run that ended early (the tour went stale, every replan_period) is followed by a new
        # run towards the same or another goal from the same spot: a robot the guards hold in
        # place would start a fresh 20 s clock every 6 s and never give up (demo seed 1 hovered
        # 180 s in the shaft that way). The clock goes on across such runs until the robot moves.
        # Only giving up and arriving end it: a composite restarting stops its finished children
        # with INVALID, which says nothing (the first version reset on it, and never fired).
        if new_status == Status.FAILURE or self.decorated.arrived:
            self.last_progress = None

    def tick(self):
        if self.status == Status.RUNNING and self.best is not None and self._stalled():
            self._give_up(f"no progress for {self.no_progress:.0f} s")
            self.stop(Status.FAILURE)  # the child is not ticked: end as a tick would
            yield self
            return
        yield from super().tick()

    def _stalled(self) -> bool:
        now = self.flight.time()
        progress = self.decorated.progress(self.flight.position_world())
        stage, distance, since = self.best
        if progress.stage > stage or progress.to_waypoint < distance - self.min_gain:
            self.best = (progress.stage, progress.to_waypoint, now)
            self.last_progress = (self.flight.position_world().copy(), now)
            return False
        return now - since > self.no_progress

    def update(self) -> Status:
        child = self.decorated
        if child.status != Status.RUNNING:
            return child.status
        progress = child.progress(self.flight.position_world())
        if self.best is None:
            # The child's first tick. The robot does not move within a tick, so this is the
            # distance it started at: exact while the stage is still (0, 0), and a stage already
            # past it counts as progress at the next check anyway. The clock starts now, or goes
            # on from the last progress of earlier runs that ended early if the robot has not
            # moved since (see terminate).
            here, now = self.flight.position_world(), self.flight.time()
            since = now
            if self.last_progress is not None:
                where, when = self.last_progress
                if float(np.linalg.norm(here - where)) < self.min_gain:
                    since = when
            if self.last_progress is None or since == now:
                self.last_progress = (here.copy(), now)
            self.best = ((0, 0), progress.to_waypoint, since)
        if progress.replanned > self.blocks_seen:
            here = self.flight.position_world()
            new = progress.replanned - self.blocks_seen
            self.blocks_seen = progress.replanned
            if self.blocks_here is None or np.linalg.norm(here - self.blocks_here[0]) > self.block_radius:
                self.blocks_here = (here.copy(), new)
            else:
                self.blocks_here = (self.blocks_here[0], self.blocks_here[1] + new)
        if self.blocks_here is not None and self.blocks_here[1] >= self.max_blocked:
            self._give_up(f"the local map showed the way blocked {self.blocks_here[1]} times")
            return Status.FAILURE
        self.feedback_message = child.feedback_message
        return Status.RUNNING

    def _give_up(self, why: str) -> None:
        self.decorated.give_up(why)
        self.decorated.stop(Status.FAILURE)  # not INVALID: giving up already held position
        self.feedback_message = why


class SkipUnreachable(Decorator):
    """An unreachable goal is skipped (the child's FAILURE becomes SUCCESS, so the loop replans)
    until ``max_unreachable`` goals in a row were unreachable; then FAILURE: exploration gives up
    and ``/exploration`` says why. A goal reached (SUCCESS) resets the count."""

    def __init__(
        self,
        name: str,
        child: py_trees.behaviour.Behaviour,
        max_unreachable: int = ExplorationSection().max_unreachable,
    ):
        super().__init__(name=name, child=child)
        self.max_unreachable = max_unreachable
        self.in_a_row = 0  # kept across runs: that is the point (see the module's docstring)
        self.bb = self.attach_blackboard_client(name=name)
        self.bb.register_key("/exploration", access=Access.WRITE)

    def update(self) -> Status:
        status = self.decorated.status
        if status == Status.SUCCESS:
            self.in_a_row = 0
        if status != Status.FAILURE:
            return status
        self.in_a_row += 1
        if self.in_a_row >= self.max_unreachable:
            self.bb.set("/exploration", f"stopped: {self.in_a_row} goals in a row unreachable")
            self.feedback_message = "too many unreachable goals"
            return Status.FAILURE
        self.feedback_message = f"skipped ({self.in_a_row} in a row)"
        return Status.SUCCESS


class WaypointProgress(NamedTuple):
    """How far a waypoint flight has got: the waypoint flown to, and the distance left to it, m."""

    index: int
    distance: float


class FliesWaypoints(Protocol):
    """What :class:`SkipStalledWaypoint` needs of its child (the ``FlyWaypoints`` leaf)."""

    def progress(self, here) -> WaypointProgress: ...

    def skip(self, why: str) -> None:
        """Give the current waypoint up, say why, fly on to the next."""


class SkipStalledWaypoint(Decorator):
    """Skip the waypoint its child comes no nearer to (by ``min_gain`` m) for ``after`` seconds of
    the run's clock: the setpoint guards holding the vehicle back from something in its way (a
    PAMS overhead survey hovered 770 s before a light pole), or a wind it cannot beat.

    The check runs before the child's tick; the child then flies to the next waypoint from where
    the vehicle is, in the same tick. A waypoint reached restarts the clock.
    """

    uses = ("flight",)
    flight: Flight

    def __init__(
        self, name: str, child: py_trees.behaviour.Behaviour, after: float = 15.0, min_gain: float = 0.1
    ):
        super().__init__(name=name, child=child)
        self.after = after
        self.min_gain = min_gain
        #: the best progress so far and since when: (index, distance, time)
        self.best: tuple[int, float, float] | None = None

    def setup(self, **kwargs) -> None:
        require_services(self, self.uses, kwargs)

    def initialise(self) -> None:
        self.best = None

    def tick(self):
        if self.status == Status.RUNNING:
            now = self.flight.time()
            index, distance = self.decorated.progress(self.flight.position_world())
            if self.best is None or index != self.best[0] or distance < self.best[1] - self.min_gain:
                self.best = (index, distance, now)
            elif now - self.best[2] >= self.after:
                self.decorated.skip(f"no nearer than {distance:.2f} m for {self.after:.0f} s")
                self.best = None
        yield from super().tick()

    def update(self) -> Status:
        self.feedback_message = self.decorated.feedback_message
        return self.decorated.status
