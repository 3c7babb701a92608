"""``gtsam`` SLAM backend: a semantic factor graph solved by iSAM2 (paper 1, §V-B, §V-C, §VI-C).

Variables are key poses ``X(i)`` (``gtsam.Pose3``, world ← body) and object landmarks ``L(j)``
(centroids, ``Point3``). Factors:

* a prior on ``X(0)`` (the world frame is the odometry frame at start);
* VIO odometry ``x_i^vio ⊖ x_{i-1}^vio`` between consecutive key poses, noise scaled with the
  distance travelled and the yaw turned, roll and pitch tight (the IMU observes them);
* ``BearingRangeFactor3D`` from a key pose to each detected object centroid (detections arrive in
  the camera frame and are moved to the body with ``T_body_cam``), with a robust kernel;
* semantic loop-closure constraints: range-bearing factors from the panorama's key poses to the
  old landmarks found by :mod:`.slc`, and a zero-offset ``BetweenFactorPoint3`` fusing each
  duplicate landmark (created while drifting) with its old twin.

Key poses are created every ``keypose_distance`` metres or ``keypose_yaw`` radians, and whenever
objects are detected away from the last key pose. Data association is nearest neighbour per class
with a metric gate, one-to-one per frame (Hungarian). A new object is *tentative* until it has
been seen ``min_observations`` times; only then does it enter the graph with all its buffered
measurements, so a single false positive never reaches the optimiser.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X
from pydantic import Field
from scipy.optimize import linear_sum_assignment

from amslam.geometry import invert, wrap_angle, yaw_of
from amslam.interfaces import BackendParams, RunContext, Slam
from amslam.lib import shapes
from amslam.plugins.gtsam_slam import slc
from amslam.plugins.gtsam_slam.information import LinearizedGraph, virtual_factor
from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks, ShapeParams
from amslam.types import Detection, KeyPose, Landmark, LoopClosureResult, Odometry, SlcCandidate

__all__ = ["GtsamSlam"]


@dataclass
class _KeyPoseRec:
    id: int
    stamp: float
    T_odom_body: np.ndarray  # VIO pose when created
    distance: float


@dataclass
class _Observation:
    keypose: int
    stamp: float
    class_name: str
    p_body: np.ndarray  # centroid in the key pose's body frame
    p_odom: np.ndarray  # centroid in the odometry frame (VIO), for panoramas
    landmark: int  # id of the landmark the front end associated it with


@dataclass
class _LandmarkRec:
    id: int
    class_name: str
    first_keypose: int
    first_distance: float
    sum_world: np.ndarray
    observations: list[_Observation] = field(default_factory=list)
    in_graph: bool = False
    alias_of: int | None = None  # merged into this landmark by a loop closure
    last_keypose: int = 0
    var_sum: float = 0.0  # sum of the observations' isotropic position variances, m²

    @property
    def count(self) -> int:
        return len(self.observations)


class GtsamSlam(Slam):
    """Semantic SLAM on GTSAM iSAM2 with semantic loop closure and eq. (10) information gain."""

    class Params(BackendParams):
        keypose_distance: float = Field(0.5, gt=0, description="a key pose every this many metres")
        keypose_yaw: float = Field(0.35, gt=0, description="or every this much yaw change, rad")
        detection_keypose_distance: float = Field(
            0.1, ge=0, description="detections farther than this from the last key pose get their own, m"
        )
        detection_keypose_yaw: float = Field(
            0.1, ge=0, description="detections turned more than this from the last key pose get their own"
        )
        # VIO drifts as a random walk in the distance travelled (variance ∝ distance), so the std of
        # a relative pose grows with the square root of its length; these match the simulator's VIO.
        odom_sigma_translation: float = Field(
            0.05, gt=0, description="VIO translation random walk per axis, m/√m travelled"
        )
        odom_sigma_translation_min: float = Field(0.005, gt=0, description="VIO translation std floor, m")
        odom_sigma_yaw: float = Field(0.004, ge=0, description="VIO yaw random walk, rad/√m travelled")
        odom_sigma_yaw_per_rad: float = Field(0.01, ge=0, description="VIO yaw std per radian turned")
        odom_sigma_yaw_min: float = Field(0.002, gt=0, description="VIO yaw std floor, rad")
        odom_sigma_roll_pitch: float = Field(0.002, gt=0, description="roll/pitch std (IMU), rad")
        prior_sigma_translation: float = Field(0.01, gt=0, description="prior on the first pose, m")
        prior_sigma_rotation: float = Field(0.005, gt=0, description="prior on the first pose, rad")
        bearing_sigma: float = Field(0.05, gt=0, description="bearing std of an object centroid, rad")
        range_sigma: float = Field(0.05, gt=0, description="range std at zero range, m")
        range_sigma_per_m: float = Field(0.03, ge=0, description="range std growth per metre")
        robust: Literal["huber", "cauchy", "none"] = Field("huber", description="robust kernel")
        robust_k: float = Field(1.345, gt=0, description="robust kernel width (whitened units)")
        association_gate: float = Field(0.6, gt=0, description="largest association distance, m")
        association_chi2: float = Field(
            11.34, gt=0, description="Mahalanobis gate (χ², 3 dof; 11.34 = 99 %) on detection − landmark"
        )
        association_ambiguity: float = Field(
            4.6,
            ge=0,
            description="a detection whose second-best landmark is within this many χ² units of the best"
            " is ambiguous and starts a new landmark (4.6 ≈ likelihood ratio 10)",
        )
        association_object_sigma: float = Field(
            0.15,
            ge=0,
            description="spread of an object's detected centroid across viewpoints (the visible part"
            " moves with the view), per axis, m",
        )
        association_track_distance: float = Field(
            3.0, ge=0, description="landmarks seen within this much travel are matched first, m"
        )
        min_observations: int = Field(3, ge=1, description="observations before a landmark is trusted")
        landmark_models: dict[str, Literal["centroid", "cuboid", "cylinder", "plane"]] = Field(
            default_factory=dict,
            description="landmark model per class (default centroid); cuboid / cylinder: paper 2's shape"
            " landmarks (eqs. 1-2); plane: ground points for the local ground planes, no landmarks",
        )
        shapes: ShapeParams = Field(default_factory=ShapeParams, description="shape landmark parameters")
        tentative_timeout: int = Field(40, ge=1, description="key poses a tentative landmark may go unseen")
        min_confidence: float = Field(0.3, ge=0, le=1, description="ignore weaker detections")
        max_range: float = Field(8.0, gt=0, description="ignore detections farther than this, m")
        factorization: Literal["QR", "CHOLESKY"] = Field(
            "QR", description="iSAM2 factorisation (gtsam 4.3 Cholesky fails at loop closures)"
        )
        relinearize_threshold: float = Field(0.01, gt=0, description="iSAM2 relinearisation threshold")
        # semantic loop closure
        slc_solver: Literal["scalable", "exhaustive"] = Field("scalable", description="SLC registration")
        slc_tolerance: float = Field(0.3, gt=0, description="accepted RMS residual per landmark, m")
        slc_inlier_gate: float = Field(0.5, gt=0, description="largest matched-pair error, m")
        slc_min_matches: int = Field(3, ge=3, description="fewest matched landmarks")
        slc_ambiguity_ratio: float = Field(0.75, gt=0, le=1, description="runner-up share that rejects")
        slc_min_age: float = Field(
            8.0, ge=0, description="map landmarks first seen within this travel (m) are not loop targets"
        )
        slc_window: float = Field(30.0, gt=0, description="panorama: detections of the last N seconds")
        slc_panorama_radius: float = Field(1.0, gt=0, description="panorama: within this of the robot, m")
        slc_merge_radius: float = Field(0.4, gt=0, description="same-class panorama detections merge, m")
        slc_max_drift_ratio: float = Field(
            0.1, gt=0, description="reject corrections beyond this share of the distance travelled"
        )
        slc_max_drift_floor: float = Field(1.0, ge=0, description="plus this many metres")
        slc_merge_sigma: float = Field(0.05, gt=0, description="std of the duplicate-landmark fusion, m")
        slc_fuse_ratio: float = Field(
            0.5,
            gt=0,
            description="fuse a duplicate with its old twin only if their post-alignment error is below"
            " this share of slc_tolerance (a looser pair still gets its range-bearing factors)",
        )
        slc_prior: bool = Field(
            True,
            description="only corrections within the drift bound of the current estimate are candidates"
            " (False: the paper's search over all transforms)",
        )
        slc_prior_translation_floor: float = Field(
            0.4, ge=0, description="drift bound: position correction at zero untied travel, m"
        )
        slc_prior_translation_ratio: float = Field(
            0.03, ge=0, description="drift bound: plus this share of the travel since the map here was seen"
        )
        slc_prior_yaw_floor: float = Field(
            0.15, ge=0, description="drift bound: yaw correction at zero untied travel, rad"
        )
        slc_prior_yaw_ratio: float = Field(
            0.005, ge=0, description="drift bound: plus this much yaw per metre of untied travel, rad/m"
        )
        # active SLC
        dbscan_eps: float = Field(2.5, gt=0, description="DBSCAN neighbourhood of landmark clusters, m")
        cluster_min_landmarks: int = Field(3, ge=1, description="fewest landmarks of an SLC cluster")
        floor_height: float = Field(3.0, gt=0, description="height of a floor for per-floor clustering, m")
        ig_variables: Literal["poses", "all"] = Field(
            "all", description="variables whose covariance trace eq. (10) measures"
        )

    def __init__(self) -> None:
        self.params: GtsamSlam.Params = GtsamSlam.Params()
        self._context: RunContext | None = None
        self._isam: gtsam.ISAM2 | None = None
        self._graph = gtsam.NonlinearFactorGraph()  # the whole history (for IG and marginals)
        self._new_graph = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._estimate = gtsam.Values()
        self._kps: list[_KeyPoseRec] = []
        self._lms: dict[int, _LandmarkRec] = {}
        self._obs: list[_Observation] = []
        self._last_odom: Odometry | None = None
        self._distance = 0.0
        self._version = 0
        self._cache: dict[str, tuple[int, object]] = {}
        self._shapes = ShapeLandmarks({}, ShapeParams(), np.random.default_rng(0))
        self._shape_assoc: dict[int, int] = {}  # detection index → shape landmark (this call)
        self._shape_meas: dict[int, dict] = {}  # detection index → measured shape, body frame
        self._shape_version = -1  # graph version of the shape estimates used for association
        self._shape_twins: list[tuple[int, int]] = []  # (measured landmark, same-object landmark)

    # ---------------------------------------------------------------- lifecycle

    def configure(self, params: Params, context: RunContext) -> None:
        """Set parameters and start an empty graph."""
        self.params = params
        self._context = context
        self._shapes = ShapeLandmarks(params.landmark_models, params.shapes, context.rng)
        isam_params = gtsam.ISAM2Params()
        isam_params.setFactorization(params.factorization)
        isam_params.setRelinearizeThreshold(params.relinearize_threshold)
        isam_params.relinearizeSkip = 1
        self._isam = gtsam.ISAM2(isam_params)

    def close(self) -> None:
        """Drop the solver; safe to call twice."""
        self._isam = None

    # ---------------------------------------------------------------- noise models

    def _odometry_noise(self, distance: float, dyaw: float) -> gtsam.noiseModel.Base:
        p = self.params
        st = max(p.odom_sigma_translation_min, p.odom_sigma_translation * math.sqrt(distance))
        sy = p.odom_sigma_yaw * math.sqrt(distance) + p.odom_sigma_yaw_per_rad * abs(dyaw)
        sy = max(p.odom_sigma_yaw_min, sy)
        sr = p.odom_sigma_roll_pitch
        return gtsam.noiseModel.Diagonal.Sigmas(np.array([sr, sr, sy, st, st, st]))

    def _robust(self, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
        """``base`` wrapped in the configured M-estimator (unchanged with ``robust="none"``)."""
        p = self.params
        if p.robust == "none":
            return base
        kernel = (
            gtsam.noiseModel.mEstimator.Huber.Create(p.robust_k)
            if p.robust == "huber"
            else gtsam.noiseModel.mEstimator.Cauchy.Create(p.robust_k)
        )
        return gtsam.noiseModel.Robust.Create(kernel, base)

    def _measurement_noise(self, rng: float, robust: bool = True) -> gtsam.noiseModel.Base:
        p = self.params
        base = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([p.bearing_sigma, p.bearing_sigma, p.range_sigma + p.range_sigma_per_m * rng])
        )
        return self._robust(base) if robust else base

    # ---------------------------------------------------------------- graph plumbing

    def _add_factor(self, factor: gtsam.NonlinearFactor) -> None:
        self._new_graph.add(factor)
        self._graph.add(factor)

    def _flush(self, extra_iterations: int = 0) -> None:
        """One iSAM2 update with the new factors and values (a fresh graph each time)."""
        if self._new_graph.size() == 0 and self._new_values.size() == 0:
            return
        assert self._isam is not None, "configure() first"
        self._isam.update(self._new_graph, self._new_values)
        for _ in range(extra_iterations):
            self._isam.update()
        self._new_graph = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._estimate = self._isam.calculateEstimate()
        self._version += 1

    def _pose(self, i: int) -> np.ndarray:
        if self._new_values.exists(X(i)):
            return self._new_values.atPose3(X(i)).matrix()
        return self._estimate.atPose3(X(i)).matrix()

    def _point(self, j: int) -> np.ndarray:
        if self._new_values.exists(L(j)):
            return np.asarray(self._new_values.atPoint3(L(j)))
        return np.asarray(self._estimate.atPoint3(L(j)))

    def _cached(self, name: str, compute):  # noqa: ANN001, ANN202 — tiny private memo
        hit = self._cache.get(name)
        if hit is not None and hit[0] == self._version:
            return hit[1]
        value = compute()
        self._cache[name] = (self._version, value)
        return value

    # ---------------------------------------------------------------- key poses

    def _track(self, odom: Odometry) -> None:
        if self._last_odom is not None and odom.stamp >= self._last_odom.stamp:
            step = odom.T_odom_body[:3, 3] - self._last_odom.T_odom_body[:3, 3]
            self._distance += float(np.linalg.norm(step))
        self._last_odom = odom

    def _new_keypose(self, odom: Odometry) -> int:
        i = len(self._kps)
        T = odom.T_odom_body
        if i == 0:
            p = self.params
            sig = np.array([p.prior_sigma_rotation] * 3 + [p.prior_sigma_translation] * 3)
            prior = gtsam.noiseModel.Diagonal.Sigmas(sig)
            self._add_factor(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(T), prior))
            self._new_values.insert(X(0), gtsam.Pose3(T))
        else:
            prev = self._kps[-1]
            rel = invert(prev.T_odom_body) @ T
            d = float(np.linalg.norm(rel[:3, 3]))
            dyaw = wrap_angle(yaw_of(T) - yaw_of(prev.T_odom_body))
            self._add_factor(
                gtsam.BetweenFactorPose3(X(i - 1), X(i), gtsam.Pose3(rel), self._odometry_noise(d, dyaw))
            )
            self._new_values.insert(X(i), gtsam.Pose3(self._pose(i - 1) @ rel))
        self._kps.append(_KeyPoseRec(i, odom.stamp, T.copy(), self._distance))
        return i

    def _due(self, T: np.ndarray, dist: float, dyaw: float) -> bool:
        ref = self._kps[-1].T_odom_body
        return (
            float(np.linalg.norm(T[:3, 3] - ref[:3, 3])) >= dist
            or abs(wrap_angle(yaw_of(T) - yaw_of(ref))) >= dyaw
        )

    def add_odometry(self, odom: Odometry) -> bool:
        """Track VIO; create a key pose every ``keypose_distance`` m or ``keypose_yaw`` rad."""
        self._track(odom)
        p = self.params
        if self._kps and not self._due(odom.T_odom_body, p.keypose_distance, p.keypose_yaw):
            return False
        self._new_keypose(odom)
        self._expire_tentative()
        self._flush()
        return True

    # ---------------------------------------------------------------- detections

    def add_detections(self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]) -> None:
        """Associate detections (camera frame, made at VIO pose ``odom``) and add their factors."""
        p = self.params
        dets = [d for d in detections if d.confidence >= p.min_confidence]
        pts_cam = [np.asarray(d.centroid_cam, float) for d in dets]
        keep = [i for i, c in enumerate(pts_cam) if 1e-3 < np.linalg.norm(c) <= p.max_range]
        dets = [dets[i] for i in keep]
        if not dets:
            return
        if self._last_odom is None or odom.stamp > self._last_odom.stamp:
            self._track(odom)
        due = not self._kps or self._due(
            odom.T_odom_body, p.detection_keypose_distance, p.detection_keypose_yaw
        )
        kp = self._new_keypose(odom) if due else len(self._kps) - 1
        T_odom_kp = self._kps[kp].T_odom_body
        # Re-express the detections in the key pose's body frame with the (locally exact) VIO motion.
        T_kp_cam = invert(T_odom_kp) @ odom.T_odom_body @ T_body_cam
        p_body = np.array([T_kp_cam[:3, :3] @ pts_cam[i] + T_kp_cam[:3, 3] for i in keep])
        T_world_kp = self._pose(kp)
        if self.params.landmark_models:  # paper 2's shape landmarks: their own front end
            dets, p_body = self._shape_detections(odom.stamp, kp, T_kp_cam, dets, p_body)
            if not dets:
                self._expire_tentative()
                self._flush()
                return
        p_world = p_body @ T_world_kp[:3, :3].T + T_world_kp[:3, 3]
        p_odom = p_body @ T_odom_kp[:3, :3].T + T_odom_kp[:3, 3]
        assoc = self._associate([d.class_name for d in dets], p_world, p_body, self._kps[kp].distance)
        for i, lm_id in self._shape_assoc.items():
            assoc[i] = lm_id
        for k, (d, pb, pw, po, lm_id) in enumerate(zip(dets, p_body, p_world, p_odom, assoc, strict=True)):
            if lm_id < 0:
                lm_id = self._new_landmark_id()
                self._lms[lm_id] = _LandmarkRec(lm_id, d.class_name, kp, self._kps[kp].distance, np.zeros(3))
            lm = self._lms[lm_id]
            ob = _Observation(kp, odom.stamp, d.class_name, pb, po, lm_id)
            self._obs.append(ob)
            self._observe(lm, ob, pw)
            if k in self._shape_meas:
                self._shape_observe(lm, kp, self._shape_meas[k])
        if self._shape_twins:
            self._fuse_shape_twins()
        self._expire_tentative()
        self._flush()

    # ---------------------------------------------------------------- shape landmarks (paper 2)

    def _shape_detections(
        self, stamp: float, kp: int, T_kp_cam: np.ndarray, dets: list[Detection], p_body: np.ndarray
    ) -> tuple[list[Detection], np.ndarray]:
        """The shape-class front end (:mod:`.shape_landmarks`), before centroid association.

        ``plane`` detections feed the ground buffer and leave. A ``cuboid`` / ``cylinder``
        detection is associated by overlap, its points join its landmark's window and the
        window's fitted shape becomes the measurement: its reference point (box centre, cylinder
        root) replaces the visible-surface centroid as the detection's point, so ``L(j)`` is the
        shape's reference point. A detection that yields no shape is dropped.

        Returns:
            The detections and body-frame points that go on to :meth:`_associate`;
            ``self._shape_assoc`` / ``self._shape_meas`` hold, by their new index, the landmark
            and the measured shape of the shape-class ones.
        """
        sh = self._shapes
        T_odom_kp = self._kps[kp].T_odom_body
        T_odom_cam = T_odom_kp @ T_kp_cam
        T_world_kp = self._pose(kp)
        T_world_odom = T_world_kp @ invert(T_odom_kp)
        live = {lm.id: lm.class_name for lm in self._lms.values() if lm.alias_of is None}
        if self._shape_version != self._version:
            sh.refresh_estimates(self._estimate)
            self._shape_version = self._version
        out_d: list[Detection] = []
        out_p: list[np.ndarray] = []
        self._shape_assoc, self._shape_meas, self._shape_twins = {}, {}, []
        for d, pb in zip(dets, p_body, strict=True):
            model = sh.model(d.class_name)
            if model == "centroid":
                out_d.append(d)
                out_p.append(pb)
                continue
            pts = np.asarray(d.points_cam, float).reshape(-1, 3) @ T_odom_cam[:3, :3].T + T_odom_cam[:3, 3]
            if model == "plane":
                sh.add_ground(stamp, pts)
                continue
            if len(pts) == 0:
                continue
            pts_world = pts @ T_world_odom[:3, :3].T + T_world_odom[:3, 3]
            # two detections of one frame are two objects: a landmark this frame measured is taken
            taken = set(self._shape_assoc.values())
            free = {j: c for j, c in live.items() if j not in taken}
            lm_id = sh.associate(d.class_name, pts, pts_world, free, stamp)
            new = lm_id < 0
            if new:
                lm_id = max(self._new_landmark_id(), max(sh.recs, default=-1) + 1)
            shape_body = sh.measure(
                lm_id, d.class_name, stamp, pts, T_odom_kp, T_odom_cam[:3, 3], T_world_odom
            )
            if shape_body is None:
                if new:
                    sh.recs.pop(lm_id, None)
                continue
            if new:
                self._lms[lm_id] = _LandmarkRec(lm_id, d.class_name, kp, self._kps[kp].distance, np.zeros(3))
                live[lm_id] = d.class_name
            sh.set_world(lm_id, shapes.transform_shape(shape_body, T_world_kp))
            sh.record_slack(lm_id, kp, shape_body)
            self._shape_twins += [(lm_id, j) for j in sh.twins(lm_id, live)]
            k = len(out_d)
            self._shape_assoc[k] = lm_id
            self._shape_meas[k] = shape_body
            out_d.append(d)
            out_p.append(shapes.shape_center(shape_body))
        return out_d, np.array(out_p).reshape(-1, 3)

    def _shape_observe(self, lm: _LandmarkRec, kp: int, shape_body: dict) -> None:
        """Queue or add the eq. 1 / eq. 2 factor of one measurement of a shape landmark."""
        sh = self._shapes
        rec = sh.recs[lm.id]
        rec.pending.append((kp, shape_body))
        if not lm.in_graph:
            return
        if not rec.in_graph:
            T = self._pose(kp)
            sh.initial_values(lm.id, shapes.transform_shape(shape_body, T), self._new_values)
        est = sh.estimate(lm.id, self._new_values) or sh.estimate(lm.id, self._estimate)
        if not sh.p.factors:  # shapes are reported, not optimised: keep the variables anchored
            if not self._estimate.exists(gtsam.symbol("o" if rec.model == "cuboid" else "b", lm.id)):
                k, s = rec.pending[0]
                self._add_factor(sh.factor(X(k), k, lm.id, s, self._pose(k), est, lambda n: n))
            rec.pending = []
            return
        for k, s in rec.pending:
            T = self._pose(k)
            self._add_factor(sh.factor(X(k), k, lm.id, s, T, est, self._robust))
        rec.pending = []

    @staticmethod
    def _fusion_order(a: _LandmarkRec, b: _LandmarkRec) -> tuple[_LandmarkRec, _LandmarkRec] | None:
        """(survivor, fused) for two landmarks of one object, or None when they must stay apart.

        Two landmarks a single key pose observed are two objects. Otherwise the one seen first
        survives, unless only the other is in the graph; two tentative landmarks are left to the
        front end.
        """
        if {o.keypose for o in a.observations} & {o.keypose for o in b.observations}:
            return None
        old, new = (a, b) if a.first_distance <= b.first_distance else (b, a)
        if not old.in_graph:
            if not new.in_graph:
                return None
            old, new = new, old
        return old, new

    def _fuse_shape_twins(self) -> None:
        """Fuse shape landmarks found to be one object (:meth:`.ShapeLandmarks.twins`).

        Two landmarks a single view observed are two objects and stay apart; otherwise the one
        seen first survives (it must be in the graph, else both wait until one is), with a stiff
        tie of the reference points (:meth:`_fuse`), and its shape record takes the twin's
        points, cameras and per-key-pose slack.
        """
        sh = self._shapes
        for a, b in self._shape_twins:
            a, b = self._live_id(a), self._live_id(b)
            if a == b or a < 0 or b < 0:
                continue
            la, lb = self._lms[a], self._lms[b]
            if la.alias_of is not None or lb.alias_of is not None:
                continue
            order = self._fusion_order(la, lb)
            if order is None:
                continue
            old, new = order
            keep, gone = sh.recs[old.id], sh.recs[new.id]
            keep.points = sorted(keep.points + gone.points, key=lambda tq: tq[0])
            keep.cameras = sorted(keep.cameras + gone.cameras, key=lambda tq: tq[0])
            for kp, v in gone.slack.items():
                keep.slack.setdefault(kp, v)
            self._fuse(old, new)
            if self._context is not None:
                self._context.emit("slam_shape_twins_fused", kept=old.id, fused=new.id, cls=old.class_name)
        self._shape_twins = []

    def _new_landmark_id(self) -> int:
        return max(self._lms, default=-1) + 1

    def _landmark_position(self, lm: _LandmarkRec) -> np.ndarray:
        return self._point(lm.id) if lm.in_graph else lm.sum_world / max(lm.count, 1)

    def _detection_variance(self, p_body: np.ndarray) -> float:
        """Isotropic variance (m²) of a detected centroid: the largest axis of its range-bearing noise."""
        p = self.params
        rng = float(np.linalg.norm(p_body))
        return max(p.range_sigma + p.range_sigma_per_m * rng, p.bearing_sigma * rng) ** 2

    def _associate(
        self, classes: list[str], p_world: np.ndarray, p_body: np.ndarray, distance: float
    ) -> list[int]:
        """Per class, one-to-one (Hungarian) on Mahalanobis distance, tracked landmarks first.

        A metric nearest-neighbour gate wider than the spacing of similar objects (chairs 0.75 m
        apart) makes the estimate lock onto the neighbouring object and slide along a row of them.
        So the gate is statistical: the innovation variance is the detection's range-bearing noise,
        plus the spread of an object's centroid across viewpoints (the visible part moves with the
        view), plus the landmark's own estimate noise, plus the drift the robot may have accumulated
        relative to the landmark since it last saw it (VIO's random walk over that travel, in
        position and, through yaw, at the detection's range), capped by ``association_gate``.

        Landmarks seen within the last ``association_track_distance`` metres of travel are matched
        first (tracking: drift is negligible, the gate is tight); only detections none of them
        explains are matched against older landmarks. A detection that two candidates explain
        nearly equally well (χ² within ``association_ambiguity``) is not matched to either: it
        starts a new tentative landmark, which semantic loop closure fuses with its old twin later.
        A duplicate costs little; a wrong association corrupts the map.

        Returns, per detection, a landmark id or ``-1`` for a new landmark.
        """
        p = self.params
        out = [-1] * len(classes)
        live = [lm for lm in self._lms.values() if lm.alias_of is None]
        if not live:
            return out
        travel = np.array([max(0.0, distance - self._kps[lm.last_keypose].distance) for lm in live])
        recent = travel <= p.association_track_distance
        for stage in (recent, ~recent):
            todo = [i for i in range(len(classes)) if out[i] == -1]
            cands = [lm for lm, keep in zip(live, stage, strict=True) if keep]
            if not todo or not cands:
                continue
            m2, gated = self._innovations(
                [classes[i] for i in todo], p_world[todo], p_body[todo], cands, travel[stage]
            )
            if not gated.any():
                continue
            r, c = linear_sum_assignment(np.where(gated, m2, 1e9))
            for i, j in zip(r, c, strict=True):
                rivals = np.flatnonzero(gated[i])
                rivals = rivals[rivals != j]
                if gated[i, j] and not np.any(m2[i, rivals] - m2[i, j] < p.association_ambiguity):
                    out[todo[i]] = cands[j].id
        return out

    def _innovations(
        self,
        classes: list[str],
        p_world: np.ndarray,
        p_body: np.ndarray,
        cands: list[_LandmarkRec],
        travel: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Squared Mahalanobis distances detections × landmarks, and which pairs pass the gates."""
        p = self.params
        pos = np.array([self._landmark_position(lm) for lm in cands])
        lm_var = np.array([lm.var_sum / max(lm.count, 1) ** 2 for lm in cands])
        rng = np.linalg.norm(p_body, axis=1)
        det_var = np.array([self._detection_variance(pb) for pb in p_body])
        drift_var = travel[None, :] * (p.odom_sigma_translation**2 + p.odom_sigma_yaw**2 * rng[:, None] ** 2)
        d2 = np.sum((p_world[:, None, :] - pos[None, :, :]) ** 2, axis=2)
        m2 = d2 / (det_var[:, None] + p.association_object_sigma**2 + lm_var[None, :] + drift_var)
        same_class = np.array(classes)[:, None] == np.array([lm.class_name for lm in cands])[None, :]
        gated = same_class & (d2 <= p.association_gate**2) & (m2 <= p.association_chi2)
        return m2, gated

    def _bearing_range(
        self, kp: int, lm_id: int, p_body: np.ndarray, robust: bool = True
    ) -> gtsam.NonlinearFactor:
        rng = float(np.linalg.norm(p_body))
        noise = self._measurement_noise(rng, robust)
        slack = self._shapes.point_slack(lm_id, kp)
        scale = self._shapes.point_scale(lm_id, kp)
        if slack > 0 or scale != 1.0:  # a shape's reference point from a partial view: as uncertain
            p = self.params  # as its slack; and a window of points counts once (decorrelate)
            sig = [p.bearing_sigma + slack / max(rng, 1e-3)] * 2 + [
                p.range_sigma + p.range_sigma_per_m * rng + slack
            ]
            noise = gtsam.noiseModel.Diagonal.Sigmas(scale * np.array(sig))
            noise = self._robust(noise) if robust else noise
        return gtsam.BearingRangeFactor3D(X(kp), L(lm_id), gtsam.Unit3(p_body), rng, noise)

    def _observe(self, lm: _LandmarkRec, ob: _Observation, p_world: np.ndarray) -> None:
        lm.observations.append(ob)
        lm.sum_world = lm.sum_world + p_world
        lm.var_sum += self._detection_variance(ob.p_body)
        lm.last_keypose = ob.keypose
        if lm.in_graph:
            self._add_factor(self._bearing_range(ob.keypose, lm.id, ob.p_body))
        elif lm.count >= self.params.min_observations:
            lm.in_graph = True
            self._new_values.insert(L(lm.id), lm.sum_world / lm.count)
            for o in lm.observations:
                self._add_factor(self._bearing_range(o.keypose, lm.id, o.p_body))

    def _expire_tentative(self) -> None:
        if not self._kps:
            return
        now = len(self._kps) - 1
        timeout = self.params.tentative_timeout
        for lm in self._lms.values():
            if not lm.in_graph and lm.alias_of is None and now - lm.last_keypose > timeout:
                lm.alias_of = -1  # dropped: never re-associated, never reported

    # ---------------------------------------------------------------- outputs

    def T_world_odom(self) -> np.ndarray:
        """SLAM-minus-VIO correction at the latest key pose (drift compensation, §VI-E)."""
        if not self._kps:
            return np.eye(4)
        kp = self._kps[-1]
        return self._pose(kp.id) @ invert(kp.T_odom_body)

    def current_pose(self) -> np.ndarray:
        """World-frame body pose now: the correction applied to the latest VIO pose."""
        if self._last_odom is None:
            return np.eye(4)
        return self.T_world_odom() @ self._last_odom.T_odom_body

    @property
    def num_keyposes(self) -> int:
        """Number of key poses (cheaper than ``len(keyposes())``)."""
        return len(self._kps)

    def keyposes(self) -> list[KeyPose]:
        """Optimised key poses, oldest first (cached per graph version)."""
        self._flush()
        return list(
            self._cached(
                "keyposes",
                lambda: [
                    KeyPose(k.id, k.stamp, self._estimate.atPose3(X(k.id)).matrix(), k.distance)
                    for k in self._kps
                ],
            )
        )

    def _graph_landmarks(self) -> list[_LandmarkRec]:
        return [lm for lm in self._lms.values() if lm.in_graph and lm.alias_of is None]

    def _linearized(self) -> LinearizedGraph | None:
        self._flush()
        if not self._kps:
            return None
        return self._cached("linearized", lambda: LinearizedGraph.build(self._graph, self._estimate))

    def _marginals(self) -> dict[int, np.ndarray]:
        """Marginal covariances of every variable, computed once per graph version.

        ``gtsam.Marginals`` eliminates the whole graph at the current estimate (multifrontal
        Cholesky); measured faster than per-key ``ISAM2.marginalCovariance`` and than solving for
        every column of H⁻¹ (benchmarks/slam.py).
        """

        def compute() -> dict[int, np.ndarray]:
            if not self._kps:
                return {}
            self._flush()
            marginals = gtsam.Marginals(self._graph, self._estimate)
            keys = [X(k.id) for k in self._kps] + [L(lm.id) for lm in self._graph_landmarks()]
            return {k: marginals.marginalCovariance(k) for k in keys}

        return self._cached("marginals", compute)

    def landmarks(self) -> list[Landmark]:
        """Landmarks in the graph with class, position, marginal covariance and observation count."""
        cov = self._marginals()
        out = []
        for lm in self._graph_landmarks():
            n = lm.count + sum(o.count for o in self._lms.values() if o.alias_of == lm.id)
            out.append(
                Landmark(
                    lm.id,
                    lm.class_name,
                    self._point(lm.id),
                    cov.get(L(lm.id), np.full((3, 3), np.nan)),
                    n,
                    lm.first_keypose,
                    self._shapes.estimate(lm.id, self._estimate),
                )
            )
        return out

    def uncertainty(self) -> tuple[float, float]:
        """(mean trace of the 6×6 pose marginals, mean trace of the landmark marginals)."""
        cov = self._marginals()
        if not cov:
            return (0.0, 0.0)
        poses = [np.trace(cov[X(k.id)]) for k in self._kps if X(k.id) in cov]
        lms = [np.trace(cov[L(lm.id)]) for lm in self._graph_landmarks() if L(lm.id) in cov]
        return (float(np.mean(poses)) if poses else 0.0, float(np.mean(lms)) if lms else 0.0)

    # ---------------------------------------------------------------- information gain (eq. 10)

    def _ig_keys(self) -> list[int] | None:
        if self.params.ig_variables == "all":
            return None
        return [X(k.id) for k in self._kps]

    def information_gain(self, keypose_ids: list[int], travel_distances: list[float]) -> np.ndarray:
        """Eq. (10) for a virtual odometry factor from the current pose to each key pose.

        The factor's noise is the odometry model over ``travel_distances[i]`` metres. Each
        candidate is evaluated alone against the current graph; the estimate never changes.
        """
        lg = self._linearized()
        if lg is None or not keypose_ids:
            return np.zeros(len(keypose_ids))
        cur = self._kps[-1].id
        jac = []
        for k, dist in zip(keypose_ids, travel_distances, strict=True):
            dyaw = wrap_angle(yaw_of(self._pose(k)) - yaw_of(self._pose(cur)))
            _, J = virtual_factor(X(cur), X(k), self._estimate, self._odometry_noise(float(dist), dyaw))
            jac.append(J)
        return lg.information_gain(X(cur), [X(k) for k in keypose_ids], jac, self._ig_keys())

    def virtual_factor(self, keypose_id: int, travel_distance: float) -> gtsam.BetweenFactorPose3:
        """The virtual factor :meth:`information_gain` evaluates (for brute-force checks)."""
        cur = self._kps[-1].id
        dyaw = wrap_angle(yaw_of(self._pose(keypose_id)) - yaw_of(self._pose(cur)))
        noise = self._odometry_noise(travel_distance, dyaw)
        f, _ = virtual_factor(X(cur), X(keypose_id), self._estimate, noise)
        return f

    def graph(self) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """The whole factor graph and the current estimate (copies)."""
        self._flush()
        return gtsam.NonlinearFactorGraph(self._graph), gtsam.Values(self._estimate)

    # ---------------------------------------------------------------- active SLC candidates (§VI-C)

    def slc_candidates(self, sensing_range: float) -> list[SlcCandidate]:
        """DBSCAN clusters of landmarks per floor → oldest key pose seeing the cluster → IG.

        A cluster needs ``cluster_min_landmarks`` landmarks (three fix position and yaw). Its
        viewpoint is the oldest key pose from which any landmark of the cluster lies within
        ``sensing_range``; the candidate's information gain uses the straight-line distance from
        the current pose as the travel distance (the planner refines with path costs).
        """
        from sklearn.cluster import DBSCAN

        lms = self._graph_landmarks()
        if len(lms) < self.params.cluster_min_landmarks or not self._kps:
            return []
        pos = np.array([self._point(lm.id) for lm in lms])
        floors = np.floor(pos[:, 2] / self.params.floor_height).astype(int)
        kp_pos = np.array([self._pose(k.id)[:3, 3] for k in self._kps])
        cur = self._kps[-1].id
        out: list[tuple[int, np.ndarray, float, tuple[int, ...]]] = []
        for f in np.unique(floors):
            sel = np.flatnonzero(floors == f)
            if len(sel) < self.params.cluster_min_landmarks:
                continue
            labels = DBSCAN(eps=self.params.dbscan_eps, min_samples=1).fit(pos[sel]).labels_
            for lab in np.unique(labels):
                members = sel[labels == lab]
                if len(members) < self.params.cluster_min_landmarks:
                    continue
                i = self._slc_viewpoint(lms, members, pos, kp_pos, sensing_range)
                if i is None or i == cur:
                    continue
                T = self._pose(i)
                out.append((i, T[:3, 3].copy(), yaw_of(T), tuple(int(lms[j].id) for j in members)))
        if not out:
            return []
        here = self._pose(cur)[:3, 3]
        ig = self.information_gain([o[0] for o in out], [float(np.linalg.norm(o[1] - here)) for o in out])
        return [SlcCandidate(i, p, y, ids, float(g)) for (i, p, y, ids), g in zip(out, ig, strict=True)]

    def _slc_viewpoint(
        self,
        lms: list[_LandmarkRec],
        members: np.ndarray,
        pos: np.ndarray,
        kp_pos: np.ndarray,
        sensing_range: float,
    ) -> int | None:
        """The oldest key pose a panorama from which would see enough of the cluster.

        Paper 1 takes the oldest key pose within sensing range of a landmark of the cluster. An
        SLC needs ``slc_min_matches`` landmarks in one panorama, and range alone ignores walls:
        so prefer the oldest key pose where the landmarks actually *observed* from key poses
        within ``slc_panorama_radius`` of it (what a panorama there would see) number enough;
        fall back to the paper's rule when no key pose qualifies.
        """
        need = min(self.params.slc_min_matches, len(members))
        observed_from: dict[int, set[int]] = {}
        for j in members:
            for obs in lms[j].observations:
                observed_from.setdefault(obs.keypose, set()).add(int(j))
        if observed_from:
            kps = np.array(sorted(observed_from))
            near = (
                np.linalg.norm(kp_pos[kps][:, None] - kp_pos[kps][None], axis=2)
                <= self.params.slc_panorama_radius
            )
            for row, k in enumerate(kps):
                seen = set().union(*(observed_from[int(m)] for m in kps[near[row]]))
                close = np.linalg.norm(pos[list(seen)] - kp_pos[k], axis=1) <= sensing_range
                if close.sum() >= need:
                    return int(k)
        d = np.linalg.norm(kp_pos[:, None, :] - pos[members][None], axis=2)
        seen_any = np.flatnonzero((d <= sensing_range).any(axis=1))
        return int(seen_any[0]) if len(seen_any) else None

    # ---------------------------------------------------------------- semantic loop closure (§V-C)

    def _live_id(self, lm_id: int) -> int:
        """The landmark an id stands for now (following merges; a dropped one stands for itself)."""
        seen = {lm_id}
        while (nxt := self._lms[lm_id].alias_of) is not None and nxt >= 0 and nxt not in seen:
            lm_id = nxt
            seen.add(lm_id)
        return lm_id

    def _panorama(self, odom: Odometry) -> tuple[list[list[_Observation]], np.ndarray, list[str]]:
        """Objects seen in the current panorama, in the yaw-free local frame.

        Detections the front end associated with the same landmark are one object (one chair seen
        from several headings gives centroids more than ``slc_merge_radius`` apart, biased towards
        the visible side; splitting it would put several B points on one map landmark). Objects of
        one class whose centres (odometry frame) lie within ``slc_merge_radius`` are then merged:
        duplicates the drifting front end created for one physical object.
        """
        p = self.params
        T = odom.T_odom_body
        recent = [
            o
            for o in self._obs
            if odom.stamp - o.stamp <= p.slc_window
            and np.linalg.norm(self._kps[o.keypose].T_odom_body[:3, 3] - T[:3, 3]) <= p.slc_panorama_radius
        ]
        by_landmark: dict[int, list[_Observation]] = {}
        for o in recent:
            by_landmark.setdefault(self._live_id(o.landmark), []).append(o)
        groups: list[list[_Observation]] = []
        centres: list[np.ndarray] = []
        for obs in by_landmark.values():
            c = np.mean([q.p_odom for q in obs], axis=0)
            best, bd = -1, p.slc_merge_radius
            for g, (grp, cg) in enumerate(zip(groups, centres, strict=True)):
                dd = float(np.linalg.norm(cg - c))
                if grp[0].class_name == obs[0].class_name and dd <= bd:
                    best, bd = g, dd
            if best < 0:
                groups.append(list(obs))
                centres.append(c)
            else:
                groups[best].extend(obs)
                centres[best] = np.mean([q.p_odom for q in groups[best]], axis=0)
        psi = yaw_of(T)
        c, s = math.cos(psi), math.sin(psi)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        local = (np.array(centres).reshape(-1, 3) - T[:3, 3]) @ Rz  # Rzᵀ (p − t), row-wise
        return groups, local, [g[0].class_name for g in groups]

    def _slc_prior(
        self, odom: Odometry, old: list[_LandmarkRec], groups: list[list[_Observation]]
    ) -> tuple[slc.SlcPrior, np.ndarray]:
        """The current estimate of the robot's world yaw and position, and per-landmark drift bounds.

        A registration's correction is the drift of the estimate relative to the landmarks it
        matches, accumulated since the estimate was last tied to them: since each landmark was last
        observed by a detection *other than the panorama's own* (those are what the loop closure
        verifies), or since its first sighting. Landmark ``i`` thus bounds the correction by
        ``floor + ratio × untied_i`` (position and yaw alike), and a solution must respect the
        bound of every landmark it matches (:class:`.slc.SlcPrior`). A robot that returns after a
        long loop, whose detections made new duplicates instead of re-observing the old landmarks,
        gets a wide bound; one whose front end kept re-observing them a narrow one, which rules out
        alignments shifted by a row of a repeated layout.

        Returns:
            The prior and the untied travel of each landmark of ``old`` (m).
        """
        p = self.params
        T = self.T_world_odom() @ odom.T_odom_body
        own = {id(o) for g in groups for o in g}
        tie = np.array(
            [
                max(
                    (self._kps[o.keypose].distance for o in lm.observations if id(o) not in own),
                    default=lm.first_distance,
                )
                for lm in old
            ]
        )
        untied = np.maximum(self._distance - tie, 0.0)
        prior = slc.SlcPrior(
            yaw=yaw_of(T),
            translation=T[:3, 3].copy(),
            max_translation=p.slc_prior_translation_floor + p.slc_prior_translation_ratio * untied,
            max_yaw=p.slc_prior_yaw_floor + p.slc_prior_yaw_ratio * untied,
        )
        return prior, untied

    def try_loop_closure(
        self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]
    ) -> LoopClosureResult:
        """Register the panorama's objects against old map landmarks (eqs. 2–6) and close the loop.

        ``detections`` (seen now) are added first; the objects are all detections of the last
        ``slc_window`` seconds taken within ``slc_panorama_radius`` of the robot, so a panorama
        made of several ``add_detections`` calls is registered at once.
        """
        p = self.params
        if detections:
            self.add_detections(odom, T_body_cam, detections)
        if not self._kps:
            return LoopClosureResult(False, "no key poses yet")
        groups, B, cb = self._panorama(odom)
        if len(groups) < p.slc_min_matches:
            return LoopClosureResult(False, f"only {len(groups)} objects in view")
        now = self._distance
        old = [lm for lm in self._graph_landmarks() if lm.first_distance <= now - p.slc_min_age]
        if len(old) < p.slc_min_matches:
            return LoopClosureResult(False, f"only {len(old)} old landmarks in the map")
        A = np.array([self._point(lm.id) for lm in old])
        ca = [lm.class_name for lm in old]
        sp = slc.SlcParams(
            tolerance=p.slc_tolerance,
            inlier_gate=p.slc_inlier_gate,
            min_matches=p.slc_min_matches,
            ambiguity_ratio=p.slc_ambiguity_ratio,
        )
        rng = self._context.rng if self._context is not None else None
        prior, untied = self._slc_prior(odom, old, groups) if p.slc_prior else (None, np.zeros(0))
        bound: dict[str, float] = {}
        sol = (
            slc.solve_scalable(A, B, ca, cb, sp, prior=prior, rng=rng)
            if p.slc_solver == "scalable"
            else slc.solve_exhaustive(A, B, ca, cb, sp, prior=prior)
        )
        if prior is not None and sol.matched:
            # The bound the solution (or the rejected best) was held to: its freshest landmark's.
            fresh = int(sol.pairs[np.argmin(untied[sol.pairs[:, 0]]), 0])
            bound = dict(
                untied_distance=float(untied[fresh]),
                bound_translation=float(prior.max_translation[fresh]),
                bound_yaw=float(prior.max_yaw[fresh]),
            )
        if not sol.accepted:
            return self._report(LoopClosureResult(False, sol.reason, sol.matched, sol.rms), **bound)
        # The robot's world pose implied by the registration vs the current SLAM estimate.
        T = odom.T_odom_body
        Rz_vio = slc.yaw_matrix(yaw_of(T))
        T_world_body = np.eye(4)
        T_world_body[:3, :3] = slc.yaw_matrix(sol.yaw) @ Rz_vio.T @ T[:3, :3]
        T_world_body[:3, 3] = sol.translation
        before = self.T_world_odom() @ T
        dyaw = wrap_angle(yaw_of(T_world_body) - yaw_of(before))
        dt = float(np.linalg.norm(T_world_body[:3, 3] - before[:3, 3]))
        oldest = min(old[int(a)].first_distance for a, _ in sol.pairs)
        limit = p.slc_max_drift_floor + p.slc_max_drift_ratio * (now - oldest)
        if dt > limit:
            reason = f"correction {dt:.2f} m exceeds {limit:.2f} m"
            return self._report(LoopClosureResult(False, reason, sol.matched, sol.rms), **bound)
        self._close_loop(sol, old, groups, A, B)
        return self._report(LoopClosureResult(True, sol.reason, sol.matched, sol.rms, dyaw, dt), **bound)

    def _close_loop(
        self,
        sol: slc.SlcSolution,
        old: list[_LandmarkRec],
        groups: list[list[_Observation]],
        A: np.ndarray,
        B: np.ndarray,
    ) -> None:
        """Add the loop-closure constraints and let iSAM2 propagate the correction.

        A registration accepted at an RMS near the tolerance may hold a wrong pairing (chairs on a
        0.75 m grid against a 0.5 m inlier gate), so every loop-closure factor carries the robust
        kernel, and a duplicate is fused with its old twin (a stiff ``slc_merge_sigma`` constraint)
        only when that pair's own post-alignment error is below ``slc_fuse_ratio × slc_tolerance``.
        """
        p = self.params
        pair_err = np.linalg.norm(A[sol.pairs[:, 0]] - sol.transform(B[sol.pairs[:, 1]]), axis=1)
        for (a, b), err in zip(sol.pairs, pair_err, strict=True):
            target = old[int(a)]
            for o in groups[int(b)]:
                # The panorama's own measurement, now tied to the old landmark.
                self._add_factor(self._bearing_range(o.keypose, target.id, o.p_body))
            # The robot is tied to this landmark again: the front end may track it with a tight gate.
            target.last_keypose = max(target.last_keypose, max(o.keypose for o in groups[int(b)]))
            if err > p.slc_fuse_ratio * p.slc_tolerance:
                continue
            for dup_id in {o.landmark for o in groups[int(b)]} - {target.id}:
                dup = self._lms[dup_id]
                while dup.alias_of is not None and dup.alias_of >= 0 and dup.alias_of != target.id:
                    dup = self._lms[dup.alias_of]
                if dup.id == target.id or dup.alias_of == target.id:
                    continue
                self._fuse(target, dup, skip_keyposes={q.keypose for q in groups[int(b)]})
        # Large corrections need a few relinearisation rounds to settle.
        self._flush(extra_iterations=5)
        self._fuse_remaining_duplicates()

    def _fuse(self, target: _LandmarkRec, dup: _LandmarkRec, skip_keyposes: set[int] = frozenset()) -> None:
        """Make ``dup`` an alias of ``target`` (which is in the graph): a stiff zero-offset tie, or
        its measurements moved over."""
        assert target.in_graph, "a duplicate is fused into a landmark of the graph"
        p = self.params
        target.sum_world = target.sum_world + dup.sum_world
        if dup.in_graph:
            noise = self._robust(gtsam.noiseModel.Isotropic.Sigma(3, p.slc_merge_sigma))
            self._add_factor(gtsam.BetweenFactorPoint3(L(target.id), L(dup.id), np.zeros(3), noise))
        else:
            for o in dup.observations:
                if o.keypose not in skip_keyposes:
                    self._add_factor(self._bearing_range(o.keypose, target.id, o.p_body))
        target.observations.extend(dup.observations)
        target.var_sum += dup.var_sum
        target.last_keypose = max(target.last_keypose, dup.last_keypose)
        dup.observations = []
        dup.alias_of = target.id
        for o in self._obs:
            if o.landmark == dup.id:
                o.landmark = target.id

    def _fuse_remaining_duplicates(self) -> None:
        """After a loop closure, fuse same-class landmarks it brought together that no frame saw apart.

        The panorama matches only the objects it sees; duplicates of objects just outside it were
        also created while drifting and now, corrected, sit on their old twins. Two landmarks are
        one object when they are closer than ``slc_fuse_ratio × slc_tolerance`` (the bar matched pairs
        must pass to be fused) and within the χ² gate of each other's estimate noise, and no key pose
        observed both (two detections in one view are two
        objects). The older landmark survives.
        """
        p = self.params
        live = [lm for lm in self._lms.values() if lm.alias_of is None and lm.count]
        fused = False
        for i, a in enumerate(live):
            for b in live[i + 1 :]:
                if a.alias_of is not None or b.alias_of is not None or a.class_name != b.class_name:
                    continue
                d2 = float(np.sum((self._landmark_position(a) - self._landmark_position(b)) ** 2))
                var = a.var_sum / a.count**2 + b.var_sum / b.count**2
                if d2 > (p.slc_fuse_ratio * p.slc_tolerance) ** 2 or d2 > p.association_chi2 * var:
                    continue
                order = self._fusion_order(a, b)
                if order is None:
                    continue
                self._fuse(*order)
                fused = True
        if fused:
            self._flush(extra_iterations=2)

    def _report(self, result: LoopClosureResult, **extra: float) -> LoopClosureResult:
        if self._context is not None:
            self._context.emit(
                "slam_loop_closure",
                accepted=result.accepted,
                reason=result.reason,
                matched=result.matched,
                residual=result.residual,
                yaw_correction=result.yaw_correction,
                translation_correction=result.translation_correction,
                **extra,
            )
        return result
