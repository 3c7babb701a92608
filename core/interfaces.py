"""One abstract base per backend kind, Nav2-style.

Every backend has the same lifecycle:

1. the factory returned by a ``amslam_<kind>_backends`` hook is called with no arguments;
2. ``configure(params, context)`` receives the backend's own validated ``Params`` model and the
   run's :class:`RunContext`; no hardware, network or heavy work happens before this;
3. work methods are called by the runner;
4. ``close()`` releases everything, and is safe to call twice.

Each backend declares ``Params``: a pydantic model (``extra="forbid"``) of its parameters with
defaults and descriptions. The mission's section for the backend is validated against it
(``amslam validate``) and ``amslam dump-config KIND PLUGIN`` prints it.
"""

from __future__ import annotations

import abc
import importlib.util
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationInfo

from amslam.types import (
    BoundingBox,
    CameraModel,
    Detection,
    Failsafe,
    Frame,
    KeyPose,
    Landmark,
    LoopClosureResult,
    Odometry,
    PlanRequest,
    PoseUncertainty,
    RobotSpec,
    SlcCandidate,
    SlcGainModel,
    TourItem,
    VehicleStatus,
    Viewpoint,
    VoxelState,
    WorldSummary,
)


class BackendParams(BaseModel):
    """Base of every backend's parameter model: unknown keys are errors, and so is a number that
    is not finite (NaN, inf) anywhere in it (pydantic's ``allow_inf_nan=False``). Every number
    also has a stated range (``Field(ge=, le=)``), so a value that validates is one a run can use."""

    # defer_build: the validator is built when the model first validates; every command imports
    # every plugin's models and most of them never validate (0.03 s of `amslam --help`)
    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)


#: a coordinate in metres: finite and within 10 km of the origin (a building, a site; not a country)
Coordinate = Annotated[float, Field(ge=-10_000, le=10_000)]
Point = tuple[Coordinate, Coordinate, Coordinate]


