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
  stays well below that);
* ``host_load``: the 1, 5 and 15 minute load averages at the start and the end of the flight and
  the number of CPUs, because on a shared machine the overruns say as much about the other jobs
  as about amslam.

A simulated run (simulated time advances by exactly one period per tick) gets none of these.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

import amslam

#: a tick this many periods after the previous one overran
OVERRUN_FACTOR = 1.25


class _Ticks:
    def __init__(self, period: float):
        self.period = period
        self.last: float | None = None
        self.intervals: list[float] = []
        self.load_start = _load()


_current: _Ticks | None = None


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # not on this system
        return None


@amslam.hookimpl
def amslam_run_start(run_dir: Path, mission: dict[str, Any], world: Any) -> None:
    global _current
    _current = None
    if world is not None:  # simulated: its clock is not the wall clock
        return
    rate = (mission.get("exploration") or {}).get("control_rate_hz") or 10.0
    _current = _Ticks(1.0 / float(rate))


@amslam.hookimpl
def amslam_tick(t: float) -> None:
    ticks = _current
    if ticks is None:
        return
    if ticks.last is not None:
        ticks.intervals.append(t - ticks.last)
    ticks.last = t


@amslam.hookimpl
def amslam_run_metrics(summary: Any) -> dict[str, Any]:
    global _current
    ticks, _current = _current, None
    if ticks is None:
        return {}
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
    return out
