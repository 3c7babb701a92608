"""benchmarks/mission.py: each module is charged its own time, and the table and plot are made."""

from __future__ import annotations

import time

from tests.apps.benchmark_script import load_benchmark

mission = load_benchmark("mission")


class Inner:
    def work(self) -> None:
        time.sleep(0.02)


class Outer:
    def __init__(self) -> None:
        self.inner = Inner()

    def work(self) -> None:
        time.sleep(0.01)
        self.inner.work()
        self.inner.work()


def test_a_call_is_charged_its_own_time_not_its_callees() -> None:
    watch = mission.Stopwatch()
    watch.patch(Outer, "work", "planner")
    watch.patch(Inner, "work", "path costs")
    Outer().work()
    assert watch.calls == {"planner": 1, "path costs": 2}
    assert 0.04 <= watch.own["path costs"] < watch.own["path costs"] + watch.own["planner"]
    assert 0.01 <= watch.own["planner"] < 0.04  # not the 0.05 s the call lasted
    watch.restore()
    assert "work" in vars(Outer) and Outer.work.__qualname__ == "Outer.work"  # the original is back


def test_an_inherited_method_is_timed_on_the_class_and_removed_after() -> None:
    class Child(Inner):
        pass

    watch = mission.Stopwatch()
    watch.patch(Child, "work", "render")
    Child().work()
    Inner().work()  # the parent is not timed
    assert watch.calls == {"render": 1}
    watch.restore()
    assert "work" not in vars(Child)


def test_every_interface_method_of_the_demo_stack_is_charged_to_a_module() -> None:
    from amslam.mission import load_mission
    from amslam.registry import build_plugin_manager

    registry = build_plugin_manager()
    watch = mission.Stopwatch()
    mission.instrument(watch, registry, load_mission("demo", registry, []))
    try:
        charged = {cls.__name__ + "." + name for cls, name, _ in watch._patched}
        assert {"Open3dVoxelMap.path_costs", "SimPlatform.capture", "Runner._finish"} <= charged
        assert {m for kind in mission.MODULES.values() for m in kind.values()} <= set(mission.ORDER)
    finally:
        watch.restore()


def test_table_and_plot(tmp_path) -> None:
    def row(name: str, volume: float, scale: float) -> dict:
        return {
            "building": name,
            "reachable_free_volume_m3": volume,
            "explored_percent": 90.0,
            "sim_s": 100.0,
            "ticks": 1000,
            "loop_s": 20.0 * scale,
            "realtime_factor": 5.0 / scale,
            "realtime_factor_cpu": 5.5 / scale,
            "ms_per_tick": {m: scale * (i + 1) for i, m in enumerate(mission.ORDER)},
            "setup_s": 1.0,
            "report_s": 0.5,
            "load": [1.0, 1.2],
        }

    rows = [row("demo", 500.0, 1.0), row("hall", 5000.0, 3.0)]
    text = mission.table(rows)
    assert "| | demo | hall |" in text
    assert "| **real-time factor** (wall) | **5.00×** | **1.67×** |" in text
    assert "| path costs, ms/tick | 5.00 | 15.00 |" in text
    mission.plot(rows, tmp_path / "m.png")
    assert (tmp_path / "m.png").stat().st_size > 10_000
