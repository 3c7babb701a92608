"""``gtsam`` SLAM backend: a semantic factor graph solved by iSAM2 (paper 1, §V-B, §V-C, §VI-C).

:class:`GtsamSlam` composes the parts, each in its own module, and implements
:class:`amslam.interfaces.Slam` with them:

* :mod:`.frontend` — key poses, data association (Mahalanobis gate, Hungarian), the tentative
  landmark buffer, and the shape front end (:mod:`.shape_landmarks`) for cuboid / cylinder /
  plane classes (``slam.keyposes``, ``slam.association``, ``slam.landmark_models``, ``slam.shapes``);
* :mod:`.graph` — variables and keys, noise models, fusion of duplicate landmarks, marginals
  (``slam.graph``);
* :mod:`.loop_closure` — semantic loop closure with :mod:`.slc` (``slam.loop_closure``);
* :mod:`.active` — SLC candidates and eq. (10) information gain with :mod:`.information`
  (``slam.active``).

The base station's merge (:mod:`.merge`) runs the same front end and graph for several robots.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from amslam.interfaces import BackendParams, RunContext, Slam
from amslam.plugins.gtsam_slam.params import (
    ActiveParams,
    AssociationParams,
    GraphParams,
    KeyPoseParams,
    LoopClosureParams,
    ObjectMap,
    ObjectTrimSpreads,
    ObjectTwinMargin,
    ObjectTwinShare,
    ShapeParams,
)
from amslam.types import (
    Detection,
    KeyPose,
    Landmark,
    LoopClosureResult,
    Odometry,
    PoseUncertainty,
    SlcCandidate,
    SlcGainModel,
)

if TYPE_CHECKING:
    import gtsam

__all__ = ["MOVED_PARAMETERS", "GtsamSlam"]

#: Object points kept per detection for the reported boxes (``object_map: boxes``): as many as the
#: measurement log keeps, ~10 MB over a 5000-detection flight.
KEPT_POINTS = 128


def _moved() -> dict[str, str]:
    """The flat parameter names of the backend before its parts had sections → their new paths."""
    moved = {
        "keypose_distance": "keyposes.distance",
        "keypose_yaw": "keyposes.yaw",
        "detection_keypose_distance": "keyposes.detection_distance",
        "detection_keypose_yaw": "keyposes.detection_yaw",
        "slc_merge_sigma": "graph.fusion_sigma",
        "min_observations": "association.min_observations",
        "tentative_timeout": "association.tentative_timeout",
        "min_confidence": "association.min_confidence",
        "max_range": "association.max_range",
        "dbscan_eps": "active.dbscan_eps",
        "cluster_min_landmarks": "active.cluster_min_landmarks",
        "floor_height": "active.floor_height",
        "ig_variables": "active.ig_variables",
    }
    for name in ("translation", "translation_min", "yaw", "yaw_per_rad", "yaw_min", "roll_pitch"):
        moved[f"odom_sigma_{name}"] = f"graph.odometry_sigma_{name}"
    for name in (
        "prior_sigma_translation",
        "prior_sigma_rotation",
        "bearing_sigma",
        "range_sigma",
        "range_sigma_per_m",
        "robust",
        "robust_k",
        "factorization",
        "relinearize_threshold",
    ):
        moved[name] = f"graph.{name}"
    for name in ("gate", "chi2", "ambiguity", "object_sigma", "track_distance"):
        moved[f"association_{name}"] = f"association.{name}"
    for name in LoopClosureParams.model_fields:
        moved[f"slc_{name}"] = f"loop_closure.{name}"
    return moved


#: Old flat parameter name → its path under the SLAM section now (a mission using one is refused).
MOVED_PARAMETERS: dict[str, str] = _moved()


class GtsamSlam(Slam):
    """Semantic SLAM on GTSAM iSAM2 with semantic loop closure and eq. (10) information gain."""

    requires = ("gtsam", "sklearn")  # imported when built (see Backend.requires)
    #: gtsam's calls hold the interpreter lock: the marginals of a 2000-key-pose graph stop every
    #: other thread for 0.2-0.4 s, so on a real vehicle the graph lives in a process of its own
    own_process = True

    class Params(BackendParams):
        keyposes: KeyPoseParams = Field(default_factory=KeyPoseParams, description="when key poses are made")
        graph: GraphParams = Field(default_factory=GraphParams, description="noise models and solver")
        association: AssociationParams = Field(
            default_factory=AssociationParams, description="data association and the tentative buffer"
        )
        loop_closure: LoopClosureParams = Field(
            default_factory=LoopClosureParams, description="semantic loop closure"
        )
        active: ActiveParams = Field(default_factory=ActiveParams, description="SLC candidates and eq. (10)")
        landmark_models: dict[str, Literal["centroid", "cuboid", "cylinder", "plane"]] = Field(
            default_factory=dict,
            description="landmark model per class ('*': every class not named; default centroid); cuboid /"
            " cylinder: paper 2's shape"
            " landmarks (eqs. 1-2); plane: ground points for the local ground planes, no landmarks",
        )
        shapes: ShapeParams = Field(default_factory=ShapeParams, description="shape landmark parameters")
        object_map: ObjectMap = "boxes"
        object_twin_margin: ObjectTwinMargin = 0.2
        object_twin_share: ObjectTwinShare = 0.6
        object_trim_spreads: ObjectTrimSpreads = 2.5

        @model_validator(mode="before")
        @classmethod
        def _refuse_moved_keys(cls, data: Any) -> Any:
            """One error per old flat key, at that key, naming where it lives now."""
            if isinstance(data, dict) and (moved := [k for k in data if k in MOVED_PARAMETERS]):
                raise ValidationError.from_exception_data(
                    cls.__name__,
                    [
                        InitErrorDetails(
                            type=PydanticCustomError(
                                "moved_parameter",
                                "moved: it is now slam.{new} (the gtsam parameters are grouped by part)",
                                {"new": MOVED_PARAMETERS[k]},
                            ),
                            loc=(k,),
                            input=data[k],
                        )
                        for k in moved
                    ],
                )
            return data

    def __init__(self) -> None:
        self.params: GtsamSlam.Params = GtsamSlam.Params()
        self._context: RunContext | None = None
        self._build(self.params, np.random.default_rng(0), lambda *a, **k: None)

    def _build(self, params: Params, rng: np.random.Generator, emit: Any) -> None:
        # The parts import gtsam (0.1 s) and scipy: imported when a backend is built, so that
        # listing plugins and validating a mission read GtsamSlam.Params without them.
        from amslam.plugins.gtsam_slam.active import ActiveSlam
        from amslam.plugins.gtsam_slam.frontend import FrontEnd
        from amslam.plugins.gtsam_slam.graph import SlamGraph
        from amslam.plugins.gtsam_slam.loop_closure import LoopCloser
        from amslam.plugins.gtsam_slam.shape_landmarks import ShapeLandmarks

        shape_landmarks = ShapeLandmarks(params.landmark_models, params.shapes, rng)
        self._graph = SlamGraph(params.graph, shape_landmarks)
        self._front = FrontEnd(
            self._graph,
            params.association,
            params.keyposes,
            emit=emit,
            keep_points=params.object_map == "boxes",
            max_kept_points=KEPT_POINTS,
        )
        self._T_body_cam: np.ndarray | None = None
        self._loops = LoopCloser(params.loop_closure, self._front, params.association.chi2, rng, emit)
        lc = params.loop_closure
        self._active = ActiveSlam(params.active, self._front, lc.panorama_radius, lc.min_matches)

    # ---------------------------------------------------------------- lifecycle

    def configure(self, params: Params, context: RunContext) -> None:
        """Set parameters and start an empty graph."""
        self.params = params
        self._context = context
        self._build(params, context.rng, context.emit)
        # What association, shape fitting and SLC candidates import on first use, imported now,
        # before take-off: on a real vehicle the first SLC candidates imported scikit-learn on the
        # planner thread holding this backend's lock, and the control loop waited 1.4 s for it
        # (a SITL flight's late_ticks.jsonl).
        import scipy.optimize  # noqa: F401
        import scipy.spatial  # noqa: F401
        import sklearn.cluster  # noqa: F401

    def close(self) -> None:
        """Nothing to release (the graph lives in memory); safe to call twice."""

    # ---------------------------------------------------------------- inputs

    def add_odometry(self, odom: Odometry) -> bool:
        """Track VIO; create a key pose every ``keyposes.distance`` m or ``keyposes.yaw`` rad."""
        return self._front.add_odometry(odom)

    def add_detections(self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]) -> None:
        """Associate detections (camera frame, made at VIO pose ``odom``) and add their factors."""
        self._T_body_cam = np.asarray(T_body_cam, float)
        self._front.add_detections(odom, T_body_cam, detections)

    def try_loop_closure(
        self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]
    ) -> LoopClosureResult:
        """Register the panorama's objects against old map landmarks (eqs. 2–6) and close the loop."""
        return self._loops.try_loop_closure(odom, T_body_cam, detections)

    # ---------------------------------------------------------------- outputs

    def T_world_odom(self) -> np.ndarray:
        """SLAM-minus-VIO correction at the latest key pose (drift compensation, §VI-E)."""
        return self._front.T_world_odom()

    def current_pose(self) -> np.ndarray:
        """World-frame body pose now: the correction applied to the latest VIO pose."""
        if self._front.last_odom is None:
            return np.eye(4)
        return self.T_world_odom() @ self._front.last_odom.T_odom_body

    @property
    def num_keyposes(self) -> int:
        """Number of key poses (cheaper than ``len(keyposes())``)."""
        return len(self._front.kps)

    def keyposes(self) -> list[KeyPose]:
        """Optimised key poses, oldest first (cached per graph version)."""
        g = self._graph
        g.flush()
        return list(
            g.cached(
                "keyposes",
                lambda: [
                    KeyPose(k.id, k.stamp, g.estimate.atPose3(k.key).matrix(), k.distance)
                    for k in self._front.kps
                ],
            )
        )

    def landmarks(self) -> list[Landmark]:
        """Landmarks in the graph with class, position, marginal covariance, observation count and
        class posterior (a shape landmark's position and covariance are its reference point's)."""
        g = self._graph
        lms = g.graph_landmarks()
        cov = g.position_covariances(lms)
        out = []
        for lm in lms:
            n = lm.count + sum(o.count for o in g.landmarks.values() if o.alias_of == lm.id)
            out.append(
                Landmark(
                    lm.id,
                    lm.class_name,
                    g.point(lm.id),
                    cov.get(lm.id, np.full((3, 3), np.nan)),
                    n,
                    lm.first_keypose,
                    g.shapes.estimate(lm.id, g.estimate),
                    g.class_probabilities(lm),
                )
            )
        return out

    def object_map(self) -> list[Landmark]:
        """:meth:`landmarks`, each centroid-class object at the box fitted to all its points and
        a landmark whose box is another's twin folded into it (``object_map: boxes``,
        :mod:`.object_boxes`); shape landmarks keep the graph's shape."""
        out = self.landmarks()
        if self.params.object_map != "boxes" or self._T_body_cam is None:
            return out
        from amslam.plugins.gtsam_slam.object_boxes import placed, reported_boxes

        reported = reported_boxes(self._graph, self._graph.estimate, self._T_body_cam, self.params)
        return placed(out, reported)

    def uncertainty(self) -> tuple[float, float]:
        """(mean trace of the 6×6 pose marginals, mean trace of the landmarks' position marginals)."""
        g = self._graph
        pose_keys = [k.key for k in self._front.kps]
        pose_cov = g.marginals(pose_keys)
        landmark_cov = g.position_covariances(g.graph_landmarks())
        if not pose_cov and not landmark_cov:
            return (0.0, 0.0)
        poses = [np.trace(c) for c in pose_cov.values()]
        lms = [np.trace(c) for c in landmark_cov.values()]
        return (float(np.mean(poses)) if poses else 0.0, float(np.mean(lms)) if lms else 0.0)

    def information_gain(self, keypose_ids: list[int], travel_distances: list[float]) -> np.ndarray:
        """Eq. (10) for a virtual odometry factor from the current pose to each key pose."""
        return self._active.information_gain(keypose_ids, travel_distances)

    def slc_gain_model(self, keypose_ids: list[int]) -> SlcGainModel | None:
        """Eq. (10) for chains of loop closures among the current key pose and ``keypose_ids``."""
        return self._active.slc_gain_model(keypose_ids)

    def pose_uncertainty(self) -> PoseUncertainty | None:
        """The latest key pose's position marginal, rotated into the world frame (gtsam's Pose3
        covariance is in the body frame's tangent space: roll, pitch, yaw, x, y, z), and the
        odometry noise of its factors. None before the first key pose."""
        kps = self._front.kps
        if not kps:
            return None
        g = self._graph
        key = kps[-1].key
        cov = g.marginals([key])[key]
        R = g.pose(key)[:3, :3]
        position = R @ cov[3:, 3:] @ R.T
        return PoseUncertainty(0.5 * (position + position.T), g.noise.odometry_noise())

    def virtual_factor(self, keypose_id: int, travel_distance: float) -> gtsam.BetweenFactorPose3:
        """The virtual factor :meth:`information_gain` evaluates (for brute-force checks)."""
        return self._active.virtual_factor(keypose_id, travel_distance)

    def slc_candidates(self, sensing_range: float) -> list[SlcCandidate]:
        """DBSCAN clusters of landmarks per floor → oldest key pose seeing the cluster → IG."""
        return self._active.slc_candidates(sensing_range)

    def graph(self) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """The whole factor graph and the current estimate (copies)."""
        import gtsam

        g = self._graph
        g.flush()
        return gtsam.NonlinearFactorGraph(g.history), gtsam.Values(g.estimate)
