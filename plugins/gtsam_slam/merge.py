"""Multi-robot map merging at the base (paper 2 §IV-B4, Fig. 5).

"Each robot maintains its own factor graph. When robots establish communication, they exchange
their history object detections and odometry, with each other. Robots can treat other robots'
data in the same way as their own by maintaining an odometry graph for each robot and performing
data association in the same way as their own measurements."

So the base builds one factor graph from the robots' measurement logs
(:mod:`amslam.measurements`):

1. **Odometry graphs** — robot *r*'s key poses are ``gtsam.Symbol(ROBOT_CHARS[r], i)``; its first
   key pose gets a prior at its *known base* (``T_world_odom`` of its log composed with its first
   VIO pose; the bases are known and nearby, as in the paper's experiments), its VIO motion
   between consecutive key poses becomes ``BetweenFactorPose3`` with the same distance-scaled
   noise as the onboard graph (:class:`amslam.plugins.gtsam_slam.backend.GtsamSlam`).
2. **Data association, the same way as onboard** — the robots' logs are replayed one after the
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

Steps 3 and 4 alternate with a re-association of every detection against the optimised map
(``refine_rounds``): once robot 2's observations have corrected robot 1's drifted chain, robot
1's late detections fall within the gate of the objects they saw, and move there.

The merged landmark map comes out as :class:`amslam.types.Landmark` and is written with
:func:`write_landmarks` in the run folder's ``landmarks.json`` format. Shapes (cuboids, cylinders)
are fitted per landmark from the points of all its detections, moved into the world frame with
the optimised key poses, when a ``shape_fitter`` is given.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import linear_sum_assignment

from amslam.geometry import transform_points, wrap_angle, yaw_of
from amslam.measurements import RobotMeasurements, read_measurements
from amslam.rundir import jsonable
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
    "write_landmarks",
]

#: Key-pose symbol character of robot r (``l`` is the landmarks', ``x`` the onboard graph's).
ROBOT_CHARS = "abcdefghijkmnopqrstuvwyz"

#: ``fit(class_name, world_points) -> shape dict | None``: fits a cuboid or cylinder (paper 2 §IV-A).
ShapeFitter = Callable[[str, np.ndarray], dict | None]


def robot_key(robot: int, keypose: int) -> int:
    """The gtsam key of robot ``robot``'s key pose ``keypose``."""
    return gtsam.symbol(ROBOT_CHARS[robot], keypose)


