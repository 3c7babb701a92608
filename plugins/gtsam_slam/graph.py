"""The semantic factor graph (paper 1 §V-B; paper 2 §IV-B): keys, noise models, fusion, marginals.

One :class:`SlamGraph` holds the variables of one map: key poses (one chain per robot, each robot's
keys made by its own :class:`PoseKeys`), point landmarks ``L(j)`` (``Point3``, the ``centroid``
classes) and the variables of the shape landmarks (:mod:`.shape_landmarks`, eqs. 1–2 of paper 2),
which have no ``L(j)``: a shape landmark's position is its reference point (cuboid centre,
cylinder root), read off its own variables (:meth:`SlamGraph.point`,
:meth:`SlamGraph.position_covariances`). It is
solved incrementally by iSAM2 (a fresh graph of new factors and values per update) and keeps the
whole history for marginals, eq. (10) and batch optimisation.

The onboard backend (:class:`.backend.GtsamSlam`) is one robot on a graph; the base station's
merge (:mod:`.merge`) is N robots on one graph. Both use the same :class:`NoiseModels`:

* VIO odometry between consecutive key poses: translation and yaw as random walks in the
  distance travelled (std ∝ √distance), yaw also per radian turned, roll and pitch tight (the IMU
  observes them); optionally an attitude factor per key pose (gravity);
* one factor per detection: ``BearingRangeFactor3D`` from a key pose to a point landmark, range
  noise growing with range, with a robust kernel; a shape class's detection is its eq. 1 / eq. 2
  factor alone (with ``shapes.factors`` off, a range-bearing factor on the shape's reference
  variable instead);
* a stiff zero-offset tie of the reference points fusing two landmarks of one object.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from amslam.lib import shapes
from amslam.plugins.gtsam_slam.information import LinearizedGraph
from amslam.plugins.gtsam_slam.params import GraphParams
from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks
from amslam.types import OdometryNoise

__all__ = [
    "GraphParams",
    "LandmarkRec",
    "NoiseModels",
    "Observation",
    "PoseKeys",
    "SlamGraph",
    "class_posterior",
]

#: detector scores are clipped to [SCORE_CLIP, 1 − SCORE_CLIP]: a score of 1 would make one
#: detection's label certain for good
SCORE_CLIP = 0.01


def class_posterior(evidence: dict[str, list[float]], classes: Iterable[str]) -> dict[str, float]:
    """An object's class posterior from its detections (a Bayesian update, not a score histogram).

    The detector reports its top class ``c`` and a score ``p``; read as a symmetric confusion
    model, ``P(c | true k) = p`` if ``c = k``, else ``(1 − p)/(K − 1)`` over the ``K`` classes the
    map knows (at least 2), with a uniform prior. Each detection multiplies the posterior of its
    own class by ``p (K − 1)/(1 − p)`` relative to every other (the common factor cancels), so
    ``ln P(k) = Σ_{i labelled k} (logit p_i + ln(K − 1))`` + const: ``evidence`` keeps, per
    label, ``[Σ logit p_i, count]``, and a class the map learns later is simply one more ``K``.
    One detection gives its label probability ``p``; agreeing ones sharpen it.
    """
    names = sorted(set(classes) | set(evidence))
    ln_other = math.log(max(len(names), 2) - 1)
    logs = np.array([evidence[c][0] + evidence[c][1] * ln_other if c in evidence else 0.0 for c in names])
    w = np.exp(logs - logs.max())
    return dict(zip(names, (w / w.sum()).tolist(), strict=True))


class NoiseModels:
    """The noise models of every factor the graph holds, and the variances association gates with."""

    def __init__(self, params: GraphParams) -> None:
        self.p = params

    def odometry(self, distance: float, dyaw: float) -> gtsam.noiseModel.Base:
        """VIO motion over ``distance`` metres turning ``dyaw`` radians."""
        return gtsam.noiseModel.Diagonal.Sigmas(self.odometry_noise().sigmas(distance, dyaw))

    def odometry_noise(self) -> OdometryNoise:
        """The odometry model as plain numbers (the planner's virtual factors use the same)."""
        p = self.p
        return OdometryNoise(
            translation=p.odometry_sigma_translation,
            vertical=p.odometry_sigma_vertical,
            translation_min=p.odometry_sigma_translation_min,
            yaw=p.odometry_sigma_yaw,
            yaw_per_rad=p.odometry_sigma_yaw_per_rad,
            yaw_min=p.odometry_sigma_yaw_min,
            roll_pitch=p.odometry_sigma_roll_pitch,
        )

    def drift_variance(self, travel: np.ndarray, ranges: np.ndarray) -> np.ndarray:
        """Variance (m², ranges × travel) a point seen at ``ranges`` moves by after ``travel`` m of VIO:
        the translation random walk, plus the yaw random walk's sweep at that range."""
        p = self.p
        return np.asarray(travel)[None, :] * (
            p.odometry_sigma_translation**2 + p.odometry_sigma_yaw**2 * np.asarray(ranges)[:, None] ** 2
        )

    def prior(self) -> gtsam.noiseModel.Base:
        """A robot's first key pose at its known start (base)."""
        p = self.p
        return gtsam.noiseModel.Diagonal.Sigmas(
            np.array([p.prior_sigma_rotation] * 3 + [p.prior_sigma_translation] * 3)
        )

    def robust(self, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
        """``base`` wrapped in the configured M-estimator (unchanged with ``robust="none"``)."""
        p = self.p
        if p.robust == "none":
            return base
        kernel = (
            gtsam.noiseModel.mEstimator.Huber.Create(p.robust_k)
            if p.robust == "huber"
            else gtsam.noiseModel.mEstimator.Cauchy.Create(p.robust_k)
        )
        return gtsam.noiseModel.Robust.Create(kernel, base)

    def bearing_range(
        self, rng: float, slack: float = 0.0, scale: float = 1.0, robust: bool = True
    ) -> gtsam.noiseModel.Base:
        """Range-bearing noise at range ``rng``; a shape's reference point from a partial view is as
        uncertain as its ``slack`` (m), and a window of points counts once (``scale``)."""
        p = self.p
        sigmas = np.array(
            [p.bearing_sigma + slack / max(rng, 1e-3)] * 2
            + [p.range_sigma + p.range_sigma_per_m * rng + slack]
        )
        base = gtsam.noiseModel.Diagonal.Sigmas(scale * sigmas)
        return self.robust(base) if robust else base

    def detection_variance(self, p_body: np.ndarray) -> float:
        """Isotropic variance (m²) of a detected point: the largest axis of its range-bearing noise."""
        p = self.p
        rng = float(np.linalg.norm(p_body))
        return max(p.range_sigma + p.range_sigma_per_m * rng, p.bearing_sigma * rng) ** 2

    def fusion(self) -> gtsam.noiseModel.Base:
        return self.robust(gtsam.noiseModel.Isotropic.Sigma(3, self.p.fusion_sigma))


@dataclass(frozen=True)
class PoseKeys:
    """The gtsam keys of one robot's key poses: ``X(i)`` onboard, a robot's own letter at the base."""

    char: str = "x"

    def __call__(self, i: int) -> int:
        return X(i) if self.char == "x" else gtsam.symbol(self.char, i)


@dataclass
class Observation:
    """One detection of a landmark: where it was seen from and where it was."""

    robot: int
    keypose: int  # index in that robot's chain
    pose_key: int  # the key pose's gtsam key
    distance: float  # the robot's travel at that key pose, m
    stamp: float
    class_name: str
    p_body: np.ndarray  # the object's point in the key pose's body frame
    p_odom: np.ndarray  # the same in the robot's odometry frame (VIO), for panoramas
    landmark: int  # the landmark the front end associated it with
    points: np.ndarray | None = None  # the object's points, body frame (kept at the base only)
    confidence: float = 1.0  # the detector's score of ``class_name``
    #: horizontal RMS spread of the detection's points about their centroid, m: how far the
    #: visible part's centroid may sit from the object's centre (``graph.spread_slack``)
    spread: float = 0.0


@dataclass
class LandmarkRec:
    id: int
    class_name: str
    first_keypose: int
    first_distance: float
    sum_world: np.ndarray
    robot: int = 0  # the robot that first saw it
    observations: list[Observation] = field(default_factory=list)
    in_graph: bool = False
    alias_of: int | None = None  # fused into this landmark; -1: dropped (a tentative one that expired)
    last_robot: int = 0  # who saw it last, and at which key pose / travel
    last_keypose: int = 0
    last_distance: float = 0.0
    var_sum: float = 0.0  # sum of the observations' isotropic position variances, m²
    #: class → [Σ logit(score), count] of the detections labelled with it (:func:`class_posterior`)
    class_evidence: dict[str, list[float]] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.observations)

    def add_class_evidence(self, class_name: str, score: float) -> None:
        """One detection labelled ``class_name`` with the detector's ``score``."""
        p = min(max(float(score), SCORE_CLIP), 1.0 - SCORE_CLIP)
        e = self.class_evidence.setdefault(class_name, [0.0, 0.0])
        e[0] += math.log(p / (1.0 - p))
        e[1] += 1.0

    def seen_by(self, robot: int, keypose: int, distance: float) -> None:
        """Record a sighting (kept monotonic per robot: a loop closure may tie it to an older pose)."""
        if robot != self.last_robot or distance >= self.last_distance:
            self.last_robot, self.last_keypose, self.last_distance = robot, keypose, distance


class SlamGraph:
    """Variables, factors, estimate and landmark records of one map (one or several robots)."""

    def __init__(self, params: GraphParams, shape_landmarks: ShapeLandmarks) -> None:
        self.p = params
        self.noise = NoiseModels(params)
        self.shapes = shape_landmarks
        isam_params = gtsam.ISAM2Params()
        isam_params.setFactorization(params.factorization)
        isam_params.setRelinearizeThreshold(params.relinearize_threshold)
        isam_params.relinearizeSkip = 1
        self._isam = gtsam.ISAM2(isam_params)
        self.history = gtsam.NonlinearFactorGraph()  # every factor ever added (IG, marginals, batch)
        self._new_graph = gtsam.NonlinearFactorGraph()
        self.new_values = gtsam.Values()
        self.estimate = gtsam.Values()
        # a cuboid's extent factor is replaced as its views grow: landmark → (index in history,
        # index in iSAM2 or None until flushed); landmark → its position in _new_graph; and the
        # iSAM2 indices of the replaced ones, removed at the next flush
        self._extents: dict[int, tuple[int, int | None]] = {}
        self._staged_extents: dict[int, int] = {}
        self._removed: list[int] = []
        self.version = 0
        self._cache: dict[str, tuple[int, object]] = {}
        self.landmarks: dict[int, LandmarkRec] = {}
        self.observations: list[Observation] = []
        self.classes: set[str] = set()  # every class detected so far (the posteriors' K)

    # ---------------------------------------------------------------- plumbing

    def add_factor(self, factor: gtsam.NonlinearFactor) -> None:
        self._new_graph.add(factor)
        self.history.add(factor)

    def flush(self, extra_iterations: int = 0) -> None:
        """One iSAM2 update with the new factors and values (a fresh graph each time)."""
        if self._new_graph.size() == 0 and self.new_values.size() == 0 and not self._removed:
            return
        result = self._isam.update(self._new_graph, self.new_values, self._removed)
        indices = result.getNewFactorsIndices()
        for lm_id, at in self._staged_extents.items():
            self._extents[lm_id] = (self._extents[lm_id][0], int(indices[at]))
        self._staged_extents, self._removed = {}, []
        for _ in range(extra_iterations):
            self._isam.update()
        self._new_graph = gtsam.NonlinearFactorGraph()
        self.new_values = gtsam.Values()
        self.estimate = self._isam.calculateEstimate()
        self.version += 1

    def measure_extent(self, lm_id: int) -> None:
        """(Re)place a cuboid landmark's one dims measurement by what its views reach now
        (:meth:`.ShapeLandmarks.extent_factor`): the previous one leaves iSAM2 at the next flush,
        and ``history`` holds the latest in its place."""
        est = self.shapes.estimate(lm_id, self.new_values) or self.shapes.estimate(lm_id, self.estimate)
        factor = None if est is None else self.shapes.extent_factor(lm_id, est, self.pose)
        if factor is None:
            return
        if lm_id in self._staged_extents:
            self._new_graph.replace(self._staged_extents[lm_id], factor)
            self.history.replace(self._extents[lm_id][0], factor)
            return
        if lm_id in self._extents:
            at, in_isam = self._extents[lm_id]
            self.history.replace(at, factor)
            self._removed.append(in_isam)
        else:
            at = self.history.size()
            self.history.add(factor)
        self._staged_extents[lm_id] = self._new_graph.size()
        self._new_graph.add(factor)
        self._extents[lm_id] = (at, None)

    def pose(self, key: int) -> np.ndarray:
        if self.new_values.exists(key):
            return self.new_values.atPose3(key).matrix()
        return self.estimate.atPose3(key).matrix()

    def shape_model(self, lm_id: int) -> str | None:
        """A landmark's shape model (``cuboid`` / ``cylinder``), or ``None`` for a point landmark."""
        model = self.shapes.model(self.landmarks[lm_id].class_name)
        return model if model in ("cuboid", "cylinder") else None

    def position_key(self, lm_id: int) -> int:
        """The variable holding a landmark's position: ``L(j)``, or a shape's reference variable."""
        model = self.shape_model(lm_id)
        return L(lm_id) if model is None else self.shapes.reference_key(model, lm_id)

    def point(self, lm_id: int, values: gtsam.Values | None = None) -> np.ndarray:
        """A landmark's position (world frame) at ``values`` (default: the current estimate, with the
        values not yet optimised): the point landmark, or the shape's reference point."""
        if values is None:
            values = self.new_values if self.new_values.exists(self.position_key(lm_id)) else self.estimate
        model = self.shape_model(lm_id)
        if model is None:
            return np.asarray(values.atPoint3(L(lm_id)))
        return self.shapes.reference_point(model, lm_id, values)

    def position_covariance(self, lm_id: int, marginal: np.ndarray, values: gtsam.Values) -> np.ndarray:
        """A landmark's 3 × 3 position covariance from the marginal of :meth:`position_key`."""
        model = self.shape_model(lm_id)
        return marginal if model is None else self.shapes.reference_covariance(model, lm_id, marginal, values)

    def position_covariances(self, lms: list[LandmarkRec]) -> dict[int, np.ndarray]:
        """Position covariances (landmark id → 3 × 3) of landmarks of the graph at the estimate."""
        keys = {lm.id: self.position_key(lm.id) for lm in lms}
        cov = self.marginals(list(keys.values()))
        return {j: self.position_covariance(j, cov[k], self.estimate) for j, k in keys.items() if k in cov}

    def cached(self, name: str, compute: Callable[[], object]) -> object:
        """``compute()``, once per graph version."""
        hit = self._cache.get(name)
        if hit is not None and hit[0] == self.version:
            return hit[1]
        value = compute()
        self._cache[name] = (self.version, value)
        return value

    # ---------------------------------------------------------------- key poses

    def add_first_pose(self, key: int, T_world_body: np.ndarray) -> None:
        """A robot's first key pose, held at its known start by a prior."""
        self.add_factor(gtsam.PriorFactorPose3(key, gtsam.Pose3(T_world_body), self.noise.prior()))
        self.new_values.insert(key, gtsam.Pose3(T_world_body))
        self._add_attitude(key, T_world_body)

    def add_odometry(
        self, prev_key: int, key: int, rel: np.ndarray, dyaw: float, T_world_body_vio: np.ndarray
    ) -> None:
        """The VIO motion ``rel`` from key pose ``prev_key`` to the new key pose ``key``, whose VIO
        pose (moved into the world frame by the known start) is ``T_world_body_vio``."""
        noise = self.noise.odometry(float(np.linalg.norm(rel[:3, 3])), dyaw)
        self.add_factor(gtsam.BetweenFactorPose3(prev_key, key, gtsam.Pose3(rel), noise))
        self.new_values.insert(key, gtsam.Pose3(self.pose(prev_key) @ rel))
        self._add_attitude(key, T_world_body_vio)

    def _add_attitude(self, key: int, T_world_body_vio: np.ndarray) -> None:
        # The IMU observes roll and pitch against gravity at every key pose; without this the
        # between-factors let the tilt random-walk along a long chain. The measured tilt is VIO's
        # (gravity-aligned), never the current estimate's: an estimate bent by a landmark would
        # otherwise be frozen into every later key pose (measured on a lot_team log: the chain
        # 0.65 m off the truth instead of VIO's 0.34 m).
        if self.p.attitude_sigma <= 0:
            return
        up = gtsam.Unit3(np.array([0.0, 0.0, 1.0]))
        noise = gtsam.noiseModel.Isotropic.Sigma(2, self.p.attitude_sigma)
        up_in_body = gtsam.Unit3(np.asarray(T_world_body_vio, float)[2, :3])
        self.add_factor(gtsam.AttitudeFactorPose3(key, up, noise, up_in_body))

    # ---------------------------------------------------------------- landmarks

    def new_landmark_id(self) -> int:
        return max(max(self.landmarks, default=-1), max(self.shapes.recs, default=-1)) + 1

    def live_id(self, lm_id: int) -> int:
        """The landmark an id stands for now (following fusions; a dropped one stands for itself)."""
        seen = {lm_id}
        while (nxt := self.landmarks[lm_id].alias_of) is not None and nxt >= 0 and nxt not in seen:
            lm_id = nxt
            seen.add(lm_id)
        return lm_id

    def live_landmarks(self) -> list[LandmarkRec]:
        """Landmarks in the graph or tentative, not fused into another nor dropped."""
        return [lm for lm in self.landmarks.values() if lm.alias_of is None]

    def graph_landmarks(self) -> list[LandmarkRec]:
        return [lm for lm in self.landmarks.values() if lm.in_graph and lm.alias_of is None]

    def landmark_position(self, lm: LandmarkRec) -> np.ndarray:
        return self.point(lm.id) if lm.in_graph else lm.sum_world / max(lm.count, 1)

    def class_probabilities(self, lm: LandmarkRec, also: Iterable[str] = ()) -> dict[str, float]:
        """A landmark's class posterior over the classes the map has seen and ``also`` (those of
        detections being associated) (:func:`class_posterior`)."""
        return class_posterior(lm.class_evidence, self.classes.union(also))

    def classes_agree(self, a: LandmarkRec, b: LandmarkRec, gate: float | None) -> bool:
        """Whether two landmarks may be one object by their classes: the same label (``gate``
        None), or each one's posterior gives the other's label at least ``gate`` (an object whose
        class posterior clearly disagrees is not merged)."""
        if gate is None:
            return a.class_name == b.class_name
        return (
            self.class_probabilities(a).get(b.class_name, 0.0) >= gate
            and self.class_probabilities(b).get(a.class_name, 0.0) >= gate
        )

    def landmark_variance(self, lm: LandmarkRec) -> float:
        """Isotropic variance of a landmark's position as the mean of its observations, m²."""
        return lm.var_sum / max(lm.count, 1) ** 2

    def bearing_range(self, ob: Observation, lm_id: int, robust: bool = True) -> gtsam.NonlinearFactor:
        """The range-bearing factor of an observation, from its key pose to landmark ``lm_id``'s
        position (:meth:`position_key`; the observation's own landmark or the one it was fused into).

        A point landmark is the centroid of the part in view, which moves with the viewpoint by
        about the object's size (a table's 0.45 m mean, a chair's 0.21 m): ``graph.spread_slack``
        × the detection's point spread (:attr:`Observation.spread`) widens the measurement by that
        much, so that re-observing a large object from another side does not bend the trajectory
        to make the two centroids one point."""
        pose_key, p_body = ob.pose_key, ob.p_body
        rng = float(np.linalg.norm(p_body))
        model = self.shape_model(lm_id)
        slack = self.shapes.point_slack(lm_id, pose_key)
        if model is None:
            slack = max(
                slack, self.p.spread_slack * ob.spread * np.sqrt(self._views_sharing_offset(ob, lm_id))
            )
        noise = self.noise.bearing_range(rng, slack, self.shapes.point_scale(lm_id, pose_key), robust)
        if model == "cuboid":  # to the box pose's translation, its centre
            return gtsam.BearingRangeFactorPose3(
                pose_key, self.position_key(lm_id), gtsam.Unit3(p_body), rng, noise
            )
        return gtsam.BearingRangeFactor3D(pose_key, self.position_key(lm_id), gtsam.Unit3(p_body), rng, noise)

    def _views_sharing_offset(self, ob: Observation, lm_id: int) -> int:
        """How many of the landmark's detections by this robot, this one included, were made within
        ``graph.spread_window`` seconds before it (1 with the window off)."""
        window = self.p.spread_window
        if window <= 0:
            return 1
        lm = self.landmarks.get(lm_id)
        seen = lm.observations if lm is not None else []
        return max(1, sum(1 for o in seen if o.robot == ob.robot and 0 <= ob.stamp - o.stamp <= window))

    def measured_as_point(self, lm: LandmarkRec) -> bool:
        """Whether a detection of ``lm`` is measured by a range-bearing factor: a point landmark's,
        or a shape's with ``shapes.factors`` off; otherwise its eq. 1 / eq. 2 factor alone
        (:meth:`observe_shape`) measures it."""
        return self.shape_model(lm.id) is None or not self.shapes.p.factors

    def observe(self, lm: LandmarkRec, ob: Observation, p_world: np.ndarray) -> None:
        """Record an observation; its range-bearing factor joins the graph if the landmark is in it
        and is measured as a point (:meth:`measured_as_point`)."""
        self.observations.append(ob)
        lm.observations.append(ob)
        self.classes.add(ob.class_name)
        lm.add_class_evidence(ob.class_name, ob.confidence)
        lm.sum_world = lm.sum_world + p_world
        lm.var_sum += self.noise.detection_variance(ob.p_body)
        lm.seen_by(ob.robot, ob.keypose, ob.distance)
        if lm.in_graph and self.measured_as_point(lm):
            self.add_factor(self.bearing_range(ob, lm.id))

    def admit(self, lm: LandmarkRec) -> None:
        """Put a tentative landmark into the graph with all its buffered observations (a shape
        landmark's variables and held-back measurements enter with :meth:`observe_shape`)."""
        lm.in_graph = True
        if self.shape_model(lm.id) is None:
            self.new_values.insert(L(lm.id), lm.sum_world / lm.count)
        if self.measured_as_point(lm):
            for o in lm.observations:
                self.add_factor(self.bearing_range(o, lm.id))

    def observe_shape(self, lm: LandmarkRec, pose_key: int, shape_body: dict) -> None:
        """Queue or add the eq. 1 / eq. 2 factor of one shape measurement (body frame) of ``lm``."""
        sh = self.shapes
        rec = sh.recs[lm.id]
        rec.pending.append((pose_key, shape_body))
        if not lm.in_graph:
            return
        if not rec.in_graph:
            first = shapes.transform_shape(shape_body, self.pose(pose_key))
            sh.initial_values(lm.id, first, self.new_values)
            if not sh.p.factors:  # shapes are reported, not optimised: their other variables anchored
                for f in sh.anchor(lm.id, first):
                    self.add_factor(f)
        if not sh.p.factors:
            rec.pending = []
            return
        est = sh.estimate(lm.id, self.new_values) or sh.estimate(lm.id, self.estimate)
        for k, s in rec.pending:
            self.add_factor(sh.factor(k, k, lm.id, s, self.pose(k), est, self.noise.robust))
        rec.measured += [(lm.id, k, s) for k, s in rec.pending]
        rec.pending = []
        self.measure_extent(lm.id)

    # ---------------------------------------------------------------- fusion

    @staticmethod
    def fusion_order(a: LandmarkRec, b: LandmarkRec) -> tuple[LandmarkRec, LandmarkRec] | None:
        """(survivor, fused) for two landmarks of one object, or None when they must stay apart.

        Two landmarks a single key pose observed are two objects. Otherwise the one seen first
        survives (the first robot's, at the base), unless only the other is in the graph; two
        tentative landmarks are left to the front end.
        """
        if {o.pose_key for o in a.observations} & {o.pose_key for o in b.observations}:
            return None
        old, new = (a, b) if (a.robot, a.first_distance) <= (b.robot, b.first_distance) else (b, a)
        if not old.in_graph:
            if not new.in_graph:
                return None
            old, new = new, old
        return old, new

    def fuse(self, target: LandmarkRec, dup: LandmarkRec, skip_pose_keys: Iterable[int] = ()) -> None:
        """Make ``dup`` an alias of ``target`` (which is in the graph): a stiff zero-offset tie, or
        its measurements moved over (except those from ``skip_pose_keys``, already tied)."""
        assert target.in_graph, "a duplicate is fused into a landmark of the graph"
        skip = set(skip_pose_keys)
        target.sum_world = target.sum_world + dup.sum_world
        if dup.in_graph:
            if self.shape_model(target.id) is None:
                self.add_factor(
                    gtsam.BetweenFactorPoint3(L(target.id), L(dup.id), np.zeros(3), self.noise.fusion())
                )
            else:
                self.add_factor(self.shapes.tie(target.id, dup.id, self.noise.fusion()))
        elif not self.measured_as_point(dup):
            # a tentative shape's held-back measurements become the target's, each still counted once
            sh = self.shapes
            est = sh.estimate(target.id, self.new_values) or sh.estimate(target.id, self.estimate)
            for k, s in sh.take_measurements(target.id, dup.id, skip):
                self.add_factor(sh.factor(k, k, target.id, s, self.pose(k), est, self.noise.robust))
                sh.recs[target.id].measured.append((target.id, k, s))
            self.measure_extent(target.id)
        else:
            for o in dup.observations:
                if o.pose_key not in skip:
                    self.add_factor(self.bearing_range(o, target.id))
        target.observations.extend(dup.observations)
        target.var_sum += dup.var_sum
        for c, (logits, n) in dup.class_evidence.items():
            e = target.class_evidence.setdefault(c, [0.0, 0.0])
            e[0] += logits
            e[1] += n
        if dup.last_distance > target.last_distance or dup.last_robot != target.last_robot:
            target.seen_by(dup.last_robot, dup.last_keypose, dup.last_distance)
        dup.observations = []
        dup.alias_of = target.id
        for o in self.observations:
            if o.landmark == dup.id:
                o.landmark = target.id

    def fuse_duplicates(
        self,
        max_distance: float,
        chi2: float,
        positions: Callable[[LandmarkRec], np.ndarray] | None = None,
        include: Callable[[LandmarkRec], bool] = lambda lm: True,
        covariances: dict[int, np.ndarray] | None = None,
        class_gate: float | None = None,
    ) -> int:
        """Fuse same-class landmarks that sit on each other and that no key pose saw apart.

        Two landmarks are one object when they are closer than ``max_distance`` and their
        difference is within the χ² gate ``chi2`` (the association's rule) of their position
        noise, and no key pose observed both (two detections in one view are two objects);
        :meth:`fusion_order` says which survives. The position noise is each landmark's
        isotropic observation variance, or with ``covariances`` (landmark id → 3×3 marginal) the
        sum of their marginals; pairs are then taken most likely first. ``positions`` (landmark →
        position) defaults to the current estimate; only the landmarks ``include`` accepts are
        considered, and their classes must agree (:meth:`classes_agree` with ``class_gate``).

        Returns:
            How many landmarks were fused.
        """
        where = positions or self.landmark_position
        live = [lm for lm in self.landmarks.values() if lm.alias_of is None and lm.count and include(lm)]

        def m2(a: LandmarkRec, b: LandmarkRec) -> float:
            """χ² of the pair (inf beyond ``max_distance`` or without marginals)."""
            diff = where(a) - where(b)
            d2 = float(diff @ diff)
            if d2 > max_distance**2:
                return np.inf
            if covariances is None:
                return d2 / (self.landmark_variance(a) + self.landmark_variance(b))
            if a.id not in covariances or b.id not in covariances:
                return np.inf
            return float(diff @ np.linalg.solve(covariances[a.id] + covariances[b.id], diff))

        pairs = [
            (a, b) for i, a in enumerate(live) for b in live[i + 1 :] if self.classes_agree(a, b, class_gate)
        ]
        if covariances is not None:
            pairs.sort(key=lambda ab: m2(*ab))
        fused = 0
        for a, b in pairs:
            if a.alias_of is not None or b.alias_of is not None or m2(a, b) > chi2:
                continue
            order = self.fusion_order(a, b)
            if order is None:
                continue
            self.fuse(*order)
            fused += 1
        return fused

    def fuse_shape_twins(self, twins: list[tuple[int, int]], emit: Callable[..., None]) -> int:
        """Fuse shape landmarks found to be one object (:meth:`.ShapeLandmarks.twins`).

        Two landmarks a single view observed are two objects and stay apart; otherwise
        :meth:`fusion_order` picks the survivor (it must be in the graph, else both wait until one
        is), with a stiff tie of the reference points (:meth:`fuse`), and its shape record takes
        the twin's points, cameras and per-key-pose slack.
        """
        fused = 0
        for a, b in twins:
            a, b = self.live_id(a), self.live_id(b)
            if a == b or a < 0 or b < 0:
                continue
            la, lb = self.landmarks[a], self.landmarks[b]
            if la.alias_of is not None or lb.alias_of is not None:
                continue
            order = self.fusion_order(la, lb)
            if order is None:
                continue
            old, new = order
            self.shapes.absorb(old.id, new.id)
            self.fuse(old, new)
            self.measure_extent(old.id)
            emit("slam_shape_twins_fused", kept=old.id, fused=new.id, cls=old.class_name)
            fused += 1
        return fused

    # ---------------------------------------------------------------- outputs

    def linearized(self) -> LinearizedGraph:
        self.flush()
        return self.cached("linearized", lambda: LinearizedGraph.build(self.history, self.estimate))

    def marginals(self, keys: list[int]) -> dict[int, np.ndarray]:
        """Marginal covariances of ``keys``: one elimination per graph version, each key's
        covariance computed once per version, when it is first asked for.

        ``gtsam.Marginals`` eliminates the whole graph at the current estimate (multifrontal
        Cholesky); measured faster than per-key ``ISAM2.marginalCovariance`` and than solving for
        every column of H⁻¹ (benchmarks/slam.py). A planner asking for the landmarks' marginals
        does not pay for the key poses' (2000 of them late in the demo's flight).
        """
        self.flush()
        if not keys:
            return {}
        elimination = self.cached("marginals", lambda: gtsam.Marginals(self.history, self.estimate))
        known: dict[int, np.ndarray] = self.cached("marginal_covariances", dict)
        for k in keys:
            if k not in known:
                known[k] = elimination.marginalCovariance(k)
        return {k: known[k] for k in keys}

    def optimise(self, max_iterations: int = 100) -> gtsam.Values:
        """Levenberg–Marquardt on the whole graph from the current estimate (batch smoothing)."""
        self.flush()
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        return gtsam.LevenbergMarquardtOptimizer(self.history, self.estimate, params).optimize()
