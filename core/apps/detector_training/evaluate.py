"""Accuracy of a YOLOv8-seg model on held-out simulator frames: precision, recall, mask IoU.

Frames come from buildings whose seeds the training never saw (``dataset.HELDOUT_SEEDS``), rendered
at the demo camera's 320×240 and at the D435i's 640×480. The model runs through the plugin's own
path (letterbox, threshold, NMS, masks: :class:`~.decoder.SegmentationModel`). A prediction is a
true positive when it overlaps a not yet matched ground-truth instance of the same class with
IoU ≥ 0.5 (greedy, best score first), the overlap being that of the masks (``match="mask"``, the
instance-segmentation criterion) or of the boxes (``match="box"``, the detection criterion; the
box of an instance is its visible mask's). The mask IoU column averages the true positives' mask
IoU either way. Instances smaller than the detector's ``min_pixels`` (60 at 640×480, scaled with
the image area) are "don't care": a prediction on one counts neither way, missing one is no miss.

    python -m amslam.apps.detector_training.evaluate [--model FILE] [--frames 40] [--seeds 900,901]
        [--world MESH_WORLD_DIR ...] [--choose-threshold]

``--world`` renders frames of a mesh world (a folder written by ``amslam world import``, such as
the shared house) with its instance labels; its objects of classes the model has not (cabinet,
tv, bed, …) are background, so a detection on one is a false positive. ``--choose-threshold``
picks the confidence of the best F1 on the frames given: run it on a validation set (other
seeds, another mesh world), never on the buildings the model is judged on.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from amslam.apps.detector_training.dataset import CLASSES, HELDOUT_SEEDS, Dataset, mask_box, render_dataset
from amslam.cli import positive_int
from amslam.errors import AmslamError
from amslam.plugins.onnx_detector.decoder import Instance, ModelInfo, SegmentationModel, inspect_model

#: confidence thresholds ``--choose-threshold`` tries
THRESHOLDS: tuple[float, ...] = (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7)


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


def _mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = np.count_nonzero(a & b)
    return inter / max(np.count_nonzero(a | b), 1)


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
    return score(
        predict(model, data, conf=conf, iou=iou), data, conf=conf, min_pixels=min_pixels, match=match
    )


def check_classes(info: ModelInfo, names: tuple[str, ...]) -> None:
    """Refuse a model whose classes are not ``names``: ValueError saying what it has.

    Predictions are scored by class index, so a model of other classes (an ultralytics COCO
    export) would be counted against the wrong instances, or index past ``names``.
    """
    if info.num_classes != len(names) or (info.names and info.names != tuple(names)):
        has = list(info.names) if info.names else f"{info.num_classes} unnamed classes"
        raise ValueError(f"the model's classes ({has}) are not the frames' {list(names)}")


def predict(
    model: SegmentationModel, data: Dataset, *, conf: float = 0.25, iou: float = 0.5
) -> list[list[Instance]]:
    """The model's instances on every frame of ``data`` (best first), at confidence ``conf``.

    Scoring them at a higher threshold (:func:`score`) gives what the model run at that
    threshold gives: NMS keeps a box only for boxes scored above it, so dropping the weaker
    ones afterwards changes no survivor. ValueError if the model's classes are not ``data``'s.
    """
    check_classes(model.info, data.names)
    return [model(data.images[i], conf=conf, iou=iou) for i in range(len(data))]


def score(
    predictions: list[list[Instance]],
    data: Dataset,
    *,
    conf: float = 0.25,
    min_pixels: int = 60,
    match: str = "mask",
) -> dict[str, Counts]:
    """Counts per class name (and ``"all"``) of ``predictions`` (:func:`predict`) scoring ``conf`` or more."""
    if match not in ("mask", "box"):
        raise ValueError(f"match must be 'mask' or 'box', got {match!r}")
    H, W = data.images.shape[1:3]
    min_px = max(1, int(round(min_pixels * H * W / (640 * 480))))
    per_class = {n: Counts() for n in data.names}
    for i in range(len(data)):
        preds = [q for q in predictions[i] if q.score >= conf]
        gts = data.objects(i)
        counted = [np.count_nonzero(m) >= min_px for _, m in gts]  # the others are "don't care"
        boxes = [mask_box(m) for _, m in gts]
        used = [False] * len(gts)
        for p in preds:  # best score first: an instance goes to the strongest prediction on it
            best, best_iou = -1, 0.5
            for g, (c, m) in enumerate(gts):
                if c == p.class_id and not used[g]:
                    v = _mask_iou(p.mask, m) if match == "mask" else _box_iou(p.box, boxes[g])
                    if v >= best_iou:
                        best, best_iou = g, v
            counts = per_class[data.names[p.class_id]]
            if best < 0:
                counts.fp += 1
                continue
            used[best] = True
            if counted[best]:
                counts.tp += 1
                counts.ious.append(_mask_iou(p.mask, gts[best][1]))
        for g, (c, m) in enumerate(gts):
            if counted[g]:
                # size in pixels of a 320×240 image, so that resolutions compare
                area = np.count_nonzero(m) * 320 * 240 / (H * W)
                per_class[data.names[c]].sizes.append((int(round(area)), used[g]))
                if not used[g]:
                    per_class[data.names[c]].fn += 1
    total = Counts()
    for c in per_class.values():
        total.add(c)
    per_class["all"] = total
    return per_class


def f1(c: Counts) -> float:
    """The harmonic mean of precision and recall."""
    return 2 * c.precision * c.recall / max(c.precision + c.recall, 1e-9)


def choose_threshold(
    predictions: list[list[list[Instance]]],
    sets: list[Dataset],
    thresholds: tuple[float, ...],
    match: str = "box",
) -> tuple[float, list[tuple[float, Counts]]]:
    """The confidence threshold of the best F1 (all classes, all sets pooled) and every threshold's counts.

    ``predictions[k]`` are :func:`predict`'s of ``sets[k]`` at the lowest threshold. The sets
    are validation sets: never the buildings the model is judged on.
    """
    rows = []
    for t in thresholds:
        total = Counts()
        for preds, data in zip(predictions, sets, strict=True):
            total.add(score(preds, data, conf=t, match=match)["all"])
        rows.append((t, total))
    best = max(rows, key=lambda r: f1(r[1]))[0]
    return best, rows


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
      reference: what a perfect mask gives);
    * ``"on_object"``: the share of the detection's points on that instance (not a distance:
      what of a network mask's bleed onto the wall, the floor or a neighbour survives the 3-D step).
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
                e = out.setdefault(d.class_name, {"mask": [], "object": [], "exact": [], "on_object": []})
                e["mask"].append(float(np.linalg.norm(d.centroid_cam - c)))
                e["object"].append(float(np.linalg.norm(d.centroid_cam - o)))
                e["exact"].append(float(np.linalg.norm(c - o)))
                e["on_object"].append(points_on_instance(d.points_cam, cam.K, r.instance, iid))
    return {k: {m: np.array(v) for m, v in e.items()} for k, e in out.items()}


def points_on_instance(points_cam: np.ndarray, K: np.ndarray, instance: np.ndarray, iid: int) -> float:
    """The share of camera-frame points whose pixel in the ``instance`` image is instance ``iid``.

    The points are back-projected depth pixels (pixel centres), so projecting them again finds
    their own pixels.
    """
    if len(points_cam) == 0:
        return 0.0
    uvw = points_cam @ np.asarray(K, dtype=float).T
    u = np.clip(np.rint(uvw[:, 0] / uvw[:, 2]).astype(int), 0, instance.shape[1] - 1)
    v = np.clip(np.rint(uvw[:, 1] / uvw[:, 2]).astype(int), 0, instance.shape[0] - 1)
    return float(np.mean(instance[v, u] == iid))


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


def _size_table(results: dict[tuple[str, str], dict[str, Counts]]) -> str:
    edges = (0, 400, 1600, 6400)
    heads = [f"recall, {lo}–{hi} px" for lo, hi in zip(edges, edges[1:], strict=False)] + [
        f"recall, {edges[-1]}+ px"
    ]
    lines = ["| frames | match | " + " | ".join(heads) + " |", "|---|---|" + "---:|" * len(edges)]
    for (res, match), per in results.items():
        cells = [f"{r:.2f} ({n})" for _, n, r in per["all"].recall_by_size(edges)]
        lines.append(f"| {res} | {match} IoU ≥ 0.5 | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _seeds(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds: comma-separated integers, got {text!r}") from None


def _sizes(text: str) -> tuple[tuple[int, int], ...]:
    """``--sizes``: ``WxH,...`` as ((W, H), ...)."""
    try:
        sizes = [tuple(int(v) for v in spec.split("x")) for spec in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or any(len(wh) != 2 or min(wh) < 1 for wh in sizes):
        raise argparse.ArgumentTypeError(f"WxH,... such as 320x240,640x480, got {text!r}")
    return tuple((w, h) for w, h in sizes)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--frames", type=positive_int, default=40, help="frames per held-out building")
    ap.add_argument("--conf", type=float, default=0.25)
    ap.add_argument("--sizes", type=_sizes, default="320x240,640x480", help="image sizes to render, WxH,...")
    ap.add_argument(
        "--seeds",
        type=_seeds,
        default=HELDOUT_SEEDS,
        help="procedural buildings, comma-separated (default: the held-out "
        f"{','.join(map(str, HELDOUT_SEEDS))}; none: '')",
    )
    ap.add_argument(
        "--world",
        type=Path,
        action="append",
        default=[],
        help="also a mesh world (a folder written by `amslam world import`, e.g. "
        "/work/shared/worlds/small_house); its objects of other classes are background. Repeatable",
    )
    ap.add_argument(
        "--choose-threshold",
        action="store_true",
        help="on these frames (a validation set, not the test buildings!): precision, recall and F1 "
        "(320×240, box IoU ≥ 0.5, all classes) per confidence threshold, and the best",
    )
    ap.add_argument("--centroids", action="store_true", help="also: centroid errors (masks, centres)")
    return ap


def parse_arguments(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line's arguments, checked before any frame is rendered (exit status 2 otherwise)."""
    from amslam.plugins.onnx_detector.detector import shipped_model

    ap = _parser()
    args = ap.parse_args(argv)
    for folder in args.world:
        if not (folder / "world.ply").is_file():
            ap.error(f"--world {folder}: no world.ply there (a folder written by `amslam world import`)")
    if not args.seeds and not args.world:
        ap.error("nothing to evaluate: --seeds '' and no --world")
    if not 0.0 < args.conf < 1.0:
        ap.error(f"--conf {args.conf}: a class score threshold, between 0 and 1")
    if args.choose_threshold and (320, 240) not in args.sizes:
        ap.error("--choose-threshold scores the 320×240 frames: --sizes must hold 320x240")
    if args.centroids and not args.seeds:
        ap.error("--centroids renders procedural buildings: not with --seeds ''")
    model = args.model or shipped_model()
    try:
        check_classes(inspect_model(model), CLASSES)
    except ValueError as exc:  # ModelError too: missing, unreadable, not the YOLOv8-seg layout
        ap.error(f"--model {model}: {exc}")
    return args


