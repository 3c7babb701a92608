"""Exploration planners (paper 1 §VI-B, §VI-D): ``greedy``, ``cop`` and ``tsp``.

Registered through the ``amslam`` entry point ``planners`` like any third-party plugin.
"""

from __future__ import annotations

import amslam
from amslam.plugins.planners.greedy import GreedyParams, GreedyPlanner

__all__ = ["GreedyParams", "GreedyPlanner"]


@amslam.hookimpl
def amslam_planner_backends():
    """The built-in planners by name."""
    return {"greedy": GreedyPlanner}
