"""What bounds SLAM's error and the object map's: flights re-solved offline with one thing changed.

Each flight's measurement log (``measurements.jsonl``: VIO key poses, detections with their object
points) is solved again through the onboard front end and factor graph — the base merge with one
robot (:func:`amslam.plugins.gtsam_slam.merge.merge_measurements`) — with the flight's own SLAM
parameters (its ``mission.yaml``), in seconds instead of a flight's minutes, and with variants:

* ``--models``: landmark models, e.g. ``centroid``, ``cuboid``, ``"chair=cuboid,*=centroid"``;
* ``--odometry true``: the true key poses as the odometry (what the landmarks do to a perfect
  trajectory: the map's error that is the landmark model's alone);
* ``--points true-surface``: every detection's points moved onto the surface of its true object's
  box, from the same views (a perfect depth sensor and mask: the landmark model's best case);
* ``--depth-noise K``: the camera's depth noise coefficient the cuboid classes' boxes (cars) are
  fitted past (``CameraModel.depth_noise``; ``logged``: the log's own, 0 in logs written before
  it had one);
* ``--set KEY=VALUE``: the flight's parameters overridden, as missions spell them
  (``slam.shapes.window=6``, ``slam.graph.robust=cauchy``);
* ``--drop-unknown-keys``: a flight of an older version, whose ``mission.yaml`` names parameters
  since renamed or removed, re-solved without them (refused otherwise, naming them).

Per flight and variant it prints VIO's and the re-solved trajectory's position error against the
truth at the key poses (RMS, at the end) and the largest yaw error, then the landmarks as the
flights' ``metrics.json`` scores them (:func:`amslam.apps.report.landmark_accuracy`): objects
mapped, duplicates, spurious, mean error and the error about the map's shift; then mean ± std per
variant over the flights.

What a re-solve is not: no semantic loop closure (a panorama's matches are not logged), and
duplicates are fused after the solve by the merge's rounds rather than after each loop closure;
a log keeps 128 points per detection where the onboard front end had all of them. Compare
variants with each other, not with the flights' own figures. The ``true`` variants and the
scores read the simulator's ground truth: they measure the system, like the metrics; no backend
sees them.

    .venv/bin/python benchmarks/slam_offline.py runs/calibrate-one_floor-... --models centroid --models cuboid
    .venv/bin/python benchmarks/slam_offline.py RUN_DIR --models cuboid --odometry logged,true
    .venv/bin/python benchmarks/slam_offline.py RUN_DIR --models cuboid --set slam.shapes.decorrelate=false
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from amslam.apps.tables import mean_std
from amslam.geometry import invert, transform_points, wrap_angle
from amslam.lib.shapes import cuboid_pose
from amslam.measurements import RobotMeasurements, read_measurements
from amslam.types import WorldSummary

ODOMETRY = ("logged", "true")
POINTS = ("logged", "true-surface")


class OfflineError(Exception):
    """A flight or an option that cannot be re-solved: the message names which and why."""


def parse_models(spec: str) -> dict[str, str]:
    """``cuboid`` → every class; ``chair=cuboid,*=centroid`` → per class (``*``: the others)."""
    spec = spec.strip()
    if "=" not in spec:
        return {"*": spec}
    out = {}
    for part in spec.split(","):
        cls, sep, model = part.partition("=")
        if not sep or not cls.strip() or not model.strip():
            raise OfflineError(f"--models {spec!r}: {part!r} is not CLASS=MODEL")
        out[cls.strip()] = model.strip()
    return out


def flight_dirs(paths: list[Path]) -> list[Path]:
    """The run folders among ``paths``: each one itself, or the run folders under it."""
    out: list[Path] = []
    for p in paths:
        if (p / "measurements.jsonl").is_file():
            out.append(p)
            continue
        found = sorted(f.parent for f in p.rglob("measurements.jsonl")) if p.is_dir() else []
        if not found:
            raise OfflineError(f"{p}: no run folder (measurements.jsonl) there")
        out += found
    return out


def with_true_odometry(log: RobotMeasurements) -> RobotMeasurements:
    """The log with its true key poses as the VIO (odometry frame = world frame)."""
    truth = np.asarray(log.truth, float)
    rel = [np.eye(4)] + [invert(a) @ b for a, b in zip(truth[:-1], truth[1:], strict=True)]
    return dataclasses.replace(log, T_odom_body=truth.copy(), rel=np.array(rel), T_world_odom=np.eye(4))


def with_true_surface_points(log: RobotMeasurements, world: WorldSummary) -> RobotMeasurements:
    """Each detection's points moved onto the nearest face of its true object's box.

    The object is the true box of the detection's class nearest the points' centroid (seen from
    the true key pose); points of a detection with no such box stay as logged (a false positive
    keeps its patch). The centroid becomes the moved points' median, as the detectors take it.
    """
    boxes = [(oid, s) for oid, s in world.object_shapes.items() if s.get("model") == "cuboid"]
    by_class: dict[str, list[dict]] = {}
    for oid, s in boxes:
        by_class.setdefault(world.object_classes.get(oid, ""), []).append(s)
    out = []
    for d in log.detections:
        pts = np.asarray(d.points, float).reshape(-1, 3)
        shapes_of_class = by_class.get(d.class_name)
        if not len(pts) or not shapes_of_class:
            out.append(d)
            continue
        T = log.truth[d.keypose]
        world_pts = transform_points(T, pts)
        centre = np.median(world_pts, axis=0)
        box = min(shapes_of_class, key=lambda s: float(np.linalg.norm(np.asarray(s["center"]) - centre)))
        B, half = cuboid_pose(box), np.asarray(box["dims"], float) / 2
        local = np.clip((world_pts - B[:3, 3]) @ B[:3, :3], -half, half)
        axis = np.argmin(half - np.abs(local), axis=1)  # the nearest face of each point
        rows = np.arange(len(local))
        local[rows, axis] = np.where(local[rows, axis] >= 0, 1.0, -1.0) * half[axis]
        body = transform_points(invert(T), local @ B[:3, :3].T + B[:3, 3])
        out.append(dataclasses.replace(d, points=body, p_body=np.median(body, axis=0)))
    return dataclasses.replace(log, detections=out)


def trajectory_errors(poses: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Position error at every key pose (RMS, at the end) and the largest yaw error (degrees)."""
    d = np.linalg.norm(poses[:, :3, 3] - truth[:, :3, 3], axis=1)
    yaw = np.arctan2(poses[:, 1, 0], poses[:, 0, 0]) - np.arctan2(truth[:, 1, 0], truth[:, 0, 0])
    return {
        "rms_m": round(float(np.sqrt(np.mean(d**2))), 4),
        "end_m": round(float(d[-1]), 4),
        "max_yaw_deg": round(float(np.degrees(np.max(np.abs(wrap_angle(yaw))))), 3),
    }


