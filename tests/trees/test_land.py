"""Land: a robot beside furniture first moves to a spot whose descent is clear."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from py_trees.common import Status

from amslam.trees.behaviours import Land


class FakeFlight:
    """Moves 0.1 m per setpoint towards it; lands when asked; knows one clear landing spot."""

    def __init__(self, spot):
        self.p = np.array([0.0, 0.0, 1.2])
        self.spot = None if spot is None else np.asarray(spot, float)
        self.landed_at = None
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

    def send_setpoint_world(self, position, yaw):
        step = np.asarray(position, float) - self.p
        n = np.linalg.norm(step)
        self.p = self.p + (step if n <= 0.1 else step * 0.1 / n)
        return position

    def land(self):
        self.landed_at = self.p.copy()


class Events:
    def __init__(self):
        self.seen = []

    def emit(self, name, **fields):
        self.seen.append(name)


def run(flight, ticks=50):
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
