"""Multi-robot map merging at the base (paper 2 §IV-B4, Fig. 5).

"Each robot maintains its own factor graph. When robots establish communication, they exchange
their history object detections and odometry, with each other. Robots can treat other robots'
data in the same way as their own by maintaining an odometry graph for each robot and performing
data association in the same way as their own measurements."

So the base runs the onboard SLAM code once per robot, on one graph: each robot's measurement log
(:mod:`amslam.measurements`) is replayed through its own :class:`.frontend.FrontEnd` — the
onboard front end — into one :class:`.graph.SlamGraph`, robot after robot:

1. **Odometry graphs** — robot *r*'s key poses are ``gtsam.Symbol(ROBOT_CHARS[r], i)``, one per
   logged key pose; its first key pose is held at its *known base* (``T_world_odom`` of its log
   composed with its first VIO pose; the bases are known and nearby, as in the paper's
   experiments) and its VIO motion between consecutive key poses becomes ``BetweenFactorPose3``
   with the onboard noise model (std ∝ √distance, :class:`.graph.NoiseModels`); each key pose also
   gets an attitude factor (``graph.attitude_sigma``: the IMU's gravity direction).
2. **Data association as onboard** (:meth:`.frontend.FrontEnd.associate`): each detection frame
   is moved into the world frame with the current estimate of its key pose and matched per class
   to the landmarks of all robots on the Mahalanobis distance (``association.chi2``, capped by
   ``association.gate``), one-to-one (Hungarian), tracked landmarks first; a landmark another robot
   saw is as uncertain relative to this robot as its travel from its base makes it. So robot 2's
   detections land on the objects robot 1 mapped, and pull robot 2's drifting chain into place.
   A landmark enters the graph after ``association.min_observations`` detections (from any
   robots); range-bearing factors carry the robust kernel.
3. **Shape classes** (``landmark_models``: class → ``cuboid`` | ``cylinder``) go through the
   onboard shape front end (:mod:`.shape_landmarks`): associated by overlap with a landmark's
   window points or fitted shape, measured as a shape fitted to the points of the last
   ``shapes.window`` seconds of the robot's log, giving the eq. 1 / eq. 2 factors
   (:mod:`.shape_factors`), one per detection, whose reference point (cuboid centre, cylinder
   root) is the landmark's position, with the onboard noise: each window fit weighed by the range and viewing
   angle of the cameras that saw it (``shapes.view_noise``, the characterised models of paper 2
   §IV-C). A log keeps 128 points per detection, so a window holds as many points as onboard.
4. **One set of variables per object, fusion and joint optimisation** (``refine_rounds``) —
   Levenberg–Marquardt on the *shared graph* (:meth:`_Merger.shared_graph`): the replay's
   odometry, attitude, prior and centroid-class factors, and for every shape object one pose +
   dims (cuboid) or root + axis + radius (cylinder) variable carrying one eq. 1 / eq. 2 factor
   per shape measurement of any robot (a twin fused into it brings its measurements, each with
   the noise of the landmark that made it) and no other factor: a detection is measured once, as
   onboard (with ``shapes.factors`` off, once by a range-bearing factor on the reference
   variable); no point landmark ``L(j)``, no ties between two variables of one object. Then
   landmarks that are one object are fused and the graph optimised again, until nothing changes.
   Centroid classes: the onboard rule after a loop closure
   (:meth:`.graph.SlamGraph.fuse_duplicates`: closer than ``fuse_gate`` and within the
   association's χ² gate, never seen from one key pose; a stiff tie). Shape classes: landmarks
   never seen from one key pose that overlap (the shape front end's point overlap, or each shape
   holding the other's reference point) and whose positions differ by less than the
   association's χ² gate under their joint marginal covariance (the factors' noise through the
   graph, both robots' chains included): two parked neighbours do not overlap and stay apart; no
   class size is set by hand.

The merged landmark map comes out as :class:`amslam.types.Landmark` with marginal covariances and
is written with :func:`write_landmarks` in the run folder's ``landmarks.json`` format. A shape
landmark's shape is fitted to the points of all its detections moved into the world frame with
the optimised key poses (by ``shape_fitter`` when given), a box then completed behind its visible
faces with the class's size prior from the cameras of all its detections (the onboard window
fits' rule); the graph's optimised shape is the fallback. A centroid-class object is reported
as onboard (``object_map: boxes``, :mod:`.object_boxes`): at the box fitted to all its detections'
points, every robot's, twins folded together — so a merged or re-solved map (``benchmarks/
slam_offline.py``) is scored as the flight's own. The merge never reads the logs' ``truth``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import gtsam
import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from amslam.geometry import invert, transform_points
from amslam.lib import shapes
from amslam.lib.shape_factors import cuboid_keys, cylinder_keys
from amslam.measurements import RobotMeasurements, read_measurements
from amslam.plugins.gtsam_slam.frontend import FrontEnd
from amslam.plugins.gtsam_slam.graph import LandmarkRec, PoseKeys, SlamGraph
from amslam.plugins.gtsam_slam.object_boxes import ObjectBoxes, placed, reported_boxes
from amslam.plugins.gtsam_slam.params import (
    AssociationParams,
    GraphParams,
    ObjectMap,
    ObjectTrimSpreads,
    ObjectTwinMargin,
    ObjectTwinShare,
    ShapeParams,
)
from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks
from amslam.rundir import read_tum, write_landmarks
from amslam.types import Detection, Landmark, Odometry

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

#: Key-pose symbol character of robot r (``l`` is the landmarks', ``x`` the onboard graph's; ``o``,
#: ``d``, ``b``, ``n``, ``r`` the shape variables').
ROBOT_CHARS = "acefghijkmpqstuvwyz"

#: ``fit(class_name, world_points) -> shape dict | None``: fits a cuboid or cylinder (paper 2 §IV-A).
ShapeFitter = Callable[[str, np.ndarray], dict | None]


def robot_key(robot: int, keypose: int) -> int:
    """The gtsam key of robot ``robot``'s key pose ``keypose``."""
    return gtsam.symbol(ROBOT_CHARS[robot], keypose)


