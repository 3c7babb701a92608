"""Detector plugin ``onnx``: a YOLOv8-seg ONNX model on the RGB image, lifted to 3-D with depth.

Paper 1 (§IV, §VII) segments chair instances with YOLOv8 on the RGB image of the D435i at 2 Hz
and takes each object's centroid from the depth pixels under its mask. This backend does that
with any model in the YOLOv8-seg ONNX layout (see :mod:`.decoder`): by default the small model
the project trains on the simulator's images (``models/sim_yolov8seg.onnx``, see ``train.py``),
or an ultralytics export named in the mission.

The 3-D step is the ``sim`` detector's: the masked depth pixels are back-projected and the
median of the points is the centroid; the points (subsampled) go to shape fitting. A network's
mask, unlike the simulator's exact one, bleeds over the object's outline and through its gaps (a
chair's legs) onto the wall behind, so before that the mask's depths are split at gaps larger
than ``depth_gap`` and only the largest depth cluster (the nearest one on ties) is kept; then
only the mask's largest connected surface is kept (``surface_step``): a mask spanning two chairs
of a row, or a table's with the floor between its legs, holds two surfaces at the same depths.
Last, a surface that does not stand out of what surrounds it (``min_relief``: its outline is
flush with its surroundings all round, like a picture on a wall or a door in it) is no piece of
furniture and is dropped.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, ValidationInfo, field_validator, model_validator

from amslam.errors import AmslamError
from amslam.interfaces import BackendParams, Detector, RunContext
from amslam.lib.camera import backproject
from amslam.plugins.onnx_detector.decoder import Instance, ModelError, SegmentationModel, inspect_model
from amslam.types import Detection, Frame

#: File name of the shipped model, inside this package's ``models`` folder.
SHIPPED_MODEL = "sim_yolov8seg.onnx"


def shipped_model() -> Path:
    """Path of the model the project ships (trained on simulator images)."""
    return Path(str(importlib.resources.files("amslam.plugins.onnx_detector") / "models" / SHIPPED_MODEL))


def resolve_model(model: str | None, mission_dir: Path | None) -> Path:
    """The model file a mission names: the shipped one by default, else relative to the mission."""
    if model is None:
        return shipped_model()
    path = Path(model).expanduser()
    if not path.is_absolute() and mission_dir is not None:
        path = Path(mission_dir) / path
    return path


class OnnxDetector(Detector):
    """Detector plugin ``onnx``: YOLOv8-seg instance segmentation with onnxruntime on the CPU."""

    requires = ("onnxruntime", "cv2")  # imported when built (see Backend.requires)

    class Params(BackendParams):
        """Parameters of the ONNX instance-segmentation detector."""

        model: str | None = Field(
            None,
            description="ONNX model in the YOLOv8-seg layout, relative to the mission file; "
            "default: the shipped model trained on simulator images (chair, table, shelf, sofa)",
        )
        rate_hz: float = Field(
            2.0, gt=0.0, le=1000.0, description="how often the runner calls detect() (paper 1: 2 Hz)"
        )
        confidence: float = Field(
            0.45,
            gt=0.0,
            lt=1.0,
            description="minimum class score of a detection; 0.45: the shipped model's best F1 on "
            "validation renders (docs/detector.md; ultralytics: 0.25)",
        )
        iou: float = Field(
            0.5,
            gt=0.0,
            le=1.0,
            description="NMS IoU: the weaker of two same-class boxes overlapping more is dropped",
        )
        max_detections: int = Field(50, ge=1, le=10_000, description="most detections per image")
        mask_threshold: float = Field(0.5, gt=0.0, lt=1.0, description="mask probability of an object pixel")
        class_names: list[str] | None = Field(
            None, description="class names by class index; default: the model's 'names' metadata"
        )
        classes: list[str] | None = Field(None, description="classes to report; None = every class")
        max_range: float = Field(
            5.0, gt=0.0, le=1000, description="depth pixels farther than this are ignored (m)"
        )
        min_pixels: int = Field(
            60,
            ge=1,
            le=1_000_000,
            description="fewest valid depth pixels under a mask at 640×480 (scaled with image area)",
        )
        depth_gap: float = Field(
            0.3,
            ge=0.0,
            le=1000,
            description="split the mask's depths at gaps larger than this (m); 0 = keep all",
        )
        surface_step: float = Field(
            0.05,
            ge=0.0,
            le=1000,
            description="keep the mask's largest connected surface: neighbouring pixels are on one "
            "surface when their depths differ by less than surface_step + surface_slope·depth (m); "
            "0 = keep every surface",
        )
        surface_slope: float = Field(
            0.03,
            ge=0.0,
            le=10,
            description="depth step between neighbouring pixels allowed per metre of depth (a slanted face "
            "and the camera's depth noise grow with depth)",
        )
        min_relief: float = Field(
            0.1,
            ge=0.0,
            le=1.0,
            description="drop a detection whose surface stands out of its surroundings on less than this"
            " share of its outline (a picture on a wall, a door in it: flush all round; a piece of"
            " furniture has the room behind it on a side: docs/detector.md); 0 = keep all",
        )
        flush_classes: list[str] = Field(
            default_factory=list,
            description="classes that may lie flush with a wall, not held to min_relief (a model's tv,"
            " picture or window)",
        )
        centroid_height: Literal["mask", "box"] = Field(
            "box",
            description="height of the centroid: the median of the mask's points, or the middle of the"
            " box at their median depth (masks miss thin parts such as chair legs, boxes do not)",
        )
        duplicate_overlap: float = Field(
            0.5,
            gt=0.0,
            le=1.0,
            description="a detection whose depth pixels lie more than this share in stronger detections of"
            " its class is a part or a merge of them and is dropped (mask NMS); 1 = off",
        )
        max_points: int = Field(
            400, ge=0, le=1_000_000, description="points_cam is subsampled to at most this many"
        )
        threads: int = Field(1, ge=1, le=16, description="onnxruntime intra-op threads")

        @field_validator("model")
        @classmethod
        def _model_file(cls, value: str | None, info: ValidationInfo) -> str | None:
            # The mission directory comes with the validation context; without it a relative
            # path cannot be located yet and is checked at configure time instead.
            mission_dir = (info.context or {}).get("mission_dir")
            path = resolve_model(value, mission_dir)
            if value is None or path.is_absolute():
                try:
                    inspect_model(path)
                except ModelError as exc:
                    raise ValueError(f"{exc}: {path}") from None
            return value

        @model_validator(mode="after")
        def _names_match(self, info: ValidationInfo) -> OnnxDetector.Params:
            if self.class_names is None:
                return self
            path = resolve_model(self.model, (info.context or {}).get("mission_dir"))
            if path.is_absolute() and path.is_file():
                n = inspect_model(path).num_classes
                if len(self.class_names) != n:
                    raise ValueError(f"class_names lists {len(self.class_names)} classes, the model has {n}")
            return self

    def __init__(self) -> None:
        self.params: OnnxDetector.Params | None = None
        self.rate_hz = 2.0
        self._model: SegmentationModel | None = None

    def configure(self, params: BackendParams, context: RunContext) -> None:
        assert isinstance(params, OnnxDetector.Params), type(params)
        self.params = params
        self.rate_hz = params.rate_hz
        self.rng = context.rng
        path = resolve_model(params.model, context.mission_dir)
        try:
            self._model = SegmentationModel(path, threads=params.threads)
        except ModelError as exc:
            raise AmslamError(f"detector.model: {exc}: {path}") from None
        names = tuple(params.class_names) if params.class_names else self._model.info.names
        if not names:
            names = tuple(f"class{i}" for i in range(self._model.info.num_classes))
        n = self._model.info.num_classes
        if len(names) != n:
            raise AmslamError(f"detector.class_names: {len(names)} names for a model with {n} classes")
        self.names = names
        if unknown := sorted(set(params.flush_classes) - set(names)):
            raise AmslamError(
                f"detector.flush_classes: {unknown} not among the model's classes {list(names)}"
            )
        context.emit(
            "onnx_detector_model", path=str(path), input=list(self._model.info.input_hw), names=list(names)
        )

    @property
    def model(self) -> SegmentationModel:
        """The loaded model (after configure)."""
        if self._model is None:
            raise RuntimeError("OnnxDetector used before configure()")
        return self._model

    def detect(self, frame: Frame) -> list[Detection]:
        """Objects segmented in the frame's RGB image, lifted to the camera frame with its depth."""
        p = self.params
        if p is None:
            raise RuntimeError("OnnxDetector.detect() called before configure()")
        if frame.rgb is None:
            raise ValueError("the onnx detector needs RGB frames (the platform renders no image)")
        if frame.rgb.shape[:2] != frame.depth.shape:
            raise ValueError(
                f"RGB {frame.rgb.shape[:2]} and depth {frame.depth.shape} images must be registered"
            )
        instances = self.model(
            frame.rgb, conf=p.confidence, iou=p.iou, max_det=p.max_detections, mask_threshold=p.mask_threshold
        )
        wanted = None if p.classes is None else set(p.classes)
        H, W = frame.depth.shape
        claimed: dict[int, np.ndarray] = {}  # per class: pixels of the stronger detections kept so far
        out: list[Detection] = []
        for inst in instances:  # best first
            if wanted is not None and self.names[inst.class_id] not in wanted:
                continue
            lifted = self._lift(inst, frame.depth, frame.K)
            if lifted is None:
                continue
            det, (v, u) = lifted
            if p.duplicate_overlap < 1.0:
                # Mask NMS: box NMS keeps a box on a chair's back next to one on the whole chair, or
                # one spanning two chairs next to theirs (their IoU is small); in 3-D these repeat an
                # object already reported. Each one becomes a second tentative landmark within a few
                # decimetres of the first, and the SLAM front end then finds every later detection of
                # that chair ambiguous between the two and starts yet another (issue #8).
                taken = claimed.setdefault(inst.class_id, np.zeros((H, W), dtype=bool))
                if np.count_nonzero(taken[v, u]) > p.duplicate_overlap * len(v):
                    continue
                taken[v, u] = True
            out.append(det)
        return out

    def lift(self, inst: Instance, depth: np.ndarray, K: np.ndarray) -> Detection | None:
        """The 3-D step of one instance: its mask's depth → centroid and points (None if too few)."""
        lifted = self._lift(inst, depth, K)
        return None if lifted is None else lifted[0]

    def _lift(
        self, inst: Instance, depth: np.ndarray, K: np.ndarray
    ) -> tuple[Detection, tuple[np.ndarray, np.ndarray]] | None:
        """:meth:`lift`, plus the image rows and columns of the pixels the detection claims.

        The claimed pixels are the mask's depth cluster before its largest surface is chosen: the
        mask NMS compares what the network segmented. Were it to compare the surfaces, a second
        detection of one table (its front half beside the whole table) would keep a surface the
        first did not and survive, and the map would hold two tables seen at once.
        """
        p = self.params
        assert p is not None
        H, W = depth.shape
        min_px = max(1, int(round(p.min_pixels * (H * W) / (640 * 480))))
        # work inside the box (the mask is empty outside it) and a margin around it, where the
        # outline the relief test reads lies; the window's intrinsics are K with the principal
        # point shifted by the window's corner
        width = max(1, round(2 * W / 320))  # the relief outline: 2 px at 320×240, scaled with the image
        margin = width + 2
        u0, v0 = max(0, int(np.floor(inst.box[0])) - margin), max(0, int(np.floor(inst.box[1])) - margin)
        u1, v1 = min(W, int(np.ceil(inst.box[2])) + margin), min(H, int(np.ceil(inst.box[3])) + margin)
        win = (slice(v0, v1), slice(u0, u1))
        d = depth[win]
        mask = inst.mask[win] & (d > 0) & (d <= p.max_range)
        if p.depth_gap > 0:
            mask = largest_depth_cluster(mask, d, p.depth_gap)
        claimed = np.nonzero(mask)
        if p.surface_step > 0:
            mask = largest_surface(mask, d, p.surface_step, p.surface_slope)
        if np.count_nonzero(mask) < min_px:
            return None
        if p.min_relief > 0 and self.names[inst.class_id] not in p.flush_classes:
            share = relief(mask, d, p.surface_step, p.surface_slope, width)
            if share is not None and share < p.min_relief:
                return None
        Kw = np.array(K, dtype=float)
        Kw[0, 2] -= u0
        Kw[1, 2] -= v0
        pts = backproject(mask, d, np.linalg.inv(Kw))
        centroid = np.median(pts, axis=0)
        if p.centroid_height == "box" and inst.box[1] > 0.5 and inst.box[3] < H - 0.5:
            # The camera's y axis points down the image: the box's middle row (box edges are pixel
            # edges, K counts pixel centres: − ½) at the points' median depth.
            fy, cy = float(K[1, 1]), float(K[1, 2])
            centroid[1] = (0.5 * (inst.box[1] + inst.box[3]) - 0.5 - cy) / fy * centroid[2]
        det = Detection(self.names[inst.class_id], float(inst.score), centroid, self._subsample(pts))
        return det, (claimed[0] + v0, claimed[1] + u0)

    def _subsample(self, pts: np.ndarray) -> np.ndarray:
        assert self.params is not None
        m = self.params.max_points
        if len(pts) <= m:
            return pts
        idx = self.rng.choice(len(pts), size=m, replace=False)
        return pts[np.sort(idx)]

    def close(self) -> None:
        self._model = None


