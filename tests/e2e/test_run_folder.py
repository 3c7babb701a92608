"""A simulated mission end to end: verdict, run folder contents, determinism, failures."""

from __future__ import annotations

import json

import numpy as np
import pytest

import amslam
from amslam.apps.mapformats import read_map_ply
from amslam.cli import main
from amslam.mission import load_mission
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from amslam.testing.mapping import make_context
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
    # which environment flew it: the same code and seed fly differently on other numerics
    from importlib.metadata import version

    start = next(e for e in events if e["event"] == "run_start")
    assert start["packages"]["numpy"] == version("numpy") and start["packages"]["gtsam"] == version("gtsam")


def test_same_seed_same_trajectory(tmp_path):
    registry = build_plugin_manager()
    mission = load_mission(small_mission(tmp_path, max_time=40), registry)  # exploring, home, landing
    first, again = (Runner(mission, registry, tmp_path / name).run() for name in ("a", "b"))
    for name in ("ground_truth.tum", "vio.tum"):
        assert (again.run_dir / name).read_text() == (first.run_dir / name).read_text(), name


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


def test_the_map_ply_carries_class_probability_and_voxel_size(small_run):
    cloud = read_map_ply(small_run.run_dir / "map.ply")
    metrics = json.loads((small_run.run_dir / "metrics.json").read_text())
    assert cloud.voxel_size == 0.25 and len(cloud) > 1000
    assert set(cloud.class_names[1:]) == set(metrics["landmarks"]["by_class"])
    assert set(np.unique(cloud.classes)) > {0}  # some voxels belong to mapped objects
    assert np.all(cloud.probability > 0.8)  # every occupied voxel is above the backend's p_occ


def test_a_later_run_starts_from_an_octomap_of_a_run(small_run, tmp_path):
    pytest.importorskip("pyoctomap", reason="OctoMap files need pyoctomap (amslam[interop])")
    bt = tmp_path / "small.bt"
    assert main(["map", str(small_run.run_dir), "--bt", str(bt)]) == 0
    registry = build_plugin_manager()
    mission_file = small_mission(tmp_path, max_time=3)
    mission_file.write_text(mission_file.read_text() + f"prior_map: {bt.name}\n")
    mission = load_mission(mission_file, registry)
    result = Runner(mission, registry, tmp_path / "runs").run()
    assert result.verdict == "completed"
    assert result.metrics["explored_percent"] >= 90.0  # the known space came from the .bt
    assert "prior_map_loaded" in (result.run_dir / "events.jsonl").read_text()
    # the prior's occupied voxels are the exported run's, one for one
    prior = Open3dVoxelMap()
    prior.configure(mission.backends["mapping"].params, make_context(tmp_path))
    prior.load(bt)
    exported = read_map_ply(small_run.run_dir / "map.ply").points
    np.testing.assert_allclose(np.sort(prior.occupied_points(), axis=0), np.sort(exported, axis=0), atol=1e-5)


def test_a_prior_that_is_not_an_octree_fails_the_run_in_one_line(tmp_path):
    bad = tmp_path / "map.bt"
    bad.write_text("not a tree\n")
    registry = build_plugin_manager()
    mission_file = small_mission(tmp_path, max_time=3)
    mission_file.write_text(mission_file.read_text() + "prior_map: map.bt\n")
    result = Runner(load_mission(mission_file, registry), registry, tmp_path / "runs").run()
    assert result.verdict == (
        f"failed: {bad}: not an OctoMap binary tree (.bt files start with '# Octomap OcTree binary file')"
    )
