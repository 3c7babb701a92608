"""The exploration tree's shape, its leaves, and the decorators that give goals up."""

from __future__ import annotations

from concurrent.futures import Future
from types import SimpleNamespace

import numpy as np
import py_trees
import pytest
from py_trees.common import Status

from amslam.mission import ExplorationSection, MissionModel
from amslam.trees.behaviours import Replan, WithinLimits, go_to
from amslam.trees.decorators import SkipUnreachable
from amslam.trees.exploration import build_exploration_tree
from amslam.trees.plugins import Behaviours
from amslam.types import TourItem, TourItemKind

STOCK = Behaviours.amslam_behaviours()


def names(root) -> set[str]:
    return {node.name for node in root.iterate()}


def mission(**exploration) -> MissionModel:
    return MissionModel(name="test", exploration=ExplorationSection(**exploration))


def test_tree_has_the_named_behaviours(registry):
    root = build_exploration_tree(mission(slc=True), registry.behaviours)
    assert {"TakeOff", "Replan", "Explore", "InsertSLC", "Panorama", "AttemptSLC", "Land"} <= names(root)
    without = build_exploration_tree(mission(slc=False), registry.behaviours)
    assert "InsertSLC" not in names(without)
    # With SLC on, one last loop closure at home before landing; none without.
    assert {"HomePanorama", "HomeSLC"} <= names(root)
    assert not {"HomePanorama", "HomeSLC"} & names(without)


class FakeRobot(SimpleNamespace):
    """Every service a leaf may use (flight, navigation, planning, events) in one fake."""

    def __init__(self, plans):
        super().__init__(
            events=[],
            holds=0,
            plans=list(plans),
            viewpoint_count=0,
            home_world=np.zeros(3),
            spec=SimpleNamespace(altitude=1.0),
            limit=None,
        )

    def services(self) -> dict:
        return {"flight": self, "navigation": self, "planning": self, "events": self}

    def plan(self):
        outcome = self.plans.pop(0)
        if isinstance(outcome, Exception):
            raise outcome
        return outcome

    def plan_async(self, cruise_z, goal=None):
        self.goals_kept = [*getattr(self, "goals_kept", []), goal]
        future = Future()
        try:
            future.set_result(self.plan())
        except Exception as exc:
            future.set_exception(exc)
        return future

    plans_frontiers = True

    def frontier_change(self):
        return 0.0

    def emit(self, name, **fields):
        self.events.append(name)

    def plugin_hook(self, name, **kwargs):
        pass

    def hold(self):
        self.holds += 1

    def time(self):
        return 0.0

    def limit_reached(self):
        return self.limit


@pytest.fixture(autouse=True)
def clean_blackboard():
    py_trees.blackboard.Blackboard.clear()
    yield
    py_trees.blackboard.Blackboard.clear()


def tick(behaviour) -> Status:
    behaviour.tick_once()
    status = behaviour.status
    if status != Status.RUNNING:
        behaviour.stop(status)  # as a parent composite would: the next tick initialises again
    return status


def retry_planning(robot, max_replan_failures: int):
    """The tree's RetryPlanning decorator around its Replan leaf, set up with ``robot``."""
    root = build_exploration_tree(mission(max_replan_failures=max_replan_failures), {**STOCK})
    (retry,) = [n for n in root.iterate() if n.name == "RetryPlanning"]
    assert isinstance(retry.decorated, Replan)
    retry.decorated.setup(**robot.services())
    return retry


def test_replan_is_retried_after_planner_failures_then_gives_up():
    robot = FakeRobot([RuntimeError("boom")] * 3)
    retry = retry_planning(robot, max_replan_failures=3)
    assert tick(retry) == Status.RUNNING
    assert tick(retry) == Status.RUNNING
    assert tick(retry) == Status.FAILURE
    assert robot.events.count("planner_error") == 3 and robot.holds == 3
    assert "the planner failed (RuntimeError: boom)" in py_trees.blackboard.Blackboard.storage["/exploration"]


