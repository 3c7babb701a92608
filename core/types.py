"""Plain data that crosses backend boundaries.

Only numpy arrays, Python scalars and small frozen dataclasses live here: no backend's own
objects (no ``gtsam.Pose3``, no Open3D tensor) ever appear in an interface signature.

Frames and conventions (see docs/architecture.md):

* **world** — the SLAM frame: global map, semantic map, planner, tour. ENU, z up.
* **odom** — the VIO frame: local map, trajectory tracking, setpoints. ENU, z up.
* **body** — FLU: x forward, y left, z up.
* **camera** — optical: z forward, x right, y down.

Poses are 4×4 homogeneous numpy arrays ``T_a_b`` mapping points in frame *b* into frame *a*.
Yaw is in radians in (-π, π]. Units are SI.
"""

from __future__ import annotations

import math
from collections.abc import Mapping as MappingOf
from dataclasses import dataclass, field
from enum import Enum, StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

if TYPE_CHECKING:
    from amslam.interfaces import Mapping
    from amslam.mission import Mission

#: Fixed rotation from the camera optical frame to the body frame (camera looks along body +x).
R_BODY_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class VoxelState(int, Enum):
    """Occupancy state of a voxel as reported by a mapping backend."""

    UNKNOWN = -1
    FREE = 0
    OCCUPIED = 1


@dataclass(frozen=True)
class CameraModel:
    """A pinhole depth camera rigidly mounted on the body.

    Attributes:
        width: image width in pixels.
        height: image height in pixels.
        K: 3×3 intrinsic matrix.
        T_body_cam: 4×4 pose of the camera optical frame in the body frame.
        min_range: closest valid depth in metres.
        max_range: farthest valid depth in metres.
        rate_hz: frame rate the platform delivers.
        depth_noise: the std of a depth reading is ``depth_noise·z²`` (m; a stereo camera's
            noise, 0.005 for the simulated D435i-like camera; 0: not modelled). Box fits take
            their extents past it (:func:`amslam.lib.shapes.depth_noise`).
    """

    width: int
    height: int
    K: np.ndarray
    T_body_cam: np.ndarray
    min_range: float = 0.3
    max_range: float = 5.0
    rate_hz: float = 10.0
    depth_noise: float = 0.0

    @staticmethod
    def from_fov(
        width: int,
        height: int,
        hfov_deg: float,
        vfov_deg: float,
        *,
        min_range: float = 0.3,
        max_range: float = 5.0,
        rate_hz: float = 10.0,
        T_body_cam: np.ndarray | None = None,
        depth_noise: float = 0.0,
    ) -> CameraModel:
        """Build a camera from its resolution and fields of view (degrees)."""
        fx = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        fy = (height / 2.0) / np.tan(np.radians(vfov_deg) / 2.0)
        K = np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        if T_body_cam is None:
            T_body_cam = CameraModel.forward_mount()
        return CameraModel(width, height, K, T_body_cam, min_range, max_range, rate_hz, depth_noise)

    @staticmethod
    def forward_mount(
        pitch_deg: float = 0.0, offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ) -> np.ndarray:
        """``T_body_cam`` of a camera looking along body +x, tilted down by ``pitch_deg``."""
        p = np.radians(pitch_deg)
        tilt = np.array([[np.cos(p), 0.0, np.sin(p)], [0.0, 1.0, 0.0], [-np.sin(p), 0.0, np.cos(p)]])
        T = np.eye(4)
        T[:3, :3] = tilt @ R_BODY_CAM
        T[:3, 3] = offset
        return T

    @property
    def hfov(self) -> float:
        """Horizontal field of view in radians."""
        return 2.0 * float(np.arctan((self.width / 2.0) / self.K[0, 0]))

    @property
    def vfov(self) -> float:
        """Vertical field of view in radians."""
        return 2.0 * float(np.arctan((self.height / 2.0) / self.K[1, 1]))


