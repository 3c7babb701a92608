"""The ``pams`` planner (paper 2 §IV-D) and the ``prior_visit`` baseline (paper 2 §V-A).

**Targets.** The objects of a prior map: ``prior_objects`` names a ``landmarks.json`` of an earlier
run (paper 2 §V: a prior map "which could come from the high-altitude UAV"; ``amslam experiment
pams`` flies that survey first); without one, the objects the SLAM backend has mapped so far
(``PlanRequest.landmarks``). Never the simulator's truth: a real robot has none. Only
``target_classes`` (default: every class the uncertainty models know) are targets. Their visiting
order is an open travelling-salesman tour from the robot (exact below 13 targets, 2-opt beyond:
:mod:`amslam.lib.tours`).

**Viewpoints per target.** Around the current target a polar grid of candidate positions (horizontal
distance × bearing, at the flight height) is scored with the fitted models
(:mod:`amslam.plugins.pams.uncertainty`): predicted confidence ``f^s(range, angle)`` and predicted
measurement variances ``f^g(range, angle)``. The valid set ``X^visible`` is the intersection of the
high-confidence region (confidence ≥ ``min_confidence``) and the low-uncertainty region (each
component's error predicted within ``max_position_error`` for positions, ``max_dimension_error``
for dimensions, with probability ``error_confidence``: paper 2's 95 %, 0.1 m, 0.2 m), minus cells
too close to other objects or outside the area. Samples are drawn from it either uniformly
(``sampling: uniform``, ``samples`` cells at random) or as the centroids of its connected regions
(``sampling: centroid``), paper 2 Fig. 6. Each faces the object.

**Information gain.** With horizon ``T``, every ordered choice of ``T`` of the ``a`` remaining
samples is a candidate path: ``P(a, T) = a!/(a−T)!`` of them. A target's geometric covariance is
updated recursively in information form, ``Σ_{t+1} = (Σ_t⁻¹ + R_{t+1}⁻¹)⁻¹`` with ``R`` the
models' predicted measurement covariance at that viewpoint, and the gain of a path is the drop
of differential entropy ``I = ½ ln det Σ_t − ½ ln det Σ_{t+τ}``. The path with the largest gain
wins (the information sum does not depend on the order, so ``cost_weight``·path length breaks
ties between orders of the same set). A target is done when its entropy falls below
``entropy_threshold`` (default: every component's std at ``target_std``) or its samples run out;
a path stops early at the viewpoint where the threshold is reached.

**Localisation constraint.** Paper 2 §IV-D minimises a target's uncertainty "while guaranteeing
that the classification confidence and robot localization uncertainty are within a threshold".
The first is the high-confidence region above; the second reads the SLAM backend's
:class:`~amslam.types.PoseUncertainty` (the latest key pose's position covariance and the
odometry noise that grows it): a path is a candidate only while the robot's predicted position
std stays within ``max_position_std`` along it (variance ``σ² + translation² · metres flown``,
the odometry's random walk with no correction on the way). When no path of the current target
fits — the robot already knows its position too poorly, or every sample is too far — it first
**relocalises**: it flies to look at the nearest landmark of the map known better than the bound
(its marginal position std below ``max_position_std``), from ``relocalise_range``, facing it,
where the SLAM backend's measurement of that landmark shrinks the pose's covariance. Each
landmark is used for that once; with none left the target is planned without the constraint
(event ``pams_localisation_unmet``), so a robot that cannot relocalise still maps. Without a
backend covariance (the odometry baseline) there is no constraint. The paper gives no number
(its footnote assumes accurate LIDAR-inertial odometry): the default 1 m is not calibrated.

**Bookkeeping.** A planner only sees the robot's position at each request, so a planned viewpoint
counts as *taken* (its information is added to the target) when the robot is found within
``reach_tolerance`` of it at a later request, as are the viewpoints planned before it on the same
path; when the robot is at none of them it gave up the first, which is dropped (unreachable)
after ``max_attempts`` such requests. Requests therefore never double-count information or retry a
blocked place forever.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, ValidationInfo, field_validator

from amslam.errors import PlanningError, RunFileError
from amslam.interfaces import (
    BackendParams,
    Coordinate,
    MissionFile,
    Planner,
    RunContext,
    check_mission_file,
    mission_file_path,
)
from amslam.lib.tours import exact_open_tour, nearest_neighbour_tour, two_opt
from amslam.plugins.pams.uncertainty import POSITION_COMPONENTS, ClassModel, UncertaintyModels
from amslam.rundir import read_landmarks
from amslam.types import BoundingBox, PlanRequest, PoseUncertainty, TourItem, TourItemKind

# -- targets -----------------------------------------------------------------------------------


@dataclass
class Target:
    """One object to map: its class, reference position, heading and half-size."""

    id: int
    class_name: str
    position: np.ndarray
    yaw: float = 0.0
    radius: float = 0.5  # horizontal half-diagonal, for clearance
    top: float = math.inf  # highest point (world z); unknown: as tall as anything
    shaped: bool = False  # has a cuboid or cylinder shape (a real obstacle, not a ground tile)


def _shape_radius_yaw(shape: dict | None, default_radius: float) -> tuple[float, float]:
    from amslam.lib.viewing import object_yaw

    if not shape:
        return default_radius, 0.0
    if shape.get("model") == "cuboid" and "dims" in shape:
        length, width = float(shape["dims"][0]), float(shape["dims"][1])
        return 0.5 * math.hypot(length, width), object_yaw(shape)
    if shape.get("model") == "cylinder":
        return float(shape.get("radius", default_radius)), 0.0
    return default_radius, object_yaw(shape)


def _shape_top(shape: dict | None) -> float:
    """Highest point of a shape (world z): cuboid centre + half height, cylinder root + height."""
    if shape and shape.get("model") == "cuboid" and "center" in shape and "dims" in shape:
        return float(shape["center"][2]) + 0.5 * float(shape["dims"][2])
    if shape and shape.get("model") == "cylinder" and "root" in shape and "height" in shape:
        return float(shape["root"][2]) + float(shape["height"])
    return math.inf


def _shaped(shape: dict | None) -> bool:
    return bool(shape) and shape.get("model") in ("cuboid", "cylinder")


def _shape_position(shape: dict | None, position: np.ndarray) -> np.ndarray:
    if shape and shape.get("model") == "cuboid" and "center" in shape:
        return np.asarray(shape["center"], float)
    if shape and shape.get("model") == "cylinder" and "root" in shape:
        return np.asarray(shape["root"], float)
    return np.asarray(position, float)


def load_prior_objects(path: Path, default_radius: float = 0.5) -> list[Target]:
    """Targets from a run's ``landmarks.json`` (:func:`amslam.rundir.read_landmarks`: a list of
    ``{id, class, position, shape?}``)."""
    try:
        data = read_landmarks(Path(path))
    except RunFileError as exc:  # names the file, and the landmark
        raise PlanningError(f"prior_objects: {exc}") from None
    out = []
    for i, lm in enumerate(data):
        shape = lm.get("shape")
        radius, yaw = _shape_radius_yaw(shape, default_radius)
        out.append(
            Target(
                int(lm.get("id", i)),
                str(lm["class"]),
                _shape_position(shape, np.asarray(lm["position"], float)),
                yaw,
                radius,
                _shape_top(shape),
                _shaped(shape),
            )
        )
    return out


def target_order(start: np.ndarray, positions: np.ndarray, exact_max: int = 12) -> list[int]:
    """Open TSP tour from ``start`` over ``positions`` (Euclidean), as indices into ``positions``."""
    if len(positions) == 0:
        return []
    nodes = np.vstack([np.asarray(start, float)[None, :2], np.asarray(positions, float)[:, :2]])
    costs = np.linalg.norm(nodes[:, None] - nodes[None], axis=2)
    idx = list(range(1, len(nodes)))
    tour = (
        exact_open_tour(costs, idx)
        if len(idx) <= exact_max
        else two_opt(costs, nearest_neighbour_tour(costs, idx))
    )
    return [k - 1 for k in tour]


# -- entropy and information gain ------------------------------------------------------------------


def entropy(cov: np.ndarray) -> float:
    """Differential entropy up to a constant: ½ ln det Σ (paper 2 §IV-D)."""
    sign, logdet = np.linalg.slogdet(np.asarray(cov, float))
    if sign <= 0:
        raise ValueError("covariance is not positive definite")
    return 0.5 * float(logdet)


def fuse(cov: np.ndarray, measurement_covs: list[np.ndarray]) -> np.ndarray:
    """Recursive covariance update in information form: ``Σ⁻¹ ← Σ⁻¹ + Σ R_k⁻¹``."""
    info = np.linalg.inv(cov)
    for R in measurement_covs:
        info = info + np.linalg.inv(R)
    return np.linalg.inv(info)


def information_gain(cov: np.ndarray, measurement_covs: list[np.ndarray]) -> float:
    """``I = ½ ln det Σ_t − ½ ln det Σ_{t+τ}`` after fusing the measurements."""
    return entropy(cov) - entropy(fuse(cov, measurement_covs))


def count_paths(a: int, T: int) -> int:
    """Number of ordered paths of ``T`` of ``a`` samples: ``a!/(a−T)!`` (0 if T > a)."""
    return math.perm(a, T)


# -- parameters ----------------------------------------------------------------------------------


def _prior_objects_file(value: str | None, info: ValidationInfo) -> str | None:
    """``prior_objects``: a landmarks file that is there and readable."""
    if value == "world":  # what earlier versions accepted: said plainly, not "no such file"
        raise ValueError(
            "'world' (the simulator's true objects) is no longer a prior map: a real robot has no such "
            "thing. Name the landmarks.json of a survey flight (amslam experiment pams flies one first), "
            "or leave prior_objects out to target the objects SLAM has mapped"
        )
    return check_mission_file(value, info)


class _VisitParams(BackendParams):
    """What both object-visiting planners (``pams`` and its ``prior_visit`` baseline) share: the
    prior map, where the robot may look from and when a stop is done."""

    prior_objects: str | None = Field(
        None,
        description="landmarks.json of an earlier run, e.g. an overhead survey (relative to the mission"
        " file); None = the objects SLAM has mapped so far",
    )
    height: Coordinate | None = Field(
        None, description="flight height of the stops (world z); None = the robot's"
    )
    clearance: float = Field(
        1.0, ge=0.0, le=100, description="stops keep this far from every object's footprint, m"
    )
    overfly: float | None = Field(
        None,
        ge=0.0,
        le=1000,
        description="objects whose top is this far (m) below the stops' height do not block them; "
        "None = every object's footprint (plus clearance) blocks",
    )
    reach_tolerance: float = Field(
        1.0, gt=0.0, le=1000, description="a stop counts as reached within this, m"
    )
    max_attempts: int = Field(
        3,
        ge=1,
        le=1000,
        description="times a stop may be given up (the robot's first open stop) before it is dropped",
    )
    default_radius: float = Field(0.5, gt=0.0, le=100, description="half-size of objects without a shape, m")

    _prior_file = field_validator("prior_objects")(_prior_objects_file)


class PamsParams(_VisitParams):
    """Parameters of the ``pams`` planner."""

    @field_validator("models")
    @classmethod
    def _models_load(cls, value: str | None, info: ValidationInfo) -> str | None:
        # present and readable (MissionFile) is not enough: a truncated file is named here, not mid-run
        path = mission_file_path(value, info) if value is not None else None
        if path is not None and path.is_absolute():
            try:
                UncertaintyModels.load(path)
            except Exception as exc:  # noqa: BLE001 — any reason it cannot be read, in one line
                raise ValueError(
                    f"not readable uncertainty models ({type(exc).__name__}: {exc}): {path}"
                ) from None
        return value

    models: MissionFile | None = Field(
        None, description="uncertainty models (.npz from `amslam characterise`); None = the packaged ones"
    )
    target_classes: list[str] | None = Field(None, description="classes to map; None = every modelled class")
    horizon: int = Field(3, ge=1, le=5, description="planning horizon T (viewpoints per path)")
    sampling: Literal["uniform", "centroid"] = Field("centroid", description="how samples are drawn (Fig. 6)")
    samples: int = Field(8, ge=1, le=10_000, description="uniform sampling: samples per target")
    min_confidence: float = Field(0.8, ge=0.0, le=1.0, description="high-confidence region threshold")
    # Paper 2 Fig. 6: "95 % confidence in localization and dimension estimation (with less than
    # 0.1 m and 0.2 m error, respectively)": a cell qualifies when a measurement's error on each
    # component is predicted within the limit with that probability (Gaussian: std ≤ limit / 1.96).
    max_position_error: float = Field(
        0.1, gt=0.0, le=100, description="low-uncertainty region: position error limit, m"
    )
    max_dimension_error: float = Field(
        0.2, gt=0.0, le=100, description="low-uncertainty region: dimension error limit, m"
    )
    error_confidence: float = Field(
        0.95,
        gt=0.0,
        lt=1.0,
        description="low-uncertainty region: probability that each error is within its limit",
    )
    min_region_share: float = Field(
        0.1,
        gt=0.0,
        le=1.0,
        description="if the intersection is empty, the lowest-entropy share of the confident cells instead",
    )
    range_step: float = Field(
        0.5,
        ge=0.05,
        le=100,
        description="grid step of the horizontal distance, m (from 0.05: the grid of candidates stays small)",
    )
    bearing_step_deg: float = Field(
        10.0,
        ge=0.5,
        le=360,
        description="grid step of the bearing, degrees (from 0.5: the grid of candidates stays small)",
    )
    max_distance: float = Field(12.0, gt=0.0, le=200, description="farthest candidate from a target, m")
    prior_std: float = Field(0.5, gt=0.0, le=1000, description="std of every component before any look, m")
    target_std: float = Field(
        0.05, gt=0.0, le=1000, description="stop when the entropy is that of this std per component"
    )
    entropy_threshold: float | None = Field(
        None, ge=-1000, le=1000, description="explicit stop threshold on ½ ln det Σ, nats"
    )
    cost_weight: float = Field(
        0.01, ge=0.0, le=1000, description="nats per metre of path: breaks ties between orders"
    )
    max_position_std: float | None = Field(
        1.0,
        gt=0.0,
        le=1000,
        description="localisation constraint: paths keep the robot's predicted position std within"
        " this, m (relocalising at a known landmark first when none does); None = no constraint",
    )
    relocalise_range: float = Field(
        3.0, gt=0.0, le=100, description="distance from which a landmark is looked at to relocalise, m"
    )


def region_std_limits(params: PamsParams, components: list[str]) -> np.ndarray:
    """Each component's largest predicted std inside the low-uncertainty region: its error limit
    over the two-sided Gaussian quantile of ``error_confidence`` (0.1 m / 1.96 ≈ 0.051 m at 95 %)."""
    from scipy.special import erfinv  # imported when PAMS samples, not when it is listed

    z = math.sqrt(2.0) * float(erfinv(params.error_confidence))
    errors = [
        params.max_position_error if c in POSITION_COMPONENTS else params.max_dimension_error
        for c in components
    ]
    return np.array(errors) / z


class PriorVisitParams(_VisitParams):
    """Parameters of the ``prior_visit`` baseline."""

    target_classes: list[str] | None = Field(None, description="classes to visit; None = every class")
    standoff: float = Field(
        3.0, gt=0.0, le=1000, description="horizontal distance from an object's edge to look from, m"
    )


# -- shared bookkeeping ---------------------------------------------------------------------------


@dataclass
class _Pending:
    """A planned stop: target id, sample index, position, requests it has stayed unreached."""

    target: int
    sample: int
    position: np.ndarray
    attempts: int = 0


class _TargetPlanner(Planner):
    """Targets from a prior map, a TSP order over them, and the taken/dropped bookkeeping."""

    needs_frontiers = False

    def __init__(self) -> None:
        self.params = None
        self.context: RunContext | None = None
        self.targets: dict[int, Target] = {}
        self.order: list[int] = []  # target ids in visiting order
        self.pending: list[_Pending] = []
        self._loaded = False

    def configure(self, params, context: RunContext) -> None:
        """Keep the parameters and the context (the prior map is read at the first request)."""
        self.params = params
        self.context = context
        self._loaded = False
        self.targets, self.order, self.pending = {}, [], []
        self.obstacles: dict[int, Target] = {}

    def _classes(self) -> set[str] | None:
        return None if self.params.target_classes is None else set(self.params.target_classes)

    def _load_targets(self, request: PlanRequest) -> None:
        """Read the prior map once; without one, take SLAM's current map at every request."""
        p, ctx = self.params, self.context
        if p.prior_objects is not None:
            base = ctx.mission_dir if ctx is not None else Path.cwd()
            found = load_prior_objects((base / p.prior_objects).resolve(), p.default_radius)
        else:
            found = [
                Target(lm.id, lm.class_name, *_lm_pose(lm, p.default_radius)) for lm in request.landmarks
            ]
        wanted = self._classes()
        new = {t.id: t for t in found if wanted is None or t.class_name in wanted}
        if set(new) != set(self.targets):
            ids = list(new)
            order = target_order(request.start, np.array([new[i].position for i in ids]).reshape(-1, 3))
            self.order = [ids[j] for j in order]
        self.targets = new
        # every shaped prior object keeps viewpoints off its footprint, targets or not (poles, trunks)
        self.obstacles = {t.id: t for t in found if t.shaped or t.id in new}
        self._loaded = p.prior_objects is not None

    def _height(self, request: PlanRequest) -> float:
        return float(self.params.height if self.params.height is not None else request.start[2])

    def _free(self, xy: np.ndarray, skip: int | None = None, height: float | None = None) -> np.ndarray:
        """Cells (N×2) clear of every other object's footprint (plus clearance) and inside the area.

        With ``overfly`` set and the viewpoint ``height`` given, objects whose top is at least
        ``overfly`` below it do not block: a UAV over a parking lot looks at a car from above its
        neighbours (the local map still guards every step of the flight).
        """
        ok = np.ones(len(xy), dtype=bool)
        overfly = self.params.overfly
        for tid, t in self.targets_all.items():
            if tid == skip:
                continue
            if overfly is not None and height is not None and t.top <= height - overfly:
                continue
            ok &= np.linalg.norm(xy - t.position[:2], axis=1) > t.radius + self.params.clearance
        area: BoundingBox | None = self.context.area if self.context is not None else None
        if area is not None and not area.empty:
            ok &= np.all((xy >= area.lo[:2] + 0.5) & (xy <= area.hi[:2] - 0.5), axis=1)
        return ok

    def spots_facing(self, centre: np.ndarray, distance: float, came_from: np.ndarray) -> np.ndarray:
        """Places (N×2) ``distance`` from ``centre``, the first on the side facing ``came_from``,
        then turned around it 15°, 30° … 180° to either side: where to look at an object from,
        in the order to try them while another object blocks the place."""
        d = np.asarray(came_from, float)[:2] - np.asarray(centre, float)[:2]
        base = math.atan2(d[1], d[0]) if np.linalg.norm(d) > 1e-6 else 0.0
        offsets = np.radians(np.arange(15, 181, 15))
        bearings = base + np.concatenate([[0.0], np.ravel(np.column_stack([offsets, -offsets]))])
        return np.asarray(centre, float)[:2] + distance * np.column_stack(
            [np.cos(bearings), np.sin(bearings)]
        )

    @property
    def targets_all(self) -> dict[int, Target]:
        """Every object to keep clear of: the targets and the other shaped prior objects."""
        return {**self.obstacles, **self.targets}

    def _settle(self, here: np.ndarray) -> tuple[list[_Pending], list[_Pending], list[_Pending]]:
        """Sort the previous path's stops into taken, dropped and still open.

        The tree flies a tour in order and asks again after arriving at a stop or giving one up.
        Taken: the first stop within ``reach_tolerance`` of the robot and every stop planned before
        it (the first, not the last: a later stop of a long tour may lie near this one, and the
        stops between were not flown). When the robot is at none of them it gave up the first open
        stop: only that one counts an attempt (the stops behind it were never tried — counting
        them made a 20-stop baseline tour drop every stop after three replans); it is dropped after
        ``max_attempts``. ``self.pending`` is emptied.
        """
        tol = self.params.reach_tolerance
        reached = [k for k, it in enumerate(self.pending) if np.linalg.norm(it.position[:2] - here[:2]) < tol]
        cut = min(reached) + 1 if reached else 0
        taken, rest = self.pending[:cut], self.pending[cut:]
        dropped: list[_Pending] = []
        if not reached and rest:
            rest[0].attempts += 1
            if rest[0].attempts >= self.params.max_attempts:
                dropped, rest = [rest[0]], rest[1:]
        self.pending = []
        return taken, dropped, rest


