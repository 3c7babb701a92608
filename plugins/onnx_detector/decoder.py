"""Running and decoding instance-segmentation models in the YOLOv8-seg ONNX layout.

The layout (what ultralytics exports for ``yolov8*-seg`` and what ``train.py`` exports)::

    input   images   [1, 3, S_h, S_w]       float RGB in 0..1, letterboxed (grey 114 borders)
    output0          [1, 4 + nc + nm, N]    per candidate: cx, cy, w, h (input pixels),
                                            nc class scores (after the sigmoid), nm mask coefficients
    output1          [1, nm, S_h/4, S_w/4]  mask prototypes (nm = 32)

Decoding follows ultralytics' ``ops.non_max_suppression`` + ``ops.process_mask``: best class
and its score per candidate, confidence threshold, class-wise NMS (OpenCV's
``cv2.dnn.NMSBoxesBatched``, the per-class form of ``NMSBoxes``), at most ``max_det`` survivors;
a survivor's mask is ``sigmoid(coefficients @ prototypes)``, upsampled bilinearly, cropped to its
box and thresholded. Here the upsampling, the removal of the letterbox borders and the resize to
the original image are one bilinear warp straight from the prototype grid to the original pixels
(the composition of ultralytics' two bilinear resizes, up to interpolation rounding), evaluated
only inside the box.

Nothing here depends on torch: onnxruntime, OpenCV and numpy only.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

#: Letterbox border value (ultralytics' ``LetterBox`` default).
PAD_VALUE = 114


class ModelError(ValueError):
    """A model file that is missing, unreadable or not in the YOLOv8-seg layout."""


@dataclass(frozen=True)
class ModelInfo:
    """What the decoder needs to know about a model file.

    Attributes:
        input_name: name of the image input.
        input_hw: (height, width) of the network input.
        num_classes: nc.
        num_masks: nm, the number of prototypes.
        names: class names by class index (from the ``names`` metadata), may be empty.
    """

    input_name: str
    input_hw: tuple[int, int]
    num_classes: int
    num_masks: int
    names: tuple[str, ...]


@dataclass(frozen=True)
class Letterbox:
    """How an image was fitted into the network input: scale, then centred borders.

    Attributes:
        src_hw: original image (height, width).
        new_hw: scaled image (height, width) inside the input.
        pad: (left, top) border in input pixels.
        input_hw: network input (height, width).
    """

    src_hw: tuple[int, int]
    new_hw: tuple[int, int]
    pad: tuple[int, int]
    input_hw: tuple[int, int]

    @property
    def scale(self) -> tuple[float, float]:
        """(sx, sy): input pixels per original pixel."""
        return self.new_hw[1] / self.src_hw[1], self.new_hw[0] / self.src_hw[0]


@dataclass(frozen=True)
class Instance:
    """One decoded instance, in original image pixels.

    Attributes:
        class_id: model class index.
        score: class score in [0, 1].
        box: (x1, y1, x2, y2), clipped to the image.
        mask: H×W boolean mask (False outside the box).
    """

    class_id: int
    score: float
    box: np.ndarray
    mask: np.ndarray


def parse_names(text: str) -> tuple[str, ...]:
    """Class names from ultralytics' ``names`` metadata: ``"{0: 'chair', 1: 'table'}"`` (or a list)."""
    value = ast.literal_eval(text)
    if isinstance(value, dict):
        keys = sorted(int(k) for k in value)
        if keys != list(range(len(keys))):
            raise ValueError(f"class ids are not 0..{len(keys) - 1}: {keys}")
        return tuple(str(value[k] if k in value else value[str(k)]) for k in keys)
    if isinstance(value, list | tuple):
        return tuple(str(v) for v in value)
    raise ValueError(f"expected a dict or list of class names, got {type(value).__name__}")


