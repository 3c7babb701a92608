"""The greedy next-best-viewpoint planner."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from amslam.errors import PlanningError
from amslam.plugins.planners.greedy import GreedyParams, GreedyPlanner
from amslam.types import TourItemKind

from .conftest import make_request


def planner(**params) -> GreedyPlanner:
    p = GreedyPlanner()
    p.params = GreedyParams(**params)
    return p


def test_ratio_utility_trades_gain_against_cost(camera):
    # near: 2 m, 10 m³ -> 10/2.5 = 4; far: 10 m, 60 m³ -> 60/10.5 = 5.7
    req = make_request([[2, 0, 1], [10, 0, 1]], [10.0, 60.0], camera)
    tour = planner().plan(req)
    assert [t.ref for t in tour] == [1]
    assert tour[0].kind is TourItemKind.EXPLORE
    np.testing.assert_allclose(tour[0].position, [10, 0, 1])
    # a steep exp discount prefers the near one
    assert [t.ref for t in planner(utility="exp", lam=1.0).plan(req)] == [0]


def test_unreachable_and_gainless_viewpoints_are_skipped(camera):
    req = make_request([[1, 0, 1], [2, 0, 1], [3, 0, 1]], [50.0, 0.0, 5.0], camera)
    costs = req.costs.copy()
    costs[0, 1] = costs[1, 0] = np.inf  # the best one is unreachable from the robot
    costs[1, 2:] = costs[2:, 1] = np.inf
    req = make_request([[1, 0, 1], [2, 0, 1], [3, 0, 1]], [50.0, 0.0, 5.0], camera, costs=costs)
    assert [t.ref for t in planner(items=3).plan(req)] == [2]


def test_nothing_reachable_gives_empty_tour(camera):
    req = make_request([[1, 0, 1]], [5.0], camera)
    costs = req.costs.copy()
    costs[0, 1] = costs[1, 0] = np.inf
    assert planner().plan(make_request([[1, 0, 1]], [5.0], camera, costs=costs)) == []
    assert planner().plan(make_request(np.zeros((0, 3)), [], camera)) == []


def test_chained_items_measure_cost_from_previous_stop(camera):
    # From the robot, A (x=2) wins; from A, C (x=4) beats B (x=-2) which is 4 m back.
    req = make_request([[2, 0, 1], [-2, 0, 1], [4, 0, 1]], [10.0, 10.0, 8.0], camera)
    assert [t.ref for t in planner(items=3).plan(req)] == [0, 2, 1]


def test_malformed_costs_raise(camera):
    req = make_request([[1, 0, 1]], [5.0], camera, costs=np.zeros((3, 3)))
    with pytest.raises(PlanningError, match="costs must be"):
        planner().plan(req)


def test_params_forbid_unknown_keys():
    with pytest.raises(ValidationError):
        GreedyParams(epsilonn=1.0)


def test_registered_through_entry_point():
    from amslam.registry import build_plugin_manager

    registry = build_plugin_manager()
    assert registry.factory("planner", "greedy") is GreedyPlanner
