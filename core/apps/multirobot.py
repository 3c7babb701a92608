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

import amslam
from amslam.cli import Experiment
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


def overhead_seed(seed: int, j: int = 0) -> int:
    """Mission seed of the ``j``-th overhead robot of a heterogeneous team (the same in every team size)."""
    return seed * 1000 + 100 + j


def lawnmower(
    world: Any,
    lo: np.ndarray,
    hi: np.ndarray,
    base: np.ndarray,
    altitude: float,
    spacing: float,
    clearance: float,
    margin: float = 1.5,
) -> list[list[float]]:
    """Lanes along the longer side of ``[lo, hi]`` at ``altitude``, ``spacing`` apart, clear of obstacles.

    Each lane is moved across (up to half the spacing, in 0.25 m steps) to where the whole lane, and the
    leg to it from the previous point, keep ``clearance`` from every surface (light poles and tree
    trunks reach above the overhead altitude); a lane that finds no such place is left out.
    Returns the waypoints relative to ``base`` (``tree: waypoints``), starting with the climb.
    """
    axis = 0 if hi[0] - lo[0] >= hi[1] - lo[1] else 1
    other = 1 - axis
    a0, a1 = lo[axis] + margin, hi[axis] - margin
    c0, c1 = lo[other] + margin, hi[other] - margin
    n = max(1, int(np.ceil((c1 - c0) / spacing)) + 1)
    offsets = np.linspace(c0, c1, n) if n > 1 else np.array([(c0 + c1) / 2])

    def point(a: float, c: float) -> np.ndarray:
        q = np.zeros(3)
        q[axis], q[other], q[2] = a, c, altitude
        return q

    def clear(p: np.ndarray, q: np.ndarray) -> bool:
        k = max(2, int(np.linalg.norm(q - p) / 0.25) + 1)
        seg = p[None] + np.linspace(0, 1, k)[:, None] * (q - p)[None]
        return bool(np.all(world.distance(seg) > clearance))

    here = np.array([base[0], base[1], altitude])
    pts = [here]
    forward = True
    for c in offsets:
        for shift in [0.0, *[s * d for d in np.arange(0.25, spacing / 2 + 0.01, 0.25) for s in (1, -1)]]:
            ends = (point(a0, c + shift), point(a1, c + shift))
            if not forward:
                ends = ends[::-1]
            if clear(*ends) and clear(pts[-1], ends[0]):
                pts += list(ends)
                forward = not forward
                break
    rel = [
        [round(float(q[0] - base[0]), 2), round(float(q[1] - base[1]), 2), round(float(q[2]), 2)] for q in pts
    ]
    return rel


