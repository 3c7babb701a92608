"""The runner: builds the backends and the tree from a mission and runs the tick loop.

The loop runs on the platform's clock. With the simulator that clock is simulated and advances by
exactly one control period per tick, and every module runs inline at its own rate in a fixed
order (VIO → SLAM key poses → camera → local and global maps → frontiers → detector at its rate →
tree tick), so the same mission and seed give identical outputs; time does not pass while a
module computes, so a slow module cannot stall the simulated vehicle. With a real vehicle the
same schedule runs against wall-clock time.

Every exit path — completion, a crash, a failing backend, Ctrl-C — goes through
:meth:`Runner._finish`, which writes metrics, map, plots and report with the verdict.
"""

from __future__ import annotations

import dataclasses
import json
import traceback
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import py_trees
from py_trees.common import Status

from amslam import __version__
from amslam.errors import AmslamError, MissionError
from amslam.geometry import invert, pose_from
from amslam.interfaces import BACKEND_KINDS, Backend, RunContext
from amslam.measurements import FILENAME as MEASUREMENTS
from amslam.measurements import MeasurementLog
from amslam.mission import Mission
from amslam.recording import TreeRecorder
from amslam.registry import Registry
from amslam.report import compute_metrics, write_outputs
from amslam.robot import Robot
from amslam.rundir import RunDir
from amslam.trees.flight import build_mission_tree
from amslam.types import BoundingBox, Frame, Odometry


@dataclass
class RunResult:
    """What a finished run says about itself."""

    run_dir: Path
    verdict: str
    metrics: dict[str, Any]

    @property
    def report(self) -> Path:
        return self.run_dir / "report.md"


