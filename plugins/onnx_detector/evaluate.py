"""Accuracy of a YOLOv8-seg model on held-out simulator frames: precision, recall, mask IoU.

Frames come from buildings whose seeds the training never saw (``train.HELDOUT_SEEDS``), rendered
at the demo camera's 320×240 and at the D435i's 640×480. The model runs through the plugin's own
path (letterbox, threshold, NMS, masks: :class:`~.decoder.SegmentationModel`). A prediction is a
true positive when its mask overlaps a not yet matched ground-truth instance of the same class
with IoU ≥ 0.5 (greedy, best score first). Instances smaller than the detector's ``min_pixels``
(60 at 640×480, scaled with the image area) are "don't care": a prediction on one counts neither
way, missing one is no miss.

    python -m amslam.plugins.onnx_detector.evaluate [--model FILE] [--frames 40]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from amslam.plugins.onnx_detector.dataset import Dataset, render_dataset
from amslam.plugins.onnx_detector.decoder import SegmentationModel

HELDOUT_SEEDS = (900, 901, 902, 903)


@dataclass
class Counts:
    """True and false positives, misses and the mask IoUs of the true positives, of one class."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    ious: list[float] = field(default_factory=list)

    def add(self, other: Counts) -> None:
        self.tp += other.tp
        self.fp += other.fp
        self.fn += other.fn
        self.ious += other.ious

    @property
    def precision(self) -> float:
        return self.tp / max(self.tp + self.fp, 1)

    @property
    def recall(self) -> float:
        return self.tp / max(self.tp + self.fn, 1)

    @property
    def mask_iou(self) -> float:
        return float(np.mean(self.ious)) if self.ious else float("nan")


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = np.count_nonzero(a & b)
    return inter / max(np.count_nonzero(a | b), 1)


def evaluate(
    model: SegmentationModel, data: Dataset, *, conf: float = 0.4, iou: float = 0.5, min_pixels: int = 60
) -> dict[str, Counts]:
    """Counts per class name (and ``"all"``) of the model on every frame of ``data``."""
    H, W = data.images.shape[1:3]
    min_px = max(1, int(round(min_pixels * H * W / (640 * 480))))
    per = {n: Counts() for n in data.names}
    for i in range(len(data)):
        preds = model(data.images[i], conf=conf, iou=iou)
        gts = data.objects(i)
        big = [np.count_nonzero(m) >= min_px for _, m in gts]
        used = [False] * len(gts)
        for p in preds:  # best score first
            best, best_iou = -1, 0.5
            for g, (c, m) in enumerate(gts):
                if c == p.class_id and not used[g]:
                    v = _iou(p.mask, m)
                    if v >= best_iou:
                        best, best_iou = g, v
            counts = per[data.names[p.class_id]]
            if best < 0:
                counts.fp += 1
                continue
            used[best] = True
            if big[best]:
                counts.tp += 1
                counts.ious.append(best_iou)
        for g, (c, _) in enumerate(gts):
            if big[g] and not used[g]:
                per[data.names[c]].fn += 1
    total = Counts()
    for c in per.values():
        total.add(c)
    per["all"] = total
    return per


def table(results: dict[str, dict[str, Counts]]) -> str:
    """A markdown table: one row per (resolution, class)."""
    lines = [
        "| frames | class | ground truth | detections | precision | recall | mask IoU |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for res, per in results.items():
        for name, c in per.items():
            lines.append(
                f"| {res} | {name} | {c.tp + c.fn} | {c.tp + c.fp} | {c.precision:.3f} | {c.recall:.3f} "
                f"| {c.mask_iou:.3f} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Command line: render the held-out frames, run the model, print the table."""
    from amslam.plugins.onnx_detector.detector import shipped_model

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--frames", type=int, default=40, help="frames per held-out building")
    ap.add_argument("--conf", type=float, default=0.4)
    ap.add_argument("--sizes", default="320x240,640x480", help="image sizes to render, WxH,...")
    args = ap.parse_args(argv)
    model = SegmentationModel(args.model or shipped_model())
    results = {}
    for spec in args.sizes.split(","):
        w, h = (int(v) for v in spec.split("x"))
        data = render_dataset(list(HELDOUT_SEEDS), args.frames, width=w, height=h)
        results[f"{w}×{h}, {len(data)}"] = evaluate(model, data, conf=args.conf)
    print(f"model {args.model or shipped_model()}, held-out seeds {list(HELDOUT_SEEDS)}, conf {args.conf}")
    print(table(results))


if __name__ == "__main__":
    main()
