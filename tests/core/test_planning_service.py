"""The planning service picks, for each frontier cluster, a view the robot can reach."""

from __future__ import annotations

import dataclasses

import numpy as np

from amslam.mission import ExplorationSection
from amslam.perception import Snapshot
from amslam.planning import PlanningService
from amslam.types import CameraModel, Odometry, TourItem, TourItemKind, Viewpoint

UPSTAIRS = np.array([5.0, 0.0, 4.2])  # the cluster's best view, on a floor not reached yet
IN_SHAFT = np.array([5.0, 0.0, 2.6])  # a lower view of it, from where the robot can fly


def viewpoint(position, gain, alternatives=()) -> Viewpoint:
    return Viewpoint(7, np.asarray(position, float), 0.0, gain, np.array([5.0, 0.0, 3.4]), 30, alternatives)


class UpperFloorOutOfReach:
    """A mapping whose free-space graph reaches everything below z = 3 m."""

    def path_costs(self, sources, targets):
        s, t = np.atleast_2d(sources), np.atleast_2d(targets)
        cost = np.linalg.norm(s[:, None] - t[None], axis=2)
        up = (s[:, None, 2] > 3.0) != (t[None, :, 2] > 3.0)
        return np.where(up, np.inf, cost)


class Recorder:
    needs_frontiers = True
    needs_pose_uncertainty = False

    def __init__(self):
        self.requests = []

    def plan(self, request):
        self.requests.append(request)
        ok = np.isfinite(request.costs[0, 1:])
        return [
            TourItem(TourItemKind.EXPLORE, vp.position, vp.yaw, vp.gain, vp.id)
            for vp, r in zip(request.viewpoints, ok, strict=True)
            if r
        ]


class NoSlam:
    def landmarks(self):
        return []


def service(vps) -> tuple[PlanningService, Recorder]:
    planner = Recorder()
    snap = Snapshot(0.0, Odometry(0.0, np.eye(4)), np.eye(4), 0.0, tuple(vps), 0.0)
    snap.odometry.T_odom_body[:3, 3] = [0.0, 0.0, 1.2]
    s = PlanningService(
        planner=planner,
        slam=NoSlam(),
        mapping=UpperFloorOutOfReach(),
        exploration=ExplorationSection(slc=False),
        camera=CameraModel.from_fov(64, 48, 87.0, 58.0),
        threaded=False,
        snapshot=snap,
    )
    return s, planner


def test_an_unreachable_view_is_replaced_by_a_reachable_alternative() -> None:
    s, planner = service([viewpoint(UPSTAIRS, 30.0, (viewpoint(IN_SHAFT, 4.0),))])
    tour = s.plan_async(1.2).result()
    assert [item.position.tolist() for item in tour] == [IN_SHAFT.tolist()]
    assert planner.requests[0].viewpoints[0].gain == 4.0
    # the goal stays wanted while the cluster's best view is still out of reach
    assert s.wants_view_near(IN_SHAFT, 0.3)


def test_the_goal_not_reached_reaches_the_planner() -> None:
    s, planner = service([viewpoint(IN_SHAFT, 30.0)])
    s.plan_async(1.2).result()
    goal = IN_SHAFT + [0.2, 0.0, 0.0]
    s.plan_async(1.2, goal=goal).result()
    goal[0] = 99.0  # the request holds its own copy
    assert planner.requests[0].goal is None
    np.testing.assert_allclose(planner.requests[1].goal, IN_SHAFT + [0.2, 0.0, 0.0])
    # a goal the robot arrived at (GoTo marks it visited), or gave up, is no goal to keep
    away = np.array([3.0, 0.0, 1.2])
    assert s.inputs(1.2, goal=away).goal is not None
    s.mark_visited(IN_SHAFT + [0.2, 0.0, 0.0])
    assert s.inputs(1.2, goal=IN_SHAFT + [0.3, 0.0, 0.0]).goal is None
    s.mark_unreachable(away)
    assert s.inputs(1.2, goal=away).goal is None