def test_replan_recovers_after_a_failure_and_leaves_no_goal_when_nothing_is_left():
    item = TourItem(TourItemKind.EXPLORE, np.array([1.0, 2.0, 1.0]), 0.0, 5.0, 7)
    robot = FakeRobot([RuntimeError("once"), [item], []])
    retry = retry_planning(robot, max_replan_failures=3)
    assert tick(retry) == Status.RUNNING
    assert tick(retry) == Status.SUCCESS
    storage = py_trees.blackboard.Blackboard.storage
    assert storage["/goal"] is item and storage["/exploration"] == "exploring"
    assert tick(retry) == Status.SUCCESS
    assert storage["/goal"] is None and storage["/exploration"].startswith("complete")


def test_behaviour_refuses_setup_without_its_services():
    with pytest.raises(KeyError, match="needs setup\\(flight=..., planning=..., events=...\\)"):
        Replan().setup()
    with pytest.raises(KeyError, match="needs setup\\(planning=...\\)"):
        Replan().setup(flight=object(), events=object())


class Forever(py_trees.behaviour.Behaviour):
    def __init__(self):
        super().__init__("Forever")
        self.stopped = False

    def update(self):
        return Status.RUNNING

    def terminate(self, new_status):
        self.stopped = new_status == Status.INVALID


def test_within_limits_cuts_its_child_short_once_a_limit_is_reached():
    robot = FakeRobot([])
    child = Forever()
    guard = WithinLimits("WithinLimits", child)
    guard.setup(flight=robot, events=robot)
    assert tick(guard) == Status.RUNNING
    robot.limit = "time limit 300 s"
    assert tick(guard) == Status.FAILURE and child.stopped
    assert py_trees.blackboard.Blackboard.storage["/exploration"] == "stopped: time limit 300 s"
    assert robot.events == ["limit_reached"]


class Scripted(py_trees.behaviour.Behaviour):
    """Returns the given statuses, one per tick."""

    def __init__(self, statuses):
        super().__init__("Scripted")
        self.statuses = list(statuses)

    def update(self):
        return self.statuses.pop(0)


def test_skip_unreachable_counts_goals_in_a_row_across_its_runs():
    F, S, R = Status.FAILURE, Status.SUCCESS, Status.RUNNING
    skip = SkipUnreachable("SkipUnreachable", Scripted([F, R, F, S, F, F, F]), max_unreachable=3)
    # each run is one iteration of the exploration loop: a new goal, a new run of the decorator
    assert [tick(skip) for _ in range(6)] == [S, R, S, S, S, S]  # 2 in a row, reached, 2 in a row
    assert skip.feedback_message == "skipped (2 in a row)"
    assert tick(skip) == F
    assert py_trees.blackboard.Blackboard.storage["/exploration"] == "stopped: 3 goals in a row unreachable"


def test_replan_follows_the_tour_until_half_is_done():
    items = [TourItem(TourItemKind.EXPLORE, np.array([float(i), 0.0, 1.0]), 0.0, 5.0, i) for i in range(4)]
    fresh = TourItem(TourItemKind.EXPLORE, np.array([9.0, 9.0, 1.0]), 0.0, 5.0, 9)
    robot = FakeRobot([list(items), [fresh]])
    replan = Replan()
    replan.setup(**robot.services())
    storage = py_trees.blackboard.Blackboard.storage
    assert tick(replan) == Status.SUCCESS and storage["/goal"] is items[0]
    assert tick(replan) == Status.SUCCESS and storage["/goal"] is items[1]  # 1 of 4 done: follow
    assert replan.feedback_message == "following the tour: 3 stops left"
    assert tick(replan) == Status.SUCCESS  # 2 of 4 done: receding horizon
    assert storage["/tour"] == [fresh] and robot.plans == []


