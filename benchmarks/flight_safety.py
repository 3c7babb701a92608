"""Flight safety over many buildings (issue #19): does every flight complete, explore, and never touch?

Flies the procedural buildings over seeds, the shared real house, and any imported world's mission
(``amslam world import`` writes one), each with its mission's own stack, and prints one row per
flight and a summary: flights completed, contacts (closest approach at or below the robot's
radius), explored share of the reachable free volume (min, mean ± std, how many ≥ 90 %), and the
distribution of the closest approach (min, 5th percentile, median), overall and per building.

Buildings: ``demo`` (the demo mission: two 14 × 10 m floors and a shaft, one generated building
per seed), ``floors1`` and ``floors3`` (the same generator with one and three floors), ``house``
(``missions/small_house.yaml``, the shared real house). ``--world MISSION.yaml`` adds an imported
world, flown once at its mission's seed.

    .venv/bin/python benchmarks/flight_safety.py --demo-seeds 20 --seeds 3    # docs/experiments.md
    .venv/bin/python benchmarks/flight_safety.py --buildings house --world imported/cafe/mission.yaml
    .venv/bin/python benchmarks/flight_safety.py --ray                         # flights as Ray tasks
    .venv/bin/python benchmarks/flight_safety.py --tabulate /tmp/sweep         # flown already

Flights run through :mod:`amslam.apps.flights` (serially, or as Ray tasks with ``--ray``;
``--resume FOLDER`` goes on in an earlier benchmark folder). ``--tabulate FOLDER ...`` flies
nothing: it tables every run folder (a folder with ``metrics.json``) found under the folders
given, for sweeps flown by hand (``amslam run ... --out FOLDER``). Results: ``results.json`` and
``table.md`` in the benchmark folder, printed as well. A flight takes minutes (the demo at about
3× real time on two quiet cores); the default sweep (20 demo seeds, 3 seeds of the one- and
three-floor buildings, the house) is a few hours serially.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
BUILDINGS = {
    "demo": ("demo", []),
    "floors1": ("demo", ["platform.world.floors=1"]),
    "floors3": ("demo", ["platform.world.floors=3"]),
    "house": (str(REPO / "missions" / "small_house.yaml"), []),
}
#: the explored share the issue asks of every flight, percent
EXPLORED_TARGET = 90.0


def flight_row(metrics: dict[str, Any], mission: dict[str, Any], run_dir: str | None) -> dict[str, Any]:
    """One flight's row from its ``metrics.json`` and the mission it flew (the run folder's copy)."""
    close = metrics.get("closest_approach") or {}
    err = metrics.get("final_error") or {}
    acc = (metrics.get("landmarks") or {}).get("accuracy") or {}
    world = (mission.get("platform") or {}).get("world") or {}
    name = mission.get("name", "?")
    if world.get("kind", "procedural") == "procedural" and world.get("floors", 2) != 2:
        name = f"{name}, {world['floors']} floor{'s' if world['floors'] > 1 else ''}"
    clearance, radius = close.get("clearance_m"), close.get("robot_radius_m")
    return {
        "building": name,
        "seed": mission.get("seed"),
        "run_dir": run_dir,
        "verdict": metrics.get("verdict", "?"),
        "explored_pct": metrics.get("explored_percent"),
        "per_floor_pct": metrics.get("explored_percent_per_floor") or [],
        "distance_m": metrics.get("distance_m"),
        "time_s": metrics.get("sim_duration_s"),
        "closest_m": clearance,
        "closest_to": close.get("to"),
        # contact as the simulator judges it: a crash, or the vehicle's sphere reaching a surface
        "contact": str(metrics.get("verdict", "")).startswith("crashed")
        or (clearance is not None and radius is not None and clearance <= radius),
        "vio_m": err.get("vio_position_m"),
        "slam_m": err.get("slam_position_m"),
        "objects": acc.get("objects"),
        "mapped": acc.get("matched"),
        "top_z_m": _highest_point(run_dir),
    }


def _highest_point(run_dir: str | None) -> float | None:
    """The highest point the vehicle flew (m, world z): an open-topped building's test."""
    path = Path(run_dir) / "ground_truth.tum" if run_dir else None
    if path is None or not path.exists():
        return None
    from amslam.rundir import read_tum  # the run folder's own checked reader

    poses = read_tum(path).poses
    return round(float(poses[:, 2].max()), 3) if len(poses) else None


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def summary(rows: list[dict[str, Any]]) -> str:
    """Flights, completed, contacts, explored and the closest-approach distribution of ``rows``."""
    explored = np.array([r["explored_pct"] for r in rows if r["explored_pct"] is not None], float)
    closest = np.array([r["closest_m"] for r in rows if r["closest_m"] is not None], float)
    parts = [
        f"flights {len(rows)}",
        f"completed {sum(r['verdict'] == 'completed' for r in rows)}",
        f"contacts {sum(r['contact'] for r in rows)}",
    ]
    if explored.size:
        parts.append(
            f"explored min {explored.min():.2f}, mean {explored.mean():.2f} ± {explored.std():.2f} %, "
            f"{int((explored >= EXPLORED_TARGET).sum())} of {explored.size} ≥ {EXPLORED_TARGET:.0f} %"
        )
    if closest.size:
        parts.append(
            f"closest approach min {closest.min():.3f}, 5th percentile {np.percentile(closest, 5):.3f}, "
            f"median {np.median(closest):.3f} m"
        )
    return "; ".join(parts)