def test_a_reachable_view_is_kept_and_unreachable_alternatives_change_nothing() -> None:
    s, _ = service([viewpoint(IN_SHAFT, 30.0, (viewpoint(UPSTAIRS, 40.0),))])
    tour = s.plan_async(1.2).result()
    assert [item.position.tolist() for item in tour] == [IN_SHAFT.tolist()]


def test_visited_and_unreachable_options_are_skipped() -> None:
    s, _ = service([viewpoint(UPSTAIRS, 30.0, (viewpoint(IN_SHAFT, 4.0),))])
    s.mark_unreachable(UPSTAIRS)
    (only,) = s.candidate_viewpoints()
    assert np.array_equal(only.position, IN_SHAFT) and only.alternatives == ()
    s.mark_visited(IN_SHAFT)
    assert s.candidate_viewpoints() == []
    assert not s.wants_view_near(IN_SHAFT, 0.3)


class RobotInPhantomWall(UpperFloorOutOfReach):
    """The map shows the robot's own voxel occupied (a surface SLAM moved after it was integrated):
    a path may leave it, but as a target it is off the graph."""

    robot = np.array([0.0, 0.0, 1.2])

    def path_costs(self, sources, targets):
        cost = super().path_costs(sources, targets)
        at_robot = np.all(np.isclose(np.atleast_2d(targets), self.robot), axis=1)
        return np.where(at_robot[None], np.inf, cost)


def test_views_stay_reachable_when_the_map_shows_the_robot_inside_a_wall() -> None:
    from amslam.lib.tours import planning_graph

    s, planner = service([viewpoint([3.0, 0.0, 1.2], 30.0), viewpoint([4.0, 1.0, 1.2], 20.0)])
    s.mapping = RobotInPhantomWall()
    tour = s.plan_async(1.2).result()
    assert len(tour) == 2
    request = planner.requests[0]
    assert np.all(np.isfinite(request.costs)) and np.allclose(request.costs, request.costs.T)
    # the tour's closure (larger of a pair's two directions) keeps both views: seed 3 lost them all
    assert planning_graph(request).size == 2


def test_the_pose_uncertainty_is_asked_for_only_by_planners_that_read_it() -> None:
    asked = []

    class SlamWithCovariance(NoSlam):
        def pose_uncertainty(self):
            asked.append(True)
            return "the backend's pose uncertainty"

    s, planner = service([viewpoint(IN_SHAFT, 30.0)])
    s.slam = SlamWithCovariance()
    s.plan_async(1.2).result()
    assert planner.requests[-1].pose_uncertainty is None and not asked  # a marginal costs time
    planner.needs_pose_uncertainty = True
    s.plan_async(1.2).result()
    assert planner.requests[-1].pose_uncertainty == "the backend's pose uncertainty" and asked


def test_a_loop_closure_place_found_unreachable_is_not_offered_again() -> None:
    # one-floor seed 10: the same SLC goal came back at every replan, was given up eight times in
    # 0.7 s, and exploration stopped at 77 % ("8 goals in a row unreachable")
    from amslam.types import SlcCandidate

    class SlamWithCandidates(NoSlam):
        def slc_candidates(self, sensing_range):
            return [
                SlcCandidate(3, np.array([1.68, 6.94, 0.4]), 0.0, (1, 2), 0.5),
                SlcCandidate(9, np.array([4.0, 2.0, 1.2]), 0.0, (5,), 0.2),
            ]

        def slc_gain_model(self, keypose_ids):
            return None

    s, planner = service([viewpoint(IN_SHAFT, 30.0)])
    s.slam, s.exploration = SlamWithCandidates(), ExplorationSection(slc=True, slc_min_travel=1.0)
    s.snapshot = dataclasses.replace(s.snapshot, distance=50.0)
    s.plan_async(1.2).result()
    offered = planner.requests[-1].slc_candidates
    assert [c.keypose_id for c in offered] == [3, 9] and offered[0].position[2] == 1.2  # lifted
    s.mark_unreachable(np.array([1.68, 6.94, 1.2]))  # GoToSLC gave it up
    s.plan_async(1.2).result()
    assert [c.keypose_id for c in planner.requests[-1].slc_candidates] == [9]
