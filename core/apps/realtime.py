"""Real-time health of a flight on a real platform: control ticks, their overruns, the machine's load.

A run observer (the plugin ``realtime``, through the ``amslam`` entry points). On a real vehicle
(a run without a simulated world: ``amslam fly``, a SITL flight) the control loop runs on the wall
clock, and a tick that takes longer than its period delays the next one: the vehicle then flies on
its last setpoint and the frames wait. The runner's clock for such a run is the wall clock, so the
interval between two ``amslam_tick`` calls is the tick's real period. This observer adds to
``metrics.json``:

* ``control_ticks``, ``control_period_ms`` (from ``exploration.control_rate_hz``);
* ``control_tick_interval_ms``: median, p95, p99 and largest interval between two ticks;
* ``control_tick_overruns`` and ``control_tick_overrun_percent``: ticks that came more than a
  quarter period late (an interval above 1.25 periods; the sleep's own jitter on a loaded machine
  stays well below that); ``control_tick_overruns_by_behaviour``: how many of them followed a
  tick that ended in each behaviour (the tree's tip), where the time went;
* ``host_load``: the 1, 5 and 15 minute load averages at the start and the end of the flight and
  the number of CPUs, because on a shared machine the overruns say as much about the other jobs
  as about amslam;
* ``pipeline``: what became of the camera's frames (``frames``, ``mapped``, ``skipped_by_mapper``,
  ``detected``) and the latency table, in ms: from a frame's stamp to the local map, to the global
  map, to its detections in SLAM, and from a plan's snapshot to the plan's adoption (``median``,
  ``p95``, ``max``, ``n`` each).

Each late tick is also logged, never only counted: ``late_ticks.jsonl`` in the run folder has a
line per late tick (its time, interval, the behaviour the tick before it ended in) with what every
thread was doing when the tick was a quarter period late. A watchdog thread (``amslam-tick-watch``)
takes those stacks at that moment, as ``py-spy dump`` would; it needs the GIL to run, so a C++ call
that holds the GIL for longer is seen only when it returns (``seen_after_ms`` says how late). When
the watchdog itself could not run for a quarter period or more during the tick (a C++ call held
the GIL: a gtsam elimination, say), the line says for how long (``gil_held_ms``) and what every
thread was doing the moment it ran again (``threads_when_released``): the thread that held the GIL
is still at, or just after, the call. A line is written at the tick after the late one, so the
watchdog has had its turn.

A simulated run (simulated time advances by exactly one period per tick) gets none of these.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

import amslam

#: a tick this many periods after the previous one overran
OVERRUN_FACTOR = 1.25


#: stack frames kept per thread in ``late_ticks.jsonl`` (innermost last), and of amslam's own
#: frames below them
STACK_DEPTH = 8
AMSLAM_DEPTH = 4


class _Ticks:
    def __init__(self, period: float, run_dir: Path):
        self.period = period
        self.last: float | None = None
        self.last_tip = ""
        self.intervals: list[float] = []
        self.late_after: dict[str, int] = {}  # behaviour the tick before a late one ended in
        self.load_start = _load()
        self.log_path = run_dir / "late_ticks.jsonl"
        self.watch = _Watchdog(OVERRUN_FACTOR * period, threading.get_ident())
        self.pending: dict[str, Any] | None = None  # the last late tick, written at the next

    def late(self, t: float, interval: float) -> None:
        self.flush()
        self.pending = {
            "t": round(t, 3),
            "interval_ms": round(1000 * interval, 1),
            "after": self.last_tip,
            **self.watch.take(),
            "_since": time.monotonic() - interval,  # when the late tick began (not written)
        }

    def flush(self) -> None:
        """Write the pending late tick, with a GIL stall the watchdog saw during it."""
        record, self.pending = self.pending, None
        if record is None:
            return
        stall = self.watch.stall_since(record.pop("_since"))
        if stall is not None:
            record.update(stall)
        try:
            with self.log_path.open("a") as out:
                out.write(json.dumps(record) + "\n")
        except OSError:  # a full disk must not stop the flight; the count still says it
            pass


class _Watchdog:
    """Takes every thread's stack once a tick has run ``late`` seconds (``late_ticks.jsonl``)."""

    def __init__(self, late: float, control_thread: int):
        self.late, self.control_thread = late, control_thread
        self.tick_wall = time.monotonic()
        self.seen: dict[str, Any] = {}
        self.stall: tuple[float, dict[str, Any]] | None = None  # (when, what) the GIL held it off
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="amslam-tick-watch", daemon=True)
        self._thread.start()

    def ticked(self) -> None:
        with self._lock:
            self.tick_wall = time.monotonic()

    def take(self) -> dict[str, Any]:
        """What was seen during the late tick that just ended (nothing if the watchdog was late)."""
        with self._lock:
            seen, self.seen = self.seen, {}
        return seen

    def stall_since(self, since: float) -> dict[str, Any] | None:
        """The latest time the watchdog could not run for ``late`` or more, if it ended after
        ``since``: how long, and every thread's stack when it ran again."""
        with self._lock:
            stall = self.stall
        if stall is None or stall[0] < since:
            return None
        return stall[1]

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        captured_for = None
        nap = self.late / 5
        while True:
            before = time.monotonic()
            if self._stop.wait(nap):
                return
            now = time.monotonic()
            if now - before - nap >= self.late:  # held off: a call held the GIL that long
                stall = {
                    "gil_held_ms": round(1000 * (now - before - nap), 1),
                    "threads_when_released": _stacks(self.control_thread),
                }
                with self._lock:
                    self.stall = (now, stall)
            with self._lock:
                started = self.tick_wall
            since = time.monotonic() - started
            if since < self.late or captured_for == started:
                continue
            captured_for = started
            stacks = _stacks(self.control_thread)
            with self._lock:
                if self.tick_wall == started:  # still the same tick
                    self.seen = {"seen_after_ms": round(1000 * since, 1), "threads": stacks}


