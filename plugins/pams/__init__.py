"""Planner plugins ``pams`` and ``prior_visit``: active metric-semantic mapping of known objects.

``pams`` (paper 2 §IV-D) plans views of the objects of a prior map where fitted empirical models
(:mod:`amslam.plugins.pams.uncertainty`, paper 2 §IV-C) predict confident classification and
small geometric error, choosing the path that most reduces the differential entropy of each
object's geometry; ``prior_visit`` is the paper's baseline, one look at each prior object.
See docs/pams.md.
"""

from __future__ import annotations

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_planner_backends():
    """The PAMS planner and its baseline."""
    return {
        "pams": Deferred("amslam.plugins.pams.planner:PamsPlanner"),
        "prior_visit": Deferred("amslam.plugins.pams.planner:PriorVisitPlanner"),
    }
