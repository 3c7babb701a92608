"""The ``greedy`` planner: the next viewpoint with the best gain for its travel cost.

The baseline of issue #6 ("nearest viewpoint by cost/gain"). Two documented utilities:

* ``ratio`` (default): ``u(v) = gain_v / (cost_v + epsilon)``, the cost-benefit index that
  Algorithm 1 of paper 1 also uses for an exploration viewpoint;
* ``exp``: ``u(v) = gain_v · exp(−lambda · cost_v)``, the classic next-best-view utility
  (Bircher et al.), where ``lambda`` (1/m) sets how fast distance discounts gain.

With ``items > 1`` the tour chains greedy choices: each next stop maximises the utility with the
cost measured from the previous stop.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from amslam.interfaces import BackendParams, Planner, RunContext
from amslam.lib.tours import explore_item, planning_graph
from amslam.types import PlanRequest, TourItem


class GreedyParams(BackendParams):
    """Parameters of the ``greedy`` planner."""

    utility: Literal["ratio", "exp"] = Field(
        "ratio", description="ratio: gain/(cost+epsilon); exp: gain*exp(-lam*cost)"
    )
    epsilon: float = Field(0.5, gt=0.0, le=1000, description="metres added to the cost in the ratio utility")
    lam: float = Field(0.25, ge=0.0, le=100, description="distance discount (1/m) of the exp utility")
    items: int = Field(1, ge=1, le=10_000, description="viewpoints in the returned tour, chained greedily")
    min_gain: float = Field(
        0.0, ge=0.0, le=1_000_000, description="viewpoints with gain (m³) at or below this are ignored"
    )


def greedy_utility(gains: np.ndarray, costs: np.ndarray, params: GreedyParams) -> np.ndarray:
    """Utility of each viewpoint given its gains (m³) and travel costs (m); -inf if unreachable."""
    ratio = params.utility == "ratio"
    u = gains / (costs + params.epsilon) if ratio else gains * np.exp(-params.lam * costs)
    return np.where(np.isfinite(costs), u, -np.inf)


class GreedyPlanner(Planner):
    """Next-best-viewpoint planner by utility of gain and path cost."""

    Params = GreedyParams

    def __init__(self) -> None:
        self.params = GreedyParams()
        self._emit = None

    def configure(self, params: GreedyParams, context: RunContext) -> None:
        """Keep the validated parameters."""
        self.params = params
        self._emit = context.emit

    def plan(self, request: PlanRequest) -> list[TourItem]:
        """The best viewpoint (or ``items`` chained ones); empty when none is reachable.

        Raises:
            PlanningError: the request's cost matrix does not match its viewpoints.
        """
        graph = planning_graph(request, self.params.min_gain)
        left = list(range(1, graph.size + 1))
        here, order = 0, []
        while left and len(order) < self.params.items:
            u = greedy_utility(graph.gains[np.array(left) - 1], graph.costs[here, left], self.params)
            k = int(np.argmax(u))
            if not np.isfinite(u[k]):
                break
            here = left.pop(k)
            order.append(here)
        tour = [explore_item(graph.viewpoints[node - 1]) for node in order]
        if self._emit is not None:
            self._emit("planner_tour", planner="greedy", viewpoints=graph.size, selected=len(tour))
        return tour
