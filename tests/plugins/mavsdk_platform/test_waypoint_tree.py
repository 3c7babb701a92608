"""The waypoint tree is platform-independent: it flies in the simulator too (without the guard)."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.errors import MissionError
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from amslam.trees.flight import build_mission_tree

from .conftest import events

POINTS = [[1.0, 0.0, 1.2], [1.0, 0.5, 1.2]]
OVERRIDES = [
    "tree=waypoints",
    f"waypoints.points={POINTS}",
    "platform.camera.width=64",
    "platform.camera.height=48",
]


def test_waypoints_in_the_simulator(tmp_path):
    registry = build_plugin_manager()
    mission = load_mission("demo", registry, OVERRIDES)
    result = Runner(mission, registry, tmp_path).run()

    assert result.verdict == "completed", result.verdict
    reached = [e for e in events(result.run_dir) if e["event"] == "waypoint_reached"]
    assert [e["index"] for e in reached] == [0, 1]
    home = np.array(reached[0]["position"]) - POINTS[0]
    assert np.allclose(np.array(reached[1]["position"]) - home, POINTS[1], atol=1e-3)


def test_guard_only_on_real_vehicles():
    registry = build_plugin_manager()
    model = load_mission("demo", registry, OVERRIDES).model
    plain = build_mission_tree(model, registry.behaviours, failsafe=False)
    guarded = build_mission_tree(model, registry.behaviours, failsafe=True)
    assert plain.name == "Mission"
    assert [c.name for c in plain.children] == ["TakeOff", "FlyWaypointsInTime", "Land"]
    assert [c.name for c in guarded.children] == ["FailsafeGuard", "Mission"]
    exploring = build_mission_tree(load_mission("demo", registry).model, registry.behaviours, failsafe=True)
    assert exploring.children[1].children[0].name == "TakeOff"  # the exploration tree, guarded


def test_waypoint_tree_needs_points():
    with pytest.raises(MissionError, match="tree: waypoints needs at least one point"):
        load_mission("demo", build_plugin_manager(), ["tree=waypoints"])
