"""The perception step: every module that turns sensor data into estimates, in one order, at its rate.

Each control tick :meth:`Perception.step` runs, on the control thread:

1. ``platform.advance(dt)``; VIO odometry → distance travelled → ``slam.add_odometry`` (the
   backend decides key poses; each is logged for the base and announced to observers);
2. a camera frame when one is due → ``mapping.integrate_local`` (VIO pose) and
   ``mapping.integrate_global`` (SLAM pose) → ``mapping.viewpoints()`` every
   ``viewpoint_period`` s or at once when asked (:meth:`refresh_viewpoints`);
3. the detector at its own rate → ``slam.add_detections`` at the pose of the frame it saw;
4. trajectories, uncertainty and explored-volume samples at their rates;

and publishes what it knows as an immutable :class:`Snapshot`. With a simulated platform
everything runs inline (the clock waits, runs stay repeatable). On a real vehicle the clock does
not wait, so two steps leave the control thread:

* the detector runs on the detector thread; frames arriving while it is busy are skipped, and
  its detections are handed to SLAM once they are ready;
* the global map's update (``integrate_global``, a rebuild, ``viewpoints()`` and the explored
  volume) runs on the mapper thread, newest frame first: a frame waiting for it is replaced by a
  newer one (and counted). The local map, which the setpoint guard reads, is still updated on the
  control thread at once. The control thread then ticks on time while the global map takes a
  tenth of a second or more per frame (issue #17: 10 % of ticks overran with both on it);
* every SLAM call runs on the SLAM thread, in the order the control thread made them (odometry,
  detections, uncertainty samples, loop-closure attempts). The control thread reads the
  correction ``T_world_odom`` the SLAM thread published after its latest call, and never waits for
  the graph: the marginals of a demo flight's 2000 key poses take a quarter of a second, and the
  planner thread holds the graph's lock for as long while it ranks loop-closure candidates
  (issue #17: a third of the demo flight's late ticks).

:class:`PipelineHealth` counts the frames and times each one's way from its stamp to the maps and
to SLAM on the platform's clock (a real vehicle's run has them in ``metrics.json``).
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from amslam.boundary import Boundary
from amslam.geometry import invert, yaw_of
from amslam.interfaces import Detector, Mapping, Platform, Slam
from amslam.measurements import MeasurementLog
from amslam.mission import ExplorationSection
from amslam.rundir import RunDir
from amslam.sharing import finished
from amslam.types import Detection, Frame, Odometry, Viewpoint, VoxelState


def _frozen(array: np.ndarray) -> np.ndarray:
    out = np.array(array, dtype=float, copy=True)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class Snapshot:
    """What perception knew at the end of one tick; copies only, safe to hand to another thread."""

    t: float
    odometry: Odometry  # the latest VIO pose, with its own stamp
    T_world_odom: np.ndarray  # SLAM correction (drift compensation)
    distance: float  # travelled since the start, m (VIO)
    viewpoints: tuple[Viewpoint, ...]  # the mapping backend's latest, in the safe height band
    explored_volume: float  # m³, at the latest sample

    @property
    def T_odom_body(self) -> np.ndarray:
        return self.odometry.T_odom_body

    @property
    def T_world_body(self) -> np.ndarray:
        return self.T_world_odom @ self.T_odom_body

    @property
    def position_world(self) -> np.ndarray:
        return self.T_world_body[:3, 3]

    @property
    def yaw_world(self) -> float:
        return yaw_of(self.T_world_body)


@dataclass
class Rates:
    """When each rate-limited module runs next (simulated or wall-clock seconds)."""

    detect: float = 0.0
    viewpoints: float = 0.0
    trajectory: float = 0.0
    sample: float = 0.0


@dataclass
class PipelineHealth:
    """What became of the camera's frames on a real vehicle, on the platform's clock.

    Latencies are seconds from a frame's stamp (the telemetry time it was taken at) to the moment
    it was in the local map, in the global map, and its detections in SLAM.
    """

    skipped_by_mapper: int = 0  # replaced by a newer frame while the mapper was busy
    local_latency: list[float] = field(default_factory=list)  # one per frame handed over
    global_latency: list[float] = field(default_factory=list)  # one per frame in the global map
    detection_latency: list[float] = field(default_factory=list)  # one per frame the detector saw

    @property
    def frames(self) -> int:
        return len(self.local_latency)

    @property
    def mapped(self) -> int:
        return len(self.global_latency)

    @property
    def detected(self) -> int:
        return len(self.detection_latency)

    def figures(self) -> dict[str, Any]:
        """The counts and the latency samples, as ``RunSummary.pipeline`` holds them."""
        counts = {"frames": self.frames, "mapped": self.mapped, "detected": self.detected}
        return {**counts, **dataclasses.asdict(self)}


@dataclass(frozen=True)
class _GlobalUpdate:
    frame: Frame
    T_world_odom: np.ndarray
    refresh: bool  # recompute viewpoints whatever their period


class _Mapper:
    """The mapper thread: one global-map update at a time, the newest waiting frame next.

    Written by hand, not a ``ThreadPoolExecutor``: an executor queues every frame, and a frame
    that waited behind slower updates is worth less than the one after it. An exception ends the
    thread and is raised on the control thread at its next :meth:`check`.
    """

    def __init__(self, update: Callable[[_GlobalUpdate], None], health: PipelineHealth):
        self._update, self._health = update, health
        self._wake = threading.Condition()
        self._next: _GlobalUpdate | None = None
        self._error: BaseException | None = None
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="amslam-mapper", daemon=True)
        self._thread.start()

    def submit(self, job: _GlobalUpdate) -> None:
        with self._wake:
            if self._next is not None:
                self._health.skipped_by_mapper += 1
                job = dataclasses.replace(job, refresh=job.refresh or self._next.refresh)
            self._next = job
            self._wake.notify()

    def check(self) -> None:
        """Raise, on the caller's thread, what ended the mapper thread."""
        with self._wake:
            error, self._error = self._error, None
        if error is not None:
            raise error

    def _run(self) -> None:
        while True:
            with self._wake:
                while self._next is None and not self._stop:
                    self._wake.wait()
                if self._stop:
                    return
                job, self._next = self._next, None
            try:
                self._update(job)
            except BaseException as exc:  # noqa: BLE001 — handed to the control thread
                with self._wake:
                    self._error, self._stop = exc, True
                return

    def close(self) -> None:
        with self._wake:
            self._stop = True
            self._next = None
            self._wake.notify()
        self._thread.join()