def _render_sets(args: argparse.Namespace) -> dict[str, Dataset]:
    """The frames to evaluate on, by ``"W×H, seeds"`` or ``"W×H, <mesh world>"``."""
    sets: dict[str, Dataset] = {}
    for w, h in args.sizes:
        if args.seeds:
            sets[f"{w}×{h}, seeds"] = render_dataset(list(args.seeds), args.frames, width=w, height=h)
        for folder in args.world:
            sets[f"{w}×{h}, {folder.name}"] = render_dataset(
                [], 0, width=w, height=h, mesh_worlds=(folder,), mesh_frames=args.frames
            )
    return sets


def _threshold_table(keys: list[str], best: float, rows: list[tuple[float, Counts]]) -> str:
    """:func:`choose_threshold`'s result on the sets ``keys``, as a titled markdown table."""
    lines = [
        f"Confidence threshold on {', '.join(keys)} (box IoU ≥ 0.5, all classes):",
        "",
        "| threshold | detections | precision | recall | F1 |",
        "|---:|---:|---:|---:|---:|",
    ]
    for t, c in rows:
        mark = " **best**" if t == best else ""
        lines.append(f"| {t:.2f}{mark} | {c.tp + c.fp} | {c.precision:.3f} | {c.recall:.3f} | {f1(c):.3f} |")
    return "\n".join(lines)


