"""Land: a robot beside furniture first moves to a spot whose descent is clear."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from py_trees.common import Status

from amslam.trees.behaviours import Land


class FakeFlight:
    """Moves 0.1 m per setpoint towards it; lands when asked; knows one clear landing spot; has
    seen its column free down to ``seen_free_to`` m (none of it by default); its local map sees
    the surface below once it is lower than ``local_reach`` (always by default)."""

    def __init__(self, spot, height=1.2, seen_free_to=None, local_reach=np.inf):
        self.p = np.array([0.0, 0.0, height])
        self.local_reach = local_reach
        self.spot = None if spot is None else np.asarray(spot, float)
        self.seen_free_to = height if seen_free_to is None else seen_free_to
        self.landed_at = None
        self.lowest = height  # the lowest point flown before landing
        self.yaws = [0.0]  # the headings asked for
        self.t = 0.0

    def airborne(self):
        return self.landed_at is None

    def position_world(self):
        return self.p.copy()

    def yaw_world(self):
        return 0.0

    def time(self):
        self.t += 0.1
        return self.t

    def landing_spot_world(self):
        return None if self.spot is None else self.spot.copy()

    def seen_free_below(self):
        return max(0.0, float(self.p[2] - self.seen_free_to))

    def landing_surface_seen(self):
        return bool(self.p[2] < self.local_reach)

    def send_setpoint_world(self, position, yaw):
        step = np.asarray(position, float) - self.p
        n = np.linalg.norm(step)
        self.p = self.p + (step if n <= 0.1 else step * 0.1 / n)
        self.lowest = min(self.lowest, float(self.p[2]))
        self.yaws.append(float(yaw))
        return position

    def land(self):
        self.landed_at = self.p.copy()


class Events:
    def __init__(self):
        self.seen = []

    def emit(self, name, **fields):
        self.seen.append(name)


def run(flight, ticks=300):
    leaf, events = Land(), Events()
    leaf.setup(flight=flight, events=events)
    status = None
    for _ in range(ticks):
        leaf.tick_once()
        status = leaf.status
        if status == Status.SUCCESS:
            break
    return status, events.seen


def test_moves_to_the_clear_spot_before_descending():
    flight = FakeFlight(spot=[0.6, 0.0, 1.2])
    status, seen = run(flight)
    assert status == Status.SUCCESS
    np.testing.assert_allclose(flight.landed_at, [0.6, 0.0, 1.2], atol=0.11)
    assert "landing_spot" in seen


def test_lands_in_place_when_here_is_clear_or_nothing_is():
    here_clear = FakeFlight(spot=[0.0, 0.0, 1.2])
    assert run(here_clear)[0] == Status.SUCCESS
    np.testing.assert_allclose(here_clear.landed_at, [0.0, 0.0, 1.2])
    nothing = FakeFlight(spot=None)
    status, seen = run(nothing)
    assert status == Status.SUCCESS and "landing_unchecked" in seen
    np.testing.assert_allclose(nothing.landed_at, [0.0, 0.0, 1.2])


def test_from_altitude_steps_down_through_seen_free_space_then_judges_again():
    # a PAMS survey ends 6 m over the lot and maps 5 m deep: from up there no landing column can
    # be judged (no surface below in reach); its column was seen free down to 1.7 m
    class Survey(FakeFlight):
        def landing_spot_world(self):
            # judged once the ground is in the maps' reach: a clear column 0.4 m aside
            return None if self.p[2] > 3.0 else np.array([0.4, 0.0, self.p[2]])

    flight = Survey(spot=None, height=6.0, seen_free_to=1.7)
    status, seen = run(flight)
    assert status == Status.SUCCESS
    assert seen[:2] == ["landing_step_down", "landing_spot"] and "landing_unchecked" not in seen
    # stepped down no lower than the seen-free part allows, then moved to the judged spot
    assert flight.lowest >= 1.7 + Land.STEP_MARGIN - 0.11
    assert max(flight.yaws) > 0.9 * np.pi  # turned half round down there: the camera saw all the column
    np.testing.assert_allclose(flight.landed_at[:2], [0.4, 0.0], atol=0.11)
    assert flight.landed_at[2] < 3.0


def test_a_spot_judged_on_the_global_map_only_is_stepped_down_to_and_judged_again():
    # a PAMS survey, stepped down to 3.3 m over the lot, judged a spot 0.25 m aside on the global
    # map (the local map's window ends above the ground) and landed half off the ground slab's edge,
    # which the global map had put 0.3 m further out; its local map sees the ground below 2.5 m
    class Survey(FakeFlight):
        def landing_spot_world(self):
            if self.p[2] > 2.5:
                return np.array([0.25, 0.0, self.p[2]])  # the global map's judgement
            return np.array([-0.3, 0.0, self.p[2]])  # the local map's: the edge is nearer

    flight = Survey(spot=None, height=3.3, seen_free_to=0.6, local_reach=2.5)
    status, seen = run(flight)
    assert status == Status.SUCCESS
    assert seen == ["landing_spot", "landing_step_down", "landing_spot"]
    assert flight.lowest >= 0.6 + Land.STEP_MARGIN - 0.11
    assert max(flight.yaws) > 0.9 * np.pi
    np.testing.assert_allclose(flight.landed_at[:2], [-0.3, 0.0], atol=0.11)
    # with no room to step down it lands on the global map's judgement
    low = Survey(spot=None, height=3.3, seen_free_to=3.0, local_reach=2.5)
    status, seen = run(low)
    assert status == Status.SUCCESS and seen == ["landing_spot"]
    np.testing.assert_allclose(low.landed_at[:2], [0.25, 0.0], atol=0.11)


def test_a_column_never_seen_below_is_no_step_down():
    flight = FakeFlight(spot=None, height=6.0)  # nothing below seen free
    status, seen = run(flight)
    assert status == Status.SUCCESS and seen == ["landing_unchecked"]
    np.testing.assert_allclose(flight.landed_at, [0.0, 0.0, 6.0])


def test_home_goal_moves_off_an_occupied_take_off_point():
    from amslam.trees.behaviours import SetHome

    class Flight:
        home_world = np.array([1.2, 5.0, 0.3])
        spec = SimpleNamespace(altitude=0.9)

        def yaw_world(self):
            return 0.0

    moved = np.array([1.45, 5.0, 1.2])
    for near, expected in ((moved, moved), (None, np.array([1.2, 5.0, 1.2]))):
        leaf, events = SetHome(), Events()
        leaf.setup(
            flight=Flight(), navigation=SimpleNamespace(reachable_near=lambda goal, n=near: n), events=events
        )
        leaf.tick_once()
        np.testing.assert_allclose(leaf.bb.get("/home").position, expected)
        assert ("home_moved" in events.seen) == (near is not None)
