"""The ``tsp`` planner: every reachable viewpoint, shortest open tour from the robot (like FUEL).

The baseline of issue #6. Up to ``exact_max`` viewpoints the tour is optimal (Held–Karp dynamic
programming, :func:`~amslam.lib.tours.exact_open_tour`); beyond, it is built by
nearest neighbour and improved with 2-opt and or-opt moves (typically within a few percent of the
optimum on Euclidean instances). Gains only decide which viewpoints are kept (``min_gain``).
"""

from __future__ import annotations

from pydantic import Field

from amslam.interfaces import BackendParams, Planner, RunContext
from amslam.lib.tours import (
    exact_open_tour,
    explore_item,
    nearest_neighbour_tour,
    or_opt,
    planning_graph,
    tour_cost,
    two_opt,
)
from amslam.types import PlanRequest, TourItem


class TspParams(BackendParams):
    """Parameters of the ``tsp`` planner."""

    exact_max: int = Field(
        12, ge=0, le=15, description="largest number of viewpoints solved exactly by dynamic programming"
    )
    min_gain: float = Field(
        0.0, ge=0.0, le=1_000_000, description="viewpoints with gain (m³) at or below this are ignored"
    )
    max_rounds: int = Field(
        50, ge=1, le=100_000, description="improvement rounds of the 2-opt / or-opt heuristic"
    )


def open_tsp(costs, nodes: list[int], params: TspParams) -> list[int]:
    """Shortest (exact or heuristic, see module docstring) open tour from node 0 through ``nodes``."""
    if len(nodes) <= params.exact_max:
        return exact_open_tour(costs, nodes)
    tour = two_opt(costs, nearest_neighbour_tour(costs, nodes), params.max_rounds)
    return two_opt(costs, or_opt(costs, tour, params.max_rounds), params.max_rounds)


class TspPlanner(Planner):
    """Open travelling-salesman tour over all reachable viewpoints."""

    Params = TspParams

    def __init__(self) -> None:
        self.params = TspParams()
        self.last_cost = 0.0
        self._emit = None

    def configure(self, params: TspParams, context: RunContext) -> None:
        """Keep the validated parameters."""
        self.params = params
        self._emit = context.emit

    def plan(self, request: PlanRequest) -> list[TourItem]:
        """All reachable viewpoints with gain above ``min_gain``, in shortest-tour order.

        Raises:
            PlanningError: the request's cost matrix does not match its viewpoints.
        """
        graph = planning_graph(request, self.params.min_gain)
        tour = open_tsp(graph.costs, list(range(1, graph.size + 1)), self.params)
        self.last_cost = tour_cost(graph.costs, tour)
        if self._emit is not None:
            self._emit("planner_tour", planner="tsp", viewpoints=graph.size, cost=round(self.last_cost, 3))
        return [explore_item(graph.viewpoints[node - 1]) for node in tour]
