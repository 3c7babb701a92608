"""Shape landmarks of the front end and the graph (paper 2, §IV-A/B), onboard and at the base.

A class declares its landmark model in ``landmark_models`` (the SLAM section's, or the merge's;
class → ``centroid`` | ``cuboid`` | ``cylinder`` | ``plane``). This module holds the
front end of the shape classes:

* ``plane`` classes (the ground) make no landmarks: their points (odometry frame) fill a
  voxel-thinned buffer from which the local ground plane of each object is fitted.
* ``cuboid`` / ``cylinder`` classes are associated by **overlap**: a detection belongs to the
  landmark of its class whose current shape (inflated by ``association_margin``) holds most of
  its points (at least ``association_overlap``) — a car's visible-surface centroid moves by
  metres with the view, its box does not. Each landmark keeps its points in the odometry frame
  with their stamps; a **measurement** is the shape fitted (:mod:`.shapes`) to the points of the
  last ``window`` seconds (the paper accumulates 1–3 s of LIDAR scans with LIDAR odometry; VIO
  is locally exact in the same way), expressed in the key pose's body frame with VIO. It yields
  one factor, eq. 1 / eq. 2 (:mod:`.shape_factors`): a detection is measured once. The position
  the rest of the backend uses (association, loop closure, covariances, the reported landmark)
  is the shape's reference point (cuboid centre, cylinder root) read off the shape's own
  variables (:meth:`reference_key`), not a second, point measurement of the same fit.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from amslam.geometry import yaw_matrix
from amslam.lib import shapes
from amslam.lib.shape_factors import (
    cuboid_centre_tie,
    cuboid_factor,
    cuboid_keys,
    cylinder_factor,
    cylinder_keys,
)
from amslam.lib.uncertainty import POSITION_COMPONENTS, ClassModel, UncertaintyModels
from amslam.lib.viewing import viewing_angle
from amslam.plugins.gtsam_slam.params import ShapeParams, SizePrior

__all__ = ["ShapeLandmarks", "ShapeParams", "SizePrior"]

MODELS = ("centroid", "cuboid", "cylinder", "plane")
#: The ``landmark_models`` key that stands for every class not named (a mesh world has dozens).
ANY_CLASS = "*"


class GroundBuffer:
    """Ground points (odometry frame) of the last ``window`` seconds, one per ``voxel`` across
    frames: a voxel seen again keeps its newest point.

    Thinned per frame only, the buffer held every frame's copy of the same ground (a PAMS flight
    passes a patch of the lot in 50 frames of the 300 in its window), and fitting each object's
    ground plane to it was 18 % of that flight's time (py-spy, session 53); the newest point of
    each voxel is also the one in the odometry frame of now, which VIO's drift moves against
    the older ones.
    """

    #: voxel indices are packed into one int64, 21 bits per axis: ±2^20 voxels (±42 km at 4 cm)
    _BITS = 21

    def __init__(self, voxel: float, window: float):
        self.voxel, self.window = float(voxel), float(window)
        self.keys = np.empty(0, np.int64)
        self.points = np.empty((0, 3))
        self.stamps = np.empty(0)

    def _pack(self, points: np.ndarray) -> np.ndarray:
        half = 1 << (self._BITS - 1)
        idx = np.clip(np.floor(points / self.voxel), -half, half - 1).astype(np.int64) + half
        return (idx[:, 0] << (2 * self._BITS)) | (idx[:, 1] << self._BITS) | idx[:, 2]

    def add(self, stamp: float, points: np.ndarray) -> None:
        """Add one frame's ground points; forget voxels not seen within ``window`` seconds."""
        points = np.asarray(points, float).reshape(-1, 3)
        keys, first = np.unique(self._pack(points), return_index=True)
        keep = (stamp - self.stamps <= self.window) & ~np.isin(self.keys, keys, assume_unique=True)
        self.keys = np.concatenate([self.keys[keep], keys])
        self.points = np.concatenate([self.points[keep], points[first]])
        self.stamps = np.concatenate([self.stamps[keep], np.full(len(keys), float(stamp))])

    def __len__(self) -> int:
        return len(self.keys)


@dataclass
class _ShapeRec:
    model: str
    cls: str
    points: list[tuple[float, np.ndarray]] = field(default_factory=list)  # (stamp, odom-frame points)
    last_world: dict | None = None  # latest shape in the world frame (for association)
    height: float = float("nan")  # latest cylinder height (not a graph variable)
    pending: list[tuple[int, dict]] = field(default_factory=list)  # (key pose, body-frame shape)
    in_graph: bool = False
    ref_dims: np.ndarray | None = None  # largest dimensions measured so far (cuboids, sorted l ≥ w)
    slack: dict[int, np.ndarray] = field(default_factory=dict)  # key pose → per-axis slack, m
    cameras: list[tuple[float, np.ndarray]] = field(default_factory=list)  # (stamp, odom-frame camera)
    est_world: dict | None = None  # the optimised shape (world frame), for association
    completion: shapes.Completion | None = None  # of the latest measurement
    loose: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # kp → (centre, dims) σ+
    fits: list[float] = field(default_factory=list)  # stamps of the measurements within the window
    scale: dict[int, float] = field(default_factory=dict)  # key pose → noise scale (decorrelate)
    view_scale: float = 1.0  # the latest measurement's noise scale from its views (view_noise)
    # every measurement of the object that became an eq. 1 / eq. 2 factor, its own and its fused
    # twins' (a tentative twin's held-back ones included): (landmark whose noise it has, key pose,
    # body-frame shape), for the base merge
    measured: list[tuple[int, int, dict]] = field(default_factory=list)
    # key pose → (fitted dims before completion, which box axes the completion extended)
    fitted: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