@dataclass(frozen=True)
class Odometry:
    """A VIO estimate of the body pose in the odometry frame."""

    stamp: float
    T_odom_body: np.ndarray


@dataclass(frozen=True)
class Frame:
    """One RGB-D capture.

    Attributes:
        stamp: capture time in seconds (platform clock).
        depth: H×W float32 depth along the optical axis in metres; 0 means no return.
        K: 3×3 intrinsics of this image.
        T_odom_cam: VIO pose of the camera at capture time.
        rgb: H×W×3 uint8 image, if the platform renders one.
        instance: H×W int32 instance ids (0 = background), simulator only.
        class_id: H×W int32 class ids (0 = background), simulator only.
        class_names: names of the class ids, index 0 unused.
        T_world_cam_truth: ground-truth camera pose, simulator only.
    """

    stamp: float
    depth: np.ndarray
    K: np.ndarray
    T_odom_cam: np.ndarray
    rgb: np.ndarray | None = None
    instance: np.ndarray | None = None
    class_id: np.ndarray | None = None
    class_names: tuple[str, ...] = ()
    T_world_cam_truth: np.ndarray | None = None


@dataclass(frozen=True)
class Detection:
    """One object seen in one frame, already lifted to 3-D.

    Attributes:
        class_name: semantic class, e.g. ``"chair"``.
        confidence: classification confidence in [0, 1].
        centroid_cam: robust centroid of the object's surface points in the camera frame.
        points_cam: N×3 object points in the camera frame (for shape fitting), may be empty.
    """

    class_name: str
    confidence: float
    centroid_cam: np.ndarray
    points_cam: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


