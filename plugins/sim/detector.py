"""The simulator's object detector: detections from the rendered instance masks.

It stands in for an instance-segmentation network (paper 1 runs YOLOv8 at 2 Hz) followed by the
point-cloud post-processing: every visible instance with enough valid depth pixels becomes a
detection whose centroid is the median of its back-projected depth pixels. That centroid is
biased towards the visible side of the object on partial views and occlusions, as in reality.
Misses, centroid noise and false positives (on random surfaces) are drawn from the context's
generator, so a seed fixes them.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from amslam.interfaces import BackendParams, Detector, RunContext
from amslam.types import Detection, Frame


class SimDetector(Detector):
    """Detector plugin ``sim``: reads the simulator's instance and class masks."""

    class Params(BackendParams):
        """Parameters of the simulated detector."""

        rate_hz: float = Field(2.0, gt=0.0, description="how often the runner should call detect()")
        classes: list[str] | None = Field(None, description="classes to report; None = every object class")
        max_range: float = Field(5.0, gt=0.0, description="pixels farther than this are ignored (m)")
        min_pixels: int = Field(
            60, ge=1, description="fewest valid pixels of an instance at 640×480 (scaled with image area)"
        )
        miss_probability: float = Field(0.05, ge=0.0, le=1.0, description="chance to miss a visible object")
        false_positive_rate: float = Field(
            0.02, ge=0.0, description="expected false detections per frame (Poisson)"
        )
        centroid_noise: float = Field(0.03, ge=0.0, description="σ of noise added to each centroid axis (m)")
        max_points: int = Field(400, ge=0, description="points_cam is subsampled to at most this many")

    def __init__(self) -> None:
        self.params: SimDetector.Params | None = None
        self.rate_hz = 2.0

    def configure(self, params: BackendParams, context: RunContext) -> None:
        assert isinstance(params, SimDetector.Params), type(params)
        self.params = params
        self.rate_hz = params.rate_hz
        self.rng = context.rng

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
            if self.rng.random() < p.miss_probability:
                continue
            pts = _backproject(mask, depth, Kinv)
            centroid = np.median(pts, axis=0) + self.rng.normal(0.0, p.centroid_noise, 3)
            # confidence grows with how much of the object is seen
            conf = float(
                np.clip(0.55 + 0.4 * min(1.0, cnt / (20 * min_px)) + self.rng.normal(0, 0.03), 0, 0.99)
            )
            out.append(Detection(cls, conf, centroid, self._subsample(pts)))
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
            pts = _backproject(patch, depth, Kinv)
            cls = classes[int(self.rng.integers(len(classes)))]
            conf = float(self.rng.uniform(0.3, 0.7))
            out.append(Detection(cls, conf, np.median(pts, axis=0), self._subsample(pts)))
        return out

    def _subsample(self, pts: np.ndarray) -> np.ndarray:
        assert self.params is not None
        m = self.params.max_points
        if len(pts) <= m:
            return pts
        idx = self.rng.choice(len(pts), size=m, replace=False)
        return pts[np.sort(idx)]


def _backproject(mask: np.ndarray, depth: np.ndarray, Kinv: np.ndarray) -> np.ndarray:
    """Camera-frame points (N×3) of the masked depth pixels."""
    v, u = np.nonzero(mask)
    z = depth[v, u].astype(np.float64)
    pix = np.stack([u, v, np.ones_like(u)], axis=1).astype(np.float64)
    return (pix @ Kinv.T) * z[:, None]
