"""Accuracy of a YOLOv8-seg model on held-out simulator frames: precision, recall, mask IoU.

Frames come from buildings whose seeds the training never saw (``train.HELDOUT_SEEDS``), rendered
at the demo camera's 320×240 and at the D435i's 640×480. The model runs through the plugin's own
path (letterbox, threshold, NMS, masks: :class:`~.decoder.SegmentationModel`). A prediction is a
true positive when it overlaps a not yet matched ground-truth instance of the same class with
IoU ≥ 0.5 (greedy, best score first), the overlap being that of the masks (``match="mask"``, the
instance-segmentation criterion) or of the boxes (``match="box"``, the detection criterion; the
box of an instance is its visible mask's). The mask IoU column averages the true positives' mask
IoU either way. Instances smaller than the detector's ``min_pixels`` (60 at 640×480, scaled with
the image area) are "don't care": a prediction on one counts neither way, missing one is no miss.

    python -m amslam.apps.detector_training.evaluate [--model FILE] [--frames 40]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from amslam.apps.detector_training.dataset import Dataset, render_dataset
from amslam.plugins.onnx_detector.decoder import SegmentationModel

HELDOUT_SEEDS = (900, 901, 902, 903)


@dataclass
class Counts:
    """True and false positives, misses and the mask IoUs of the true positives, of one class."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    ious: list[float] = field(default_factory=list)
    #: (visible pixels at 320×240, found) of every ground-truth instance counted
    sizes: list[tuple[int, bool]] = field(default_factory=list)

    def add(self, other: Counts) -> None:
        self.tp += other.tp
        self.fp += other.fp
        self.fn += other.fn
        self.ious += other.ious
        self.sizes += other.sizes

    def recall_by_size(self, edges: tuple[int, ...]) -> list[tuple[int, int, float]]:
        """(low edge, instances, recall) of instances binned by visible pixels."""
        a = np.array([s for s, _ in self.sizes])
        f = np.array([ok for _, ok in self.sizes], dtype=bool)
        out = []
        for lo, hi in zip(edges, (*edges[1:], 1 << 62), strict=True):
            sel = (a >= lo) & (a < hi)
            out.append((lo, int(sel.sum()), float(f[sel].mean()) if sel.any() else float("nan")))
        return out

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


def _box(mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    return np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], dtype=float)


def _box_iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = float(np.prod(np.clip(np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2]), 0, None)))
    union = float(np.prod(a[2:] - a[:2]) + np.prod(b[2:] - b[:2])) - inter
    return inter / max(union, 1e-9)


def evaluate(
    model: SegmentationModel,
    data: Dataset,
    *,
    conf: float = 0.25,
    iou: float = 0.5,
    min_pixels: int = 60,
    match: str = "mask",
) -> dict[str, Counts]:
    """Counts per class name (and ``"all"``) of the model on every frame of ``data``.

    ``match`` is ``"mask"`` or ``"box"``: which overlap pairs predictions with instances.
    """
    if match not in ("mask", "box"):
        raise ValueError(f"match must be 'mask' or 'box', got {match!r}")
    H, W = data.images.shape[1:3]
    min_px = max(1, int(round(min_pixels * H * W / (640 * 480))))
    per = {n: Counts() for n in data.names}
    for i in range(len(data)):
        preds = model(data.images[i], conf=conf, iou=iou)
        gts = data.objects(i)
        big = [np.count_nonzero(m) >= min_px for _, m in gts]
        boxes = [_box(m) for _, m in gts]
        used = [False] * len(gts)
        for p in preds:  # best score first
            best, best_iou = -1, 0.5
            for g, (c, m) in enumerate(gts):
                if c == p.class_id and not used[g]:
                    v = _iou(p.mask, m) if match == "mask" else _box_iou(p.box, boxes[g])
                    if v >= best_iou:
                        best, best_iou = g, v
            counts = per[data.names[p.class_id]]
            if best < 0:
                counts.fp += 1
                continue
            used[best] = True
            if big[best]:
                counts.tp += 1
                counts.ious.append(_iou(p.mask, gts[best][1]))
        for g, (c, m) in enumerate(gts):
            if big[g]:
                # size in pixels of a 320×240 image, so that resolutions compare
                area = np.count_nonzero(m) * 320 * 240 / (H * W)
                per[data.names[c]].sizes.append((int(round(area)), used[g]))
                if not used[g]:
                    per[data.names[c]].fn += 1
    total = Counts()
    for c in per.values():
        total.add(c)
    per["all"] = total
    return per


