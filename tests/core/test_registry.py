"""Plugin discovery through entry points, disabling by name, clear load errors."""

from __future__ import annotations

import pytest

import amslam
from amslam.errors import PluginError
from amslam.interfaces import BACKEND_KINDS, Planner
from amslam.registry import build_plugin_manager


def test_builtins_come_through_entry_points(registry):
    assert "greedy" in registry.backends["planner"]
    assert registry.distributions[registry.providers["planner"]["greedy"]].startswith("amslam ")
    assert set(registry.backends) == set(BACKEND_KINDS)


def test_disable_plugin_by_name():
    registry = build_plugin_manager(disabled=["planners"])
    assert "greedy" not in registry.backends["planner"]
    with pytest.raises(PluginError, match="no planner backend named 'greedy'"):
        registry.factory("planner", "greedy")


class _Dup(Planner):
    def plan(self, request):
        return []


class _DupPlugin:
    @amslam.hookimpl
    def amslam_planner_backends(self):
        return {"greedy": _Dup}


def test_duplicate_backend_names_are_an_error_naming_both():
    with pytest.raises(PluginError, match="provided by both plugin 'planners'"):
        build_plugin_manager(extra_plugins=[_DupPlugin()])