def test_a_planner_of_known_objects_is_not_replanned_for_moving_frontiers():
    items = [TourItem(TourItemKind.EXPLORE, np.array([float(i), 0.0, 1.0]), 0.0, 5.0, i) for i in range(4)]
    fresh = TourItem(TourItemKind.EXPLORE, np.array([9.0, 9.0, 1.0]), 0.0, 5.0, 9)
    frontiers = FakeRobot([list(items), [fresh]])
    frontiers.frontier_change = lambda: 1.0  # every frontier changed since the tour was planned
    replan = Replan()
    replan.setup(**frontiers.services())
    storage = py_trees.blackboard.Blackboard.storage
    assert tick(replan) == Status.SUCCESS and storage["/goal"] is items[0]
    assert tick(replan) == Status.SUCCESS and storage["/tour"] == [fresh]  # replanned at once
    objects = FakeRobot([list(items), [fresh]])
    objects.frontier_change = lambda: 1.0
    objects.plans_frontiers = False  # PAMS: views of known objects
    replan = Replan()
    replan.setup(**objects.services())
    assert tick(replan) == Status.SUCCESS and storage["/goal"] is items[0]
    assert tick(replan) == Status.SUCCESS and storage["/goal"] is items[1]  # keeps following


def test_a_replan_hands_the_planner_the_exploration_goal_the_robot_was_flying_to():
    far = TourItem(TourItemKind.EXPLORE, np.array([8.0, 0.0, 1.0]), 0.0, 5.0, 0)
    slc = TourItem(TourItemKind.SLC, np.array([8.0, 0.0, 1.0]), 0.0, 5.0, 2)
    robot = FakeRobot([[far], [slc], [far]])
    robot.frontier_change = lambda: 1.0  # replan at every iteration
    replan = Replan()
    replan.setup(**robot.services())
    for _ in range(3):
        assert tick(replan) == Status.SUCCESS
    # no goal yet; the exploration goal (whether it was reached is the planning service's to
    # say: test_planning_service); an SLC stop is no exploration goal
    assert robot.goals_kept[0] is None
    np.testing.assert_allclose(robot.goals_kept[1], far.position)
    assert robot.goals_kept[2] is None


class StuckRobot(FakeRobot):
    """A robot whose setpoints never move it (a goal the guard or controller cannot reach)."""

    def __init__(self):
        super().__init__([])
        self.t = 0.0
        self.unreachable_marked = []
        self.paths = 0
        self.camera = SimpleNamespace(hfov=1.5)

    def time(self):
        return self.t

    def request_path(self, goal, *, along_trail=False):
        from concurrent.futures import Future

        self.paths += 1
        future = Future()
        future.set_result(np.array([[0.0, 0.0, 1.0], goal]))
        return future

    def position_world(self):
        return np.array([0.0, 0.0, 1.0])

    def yaw_world(self):
        return 0.0

    def limit_reached(self):
        return None

    def candidate_viewpoints(self):
        return []

    def wants_view_near(self, position, within):
        return False

    def segment_clear_local(self, a, b):
        return True

    def plan_local_path(self, a, b):
        return None

    def send_setpoint_world(self, position, yaw):
        pass

    def mark_unreachable(self, position):
        self.unreachable_marked.append(position)


def fly(robot, go, ticks: int, dt: float = 0.1) -> list[Status]:
    statuses = []
    for _ in range(ticks):
        statuses.append(tick(go))
        robot.t += dt
        if statuses[-1] != Status.RUNNING:
            break
    return statuses


def goal_to(robot, name="GoToSLC"):
    """A GoTo to an SLC goal 5 m ahead under its give-up decorator, as the stock trees build it."""
    py_trees.blackboard.Blackboard.set(
        "/goal", TourItem(TourItemKind.SLC, np.array([5.0, 0.0, 1.0]), 0.0, 1.0, 3)
    )
    go = go_to(STOCK, name, early_exit=False)
    for node in go.iterate():
        node.setup(**robot.services())
    return go