def _lm_pose(lm, default_radius: float) -> tuple[np.ndarray, float, float, float, bool]:
    radius, yaw = _shape_radius_yaw(lm.shape, default_radius)
    return _shape_position(lm.shape, lm.position), yaw, radius, _shape_top(lm.shape), _shaped(lm.shape)


def _item(position: np.ndarray, yaw: float, gain: float, ref: int) -> TourItem:
    return TourItem(TourItemKind.EXPLORE, np.asarray(position, float), float(yaw), float(gain), int(ref))


def _facing(position: np.ndarray, target: np.ndarray) -> float:
    d = np.asarray(target, float)[:2] - np.asarray(position, float)[:2]
    return float(math.atan2(d[1], d[0]))


# -- the baseline ----------------------------------------------------------------------------------


class PriorVisitPlanner(_TargetPlanner):
    """``prior_visit``: look once at every prior object, in TSP order (paper 2's baseline)."""

    Params = PriorVisitParams

    def __init__(self) -> None:
        super().__init__()
        self.params = PriorVisitParams()
        self.done: set[int] = set()
        self.attempts: dict[int, int] = {}

    def configure(self, params: PriorVisitParams, context: RunContext) -> None:
        super().configure(params, context)
        self.done, self.attempts = set(), {}

    def stop_for(self, tid: int, request: PlanRequest, came_from: np.ndarray) -> np.ndarray:
        """Where to look at target ``tid`` from: ``standoff`` beyond its edge on the side facing
        ``came_from`` (the approach), turned around the object while that place is blocked."""
        t = self.targets[tid]
        xy = self.spots_facing(t.position, t.radius + self.params.standoff, came_from)
        ok = self._free(xy, skip=tid, height=self._height(request))
        j = int(np.argmax(ok)) if ok.any() else 0
        return np.array([xy[j, 0], xy[j, 1], self._height(request)])

    def plan(self, request: PlanRequest) -> list[TourItem]:
        """The prior objects not yet looked at, one stop each, in TSP order from the robot."""
        if not self._loaded:
            self._load_targets(request)
        taken, dropped, still = self._settle(request.start)
        for it in taken + dropped:
            self.done.add(it.target)  # a dropped stop is given up, like a failed look
        for it in still:
            self.attempts[it.target] = it.attempts
        here, items = request.start, []
        for tid in self.order:
            if tid in self.done or tid not in self.targets:
                continue
            pos = self.stop_for(tid, request, here)
            self.pending.append(_Pending(tid, 0, pos, self.attempts.get(tid, 0)))
            items.append(_item(pos, _facing(pos, self.targets[tid].position), 1.0, tid))
            here = pos
        return items


