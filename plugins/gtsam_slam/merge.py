"""Multi-robot map merging at the base (paper 2 §IV-B4, Fig. 5).

"Each robot maintains its own factor graph. When robots establish communication, they exchange
their history object detections and odometry, with each other. Robots can treat other robots'
data in the same way as their own by maintaining an odometry graph for each robot and performing
data association in the same way as their own measurements."

So the base builds one factor graph from the robots' measurement logs
(:mod:`amslam.measurements`). It is its own code, not the onboard parts run once per robot: that
was built and measured (fewer objects mapped on the lot_team pair, 16 against 22 of 29, and 15
times slower) and is not in use until it does as well:

1. **Odometry graphs** — robot *r*'s key poses are ``gtsam.Symbol(ROBOT_CHARS[r], i)``; its first
   key pose gets a prior at its *known base* (``T_world_odom`` of its log composed with its first
   VIO pose; the bases are known and nearby, as in the paper's experiments), its VIO motion
   between consecutive key poses becomes ``BetweenFactorPose3`` with a noise *proportional to*
   the distance (the onboard graph, :mod:`.graph`, grows it with √distance: the two differ).
2. **Data association, like onboard but with a Euclidean gate** (the onboard front end,
   :mod:`.frontend`, gates by Mahalanobis distance) — the robots' logs are replayed one after the
   other through iSAM2; each batch of detections is moved into the world frame with the current
   estimate of its key pose and matched to the map's landmarks of its class by nearest neighbour
   within ``association_gate``, one-to-one per batch (Hungarian). So robot 2's detections land on
   the objects robot 1 mapped, and those objects pull robot 2's drifting chain into place while
   its log is replayed, exactly as its own old landmarks would. A landmark enters the graph after
   ``min_observations`` detections (from any robots). Range-bearing factors carry a Huber kernel.
3. **Duplicate fusion** — an object first seen by a robot whose chain had drifted beyond the gate
   becomes a second landmark. After a joint optimisation, same-class landmarks closer than
   ``fuse_gate`` that were never detected in the same frame (two objects seen together are two
   objects) are fused, and the graph optimised again.
4. **Joint optimisation** — Levenberg–Marquardt on the whole merged graph from the iSAM2 estimate
   (``optimizer="lm"``; ``"isam2"`` keeps the incremental solution), then marginal covariances of
   the landmarks.

**Shape classes** (``landmark_models``: class → ``cuboid`` | ``cylinder``, as onboard): the
centroid of a car's visible surface moves by metres with the view, so a car seen from two sides
by two robots would become several landmarks. These classes are therefore associated as the
onboard shape front end does (:mod:`.shape_landmarks`): by the share of a detection's points
within ``shape_margin`` of a landmark's points or inside its fitted, inflated shape; and after
each joint optimisation, landmarks of a shape class never detected in one frame are fused when
their points overlap or together still fit one object of the class (``shape_max_dims``: a car's
box; two parked neighbours make a box far wider or longer). Their detection centroids stay in
the graph as weak range-bearing measurements (``shape_centroid_sigma``), and a landmark's
reported position is its fitted shape's reference point (cuboid centre, cylinder root).
Every key pose also gets an attitude factor (the IMU's gravity direction), as roll and pitch do
not drift.

Steps 3 and 4 alternate with a re-association of every detection against the optimised map
(``refine_rounds``): once robot 2's observations have corrected robot 1's drifted chain, robot
1's late detections fall within the gate of the objects they saw, and move there.

The merged landmark map comes out as :class:`amslam.types.Landmark` and is written with
:func:`write_landmarks` in the run folder's ``landmarks.json`` format. Shapes (cuboids, cylinders)
are fitted per landmark from the points of all its detections, moved into the world frame with
the optimised key poses, when a ``shape_fitter`` is given.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from amslam.geometry import transform_points, wrap_angle, yaw_of
from amslam.lib import shapes
from amslam.measurements import RobotMeasurements, read_measurements
from amslam.plugins.gtsam_slam.shape_landmarks import ShapeParams
from amslam.rundir import read_tum, write_landmarks
from amslam.types import Landmark

__all__ = [
    "ROBOT_CHARS",
    "MergeParams",
    "MergeResult",
    "ShapeFitter",
    "merge_measurements",
    "merge_runs",
    "position_errors",
    "chain_from_base",
    "robot_key",
    "with_slam_odometry",
    "write_landmarks",
]

#: Key-pose symbol character of robot r (``l`` is the landmarks', ``x`` the onboard graph's).
ROBOT_CHARS = "abcdefghijkmnopqrstuvwyz"

#: ``fit(class_name, world_points) -> shape dict | None``: fits a cuboid or cylinder (paper 2 §IV-A).
ShapeFitter = Callable[[str, np.ndarray], dict | None]


#: The onboard shape front end's defaults (:mod:`.shape_landmarks`), shared by the merge.
_SHAPE = ShapeParams()


def robot_key(robot: int, keypose: int) -> int:
    """The gtsam key of robot ``robot``'s key pose ``keypose``."""
    return gtsam.symbol(ROBOT_CHARS[robot], keypose)