class FieldError(ValueError):
    """A cross-field rule broken, raised in a ``model_validator``: ``field`` (a dotted path inside
    the model) is where ``amslam validate`` points, rather than at the whole section."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


def lo_below_hi(lo: tuple[float, ...], hi: tuple[float, ...], axes: str = "xyz") -> None:
    """Raise ValueError unless ``lo`` is below ``hi`` on every axis (a box, a geofence, a range)."""
    bad = [axis for axis, a, b in zip(axes, lo, hi, strict=False) if not a < b]
    if bad:
        raise FieldError(
            "hi", f"{list(hi)} must be above lo {list(lo)} on every axis; it is not on {', '.join(bad)}"
        )


def mission_file_path(value: str, info: ValidationInfo | None = None) -> Path:
    """Where a file a mission names is: absolute, or relative to the mission's folder (the
    ``mission_dir`` of the validation context, else the working directory)."""
    path = Path(value).expanduser()
    if not path.is_absolute():
        base = ((info.context or {}) if info is not None else {}).get("mission_dir")
        path = Path(base) / path if base is not None else path
    return path


def check_mission_file(value: str | None, info: ValidationInfo) -> str | None:
    """A file a mission names, checked: present and readable (see :data:`MissionFile`)."""
    if value is None:
        return value
    context = info.context or {}
    path = mission_file_path(value, info)
    if not path.is_absolute() and "mission_dir" not in context:
        return value  # no mission folder to resolve against: checked when the backend configures
    if not path.exists():
        raise ValueError(f"no such file: {path}")
    if not path.is_file():
        raise ValueError(f"not a regular file: {path}")
    if not os.access(path, os.R_OK):
        raise ValueError(f"cannot read {path}: permission denied")
    return value


#: a file a mission names (a mesh, an objects file, a model, a prior map): relative to the mission
#: file, and present and readable when the mission is validated (``amslam validate`` names it)
MissionFile = Annotated[str, AfterValidator(check_mission_file)]


@dataclass
class RunContext:
    """What the runner hands every backend at configure time.

    Attributes:
        rng: the backend's own generator, spawned from the mission seed.
        run_dir: the run folder (backends may write extra artefacts there).
        emit: ``emit(event_name, **fields)`` appends to ``events.jsonl``.
        camera: the platform's camera (None while the platform itself is configured).
        world: ground truth of a simulated world: handed only to the simulator's own backends
            (:attr:`Backend.simulator`); None for every other backend, and on a real vehicle.
        robot: size and motion limits of the vehicle.
        area: the region to explore (world frame); frontiers outside it are ignored.
        mission_dir: folder of the mission file, for resolving relative paths.
        extras: anything a plugin-specific integration needs (kept small).
    """

    rng: np.random.Generator
    run_dir: Path
    emit: Callable[..., None] = lambda *a, **k: None
    camera: CameraModel | None = None
    world: WorldSummary | None = None
    robot: RobotSpec = field(default_factory=RobotSpec)
    area: BoundingBox | None = None
    mission_dir: Path = field(default_factory=Path.cwd)
    extras: dict[str, Any] = field(default_factory=dict)


class Backend(abc.ABC):  # noqa: B024 — the lifecycle methods are optional
    """Lifecycle shared by all backend kinds."""

    Params: ClassVar[type[BackendParams]] = BackendParams
    #: top-level Python modules the backend imports when it is built (heavy libraries are imported
    #: lazily, so listing the plugin or validating a mission does not); a mission choosing the
    #: backend is refused when one is not installed, before anything flies
    requires: ClassVar[tuple[str, ...]] = ()
    #: on a real vehicle, run the backend in a process of its own (:mod:`amslam.backend_process`):
    #: for backends whose library calls hold the interpreter lock long enough to delay the
    #: control loop (a SLAM graph's marginals). Only SLAM backends can run so today.
    own_process: ClassVar[bool] = False
    #: part of the simulator (its platform, its detector): the only backends handed the simulated
    #: world's ground truth (``RunContext.world``). Every other backend is configured with
    #: ``world=None`` in simulation too, as on a real vehicle, so nothing a real robot could not
    #: know reaches mapping, SLAM or planning (``tests/e2e/test_ground_truth_withheld.py``).
    simulator: ClassVar[bool] = False

    def configure(self, params: BackendParams, context: RunContext) -> None:  # noqa: B027
        """Receive validated parameters and the run context."""

    def close(self) -> None:  # noqa: B027
        """Release resources. Safe to call twice."""


def missing_modules(names: Sequence[str]) -> list[str]:
    """The top-level modules among ``names`` that are not installed (looked up, not imported)."""
    missing = []
    for name in names:
        try:
            found = importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):  # ValueError: sys.modules holds None for it (blocked)
            found = False
        if not found:
            missing.append(name)
    return missing


class Platform(Backend):
    """The vehicle: the built-in simulator or a real one.

    Setpoints are in the odometry frame. The runner owns the clock: for a simulated platform
    ``advance(dt)`` integrates the world by ``dt`` seconds of simulated time; for a real one it
    waits until ``dt`` of wall-clock time has passed.
    """

    simulated: ClassVar[bool] = True

    @property
    @abc.abstractmethod
    def camera(self) -> CameraModel:
        """The depth camera (valid after configure)."""

    @abc.abstractmethod
    def start(self) -> None:
        """Connect (real) or build the world (simulated). Called once before the first tick."""

    @abc.abstractmethod
    def time(self) -> float:
        """Platform clock in seconds since start."""

    @abc.abstractmethod
    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds pass (see class docstring)."""

    @abc.abstractmethod
    def odometry(self) -> Odometry:
        """The latest VIO estimate."""

    @abc.abstractmethod
    def capture(self) -> Frame | None:
        """A new RGB-D frame if one is due at the current time, else None."""

    @abc.abstractmethod
    def set_setpoint(self, position_odom: np.ndarray, yaw: float) -> None:
        """Fly towards a position (odometry frame) and heading."""

    @abc.abstractmethod
    def arm_and_takeoff(self, altitude: float) -> None:
        """Arm and climb to ``altitude`` above the start; idempotent."""

    @abc.abstractmethod
    def land(self) -> None:
        """Descend and disarm at the current place; idempotent."""

    @abc.abstractmethod
    def status(self) -> VehicleStatus:
        """Armed / airborne / crashed."""

    def ground_truth(self) -> np.ndarray | None:
        """True ``T_world_body`` (simulator only)."""
        return None

    def world_summary(self) -> WorldSummary | None:
        """Ground truth about the world for metrics (simulator only)."""
        return None

    def failsafe(self) -> Failsafe | None:
        """The condition that must end the mission now (link lost, battery, geofence, ...), latched
        once raised; None while all is well. The simulator never raises one."""
        return None