def centroid_errors(
    model_path: Path, seeds: tuple[int, ...], frames: int, *, width: int = 320, height: int = 240
) -> dict[str, dict[str, np.ndarray]]:
    """Per class, distances (m) of the ``onnx`` detector's centroids from two references.

    Renders frames with depth, runs :class:`~.detector.OnnxDetector` (default parameters) on them
    and pairs each detection with the ground-truth instance that most of its mask covers. Returns
    per class name a dict of arrays:

    * ``"mask"``: the detection's centroid against the median of the back-projected depth pixels
      of the instance's exact mask — the ``sim`` detector's centroid without its noise; says what
      the coarser network masks cost the 3-D step;
    * ``"object"``: the detection's centroid against the object's true centre (the centre of its
      bounds, what the semantic map is scored against);
    * ``"exact"``: the exact mask's median against the object's true centre (the same frames'
      reference: what a perfect mask gives).
    """
    from amslam.apps.detector_training.dataset import building, sample_poses
    from amslam.interfaces import RunContext
    from amslam.lib.camera import backproject
    from amslam.plugins.onnx_detector.detector import OnnxDetector
    from amslam.plugins.sim.camera import CameraParams, Renderer

    cp = CameraParams(width=width, height=height)
    cam = cp.model()
    renderer = Renderer(cam, cp)
    det = OnnxDetector()
    ctx = RunContext(rng=np.random.default_rng(0), run_dir=Path("."))
    det.configure(OnnxDetector.Params(model=str(model_path)), ctx)
    p = det.params
    assert p is not None
    Kinv = np.linalg.inv(cam.K)
    out: dict[str, dict[str, list[float]]] = {}
    for seed in seeds:
        world = building(seed)
        centre = {o.instance_id: o.centroid for o in world.objects}
        rng = np.random.default_rng(20_000 + seed)
        for T in sample_poses(world, frames, rng):
            r = renderer.render(world, T, rng)
            valid = (r.depth > 0) & (r.depth <= p.max_range)
            T_cw = np.linalg.inv(T)
            for inst in det.model(r.rgb, conf=p.confidence, iou=p.iou, mask_threshold=p.mask_threshold):
                d = det.lift(inst, r.depth, cam.K)
                ids, counts = np.unique(r.instance[inst.mask & valid], return_counts=True)
                counts, ids = counts[ids > 0], ids[ids > 0]
                if d is None or len(ids) == 0:
                    continue
                iid = int(ids[np.argmax(counts)])
                truth = (r.instance == iid) & valid
                if truth.sum() < 15:
                    continue
                c = np.median(backproject(truth, r.depth, Kinv), axis=0)
                o = T_cw[:3, :3] @ centre[iid] + T_cw[:3, 3]
                e = out.setdefault(d.class_name, {"mask": [], "object": [], "exact": []})
                e["mask"].append(float(np.linalg.norm(d.centroid_cam - c)))
                e["object"].append(float(np.linalg.norm(d.centroid_cam - o)))
                e["exact"].append(float(np.linalg.norm(c - o)))
    return {k: {m: np.array(v) for m, v in e.items()} for k, e in out.items()}


def table(results: dict[tuple[str, str], dict[str, Counts]]) -> str:
    """A markdown table: one row per (frames, match, class)."""
    lines = [
        "| frames | match | class | ground truth | detections | precision | recall | mask IoU |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for (res, match), per in results.items():
        for name, c in per.items():
            lines.append(
                f"| {res} | {match} IoU ≥ 0.5 | {name} | {c.tp + c.fn} | {c.tp + c.fp} | {c.precision:.3f} "
                f"| {c.recall:.3f} | {c.mask_iou:.3f} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Command line: render the held-out frames, run the model, print the table."""
    from amslam.plugins.onnx_detector.detector import shipped_model

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--frames", type=int, default=40, help="frames per held-out building")
    ap.add_argument("--conf", type=float, default=0.25)
    ap.add_argument("--sizes", default="320x240,640x480", help="image sizes to render, WxH,...")
    ap.add_argument("--centroids", action="store_true", help="also: centroid errors (masks, centres)")
    args = ap.parse_args(argv)
    model = SegmentationModel(args.model or shipped_model())
    results = {}
    for spec in args.sizes.split(","):
        w, h = (int(v) for v in spec.split("x"))
        data = render_dataset(list(HELDOUT_SEEDS), args.frames, width=w, height=h)
        for match in ("mask", "box"):
            results[(f"{w}×{h}, {len(data)}", match)] = evaluate(model, data, conf=args.conf, match=match)
    print(f"model {args.model or shipped_model()}, held-out seeds {list(HELDOUT_SEEDS)}, conf {args.conf}")
    print(table(results))
    print()
    edges = (0, 400, 1600, 6400)
    heads = [f"recall, {lo}–{hi} px" for lo, hi in zip(edges, edges[1:], strict=False)] + [
        f"recall, {edges[-1]}+ px"
    ]
    print("Recall by object size (visible pixels, scaled to a 320×240 image; instances in brackets):")
    print()
    print("| frames | match | " + " | ".join(heads) + " |")
    print("|---|---|" + "---:|" * len(edges))
    for (res, match), per in results.items():
        cells = [f"{r:.2f} ({n})" for _, n, r in per["all"].recall_by_size(edges)]
        print(f"| {res} | {match} IoU ≥ 0.5 | " + " | ".join(cells) + " |")
    if args.centroids:
        errors = centroid_errors(args.model or shipped_model(), HELDOUT_SEEDS, args.frames)
        print()
        print("Centroid of each detection (320×240, m) against the exact mask's centroid, against the")
        print("object's true centre, and the exact mask's centroid against the true centre:")
        print()
        print("| class | detections | reference | median | 75th percentile | 90th percentile | mean |")
        print("|---|---:|---|---:|---:|---:|---:|")
        refs = {
            "mask": "onnx − exact mask",
            "object": "onnx − object centre",
            "exact": "exact mask − object centre",
        }
        for name, e in sorted(errors.items()):
            for key, label in refs.items():
                q = np.percentile(e[key], [50, 75, 90])
                print(
                    f"| {name} | {len(e[key])} | {label} | {q[0]:.3f} | {q[1]:.3f} | {q[2]:.3f} "
                    f"| {e[key].mean():.3f} |"
                )


if __name__ == "__main__":
    main()