def team_overrides(
    spec: str,
    registry: Registry,
    n: int,
    mode: Mode,
    seed: int,
    overrides: Sequence[str] = (),
    overhead_altitude: float | None = None,
    overhead_pitch: float = 60.0,
    overhead_spacing: float = 6.0,
    base_spacing: float = 1.0,
    split: bool | None = None,
    scratch: Path = Path("."),
) -> list[list[str]]:
    """The ``--set`` overrides of each robot of a team: seed, world pin, start, area, altitude.

    Homogeneous: ``n`` low-altitude robots, each exploring its own strip of the area. Heterogeneous
    (paper 2 Fig. 10): ``n − 1`` low-altitude robots exactly as a homogeneous team of ``n − 1``
    (same seeds, strips and bases, so each low robot alone is a homogeneous run), plus one
    **overhead** robot (the last; ``n = 1`` is the overhead robot alone). Outdoors (a world
    without a roof) the overhead robot flies a lawnmower (``tree: waypoints``) over the whole
    area at ``overhead_altitude`` with its camera pitched ``overhead_pitch`` down, holding its
    altitude; elsewhere it explores the whole area like a low robot from that altitude.

    Args:
        spec: the mission.
        registry: the plugins.
        n: robots in the team.
        mode: homogeneous (same robots) or heterogeneous (low-altitude robots and an overhead one).
        seed: the experiment seed (robot 1 flies it; the others fly in the same world).
        overrides: applied to every robot first.
        overhead_altitude: the overhead robot's altitude (m); default: twice the mission's altitude,
            at most 1 m below the top of the world's flight volume.
        overhead_pitch: its camera's downward tilt (degrees).
        overhead_spacing: distance between its lawnmower lanes (m).
        base_spacing: smallest distance between two bases (m).
        split: give each low robot its own strip of the area (default: yes).
        scratch: a folder for the throw-away run context of the world look-up.
    """
    if split is None:
        split = True
    base = [*overrides, f"seed={seed}"]
    mission = load_mission(spec, registry, base)
    if mission.backends["platform"].plugin != "sim":
        raise ValueError("the multi-robot experiment needs the simulator platform (plugin sim)")
    n_low = n if mode == "homogeneous" else n - 1
    platform = _build_platform(mission, registry, scratch)
    try:
        world = platform.world_summary()
        area = mission.model.area
        lo = np.array(area.lo if area else world.bounds_lo, float)
        hi = np.array(area.hi if area else world.bounds_hi, float)
        radius = mission.model.robot.radius
        low_alt = mission.model.robot.altitude
        top = float(world.bounds_hi[2]) - float(world.floor_heights[0])
        high_alt = (
            overhead_altitude if overhead_altitude is not None else round(min(2 * low_alt, top - 1.0), 2)
        )
        boxes = split_area(lo, hi, n_low) if split and n_low > 0 else [(lo, hi)] * n_low
        bases: list[np.ndarray] = []
        for k in range(n_low):
            spots = open_spots(platform, boxes[k][0], boxes[k][1], low_alt, radius)
            far = [s for s in spots if all(np.linalg.norm(s - b) >= base_spacing for b in bases)]
            if not far:
                raise ValueError(
                    f"no free base for robot {k + 1} of {n} in {boxes[k][0][:2]}–{boxes[k][1][:2]}"
                )
            bases.append(np.asarray(far[0], float))
        overhead_flags: list[str] = []
        if mode == "heterogeneous":
            spots = open_spots(platform, lo, hi, high_alt, radius)
            # the lawnmower starts at the area's low corner: take off from the open spot nearest it
            spots = spots[np.argsort(np.linalg.norm(spots - (lo[:2] + 1.5), axis=1), kind="stable")]
            far = [s for s in spots if all(np.linalg.norm(s - b) >= base_spacing for b in bases)]
            if not far:
                raise ValueError(f"no free base for the overhead robot in {lo[:2]}–{hi[:2]}")
            bases.append(np.asarray(far[0], float))
            overhead_flags = [
                f"robot.altitude={high_alt}",
                f"platform.camera.pitch_deg={overhead_pitch}",
            ]
            world_params = mission.backends["platform"].params.world
            if getattr(world_params, "kind", None) == "outdoor":
                wps = lawnmower(platform.world, lo, hi, bases[-1], high_alt, overhead_spacing, radius + 0.75)
                overhead_flags += [
                    "tree=waypoints",
                    f"waypoints.points={wps}",
                    "waypoints.heading=travel",
                    "waypoints.tolerance=0.3",
                ]
    finally:
        platform.close()
    pin = sim_world_seed(seed)
    teams = []
    for k in range(n):
        overhead = mode == "heterogeneous" and k == n - 1
        s = overhead_seed(seed) if overhead else robot_seed(seed, k)
        flags = [*base, f"seed={s}", f"name={mission.name}-{'overhead' if overhead else f'r{k + 1}'}"]
        world_params = mission.backends["platform"].params.world
        if hasattr(world_params, "seed_offset"):  # a generated world: pin it to robot 1's
            flags.append(f"platform.world.seed_offset={pin - sim_world_seed(s) + world_params.seed_offset}")
        flags.append(f"platform.start=[{bases[k][0]:.2f}, {bases[k][1]:.2f}]")
        if overhead:
            flags += overhead_flags
        elif split:
            blo, bhi = boxes[k]
            flags.append(f"area={{lo: {np.round(blo, 2).tolist()}, hi: {np.round(bhi, 2).tolist()}}}")
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
    from amslam.lib.shapes import fit_cuboid, fit_cylinder

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
    out: dict[str, dict] = {}
    for folder in folders:
        for log in sorted(Path(folder).rglob("measurements.jsonl")):
            run = log.parent
            if not (run / "mission.yaml").exists() or not (run / "metrics.json").exists():
                continue  # a run still flying, or killed
            mission = load_mission(str(run / "mission.yaml"), registry, [])
            metrics = json.loads((run / "metrics.json").read_text())
            out.setdefault(
                flight_key(mission), {"flags": None, "run_dir": run, "metrics": metrics, "world": None}
            )
    return out


