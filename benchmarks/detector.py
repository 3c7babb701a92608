"""Detector benchmark: ms per frame of the ``onnx`` detector next to the ``sim`` detector.

One frame of the default procedural building is rendered from a furnished room's doorway side
(640×480 by default, the D435i's resolution; 320×240 is the demo camera), then each detector's
``detect()`` is timed (best of ``--repeats``). The ``onnx`` detector's time is split into its
stages: letterbox (resize + blob), the network (onnxruntime, ``threads`` intra-op threads), the
decoding (threshold, NMS, masks) and the 3-D step (depth clustering, back-projection, centroid).
The reference is the ``sim`` detector on the same frame, measured in the same run: it reads the
simulator's masks and performs the same 3-D step, so the ratio is what running a network costs.
The last column is the share of one CPU core the detector takes at its rate (2 Hz, paper 1).

Run: ``.venv/bin/python benchmarks/detector.py [--size 640x480] [--repeats 20] [--model FILE]``.

``--compare RUN_DIR...`` instead prints the semantic maps of finished simulator runs next to each
other (e.g. ``amslam run demo`` and ``amslam run missions/demo_onnx.yaml``): landmark count, and
for chairs and for all classes the landmarks paired one-to-one with the world's objects within
1 m (``amslam.apps.report.landmark_accuracy``), their mean distance to the true object centres, the
matched fraction (paired / landmarks) and the objects mapped (paired / objects in the world). The
world is rebuilt from the run's ``mission.yaml`` and seed, as the runner built it.

``--objects RUN_DIR...`` says where a run's objects of one class (``--class``, default chair) are
lost, from its measurement log (detections with the true key poses) and its landmarks: each
object is *never in view* (never 60 px at 640×480, scaled, within 5 m from any key pose, rendered
from the true pose), *in view, never detected* (no detection of its class within 0.5 m of it),
*detected, no landmark* (detections, but no landmark within 0.5 m), or mapped (a landmark within
0.5 m). The last column counts same-class landmark pairs closer than 0.5 m: duplicates, as no two
objects are that close.

``--replay RUN_DIR...`` feeds each run's logged detections, frame by frame, through a fresh SLAM
front end (``GtsamSlam``, default parameters, no loop closure), once with the true key poses and
once with the VIO ones: what the detections make of the map without drift, and with it.
``--openloop RUN_DIR... --detectors sim onnx[:key=value,...]`` re-renders the run's detection
key poses from their true poses, runs each detector on them and feeds the front end (true poses,
no loop closure): detectors compared on one trajectory, without the flights diverging.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import yaml

from amslam.apps.report import landmark_accuracy
from amslam.interfaces import BACKEND_KINDS, RunContext
from amslam.measurements import read_measurements
from amslam.plugins.onnx_detector.decoder import decode, letterbox
from amslam.plugins.onnx_detector.detector import OnnxDetector
from amslam.plugins.sim.camera import viewing_pose
from amslam.plugins.sim.detector import SimDetector
from amslam.plugins.sim.platform import SimPlatform
from amslam.types import Frame, Landmark, RobotSpec, WorldSummary


def _best_ms(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def _frame(width: int, height: int) -> Frame:
    plat = SimPlatform()
    params = SimPlatform.Params(camera={"width": width, "height": height})
    plat.configure(params, RunContext(rng=np.random.default_rng(7), run_dir=Path(".")))
    plat.start()
    world = plat.world
    chairs = [o for o in world.objects if o.class_name == "chair"]
    target = max(chairs, key=lambda o: sum(np.linalg.norm(o.centroid - p.centroid) < 3 for p in chairs))
    T_wc = viewing_pose(world, target.centroid, plat.camera.T_body_cam, distance=2.5)
    r = plat._renderer.render(world, T_wc, np.random.default_rng(0))
    cam = plat.camera
    return Frame(1.0, r.depth, cam.K.copy(), T_wc, r.rgb, r.instance, r.class_id, world.class_names, T_wc)


def _run_world(run_dir: Path) -> WorldSummary:
    """The world of a simulator run, rebuilt from its mission and seed as the runner does."""
    return _run_platform(run_dir).world_summary()


def _run_platform(run_dir: Path) -> SimPlatform:
    """The simulator of a run (world and camera), rebuilt from its mission and seed as the runner does."""
    mission = yaml.safe_load((run_dir / "mission.yaml").read_text())
    section = {k: v for k, v in mission["platform"].items() if k != "plugin"}
    seed = np.random.SeedSequence(mission["seed"]).spawn(len(BACKEND_KINDS))[0]
    plat = SimPlatform()
    known = {f.name for f in dataclasses.fields(RobotSpec)}  # the mission's robot section has more (base)
    robot = RobotSpec(**{k: v for k, v in mission["robot"].items() if k in known})
    plat.configure(
        SimPlatform.Params.model_validate(section),
        RunContext(rng=np.random.default_rng(seed), run_dir=run_dir, robot=robot),
    )
    plat.start()
    return plat


def compare(run_dirs: list[Path]) -> None:
    """Print the semantic maps of finished runs side by side (see the module docstring)."""
    print(
        "| run | detector | verdict | landmarks | classes | objects | paired ≤ 1 m | mean distance, m "
        "| matched fraction | objects mapped |"
    )
    print("|---|---|---|---:|---|---:|---:|---:|---:|---:|")
    for run in run_dirs:
        metrics = json.loads((run / "metrics.json").read_text())
        raw = json.loads((run / "landmarks.json").read_text())
        lms = [
            Landmark(
                d["id"], d["class"], np.asarray(d["position"]), np.asarray(d["covariance"]), d["observations"]
            )
            for d in raw
        ]
        world = _run_world(run)
        assert world.objects_by_class == metrics["landmarks"]["objects_in_world"], "world rebuilt differently"
        for label, classes in (("chair", {"chair"}), ("all", None)):
            keep = [k for k, c in world.object_classes.items() if classes is None or c in classes]
            sub = WorldSummary(
                world.name, world.bounds_lo, world.bounds_hi, 0.0, world.floor_heights, (), {},
                object_positions={k: world.object_positions[k] for k in keep},
                object_classes={k: world.object_classes[k] for k in keep},
            )  # fmt: skip
            mine = [lm for lm in lms if classes is None or lm.class_name in classes]
            acc = landmark_accuracy(mine, sub)
            err = acc.get("mean_error_m")
            det = metrics["plugins"]["detector"]
            print(
                f"| {run.name} | {det} | {metrics['verdict']} | {len(mine)} | {label} | {len(keep)}"
                f" | {acc['matched']} | {err if err is not None else float('nan'):.3f} "
                f"| {acc['matched'] / max(len(mine), 1):.2f} | {acc['matched'] / max(len(keep), 1):.2f} |"
            )


def objects(run_dirs: list[Path], class_name: str = "chair", near: float = 0.5) -> None:
    """Where a run's objects of one class are lost (see the module docstring)."""
    print(
        f"| run | {class_name}s | never in view | in view, never detected | detected, no landmark "
        f"| landmark ≤ {near} m | duplicate landmark pairs < {near} m |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    details = []
    for run in run_dirs:
        plat = _run_platform(run)
        world = plat.world
        objs = [o for o in world.objects if o.class_name == class_name]
        log = read_measurements(run)
        if log.truth is None:
            raise SystemExit(f"{run}: the measurement log has no true poses (not a simulator run)")
        T_bc = plat.camera.T_body_cam
        rng = np.random.default_rng(0)
        seen = np.zeros(len(objs), bool)
        closest = np.full(len(objs), np.inf)
        min_px = max(1, round(60 * plat.camera.width * plat.camera.height / (640 * 480)))
        for T_wb in log.truth:  # every key pose's view, rendered from the true pose
            T_wc = T_wb @ T_bc
            r = plat._renderer.render(world, T_wc, rng)
            ids, counts = np.unique(r.instance, return_counts=True)
            px = dict(zip(ids.tolist(), counts.tolist(), strict=True))
            for k, o in enumerate(objs):
                if px.get(o.instance_id, 0) >= min_px:
                    rng_m = float(np.linalg.norm(o.centroid - T_wc[:3, 3]))
                    if rng_m <= 5.0:  # the detectors' depth range
                        seen[k] = True
                        closest[k] = min(closest[k], rng_m)
        C = np.array([o.centroid for o in objs])
        hits = np.zeros(len(objs), int)
        for d in log.detections:
            if d.class_name != class_name:
                continue
            T = log.truth[d.keypose]
            dist = np.linalg.norm(C - (T[:3, :3] @ d.p_body + T[:3, 3]), axis=1)
            if dist.min() <= near:
                hits[int(dist.argmin())] += 1
        lms = [d for d in json.loads((run / "landmarks.json").read_text()) if d["class"] == class_name]
        L = np.array([d["position"] for d in lms]).reshape(-1, 3)
        mapped = np.array([len(L) > 0 and np.linalg.norm(L - c, axis=1).min() <= near for c in C])
        dl = np.linalg.norm(L[:, None] - L[None], axis=2) + np.eye(len(L)) * 1e9
        dups = int(np.triu(dl < near).sum())
        never = ~seen & (hits == 0) & ~mapped
        missed = seen & (hits == 0) & ~mapped
        lost = (hits > 0) & ~mapped
        counts = (len(objs), never.sum(), missed.sum(), lost.sum(), mapped.sum(), dups)
        print(f"| {run.name} | " + " | ".join(str(int(c)) for c in counts) + " |")
        listed = {
            label: ", ".join(f"{objs[k].name} ({closest[k]:.1f} m, {hits[k]})" for k in np.flatnonzero(sel))
            for label, sel in (("in view, never detected", missed), ("detected, no landmark", lost))
        }
        for label, text in listed.items():
            details.append(f"{run.name}: {label}: {text or '-'}")
    print()
    print("(object (closest range in view, detections within the radius))")
    for line in details:
        print(line)


def _chair_summary(lms: list[Landmark], world: WorldSummary, class_name: str) -> str:
    """Landmarks of a class, paired (≤ 1 m) and their mean distance, and duplicate pairs (< 0.5 m)."""
    keep = [k for k, c in world.object_classes.items() if c == class_name]
    sub = WorldSummary(
        world.name, world.bounds_lo, world.bounds_hi, 0.0, world.floor_heights, (), {},
        object_positions={k: world.object_positions[k] for k in keep},
        object_classes={k: world.object_classes[k] for k in keep},
    )  # fmt: skip
    mine = [lm for lm in lms if lm.class_name == class_name]
    acc = landmark_accuracy(mine, sub)
    P = np.array([lm.position for lm in mine]).reshape(-1, 3)
    dl = np.linalg.norm(P[:, None] - P[None], axis=2) + np.eye(len(P)) * 1e9
    err = acc.get("mean_error_m")
    return (
        f"{len(mine)} | {acc['matched']} | {err if err is not None else float('nan'):.3f} "
        f"| {int(np.triu(dl < 0.5).sum())}"
    )


def _slam():
    from amslam.plugins.gtsam_slam.backend import GtsamSlam

    slam = GtsamSlam()
    slam.configure(GtsamSlam.Params(), RunContext(rng=np.random.default_rng(0), run_dir=Path(".")))
    return slam


def replay(run_dirs: list[Path], class_name: str = "chair") -> None:
    """Each run's logged detections through the SLAM front end, frame by frame, no loop closure."""
    from amslam.measurements import pose_from_list
    from amslam.types import Detection, Odometry

    print(f"| run | poses | {class_name} landmarks | paired ≤ 1 m | mean distance, m | pairs < 0.5 m |")
    print("|---|---|---:|---:|---:|---:|")
    for run in run_dirs:
        world = _run_world(run)
        records = [json.loads(line) for line in (run / "measurements.jsonl").read_text().splitlines()]
        for truth in (True, False):
            slam, kps = _slam(), {}
            for r in records:
                if r["type"] == "keypose":
                    T = pose_from_list(r["truth"] if truth else r["T_odom_body"])
                    kps[r["id"]] = T
                    slam.add_odometry(Odometry(r["t"], T))
                elif r["type"] == "detections":  # one frame: detections in the key pose's body frame
                    dets = [
                        Detection(o["class"], o["confidence"], np.asarray(o["p_body"], float))
                        for o in r["objects"]
                    ]
                    slam.add_detections(Odometry(r["t"], kps[r["keypose"]]), np.eye(4), dets)
            label = "true" if truth else "VIO"
            print(f"| {run.name} | {label} | {_chair_summary(slam.landmarks(), world, class_name)} |")


def openloop(run_dirs: list[Path], specs: list[str], class_name: str = "chair") -> None:
    """Re-render each run's detection key poses from the true pose, detect, feed the SLAM front end."""
    from amslam.types import Odometry

    print(
        f"| run | detector | detections | {class_name} landmarks | paired ≤ 1 m | mean distance, m "
        "| pairs < 0.5 m |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for run in run_dirs:
        plat = _run_platform(run)
        world, cam = plat.world_summary(), plat.camera
        log = read_measurements(run)
        if log.truth is None:
            raise SystemExit(f"{run}: the measurement log has no true poses (not a simulator run)")
        rng = np.random.default_rng(1)
        frames = []
        for k in sorted({d.keypose for d in log.detections}):
            T_wc = log.truth[k] @ cam.T_body_cam
            r = plat._renderer.render(plat.world, T_wc, rng)
            frames.append(
                Frame(float(log.stamps[k]), r.depth, cam.K.copy(), T_wc, r.rgb, r.instance, r.class_id,
                      plat.world.class_names, T_wc)
            )  # fmt: skip
        for spec in specs:  # "sim" or "onnx[:key=value,...]"
            name, _, rest = spec.partition(":")
            kw = {
                k: yaml.safe_load(v)
                for k, v in (item.split("=", 1) for item in filter(None, rest.split(",")))
            }
            det = SimDetector() if name == "sim" else OnnxDetector()
            ctx = RunContext(rng=np.random.default_rng(5), run_dir=Path("."), camera=cam, world=world)
            det.configure(type(det).Params(**kw), ctx)
            slam, n = _slam(), 0
            for f in frames:
                dets = det.detect(f)
                n += len(dets)
                odom = Odometry(f.stamp, f.T_odom_cam @ np.linalg.inv(cam.T_body_cam))
                slam.add_odometry(odom)
                slam.add_detections(odom, cam.T_body_cam, dets)
            print(f"| {run.name} | {spec} | {n} | {_chair_summary(slam.landmarks(), world, class_name)} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="640x480", help="image WxH")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    ap.add_argument("--compare", type=Path, nargs="+", help="run folders to compare instead")
    ap.add_argument("--objects", type=Path, nargs="+", help="run folders: where their objects are lost")
    ap.add_argument("--replay", type=Path, nargs="+", help="run folders: their logs through the SLAM")
    ap.add_argument("--openloop", type=Path, nargs="+", help="run folders: re-render, detect, SLAM")
    ap.add_argument(
        "--detectors", nargs="+", default=["sim", "onnx"], help="for --openloop: sim, onnx[:key=value,...]"
    )
    ap.add_argument("--class", dest="class_name", default="chair", help="class for --objects etc.")
    args = ap.parse_args()
    if args.replay:
        replay(args.replay, args.class_name)
        return
    if args.openloop:
        openloop(args.openloop, args.detectors, args.class_name)
        return
    if args.compare:
        compare(args.compare)
        return
    if args.objects:
        objects(args.objects, args.class_name)
        return
    w, h = (int(v) for v in args.size.split("x"))
    frame = _frame(w, h)
    ctx = RunContext(rng=np.random.default_rng(0), run_dir=Path("."))

    sim = SimDetector()
    sim.configure(SimDetector.Params(miss_probability=0.0, false_positive_rate=0.0), ctx)
    ref = _best_ms(lambda: sim.detect(frame), args.repeats)

    print(f"frame {w}×{h}, {len(np.unique(frame.instance)) - 1} objects in view; best of {args.repeats}")
    print()
    print("| figure | ms | reference: sim detector, ms | ratio | CPU share at 2 Hz |")
    print("|---|---:|---:|---:|---:|")
    for threads in (1, 2):
        n, rows, input_hw = _onnx_rows(frame, ctx, args.model, threads, args.repeats)
        plural = "s" if threads > 1 else ""
        for name, ms, share in rows:
            label = f"onnx {name}, {input_hw[1]}×{input_hw[0]} input, {threads} thread{plural}"
            share_s = f"{100 * share:.1f} %" if share is not None else ""
            print(f"| {label} | {ms:.2f} | {ref:.2f} | {ms / ref:.1f} | {share_s} |")
        print(f"| onnx detections in the frame ({threads} thread{plural}) | {n} | | | |")


def _onnx_rows(frame: Frame, ctx: RunContext, model_path: str | None, threads: int, repeats: int):
    """(detections, [(stage, ms, CPU share or None)], input size) of the onnx detector."""
    det = OnnxDetector()
    det.configure(OnnxDetector.Params(model=model_path, threads=threads), ctx)
    model, p = det.model, det.params
    n = len(det.detect(frame))
    blob, lb = letterbox(frame.rgb, model.info.input_hw)
    feeds = {model.info.input_name: blob}
    out0, out1 = model.session.run(None, feeds)[:2]
    total = _best_ms(lambda: det.detect(frame), repeats)
    rows = [
        ("letterbox", _best_ms(lambda: letterbox(frame.rgb, model.info.input_hw), repeats), None),
        ("network (onnxruntime)", _best_ms(lambda: model.session.run(None, feeds), repeats), None),
        (
            "decode (NMS + masks)",
            _best_ms(lambda: decode(out0, out1, lb, conf=p.confidence, iou=p.iou), repeats),
            None,
        ),
        ("detect() total", total, total * det.rate_hz / 1e3),
    ]
    det.close()
    return n, rows, model.info.input_hw


if __name__ == "__main__":
    main()
