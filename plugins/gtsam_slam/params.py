"""The parameter models of the ``gtsam`` SLAM backend's parts, apart from the parts themselves.

Validating a mission, listing plugins or printing ``amslam dump-config slam gtsam`` reads these
models only: keeping them in a module that imports neither gtsam nor scipy keeps those commands
instant (gtsam is imported when the backend is built, :meth:`GtsamSlam.configure`). Each part's
module re-exports its own model (``graph.GraphParams``, ``shape_landmarks.ShapeParams``, ...).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = [
    "ActiveParams",
    "AssociationParams",
    "GraphParams",
    "KeyPoseParams",
    "LoopClosureParams",
    "ObjectMap",
    "ObjectTrimSpreads",
    "ObjectTwinMargin",
    "ObjectTwinShare",
    "ShapeParams",
    "SizePrior",
]


#: a size or its spread, m: above zero and at most 100 m (no object is larger)
_Size = Annotated[float, Field(gt=0, le=100)]
_Percentile = Annotated[float, Field(gt=0, le=100)]

# The reported object map's rules (:mod:`.object_boxes`), one definition for the onboard backend's
# ``object_*`` parameters and the base merge's (``MergeParams``): both report objects alike.
ObjectMap = Annotated[
    Literal["boxes", "landmarks"],
    Field(
        description="the object map reported at the end (landmarks.json, the metrics): 'boxes', an"
        " object of a centroid class at the box fitted to all its detections' points, moved with the"
        " optimised key poses and completed with its class's median box (a visible part's middle"
        " sits on the viewer's side); 'landmarks', the graph's points",
    ),
]
ObjectTwinMargin = Annotated[
    float,
    Field(
        ge=0,
        le=10,
        description="reported boxes of a class that hold each other's centres within this margin (m),"
        " never seen from one key pose, are one object (object_map: boxes); 0.2 m halved the"
        " duplicates left on 5 seeds x 3 buildings (docs/objects.md)",
    ),
]
ObjectTwinShare = Annotated[
    float | None,
    Field(
        gt=0,
        le=1,
        description="a reported box of a class seen from fewer key poses is a part of another's object"
        " (a table's top or one face mapped again after the drift) when this share of its points lies"
        " inside the other's box inflated by object_twin_margin, never seen from one key pose with it;"
        " null: only the centres' rule (object_map: boxes; docs/objects.md)",
    ),
]
ObjectTrimSpreads = Annotated[
    float | None,
    Field(
        gt=0,
        le=100,
        description="a detection whose points' middle lies farther than this many of its landmark's"
        " median detection spreads from the middle of the landmark's detections is left out of the"
        " reported box (a neighbour's detection the association took under drift); null: all count"
        " (object_map: boxes; docs/objects.md)",
    ),
]


class SizePrior(BaseModel):
    """A class's typical box (for completing partial views) and its spread."""

    model_config = ConfigDict(defer_build=True, extra="forbid", allow_inf_nan=False)

    dims: tuple[_Size, _Size, _Size] = Field(description="typical length, width, height (length ≥ width), m")
    std: tuple[_Size, _Size, _Size] = Field(
        (0.4, 0.15, 0.3), description="spread of the class's length, width, height, m"
    )


