"""Exploration planners (paper 1 §VI-B, §VI-D): ``greedy``, ``cop`` and ``tsp``.

Registered through the ``amslam`` entry point ``planners`` like any third-party plugin.
"""

from __future__ import annotations

import amslam
from amslam.plugins.planners.cop import CopParams, CopPlanner
from amslam.plugins.planners.greedy import GreedyParams, GreedyPlanner
from amslam.plugins.planners.tsp import TspParams, TspPlanner

__all__ = ["CopParams", "CopPlanner", "GreedyParams", "GreedyPlanner", "TspParams", "TspPlanner"]


@amslam.hookimpl
def amslam_planner_backends():
    """The built-in planners by name."""
    return {"greedy": GreedyPlanner, "cop": CopPlanner, "tsp": TspPlanner}
