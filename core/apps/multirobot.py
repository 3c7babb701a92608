"""Multi-robot experiment: several robots map one simulated world, their maps merge at the base.

Paper 2 §V, Figs. 10–11: heterogeneous robots (a low-altitude robot and an overhead robot) map
the same area, and the merged map is more accurate than either robot's; homogeneous robots each
map their own lot, and coverage speeds up with the number of robots.

``amslam experiment multi-robot MISSION --robots 1,2,3 --mode homogeneous|heterogeneous --seeds N``
flies, for every seed and every team size ``n``:

* ``n`` ordinary runs of the mission in **the same world** (the world seed is pinned while each
  robot gets its own VIO, camera and detector noise), from **known nearby bases**: different
  start positions, each with its own SLAM graph and run folder (so its own ``measurements.jsonl``);
* **homogeneous**: the mission area is split into ``n`` strips along its longer side, and each
  robot explores its own strip (``area`` of its mission) from a base inside it;
* **heterogeneous**: robots alternate low-altitude (the mission's altitude) and overhead (higher,
  with the camera tilted down); all cover the whole area from bases near the default start, as
  in the paper's Fig. 10 where both robots map the same lot;
* then the base merges the logs (:func:`amslam.plugins.gtsam_slam.merge.merge_runs`) and scores
  each robot's map alone (its own log through the same merge) and the merged map against the
  simulator's ground truth: objects mapped, position error, dimension error (objects a class
  models as a shape), objects per minute.

Robots do not interact in the simulator, so they fly one after the other; ``schedule``
"simultaneous" (default) scores them as if they had flown at the same time from their bases:
the team's mission time is the *longest* robot's time; "sequential" adds the times up (the
paper flew sequentially and fused afterwards, but its objects-per-minute figure assumes
simultaneous flights).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

import amslam
from amslam.cli import Experiment, positive_int
from amslam.errors import AmslamError
from amslam.registry import Registry
from amslam.rundir import new_folder, read_metrics, write_landmarks
from amslam.types import WorldSummary

if TYPE_CHECKING:  # amslam.mission (and PyYAML) is imported where it is used: every command loads this module
    from amslam.mission import Mission

Mode = Literal["homogeneous", "heterogeneous"]
Schedule = Literal["simultaneous", "sequential"]


# -- the robots' set-up ---------------------------------------------------------------------------


def team_overrides(
    spec: str, registry: Registry, n: int, mode: Mode, seed: int, overrides: Sequence[str] = (), **setup: Any
) -> list[list[str]]:
    """Each robot's ``--set`` overrides, from the mission's platform backend (its ``team_overrides``).

    Only a simulator can put several robots in one world, and only it knows its own parameters
    (start spot, world pin, camera tilt); a platform that cannot is refused by name.
    """
    from amslam.mission import load_mission

    plugin = load_mission(spec, registry, list(overrides)).backends["platform"].plugin
    place = getattr(registry.backend_class("platform", plugin), "team_overrides", None)
    if place is None:
        raise AmslamError(
            "the multi-robot experiment needs a platform that can place a team of robots in one world "
            f"(team_overrides); platform {plugin!r} cannot: use the simulator (plugin sim)"
        )
    return place(spec, registry, n, mode, seed, overrides, **setup)


# -- scoring ------------------------------------------------------------------------------------


def class_models(mission: Mission) -> dict[str, str]:
    """The shape model of each class the robots' SLAM used (``slam.landmark_models``, cuboid and
    cylinder classes): the base merges as the robots mapped, not by the world's true shapes."""
    slam = mission.backends.get("slam")
    models = getattr(slam.params, "landmark_models", {}) if slam is not None else {}
    return {cls: model for cls, model in models.items() if model in ("cuboid", "cylinder")}


