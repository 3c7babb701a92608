"""The real-time health observer: control-tick intervals and overruns of real-platform runs."""

from __future__ import annotations

import json
import re
import threading
import time

from amslam.apps import realtime


class _Tree:
    def __init__(self, tip: str):
        self._tip = type("Behaviour", (), {"name": tip})()

    def tip(self):
        return self._tip


def test_overruns_are_ticks_more_than_a_quarter_period_late(tmp_path):
    realtime.amslam_run_start(tmp_path, {"exploration": {"control_rate_hz": 10}}, world=None)
    for t in (0.0, 0.1, 0.2, 0.3, 0.56, 0.66, 0.78):  # one tick 0.26 s after the last, one 0.12 s
        realtime.amslam_tick(t, tree=_Tree("GoTo" if t == 0.3 else "Replan"))
    metrics = realtime.amslam_run_metrics(summary=None)
    assert metrics["control_ticks"] == 7 and metrics["control_period_ms"] == 100.0
    assert metrics["control_tick_overruns"] == 1  # 120 ms is late, but by less than a quarter period
    assert metrics["control_tick_overrun_percent"] == round(100 / 6, 2)
    assert metrics["control_tick_interval_ms"]["max"] == 260.0
    assert set(metrics["host_load"]) == {"start", "end", "cpus"}
    assert metrics["control_tick_overruns_by_behaviour"] == {"GoTo": 1}  # the tick that took long
    (line,) = (tmp_path / "late_ticks.jsonl").read_text().splitlines()  # each late tick is logged
    assert json.loads(line) | {"threads": None} == {
        "t": 0.56,
        "interval_ms": 260.0,
        "after": "GoTo",
        "threads": None,
    }
    assert realtime.amslam_run_metrics(summary=None) == {}  # measured once, for its own run


def test_a_simulated_run_is_not_measured(tmp_path):
    realtime.amslam_run_start(tmp_path, {}, world=object())
    realtime.amslam_tick(0.0, tree=None)
    realtime.amslam_tick(5.0, tree=None)
    assert realtime.amslam_run_metrics(summary=None) == {}


def test_the_camera_pipelines_counts_and_latency_table(tmp_path):
    from types import SimpleNamespace

    realtime.amslam_run_start(tmp_path, {}, world=None)
    realtime.amslam_tick(0.0, tree=None)
    pipeline = {
        "frames": 50,
        "mapped": 40,
        "skipped_by_mapper": 10,
        "detected": 12,
        "local_latency": [0.01] * 49 + [0.05],
        "global_latency": [0.1, 0.2, 0.3],
        "detection_latency": [],  # none fed: no row
        "plan_latency": [1.5],
    }
    metrics = realtime.amslam_run_metrics(summary=SimpleNamespace(pipeline=pipeline))
    figures = metrics["pipeline"]
    assert (figures["frames"], figures["mapped"], figures["skipped_by_mapper"], figures["detected"]) == (
        50,
        40,
        10,
        12,
    )
    latency = figures["latency_ms"]
    assert set(latency) == {"frame_to_local_map", "frame_to_global_map", "snapshot_to_plan"}
    assert latency["frame_to_local_map"] == {"median": 10.0, "p95": 10.0, "max": 50.0, "n": 50}
    assert latency["frame_to_global_map"]["median"] == 200.0 and latency["snapshot_to_plan"]["n"] == 1


def test_a_late_tick_is_logged_with_what_the_control_thread_was_doing_then(tmp_path):
    realtime.amslam_run_start(tmp_path, {"exploration": {"control_rate_hz": 10}}, world=None)
    start = time.monotonic()
    realtime.amslam_tick(0.0, tree=_Tree("TakeOff"))

    def a_slow_map_update():
        time.sleep(0.4)  # the tick runs 0.4 s where 0.1 s were its period

    a_slow_map_update()
    realtime.amslam_tick(time.monotonic() - start, tree=_Tree("GoTo"))
    realtime.amslam_run_metrics(summary=None)
    (line,) = (tmp_path / "late_ticks.jsonl").read_text().splitlines()
    record = json.loads(line)
    assert record["after"] == "TakeOff" and record["interval_ms"] >= 400.0
    assert record["seen_after_ms"] >= 125.0
    control = record["threads"]["control"]
    assert any(f.endswith(" a_slow_map_update") for f in control), control
    assert "amslam-tick-watch" not in record["threads"]
    assert not [t for t in threading.enumerate() if t.name == "amslam-tick-watch"]  # stopped


def _hold_the_gil(at_least: float) -> None:
    """A C call that does not let go of the GIL (the regular expression engine backtracking),
    made longer until one has held it ``at_least`` seconds: like a long gtsam elimination."""
    n = 16
    while True:
        start = time.monotonic()
        re.match(r"(a+)+$", "a" * n + "b")
        if time.monotonic() - start >= at_least:
            return
        n += 1


def test_a_late_tick_names_the_thread_whose_c_call_held_the_gil(tmp_path):
    realtime.amslam_run_start(tmp_path, {"exploration": {"control_rate_hz": 10}}, world=None)
    start = time.monotonic()
    realtime.amslam_tick(0.0, tree=_Tree("Replan"))

    def a_c_call_holding_the_gil():
        _hold_the_gil(0.3)
        time.sleep(0.3)  # still here when the watchdog runs again

    planner = threading.Thread(target=a_c_call_holding_the_gil, name="amslam-planner_0")
    planner.start()
    planner.join()
    now = time.monotonic() - start
    realtime.amslam_tick(now, tree=_Tree("GoTo"))  # late
    realtime.amslam_tick(now + 0.1, tree=_Tree("GoTo"))  # on time: the late one is written now
    realtime.amslam_run_metrics(summary=None)
    (line,) = (tmp_path / "late_ticks.jsonl").read_text().splitlines()
    record = json.loads(line)
    assert record["after"] == "Replan"
    assert record["gil_held_ms"] >= 125.0
    held = record["threads_when_released"]["amslam-planner_0"]
    assert any(f.endswith(" a_c_call_holding_the_gil") for f in held), held
