"""Every extension point of amslam, grouped by the phase of a run in which it is called.

Plugins implement these with ``@amslam.hookimpl``. An implementation may accept fewer arguments
than the specification, so arguments are only ever added, never renamed.

Backend hooks are called once when the plugin manager is built; their results are merged into
one registry per kind (a name provided twice is an error naming both plugins). Observer hooks
are called by the runner one implementation at a time, so an exception in one is logged as an
``observer_failed`` event naming the plugin and stops neither the run nor the other observers;
their return values are ignored, except ``amslam_run_metrics``'s.

Versioning: the hooks are amslam's stable plugin API. Every specification's docstring ends with
``Since: X.Y``, the amslam version that introduced it (``amslam.hookspecs.since(name)`` reads it);
a hook is never renamed or removed within a major version, and an argument added later says
``(since X.Y)`` in its description. A plugin that fails to import, implements an ``amslam_*`` hook
that is not specified here, or raises in a backend hook is reported by name and left out.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pluggy

if TYPE_CHECKING:
    import numpy as np
    import py_trees

    from amslam.cli import Command, Experiment
    from amslam.interfaces import Detector, Mapping, Planner, Platform, Slam
    from amslam.perception import Snapshot
    from amslam.types import KeyPose, LoopClosureResult, RunSummary, TourItem, WorldSummary

hookspec = pluggy.HookspecMarker("amslam")


def since(hook_name: str) -> str:
    """The amslam version that introduced a hook (the ``Since:`` line of its specification)."""
    func = globals().get(hook_name)
    if func is None or not hasattr(func, "amslam_spec"):
        raise KeyError(f"no hook specification named {hook_name!r}")
    for line in reversed((func.__doc__ or "").strip().splitlines()):
        if line.strip().startswith("Since:"):
            return line.split(":", 1)[1].strip()
    raise ValueError(f"hook specification {hook_name!r} does not say since which version it exists")


# --------------------------------------------------------------------------------------------
# Phase 1 — discovery: backends and behaviours a plugin provides (since 0.1)
# --------------------------------------------------------------------------------------------


@hookspec
def amslam_platform_backends() -> dict[str, Callable[[], Platform]]:
    """Platform backends (simulator, real vehicles) this plugin provides, by name.

    Called once at start-up; the results of all plugins are merged.

    Since: 0.1
    """


@hookspec
def amslam_mapping_backends() -> dict[str, Callable[[], Mapping]]:
    """Volumetric mapping backends this plugin provides, by name.

    Called once at start-up; the results of all plugins are merged.

    Since: 0.1
    """


@hookspec
def amslam_slam_backends() -> dict[str, Callable[[], Slam]]:
    """SLAM backends this plugin provides, by name.

    Called once at start-up; the results of all plugins are merged.

    Since: 0.1
    """


@hookspec
def amslam_planner_backends() -> dict[str, Callable[[], Planner]]:
    """Exploration planner backends this plugin provides, by name.

    Called once at start-up; the results of all plugins are merged.

    Since: 0.1
    """


@hookspec
def amslam_detector_backends() -> dict[str, Callable[[], Detector]]:
    """Object detector backends this plugin provides, by name.

    Called once at start-up; the results of all plugins are merged.

    Since: 0.1
    """


@hookspec
def amslam_behaviours() -> dict[str, Callable[..., py_trees.behaviour.Behaviour]]:
    """Extra behaviour-tree leaves this plugin provides, by name.

    Tree builders look behaviours up by name, so a plugin can replace a stock one.

    Since: 0.1
    """


# --------------------------------------------------------------------------------------------
# Phase 2 — run events, for recorders and visualisers (since 0.1). Return values are ignored.
# --------------------------------------------------------------------------------------------


@hookspec
def amslam_run_start(run_dir: Path, mission: dict[str, Any], world: WorldSummary | None) -> None:
    """The run folder exists and the backends are configured; nothing has flown yet.

    ``world`` (since 0.2) is the simulated world's ground truth (None on a real vehicle): what a
    live view measures the map against, e.g. the explored share of its reachable free cells.

    Since: 0.1
    """


@hookspec
def amslam_tick(t: float, tree: py_trees.trees.BehaviourTree, snapshot: Snapshot, mapping: Mapping) -> None:
    """After every behaviour-tree tick, with the simulated (or wall-clock) time.

    ``snapshot`` (since 0.2) is what perception knew at the end of the tick
    (:class:`amslam.perception.Snapshot`: pose, distance travelled, explored volume). ``mapping``
    (since 0.2) is the run's mapping backend behind its lock (the thread rule): an observer may
    query it (``states``, ``explored_volume``) on the control thread it is called on, and must not
    change it or keep it past the run.

    Since: 0.1
    """


@hookspec
def amslam_keyframe(t: float, keypose: KeyPose) -> None:
    """The SLAM backend created a key pose.

    Since: 0.1
    """


@hookspec
def amslam_replan(t: float, tour: list[TourItem], reason: str) -> None:
    """A new tour was adopted.

    Since: 0.1
    """


@hookspec
def amslam_loop_closure(t: float, result: LoopClosureResult) -> None:
    """A semantic loop closure was attempted (accepted or not).

    Since: 0.1
    """


@hookspec
def amslam_run_metrics(summary: RunSummary) -> dict[str, Any]:
    """Figures of the finished run, measured from its typed :class:`amslam.types.RunSummary`.

    The runner merges every answer into what it knows itself (``verdict``, ``mission``, ``seed``,
    ``plugins``): the result is ``metrics.json``, ``RunResult.metrics`` (what ``amslam run`` and
    the experiments print) and the ``metrics`` of :func:`amslam_run_end`. A key already given (by
    the runner or by an observer called earlier) is kept, and the later one is reported as an
    ``observer_failed`` event. The built-in report (``amslam.apps.report``) measures through this
    hook; with it disabled, ``metrics.json`` holds only what the runner knows. Called once, after
    the flight and before :func:`amslam_run_end`; the backends are still open.

    Since: 0.2
    """


@hookspec
def amslam_run_end(
    run_dir: Path, verdict: str, metrics: dict[str, Any], trajectory: np.ndarray, summary: RunSummary
) -> None:
    """The run ended with ``verdict``; ``metrics`` is what ``metrics.json`` holds (already written,
    see :func:`amslam_run_metrics`). The backends are still open and the trajectory streams closed,
    so an observer may write the map or replace a trajectory (``amslam.rundir.RunFiles``).

    ``trajectory`` holds the true positions (N×3, simulation only). ``summary`` (since 0.2) is the
    typed :class:`amslam.types.RunSummary` of the run: trajectories, samples, loop closures, the
    semantic map, the world's ground truth; an observer taking only the older arguments still
    works.

    Since: 0.1
    """


# --------------------------------------------------------------------------------------------
# Phase 3 — mission trees (since 0.2)
# --------------------------------------------------------------------------------------------


@hookspec
def amslam_mission_trees() -> dict[str, Callable[..., py_trees.behaviour.Behaviour]]:
    """Mission trees this plugin provides, by name; a mission's ``tree`` field selects one.

    Each value is called once per run as ``build(model, behaviours, failsafe=...)`` with the
    validated :class:`amslam.mission.MissionModel`, the registered behaviours by name
    (``amslam_behaviours``; look leaves up there so a plugin can replace one) and ``failsafe``:
    True on a real vehicle (``Platform.simulated`` is False), where the tree must answer the
    platform's failsafes (``amslam.trees.flight.with_failsafe_guard`` puts a tree under the stock
    guard). It returns the root behaviour. The leaves receive the runtime's services in
    ``setup`` (see :mod:`amslam.robot`). Called once at start-up; the results of all plugins are
    merged.

    Since: 0.2
    """


# --------------------------------------------------------------------------------------------
# Applications: command-line subcommands and experiments (since 0.2). Called once when the
# plugin manager is built, like the backend hooks; a name provided twice is an error.
# --------------------------------------------------------------------------------------------


@hookspec
def amslam_cli_commands() -> dict[str, Command]:
    """``amslam`` subcommands this plugin provides, by name (:class:`amslam.cli.Command`).

    The built-in ``run``, ``fly``, ``tree``, ``view``, … come through this hook too.

    Since: 0.2
    """


@hookspec
def amslam_experiments() -> dict[str, Experiment]:
    """``amslam experiment NAME`` experiments this plugin provides (:class:`amslam.cli.Experiment`).

    Since: 0.2
    """