T = TypeVar("T")


class _SlamThread:
    """The SLAM thread: every SLAM call of perception and of the tree's loop closures, in order.

    A FIFO, unlike the mapper: SLAM needs every odometry reading and every detection, in the
    order they happened. After each call it publishes the backend's ``T_world_odom``, which the
    control thread reads instead of calling the backend. An exception ends the thread and is
    raised on the control thread at its next :meth:`check` (and by the futures of the jobs it did not run).
    """

    def __init__(self, publish: Callable[[], None]):
        self._publish = publish
        self._jobs: queue.SimpleQueue[tuple[Callable[[], Any], Future] | None] = queue.SimpleQueue()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="amslam-slam", daemon=True)
        self._thread.start()

    def submit(self, job: Callable[[], T]) -> Future:
        """Queue ``job``; its future has its result once every earlier job has run."""
        self.check()
        future: Future = Future()
        self._jobs.put((job, future))
        return future

    def check(self) -> None:
        """Raise, on the caller's thread, what ended the SLAM thread."""
        error, self._error = self._error, None
        if error is not None:
            raise error

    def _run(self) -> None:
        while (item := self._jobs.get()) is not None:
            job, future = item
            try:
                result = job()
                self._publish()
            except BaseException as exc:  # noqa: BLE001 — handed to the control thread
                self._error = exc
                future.set_exception(exc)
                self._fail_queued(exc)
                return
            future.set_result(result)

    def _fail_queued(self, exc: BaseException) -> None:
        while (item := self._jobs.get()) is not None:
            item[1].set_exception(exc)

    def close(self) -> None:
        """Run what is queued, then stop."""
        self._jobs.put(None)
        self._thread.join()


#: width (px) a frame is kept at for a rebuild of the global map: the global map's 0.25 m voxels
#: take every 4th pixel of 320 and every 8th of 640 (``auto_stride``), about 80 across
KEPT_FRAME_WIDTH = 80


