"""An object a plugin names without importing it: its module is imported when it is first used.

A plugin's discovery hooks (backends, behaviours, mission trees) return what they provide by
name. Returning the classes themselves imports their modules, and with them numpy, py_trees and
the rest, every time the registry is built: for ``amslam plugins`` and ``amslam validate`` too,
which use none of them (issue #20). A :class:`Deferred` stands in for the object until then:

    @amslam.hookimpl
    def amslam_planner_backends():
        return {"greedy": Deferred("amslam.plugins.planners.greedy:GreedyPlanner")}

Calling it calls the object (a factory builds a backend, a behaviour class a behaviour, a tree
builder a tree), so behaviours and trees are used as they are; a backend's class is also read
(``Params``, ``requires``, ``simulated``), so :meth:`amslam.registry.Registry.factory` hands out
the class itself.
"""

from __future__ import annotations

import importlib
from typing import Any


class Deferred:
    """The object ``module:attribute``, imported on first use and kept."""

    __slots__ = ("path", "_loaded")

    def __init__(self, path: str):
        module, _, attribute = path.partition(":")
        if not module or not attribute:
            raise ValueError(f"Deferred({path!r}): expected 'package.module:attribute'")
        self.path = path
        self._loaded: Any = None

    def load(self) -> Any:
        """The object, importing its module the first time (its import errors propagate)."""
        if self._loaded is None:
            module, _, attribute = self.path.partition(":")
            self._loaded = getattr(importlib.import_module(module), attribute)
        return self._loaded

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.load()(*args, **kwargs)

    def __repr__(self) -> str:
        return f"Deferred({self.path!r})"