def score(landmarks: Sequence[Any], world: WorldSummary, gate: float = 1.0) -> dict[str, Any]:
    """Objects mapped, spurious landmarks, position and dimension errors against the truth."""
    from amslam.lib.shapes import shape_center
    from amslam.plugins.gtsam_slam.merge import position_errors

    # an object with a true cuboid / cylinder is scored at its shape's reference point (box
    # centre, cylinder root), as the merge reports shape landmarks at their fitted shape's
    truth = {
        k: shape_center(world.object_shapes[k])
        if world.object_shapes.get(k, {}).get("model") in ("cuboid", "cylinder")
        else np.asarray(v, float)
        for k, v in world.object_positions.items()
    }
    err, pairs = position_errors(landmarks, truth, dict(world.object_classes), gate)
    out: dict[str, Any] = {
        "objects": len(truth),
        "mapped": len(pairs),
        "landmarks": len(landmarks),
        "spurious": len(landmarks) - len(pairs),
        "position_error_mean": float(err.mean()) if len(err) else None,
        "position_error_std": float(err.std()) if len(err) else None,
        "errors": {oid: float(e) for (_, oid), e in zip(pairs, err, strict=True)},
    }
    if world.object_shapes:
        from amslam.lib.shapes import shape_errors

        by_id = {lm.id: lm for lm in landmarks}
        dims, length_width = [], []
        for lm_id, oid in pairs:
            est, true = by_id[lm_id].shape, world.object_shapes.get(oid)
            if est and true and est.get("model") == true.get("model"):
                err = shape_errors(est, true)
                dims.append(err["dims"])
                if true["model"] == "cuboid":
                    length_width += [err["length"], err["width"]]
        out["dimension_error_mean"] = float(np.mean(dims)) if dims else None
        out["dimension_error_std"] = float(np.std(dims)) if dims else None
        out["shapes_compared"] = len(dims)
        # paper 2's error of Figs. 10-11 (§VI-B): the vehicles' length and width estimates, each
        # an absolute error, pooled
        out["length_width_error_mean"] = float(np.mean(length_width)) if length_width else None
        out["length_width_error_std"] = float(np.std(length_width)) if length_width else None
        out["vehicles_compared"] = len(length_width) // 2
    return out


# -- the experiment ----------------------------------------------------------------------------


def flight_key(mission: Mission) -> str:
    """What makes two robot runs the same flight: seed, world, base, area, altitude, camera, tree.

    The name and the plugins' other settings are left out, so a robot of one team (a low robot of
    a heterogeneous team is a homogeneous team's robot) or of an earlier experiment is reused.
    """
    m = mission.model
    plat = mission.backends["platform"].params
    world = getattr(plat, "world", None)
    return json.dumps(
        {
            "seed": m.seed,
            "world": [getattr(world, "name", None), getattr(world, "seed_offset", None)],
            "start": list(plat.start) if getattr(plat, "start", None) is not None else None,
            "area": [list(m.area.lo), list(m.area.hi)] if m.area else None,
            "altitude": m.robot.altitude,
            "pitch": getattr(getattr(plat, "camera", None), "pitch_deg", None),
            "tree": m.tree,
            "waypoints": [list(q) for q in m.waypoints.points] if m.tree == "waypoints" else None,
            "planner": mission.backends["planner"].plugin,
            "max_time": m.limits.max_time,
        },
        default=float,
    )


def index_runs(folders: Sequence[Path], registry: Registry) -> dict[str, dict]:
    """Earlier robot runs (folders holding run folders, searched recursively) by :func:`flight_key`."""
    from amslam.mission import load_mission

    out: dict[str, dict] = {}
    for folder in folders:
        for log in sorted(Path(folder).rglob("measurements.jsonl")):
            run = log.parent
            if not (run / "mission.yaml").exists() or not (run / "metrics.json").exists():
                continue  # a run still flying, or killed
            mission = load_mission(str(run / "mission.yaml"), registry, [])
            metrics = read_metrics(run / "metrics.json")
            out.setdefault(
                flight_key(mission), {"flags": None, "run_dir": run, "metrics": metrics, "world": None}
            )
    return out


def run_world(run_dir: Path, registry: Registry, mission: Any = None) -> WorldSummary:
    """The world summary of a run, rebuilt from its mission (same seed, same pin): its
    ``mission.yaml``, or ``mission`` when the caller has loaded it already."""
    from amslam.mission import load_mission
    from amslam.runner import started_platform

    if mission is None:
        mission = load_mission(str(Path(run_dir) / "mission.yaml"), registry, [])
    platform = started_platform(mission, registry, Path(run_dir).parent)
    try:
        return platform.world_summary()
    finally:
        platform.close()