@dataclass(frozen=True)
class KeptFrame:
    """A depth frame as kept for rebuilding the global map (``exploration.reanchor_map``)."""

    stamp: float
    depth: np.ndarray  # float16, every ``f``-th pixel
    K: np.ndarray  # the intrinsics of that subsampled image
    T_odom_cam: np.ndarray

    @classmethod
    def of(cls, frame: Frame) -> KeptFrame:
        f = max(1, int(np.ceil(frame.depth.shape[1] / KEPT_FRAME_WIDTH)))
        K = np.array(frame.K, dtype=float)
        K[:2] /= f  # pixel u' of the kept image is pixel f·u' of the frame
        K[2] = [0.0, 0.0, 1.0]
        depth = np.asarray(frame.depth)[::f, ::f].astype(np.float16)
        return cls(float(frame.stamp), depth, K, np.array(frame.T_odom_cam, dtype=float))


def keypose_corrections(
    stamps: np.ndarray, keyposes: list, keypose_odometry: dict[float, np.ndarray], fallback: np.ndarray
) -> list[np.ndarray]:
    """The odometry-to-world correction at each of ``stamps``: that of the latest key pose at or
    before it (the first key pose's before any), ``T_world_body`` as SLAM optimised it times the
    inverse of the odometry pose the key pose was made at; ``fallback`` without key poses."""
    corr, times = [], []
    for kp in keyposes:
        T_odom = keypose_odometry.get(float(kp.stamp))
        if T_odom is not None:
            corr.append(np.asarray(kp.T_world_body, float) @ invert(T_odom))
            times.append(float(kp.stamp))
    if not corr:
        return [fallback for _ in stamps]
    index = np.clip(np.searchsorted(np.array(times), np.asarray(stamps, float), side="right") - 1, 0, None)
    return [corr[i] for i in index]