@dataclass(frozen=True)
class BoundingBox:
    """Axis-aligned box, ``lo`` and ``hi`` corners in metres."""

    lo: np.ndarray
    hi: np.ndarray

    @property
    def empty(self) -> bool:
        return bool(np.any(self.hi < self.lo))

    @staticmethod
    def nothing() -> BoundingBox:
        return BoundingBox(np.full(3, np.inf), np.full(3, -np.inf))

    def flyable(self, radius: float) -> BoundingBox:
        """Where a robot of ``radius`` may have its centre inside this box as a flight bound: its
        body inside every face but the floor (it stands on the floor; an open-topped building is
        explored inside, not over its walls)."""
        return BoundingBox(
            np.asarray(self.lo, float) + np.array([radius, radius, -np.inf]),
            np.asarray(self.hi, float) - radius,
        )

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Which of the points (N×3) lie inside, faces included."""
        p = np.asarray(points, float)
        return np.all((p >= self.lo) & (p <= self.hi), axis=-1)


@dataclass(frozen=True)
class Viewpoint:
    """A place to look from, covering one frontier cluster.

    Attributes:
        id: stable within one mapping backend while its cluster lives.
        position: world-frame position of the body.
        yaw: heading in radians.
        gain: information gain — unknown volume (m³) expected to be seen.
        cluster_centroid: centroid of the frontier cluster it covers.
        cluster_size: number of frontier voxels in that cluster.
        alternatives: other places to look at the same cluster from (same id), best gain first,
            each without alternatives of its own. The best view of a cluster may be out of reach
            (the camera looks level, so a cluster above a shaft is best seen from the floor above,
            which the robot reaches only once the way up was seen free); a planner then looks from
            the best alternative it can reach.
    """

    id: int
    position: np.ndarray
    yaw: float
    gain: float
    cluster_centroid: np.ndarray
    cluster_size: int
    alternatives: tuple[Viewpoint, ...] = ()

    def options(self) -> tuple[Viewpoint, ...]:
        """This viewpoint, then its alternatives."""
        return (self, *self.alternatives)


@dataclass(frozen=True)
class KeyPose:
    """An optimised key pose of the SLAM graph."""

    id: int
    stamp: float
    T_world_body: np.ndarray
    distance: float  # odometry distance travelled when the key pose was created


@dataclass(frozen=True)
class Landmark:
    """An object landmark of the semantic map (world frame)."""

    id: int
    class_name: str
    position: np.ndarray
    covariance: np.ndarray
    observations: int
    first_keypose: int = -1
    shape: dict | None = None  # model-specific parameters (cuboid, cylinder), see paper 2
    #: the object's class posterior from its detections' class scores (class → probability, the
    #: classes the map has seen; paper 2's per-object class probability), or None if not kept
    class_probabilities: dict[str, float] | None = None


@dataclass(frozen=True)
class LoopClosureResult:
    """Outcome of one semantic loop-closure attempt."""

    accepted: bool
    reason: str
    matched: int = 0
    residual: float = float("nan")
    yaw_correction: float = 0.0
    translation_correction: float = 0.0


@dataclass(frozen=True)
class SlcCandidate:
    """A place to revisit for a semantic loop closure (paper 1 §VI-C)."""

    keypose_id: int
    position: np.ndarray
    yaw: float
    landmark_ids: tuple[int, ...]
    info_gain: float = 0.0


@dataclass(frozen=True)
class OdometryNoise:
    """A VIO's relative-pose noise: random walks in the distance travelled (std ∝ √distance).

    The SLAM backend's odometry factors and the planner's virtual ones (eq. 10) use the same
    numbers, so what a planned loop closure is predicted to remove is what flying it would.
    """

    translation: float  # horizontal, m/√m travelled
    vertical: float  # m/√m travelled
    translation_min: float  # floor, m
    yaw: float  # rad/√m travelled
    yaw_per_rad: float  # rad per radian turned
    yaw_min: float  # floor, rad
    roll_pitch: float  # rad (the IMU observes them)

    def sigmas(self, distance: float, dyaw: float) -> np.ndarray:
        """Stds over ``distance`` metres turning ``dyaw`` radians, in gtsam's Pose3 tangent order
        (roll, pitch, yaw, x, y, z)."""
        return self.sigmas_of_steps(np.array([distance], float), np.array([dyaw], float))[0]

    def sigmas_of_steps(self, distances: np.ndarray, dyaws: np.ndarray) -> np.ndarray:
        """:meth:`sigmas` of many steps at once: ``(n, 6)`` for ``n`` distances and turns."""
        root = np.sqrt(np.maximum(0.0, np.asarray(distances, float)))
        st = np.maximum(self.translation_min, self.translation * root)
        sz = np.maximum(self.translation_min, self.vertical * root)
        sy = np.maximum(self.yaw_min, self.yaw * root + self.yaw_per_rad * np.abs(np.asarray(dyaws, float)))
        rp = np.full_like(st, self.roll_pitch)
        return np.stack([rp, rp, sy, st, st, sz], axis=1)

    def drift_to_end(
        self, positions: np.ndarray, yaws: np.ndarray, distances: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """How far the last pose of a path may have drifted relative to each earlier pose of it.

        The odometry chains one step per consecutive pair of poses (``positions`` (n, 3), world
        ``yaws`` and travelled ``distances``, n of each). Propagated to first order, the step into
        pose k adds its translation noise to the end, and its yaw noise rotates the rest of the
        path about pose k, moving the end by ``δψ · |p_end − p_k|`` (horizontally): over a long
        path in a small building the end's error grows like √travel, not like the travel.

        Returns:
            Per pose j, the variance of the end's position relative to pose j (m², summed over the
            three axes) and of its yaw (rad²); zero for the end itself.
        """
        positions = np.asarray(positions, float).reshape(-1, 3)
        steps = self.sigmas_of_steps(
            np.diff(np.asarray(distances, float)), np.diff(np.unwrap(np.asarray(yaws, float)))
        )
        lever_sq = np.sum((positions[-1, :2] - positions[1:, :2]) ** 2, axis=1)
        position_step = steps[:, 3] ** 2 + steps[:, 4] ** 2 + steps[:, 5] ** 2 + steps[:, 2] ** 2 * lever_sq
        yaw_step = steps[:, 2] ** 2

        def after(step: np.ndarray) -> np.ndarray:  # Σ over the steps after pose j
            return np.append(np.cumsum(step[::-1])[::-1], 0.0)

        return after(position_step), after(yaw_step)


@dataclass(frozen=True)
class PoseUncertainty:
    """How well the robot knows where it is, as its SLAM backend sees it when a plan is asked for:
    what a planner keeping the robot's localisation uncertainty within a bound needs (paper 2
    §IV-D), without the factor graph.

    Attributes:
        position_covariance: (3, 3) marginal covariance of the latest key pose's position, world
            frame, m².
        odometry: how it grows with the distance flown until a measurement corrects it.
    """

    position_covariance: np.ndarray
    odometry: OdometryNoise

    def __post_init__(self) -> None:
        if np.shape(self.position_covariance) != (3, 3):
            raise ValueError(
                f"PoseUncertainty: position covariance {np.shape(self.position_covariance)}, expected (3, 3)"
            )

    @property
    def position_std(self) -> float:
        """The std along the worst-known direction, m (the largest eigenvalue's root)."""
        return float(np.sqrt(max(0.0, float(np.linalg.eigvalsh(self.position_covariance)[-1]))))

    def reach(self, max_std: float) -> float:
        """How far the robot may fly before its std passes ``max_std``, m (0 when it already has):
        with no correction on the way the odometry's horizontal random walk adds
        ``translation² · distance`` to the worst direction's variance."""
        room = max_std**2 - self.position_std**2
        if room <= 0.0:
            return 0.0
        rate = self.odometry.translation**2
        return math.inf if rate <= 0.0 else room / rate


@dataclass(frozen=True)
class SlcGainModel:
    """What eq. (10) needs to score a *sequence* of loop closures without the factor graph.

    Algorithm 1 of paper 1 re-estimates each candidate's gain given the loop closures already in
    the refined tour (line 6). Every virtual odometry factor of such a chain joins two of the
    poses ``S`` = {current key pose, candidate key poses}, so the joint covariance of ``S`` and
    ``Σ_{S,V} Σ_{V,S}`` (V: the variables whose trace eq. 10 measures) give the trace reduction
    of any chain exactly (Woodbury; :func:`amslam.lib.slc_gain.chain_gain`).

    Attributes:
        keypose_ids: the current key pose first, then each candidate key pose once.
        poses: (n, 4, 4) their estimates, world frame.
        covariance: (6n, 6n) their joint covariance Σ_SS, gtsam's Pose3 tangent order per pose.
        gram: (6n, 6n) Σ_{S,V} Σ_{V,S}.
        odometry: the noise of a virtual odometry factor over a travelled distance.
    """

    keypose_ids: tuple[int, ...]
    poses: np.ndarray
    covariance: np.ndarray
    gram: np.ndarray
    odometry: OdometryNoise

    def __post_init__(self) -> None:
        n = len(self.keypose_ids)
        if len(set(self.keypose_ids)) != n:
            raise ValueError(f"SlcGainModel: key pose ids repeat: {self.keypose_ids}")
        if np.shape(self.poses) != (n, 4, 4):
            raise ValueError(
                f"SlcGainModel: poses {np.shape(self.poses)} for {n} key poses, expected ({n}, 4, 4)"
            )
        for name in ("covariance", "gram"):
            if np.shape(getattr(self, name)) != (6 * n, 6 * n):
                raise ValueError(
                    f"SlcGainModel: {name} {np.shape(getattr(self, name))} for {n} key poses, "
                    f"expected ({6 * n}, {6 * n})"
                )


class TourItemKind(StrEnum):
    EXPLORE = "explore"
    SLC = "slc"


@dataclass(frozen=True)
class TourItem:
    """One stop of the refined tour (world frame)."""

    kind: TourItemKind
    position: np.ndarray
    yaw: float
    gain: float
    ref: int  # viewpoint id for EXPLORE, key-pose id for SLC


@dataclass(frozen=True)
class PlanRequest:
    """Everything a planner needs, computed by the runner from the other backends.

    Attributes:
        start: world-frame position of the robot.
        start_yaw: current yaw.
        viewpoints: frontier viewpoints (index i ↔ row/column i+1 of ``costs``).
        costs: (N+1)×(N+1) path costs in metres; index 0 is the robot; ``inf`` = unreachable.
        slc_candidates: loop-closure candidates with their predicted information gain.
        slc_costs: (C)×(N+1) path cost from each candidate to the robot and each viewpoint.
        slc_gain: the SLAM backend's model for scoring chains of loop closures (eq. 10 given the
            tour so far); None when the backend has none (each candidate's own ``info_gain`` then).
        camera: the camera model, for field-of-view overlap.
        landmarks: the SLAM backend's current object map (world frame), for planners that plan
            views of known objects (paper 2's PAMS) rather than of frontiers.
        pose_uncertainty: the robot's localisation uncertainty, for planners that ask for it
            (``Planner.needs_pose_uncertainty``) from a backend that has one; None otherwise.
        goal: world position of the exploration goal the robot was flying to and had not reached
            when this plan was asked for (the tour went stale, or the frontiers changed, on the
            way); None otherwise. A planner may keep it first, so that plans made every few
            seconds from a moving robot do not send it back and forth between far viewpoints.
    """

    start: np.ndarray
    start_yaw: float
    viewpoints: tuple[Viewpoint, ...]
    costs: np.ndarray
    camera: CameraModel
    slc_candidates: tuple[SlcCandidate, ...] = ()
    slc_costs: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    slc_gain: SlcGainModel | None = None
    landmarks: tuple[Landmark, ...] = ()
    pose_uncertainty: PoseUncertainty | None = None
    goal: np.ndarray | None = None


@dataclass(frozen=True)
class RobotSpec:
    """The vehicle's size and motion limits, from the mission's ``robot`` section."""

    radius: float = 0.25
    max_speed: float = 1.0
    max_acceleration: float = 1.5
    max_yaw_rate: float = 1.0
    altitude: float = 1.2  # take-off height above the start, metres
    clearance: float = 0.15  # extra distance paths keep from obstacles, metres

    @property
    def planning_radius(self) -> float:
        """The radius paths are planned with: the robot plus a margin for tracking error."""
        return self.radius + self.clearance


@dataclass(frozen=True)
class VehicleStatus:
    """What the platform says about the vehicle."""

    armed: bool
    airborne: bool
    crashed: bool = False
    crash_reason: str = ""
    #: the smallest distance from the vehicle's centre to any geometry so far while cruising
    #: (after take-off, before landing), with what and where it was: known only in simulation
    closest_approach: float | None = None
    closest_to: str = ""
    closest_position: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class WorldSummary:
    """Ground truth about a simulated world, for metrics (None on a real vehicle).

    ``floor_heights`` are the z of each floor's slab (ascending); floor i spans
    [floor_heights[i], floor_heights[i+1]) and the last floor up to ``bounds_hi[2]``.
    """

    name: str
    bounds_lo: np.ndarray
    bounds_hi: np.ndarray
    reachable_free_volume: float
    floor_heights: tuple[float, ...]
    reachable_free_volume_per_floor: tuple[float, ...]
    objects_by_class: dict[str, int]
    object_positions: dict[str, np.ndarray] = field(default_factory=dict)
    object_classes: dict[str, str] = field(default_factory=dict)
    #: centres of the reachable free cells (M×3) on a grid of ``reachable_cell`` metres: free
    #: space connected to the start. Explored % = share of these a map knows (free or occupied).
    reachable_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    reachable_cell: float = 0.25
    #: true shape of each object id, for objects a class models as a shape (paper 2): a dict with
    #: ``model`` ("cuboid" | "cylinder") and that model's parameters, same keys as
    #: :attr:`Landmark.shape`.
    object_shapes: dict[str, dict] = field(default_factory=dict)


FailsafeAction = Literal["land", "return_and_land", "hand_over"]


@dataclass(frozen=True)
class Failsafe:
    """A condition that ends the mission, and what the tree does about it (real vehicles).

    Attributes:
        kind: ``link_lost``, ``geofence``, ``low_battery``, ``critical_battery``,
            ``command_refused``, ``mode_changed`` (the vehicle or its pilot left offboard).
        reason: one sentence for the operator.
        action: ``land`` here, ``return_and_land`` over the take-off point, or ``hand_over``:
            send nothing and wait for the vehicle (or its pilot) to land.
        t: platform time it was raised.
    """

    kind: str
    reason: str
    action: FailsafeAction = "land"
    t: float = 0.0


@dataclass(frozen=True)
class RunSummary:
    """What a finished run hands to its run-end observers (``amslam_run_metrics``, ``amslam_run_end``;
    the report is one).

    Built once, on every exit path, after the threads have stopped. Figures of the vehicle
    (``status``, the final poses) are None when the run failed before the platform started.

    Attributes:
        mission: the validated mission as flown (name, seed, backend choices).
        run_dir: the run folder.
        verdict: ``completed``, ``crashed: …``, ``aborted`` or ``failed: …``.
        duration_s: platform time at the end (simulated or wall-clock seconds).
        distance_m: distance travelled by VIO.
        truth, vio: ``(t, T_odom_body)`` at the trajectory rate (truth: simulation only).
        samples: ``"uncertainty"``: ``(t, distance, mean pose trace, mean landmark trace)``;
            ``"explored"``: ``(t, distance, explored m³)``.
        slc_log: ``(t, distance, result)`` of every loop-closure attempt.
        landmarks, keyposes: the SLAM backend's final semantic map and key poses.
        slam_optimises: whether the SLAM backend optimises key poses (its ``slam.tum`` is
            rewritten from them), False for the odometry baseline.
        world: ground truth of a simulated world.
        status: the vehicle's last status (closest approach, crash).
        final_truth, final_vio, final_T_world_odom: the last true pose, VIO pose and SLAM correction.
        robot_radius: the robot's radius, m.
        home_world: the take-off point in the world frame.
        mapping: the mapping backend, for the explored share and the map files; read it only
            after the flight, as the report does.
        pipeline: a real vehicle's camera pipeline (None in the simulator): frame counts
            (``frames``, ``mapped``, ``skipped_by_mapper``, ``detected``) and latency samples in
            seconds from a frame's stamp (``local_latency``, ``global_latency``,
            ``detection_latency``) and from a plan's snapshot to its adoption (``plan_latency``).
    """

    mission: Mission
    run_dir: Path
    verdict: str
    duration_s: float | None = None
    distance_m: float = 0.0
    truth: tuple[tuple[float, np.ndarray], ...] = ()
    vio: tuple[tuple[float, np.ndarray], ...] = ()
    samples: MappingOf[str, tuple] = field(default_factory=lambda: {"uncertainty": (), "explored": ()})
    slc_log: tuple[tuple[float, float, LoopClosureResult], ...] = ()
    landmarks: tuple[Landmark, ...] | None = None
    keyposes: tuple[KeyPose, ...] = ()
    slam_optimises: bool = False
    world: WorldSummary | None = None
    status: VehicleStatus | None = None
    final_truth: np.ndarray | None = None
    final_vio: np.ndarray | None = None
    final_T_world_odom: np.ndarray | None = None
    robot_radius: float | None = None
    home_world: np.ndarray | None = None
    mapping: Mapping | None = None
    pipeline: MappingOf[str, Any] | None = None

    @property
    def trajectory(self) -> np.ndarray:
        """True positions (N×3) along the flight: what ``amslam_run_end`` observers always got."""
        return np.array([T[:3, 3] for _, T in self.truth]).reshape(-1, 3)
