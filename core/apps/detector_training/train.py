"""Train the shipped detector: a tiny YOLOv8-seg-like network on the simulator's images.

The network follows YOLOv8-seg's structure at a fraction of its width: a strided convolutional
backbone with residual blocks, a top-down feature pyramid, anchor-free heads at strides 8, 16
and 32 (box distances to the four sides, class logits, 32 mask coefficients per cell) and a
prototype head at stride 4. Its ONNX export has exactly the layout of an ultralytics
YOLOv8-seg export, so the plugin's decoder runs either:

* input ``images`` [1, 3, S, S], float RGB in 0..1, letterboxed (grey 114 padding);
* ``output0`` [1, 4 + nc + 32, N]: cx, cy, w, h in input pixels, class scores after the sigmoid,
  mask coefficients;
* ``output1`` [1, 32, S/4, S/4]: mask prototypes;
* metadata ``names`` ("{0: 'chair', ...}"), ``imgsz``, ``stride``, ``task`` as ultralytics writes.

Training (simplified from YOLOv8 to fit a CPU budget): each ground-truth instance is assigned
the cells of its size's pyramid levels whose centres lie inside its box and within 2.5 strides
of its centre (FCOS/YOLOX-style centre sampling; YOLOv8's task-aligned assigner needs a trained
network to rank cells). Losses: binary cross-entropy for the classes (summed over all cells,
normalised by the positives, as YOLOv8 does) against IoU-aware targets (a positive cell's
target is the IoU of its box with the object's, like YOLOv8's task-aligned scores), generalised
IoU for the boxes, and YOLOv8's mask loss: per-pixel cross-entropy of ``sigmoid(coeffs @ protos)``
against the instance mask at prototype resolution, inside the box, normalised by the box area.

Re-train (about 20 minutes on one core, plus 2.5 minutes to render the frames; torch is needed
for training only)::

    pip install 'amslam[train]'        # torch 2.13.0 and onnx
    python -m amslam.apps.detector_training.train --no-randomise \
        --out plugins/onnx_detector/models/sim_yolov8seg.onnx

(the shipped model's data; without ``--no-randomise`` the buildings and their look are
randomised, and ``--mesh-worlds`` adds imported worlds: see ``dataset.py`` and docs/detector.md)

then measure it on held-out buildings with ``python -m amslam.apps.detector_training.evaluate``.
"""

from __future__ import annotations

import argparse
import ast
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from amslam.apps.detector_training.dataset import (
    CLASSES,
    HELDOUT_SEEDS,
    Dataset,
    labelled_masks,
    mask_box,
    render_dataset,
)
from amslam.cli import positive_int, whole_number
from amslam.errors import AmslamError
from amslam.interfaces import missing_modules
from amslam.plugins.onnx_detector.decoder import PAD_VALUE

#: Strides of the detection levels (YOLOv8's P3–P5) and the prototype stride.
STRIDES: tuple[int, ...] = (8, 16, 32)
#: With the extra stride-4 level (YOLOv8's "-p2" variant) for small, far objects.
P2_STRIDES: tuple[int, ...] = (4, 8, 16, 32)
PROTO_STRIDE = 4
#: Box size ranges (longest side, input pixels at 320) that each level learns, overlapping.
LEVEL_SIZES: tuple[tuple[float, float], ...] = ((0.0, 80.0), (40.0, 160.0), (100.0, 1e9))
#: The same with the stride-4 level, which takes the boxes under 40 px (a chair beyond ~4 m).
P2_LEVEL_SIZES: tuple[tuple[float, float], ...] = ((0.0, 40.0), (16.0, 80.0), (40.0, 160.0), (100.0, 1e9))


def level_sizes(strides: tuple[int, ...]) -> dict[int, tuple[float, float]]:
    """Box size range of each detection level, by stride, for the levels ``strides``."""
    if tuple(strides) == STRIDES:
        return dict(zip(STRIDES, LEVEL_SIZES, strict=True))
    if tuple(strides) == P2_STRIDES:
        return dict(zip(P2_STRIDES, P2_LEVEL_SIZES, strict=True))
    raise ValueError(f"detection levels must be {STRIDES} or {P2_STRIDES}, got {strides}")


NUM_MASKS = 32