class Perception:
    """Owns module order and rates, the trajectories, samples and distance travelled."""

    def __init__(
        self,
        platform: Platform,
        slam: Slam,
        mapping: Mapping,
        detector: Detector,
        exploration: ExplorationSection,
        rundir: RunDir,
        measurements: MeasurementLog,
        hook: Callable[..., None],
        boundary: Boundary | None = None,
    ):
        self.platform, self.slam, self.mapping, self.detector = platform, slam, mapping, detector
        self.boundary = check = boundary or Boundary()
        self.exploration = exploration
        self.rundir, self.measurements, self.hook = rundir, measurements, hook
        self.T_body_cam = platform.camera.T_body_cam
        self.detect_period = 1.0 / max(getattr(detector, "rate_hz", 2.0), 1e-6)
        self.rates = Rates()
        self.distance = 0.0
        self.truth: list[tuple[float, np.ndarray]] = []
        self.vio: list[tuple[float, np.ndarray]] = []
        self.samples: dict[str, list] = {"uncertainty": [], "explored": []}
        self._viewpoints: tuple[Viewpoint, ...] = ()
        self._refresh = False  # set by the control thread, handed to the next global update
        self._refresh_after_rebuild = False  # set and read where the global map is updated
        # exploration.reanchor_map: the frames, the odometry pose of each key pose, the correction
        # the global map stands at
        self._kept: list[KeptFrame] = []
        self._kept_at: list[np.ndarray] = []  # the correction each kept frame is in the map at
        self._keypose_odometry: dict[float, np.ndarray] = {}
        self._anchored: np.ndarray | None = None
        with check.calling("platform", "odometry()"):
            odom = check.odometry(platform.odometry())
        self._last_position = odom.T_odom_body[:3, 3].copy()
        self._explored_volume = 0.0  # the mapper's latest (real vehicle)
        self.health = PipelineHealth()
        # On a real vehicle the network and the global map run beside the control loop; in the
        # simulator inline.
        self._pool = (
            None if platform.simulated else ThreadPoolExecutor(1, thread_name_prefix="amslam-detector")
        )
        self._detecting: tuple[Future, Frame] | None = None
        self._mapper = None if platform.simulated else _Mapper(self._update_global, self.health)
        self._correction = _frozen(slam.T_world_odom())  # the SLAM thread's latest (real vehicle)
        self._slam = None if platform.simulated else _SlamThread(self._publish_correction)
        #: what the mapper and SLAM threads leave for the control thread: the run folder and the
        #: observers are its own (the thread rule); made at the start of its next step
        self._for_control: deque[Callable[[], None]] = deque()
        self.snapshot = self._publish(platform.time(), platform.odometry())

    def T_world_odom(self) -> np.ndarray:
        """SLAM's correction of the odometry frame: the backend's now in the simulator, on a real
        vehicle the one the SLAM thread published after its latest call (never a wait)."""
        return self.slam.T_world_odom() if self._slam is None else self._correction

    def slam_job(self, job: Callable[[], T]) -> Future:
        """Run ``job`` (SLAM calls) after everything perception handed SLAM so far: a future of
        its result (a loop-closure attempt must see every detection made before it). In the
        simulator it runs now and the future is done when returned."""
        return finished(job) if self._slam is None else self._slam.submit(job)

    def _publish_correction(self) -> None:
        self._correction = _frozen(self.slam.T_world_odom())

    def refresh_viewpoints(self) -> None:
        """Recompute viewpoints at the next frame (a goal was visited or found unreachable)."""
        self._refresh = True

    def step(self, dt: float) -> Snapshot:
        """Advance the platform by ``dt`` and run every module that is due; the new snapshot."""
        check = self.boundary
        with check.calling("platform", "advance()"):
            self.platform.advance(dt)
            t = self.platform.time()
        with check.calling("platform", "odometry()"):
            odom = check.odometry(self.platform.odometry())
        with check.calling("platform", "ground_truth()"):
            truth = self.platform.ground_truth()
            if truth is not None:
                truth = check.pose("platform", "ground_truth()", truth)
        here = odom.T_odom_body[:3, 3]
        self.distance += float(np.linalg.norm(here - self._last_position))
        self._last_position = here.copy()
        if self._slam is None:
            self._add_odometry(t, odom, truth)
        else:
            self._slam.submit(lambda: self._add_odometry(t, odom, truth))
        if self._mapper is not None:
            self._mapper.check()
        while self._for_control:
            self._for_control.popleft()()
        with check.calling("platform", "capture()"):
            frame = check.frame(self.platform.capture())
        if frame is not None:
            self._integrate(frame)
        if self._detecting is not None and self._detecting[0].done():
            (done, seen), self._detecting = self._detecting, None
            with check.calling("detector", "detect()"):
                detections = check.detections(done.result())
            self._feed(seen, detections)
        self._record(t, odom, truth)
        self.snapshot = self._publish(t, odom)
        return self.snapshot

    def close(self) -> None:
        if self._mapper is not None:
            self._mapper.close()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        if self._slam is not None:
            self._slam.close()

    # -- the modules ---------------------------------------------------------------------------

    def _add_odometry(self, t: float, odom: Odometry, truth: np.ndarray | None) -> None:
        """Odometry to SLAM; a key pose it made to the base's log and the observers."""
        with self.boundary.calling("slam", "add_odometry()"):
            keyposed = self.slam.add_odometry(odom)
        if not keyposed:
            return
        self.measurements.keypose(odom, truth)
        if self.exploration.reanchor_map:
            self._keypose_odometry[float(odom.stamp)] = odom.T_odom_body.copy()
        keyposes = self.slam.keyposes()
        if keyposes:
            keypose = keyposes[-1]
            self._on_control_thread(lambda: self.hook("amslam_keyframe", t=t, keypose=keypose))

    def _integrate(self, frame: Frame) -> None:
        check = self.boundary
        with check.calling("slam", "T_world_odom()"):
            T_world_odom = check.pose("slam", "T_world_odom()", self.T_world_odom())
        with check.calling("mapping", "integrate_local()"):
            self.mapping.integrate_local(frame.depth, frame.K, frame.T_odom_cam)
        job, self._refresh = _GlobalUpdate(frame, T_world_odom, self._refresh), False
        if self._mapper is None:
            self._update_global(job)
        else:
            self.health.local_latency.append(self.platform.time() - frame.stamp)
            self._mapper.submit(job)
        if frame.stamp >= self.rates.detect and self._detecting is None:
            self.rates.detect = frame.stamp + self.detect_period
            if self._pool is None:
                with check.calling("detector", "detect()"):
                    detections = check.detections(self.detector.detect(frame))
                self._feed(frame, detections)
            else:
                self._detecting = (self._pool.submit(self.detector.detect, frame), frame)

    def _update_global(self, job: _GlobalUpdate) -> None:
        """The global map's part of a frame: on the control thread in the simulator, on the
        mapper thread on a real vehicle (the only thread that writes the global map there)."""
        check, frame, T_world_odom = self.boundary, job.frame, job.T_world_odom
        if self.exploration.reanchor_map:
            self._reanchor_if_moved(frame.stamp, T_world_odom)
            self._kept.append(KeptFrame.of(frame))
            self._kept_at.append(T_world_odom)
        with check.calling("mapping", "integrate_global()"):
            self.mapping.integrate_global(frame.depth, frame.K, T_world_odom @ frame.T_odom_cam)
        if frame.stamp >= self.rates.viewpoints or job.refresh or self._refresh_after_rebuild:
            self._refresh_after_rebuild = False
            self.rates.viewpoints = frame.stamp + self.exploration.viewpoint_period
            with check.calling("mapping", "viewpoints()"):
                self._viewpoints = self._within_band(check.viewpoints(self.mapping.viewpoints()))
            if self._mapper is not None:  # the control thread's samples read this, not the map
                with check.calling("mapping", "explored_volume()"):
                    self._explored_volume = self.mapping.explored_volume()
        if self._mapper is not None:
            self.health.global_latency.append(self.platform.time() - frame.stamp)

    def _reanchor_if_moved(self, t: float, T_world_odom: np.ndarray) -> None:
        """Rebuild the global map from the kept frames at SLAM's corrected key poses when SLAM
        moved where they belong (a loop closure): surfaces integrated before it stand where the
        robot thought it was, e.g. a phantom wall through home (demo seed 3).

        Cheap test first: the odometry frame's correction moved by ``reanchor_min_shift`` since
        the last check. SLAM's correction also follows the current drift as it grows, which moves
        no earlier frame; so the map is rebuilt only when at least 5 % of the kept frames now
        belong more than ``reanchor_min_shift`` from where they were integrated.
        """
        if self._anchored is None:
            self._anchored = T_world_odom
        shift = float(np.linalg.norm(T_world_odom[:3, 3] - self._anchored[:3, 3]))
        if shift <= self.exploration.reanchor_min_shift or not self._kept:
            return
        self._anchored = T_world_odom
        check = self.boundary
        with check.calling("slam", "keyposes()"):
            keyposes = self.slam.keyposes()
        stamps = np.array([k.stamp for k in self._kept])
        corrections = keypose_corrections(stamps, keyposes, self._keypose_odometry, T_world_odom)
        moved = np.array(
            [np.linalg.norm(C[:3, 3] - U[:3, 3]) for C, U in zip(corrections, self._kept_at, strict=True)]
        )
        far = int(np.count_nonzero(moved > self.exploration.reanchor_min_shift))
        if far < max(1, 0.05 * len(moved)):
            return
        frames = (
            (k.depth.astype(np.float32), k.K, C @ k.T_odom_cam)
            for k, C in zip(self._kept, corrections, strict=True)
        )
        with check.calling("mapping", "rebuild_global()"):
            rebuilt = self.mapping.rebuild_global(frames)
        if rebuilt:
            self._kept_at = list(corrections)
            self._refresh_after_rebuild = True
            self._event(
                t,
                "map_reanchored",
                frames=len(self._kept),
                moved=far,
                max_move_m=round(float(moved.max()), 3),
            )

    def _event(self, t: float, name: str, **fields) -> None:
        """An event of the global map's update, written by the control thread."""
        self._on_control_thread(lambda: self.rundir.event(t, name, **fields))

    def _on_control_thread(self, call: Callable[[], None]) -> None:
        """``call()`` now in the simulator (one thread); on a real vehicle, from the mapper or
        SLAM thread, at the control thread's next step."""
        if self.platform.simulated:
            call()
        else:
            self._for_control.append(call)

    def _feed(self, frame: Frame, detections: list[Detection]) -> None:
        if self._slam is None:
            self._add_detections(frame, detections)
        else:
            self._slam.submit(lambda: self._add_detections(frame, detections))

    def _add_detections(self, frame: Frame, detections: list[Detection]) -> None:
        """Detections to SLAM at the pose of the frame they were made in, and to the base's log."""
        frame_odom = Odometry(frame.stamp, frame.T_odom_cam @ invert(self.T_body_cam))
        with self.boundary.calling("slam", "add_detections()"):
            self.slam.add_detections(frame_odom, self.T_body_cam, detections)
        if self._slam is not None:
            self.health.detection_latency.append(self.platform.time() - frame.stamp)
        T_truth = frame.T_world_cam_truth
        body_truth = None if T_truth is None else T_truth @ invert(self.T_body_cam)
        self.measurements.detections(frame_odom, detections, body_truth)

    def _record(self, t: float, odom: Odometry, truth: np.ndarray | None) -> None:
        ex = self.exploration
        if t >= self.rates.trajectory:
            self.rates.trajectory = t + 1.0 / ex.trajectory_rate_hz
            self.rundir.pose("vio", t, odom.T_odom_body)
            self.rundir.pose("slam", t, self.T_world_odom() @ odom.T_odom_body)
            self.vio.append((t, odom.T_odom_body.copy()))
            if truth is not None:
                self.rundir.pose("ground_truth", t, truth)
                self.truth.append((t, truth.copy()))
        if t >= self.rates.sample:
            self.rates.sample = t + ex.uncertainty_period
            distance = self.distance
            if self._slam is None:
                self._sample_uncertainty(t, distance)
            else:
                self._slam.submit(lambda: self._sample_uncertainty(t, distance))
            explored = self.mapping.explored_volume() if self._mapper is None else self._explored_volume
            self.samples["explored"].append((t, self.distance, explored))

    def _sample_uncertainty(self, t: float, distance: float) -> None:
        pose_trace, landmark_trace = self.slam.uncertainty()
        self.samples["uncertainty"].append((t, distance, pose_trace, landmark_trace))

    def _publish(self, t: float, odom: Odometry) -> Snapshot:
        explored = self.samples["explored"]
        return Snapshot(
            t=t,
            odometry=Odometry(odom.stamp, _frozen(odom.T_odom_body)),
            T_world_odom=_frozen(self.boundary.pose("slam", "T_world_odom()", self.T_world_odom())),
            distance=self.distance,
            viewpoints=self._viewpoints,
            explored_volume=explored[-1][2] if explored else 0.0,
        )

    def _within_band(self, vps: list[Viewpoint]) -> tuple[Viewpoint, ...]:
        """Move each viewpoint, and each of its alternatives, vertically into the band between
        floor and ceiling the tree flies in.

        The coarse map allows any height with a robot radius of clearance, but odometry drift is
        largest in z: a goal a radius above the floor or below the ceiling is a crash waiting for
        a few centimetres of drift. Floor and ceiling are the nearest occupied voxels below and
        above in the global map: one query for the columns of every option at once (this runs
        at every viewpoint update, for up to 7 options per cluster).
        """
        options = [vp.options() for vp in vps]
        flat = [o for opts in options for o in opts]
        if not flat:
            return ()
        ex = self.exploration
        step = self.mapping.voxel_size()
        offsets = np.arange(step, 3.0 + step, step)
        n = len(offsets)
        signed = np.concatenate([-offsets, offsets])  # below, then above
        centres = np.array([o.position for o in flat])
        columns = centres[:, None, :] + signed[None, :, None] * np.array([0.0, 0.0, 1.0])
        occupied = (self.mapping.states(columns.reshape(-1, 3)) == VoxelState.OCCUPIED).reshape(
            len(flat), 2 * n
        )
        below, above = occupied[:, :n], occupied[:, n:]
        z = centres[:, 2]
        floor = np.where(below.any(axis=1), z - offsets[np.argmax(below, axis=1)], -np.inf)
        ceiling = np.where(above.any(axis=1), z + offsets[np.argmax(above, axis=1)], np.inf)
        lo, hi = floor + ex.min_height, ceiling - ex.min_headroom
        # a low gap (lo > hi) is left to the path planner's clearance
        new_z = np.where(lo > hi, z, np.clip(z, lo, hi))
        moved = [
            o if nz == o.position[2] else dataclasses.replace(o, position=np.array([*o.position[:2], nz]))
            for o, nz in zip(flat, new_z.tolist(), strict=True)
        ]
        out, k = [], 0
        for opts in options:
            first, *rest = moved[k : k + len(opts)]
            k += len(opts)
            out.append(dataclasses.replace(first, alternatives=tuple(rest)))
        return tuple(out)
