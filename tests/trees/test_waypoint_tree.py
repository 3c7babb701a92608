"""The waypoint tree keeps to the mission's limits: a waypoint it cannot reach does not hold it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.runner import Runner

MAX_TIME = 12.0


def fly_waypoints(tmp_path, points: str, *overrides: str):
    """The demo building under a flight area whose ceiling is 2.2 m (under the first floor's slab)."""
    registry = build_plugin_manager()
    overrides = (
        "tree=waypoints",
        f"waypoints.points={points}",
        "area.lo=[-100.0, -100.0, -1.0]",
        "area.hi=[100.0, 100.0, 2.2]",
        "platform.camera.width=64",
        "platform.camera.height=48",
        *overrides,
    )
    return Runner(load_mission("demo", registry, list(overrides)), registry, tmp_path).run()


def test_an_unreachable_waypoint_ends_the_mission_at_the_time_limit(tmp_path):
    # 100 m up, above the flight area's ceiling (2.2 m, under the first floor's slab): the
    # setpoint guard holds the vehicle under it, so the second waypoint is never reached
    result = fly_waypoints(tmp_path, "[[1.0, 0.0, 1.2], [1.0, 0.0, 100.0]]", f"limits.max_time={MAX_TIME}")

    events = [json.loads(line) for line in (result.run_dir / "events.jsonl").read_text().splitlines()]
    assert result.verdict == "completed", result.verdict
    assert [e["index"] for e in events if e["event"] == "waypoint_reached"] == [0]
    (limit,) = [e for e in events if e["event"] == "limit_reached"]
    assert limit["reason"] == f"time limit {MAX_TIME:.0f} s" and limit["behaviour"] == "FlyWaypointsOrSkip"
    assert MAX_TIME <= limit["t"] < MAX_TIME + 1.0
    (end,) = [e for e in events if e["event"] == "mission_end"]
    assert end["exploration"] == f"stopped: time limit {MAX_TIME:.0f} s" and end["landing"] == "landed"
    # "completed" (it came home) does not hide that the mission was cut short: metrics and report say so
    assert result.metrics["exploration_end"] == end["exploration"]
    metrics = json.loads((result.run_dir / "metrics.json").read_text())
    assert metrics["exploration_end"] == end["exploration"]
    assert f"| exploration ended | {end['exploration']} |" in (result.run_dir / "report.md").read_text()
    assert (
        metrics["way_home"] == "came home"
        and "| way home | came home |" in (result.run_dir / "report.md").read_text()
    )
    # it came back over the take-off point before landing (the return home, as exploration does)
    truth = np.loadtxt(result.run_dir / "ground_truth.tum", ndmin=2)
    assert np.linalg.norm(truth[-1, 1:3] - truth[0, 1:3]) < 0.5


@pytest.mark.parametrize("follow", ["straight", "paths"])
def test_a_waypoint_the_guards_hold_the_vehicle_back_from_is_skipped(tmp_path, follow):
    # the same waypoint above the area's ceiling, with a third one behind it: the vehicle comes
    # no nearer for skip_after seconds (straight legs) or finds no path there (paths), gives the
    # second up and flies on to the third; either way the event says where it was
    points = "[[1.0, 0.0, 1.2], [1.0, 0.0, 100.0], [0.0, 0.0, 1.2]]"
    result = fly_waypoints(
        tmp_path, points, "waypoints.skip_after=4", "limits.max_time=60", f"waypoints.follow={follow}"
    )

    events = [json.loads(line) for line in (result.run_dir / "events.jsonl").read_text().splitlines()]
    assert result.verdict == "completed", result.verdict
    assert [e["index"] for e in events if e["event"] == "waypoint_reached"] == [0, 2]
    (skipped,) = [e for e in events if e["event"] == "waypoint_skipped"]
    reason = "for 4 s" if follow == "straight" else "no way there"
    assert skipped["index"] == 1 and skipped["reason"].endswith(reason)
    assert skipped["at"][2] <= 2.2  # held under the ceiling
    assert not [e for e in events if e["event"] == "limit_reached"]
    (end,) = [e for e in events if e["event"] == "mission_end"]
    assert end["landing"] == "landed" and end["exploration"] == "complete: 3 waypoints, 1 skipped"
    # metrics and report say a waypoint was skipped
    assert result.metrics["exploration_end"] == "complete: 3 waypoints, 1 skipped"
    assert (
        "| exploration ended | complete: 3 waypoints, 1 skipped |"
        in (result.run_dir / "report.md").read_text()
    )


@pytest.mark.parametrize("follow", ["straight", "paths"])
def test_a_waypoint_behind_a_wall_is_reached_along_a_path_and_skipped_in_a_straight_line(tmp_path, follow):
    # the second waypoint is in the room south of the corridor: a straight leg meets the wall
    # (the guards hold the vehicle, and it skips the waypoint); a path goes round through the door
    points = "[[2.2, 0.0, 1.2], [3.0, -2.2, 1.2]]"
    result = fly_waypoints(
        tmp_path,
        points,
        f"waypoints.follow={follow}",
        "mapping.plan_through_unknown=true",
        "limits.max_time=120",
    )
    events = [json.loads(line) for line in (result.run_dir / "events.jsonl").read_text().splitlines()]
    assert result.verdict == "completed", result.verdict
    reached = [e["index"] for e in events if e["event"] == "waypoint_reached"]
    skipped = [e["index"] for e in events if e["event"] == "waypoint_skipped"]
    if follow == "paths":
        assert (reached, skipped) == ([0, 1], [])
        assert result.metrics["exploration_end"] == "complete: 2 waypoints"
        truth = np.loadtxt(result.run_dir / "ground_truth.tum", ndmin=2)
        assert np.min(np.linalg.norm(truth[:, 1:3] - [4.2, 2.8], axis=1)) < 0.5  # it got into the room
    else:
        assert (reached, skipped) == ([0], [1])
    assert result.metrics["closest_approach"]["clearance_m"] > 0.25  # no contact either way