class ShapeLandmarks:
    """Point buffers, measurements and factors of the shape landmarks of one backend."""

    def __init__(self, models: dict[str, str], params: ShapeParams, rng: np.random.Generator):
        bad = {c: m for c, m in models.items() if m not in MODELS}
        if bad:
            raise ValueError(f"landmark_models: unknown model(s) {bad}; expected one of {MODELS}")
        if models.get(ANY_CLASS) == "plane":
            # every class not named would feed the ground buffer and map nothing
            raise ValueError(f"landmark_models: {ANY_CLASS!r} (every other class) cannot be 'plane'")
        self.models = dict(models)
        self.p = params
        self.rng = rng
        self.recs: dict[int, _ShapeRec] = {}
        self._ground = GroundBuffer(params.voxel, params.ground_window)
        wanted = params.view_noise or params.model_sigmas
        self._uncertainty = _load_models(params.uncertainty_models) if wanted else None
        self._best_stds_cache: dict[str, tuple[float, float | None]] = {}

    def model(self, class_name: str) -> str:
        """The landmark model of a class: its own entry, else the ``"*"`` entry, else ``centroid``."""
        return self.models.get(class_name, self.models.get(ANY_CLASS, "centroid"))

    # ------------------------------------------------------------------ ground
    def add_ground(self, stamp: float, points_odom: np.ndarray) -> None:
        """Add ground points (odometry frame) to the buffer, one per ``voxel`` (:class:`GroundBuffer`)."""
        if len(points_odom) == 0:
            return
        self._ground.add(stamp, points_odom)

    def ground_near(self, centre_odom: np.ndarray) -> shapes.GroundPlane | None:
        """The local ground plane (odometry frame) around a point, if ground points are known."""
        if not len(self._ground):
            return None
        return shapes.local_ground(self._ground.points, centre_odom, self.p.ground_radius)

    # ------------------------------------------------------------------ association
    def associate(
        self,
        class_name: str,
        points_odom: np.ndarray,
        points_world: np.ndarray,
        candidates: dict[int, str],
        stamp: float,
    ) -> int:
        """The landmark (of ``candidates``: id → class) the detection's points overlap most, or -1.

        A point overlaps a landmark when it lies within ``association_margin`` of the landmark's
        window points (odometry frame: over a few seconds VIO is exact), or inside its inflated
        shape (world frame: for a landmark seen again after its window emptied). The landmark with
        the largest share of overlapping points wins if the share reaches ``association_overlap``
        and the detection's own middle (the median of its points) overlaps it too: half of a chair
        0.75 m from its neighbour in a row lies inside the neighbour's inflated box, its middle
        does not (without this check one box took two chairs: 0.9-1.2 m chair boxes, one_floor).
        """
        from scipy.spatial import cKDTree

        best, best_share = -1, self.p.association_overlap
        # rows: the detection's points, then its middle
        pts_world = np.vstack([points_world, np.median(points_world, axis=0)])
        pts_odom = np.vstack([points_odom, np.median(points_odom, axis=0)])
        for lm_id, cls in candidates.items():
            rec = self.recs.get(lm_id)
            if cls != class_name or rec is None or rec.last_world is None:
                continue
            # the latest window fit stands for the landmark only while it agrees with the estimate
            # (its centre inside it): a window that saw one end of a car and completed it the
            # wrong way reaches into the next stall
            if (
                rec.est_world is None
                or self._inside(rec.est_world, shapes.shape_center(rec.last_world)[None])[0]
            ):
                inside = self._inside(rec.last_world, pts_world)
            else:
                inside = np.zeros(len(pts_world), bool)
            if rec.est_world is not None:  # not inflated: it already holds every view
                inside |= self._inside(rec.est_world, pts_world, 0.0)
            recent = [q for t, q in rec.points if stamp - t <= self.p.window]
            if recent:
                tree = cKDTree(np.concatenate(recent)[:: max(1, sum(map(len, recent)) // 3000)])
                d, _ = tree.query(pts_odom, distance_upper_bound=self.p.association_margin)
                inside |= np.isfinite(d)
            share = float(np.mean(inside[:-1]))
            if inside[-1] and share >= best_share:
                best, best_share = lm_id, share
        return best

    def measure_view(
        self, lm_id: int, associated: bool, new_id: Callable[[], int], T_world_kp: np.ndarray, *view: object
    ) -> tuple[int, dict | None]:
        """:meth:`measure` (``view``: its arguments after ``lm_id``) of a detection for landmark
        ``lm_id`` (``associated``: an existing one), unless ``return_gate`` finds it another
        object's: a cuboid landmark seen again after its window emptied whose box the view's does
        not agree with (:meth:`agrees`; ``T_world_kp`` places the view) keeps nothing of the view,
        which goes to a new landmark (``new_id()``).

        Returns:
            (the landmark measured, the measured shape in the key pose's body frame or ``None``).
        """
        stamp = float(view[1])
        returning = associated and self.p.return_gate and self.returning(lm_id, stamp)
        shape_body = self.measure(lm_id, *view)
        if (
            returning
            and shape_body is not None
            and not self.agrees(lm_id, shapes.transform_shape(shape_body, T_world_kp))
        ):
            self.forget_latest(lm_id)
            lm_id = new_id()
            shape_body = self.measure(lm_id, *view)
        return lm_id, shape_body

    def returning(self, lm_id: int, stamp: float) -> bool:
        """Whether cuboid landmark ``lm_id`` is seen again after its window emptied (no points
        within ``window`` of ``stamp``): only its world-frame boxes associated the detection."""
        rec = self.recs.get(lm_id)
        return (
            rec is not None
            and rec.model == "cuboid"
            and not any(stamp - t <= self.p.window for t, _ in rec.points)
        )

    def agrees(self, lm_id: int, shape_world: dict) -> bool:
        """Whether a returning view's box (world frame) and the landmark's are one object: one of
        them holds the other's centre (within ``association_margin``).

        The association of a returning view goes by the detection's points against the
        landmark's box in the world, placed with the drifted key poses. In a row of cars parked
        end to end, the near end of the next car lies against the landmark's box, and a metre of
        drift puts it inside: on a PAMS lot flight one landmark took car_9's views, then (400 key
        poses later) car_3's, the next car down the row 5 m away, and pulled the key poses by
        the row's spacing (``docs/pams.md``). The view's own box, completed behind its seen
        faces, is centred on the car it saw: 4 m from the landmark's there.
        """
        rec = self.recs[lm_id]
        ref = rec.est_world or rec.last_world
        if ref is None:
            return True
        c_new = shapes.shape_center(shape_world)[None]
        c_ref = shapes.shape_center(ref)[None]
        return bool(self._inside(ref, c_new)[0] or self._inside(shape_world, c_ref)[0])

    def forget_latest(self, lm_id: int) -> None:
        """Take back what :meth:`measure` kept of a returning landmark's view (its window held
        nothing else): the view goes to a new landmark."""
        rec = self.recs[lm_id]
        rec.points, rec.cameras, rec.fits, rec.completion = [], [], rec.fits[:-1], None

    def _inside(self, shape: dict, pts: np.ndarray, margin: float | None = None) -> np.ndarray:
        return shapes.points_inside(shape, pts, self.p.association_margin if margin is None else margin)

    # ------------------------------------------------------------------ measurements
    def measure(
        self,
        lm_id: int,
        class_name: str,
        stamp: float,
        points_odom: np.ndarray,
        T_odom_kp: np.ndarray,
        camera_odom: np.ndarray | None = None,
        T_world_odom: np.ndarray | None = None,
    ) -> dict | None:
        """Add a detection's points to landmark ``lm_id`` and fit its shape over the window.

        With ``complete`` and the camera position (odometry frame), a cuboid that falls short
        of its class's size prior is completed behind its visible faces
        (:func:`.shapes.complete_cuboid`; the landmark's estimate, through ``T_world_odom``,
        tells its length from its width).

        Returns:
            The measured shape in the key pose's body frame, or ``None`` (too few points).
        """
        rec = self.recs.setdefault(lm_id, _ShapeRec(self.model(class_name), class_name))
        rec.points.append((stamp, np.asarray(points_odom, float)))
        rec.points = [(t, q) for t, q in rec.points if stamp - t <= self.p.window]
        if camera_odom is not None:
            rec.cameras.append((stamp, np.asarray(camera_odom, float)))
            rec.cameras = [(t, q) for t, q in rec.cameras if stamp - t <= self.p.window]
        rec.completion = None
        pts = np.concatenate([q for _, q in rec.points])
        if len(pts) < self.p.min_points:
            return None
        if len(pts) > self.p.max_points:
            pts = pts[self.rng.choice(len(pts), self.p.max_points, replace=False)]
        ground = self.ground_near(np.median(pts, axis=0))
        if rec.model == "cuboid":
            s = shapes.fit_cuboid(pts, ground, percentile=self.p.percentile, extrapolate=self.p.extrapolate)
        else:
            s = shapes.fit_cylinder(pts, ground, axis=self.p.cylinder_axis)
        if s is not None and rec.model == "cuboid" and self.p.seat_faces and rec.cameras:
            s = shapes.seat_seen_faces(s, pts, np.array([q for _, q in rec.cameras]))
        if s is None or not self._plausible(s):
            return None
        rec.fits = [t for t in rec.fits if stamp - t < self.p.window] + [stamp]
        if rec.model == "cylinder":
            rec.height = s["height"]
        elif self.p.complete and rec.cameras:
            prior = self.size_prior(rec)
            if prior is not None:
                ref = rec.est_world or rec.last_world
                if ref is not None and T_world_odom is not None:
                    ref = shapes.transform_shape(ref, np.linalg.inv(T_world_odom))
                else:
                    ref = None
                rec.completion = shapes.complete_cuboid(
                    s,
                    np.array([q for _, q in rec.cameras]),
                    prior[0],
                    reference=ref,
                    tolerance=self.p.completion_tolerance,
                )
                s = rec.completion.shape
        rec.view_scale = self.view_scale(rec.cls, s, np.array([q for _, q in rec.cameras]))
        return shapes.transform_shape(s, np.linalg.inv(T_odom_kp))

    def class_model(self, class_name: str, model: str) -> ClassModel | None:
        """The characterised model of a class, else of the one characterised class of its shape
        (tree trunks as light poles: both cylinders whose error grows with range alone)."""
        if self._uncertainty is None:
            return None
        if class_name in self._uncertainty:
            return self._uncertainty[class_name]
        same = [m for m in self._uncertainty.classes.values() if m.shape_model == model]
        return same[0] if len(same) == 1 else None

    def view_scale(self, class_name: str, shape: dict, cameras: np.ndarray) -> float:
        """Noise scale of a fit of ``shape`` from the cameras that saw its points (``view_noise``).

        Each camera's look at the shape has a position variance (the mean over the model's x / y
        components) at its range and viewing angle; the window's is their harmonic mean (a fit
        of several views is as good as their information on average; their number is
        ``decorrelate``'s), relative to the class's best looks (5th percentile over the model's
        domain), never below 1. ``shape`` and ``cameras`` (N × 3) are in one frame.
        """
        cm = self.class_model(class_name, shape["model"]) if self.p.view_noise else None
        cams = np.asarray(cameras, float).reshape(-1, 3)
        if cm is None or not len(cams):
            return 1.0
        if shape["model"] == "cuboid":
            centre = np.asarray(shape["center"], float)
            dims = shape["dims"]
            # the models' angle is from the object's forward (length) axis
            yaw = float(shape["yaw"]) + (0.0 if dims[0] >= dims[1] else math.pi / 2)
            angles = np.array([viewing_angle(centre, yaw, c) for c in cams])
        else:
            half = 0.5 * float(shape.get("height", 0.0))
            centre = np.asarray(shape["root"], float) + half * np.asarray(shape["axis"], float)
            angles = np.zeros(len(cams))
        position = [i for i, c in enumerate(cm.components) if c in POSITION_COMPONENTS]
        ranges = np.linalg.norm(cams - centre, axis=1)
        var = cm.variances(ranges, angles)[:, position].mean(axis=1)
        if shape["model"] == "cuboid":
            # a fitted box is the same after a half turn: its front may be the object's back, so
            # a look is as good as the mean of the two (a chair seen from the front or behind)
            var = 0.5 * (var + cm.variances(ranges, math.pi - angles)[:, position].mean(axis=1))
        window = len(var) / float(np.sum(1.0 / var))
        best = self._best_stds(cm)[0] ** 2
        return float(np.sqrt(max(window / best, 1.0)))

    def _best_stds(self, cm: ClassModel) -> tuple[float, float | None]:
        """The std of a class's best looks: position (mean over x / y) and, for a model with them,
        dimensions (mean over length / width); the 5th percentile over the model's domain."""
        best = self._best_stds_cache.get(cm.class_name)
        if best is None:
            r, a = np.meshgrid(np.linspace(*cm.range_bounds, 40), np.linspace(*cm.angle_bounds, 37))
            var = cm.variances(r.ravel(), a.ravel())
            position = [i for i, c in enumerate(cm.components) if c in POSITION_COMPONENTS]
            dims = [i for i, c in enumerate(cm.components) if c in ("length", "width")]
            # the 5th percentile, not the minimum: the spline's corners (few samples) dip lower
            # (the packaged car model: 0.03 m at 9 m behind the car, 0.13 m at the 5th percentile)
            best = (
                float(np.sqrt(np.percentile(var[:, position].mean(axis=1), 5))),
                float(np.sqrt(np.percentile(var[:, dims].mean(axis=1), 5))) if dims else None,
            )
            self._best_stds_cache[cm.class_name] = best
        return best

    def base_sigmas(self, class_name: str, model: str) -> tuple[float, float]:
        """Translation and dimension std of a measurement from the best views (before its views
        and ``decorrelate`` scale it): ``sigma_translation`` / ``sigma_dims``, or with
        ``model_sigmas`` the class's characterised best look (paper 2's Σ = f^g(x, ℓ): the
        window's noise is then the model's own at its views)."""
        cm = self.class_model(class_name, model) if self.p.model_sigmas else None
        if cm is None:
            return self.p.sigma_translation, self.p.sigma_dims
        position, dims = self._best_stds(cm)
        return position, self.p.sigma_dims if dims is None else dims

    def size_prior(self, rec: _ShapeRec) -> tuple[np.ndarray, np.ndarray] | None:
        """The typical box (length ≥ width, height) of a landmark's class and its spread, if known.

        Declared (``size_prior``) or learned: the median of the largest boxes measured for the
        class's other landmarks, once ``size_prior_min_boxes`` exist (a landmark's largest box
        grows with its views, so the median settles on the whole objects); the spread is then
        10 % of the median (at least 0.1 m).
        """
        declared = self.p.size_prior.get(rec.cls)
        if declared is not None:
            return np.asarray(declared.dims, float), np.asarray(declared.std, float)
        boxes = [
            r.ref_dims
            for r in self.recs.values()
            if r is not rec and r.cls == rec.cls and r.ref_dims is not None
        ]
        if len(boxes) < self.p.size_prior_min_boxes:
            return None
        med = np.median(boxes, axis=0)
        return med, np.maximum(0.1 * med, 0.1)

    def record_slack(self, lm_id: int, kp: int, shape: dict) -> np.ndarray:
        """How much of a cuboid this measurement may have missed, per box axis (m).

        A partial view gives a box shorter than the object, and a centre shifted by up to half
        the missing length. The slack is half the shortfall of each dimension against the
        largest seen so far for this landmark (and the class's typical box); it widens that
        measurement's noise (eq. 1's translation and dimensions along the box axes, and the
        point landmark's range-bearing), so that partial views do not drag the key poses.

        A measurement completed with the size prior (:meth:`measure`) has, along an extended
        axis, a centre as uncertain as half the prior's spread and a dimension that is the
        prior's (loose by the shortfall plus the spread); along an axis whose missing side is
        unknown, a centre loose by half the shortfall.
        """
        rec = self.recs[lm_id]
        rec.scale[kp] = float(np.sqrt(len(rec.fits))) if self.p.decorrelate and rec.fits else 1.0
        rec.scale[kp] *= rec.view_scale
        if shape["model"] != "cuboid":
            rec.slack[kp] = np.zeros(3)
            return rec.slack[kp]
        d = np.asarray(shape["dims"], float)
        comp = rec.completion
        raw = comp.measured if comp is not None else d
        rec.fitted[kp] = (np.asarray(raw, float), comp.extended if comp is not None else np.zeros(3, bool))
        raw_sorted = np.array([max(raw[0], raw[1]), min(raw[0], raw[1]), raw[2]])  # length ≥ width
        rec.ref_dims = raw_sorted if rec.ref_dims is None else np.maximum(rec.ref_dims, raw_sorted)
        # objects of one class are alike: the first, partial views of a new car are measured
        # against the median of the other cars' largest boxes
        others = [
            r.ref_dims
            for r in self.recs.values()
            if r is not rec and r.ref_dims is not None and r.cls == rec.cls
        ]
        ref = np.maximum(rec.ref_dims, np.median(others, axis=0)) if others else rec.ref_dims
        ref = ref if d[0] >= d[1] else ref[[1, 0, 2]]
        slack = np.maximum(ref - d, 0.0) / 2.0
        loose_c, loose_d = np.zeros(3), np.zeros(3)
        if comp is not None:
            prior = self.size_prior(rec)
            std = np.zeros(3) if prior is None else prior[1][[1, 0, 2]] if comp.swapped else prior[1]
            loose_c = np.where(comp.extended, std / 2, np.where(comp.ambiguous, comp.missing / 2, 0.0))
            loose_d = np.where(comp.extended | comp.ambiguous, comp.missing + std * comp.extended, 0.0)
            slack = np.where(comp.extended, 0.0, slack)  # the extended extent is the prior's
        rec.loose[kp] = (loose_c, loose_d)
        rec.slack[kp] = np.maximum(slack, loose_c)
        return rec.slack[kp]

    def point_slack(self, lm_id: int, kp: int) -> float:
        """The slack (norm, m) of a landmark's measurement at a key pose (0 if none)."""
        rec = self.recs.get(lm_id)
        if rec is None or kp not in rec.slack:
            return 0.0
        return float(np.linalg.norm(rec.slack[kp]))

    def point_scale(self, lm_id: int, kp: int) -> float:
        """The noise scale of a landmark's measurement at a key pose (``decorrelate``; 1 if none)."""
        rec = self.recs.get(lm_id)
        return 1.0 if rec is None else rec.scale.get(kp, 1.0)

    def _plausible(self, s: dict) -> bool:
        """Reject degenerate fits (a circle fitted to a flat patch, a sliver of a box)."""
        if s["model"] == "cylinder":
            return 0.01 <= s["radius"] <= self.p.max_radius
        dims = np.asarray(s["dims"])
        return bool(np.all(dims >= self.p.min_dim) and np.all(dims <= self.p.max_dim))

    def refresh_estimates(self, values: gtsam.Values) -> None:
        """Keep each landmark's optimised shape (world frame) for association: it holds every view,
        while the latest measurement may cover only the part of the object seen last."""
        for lm_id, rec in self.recs.items():
            if rec.in_graph:
                rec.est_world = self.estimate(lm_id, values)

    def twins(self, lm_id: int, candidates: dict[int, str]) -> list[int]:
        """Landmarks of ``candidates`` (id → class) that are the same object as ``lm_id``.

        Two boxes of one class are one object when each one's centre lies inside the other
        (latest measurement or estimate, world frame; no margin): two cars parked side by side
        are 2.5 m apart, more than half a car's width. A car first seen at its two ends in two
        passes gets two landmarks, each on its own end; once completed behind their visible faces
        (:meth:`measure`) the two boxes hold each other's centres. Cylinders: roots closer than
        the larger radius plus ``association_margin``.
        """
        rec = self.recs.get(lm_id)
        if rec is None:
            return []
        mine = [s for s in (rec.last_world, rec.est_world) if s is not None]
        out = []
        for j, cls in candidates.items():
            other = self.recs.get(j)
            if j == lm_id or other is None or cls != rec.cls or other.model != rec.model:
                continue
            theirs = [s for s in (other.last_world, other.est_world) if s is not None]
            if not mine or not theirs:
                continue
            if rec.model == "cuboid":
                a_in_b = any(
                    self._inside(t, shapes.shape_center(m)[None], 0.0)[0] for m in mine for t in theirs
                )
                b_in_a = any(
                    self._inside(m, shapes.shape_center(t)[None], 0.0)[0] for m in mine for t in theirs
                )
                if a_in_b and b_in_a:
                    out.append(j)
            else:
                gap = min(
                    np.linalg.norm(np.asarray(m["root"])[:2] - np.asarray(t["root"])[:2])
                    - max(m["radius"], t["radius"])
                    for m in mine
                    for t in theirs
                )
                if gap <= self.p.association_margin:
                    out.append(j)
        return out

    def all_twins(self, candidates: dict[int, str]) -> list[tuple[int, int]]:
        """Every pair of ``candidates`` (id → class) that :meth:`twins` finds to be one object.

        :meth:`twins` runs when a landmark is measured, against the shapes as they are then; a
        loop closure or a later measurement moves the estimates, and two landmarks of one chair
        that drift had kept apart may come to hold each other's centres while neither is measured
        again (three of the demo's four box duplicates, seed 7). Run when the estimates change.
        """
        rows = [  # (landmark, centre, reach) of each shape a landmark has: the cheap bound first
            (j, shapes.shape_center(s), self._reach(s))
            for j in sorted(candidates)
            if (rec := self.recs.get(j)) is not None
            for s in (rec.last_world, rec.est_world)
            if s is not None
        ]
        if len(rows) < 2:
            return []
        ids = np.array([r[0] for r in rows])
        C = np.array([r[1] for r in rows])
        reach = np.array([r[2] for r in rows])
        close = np.linalg.norm(C[:, None] - C[None], axis=2) <= np.maximum(reach[:, None], reach[None])
        near = {(int(ids[i]), int(ids[k])) for i, k in np.argwhere(close) if ids[i] < ids[k]}
        same_class = sorted((a, b) for a, b in near if candidates[a] == candidates[b])
        return [(a, b) for a, b in same_class if self.twins(a, {b: candidates[b]})]

    def _reach(self, shape: dict) -> float:
        """How far from its reference point a shape can hold another's: a box's half-diagonal, a
        cylinder's radius plus ``association_margin`` (the bound :meth:`twins` tests within)."""
        if shape["model"] == "cuboid":
            return 0.5 * float(np.linalg.norm(shape["dims"]))
        return float(shape["radius"]) + self.p.association_margin

    def absorb(self, keep_id: int, gone_id: int) -> None:
        """Landmark ``keep_id`` takes the points, cameras, measurements that became factors
        (``measured``, which the base merge re-expresses on ``keep_id``'s variables) and per-key-pose
        noise (slack, loose extents, scale) of its twin ``gone_id``."""
        keep, gone = self.recs[keep_id], self.recs[gone_id]
        keep.points = sorted(keep.points + gone.points, key=lambda tq: tq[0])
        keep.cameras = sorted(keep.cameras + gone.cameras, key=lambda tq: tq[0])
        keep.measured, gone.measured = keep.measured + gone.measured, []
        self._take_noise(keep, gone)

    @staticmethod
    def _take_noise(keep: _ShapeRec, gone: _ShapeRec) -> None:
        for kp, v in gone.slack.items():
            keep.slack.setdefault(kp, v)
        for kp, lv in gone.loose.items():
            keep.loose.setdefault(kp, lv)
        for kp, sc in gone.scale.items():
            keep.scale.setdefault(kp, sc)
        for kp, fe in gone.fitted.items():
            keep.fitted.setdefault(kp, fe)

    def take_measurements(self, keep_id: int, gone_id: int, skip: set[int]) -> list[tuple[int, dict]]:
        """The measurements (key pose, body-frame shape) twin ``gone_id`` holds back while it is
        tentative, handed to ``keep_id`` with their noise, except those from key poses ``skip``:
        once fused they are measurements of ``keep_id``, each still counted once."""
        keep, gone = self.recs[keep_id], self.recs[gone_id]
        self._take_noise(keep, gone)
        out = [(k, s) for k, s in gone.pending if k not in skip]
        gone.pending = []
        return out

    @staticmethod
    def reference_key(model: str, lm_id: int) -> int:
        """The variable holding a shape landmark's reference point: the cuboid's pose (its centre
        is the pose's translation), the cylinder's root."""
        return cuboid_keys(lm_id)[0] if model == "cuboid" else cylinder_keys(lm_id)[0]

    @staticmethod
    def reference_point(model: str, lm_id: int, values: gtsam.Values) -> np.ndarray:
        """A shape landmark's reference point (world frame) at ``values``."""
        key = ShapeLandmarks.reference_key(model, lm_id)
        if model == "cuboid":
            return np.asarray(values.atPose3(key).translation(), float)
        return np.asarray(values.atPoint3(key), float)

    @staticmethod
    def reference_jacobian(model: str, lm_id: int, values: gtsam.Values) -> np.ndarray:
        """How the reference point (world frame) moves with its variable's tangent at ``values``.

        A ``Pose3``'s tangent is ``[ω; v]`` with ``v`` in the box frame (the translation moves by
        ``R v``), so a box centre's Jacobian is ``[0, R]`` (3 × 6); a cylinder root's is ``I``."""
        if model != "cuboid":
            return np.eye(3)
        R = values.atPose3(ShapeLandmarks.reference_key(model, lm_id)).rotation().matrix()
        return np.hstack([np.zeros((3, 3)), R])

    @staticmethod
    def reference_covariance(
        model: str, lm_id: int, marginal: np.ndarray, values: gtsam.Values
    ) -> np.ndarray:
        """The 3 × 3 world-frame covariance of the reference point from its variable's marginal:
        ``J Σ Jᵀ`` with :meth:`reference_jacobian` (``R Σ_vv Rᵀ`` for a box)."""
        J = ShapeLandmarks.reference_jacobian(model, lm_id, values)
        return J @ np.asarray(marginal, float) @ J.T

    def tie(self, keep_id: int, gone_id: int, noise: gtsam.noiseModel.Base) -> gtsam.NonlinearFactor:
        """The zero-offset tie of two shape landmarks of one object (their reference points)."""
        model = self.recs[keep_id].model
        a, b = self.reference_key(model, keep_id), self.reference_key(model, gone_id)
        if model == "cuboid":
            return cuboid_centre_tie(a, b, noise)
        return gtsam.BetweenFactorPoint3(a, b, np.zeros(3), noise)

    def new_odometry_frame(self) -> None:
        """Forget the time windows (points, cameras, fits, ground), which are kept in the odometry
        frame of the robot that made them: the base replays another robot's log next."""
        for rec in self.recs.values():
            rec.points, rec.cameras, rec.fits = [], [], []
        self._ground = GroundBuffer(self.p.voxel, self.p.ground_window)

    def set_world(self, lm_id: int, shape_world: dict) -> None:
        """Record the latest world-frame shape of a landmark (for association)."""
        self.recs[lm_id].last_world = shape_world

    # ------------------------------------------------------------------ factors
    def noise(
        self,
        model: str,
        slack: np.ndarray | None = None,
        loose_dims: np.ndarray | None = None,
        scale: float = 1.0,
        base: tuple[float, float] | None = None,
    ) -> gtsam.noiseModel.Base:
        """Eq. 1 / eq. 2 noise; a cuboid's translation and dims widened by the measurement's slack.

        ``loose_dims`` (per box axis) replaces ``2·slack`` for the dims where it is larger: a
        dimension completed with the size prior is the prior's, not a measurement. ``scale``
        multiplies every sigma (``decorrelate``). ``base``: translation and dimension std of the
        class's best look (:meth:`base_sigmas`; default ``sigma_translation``, ``sigma_dims``).
        """
        p = self.p
        translation, dims = (p.sigma_translation, p.sigma_dims) if base is None else base
        if model == "cuboid":
            sl = np.zeros(3) if slack is None else np.asarray(slack, float)
            ld = 2 * sl if loose_dims is None else np.maximum(2 * sl, loose_dims)
            # eq. 1's translation error is expressed along the measured box axes, like the slack
            s = [p.sigma_rotation] * 3 + list(translation + sl) + list(dims + ld)
        else:
            s = [translation] * 3 + [p.sigma_axis] * 3 + [p.sigma_radius]
        return gtsam.noiseModel.Diagonal.Sigmas(scale * np.array(s))

    def extent(self, lm_id: int, estimate: dict, pose: Callable[[int], np.ndarray]) -> np.ndarray | None:
        """The box a cuboid landmark's views reach, along its estimate's axes (``shapes.extent``).

        A view sees part of a car as often as all of it (one end, one side, cut by the image) and
        never more than all of it: each measurement's fitted dims bound the object's from below.
        Averaging them, as eq. 1's dims residual does over hundreds of partial views, makes every
        car short (measured on PAMS flights, ``docs/pams.md``); an upper percentile over the
        landmark's measurements (its own and its fused twins', each counted once) is the extent
        its whole views agree on, and a few long outliers (a mask bleeding onto the next car) do
        not move it: ``extent_percentiles`` — the length's high (few views see a whole van),
        the width's and height's lower (most views see them whole, and the masks bleed). Per
        axis, the fitted dims of the measurements that did not complete it with the class prior
        (:func:`.shapes.complete_cuboid`: a part whose far face was not seen); an axis every
        measurement completed is known only by the prior, so the completed dims are its extent.
        Each measurement's box axes are matched to the estimate's horizontal axes by direction
        (world frame, ``pose``: key pose key → 4 × 4 world ← body), so an end-on view of a car
        measures its width, not its length.

        Returns:
            ``dims`` in the estimate's axis order, or ``None`` (no cuboid measurement).
        """
        R_est = np.asarray(estimate["rotation"], float)
        fitted, completed, extended = [], [], []
        for owner, k, s in self.recs[lm_id].measured:
            if s["model"] != "cuboid":
                continue
            rec = self.recs.get(owner)
            dims = np.asarray(s["dims"], float)
            as_measured = (dims, np.zeros(3, bool))  # no fit kept: its dims as measured
            raw, ext = rec.fitted.get(k, as_measured) if rec is not None else as_measured
            b1 = pose(k)[:3, :3] @ np.asarray(s["rotation"], float)[:, 0]
            order = [0, 1, 2] if abs(float(b1 @ R_est[:, 0])) >= abs(float(b1 @ R_est[:, 1])) else [1, 0, 2]
            fitted.append(np.asarray(raw, float)[order])
            completed.append(dims[order])
            extended.append(np.asarray(ext, bool)[order])
        if not fitted:
            return None
        fitted, completed, extended = np.array(fitted), np.array(completed), np.array(extended)
        d_est = np.asarray(estimate["dims"], float)
        length_axis = 0 if d_est[0] >= d_est[1] else 1
        q_length, q_other = self.p.extent_percentiles
        q = [q_length if a == length_axis else q_other for a in range(3)]
        return np.array(
            [
                np.percentile(fitted[~extended[:, a], a], q[a])
                if (~extended[:, a]).any()
                else np.percentile(completed[:, a], q[a])
                for a in range(3)
            ]
        )

    def extent_factor(
        self, lm_id: int, estimate: dict, pose: Callable[[int], np.ndarray]
    ) -> gtsam.NonlinearFactor | None:
        """The one measurement of a cuboid landmark's dims (``extent``): its views' :meth:`extent`
        with one good look's dims std (``base_sigmas``); ``None`` without ``extent`` or views."""
        rec = self.recs[lm_id]
        if not self.p.extent or rec.model != "cuboid":
            return None
        dims = self.extent(lm_id, estimate, pose)
        if dims is None:
            return None
        sigma = self.base_sigmas(rec.cls, "cuboid")[1]
        return gtsam.PriorFactorPoint3(
            cuboid_keys(lm_id)[1], dims, gtsam.noiseModel.Isotropic.Sigma(3, sigma)
        )

    def initial_values(self, lm_id: int, shape_world: dict, values: gtsam.Values) -> None:
        """Insert the variables of a landmark entering the graph, from a world-frame shape."""
        if shape_world["model"] == "cuboid":
            o, d = cuboid_keys(lm_id)
            values.insert(o, gtsam.Pose3(shapes.cuboid_pose(shape_world)))
            values.insert(d, np.asarray(shape_world["dims"], float))
        else:
            b, n, r = cylinder_keys(lm_id)
            values.insert(b, np.asarray(shape_world["root"], float))
            values.insert(n, gtsam.Unit3(np.asarray(shape_world["axis"], float)))
            values.insert(r, np.array([shape_world["radius"]]))
        self.recs[lm_id].in_graph = True

    def factor(
        self,
        pose_key: int,
        kp_id: int,
        lm_id: int,
        shape_body: dict,
        T_world_body: np.ndarray,
        estimate: dict | None,
        robust,  # noqa: ANN001 — the backend's M-estimator wrapper
        on: int | None = None,
    ) -> gtsam.NonlinearFactor:
        """The eq. 1 / eq. 2 factor of one measurement (body frame) of landmark ``lm_id``.

        A box looks the same after a half turn (and after a quarter turn with length and width
        swapped): the measured pose is replaced by the equivalent closest in rotation to the
        current estimate (``estimate``, world frame), so that the SE(3) log of eq. 1 stays small
        even when a view of one face swapped length and width or the facing cue flipped. The
        translation and dimension noise is widened by the measurement's slack along each axis
        (half of what its dims lack against the estimate's and the class's typical box).
        ``on``: the landmark whose variables the factor constrains, when it is not ``lm_id`` (the
        base merge puts a fused twin's measurements, with their own noise, on the survivor's).
        """
        rec = self.recs[lm_id]
        on = lm_id if on is None else on
        if shape_body["model"] == "cuboid":
            o, d = cuboid_keys(on)
            Z = shapes.cuboid_pose(shape_body)
            dims = np.asarray(shape_body["dims"], float)
            slack = rec.slack.get(kp_id)
            loose_c, loose_d = rec.loose.get(kp_id, (np.zeros(3), np.zeros(3)))
            if estimate is not None:
                Z, dims, k = _closest_equivalent(
                    Z, dims, np.linalg.inv(T_world_body) @ shapes.cuboid_pose(estimate)
                )
                if k % 2:
                    loose_c, loose_d = loose_c[[1, 0, 2]], loose_d[[1, 0, 2]]
                # the slack along the axes the measurement now has: what it lacks against the
                # estimate and against the class's typical (sorted) box in the estimate's order
                ref = np.asarray(estimate["dims"], float)
                if rec.ref_dims is not None:
                    typ = rec.ref_dims if ref[0] >= ref[1] else rec.ref_dims[[1, 0, 2]]
                    ref = np.maximum(ref, typ)
                slack = np.maximum(ref - dims, 0.0) / 2.0
                slack = np.where(loose_d > 0, np.maximum(slack, loose_c), slack)
            base = self.base_sigmas(rec.cls, "cuboid")
            if self.p.extent:  # the dims are measured once per landmark, by its views' extent
                loose_d = np.full(3, UNMEASURED)
            noise = self.noise("cuboid", slack, loose_d, rec.scale.get(kp_id, 1.0), base)
            return cuboid_factor(pose_key, o, d, Z, dims, robust(noise))
        base = self.base_sigmas(rec.cls, shape_body["model"])
        noise = robust(self.noise(shape_body["model"], scale=rec.scale.get(kp_id, 1.0), base=base))
        b, n, r = cylinder_keys(on)
        return cylinder_factor(
            pose_key, b, n, r, shape_body["root"], shape_body["axis"], shape_body["radius"], noise
        )

    def anchor(self, lm_id: int, shape_world: dict) -> list[gtsam.NonlinearFactor]:
        """With ``factors`` off: priors holding a shape's variables at its first fit (world frame),
        all but its reference point, which the detections measure as a point. The shape is reported,
        the graph stays determined, and no detection is counted twice."""
        p = self.p
        if shape_world["model"] == "cuboid":
            o, d = cuboid_keys(lm_id)
            free = 1e3  # the centre: a prior this loose says nothing next to a detection's metres
            rotation = gtsam.noiseModel.Diagonal.Sigmas(np.array([p.sigma_rotation] * 3 + [free] * 3))
            return [
                gtsam.PriorFactorPose3(o, gtsam.Pose3(shapes.cuboid_pose(shape_world)), rotation),
                gtsam.PriorFactorPoint3(
                    d,
                    np.asarray(shape_world["dims"], float),
                    gtsam.noiseModel.Isotropic.Sigma(3, p.sigma_dims),
                ),
            ]
        _, n, r = cylinder_keys(lm_id)
        return [
            gtsam.PriorFactorUnit3(
                n,
                gtsam.Unit3(np.asarray(shape_world["axis"], float)),
                gtsam.noiseModel.Isotropic.Sigma(2, p.sigma_axis),
            ),
            gtsam.PriorFactorVector(
                r, np.array([shape_world["radius"]]), gtsam.noiseModel.Isotropic.Sigma(1, p.sigma_radius)
            ),
        ]

    def estimate(self, lm_id: int, values: gtsam.Values) -> dict | None:
        """The optimised shape of a landmark (world frame), or ``None`` if it has no variables."""
        rec = self.recs.get(lm_id)
        if rec is None or not rec.in_graph:
            return None
        if rec.model == "cuboid":
            o, d = cuboid_keys(lm_id)
            if not values.exists(o):
                return None
            T = values.atPose3(o).matrix()
            return shapes.cuboid_shape(T[:3, :3], T[:3, 3], values.atPoint3(d))
        b, n, r = cylinder_keys(lm_id)
        if not values.exists(b):
            return None
        return shapes.cylinder_shape(
            values.atPoint3(b), values.atUnit3(n).point3(), float(values.atVector(r)[0]), rec.height
        )


#: the dims std of an eq. 1 measurement whose dims are measured by the landmark's extent
#: instead (``extent``): metres, nothing next to the extent's tenths
UNMEASURED = 1e3


@functools.lru_cache(maxsize=4)
def _load_models(path: Path | None) -> UncertaintyModels:
    # one backend per robot at the base: the file is read once
    return UncertaintyModels.load(path)


def _closest_equivalent(Z: np.ndarray, dims: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Among the box's symmetric poses (turns by k·90° about b3), the one closest to ``E``, and k."""
    best, best_err = (Z, dims, 0), np.inf
    for k in range(4):
        Rk = yaw_matrix(k * np.pi / 2)
        Zk = Z.copy()
        Zk[:3, :3] = Z[:3, :3] @ Rk
        dk = dims[[1, 0, 2]] if k % 2 else dims
        # by rotation alone: a partial view (one face) may have its length and width swapped
        err = np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(Zk[:3, :3].T @ E[:3, :3])))
        if err < best_err:
            best, best_err = (Zk, dk, k), err
    return best
