"""One small mission flown once per test session, shared by the end-to-end tests that read it."""

from __future__ import annotations

import pytest

from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from tests.e2e.missions import small_mission


@pytest.fixture(scope="session")
def small_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("small")
    registry = build_plugin_manager()
    mission = load_mission(small_mission(folder), registry)
    return Runner(mission, registry, folder / "runs").run()
