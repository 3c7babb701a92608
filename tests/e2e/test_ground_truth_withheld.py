"""No shortcut a real robot could not take: the simulator's ground truth reaches the simulator and
the metrics, never mapping, SLAM, planning, PAMS or a behaviour (issue #21).

Two checks, each failing on its own kind of leak:

* **In flight.** Short flights of the demo stack (open3d, gtsam with semantic loop closure, cop,
  sim detector) and of PAMS on the parking lot (gtsam with cuboid and cylinder landmarks, the pams
  planner and its size priors), with the simulated world's summary replaced by a copy that notes
  every module reading it. Only the simulator's own modules, the runner (the flight area from the
  world's bounds, the run's closing summary) and the metrics may.
* **In the source.** No module of a plugin other than the simulator's, and no behaviour, names
  the truth a frame or the platform carries (``T_world_cam_truth``, ``true_pose``,
  ``world_summary``), a run context's ``world``, or takes the world in the run-start hook.
"""

from __future__ import annotations

import ast
import dataclasses
import sys
from pathlib import Path

import pytest

from amslam.mission import load_mission
from amslam.plugins.sim.platform import SimPlatform
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from amslam.types import WorldSummary

ROOT = Path(__file__).resolve().parents[2]
#: modules that may read the truth: the simulator, the runner (the flight area from the world's
#: bounds when a mission gives none, and the run's summary it hands the metrics), the metrics
ALLOWED = ("amslam.plugins.sim", "amslam.runner", "amslam.apps.report", "dataclasses", "copy")
#: attributes that are the simulator's truth wherever they are read
TRUTH_ATTRIBUTES = {"T_world_cam_truth", "true_pose", "world_summary"}


def _recording_world(world: WorldSummary, readers: list[tuple[str, str]]) -> WorldSummary:
    """A copy of ``world`` that appends (module, attribute) to ``readers`` on every read."""

    class Recorded(type(world)):
        def __getattribute__(self, name):
            if not name.startswith("__"):
                readers.append((sys._getframe(1).f_globals.get("__name__", "?"), name))
            return object.__getattribute__(self, name)

    fields = {f.name: getattr(world, f.name) for f in dataclasses.fields(world)}
    readers.clear()  # the copy above is no one's read
    return Recorded(**fields)


@pytest.mark.parametrize(
    ("mission", "overrides"),
    [
        ("demo", ["limits.max_time=15"]),
        ("pams_lot_a", ["limits.max_time=15"]),
    ],
    ids=["demo-stack", "pams"],
)
def test_only_the_simulator_runner_and_metrics_read_the_world(tmp_path, monkeypatch, mission, overrides):
    readers: list[tuple[str, str]] = []
    original = SimPlatform.world_summary

    def recorded(self):
        return _recording_world(original(self), readers)

    monkeypatch.setattr(SimPlatform, "world_summary", recorded)
    registry = build_plugin_manager()
    result = Runner(load_mission(mission, registry, overrides), registry, tmp_path).run()
    assert result.metrics["verdict"] == "completed", result.metrics["verdict"]
    assert readers, "the tripwire saw no read at all: the metrics read the world, so it is not wired"
    leaks = sorted({(module, name) for module, name in readers if not module.startswith(ALLOWED)})
    assert not leaks, f"read the simulator's ground truth: {leaks}"


def test_backends_other_than_the_simulators_are_configured_without_the_world(tmp_path, monkeypatch):
    handed: dict[str, object] = {}
    build = Runner._build

    def noting(self, kind, plugin):
        backend = build(self, kind, plugin)
        configure = backend.configure

        def configure_noting(params, context):
            handed[kind] = context.world
            return configure(params, context)

        backend.configure = configure_noting
        return backend

    monkeypatch.setattr(Runner, "_build", noting)
    registry = build_plugin_manager()
    Runner(load_mission("demo", registry, ["limits.max_time=1"]), registry, tmp_path).run()
    assert set(handed) == {"platform", "mapping", "slam", "detector", "planner"}
    assert handed["detector"] is not None  # the sim detector is the simulator's: it has the world
    assert {kind for kind, world in handed.items() if world is not None} == {"detector"}


def _source_files() -> list[Path]:
    plugins = [
        p for p in (ROOT / "plugins").rglob("*.py") if "sim" not in p.relative_to(ROOT / "plugins").parts[:1]
    ]
    return sorted(plugins + list((ROOT / "trees").rglob("*.py")))


def _leaks(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Attribute):
            if node.attr in TRUTH_ATTRIBUTES:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: .{node.attr}")
            owner = (
                node.value.attr if isinstance(node.value, ast.Attribute) else getattr(node.value, "id", "")
            )
            if node.attr == "world" and owner in {"context", "ctx", "run_context"}:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {owner}.world")
        hook = isinstance(node, ast.FunctionDef) and node.name == "amslam_run_start"
        if hook and any(a.arg == "world" for a in node.args.args + node.args.kwonlyargs):
            found.append(f"{path.relative_to(ROOT)}:{node.lineno}: amslam_run_start(world)")
    return sorted(found, key=lambda leak: int(leak.split(":")[1]))


def test_no_plugin_or_behaviour_names_the_truth_in_its_source():
    files = _source_files()
    assert any("gtsam_slam" in str(p) for p in files) and any("pams" in str(p) for p in files)
    leaks = [leak for path in files for leak in _leaks(path)]
    assert not leaks, "\n".join(leaks)


def test_the_source_check_catches_a_leak(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    bad = tmp_path / "plugins" / "mine" / "slam.py"
    bad.parent.mkdir(parents=True)
    bad.write_text(
        "def configure(self, params, context):\n"
        "    self.truth = context.world.object_positions\n"
        "def add_frame(self, frame):\n"
        "    return frame.T_world_cam_truth\n"
        "def amslam_run_start(run_dir, mission, world):\n"
        "    pass\n"
    )
    assert [leak.split(": ", 1)[1] for leak in _leaks(bad)] == [
        "context.world",
        ".T_world_cam_truth",
        "amslam_run_start(world)",
    ]