class Mapping(Backend):
    """Volumetric occupancy mapping: a global world-frame map and a local odometry-frame map."""

    #: True when the local map's calls (``integrate_local``, ``plan_local_path`` and ``states``,
    #: ``segment_free``, ``blocked`` with ``local=True``) read and write no state the other calls
    #: touch. On a real vehicle the runtime then lets the control thread fly by the local map while
    #: the mapper thread updates the global map (docs/architecture.md, "Threads"); with the
    #: default False every call waits for the one lock, and a slow global update delays a tick.
    separate_local_map: ClassVar[bool] = False

    @abc.abstractmethod
    def integrate_global(self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> BoundingBox:
        """Fuse a depth image into the global map; return the box it touched."""

    @abc.abstractmethod
    def integrate_local(self, depth: np.ndarray, K: np.ndarray, T_odom_cam: np.ndarray) -> BoundingBox:
        """Fuse a depth image into the ego-centric local map; return the box it touched."""

    @abc.abstractmethod
    def states(self, points: np.ndarray, *, local: bool = False) -> np.ndarray:
        """``VoxelState`` values (int8) of the voxels holding ``points`` (N×3)."""

    @abc.abstractmethod
    def viewpoints(self) -> list[Viewpoint]:
        """Frontier viewpoints, updated incrementally since the last call."""

    @abc.abstractmethod
    def path_costs(self, sources: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """S×T path lengths (m) through known free space of the global map; inf if unreachable.

        A source is where a path starts: one the map shows inside an occupied voxel (the robot,
        after SLAM moved a surface it had integrated) may leave it to the nearest free space. A
        target must be free. So the matrix need not be symmetric where a point is both.
        """

    @abc.abstractmethod
    def plan_path(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Collision-free waypoints (K×3, world frame) from start to goal, or None."""

    def plan_path_along_trail(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Waypoints (K×3, world frame) from start to goal that follow the robot's own flown trail
        where the global map has no path, or None.

        The rules that keep paths off carved slabs and unseen rims may leave no way back through
        the map (a three-floor flight ended on the top floor, its map holding no way down); the
        way the robot came is free: it flew it. Optional: the default None (a backend that keeps
        no trail). The runtime asks for it only on the way home, after :meth:`plan_path` failed.
        """
        return None

    def rebuild_global(self, frames: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> bool:
        """Build the global map anew from ``(depth, K, T_world_cam)`` frames, on top of a loaded
        prior map; True when done.

        The runtime calls it when ``exploration.reanchor_map`` is on and SLAM corrected the
        odometry frame: surfaces integrated at poses a loop closure moved stand where the robot
        thought it was. Optional: the default False keeps the map as it is.
        """
        return False

    def plan_local_path(
        self, start: np.ndarray, goal: np.ndarray, *, margin: float = 1.0
    ) -> np.ndarray | None:
        """Collision-free waypoints (K×3, odometry frame) from start to goal on the fine local map,
        inside the box spanned by the two ends plus ``margin`` m, or None.

        The runtime flies round what blocks a global path this way (a detour that rejoins the
        path a few metres on). Optional: the default None makes it plan a new global path instead.
        """
        return None

    @abc.abstractmethod
    def segment_free(self, a: np.ndarray, b: np.ndarray, *, local: bool = False) -> bool:
        """Whether the straight segment, inflated by the robot radius, avoids occupied voxels."""

    def blocked(self, points: np.ndarray, *, local: bool = False, climbing: bool = False) -> np.ndarray:
        """Whether each point (N×3) lies in an obstacle: the setpoint filter's guards keep the
        vehicle off these. A backend may count unseen space it takes for part of a seen surface,
        and more of it for a climb (``climbing``: the camera looks level and never shows the
        ceiling overhead); the default: occupied voxels."""
        return self.states(points, local=local) == VoxelState.OCCUPIED

    @abc.abstractmethod
    def explored_volume(self) -> float:
        """Known (free or occupied) volume of the global map in m³."""

    def explored_volume_in(self, lo: np.ndarray, hi: np.ndarray) -> float:
        """Known volume of the global map inside a box, in m³."""
        raise NotImplementedError

    def free_volume_in(self, lo: np.ndarray, hi: np.ndarray) -> float:
        """Known free volume of the global map inside a box, in m³."""
        raise NotImplementedError

    @abc.abstractmethod
    def occupied_points(self) -> np.ndarray:
        """Centres of occupied global voxels (N×3)."""

    @abc.abstractmethod
    def voxel_size(self) -> float:
        """Edge of a global voxel in metres."""

    def save(self, path: Path) -> None:
        """Write the whole map to a compressed file."""
        raise NotImplementedError(f"{type(self).__name__} cannot save maps")

    def load(self, path: Path) -> None:
        """Load a map written by :meth:`save`."""
        raise NotImplementedError(f"{type(self).__name__} cannot load maps")


class Detector(Backend):
    """Object detection: a frame in, 3-D detections (camera frame) out."""

    rate_hz: float = 2.0

    @abc.abstractmethod
    def detect(self, frame: Frame) -> list[Detection]:
        """Objects in the frame, lifted to the camera frame with depth."""


class Slam(Backend):
    """Pose-graph SLAM: world-frame estimates from VIO and object detections."""

    @abc.abstractmethod
    def add_odometry(self, odom: Odometry) -> bool:
        """Feed a VIO pose; return True when a key pose was created."""

    @abc.abstractmethod
    def add_detections(self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]) -> None:
        """Feed detections made at the VIO pose ``odom``."""

    @abc.abstractmethod
    def T_world_odom(self) -> np.ndarray:
        """Current correction from the odometry frame to the world frame (drift compensation)."""

    @abc.abstractmethod
    def keyposes(self) -> list[KeyPose]:
        """Optimised key poses, oldest first."""

    @abc.abstractmethod
    def landmarks(self) -> list[Landmark]:
        """The semantic map."""

    def object_map(self) -> list[Landmark]:
        """The map of objects reported at the end of a run (``landmarks.json``, the metrics): by
        default :meth:`landmarks`; a backend may place each object better from all it saw (the
        gtsam backend: at the box fitted to all its points) than the points its graph needs."""
        return self.landmarks()

    def uncertainty(self) -> tuple[float, float]:
        """(mean pose covariance trace, mean landmark covariance trace)."""
        return (0.0, 0.0)

    def try_loop_closure(
        self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]
    ) -> LoopClosureResult:
        """Attempt a semantic loop closure with what is in view now.

        ``detections`` are seen *now*, at the VIO pose ``odom``, and were not fed before; a
        backend that closes loops adds them like :meth:`add_detections` would. Everything seen earlier (the
        panorama leading up to the attempt) was already fed through :meth:`add_detections` at
        the pose of its own frame, and must not be passed again: a detection handed over twice
        counts twice, the second time displaced by however far the robot moved or turned since.
        The runtime passes an empty list; a backend registers what it was fed recently.
        """
        return LoopClosureResult(False, f"{type(self).__name__} does not close loops")

    def slc_candidates(self, sensing_range: float) -> list[SlcCandidate]:
        """Loop-closure candidates (paper 1 §VI-C) with their information gain."""
        return []

    def information_gain(self, keypose_ids: list[int], travel_distances: list[float]) -> np.ndarray:
        """Eq. (10): trace reduction from a virtual factor to each key pose."""
        return np.zeros(len(keypose_ids))

    def slc_gain_model(self, keypose_ids: list[int]) -> SlcGainModel | None:
        """What scores chains of loop closures at ``keypose_ids`` from the current key pose (eq. 10
        given the closures already planned, Algorithm 1). None: the planner uses each candidate's
        own ``info_gain``."""
        return None

    def pose_uncertainty(self) -> PoseUncertainty | None:
        """The latest key pose's position covariance (world frame) and the odometry noise that
        grows it, for planners that keep the robot's localisation uncertainty within a bound
        (paper 2 §IV-D). None: the backend keeps no covariances (the odometry baseline)."""
        return None


class Planner(Backend):
    """Exploration planning: a tour over viewpoints (and loop-closure candidates)."""

    #: False for planners that plan views of known objects (``PlanRequest.landmarks``) rather than
    #: of frontiers: the robot then asks them for a tour even when no frontier viewpoint is left.
    needs_frontiers: bool = True
    #: True for planners that read ``PlanRequest.pose_uncertainty``: the runtime asks the SLAM
    #: backend for it (a marginal covariance) only for them.
    needs_pose_uncertainty: bool = False

    @abc.abstractmethod
    def plan(self, request: PlanRequest) -> list[TourItem]:
        """An ordered tour; empty when nothing is worth visiting."""


#: Backend kind name → its abstract base; the order is the order of configuration.
BACKEND_KINDS: dict[str, type[Backend]] = {
    "platform": Platform,
    "mapping": Mapping,
    "slam": Slam,
    "detector": Detector,
    "planner": Planner,
}