#: a size, m: above zero and at most 100 m (no object is larger)
_Size = Annotated[float, Field(gt=0, le=100)]


class MergeParams(BaseModel):
    """Noise models and gates of the merged graph (defaults: the onboard ``gtsam`` backend's).

    Bounds as in :class:`~amslam.plugins.gtsam_slam.graph.GraphParams`: angle stds (rad) at most π."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    base_sigma_translation: float = Field(0.01, gt=0, le=1000, description="std of a known base position, m")
    base_sigma_rotation: float = Field(
        0.005, gt=0, le=math.pi, description="std of a known base attitude, rad"
    )
    odom_sigma_translation_per_m: float = Field(
        0.02, gt=0, le=10, description="VIO translation std per metre"
    )
    odom_sigma_translation_min: float = Field(0.005, gt=0, le=10, description="VIO translation std floor, m")
    odom_sigma_yaw_per_m: float = Field(0.005, ge=0, le=math.pi, description="VIO yaw std per metre, rad/m")
    odom_sigma_yaw_per_rad: float = Field(0.01, ge=0, le=10, description="VIO yaw std per radian turned")
    odom_sigma_yaw_min: float = Field(0.002, gt=0, le=math.pi, description="VIO yaw std floor, rad")
    odom_sigma_roll_pitch: float = Field(0.002, gt=0, le=math.pi, description="roll/pitch std (IMU), rad")
    attitude_sigma: float = Field(
        0.01,
        ge=0,
        le=math.pi,
        description="std of each key pose's tilt against gravity (IMU), rad (0: no attitude factors)",
    )
    bearing_sigma: float = Field(0.05, gt=0, le=math.pi, description="bearing std of an object centroid, rad")
    range_sigma: float = Field(0.05, gt=0, le=100, description="range std at zero range, m")
    range_sigma_per_m: float = Field(0.03, ge=0, le=10, description="range std growth per metre")
    robust_k: float = Field(1.345, gt=0, le=100, description="Huber kernel width (whitened units)")
    association_gate: float = Field(0.8, gt=0, le=100, description="nearest-neighbour gate, m")
    min_observations: int = Field(3, ge=1, le=1000, description="detections before a landmark is trusted")
    min_confidence: float = Field(0.3, ge=0, le=1, description="ignore weaker detections")
    max_range: float = Field(8.0, gt=0, le=1000, description="ignore detections farther than this, m")
    fuse_gate: float = Field(
        0.8, ge=0, le=100, description="fuse same-class landmarks closer than this, m (0: off)"
    )
    optimizer: Literal["lm", "isam2"] = Field("lm", description="final joint optimisation")
    refine_rounds: int = Field(
        8, ge=0, le=1000, description="rounds of re-association + duplicate fusion + joint optimisation"
    )
    update_every: int = Field(
        20, ge=1, le=1_000_000, description="iSAM2 update at least every this many key poses"
    )
    landmark_models: dict[str, Literal["centroid", "cuboid", "cylinder"]] = Field(
        default_factory=dict,
        description="landmark model per class (default centroid); cuboid / cylinder classes are "
        "associated and fused by their points and fitted shapes, not by the centroid gate",
    )
    shape_margin: float = Field(
        _SHAPE.association_margin,
        ge=0,
        le=100,
        description="shape association: distance to a landmark's points or shape, m",
    )
    shape_overlap: float = Field(
        _SHAPE.association_overlap,
        gt=0,
        le=1,
        description="share of a detection's points inside to associate",
    )
    shape_max_dims: dict[str, tuple[_Size, _Size, _Size]] = Field(
        default_factory=lambda: {"car": (6.0, 2.6, 2.8)},
        description="largest single object of a cuboid class (length, width, height), m: two landmarks "
        "whose points fit in one such box are fused (cars and vans are <= 5.5 x 2.05 x 2.3 m)",
    )
    shape_max_radius: float = Field(
        _SHAPE.max_radius, gt=0, le=100, description="largest radius of one cylinder object (fusion), m"
    )
    shape_centroid_sigma: dict[str, Annotated[float, Field(ge=0, le=1000)]] = Field(
        default_factory=lambda: {"car": 5.0, "cuboid": 0.5, "cylinder": 0.3},
        description="extra std (m) of a shape-class detection's centroid as a range-bearing measurement, "
        "by class, else by model (cuboid: furniture-sized, <= 1.5 m): "
        "the centroid of a visible surface is biased towards the viewer by up to half the object "
        "(a car's: metres, consistently along a pass), a pole's by its radius (docs/multirobot.md: on "
        "two lot_a logs, 1.0 m for cars bent the chains to 0.90 / 0.69 m mean error, VIO alone "
        "0.53 / 0.41 m, 5.0 m gave 0.15 / 0.36 m)",
    )
    shape_cloud: int = Field(
        1500, ge=50, le=1_000_000, description="points kept per shape landmark (even thinning)"
    )
    shape_fit_points: int = Field(
        400,
        ge=20,
        le=1_000_000,
        description="points a landmark's shape is fitted to during association (cost of the fit)",
    )


@dataclass
class _Obs:
    robot: int
    keypose: int
    batch: int  # detection frame (robot, key pose) id: objects seen together are distinct
    class_name: str
    p_body: np.ndarray
    points: np.ndarray
    landmark: int = -1
    points_world: np.ndarray | None = None  # at association time (incremental pass)


@dataclass
class _Lm:
    id: int
    class_name: str
    obs: list[_Obs] = field(default_factory=list)
    sum_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    in_graph: bool = False
    alias_of: int | None = None
    # shape classes: the world points of all detections, their k-d tree and the fitted shape
    cloud: np.ndarray | None = None
    tree: cKDTree | None = None
    shape: dict | None = None
    fitted: int = 0  # observations when cloud / shape were last computed


@dataclass
class MergeResult:
    """The merged map and what went into it.

    Attributes:
        landmarks: the merged object map (world frame), marginal covariances.
        trajectories: per robot, its optimised key poses (K×4×4, world frame).
        robots: robot names, in input order.
        contributors: per landmark id, the indices of the robots that detected it.
        fused: landmarks fused as duplicates after the joint optimisation.
        graph: the merged factor graph.
        values: its optimised values.
    """

    landmarks: list[Landmark]
    trajectories: list[np.ndarray]
    robots: list[str]
    contributors: dict[int, tuple[int, ...]]
    fused: int
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values

    def shared(self) -> int:
        """Landmarks detected by more than one robot."""
        return sum(1 for c in self.contributors.values() if len(c) > 1)


class _Merger:
    def __init__(self, logs: Sequence[RobotMeasurements], params: MergeParams) -> None:
        if len(logs) > len(ROBOT_CHARS):
            raise ValueError(f"at most {len(ROBOT_CHARS)} robots can be merged, got {len(logs)}")
        self.logs = list(logs)
        self.p = params
        self.odometry = gtsam.NonlinearFactorGraph()  # priors and VIO factors, all robots
        self.lms: dict[int, _Lm] = {}
        self.obs: list[_Obs] = []
        isam_params = gtsam.ISAM2Params()
        isam_params.setFactorization("QR")
        isam_params.setRelinearizeThreshold(0.01)
        self.isam = gtsam.ISAM2(isam_params)
        self.new_graph = gtsam.NonlinearFactorGraph()
        self.new_values = gtsam.Values()
        self.estimate = gtsam.Values()
        self.batches = 0

    # ---------------------------------------------------------------- noise models

    def odometry_noise(self, distance: float, dyaw: float) -> gtsam.noiseModel.Base:
        p = self.p
        st = max(p.odom_sigma_translation_min, p.odom_sigma_translation_per_m * distance)
        sy = max(
            p.odom_sigma_yaw_min, p.odom_sigma_yaw_per_m * distance + p.odom_sigma_yaw_per_rad * abs(dyaw)
        )
        sr = p.odom_sigma_roll_pitch
        return gtsam.noiseModel.Diagonal.Sigmas(np.array([sr, sr, sy, st, st, st]))

    def bearing_range(self, key: int, lm: int, p_body: np.ndarray) -> gtsam.NonlinearFactor:
        p = self.p
        rng = float(np.linalg.norm(p_body))
        # a shape class's detection centroid (the median of the visible surface) lies anywhere
        # within about the object's size of its centre: widen range and bearing by that spread
        cls = self.lms[lm].class_name
        spread = p.shape_centroid_sigma.get(cls, p.shape_centroid_sigma.get(self.model(cls), 0.0))
        spread = spread if self.is_shape(cls) else 0.0
        sb = float(np.hypot(p.bearing_sigma, np.arctan2(spread, max(rng, 1e-3))))
        base = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([sb, sb, p.range_sigma + p.range_sigma_per_m * rng + spread])
        )
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(p.robust_k), base)
        return gtsam.BearingRangeFactor3D(key, L(lm), gtsam.Unit3(p_body), rng, noise)

    # ---------------------------------------------------------------- incremental pass

    def flush(self) -> None:
        if self.new_graph.size() == 0 and self.new_values.size() == 0:
            return
        self.isam.update(self.new_graph, self.new_values)
        self.new_graph = gtsam.NonlinearFactorGraph()
        self.new_values = gtsam.Values()
        self.estimate = self.isam.calculateEstimate()

    def pose(self, key: int) -> np.ndarray:
        if self.new_values.exists(key):
            return self.new_values.atPose3(key).matrix()
        return self.estimate.atPose3(key).matrix()

    def landmark_position(self, lm: _Lm) -> np.ndarray:
        if not lm.in_graph:
            return lm.sum_world / max(len(lm.obs), 1)
        if self.new_values.exists(L(lm.id)):
            return np.asarray(self.new_values.atPoint3(L(lm.id)))
        return np.asarray(self.estimate.atPoint3(L(lm.id)))

    def add_robot(self, r: int) -> None:
        log = self.logs[r]
        p = self.p
        by_kp: dict[int, list] = {}
        for d in log.detections:
            rng = float(np.linalg.norm(d.p_body))
            if d.confidence >= p.min_confidence and 1e-3 < rng <= p.max_range:
                by_kp.setdefault(d.keypose, []).append(d)
        since_update = 0
        for i in range(len(log.stamps)):
            key = robot_key(r, i)
            if i == 0:
                T0 = log.T_world_odom @ log.T_odom_body[0]
                sig = np.array([p.base_sigma_rotation] * 3 + [p.base_sigma_translation] * 3)
                factor = gtsam.PriorFactorPose3(key, gtsam.Pose3(T0), gtsam.noiseModel.Diagonal.Sigmas(sig))
                self.new_values.insert(key, gtsam.Pose3(T0))
            else:
                rel = log.rel[i]
                dyaw = wrap_angle(yaw_of(log.T_odom_body[i]) - yaw_of(log.T_odom_body[i - 1]))
                noise = self.odometry_noise(float(np.linalg.norm(rel[:3, 3])), dyaw)
                factor = gtsam.BetweenFactorPose3(robot_key(r, i - 1), key, gtsam.Pose3(rel), noise)
                self.new_values.insert(key, gtsam.Pose3(self.pose(robot_key(r, i - 1)) @ rel))
            self.odometry.add(factor)
            self.new_graph.add(factor)
            if p.attitude_sigma > 0:
                # the IMU observes roll and pitch against gravity at every key pose: without this,
                # the between-factors let the tilt random-walk along a long chain, and biased
                # landmark measurements bend it (metres of height error across a 36 m lot)
                R = (log.T_world_odom @ log.T_odom_body[i])[:3, :3]
                up = gtsam.Unit3(np.array([0.0, 0.0, 1.0]))
                att = gtsam.AttitudeFactorPose3(
                    key, up, gtsam.noiseModel.Isotropic.Sigma(2, p.attitude_sigma), gtsam.Unit3(R[2])
                )
                self.odometry.add(att)
                self.new_graph.add(att)
            since_update += 1
            dets = by_kp.get(i)
            if dets:
                self.associate(r, i, dets)
            if dets or since_update >= p.update_every:
                self.flush()
                since_update = 0
        self.flush()

    def associate(self, r: int, i: int, dets: list) -> None:
        T = self.pose(robot_key(r, i))
        p_body = np.array([d.p_body for d in dets])
        p_world = transform_points(T, p_body)
        pts_world = [transform_points(T, d.points) if len(d.points) else np.zeros((0, 3)) for d in dets]
        live = [lm for lm in self.lms.values() if lm.alias_of is None]
        assoc = [-1] * len(dets)
        if live:
            cost, bad = self.association_costs([d.class_name for d in dets], p_world, pts_world, live)
            if not bad.all():
                rows, cols = linear_sum_assignment(np.where(bad, 1e9, cost))
                for a, b in zip(rows, cols, strict=True):
                    if not bad[a, b]:
                        assoc[a] = live[b].id
        batch = self.batches
        self.batches += 1
        for d, pw, pts, lm_id in zip(dets, p_world, pts_world, assoc, strict=True):
            if lm_id < 0:
                lm_id = max(self.lms, default=-1) + 1
                self.lms[lm_id] = _Lm(lm_id, d.class_name)
            lm = self.lms[lm_id]
            ob = _Obs(r, i, batch, d.class_name, np.asarray(d.p_body, float), d.points, lm_id, pts)
            self.obs.append(ob)
            lm.obs.append(ob)
            lm.sum_world = lm.sum_world + pw
            key = robot_key(r, i)
            if lm.in_graph:
                self.new_graph.add(self.bearing_range(key, lm.id, ob.p_body))
            elif len(lm.obs) >= self.p.min_observations:
                lm.in_graph = True
                self.new_values.insert(L(lm.id), lm.sum_world / len(lm.obs))
                for o in lm.obs:
                    self.new_graph.add(self.bearing_range(robot_key(o.robot, o.keypose), lm.id, o.p_body))

    def association_costs(
        self,
        classes: list[str],
        p_world: np.ndarray,
        pts_world: list[np.ndarray],
        live: list[_Lm],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Cost and infeasibility (detections × landmarks) of one detection frame's association.

        Centroid classes: the distance of the detection's centroid to the landmark within
        ``association_gate``. Shape classes (as the onboard shape front end,
        :meth:`.shape_landmarks.ShapeLandmarks.associate`): one minus the share of the
        detection's points within ``shape_margin`` of the landmark's points or inside its
        inflated fitted shape, feasible from ``shape_overlap`` on; a detection without points
        falls back to the centroid gate.
        """
        pos = np.array([self.landmark_position(lm) for lm in live])
        cls = np.array([lm.class_name for lm in live])
        dist = np.linalg.norm(p_world[:, None] - pos[None], axis=2)
        cost = dist.copy()
        bad = (np.array(classes)[:, None] != cls[None]) | (dist > self.p.association_gate)
        for a, c in enumerate(classes):
            if not self.is_shape(c) or len(pts_world[a]) < 5:
                continue
            reach = self.reach(c)
            for b, lm in enumerate(live):
                cost[a, b], bad[a, b] = 1.0, True
                if lm.class_name != c:
                    continue
                self.refresh(lm)
                if lm.cloud is None or np.linalg.norm(lm.cloud.mean(axis=0)[:2] - p_world[a, :2]) > reach:
                    continue
                share = self.overlap(lm, pts_world[a])
                if share >= self.p.shape_overlap:
                    cost[a, b], bad[a, b] = 1.0 - share, False
        return cost, bad

    # ---------------------------------------------------------------- shape classes

    def model(self, class_name: str) -> str:
        return self.p.landmark_models.get(class_name, "centroid")

    def is_shape(self, class_name: str) -> bool:
        return self.model(class_name) in ("cuboid", "cylinder")

    def reach(self, class_name: str) -> float:
        """How far apart (horizontally) two parts of one object of this class can be, m."""
        if self.model(class_name) == "cylinder":
            return 2.0 * self.p.shape_max_radius + self.p.shape_margin
        dims = self.p.shape_max_dims.get(class_name)
        return float(dims[0]) if dims else _SHAPE.max_dim

    def fit_shape(self, class_name: str, cloud: np.ndarray) -> dict | None:
        """The class's shape fitted to world points with the onboard front end's settings."""
        if len(cloud) < 20:
            return None
        if self.model(class_name) == "cuboid":
            s = shapes.fit_cuboid(cloud, percentile=_SHAPE.percentile, extrapolate=_SHAPE.extrapolate)
            ok = s is not None and max(s["dims"]) <= _SHAPE.max_dim
        else:
            s = shapes.fit_cylinder(cloud, axis=_SHAPE.cylinder_axis)
            ok = s is not None and 0.01 <= s["radius"] <= self.p.shape_max_radius
        return s if ok else None

    def refresh(self, lm: _Lm, values: gtsam.Values | None = None, force: bool = False) -> None:
        """Recompute a shape landmark's cloud, k-d tree and shape.

        Without ``values`` (incremental pass) the points as placed at association time are used,
        and only once the landmark has grown by a quarter since the last fit (fits are the cost
        here); with ``values``, every detection's points are moved with the optimised poses.
        """
        n = len(lm.obs)
        if not force and lm.cloud is not None and n < max(lm.fitted + 1, 1.25 * lm.fitted):
            return
        pts = []
        for o in lm.obs:
            if values is not None:
                pts.append(transform_points(values.atPose3(robot_key(o.robot, o.keypose)).matrix(), o.points))
            elif o.points_world is not None:
                pts.append(o.points_world)
        cloud = np.vstack(pts) if pts else np.zeros((0, 3))
        if len(cloud) > self.p.shape_cloud:  # evenly thinned, deterministic
            cloud = cloud[np.linspace(0, len(cloud) - 1, self.p.shape_cloud).round().astype(int)]
        lm.cloud = cloud if len(cloud) else None
        lm.tree = cKDTree(cloud) if len(cloud) else None
        k = self.p.shape_fit_points  # the L-shape search costs O(points): thin for association
        sub = cloud[np.linspace(0, len(cloud) - 1, k).round().astype(int)] if len(cloud) > k else cloud
        lm.shape = self.fit_shape(lm.class_name, sub)
        lm.fitted = n

    def overlap(self, lm: _Lm, pts: np.ndarray) -> float:
        """Share of ``pts`` within ``shape_margin`` of the landmark's points or inside its shape."""
        if lm.tree is None or len(pts) == 0:
            return 0.0
        d, _ = lm.tree.query(pts, distance_upper_bound=self.p.shape_margin)
        inside = np.isfinite(d)
        if lm.shape is not None:
            inside |= shapes.points_inside(lm.shape, pts, self.p.shape_margin)
        return float(inside.mean())

    def one_object(self, a: _Lm, b: _Lm) -> bool:
        """Whether two landmarks of a shape class are parts of one object.

        Either one's points overlap the other's (as in association), or their points together
        still fit one object of the class: a cuboid within ``shape_max_dims`` (length ≥ width),
        a cylinder within ``shape_max_radius``. Two parked cars side by side or nose to nose
        make a box far wider or longer than any car.
        """
        small, large = (a, b) if len(a.cloud) <= len(b.cloud) else (b, a)
        if self.overlap(large, small.cloud) >= self.p.shape_overlap:
            return True
        union = self.fit_shape(a.class_name, np.vstack([a.cloud, b.cloud]))
        if union is None:
            return False
        if union["model"] == "cylinder":
            return True  # fit_shape already bounded the radius
        limit = self.p.shape_max_dims.get(a.class_name)
        if limit is None:
            return False
        d = union["dims"]
        return max(d[0], d[1]) <= limit[0] and min(d[0], d[1]) <= limit[1] and d[2] <= limit[2]

    def fuse_shapes(self, values: gtsam.Values) -> int:
        """Fuse landmarks of shape classes that are parts of one object (:meth:`one_object`).

        A car seen from different sides by different robots (or by one robot whose chain
        drifted) gives point clouds that need not overlap, so association left several
        landmarks; after a joint optimisation, same-class landmarks within reach that were
        never detected in one frame (objects seen together are distinct) are fused, closest
        first, when their points together still make one object of the class.
        """
        fused = 0
        graph_lms = self.graph_landmarks()
        for cls in sorted({lm.class_name for lm in graph_lms if self.is_shape(lm.class_name)}):
            lms = [lm for lm in graph_lms if lm.class_name == cls]
            for lm in lms:
                self.refresh(lm, values, force=True)
            lms = [lm for lm in lms if lm.cloud is not None]
            if len(lms) < 2:
                continue
            centre = np.array([lm.cloud.mean(axis=0) for lm in lms])
            d = np.linalg.norm(centre[:, None, :2] - centre[None, :, :2], axis=2)
            reach = self.reach(cls)
            pairs = sorted(
                (d[a, b], a, b) for a in range(len(lms)) for b in range(a + 1, len(lms)) if d[a, b] <= reach
            )
            batches = {lm.id: {o.batch for o in lm.obs} for lm in lms}
            for _, a, b in pairs:
                A, B = lms[a], lms[b]
                if A.alias_of is not None or B.alias_of is not None or batches[A.id] & batches[B.id]:
                    continue
                if not self.one_object(A, B):
                    continue
                keep, drop = (A, B) if len(A.obs) >= len(B.obs) else (B, A)
                self.absorb(keep, drop)
                batches[keep.id] |= batches.pop(drop.id)
                self.refresh(keep, values, force=True)
                fused += 1
        return fused

    def absorb(self, keep: _Lm, drop: _Lm) -> None:
        """Move ``drop``'s detections to ``keep``; ``drop`` becomes an alias."""
        for o in drop.obs:
            o.landmark = keep.id
        keep.obs.extend(drop.obs)
        drop.obs = []
        drop.alias_of = keep.id

    # ---------------------------------------------------------------- joint optimisation

    def graph_landmarks(self) -> list[_Lm]:
        return [lm for lm in self.lms.values() if lm.in_graph and lm.alias_of is None]

    def full_graph(self) -> gtsam.NonlinearFactorGraph:
        graph = gtsam.NonlinearFactorGraph(self.odometry)
        for lm in self.graph_landmarks():
            for o in lm.obs:
                graph.add(self.bearing_range(robot_key(o.robot, o.keypose), lm.id, o.p_body))
        return graph

    def optimise(self, values: gtsam.Values) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        graph = self.full_graph()
        keep = gtsam.Values()
        for key in graph.keyVector():
            if not keep.exists(key):
                keep.insert(key, values.atPose3(key) if _is_pose(key) else values.atPoint3(key))
        if self.p.optimizer == "isam2":
            return graph, keep
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(100)
        return graph, gtsam.LevenbergMarquardtOptimizer(graph, keep, params).optimize()

    def fuse_duplicates(self, values: gtsam.Values) -> int:
        """Fuse same-class landmarks within ``fuse_gate`` never detected in one frame; closest first."""
        if self.p.fuse_gate <= 0:
            return 0
        lms = self.graph_landmarks()
        if len(lms) < 2:
            return 0
        pos = np.array([values.atPoint3(L(lm.id)) for lm in lms])
        dist = np.linalg.norm(pos[:, None] - pos[None], axis=2)
        pairs = [
            (dist[a, b], a, b)
            for a in range(len(lms))
            for b in range(a + 1, len(lms))
            if lms[a].class_name == lms[b].class_name
            and dist[a, b] <= self.p.fuse_gate
            and not self.is_shape(lms[a].class_name)  # shape classes: fuse_shapes
        ]
        fused = 0
        batches = {lm.id: {o.batch for o in lm.obs} for lm in lms}
        for _, a, b in sorted(pairs):
            keep, drop = lms[a], lms[b]
            if keep.alias_of is not None or drop.alias_of is not None:
                continue
            if batches[keep.id] & batches[drop.id]:
                continue  # seen together in one frame: two objects
            self.absorb(keep, drop)
            batches[keep.id] |= batches.pop(drop.id)
            fused += 1
        return fused

    def reassociate(self, values: gtsam.Values) -> int:
        """Re-run nearest-neighbour association of every detection with the optimised poses.

        Each detection frame is matched one-to-one (Hungarian, class-gated, ``association_gate``)
        to the optimised landmarks; a detection that matches none keeps its landmark. Returns how
        many detections changed landmark. Landmarks left with fewer than ``min_observations``
        leave the graph.
        """
        lms = [lm for lm in self.graph_landmarks() if not self.is_shape(lm.class_name)]
        if not lms:
            return 0
        ids = np.array([lm.id for lm in lms])
        pos = np.array([values.atPoint3(L(lm.id)) for lm in lms])
        cls = np.array([lm.class_name for lm in lms])
        by_batch: dict[int, list[_Obs]] = {}
        for o in self.obs:
            if self.lms[o.landmark].alias_of is None and not self.is_shape(o.class_name):
                by_batch.setdefault(o.batch, []).append(o)
        changed = 0
        for group in by_batch.values():
            T = values.atPose3(robot_key(group[0].robot, group[0].keypose)).matrix()
            pw = transform_points(T, np.array([o.p_body for o in group]))
            dist = np.linalg.norm(pw[:, None] - pos[None], axis=2)
            bad = (np.array([o.class_name for o in group])[:, None] != cls[None]) | (
                dist > self.p.association_gate
            )
            if bad.all():
                continue
            rows, cols = linear_sum_assignment(np.where(bad, 1e9, dist))
            for a, b in zip(rows, cols, strict=True):
                if not bad[a, b] and group[a].landmark != int(ids[b]):
                    group[a].landmark = int(ids[b])
                    changed += 1
        if changed:
            for lm in self.lms.values():
                lm.obs = []
            for o in self.obs:
                self.lms[o.landmark].obs.append(o)
            for lm in self.lms.values():
                if lm.in_graph and len(lm.obs) < self.p.min_observations:
                    lm.in_graph = False
        return changed

    def run(self, shape_fitter: ShapeFitter | None) -> MergeResult:
        for r in range(len(self.logs)):
            self.add_robot(r)
        graph, values = self.optimise(self.estimate)
        fused = 0
        for _ in range(self.p.refine_rounds):
            moved = self.reassociate(values)
            n = self.fuse_duplicates(values) + self.fuse_shapes(values)
            if moved == 0 and n == 0:
                break
            fused += n
            graph, values = self.optimise(values)
        return self.result(graph, values, fused, shape_fitter)

    def result(
        self,
        graph: gtsam.NonlinearFactorGraph,
        values: gtsam.Values,
        fused: int,
        shape_fitter: ShapeFitter | None,
    ) -> MergeResult:
        lms = self.graph_landmarks()
        try:
            marginals = gtsam.Marginals(graph, values)
            cov = {lm.id: marginals.marginalCovariance(L(lm.id)) for lm in lms}
        except RuntimeError:  # an indeterminate system (should not happen with priors on every chain)
            cov = {}
        trajectories = [
            np.array([values.atPose3(robot_key(r, i)).matrix() for i in range(len(log.stamps))]).reshape(
                -1, 4, 4
            )
            for r, log in enumerate(self.logs)
        ]
        out, contributors = [], {}
        for new_id, lm in enumerate(sorted(lms, key=lambda m: m.id)):
            shape = None
            if shape_fitter is not None:
                pts = [
                    transform_points(trajectories[o.robot][o.keypose], o.points)
                    for o in lm.obs
                    if len(o.points)
                ]
                if pts:
                    shape = shape_fitter(lm.class_name, np.vstack(pts))
            elif self.is_shape(lm.class_name):
                self.refresh(lm, values, force=True)
                shape = lm.shape
            position = np.asarray(values.atPoint3(L(lm.id)))
            if self.is_shape(lm.class_name) and shape and shape.get("model") == self.model(lm.class_name):
                # a shape landmark's position is its shape's reference point (cuboid centre,
                # cylinder root), as onboard; the graph's point is a mean of visible surfaces
                position = shapes.shape_center(shape)
            out.append(
                Landmark(
                    new_id,
                    lm.class_name,
                    position,
                    cov.get(lm.id, np.full((3, 3), np.nan)),
                    len(lm.obs),
                    -1,
                    shape,
                )
            )
            contributors[new_id] = tuple(sorted({o.robot for o in lm.obs}))
        return MergeResult(
            out, trajectories, [log.robot for log in self.logs], contributors, fused, graph, values
        )


