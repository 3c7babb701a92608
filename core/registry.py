"""The plugin manager: hookspecs + every plugin found through the ``amslam`` entry points.

Built-in backends register through the very same entry points (see pyproject.toml) as third
party ones, so there is exactly one discovery path.
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import pluggy

from amslam import hookspecs
from amslam.deferred import Deferred
from amslam.errors import PluginError
from amslam.interfaces import BACKEND_KINDS, Backend

ENTRY_POINT_GROUP = "amslam"


@dataclass
class Registry:
    """Backends by kind and name, and where each came from."""

    pm: pluggy.PluginManager
    backends: dict[str, dict[str, Callable[[], Backend]]] = field(default_factory=dict)
    providers: dict[str, dict[str, str]] = field(default_factory=dict)  # kind -> name -> plugin
    #: behaviour factories by name (``amslam_behaviours``); a :class:`Deferred` one imports its
    #: module when it is first called, that is when a tree is built
    behaviours: dict[str, Callable] = field(default_factory=dict)
    #: mission tree builders by name (``amslam_mission_trees``)
    trees: dict[str, Callable] = field(default_factory=dict)
    #: ``amslam`` subcommands by name (:class:`amslam.cli.Command`)
    commands: dict[str, Any] = field(default_factory=dict)
    #: ``amslam experiment`` names (:class:`amslam.cli.Experiment`)
    experiments: dict[str, Any] = field(default_factory=dict)
    distributions: dict[str, str] = field(default_factory=dict)  # plugin name -> "dist version"
    #: plugin name -> one-line reason it was left out (failed to import, rejected hooks, raised in a hook)
    load_errors: dict[str, str] = field(default_factory=dict)

    def factory(self, kind: str, name: str) -> Callable[[], Backend]:
        """The factory of backend ``name`` of ``kind`` (imported now if its plugin named it with a
        :class:`~amslam.deferred.Deferred`), or a PluginError listing the installed ones or saying
        why it could not be imported."""
        if kind not in BACKEND_KINDS:
            raise PluginError(f"unknown backend kind {kind!r}; kinds are {', '.join(BACKEND_KINDS)}")
        found = self.backends.get(kind, {})
        if name not in found:
            installed = ", ".join(sorted(found)) or "none"
            broken = (
                f"; plugins that failed to load: {', '.join(sorted(self.load_errors))}"
                if self.load_errors
                else ""
            )
            raise PluginError(f"no {kind} backend named {name!r}; installed: {installed}{broken}")
        return _load(found[name], f"{kind} backend {name!r}")

    def origin(self, kind: str, name: str) -> str:
        """``planner 'x' from dist y 1.0``: a backend as a verdict names it (kind, name, distribution)."""
        plugin = self.providers.get(kind, {}).get(name)
        dist = self.distributions.get(plugin) if plugin is not None else None
        if dist is not None:
            return f"{kind} {name!r} from dist {dist}"
        return f"{kind} {name!r} (registered in-process, from no distribution)"

    def tree(self, name: str) -> Callable:
        """The builder of mission tree ``name``, or a PluginError listing the installed ones."""
        if name not in self.trees:
            installed = ", ".join(sorted(self.trees)) or "none"
            raise PluginError(f"no mission tree named {name!r}; installed trees: {installed}")
        return self.trees[name]  # a Deferred one imports its module when the tree is built

    def backend_class(self, kind: str, name: str) -> type[Backend]:
        """The class a factory builds, for reading its ``Params`` without configuring it."""
        factory = self.factory(kind, name)
        return factory if isinstance(factory, type) else type(factory())


def _load(provided: Any, what: str) -> Any:
    """What a plugin provided, imported now if it is a :class:`Deferred`; a PluginError if that fails."""
    if not isinstance(provided, Deferred):
        return provided
    try:
        return provided.load()
    except Exception as exc:  # noqa: BLE001 — a broken module is reported by name, never a traceback
        raise PluginError(f"{what} ({provided.path}) failed to load: {_one_line(exc)}") from exc


def build_plugin_manager(disabled: Iterable[str] = (), extra_plugins: Iterable[object] = ()) -> Registry:
    """Add the hookspecs, load every ``amslam`` entry point (minus ``disabled``), collect backends.

    ``extra_plugins`` are registered in-process after the entry points (for tests and for
    applications that embed amslam); everything else comes through the entry-point group.

    A plugin that fails to import, whose hooks do not match the specifications, or whose backend
    hook raises is left out and recorded in ``Registry.load_errors`` with a one-line reason; the
    other plugins load normally. Whoever uses the registry decides what a load error means (a
    mission refuses to fly unless it marks the plugin optional, see :func:`amslam.mission.load_mission`).

    Raises:
        PluginError: two plugins provide the same backend name.
    """
    pm = pluggy.PluginManager("amslam")
    pm.add_hookspecs(hookspecs)
    disabled = set(disabled)
    for name in disabled:
        pm.set_blocked(name)
    registry = Registry(pm)
    # "name version" per distribution: each ``Distribution.name`` / ``.version`` parses its METADATA
    # file again, which for amslam's twenty-odd entry points was a tenth of every command's start
    described: dict[int, str] = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in disabled or pm.is_blocked(ep.name) or pm.has_plugin(ep.name):
            continue
        dist = None
        if ep.dist is not None:
            if id(ep.dist) not in described:
                meta = ep.dist.metadata
                described[id(ep.dist)] = f"{meta['Name']} {meta['Version']}"
            dist = described[id(ep.dist)]
        where = f"distribution {dist}, {ep.value}" if dist else ep.value
        try:
            plugin = ep.load()
        except BaseException as exc:  # noqa: BLE001 — a broken plugin must not produce a traceback
            if isinstance(exc, KeyboardInterrupt):
                raise
            registry.load_errors[ep.name] = f"plugin {ep.name!r} ({where}) failed to load: {_one_line(exc)}"
            continue
        try:
            pm.register(plugin, name=ep.name)
        except pluggy.PluginValidationError as exc:
            registry.load_errors[ep.name] = f"plugin {ep.name!r} ({where}) was rejected: {_one_line(exc)}"
            continue
        if dist is not None:
            registry.distributions[ep.name] = dist
    for plugin in extra_plugins:
        pm.register(plugin)
    _check_pending(pm, registry)
    for kind in BACKEND_KINDS:
        registry.backends[kind], registry.providers[kind] = _collect(pm, f"amslam_{kind}_backends", registry)
    registry.behaviours, _ = _collect(pm, "amslam_behaviours", registry)
    registry.trees, _ = _collect(pm, "amslam_mission_trees", registry)
    registry.commands, _ = _collect(pm, "amslam_cli_commands", registry)
    registry.experiments, _ = _collect(pm, "amslam_experiments", registry)
    return registry


def _one_line(exc: BaseException, limit: int = 300) -> str:
    """``Type: message`` on one line: the message's lines joined with "; ", cut at ``limit`` characters."""
    text = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _named(registry: Registry, name: str) -> str:
    """``plugin 'name'``, with its distribution when it came from one."""
    dist = registry.distributions.get(name)
    return f"plugin {name!r} (distribution {dist})" if dist else f"plugin {name!r}"


