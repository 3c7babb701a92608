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

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from amslam.interfaces import BACKEND_KINDS, RunContext
from amslam.mission import Mission, load_mission
from amslam.registry import Registry
from amslam.runner import Runner
from amslam.types import WorldSummary

Mode = Literal["homogeneous", "heterogeneous"]
Schedule = Literal["simultaneous", "sequential"]


# -- the robots' set-up ---------------------------------------------------------------------------


def sim_world_seed(seed: int) -> int:
    """The world seed the ``sim`` platform derives from a mission seed (see its ``configure``)."""
    ss = np.random.SeedSequence(seed).spawn(len(BACKEND_KINDS))[list(BACKEND_KINDS).index("platform")]
    return int(np.random.default_rng(ss).integers(0, 2**63 - 1, size=3)[0])


def robot_seed(seed: int, k: int) -> int:
    """Mission seed of robot ``k`` of a team flown for experiment seed ``seed``."""
    return seed if k == 0 else seed * 1000 + k


def split_area(lo: np.ndarray, hi: np.ndarray, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` equal strips of the box ``[lo, hi]`` along its longer horizontal side."""
    axis = 0 if hi[0] - lo[0] >= hi[1] - lo[1] else 1
    edges = np.linspace(lo[axis], hi[axis], n + 1)
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        slo, shi = np.array(lo, float), np.array(hi, float)
        slo[axis], shi[axis] = a, b
        out.append((slo, shi))
    return out


def open_spots(platform: Any, lo: np.ndarray, hi: np.ndarray, altitude: float, radius: float) -> np.ndarray:
    """Take-off spots (x, y) in the box on the ground floor, most open first.

    A spot needs the floor right below it and a free column from the ground to ``altitude``
    (clearance above ``radius`` plus a margin); spots are ranked by their clearance.
    """
    world = platform.world
    floor = float(world.spec.floor_heights[0]) if hasattr(world, "spec") else float(lo[2])
    xs = np.arange(lo[0] + 0.5, hi[0] - 0.25, 0.25)
    ys = np.arange(lo[1] + 0.5, hi[1] - 0.25, 0.25)
    if len(xs) == 0 or len(ys) == 0:
        return np.zeros((0, 2))
    g = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    clear = np.full(len(g), np.inf)
    for h in np.linspace(radius + 0.5, altitude, 5):  # the floor itself is not an obstacle
        clear = np.minimum(clear, world.distance(np.column_stack([g, np.full(len(g), floor + h)])))
    below = np.array([world.ground_below(np.array([x, y, floor + 1.0])) for x, y in g])
    ok = (clear > radius + 0.3) & (np.abs(below - floor) < 0.1)
    g, clear = g[ok], clear[ok]
    return g[np.argsort(-clear)]


def _build_platform(mission: Mission, registry: Registry, run_dir: Path) -> Any:
    """The mission's platform, configured and started (to read the world before flying)."""
    choice = mission.backends["platform"]
    platform = registry.factory("platform", choice.plugin)()
    ss = np.random.SeedSequence(mission.model.seed).spawn(len(BACKEND_KINDS))[0]
    platform.configure(
        choice.params,
        RunContext(
            rng=np.random.default_rng(ss),
            run_dir=run_dir,
            robot=mission.model.robot.spec(),
            mission_dir=mission.directory,
        ),
    )
    platform.start()
    return platform


def team_overrides(
    spec: str,
    registry: Registry,
    n: int,
    mode: Mode,
    seed: int,
    overrides: Sequence[str] = (),
    overhead_altitude: float = 2.0,
    overhead_pitch: float = 35.0,
    base_spacing: float = 1.0,
    split: bool | None = None,
    scratch: Path = Path("."),
) -> list[list[str]]:
    """The ``--set`` overrides of each robot of a team: seed, world pin, start, area, altitude.

    Args:
        spec: the mission.
        registry: the plugins.
        n: robots in the team.
        mode: homogeneous (same robots) or heterogeneous (low-altitude and overhead alternate).
        seed: the experiment seed (robot 0 flies it; the others fly in the same world).
        overrides: applied to every robot first.
        overhead_altitude: take-off altitude of overhead robots (m); when it is not above the
            mission's altitude (outdoor missions fly at 3.5 m), overhead robots fly at 1.5 × that
            altitude instead, so that they are always the higher robots.
        overhead_pitch: their camera's downward tilt (degrees).
        base_spacing: smallest distance between two bases (m).
        split: give each robot its own strip of the area (default: homogeneous only).
        scratch: a folder for the throw-away run context of the world look-up.
    """
    if split is None:
        split = mode == "homogeneous"
    base = [*overrides, f"seed={seed}"]
    mission = load_mission(spec, registry, base)
    if mission.backends["platform"].plugin != "sim":
        raise ValueError("the multi-robot experiment needs the simulator platform (plugin sim)")
    platform = _build_platform(mission, registry, scratch)
    try:
        world = platform.world_summary()
        area = mission.model.area
        lo = np.array(area.lo if area else world.bounds_lo, float)
        hi = np.array(area.hi if area else world.bounds_hi, float)
        radius = mission.model.robot.radius
        low_alt = mission.model.robot.altitude
        high_alt = overhead_altitude if overhead_altitude > low_alt else round(1.5 * low_alt, 2)
        alts = [low_alt if mode == "homogeneous" or k % 2 == 0 else high_alt for k in range(n)]
        boxes = split_area(lo, hi, n) if split else [(lo, hi)] * n
        start = np.asarray(platform.ground_truth())[:2, 3]
        bases: list[np.ndarray] = []
        for k in range(n):
            spots = open_spots(platform, boxes[k][0], boxes[k][1], max(alts), radius)
            if not split:  # nearby bases around the default start
                spots = spots[np.linalg.norm(spots - start, axis=1) <= 4.0] if len(spots) else spots
                if k == 0 or len(spots) == 0:
                    spots = np.vstack([start[None], spots]) if len(spots) else start[None]
            far = [s for s in spots if all(np.linalg.norm(s - b) >= base_spacing for b in bases)]
            if not far:
                raise ValueError(
                    f"no free base for robot {k + 1} of {n} in {boxes[k][0][:2]}–{boxes[k][1][:2]}"
                )
            bases.append(np.asarray(far[0], float))
    finally:
        platform.close()
    pin = sim_world_seed(seed)
    teams = []
    for k in range(n):
        s = robot_seed(seed, k)
        flags = [*base, f"seed={s}", f"name={mission.name}-r{k + 1}"]
        world_params = mission.backends["platform"].params.world
        if hasattr(world_params, "seed_offset"):  # a generated world: pin it to robot 1's
            flags.append(f"platform.world.seed_offset={pin - sim_world_seed(s) + world_params.seed_offset}")
        flags.append(f"platform.start=[{bases[k][0]:.2f}, {bases[k][1]:.2f}]")
        if split:
            blo, bhi = boxes[k]
            flags.append(f"area={{lo: {np.round(blo, 2).tolist()}, hi: {np.round(bhi, 2).tolist()}}}")
        if alts[k] != low_alt:
            flags += [f"robot.altitude={alts[k]}", f"platform.camera.pitch_deg={overhead_pitch}"]
        teams.append(flags)
    return teams


# -- scoring ------------------------------------------------------------------------------------


def class_models(world: WorldSummary) -> dict[str, str]:
    """Which shape model each class uses in this world (from its true object shapes)."""
    out: dict[str, str] = {}
    for oid, shape in world.object_shapes.items():
        cls = world.object_classes.get(oid)
        if cls is not None and shape.get("model") in ("cuboid", "cylinder"):
            out[cls] = shape["model"]
    return out


def shape_fitter(models: dict[str, str]) -> Callable[[str, np.ndarray], dict | None] | None:
    """Fit each landmark's points with its class's model (paper 2 §IV-A), or None if no shapes."""
    if not models:
        return None
    from amslam.plugins.gtsam_slam.shapes import fit_cuboid, fit_cylinder

    def fit(class_name: str, points: np.ndarray) -> dict | None:
        model = models.get(class_name)
        if model == "cuboid":
            return fit_cuboid(points)
        if model == "cylinder":
            return fit_cylinder(points)
        return None

    return fit


def score(landmarks: Sequence[Any], world: WorldSummary, gate: float = 1.0) -> dict[str, Any]:
    """Objects mapped, spurious landmarks, position and dimension errors against the truth."""
    from amslam.plugins.gtsam_slam.merge import position_errors

    truth = {k: np.asarray(v, float) for k, v in world.object_positions.items()}
    err, pairs = position_errors(landmarks, truth, dict(world.object_classes), gate)
    out: dict[str, Any] = {
        "objects": len(truth),
        "mapped": len(pairs),
        "landmarks": len(landmarks),
        "spurious": len(landmarks) - len(pairs),
        "position_error_mean": float(err.mean()) if len(err) else None,
        "position_error_std": float(err.std()) if len(err) else None,
    }
    if world.object_shapes:
        from amslam.plugins.gtsam_slam.shapes import shape_errors

        by_id = {lm.id: lm for lm in landmarks}
        dims = []
        for lm_id, oid in pairs:
            est, true = by_id[lm_id].shape, world.object_shapes.get(oid)
            if est and true and est.get("model") == true.get("model"):
                dims.append(shape_errors(est, true)["dims"])
        out["dimension_error_mean"] = float(np.mean(dims)) if dims else None
        out["dimension_error_std"] = float(np.std(dims)) if dims else None
        out["shapes_compared"] = len(dims)
    return out


# -- the experiment ----------------------------------------------------------------------------


def _fly(spec: str, registry: Registry, flags: list[str], runs: Path, log: Callable[[str], None]) -> dict:
    mission = load_mission(spec, registry, flags)
    started = time.perf_counter()
    runner = Runner(mission, registry, runs)
    result = runner.run()
    took = time.perf_counter() - started
    log(f"    {mission.name:<28} {result.verdict:<10} ({took:.0f} s) {result.run_dir}")
    world = getattr(getattr(runner, "context", None), "world", None)
    return {"flags": flags, "run_dir": result.run_dir, "metrics": result.metrics, "world": world}


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
    **setup: Any,
) -> dict[str, Any]:
    """Fly one team, merge at the base, score each robot alone and the merged map."""
    from amslam.plugins.gtsam_slam.merge import merge_runs, write_landmarks

    runs.mkdir(parents=True, exist_ok=True)
    teams = team_overrides(spec, registry, n, mode, seed, overrides, scratch=runs, **setup)
    flown = [_fly(spec, registry, flags, runs, log) for flags in teams]
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
    fit = shape_fitter(class_models(world))
    times = [float(f["metrics"].get("sim_duration_s") or 0.0) for f in flown]
    rows = []
    for k, f in enumerate(flown):
        alone = merge_runs([f["run_dir"]], shape_fitter=fit)
        rows.append({"name": f"robot {k + 1}", "minutes": times[k] / 60.0, **score(alone.landmarks, world)})
    merged = merge_runs([f["run_dir"] for f in flown], shape_fitter=fit)
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
    for row in rows:
        row["objects_per_minute"] = row["mapped"] / row["minutes"] if row["minutes"] > 0 else None
    return {
        "seed": seed,
        "n": n,
        "mode": mode,
        "schedule": schedule,
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
    mode: Mode = "homogeneous",
    overrides: Sequence[str] = (),
    schedule: Schedule = "simultaneous",
    log: Callable[[str], None] = print,
    **setup: Any,
) -> Path:
    """The experiment: every team size for every seed; writes results.json and table.md."""
    folder = Path(out) / f"multi-robot-{mode}-{Path(spec).stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    (folder / "runs").mkdir(parents=True)
    results = []
    for seed in seeds:
        for n in robots:
            log(f"  seed {seed}, {n} robot(s), {mode}")
            results.append(
                fly_team(spec, registry, n, mode, seed, folder / "runs", overrides, schedule, log, **setup)
            )
            (folder / "results.json").write_text(json.dumps(results, indent=2, default=str))
    (folder / "table.md").write_text(tables(results))
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
        measures = [
            ("Num. of obj. / min", "objects_per_minute"),
            ("Objects mapped", "mapped"),
            ("Spurious landmarks", "spurious"),
            ("Pos. err. mean (m)", "position_error_mean"),
            ("Pos. err. std (m)", "position_error_std"),
        ]
        if shapes:
            measures += [
                ("Dim. err. mean (m)", "dimension_error_mean"),
                ("Dim. err. std (m)", "dimension_error_std"),
            ]
        measures.append(("Mission time (min)", "minutes"))
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
        + (" dim. err. mean (m) |" if shapes else ""),
        "|---|---|---|---|---|---|" + ("---|" if shapes else ""),
    ]
    for n in sorted({r["n"] for r in results}):
        comb = [r["rows"][-1] for r in results if r["n"] == n]
        line = (
            f"| {n} | {_fmt(_mean(comb, 'objects_per_minute'))} | {_fmt(_mean(comb, 'mapped'), 1)} | "
            f"{_fmt(_mean(comb, 'spurious'), 1)} | {_fmt(_mean(comb, 'position_error_mean'))} | "
            f"{_fmt(_mean(comb, 'position_error_std'))} |"
        )
        if shapes:
            line += f" {_fmt(_mean(comb, 'dimension_error_mean'))} |"
        lines.append(line)
    return "\n".join(lines) + "\n"