class MergeParams(BaseModel):
    """Noise models and gates of the merged graph (defaults: the onboard ``gtsam`` backend's)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    base_sigma_translation: float = Field(0.01, gt=0, description="std of a known base position, m")
    base_sigma_rotation: float = Field(0.005, gt=0, description="std of a known base attitude, rad")
    odom_sigma_translation_per_m: float = Field(0.02, gt=0, description="VIO translation std per metre")
    odom_sigma_translation_min: float = Field(0.005, gt=0, description="VIO translation std floor, m")
    odom_sigma_yaw_per_m: float = Field(0.005, ge=0, description="VIO yaw std per metre, rad/m")
    odom_sigma_yaw_per_rad: float = Field(0.01, ge=0, description="VIO yaw std per radian turned")
    odom_sigma_yaw_min: float = Field(0.002, gt=0, description="VIO yaw std floor, rad")
    odom_sigma_roll_pitch: float = Field(0.002, gt=0, description="roll/pitch std (IMU), rad")
    bearing_sigma: float = Field(0.05, gt=0, description="bearing std of an object centroid, rad")
    range_sigma: float = Field(0.05, gt=0, description="range std at zero range, m")
    range_sigma_per_m: float = Field(0.03, ge=0, description="range std growth per metre")
    robust_k: float = Field(1.345, gt=0, description="Huber kernel width (whitened units)")
    association_gate: float = Field(0.8, gt=0, description="nearest-neighbour gate, m")
    min_observations: int = Field(3, ge=1, description="detections before a landmark is trusted")
    min_confidence: float = Field(0.3, ge=0, le=1, description="ignore weaker detections")
    max_range: float = Field(8.0, gt=0, description="ignore detections farther than this, m")
    fuse_gate: float = Field(0.8, ge=0, description="fuse same-class landmarks closer than this, m (0: off)")
    optimizer: Literal["lm", "isam2"] = Field("lm", description="final joint optimisation")
    refine_rounds: int = Field(
        8, ge=0, description="rounds of re-association + duplicate fusion + joint optimisation"
    )
    update_every: int = Field(20, ge=1, description="iSAM2 update at least every this many key poses")


@dataclass
class _Obs:
    robot: int
    keypose: int
    batch: int  # detection frame (robot, key pose) id: objects seen together are distinct
    class_name: str
    p_body: np.ndarray
    points: np.ndarray
    landmark: int = -1


@dataclass
class _Lm:
    id: int
    class_name: str
    obs: list[_Obs] = field(default_factory=list)
    sum_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    in_graph: bool = False
    alias_of: int | None = None


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
        base = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([p.bearing_sigma, p.bearing_sigma, p.range_sigma + p.range_sigma_per_m * rng])
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
        live = [lm for lm in self.lms.values() if lm.alias_of is None]
        assoc = [-1] * len(dets)
        if live:
            pos = np.array([self.landmark_position(lm) for lm in live])
            cls = np.array([lm.class_name for lm in live])
            dist = np.linalg.norm(p_world[:, None] - pos[None], axis=2)
            bad = (np.array([d.class_name for d in dets])[:, None] != cls[None]) | (
                dist > self.p.association_gate
            )
            if not bad.all():
                rows, cols = linear_sum_assignment(np.where(bad, 1e9, dist))
                for a, b in zip(rows, cols, strict=True):
                    if not bad[a, b]:
                        assoc[a] = live[b].id
        batch = self.batches
        self.batches += 1
        for d, pw, lm_id in zip(dets, p_world, assoc, strict=True):
            if lm_id < 0:
                lm_id = max(self.lms, default=-1) + 1
                self.lms[lm_id] = _Lm(lm_id, d.class_name)
            lm = self.lms[lm_id]
            ob = _Obs(r, i, batch, d.class_name, np.asarray(d.p_body, float), d.points, lm_id)
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
            if lms[a].class_name == lms[b].class_name and dist[a, b] <= self.p.fuse_gate
        ]
        fused = 0
        batches = {lm.id: {o.batch for o in lm.obs} for lm in lms}
        for _, a, b in sorted(pairs):
            keep, drop = lms[a], lms[b]
            if keep.alias_of is not None or drop.alias_of is not None:
                continue
            if batches[keep.id] & batches[drop.id]:
                continue  # seen together in one frame: two objects
            for o in drop.obs:
                o.landmark = keep.id
            keep.obs.extend(drop.obs)
            drop.obs = []
            drop.alias_of = keep.id
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
        lms = self.graph_landmarks()
        if not lms:
            return 0
        ids = np.array([lm.id for lm in lms])
        pos = np.array([values.atPoint3(L(lm.id)) for lm in lms])
        cls = np.array([lm.class_name for lm in lms])
        by_batch: dict[int, list[_Obs]] = {}
        for o in self.obs:
            if self.lms[o.landmark].alias_of is None:
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
            n = self.fuse_duplicates(values)
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
            out.append(
                Landmark(
                    new_id,
                    lm.class_name,
                    np.asarray(values.atPoint3(L(lm.id))),
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


def merge_runs(
    run_dirs: Sequence[Path],
    params: MergeParams | None = None,
    shape_fitter: ShapeFitter | None = None,
    bases: Sequence[np.ndarray] | None = None,
) -> MergeResult:
    """:func:`merge_measurements` of run folders' ``measurements.jsonl``.

    ``bases`` overrides each log's ``T_world_odom`` (the robots' known base poses).
    """
    logs = [read_measurements(Path(d)) for d in run_dirs]
    if bases is not None:
        for log, T in zip(logs, bases, strict=True):
            log.T_world_odom = np.asarray(T, float)
    return merge_measurements(logs, params, shape_fitter)


def write_landmarks(path: Path, landmarks: Sequence[Landmark]) -> Path:
    """Write landmarks as a run folder's ``landmarks.json`` (id, class, position, covariance, ...)."""

    def clean(a: np.ndarray) -> list:
        return [[None if not np.isfinite(v) else float(v) for v in row] for row in np.atleast_2d(a)]

    records = [
        {
            "id": lm.id,
            "class": lm.class_name,
            "position": [float(v) for v in lm.position],
            "covariance": clean(lm.covariance),
            "observations": lm.observations,
            **({"shape": jsonable(lm.shape)} if lm.shape else {}),
        }
        for lm in landmarks
    ]
    path = Path(path)
    path.write_text(json.dumps(records, indent=2) + "\n")
    return path


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
