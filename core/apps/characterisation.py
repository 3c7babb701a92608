"""Uncertainty characterisation samples from simulated spiral flights (paper 2 §IV-C1).

Paper 2 flies a spiral-shaped trajectory around an object "to cover as many angles and ranges as
possible", and records for each frame the range and viewing angle of the sensor together with the
object's classification confidence and the error of its geometric model against ground truth.
Here the same is done in the simulator, without flying: one small world per target class (the
object alone on a ground plane, so nothing else occludes it), frames rendered directly at poses
on spirals of growing radius at several heights, each facing the object, and the simulated
detector run on every frame.

Each sample is one frame in which the object is in view (enough pixels):

* ``range`` — distance from the camera to the true object centre, m;
* ``angle`` — viewing angle in [0, π] (:func:`amslam.lib.viewing.viewing_angle`):
  0 = in front, π/2 = beside, π = behind;
* ``detected`` and ``confidence`` — the detector's confidence, 0 when it missed the object;
* ``errors`` — the geometric error of the detection in the object frame: ``x`` (along the
  object's forward axis) and ``y`` (lateral) of the detected centre, and — for cuboid classes,
  when a cuboid fit is available (:mod:`amslam.lib.shapes`) — ``length`` and
  ``width`` of the fitted box minus the true ones (paper 2 §IV-C: "for vehicles we only consider
  uncertainties in X-Y localization, length, and width"; for cylinders only X-Y localisation).

:func:`collect` returns :class:`Samples`, saved as a plain ``.npz`` (no pickle). The command
``amslam characterise`` (:mod:`amslam.apps.characterise`) runs :func:`characterise`.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from amslam.errors import AmslamError
from amslam.geometry import yaw_matrix
from amslam.interfaces import RunContext
from amslam.lib.class_colours import class_colour
from amslam.lib.viewing import viewing_angle
from amslam.plugins.pams.uncertainty import COMPONENTS, UncertaintyModels, fit_models, plot_models
from amslam.plugins.sim.camera import CameraParams, Renderer
from amslam.plugins.sim.detector import SimDetector
from amslam.plugins.sim.procedural import FURNITURE_CLASSES, furniture_boxes, piece_shape
from amslam.plugins.sim.world import (
    MeshPart,
    World,
    WorldObject,
    WorldSpec,
    box_mesh,
    boxes_mesh,
    prism_mesh,
)
from amslam.types import CameraModel, Frame, WorldSummary

#: Error components recorded for every sample (NaN where a component does not apply).


class TargetSpec(BaseModel):
    """One object class to characterise and the true shape of its specimen."""

    model_config = ConfigDict(defer_build=True, extra="forbid", allow_inf_nan=False)

    class_name: str
    model: Literal["cuboid", "cylinder"] = "cuboid"
    size: tuple[float, float, float] = Field(
        (4.6, 1.9, 1.5), description="cuboid: length, width, height; cylinder: radius, radius, height (m)"
    )
    yaw: float = Field(0.3, description="heading of the specimen's forward axis, rad")
    range_max: float | None = Field(None, gt=0.0, description="this class's spiral radius limit, m")
    specimen: Literal["solid", "furniture"] = Field(
        "solid",
        description="solid: a box or prism of ``size``; furniture: the procedural buildings' piece of"
        " the class (legs, seat, backrest, shelves: what the camera sees of real furniture), its"
        " size drawn as theirs (``size`` unused)",
    )


#: The specimens ``amslam characterise --classes`` knows: outdoor solids and indoor furniture.
SPECIMENS: dict[str, TargetSpec] = {
    "car": TargetSpec(class_name="car", model="cuboid", size=(4.6, 1.9, 1.5)),
    "pole": TargetSpec(class_name="pole", model="cylinder", size=(0.15, 0.15, 4.0)),
    **{c: TargetSpec(class_name=c, model="cuboid", yaw=0.3, specimen="furniture") for c in FURNITURE_CLASSES},
}


class CharacteriseConfig(BaseModel):
    """Where the spirals go and what sensor and detector fly them."""

    model_config = ConfigDict(defer_build=True, extra="forbid", allow_inf_nan=False)

    targets: list[TargetSpec] = Field(
        default_factory=lambda: [
            SPECIMENS["car"],
            SPECIMENS["pole"],
            SPECIMENS["chair"].model_copy(update={"range_max": 8.0}),
        ]
    )
    range_min: float = Field(2.0, gt=0.0, description="horizontal radius where a spiral starts, m")
    range_max: float = Field(16.0, gt=0.0, description="horizontal radius where a spiral ends, m")
    heights: list[float] = Field(
        default_factory=lambda: [1.5, 3.0, 5.0], description="one spiral per flight height above ground, m"
    )
    turns: float = Field(6.0, gt=0.0, description="turns of each spiral around the object")
    poses_per_spiral: int = Field(240, ge=4, description="frames per spiral")
    camera: CameraParams = Field(
        default_factory=lambda: CameraParams(
            width=320, height=240, max_range=20.0, depth_noise=0.002, rgb=False
        )
    )
    detector: SimDetector.Params = Field(
        default_factory=lambda: SimDetector.Params(max_range=20.0, false_positive_rate=0.0)
    )
    seed: int = 0


@dataclass
class Samples:
    """Characterisation samples (one per frame with the object in view)."""

    class_name: np.ndarray  # (N,) str
    range: np.ndarray  # (N,) m
    angle: np.ndarray  # (N,) rad in [0, π]
    detected: np.ndarray  # (N,) bool
    confidence: np.ndarray  # (N,) in [0, 1], 0 when missed
    errors: np.ndarray  # (N, len(COMPONENTS)) in the object frame, NaN where not applicable
    models: dict[str, str]  # class → "cuboid" | "cylinder"

    def __len__(self) -> int:
        return len(self.range)

    def of(self, class_name: str) -> Samples:
        """The samples of one class."""
        sel = self.class_name == class_name
        return Samples(
            self.class_name[sel],
            self.range[sel],
            self.angle[sel],
            self.detected[sel],
            self.confidence[sel],
            self.errors[sel],
            {class_name: self.models[class_name]},
        )

    def save(self, path: Path) -> None:
        """Write a plain ``.npz`` (strings as unicode arrays: loadable without pickle)."""
        classes = sorted(self.models)
        np.savez_compressed(
            Path(path),
            format=np.array("amslam-characterisation-1"),
            class_name=self.class_name.astype(str),
            range=self.range,
            angle=self.angle,
            detected=self.detected,
            confidence=self.confidence,
            errors=self.errors,
            components=np.array(COMPONENTS),
            model_classes=np.array(classes),
            model_kinds=np.array([self.models[c] for c in classes]),
        )

    @staticmethod
    def load(path: Path) -> Samples:
        """Read samples written by :meth:`save`."""
        with np.load(Path(path), allow_pickle=False) as f:
            return Samples(
                f["class_name"],
                f["range"],
                f["angle"],
                f["detected"],
                f["confidence"],
                f["errors"],
                dict(zip(f["model_classes"].tolist(), f["model_kinds"].tolist(), strict=True)),
            )

    @staticmethod
    def concatenate(parts: list[Samples]) -> Samples:
        """All samples of several collections."""
        models: dict[str, str] = {}
        for p in parts:
            models.update(p.models)
        return Samples(
            np.concatenate([p.class_name for p in parts]).astype(str),
            np.concatenate([p.range for p in parts]),
            np.concatenate([p.angle for p in parts]),
            np.concatenate([p.detected for p in parts]),
            np.concatenate([p.confidence for p in parts]),
            np.concatenate([p.errors for p in parts]),
            models,
        )


# -- the specimen world ------------------------------------------------------------------------


def specimen_world(
    target: TargetSpec, extent: float, rng: np.random.Generator | None = None
) -> tuple[World, WorldSummary, dict]:
    """The object alone at the origin on a ground slab ``2·extent`` wide, and its ground truth.

    A furniture specimen's size is drawn with ``rng``; its true shape is the box bounding its
    parts, the box the simulator's metrics score a fitted landmark against.

    Returns:
        (world, summary with the object's position, class and shape, the true shape dict).
    """
    ground_v, ground_t = box_mesh(np.array([-extent, -extent, -0.2]), np.array([extent, extent, 0.0]))
    parts = [MeshPart.uniform("ground", ground_v, ground_t, 0, class_colour("floor"))]
    if target.specimen == "furniture":
        boxes = furniture_boxes(target.class_name, rng if rng is not None else np.random.default_rng(0))
        shape = piece_shape(boxes, np.zeros(3), target.yaw)
        # centred on the origin like a solid specimen, standing on the ground
        offset = -np.array([shape["center"][0], shape["center"][1], 0.0])
        v, t = boxes_mesh(boxes)
        v = v @ yaw_matrix(target.yaw).T + offset
        height = float(shape["dims"][2])
        shape["center"] = [0.0, 0.0, height / 2]
    elif target.model == "cuboid":
        length, width, height = target.size
        v, t = box_mesh(np.array([-length / 2, -width / 2, 0.0]), np.array([length / 2, width / 2, height]))
        v = v @ yaw_matrix(target.yaw).T
        shape = {
            "model": "cuboid",
            "center": [0.0, 0.0, height / 2],
            "dims": [length, width, height],
            "yaw": target.yaw,
        }
    else:
        v, t = prism_mesh(target.size[0], 0.0, target.size[2], sides=24)
        height = target.size[2]
        shape = {
            "model": "cylinder",
            "root": [0.0, 0.0, 0.0],
            "axis": [0.0, 0.0, 1.0],
            "radius": target.size[0],
            "height": height,
        }
    name = f"{target.class_name}_1"
    parts.append(MeshPart.uniform(name, v, t, 1, class_colour(target.class_name)))
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = np.array([0.0, 0.0, height / 2])
    obj = WorldObject(name, target.class_name, 1, centre, lo, hi)
    spec = WorldSpec(
        name=f"specimen-{target.class_name}",
        parts=parts,
        objects=[obj],
        floor_heights=(0.0,),
        bounds_lo=np.array([-extent, -extent, -0.2]),
        bounds_hi=np.array([extent, extent, 10.0]),
        start_xy=np.array([extent - 1.0, 0.0]),
        start_floor_z=0.0,
    )
    world = World(spec)
    summary = WorldSummary(
        name=spec.name,
        bounds_lo=spec.bounds_lo,
        bounds_hi=spec.bounds_hi,
        reachable_free_volume=0.0,
        floor_heights=(0.0,),
        reachable_free_volume_per_floor=(0.0,),
        objects_by_class={target.class_name: 1},
        object_positions={name: centre},
        object_classes={name: target.class_name},
        object_shapes={name: shape},
    )
    return world, summary, shape


def spiral_poses(
    centre: np.ndarray, config: CharacteriseConfig, range_max: float | None = None
) -> list[np.ndarray]:
    """``T_world_body`` of level bodies on spirals around ``centre``, each facing it.

    One spiral per height: the horizontal radius grows linearly from ``range_min`` to
    ``range_max`` over ``turns`` turns; the spirals start at staggered bearings.
    """
    poses = []
    n = config.poses_per_spiral
    for k, h in enumerate(config.heights):
        t = np.linspace(0.0, 1.0, n)
        r_max = config.range_max if range_max is None else range_max
        radius = config.range_min + (r_max - config.range_min) * t
        bearing = 2.0 * np.pi * (config.turns * t + k / max(len(config.heights), 1))
        for r, b in zip(radius, bearing, strict=True):
            T = np.eye(4)
            yaw = b + np.pi
            T[:3, :3] = yaw_matrix(yaw)
            T[:3, 3] = [centre[0] + r * np.cos(b), centre[1] + r * np.sin(b), h]
            poses.append(T)
    return poses


# -- collection -------------------------------------------------------------------------------


def _shape_fitters() -> dict[str, Callable[[np.ndarray], dict | None]]:
    """The "shapes" fits (world points → shape dict or None) by model, when that module exists."""
    try:
        from amslam.lib import shapes
    except ImportError:
        return {}
    return {"cuboid": shapes.fit_cuboid, "cylinder": shapes.fit_cylinder}


def _plausible(shape: dict, centroid: np.ndarray, gate: float = 3.0) -> bool:
    """A fit a pipeline would keep: reference point near the detection, sane size.

    Far from the object the points are few and noisy and a circle or box fit can diverge (a pole
    of 50 m radius); a real pipeline gates such fits out, judged by the detection alone.
    """
    if shape["model"] == "cuboid":
        ref, size = np.asarray(shape["center"], float), float(max(shape["dims"]))
        sane = size < 15.0
    else:
        ref, size = np.asarray(shape["root"], float), float(shape["radius"])
        sane = size < 1.5
    return bool(sane and np.linalg.norm(ref[:2] - centroid[:2]) < gate)


def _dims_error(fitted: dict, truth: dict) -> tuple[float, float]:
    """(length, width) of a fitted cuboid minus the true ones (length = the longer side)."""
    d = np.asarray(fitted["dims"], float)
    t = np.asarray(truth["dims"], float)
    fl, fw = sorted(d[:2], reverse=True)
    tl, tw = sorted(t[:2], reverse=True)
    return float(fl - tl), float(fw - tw)


def collect(config: CharacteriseConfig, log: Callable[[str], None] = lambda s: None) -> Samples:
    """Fly the spirals around every target and return the samples."""
    camera: CameraModel = config.camera.model()
    renderer = Renderer(camera, config.camera)
    rng = np.random.default_rng(config.seed)
    fitters = _shape_fitters()
    parts = []
    extent = config.range_max + 6.0
    for target in config.targets:
        world, summary, truth = specimen_world(target, extent, rng)
        # the models' angle and x / y errors are from the box's longer horizontal axis, as the
        # SLAM backend reads them (a shelf's and a sofa's length is across their own x)
        forward = target.yaw
        if target.model == "cuboid" and truth["dims"][0] < truth["dims"][1]:
            forward += math.pi / 2
        det = SimDetector()
        det.configure(
            config.detector,
            RunContext(rng=np.random.default_rng(rng.integers(2**63)), run_dir=Path("."), world=summary),
        )
        centre = next(iter(summary.object_positions.values()))
        H, W = camera.height, camera.width
        min_px = max(1, int(round(config.detector.min_pixels * (H * W) / (640 * 480))))
        rows: list[tuple] = []
        for T_wb in spiral_poses(centre, config, target.range_max):
            T_wc = T_wb @ camera.T_body_cam
            r = renderer.render(world, T_wc, rng)
            visible = int(
                np.count_nonzero((r.instance == 1) & (r.depth > 0) & (r.depth <= config.detector.max_range))
            )
            if visible < min_px:
                continue  # out of view or too small: not a sample of the detector's behaviour
            frame = Frame(
                0.0, r.depth, camera.K, T_wc, r.rgb, r.instance, r.class_id, world.class_names, T_wc
            )
            dets = [d for d in det.detect(frame) if d.class_name == target.class_name]
            cam = T_wc[:3, 3]
            rng_m = float(np.linalg.norm(cam - centre))
            angle = viewing_angle(centre, forward, cam) if target.model == "cuboid" else 0.0
            err = np.full(len(COMPONENTS), np.nan)
            if dets:
                d = max(dets, key=lambda x: len(x.points_cam))
                c_world = T_wc[:3, :3] @ d.centroid_cam + T_wc[:3, 3]
                R_obj = yaw_matrix(forward if target.model == "cuboid" else 0.0)
                e = R_obj.T @ (c_world - centre)
                err[0], err[1] = e[0], e[1]
                fit = fitters.get(target.model)
                fitted = None
                if fit is not None and len(d.points_cam) >= 20:
                    pts_world = d.points_cam @ T_wc[:3, :3].T + T_wc[:3, 3]
                    with contextlib.suppress(ValueError, np.linalg.LinAlgError):
                        fitted = fit(pts_world)
                if fitted is not None and _plausible(fitted, c_world):
                    # the fitted model's reference point replaces the surface median
                    ref = fitted["center"] if target.model == "cuboid" else fitted["root"]
                    true_ref = truth["center"] if target.model == "cuboid" else truth["root"]
                    e = R_obj.T @ (np.asarray(ref, float) - np.asarray(true_ref, float))
                    err[0], err[1] = e[0], e[1]
                    if target.model == "cuboid":
                        err[2], err[3] = _dims_error(fitted, truth)
                elif fit is not None:
                    err[:] = np.nan  # the fit failed: no geometric measurement from this frame
                rows.append((rng_m, angle, True, d.confidence, err))
            else:
                rows.append((rng_m, angle, False, 0.0, err))
        n = len(rows)
        log(f"  {target.class_name}: {n} frames in view, {sum(r[2] for r in rows)} detected")
        parts.append(
            Samples(
                np.array([target.class_name] * n, dtype=str),
                np.array([r[0] for r in rows], float),
                np.array([r[1] for r in rows], float),
                np.array([r[2] for r in rows], bool),
                np.array([r[3] for r in rows], float),
                np.array([r[4] for r in rows], float).reshape(n, len(COMPONENTS)),
                {target.class_name: target.model},
            )
        )
    return Samples.concatenate(parts)


def angle_degrees(angle: np.ndarray | float) -> np.ndarray | float:
    """Radians to degrees (for tables and plots)."""
    return np.asarray(angle) * (180.0 / math.pi)


def _kept_models(keep: Path | None) -> UncertaintyModels | None:
    """``--keep``'s models, read before anything is flown (a bad file fails then, not after)."""
    if keep is None:
        return None
    try:
        return UncertaintyModels.load(keep)
    except (OSError, ValueError, KeyError) as e:
        raise AmslamError(
            f"characterise --keep {keep}: not a models file written by amslam characterise"
            f" ({type(e).__name__})"
        ) from e


def _config(
    mission,
    classes: list[str] | None,
    heights: list[float] | None,
    range_min: float | None,
    poses_per_spiral: int | None,
    seed: int,
) -> CharacteriseConfig:
    """The spirals, targets, camera and detector of a characterisation (see :func:`characterise`)."""
    config = CharacteriseConfig(seed=seed)
    if classes is not None:
        unknown = [c for c in classes if c not in SPECIMENS]
        if unknown:
            raise AmslamError(
                f"characterise --classes: no specimen for {', '.join(unknown)}; known: {', '.join(SPECIMENS)}"
            )
        config.targets = [SPECIMENS[c] for c in classes]
    if heights is not None:
        config.heights = list(heights)
    if range_min is not None:
        config.range_min = range_min
    if mission is not None:
        platform, detector = mission.backends.get("platform"), mission.backends.get("detector")
        if platform is not None and hasattr(platform.params, "camera"):
            config.camera = platform.params.camera.model_copy(update={"rgb": False})
        if detector is not None and detector.plugin == "sim":
            config.detector = detector.params.model_copy(update={"false_positive_rate": 0.0})
            if classes is None and config.detector.classes is not None:  # what the detector reports
                config.targets = [t for t in config.targets if t.class_name in config.detector.classes]
        # the mission's sensor as it is: spirals reach a little beyond what it can detect
        reach = min(config.camera.max_range, config.detector.max_range)
        config.range_max = min(config.range_max, reach + 1.0)
        config.targets = [t.model_copy(update={"range_max": None}) for t in config.targets]
    if poses_per_spiral is not None:
        config.poses_per_spiral = poses_per_spiral
    return config


def characterise(
    out: Path,
    *,
    mission=None,
    poses_per_spiral: int | None = None,
    seed: int = 0,
    samples_in: Path | None = None,
    classes: list[str] | None = None,
    heights: list[float] | None = None,
    range_min: float | None = None,
    keep: Path | None = None,
    log=print,
) -> UncertaintyModels:
    """``amslam characterise``: fly the spirals, fit the models, write models, samples and a plot.

    Args:
        out: the models file to write (``.npz``); ``<stem>-samples.npz`` and ``<stem>.png`` go
            beside it.
        mission: a loaded :class:`amslam.mission.Mission` whose simulated camera and detector
            are the ones to characterise (its world is not used: every class is characterised on
            its own specimen, see :mod:`amslam.apps.characterisation`); None = the defaults.
        poses_per_spiral: frames per spiral (default: the characterisation default).
        seed: seed of the rendering and detector noise and of the MLP.
        samples_in: refit samples saved by an earlier call instead of flying again.
        classes: the classes to characterise, from :data:`SPECIMENS` (default: car, pole and
            chair, those the mission's detector reports).
        heights: the spirals' heights above the ground, m (indoors: the heights the robot flies).
        range_min: the spirals' starting radius, m (indoors: as close as the robot comes).
        keep: a models file whose classes not characterised now are written out as they are
            (one file for the outdoor classes, fitted with the outdoor camera, and the indoor
            ones); its header is kept under ``meta["kept"]``.
    """
    out = Path(out)
    kept = _kept_models(keep)
    config = _config(mission, classes, heights, range_min, poses_per_spiral, seed)
    out.parent.mkdir(parents=True, exist_ok=True)  # the samples are written there first
    if samples_in is not None:
        samples = Samples.load(samples_in)
        log(f"samples: {len(samples)} from {samples_in}")
    else:
        log(
            f"flying {len(config.heights)} spirals of {config.poses_per_spiral} frames around each of "
            f"{', '.join(t.class_name for t in config.targets)}"
        )
        samples = collect(config, log)
        samples.save(out.with_name(out.stem + "-samples.npz"))
    models = fit_models(samples, seed=seed)
    models.meta.update(
        {"samples": len(samples), "seed": seed, "camera": config.camera.model_dump(mode="json")}
    )
    if kept is not None:
        names = [n for n in kept.classes if n not in models.classes]
        models.classes.update({n: kept.classes[n] for n in names})
        models.meta["kept"] = {"from": Path(keep).name, "classes": names, "meta": kept.meta}
    models.save(out)
    fitted = {n: m for n, m in models.classes.items() if n in samples.models}  # kept ones have no samples
    plot_models(UncertaintyModels(fitted, models.meta), out.with_suffix(".png"), samples)
    for name, m in models.classes.items():
        log(
            f"  {name}: {m.samples} samples, components {m.components}, range {m.range_bounds[0]:.1f}–"
            f"{m.range_bounds[1]:.1f} m{', angle-dependent' if m.angle_dependent else ''}"
        )
    log(f"models: {out}")
    return models
