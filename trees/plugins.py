"""The tree plugins' hooks: the stock behaviours and the two mission trees, named, not imported.

Every command builds the registry, but only drawing a tree and flying build one: the modules that
define the behaviours and trees import py_trees (and with it pydot and multiprocessing), numpy and
the robot's services, which listing plugins and validating a mission need none of (issue #20).
So the entry points ``behaviours``, ``flight`` and ``exploration_tree`` name these three plugins,
which give their behaviours and trees as :class:`~amslam.deferred.Deferred` references; each
module is imported when a tree first calls one of its behaviours or builders.
"""

from __future__ import annotations

import amslam
from amslam.deferred import Deferred


def _named(module: str, names: dict[str, str]) -> dict[str, Deferred]:
    """``{behaviour name: Deferred("module:attribute")}``."""
    return {name: Deferred(f"{module}:{attribute}") for name, attribute in names.items()}


class Behaviours:
    """Plugin ``behaviours``: the leaves of the exploration tree (:mod:`amslam.trees.behaviours`)."""

    @staticmethod
    @amslam.hookimpl
    def amslam_behaviours():
        stock = _named(
            "amslam.trees.behaviours",
            {
                "TakeOff": "TakeOff",
                "WithinLimits": "WithinLimits",
                "Replan": "Replan",
                "GoTo": "GoTo",
                "Panorama": "Panorama",
                "AttemptSLC": "AttemptLoopClosure",
                "SetHomeGoal": "SetHome",
                "Land": "Land",
                "HasGoal": "HasGoal",
            },
        )
        decorators = _named(
            "amslam.trees.decorators",
            {
                "GiveUpGoal": "GiveUpGoal",
                "SkipUnreachable": "SkipUnreachable",
                "SkipStalledWaypoint": "SkipStalledWaypoint",
            },
        )
        return {**stock, **decorators}


class Flight:
    """Plugin ``flight``: waypoint flight and the failsafe guard (:mod:`amslam.trees.flight`)."""

    @staticmethod
    @amslam.hookimpl
    def amslam_behaviours():
        return _named(
            "amslam.trees.flight",
            {
                "FlyWaypoints": "FlyWaypoints",
                "FailsafeTriggered": "FailsafeTriggered",
                "FailsafeReturn": "FailsafeReturn",
                "FailsafeLand": "FailsafeLand",
                "FailsafeEnd": "FailsafeEnd",
            },
        )

    @staticmethod
    @amslam.hookimpl
    def amslam_mission_trees():
        return {"waypoints": Deferred("amslam.trees.flight:waypoints_tree")}


class Exploration:
    """Plugin ``exploration_tree``: the ``exploration`` mission tree (:mod:`amslam.trees.exploration`)."""

    @staticmethod
    @amslam.hookimpl
    def amslam_mission_trees():
        return {"exploration": Deferred("amslam.trees.exploration:exploration_tree")}