def _is_pose(key: int) -> bool:
    return chr(gtsam.Symbol(key).chr()) != "l"


def merge_measurements(
    logs: Sequence[RobotMeasurements],
    params: MergeParams | None = None,
    shape_fitter: ShapeFitter | None = None,
) -> MergeResult:
    """Build and optimise the merged graph of several robots' measurement logs.

    Args:
        logs: one measurement log per robot (:func:`amslam.measurements.read_measurements`), each
            with its known base ``T_world_odom``; robots are replayed in this order.
        params: noise models and gates; the onboard backend's defaults when omitted.
        shape_fitter: fits a shape to a landmark's world-frame points (optional).

    Returns:
        The merged map, the robots' optimised trajectories and the graph.
    """
    if not logs:
        raise ValueError("nothing to merge: no measurement logs")
    return _Merger(logs, params or MergeParams()).run(shape_fitter)


def with_slam_odometry(log: RobotMeasurements, run_dir: Path) -> RobotMeasurements:
    """The log with the robot's onboard SLAM estimate as its odometry (``slam.tum``, ``vio.tum``).

    A robot may send its own SLAM-corrected trajectory instead of raw VIO: its onboard graph
    used everything it saw (eq. 1 / eq. 2 shape factors on all points, which the log's 24 points
    per detection cannot give the base). Each key pose becomes the VIO pose corrected by the
    latest SLAM correction at or before it, ``T_slam(t_k) · T_vio(t_k)⁻¹ · T_vio(t)`` (the SLAM
    estimate is written at its key poses, the VIO at every tick), in the odometry frame (the
    onboard graph is anchored at the robot's start).
    """
    slam, vio = read_tum(Path(run_dir) / "slam.tum"), read_tum(Path(run_dir) / "vio.tum")
    ts, Ts, tv, Tv = slam.stamps, slam.matrices(), vio.stamps, vio.matrices()
    if len(ts) == 0 or len(tv) == 0:
        return log
    out = []
    for t, T in zip(log.stamps, log.T_odom_body, strict=True):
        k = int(np.searchsorted(ts, t + 1e-6)) - 1
        if k < 0:
            out.append(T)
            continue
        j = int(np.argmin(np.abs(tv - ts[k])))
        out.append(Ts[k] @ np.linalg.inv(Tv[j]) @ T)
    poses = np.array(out).reshape(-1, 4, 4)
    rel = np.array([np.eye(4)] + [np.linalg.inv(a) @ b for a, b in zip(poses[:-1], poses[1:], strict=True)])
    log.T_odom_body, log.rel = poses, rel.reshape(-1, 4, 4)
    return log