def test_goto_gives_up_a_goal_it_makes_no_progress_towards():
    robot = StuckRobot()
    go = goal_to(robot)
    statuses = fly(robot, go, 250)  # 25 s of 0.1 s ticks
    assert statuses[-1] == Status.FAILURE and go.feedback_message == "no progress for 20 s"
    # the clock starts at the first tick (t = 0): the first tick with more than 20 s gone gives up
    assert len(statuses) == 201 and robot.unreachable_marked and robot.paths == 1
    assert robot.holds == 1 and go.decorated.status == Status.FAILURE


class CrawlingRobot(StuckRobot):
    """Gets 0.05 m closer per tick: 0.1 m every other tick, progress each time."""

    def __init__(self):
        super().__init__()
        self.here = np.array([0.0, 0.0, 1.0])

    def position_world(self):
        return self.here.copy()

    def send_setpoint_world(self, position, yaw):
        self.here = self.here + [0.05, 0.0, 0.0] if self.t < 5.0 else self.here  # then it stalls


def test_goto_progress_resets_the_no_progress_clock():
    robot = CrawlingRobot()
    go = goal_to(robot)
    statuses = fly(robot, go, 400)
    assert statuses[-1] == Status.FAILURE and go.feedback_message == "no progress for 20 s"
    assert 24.9 < robot.t < 25.5  # the last 0.1 m gained just before 5 s, then 20 s


class HeldInPlaceRobot(StuckRobot):
    """Stuck under a goal whose frontier stays (an exploration goal, the tour going stale)."""

    plans_frontiers = True

    def wants_view_near(self, position, within):
        return True


def test_goto_gives_up_a_goal_it_is_held_from_although_the_tour_keeps_going_stale():
    """The tour goes stale every 6 s and the same goal starts again from the same spot: the
    no-progress clock goes on across those runs (a fresh clock each time never gave up)."""
    robot = HeldInPlaceRobot()
    py_trees.blackboard.Blackboard.set(
        "/goal", TourItem(TourItemKind.EXPLORE, np.array([5.0, 0.0, 1.0]), 0.0, 1.0, 3)
    )
    go = go_to(STOCK, "GoToViewpoint", early_exit=True, replan_period=6.0)
    for node in go.iterate():
        node.setup(**robot.services())
    runs, status = 0, Status.SUCCESS
    while status == Status.SUCCESS and robot.t < 60.0:
        py_trees.blackboard.Blackboard.set("/tour_time", robot.t)  # a new plan, the same goal
        if runs:
            go.stop(Status.INVALID)  # as the exploration loop's sequence does when it restarts
        runs += 1
        statuses = fly(robot, go, 100)
        status = statuses[-1]
    assert status == Status.FAILURE and go.feedback_message == "no progress for 20 s"
    assert 3 <= runs <= 5 and 20.0 < robot.t < 21.0
    assert len(robot.unreachable_marked) == 1


class BlockedRobot(StuckRobot):
    """The local map shows every way blocked."""

    def segment_clear_local(self, a, b):
        return False


def test_goto_gives_up_when_the_way_is_blocked_three_times():
    robot = BlockedRobot()
    go = goal_to(robot)
    statuses = fly(robot, go, 10)
    # blocked twice: new paths, flying on; the third time the goal is given up, in that tick
    assert statuses == [Status.RUNNING, Status.RUNNING, Status.FAILURE]
    assert go.feedback_message == "the local map showed the way blocked 3 times"
    assert len(robot.unreachable_marked) == 1 and robot.holds == 1


class LongWayRobot(BlockedRobot):
    """Blocked at every look, but 2 m further on each time: a long way with obstacles, each flown
    round (each block's new path starts where the last one took it)."""

    def position_world(self):
        return np.array([2.0 * (self.paths - 1), 0.0, 1.0])


