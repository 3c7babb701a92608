"""The real-time health observer: control-tick intervals and overruns of real-platform runs."""

from __future__ import annotations

from pathlib import Path

from amslam.apps import realtime


def test_overruns_are_ticks_more_than_a_quarter_period_late():
    realtime.amslam_run_start(Path("."), {"exploration": {"control_rate_hz": 10}}, world=None)
    for t in (0.0, 0.1, 0.2, 0.3, 0.56, 0.66, 0.78):  # one tick 0.26 s after the last, one 0.12 s
        realtime.amslam_tick(t)
    metrics = realtime.amslam_run_metrics(summary=None)
    assert metrics["control_ticks"] == 7 and metrics["control_period_ms"] == 100.0
    assert metrics["control_tick_overruns"] == 1  # 120 ms is late, but by less than a quarter period
    assert metrics["control_tick_overrun_percent"] == round(100 / 6, 2)
    assert metrics["control_tick_interval_ms"]["max"] == 260.0
    assert set(metrics["host_load"]) == {"start", "end", "cpus"}
    assert realtime.amslam_run_metrics(summary=None) == {}  # measured once, for its own run


def test_a_simulated_run_is_not_measured():
    realtime.amslam_run_start(Path("."), {}, world=object())
    realtime.amslam_tick(0.0)
    realtime.amslam_tick(5.0)
    assert realtime.amslam_run_metrics(summary=None) == {}