def tables(rows: list[dict[str, Any]]) -> str:
    """Every flight's row, then the summary per building and over all flights."""
    out = [
        "| building | seed | verdict | explored (%) | per floor (%) | distance (m) | time (s) | "
        "closest approach (m) | to | highest point (m) | VIO / SLAM end error (m) | objects | contact |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        floors = ", ".join(f"{p:.1f}" for p in r["per_floor_pct"])
        objects = f"{r['mapped']}/{r['objects']}" if r["objects"] else "—"
        out.append(
            f"| {r['building']} | {_fmt(r['seed'])} | {r['verdict']} | {_fmt(r['explored_pct'])} | "
            f"{floors} | "
            f"{_fmt(r['distance_m'], 1)} | {_fmt(r['time_s'], 0)} | {_fmt(r['closest_m'], 3)} | "
            f"{r['closest_to'] or '—'} | {_fmt(r['top_z_m'])} | {_fmt(r['vio_m'])} / {_fmt(r['slam_m'])} | "
            f"{objects} | {'**yes**' if r['contact'] else 'no'} |"
        )
    out.append("")
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(r["building"], []).append(r)
    if len(groups) > 1:
        out += [f"- {name}: {summary(group)}" for name, group in groups.items()]
    out.append(f"\n**All: {summary(rows)}**")
    return "\n".join(out) + "\n"


def _flown_mission(run: Path) -> dict[str, Any]:
    """The mission a run flew, as its run folder keeps it (overrides applied); {} if absent."""
    import yaml

    path = run / "mission.yaml"
    return (yaml.safe_load(path.read_text()) or {}) if path.exists() else {}


def _record_row(flight: Any, rec: dict[str, Any]) -> dict[str, Any]:
    """A flown flight's row; a flight that raised has no run folder and is named by its mission."""
    if rec["run_dir"]:
        return flight_row(rec["metrics"], _flown_mission(Path(rec["run_dir"])), rec["run_dir"])
    seed = next((o.split("=", 1)[1] for o in flight.overrides if o.startswith("seed=")), None)
    return flight_row(rec["metrics"], {"name": Path(flight.mission).stem, "seed": seed}, None)


def _run_folders(folders: list[str]) -> list[dict[str, Any]]:
    """The row of every run folder (one holding ``metrics.json``) under ``folders``, in path order."""
    rows = []
    for folder in folders:
        # symbolic links followed: a sweep's final flights gathered as links to their run folders
        found = sorted(
            Path(d) / "metrics.json"
            for d, _, files in os.walk(folder, followlinks=True)
            if "metrics.json" in files
        )
        if not found:
            raise ValueError(f"--tabulate {folder}: no run folder (a folder with metrics.json) under it")
        for path in found:
            rows.append(
                flight_row(json.loads(path.read_text()), _flown_mission(path.parent), str(path.parent))
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--buildings", default=",".join(BUILDINGS), help=f"of {', '.join(BUILDINGS)}")
    ap.add_argument("--demo-seeds", type=int, default=20, help="seeds 1..N of the demo building")
    ap.add_argument("--seeds", type=int, default=3, help="seeds 1..N of every other building")
    ap.add_argument(
        "--world", action="append", default=[], metavar="MISSION", help="an imported world's mission"
    )
    ap.add_argument(
        "--max-time", type=float, help="limits.max_time of every flight, s (default: the mission's)"
    )
    ap.add_argument("--out", default="runs", help="folder that receives the benchmark folder")
    ap.add_argument("--ray", action="store_true", help="fly as Ray tasks (local Ray unless --address)")
    ap.add_argument("--address", help="a Ray cluster")
    ap.add_argument("--resume", metavar="FOLDER", help="an earlier benchmark folder to go on in")
    ap.add_argument(
        "--tabulate", nargs="+", metavar="FOLDER", help="table run folders flown already; fly nothing"
    )
    args = ap.parse_args(argv)
    if args.tabulate:
        try:
            print(tables(_run_folders(args.tabulate)))
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        return 0

    from amslam.apps.flights import Flight, fly_benchmark

    buildings = [b for b in args.buildings.split(",") if b]
    if unknown := [b for b in buildings if b not in BUILDINGS]:
        print(
            f"error: unknown building {', '.join(unknown)}; choose from {', '.join(BUILDINGS)}",
            file=sys.stderr,
        )
        return 2
    if missing := [w for w in args.world if not Path(w).is_file()]:
        print(f"error: --world {missing[0]}: no such mission file", file=sys.stderr)
        return 2
    extra = [f"limits.max_time={args.max_time}"] if args.max_time else []
    flights = []
    for b in buildings:
        mission, overrides = BUILDINGS[b]
        for s in range(1, (args.demo_seeds if b == "demo" else args.seeds) + 1):
            flights.append(Flight(mission, (*overrides, *extra, f"seed={s}")))
    flights += [Flight(str(Path(w).resolve()), tuple(extra)) for w in args.world]
    if (flown := fly_benchmark(flights, args, "flight-safety")) is None:
        return 2
    folder, records = flown
    rows = [_record_row(f, rec) for f, rec in zip(flights, records, strict=True)]
    (folder / "results.json").write_text(json.dumps(rows, indent=2, default=str))
    text = tables(rows)
    (folder / "table.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
