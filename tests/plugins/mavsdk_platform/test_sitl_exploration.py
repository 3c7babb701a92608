"""Software in the loop: ``amslam fly sitl_small`` explores against ``amslam sitl`` (issue #17).

Both run as child processes, as a user runs them in two terminals. amslam sees only MAVLink (a
drifting estimate) and the rendered frames; the SITL's own record of the truth (``sitl.json``,
``reachable.npz``, ``ground_truth.tum``) judges the flight: explored share of the world's
reachable cells in amslam's ``map.npz``, contacts, landed and disarmed.

The whole exploration takes about two minutes of wall-clock time (start-up, ≤ 90 s of flight,
landing): it is in ``make test`` because it is the only test of exploration on the real-vehicle
path (planner thread, wall clock, MAVLink). The stop tests end a minute earlier: a signal as soon
as the vehicle explores in offboard.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from amslam.apps.sitl.record import judge
from amslam.plugins.mavsdk_platform.emulator import free_udp_port

from .conftest import assert_complete_run_folder, events

AMSLAM = Path(sys.executable).with_name("amslam")
#: bound on any wait (a hang fails the test instead of the suite)
BOUND = 400.0


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Sitl:
    """``amslam sitl sitl_small --once`` in a child process, its stdout collected line by line."""

    def __init__(self, tmp_path: Path):
        self.overrides = [
            "--set",
            f"platform.url=udpin://127.0.0.1:{free_udp_port()}",
            "--set",
            f"platform.camera.port={_free_tcp_port()}",
        ]
        self.truth = tmp_path / "truth"
        self.proc = subprocess.Popen(
            [AMSLAM, "sitl", "sitl_small", "--once", "--out", str(self.truth), *self.overrides],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        threading.Thread(target=self._collect, daemon=True).start()
        self.wait_for("ready: waiting for amslam fly")

    def _collect(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)

    def wait_for(self, text: str) -> None:
        deadline = time.monotonic() + BOUND
        while not any(text in line for line in self.lines):
            assert self.proc.poll() is None or any(text in line for line in self.lines), "".join(self.lines)
            assert time.monotonic() < deadline, f"no {text!r} from the SITL: {''.join(self.lines)}"
            time.sleep(0.1)

    def finish(self) -> dict:
        """Wait for the SITL to exit (``--once``: after the landing) and return its summary."""
        try:
            code = self.proc.wait(timeout=BOUND)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
        assert code == 0, "".join(self.lines)
        return json.loads((self.truth / "sitl.json").read_text())


def fly(sitl: Sitl, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [AMSLAM, "fly", "sitl_small", "--out", str(out), "--quiet", *sitl.overrides],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def assert_down_safely(summary: dict) -> None:
    assert summary["contacts"] == [], summary["contacts"]
    assert summary["vehicle"]["landed"] and not summary["vehicle"]["armed"], summary["vehicle"]
    assert summary["closest_approach_m"] is not None and summary["closest_approach_m"] > 0.25


def test_exploration_over_mavlink_completes_explores_and_lands(tmp_path):
    sitl = Sitl(tmp_path)
    proc = fly(sitl, tmp_path / "runs")
    stdout, stderr = proc.communicate(timeout=BOUND)
    summary = sitl.finish()

    assert proc.returncode == 0, stdout + stderr
    assert "pre-flight check passed" in stdout and "verdict: completed" in stdout
    (run,) = (tmp_path / "runs").iterdir()
    assert_complete_run_folder(run, "completed")
    found = judge(sitl.truth, run)
    assert found["explored_percent"] >= 80.0, found
    # the figures a simulated run's report gives, judged against the SITL's truth: slam.tum reads
    # (in time order, although key poses made for detections carry older frame stamps)
    assert set(found["final_error"]) == {"vio_position_m", "slam_position_m"}, found
    assert found["landmarks"]["matched"] >= 1, found
    # the real-time figures of a real vehicle's run: the frames' way and the late ticks, logged
    metrics = json.loads((run / "metrics.json").read_text())
    pipeline = metrics["pipeline"]
    assert pipeline["frames"] > 50 and 0 < pipeline["mapped"] <= pipeline["frames"], pipeline
    assert {"frame_to_local_map", "frame_to_global_map"} <= set(pipeline["latency_ms"]), pipeline
    late = (run / "late_ticks.jsonl").read_text().splitlines() if (run / "late_ticks.jsonl").exists() else []
    assert len(late) == metrics["control_tick_overruns"]  # each late tick is a line
    assert_down_safely(summary)
    names = [e["event"] for e in events(run)]
    assert "failsafe" not in names and "disarm_failed" not in names and names.count("touchdown") == 1
    assert summary["camera"]["frames_sent"] > 50  # the map was built from the SITL's frames
    (stream,) = [e for e in events(run) if e["event"] == "camera_stream"]
    assert 50 < stream["received"] <= summary["camera"]["frames_sent"], stream
    # amslam flew its exploration tree over MAVLink: offboard, then PX4's landing
    log = " ".join(summary["vehicle_log"])
    assert "mode OFFBOARD" in log and "mode LAND" in log and "disarmed after landing" in log
    # the truth carries the drift amslam never saw: the estimate ended off the true position
    truth = np.loadtxt(sitl.truth / "ground_truth.tum")
    estimate = np.loadtxt(sitl.truth / "estimate.tum")
    assert len(truth) == len(estimate) > 100
    assert summary["estimate_error_m"] > 0.0


@pytest.mark.parametrize("stop", ["SIGTERM", "double SIGINT"])
def test_a_stop_signal_mid_exploration_lands_disarms_and_completes_the_run_folder(tmp_path, stop):
    sitl = Sitl(tmp_path)
    proc = fly(sitl, tmp_path / "runs")
    sitl.wait_for("mode OFFBOARD")
    time.sleep(3.0)  # exploring, moving
    assert proc.poll() is None, proc.communicate()
    if stop == "SIGTERM":
        proc.send_signal(signal.SIGTERM)
        expected = 128 + signal.SIGTERM
    else:
        proc.send_signal(signal.SIGINT)
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)  # while landing and saving: must not skip either
        expected = 128 + signal.SIGINT
    stdout, stderr = proc.communicate(timeout=BOUND)
    summary = sitl.finish()

    assert proc.returncode == expected, stdout + stderr
    assert "Traceback" not in stderr
    (run,) = (tmp_path / "runs").iterdir()
    assert_complete_run_folder(run, "aborted")
    names = [e["event"] for e in events(run)]
    assert "aborted" in names and "touchdown" in names and "camera_stream" in names
    assert_down_safely(summary)
    log = " ".join(summary["vehicle_log"])
    assert "mode LAND" in log and "failsafe" not in log  # amslam landed it, not the offboard-loss failsafe


@pytest.mark.parametrize(
    ("mission", "overrides", "error"),
    [
        ("px4_square", [], "px4_square.yaml: platform.world: the SITL vehicle needs a world to fly in"),
        ("demo", [], "demo.yaml: platform.plugin is 'sim': amslam sitl flies a mavsdk mission"),
        ("sitl_small", ["platform.world.size=[1, 1]"], "platform.world: Value error, building 1x1 m"),
        ("sitl_small", ["platform.url=serial:///dev/ttyUSB0"], "platform.url 'serial:///dev/ttyUSB0'"),
    ],
)
def test_a_mission_the_sitl_cannot_fly_is_one_error_line(mission, overrides, error, tmp_path):
    args = [arg for o in overrides for arg in ("--set", o)]
    done = subprocess.run(
        [AMSLAM, "sitl", mission, *args], capture_output=True, text=True, timeout=BOUND, cwd=tmp_path
    )
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: ") and error in line, line
    assert not (tmp_path / "sitl").exists()  # no empty truth folder left behind


def test_a_camera_port_in_use_is_one_error_line(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        url = f"platform.url=udpin://127.0.0.1:{free_udp_port()}"
        camera = f"platform.camera.port={port}"
        done = subprocess.run(
            [AMSLAM, "sitl", "sitl_small", "--out", str(tmp_path), "--set", url, "--set", camera],
            capture_output=True,
            text=True,
            timeout=BOUND,
        )
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert line.startswith(f"error: cannot serve camera frames on 127.0.0.1:{port} ("), line
