"""Plugins that fail at load time are left out and named, one line each; missions refuse or skip them."""

from __future__ import annotations

import importlib.metadata
import inspect
import sys
import types

import pluggy
import pytest

import amslam
from amslam import hookspecs
from amslam.errors import MissionError, PluginError
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from tests.e2e.missions import small_mission


def _with_entry_points(monkeypatch, *extra: importlib.metadata.EntryPoint) -> None:
    """The installed ``amslam`` entry points plus ``extra`` (in-process, nothing installed)."""
    real = importlib.metadata.entry_points

    def entry_points(**kwargs):
        found = list(real(**kwargs))
        if kwargs.get("group") == "amslam":
            found += list(extra)
        return found

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)


def _module(monkeypatch, name: str, **attrs) -> None:
    module = types.ModuleType(name)
    module.__dict__.update(attrs)
    monkeypatch.setitem(sys.modules, name, module)


def _ep(name: str, value: str) -> importlib.metadata.EntryPoint:
    return importlib.metadata.EntryPoint(name=name, value=value, group="amslam")


@pytest.fixture
def broken_plugins(monkeypatch):
    """Four broken plugins: an import error, a hook that raises, an unknown hook, a bad signature."""

    @amslam.hookimpl
    def amslam_mapping_backends():
        raise RuntimeError("licence server unreachable\nsecond line of detail")

    @amslam.hookimpl
    def amslam_mapping_backend():  # a typo: not a hook amslam specifies
        return {}

    @amslam.hookimpl
    def amslam_planner_backends(colour):  # an argument the specification does not have
        return {}

    _module(monkeypatch, "amslam_test_raises", amslam_mapping_backends=amslam_mapping_backends)
    _module(monkeypatch, "amslam_test_typo", amslam_mapping_backend=amslam_mapping_backend)
    _module(monkeypatch, "amslam_test_signature", amslam_planner_backends=amslam_planner_backends)
    _with_entry_points(
        monkeypatch,
        _ep("missing_dep", "amslam_test_no_such_module_anywhere"),
        _ep("raises", "amslam_test_raises"),
        _ep("typo", "amslam_test_typo"),
        _ep("signature", "amslam_test_signature"),
    )


def test_every_broken_plugin_is_named_and_the_others_load(broken_plugins):
    registry = build_plugin_manager()
    errors = registry.load_errors
    assert set(errors) == {"missing_dep", "raises", "typo", "signature"}
    assert errors["missing_dep"].startswith(
        "plugin 'missing_dep' (amslam_test_no_such_module_anywhere) failed"
    )
    assert (
        "ModuleNotFoundError: No module named 'amslam_test_no_such_module_anywhere'" in errors["missing_dep"]
    )
    assert errors["raises"] == (
        "plugin 'raises' raised in amslam_mapping_backends: RuntimeError: licence server unreachable; "
        "second line of detail"
    )
    assert "amslam_mapping_backend" in errors["typo"] and "unknown hook" in errors["typo"]
    assert "colour" in errors["signature"]
    assert all("\n" not in e for e in errors.values())
    # the healthy plugins are all there, the broken ones are not registered
    assert {"open3d", "numpy"} <= set(registry.backends["mapping"])
    assert "greedy" in registry.backends["planner"]
    for name in errors:
        assert registry.pm.get_plugin(name) is None


def test_unknown_backend_hints_at_plugins_that_failed(broken_plugins):
    registry = build_plugin_manager()
    with pytest.raises(
        PluginError, match="plugins that failed to load: missing_dep, raises, signature, typo"
    ):
        registry.factory("mapping", "octomap")


def test_mission_refuses_naming_each_broken_plugin(broken_plugins, tmp_path):
    registry = build_plugin_manager()
    mission = small_mission(tmp_path)
    with pytest.raises(MissionError) as exc:
        load_mission(mission, registry)
    problems = exc.value.problems
    assert len(problems) == 4
    for name in ("missing_dep", "raises", "typo", "signature"):
        (line,) = [p for p in problems if f"plugin {name!r}" in p]
        assert line.startswith(f"{mission}: plugins: ") and "plugins.optional" in line


