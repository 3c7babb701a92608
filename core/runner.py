"""The runner: builds the backends, the services and the tree from a mission and ticks them.

Each tick on the platform's clock is one pass over the services (docs/architecture.md, "The
runtime"): :class:`amslam.perception.Perception` runs every module that is due, in a fixed order
(VIO → SLAM key poses → camera → local and global maps → frontiers → detector at its rate), and
publishes a :class:`amslam.perception.Snapshot`; the planning service sees it; the tree ticks.
With the simulator the clock advances by exactly one control period per tick and everything runs
inline, so the same mission and seed give identical outputs; with a real vehicle the same
schedule runs against wall-clock time, with the planner and the detector on their own threads
under the thread rule (:mod:`amslam.sharing`).

Every exit path — completion, a crash, a failing backend, Ctrl-C — goes through
:meth:`Runner._finish`, which writes the verdict to ``metrics.json``, builds the
:class:`amslam.types.RunSummary` and hands it to the run-end observers (the report among them, an
application: ``amslam.apps.report``), then closes the backends.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import py_trees
from py_trees.common import Status

from amslam import __version__, console
from amslam.backend_process import SlamProcess, implementation
from amslam.boundary import BackendError, Boundary
from amslam.errors import AmslamError, MissionError
from amslam.geometry import pose_from
from amslam.interfaces import BACKEND_KINDS, Backend, Mapping, Platform, RunContext
from amslam.measurements import FILENAME as MEASUREMENTS
from amslam.measurements import MeasurementLog
from amslam.mission import Mission
from amslam.perception import Perception
from amslam.planning import PlanningService
from amslam.recording import TreeRecorder
from amslam.registry import Registry
from amslam.robot import EventSink, Robot
from amslam.rundir import RunDir, jsonable, write_atomically
from amslam.setpoints import SetpointFilter
from amslam.sharing import share
from amslam.types import BoundingBox, RunSummary

#: the interpreter's thread switch interval during a real vehicle's flight, s (Python's default is
#: 0.005). The control thread lets go of the interpreter at every numpy call of a frame's
#: integration, and then waits until a thread running Python (the mapper's, SLAM's marginals, the
#: planner's) gives it back, up to one interval each time: beside two such threads a 10 Hz loop
#: whose tick is 17 ms of local-map update made 3 of its 40 ticks at 5 ms and all 40 at 0.2 ms
#: (4 of them over the period), for 17 % less of the other threads' work while all three compete
#: (benchmarks/switch_interval.py, docs/benchmarks.md).
REAL_TIME_SWITCH_INTERVAL = 0.0002


@dataclass
class RunResult:
    """What a finished run says about itself."""

    run_dir: Path
    verdict: str
    metrics: dict[str, Any]

    @property
    def report(self) -> Path:
        return self.run_dir / "report.md"


#: the packages a flight's numbers depend on: the same mission and seed flew demo seed 7 to SLAM
#: RMS 0.165 m before the environment was rebuilt (session 52) and 0.295 m after, with the same code
NUMERIC_PACKAGES = ("numpy", "scipy", "gtsam", "open3d", "numba", "scikit-learn", "onnxruntime")


def numeric_packages() -> dict[str, str]:
    """Versions of :data:`NUMERIC_PACKAGES` installed (``run_start`` event): which environment flew a run."""
    from importlib.metadata import PackageNotFoundError, version

    found = {}
    for name in NUMERIC_PACKAGES:
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = "absent"
    return found


def backend_rng(seed: int, kind: str) -> np.random.Generator:
    """The random generator a run gives the backend of ``kind``: one independent stream per kind
    from the mission's seed, so a backend configured outside a run (to look at a simulated world
    before flying it) draws exactly what it draws in the run."""
    streams = np.random.SeedSequence(seed).spawn(len(BACKEND_KINDS))
    return np.random.default_rng(streams[list(BACKEND_KINDS).index(kind)])


def started_platform(mission: Mission, registry: Registry, run_dir: Path) -> Platform:
    """The mission's platform configured as its run would configure it, and started: to read
    its world (``world_summary``) without flying. The caller closes it."""
    choice = mission.backends["platform"]
    platform = registry.factory("platform", choice.plugin)()
    context = RunContext(
        rng=backend_rng(mission.model.seed, "platform"),
        run_dir=Path(run_dir),
        robot=mission.model.robot.spec(),
        mission_dir=mission.directory,
    )
    platform.configure(choice.params, context)
    platform.start()
    return platform


class Runner:
    """Flies one mission and fills one run folder."""

    def __init__(
        self,
        mission: Mission,
        registry: Registry,
        out_root: Path = Path("runs"),
        on_start: Callable[[Path], None] = lambda run_dir: None,
    ):
        self.mission = mission
        self.registry = registry
        self.out_root = Path(out_root)
        self.on_start = on_start
        self.backends: dict[str, Backend] = {}
        self.context: RunContext | None = None  # once the backends are configured
        self.runtime: Runtime | None = None  # once the services are built
        self._write_errors: list[str] = []  # outputs that could not be written (a full disk)
        self._exploration_end: str | None = None  # how the exploration ended (once the tree has)
        self._way_home: str | None = None  # whether the vehicle came home (trees that fly there)
        self._closed_outputs: deque[str] = deque()  # stdout/stderr lost their reader (any thread)
        # each backend's outputs are checked where they enter the runtime, and named in verdicts
        self.boundary = Boundary(
            {kind: registry.origin(kind, choice.plugin) for kind, choice in mission.backends.items()}
        )

    # -- observer hooks ------------------------------------------------------------------------

    def _hook(self, name: str, **kwargs: Any) -> list[tuple[str, Any]]:
        """Call each implementation of observer hook ``name`` on its own, in pluggy's order; the
        (plugin, answer) of each that returned.

        Not ``pm.hook.<name>(**kwargs)``: pluggy stops at the first exception, so one broken
        observer would silence every later one (the report among them) and could not be named.
        """
        answers: list[tuple[str, Any]] = []
        for impl in reversed(getattr(self.registry.pm.hook, name).get_hookimpls()):
            if impl.wrapper or impl.hookwrapper:  # a wrapper needs pluggy's call loop, which we left
                self._observer_failed(name, impl.plugin_name, "a wrapper cannot observe a run")
                continue
            try:
                answer = impl.function(*(kwargs[arg] for arg in impl.argnames))
            except Exception as exc:  # an observer must never stop the flight
                self._observer_failed(name, impl.plugin_name, f"{type(exc).__name__}: {exc}")
                if isinstance(exc, OSError):  # it could not write its files: the run's outputs are short
                    self._write_errors.append(f"{impl.plugin_name}: {type(exc).__name__}: {exc}")
                continue
            answers.append((impl.plugin_name, answer))
        return answers

    def _observer_failed(self, hook: str, plugin: str, error: str) -> None:
        self.rundir.event(self._now(), "observer_failed", hook=hook, plugin=plugin, error=error)

    def _now(self) -> float:
        platform = self.backends.get("platform")
        try:
            return platform.time() if platform else 0.0
        except Exception:
            return 0.0

    # -- set-up --------------------------------------------------------------------------------

    def _build(self, kind: str, plugin: str) -> Backend:
        """The backend of ``kind``; one that asks for a process of its own gets one on a real
        vehicle (:mod:`amslam.backend_process`)."""
        platform = self.backends.get("platform")
        factory = self.registry.factory(kind, plugin)
        real = platform is not None and not platform.simulated
        if kind == "slam" and real and isinstance(factory, type) and factory.own_process:
            return SlamProcess(factory)
        return factory()

    def _configure(self) -> None:
        model = self.mission.model
        context = RunContext(
            rng=np.random.default_rng(),
            run_dir=self.rundir.path,
            emit=lambda name, **f: self.rundir.event(self._now(), name, **f),
            robot=model.robot.spec(),
            mission_dir=self.mission.directory,
        )
        for kind in BACKEND_KINDS:
            choice = self.mission.backends[kind]
            context = dataclasses.replace(context, rng=backend_rng(model.seed, kind))
            with self.boundary.calling(kind, "configure()"):
                backend = self._build(kind, choice.plugin)
                # the simulator's truth goes to the simulator alone: a real robot has none
                own = (
                    context
                    if getattr(backend, "simulator", False)
                    else dataclasses.replace(context, world=None)
                )
                backend.configure(choice.params, own)
            self.backends[kind] = backend
            if kind == "mapping" and model.prior_map:
                prior = (self.mission.directory / model.prior_map).resolve()
                if not prior.exists():
                    raise MissionError([f"{self.mission.source}: prior_map: no such file {prior}"])
                backend.load(prior)
                self.rundir.event(0.0, "prior_map_loaded", path=str(prior))
            if kind == "platform":
                with self.boundary.calling(kind, "start()"):
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
        # `amslam run | head -1`: a closed stdout does not stop the flight, the events say so
        stop_watching = console.when_closed(self._output_closed)
        try:
            return self._run()
        finally:
            stop_watching()

    def _output_closed(self, name: str) -> None:
        # Called on the thread that met the closed pipe, which may be another than the control
        # thread (a run observer's, like the status line's heartbeat): only noted here, and
        # recorded by the control thread (thread rule: the run folder and the platform are its).
        self._closed_outputs.append(name)

    def _record_closed_outputs(self) -> None:
        """The outputs whose reader went away since the last call, as events (control thread)."""
        while self._closed_outputs:
            name = self._closed_outputs.popleft()
            self.rundir.event(
                self._now(),
                f"{name}_closed",
                reason=f"{name}'s reader went away; the run goes on to its end, printing nothing more there",
            )

    def _run(self) -> RunResult:
        try:
            self.rundir.write_yaml("mission.yaml", self.mission.resolved())
        except OSError as exc:  # a full disk: the flight goes on, the outputs say what is missing
            self._write_errors.append(f"mission.yaml: {type(exc).__name__}: {exc}")
        self.on_start(self.rundir.path)
        verdict = "failed: did not start"
        try:
            self._configure()
            verdict = self._loop()
        except KeyboardInterrupt as exc:
            # Ctrl-C, or SIGTERM / SIGHUP raised as a KeyboardInterrupt by the command line
            verdict = "aborted"
            by = str(exc) if str(exc).startswith("SIG") else "SIGINT"
            self.rundir.event(self._now(), "aborted", reason=f"stopped by {by}: landing where it is")
            self._safe_land()
        except BackendError as exc:  # a backend raised or handed over garbage: the verdict names it
            verdict = f"failed: {exc}"
            self.rundir.event(self._now(), "error", error=str(exc), traceback=traceback.format_exc())
            self._land_after_error()
        except AmslamError as exc:
            verdict = f"failed: {exc}"
            self.rundir.event(self._now(), "error", error=str(exc))
            self._land_after_error()
        except Exception as exc:
            verdict = f"failed: {type(exc).__name__}: {exc}"
            self.rundir.event(self._now(), "error", error=verdict, traceback=traceback.format_exc())
            self._land_after_error()
        return self._finish(verdict)

    def _land_after_error(self) -> None:
        """The run failed in flight: land where the vehicle is. A real vehicle left in offboard
        mode by software that stopped sending setpoints only falls back to what its autopilot was
        told to do on offboard loss; the landing is commanded, not left to chance."""
        if self.runtime is None:  # failed while setting up: nothing has taken off
            return
        self.rundir.event(self._now(), "landing", reason="the run failed: landing where it is")
        self._safe_land()

    def _loop(self) -> str:
        """Tick until the tree ends, the vehicle crashes or the run overruns its time budget."""
        if self.backends["platform"].simulated:
            return self._ticks()
        # On a real vehicle the control thread shares the interpreter with the mapper, SLAM,
        # planner and path threads; see REAL_TIME_SWITCH_INTERVAL
        default = sys.getswitchinterval()
        sys.setswitchinterval(REAL_TIME_SWITCH_INTERVAL)
        try:
            return self._ticks()
        finally:
            sys.setswitchinterval(default)

    def _ticks(self) -> str:
        runtime = self.runtime = self._start_runtime()
        limits = self.mission.model.limits
        dt = 1.0 / self.mission.model.exploration.control_rate_hz
        hard_stop = limits.max_time * 1.5 + 300.0
        self._hook(
            "amslam_run_start",
            run_dir=self.rundir.path,
            mission=self.mission.resolved(),
            world=self.context.world,
        )
        self.rundir.event(
            0.0, "run_start", mission=self.mission.name, amslam=__version__, packages=numeric_packages()
        )
        try:
            while True:
                snapshot = runtime.perception.step(dt)
                runtime.planning.observe(snapshot)
                status = self.backends["platform"].status()
                if status.crashed:
                    self.rundir.event(snapshot.t, "crash", where=status.crash_reason)
                    return f"crashed: {status.crash_reason}"
                runtime.tree.tick()
                if runtime.planning.fault is not None:  # the planner handed back what it was not asked for
                    self._land_after_error()
                    return f"failed: {runtime.planning.fault}"
                runtime.recorder.record(snapshot.t)
                self._hook(
                    "amslam_tick", t=snapshot.t, tree=runtime.tree, snapshot=snapshot, mapping=runtime.mapping
                )
                self._record_closed_outputs()
                verdict = self._tree_verdict(snapshot.t)
                if verdict is None and snapshot.t > hard_stop:
                    self._safe_land()
                    verdict = (
                        f"failed: still flying {hard_stop:.0f} s after start (time limit {limits.max_time} s)"
                    )
                if verdict is not None:
                    return verdict
        finally:
            runtime.close()

    def _start_runtime(self) -> Runtime:
        """The services of one flight: perception, planning, the robot and the tree."""
        model = self.mission.model
        platform = self.backends["platform"]
        shared = share(self.backends)  # the thread rule: slam and mapping behind their locks
        odom0 = platform.odometry()
        # what this robot would send to the base for multi-robot merging (paper 2 §IV-B4)
        base = model.robot.base
        T_world_odom = None if base is None else pose_from(np.array(base[:3]), float(np.radians(base[3])))
        measurements = MeasurementLog(
            self.rundir.path / MEASUREMENTS,
            self.mission.name,
            platform.camera.T_body_cam,
            T_world_odom=T_world_odom,
            depth_noise=platform.camera.depth_noise,
        )
        ex = model.exploration
        perception = Perception(
            platform,
            shared["slam"],
            shared["mapping"],
            shared["detector"],
            ex,
            self.rundir,
            measurements,
            self._hook,
            boundary=self.boundary,
        )
        planning = PlanningService(
            planner=shared["planner"],
            slam=shared["slam"],
            mapping=shared["mapping"],
            exploration=ex,
            camera=platform.camera,
            threaded=not platform.simulated,
            clock=None if platform.simulated else platform.time,
            refresh_viewpoints=perception.refresh_viewpoints,
            slam_jobs=perception.slam_job,
            snapshot=perception.snapshot,
            boundary=self.boundary,
        )
        robot = Robot(
            platform=platform,
            mapping=shared["mapping"],
            correction=perception.T_world_odom,
            slam_name=implementation(self.backends["slam"]).__name__,
            spec=self.context.robot,
            limits=model.limits,
            setpoints=SetpointFilter(
                shared["mapping"],
                self.context.robot.radius,
                ex.min_height,
                ex.min_headroom,
                ceiling=self._ceiling(),
            ),
            odometer=lambda: perception.distance,
            home_world=odom0.T_odom_body[:3, 3].copy(),
            path_thread=None if platform.simulated else ThreadPoolExecutor(1, "amslam-paths"),
        )
        events = EventSink(lambda name, **f: self.rundir.event(self._now(), name, **f), self._hook)
        py_trees.blackboard.Blackboard.clear()
        build = self.registry.tree(model.tree)
        tree = py_trees.trees.BehaviourTree(
            build(model, self.registry.behaviours, failsafe=not platform.simulated)
        )
        tree.setup(flight=robot, navigation=robot, planning=planning, events=events)
        return Runtime(
            perception,
            planning,
            robot,
            tree,
            TreeRecorder(tree, self.rundir),
            measurements,
            shared["mapping"],
        )

    def _ceiling(self) -> float:
        """The highest a setpoint may go, world frame: the flight area's top less the radius."""
        area = self.context.area
        if area is None:
            return float("inf")
        return float(area.flyable(self.context.robot.radius).hi[2])

    def _tree_verdict(self, t: float) -> str | None:
        """The verdict once the tree has ended (None while it runs)."""
        root = self.runtime.tree.root
        if root.status == Status.SUCCESS:
            outcome = root.children[-1].feedback_message
            exploration = py_trees.blackboard.Blackboard.storage.get("/exploration", "")
            self._exploration_end = exploration or None
            self._way_home = self._home_outcome(root)
            self.rundir.event(t, "mission_end", exploration=exploration, landing=outcome)
            planning = self.runtime.planning
            if planning.failures >= self.mission.model.exploration.max_replan_failures:
                # the vehicle came home and landed, but exploration stopped because the planner
                # kept failing: that is a failed run, not a completed one
                return f"failed: {planning.last_error} ({planning.failures} plans in a row failed)"
            return "completed"
        if root.status == Status.FAILURE:
            failed = [n for n in root.iterate() if n.status == Status.FAILURE and not n.children]
            why = failed[-1].name + ": " + failed[-1].feedback_message if failed else "tree failed"
            self._safe_land()
            return f"failed: {why}"
        return None

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
        """The verdict in ``metrics.json``, the run-end observers, the backends closed."""
        self._record_closed_outputs()
        metrics = self._write_metrics(self._identity(verdict))  # first: whatever fails below, it is there
        summary = RunSummary(self.mission, self.rundir.path, verdict)
        try:
            summary = self._summary(verdict)
        except Exception as exc:  # a backend that cannot say what it holds: the observers get less
            self.rundir.event(
                self._now(),
                "summary_failed",
                error=f"{type(exc).__name__}: {exc}",
                traceback=traceback.format_exc(),
            )
        self.rundir.close_trajectories()
        self._stream_errors()
        metrics = self._write_metrics(self._measured(metrics, summary))
        self._hook(
            "amslam_run_end",
            run_dir=self.rundir.path,
            verdict=verdict,
            metrics=metrics,
            trajectory=summary.trajectory,
            summary=summary,
        )
        self._stream_errors()  # an observer's appends, too
        if self._write_errors:  # a full disk, say: say so where it can still be said
            metrics["outputs_error"] = "; ".join(dict.fromkeys(self._write_errors))  # each once
            self.rundir.event(self._now(), "outputs_error", error=metrics["outputs_error"])
            self._keep_what_can_be_kept(verdict, metrics)
        self._record_closed_outputs()  # a pipe closed while the observers wrote
        self.rundir.event(self._now(), "run_end", verdict=verdict)  # the last event of every run
        for backend in reversed(list(self.backends.values())):
            try:
                backend.close()
            except Exception as exc:  # noqa: BLE001
                self.rundir.event(self._now(), "close_failed", backend=type(backend).__name__, error=str(exc))
        self.rundir.close()
        return RunResult(self.rundir.path, verdict, metrics)

    def _stream_errors(self) -> None:
        """The streams that could not all be written (a full disk) join the output errors."""
        errors = self.rundir.stream_errors()
        if self.runtime is not None and self.runtime.measurements.error is not None:
            errors.append(self.runtime.measurements.error)
        self._write_errors += [e for e in errors if e not in self._write_errors]

    @staticmethod
    def _home_outcome(root: py_trees.behaviour.Behaviour) -> str | None:
        """How the stock trees' way home (their ``GoHome`` leaf) ended: "came home", or why it was
        given up (the vehicle then landed where it was); None for a tree without one."""
        home = next((node for node in root.iterate() if node.name == "GoHome"), None)
        if home is None or home.status not in (Status.SUCCESS, Status.FAILURE):
            return None
        return "came home" if home.status == Status.SUCCESS else f"gave up: {home.feedback_message}"

    def _identity(self, verdict: str) -> dict[str, Any]:
        """What the runner itself knows of every run, flown or not: the rest is measured by observers."""
        return {
            "verdict": verdict,
            "mission": self.mission.name,
            "seed": self.mission.model.seed,
            "plugins": {kind: choice.plugin for kind, choice in self.mission.backends.items()},
            # "completed" says the mission's tree ran to its end; this says whether the building was done
            # ("complete: no reachable frontier left") or given up ("stopped: 8 goals in a row
            # unreachable"), which a flight compared by its verdict alone would hide
            **({"exploration_end": self._exploration_end} if self._exploration_end else {}),
            # nor does it say the vehicle came home: a way home given up lands it where it is
            **({"way_home": self._way_home} if self._way_home else {}),
        }

    def _measured(self, metrics: dict[str, Any], summary: RunSummary) -> dict[str, Any]:
        """``metrics`` with every ``amslam_run_metrics`` answer merged in; the first to give a key keeps it.

        The figures come back as the hooks' return values rather than the runner reading the files
        its observers wrote: the kernel then depends on no application's file layout, a disabled or
        failing report leaves exactly the runner's own metrics, and several observers (the report,
        a third party's figures) each add theirs without one silencing the others, which a
        ``firstresult`` hook would do. Nobody overrides the verdict: the runner's keys come first.
        """
        merged = dict(metrics)
        for plugin, answer in self._hook("amslam_run_metrics", summary=summary):
            if not isinstance(answer, dict):
                if answer is not None:
                    self._observer_failed(
                        "amslam_run_metrics", plugin, f"returned {type(answer).__name__}, not a dict"
                    )
                continue
            taken = sorted(str(key) for key in answer if key in merged)
            if taken:
                self._observer_failed(
                    "amslam_run_metrics",
                    plugin,
                    f"metrics {', '.join(taken)} already given; the earlier kept",
                )
            merged.update({key: value for key, value in answer.items() if key not in merged})
        return merged

    def _write_metrics(self, metrics: dict[str, Any]) -> dict[str, Any]:
        """``metrics.json``, atomically (a full disk leaves the previous one); ``metrics`` back."""
        try:
            self.rundir.write_json("metrics.json", metrics)
        except (
            OSError,
            TypeError,
            ValueError,
        ) as exc:  # the run still ends: backends closed, verdict returned
            self.rundir.event(self._now(), "metrics_not_written", error=f"{type(exc).__name__}: {exc}")
            self._write_errors.append(f"metrics.json: {type(exc).__name__}: {exc}")
        return metrics

    def _keep_what_can_be_kept(self, verdict: str, metrics: dict[str, Any]) -> None:
        """After the outputs failed (a full disk, a broken summary): metrics.json with the verdict
        and the error, and a report saying so — each written atomically, or not at all."""
        report = (
            f"# {self.mission.name}\n\n**Verdict:** {verdict}\n\n"
            f"The run's outputs could not all be written: {metrics['outputs_error']}. "
            "The streams (events.jsonl, trajectories) hold what was recorded.\n"
        )
        for name, text in (
            ("metrics.json", json.dumps(jsonable(metrics), indent=2, default=str) + "\n"),
            ("report.md", report),
        ):
            if name == "report.md" and (self.rundir.path / name).exists():
                continue  # the full report was written: keep it
            try:
                write_atomically(self.rundir.path / name, text)
            except OSError as exc:
                self.rundir.event(self._now(), "write_failed", file=name, error=f"{exc.strerror or exc}")

    def _summary(self, verdict: str) -> RunSummary:
        """The run as the run-end observers see it (the threads have stopped)."""
        summary = RunSummary(self.mission, self.rundir.path, verdict)
        platform, slam, mapping = (self.backends.get(k) for k in ("platform", "slam", "mapping"))
        if platform is None:
            return summary
        runtime = self.runtime
        flown = {}
        if runtime is not None:
            perception = runtime.perception
            flown = dict(
                distance_m=perception.distance,
                truth=tuple(perception.truth),
                vio=tuple(perception.vio),
                samples={k: tuple(v) for k, v in perception.samples.items()},
                slc_log=tuple(runtime.planning.slc_log),
                home_world=runtime.robot.home_world,
            )
            if not platform.simulated:
                flown["pipeline"] = {
                    **perception.health.figures(),
                    "plan_latency": list(runtime.planning.plan_latency),
                }
        ask = self._ask
        check = self.boundary
        if slam is not None:
            flown.update(
                landmarks=ask("slam", "object_map()", lambda: tuple(slam.object_map())),
                keyposes=ask("slam", "keyposes()", lambda: tuple(slam.keyposes())),
                slam_optimises=implementation(slam).__name__ != "OdometrySlam",
                final_T_world_odom=ask(
                    "slam",
                    "T_world_odom()",
                    lambda: check.pose("slam", "T_world_odom()", slam.T_world_odom()),
                ),
            )
        vio = flown.get("vio") or ()
        final_vio = ask("platform", "odometry()", lambda: check.odometry(platform.odometry()).T_odom_body)
        return dataclasses.replace(
            summary,
            duration_s=ask("platform", "time()", platform.time),
            world=ask("platform", "world_summary()", platform.world_summary),
            status=ask("platform", "status()", platform.status),
            final_truth=ask("platform", "ground_truth()", platform.ground_truth),
            final_vio=final_vio if final_vio is not None else (vio[-1][1] if vio else None),
            robot_radius=self.context.robot.radius if self.context is not None else None,
            mapping=mapping,
            **flown,
        )

    def _ask(self, kind: str, call: str, fn: Callable[[], Any]) -> Any:
        """What a backend says for the summary; None (and an event) when it fails to say it: a
        backend that broke the run must not cost the run's report."""
        try:
            with self.boundary.calling(kind, call):
                return fn()
        except Exception as exc:  # noqa: BLE001 — the summary goes on without this value
            self.rundir.event(self._now(), "summary_incomplete", backend=kind, error=str(exc))
            return None


@dataclass
class Runtime:
    """The services of one flight, built by :meth:`Runner._start_runtime`, all on the control thread."""

    perception: Perception
    planning: PlanningService
    robot: Robot
    tree: py_trees.trees.BehaviourTree
    recorder: TreeRecorder
    measurements: MeasurementLog
    #: the mapping backend behind its lock, as the run-event observers may query it
    mapping: Mapping

    def close(self) -> None:
        """Stop the detector, mapper, planner and path threads, close the streams."""
        self.perception.close()
        self.planning.close()
        if self.robot.path_thread is not None:
            self.robot.path_thread.shutdown(wait=True, cancel_futures=True)
        self.recorder.close()
        self.measurements.close()
