"""Missions flown through the real ``mavsdk`` plugin and MAVSDK core against the MAVLink emulator.

The emulator's own trace (true positions, NED) is the judge of what the vehicle flew.
"""

from __future__ import annotations

import _thread
import signal

import numpy as np
import pytest

from amslam.cli import main
from amslam.plugins.mavsdk_platform.emulator import MavlinkVehiclePeer
from amslam.runner import RunResult

from .conftest import QUICK, assert_complete_run_folder, events, when

#: The px4_square corners (ENU from take-off: (2,0), (2,2), (0,2), (0,0) at 1.5 m) in NED.
CORNERS_NED = np.array([[0.0, 2.0, -1.5], [2.0, 2.0, -1.5], [2.0, 0.0, -1.5], [0.0, 0.0, -1.5]])


def _positions(peer: MavlinkVehiclePeer) -> np.ndarray:
    return np.array([p.position for p in peer.trace])


def _visit_order(peer: MavlinkVehiclePeer, corners: np.ndarray, radius: float = 0.2) -> list[int]:
    """Trace index at which each corner is first reached after the previous one (-1: never)."""
    pos = _positions(peer)
    order, start = [], 0
    for corner in corners:
        near = np.flatnonzero(np.linalg.norm(pos[start:] - corner, axis=1) < radius)
        if len(near) == 0:
            return [*order, -1]
        start += int(near[0])
        order.append(start)
    return order


def _near_corner(peer: MavlinkVehiclePeer, i: int, radius: float = 0.2) -> bool:
    trace = peer.trace
    return bool(trace) and float(np.linalg.norm(trace[-1].position - CORNERS_NED[i])) < radius


def test_square_flown_landed_and_disarmed(make_peer, tmp_path, capsys):
    """``amslam fly px4_square``: pre-flight check, then the square, through the command line."""
    peer, url = make_peer()
    overrides = [arg for o in (f"platform.url={url}", *QUICK) for arg in ("--set", o)]
    code = main(["fly", "px4_square", "--out", str(tmp_path), "--quiet", *overrides])

    out = capsys.readouterr().out
    assert code == 0, out
    assert "pre-flight check passed" in out and "verdict: completed" in out
    (run_dir,) = tmp_path.iterdir()
    result = RunResult(run_dir, "completed", {})
    order = _visit_order(peer, CORNERS_NED)
    assert -1 not in order and order == sorted(order), f"corners reached at trace steps {order}"
    # between the first and the last corner the vehicle stayed on the square's edges
    legs = _positions(peer)[order[0] : order[-1]]
    assert np.all(legs[:, :2] > -0.25) and np.all(legs[:, :2] < 2.25)
    assert np.all(np.abs(legs[:, 2] + 1.5) < 0.2), "left the 1.5 m flight level"
    on_edge = np.minimum(
        np.minimum(np.abs(legs[:, 0]), np.abs(legs[:, 0] - 2)),
        np.minimum(np.abs(legs[:, 1]), np.abs(legs[:, 1] - 2)),
    )
    assert on_edge.max() < 0.25, "cut a corner of the square"
    modes = {p.mode for p in peer.trace[order[0] : order[-1]]}
    assert modes == {"OFFBOARD"}
    last = peer.trace[-1]
    assert not last.armed and last.landed and np.linalg.norm(last.position[:2]) < 0.3
    assert sum(1 for _, name, _ in peer.commands if name == "land") == 1
    names = [e["event"] for e in events(result.run_dir)]
    assert names.count("waypoint_reached") == 4
    assert "failsafe" not in names
    assert_complete_run_folder(result.run_dir, "completed")


def test_link_loss_mid_flight_ends_in_failsafe_landing(make_peer, fly):
    peer, url = make_peer()
    cut = when(lambda: _near_corner(peer, 1), peer.cut_link)
    result = fly(url)
    cut.join(timeout=1.0)

    assert result.verdict.startswith("failed: FailsafeLand:"), result.verdict
    assert "link lost" in result.verdict
    failsafes = [e for e in events(result.run_dir) if e["event"] == "failsafe"]
    assert failsafes and failsafes[0]["kind"] == "link_lost" and failsafes[0]["action"] == "land"
    # the vehicle's own failsafe brought it down where it was: on the far side of the square
    notes = [what for _, what in peer.log]
    assert "failsafe: offboard setpoints lost, landing" in notes
    last = peer.trace[-1]
    assert last.landed and not last.armed
    assert np.linalg.norm(last.position[:2]) > 1.5 and np.all(np.abs(last.position[:2] - 1.0) < 1.3)
    assert_complete_run_folder(result.run_dir, result.verdict)


def test_refused_offboard_lands_by_failsafe(make_peer, fly):
    peer, url = make_peer(refuse={"offboard"})
    result = fly(url)

    assert result.verdict.startswith("failed: FailsafeEnd: command_refused: offboard refused"), result.verdict
    assert result.verdict.endswith("landed")
    assert not any(p.mode == "OFFBOARD" for p in peer.trace)
    assert min(p.position[2] for p in peer.trace) < -1.2, "took off before the refusal"
    last = peer.trace[-1]
    assert last.landed and not last.armed
    assert_complete_run_folder(result.run_dir, result.verdict)


def test_refused_arming_never_leaves_the_ground(make_peer, fly):
    peer, url = make_peer(refuse={"arm"})
    result = fly(url)

    assert result.verdict.startswith("failed: FailsafeEnd: command_refused: arm refused"), result.verdict
    assert all(p.landed and not p.armed for p in peer.trace)
    assert [name for _, name, _ in peer.commands if name in ("takeoff", "land")] == []
    assert_complete_run_folder(result.run_dir, result.verdict)