def test_mission_skips_optional_plugins(broken_plugins, tmp_path):
    registry = build_plugin_manager()
    mission = small_mission(tmp_path)
    text = mission.read_text() + "plugins: {optional: [missing_dep, raises, typo]}\n"
    mission.write_text(text)
    with pytest.raises(MissionError) as exc:  # 'signature' is not optional
        load_mission(mission, registry)
    assert len(exc.value.problems) == 1 and "plugin 'signature'" in exc.value.problems[0]
    mission.write_text(text.replace("typo]", "typo, signature]"))
    loaded = load_mission(mission, registry)
    assert loaded.backends["mapping"].plugin == "open3d"
    assert loaded.model.plugins.optional == ["missing_dep", "raises", "typo", "signature"]


def test_disabled_plugins_are_not_even_imported(broken_plugins):
    registry = build_plugin_manager(disabled=["missing_dep", "raises", "typo", "signature"])
    assert registry.load_errors == {}


def test_raising_in_a_later_hook_withdraws_earlier_backends(monkeypatch):
    from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap

    @amslam.hookimpl
    def amslam_platform_backends():
        return {"half": NumpyVoxelMap}

    @amslam.hookimpl
    def amslam_planner_backends():
        raise ImportError("cannot import name 'solver'")

    _module(
        monkeypatch,
        "amslam_test_half",
        amslam_platform_backends=amslam_platform_backends,
        amslam_planner_backends=amslam_planner_backends,
    )
    _with_entry_points(monkeypatch, _ep("half", "amslam_test_half"))
    registry = build_plugin_manager()
    assert registry.load_errors["half"].endswith("ImportError: cannot import name 'solver'")
    assert "half" not in registry.backends["platform"]
    assert "sim" in registry.backends["platform"]


def test_every_hookspec_says_since_which_version():
    pm = pluggy.PluginManager("amslam")
    pm.add_hookspecs(hookspecs)
    names = [n for n, f in inspect.getmembers(hookspecs, inspect.isfunction) if hasattr(f, "amslam_spec")]
    assert len(names) >= 12
    for name in names:
        version = hookspecs.since(name)
        assert version.count(".") == 1 and all(p.isdigit() for p in version.split(".")), (name, version)
        assert getattr(hookspecs, name).__doc__.rstrip().splitlines()[-1].strip() == f"Since: {version}"
    with pytest.raises(KeyError):
        hookspecs.since("amslam_no_such_hook")


class _DeferredOctomap:
    """A plugin naming its backend by module, the module broken (it imports what is not installed)."""

    @staticmethod
    @amslam.hookimpl
    def amslam_mapping_backends():
        from amslam.deferred import Deferred

        return {"octomap": Deferred("amslam_octomap_missing.backend:OctomapMapping")}


def test_a_deferred_backend_is_imported_when_asked_for_and_a_broken_one_named(tmp_path):
    """A Deferred backend is listed without importing its module; asking for it imports it, and a
    module that fails to import is a PluginError naming the backend and the module (a mission
    choosing it: one line at ``mapping.plugin``), never a traceback."""
    registry = build_plugin_manager(extra_plugins=[_DeferredOctomap])
    assert "octomap" in registry.backends["mapping"] and registry.load_errors == {}
    with pytest.raises(PluginError, match=r"mapping backend 'octomap' \(amslam_octomap_missing.backend:"):
        registry.backend_class("mapping", "octomap")
    mission = small_mission(tmp_path, mapping="{plugin: octomap}")
    with pytest.raises(MissionError) as exc:
        load_mission(mission, registry)
    (line,) = exc.value.problems
    assert line.startswith(f"{mission}:") and ": mapping.plugin: mapping backend 'octomap'" in line
    assert "failed to load: ModuleNotFoundError" in line
    # a built-in deferred backend resolves to its class
    from amslam.plugins.planners.greedy import GreedyPlanner

    assert registry.factory("planner", "greedy") is GreedyPlanner