def load_flight_mission(
    run_dir: Path, sets: list[str], registry: Any, drop_unknown_keys: bool = False
) -> Any:
    """The flight's ``mission.yaml`` with ``sets`` applied. A flight of an older version may name
    parameters since renamed or removed: refused, naming them, unless ``drop_unknown_keys``, which
    leaves them out (the re-solve then uses today's defaults for what replaced them) and says so."""
    from amslam.errors import MissionError
    from amslam.mission import load_mission

    overrides = ["slam.plugin=gtsam", *sets]
    try:
        return load_mission(str(run_dir / "mission.yaml"), registry, overrides)
    except MissionError as exc:
        only_unknown = exc.unknown_keys and len(exc.unknown_keys) == len(exc.problems)
        if not (drop_unknown_keys and only_unknown):
            hint = " (a flight of an older version: --drop-unknown-keys re-solves it without them)"
            raise OfflineError(f"{run_dir}: {exc}{hint if only_unknown else ''}") from exc
        print(
            f"{run_dir.name}: left out {', '.join(exc.unknown_keys)} (unknown to this version)",
            file=sys.stderr,
        )
        try:
            return load_mission(str(run_dir / "mission.yaml"), registry, overrides, unset=exc.unknown_keys)
        except MissionError as again:
            raise OfflineError(f"{run_dir}: {again}") from again


