"""Exploration planners (paper 1 §VI-B, §VI-D): ``greedy``, ``cop`` and ``tsp``.

Registered through the ``amslam`` entry point ``planners`` like any third-party plugin.
"""

from __future__ import annotations

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_planner_backends():
    """The built-in planners by name."""
    return {
        "greedy": Deferred("amslam.plugins.planners.greedy:GreedyPlanner"),
        "cop": Deferred("amslam.plugins.planners.cop:CopPlanner"),
        "tsp": Deferred("amslam.plugins.planners.tsp:TspPlanner"),
    }