# -- PAMS ----------------------------------------------------------------------------------------


@dataclass
class _TargetState:
    model: ClassModel
    cov: np.ndarray
    samples: np.ndarray  # (S, 3) positions
    sample_covs: list[np.ndarray]
    used: np.ndarray  # (S,) bool: taken, dropped or on the current path
    attempts: np.ndarray  # (S,) requests each sample stayed unreached
    done: bool = False
    looks: int = 0
    history: list[float] = field(default_factory=list)  # entropy after each taken look


class PamsPlanner(_TargetPlanner):
    """``pams``: viewpoints where the models predict confident, accurate looks (paper 2 §IV-D)."""

    requires = ("sklearn",)  # imported when built (see Backend.requires)
    needs_pose_uncertainty = True

    Params = PamsParams

    def __init__(self) -> None:
        super().__init__()
        self.params = PamsParams()
        self.models: UncertaintyModels | None = None
        self.states: dict[int, _TargetState] = {}
        self.rng = np.random.default_rng(0)
        self._emit = None
        self.relocalised_at: set[int] = set()  # landmarks already flown to for relocalisation

    def configure(self, params: PamsParams, context: RunContext) -> None:
        """Load the uncertainty models; the prior map is read at the first request.

        Raises:
            PlanningError: the models file cannot be read.
        """
        super().configure(params, context)
        path = None
        if params.models is not None:
            path = Path(params.models)
            if not path.is_absolute():
                path = (context.mission_dir / path).resolve()
        try:
            self.models = UncertaintyModels.load(path)
        except Exception as exc:  # noqa: BLE001 — a truncated or foreign file: one line naming it
            raise PlanningError(
                f"pams: cannot load uncertainty models {path or 'default'}: {type(exc).__name__}: {exc}"
            ) from None
        self.rng = context.rng
        self.states = {}
        self._emit = context.emit
        self.relocalised_at = set()

    def _classes(self) -> set[str] | None:
        wanted = super()._classes()
        known = set(self.models.classes) if self.models is not None else set()
        return known if wanted is None else wanted & known

    def threshold(self, model: ClassModel) -> float:
        """Entropy below which a target is done: ``entropy_threshold``, or ``c · ln(target_std)``."""
        p = self.params
        if p.entropy_threshold is not None:
            return p.entropy_threshold
        return len(model.components) * math.log(p.target_std)

    # -- viewpoint sampling ------------------------------------------------------------------
    def candidate_grid(self, tid: int, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
        """Polar grid around a target: positions (N×3), range, viewing angle, grid shape (dist, bearing)."""
        p, t = self.params, self.targets[tid]
        m = self.models[t.class_name]
        dists = np.arange(t.radius + p.clearance, p.max_distance + 1e-9, p.range_step)
        bearings = np.radians(np.arange(0.0, 360.0, p.bearing_step_deg))
        D, B = np.meshgrid(dists, bearings, indexing="ij")
        xy = t.position[:2] + np.column_stack([(D * np.cos(B)).ravel(), (D * np.sin(B)).ravel()])
        pos = np.column_stack([xy, np.full(len(xy), height)])
        rng = np.linalg.norm(pos - t.position, axis=1)
        if m.angle_dependent:
            angle = np.abs((B.ravel() - t.yaw + np.pi) % (2 * np.pi) - np.pi)
        else:
            angle = np.zeros(len(xy))
        return pos, rng, angle, D.shape

    def good_region(self, tid: int, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
        """Grid cells in the high-confidence ∩ low-uncertainty region (paper 2 Fig. 6).

        Returns:
            (positions N×3, mask over the cells, predicted variances N×c, grid shape).
        """
        p, t = self.params, self.targets[tid]
        m = self.models[t.class_name]
        pos, rng, angle, shape = self.candidate_grid(tid, height)
        conf = m.confidence(rng, angle)
        var = m.variances(rng, angle)
        limits = region_std_limits(p, m.components)
        confident = (conf >= p.min_confidence) & self._free(pos[:, :2], skip=tid, height=height)
        good = confident & np.all(np.sqrt(var) <= limits, axis=1)
        if not good.any() and confident.any():
            # nothing meets both limits: the best-predicted share of the confident cells instead
            ent = 0.5 * np.log(var).sum(axis=1)
            good = confident & (ent <= np.quantile(ent[confident], p.min_region_share))
        return pos, good, var, shape

    def sample_viewpoints(self, tid: int, height: float) -> tuple[np.ndarray, list[np.ndarray]]:
        """Sampled viewpoints of a target and their predicted measurement covariances."""
        p = self.params
        pos, good, var, shape = self.good_region(tid, height)
        idx = np.flatnonzero(good)
        if len(idx) == 0:
            return np.zeros((0, 3)), []
        if p.sampling == "uniform":
            pick = np.sort(self.rng.choice(idx, size=min(p.samples, len(idx)), replace=False))
        else:
            from scipy import ndimage  # imported when PAMS samples, not when it is listed

            labels, _ = ndimage.label(good.reshape(shape))
            # regions wrap around in bearing: join labels that touch across 360° → 0°
            for a, b in zip(labels[:, 0].tolist(), labels[:, -1].tolist(), strict=True):
                if a and b and a != b:
                    labels[labels == b] = a
            flat = labels.ravel()
            pick_list = []
            for lab in np.unique(flat[flat > 0]):
                cells = np.flatnonzero(flat == lab)
                c = pos[cells].mean(axis=0)
                # the region's cell nearest its centroid (the centroid may fall outside a curved region)
                pick_list.append(int(cells[np.argmin(np.linalg.norm(pos[cells] - c, axis=1))]))
            pick = np.array(pick_list, dtype=int)
        return pos[pick], [np.diag(var[i]) for i in pick]

    def state(self, tid: int, height: float) -> _TargetState:
        """A target's belief and samples (made at its first request)."""
        if tid not in self.states:
            m = self.models[self.targets[tid].class_name]
            samples, covs = self.sample_viewpoints(tid, height)
            n = len(samples)
            self.states[tid] = _TargetState(
                m,
                np.eye(len(m.components)) * self.params.prior_std**2,
                samples,
                covs,
                np.zeros(n, dtype=bool),
                np.zeros(n, dtype=int),
            )
        return self.states[tid]

    # -- path choice --------------------------------------------------------------------------
    def best_path(
        self, st: _TargetState, start: np.ndarray, threshold: float, max_length: float = math.inf
    ) -> tuple[list[int], float]:
        """The ordered samples (at most ``horizon``) of largest gain and that gain; ``([], 0.0)``
        when no sample lies within ``max_length`` metres (the localisation constraint's reach).

        Every one of the ``P(a, T)`` orders of the ``a`` free samples is evaluated; a path is cut
        at the viewpoint where the entropy reaches ``threshold`` (the target is done there). The
        orders are walked depth first in ``itertools.permutations``' order, each prefix's
        information summed once and the last viewpoint of all paths through a prefix evaluated
        at once (one stacked ``slogdet``): P(a, T)·T determinants one at a time took seconds per
        plan with the default 120 samples. Ties keep the first order, as a plain loop over the
        permutations would (``_better``). A path is cut before the first viewpoint beyond
        ``max_length`` metres of flight: shorter paths of the same prefix compete instead.
        """
        left = np.flatnonzero(~st.used).tolist()
        T = min(self.params.horizon, len(left))
        if T == 0:
            return [], 0.0
        h0 = entropy(st.cov)
        meas = np.stack([np.linalg.inv(st.sample_covs[i]) for i in left])
        points = st.samples[left]
        # distances as the path sums them, one float each: from the start, and between samples
        from_start = np.array([float(np.linalg.norm(p - start)) for p in points])
        between = np.array([[float(np.linalg.norm(q - p)) for q in points] for p in points])
        weight = self.params.cost_weight
        best: list = [None]  # (utility, positions in ``left``, gain)

        def offer(utility: np.ndarray, paths: list[list[int]], gain: np.ndarray) -> None:
            """Offer paths in order: each replaces the best only by more than 1e-12."""
            first = 0
            while first < len(utility):
                bar = -np.inf if best[0] is None else best[0][0] + 1e-12
                over = np.flatnonzero(utility[first:] > bar)
                if len(over) == 0:
                    return
                k = first + int(over[0])
                best[0] = (float(utility[k]), paths[k], float(gain[k]))
                first = k + 1

        def extend(info: np.ndarray, last: int | None, length: float, taken: list[int]) -> None:
            rest = [k for k in range(len(left)) if k not in taken]
            steps = from_start[rest] if last is None else between[last, rest]
            within = length + steps <= max_length + 1e-9
            if taken and not within.all():  # the path may also end here, short of what is too far
                h = -0.5 * float(np.linalg.slogdet(info)[1])
                offer(np.array([h0 - h - weight * length]), [list(taken)], np.array([h0 - h]))
            rest, steps = [k for k, ok in zip(rest, within, strict=True) if ok], steps[within]
            if not rest:
                return
            if len(taken) == T - 1:  # the paths' last viewpoints, all at once
                h = -0.5 * np.linalg.slogdet(info + meas[rest])[1]
                gain = h0 - h
                offer(gain - weight * (length + steps), [[*taken, k] for k in rest], gain)
                return
            for k, step in zip(rest, steps, strict=True):
                here_info, here_length = info + meas[k], length + float(step)
                h = -0.5 * float(np.linalg.slogdet(here_info)[1])  # entropy of Σ = info⁻¹
                if h <= threshold:  # cut here: every order through this prefix is this path
                    offer(np.array([h0 - h - weight * here_length]), [[*taken, k]], np.array([h0 - h]))
                else:
                    extend(here_info, k, here_length, [*taken, k])

        extend(np.linalg.inv(st.cov), None, 0.0, [])
        if best[0] is None:
            return [], 0.0
        _, taken, gain = best[0]
        return [left[k] for k in taken], gain

    def plan(self, request: PlanRequest) -> list[TourItem]:
        """The best path of views of the current target (empty when every target is done).

        Raises:
            PlanningError: called before configure, or the prior map cannot be read.
        """
        if self.models is None:
            raise PlanningError("pams: plan() before configure()")
        if not self._loaded:
            self._load_targets(request)
        height = self._height(request)
        taken, dropped, still = self._settle(request.start)
        for it in taken:
            st = self.states[it.target]
            st.cov = fuse(st.cov, [st.sample_covs[it.sample]])
            st.looks += 1
            st.history.append(entropy(st.cov))
        for it in still:  # back into the pool, remembering how often they were not reached
            st = self.states[it.target]
            st.used[it.sample] = False
            st.attempts[it.sample] = it.attempts
        del dropped  # their samples stay used: unreachable, no information
        for tid in self.order:
            if tid not in self.targets:
                continue
            st = self.state(tid, height)
            if st.done:
                continue
            threshold = self.threshold(st.model)
            h = entropy(st.cov)
            if h <= threshold or st.used.all():
                st.done = True
                self._event(
                    "pams_target_done",
                    tid,
                    looks=st.looks,
                    entropy=round(h, 3),
                    reason="entropy below threshold" if h <= threshold else "samples exhausted",
                )
                continue
            free = int((~st.used).sum())
            reach = self.localisation_reach(request)
            path, gain = self.best_path(st, request.start, threshold, reach)
            if not path:  # no path keeps the robot localised: look at a known landmark first
                if relocalise := self.relocalise(request, height, st):
                    return relocalise
                self._event(
                    "pams_localisation_unmet",
                    tid,
                    position_std=round(request.pose_uncertainty.position_std, 3),
                    reach=round(reach, 2),
                )
                path, gain = self.best_path(st, request.start, threshold)
            st.used[path] = True
            target = self.targets[tid]
            items = []
            for i in path:
                pos = st.samples[i]
                self.pending.append(_Pending(tid, i, pos, int(st.attempts[i])))
                items.append(_item(pos, _facing(pos, target.position), gain, tid))
            self._event(
                "pams_path",
                tid,
                samples=len(st.samples),
                free=free,
                candidates=count_paths(free, min(self.params.horizon, free)),
                chosen=len(path),
                gain=round(gain, 4),
                entropy=round(h, 4),
            )
            return items
        return []

    # -- localisation constraint ------------------------------------------------------------
    def localisation_reach(self, request: PlanRequest) -> float:
        """How far the robot may fly before its predicted position std passes
        ``max_position_std``, m; unbounded without the constraint or a backend covariance."""
        bound, pose = self.params.max_position_std, request.pose_uncertainty
        if bound is None or pose is None:
            return math.inf
        return pose.reach(bound)

    def relocalise(self, request: PlanRequest, height: float, st: _TargetState) -> list[TourItem]:
        """A stop that looks at a landmark known well enough to bring one of the target's free
        samples back within reach, from ``relocalise_range`` (on the robot's side of it, turned
        when an object blocks that spot: :meth:`spots_facing`), facing it; empty when no landmark does.

        Measuring a landmark ties the pose to it, so after the stop the robot's std is about the
        landmark's own (the measurement's noise is left out: the models give it for targets, not
        for every class). A landmark qualifies when that std, grown over the flight on to the
        nearest free sample, stays within ``max_position_std``; among those the shortest detour
        (robot → stop → that sample) wins. A landmark barely better known than the robot (in a
        parking lot far from the take-off, every landmark's std is near the robot's) is no
        relocalisation. Each landmark serves once.
        """
        p, pose = self.params, request.pose_uncertainty
        samples = st.samples[~st.used]
        if not len(samples):
            return []
        best = None
        for lm in request.landmarks:
            cov = np.asarray(lm.covariance, float)
            if lm.id in self.relocalised_at or cov.shape != (3, 3) or not np.isfinite(cov).all():
                continue
            after = PoseUncertainty(cov, pose.odometry)  # the robot's, once it has looked
            std = after.position_std
            if std >= p.max_position_std:
                continue
            xy = self.spots_facing(lm.position, p.relocalise_range, request.start)
            free = np.flatnonzero(self._free(xy, height=height))
            if len(free) == 0:
                continue
            spot = np.array([*xy[free[0]], height])
            on = float(np.min(np.linalg.norm(samples - spot, axis=1)))
            if after.reach(p.max_position_std) < on:
                continue
            detour = float(np.linalg.norm(spot - request.start)) + on
            if best is None or detour < best[0]:
                best = (detour, lm, std, spot)
        if best is None:
            return []
        detour, lm, std, spot = best
        self.relocalised_at.add(lm.id)
        if self._emit is not None:
            self._emit(
                "pams_relocalise",
                landmark=lm.id,
                cls=lm.class_name,
                landmark_std=round(std, 3),
                position_std=round(pose.position_std, 3),
                detour=round(detour, 2),
            )
        return [_item(spot, _facing(spot, lm.position), 0.0, lm.id)]

    def _event(self, name: str, tid: int, **fields) -> None:
        if self._emit is not None:
            self._emit(name, target=tid, cls=self.targets[tid].class_name, **fields)