class Runner:
    """Flies one mission and fills one run folder."""

    def __init__(
        self,
        mission: Mission,
        registry: Registry,
        out_root: Path = Path("runs"),
        progress: bool = False,
        on_start: Callable[[Path], None] = lambda run_dir: None,
    ):
        self.mission = mission
        self.registry = registry
        self.out_root = Path(out_root)
        self.progress = progress
        self.on_start = on_start
        self.backends: dict[str, Backend] = {}
        self.samples: dict[str, list] = {"uncertainty": [], "explored": []}

    # -- observer hooks ------------------------------------------------------------------------

    def _hook(self, name: str, **kwargs: Any) -> None:
        try:
            getattr(self.registry.pm.hook, name)(**kwargs)
        except Exception as exc:  # an observer must never stop the flight
            self.rundir.event(self._now(), "observer_error", hook=name, error=f"{type(exc).__name__}: {exc}")

    def _now(self) -> float:
        platform = self.backends.get("platform")
        try:
            return platform.time() if platform else 0.0
        except Exception:
            return 0.0

    # -- set-up --------------------------------------------------------------------------------

    def _configure(self) -> None:
        model = self.mission.model
        seeds = np.random.SeedSequence(model.seed).spawn(len(BACKEND_KINDS))
        context = RunContext(
            rng=np.random.default_rng(seeds[0]),
            run_dir=self.rundir.path,
            emit=lambda name, **f: self.rundir.event(self._now(), name, **f),
            robot=model.robot.spec(),
            mission_dir=self.mission.directory,
        )
        for i, kind in enumerate(BACKEND_KINDS):
            choice = self.mission.backends[kind]
            backend = self.registry.factory(kind, choice.plugin)()
            context = dataclasses.replace(context, rng=np.random.default_rng(seeds[i]))
            backend.configure(choice.params, context)
            self.backends[kind] = backend
            if kind == "mapping" and model.prior_map:
                prior = (self.mission.directory / model.prior_map).resolve()
                if not prior.exists():
                    raise MissionError([f"{self.mission.source}: prior_map: no such file {prior}"])
                backend.load(prior)
                self.rundir.event(0.0, "prior_map_loaded", path=str(prior))
            if kind == "platform":
                backend.start()
                world = backend.world_summary()
                area = model.area.box() if model.area else None
                if area is None and world is not None:
                    area = BoundingBox(np.asarray(world.bounds_lo, float), np.asarray(world.bounds_hi, float))
                context = dataclasses.replace(context, camera=backend.camera, world=world, area=area)
        self.context = context

    # -- the loop ------------------------------------------------------------------------------

    def run(self) -> RunResult:
        """Fly the mission; always returns with a verdict and a complete run folder."""
        self.rundir = RunDir(self.out_root, self.mission.name)
        self.rundir.write_yaml("mission.yaml", self.mission.resolved())
        self.on_start(self.rundir.path)
        verdict = "failed: did not start"
        try:
            self._configure()
            verdict = self._loop()
        except KeyboardInterrupt:
            verdict = "aborted"
            self.rundir.event(self._now(), "aborted", reason="interrupted by the operator (Ctrl-C)")
            self._safe_land()
        except AmslamError as exc:
            verdict = f"failed: {exc}"
            self.rundir.event(self._now(), "error", error=str(exc))
        except Exception as exc:
            verdict = f"failed: {type(exc).__name__}: {exc}"
            self.rundir.event(self._now(), "error", error=verdict, traceback=traceback.format_exc())
        return self._finish(verdict)

    def _loop(self) -> str:
        model = self.mission.model
        ex = model.exploration
        platform, mapping, slam = self.backends["platform"], self.backends["mapping"], self.backends["slam"]
        detector = self.backends["detector"]
        T_body_cam = platform.camera.T_body_cam
        odom0 = platform.odometry()
        self.robot = Robot(
            platform=platform,
            mapping=mapping,
            slam=slam,
            detector=detector,
            planner=self.backends["planner"],
            spec=self.context.robot,
            limits=model.limits,
            exploration=ex,
            emit=lambda name, **f: self.rundir.event(self._now(), name, **f),
            hooks=self._hook,
            home_world=odom0.T_odom_body[:3, 3].copy(),
        )
        py_trees.blackboard.Blackboard.clear()
        root = build_mission_tree(model, self.registry.behaviours, failsafe=not platform.simulated)
        tree = py_trees.trees.BehaviourTree(root)
        tree.setup(robot=self.robot)
        recorder = TreeRecorder(tree, self.rundir)
        # what this robot would send to the base for multi-robot merging (paper 2 §IV-B4)
        base = model.robot.base
        T_world_odom = None if base is None else pose_from(np.array(base[:3]), float(np.radians(base[3])))
        measurements = MeasurementLog(
            self.rundir.path / MEASUREMENTS, self.mission.name, T_body_cam, T_world_odom=T_world_odom
        )
        self._hook("amslam_run_start", run_dir=self.rundir.path, mission=self.mission.resolved())
        self.rundir.event(0.0, "run_start", mission=self.mission.name, amslam=__version__)

        dt = 1.0 / ex.control_rate_hz
        detect_period = 1.0 / max(getattr(detector, "rate_hz", 2.0), 1e-6)
        next_detect = 0.0
        next_viewpoints = 0.0
        next_traj = 0.0
        next_sample = 0.0
        hard_stop = model.limits.max_time * 1.5 + 300.0
        last_pos = odom0.T_odom_body[:3, 3].copy()
        bar = self._progress_bar(model.limits.max_time)
        self.truth: list[tuple[float, np.ndarray]] = []
        self.vio: list[tuple[float, np.ndarray]] = []

        def use_detections(frame: Frame, detections: list) -> None:
            frame_odom = Odometry(frame.stamp, frame.T_odom_cam @ invert(T_body_cam))
            slam.add_detections(frame_odom, T_body_cam, detections)
            T_truth = frame.T_world_cam_truth
            measurements.detections(
                frame_odom, detections, None if T_truth is None else T_truth @ invert(T_body_cam)
            )

        # On a real vehicle the network runs beside the control loop (frames arriving while it is
        # busy are skipped); in the simulator it runs inline: the clock waits, runs stay repeatable.
        detect_pool = (
            None if platform.simulated else ThreadPoolExecutor(1, thread_name_prefix="amslam-detector")
        )
        detecting: tuple[Future, Frame] | None = None
        try:
            while True:
                platform.advance(dt)
                t = platform.time()
                odom = platform.odometry()
                truth = platform.ground_truth()
                self.robot.distance += float(np.linalg.norm(odom.T_odom_body[:3, 3] - last_pos))
                last_pos = odom.T_odom_body[:3, 3].copy()
                if slam.add_odometry(odom):
                    measurements.keypose(odom, truth)
                    kps = slam.keyposes()
                    if kps:
                        self._hook("amslam_keyframe", t=t, keypose=kps[-1])
                frame = platform.capture()
                if frame is not None:
                    mapping.integrate_local(frame.depth, frame.K, frame.T_odom_cam)
                    T_world_cam = slam.T_world_odom() @ frame.T_odom_cam
                    mapping.integrate_global(frame.depth, frame.K, T_world_cam)
                    if frame.stamp >= next_viewpoints or self.robot.viewpoints_stale:
                        self.robot.viewpoints_stale = False
                        next_viewpoints = frame.stamp + ex.viewpoint_period
                        self.robot.set_viewpoints(mapping.viewpoints())
                    if frame.stamp >= next_detect and detecting is None:
                        next_detect = frame.stamp + detect_period
                        if detect_pool is None:
                            use_detections(frame, detector.detect(frame))
                        else:
                            detecting = (detect_pool.submit(detector.detect, frame), frame)
                if detecting is not None and detecting[0].done():
                    (done, frame_seen), detecting = detecting, None
                    use_detections(frame_seen, done.result())
                if t >= next_traj:
                    next_traj = t + 1.0 / ex.trajectory_rate_hz
                    self.rundir.pose("vio", t, odom.T_odom_body)
                    self.rundir.pose("slam", t, slam.T_world_odom() @ odom.T_odom_body)
                    self.vio.append((t, odom.T_odom_body.copy()))
                    if truth is not None:
                        self.rundir.pose("ground_truth", t, truth)
                        self.truth.append((t, truth.copy()))
                if t >= next_sample:
                    next_sample = t + ex.uncertainty_period
                    pose_tr, lm_tr = slam.uncertainty()
                    self.samples["uncertainty"].append((t, self.robot.distance, pose_tr, lm_tr))
                    self.samples["explored"].append((t, self.robot.distance, mapping.explored_volume()))
                status = platform.status()
                if status.crashed:
                    self.rundir.event(t, "crash", where=status.crash_reason)
                    return f"crashed: {status.crash_reason}"
                tree.tick()
                recorder.record(t)
                self._hook("amslam_tick", t=t, tree=tree)
                if bar is not None:
                    bar.n = min(t, bar.total)
                    bar.set_postfix_str(
                        f"dist {self.robot.distance:5.1f} m, "
                        f"explored {self.samples['explored'][-1][2]:6.1f} m³",
                        refresh=False,
                    )
                    bar.update(0)
                if root.status == Status.SUCCESS:
                    outcome = tree.root.children[-1].feedback_message
                    exploration = py_trees.blackboard.Blackboard.storage.get("/exploration", "")
                    self.rundir.event(t, "mission_end", exploration=exploration, landing=outcome)
                    return "completed"
                if root.status == Status.FAILURE:
                    failed = [n for n in root.iterate() if n.status == Status.FAILURE and not n.children]
                    why = failed[-1].name + ": " + failed[-1].feedback_message if failed else "tree failed"
                    self._safe_land()
                    return f"failed: {why}"
                if t > hard_stop:
                    self._safe_land()
                    limit = model.limits.max_time
                    return f"failed: still flying {hard_stop:.0f} s after start (time limit {limit} s)"
        finally:
            if detect_pool is not None:
                detect_pool.shutdown(wait=True, cancel_futures=True)
            if bar is not None:
                bar.close()
            recorder.close()
            measurements.close()

    def _progress_bar(self, total: float):
        if not self.progress:
            return None
        from tqdm import tqdm

        return tqdm(
            total=total, unit="s", desc=f"{self.mission.name} (sim time)", mininterval=0.5, leave=False
        )

    def _safe_land(self) -> None:
        platform = self.backends.get("platform")
        if platform is None:
            return
        try:
            platform.land()
        except Exception as exc:  # noqa: BLE001 — landing on the way out must not mask the verdict
            self.rundir.event(self._now(), "land_failed", error=str(exc))

    # -- outputs -------------------------------------------------------------------------------

    def _finish(self, verdict: str) -> RunResult:
        metrics: dict[str, Any] = {"verdict": verdict}
        try:
            metrics = compute_metrics(self, verdict)
            write_outputs(self, metrics)
        except Exception as exc:  # a broken summary must still leave the streams and the verdict
            metrics["outputs_error"] = f"{type(exc).__name__}: {exc}"
            self.rundir.event(
                self._now(), "outputs_error", error=metrics["outputs_error"], traceback=traceback.format_exc()
            )
            (self.rundir.path / "metrics.json").write_text(json.dumps(metrics, indent=2, default=str))
        self.rundir.event(self._now(), "run_end", verdict=verdict)
        self._hook(
            "amslam_run_end",
            run_dir=self.rundir.path,
            verdict=verdict,
            metrics=metrics,
            trajectory=np.array([T[:3, 3] for _, T in getattr(self, "truth", [])]).reshape(-1, 3),
        )
        if getattr(self, "robot", None) is not None:
            self.robot.close()
        for backend in reversed(list(self.backends.values())):
            try:
                backend.close()
            except Exception as exc:  # noqa: BLE001
                self.rundir.event(self._now(), "close_failed", backend=type(backend).__name__, error=str(exc))
        self.rundir.close()
        return RunResult(self.rundir.path, verdict, metrics)