def _check_pending(pm: pluggy.PluginManager, registry: Registry) -> None:
    """``check_pending()``, but a plugin implementing an unknown ``amslam_*`` hook is left out, named."""
    while True:
        try:
            pm.check_pending()
            return
        except pluggy.PluginValidationError as exc:
            name = pm.get_name(exc.plugin) or repr(exc.plugin)
            pm.unregister(exc.plugin)
            registry.load_errors[name] = f"{_named(registry, name)} was rejected: {_one_line(exc)}"
            registry.distributions.pop(name, None)


def _collect(pm: pluggy.PluginManager, hook_name: str, registry: Registry) -> tuple[dict, dict]:
    merged: dict[str, Callable] = {}
    provider: dict[str, str] = {}
    for impl in getattr(pm.hook, hook_name).get_hookimpls():
        if impl.plugin_name in registry.load_errors:
            continue  # already left out by another hook
        try:
            result = dict(impl.function() or {})
        except Exception as exc:  # noqa: BLE001 — a plugin raising at load time is reported, by name
            registry.load_errors[impl.plugin_name] = (
                f"{_named(registry, impl.plugin_name)} raised in {hook_name}: {_one_line(exc)}"
            )
            _forget(registry, impl.plugin_name)
            continue
        for name, factory in result.items():
            if name in merged:
                raise PluginError(
                    f"{hook_name}: name {name!r} is provided by both plugin "
                    f"{provider[name]!r} and plugin {impl.plugin_name!r}; disable one in the mission"
                )
            merged[name] = factory
            provider[name] = impl.plugin_name
    return merged, provider


def _forget(registry: Registry, plugin_name: str) -> None:
    """Drop what a plugin already contributed to earlier kinds and unregister it."""
    for kind, providers in registry.providers.items():
        for name in [n for n, p in providers.items() if p == plugin_name]:
            del providers[name]
            registry.backends[kind].pop(name, None)
    registry.distributions.pop(plugin_name, None)
    plugin = registry.pm.get_plugin(plugin_name)
    if plugin is not None:
        registry.pm.unregister(plugin)
