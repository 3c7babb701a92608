"""Fixtures: a MAVLink vehicle emulator on a free port, and a runner flying a mission against it."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from amslam.mission import load_mission
from amslam.plugins.mavsdk_platform.emulator import MavlinkVehiclePeer, free_udp_port
from amslam.registry import build_plugin_manager
from amslam.runner import Runner, RunResult

#: Fast enough to keep each flight to a few seconds of wall-clock time.
FAST = {"max_speed": 4.0, "max_vertical_speed": 3.0, "position_gain": 4.0, "land_speed": 2.0}

#: Tight bounds so that failsafes end in seconds.
QUICK = ["platform.land_timeout=2.5", "platform.link_timeout=0.8", "waypoints.land_timeout=2"]


@pytest.fixture
def make_peer() -> Iterator[Callable[..., tuple[MavlinkVehiclePeer, str]]]:
    """``make_peer(**kwargs) -> (peer, url)``: an emulator sending to a free port MAVSDK listens on."""
    peers: list[MavlinkVehiclePeer] = []

    def make(**kwargs) -> tuple[MavlinkVehiclePeer, str]:
        port = free_udp_port()
        peer = MavlinkVehiclePeer(connect_to=("127.0.0.1", port), **{**FAST, **kwargs}).start()
        peers.append(peer)
        return peer, f"udpin://127.0.0.1:{port}"

    yield make
    for peer in peers:
        peer.stop()


@pytest.fixture
def fly(tmp_path: Path) -> Callable[..., RunResult]:
    """``fly(url, *overrides) -> RunResult``: the packaged px4_square mission, through the real runner."""

    def run(url: str, *overrides: str) -> RunResult:
        registry = build_plugin_manager()
        mission = load_mission("px4_square", registry, [f"platform.url={url}", *QUICK, *overrides])
        return Runner(mission, registry, tmp_path / "runs").run()

    return run


def when(condition: Callable[[], bool], then: Callable[[], None], timeout: float = 180.0) -> threading.Thread:
    """Run ``then`` on a helper thread as soon as ``condition`` holds (e.g. cut the link mid-flight).

    The watch starts before the flight does, and on a loaded machine building the plugins and
    connecting can take most of a minute, so the timeout is generous: it only bounds a test gone
    wrong.
    """

    def watch() -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                then()
                return
            time.sleep(0.02)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


def events(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]


def assert_complete_run_folder(run_dir: Path, verdict: str) -> None:
    """Every summary written, the verdict recorded, the stream closed with run_end."""
    for name in ("mission.yaml", "events.jsonl", "metrics.json", "report.md", "vio.tum", "tree.jsonl"):
        assert (run_dir / name).exists(), f"{name} missing from {sorted(p.name for p in run_dir.iterdir())}"
    assert json.loads((run_dir / "metrics.json").read_text())["verdict"] == verdict
    ends = [e for e in events(run_dir) if e["event"] == "run_end"]
    assert ends and ends[-1]["verdict"] == verdict
