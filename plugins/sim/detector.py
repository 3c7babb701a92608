"""The simulator's object detector: detections from the rendered instance masks.

It stands in for an instance-segmentation network (paper 1 runs YOLOv8 at 2 Hz; paper 2 a
RangeNet++-like segmentation) followed by the point-cloud post-processing: every visible instance
with enough valid depth pixels becomes a detection whose centroid is the median of its
back-projected depth pixels. That centroid is biased towards the visible side of the object on
partial views and occlusions, as in reality.

**Perception model (paper 2 §IV-C).** A real detector is more confident, and a real object fit more
accurate, from some places than from others; paper 2 characterises that against the *range* and
the *viewing angle* of the sensor. So that such a characterisation of the simulated detector is
meaningful, confidence, misses and geometric noise depend on both, per class
(:class:`PerceptionModel`):

* range ``r``: distance from the camera to the detection's centroid (what a pipeline measures);
* viewing angle ``θ`` ∈ [0, π]: horizontal angle, at the object, between the object's forward
  axis (+x of its frame) and the direction to the camera: 0 = seen from the front, π/2 = from the
  side, π = from behind. The object's frame comes from the world's ground truth: the yaw of its
  shape (:attr:`WorldSummary.object_shapes`) or, for the axis-aligned boxes of procedural worlds,
  the world axes. Without ground truth (no world in the context) θ is unknown and only range acts.

``confidence = c_max · f_r(r) · f_θ(θ) · f_vis + ε`` with a logistic range fall-off
``f_r = 1 / (1 + exp((r − r_half) / r_width))``, an end-on penalty
``f_θ = 1 − a_front · max(cos θ, 0)² − a_back · max(−cos θ, 0)²`` (vehicles are recognised best
from the side, and better from behind than from the front, paper 2 Fig. 6) and the visible share
``f_vis`` (occlusion, partial views). A detection is then kept with probability
``(1 − miss_probability) · clip((conf − miss_floor) / (miss_ceiling − miss_floor), 0, 1)``: weak
detections are the ones that get missed. The detected object is displaced as a whole (centroid
and points) by a localisation error of std ``σ(r) = centroid_noise + centroid_noise_per_m2 · r²``
per axis; the camera's depth noise (σ ∝ z²) adds per-point noise on top.

Misses, noise and false positives (on random surfaces) are drawn from the context's generator, so
a seed fixes them.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from amslam.interfaces import BackendParams, Detector, RunContext
from amslam.lib.camera import backproject
from amslam.lib.viewing import object_yaw, viewing_angle
from amslam.types import Detection, Frame, WorldSummary


class PerceptionModel(BaseModel):
    """How confidence and geometric noise of one class depend on range and viewing angle."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    confidence_max: float = Field(0.95, gt=0.0, le=1.0, description="confidence of an ideal close view")
    range_half: float = Field(
        7.0, gt=0.0, le=1000, description="range at which the range factor of the confidence halves, m"
    )
    range_width: float = Field(1.2, gt=0.0, le=1000, description="width of the logistic range fall-off, m")
    front_penalty: float = Field(
        0.1, ge=0.0, le=1.0, description="share of confidence lost when seen end-on from the front"
    )
    back_penalty: float = Field(
        0.05, ge=0.0, le=1.0, description="share of confidence lost when seen end-on from behind"
    )
    centroid_noise_per_m2: float = Field(
        0.002, ge=0.0, le=10, description="growth of the localisation std with range squared, m per m²"
    )


#: Vehicles: strongly view-dependent (paper 2 Fig. 6); poles and trunks: range only (paper 2 §V-A).
DEFAULT_MODELS: dict[str, PerceptionModel] = {
    "car": PerceptionModel(
        confidence_max=0.97,
        range_half=14.0,
        range_width=2.5,
        front_penalty=0.45,
        back_penalty=0.25,
        centroid_noise_per_m2=0.001,
    ),
    "pole": PerceptionModel(
        range_half=16.0, range_width=3.0, front_penalty=0.0, back_penalty=0.0, centroid_noise_per_m2=0.001
    ),
    "tree_trunk": PerceptionModel(
        range_half=16.0, range_width=3.0, front_penalty=0.0, back_penalty=0.0, centroid_noise_per_m2=0.001
    ),
}