class MergeParams(BaseModel):
    """The merged graph: the onboard parts' parameters, and the base's fusion and optimisation."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    graph: GraphParams = Field(
        default_factory=lambda: GraphParams(
            attitude_sigma=0.01, odometry_sigma_yaw=0.02, odometry_sigma_vertical=0.012
        ),
        description="noise models: the onboard graph's, with an attitude factor per key pose (biased"
        " landmark measurements bent the tilt of long chains) and a yaw random walk five times the"
        " simulator's VIO (a robot's VIO is not known at the base, and a yaw bias drifts faster than"
        " a random walk)",
    )
    association: AssociationParams = Field(
        default_factory=AssociationParams, description="data association and the tentative buffer (onboard's)"
    )
    landmark_models: dict[str, Literal["centroid", "cuboid", "cylinder", "plane"]] = Field(
        default_factory=dict,
        description="landmark model per class ('*': every class not named; default centroid), as onboard",
    )
    shapes: ShapeParams = Field(
        default_factory=lambda: ShapeParams(min_points=20, percentile=1.0, extrapolate=True),
        description="shape landmarks: onboard's, with the same noise (view_noise: each window fit"
        " weighed by the range and viewing angle of its cameras, paper 2 IV-C), but fitted as the"
        " library fits a whole cloud (1st percentiles extrapolated to the edges) from 20 points:"
        " trimming 2.5 % of a few points cuts a car's far end short, biasing every box towards its"
        " viewer (measured: the two chains of test_merge's car pair bent 0.25 m towards the cars)",
    )
    fuse_gate: float = Field(
        0.8,
        ge=0,
        le=100,
        description="fuse same-class centroid landmarks closer than this (and within χ²), m; 0: off",
    )
    refine_rounds: int = Field(
        8, ge=0, le=1000, description="rounds of duplicate fusion + joint optimisation"
    )
    update_every: int = Field(
        20, ge=1, le=1_000_000, description="iSAM2 update at least every this many key poses"
    )
    seed: int = Field(0, ge=0, le=2**32 - 1, description="seed of the shape front end's point thinning")
    # the reported object map: the onboard backend's rules and defaults (slam.object_*)
    object_map: ObjectMap = "boxes"
    object_twin_margin: ObjectTwinMargin = 0.2
    object_twin_share: ObjectTwinShare = 0.6
    object_trim_spreads: ObjectTrimSpreads = 2.5


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
    """N robots' fronts ends on one graph, then fusion rounds and the result."""

    def __init__(self, logs: Sequence[RobotMeasurements], params: MergeParams) -> None:
        if len(logs) > len(ROBOT_CHARS):
            raise ValueError(f"at most {len(ROBOT_CHARS)} robots can be merged, got {len(logs)}")
        self.logs = list(logs)
        self.p = params
        shape_landmarks = ShapeLandmarks(
            params.landmark_models, params.shapes, np.random.default_rng(params.seed)
        )
        self.graph = SlamGraph(params.graph, shape_landmarks)
        self.fronts: list[FrontEnd] = []

    # ---------------------------------------------------------------- replay

    def add_robot(self, r: int) -> None:
        """Replay robot ``r``'s log through its own front end: every key pose, every detection frame."""
        log = self.logs[r]
        g = self.graph
        g.shapes.new_odometry_frame()
        front = FrontEnd(
            g,
            self.p.association,
            robot=r,
            keys=PoseKeys(ROBOT_CHARS[r]),
            T_world_odom=log.T_world_odom,
            keep_points=True,
        )
        self.fronts.append(front)
        T_cam_body = invert(log.T_body_cam)
        # key pose -> its camera frames in log order (stamp -> detections): a hovering robot logs
        # several frames at one key pose, and each is associated on its own, as onboard (one
        # batch made a landmark of every extra view of an object, kept apart as "seen from one
        # key pose": a stalled overhead robot's log gave 13 spurious cars)
        frames: dict[int, dict[float, list[Detection]]] = {}
        for d in log.detections:
            points = np.asarray(d.points, float).reshape(-1, 3)
            frames.setdefault(d.keypose, {}).setdefault(d.stamp, []).append(
                Detection(
                    d.class_name,
                    d.confidence,
                    transform_points(T_cam_body, np.asarray(d.p_body, float)[None])[0],
                    transform_points(T_cam_body, points),
                )
            )
        since_update = 0
        for i, (stamp, T) in enumerate(zip(log.stamps, log.T_odom_body, strict=True)):
            odom = Odometry(float(stamp), T)
            front.add_keypose(odom)
            since_update += 1
            at_keypose = frames.get(i, {})
            for frame, (t, dets) in enumerate(at_keypose.items()):
                frame_odom = Odometry(float(t), T) if np.isfinite(t) else odom
                front.add_detections(frame_odom, log.T_body_cam, dets, keypose=i, flush=False)
                if frame < len(at_keypose) - 1:
                    g.flush()  # the next frame associates against this one's landmarks
            if at_keypose or since_update >= self.p.update_every:
                g.flush()
                since_update = 0
        g.flush()

    # ---------------------------------------------------------------- fusion

    def is_shape(self, class_name: str) -> bool:
        return self.graph.shapes.model(class_name) in ("cuboid", "cylinder")

    def world_points(self, lm: LandmarkRec, values: gtsam.Values) -> np.ndarray:
        """All the object points of a landmark's detections, moved with the optimised key poses."""
        return self.world_points_and_noise(lm, values)[0]

    def world_points_and_noise(self, lm: LandmarkRec, values: gtsam.Values) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`world_points` and each point's depth noise vector (world frame,
        :func:`amslam.lib.shapes.depth_noise` with its robot's camera; zero for a log without)."""
        pts, noise = [], []
        for o in lm.observations:
            if o.points is None or not len(o.points):
                continue
            log, T_world_body = self.logs[o.robot], values.atPose3(o.pose_key).matrix()
            T_world_cam = T_world_body @ log.T_body_cam
            world = transform_points(T_world_body, o.points)
            pts.append(world)
            noise.append(shapes.depth_noise(world, T_world_cam[:3, 3], T_world_cam[:3, 2], log.depth_noise))
        return (np.vstack(pts), np.vstack(noise)) if pts else (np.zeros((0, 3)), np.zeros((0, 3)))

    def fit_all(self, class_name: str, cloud: np.ndarray, noise: np.ndarray | None = None) -> dict | None:
        """The class's shape fitted to all of a landmark's points: the library's fits for whole
        clouds (extents extrapolated from the 1st percentiles, past each point's depth ``noise``
        when a log gave its camera's; logs without one fit as before); a window fit
        (:meth:`fit`) trims 2.5 % of a few points per side, a few decimetres of a car."""
        if len(cloud) < 20:
            return None
        if self.graph.shapes.model(class_name) == "cuboid":
            s = shapes.fit_cuboid(cloud, noise=noise if noise is not None and np.any(noise) else None)
            return s if s is not None and max(s["dims"]) <= self.p.shapes.max_dim else None
        s = shapes.fit_cylinder(cloud, axis=self.p.shapes.cylinder_axis)
        return s if s is not None and 0.01 <= s["radius"] <= self.p.shapes.max_radius else None

    def complete(self, lm: LandmarkRec, shape: dict, values: gtsam.Values) -> dict:
        """A box fitted to all of a landmark's points, completed behind its visible faces with the
        class's size prior from the cameras of all its detections: the rule of the onboard window
        fits (:meth:`.ShapeLandmarks.measure`, :func:`amslam.lib.shapes.complete_cuboid`). A car a
        robot saw only from one side, far off, is otherwise a box around that side, its centre
        half a car towards the robot (lot_team pair seed 1: the far row 1.0-1.4 m off)."""
        sh = self.graph.shapes
        rec = sh.recs.get(lm.id)
        prior = sh.size_prior(rec) if rec is not None and sh.p.complete else None
        if prior is None:
            return shape
        cameras = np.array(
            [
                (values.atPose3(o.pose_key).matrix() @ self.logs[o.robot].T_body_cam)[:3, 3]
                for o in lm.observations
            ]
        )
        return shapes.complete_cuboid(shape, cameras, prior[0], tolerance=sh.p.completion_tolerance).shape

    def overlap(
        self, a: LandmarkRec, b: LandmarkRec, clouds: dict[int, np.ndarray], values: gtsam.Values
    ) -> bool:
        """Whether two landmarks of a shape class overlap, as the shape front end associates: the
        points of one lie within ``association_margin`` of the other's (a share of at least
        ``association_overlap`` of the smaller cloud), or each one's optimised shape holds the
        other's reference point (the onboard twins' rule, :meth:`.ShapeLandmarks.twins`)."""
        sh = self.graph.shapes
        A, B = clouds[a.id], clouds[b.id]
        if len(A) and len(B):
            small, large = (A, B) if len(A) <= len(B) else (B, A)
            d, _ = cKDTree(large).query(small, distance_upper_bound=sh.p.association_margin)
            if np.mean(np.isfinite(d)) >= sh.p.association_overlap:
                return True
        sa, sb = sh.estimate(a.id, values), sh.estimate(b.id, values)
        if sa is None or sb is None:
            return False
        if sa["model"] == "cylinder":
            gap = np.linalg.norm(np.asarray(sa["root"])[:2] - np.asarray(sb["root"])[:2])
            return bool(gap - max(sa["radius"], sb["radius"]) <= sh.p.association_margin)
        return bool(
            shapes.points_inside(sa, shapes.shape_center(sb)[None], 0.0)[0]
            and shapes.points_inside(sb, shapes.shape_center(sa)[None], 0.0)[0]
        )

    def shape_chi2(
        self, a: LandmarkRec, b: LandmarkRec, values: gtsam.Values, marginals: gtsam.Marginals
    ) -> float:
        """χ² of the difference of two shape landmarks' positions (box centre, cylinder root, read
        off their own variables as onboard: :meth:`.SlamGraph.point`) under their joint marginal
        covariance: the eq. 1 / eq. 2 factors' noise carried through the graph, the robots' chains
        included (a landmark of another robot is as uncertain relative to this one as the travel
        between them makes it)."""
        g = self.graph
        model = g.shape_model(a.id)
        keys = gtsam.KeyVector()
        keys.append(g.position_key(a.id))
        keys.append(g.position_key(b.id))
        joint = marginals.jointMarginalCovariance(keys).fullMatrix()
        J = np.hstack(
            [
                g.shapes.reference_jacobian(model, a.id, values),
                -g.shapes.reference_jacobian(model, b.id, values),
            ]
        )
        diff = g.point(a.id, values) - g.point(b.id, values)
        return float(diff @ np.linalg.solve(J @ joint @ J.T, diff))

    def fuse_shapes(self, values: gtsam.Values, marginals: gtsam.Marginals) -> int:
        """Fuse landmarks of a shape class that are one object: they overlap (:meth:`overlap`) and
        their positions agree within the association's χ² gate (:meth:`shape_chi2`); most likely
        pairs first, the survivor :meth:`.SlamGraph.fusion_order`'s (never two landmarks one key
        pose saw). The survivor takes the twin's measurements (:meth:`.ShapeLandmarks.absorb`):
        :meth:`shared_graph` puts them on its variables, so an object has one set of variables."""
        g = self.graph
        fused = 0
        for cls in sorted({lm.class_name for lm in g.graph_landmarks() if self.is_shape(lm.class_name)}):
            lms = [
                lm
                for lm in g.graph_landmarks()
                if lm.class_name == cls and g.shapes.estimate(lm.id, values) is not None
            ]
            clouds = {lm.id: self.world_points(lm, values) for lm in lms}
            pairs = []
            for i, a in enumerate(lms):
                for b in lms[i + 1 :]:
                    if not self.overlap(a, b, clouds, values):
                        continue
                    chi2 = self.shape_chi2(a, b, values, marginals)
                    if chi2 <= self.p.association.chi2:
                        pairs.append((chi2, a.id, b.id))
            for _, a_id, b_id in sorted(pairs):
                A, B = g.landmarks[a_id], g.landmarks[b_id]
                if A.alias_of is not None or B.alias_of is not None:
                    continue
                order = g.fusion_order(A, B)
                if order is None:
                    continue
                keep, gone = order
                g.shapes.absorb(keep.id, gone.id)
                g.fuse(keep, gone)
                fused += 1
        return fused

    # ---------------------------------------------------------------- the shared graph

    def shape_keys(self, lm_id: int) -> list[int]:
        """Every variable a shape landmark may have: its eq. 1 / eq. 2 variables (no ``L(j)``: its
        position is its reference point, :meth:`.SlamGraph.position_key`)."""
        return [*cuboid_keys(lm_id), *cylinder_keys(lm_id)]

    def shared_graph(self, values: gtsam.Values) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """The merged graph with one set of variables per shape object, and its starting values.

        The replay's graph (``SlamGraph.history``) keeps a fused twin's variables, tied to the
        survivor's reference point. Here every factor on a shape landmark's variables is left out
        and each live shape landmark gets its measurements afresh, each counted once as onboard
        (:meth:`.SlamGraph.measured_as_point`): one eq. 1 / eq. 2 factor per shape measurement
        (its own and its fused twins', each with the noise of the landmark that made it: slack,
        loose extents, view scale) on its own variables, and nothing else. With
        ``shapes.factors`` off, the onboard alternative: one range-bearing factor per detection on
        its reference variable, the other variables held by priors at the replay's shape (its
        first fit, where the replay's own priors held it: :meth:`.ShapeLandmarks.anchor`).
        Odometry, attitude, priors and the centroid classes' factors are the replay's.
        """
        g, sh = self.graph, self.graph.shapes
        shape_lms = [lm for lm in g.landmarks.values() if self.is_shape(lm.class_name)]
        dropped = {k for lm in shape_lms for k in self.shape_keys(lm.id)}
        out = gtsam.NonlinearFactorGraph()
        for i in range(g.history.size()):
            f = g.history.at(i)
            if f is not None and not any(k in dropped for k in f.keys()):  # noqa: SIM118 — a KeyVector
                out.add(f)
        live = [lm for lm in shape_lms if lm.alias_of is None and lm.in_graph]
        start = gtsam.Values(values)
        for k in dropped - {k for lm in live for k in self.shape_keys(lm.id)}:
            if start.exists(k):
                start.erase(k)
        for lm in live:
            if g.measured_as_point(lm):  # shapes reported, not optimised (shapes.factors off)
                shape = sh.estimate(lm.id, start)
                if shape is not None:
                    for f in sh.anchor(lm.id, shape):
                        out.add(f)
                for o in lm.observations:
                    out.add(g.bearing_range(o, lm.id))
                continue
            for owner, k, shape_body in sh.recs[lm.id].measured:
                T_world_body = start.atPose3(k).matrix()
                if sh.estimate(lm.id, start) is None:
                    sh.initial_values(lm.id, shapes.transform_shape(shape_body, T_world_body), start)
                est = sh.estimate(lm.id, start)
                out.add(sh.factor(k, k, owner, shape_body, T_world_body, est, g.noise.robust, on=lm.id))
            est = sh.estimate(lm.id, start)
            extent = (
                None if est is None else sh.extent_factor(lm.id, est, lambda k: start.atPose3(k).matrix())
            )
            if extent is not None:
                out.add(extent)
        return out, start

    def landmark_estimates(
        self, values: gtsam.Values, marginals: gtsam.Marginals | None, with_tentative: bool = True
    ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
        """Position and marginal covariance of every live landmark at ``values``.

        A landmark of the graph has its own; a tentative one (fewer detections than the
        association's ``min_observations``, possibly from another robot than its twin's) is where
        its detections put it from the optimised key poses, as uncertain as those key poses'
        positions plus a detection's own noise.
        """
        g = self.graph
        live = [lm for lm in g.live_landmarks() if lm.count and (lm.in_graph or with_tentative)]
        if marginals is None:
            return {}, {}
        pos: dict[int, np.ndarray] = {}
        cov: dict[int, np.ndarray] = {}
        for lm in live:
            if lm.in_graph:
                pos[lm.id] = g.point(lm.id, values)
                cov[lm.id] = g.position_covariance(
                    lm.id, marginals.marginalCovariance(g.position_key(lm.id)), values
                )
                continue
            seen = [
                (transform_points(values.atPose3(o.pose_key).matrix(), o.p_body[None])[0], o)
                for o in lm.observations
            ]
            pos[lm.id] = np.mean([q for q, _ in seen], axis=0)
            cov[lm.id] = np.mean(
                [
                    marginals.marginalCovariance(o.pose_key)[3:, 3:]
                    + g.noise.detection_variance(o.p_body) * np.eye(3)
                    for _, o in seen
                ],
                axis=0,
            )
        return pos, cov

    def optimised(self, values: gtsam.Values) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """Levenberg–Marquardt on :meth:`shared_graph` from ``values``: the graph and its optimum."""
        graph, start = self.shared_graph(values)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(100)
        return graph, gtsam.LevenbergMarquardtOptimizer(graph, start, params).optimize()

    @staticmethod
    def marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Marginals | None:
        try:
            return gtsam.Marginals(graph, values)
        except RuntimeError:  # an indeterminate system (should not happen with priors on every chain)
            return None

    def run(self, shape_fitter: ShapeFitter | None) -> MergeResult:
        g = self.graph
        for r in range(len(self.logs)):
            self.add_robot(r)
        graph, values = self.optimised(g.estimate)
        fused = 0
        for _ in range(self.p.refine_rounds):
            marginals = self.marginals(graph, values)
            if marginals is None:
                break
            n = 0
            if self.p.fuse_gate > 0:
                pos, cov = self.landmark_estimates(values, marginals)
                n += g.fuse_duplicates(
                    self.p.fuse_gate,
                    self.p.association.chi2,
                    lambda lm, pos=pos: pos[lm.id],
                    include=lambda lm, pos=pos: (
                        lm.id in pos and not self.is_shape(lm.class_name)
                    ),  # shapes: fuse_shapes
                    covariances=cov,
                    class_gate=self.p.association.class_gate,
                )
            n += self.fuse_shapes(values, marginals)
            if n == 0:
                break
            fused += n
            graph, values = self.optimised(values)
        return self.result(graph, values, fused, shape_fitter)

    # ---------------------------------------------------------------- result

    def result(
        self,
        graph: gtsam.NonlinearFactorGraph,
        values: gtsam.Values,
        fused: int,
        shape_fitter: ShapeFitter | None,
    ) -> MergeResult:
        g = self.graph
        lms = sorted(g.graph_landmarks(), key=lambda m: m.id)
        _, cov = self.landmark_estimates(values, self.marginals(graph, values), with_tentative=False)
        trajectories = [
            np.array([values.atPose3(robot_key(r, i)).matrix() for i in range(len(log.stamps))]).reshape(
                -1, 4, 4
            )
            for r, log in enumerate(self.logs)
        ]
        out, contributors = [], {}
        for new_id, lm in enumerate(lms):
            # The base has every detection's points: a shape fitted to all of them, moved with the
            # optimised key poses, beats the graph's, whose measurements saw a window of a log's
            # few points each (a box a few decimetres short); the graph's is the fallback.
            pts, noise = self.world_points_and_noise(lm, values)
            shape = None
            if shape_fitter is not None and len(pts):
                shape = shape_fitter(lm.class_name, pts)
            elif self.is_shape(lm.class_name) and len(pts):
                shape = self.fit_all(lm.class_name, pts, noise)
            if shape and shape.get("model") == "cuboid" == g.shapes.model(lm.class_name):
                shape = self.complete(lm, shape, values)
            shape = shape or g.shapes.estimate(lm.id, values)
            position = g.point(lm.id, values)
            if shape and shape.get("model") == g.shapes.model(lm.class_name):
                position = shapes.shape_center(shape)  # the fitted shape's reference point
            out.append(
                Landmark(
                    new_id,
                    lm.class_name,
                    position,
                    cov.get(lm.id, np.full((3, 3), np.nan)),
                    lm.count,
                    -1,
                    shape,
                    g.class_probabilities(lm),
                )
            )
            contributors[new_id] = tuple(sorted({o.robot for o in lm.observations}))
        out, contributors = self.reported_objects(lms, values, out, contributors)
        return MergeResult(
            out, trajectories, [log.robot for log in self.logs], contributors, fused, graph, values
        )

    def reported_objects(
        self,
        lms: list[LandmarkRec],
        values: gtsam.Values,
        out: list[Landmark],
        contributors: dict[int, tuple[int, ...]],
    ) -> tuple[list[Landmark], dict[int, tuple[int, ...]]]:
        """The object map as onboard reports it (``object_map: boxes``, :mod:`.object_boxes`):
        each centroid-class object at the box fitted to all its points (every robot's), twins
        folded into one; ``out`` and ``contributors`` are in the order of ``lms``."""
        if self.p.object_map != "boxes":
            return out, contributors
        mounts = {r: log.T_body_cam for r, log in enumerate(self.logs)}
        reported = reported_boxes(self.graph, values, mounts, self.p)
        new_id = {lm.id: i for i, lm in enumerate(lms)}  # out's ids
        reported = ObjectBoxes(
            {new_id[j]: box for j, box in reported.boxes.items()},
            {new_id[j]: new_id[into] for j, into in reported.folded.items()},
        )
        for gone, into in reported.folded.items():  # a folded twin's robots saw the survivor
            contributors[into] = tuple(sorted({*contributors[into], *contributors.pop(gone)}))
        return placed(out, reported), contributors


def merge_measurements(
    logs: Sequence[RobotMeasurements],
    params: MergeParams | None = None,
    shape_fitter: ShapeFitter | None = None,
) -> MergeResult:
    """Build and optimise the merged graph of several robots' measurement logs.

    Args:
        logs: one measurement log per robot (:func:`amslam.measurements.read_measurements`), each
            with its known base ``T_world_odom``; robots are replayed in this order.
        params: parameters of the merged graph (the onboard parts' defaults when omitted).
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
