"""The clearance guard: setpoints keep the straight flight clear of what the local map shows."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from amslam.errors import AmslamError
from amslam.mission import LimitsSection
from amslam.robot import Robot
from amslam.setpoints import SetpointFilter
from amslam.types import Odometry, RobotSpec, VoxelState

VOXEL = 0.1
RADIUS = 0.25


class BoxMap:
    """Local map of axis-aligned solid boxes, voxelised at 0.1 m like the real local map."""

    def __init__(self, boxes):
        self.boxes = [(np.asarray(lo, float), np.asarray(hi, float)) for lo, hi in boxes]

    def states(self, points, *, local=False):
        centres = (np.floor(np.asarray(points) / VOXEL) + 0.5) * VOXEL
        out = np.full(len(centres), VoxelState.FREE, dtype=np.int8)
        for lo, hi in self.boxes:
            # a voxel is occupied when its box overlaps the solid (touching is not overlapping)
            inside = np.all((centres + VOXEL / 2 > lo + 1e-6) & (centres - VOXEL / 2 < hi - 1e-6), axis=1)
            out[inside] = VoxelState.OCCUPIED
        return out

    def blocked(self, points, *, local=False, climbing=False):
        """Every voxel of this map is seen (free or solid): the solid ones are the obstacles."""
        return self.states(points, local=local) == VoxelState.OCCUPIED

    def clearance(self, p):
        """True distance from p to the nearest box surface."""
        return min(
            float(np.linalg.norm(np.maximum(lo - p, 0) + np.maximum(p - hi, 0))) for lo, hi in self.boxes
        )


class PointVehicle:
    """Flies towards its setpoint at up to 1 m/s, first order, 10 Hz."""

    def __init__(self, start):
        self.p = np.asarray(start, float)
        self.setpoints = []

    def odometry(self):
        T = np.eye(4)
        T[:3, 3] = self.p
        return Odometry(0.0, T)

    def set_setpoint(self, position, yaw):
        self.setpoints.append(np.asarray(position, float))
        step = self.setpoints[-1] - self.p
        length = np.linalg.norm(step)
        self.p = self.p + (step if length <= 0.1 else step * 0.1 / length)


def make_robot(world: BoxMap, start) -> Robot:
    return Robot(
        platform=PointVehicle(start),
        mapping=world,
        correction=lambda: np.eye(4),
        slam_name="no SLAM",
        spec=RobotSpec(radius=RADIUS),
        limits=LimitsSection(),
        setpoints=SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0),
    )


# A wall along x at y = 2 (0.1 m thick) with a 1.2 m door from x = 0.4 to x = 1.6; floor far below.
DOOR = BoxMap([((-3, 2.0, 0), (0.4, 2.1, 3)), ((1.6, 2.0, 0), (4, 2.1, 3))])


def fly(robot: Robot, goal, ticks=80):
    clearances = []
    for _ in range(ticks):
        robot.send_setpoint_world(np.asarray(goal, float), 0.0)
        clearances.append(DOOR.clearance(robot.platform.p) if robot.mapping is DOOR else None)
    return clearances


def test_a_path_grazing_a_door_jamb_is_pushed_into_the_opening():
    # The straight line from (0.55, 1.0) to (0.55, 3.5) passes 0.15 m from the west jamb: a
    # path laid on a world map that put the door 0.2 m further west.
    start, goal = (0.55, 1.0, 1.2), (0.55, 3.5, 1.2)
    line = np.linspace(start, goal, 200)
    assert min(DOOR.clearance(p) for p in line) < RADIUS  # without the guard: a collision
    robot = make_robot(DOOR, start)
    clearances = fly(robot, goal)
    assert min(clearances) >= RADIUS + SetpointFilter.GUARD_MARGIN - 1e-9
    assert robot.platform.p[1] > 2.9  # and it went through the door


def test_a_goal_behind_a_wall_stops_the_vehicle_short_of_it():
    robot = make_robot(DOOR, (3.0, 1.0, 1.2))
    clearances = fly(robot, (3.0, 3.0, 1.2))
    assert min(clearances) >= RADIUS + SetpointFilter.GUARD_MARGIN - 1e-9
    assert robot.platform.p[1] < 2.0 - RADIUS


def test_setpoints_away_from_obstacles_are_untouched():
    robot = make_robot(DOOR, (1.0, 0.5, 1.2))
    goal = np.array([1.0, -0.5, 1.2])
    robot.send_setpoint_world(goal, 0.0)
    np.testing.assert_allclose(robot.platform.setpoints[-1], goal)


def test_sliding_along_a_wall_keeps_the_safe_distance():
    # Flying parallel to the wall but aimed 0.1 m from it: the guard keeps the flight off.
    robot = make_robot(DOOR, (-2.5, 1.6, 1.2))
    clearances = fly(robot, (-0.5, 1.9, 1.2), ticks=40)
    assert min(clearances) >= RADIUS + SetpointFilter.GUARD_MARGIN - 1e-9
    assert robot.platform.p[0] > -1.0  # still made progress along the wall


def test_a_non_finite_setpoint_holds_and_names_the_culprit():
    robot = make_robot(DOOR, (1.0, 0.5, 1.2))
    with pytest.raises(AmslamError, match="behaviour asked for setpoint"):
        robot.send_setpoint_world(np.array([np.nan, 0.0, 1.2]), 0.0)
    np.testing.assert_allclose(robot.platform.setpoints[-1], [1.0, 0.5, 1.2])  # held where it was
    robot.correction = lambda: np.full((4, 4), np.nan)
    with pytest.raises(AmslamError, match="SLAM backend no SLAM returned T_world_odom"):
        robot.send_setpoint_world(np.array([1.0, 0.0, 1.2]), 0.0)


# An open-topped building's wall (top 2.5 m) on a floor; the flight area's top is the wall's.
OPEN_WALL = BoxMap([((-3, 2.0, 0), (3, 2.1, 2.5)), ((-5, -5, -0.2), (5, 5, 0.0))])


def test_the_guards_never_lift_the_vehicle_over_the_flight_areas_top():
    # A path laid on a coarse map with a hole in the wall runs just over its top: the height guard
    # takes the wall's top for a floor and lifts the setpoint min_height above it (the PAL home
    # was flown at 3.27 m, its walls 2.5 m). Under the area's ceiling the vehicle stays inside.
    over_the_wall = (0.0, 2.05, 2.6)

    def flown(ceiling):
        robot = make_robot(OPEN_WALL, (0.0, 1.0, 2.0))
        robot.setpoints = SetpointFilter(OPEN_WALL, RADIUS, 0.7, 0.3, ceiling=ceiling)
        heights, clearances = [], []
        for _ in range(60):
            robot.send_setpoint_world(np.asarray(over_the_wall), 0.0)
            heights.append(robot.platform.p[2])
            clearances.append(OPEN_WALL.clearance(robot.platform.p))
        return robot.platform.p, max(heights), min(clearances)

    _, highest, _ = flown(np.inf)
    assert highest > 2.5 + RADIUS  # without a ceiling: over the wall
    end, highest, closest = flown(2.5 - RADIUS)
    assert highest <= 2.5 - RADIUS + 1e-6
    assert closest >= RADIUS + SetpointFilter.GUARD_MARGIN - 1e-9
    assert end[1] < 2.0 - RADIUS  # still on its side of the wall


def test_a_long_step_over_something_below_is_flown_short_under_the_top_not_refused():
    # The turtlebot3 house: the vehicle at 1.57 m, a sofa's top 0.5 m below and 0.4 m beside it,
    # a detour waypoint 2.6 m away past the sofa, the area's top at 2.25 m. The corridor turned the
    # whole step into a lift over the top, so every setpoint was refused and the vehicle was held
    # 80 s; an eighth of the step passes the sofa with little lift.
    sofa = ((-4.0, 2.0, 0.0), (-3.47, 3.5, 1.07))
    floor = ((-9, -9, -0.2), (9, 9, 0.0))
    world = BoxMap([sofa, floor])
    robot = make_robot(world, (-3.92, 2.93, 1.57))
    robot.setpoints = SetpointFilter(world, RADIUS, 0.0, 0.0, ceiling=2.25)
    start = robot.platform.p.copy()
    clearances = []
    for _ in range(40):
        robot.send_setpoint_world(np.array([-1.75, 1.57, 1.89]), 0.0)
        clearances.append(world.clearance(robot.platform.p))
    assert np.linalg.norm(robot.platform.p - start) > 1.5  # it flew on, past the sofa
    assert max(sp[2] for sp in robot.platform.setpoints) <= 2.25 + 1e-6
    assert min(clearances) >= RADIUS + SetpointFilter.GUARD_MARGIN - 1e-9


def test_the_ceiling_is_placed_in_the_odometry_frame_by_the_slam_correction():
    robot = make_robot(BoxMap([]), (0.0, 0.0, 1.0))
    robot.setpoints = SetpointFilter(robot.mapping, RADIUS, 0.0, 0.0, ceiling=2.0)
    T = np.eye(4)
    T[2, 3] = 0.5  # the odometry frame sits 0.5 m above the world's origin
    robot.correction = lambda: T
    sent_world = robot.send_setpoint_world(np.array([0.0, 0.0, 3.0]), 0.0)
    assert sent_world[2] == pytest.approx(2.0)
    np.testing.assert_allclose(robot.platform.setpoints[-1], [0.0, 0.0, 1.5])


# -- landing -------------------------------------------------------------------------------------

FLOOR = ((-5, -5, -0.2), (5, 5, 0.0))
TABLE = ((0.2, -0.5, 0.0), (1.2, 0.5, 0.75))  # its edge 0.2 m beside the column at the origin


def test_a_descent_beside_a_table_is_not_clear_and_a_spot_away_from_it_is() -> None:
    world = BoxMap([FLOOR, TABLE])
    guard = SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0)
    here = np.array([0.0, 0.0, 1.2])
    assert not guard.descent_clear(here)  # straight down passes 0.2 m from the table's edge
    spot = guard.landing_spot(here)
    assert spot is not None and spot[2] == pytest.approx(1.2)
    assert guard.descent_clear(spot)
    # the whole column keeps the robot radius from the table, and the move there is short
    column = [spot - np.array([0, 0, dz]) for dz in np.arange(0.0, 1.0, 0.05)]
    assert min(BoxMap([TABLE]).clearance(p) for p in column) > RADIUS
    assert np.linalg.norm(spot[:2]) <= 1.0
    # in the open the robot lands where it is
    open_floor = SetpointFilter(BoxMap([FLOOR]), RADIUS, min_height=0.0, min_headroom=0.0)
    np.testing.assert_allclose(open_floor.landing_spot(here), here)


def test_a_counter_top_with_free_space_under_it_is_no_landing_surface() -> None:
    # the cafe: a robot that could not get home hovered 0.7 m over a counter's top (a 6 cm board at
    # 1.3 m, free space under it) and landed straight down; the top is furniture, not the floor
    counter = ((-1.0, -0.6, 1.27), (1.0, 0.6, 1.335))
    guard = SetpointFilter(BoxMap([FLOOR, counter]), RADIUS, min_height=0.0, min_headroom=0.0)
    here = np.array([0.0, 0.0, 2.0])
    assert not guard.descent_clear(here)
    spot = guard.landing_spot(here)
    assert spot is not None and spot[2] == pytest.approx(2.0)
    # beside the counter, on the floor: the whole descent keeps the radius from the counter
    column = [spot - np.array([0, 0, dz]) for dz in np.arange(0.0, 2.0, 0.05)]
    assert min(BoxMap([counter]).clearance(p) for p in column) > RADIUS
    # a slab with the room under it taller than furniture is a floor: land on it
    slab = ((-5, -5, 2.55), (5, 5, 2.75))
    upper = SetpointFilter(BoxMap([FLOOR, slab]), RADIUS, min_height=0.0, min_headroom=0.0)
    assert upper.descent_clear(np.array([0.0, 0.0, 3.95]))


def test_a_column_half_off_a_slabs_edge_is_no_landing_column() -> None:
    # a PAMS survey landed half off the lot's ground slab (its edge 0.1 m from the column's centre,
    # the void past it seen free by the rays that went by): the surface under the centre is no
    # support for the whole vehicle
    slab = ((-5, -5, -0.3), (0.1, 5, 0.0))
    guard = SetpointFilter(BoxMap([slab]), RADIUS, min_height=0.0, min_headroom=0.0)
    here = np.array([0.0, 0.0, 1.5])
    assert guard._descent(here)[2]  # nothing beside the column to touch on the way down
    assert not guard.descent_clear(here)
    spot = guard.landing_spot(here)
    assert spot is not None and spot[2] == pytest.approx(1.5)
    assert spot[0] <= 0.1 - RADIUS + 1e-9  # the whole footprint over the slab
    assert guard.descent_clear(spot)
    # the same edge unseen beyond (unknown, not free) is no evidence of a void: a floor's far
    # side is never seen
    unseen_beyond = WindowedMap(BoxMap([slab]), np.zeros(3), bottom=-10.0)
    unseen_beyond.local_unseen = ((0.1, -5, -5), (5, 5, 0.0))
    guard = SetpointFilter(unseen_beyond, RADIUS, min_height=0.0, min_headroom=0.0)
    assert guard.descent_clear(here)


def test_low_past_a_slabs_edge_the_slab_is_the_landing_spot() -> None:
    # the same survey, stepped down to 0.8 m over the slab, found itself 0.05 m past its edge (the
    # global map had placed the edge further out): below it the local map sees free space to the
    # window's bottom and nothing under that; the slab beside it is where to land
    slab = ((-5, -5, -0.3), (0.1, 5, 0.0))
    world = WindowedMap(BoxMap([slab]), np.zeros(3), bottom=-1.0, unseen=((0.1, -5, -20), (5, 5, -1.0)))
    guard = SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0)
    T_world_odom = np.eye(4)
    here = np.array([0.15, 0.0, 0.8])
    assert not np.isfinite(guard._descent(here, T_world_odom)[1])  # no surface under it in reach
    spot = guard.landing_spot(here, T_world_odom)
    assert spot is not None and spot[0] <= 0.1 - RADIUS + 1e-9 and guard.descent_clear(spot)
    # from higher up, the surface beside is no landing spot (a car's roof over unseen ground)
    assert guard.landing_spot(here + np.array([0.0, 0.0, 1.5]), T_world_odom) is None


def test_no_floor_in_reach_or_no_clear_spot_gives_none() -> None:
    here = np.array([0.0, 0.0, 1.2])
    no_floor = SetpointFilter(BoxMap([TABLE]), RADIUS, min_height=0.0, min_headroom=0.0)
    assert not no_floor.descent_clear(here + np.array([3.0, 0.0, 0.0]))
    # pillars 0.3 m wide, 0.2 m apart, taller than the flight: no column is clear
    pillars = [
        ((x, y, 0.0), (x + 0.3, y + 0.3, 2.0))
        for x in np.arange(-2.5, 2.5, 0.5)
        for y in np.arange(-2.5, 2.5, 0.5)
    ]
    crowded = BoxMap([FLOOR, *pillars])
    here = np.array([0.4, 0.4, 1.2])
    guard = SetpointFilter(crowded, RADIUS, min_height=0.0, min_headroom=0.0)
    assert guard.landing_spot(here) is None


def test_robot_lands_at_a_clear_spot_in_the_world_frame() -> None:
    world = BoxMap([FLOOR, TABLE])
    robot = make_robot(world, [0.0, 0.0, 1.2])
    robot.correction = lambda: np.array([[1, 0, 0, 10.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    spot = robot.landing_spot_world()
    assert spot is not None
    odom = spot - np.array([10.0, 0.0, 0.0])  # back into the odometry frame
    assert np.linalg.norm(odom[:2]) >= 0.2  # it moved off the column beside the table
    assert robot.setpoints.descent_clear(odom)


class HomeMap(BoxMap):
    """The global map's path costs: every point is reachable but those within 0.2 m of ``blocked``
    (a take-off point whose voxel the map holds occupied)."""

    def __init__(self, blocked):
        super().__init__([FLOOR])
        self.blocked = np.asarray(blocked, float)

    def path_costs(self, sources, targets):
        d = np.linalg.norm(np.asarray(targets) - self.blocked, axis=1)
        return np.where(d < 0.2, np.inf, d)[None, :]


def test_home_on_an_occupied_voxel_moves_to_the_nearest_reachable_point() -> None:
    home = np.array([1.2, 5.0, 1.2])
    robot = make_robot(HomeMap(blocked=home), [5.0, 5.0, 1.2])
    near = robot.reachable_near(home)
    assert near is not None and 0.2 <= np.linalg.norm(near - home) <= 0.26
    free = np.array([3.0, 5.0, 1.2])
    np.testing.assert_allclose(robot.reachable_near(free), free)  # a reachable goal stays put
    robot.mapping = SimpleNamespace(path_costs=lambda s, t: np.full((1, len(t)), np.inf))
    assert robot.reachable_near(home) is None


def test_over_ground_the_map_cannot_see_a_car_roof_beside_is_no_landing_spot() -> None:
    # lot_team, 1 robot, seeds 1 and 2: home at 3.45 m, the ground below beyond the local map's
    # reach, a car 0.4 m beside the column: the search took the car's roof as the nearest
    # "surface", moved 1 m over it and descended into the car (clearance 0.245 m)
    car = ((0.6, -1.0, 0.0), (2.4, 3.5, 1.5))
    guard = SetpointFilter(BoxMap([car]), RADIUS, min_height=0.0, min_headroom=0.0)
    home = np.array([0.0, 0.0, 3.45])
    assert not guard.descent_clear(home)  # no surface in reach: not judged clear
    np.testing.assert_allclose(guard.landing_spot(home), home)  # but its column is free: land here
    # right beside the car's side, its column is not free: move away from the car, never over it
    beside = np.array([0.35, 0.0, 3.45])
    spot = guard.landing_spot(beside)
    assert spot is not None and spot[0] < 0.6 - RADIUS - SetpointFilter.GUARD_MARGIN + 1e-9
    column = [spot - np.array([0, 0, dz]) for dz in np.arange(0.0, 3.45, 0.05)]
    assert min(BoxMap([car]).clearance(p) for p in column) > RADIUS


class WindowedMap:
    """The local map's window ends ``bottom`` m above the ground (odometry frame, unknown below);
    the global map (world frame, ``shift`` from the odometry frame) holds the ground and a bench."""

    def __init__(self, world: BoxMap, shift, bottom: float, unseen=None):
        self.world, self.shift, self.bottom = world, np.asarray(shift, float), bottom
        self.unseen = unseen  # a box (world frame) the global map never saw
        self.local_unseen = None  # one (world frame) the local map never saw

    def states(self, points, *, local=False):
        points = np.asarray(points, float)
        if not local:
            out = self.world.states(points)
            if self.unseen is not None:
                lo, hi = (np.asarray(b, float) for b in self.unseen)
                out[np.all((points >= lo) & (points <= hi), axis=1)] = VoxelState.UNKNOWN
            return out
        out = self.world.states(points + self.shift)
        out[points[:, 2] < self.bottom] = VoxelState.UNKNOWN
        if self.local_unseen is not None:
            lo, hi = (np.asarray(b, float) for b in self.local_unseen)
            world = points + self.shift
            out[np.all((world >= lo) & (world <= hi), axis=1)] = VoxelState.UNKNOWN
        return out


def test_at_altitude_the_global_map_sees_below_the_local_maps_reach() -> None:
    # a PAMS overhead survey ended its lawnmower 6 m over the lot, its local map's window ending
    # 3.5 m above the ground, and landed straight down onto a bench it had mapped on the way
    shift = np.array([10.0, -2.0, 0.0])  # world = odometry + shift (the SLAM correction)
    bench = ((9.8, -2.3, 0.0), (11.3, -1.7, 0.5))
    ground = ((-50.0, -50.0, -0.3), (50.0, 50.0, 0.0))
    world = WindowedMap(BoxMap([ground, bench]), shift, bottom=3.5)
    guard = SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0)
    here = np.array([0.5, 0.45, 6.3])  # 0.15 m beside the bench's long side (world y -1.55)
    T_world_odom = np.eye(4)
    T_world_odom[:3, 3] = shift
    np.testing.assert_allclose(guard.landing_spot(here), here)  # blind: the column looks free
    assert not guard._descent(here, T_world_odom)[2]  # the global map shows the bench beside it
    spot = guard.landing_spot(here, T_world_odom)
    assert spot is not None and spot[2] == pytest.approx(6.3)
    column = [spot + shift - np.array([0, 0, dz]) for dz in np.arange(0.0, 6.3, 0.05)]
    assert min(BoxMap([bench]).clearance(p) for p in column) > RADIUS
    assert np.linalg.norm(spot - here) <= SetpointFilter.LANDING_SEARCH
    # away from the bench the robot lands where it is, the ground seen in the global map
    open_lot = here + np.array([0.0, 3.0, 0.0])
    np.testing.assert_allclose(guard.landing_spot(open_lot, T_world_odom), open_lot)
    assert guard._descent(open_lot, T_world_odom)[1] == pytest.approx(0.0, abs=0.11)
    # judged on the global map only: the local map sees no surface below from up here
    assert not guard.surface_seen_locally(open_lot)
    lower = WindowedMap(BoxMap([ground]), shift, bottom=-1.0)  # a window that reaches the ground
    nearer = SetpointFilter(lower, RADIUS, min_height=0.0, min_headroom=0.0)
    assert nearer.surface_seen_locally(open_lot - np.array([0.0, 0.0, 5.3]))  # 1 m over it
    assert not nearer.surface_seen_locally(open_lot - np.array([0.0, 0.0, 4.0]))  # 2.3 m over it


def test_from_altitude_a_column_the_global_map_never_saw_is_no_landing_column() -> None:
    # the survey's last waypoint: 73 % of the box under it unknown when the landing began (the
    # pitched camera had looked ahead, not below), clutter there; the ground around was seen
    shift = np.array([10.0, -2.0, 0.0])
    ground = ((-50.0, -50.0, -0.3), (50.0, 50.0, 0.0))
    unseen = ((10.0, -2.5, 0.0), (11.0, -1.5, 2.0))  # 1 m square under the vehicle, up to 2 m
    world = WindowedMap(BoxMap([ground]), shift, bottom=3.5, unseen=unseen)
    guard = SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0)
    T_world_odom = np.eye(4)
    T_world_odom[:3, 3] = shift
    here = np.array([0.5, 0.0, 6.3])  # over the unseen square's middle
    assert not guard._descent(here, T_world_odom)[2]
    spot = guard.landing_spot(here, T_world_odom)
    assert spot is not None and np.linalg.norm(spot - here) <= SetpointFilter.LANDING_SEARCH
    lo, hi = (np.asarray(b) for b in unseen)
    margin = RADIUS + SetpointFilter.LANDING_MARGIN
    world_xy = spot[:2] + shift[:2]
    assert np.any((world_xy < lo[:2] - margin) | (world_xy > hi[:2] + margin))  # clear of it


def test_how_far_below_the_column_was_seen_free() -> None:
    # the survey's last waypoint again: the global map saw the air under the vehicle down to 2 m
    # and not below (the map reaches 5 m deep from 6.3 m), the local window to 3.5 m
    shift = np.array([10.0, -2.0, 0.0])
    ground = ((-50.0, -50.0, -0.3), (50.0, 50.0, 0.0))
    unseen = ((9.0, -3.5, -0.3), (12.0, -0.5, 2.0))
    world = WindowedMap(BoxMap([ground]), shift, bottom=3.5, unseen=unseen)
    guard = SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0)
    T_world_odom = np.eye(4)
    T_world_odom[:3, 3] = shift
    here = np.array([0.5, 0.0, 6.3])
    assert guard.landing_spot(here, T_world_odom) is None  # no surface judged from up here
    assert guard.seen_free_below(here) == pytest.approx(6.3 - 3.5, abs=0.11)  # the local window
    assert guard.seen_free_below(here, T_world_odom) == pytest.approx(6.3 - 2.0, abs=0.11)
    # a pole beside the column stops what counts as seen free at its top
    pole = ((10.6, -2.0, 0.0), (10.8, -1.8, 4.0))
    world = WindowedMap(BoxMap([ground, pole]), shift, bottom=3.5, unseen=unseen)
    guard = SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0)
    assert guard.seen_free_below(here, T_world_odom) == pytest.approx(6.3 - 4.0, abs=0.11)
    # the top of the column, where the vehicle's body is, was never looked at (the camera pitched
    # down): it is free all the same
    unlooked = ((10.0, -2.5, 6.0), (11.0, -1.5, 6.7))
    world = WindowedMap(BoxMap([ground]), shift, bottom=3.5, unseen=unlooked)
    world.local_unseen = unlooked
    guard = SetpointFilter(world, RADIUS, min_height=0.0, min_headroom=0.0)
    assert guard.seen_free_below(here, T_world_odom) == pytest.approx(6.3, abs=0.11)  # to the ground