class ShapeParams(BaseModel):
    """Parameters of the shape landmarks (``shapes:`` under the gtsam SLAM section)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", allow_inf_nan=False)

    window: float = Field(
        12.0, gt=0, le=3600, description="seconds of a landmark's points in one measurement"
    )
    min_points: int = Field(80, ge=10, le=1_000_000, description="fewest window points for a measurement")
    max_points: int = Field(
        6000, ge=100, le=1_000_000, description="window points kept per landmark (random thinning)"
    )
    voxel: float = Field(
        0.1,
        gt=0,
        le=10,
        description="ground buffer voxel size, m: one point per voxel across frames (0.04 per frame held"
        " 7x the points for the same plane within 0.5 mm: benchmarks/ground_buffer.py)",
    )
    ground_radius: float = Field(
        4.0, gt=0, le=1000, description="ground points within this of an object count, m"
    )
    ground_window: float = Field(60.0, gt=0, le=86_400, description="seconds of ground points kept")
    percentile: float = Field(2.5, ge=0, lt=25, description="cuboid extent percentiles (shapes.fit_cuboid)")
    extrapolate: bool = Field(
        False, description="extrapolate the percentiles to the edges (low-noise sensors)"
    )
    cylinder_axis: str = Field("vertical", description="vertical | ground | pca (shapes.fit_cylinder)")
    association_margin: float = Field(
        0.4, ge=0, le=100, description="overlap association: distance to a landmark's points or shape, m"
    )
    association_overlap: float = Field(0.4, gt=0, le=1, description="share of points inside to associate")
    return_gate: bool = Field(
        False,
        description="a cuboid landmark seen again after its window emptied takes the view only if the"
        " view's box and the landmark's hold one another's centre (ShapeLandmarks.agrees): the next car"
        " of a row lies against a drifted landmark's box; off: 4 of 9 PAMS flights where it acted"
        " better (docs/pams.md)",
    )
    max_radius: float = Field(
        1.0, gt=0, le=100, description="cylinder fits with a larger radius are rejected, m"
    )
    min_dim: float = Field(
        0.3, gt=0, le=100, description="cuboid fits with a smaller dimension are rejected, m"
    )
    max_dim: float = Field(
        8.0, gt=0, le=1000, description="cuboid fits with a larger dimension are rejected, m"
    )
    complete: bool = Field(
        True,
        description="complete partial cuboid views with the class size prior (shapes.complete_cuboid):"
        " a box is placed behind its visible faces, and its noise covers what was not seen",
    )
    size_prior: dict[str, SizePrior] = Field(
        default_factory=dict,
        description="per cuboid class, the typical box; a class not listed uses the median of the largest"
        " boxes of its landmarks once size_prior_min_boxes of them look complete",
    )
    size_prior_min_boxes: int = Field(
        3, ge=1, le=100_000, description="landmarks before a learned size prior is used"
    )
    completion_tolerance: float = Field(
        0.15, ge=0, le=100, description="shortfall of an extent that is noise, m"
    )
    seat_faces: bool = Field(
        False,
        description="move a box face every camera of the window saw head-on to where its points crowd"
        " (shapes.seat_seen_faces): the fit's percentile edge is the depth noise's tail on the"
        " cameras' side, 0.1-0.6 m toward the robot; halves that bias on PAMS flights but did not"
        " make their SLAM better (docs/pams.md), so off",
    )
    extent: bool = Field(
        True,
        description="measure a cuboid's dims once per landmark, by the extent its views reach (the"
        " extent_percentiles of its measurements' fitted dims: partial views bound the"
        " object from below), in place of each eq. 1 measurement's dims (their mean makes cars short)",
    )
    extent_percentiles: tuple[_Percentile, _Percentile] = Field(
        (95.0, 65.0),
        description="percentiles of a landmark's measured dims that are its extent: along its length,"
        " and along its width and height (calibrated on 4 PAMS flights: docs/pams.md)",
    )
    decorrelate: bool = Field(
        True,
        description="measurements of a landmark fitted to overlapping windows share their points: each"
        " one's noise is scaled by √(its landmark's measurements within the window), so a window of"
        " points counts once against the odometry",
    )
    factors: bool = Field(True, description="add the eq. 1 / eq. 2 factors (False: shapes are only reported)")
    view_noise: bool = Field(
        True,
        description="scale every sigma of a shape measurement by how well its window's views see the"
        " object, from the characterised uncertainty models (paper 2 §IV-C: position variance against"
        " range and viewing angle): √(window variance / the class's best-view variance), at least 1;"
        " the window variance is the harmonic mean over its cameras; classes without a model (nor one"
        " of their shape) are not scaled",
    )
    model_sigmas: bool = Field(
        False,
        description="a class with a characterised model is measured with its best look's translation and"
        " dimension std (the model's 5th-percentile look) in place of sigma_translation / sigma_dims, so"
        " that with view_noise a window's noise is the model's own at its views (paper 2: Σ = f^g(x, ℓ))",
    )
    uncertainty_models: Path | None = Field(
        None, description="models file (`amslam characterise`); None: the packaged defaults"
    )
    sigma_rotation: float = Field(0.1, gt=0, le=math.pi, description="cuboid pose rotation std, rad")
    sigma_translation: float = Field(0.3, gt=0, le=1000, description="cuboid / root translation std, m")
    sigma_dims: float = Field(0.3, gt=0, le=1000, description="cuboid dimension std, m")
    sigma_axis: float = Field(0.05, gt=0, le=10, description="cylinder axis std (per component)")
    sigma_radius: float = Field(0.03, gt=0, le=100, description="cylinder radius std, m")


class KeyPoseParams(BaseModel):
    """When key poses are made (``slam.keyposes``); yaw thresholds are at most π, the largest turn."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    distance: float = Field(0.5, gt=0, le=100, description="a key pose every this many metres")
    yaw: float = Field(0.35, gt=0, le=math.pi, description="or every this much yaw change, rad")
    detection_distance: float = Field(
        0.1, ge=0, le=100, description="detections farther than this from the last key pose get their own, m"
    )
    detection_yaw: float = Field(
        0.1,
        ge=0,
        le=math.pi,
        description="detections turned more than this from the last key pose get their own, rad",
    )


