"""The SLAM thread of a real vehicle: the factor graph off the control thread.

In the SITL flight of the demo building a third of the late control ticks waited for SLAM: the
control thread computed the graph's marginals for the uncertainty samples (a quarter of a second
at 2000 key poses), and its odometry waited for the graph's lock while the planner thread ranked
loop-closure candidates (issue #17). These tests hold what replaces it: the control thread hands
SLAM its calls and goes on; SLAM gets them in the order they happened; the control thread flies
on the correction SLAM published last; a loop-closure attempt sees everything handed over before
it; key poses reach the observers on the control thread; and a failing SLAM call ends the run on
the control thread, naming the backend.
"""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from amslam.mission import ExplorationSection
from amslam.perception import Perception
from amslam.types import Detection, KeyPose, Odometry
from tests.core.test_mapper_thread import WAIT, SlowGlobalMap, WallClockPlatform, raised_on_a_later_step
from tests.core.test_mapper_thread import perception as real_vehicle_perception


class RecordingSlam:
    """Records its calls in order; ``uncertainty`` blocks until released; the correction is a
    shift along x by the number of key poses made (a key pose at every 2nd odometry reading)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, float]] = []
        self.in_uncertainty = threading.Event()
        self.release = threading.Event()
        self.threads: set[str] = set()
        self.fail: Exception | None = None
        self.shift = 0.0

    def add_odometry(self, odom: Odometry) -> bool:
        if self.fail is not None:
            raise self.fail
        self.threads.add(threading.current_thread().name)
        self.calls.append(("odometry", round(odom.stamp, 3)))
        keyposed = len([c for c in self.calls if c[0] == "odometry"]) % 2 == 0
        if keyposed:
            self.shift += 1.0
        return keyposed

    def in_order(self) -> list[tuple[str, float]]:
        """The calls but detections (the detector thread decides when the first one comes)."""
        return [c for c in self.calls if c[0] != "detections"]

    def keyposes(self) -> list[KeyPose]:
        return [KeyPose(int(self.shift), 0.0, np.eye(4), 0.0)] if self.shift else []

    def T_world_odom(self) -> np.ndarray:
        T = np.eye(4)
        T[0, 3] = self.shift
        return T

    def add_detections(self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]) -> None:
        self.calls.append(("detections", round(odom.stamp, 3)))

    def uncertainty(self) -> tuple[float, float]:
        self.calls.append(("uncertainty", 0.0))
        self.in_uncertainty.set()
        assert self.release.wait(WAIT), "the test never released the uncertainty sample"
        return (1.0, 2.0)

    def try_loop_closure(self, odom, T_body_cam, detections) -> str:
        self.calls.append(("loop closure", round(odom.stamp, 3)))
        return "closed"


def perception(slam: RecordingSlam, hook=lambda *a, **k: None) -> Perception:
    mapping = SlowGlobalMap()
    mapping.release.set()
    return real_vehicle_perception(
        mapping,
        slam=slam,
        platform=WallClockPlatform(),
        exploration=ExplorationSection(uncertainty_period=100.0),  # one sample: at the first step
        hook=hook,
    )


def _until(condition) -> bool:
    for _ in range(200):
        if condition():
            return True
        threading.Event().wait(0.02)
    return False


def test_the_control_thread_goes_on_while_slam_samples_its_uncertainty_and_slam_gets_every_call_in_order():
    slam = RecordingSlam()
    p = perception(slam)
    try:
        p.step(0.1)  # odometry 0.1, then the uncertainty sample, which blocks the SLAM thread
        assert slam.in_uncertainty.wait(WAIT)
        for _ in range(4):  # the control thread goes on: odometry 0.2 .. 0.5 wait in the queue
            snapshot = p.step(0.1)
        assert snapshot.t == pytest.approx(0.5)
        assert slam.in_order() == [("odometry", 0.1), ("uncertainty", 0.0)]
        assert snapshot.T_world_odom[0, 3] == 0.0  # the correction published before the sample
        slam.release.set()
        assert _until(lambda: len(slam.in_order()) == 6)
        assert slam.in_order()[2:] == [
            ("odometry", 0.2),
            ("odometry", 0.3),
            ("odometry", 0.4),
            ("odometry", 0.5),
        ]
        assert slam.threads == {"amslam-slam"}
        assert p.samples["uncertainty"] == [(pytest.approx(0.1), 0.0, 1.0, 2.0)]
        assert _until(lambda: p.T_world_odom()[0, 3] == 2.0)  # two key poses made
        assert p.step(0.1).T_world_odom[0, 3] == 2.0  # what the control thread flies on
    finally:
        slam.release.set()
        p.close()


def test_a_loop_closure_attempt_waits_for_what_slam_was_handed_before_it_while_the_control_thread_ticks():
    slam = RecordingSlam()
    p = perception(slam)
    try:
        p.step(0.1)
        assert slam.in_uncertainty.wait(WAIT)
        p.step(0.1)
        now = Odometry(0.2, np.eye(4))
        attempt = p.slam_job(lambda: slam.try_loop_closure(now, None, []))
        for _ in range(3):  # the control thread ticks on while the attempt waits its turn
            p.step(0.1)
        assert not attempt.done()
        slam.release.set()
        assert attempt.result(timeout=WAIT) == "closed"
        names = [c[0] for c in slam.in_order()]
        assert names[:4] == ["odometry", "uncertainty", "odometry", "loop closure"]  # 0.2 had waited
    finally:
        slam.release.set()
        p.close()


def test_attempt_slc_holds_the_vehicle_until_slam_answers():
    from concurrent.futures import Future

    import py_trees
    from py_trees.common import Status

    from amslam.planning import LoopClosureJob
    from amslam.trees.behaviours import AttemptLoopClosure
    from amslam.types import LoopClosureResult

    future: Future = Future()
    log: list = []
    service = SimpleNamespace(slc_log=log)
    job = LoopClosureJob(future, service, 1.0, 2.0)
    held, emitted = [], []
    behaviour = AttemptLoopClosure()
    behaviour.planning = SimpleNamespace(request_loop_closure=lambda goal: job)
    behaviour.flight = SimpleNamespace(hold=lambda: held.append(1), distance=lambda: 2.0, time=lambda: 1.0)
    behaviour.events = SimpleNamespace(
        emit=lambda name, **f: emitted.append(name), plugin_hook=lambda *a, **k: None
    )
    py_trees.blackboard.Blackboard.set("/goal", None)
    assert behaviour.update() == Status.RUNNING and behaviour.update() == Status.RUNNING
    assert len(held) == 2 and emitted == [] and log == []
    future.set_result(LoopClosureResult(accepted=True, reason="matched 4", matched=4))
    assert behaviour.update() == Status.SUCCESS
    assert emitted == ["loop_closure"] and [r.matched for _, _, r in log] == [4]
    assert behaviour.bb.get("/slc")["accepted"] is True


def test_key_poses_reach_the_observers_on_the_control_thread():
    slam = RecordingSlam()
    slam.release.set()
    seen = []
    p = perception(
        slam, hook=lambda name, **k: seen.append((name, k["keypose"].id, threading.current_thread().name))
    )
    try:
        for _ in range(4):
            p.step(0.1)
        assert _until(lambda: len([c for c in slam.calls if c[0] == "odometry"]) == 4)
        p.step(0.1)
        me = threading.current_thread().name
        assert seen == [("amslam_keyframe", 1, me), ("amslam_keyframe", 2, me)]
    finally:
        p.close()


def test_a_failing_slam_call_ends_the_run_on_the_control_thread_naming_the_backend():
    slam = RecordingSlam()
    slam.release.set()
    slam.fail = ValueError("indeterminant linear system")
    raised_on_a_later_step(perception(slam), r"add_odometry\(\) raised ValueError: indeterminant")