def largest_depth_cluster(mask: np.ndarray, depth: np.ndarray, gap: float) -> np.ndarray:
    """The pixels of ``mask`` in its largest depth cluster (nearest on ties).

    Depths are sorted and cut wherever two consecutive values differ by more than ``gap``: a
    surface seen at a slant spans depths continuously, the wall behind a chair does not join it.
    """
    v, u = np.nonzero(mask)
    if len(v) == 0:
        return mask
    z = depth[v, u]
    zs = np.sort(z)  # only the cluster's depth range is needed, not the order of the pixels
    cuts = np.flatnonzero(np.diff(zs) > gap) + 1
    if len(cuts) == 0:
        return mask
    bounds = np.concatenate([[0], cuts, [len(zs)]])
    sizes = np.diff(bounds)
    k = int(np.argmax(sizes))  # argmax takes the first (nearest) of equal sizes
    lo, hi = zs[bounds[k]], zs[bounds[k + 1] - 1]
    out = np.zeros_like(mask)
    keep = (z >= lo) & (z <= hi)
    out[v[keep], u[keep]] = True
    return out


def largest_surface(mask: np.ndarray, depth: np.ndarray, step: float, slope: float) -> np.ndarray:
    """The pixels of ``mask`` on its largest connected surface.

    Two pixels of the mask that touch (8-neighbours) are on one surface when their depths differ by
    less than ``step + slope·z`` (z the nearer one's depth). A depth gap alone does not split a mask
    that spans two chairs of a row, or a table's mask over the floor between its legs: the second
    surface sits at the same depths, but no chain of touching pixels with small steps joins them.
    OpenCV's and scipy.ndimage's component labelling take a binary image and cannot weigh the
    depth step between neighbours, so the neighbour graph is built here and scipy's graph
    routine labels it.
    """
    # scipy here, not at the top: reading commands (`amslam dump-config detector onnx`) load this
    # module and must not import the heavy libraries (tests/e2e/test_cli_imports.py)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    v, u = np.nonzero(mask)
    n = len(v)
    if n == 0:
        return mask
    H, W = mask.shape
    index = np.full((H, W), -1, dtype=np.int64)
    index[v, u] = np.arange(n)
    z = depth.astype(np.float64)
    rows, cols = [], []
    for dv, du in ((0, 1), (1, 0), (1, 1), (1, -1)):  # each neighbour pair once
        a = (slice(0, H - dv), slice(max(0, -du), W - max(0, du)))
        b = (slice(dv, H), slice(max(0, du), W - max(0, -du)))
        za, zb = z[a], z[b]
        joined = mask[a] & mask[b] & (np.abs(za - zb) < step + slope * np.minimum(za, zb))
        rows.append(index[a][joined])
        cols.append(index[b][joined])
    i, j = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    largest = label == np.argmax(np.bincount(label))
    out = np.zeros_like(mask)
    out[v[largest], u[largest]] = True
    return out


