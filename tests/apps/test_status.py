"""The console status of a run (amslam.apps.status): status lines off a terminal, paced by wall
time yet never silent for long; the progress bar's figures rounded and true."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
from pathlib import Path

import py_trees
from py_trees.common import Status

from amslam.apps import status
from amslam.apps.status import Progress, ProgressBar, StatusLines
from tests.e2e.missions import small_mission

AMSLAM = Path(sys.executable).with_name("amslam")
STATUS_LINE = re.compile(r"^small: t (\d+)/5 s \((\d+) % of the time budget\) \| explored ")


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_line_is_written_when_due_and_not_before():
    clock, lines = FakeClock(), []
    lines_of = StatusLines(Progress("demo", 1200.0), every=5.0, write=lines.append, clock=clock)
    for tick in range(200):  # 20 s of wall time at 0.1 s a tick
        clock.now = tick / 10
        lines_of.update(t=tick * 0.05)
        lines_of.write_if_due()
    assert len(lines) == 3  # at 5, 10 and 15 s (the next at 20 s)
    assert lines[0].startswith("demo: t 2/1200 s (0 % of the time budget) | explored 0 m³ | 0.0 m flown")


def test_the_explored_share_is_measured_at_the_pace_of_the_lines_whoever_writes_them():
    clock = FakeClock()
    lines_of = StatusLines(Progress("demo", 1200.0), every=5.0, write=lambda line: None, clock=clock)
    measured = []
    for tick in range(200):  # 20 s of wall time at 0.1 s a tick
        clock.now = tick / 10
        if tick % 7 == 0:
            lines_of.write_if_due()  # the heartbeat, between the ticks
        if lines_of.measurement_due():
            measured.append(clock.now)
    assert measured == [0.0, 5.0, 10.0, 15.0]  # at the first tick, then every 5 s


def test_the_heartbeat_writes_while_the_control_thread_is_busy():
    """No tick comes (a long planner call); the heartbeat thread writes the last known line."""
    written, got_one = [], threading.Event()

    def write(line: str) -> None:
        written.append(line)
        got_one.set()

    lines_of = StatusLines(Progress("demo", 100.0, t=42.0, activity="Replan"), every=0.0, write=write)
    lines_of.start_heartbeat()
    try:
        assert got_one.wait(timeout=60), "the heartbeat wrote nothing"  # a hang bound, not a timing
    finally:
        lines_of.stop()
    assert written[0] == (
        "demo: t 42/100 s (42 % of the time budget) | explored 0 m³ | 0.0 m flown | SLC 0/0 accepted | Replan"
    )
    assert not lines_of._heartbeat.is_alive()


def test_figures_are_rounded_and_the_budget_may_pass_100_percent():
    p = Progress(
        "demo",
        20.0,
        t=2.800000000000002,
        distance=3.14159,
        explored_percent=41.234,
        slc_attempts=3,
        slc_accepted=2,
        activity="ExploreUntilDone > GoToViewpoint",
    )
    assert p.line() == (
        "demo: t 3/20 s (14 % of the time budget) | explored 41.2 % | 3.1 m flown | "
        "SLC 2/3 accepted | ExploreUntilDone > GoToViewpoint"
    )
    assert "(125 % of the time budget)" in Progress("demo", 20.0, t=25.0).line()  # flying home late


def test_the_bar_shows_whole_seconds_of_the_time_budget(tmp_path):
    with (tmp_path / "bar").open("w") as stream:
        bar = ProgressBar(Progress("demo", 20.0), every=5.0, stream=stream)
        bar.bar.mininterval = 0  # draw every update
        bar.update(t=2.800000000000002, distance=1.0)
        drawn = str(bar.bar)
        bar.update(t=25.0)
        over = str(bar.bar)
        bar.stop()
    assert drawn.startswith("demo: t 3/20 s (14 % of the time budget) |"), drawn
    assert "2.8000" not in drawn
    assert over.startswith("demo: t 25/20 s (125 % of the time budget) |"), over  # not stuck at 100 %


def test_activity_names_the_running_step_and_its_leaf():
    leaf = py_trees.behaviours.Running(name="GoToViewpoint")
    step = py_trees.composites.Sequence("ExploreUntilDone", memory=True, children=[leaf])
    done = py_trees.behaviours.Success(name="TakeOff")
    tree = py_trees.trees.BehaviourTree(
        py_trees.composites.Sequence("Mission", memory=True, children=[done, step])
    )
    tree.tick()
    assert tree.root.status == Status.RUNNING
    assert status.activity(tree) == "ExploreUntilDone > GoToViewpoint"


def _run(tmp_path: Path, *options: str) -> subprocess.CompletedProcess:
    """A 5-s flight of the small mission, stderr a pipe, a status line due at every tick."""
    mission = small_mission(tmp_path, max_time=5)
    env = {**os.environ, status.INTERVAL_VARIABLE: "0"}
    return subprocess.run(
        [AMSLAM, *options, "run", str(mission), "--out", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=False,
    )


def test_a_flight_with_stderr_a_pipe_writes_status_lines(tmp_path):
    done = _run(tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert lines and all(STATUS_LINE.match(line) for line in lines), lines[:5]
    seconds = {int(STATUS_LINE.match(line).group(1)) for line in lines}
    # a line at every tick: every whole second of simulated time is in some line, up to the end
    assert set(range(0, 6)) <= seconds, sorted(seconds)
    assert "flight ended (completed): writing the report, map and plots" in done.stderr
    assert "verdict: completed" in done.stdout


def test_quiet_writes_nothing_on_stderr(tmp_path):
    done = _run(tmp_path, "--quiet")
    assert done.returncode == 0
    assert done.stderr == ""
    assert "verdict: completed" in done.stdout  # stdout, the command's output, is unchanged
