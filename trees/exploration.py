"""The exploration mission tree: take off → explore loop → return home → land.

Built from py_trees composites and decorators only. Leaves are looked up by name in the
behaviours the plugins provide (``amslam_behaviours``), so a plugin can replace a stock leaf.

::

    Mission (sequence)
    ├── TakeOff
    ├── LookAround (panorama at the start, optional)
    ├── ExploreUntilDone (failure is success)
    │   └── WithinLimits (eternal guard: time and distance, checked every tick)
    │       └── ExploreLoop (repeat until failure)
    │           └── ExploreStep (sequence)
    │               ├── RetryPlanning (retry: max_replan_failures planner failures in a row)
    │               │   └── Replan
    │               ├── HasGoal (FAILURE once nothing reachable is left)
    │               └── SkipUnreachable (skips an unreachable goal; FAILURE at max_unreachable in a row)
    │                   └── NextStop (selector)
    │                       ├── InsertSLC (sequence, when SLC is on): IsSLC → GoToSLC → Panorama → AttemptSLC
    │                       └── Explore (sequence): IsExplore → GoToViewpoint
    ├── ReturnHome (failure is success): SetHomeGoal → GoHome
    │   [→ HomePanorama → HomeSLC, when SLC is on]
    └── Land

Every GoTo* sits under a ``GiveUpGoal`` decorator (``…OrGiveUp``): no progress for 20 s, or the
way blocked three times, and the goal is given up as unreachable.

With SLC on, the robot closes one last loop where it started: home is where the oldest landmarks
are, so a panorama there ties the end of the trajectory to its beginning before landing. The tree
registers as ``exploration`` (``amslam_mission_trees``), under the failsafe guard on a real vehicle.
"""

from __future__ import annotations

from collections.abc import Callable

import py_trees
from py_trees.composites import Selector, Sequence
from py_trees.decorators import FailureIsSuccess, Repeat, Retry

from amslam.mission import MissionModel
from amslam.trees.behaviours import IsGoalKind, go_to, return_home
from amslam.trees.flight import with_failsafe_guard
from amslam.types import TourItemKind

Behaviours = dict[str, Callable[..., py_trees.behaviour.Behaviour]]


def _next_stop(model: MissionModel, b: Behaviours) -> py_trees.behaviour.Behaviour:
    """Fly to the goal the plan chose: an SLC viewpoint (panorama, loop closure) or a frontier."""
    ex = model.exploration
    goto = dict(
        goal_tolerance=ex.goal_tolerance, yaw_tolerance=ex.yaw_tolerance, replan_period=ex.replan_period
    )
    stops: list[py_trees.behaviour.Behaviour] = []
    if ex.slc:
        stops.append(
            Sequence(
                "InsertSLC",
                memory=True,
                children=[
                    IsGoalKind("IsSLC", TourItemKind.SLC),
                    go_to(b, "GoToSLC", early_exit=False, **goto),
                    b["Panorama"]("Panorama", steps=ex.panorama_steps, yaw_tolerance=ex.yaw_tolerance),
                    b["AttemptSLC"]("AttemptSLC"),
                ],
            )
        )
    stops.append(
        Sequence(
            "Explore",
            memory=True,
            children=[IsGoalKind("IsExplore", TourItemKind.EXPLORE), go_to(b, "GoToViewpoint", **goto)],
        )
    )
    return b["SkipUnreachable"](
        "SkipUnreachable", Selector("NextStop", False, stops), max_unreachable=ex.max_unreachable
    )


def build_exploration_tree(model: MissionModel, behaviours: Behaviours) -> py_trees.behaviour.Behaviour:
    """The exploration mission tree for a mission and the registered behaviours."""
    b = behaviours
    ex = model.exploration
    replan = b["Replan"](
        "Replan",
        replan_fraction=ex.replan_fraction,
        replan_period=ex.replan_period,
        frontier_change=ex.frontier_change,
    )
    step = Sequence(
        "ExploreStep",
        memory=True,
        children=[
            Retry("RetryPlanning", replan, num_failures=ex.max_replan_failures),
            b["HasGoal"]("HasGoal"),
            _next_stop(model, b),
        ],
    )
    loop = b["WithinLimits"]("WithinLimits", Repeat("ExploreLoop", step, num_success=-1))
    children: list[py_trees.behaviour.Behaviour] = [b["TakeOff"]("TakeOff")]
    if ex.look_around:
        children.append(b["Panorama"]("LookAround", steps=ex.panorama_steps, yaw_tolerance=ex.yaw_tolerance))
    home_slc = (
        (
            b["Panorama"]("HomePanorama", steps=ex.panorama_steps, yaw_tolerance=ex.yaw_tolerance),
            b["AttemptSLC"]("HomeSLC"),
        )
        if ex.slc
        else ()
    )
    explore = FailureIsSuccess("ExploreUntilDone", loop)
    children += [explore, return_home(b, ex, then=home_slc), b["Land"]("Land")]
    return Sequence("Mission", memory=True, children=children)


def exploration_tree(
    model: MissionModel, behaviours: Behaviours, failsafe: bool = False
) -> py_trees.behaviour.Behaviour:
    """The ``exploration`` mission tree (``amslam_mission_trees``)."""
    return with_failsafe_guard(build_exploration_tree(model, behaviours), model, behaviours, failsafe)