class AssociationParams(BaseModel):
    """Data association and the tentative buffer (``slam.association``; the merge's ``association``)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    gate: float = Field(0.6, gt=0, le=100, description="largest association distance, m")
    chi2: float = Field(
        11.34,
        gt=0,
        le=1000,
        description="Mahalanobis gate (χ², 3 dof; 11.34 = 99 %) on detection − landmark (at most 1000,"
        " a 31-σ gate: no gate at all)",
    )
    ambiguity: float = Field(
        4.6,
        ge=0,
        le=1000,
        description="a detection whose second-best landmark is within this many χ² units of the best"
        " is ambiguous and starts a new landmark (4.6 ≈ likelihood ratio 10)",
    )
    object_sigma: float = Field(
        0.15,
        ge=0,
        le=100,
        description="spread of an object's detected centroid across viewpoints (the visible part"
        " moves with the view), per axis, m",
    )
    track_distance: float = Field(
        3.0, ge=0, le=100_000, description="landmarks seen within this much travel are matched first, m"
    )
    min_observations: int = Field(3, ge=1, le=1000, description="observations before a landmark is trusted")
    tentative_timeout: int = Field(
        40, ge=1, le=1_000_000, description="key poses a tentative landmark may go unseen"
    )
    min_confidence: float = Field(0.3, ge=0, le=1, description="ignore weaker detections")
    max_range: float = Field(8.0, gt=0, le=1000, description="ignore detections farther than this, m")
    class_gate: float | None = Field(
        None,
        gt=0,
        le=1,
        description="None: a detection is associated only with landmarks of its class, and only"
        " landmarks of one class are fused. A probability: with landmarks whose class posterior"
        " (from their detections' scores, reported as class_probabilities) gives the detection's"
        " class at least this, and two landmarks fused only if each one's posterior gives the"
        " other's class at least this (a posterior that clearly disagrees keeps objects apart)",
    )


class GraphParams(BaseModel):
    """Noise models and solver of the factor graph (``slam.graph``; the merge's ``graph``).

    Every std has an upper bound a run can square and invert (10 m/√m of VIO drift, 1 km of prior);
    angle stds (rad) are at most π: a wider one says nothing about a direction."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    # VIO drifts as a random walk in the distance travelled (variance ∝ distance), so the std of
    # a relative pose grows with the square root of its length; these match the simulator's VIO.
    odometry_sigma_translation: float = Field(
        0.05, gt=0, le=10, description="VIO horizontal random walk per axis, m/√m travelled"
    )
    # A VIO aided by gravity and a barometer drifts far less in height (PX4's EKF2 fuses the
    # barometer; the simulator's VIO 0.012 m/√m). At the horizontal 0.05 the landmarks' heights,
    # biased by the side of an object in view, pulled the chain: in the imported PAL home the
    # estimate sank 1.0 m below the truth while VIO stayed within 0.05 m, and the flight's ceiling
    # sank with it.
    odometry_sigma_vertical: float = Field(
        0.012, gt=0, le=10, description="VIO vertical random walk, m/√m travelled"
    )
    odometry_sigma_translation_min: float = Field(
        0.005, gt=0, le=10, description="VIO translation std floor, m"
    )
    odometry_sigma_yaw: float = Field(
        0.004, ge=0, le=math.pi, description="VIO yaw random walk, rad/√m travelled"
    )
    odometry_sigma_yaw_per_rad: float = Field(0.01, ge=0, le=10, description="VIO yaw std per radian turned")
    odometry_sigma_yaw_min: float = Field(0.002, gt=0, le=math.pi, description="VIO yaw std floor, rad")
    odometry_sigma_roll_pitch: float = Field(0.002, gt=0, le=math.pi, description="roll/pitch std (IMU), rad")
    attitude_sigma: float = Field(
        0.0,
        ge=0,
        le=math.pi,
        description="std of each key pose's tilt against gravity (IMU), rad; 0: no attitude factors",
    )
    prior_sigma_translation: float = Field(
        0.01, gt=0, le=1000, description="prior on a robot's first pose, m"
    )
    prior_sigma_rotation: float = Field(
        0.005, gt=0, le=math.pi, description="prior on a robot's first pose, rad"
    )
    bearing_sigma: float = Field(0.05, gt=0, le=math.pi, description="bearing std of an object's point, rad")
    range_sigma: float = Field(0.05, gt=0, le=100, description="range std at zero range, m")
    range_sigma_per_m: float = Field(0.03, ge=0, le=10, description="range std growth per metre")
    # 1.0 since session 42: flown on 5 seeds x 3 buildings the SLAM RMS fell 0.266 -> 0.225 (one
    # floor), 0.251 -> 0.235 (demo), 0.157 -> 0.118 m (house); docs/objects.md, "Where the online
    # graph loses". 0 for detections without a view bias (a synthetic world's centre + noise).
    spread_slack: float = Field(
        1.0,
        ge=0,
        le=10,
        description="a point landmark's detection is as uncertain as this times its points' horizontal"
        " RMS spread (m) more, in range and across: the visible part's centroid moves with the view by"
        " about the object's size",
    )
    spread_window: float = Field(
        0.0,
        ge=0,
        le=3600,
        description="a point landmark's detections within this many seconds of each other share the"
        " visible part's offset: each one's spread slack is widened by the square root of how many"
        " of them there are, so together they weigh as one view, s (0: each view independent)",
    )
    robust: Literal["huber", "cauchy", "none"] = Field("huber", description="robust kernel")
    robust_k: float = Field(1.345, gt=0, le=100, description="robust kernel width (whitened units)")
    fusion_sigma: float = Field(
        0.05, gt=0, le=100, description="std of the zero-offset tie fusing two landmarks of one object, m"
    )
    factorization: Literal["QR", "CHOLESKY"] = Field(
        "QR", description="iSAM2 factorisation (gtsam 4.3 Cholesky fails at loop closures)"
    )
    relinearize_threshold: float = Field(0.01, gt=0, le=10, description="iSAM2 relinearisation threshold")


class LoopClosureParams(BaseModel):
    """Semantic loop closure (``slam.loop_closure``); yaw bounds are at most π (rad, rad/m)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    solver: Literal["scalable", "exhaustive"] = Field("scalable", description="SLC registration")
    tolerance: float = Field(0.3, gt=0, le=100, description="accepted RMS residual per landmark, m")
    inlier_gate: float = Field(0.5, gt=0, le=100, description="largest matched-pair error, m")
    min_matches: int = Field(3, ge=3, le=1000, description="fewest matched landmarks")
    ambiguity_ratio: float = Field(0.75, gt=0, le=1, description="runner-up share that rejects")
    min_age: float = Field(
        8.0,
        ge=0,
        le=100_000,
        description="map landmarks first seen within this travel (m) are not loop targets",
    )
    window: float = Field(30.0, gt=0, le=3600, description="panorama: detections of the last N seconds")
    panorama_radius: float = Field(1.0, gt=0, le=100, description="panorama: within this of the robot, m")
    merge_radius: float = Field(0.4, gt=0, le=100, description="same-class panorama detections merge, m")
    max_drift_sigmas: float = Field(
        4.0,
        gt=0,
        le=100,
        description="reject a correction beyond this many standard deviations of the odometry model's"
        " drift since the oldest matched landmark was first seen (graph.odometry_sigma_*), added to"
        " max_drift_floor in quadrature; never binds with the drift bound (prior) at its defaults",
    )
    max_drift_floor: float = Field(1.0, ge=0, le=1000, description="the correction refused at no travel, m")
    fuse_ratio: float = Field(
        0.5,
        gt=0,
        le=10,
        description="fuse a duplicate with its old twin only if their post-alignment error is below"
        " this share of tolerance (a looser pair still gets its range-bearing factors)",
    )
    prior: bool = Field(
        True,
        description="only corrections within the drift bound of the current estimate are candidates"
        " (False: the paper's search over all transforms)",
    )
    prior_translation_floor: float = Field(
        0.4, ge=0, le=1000, description="drift bound: position correction at zero untied travel, m"
    )
    prior_sigmas: float = Field(
        3.0,
        ge=0,
        le=100,
        description="drift bound: this many standard deviations of the odometry model's drift over"
        " the key poses flown since the map here was seen (graph.odometry_sigma_*), added to the"
        " floor in quadrature",
    )
    prior_yaw_floor: float = Field(
        0.15, ge=0, le=math.pi, description="drift bound: yaw correction at zero untied travel, rad"
    )


class ActiveParams(BaseModel):
    """Active loop-closure candidates and eq. (10) (``slam.active``)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    dbscan_eps: float = Field(2.5, gt=0, le=1000, description="DBSCAN neighbourhood of landmark clusters, m")
    cluster_min_landmarks: int = Field(3, ge=1, le=10_000, description="fewest landmarks of an SLC cluster")
    floor_height: float = Field(
        3.0, gt=0, le=100, description="height of a floor for per-floor clustering, m"
    )
    ig_variables: Literal["poses", "all"] = Field(
        "all", description="variables whose covariance trace eq. (10) measures"
    )
