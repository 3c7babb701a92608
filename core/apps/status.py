"""A run's progress on the console: a bar on a terminal, a status line every few seconds elsewhere.

A run observer (the plugin ``status``, through the ``amslam`` entry points). While a mission flies:

- stderr is a terminal: a progress bar of the **time budget used** — simulated (or flight) time
  over ``limits.max_time``, in whole seconds —, with what was explored, the distance flown, the
  semantic loop closures and what the tree is doing. It is not a measure of the mission's
  completion (no one knows that in advance): exploration may end well before the budget, and the
  way home may go past it (the bar then shows more than 100 %);
- stderr is anything else (CI, ``nohup``, a pipe, ``ssh host amslam run … | tee log``): the same
  figures as one line, written at most every :data:`DEFAULT_INTERVAL` seconds of wall time and,
  when the control loop is busy for longer (a long planner call, the report written at the end),
  by a heartbeat thread with the last known figures, so that a log never stays silent for more
  than the interval plus :data:`HEARTBEAT_PERIOD`. ``AMSLAM_STATUS_INTERVAL`` sets the interval
  (seconds; 0: every control tick).

Both are log records of the ``amslam.status`` logger at ``INFO``: ``--quiet`` (or ``--log-level
warning``) silences them, and a program that embeds the runner without configuring ``logging``
gets neither.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import amslam

log = logging.getLogger("amslam.status")

#: the environment variable that sets the interval between status lines (seconds of wall time)
INTERVAL_VARIABLE = "AMSLAM_STATUS_INTERVAL"
#: seconds of wall time between two status lines
DEFAULT_INTERVAL = 5.0
#: how often the heartbeat thread looks whether a line is due (seconds of wall time)
HEARTBEAT_PERIOD = 1.0


@dataclass(frozen=True)
class Progress:
    """What a status line says about a run."""

    mission: str
    max_time: float
    t: float = 0.0
    distance: float = 0.0
    #: share of the world's reachable free space the map knows, % (None without a world: a real vehicle)
    explored_percent: float | None = None
    explored_m3: float = 0.0
    slc_attempts: int = 0
    slc_accepted: int = 0
    #: the tree's running top-level step and its active leaf, or the phase after the flight
    activity: str = "starting"

    def figures(self) -> str:
        """``explored 41.2 % | 23.5 m flown | SLC 1/2 accepted | ExploreUntilDone > GoToViewpoint``."""
        explored = (
            f"explored {self.explored_percent:.1f} %"
            if self.explored_percent is not None
            else f"explored {self.explored_m3:.0f} m³"
        )
        slc = f"SLC {self.slc_accepted}/{self.slc_attempts} accepted"
        return f"{explored} | {self.distance:.1f} m flown | {slc} | {self.activity}"

    def head(self) -> str:
        """``demo: t 3/20 s (14 % of the time budget)``: whole seconds, past 100 % on a late way home."""
        budget = 100 * self.t / self.max_time if self.max_time > 0 else 0.0
        return f"{self.mission}: t {self.t:.0f}/{self.max_time:.0f} s ({budget:.0f} % of the time budget)"

    def line(self) -> str:
        """The status line: the mission, its time against the budget, the figures."""
        return f"{self.head()} | {self.figures()}"


def activity(tree: Any) -> str:
    """What the tree is doing: its root's running child and the active leaf (``a > b``)."""
    root = tree.root
    tip = tree.tip()
    step = next((child for child in getattr(root, "children", ()) if child.status.name == "RUNNING"), None)
    names = [node.name for node in (step, tip) if node is not None and node is not root]
    names = list(dict.fromkeys(names))  # a step that is its own leaf (TakeOff) once
    return " > ".join(names) or root.name


