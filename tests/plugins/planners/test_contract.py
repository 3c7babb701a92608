"""The greedy, COP and TSP planners pass the planner contract kit."""

from amslam.plugins.planners.cop import CopPlanner
from amslam.plugins.planners.greedy import GreedyPlanner
from amslam.plugins.planners.tsp import TspPlanner
from amslam.testing.planner import PlannerContract


class TestGreedyContract(PlannerContract):
    def make_backend(self) -> GreedyPlanner:
        return GreedyPlanner()


class TestCopContract(PlannerContract):
    def make_backend(self) -> CopPlanner:
        return CopPlanner()


class TestTspContract(PlannerContract):
    def make_backend(self) -> TspPlanner:
        return TspPlanner()
