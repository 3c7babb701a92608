"""A simulated mission end to end: verdict, run folder contents, determinism, failures."""

from __future__ import annotations

import json

import amslam
from amslam.mission import load_mission
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from tests.e2e.missions import small_mission

RUN_FILES = (
    "mission.yaml",
    "events.jsonl",
    "tree.jsonl",
    "ground_truth.tum",
    "vio.tum",
    "slam.tum",
    "landmarks.json",
    "map.ply",
    "map.npz",
    "metrics.json",
    "top_view.png",
    "report.md",
)


def test_small_mission_completes_and_explores(small_run):
    assert small_run.verdict == "completed"
    for name in RUN_FILES:
        assert (small_run.run_dir / name).exists(), name
    metrics = json.loads((small_run.run_dir / "metrics.json").read_text())
    assert metrics["verdict"] == "completed"
    assert metrics["explored_percent"] >= 90.0
    assert metrics["reachable_free_volume_m3"] > 50
    assert metrics["distance_m"] > 5
    assert metrics["ended_from_home_m"] < 0.8  # back where it took off, give or take its VIO drift (~0.4 m)
    assert metrics["closest_approach"]["clearance_m"] > metrics["closest_approach"]["robot_radius_m"]
    report = (small_run.run_dir / "report.md").read_text()
    assert "**Verdict: completed**" in report and "top_view.png" in report
    events = [json.loads(line) for line in (small_run.run_dir / "events.jsonl").read_text().splitlines()]
    assert events[-1]["event"] == "run_end" and any(e["event"] == "replan" for e in events)


def test_same_seed_same_trajectory(small_run, tmp_path):
    registry = build_plugin_manager()
    mission = load_mission(small_mission(tmp_path), registry)
    again = Runner(mission, registry, tmp_path / "runs").run()
    for name in ("ground_truth.tum", "vio.tum"):
        assert (again.run_dir / name).read_text() == (small_run.run_dir / name).read_text(), name


class FailingMap(Open3dVoxelMap):
    """A mapping backend that breaks after a few frames, like a real bug would."""

    frames = 0

    def integrate_global(self, depth, K, T_world_cam):
        FailingMap.frames += 1
        if FailingMap.frames > 40:
            raise RuntimeError("voxel block pool exhausted")
        return super().integrate_global(depth, K, T_world_cam)


class FailingMapPlugin:
    @amslam.hookimpl
    def amslam_mapping_backends(self):
        return {"failing": FailingMap}


def test_backend_exception_leaves_a_readable_run_folder(tmp_path):
    registry = build_plugin_manager(extra_plugins=[FailingMapPlugin()])
    mission = load_mission(small_mission(tmp_path, mapping="{plugin: failing}"), registry)
    result = Runner(mission, registry, tmp_path / "runs").run()
    assert result.verdict == (
        "failed: mapping 'failing' (registered in-process, from no distribution): "
        "integrate_global() raised RuntimeError: voxel block pool exhausted"
    )
    metrics = json.loads((result.run_dir / "metrics.json").read_text())
    assert metrics["verdict"] == result.verdict and metrics["sim_duration_s"] > 5
    assert (result.run_dir / "report.md").read_text().count("voxel block pool exhausted") == 1
    assert len((result.run_dir / "ground_truth.tum").read_text().splitlines()) > 50
    last = json.loads((result.run_dir / "events.jsonl").read_text().splitlines()[-1])
    assert last == {"t": last["t"], "event": "run_end", "verdict": result.verdict}


def test_a_later_run_starts_from_a_saved_map(small_run, tmp_path):
    prior = small_run.run_dir / "map.npz"
    registry = build_plugin_manager()
    mission_file = small_mission(tmp_path, max_time=3)
    mission_file.write_text(mission_file.read_text() + f"prior_map: {prior}\n")
    result = Runner(load_mission(mission_file, registry), registry, tmp_path / "runs").run()
    # Three seconds of flight see almost nothing: the explored share comes from the loaded map.
    assert result.verdict == "completed"
    assert result.metrics["explored_percent"] >= 90.0
    events = (result.run_dir / "events.jsonl").read_text()
    assert "prior_map_loaded" in events