class StatusLines:
    """The lines of one run: written when due, by the control thread or by the heartbeat.

    ``clock`` (wall time, seconds) and ``write`` are parameters so a test can drive it without
    waiting; the heartbeat thread is started by :meth:`start_heartbeat`.
    """

    def __init__(
        self,
        progress: Progress,
        every: float,
        write: Callable[[str], None] = log.info,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.progress = progress
        self.every = every
        self._write, self._clock = write, clock
        self._lock = threading.Lock()
        self._last = clock()
        self._measured = -math.inf  # when the control thread last measured the explored share
        self._stop = threading.Event()
        self._heartbeat: threading.Thread | None = None

    def measurement_due(self) -> bool:
        """Whether the control thread should measure the explored share again (at the pace of the
        lines, but on its own clock: the heartbeat may have written the last line)."""
        if self._clock() - self._measured < self.every:
            return False
        self._measured = self._clock()
        return True

    def update(self, **changes: Any) -> None:
        with self._lock:
            self.progress = replace(self.progress, **changes)

    def write_if_due(self) -> None:
        with self._lock:
            if self._clock() - self._last < self.every:
                return
            self._last = self._clock()
            line = self.progress.line()
        self._write(line)

    def start_heartbeat(self) -> None:
        """A daemon thread that writes the last known line when the control thread has not for
        ``every`` seconds (it is inside a long call): a log never stays silent much longer."""

        def beat() -> None:
            while not self._stop.wait(min(max(self.every, 0.05), HEARTBEAT_PERIOD)):
                self.write_if_due()

        self._heartbeat = threading.Thread(target=beat, name="amslam-status", daemon=True)
        self._heartbeat.start()

    def stop(self) -> None:
        self._stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join(timeout=2 * HEARTBEAT_PERIOD)


class ProgressBar(StatusLines):
    """On a terminal: a tqdm bar of the time budget used, redrawn at most twice a second."""

    def __init__(self, progress: Progress, every: float, stream: Any):
        # no line to write: the bar redraws itself at every update (tqdm paces the drawing)
        super().__init__(progress, every, write=lambda line: None)
        from tqdm import tqdm

        class Bar(tqdm):
            """tqdm with the status line's figures as ``{figures}`` (``{postfix}`` starts with a comma)."""

            figures = progress.figures()

            @property
            def format_dict(self) -> dict[str, Any]:
                return {**super().format_dict, "figures": self.figures}

        self.bar = Bar(
            total=progress.max_time,
            desc=progress.head(),
            # the head and figures of the status line, in whole seconds (tqdm's own {n_fmt} shows the
            # float sum of the ticks, 2.800000000000002); tqdm's percentage is left out, as tqdm
            # drops the bar once n passes the total
            bar_format="{desc} |{bar}| {figures} [{elapsed}]",
            mininterval=0.5,
            leave=False,
            file=stream,
        )

    def update(self, **changes: Any) -> None:
        super().update(**changes)
        p = self.progress
        # full at the budget; past it (a late way home) full still, and the head says how far past
        self.bar.total = max(p.max_time, p.t)
        self.bar.n = p.t
        self.bar.set_description_str(p.head(), refresh=False)
        self.bar.figures = p.figures()
        self.bar.update(0)

    def stop(self) -> None:
        super().stop()
        self.bar.close()


def interval_from_environment() -> float:
    """The interval between status lines: ``AMSLAM_STATUS_INTERVAL`` or :data:`DEFAULT_INTERVAL`."""
    text = os.environ.get(INTERVAL_VARIABLE, "").strip()
    if not text:
        return DEFAULT_INTERVAL
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0:
        log.warning(
            f"{INTERVAL_VARIABLE}={text!r} is not a number of seconds (0 or more); "
            f"a status line every {DEFAULT_INTERVAL:g} s"
        )
        return DEFAULT_INTERVAL
    return value


# -- the run observer ------------------------------------------------------------------------------

#: the status of the run in flight (runs in one process fly one after the other)
_current: StatusLines | None = None
#: the world of the run in flight, for the explored share (None on a real vehicle)
_world: Any = None


@amslam.hookimpl
def amslam_run_start(run_dir: Path, mission: dict[str, Any], world: Any) -> None:
    global _current, _world
    _stop_current()
    if not log.isEnabledFor(logging.INFO):  # --quiet, or a program that did not configure logging
        return
    progress = Progress(
        mission=str(mission.get("name", run_dir.name)),
        max_time=float(mission.get("limits", {}).get("max_time", 0.0)),
    )
    every = interval_from_environment()
    _world = world
    if sys.stderr.isatty():
        _current = ProgressBar(progress, every, sys.stderr)
    else:
        _current = StatusLines(progress, every)
        _current.start_heartbeat()
        log.debug(f"status line every {every:g} s of wall time ({INTERVAL_VARIABLE})")


@amslam.hookimpl
def amslam_tick(t: float, tree: Any, snapshot: Any, mapping: Any) -> None:
    status = _current
    if status is None:
        return
    changes: dict[str, Any] = {
        "t": t,
        "distance": snapshot.distance,
        "explored_m3": snapshot.explored_volume,
        "activity": activity(tree),
    }
    if status.measurement_due():  # not at every tick: it queries the map at every reachable cell
        changes["explored_percent"] = _explored_percent(mapping)
    status.update(**changes)
    status.write_if_due()


def _explored_percent(mapping: Any) -> float | None:
    if _world is None:
        return None
    from amslam.apps.report import explored_share

    share, _ = explored_share(mapping, _world)
    return None if math.isnan(share) else 100 * share


@amslam.hookimpl
def amslam_loop_closure(t: float, result: Any) -> None:
    status = _current
    if status is not None:
        p = status.progress
        status.update(slc_attempts=p.slc_attempts + 1, slc_accepted=p.slc_accepted + bool(result.accepted))


@amslam.hookimpl(tryfirst=True)
def amslam_run_metrics(summary: Any) -> None:
    """The flight is over; the observers measure it and write the report, map and plots — which
    takes a while on a big map: the heartbeat goes on saying so until :func:`amslam_run_end`."""
    status = _current
    if status is not None:
        status.update(activity=f"flight ended ({summary.verdict}): writing the report, map and plots")
        status.write_if_due()


@amslam.hookimpl(trylast=True)
def amslam_run_end(run_dir: Path, verdict: str) -> None:
    """Called after every other run-end observer (the report among them): the outputs are written."""
    _stop_current()


def _stop_current() -> None:
    global _current, _world
    if _current is not None:
        _current.stop()
    _current, _world = None, None
