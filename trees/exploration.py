"""The exploration mission tree: take off → explore loop → return home → land.

Built from py_trees composites and decorators only. Leaves are looked up by name in the
behaviours the plugins provide (``amslam_behaviours``), so a plugin can replace a stock leaf.

::

    Mission (sequence)
    ├── TakeOff
    ├── LookAround (panorama at the start, optional)
    ├── ExploreUntilDone (failure is success)
    │   └── ExploreLoop (repeat until failure)
    │       └── ExploreStep (sequence)
    │           ├── WithinLimits
    │           ├── Replan (recovery guard inside: counts planner failures)
    │           └── NextStop (selector)
    │               ├── InsertSLC (sequence, when SLC is on): IsSLC → GoToSLC → Panorama → AttemptSLC
    │               ├── Explore (sequence): IsExplore → GoToViewpoint
    │               └── SkipUnreachable
    ├── ReturnHome (failure is success): SetHomeGoal → GoHome
    │   [→ HomePanorama → HomeSLC, when SLC is on]
    └── Land

With SLC on, the robot closes one last loop where it started: home is where the oldest landmarks
are, so a panorama there ties the end of the trajectory to its beginning before landing.
"""

from __future__ import annotations

from collections.abc import Callable

import py_trees
from py_trees.composites import Selector, Sequence
from py_trees.decorators import FailureIsSuccess, Repeat

from amslam.mission import ExplorationSection
from amslam.types import TourItemKind


def build_exploration_tree(
    exploration: ExplorationSection, behaviours: dict[str, Callable[..., py_trees.behaviour.Behaviour]]
) -> py_trees.behaviour.Behaviour:
    """The mission tree for an exploration section and the registered behaviours."""
    b = behaviours
    from amslam.trees.behaviours import IsGoalKind  # a condition, not a replaceable leaf

    stops: list[py_trees.behaviour.Behaviour] = []
    if exploration.slc:
        stops.append(
            Sequence(
                "InsertSLC",
                memory=True,
                children=[
                    IsGoalKind("IsSLC", TourItemKind.SLC),
                    b["GoTo"]("GoToSLC", early_exit=False),
                    b["Panorama"]("Panorama", steps=exploration.panorama_steps),
                    b["AttemptSLC"]("AttemptSLC"),
                ],
            )
        )
    stops.append(
        Sequence(
            "Explore",
            memory=True,
            children=[IsGoalKind("IsExplore", TourItemKind.EXPLORE), b["GoTo"]("GoToViewpoint")],
        )
    )
    stops.append(b["SkipUnreachable"]("SkipUnreachable"))
    step = Sequence(
        "ExploreStep",
        memory=True,
        children=[
            b["WithinLimits"]("WithinLimits"),
            b["Replan"]("Replan"),
            Selector("NextStop", False, stops),
        ],
    )
    explore = FailureIsSuccess("ExploreUntilDone", Repeat("ExploreLoop", step, num_success=-1))
    children: list[py_trees.behaviour.Behaviour] = [b["TakeOff"]("TakeOff")]
    if exploration.look_around:
        children.append(b["Panorama"]("LookAround", steps=exploration.panorama_steps))
    home_steps = [b["SetHomeGoal"]("SetHomeGoal"), b["GoTo"]("GoHome", goal_key="/home", early_exit=False)]
    if exploration.slc:
        home_steps += [
            b["Panorama"]("HomePanorama", steps=exploration.panorama_steps),
            b["AttemptSLC"]("HomeSLC"),
        ]
    go_home = Sequence("GoHomeSteps", memory=True, children=home_steps)
    children += [explore, FailureIsSuccess("ReturnHome", go_home), b["Land"]("Land")]
    return Sequence("Mission", memory=True, children=children)
