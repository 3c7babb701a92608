"""The plugin manager: hookspecs + every plugin found through the ``amslam`` entry points.

Built-in backends register through the very same entry points (see pyproject.toml) as third
party ones, so there is exactly one discovery path.
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import pluggy

from amslam import hookspecs
from amslam.errors import PluginError
from amslam.interfaces import BACKEND_KINDS, Backend

ENTRY_POINT_GROUP = "amslam"


@dataclass
class Registry:
    """Backends by kind and name, and where each came from."""

    pm: pluggy.PluginManager
    backends: dict[str, dict[str, Callable[[], Backend]]] = field(default_factory=dict)
    providers: dict[str, dict[str, str]] = field(default_factory=dict)  # kind -> name -> plugin
    behaviours: dict[str, Callable] = field(default_factory=dict)
    distributions: dict[str, str] = field(default_factory=dict)  # plugin name -> "dist version"

    def factory(self, kind: str, name: str) -> Callable[[], Backend]:
        """The factory of backend ``name`` of ``kind``, or a PluginError listing the installed ones."""
        if kind not in BACKEND_KINDS:
            raise PluginError(f"unknown backend kind {kind!r}; kinds are {', '.join(BACKEND_KINDS)}")
        found = self.backends.get(kind, {})
        if name not in found:
            installed = ", ".join(sorted(found)) or "none"
            raise PluginError(f"no {kind} backend named {name!r}; installed: {installed}")
        return found[name]

    def backend_class(self, kind: str, name: str) -> type[Backend]:
        """The class a factory builds, for reading its ``Params`` without configuring it."""
        factory = self.factory(kind, name)
        return factory if isinstance(factory, type) else type(factory())


def build_plugin_manager(disabled: Iterable[str] = (), extra_plugins: Iterable[object] = ()) -> Registry:
    """Add the hookspecs, load every ``amslam`` entry point (minus ``disabled``), collect backends.

    ``extra_plugins`` are registered in-process after the entry points (for tests and for
    applications that embed amslam); everything else comes through the entry-point group.

    Raises:
        PluginError: a plugin failed to import, or two plugins provide the same backend name.
    """
    pm = pluggy.PluginManager("amslam")
    pm.add_hookspecs(hookspecs)
    disabled = set(disabled)
    for name in disabled:
        pm.set_blocked(name)
    registry = Registry(pm)
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in disabled or pm.is_blocked(ep.name) or pm.has_plugin(ep.name):
            continue
        try:
            plugin = ep.load()
        except Exception as exc:  # a broken third-party plugin must not produce a traceback
            dist = ep.dist.name if ep.dist else "?"
            raise PluginError(
                f"plugin {ep.name!r} (distribution {dist}, {ep.value}) failed to load: "
                f"{type(exc).__name__}: {exc}"
            ) from exc
        pm.register(plugin, name=ep.name)
        if ep.dist is not None:
            registry.distributions[ep.name] = f"{ep.dist.name} {ep.dist.version}"
    for plugin in extra_plugins:
        pm.register(plugin)
    pm.check_pending()
    for kind in BACKEND_KINDS:
        registry.backends[kind], registry.providers[kind] = _collect(pm, f"amslam_{kind}_backends")
    registry.behaviours, _ = _collect(pm, "amslam_behaviours")
    return registry


def _collect(pm: pluggy.PluginManager, hook_name: str) -> tuple[dict, dict]:
    merged: dict[str, Callable] = {}
    provider: dict[str, str] = {}
    for impl in getattr(pm.hook, hook_name).get_hookimpls():
        result = impl.function() or {}
        for name, factory in result.items():
            if name in merged:
                raise PluginError(
                    f"{hook_name}: name {name!r} is provided by both plugin "
                    f"{provider[name]!r} and plugin {impl.plugin_name!r}; disable one in the mission"
                )
            merged[name] = factory
            provider[name] = impl.plugin_name
    return merged, provider
