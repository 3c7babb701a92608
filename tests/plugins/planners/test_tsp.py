"""The tsp baseline and the open-tour helpers it shares with cop."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from amslam.lib.tours import (
    exact_open_tour,
    metric_closure,
    nearest_neighbour_tour,
    tour_cost,
    two_opt,
)
from amslam.plugins.planners.tsp import TspParams, TspPlanner

from .conftest import make_request


def brute_force(costs: np.ndarray, nodes: list[int]) -> float:
    return min(tour_cost(costs, list(p)) for p in itertools.permutations(nodes))


def random_costs(seed: int, n: int) -> np.ndarray:
    pts = np.random.default_rng(seed).uniform(0, 10, (n + 1, 2))
    return np.linalg.norm(pts[:, None] - pts[None], axis=-1)


@pytest.mark.parametrize("seed", range(4))
def test_exact_tour_is_optimal(seed):
    costs = random_costs(seed, 7)
    tour = exact_open_tour(costs, list(range(1, 8)))
    assert sorted(tour) == list(range(1, 8))
    assert tour_cost(costs, tour) == pytest.approx(brute_force(costs, list(range(1, 8))))


def test_exact_tour_on_non_euclidean_costs():
    # A ring where the nearest-neighbour choice is a trap.
    costs = np.array(
        [[0, 1, 2, 10, 10], [1, 0, 1, 10, 9], [2, 1, 0, 1, 1], [10, 10, 1, 0, 1], [10, 9, 1, 1, 0]], float
    )
    tour = exact_open_tour(costs, [1, 2, 3, 4])
    assert tour_cost(costs, tour) == pytest.approx(brute_force(costs, [1, 2, 3, 4])) == pytest.approx(4.0)


@pytest.mark.parametrize("seed", range(4))
def test_heuristic_close_to_optimal_on_small_instances(seed):
    costs = random_costs(seed + 10, 8)
    nodes = list(range(1, 9))
    nn = nearest_neighbour_tour(costs, nodes)
    improved = two_opt(costs, nn)
    assert sorted(improved) == nodes
    assert tour_cost(costs, improved) <= tour_cost(costs, nn) + 1e-12
    from amslam.plugins.planners.tsp import open_tsp

    heuristic = open_tsp(costs, nodes, TspParams(exact_max=0))
    assert tour_cost(costs, heuristic) <= 1.1 * brute_force(costs, nodes)


def test_planner_visits_all_reachable_viewpoints_in_optimal_order(camera):
    rng = np.random.default_rng(5)
    positions = rng.uniform(0, 10, (8, 3))
    req = make_request(positions, rng.uniform(1, 5, 8), camera)
    costs = req.costs.copy()
    costs[3, :] = costs[:, 3] = np.inf  # viewpoint 2 unreachable
    costs[3, 3] = 0
    req = make_request(positions, rng.uniform(1, 5, 8), camera, costs=costs)
    p = TspPlanner()
    tour = p.plan(req)
    assert sorted(t.ref for t in tour) == [0, 1, 3, 4, 5, 6, 7]
    kept = [0, 1, 2, 4, 5, 6, 7, 8]
    sub = costs[np.ix_(kept, kept)]
    assert p.last_cost == pytest.approx(brute_force(sub, list(range(1, 8))))
    # larger instances go through the heuristic and still visit everything once
    positions = rng.uniform(0, 30, (40, 3))
    big = TspPlanner().plan(make_request(positions, np.ones(40), camera))
    assert sorted(t.ref for t in big) == list(range(40))


def test_metric_closure_routes_around_missing_edges():
    inf = np.inf
    costs = np.array([[0, 1, inf], [1, 0, 2], [inf, 2, 0]])
    closed = metric_closure(costs)
    np.testing.assert_allclose(closed, [[0, 1, 3], [1, 0, 2], [3, 2, 0]])
    # the longer direction of an asymmetric pair is kept
    np.testing.assert_allclose(metric_closure(np.array([[0, 1.0], [3.0, 0]])), [[0, 3], [3, 0]])