def resolve(
    run_dir: Path,
    models: str,
    odometry: str,
    points: str,
    sets: list[str],
    registry: Any,
    drop_unknown_keys: bool = False,
    depth_noise: str = "logged",
) -> dict[str, Any]:
    """One flight re-solved in one variant: its trajectory's and its landmarks' errors."""
    from amslam.apps.multirobot import run_world
    from amslam.apps.report import landmark_accuracy
    from amslam.plugins.gtsam_slam.merge import MergeParams, chain_from_base, merge_measurements

    mission = load_flight_mission(run_dir, sets, registry, drop_unknown_keys)
    slam = mission.backends["slam"].params
    try:
        params = MergeParams(
            graph=slam.graph,
            association=slam.association,
            landmark_models=parse_models(models),
            shapes=slam.shapes,
            object_map=slam.object_map,  # the objects reported as the flight reported them
            object_twin_margin=slam.object_twin_margin,
            object_twin_share=slam.object_twin_share,
            object_trim_spreads=slam.object_trim_spreads,
        )
    except ValueError as exc:
        raise OfflineError(f"--models {models!r}: {exc}") from exc
    log = read_measurements(run_dir)
    if depth_noise != "logged":
        log = dataclasses.replace(log, depth_noise=float(depth_noise))
    if log.truth is None:
        raise OfflineError(f"{run_dir}: its log has no true key poses (a real flight): nothing to score")
    world = run_world(run_dir, registry, mission)
    vio = trajectory_errors(chain_from_base(log), log.truth)
    if odometry == "true":
        log = with_true_odometry(log)
    if points == "true-surface":
        log = with_true_surface_points(log, world)
    result = merge_measurements([log], params)
    acc = landmark_accuracy(result.landmarks, world)
    return {
        "run_dir": str(run_dir),
        "variant": {
            "models": models,
            "odometry": odometry,
            "points": points,
            "depth_noise": depth_noise,
            "set": sets,
        },
        "vio": vio,
        "slam": trajectory_errors(result.trajectories[0], log.truth),
        "objects": acc.get("objects", 0),
        "mapped": acc.get("matched", 0),
        "landmarks": len(result.landmarks),
        "duplicates": acc.get("duplicates", 0),
        "spurious": acc.get("spurious", 0),
        "mean_error_m": acc.get("mean_error_m"),
        "error_about_offset_m": acc.get("error_about_offset_m"),
        "by_class": {c: (row["matched"], row["mean_error_m"]) for c, row in acc.get("by_class", {}).items()},
    }


def variant_name(v: dict[str, Any]) -> str:
    parts = [v["models"]]
    if v["odometry"] != "logged":
        parts.append(f"odometry {v['odometry']}")
    if v["points"] != "logged":
        parts.append(f"points {v['points']}")
    if v.get("depth_noise", "logged") != "logged":
        parts.append(f"depth noise {v['depth_noise']}")
    return ", ".join(parts + list(v["set"]))


#: The summary's columns: heading, the figure of one flight, decimals.
SUMMARY_COLUMNS = (
    ("SLAM RMS (m)", lambda r: r["slam"]["rms_m"], 3),
    ("SLAM end (m)", lambda r: r["slam"]["end_m"], 3),
    ("VIO RMS (m)", lambda r: r["vio"]["rms_m"], 3),
    ("mapped %", lambda r: 100 * r["mapped"] / max(r["objects"], 1), 1),
    ("duplicates % of objects", lambda r: 100 * r["duplicates"] / max(r["objects"], 1), 1),
    ("mean error (m)", lambda r: r["mean_error_m"], 3),
    ("about the shift (m)", lambda r: r["error_about_offset_m"], 3),
)


