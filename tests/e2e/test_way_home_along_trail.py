"""A flight whose map gives no way home flies back along its trail and lands at the take-off spot."""

from __future__ import annotations

import json

import numpy as np

import amslam
from amslam.mission import load_mission
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.registry import build_plugin_manager
from amslam.runner import Runner

from .missions import small_mission


class NoPathHome(Open3dVoxelMap):
    """The open3d map whose path rules refuse every way to the take-off spot (as a map whose
    slabs were carved or misplaced by drift can): only the flown trail leads back."""

    def plan_path(self, start, goal):
        trail = self.trail()  # its first point is above the take-off spot
        if len(trail):
            to_home = np.linalg.norm(np.asarray(goal)[:2] - trail[0][:2])
            from_home = np.linalg.norm(np.asarray(start)[:2] - trail[0][:2])
            if to_home < 0.5 and from_home > 0.5:
                return None
        return super().plan_path(start, goal)


class Plugin:
    @amslam.hookimpl
    def amslam_mapping_backends(self):
        return {"no_path_home": NoPathHome}


def test_a_flight_with_no_mapped_way_home_comes_back_along_its_trail(tmp_path):
    registry = build_plugin_manager(extra_plugins=[Plugin()])
    path = small_mission(tmp_path, max_time=90, mapping="{plugin: no_path_home}")
    result = Runner(load_mission(path, registry), registry, tmp_path / "runs").run()
    events = [json.loads(line) for line in (result.run_dir / "events.jsonl").read_text().splitlines()]
    names = [e["event"] for e in events]
    assert "path_along_trail" in names, sorted(set(names))
    assert result.verdict == "completed", result.verdict
    assert result.metrics["ended_from_home_m"] < 1.0, result.metrics["ended_from_home_m"]
