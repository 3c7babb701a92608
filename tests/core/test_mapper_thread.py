"""The mapper thread of a real vehicle: the global map's update off the control thread.

On a real vehicle the clock does not wait for the map. With the global map's update (integration,
viewpoints) on the control thread, 10 % of a SITL flight's ticks came late (issue #17). These
tests hold what replaces it: the control thread integrates the local map and returns while a
global update is still running; frames that wait for the mapper are replaced by newer ones and
counted; the mapper's viewpoints reach the snapshot; its failure ends the run on the control
thread, naming the backend; and the local map's calls do not wait for the global map's lock.
"""

from __future__ import annotations

import sys
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from amslam.boundary import BackendError, Boundary
from amslam.lib.voxel_map import VoxelMapParams
from amslam.mission import ExplorationSection
from amslam.perception import Perception
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.sharing import Shared
from amslam.testing.mapping import CAMERA, camera_pose, make_context, wall_depth
from amslam.types import Frame, Odometry, Viewpoint, VoxelState
from tests.core.pausing import PauseAtCall

WAIT = 10.0  # s; a generous bound for what must happen at once, never a measured time


class WallClockPlatform:
    """A real vehicle's platform, as Perception sees it: a frame at every tick."""

    simulated = False

    def __init__(self) -> None:
        self.camera = SimpleNamespace(T_body_cam=np.eye(4))
        self.t = 0.0

    def advance(self, dt: float) -> None:
        self.t += dt

    def time(self) -> float:
        return self.t

    def odometry(self) -> Odometry:
        return Odometry(self.t, np.eye(4))

    def ground_truth(self) -> None:
        return None

    def capture(self) -> Frame:
        return Frame(self.t, np.full((4, 4), 2.0, np.float32), np.eye(3), np.eye(4))


class SlowGlobalMap:
    """Records what reaches each map; the global update blocks until released."""

    def __init__(self) -> None:
        self.local_stamps: list[float] = []
        self.global_stamps: list[float] = []
        self.in_global = threading.Event()
        self.release = threading.Event()
        self.fail: Exception | None = None

    def integrate_local(self, depth, K, T_odom_cam) -> None:
        self.local_stamps.append(float(T_odom_cam[0, 3]))

    def integrate_global(self, depth, K, T_world_cam) -> None:
        self.in_global.set()
        assert self.release.wait(WAIT), "the test never released the global update"
        if self.fail is not None:
            raise self.fail
        self.global_stamps.append(float(T_world_cam[0, 3]))

    def viewpoints(self) -> list[Viewpoint]:
        return [Viewpoint(1, np.array([1.0, 2.0, 1.0]), 0.0, 5.0, np.array([1.0, 2.5, 1.0]), 10)]

    def states(self, points, *, local: bool = False) -> np.ndarray:
        return np.full(len(points), VoxelState.FREE, np.int8)

    def voxel_size(self) -> float:
        return 0.25

    def explored_volume(self) -> float:
        return 42.0


class FrameAtItsStamp(WallClockPlatform):
    """Each frame's pose carries its stamp in x, so a map shows which frames reached it."""

    def capture(self) -> Frame:
        T = np.eye(4)
        T[0, 3] = self.t
        return Frame(self.t, np.full((4, 4), 2.0, np.float32), np.eye(3), T)


def perception(
    mapping, rundir=None, *, slam=None, platform=None, exploration=None, hook=lambda *a, **k: None
) -> Perception:
    """Perception of a real vehicle (a frame at every tick) over ``mapping``; the rest stubs."""
    slam = slam or SimpleNamespace(
        add_odometry=lambda odom: False,
        keyposes=list,
        T_world_odom=lambda: np.eye(4),
        add_detections=lambda *a: None,
        uncertainty=lambda: (0.0, 0.0),
    )
    detector = SimpleNamespace(detect=lambda frame: [], rate_hz=0.001)
    rundir = rundir or SimpleNamespace(pose=lambda *a: None, event=lambda *a, **k: None)
    measurements = SimpleNamespace(keypose=lambda *a: None, detections=lambda *a: None)
    return Perception(
        platform or FrameAtItsStamp(),
        slam,
        mapping,
        detector,
        exploration or ExplorationSection(),
        rundir,
        measurements,
        hook=hook,
        boundary=Boundary(),
    )