def _stacks(control_thread: int) -> dict[str, list[str]]:
    """Each thread's innermost frames as ``file:line function``, the control thread's first.

    Below a library's frames (an import, scipy's morphology) the innermost frames of amslam's
    own code are kept too, after a ``…``: they say which of its calls it was.
    """
    names = {t.ident: t.name for t in threading.enumerate()}
    me = threading.get_ident()
    out: dict[str, list[str]] = {}
    frames = sys._current_frames()  # the documented way to a thread's stack (faulthandler uses it)
    for ident in sorted(frames, key=lambda i: i != control_thread):
        if ident == me:
            continue
        stack = list(traceback.walk_stack(frames[ident]))  # innermost first
        inner = stack[:STACK_DEPTH]
        ours = [(f, n) for f, n in stack[STACK_DEPTH:] if _ours(f)]
        text = [_where(f, n) for f, n in reversed(inner)]
        if ours:
            text = [*(_where(f, n) for f, n in reversed(ours[:AMSLAM_DEPTH])), "…", *text]
        name = "control" if ident == control_thread else names.get(ident, str(ident))
        out[name] = text
    return out


_current: _Ticks | None = None


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # not on this system
        return None


@amslam.hookimpl
def amslam_run_start(run_dir: Path, mission: dict[str, Any], world: Any) -> None:
    global _current
    if _current is not None:  # the last run ended without its metrics
        _current.watch.stop()
    _current = None
    if world is not None:  # simulated: its clock is not the wall clock
        return
    rate = (mission.get("exploration") or {}).get("control_rate_hz") or 10.0
    _current = _Ticks(1.0 / float(rate), Path(run_dir))


@amslam.hookimpl
def amslam_tick(t: float, tree: Any) -> None:
    ticks = _current
    if ticks is None:
        return
    if ticks.last is not None:
        ticks.intervals.append(t - ticks.last)
        if t - ticks.last > OVERRUN_FACTOR * ticks.period:
            ticks.late_after[ticks.last_tip] = ticks.late_after.get(ticks.last_tip, 0) + 1
            ticks.late(t, t - ticks.last)
        else:
            ticks.flush()
    ticks.watch.ticked()
    ticks.last = t
    tip = tree.tip() if tree is not None else None
    ticks.last_tip = tip.name if tip is not None else "(tree not running)"


@amslam.hookimpl
def amslam_run_metrics(summary: Any) -> dict[str, Any]:
    global _current
    ticks, _current = _current, None
    if ticks is None:
        return {}
    ticks.watch.stop()
    ticks.flush()
    out: dict[str, Any] = {
        "control_ticks": len(ticks.intervals) + (ticks.last is not None),
        "control_period_ms": round(1000 * ticks.period, 1),
        "host_load": {"start": ticks.load_start, "end": _load(), "cpus": os.cpu_count()},
    }
    if ticks.intervals:
        ms = 1000 * np.asarray(ticks.intervals)
        late = int(np.count_nonzero(ms > 1000 * OVERRUN_FACTOR * ticks.period))
        out["control_tick_interval_ms"] = {
            "median": round(float(np.median(ms)), 1),
            "p95": round(float(np.percentile(ms, 95)), 1),
            "p99": round(float(np.percentile(ms, 99)), 1),
            "max": round(float(ms.max()), 1),
        }
        out["control_tick_overruns"] = late
        out["control_tick_overrun_percent"] = round(100 * late / len(ms), 2)
        out["control_tick_overruns_by_behaviour"] = dict(
            sorted(ticks.late_after.items(), key=lambda kv: -kv[1])
        )
    pipeline = getattr(summary, "pipeline", None)
    if pipeline:
        out["pipeline"] = pipeline_figures(pipeline)
    return out


#: the latency rows of the table: (metrics key, the summary's samples)
LATENCIES = (
    ("frame_to_local_map", "local_latency"),
    ("frame_to_global_map", "global_latency"),
    ("frame_to_slam_detections", "detection_latency"),
    ("snapshot_to_plan", "plan_latency"),
)


def pipeline_figures(pipeline: dict[str, Any]) -> dict[str, Any]:
    """The summary's frame counts as they are and each latency's median, p95 and max in ms."""
    out: dict[str, Any] = {k: pipeline[k] for k in ("frames", "mapped", "skipped_by_mapper", "detected")}
    latency = {}
    for key, samples in LATENCIES:
        ms = 1000 * np.asarray(pipeline.get(samples) or [], float)
        if len(ms):
            latency[key] = {
                "median": round(float(np.median(ms)), 1),
                "p95": round(float(np.percentile(ms, 95)), 1),
                "max": round(float(ms.max()), 1),
                "n": len(ms),
            }
    out["latency_ms"] = latency
    return out


def _where(frame: Any, line: int) -> str:
    return f"{Path(frame.f_code.co_filename).name}:{line} {frame.f_code.co_name}"


def _ours(frame: Any) -> bool:
    return frame.f_globals.get("__name__", "").startswith("amslam.")