def _world_of(run_dir: Path, registry: Registry) -> WorldSummary:
    """The world summary of a run, rebuilt from its mission (same seed, same pin)."""
    mission = load_mission(str(Path(run_dir) / "mission.yaml"), registry, [])
    platform = _build_platform(mission, registry, Path(run_dir).parent)
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
    mission = load_mission(spec, registry, flags)
    key = flight_key(mission)
    if reuse is not None and key in reuse:
        done = reuse[key]
        log(f"    {mission.name:<28} reused {done['run_dir']}")
        if done["world"] is None:
            done["world"] = _world_of(done["run_dir"], registry)
        return done
    started = time.perf_counter()
    runner = Runner(mission, registry, runs)
    result = runner.run()
    took = time.perf_counter() - started
    log(f"    {mission.name:<28} {result.verdict:<10} ({took:.0f} s) {result.run_dir}")
    world = getattr(getattr(runner, "context", None), "world", None)
    flown = {"flags": flags, "run_dir": result.run_dir, "metrics": result.metrics, "world": world}
    if reuse is not None:
        reuse[key] = flown
    return flown


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
    from amslam.plugins.gtsam_slam.merge import MergeParams, merge_runs, write_landmarks

    runs.mkdir(parents=True, exist_ok=True)
    teams = team_overrides(spec, registry, n, mode, seed, overrides, scratch=runs, **setup)
    flown = [_fly(spec, registry, flags, runs, log, reuse) for flags in teams]
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
    models = class_models(world)
    fit = shape_fitter(models)
    params = MergeParams(landmark_models=models)  # shape classes merge by their shapes
    times = [float(f["metrics"].get("sim_duration_s") or 0.0) for f in flown]
    names = [
        "overhead" if mode == "heterogeneous" and k == n - 1 else f"robot {k + 1}" for k in range(len(flown))
    ]
    cache = {} if merges is None else merges

    def merge(dirs: list[Path]) -> Any:
        key = tuple(str(d) for d in dirs)
        if key not in cache:
            cache[key] = merge_runs(dirs, params, shape_fitter=fit, odometry=odometry)
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
    for row in rows:
        row["objects_per_minute"] = row["mapped"] / row["minutes"] if row["minutes"] > 0 else None
    comb = rows[-1]["errors"]
    for row in rows[:-1]:  # each robot against the merged map on the objects both mapped
        common = sorted(set(row["errors"]) & set(comb))
        row["common"] = len(common)
        row["common_error_alone"] = float(np.mean([row["errors"][k] for k in common])) if common else None
        row["common_error_merged"] = float(np.mean([comb[k] for k in common])) if common else None
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
    folder = Path(out) / f"multi-robot-{mode}-{Path(spec).stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    (folder / "runs").mkdir(parents=True)
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
        measures = [
            ("Num. of obj. / min", "objects_per_minute"),
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


# -- registration ------------------------------------------------------------------------------


def _arguments(parser) -> None:
    parser.add_argument("--robots", default="1,2,3", help="team sizes (default 1,2,3)")
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
        [int(n) for n in args.robots.split(",")],
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
