"""A plugin adds a mission tree and a run observer; the kernel runs them without knowing either."""

from __future__ import annotations

import numpy as np
import pytest
from py_trees.composites import Sequence

import amslam
from amslam.errors import MissionError
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from amslam.types import RunSummary

from .missions import small_mission


def hop(model, behaviours, failsafe=False):
    """Take off and land again: the smallest mission there is."""
    return Sequence(
        "Hop", memory=True, children=[behaviours["TakeOff"]("TakeOff"), behaviours["Land"]("Land")]
    )


class TreePlugin:
    summaries: list = []
    old_style: list = []

    @amslam.hookimpl
    def amslam_mission_trees(self):
        return {"hop": hop}

    @amslam.hookimpl
    def amslam_run_end(self, summary):
        TreePlugin.summaries.append(summary)


class OldObserver:
    """An observer written against amslam 0.1: no ``summary`` argument."""

    @amslam.hookimpl
    def amslam_run_end(self, run_dir, verdict, trajectory):
        TreePlugin.old_style.append((run_dir, verdict, trajectory.shape))


def test_a_plugin_tree_is_flown_by_name_and_observers_get_the_run_summary(tmp_path):
    registry = build_plugin_manager(extra_plugins=[TreePlugin(), OldObserver()])
    assert {"exploration", "waypoints", "hop"} <= set(registry.trees)
    mission = load_mission(small_mission(tmp_path, max_time=60), registry, overrides=["tree=hop"])
    result = Runner(mission, registry, tmp_path / "runs").run()
    assert result.verdict == "completed", result.verdict
    events = (result.run_dir / "tree.jsonl").read_text()
    assert '"Hop"' in events and "Replan" not in events
    (summary,) = TreePlugin.summaries
    assert isinstance(summary, RunSummary)
    assert summary.verdict == "completed" and summary.mission.name == "small"
    assert summary.run_dir == result.run_dir and round(summary.distance_m, 3) == result.metrics["distance_m"]
    assert len(summary.truth) > 10 and summary.trajectory.shape == (len(summary.truth), 3)
    assert summary.world is not None and summary.landmarks is not None
    np.testing.assert_allclose(summary.trajectory[0, :2], summary.home_world[:2], atol=1e-6)
    assert TreePlugin.old_style == [(result.run_dir, "completed", summary.trajectory.shape)]


def test_an_unknown_tree_is_refused_naming_the_installed_ones(tmp_path, registry):
    with pytest.raises(
        MissionError, match="tree: no mission tree named 'hover'; installed trees: exploration, waypoints"
    ):
        load_mission(small_mission(tmp_path), registry, overrides=["tree=hover"])