#: Fewest outline pixels with a depth behind or level with the surface for :func:`relief` to judge.
MIN_OUTLINE = 8


def relief(surface: np.ndarray, depth: np.ndarray, step: float, slope: float, width: int) -> float | None:
    """The share of ``surface``'s outline behind which the scene lies farther than the surface.

    The outline is the pixels within ``width`` of the surface, outside it. Each is compared with
    the surface's mean depth around it (within ``width`` + 1): farther by more than
    ``step + slope·z`` (the step that splits surfaces, :func:`largest_surface`), it lies
    *behind*, as it does in a patch without depth (nothing within the camera's range); within
    that step it is *level* (the surface goes on: a wall around a picture, the floor under a
    leg); nearer, it hides the outline (an occluder); a lone pixel without a depth (a dropped
    return) says nothing. Neither of the last two is counted.
    Furniture stands in the room: some of its outline has the room behind it. A picture
    on a wall, a door or a window in it, is level all round. None when fewer than
    :data:`MIN_OUTLINE` pixels are behind or level (an outline hidden or off the image).
    """
    import cv2  # here, not at the top: reading commands load this module (see largest_surface)

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * width + 1, 2 * width + 1))
    outline = cv2.dilate(surface.astype(np.uint8), kernel).astype(bool) & ~surface

    # the surface's mean depth around each pixel: sums of depth and of pixels over a box
    def box_sum(image: np.ndarray) -> np.ndarray:
        size = (2 * width + 3, 2 * width + 3)
        return cv2.boxFilter(image, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)

    z_sum = box_sum(np.where(surface, depth, 0).astype(np.float32))
    n_sum = box_sum(surface.astype(np.float32))
    v, u = np.nonzero(outline & (n_sum > 0))
    near = z_sum[v, u] / n_sum[v, u]
    z = depth[v, u]
    tolerance = step + slope * near
    seen = z > 0
    # No depth over a patch: nothing within the camera's range, the room goes on behind. A lone
    # pixel without one is a dropped return (random, or at grazing incidence) and says nothing.
    far = cv2.erode((depth <= 0).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)[v, u]
    behind = far | (seen & (z - near > tolerance))
    level = seen & (np.abs(z - near) <= tolerance)
    judged = int(np.count_nonzero(behind) + np.count_nonzero(level))
    if judged < MIN_OUTLINE:
        return None
    return float(np.count_nonzero(behind)) / judged