def table(rows: list[dict[str, Any]]) -> str:
    """Per flight and variant, then mean ± std per variant over the flights."""
    head = (
        "| flight | variant | VIO RMS / end (m) | SLAM RMS / end (m) | max yaw err (°) | mapped | duplicates"
        " | spurious | mean error (m) | about the shift (m) |"
    )
    lines = [head, "|---" * 10 + "|"]
    for r in rows:
        vio, slam = r["vio"], r["slam"]
        lines.append(
            f"| {Path(r['run_dir']).name} | {variant_name(r['variant'])} | {vio['rms_m']:.3f} / "
            f"{vio['end_m']:.3f} | {slam['rms_m']:.3f} / {slam['end_m']:.3f} | {slam['max_yaw_deg']:.1f} | "
            f"{r['mapped']} / "
            f"{r['objects']} | {r['duplicates']} | {r['spurious']} | {_num(r['mean_error_m'])} | "
            f"{_num(r['error_about_offset_m'])} |"
        )
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(variant_name(r["variant"]), []).append(r)
    lines += ["", "| variant | flights | " + " | ".join(c[0] for c in SUMMARY_COLUMNS) + " |"]
    lines.append("|---" * (2 + len(SUMMARY_COLUMNS)) + "|")
    for name, rs in groups.items():
        cells = [mean_std([figure(r) for r in rs], digits) for _, figure, digits in SUMMARY_COLUMNS]
        lines.append(f"| {name} | {len(rs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _num(v: float | None) -> str:
    return "–" if v is None else f"{v:.3f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="slam_offline.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders, or folders holding run folders")
    parser.add_argument(
        "--models",
        action="append",
        metavar="SPEC",
        help="landmark models of one variant: centroid, cuboid, or CLASS=MODEL,...,*=MODEL"
        " (repeatable; default: centroid)",
    )
    parser.add_argument("--odometry", default="logged", help=f"comma-separated of {', '.join(ODOMETRY)}")
    parser.add_argument("--points", default="logged", help=f"comma-separated of {', '.join(POINTS)}")
    parser.add_argument(
        "--depth-noise",
        default="logged",
        help="comma-separated: 'logged' (the log's camera depth noise) or coefficients K (σ = K·z², m)",
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="mission override (repeatable)"
    )
    parser.add_argument(
        "--drop-unknown-keys",
        action="store_true",
        help="re-solve a flight whose mission.yaml names parameters this version renamed or removed,"
        " without them (today's defaults for what replaced them)",
    )
    parser.add_argument("--json", type=Path, help="write the rows here as well")
    args = parser.parse_args(argv)
    from amslam.registry import build_plugin_manager

    try:
        models = args.models or ["centroid"]
        for m in models:
            parse_models(m)
        odometry = _choices(args.odometry, ODOMETRY, "--odometry")
        points = _choices(args.points, POINTS, "--points")
        noises = _depth_noises(args.depth_noise)
        runs = flight_dirs(args.runs)
        registry = build_plugin_manager()
        rows = []
        for run, m, o, p, k in itertools.product(runs, models, odometry, points, noises):
            rows.append(resolve(run, m, o, p, args.set, registry, args.drop_unknown_keys, k))
            done = rows[-1]
            print(
                f"{run.name} [{variant_name(done['variant'])}]: SLAM RMS {done['slam']['rms_m']:.3f} m",
                file=sys.stderr,
            )
    except OfflineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


def _depth_noises(value: str) -> list[str]:
    out = [v.strip() for v in value.split(",") if v.strip()]
    for v in out:
        try:
            ok = v == "logged" or 0.0 <= float(v) <= 1.0
        except ValueError:
            ok = False
        if not ok:
            raise OfflineError(f"--depth-noise {value!r}: {v!r} is neither 'logged' nor a number in [0, 1]")
    return out or ["logged"]


def _choices(value: str, allowed: tuple[str, ...], option: str) -> list[str]:
    out = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in out if v not in allowed]
    if bad or not out:
        raise OfflineError(f"{option} {value!r}: choose among {', '.join(allowed)}")
    return out


if __name__ == "__main__":
    sys.exit(main())
