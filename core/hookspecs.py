"""Every extension point of amslam, grouped by the phase of a run in which it is called.

Plugins implement these with ``@amslam.hookimpl``. An implementation may accept fewer arguments
than the specification, so arguments are only ever added, never renamed.

Backend hooks are called once when the plugin manager is built; their results are merged into
one registry per kind (a name provided twice is an error naming both plugins). Observer hooks
are called by the runner; their return values are ignored and an exception in one is logged as
an event and does not stop the run.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pluggy

if TYPE_CHECKING:
    import numpy as np
    import py_trees

    from amslam.interfaces import Detector, Mapping, Planner, Platform, Slam
    from amslam.types import KeyPose, LoopClosureResult, TourItem

hookspec = pluggy.HookspecMarker("amslam")

# --------------------------------------------------------------------------------------------
# Phase 1 — discovery: backends and behaviours a plugin provides (since 0.1)
# --------------------------------------------------------------------------------------------


@hookspec
def amslam_platform_backends() -> dict[str, Callable[[], Platform]]:
    """Platform backends (simulator, real vehicles) this plugin provides, by name.

    Since 0.1. Called once at start-up; all results are merged.
    """


@hookspec
def amslam_mapping_backends() -> dict[str, Callable[[], Mapping]]:
    """Volumetric mapping backends this plugin provides, by name. Since 0.1."""


@hookspec
def amslam_slam_backends() -> dict[str, Callable[[], Slam]]:
    """SLAM backends this plugin provides, by name. Since 0.1."""


@hookspec
def amslam_planner_backends() -> dict[str, Callable[[], Planner]]:
    """Exploration planner backends this plugin provides, by name. Since 0.1."""


@hookspec
def amslam_detector_backends() -> dict[str, Callable[[], Detector]]:
    """Object detector backends this plugin provides, by name. Since 0.1."""


@hookspec
def amslam_behaviours() -> dict[str, Callable[..., py_trees.behaviour.Behaviour]]:
    """Extra behaviour-tree leaves this plugin provides, by name. Since 0.1.

    Tree builders look behaviours up by name, so a plugin can replace a stock one.
    """


# --------------------------------------------------------------------------------------------
# Phase 2 — run events, for recorders and visualisers (since 0.1). Return values are ignored.
# --------------------------------------------------------------------------------------------


@hookspec
def amslam_run_start(run_dir: Path, mission: dict[str, Any]) -> None:
    """The run folder exists and the backends are configured; nothing has flown yet."""


@hookspec
def amslam_tick(t: float, tree: py_trees.trees.BehaviourTree) -> None:
    """After every behaviour-tree tick, with the simulated (or wall-clock) time."""


@hookspec
def amslam_keyframe(t: float, keypose: KeyPose) -> None:
    """The SLAM backend created a key pose."""


@hookspec
def amslam_replan(t: float, tour: list[TourItem], reason: str) -> None:
    """A new tour was adopted."""


@hookspec
def amslam_loop_closure(t: float, result: LoopClosureResult) -> None:
    """A semantic loop closure was attempted (accepted or not)."""


@hookspec
def amslam_run_end(run_dir: Path, verdict: str, metrics: dict[str, Any], trajectory: np.ndarray) -> None:
    """The run ended with ``verdict``; ``metrics`` is what ``metrics.json`` holds."""