def merge_runs(
    run_dirs: Sequence[Path],
    params: MergeParams | None = None,
    shape_fitter: ShapeFitter | None = None,
    bases: Sequence[np.ndarray] | None = None,
    odometry: Literal["vio", "slam"] = "vio",
) -> MergeResult:
    """:func:`merge_measurements` of run folders' ``measurements.jsonl``.

    ``bases`` overrides each log's ``T_world_odom`` (the robots' known base poses);
    ``odometry="slam"`` chains each robot's key poses with its onboard SLAM estimate
    (:func:`with_slam_odometry`) instead of its VIO.
    """
    logs = [read_measurements(Path(d)) for d in run_dirs]
    if odometry == "slam":
        logs = [with_slam_odometry(log, Path(d)) for log, d in zip(logs, run_dirs, strict=True)]
    if bases is not None:
        for log, T in zip(logs, bases, strict=True):
            log.T_world_odom = np.asarray(T, float)
    return merge_measurements(logs, params, shape_fitter)


def position_errors(
    landmarks: Sequence[Landmark],
    truth: dict[str, np.ndarray],
    truth_classes: dict[str, str],
    gate: float = 1.0,
) -> tuple[np.ndarray, list[tuple[int, str]]]:
    """Match landmarks to true objects of their class (Hungarian within ``gate``).

    Returns:
        The position error of each matched pair (m) and the pairs ``(landmark id, object id)``.
    """
    ids = list(truth)
    if not ids or not landmarks:
        return np.zeros(0), []
    P = np.array([truth[i] for i in ids], float)
    Q = np.array([lm.position for lm in landmarks], float)
    d = np.linalg.norm(Q[:, None] - P[None], axis=2)
    bad = (
        np.array([lm.class_name for lm in landmarks])[:, None]
        != np.array([truth_classes[i] for i in ids])[None]
    ) | (d > gate)
    if bad.all():
        return np.zeros(0), []
    rows, cols = linear_sum_assignment(np.where(bad, 1e9, d))
    keep = [(a, b) for a, b in zip(rows, cols, strict=True) if not bad[a, b]]
    return np.array([d[a, b] for a, b in keep]), [(landmarks[a].id, ids[b]) for a, b in keep]


def chain_from_base(log: RobotMeasurements) -> np.ndarray:
    """The robot's key poses dead-reckoned from its base (K×4×4, world frame): VIO alone."""
    return np.array([log.T_world_odom @ T for T in log.T_odom_body]).reshape(-1, 4, 4)