def test_blocks_far_apart_are_a_long_way_not_a_blocked_one():
    robot = LongWayRobot()
    go = goal_to(robot)
    statuses = fly(robot, go, 6)
    assert all(st == Status.RUNNING for st in statuses) and robot.paths >= 6
    assert not robot.unreachable_marked
    # the same blocks 0.4 m apart: one place, given up at the third
    robot = LongWayRobot()
    robot.position_world = lambda: np.array([0.4 * (robot.paths - 1), 0.0, 1.0])
    go = goal_to(robot)
    assert fly(robot, go, 10)[-1] == Status.FAILURE
    assert go.feedback_message == "the local map showed the way blocked 3 times"


class CornerRobot(StuckRobot):
    """At the top of a shaft, beside a slab edge and a wall: the clearance guards send the robot
    where it is for any setpoint straight towards the far waypoint (the step projects to nothing),
    and let it fly a way round (rise first) that the fine local map has, when ``way_round``."""

    def __init__(self, way_round: bool):
        super().__init__()
        self.here = np.array([0.0, 0.0, 1.0])
        self.way_round = way_round
        self.local_plans = 0

    def position_world(self):
        return self.here.copy()

    def send_setpoint_world(self, position, yaw):
        step = np.asarray(position) - self.here
        if abs(step[1]) < 1e-6 and abs(step[2]) < 1e-6:  # straight on: held where it is
            return self.here.copy()
        self.here = self.here + step * min(1.0, 0.2 / max(np.linalg.norm(step), 1e-9))
        return self.here.copy()  # where the guards let it go this tick

    def plan_local_path(self, a, b):
        self.local_plans += 1
        return np.array([a, a + [0.0, 0.0, 0.5], b + [0.0, 0.0, 0.5], b]) if self.way_round else None

    def emit(self, name, **fields):
        self.events.append((name, fields))


def test_goto_held_in_place_by_the_guards_takes_a_detour_at_once():
    """Not 20 s of hovering per goal (demo seed 1 with box landmarks lost 300 s that way)."""
    robot = CornerRobot(way_round=True)
    go = goal_to(robot)
    statuses = fly(robot, go, 400)
    assert statuses[-1] == Status.SUCCESS and not robot.unreachable_marked
    detours = [f for name, f in robot.events if name == "detour"]
    assert detours and robot.local_plans >= 1
    first = next(i for i, (name, _) in enumerate(robot.events) if name == "detour")
    assert first == 0 and robot.t < 15.0  # held for HOLD_PATIENCE, then round


def test_goto_held_in_place_with_no_way_round_gives_up_as_blocked():
    robot = CornerRobot(way_round=False)
    go = goal_to(robot)
    statuses = fly(robot, go, 400)
    assert statuses[-1] == Status.FAILURE and len(robot.unreachable_marked) == 1
    assert go.feedback_message == "the local map showed the way blocked 3 times"
    assert robot.t < 5.0  # three holds of HOLD_PATIENCE each, not the 20 s no-progress clock


class MovingRobot(StuckRobot):
    """A robot that moves where it is sent (its ``send_setpoint_world`` says how), from the origin
    at 1 m, heading +x."""

    def __init__(self):
        super().__init__()
        self.here, self.yaw = np.array([0.0, 0.0, 1.0]), 0.0

    def position_world(self):
        return self.here.copy()

    def yaw_world(self):
        return self.yaw

    def mark_visited(self, position):
        pass


class TableRobot(MovingRobot):
    """A table the global map missed stands across the straight path at x 2 m; the local map
    shows it (segments within 0.4 m of it are blocked) and has a way round it at y 1 m."""

    TABLE = np.array([2.0, 0.0, 1.0])

    def __init__(self):
        super().__init__()
        self.local_plans = []

    def send_setpoint_world(self, position, yaw):
        step = np.asarray(position) - self.here
        self.here = self.here + step * min(1.0, 0.2 / max(np.linalg.norm(step), 1e-9))
        self.yaw = yaw

    def segment_clear_local(self, a, b):
        t = np.linspace(0.0, 1.0, 50)[:, None]
        return bool(np.all(np.linalg.norm(a + t * (b - a) - self.TABLE, axis=1) > 0.4))

    def plan_local_path(self, a, b):
        self.local_plans.append((a.copy(), b.copy()))
        return np.array([a, [1.0, 1.0, 1.0], [3.0, 1.0, 1.0], b])

    def emit(self, name, **fields):
        self.events.append((name, fields))