def _centroid_table(errors: dict[str, dict[str, np.ndarray]]) -> str:
    """:func:`centroid_errors`, as a titled markdown table."""
    lines = [
        "Centroid of each detection (320×240, m) against the exact mask's centroid, against the",
        "object's true centre, and the exact mask's centroid against the true centre:",
        "",
        "| class | detections | reference | median | 75th percentile | 90th percentile | mean |",
        "|---|---:|---|---:|---:|---:|---:|",
    ]
    refs = {
        "mask": "onnx − exact mask",
        "object": "onnx − object centre",
        "exact": "exact mask − object centre",
    }
    for name, e in sorted(errors.items()):
        for key, label in refs.items():
            q = np.percentile(e[key], [50, 75, 90])
            lines.append(
                f"| {name} | {len(e[key])} | {label} | {q[0]:.3f} | {q[1]:.3f} | {q[2]:.3f} "
                f"| {e[key].mean():.3f} |"
            )
    lines += [
        "",
        "Share of each detection's points on its object (the rest: wall, floor or a neighbour the",
        "mask bled onto and the 3-D step kept):",
        "",
        "| class | detections | mean | 10th percentile | detections under 90 % |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, e in sorted(errors.items()):
        on = e["on_object"]
        low = np.percentile(on, 10)
        lines.append(f"| {name} | {len(on)} | {on.mean():.3f} | {low:.3f} | {np.mean(on < 0.9):.3f} |")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> None:
    """Render the frames, run the model, print the tables; ``args`` as :func:`parse_arguments` gives them."""
    from amslam.plugins.onnx_detector.detector import shipped_model

    model_path = args.model or shipped_model()
    model = SegmentationModel(model_path)
    sets = _render_sets(args)
    # one run of the network per frame; a threshold search scores the same predictions at each threshold
    lowest = min(args.conf, THRESHOLDS[0]) if args.choose_threshold else args.conf
    predictions = {key: predict(model, data, conf=lowest) for key, data in sets.items()}
    results = {
        (f"{key}, {len(data)}", match): score(predictions[key], data, conf=args.conf, match=match)
        for key, data in sets.items()
        for match in ("mask", "box")
    }
    where = [f"seeds {list(args.seeds)}"] if args.seeds else []
    where += [str(f) for f in args.world]
    print(f"model {model_path}, {', '.join(where)}, conf {args.conf}")
    print(table(results))
    print()
    print("Recall by object size (visible pixels, scaled to a 320×240 image; instances in brackets):")
    print()
    print(_size_table(results))
    if args.choose_threshold:
        keys = [k for k in sets if k.startswith("320×240")]
        best, rows = choose_threshold([predictions[k] for k in keys], [sets[k] for k in keys], THRESHOLDS)
        print()
        print(_threshold_table(keys, best, rows))
    if args.centroids:
        errors = centroid_errors(model_path, tuple(args.seeds), args.frames)
        print()
        print(_centroid_table(errors))


def main(argv: list[str] | None = None) -> None:
    """Command line: render the held-out frames, run the model, print the tables."""
    args = parse_arguments(argv)
    try:
        run(args)
    except AmslamError as exc:  # a mesh world that cannot be read, or without room to fly
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