def test_the_control_thread_goes_on_while_the_global_map_updates_and_only_the_newest_frame_waits():
    mapping = SlowGlobalMap()
    p = perception(mapping)
    try:
        p.step(0.1)  # frame 0.1 goes to the mapper, which blocks inside integrate_global
        assert mapping.in_global.wait(WAIT)
        for _ in range(4):  # frames 0.2 .. 0.5: each in the local map at once
            p.step(0.1)
        assert mapping.local_stamps == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5])
        assert mapping.global_stamps == []  # still in the first global update
        mapping.release.set()
        for _ in range(100):  # the mapper finishes 0.1, then takes the newest waiting: 0.5
            if len(mapping.global_stamps) == 2:
                break
            threading.Event().wait(0.05)
        assert mapping.global_stamps == pytest.approx([0.1, 0.5])
        assert p.health.frames == 5 and p.health.mapped == 2 and p.health.skipped_by_mapper == 3
        assert p.health.global_latency[0] >= 0.4 - 1e-9  # frame 0.1 was in the map at t 0.5
        snapshot = p.step(0.1)
        assert [tuple(vp.position) for vp in snapshot.viewpoints] == [(1.0, 2.0, 1.0)]
    finally:
        mapping.release.set()
        p.close()


def test_a_failing_global_update_ends_the_run_on_the_control_thread_naming_the_backend():
    mapping = SlowGlobalMap()
    mapping.fail = ValueError("the hash map is full")
    mapping.release.set()
    raised_on_a_later_step(perception(mapping), r"integrate_global\(\) raised ValueError: the hash map")


def raised_on_a_later_step(p: Perception, match: str) -> None:
    """Step until a thread's failure is raised on this one, the control thread; then close."""
    try:
        with pytest.raises(BackendError, match=match):
            for _ in range(100):
                p.step(0.1)
                threading.Event().wait(0.05)
    finally:
        p.close()


def _mapper_paused_in_viewpoints(shared: Shared) -> tuple[threading.Thread, PauseAtCall]:
    pause = PauseAtCall("update", timeout=WAIT)  # the global map's frontier update

    def mapper() -> None:
        sys.settrace(pause)
        try:
            shared.viewpoints()
        finally:
            sys.settrace(None)

    thread = threading.Thread(target=mapper)
    thread.start()
    assert pause.paused.wait(WAIT), "the mapper thread never updated its frontiers"
    return thread, pause


def _finishes(fn) -> bool:
    done = threading.Thread(target=fn)
    done.start()
    done.join(timeout=1.0)
    return not done.is_alive()


@pytest.mark.parametrize("separate", [True, False])
def test_the_local_maps_calls_wait_for_the_global_maps_lock_only_when_the_backend_shares_state(
    tmp_path, separate
):
    mapping = NumpyVoxelMap()
    mapping.configure(VoxelMapParams(), make_context(tmp_path))
    if not separate:
        mapping.separate_local_map = False  # a backend that does not promise it
    mapping.integrate_global(wall_depth(), CAMERA.K, camera_pose())
    shared = Shared(mapping)
    thread, pause = _mapper_paused_in_viewpoints(shared)  # holds the global map's lock
    try:
        here = np.array([[1.0, 0.0, 0.0]])
        local_calls = [
            lambda: shared.integrate_local(wall_depth(), CAMERA.K, camera_pose()),
            lambda: shared.states(here, local=True),
            lambda: shared.segment_free(here[0], here[0] + 0.5, local=True),
            lambda: shared.blocked(here, local=True),
        ]
        assert [_finishes(call) for call in local_calls] == [separate] * 4
        assert not _finishes(lambda: shared.states(here))  # the global map's: always waits
    finally:
        pause.resume.set()
        thread.join()


def test_an_event_of_the_mapper_thread_is_written_by_the_control_thread():
    written = []
    rundir = SimpleNamespace(
        pose=lambda *a: None,
        event=lambda t, name, **f: written.append((t, name, f, threading.current_thread().name)),
    )
    mapping = SlowGlobalMap()
    mapping.release.set()
    p = perception(mapping, rundir)
    try:
        mapper = threading.Thread(target=p._event, args=(1.5, "map_reanchored"), kwargs={"frames": 3})
        mapper.start()
        mapper.join()
        assert written == []  # the run folder is the control thread's
        p.step(0.1)
        assert written == [(1.5, "map_reanchored", {"frames": 3}, threading.current_thread().name)]
    finally:
        p.close()