class SimDetector(Detector):
    """Detector plugin ``sim``: reads the simulator's instance and class masks."""

    #: part of the simulator: its detection errors depend on the true viewing angle of each
    #: object (``context.world``), as a real detector's depend on the real one (Backend.simulator)
    simulator = True

    class Params(BackendParams):
        """Parameters of the simulated detector."""

        rate_hz: float = Field(
            2.0, gt=0.0, le=1000.0, description="how often the runner should call detect()"
        )
        classes: list[str] | None = Field(None, description="classes to report; None = every object class")
        max_range: float = Field(
            5.0, gt=0.0, le=100.0, description="pixels farther than this are ignored (m)"
        )
        min_pixels: int = Field(
            60,
            ge=1,
            le=1_000_000,
            description="fewest valid pixels of an instance at 640×480 (scaled with image area)",
        )
        miss_probability: float = Field(
            0.05, ge=0.0, le=1.0, description="chance to miss a visible object even when confident"
        )
        miss_floor: float = Field(
            0.3, ge=0.0, le=1.0, description="detections with confidence at or below this are always missed"
        )
        miss_ceiling: float = Field(
            0.55, ge=0.0, le=1.0, description="above this confidence only miss_probability misses"
        )
        confidence_noise: float = Field(0.03, ge=0.0, le=1, description="σ of the noise on the confidence")
        false_positive_rate: float = Field(
            0.02,
            ge=0.0,
            le=100,
            description="expected false detections per frame (Poisson; at most 100: each one is drawn)",
        )
        centroid_noise: float = Field(
            0.03,
            ge=0.0,
            le=100,
            description="σ of the localisation error of a detection at zero range, per axis (m)",
        )
        max_points: int = Field(
            400, ge=0, le=1_000_000, description="points_cam is subsampled to at most this many"
        )
        default_model: PerceptionModel = Field(
            default_factory=PerceptionModel, description="perception model of classes not listed in models"
        )
        models: dict[str, PerceptionModel] = Field(
            default_factory=lambda: dict(DEFAULT_MODELS),
            description="perception model per class (confidence and noise vs range and viewing angle)",
        )

    def __init__(self) -> None:
        self.params: SimDetector.Params | None = None
        self.rate_hz = 2.0
        self.world: WorldSummary | None = None

    def configure(self, params: BackendParams, context: RunContext) -> None:
        assert isinstance(params, SimDetector.Params), type(params)
        self.params = params
        self.rate_hz = params.rate_hz
        self.rng = context.rng
        self.world = context.world

    def model(self, class_name: str) -> PerceptionModel:
        """The perception model of a class."""
        assert self.params is not None
        return self.params.models.get(class_name, self.params.default_model)

    def expected_confidence(
        self, class_name: str, rng: float, angle: float | None, visible: float = 1.0
    ) -> float:
        """Noise-free confidence of a detection at range ``rng`` (m) and viewing angle (rad).

        Args:
            class_name: semantic class.
            rng: range from the camera to the object, m.
            angle: viewing angle in [0, π] (see the module docstring); None if unknown.
            visible: visible share factor ``f_vis`` in [0.6, 1].
        """
        m = self.model(class_name)
        f_r = 1.0 / (1.0 + math.exp((rng - m.range_half) / m.range_width))
        f_a = 1.0
        if angle is not None:
            c = math.cos(angle)
            f_a = 1.0 - m.front_penalty * max(c, 0.0) ** 2 - m.back_penalty * max(-c, 0.0) ** 2
        return m.confidence_max * f_r * f_a * visible

    def detection_probability(self, confidence: float) -> float:
        """Probability that a detection of this confidence is reported (the rest are misses)."""
        p = self.params
        assert p is not None
        span = max(p.miss_ceiling - p.miss_floor, 1e-9)
        return (1.0 - p.miss_probability) * float(np.clip((confidence - p.miss_floor) / span, 0.0, 1.0))

    def localisation_sigma(self, class_name: str, rng: float) -> float:
        """Std (m, per axis) of the localisation error of a detection at range ``rng``."""
        assert self.params is not None
        return self.params.centroid_noise + self.model(class_name).centroid_noise_per_m2 * rng * rng

    def detect(self, frame: Frame) -> list[Detection]:
        """Detections of the objects visible in a simulator frame (camera frame)."""
        p = self.params
        if p is None:
            raise RuntimeError("SimDetector.detect() called before configure()")
        if frame.instance is None or frame.class_id is None:
            raise ValueError("the sim detector needs simulator frames (with instance and class masks)")
        H, W = frame.depth.shape
        min_px = max(1, int(round(p.min_pixels * (H * W) / (640 * 480))))
        depth = frame.depth
        valid = (depth > 0) & (depth <= p.max_range)
        inst = np.where(valid, frame.instance, 0)
        names = frame.class_names
        wanted = None if p.classes is None else set(p.classes)
        # invert K once for back-projection of pixel centres (u, v) at integer coordinates
        Kinv = np.linalg.inv(frame.K)

        ids, counts = np.unique(inst[inst > 0], return_counts=True)
        out: list[Detection] = []
        for iid, cnt in zip(ids.tolist(), counts.tolist(), strict=True):
            if cnt < min_px:
                continue
            mask = inst == iid
            cls_id = int(np.bincount(frame.class_id[mask]).argmax())
            cls = names[cls_id] if cls_id < len(names) else str(cls_id)
            if wanted is not None and cls not in wanted:
                continue
            pts = backproject(mask, depth, Kinv)
            centroid = np.median(pts, axis=0)
            rng_m = float(np.linalg.norm(centroid))
            angle = self._viewing_angle(cls, centroid, frame.T_world_cam_truth)
            visible = 0.6 + 0.4 * min(1.0, cnt / (20 * min_px))
            conf = self.expected_confidence(cls, rng_m, angle, visible)
            conf = float(np.clip(conf + self.rng.normal(0.0, p.confidence_noise), 0.0, 0.99))
            if self.rng.random() >= self.detection_probability(conf):
                continue
            # the detection is mislocalised as a whole: its centroid and its points move together
            offset = self.rng.normal(0.0, self.localisation_sigma(cls, rng_m), 3)
            out.append(Detection(cls, conf, centroid + offset, self._subsample(pts) + offset))
        # false positives: a patch of some surface labelled as a random wanted class
        n_fp = int(self.rng.poisson(p.false_positive_rate))
        classes = [c for c in names[1:] if wanted is None or c in wanted]
        ys, xs = np.nonzero(valid)
        for _ in range(n_fp):
            if not classes or len(ys) == 0:
                break
            k = int(self.rng.integers(len(ys)))
            r = max(2, int(0.03 * W))
            patch = np.zeros_like(valid)
            patch[max(0, ys[k] - r) : ys[k] + r, max(0, xs[k] - r) : xs[k] + r] = True
            patch &= valid
            pts = backproject(patch, depth, Kinv)
            cls = classes[int(self.rng.integers(len(classes)))]
            conf = float(self.rng.uniform(0.3, 0.7))
            out.append(Detection(cls, conf, np.median(pts, axis=0), self._subsample(pts)))
        return out

    def _viewing_angle(
        self, class_name: str, centroid_cam: np.ndarray, T_world_cam: np.ndarray | None
    ) -> float | None:
        """Viewing angle of the true object nearest the detection (None without ground truth)."""
        w = self.world
        if w is None or T_world_cam is None or not w.object_positions:
            return None
        p_world = T_world_cam[:3, :3] @ centroid_cam + T_world_cam[:3, 3]
        best, best_d = None, 3.0  # a detection lies on its object: metres, not tens of metres
        for name, pos in w.object_positions.items():
            if w.object_classes.get(name) != class_name:
                continue
            d = float(np.linalg.norm(np.asarray(pos)[:2] - p_world[:2]))
            if d < best_d:
                best, best_d = name, d
        if best is None:
            return None
        yaw = object_yaw(w.object_shapes.get(best))
        return viewing_angle(np.asarray(w.object_positions[best], float), yaw, T_world_cam[:3, 3])

    def _subsample(self, pts: np.ndarray) -> np.ndarray:
        assert self.params is not None
        m = self.params.max_points
        if len(pts) <= m:
            return pts
        idx = self.rng.choice(len(pts), size=m, replace=False)
        return pts[np.sort(idx)]