def _fly(
    spec: str,
    registry: Registry,
    flags: list[str],
    runs: Path,
    log: Callable[[str], None],
    reuse: dict[str, dict] | None = None,
) -> dict:
    from amslam.mission import load_mission
    from amslam.runner import Runner

    mission = load_mission(spec, registry, flags)
    key = flight_key(mission)
    if reuse is not None and key in reuse:
        done = reuse[key]
        log(f"    {mission.name:<28} reused {done['run_dir']}")
        if done["world"] is None:
            done["world"] = run_world(done["run_dir"], registry)
        return {**done, "mission": mission}
    started = time.perf_counter()
    runner = Runner(mission, registry, runs)
    result = runner.run()
    took = time.perf_counter() - started
    log(f"    {mission.name:<28} {result.verdict:<10} ({took:.0f} s) {result.run_dir}")
    world = getattr(getattr(runner, "context", None), "world", None)
    flown = {"flags": flags, "run_dir": result.run_dir, "metrics": result.metrics, "world": world}
    if reuse is not None:
        reuse[key] = flown
    return {**flown, "mission": mission}


def _one_world(flown: list[dict]) -> WorldSummary:
    """The world the team flew; RuntimeError when a robot's run flew another (its objects differ)."""
    world: WorldSummary = flown[0]["world"]
    for f in flown[1:]:
        same = f["world"] is not None and set(f["world"].object_positions) == set(world.object_positions)
        if not same or any(
            not np.allclose(f["world"].object_positions[k], world.object_positions[k])
            for k in world.object_positions
        ):
            raise RuntimeError(
                f"robot run {f['run_dir']} did not fly in the same world as {flown[0]['run_dir']}"
            )
    return world


def _rates_and_common_errors(rows: list[dict]) -> None:
    """Add to each row (robots, then the combined map last) its objects mapped per minute, and to
    each robot's its error and the combined map's on the objects both mapped."""
    for row in rows:
        row["objects_per_minute"] = row["mapped"] / row["minutes"] if row["minutes"] > 0 else None
    comb = rows[-1]["errors"]
    for row in rows[:-1]:
        common = sorted(set(row["errors"]) & set(comb))
        row["common"] = len(common)
        row["common_error_alone"] = float(np.mean([row["errors"][k] for k in common])) if common else None
        row["common_error_merged"] = float(np.mean([comb[k] for k in common])) if common else None


def fly_team(
    spec: str,
    registry: Registry,
    n: int,
    mode: Mode,
    seed: int,
    runs: Path,
    overrides: Sequence[str] = (),
    schedule: Schedule = "simultaneous",
    log: Callable[[str], None] = print,
    reuse: dict[str, dict] | None = None,
    merges: dict[tuple[str, ...], Any] | None = None,
    odometry: Literal["vio", "slam"] = "vio",
    **setup: Any,
) -> dict[str, Any]:
    """Fly one team, merge at the base, score each robot alone and the merged map.

    ``reuse`` (:func:`flight_key` → flight) holds robots already flown; new flights are added.
    ``merges`` (run folders → merge result) likewise keeps merges of the same robots.
    ``odometry="slam"`` merges the robots' onboard SLAM trajectories instead of their VIO
    (:func:`amslam.plugins.gtsam_slam.merge.with_slam_odometry`).
    """
    from amslam.plugins.gtsam_slam.merge import MergeParams, merge_runs

    runs.mkdir(parents=True, exist_ok=True)
    teams = team_overrides(spec, registry, n, mode, seed, overrides, scratch=runs, **setup)
    flown = [_fly(spec, registry, flags, runs, log, reuse) for flags in teams]
    world = _one_world(flown)
    models = class_models(flown[0]["mission"])
    params = MergeParams(landmark_models=models)  # shape classes merge by their shapes
    times = [float(f["metrics"].get("sim_duration_s") or 0.0) for f in flown]
    names = [
        "overhead" if mode == "heterogeneous" and k == n - 1 else f"robot {k + 1}" for k in range(len(flown))
    ]
    cache = {} if merges is None else merges

    def merge(dirs: list[Path]) -> Any:
        key = tuple(str(d) for d in dirs)
        if key not in cache:
            cache[key] = merge_runs(dirs, params, odometry=odometry)
        return cache[key]

    rows = []
    for k, f in enumerate(flown):
        alone = merge([f["run_dir"]])
        rows.append({"name": names[k], "minutes": times[k] / 60.0, **score(alone.landmarks, world)})
    merged = merge([f["run_dir"] for f in flown])
    team_dir = runs / f"merged-{mode}-n{n}-seed{seed}"
    team_dir.mkdir(exist_ok=True)
    write_landmarks(team_dir / "landmarks.json", merged.landmarks)
    minutes = (max(times) if schedule == "simultaneous" else sum(times)) / 60.0
    rows.append(
        {
            "name": "combined",
            "minutes": minutes,
            "shared": merged.shared(),
            "fused": merged.fused,
            **score(merged.landmarks, world),
        }
    )
    _rates_and_common_errors(rows)
    return {
        "seed": seed,
        "n": n,
        "mode": mode,
        "schedule": schedule,
        "odometry": odometry,
        "runs": [str(f["run_dir"]) for f in flown],
        "verdicts": [f["metrics"].get("verdict") for f in flown],
        "merged_dir": str(team_dir),
        "rows": rows,
    }


