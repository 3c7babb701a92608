"""The whole mission's speed against building size (issue #20): real-time factor and time per module.

Flies the default stack (the demo mission's: open3d maps, gtsam SLAM with semantic loop closure,
the sim detector, the cop planner) in buildings of growing size and prints, per building, the
real-time factor (simulated seconds per wall second of the flight loop, and per CPU second of
this process) and the wall time per control tick of each module:

    render        the simulator's camera (Platform.capture)
    vehicle       the rest of the simulator (Platform.advance, status, odometry, ...)
    map updates   depth frames fused into the global and local maps (Mapping.integrate_*)
    viewpoints    frontier clusters and their viewpoints (Mapping.viewpoints)
    path costs    travel costs between tour stops (Mapping.path_costs)
    paths         planned and checked paths (Mapping.plan_path, plan_local_path, segment_free)
    map queries   the rest of Mapping (states for the guards, explored volume, ...)
    SLAM          odometry and detections into the factor graph, key poses, landmarks
    SLC, gain     loop-closure candidates, eq. 10's information gain, loop-closure attempts
    detector      Detector.detect
    planner       Planner.plan (its own time: the path costs and paths it asks for are above)
    other         the rest of the loop: the behaviour tree, setpoint guards, recording

Each module's time is its own: a call that calls another timed module (the planner asking for
path costs) is charged only for what it does itself. Set-up (backend configure, numba warm-up)
and the report after landing are timed apart and not in the per-tick figures.

Buildings (``--buildings``): ``demo`` (the demo mission: two 14 × 10 m floors and a shaft),
``floors3`` (three 20 × 14 m floors), ``hall`` (a 20 × 30 × 10 m warehouse hall with rows of racks,
``world: {kind: hall}``). Each is flown once at ``--seed`` in this process, one after the other;
``--max-time`` caps the simulated time of each (the same cap makes the buildings comparable).

    .venv/bin/python benchmarks/mission.py                          # docs/benchmarks.md
    .venv/bin/python benchmarks/mission.py --buildings demo --max-time 0   # the mission's own limit
    .venv/bin/python benchmarks/mission.py --buildings demo --set mapping.seen_through_rise=0  # a rule's cost

Results: ``results.json``, ``table.md`` and ``mission.png`` (ms per tick of each module against
the building's reachable free volume, log-log) in ``--out``/mission-benchmark-TIME, printed too.
Timing is wall-clock: on a shared machine every module is slowed alike; the load average at the
start and end of each flight is recorded with it.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import threading
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

BUILDINGS = {
    "demo": ("demo", []),
    "floors3": ("demo", ["platform.world.floors=3", "platform.world.size=[20, 14]"]),
    "hall": ("demo", ["platform.world={kind: hall, size: [20, 30], height: 10}"]),
}

#: module of each interface method; a method not listed is charged to its kind's last entry
MODULES: dict[str, dict[str, str]] = {
    "platform": {"capture": "render", "*": "vehicle"},
    "mapping": {
        "integrate_global": "map updates",
        "integrate_local": "map updates",
        "rebuild_global": "map updates",
        "viewpoints": "viewpoints",
        "path_costs": "path costs",
        "plan_path": "paths",
        "plan_local_path": "paths",
        "segment_free": "paths",
        "*": "map queries",
    },
    "slam": {
        "try_loop_closure": "SLC, gain",
        "slc_candidates": "SLC, gain",
        "information_gain": "SLC, gain",
        "*": "SLAM",
    },
    "detector": {"*": "detector"},
    "planner": {"*": "planner"},
}
ORDER = [
    "render",
    "vehicle",
    "map updates",
    "viewpoints",
    "path costs",
    "paths",
    "map queries",
    "SLAM",
    "SLC, gain",
    "detector",
    "planner",
    "other",
]


class Stopwatch:
    """Own (exclusive) wall time per module, charged by wrappers around backend methods.

    Written here rather than taken from cProfile: cProfile's overhead on the many small calls of
    a flight (numpy, the tree) changes the proportions it measures, and it knows functions, not
    the modules a reader of this table asks about. The wrappers cost one perf_counter pair per
    backend call.
    """

    def __init__(self) -> None:
        self.own: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._stack = threading.local()
        self._patched: list[tuple[type, str, Any]] = []

    def reset(self) -> None:
        self.own.clear()
        self.calls.clear()

    def timed(self, module: str, fn):
        watch = self

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            stack = getattr(watch._stack, "frames", None)
            if stack is None:
                stack = watch._stack.frames = []
            stack.append(0.0)  # time charged to callees of this call
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                took = time.perf_counter() - start
                callees = stack.pop()
                watch.own[module] += took - callees
                watch.calls[module] += 1
                if stack:
                    stack[-1] += took

        return wrapper

    def patch(self, cls: type, name: str, module: str) -> None:
        """Time ``cls.name`` (inherited or own) as ``module`` until :meth:`restore`."""
        original = cls.__dict__.get(name)
        self._patched.append((cls, name, original))
        setattr(cls, name, self.timed(module, getattr(cls, name)))

    def restore(self) -> None:
        for cls, name, original in reversed(self._patched):
            if original is None:
                delattr(cls, name)
            else:
                setattr(cls, name, original)
        self._patched.clear()


def instrument(watch: Stopwatch, registry, mission) -> None:
    """Wrap every interface method of the mission's backends, their configure, and the runner's
    report, each charged to its module."""
    from amslam import interfaces
    from amslam.runner import Runner

    bases = {
        "platform": interfaces.Platform,
        "mapping": interfaces.Mapping,
        "slam": interfaces.Slam,
        "detector": interfaces.Detector,
        "planner": interfaces.Planner,
    }
    for kind, choice in mission.backends.items():
        cls = registry.backend_class(kind, choice.plugin)
        modules = MODULES[kind]
        names = [n for n, v in vars(bases[kind]).items() if callable(v) and not n.startswith("_")]
        for name in sorted(set(names) - {"configure", "close"}):
            watch.patch(cls, name, modules.get(name, modules["*"]))
        watch.patch(cls, "configure", "set-up")
    watch.patch(Runner, "_finish", "report")


def fly(building: str, seed: int, max_time: float, out: Path, extra: Sequence[str] = ()) -> dict[str, Any]:
    """One instrumented flight: its figures. ``extra``: further mission overrides (``KEY=VALUE``)."""
    from amslam.mission import load_mission
    from amslam.registry import build_plugin_manager
    from amslam.runner import Runner

    mission_name, overrides = BUILDINGS[building]
    overrides = [*overrides, *extra, f"seed={seed}"]
    if max_time > 0:
        overrides.append(f"limits.max_time={max_time:g}")
    registry = build_plugin_manager()
    mission = load_mission(mission_name, registry, overrides)
    watch = Stopwatch()
    instrument(watch, registry, mission)
    load_before = os.getloadavg()[0]
    cpu0, wall0 = time.process_time(), time.perf_counter()
    try:
        result = Runner(mission, registry, out).run()
    finally:
        watch.restore()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    metrics = result.metrics
    sim_s = float(metrics.get("sim_duration_s") or 0.0)
    rate = mission.model.exploration.control_rate_hz
    ticks = max(1, round(sim_s * rate))
    setup, report = watch.own.pop("set-up", 0.0), watch.own.pop("report", 0.0)
    loop = wall - setup - report
    own = dict(watch.own)
    own["other"] = loop - sum(own.values())
    return {
        "building": building,
        "overrides": overrides,
        "run_dir": str(result.run_dir),
        "verdict": metrics.get("verdict"),
        "explored_percent": metrics.get("explored_percent"),
        "reachable_free_volume_m3": metrics.get("reachable_free_volume_m3"),
        "sim_s": sim_s,
        "ticks": ticks,
        "wall_s": wall,
        "cpu_s": cpu,
        "setup_s": setup,
        "report_s": report,
        "loop_s": loop,
        "realtime_factor": sim_s / loop if loop > 0 else float("nan"),
        "realtime_factor_cpu": sim_s / (cpu - setup - report) if cpu > setup + report else float("nan"),
        "ms_per_tick": {m: 1e3 * own.get(m, 0.0) / ticks for m in ORDER},
        "calls": dict(watch.calls),
        "load": [load_before, os.getloadavg()[0]],
    }


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown: one column per building, one row per module (ms per tick), then the totals."""
    head = "| | " + " | ".join(r["building"] for r in rows) + " |"
    lines = [head, "|---" + "|---:" * len(rows) + "|"]

    def line(label: str, values: list[str]) -> None:
        lines.append(f"| {label} | " + " | ".join(values) + " |")

    line("reachable free volume, m³", [f"{r['reachable_free_volume_m3'] or 0:.0f}" for r in rows])
    line("explored, %", [f"{r['explored_percent'] or 0:.1f}" for r in rows])
    line("simulated s (ticks)", [f"{r['sim_s']:.0f} ({r['ticks']})" for r in rows])
    line("**real-time factor** (wall)", [f"**{r['realtime_factor']:.2f}×**" for r in rows])
    line("real-time factor (CPU)", [f"{r['realtime_factor_cpu']:.2f}×" for r in rows])
    for m in ORDER:
        line(f"{m}, ms/tick", [f"{r['ms_per_tick'][m]:.2f}" for r in rows])
    line("loop, ms/tick", [f"{1e3 * r['loop_s'] / r['ticks']:.2f}" for r in rows])
    line("set-up / report, s", [f"{r['setup_s']:.1f} / {r['report_s']:.1f}" for r in rows])
    line("load average (start, end)", [f"{r['load'][0]:.1f}, {r['load'][1]:.1f}" for r in rows])
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """ms per tick of each module against reachable free volume, log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted(rows, key=lambda r: r["reachable_free_volume_m3"] or 0)
    x = [max(r["reachable_free_volume_m3"] or 1.0, 1.0) for r in rows]
    fig, ax = plt.subplots(figsize=(9, 5))
    colours = plt.get_cmap("tab20").colors  # twelve modules: tab10 would repeat two colours
    for i, m in enumerate(ORDER):
        y = [max(r["ms_per_tick"][m], 1e-3) for r in rows]
        ax.plot(x, y, marker="o", label=m, color=colours[(2 * i) % 20 + (2 * i) // 20])
    total = [1e3 * r["loop_s"] / r["ticks"] for r in rows]
    ax.plot(x, total, marker="s", color="black", linewidth=2, label="whole loop")
    for xi, yi, r in zip(x, total, rows, strict=True):
        ax.annotate(r["building"], (xi, yi), textcoords="offset points", xytext=(0, 8), ha="center")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("reachable free volume of the building, m³")
    ax.set_ylabel("wall time per control tick, ms")
    ax.set_title("Mission time per module against building size")
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buildings", default="demo,floors3,hall", help="of demo, floors3, hall")
    parser.add_argument("--seed", type=int, default=7, help="the seed of every building (default 7)")
    parser.add_argument(
        "--max-time", type=float, default=400.0, help="simulated seconds per flight (0: the mission's limit)"
    )
    parser.add_argument("--out", default="runs", help="where the benchmark folder is made")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a mission override for every flight, as `amslam run --set` (the cost of a parameter)",
    )
    args = parser.parse_args(argv)
    names = [b.strip() for b in args.buildings.split(",") if b.strip()]
    unknown = [b for b in names if b not in BUILDINGS]
    if unknown:
        parser.error(f"--buildings: unknown {', '.join(unknown)}; known: {', '.join(BUILDINGS)}")
    folder = Path(args.out) / f"mission-benchmark-{time.strftime('%Y%m%d-%H%M%S')}"
    folder.mkdir(parents=True)
    print(f"benchmark folder: {folder}", flush=True)
    rows = []
    for name in names:
        print(f"flying {name} (seed {args.seed}) ...", flush=True)
        row = fly(name, args.seed, args.max_time, folder / "runs", args.set)
        print(
            f"  {row['verdict']}: {row['sim_s']:.0f} s simulated in {row['loop_s']:.0f} s "
            f"({row['realtime_factor']:.2f}× real time), load {row['load'][0]:.1f}",
            flush=True,
        )
        rows.append(row)
        (folder / "results.json").write_text(json.dumps(rows, indent=1))
    text = table(rows)
    (folder / "table.md").write_text(text + "\n")
    plot(rows, folder / "mission.png")
    print(text)
    print(f"plot: {folder / 'mission.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