def test_goto_flies_round_what_blocks_its_path_on_the_local_map():
    robot = TableRobot()
    go = goal_to(robot)
    statuses = fly(robot, go, 400)
    assert statuses[-1] == Status.SUCCESS and not robot.unreachable_marked
    assert robot.paths == 1  # no new global path: the detour rejoined the first one
    (start, rejoin), *_ = robot.local_plans
    assert np.isclose(np.linalg.norm(rejoin - start), go.decorated.DETOUR_REJOIN)  # 2.5 m on along it
    assert [name for name, _ in robot.events].count("detour") == 1


class CeilingRobot(StuckRobot):
    """Flies straight to what it is sent, but a guard keeps it 0.3 m below every setpoint."""

    def __init__(self):
        super().__init__()
        self.here = np.array([0.0, 0.0, 1.0])

    def position_world(self):
        return self.here.copy()

    def send_setpoint_world(self, position, yaw):
        self.here = np.asarray(position, float) - [0.0, 0.0, 0.3]
        return self.here.copy()


def test_goto_counts_a_goal_the_guards_hold_it_off_as_reached():
    from amslam.trees.behaviours import GoTo

    robot = CeilingRobot()
    py_trees.blackboard.Blackboard.set(
        "/goal", TourItem(TourItemKind.SLC, np.array([5.0, 0.0, 1.0]), 0.0, 1.0, 3)
    )
    go = GoTo("GoToSLC", early_exit=False)
    go.setup(**robot.services())
    statuses = fly(robot, go, 100)
    assert statuses[-1] == Status.SUCCESS and go.feedback_message == "arrived"
    assert robot.t < 1.0 and not robot.unreachable_marked


class NoWayBackRobot(MovingRobot):
    """Flies straight to what it is sent; its map has no path to the goal, its flown trail has."""

    TRAIL = np.array([[0.0, 0.0, 1.0], [0.0, 2.0, 1.0], [5.0, 2.0, 1.0], [5.0, 0.0, 1.0]])

    def __init__(self):
        super().__init__()
        self.asked = []

    def request_path(self, goal, *, along_trail=False):
        self.asked.append(along_trail)
        future = Future()
        future.set_result(self.TRAIL.copy() if along_trail else None)
        return future

    def send_setpoint_world(self, position, yaw):
        self.here, self.yaw = np.asarray(position, float).copy(), yaw
        return self.here.copy()


@pytest.mark.parametrize("follow_trail", [True, False])
def test_the_way_home_follows_the_flown_trail_where_the_map_has_no_path(follow_trail):
    from amslam.trees.behaviours import GoTo

    robot = NoWayBackRobot()
    py_trees.blackboard.Blackboard.set(
        "/home", TourItem(TourItemKind.EXPLORE, np.array([5.0, 0.0, 1.0]), 0.0, 0.0, -1)
    )
    go = GoTo("GoHome", goal_key="/home", early_exit=False, follow_trail=follow_trail)
    go.setup(**robot.services())
    statuses = fly(robot, go, 200)
    if follow_trail:
        # the map first, then the trail, flown waypoint by waypoint round the corner it made
        assert statuses[-1] == Status.SUCCESS and robot.asked == [False, True]
        assert "path_along_trail" in robot.events and not robot.unreachable_marked
        np.testing.assert_allclose(robot.here, [5.0, 0.0, 1.0])
    else:  # an exploration goal the map cannot reach stays unreachable
        assert statuses[-1] == Status.FAILURE and robot.asked == [False]
        assert robot.unreachable_marked and "path_along_trail" not in robot.events


def test_the_stock_way_home_follows_the_trail():
    from amslam.trees.behaviours import return_home

    home = return_home(STOCK)
    assert [n.follow_trail for n in home.iterate() if n.name == "GoHome"] == [True]