def make_session(path: Path, threads: int = 1):
    """An onnxruntime CPU session with few threads (the detector shares the CPU with the flight)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.log_severity_level = 3
    return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])


def inspect_session(session) -> ModelInfo:
    """Check a session against the YOLOv8-seg layout; raise :class:`ModelError` saying what differs."""
    inputs, outputs = session.get_inputs(), session.get_outputs()
    if len(inputs) != 1:
        raise ModelError(f"expected 1 input (images), the model has {len(inputs)}")
    if len(outputs) < 2:
        raise ModelError(
            f"expected 2 outputs (detections [1, 4+nc+nm, N], prototypes [1, nm, H/4, W/4]), "
            f"the model has {len(outputs)}: is it a detection model rather than a -seg one?"
        )
    meta = session.get_modelmeta().custom_metadata_map
    ishape = inputs[0].shape
    if len(ishape) != 4 or (isinstance(ishape[1], int) and ishape[1] != 3):
        raise ModelError(f"expected input [1, 3, H, W], got {ishape}")
    hw = ishape[2:]
    if not all(isinstance(d, int) and d > 0 for d in hw):
        # dynamic input: ultralytics writes the training size as metadata
        try:
            imgsz = ast.literal_eval(meta.get("imgsz", "[640, 640]"))
        except (ValueError, SyntaxError) as exc:
            raise ModelError(f"unreadable imgsz metadata {meta.get('imgsz')!r}") from exc
        hw = [int(imgsz), int(imgsz)] if isinstance(imgsz, int) else [int(v) for v in imgsz]
    s0, s1 = outputs[0].shape, outputs[1].shape
    if len(s0) != 3 or len(s1) != 4:
        raise ModelError(f"expected outputs of rank 3 and 4, got {s0} and {s1}")
    nm = s1[1]
    if not isinstance(nm, int) or not isinstance(s0[1], int):
        raise ModelError(f"output channel counts must be fixed, got {s0} and {s1}")
    nc = s0[1] - 4 - nm
    if nc < 1:
        raise ModelError(f"output0 has {s0[1]} channels: fewer than 4 box + 1 class + {nm} mask coefficients")
    names: tuple[str, ...] = ()
    if "names" in meta:
        try:
            names = parse_names(meta["names"])
        except (ValueError, SyntaxError) as exc:
            raise ModelError(f"unreadable 'names' metadata {meta['names']!r}: {exc}") from exc
        if len(names) != nc:
            raise ModelError(f"'names' metadata lists {len(names)} classes, output0 has {nc}")
    return ModelInfo(inputs[0].name, (int(hw[0]), int(hw[1])), int(nc), int(nm), names)


@lru_cache(maxsize=8)
def _inspect_file(path: str, mtime_ns: int, size: int) -> ModelInfo:
    try:
        session = make_session(Path(path))
    except Exception as exc:  # onnxruntime raises its own exception types
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ModelError(f"not a readable ONNX model ({first})") from exc
    return inspect_session(session)


def inspect_model(path: Path) -> ModelInfo:
    """Open a model file once (cached by path and modification time) and check its layout."""
    path = Path(path)
    if not path.is_file():
        raise ModelError("model file not found")
    st = path.stat()
    return _inspect_file(str(path.resolve()), st.st_mtime_ns, st.st_size)


def letterbox(image: np.ndarray, input_hw: tuple[int, int]) -> tuple[np.ndarray, Letterbox]:
    """Scale an H×W×3 uint8 RGB image into the input, centred on grey borders.

    Returns the network blob [1, 3, S_h, S_w] (float32 RGB in 0..1) and the transform. The
    scaled size and borders round as ultralytics' ``LetterBox`` does (``round(dw ∓ 0.1)``).
    Shrinking uses area interpolation (no aliasing), enlarging bilinear.
    """
    import cv2

    H, W = image.shape[:2]
    ih, iw = input_hw
    r = min(ih / H, iw / W)
    nh, nw = int(round(H * r)), int(round(W * r))
    dw, dh = (iw - nw) / 2.0, (ih - nh) / 2.0
    top, left = int(round(dh - 0.1)), int(round(dw - 0.1))
    canvas = np.full((ih, iw, 3), PAD_VALUE, dtype=np.uint8)
    if (nh, nw) != (H, W):
        interp = cv2.INTER_AREA if r < 1.0 else cv2.INTER_LINEAR
        image = cv2.resize(image, (nw, nh), interpolation=interp)
    canvas[top : top + nh, left : left + nw] = image
    blob = canvas.transpose(2, 0, 1)[None].astype(np.float32) * np.float32(1.0 / 255.0)
    return blob, Letterbox((H, W), (nh, nw), (left, top), (ih, iw))


def decode(
    output0: np.ndarray,
    output1: np.ndarray,
    lb: Letterbox,
    *,
    conf: float = 0.25,
    iou: float = 0.7,
    max_det: int = 100,
    mask_threshold: float = 0.5,
) -> list[Instance]:
    """Instances from the two raw outputs of one image, in original image pixels, best first.

    Args:
        output0: [1, 4 + nc + nm, N] candidates.
        output1: [1, nm, mh, mw] prototypes.
        lb: the letterbox of the image.
        conf: minimum class score.
        iou: NMS overlap above which the weaker of two same-class boxes is dropped.
        max_det: most instances kept.
        mask_threshold: a pixel belongs to the instance when the mask's sigmoid exceeds this.
    """
    import cv2

    protos = output1[0]
    nm, mh, mw = protos.shape
    pred = output0[0]
    nc = pred.shape[0] - 4 - nm
    scores_all = pred[4 : 4 + nc]
    cls = scores_all.argmax(0)
    score = scores_all[cls, np.arange(pred.shape[1])]
    keep = np.flatnonzero(score > conf)
    if len(keep) == 0:
        return []
    cx, cy, w, h = pred[0, keep], pred[1, keep], pred[2, keep], pred[3, keep]
    xywh = np.stack([cx - w / 2, cy - h / 2, w, h], 1).astype(np.float64)
    sel = cv2.dnn.NMSBoxesBatched(
        xywh.tolist(), score[keep].astype(float).tolist(), cls[keep].astype(int).tolist(), conf, iou
    )
    sel = np.asarray(sel, dtype=np.int64).reshape(-1)
    if len(sel) == 0:
        return []
    sel = sel[np.argsort(-score[keep][sel], kind="stable")][:max_det]
    idx = keep[sel]
    coeffs = pred[4 + nc :, idx].T.astype(np.float32)  # (k, nm)

    H, W = lb.src_hw
    sx, sy = lb.scale
    left, top = lb.pad
    step = (lb.input_hw[1] / mw, lb.input_hw[0] / mh)  # prototype cell size in input pixels (x, y)
    out: list[Instance] = []
    for j, k in enumerate(idx.tolist()):
        x1, y1, bw, bh = xywh[sel[j]]
        box = np.array([(x1 - left) / sx, (y1 - top) / sy, (x1 + bw - left) / sx, (y1 + bh - top) / sy])
        box = np.clip(box, 0.0, [W, H, W, H])
        mask = _instance_mask(coeffs[j], protos, box, lb, step, mask_threshold)
        out.append(Instance(int(cls[k]), float(score[k]), box, mask))
    return out


def _instance_mask(
    coeffs: np.ndarray,
    protos: np.ndarray,
    box: np.ndarray,
    lb: Letterbox,
    proto_step: tuple[float, float],
    threshold: float,
) -> np.ndarray:
    """Boolean H×W mask: ``sigmoid(coeffs @ protos)`` warped to the original pixels inside ``box``.

    Original pixel u (centre u + ½) sits at input x = (u + ½)·sx + left, i.e. at prototype index
    x / step − ½ (cell i covers [i·step, (i+1)·step) with centre i + ½): one affine map per
    axis, which ``cv2.warpAffine`` samples bilinearly. Pixels u with x1 ≤ u < x2 are in the box
    (ultralytics' ``crop_mask`` convention).
    """
    import cv2

    H, W = lb.src_hw
    nm, mh, mw = protos.shape
    m = coeffs @ protos.reshape(nm, -1)
    prob = (1.0 / (1.0 + np.exp(-m))).reshape(mh, mw).astype(np.float32)
    u0, v0 = int(np.ceil(box[0])), int(np.ceil(box[1]))
    u1, v1 = int(np.ceil(box[2])), int(np.ceil(box[3]))
    u1, v1 = min(u1, W), min(v1, H)
    full = np.zeros((H, W), dtype=bool)
    if u1 <= u0 or v1 <= v0:
        return full
    sx, sy = lb.scale
    left, top = lb.pad
    ax, ay = sx / proto_step[0], sy / proto_step[1]
    bx = (0.5 * sx + left) / proto_step[0] - 0.5
    by = (0.5 * sy + top) / proto_step[1] - 0.5
    # dst (u, v) inside the box window → src (ax (u0 + u) + bx, ay (v0 + v) + by)
    M = np.array([[ax, 0.0, ax * u0 + bx], [0.0, ay, ay * v0 + by]], dtype=np.float64)
    win = cv2.warpAffine(
        prob,
        M,
        (u1 - u0, v1 - v0),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REPLICATE,
    )
    full[v0:v1, u0:u1] = win > threshold
    return full


class SegmentationModel:
    """A YOLOv8-seg ONNX model ready to run on RGB images."""

    def __init__(self, path: Path, threads: int = 1):
        self.path = Path(path)
        self.info = inspect_model(self.path)
        self.session = make_session(self.path, threads)

    def __call__(
        self,
        rgb: np.ndarray,
        *,
        conf: float = 0.25,
        iou: float = 0.7,
        max_det: int = 100,
        mask_threshold: float = 0.5,
    ) -> list[Instance]:
        """Instances in an H×W×3 uint8 RGB image, best first."""
        blob, lb = letterbox(rgb, self.info.input_hw)
        out0, out1 = self.session.run(None, {self.info.input_name: blob})[:2]
        return decode(out0, out1, lb, conf=conf, iou=iou, max_det=max_det, mask_threshold=mask_threshold)
