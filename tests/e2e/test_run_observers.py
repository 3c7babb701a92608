"""The run report is an application observer: the kernel writes the verdict and survives observers.

Short flights of the small mission (5 s of simulated time): what is checked is who writes which
file at the end of a run, not how well it explored.
"""

from __future__ import annotations

import json
import threading

import amslam
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from tests.e2e.missions import small_mission

STREAMS = ("mission.yaml", "events.jsonl", "tree.jsonl", "ground_truth.tum", "vio.tum", "slam.tum")
REPORT_FILES = ("report.md", "map.ply", "map.npz", "landmarks.json", "top_view.png")


def _fly(tmp_path, disabled=(), extra_plugins=()):
    registry = build_plugin_manager(disabled, extra_plugins)
    mission = load_mission(small_mission(tmp_path, max_time=5), registry)
    return Runner(mission, registry, tmp_path / "runs").run()


def _events(run_dir, name):
    lines = (run_dir / "events.jsonl").read_text().splitlines()
    return [e for e in map(json.loads, lines) if e["event"] == name]


def test_without_the_report_a_run_leaves_the_verdict_and_the_streams(tmp_path):
    result = _fly(tmp_path, disabled=["report"])
    assert result.verdict == "completed"
    metrics = json.loads((result.run_dir / "metrics.json").read_text())
    assert sorted(metrics) == ["exploration_end", "mission", "plugins", "seed", "verdict", "way_home"]
    assert metrics == result.metrics and metrics["verdict"] == "completed"
    for name in STREAMS:
        assert (result.run_dir / name).exists(), name
    for name in REPORT_FILES:
        assert not (result.run_dir / name).exists(), name


class BrokenObserver:
    """Raises in both run-end hooks, like a third party's bug would."""

    __name__ = "broken_observer"  # the name pluggy registers an in-process plugin under

    @amslam.hookimpl
    def amslam_run_metrics(self, summary):
        raise RuntimeError("no figures today")

    @amslam.hookimpl
    def amslam_run_end(self, run_dir):
        raise RuntimeError("disk of the dashboard is full")


class ExtraFigures:
    """A third party's own figure, and an attempt to overrule the verdict."""

    __name__ = "extra_figures"

    @amslam.hookimpl
    def amslam_run_metrics(self, summary):
        return {"landings": 1, "verdict": "excellent"}


def test_a_raising_observer_is_named_and_changes_nothing_else(tmp_path):
    broken, extra = BrokenObserver(), ExtraFigures()
    result = _fly(tmp_path, extra_plugins=[broken, extra])
    assert result.verdict == "completed"
    metrics = json.loads((result.run_dir / "metrics.json").read_text())
    assert metrics == result.metrics
    # the report still measured and wrote (pluggy alone would have stopped at the first exception)
    assert metrics["verdict"] == "completed" and metrics["distance_m"] > 0 and metrics["landings"] == 1
    assert "**Verdict: completed**" in (result.run_dir / "report.md").read_text()
    failed = {(e["hook"], e["plugin"]): e["error"] for e in _events(result.run_dir, "observer_failed")}
    assert failed == {
        ("amslam_run_metrics", "broken_observer"): "RuntimeError: no figures today",
        ("amslam_run_end", "broken_observer"): "RuntimeError: disk of the dashboard is full",
        ("amslam_run_metrics", "extra_figures"): "metrics verdict already given; the earlier kept",
    }
    assert _events(result.run_dir, "run_end")[-1]["verdict"] == "completed"


class LosesStderrOnItsThread:
    """Meets a closed stderr on a thread of its own, as the status line's heartbeat can."""

    __name__ = "loses_stderr"

    @amslam.hookimpl
    def amslam_run_start(self, run_dir):
        from amslam import console

        def lost() -> None:
            for listener in list(console._listeners):  # what console._gone tells them
                listener("stderr")

        thread = threading.Thread(target=lost, name="observer-thread")
        thread.start()
        thread.join()


def test_an_output_closed_on_another_thread_is_recorded_by_the_control_thread(tmp_path, monkeypatch):
    """The run folder is the control thread's (thread rule): the listener only takes note."""
    from amslam.rundir import RunDir

    written_on: dict[str, str] = {}
    event = RunDir.event

    def recording(self, t, name, /, **fields):
        written_on[name] = threading.current_thread().name
        event(self, t, name, **fields)

    monkeypatch.setattr(RunDir, "event", recording)
    result = _fly(tmp_path, extra_plugins=[LosesStderrOnItsThread()])
    assert result.verdict == "completed"
    assert [e["event"] for e in _events(result.run_dir, "stderr_closed")] == ["stderr_closed"]
    assert written_on["stderr_closed"] == threading.main_thread().name
