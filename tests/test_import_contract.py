"""The dependency direction holds in the sources, and the check catches a planted violation."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.import_contract import allowed, violations

ROOT = Path(__file__).resolve().parents[1]


def test_the_sources_keep_the_layer_direction():
    found = violations(ROOT)
    assert not found, "imports against the layer direction:\n" + "\n".join(map(str, found))


@pytest.fixture
def copy_of_sources(tmp_path: Path) -> Path:
    for folder in ("core", "plugins", "trees"):
        shutil.copytree(ROOT / folder, tmp_path / folder, ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path


@pytest.mark.parametrize(
    ("file", "line", "rule"),
    [
        ("core/runner.py", "from amslam.trees.flight import build_mission_tree", "kernel imports only"),
        ("core/types.py", "import amslam.plugins.sim.world", "kernel imports only"),
        ("core/mission.py", "from amslam.apps import experiments", "never imports an application"),
        ("core/lib/shapes.py", "from amslam.plugins.gtsam_slam import slc", "library imports only"),
        ("plugins/pams/planner.py", "from amslam.plugins.sim.detector import SimDetector", "another plugin"),
        ("plugins/voxel_open3d/backend.py", "from amslam.plugins import voxel_numpy", "another plugin"),
        ("plugins/sim/world.py", "from ..gtsam_slam import slc", "another plugin"),
        ("trees/behaviours.py", "from amslam.plugins.sim import SimPlatform", "another plugin"),
        ("plugins/sim/world.py", "from amslam.testing import contract", "contract kits"),
    ],
)
def test_a_planted_forbidden_import_is_caught(copy_of_sources: Path, file: str, line: str, rule: str):
    before = set(violations(copy_of_sources))
    target = copy_of_sources / file
    target.write_text(target.read_text() + f"\n\ndef _planted():\n    {line}\n")
    planted = [v for v in violations(copy_of_sources) if v not in before]
    assert [v.file.as_posix() for v in planted] == [file], planted
    assert rule in planted[0].rule


def test_allowed_directions():
    assert allowed("amslam.apps.multirobot", "amslam.plugins.gtsam_slam.merge") is None
    assert allowed("amslam.plugins.voxel_open3d.backend", "amslam.lib.voxel_map") is None
    assert allowed("amslam.plugins.sim.platform", "amslam.plugins.sim.vio") is None
    assert allowed("amslam.lib.frontiers", "amslam.types") is None
    assert allowed("amslam.trees.behaviours", "amslam.geometry") is None
    assert allowed("amslam.testing.slam", "amslam.lib.shapes") is None