def multi_robot(
    spec: str,
    registry: Registry,
    seeds: Sequence[int],
    out: Path,
    robots: Sequence[int] = (1, 2, 3),
    mode: Mode | Literal["both"] = "homogeneous",
    overrides: Sequence[str] = (),
    schedule: Schedule = "simultaneous",
    log: Callable[[str], None] = print,
    reuse: Sequence[Path] = (),
    odometry: Literal["vio", "slam"] = "vio",
    **setup: Any,
) -> Path:
    """The experiment: every team size for every seed; writes results.json and table.md.

    ``mode="both"`` runs the homogeneous and then the heterogeneous teams. A robot flight is flown
    once and reused by every team it belongs to; ``reuse`` adds the robot runs found under
    earlier experiment folders (:func:`index_runs`).
    """
    modes: list[Mode] = ["homogeneous", "heterogeneous"] if mode == "both" else [mode]
    name = f"multi-robot-{mode}-{Path(spec).stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    folder = new_folder(Path(out), name, "an experiment folder")
    (folder / "runs").mkdir()
    results = []
    flights = index_runs(reuse, registry)
    merges: dict[tuple[str, ...], Any] = {}
    for seed, m, n in ((seed, m, n) for seed in seeds for m in modes for n in robots):
        log(f"  seed {seed}, {n} robot(s), {m}")
        results.append(
            fly_team(
                spec,
                registry,
                n,
                m,
                seed,
                folder / "runs",
                overrides,
                schedule,
                log,
                flights,
                merges,
                odometry,
                **setup,
            )
        )
        (folder / "results.json").write_text(json.dumps(results, indent=2, default=str))
    (folder / "table.md").write_text("\n".join(tables([r for r in results if r["mode"] == m]) for m in modes))
    return folder


