"""The built-in commands' mission loading: the command line's registry is used as it is unless
the mission disables plugins."""

from __future__ import annotations

import argparse

from amslam.apps.commands import load_with_registry


def test_the_command_lines_registry_is_used_when_the_mission_disables_nothing(registry):
    mission, used = load_with_registry(argparse.Namespace(mission="demo", set=None), registry)
    assert used is registry
    assert mission.backends["slam"].plugin == "gtsam"


def test_a_mission_that_disables_a_plugin_gets_a_registry_without_it(registry):
    args = argparse.Namespace(mission="demo", set=["plugins.disable=[onnx_detector]"])
    _, used = load_with_registry(args, registry)
    assert used is not registry
    assert "onnx" not in used.backends["detector"]
    assert "onnx" in registry.backends["detector"]