def test_low_battery_returns_over_take_off_point_and_lands(make_peer, fly):
    peer, url = make_peer()
    when(lambda: _near_corner(peer, 1), lambda: peer.set_battery(0.25))
    result = fly(url)

    assert "low_battery" in result.verdict and result.verdict.endswith("landed"), result.verdict
    found = events(result.run_dir)
    failsafe = next(e for e in found if e["event"] == "failsafe")
    assert failsafe["kind"] == "low_battery" and failsafe["action"] == "return_and_land"
    reached = [e for e in found if e["event"] == "waypoint_reached"]
    assert len(reached) < 4, "kept flying the square on a low battery"
    last = peer.trace[-1]
    assert last.landed and not last.armed and np.linalg.norm(last.position[:2]) < 0.35
    assert_complete_run_folder(result.run_dir, result.verdict)


def test_setpoint_outside_geofence_is_not_sent(make_peer, fly):
    peer, url = make_peer()
    result = fly(url, "platform.geofence.hi=[1.5, 6.0, 4.0]")  # the first corner is 2 m east

    assert "geofence" in result.verdict and result.verdict.endswith("landed"), result.verdict
    assert max(p.position[1] for p in peer.trace) < 0.5  # never flew east
    assert peer.trace[-1].landed and not peer.trace[-1].armed
    assert_complete_run_folder(result.run_dir, result.verdict)


def test_operator_abort_holds_then_lands(make_peer, fly):
    peer, url = make_peer()

    def moving_east() -> bool:
        # Partway along the eastward leg. (Comparing two consecutive samples, > 2 cm apart, never
        # fired when the emulator sampled finely on a quiet machine: the flight then completed.)
        trace = peer.trace
        return len(trace) > 2 and trace[-1].mode == "OFFBOARD" and 0.4 < trace[-1].position[1] < 1.6

    # A shell that starts a job in the background makes it ignore SIGINT, and then Python installs
    # no KeyboardInterrupt handler and interrupt_main() does nothing: `nohup make test &` flew the
    # square to the end. Ctrl-C at a terminal always has Python's handler.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        when(moving_east, _thread.interrupt_main)  # what Ctrl-C does
        result = fly(url)
    finally:
        signal.signal(signal.SIGINT, previous)

    assert result.verdict == "aborted"
    names = [e["event"] for e in events(result.run_dir)]
    assert names.index("holding") < names.index("touchdown")
    modes = [m for i, m in enumerate(p.mode for p in peer.trace) if i == 0 or peer.trace[i - 1].mode != m]
    assert modes[-3:] == ["LOITER", "LAND", "LOITER"]  # hold, land, disarmed (PX4 shows hold when idle)
    assert peer.trace[-1].landed and not peer.trace[-1].armed
    assert_complete_run_folder(result.run_dir, "aborted")


def test_fly_refuses_a_low_battery_without_a_run_folder(make_peer, tmp_path, capsys):
    peer, url = make_peer(battery=0.35)
    code = main(["fly", "px4_square", "--out", str(tmp_path), "--set", f"platform.url={url}"])

    err = capsys.readouterr().err
    assert code == 2
    assert "refusing to fly: battery: 35 % (< 50 %)" in err
    assert not any(tmp_path.iterdir())
    assert not peer.commands or all(name not in ("arm", "takeoff") for _, name, _ in peer.commands)


def test_fly_refuses_a_start_outside_the_geofence_and_a_silent_link(make_peer, tmp_path, capsys):
    _, url = make_peer()
    fence = "platform.geofence.lo=[1.0, -4.0, -1.0]"  # the vehicle sits at the origin
    assert (
        main(["fly", "px4_square", "--out", str(tmp_path), "--set", f"platform.url={url}", "--set", fence])
        == 2
    )
    assert "refusing to fly: geofence: start [0.0, 0.0, 0.0]" in capsys.readouterr().err

    silent = "udpin://127.0.0.1:1"  # nobody sends there
    code = main(
        ["fly", "px4_square", "--set", f"platform.url={silent}", "--set", "platform.connect_timeout=0.5"]
    )
    assert code == 2
    assert "no autopilot heard on udpin://127.0.0.1:1 within 0.5 s" in capsys.readouterr().err


def test_fly_refuses_a_simulated_platform(capsys):
    assert main(["fly", "demo"]) == 2
    assert "platform 'sim' is simulated" in capsys.readouterr().err


def test_a_real_vehicle_flies_with_a_short_switch_interval_and_gives_it_back(make_peer, fly):
    """The control thread gets the interpreter back soon after each numpy call beside the busy
    mapper, SLAM and planner threads (amslam.runner.REAL_TIME_SWITCH_INTERVAL); the process's own
    interval is restored when the run ends."""
    import sys

    from amslam.runner import REAL_TIME_SWITCH_INTERVAL

    before = sys.getswitchinterval()
    peer, url = make_peer(refuse={"arm"})  # a short run: it never leaves the ground
    seen: list[float] = []
    asked_to_arm = lambda: any(name == "arm" for _, name, _ in peer.commands)  # noqa: E731 — by the tree
    watch = when(asked_to_arm, lambda: seen.append(sys.getswitchinterval()))
    result = fly(url)
    watch.join(timeout=1.0)
    assert result.verdict.startswith("failed"), result.verdict
    assert seen == [pytest.approx(REAL_TIME_SWITCH_INTERVAL)] and before > 2 * REAL_TIME_SWITCH_INTERVAL
    assert sys.getswitchinterval() == before
