"""A SLAM backend in a process of its own: the same answers, its errors and events in the parent,
other threads running while it computes, and the runner using it on a real vehicle only."""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path

import numpy as np
import pytest

from amslam.backend_process import BackendProcessError, SlamProcess, implementation
from amslam.interfaces import BackendParams, RunContext, Slam
from amslam.plugins.gtsam_slam.backend import GtsamSlam
from amslam.testing.slam import T_BODY_CAM, flight, visible_detections
from amslam.types import KeyPose, Landmark, Odometry
from tests.core.pausing import beats_during


class HeldLockSlam(Slam):
    """A SLAM backend whose uncertainty() holds the interpreter lock for a while, as gtsam's
    marginals do (a C loop: ``sum`` over a range never lets go), and that emits an event."""

    def configure(self, params: BackendParams, context: RunContext) -> None:
        self.emit = context.emit
        self.odometry: list[Odometry] = []

    def add_odometry(self, odom: Odometry) -> bool:
        if not np.all(np.isfinite(odom.T_odom_body)):
            raise ValueError(f"odometry at {odom.stamp} is not finite")
        self.odometry.append(odom)
        self.emit("odometry_seen", n=len(self.odometry))
        return True

    def add_detections(self, odom, T_body_cam, detections) -> None:
        pass

    def T_world_odom(self) -> np.ndarray:
        T = np.eye(4)
        T[0, 3] = len(self.odometry)  # changes with every call that feeds it
        return T

    def keyposes(self) -> list[KeyPose]:
        return [KeyPose(i, o.stamp, o.T_odom_body, float(i)) for i, o in enumerate(self.odometry)]

    def landmarks(self) -> list[Landmark]:
        return []

    def uncertainty(self) -> tuple[float, float]:
        return (float(sum(range(30_000_000)) % 7), 0.0)


def _context(tmp_path: Path, events: list | None = None) -> RunContext:
    emit = (lambda name, **f: events.append((name, f))) if events is not None else (lambda *a, **k: None)
    return RunContext(rng=np.random.default_rng(0), run_dir=tmp_path, emit=emit)


def _fly(slam: Slam) -> tuple[list, list, np.ndarray, tuple[float, float]]:
    for k, odom in enumerate(flight()):
        slam.add_odometry(odom)
        if k % 5 == 0:
            slam.add_detections(odom, T_BODY_CAM, visible_detections(odom))
    return slam.keyposes(), slam.landmarks(), slam.T_world_odom(), slam.uncertainty()


def test_the_graph_in_a_process_gives_the_same_answers(tmp_path):
    here = GtsamSlam()
    here.configure(GtsamSlam.Params(), _context(tmp_path))
    there = SlamProcess(GtsamSlam)
    there.configure(GtsamSlam.Params(), _context(tmp_path))
    try:
        expected, got = _fly(here), _fly(there)
    finally:
        there.close()
    (kp_a, lm_a, T_a, u_a), (kp_b, lm_b, T_b, u_b) = expected, got
    assert len(kp_a) == len(kp_b) > 10
    for a, b in zip(kp_a, kp_b, strict=True):
        assert (a.id, a.stamp, a.distance) == (b.id, b.stamp, b.distance)
        np.testing.assert_array_equal(a.T_world_body, b.T_world_body)
    assert [(lm.id, lm.class_name, lm.observations) for lm in lm_a] == [
        (lm.id, lm.class_name, lm.observations) for lm in lm_b
    ]
    for a, b in zip(lm_a, lm_b, strict=True):
        np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(T_a, T_b)
    assert u_a == u_b
    assert implementation(there) is GtsamSlam


def test_other_threads_run_while_the_process_computes(tmp_path):
    """The reason it exists: a call that holds the interpreter lock in the backend's process
    leaves this one's threads running. The same call in this process stops them."""

    here = HeldLockSlam()
    here.configure(BackendParams(), _context(tmp_path))
    there = SlamProcess(HeldLockSlam)
    there.configure(BackendParams(), _context(tmp_path))
    try:
        # the lock is held throughout (about 500 beats when it is not): the test can fail; a beat or
        # two slips in as the call starts and ends, a few more when the machine is loaded
        assert beats_during(here.uncertainty)[0] <= 5
        assert beats_during(there.uncertainty)[0] >= 20
    finally:
        there.close()


def test_errors_and_events_of_the_backend_reach_the_caller(tmp_path):
    events: list = []
    slam = SlamProcess(HeldLockSlam)
    slam.configure(BackendParams(), _context(tmp_path, events))
    try:
        assert slam.add_odometry(Odometry(1.0, np.eye(4)))
        assert events == [("odometry_seen", {"n": 1})]
        assert slam.T_world_odom()[0, 3] == 1.0  # the correction came back with the call
        bad = np.full((4, 4), np.nan)
        with pytest.raises(ValueError, match="odometry at 2.0 is not finite") as raised:
            slam.add_odometry(Odometry(2.0, bad))
        assert "in the slam process" in raised.value.__notes__[0]
        assert "HeldLockSlam" not in str(raised.value) and "add_odometry" in raised.value.__notes__[0]
        assert slam.add_odometry(Odometry(3.0, np.eye(4)))  # it goes on after an error
        assert [k.stamp for k in slam.keyposes()] == [1.0, 3.0]
    finally:
        slam.close()
        slam.close()  # twice is safe


def test_a_process_that_dies_is_named(tmp_path):
    slam = SlamProcess(HeldLockSlam)
    slam.configure(BackendParams(), _context(tmp_path))
    os.kill(slam._process._process.pid, signal.SIGKILL)
    with pytest.raises(BackendProcessError, match=r"slam process \(HeldLockSlam\) ended during keyposes\(\)"):
        slam.keyposes()
    slam.close()


def test_a_backend_that_cannot_be_sent_is_refused_at_configure(tmp_path):
    context = _context(tmp_path)
    context = RunContext(**{**context.__dict__, "extras": {"callback": threading.Lock()}})
    slam = SlamProcess(HeldLockSlam)
    with pytest.raises(ValueError, match="HeldLockSlam cannot run in a process of its own"):
        slam.configure(BackendParams(), context)
    slam.close()


def test_the_terminal_s_ctrl_c_does_not_reach_it(tmp_path):
    """The parent lands the vehicle on Ctrl-C and then asks SLAM for its key poses."""
    slam = SlamProcess(HeldLockSlam)
    slam.configure(BackendParams(), _context(tmp_path))
    try:
        child = slam._process._process
        assert os.getpgid(child.pid) != os.getpgid(0)
        os.kill(child.pid, signal.SIGINT)
        os.kill(child.pid, signal.SIGTERM)
        assert slam.add_odometry(Odometry(1.0, np.eye(4)))
    finally:
        slam.close()


def test_a_backend_found_on_the_parent_s_path_is_found_there_too(tmp_path, monkeypatch):
    """A plugin imported from a folder the parent put on ``sys.path`` (not installed)."""
    (tmp_path / "my_local_slam.py").write_text(
        "from amslam.plugins.odometry_slam import OdometrySlam\n\nclass LocalSlam(OdometrySlam):\n    pass\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    from my_local_slam import LocalSlam

    slam = SlamProcess(LocalSlam)
    slam.configure(LocalSlam.Params(), _context(tmp_path))
    try:
        slam.add_odometry(Odometry(1.0, np.eye(4)))
        assert len(slam.keyposes()) == 1
    finally:
        slam.close()