#: The shipped model's training buildings (``--seeds N`` takes the first N of seeds 100, 101, …; never
#: the held-out ``HELDOUT_SEEDS`` 900–903, nor the demo's 7).
TRAIN_SEEDS = tuple(range(100, 136))


def _torch():
    """torch, imported lazily: only training needs it."""
    try:
        import torch
    except ImportError as exc:  # pragma: no cover — depends on the environment
        raise ImportError("training the detector needs PyTorch: pip install 'amslam[train]'") from exc
    return torch


def _blocks(torch: Any) -> tuple[type, type, type]:
    """YOLOv8's building blocks as ``torch.nn.Module`` classes: ``Conv``, ``Res`` and ``Head``."""
    nn = torch.nn

    class Conv(nn.Module):
        """Convolution, batch norm, SiLU: YOLOv8's basic block."""

        def __init__(self, c1: int, c2: int, k: int = 3, s: int = 1):
            super().__init__()
            self.conv = nn.Conv2d(c1, c2, k, s, k // 2, bias=False)
            self.bn = nn.BatchNorm2d(c2)
            self.act = nn.SiLU()

        def forward(self, x):
            return self.act(self.bn(self.conv(x)))

    class Res(nn.Module):
        """Two 3×3 convolutions with a shortcut (the bottleneck of YOLOv8's C2f)."""

        def __init__(self, c: int):
            super().__init__()
            self.a = Conv(c, c)
            self.b = Conv(c, c)

        def forward(self, x):
            return x + self.b(self.a(x))

    class Head(nn.Module):
        """Head of one level: a shared 3×3 convolution, then box distances, class logits and mask
        coefficients by 1×1 convolutions (YOLOv8 has one branch per output; one is enough here)."""

        def __init__(self, c: int, nc: int, stride: int):
            super().__init__()
            self.stem = Conv(c, c)
            self.box = nn.Conv2d(c, 4, 1)
            self.cls = nn.Conv2d(c, nc, 1)
            self.coef = nn.Conv2d(c, NUM_MASKS, 1)
            # YOLOv8's class-bias prior: few objects per cell at the start of training
            nn.init.constant_(self.cls.bias, math.log(5 / nc / (320 / stride) ** 2))

        def forward(self, x):
            x = self.stem(x)
            return self.box(x), self.cls(x), self.coef(x)

    return Conv, Res, Head


def build_model(
    nc: int, width: tuple[int, ...] = (16, 24, 32, 48, 64), strides: tuple[int, ...] = STRIDES
) -> Any:
    """The tiny YOLOv8-seg-like network (a ``torch.nn.Module``) for ``nc`` classes.

    With ``strides=P2_STRIDES`` the feature pyramid goes one step further down, to the stride-4
    features, and a fourth head detects there (as YOLOv8's ``-p2`` models do).
    """
    level_sizes(strides)  # ValueError for levels the assigner has no box sizes for
    p2 = strides[0] == 4
    torch = _torch()
    nn = torch.nn
    F = torch.nn.functional
    Conv, Res, Head = _blocks(torch)

    class TinyYoloSeg(nn.Module):
        def __init__(self, nc: int):
            super().__init__()
            c0, c1, c2, c3, c4 = width
            self.nc = nc
            self.s1 = Conv(3, c0, 3, 2)
            self.s2 = Conv(c0, c1, 3, 2)
            self.s3 = nn.Sequential(Conv(c1, c2, 3, 2), Res(c2))
            self.s4 = nn.Sequential(Conv(c2, c3, 3, 2), Res(c3))
            self.s5 = nn.Sequential(Conv(c3, c4, 3, 2), Res(c4))
            self.top4 = nn.Sequential(Conv(c4 + c3, c3, 1), Res(c3))
            self.top3 = nn.Sequential(Conv(c3 + c2, c2, 1), Res(c2))
            chans = ((c1,) if p2 else ()) + (c2, c3, c4)
            self.heads = nn.ModuleList([Head(c, nc, s) for c, s in zip(chans, strides, strict=True)])
            self.top2 = nn.Sequential(Conv(c2 + c1, c1, 1), Res(c1)) if p2 else None
            # prototypes as in YOLOv8 (convolution, ×2 upsampling, convolution, 1×1 to 32 maps),
            # with the stride-4 features added back for sharper mask edges
            cp = c1
            self.proto_in = Conv(c2, cp, 3)
            self.proto_skip = Conv(c1, cp, 1)
            self.proto_out = nn.Sequential(Conv(cp, cp, 3), nn.Conv2d(cp, NUM_MASKS, 1))

        def forward(self, x):
            p2 = self.s2(self.s1(x))
            p3 = self.s3(p2)
            p4 = self.s4(p3)
            p5 = self.s5(p4)
            n4 = self.top4(torch.cat([F.interpolate(p5, scale_factor=2.0, mode="nearest"), p4], 1))
            n3 = self.top3(torch.cat([F.interpolate(n4, scale_factor=2.0, mode="nearest"), p3], 1))
            feats = [n3, n4, p5]
            if self.top2 is not None:
                feats.insert(
                    0, self.top2(torch.cat([F.interpolate(n3, scale_factor=2.0, mode="nearest"), p2], 1))
                )
            levels = [h(f) for h, f in zip(self.heads, feats, strict=True)]
            up = F.interpolate(self.proto_in(n3), scale_factor=2.0, mode="nearest")
            protos = self.proto_out(up + self.proto_skip(p2))
            return levels, protos

    return TinyYoloSeg(nc)


def anchors(size: int, levels: tuple[int, ...] = STRIDES) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres (N×2, input pixels) and strides (N,) of all levels, level by level, row-major."""
    pts, strides = [], []
    for s in levels:
        n = size // s
        ys, xs = np.mgrid[0:n, 0:n]
        pts.append(np.stack([(xs.ravel() + 0.5) * s, (ys.ravel() + 0.5) * s], 1))
        strides.append(np.full(n * n, s, dtype=np.float32))
    return np.concatenate(pts).astype(np.float32), np.concatenate(strides)


def flatten_levels(levels):
    """Per-level (box, cls, coef) maps → (B, 4, N), (B, nc, N), (B, 32, N)."""
    torch = _torch()
    return tuple(torch.cat([lv[i].flatten(2) for lv in levels], 2) for i in range(3))


def decode_boxes(box_raw, anchor_xy, stride):
    """Distances to the four sides (softplus · stride) → xyxy in input pixels, shape (B, 4, N)."""
    torch = _torch()
    d = torch.nn.functional.softplus(box_raw) * stride
    x, y = anchor_xy[:, 0], anchor_xy[:, 1]
    return torch.stack([x - d[:, 0], y - d[:, 1], x + d[:, 2], y + d[:, 3]], 1)


# -------------------------------------------------------------------------------------------
# data
# -------------------------------------------------------------------------------------------
def make_batch(
    data: Dataset, idx: np.ndarray, size: int, rng: np.random.Generator | None
) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
    """Letterboxed images (B, 3, S, S) in 0..1 and per-image targets.

    With ``rng`` the images are augmented: random vertical placement inside the letterbox (in
    steps of the prototype stride, so masks stay aligned), horizontal flips and a brightness and
    colour-balance jitter. Without it the placement is the centred letterbox of inference.
    """
    B = len(idx)
    H, W = data.images.shape[1:3]
    r = min(size / H, size / W)
    nh, nw = round(H * r), round(W * r)
    # the border of inference's letterbox (decoder.letterbox): the network learns the same grey
    imgs = np.full((B, size, size, 3), PAD_VALUE, dtype=np.float32)
    targets = []
    proto_size = size // PROTO_STRIDE
    for b, i in enumerate(idx):
        img = data.images[i]
        inst = data.instance[i]
        if (nh, nw) != (H, W):
            img = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_AREA)
            inst = cv2.resize(inst, (nw, nh), interpolation=cv2.INTER_NEAREST)
        img = img.astype(np.float32)
        flip = False
        if rng is not None:
            oy = int(rng.integers(0, (size - nh) // PROTO_STRIDE + 1)) * PROTO_STRIDE
            ox = int(rng.integers(0, (size - nw) // PROTO_STRIDE + 1)) * PROTO_STRIDE
            flip = bool(rng.random() < 0.5)
            img = img * rng.uniform(0.7, 1.3) * rng.uniform(0.93, 1.07, 3) + rng.normal(0, 4)
        else:
            oy = (size - nh) // 2 // PROTO_STRIDE * PROTO_STRIDE
            ox = (size - nw) // 2 // PROTO_STRIDE * PROTO_STRIDE
        if flip:
            img = img[:, ::-1]
            inst = inst[:, ::-1]
        imgs[b, oy : oy + nh, ox : ox + nw] = np.clip(img, 0, 255)
        boxes, classes, masks = [], [], []
        for c, m in labelled_masks(inst, data.inst_class[i]):  # the instances left after resizing
            boxes.append(mask_box(m) + [ox, oy, ox, oy])
            classes.append(c)
            canvas = np.zeros((size, size), dtype=np.float32)
            canvas[oy : oy + nh, ox : ox + nw] = m
            masks.append(cv2.resize(canvas, (proto_size, proto_size), interpolation=cv2.INTER_AREA))
        targets.append(
            {
                "boxes": np.asarray(boxes, dtype=np.float32).reshape(-1, 4),
                "classes": np.asarray(classes, dtype=np.int64),
                "masks": np.asarray(masks, dtype=np.float32).reshape(-1, proto_size, proto_size),
            }
        )
    return imgs.transpose(0, 3, 1, 2) / 255.0, targets


# -------------------------------------------------------------------------------------------
# assignment and loss
# -------------------------------------------------------------------------------------------
def assign(boxes: np.ndarray, anchor_xy: np.ndarray, strides: np.ndarray, radius: float = 2.5) -> np.ndarray:
    """Index of the ground-truth box each cell learns (−1 = background), shape (N,).

    A cell is a candidate for a box when its centre lies inside the box, within ``radius``
    strides of the box centre, on a level whose size range holds the box's longest side. A box
    without candidate gets the nearest cell of its levels. A cell claimed by several boxes
    learns the smallest one.
    """
    N = len(anchor_xy)
    out = np.full(N, -1, dtype=np.int64)
    if len(boxes) == 0:
        return out
    x, y = anchor_xy[:, 0][None], anchor_xy[:, 1][None]
    x1, y1, x2, y2 = (boxes[:, k : k + 1] for k in range(4))
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    side = np.maximum(x2 - x1, y2 - y1)
    level_ok = np.zeros((len(boxes), N), dtype=bool)
    levels = tuple(int(s) for s in np.unique(strides))
    for s, (lo, hi) in level_sizes(levels).items():
        level_ok |= (strides[None] == s) & (side >= lo) & (side <= hi)
    r = radius * strides[None]
    cand = (x > x1) & (x < x2) & (y > y1) & (y < y2) & (np.abs(x - cx) < r) & (np.abs(y - cy) < r) & level_ok
    for g in np.flatnonzero(~cand.any(1)):
        d = np.hypot(anchor_xy[:, 0] - cx[g, 0], anchor_xy[:, 1] - cy[g, 0])
        d[~level_ok[g]] = np.inf
        cand[g, int(np.argmin(d))] = True
    area = ((x2 - x1) * (y2 - y1)).ravel()
    cost = np.where(cand, area[:, None], np.inf)
    best = np.argmin(cost, axis=0)
    pos = np.isfinite(cost[best, np.arange(N)])
    out[pos] = best[pos]
    return out


def giou(a, b):
    """Generalised IoU and IoU of matching rows of two (P, 4) xyxy tensors."""
    torch = _torch()
    lt = torch.maximum(a[:, :2], b[:, :2])
    rb = torch.minimum(a[:, 2:], b[:, 2:])
    inter = (rb - lt).clamp(min=0).prod(1)
    area_a = (a[:, 2:] - a[:, :2]).clamp(min=0).prod(1)
    area_b = (b[:, 2:] - b[:, :2]).clamp(min=0).prod(1)
    union = area_a + area_b - inter + 1e-7
    iou = inter / union
    clt = torch.minimum(a[:, :2], b[:, :2])
    crb = torch.maximum(a[:, 2:], b[:, 2:])
    hull = (crb - clt).clamp(min=0).prod(1) + 1e-7
    return iou - (hull - union) / hull, iou


def _cap_per_group(groups: np.ndarray, cap: int, rng: np.random.Generator) -> np.ndarray:
    """Indices keeping at most ``cap`` random members of each group label."""
    keep = []
    for label in np.unique(groups):
        members = np.flatnonzero(groups == label)
        if len(members) > cap:
            members = rng.choice(members, cap, replace=False)
        keep.append(members)
    return np.sort(np.concatenate(keep))


def compute_loss(levels, protos, targets, anchor_xy, strides, gains=(5.0, 1.0, 5.0), mask_cells=6, rng=None):
    """YOLOv8-seg-style loss of a batch; returns (total, {"box", "cls", "mask"}).

    The mask loss is the mean over images of the per-instance, box-normalised cross-entropy.
    """
    torch = _torch()
    F = torch.nn.functional
    box_raw, cls_logit, coef = flatten_levels(levels)
    B, nc, N = cls_logit.shape
    a_xy = torch.from_numpy(anchor_xy)
    st = torch.from_numpy(strides)
    boxes = decode_boxes(box_raw, a_xy, st)  # (B, 4, N)
    cls_target = torch.zeros_like(cls_logit)
    box_losses, mask_losses = [], []
    n_pos = n_mask = 0
    rng = rng if rng is not None else np.random.default_rng(0)
    proto_size = protos.shape[-1]
    for b, t in enumerate(targets):
        which = assign(t["boxes"], anchor_xy, strides)
        pos = np.flatnonzero(which >= 0)
        if len(pos) == 0:
            continue
        g = which[pos]
        n_pos += len(pos)
        pos_t = torch.from_numpy(pos)
        gt_boxes = torch.from_numpy(t["boxes"][g])
        pred_boxes = boxes[b, :, pos_t].T
        g_iou, iou = giou(pred_boxes, gt_boxes)
        box_losses.append((1.0 - g_iou).sum())
        # IoU-aware class target (as YOLOv8's task-aligned targets and VarifocalNet): a cell's
        # score learns how well its box fits, so NMS keeps the best box and the poorly placed
        # boxes of a large object's edge cells fall below the confidence threshold
        cls_target[b, torch.from_numpy(t["classes"][g]), pos_t] = iou.detach().clamp(0.0, 1.0)
        # mask: coefficients of the positive cells on this image's prototypes; at most
        # `mask_cells` random cells per instance (the mask loss dominated the step time otherwise)
        keep = _cap_per_group(g, mask_cells, rng)
        mpos, mg = pos_t[torch.from_numpy(keep)], g[keep]
        logits = coef[b, :, mpos].T @ protos[b].reshape(NUM_MASKS, -1)  # (P, proto_size²)
        gt_masks = torch.from_numpy(t["masks"][mg].reshape(len(mg), -1))
        bce = F.binary_cross_entropy_with_logits(logits, gt_masks, reduction="none")
        gb = t["boxes"][mg] / PROTO_STRIDE
        ii = np.arange(proto_size) + 0.5
        inside_x = (ii[None] >= gb[:, 0:1]) & (ii[None] <= gb[:, 2:3])
        inside_y = (ii[None] >= gb[:, 1:2]) & (ii[None] <= gb[:, 3:4])
        crop = (inside_y[:, :, None] & inside_x[:, None, :]).reshape(len(mg), -1).astype(np.float32)
        crop_t = torch.from_numpy(crop)
        area = crop_t.sum(1).clamp(min=1.0)
        mask_losses.append(((bce * crop_t).sum(1) / area).mean())
        n_mask += 1
    norm = max(n_pos, 1)
    l_cls = F.binary_cross_entropy_with_logits(cls_logit, cls_target, reduction="sum") / norm
    l_box = torch.stack(box_losses).sum() / norm if box_losses else cls_logit.sum() * 0
    l_mask = torch.stack(mask_losses).sum() / max(n_mask, 1) if mask_losses else cls_logit.sum() * 0
    total = gains[0] * l_box + gains[1] * l_cls + gains[2] * l_mask
    return total, {"box": float(l_box.detach()), "cls": float(l_cls.detach()), "mask": float(l_mask.detach())}


# -------------------------------------------------------------------------------------------
# export
# -------------------------------------------------------------------------------------------
def export_onnx(
    model,
    path: Path,
    size: int,
    names: tuple[str, ...],
    extra: dict[str, str] | None = None,
    levels: tuple[int, ...] = STRIDES,
):
    """Export in the YOLOv8-seg layout with ultralytics-style metadata."""
    torch = _torch()
    import onnx

    anchor_xy, strides = anchors(size, levels)

    class Exported(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.net = net
            self.register_buffer("a_xy", torch.from_numpy(anchor_xy))
            self.register_buffer("st", torch.from_numpy(strides))

        def forward(self, images):
            levels, protos = self.net(images)
            box_raw, cls_logit, coef = flatten_levels(levels)
            xyxy = decode_boxes(box_raw, self.a_xy, self.st)
            cxcy = (xyxy[:, :2] + xyxy[:, 2:]) / 2
            wh = xyxy[:, 2:] - xyxy[:, :2]
            return torch.cat([cxcy, wh, cls_logit.sigmoid(), coef], 1), protos

    wrapped = Exported(model).eval()
    path.parent.mkdir(parents=True, exist_ok=True)
    dummy = torch.zeros(1, 3, size, size)
    with torch.no_grad():
        torch.onnx.export(
            wrapped,
            (dummy,),
            str(path),
            input_names=["images"],
            output_names=["output0", "output1"],
            opset_version=17,
            do_constant_folding=True,
            dynamo=False,
        )
    m = onnx.load(str(path))
    meta = {
        "description": "amslam tiny YOLOv8-seg trained on simulator images",
        "author": "amslam",
        "task": "segment",
        "stride": str(max(levels)),
        "batch": "1",
        "imgsz": str([size, size]),
        "names": str(dict(enumerate(names))),
        **(extra or {}),
    }
    del m.metadata_props[:]
    for k, v in meta.items():
        m.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(m)
    onnx.save(m, str(path))
    assert ast.literal_eval(meta["names"]) == dict(enumerate(names))


# -------------------------------------------------------------------------------------------
# training
# -------------------------------------------------------------------------------------------
def lr_factor(step: int, warmup: int, total: int) -> float:
    """Share of the peak learning rate at optimiser step ``step`` of ``total``: a linear warm-up
    over ``warmup`` steps, then a cosine from 1 down to 0.02."""
    if step < warmup:
        return (step + 1) / warmup
    return 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * (step - warmup) / max(1, total - warmup)))


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _load_weights(model: Any, path: Path) -> None:
    """Start ``model`` from the weights in ``path``; AmslamError naming the file if they do not fit."""
    torch = _torch()
    try:
        state = torch.load(path)
    except Exception as exc:  # not a torch file: pickle, zip and EOF errors, among others
        raise AmslamError(
            f"initial weights {path}: not weights saved by train.py ({_first_line(exc)})"
        ) from None
    try:
        model.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:  # other layers (--p2 or not), not a dict
        raise AmslamError(f"initial weights {path}: not this network's ({_first_line(exc)})") from None


def _training_metadata(data: Dataset, epochs: int, levels: tuple[int, ...]) -> dict[str, str]:
    """What the exported model records of its training, besides ultralytics' own keys."""
    return {
        "train_frames": str(len(data)),
        "epochs": str(epochs),
        "train_seeds": str(sorted(set(data.seeds[data.seeds >= 0].tolist()))),
        "train_worlds": str(sorted(set(data.sources[data.seeds < 0].tolist()))),
        "levels": str(list(levels)),
    }


def train(
    data: Dataset,
    out: Path,
    *,
    size: int = 320,
    epochs: int = 12,
    batch: int = 16,
    lr: float = 2e-3,
    threads: int = 2,
    seed: int = 0,
    log_every: int = 20,
    levels: tuple[int, ...] = STRIDES,
    init: Path | None = None,
) -> Path:
    """Train on ``data`` and export the network to ``out`` (ONNX); ``levels``: detection strides.

    ``init``: start from these weights (the ``.pt`` an earlier run saved next to its ONNX file).
    """
    torch = _torch()
    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = build_model(len(data.names), strides=levels)
    if init is not None:
        _load_weights(model, init)
    # now rather than at the export: the weights are saved there first, after all the training
    out.parent.mkdir(parents=True, exist_ok=True)
    n_params = sum(p.numel() for p in model.parameters())
    anchor_xy, strides = anchors(size, levels)
    steps_per_epoch = max(1, len(data) // batch)
    total = epochs * steps_per_epoch
    warmup = min(200, total // 10)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=5e-4)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda k: lr_factor(k, warmup, total))
    print(f"{len(data)} frames, {n_params / 1e6:.2f} M parameters, {total} steps", flush=True)
    t0 = time.time()
    step = 0
    model.train()
    for epoch in range(epochs):
        order = rng.permutation(len(data))
        for k in range(steps_per_epoch):
            idx = order[k * batch : (k + 1) * batch]
            imgs, targets = make_batch(data, idx, size, rng)
            heads_out, protos = model(torch.from_numpy(imgs.astype(np.float32)))
            loss, parts = compute_loss(heads_out, protos, targets, anchor_xy, strides, rng=rng)
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            opt.step()
            sched.step()
            step += 1
            if step % log_every == 0:
                elapsed = time.time() - t0
                eta = elapsed / step * (total - step)
                print(
                    f"epoch {epoch + 1}/{epochs} step {step}/{total} loss {float(loss):.3f} "
                    f"box {parts['box']:.3f} cls {parts['cls']:.3f} mask {parts['mask']:.3f} "
                    f"lr {sched.get_last_lr()[0]:.2e} {elapsed:.0f}s (eta {eta:.0f}s)",
                    flush=True,
                )
    model.eval()
    # the weights before the export folds the batch norms: what a later run could start from
    torch.save(model.state_dict(), out.with_suffix(".pt"))
    export_onnx(model, out, size, data.names, extra=_training_metadata(data, epochs, levels), levels=levels)
    print(f"exported {out} ({out.stat().st_size / 1e6:.2f} MB) after {time.time() - t0:.0f}s", flush=True)
    return out


# -------------------------------------------------------------------------------------------
# command line
# -------------------------------------------------------------------------------------------
def _folders(text: str) -> tuple[Path, ...]:
    """``--mesh-worlds``: comma-separated folders."""
    return tuple(Path(f) for f in text.split(",") if f.strip())


def _unwritable(path: Path) -> str | None:
    """Why the file ``path`` could not be written (in a folder made as needed), or None if it can."""
    folder = path.parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        return f"{folder} is a file, not a folder"
    if not os.access(folder, os.W_OK):
        return f"{folder} is not writable"
    return None


def _default_cache(args: argparse.Namespace) -> Path:
    """The training set's cache file: named after what it holds, so other options render anew."""
    kind = ("dr-" if args.randomise else "") + ("plain-" if args.with_plain else "")
    name = f"train-{kind}{args.seeds}x{args.frames}"
    if args.mesh_worlds:
        name += f"+{'+'.join(f.name for f in args.mesh_worlds)}x{args.mesh_frames}"
    return Path(f"runs/onnx_detector/{name}.npz")


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("plugins/onnx_detector/models/sim_yolov8seg.onnx"))
    ap.add_argument(
        "--data",
        type=Path,
        default=None,
        help="training set cache: rendered once, reused when present "
        "(default: runs/onnx_detector/train-SEEDSxFRAMES.npz)",
    )
    ap.add_argument(
        "--seeds", type=whole_number(0), default=len(TRAIN_SEEDS), help="training buildings (seeds 100..)"
    )
    ap.add_argument("--frames", type=positive_int, default=64, help="frames per training building")
    ap.add_argument("--epochs", type=positive_int, default=10)
    ap.add_argument("--batch", type=positive_int, default=8)
    ap.add_argument("--size", type=positive_int, default=320, help="square network input (multiple of 32)")
    ap.add_argument(
        "--threads",
        type=positive_int,
        default=1,
        help="torch threads (1 is fastest on a busy 2-core machine)",
    )
    ap.add_argument("--p2", action="store_true", help="add the stride-4 detection level (small, far objects)")
    ap.add_argument(
        "--no-randomise",
        dest="randomise",
        action="store_false",
        help="render the procedural buildings with the simulator's own geometry rules and look, as the "
        "models before issue #23 were trained (default: domain randomisation, see dataset.py)",
    )
    ap.add_argument(
        "--mesh-worlds",
        type=_folders,
        default="",
        help="also train on these mesh worlds, comma-separated folders written by `amslam world import` "
        "(never the worlds a model is judged on)",
    )
    ap.add_argument("--mesh-frames", type=positive_int, default=160, help="frames per mesh world")
    ap.add_argument("--lr", type=float, default=2e-3, help="peak learning rate (AdamW, cosine schedule)")
    ap.add_argument(
        "--init", type=Path, default=None, help="start from these weights (a .pt written by an earlier run)"
    )
    ap.add_argument(
        "--with-plain",
        action="store_true",
        help="with randomisation: the same buildings rendered without it too (the pre-#23 training set)",
    )
    return ap


def parse_arguments(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line's arguments, checked before any rendering (exit status 2 otherwise).

    ``mesh_worlds`` is a tuple of folders; ``data`` is the default cache file when not given.
    """
    ap = _parser()
    args = ap.parse_args(argv)
    if args.init is not None and not args.init.is_file():
        ap.error(f"--init {args.init}: no such file (the .pt an earlier run wrote next to its .onnx)")
    if args.with_plain and not args.randomise:
        ap.error("--with-plain adds unrandomised buildings to randomised ones: not with --no-randomise")
    for folder in args.mesh_worlds:
        if not (folder / "world.ply").is_file():
            ap.error(
                f"--mesh-worlds: {folder} holds no world.ply (a folder written by `amslam world import`)"
            )
    most = min(HELDOUT_SEEDS) - TRAIN_SEEDS[0]
    if args.seeds > most:
        ap.error(f"--seeds {args.seeds}: at most {most}; the seeds from {min(HELDOUT_SEEDS)} on are held out")
    if args.seeds == 0 and not args.mesh_worlds:
        ap.error("--seeds 0 and no --mesh-worlds: nothing to train on")
    if args.seeds == 0 and args.with_plain:
        ap.error("--with-plain renders the --seeds buildings a second time: none with --seeds 0")
    if args.size % 32:
        ap.error(f"--size {args.size}: not a multiple of 32, the network's coarsest stride")
    if not args.lr > 0:
        ap.error(f"--lr {args.lr}: not positive")
    if args.data is None:
        args.data = _default_cache(args)
    for option, path in (("--out", args.out), ("--data", args.data)):
        problem = None if option == "--data" and args.data.exists() else _unwritable(path)
        if problem:
            ap.error(f"{option} {path}: cannot be written, {problem}")
    return args


def _training_seeds(n: int) -> list[int]:
    """The first ``n`` training buildings (``--seeds``)."""
    return list(range(TRAIN_SEEDS[0], TRAIN_SEEDS[0] + n))


def _render_training_set(args: argparse.Namespace) -> Dataset:
    """Render the training set the arguments ask for and save it to ``args.data``."""
    seeds = _training_seeds(args.seeds)
    t = time.time()
    data = render_dataset(
        seeds,
        args.frames,
        progress=True,
        classes=CLASSES,
        randomise=args.randomise,
        mesh_worlds=args.mesh_worlds,
        mesh_frames=args.mesh_frames,
    )
    if args.with_plain:
        data = Dataset.concatenate([render_dataset(seeds, args.frames, progress=True, classes=CLASSES), data])
    data.save(args.data)
    print(f"rendered {len(data)} frames in {time.time() - t:.0f}s → {args.data}", flush=True)
    return data


def run(args: argparse.Namespace) -> Path:
    """Load (or render) the training set, train, export; the exported model's path.

    ``args`` as :func:`parse_arguments` returns them. AmslamError for a cache or a mesh world that
    cannot be read and for torch or onnx missing; SystemExit for a cache of other buildings or frames.
    """
    data = Dataset.load(args.data) if args.data.exists() else None
    expected = (
        args.seeds * args.frames * (2 if args.with_plain else 1) + len(args.mesh_worlds) * args.mesh_frames
    )
    if data is not None and (
        sorted(set(data.seeds[data.seeds >= 0].tolist())) != _training_seeds(args.seeds)
        or len(data) != expected
    ):
        raise SystemExit(
            f"{args.data} holds other buildings or frames than --seeds/--frames/--mesh-worlds ask for"
        )
    # before minutes of rendering, not at the first use
    missing = missing_modules(("torch", "onnx"))
    if missing:
        raise AmslamError(f"training the detector needs {' and '.join(missing)}: pip install 'amslam[train]'")
    if data is not None:
        print(f"loaded {args.data}: {len(data)} frames", flush=True)
    else:
        data = _render_training_set(args)
    return train(
        data,
        args.out,
        size=args.size,
        epochs=args.epochs,
        batch=args.batch,
        threads=args.threads,
        levels=P2_STRIDES if args.p2 else STRIDES,
        lr=args.lr,
        init=args.init,
    )


def main(argv: list[str] | None = None) -> None:
    """Command line: render (or load) the training set, train, export."""
    args = parse_arguments(argv)
    try:
        run(args)
    except AmslamError as exc:  # an unreadable cache or mesh world, torch missing, foreign --init
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