def _fmt(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "—"
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


def _mean(rows: list[dict], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return float(np.mean(vals)) if vals else None


def tables(results: list[dict]) -> str:
    """Markdown tables like paper 2 Figs. 10–11 (means over seeds)."""
    if not results:
        return ""
    mode, schedule = results[0]["mode"], results[0]["schedule"]
    title = "Fig. 10 (heterogeneous)" if mode == "heterogeneous" else "Fig. 11 (homogeneous)"
    simultaneous = schedule == "simultaneous"
    basis = "longest robot time (robots fly simultaneously)" if simultaneous else "sum of the robot times"
    lines = [
        f"## {mode.capitalize()} robots, like paper 2 {title}",
        "",
        f"Means over {len({r['seed'] for r in results})} seed(s); objects per minute use the {basis}.",
        "",
    ]
    shapes = any("dimension_error_mean" in row for r in results for row in r["rows"])
    for n in sorted({r["n"] for r in results}):
        team = [r for r in results if r["n"] == n]
        names = [row["name"] for row in team[0]["rows"]]
        measures = [("Num. of obj. / min", "objects_per_minute")]
        if shapes:  # the paper's Err. Mean / Err. Std. Dev.: vehicles' length and width
            measures += [
                ("Err. mean: vehicle length, width (m)", "length_width_error_mean"),
                ("Err. std: vehicle length, width (m)", "length_width_error_std"),
                ("Vehicles compared", "vehicles_compared"),
            ]
        measures += [
            ("Objects mapped", "mapped"),
            ("Landmarks", "landmarks"),
            ("Spurious landmarks", "spurious"),
            ("Pos. err. mean (m)", "position_error_mean"),
            ("Pos. err. std (m)", "position_error_std"),
        ]
        if shapes:
            measures += [
                ("Dim. err. mean (m)", "dimension_error_mean"),
                ("Dim. err. std (m)", "dimension_error_std"),
            ]
        measures += [
            ("Mission time (min)", "minutes"),
            ("Objects also in the merged map", "common"),
            ("Their pos. err. alone (m)", "common_error_alone"),
            ("Their pos. err. merged (m)", "common_error_merged"),
        ]
        lines += [
            f"### {n} robot(s)",
            "",
            "| measure | " + " | ".join(names) + " |",
            "|---" * (len(names) + 1) + "|",
        ]
        for label, key in measures:
            cells = [_fmt(_mean([r["rows"][i] for r in team], key)) for i in range(len(names))]
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        objects = _mean([r["rows"][-1] for r in team], "objects")
        lines += ["", f"Objects in the world: {_fmt(objects, 0)}.", ""]
    lines += [
        "### Merged map against the team size",
        "",
        "| robots | obj. / min | mapped | spurious | pos. err. mean (m) | pos. err. std (m) |"
        + (" dim. err. mean (m) | length, width err. (m) |" if shapes else ""),
        "|---|---|---|---|---|---|" + ("---|---|" if shapes else ""),
    ]
    for n in sorted({r["n"] for r in results}):
        comb = [r["rows"][-1] for r in results if r["n"] == n]
        line = (
            f"| {n} | {_fmt(_mean(comb, 'objects_per_minute'))} | {_fmt(_mean(comb, 'mapped'), 1)} | "
            f"{_fmt(_mean(comb, 'spurious'), 1)} | {_fmt(_mean(comb, 'position_error_mean'))} | "
            f"{_fmt(_mean(comb, 'position_error_std'))} |"
        )
        if shapes:
            lw_mean, lw_std = _mean(comb, "length_width_error_mean"), _mean(comb, "length_width_error_std")
            line += f" {_fmt(_mean(comb, 'dimension_error_mean'))} | {_fmt(lw_mean)} ± {_fmt(lw_std)} |"
        lines.append(line)
    return "\n".join(lines) + "\n"


# -- registration ------------------------------------------------------------------------------


def _team_sizes(text: str) -> list[int]:
    """``--robots``: comma-separated team sizes, each ≥ 1."""
    sizes = []
    for part in text.split(","):
        try:
            sizes.append(positive_int(part.strip()))
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{text!r}: team sizes are whole numbers ≥ 1 ({exc})") from None
    return sizes


def _arguments(parser) -> None:
    parser.add_argument("--robots", type=_team_sizes, default="1,2,3", help="team sizes (default 1,2,3)")
    parser.add_argument(
        "--mode",
        choices=["homogeneous", "heterogeneous", "both"],
        default="homogeneous",
        help="same robots on split areas, low-altitude robots + an overhead robot, or both",
    )
    parser.add_argument(
        "--schedule",
        choices=["simultaneous", "sequential"],
        default="simultaneous",
        help="team time = longest robot's (simultaneous) or the sum (sequential)",
    )
    parser.add_argument(
        "--reuse",
        action="append",
        metavar="DIR",
        help="reuse robot runs under DIR (earlier experiments) that fly the same flight",
    )
    parser.add_argument(
        "--odometry",
        choices=["vio", "slam"],
        default="vio",
        help="chain each robot's key poses with its VIO (default) or its onboard SLAM estimate",
    )


def _run(args, registry: Registry) -> Path:
    return multi_robot(
        args.mission,
        registry,
        list(range(args.first_seed, args.first_seed + args.seeds)),
        Path(args.out),
        args.robots if isinstance(args.robots, list) else _team_sizes(args.robots),
        args.mode,
        args.set or [],
        args.schedule,
        reuse=[Path(d) for d in args.reuse or []],
        odometry=args.odometry,
    )


@amslam.hookimpl
def amslam_experiments():
    return {
        "multi-robot": Experiment(
            "robot teams in one simulated world, merged at the base (paper 2 Figs. 10-11)", _run, _arguments
        )
    }
