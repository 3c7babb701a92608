"""A small run folder written by hand: every file the viewer reads, with known contents.

The robot flies a square around a 6 × 4 m room (one floor, floor slab at z = 0, ceiling at
2.75 m), the tree goes TakeOff → Explore → Land, one replan holds an SLC stop, one loop closure is
accepted. ``write_run(folder, until=t)`` writes only what exists at time ``t`` — a run in
progress — so tests can append the rest and watch a poll pick it up.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import yaml

STRUCTURE = [
    {"id": 0, "name": "Mission", "type": "Sequence", "parent": None},
    {"id": 1, "name": "TakeOff", "type": "TakeOff", "parent": 0},
    {"id": 2, "name": "Explore", "type": "Sequence", "parent": 0},
    {"id": 3, "name": "Replan", "type": "Replan", "parent": 2},
    {"id": 4, "name": "GoToViewpoint", "type": "GoTo", "parent": 2},
    {"id": 5, "name": "Land", "type": "Land", "parent": 0},
]
INVALID = ["INVALID", ""]
TREE = [
    {
        "t": 0.1,
        "tick": 1,
        "nodes": {
            "0": ["RUNNING", ""],
            "1": ["RUNNING", "climbing"],
            **{str(i): INVALID for i in range(2, 6)},
        },
        "blackboard": {"/tour": [], "/goal": None},
    },
    {"t": 2.0, "tick": 20, "nodes": {"1": ["SUCCESS", "at 1.20 m"]}, "blackboard": {}},
    {
        "t": 2.1,
        "tick": 21,
        "nodes": {
            "2": ["RUNNING", ""],
            "3": ["SUCCESS", "3 stops, next explore"],
            "4": ["RUNNING", "waypoint 1/4"],
        },
        "blackboard": {"/tour": [["explore", 5.0, 1.0, 1.2]], "/goal": ["explore", 5.0, 1.0, 1.2]},
    },
    {"t": 6.0, "tick": 60, "nodes": {"4": ["RUNNING", "waypoint 3/4"]}, "blackboard": {}},
    {
        "t": 12.0,
        "tick": 120,
        "nodes": {"2": ["SUCCESS", ""], "4": ["SUCCESS", "arrived"], "5": ["RUNNING", "descending"]},
        "blackboard": {"/goal": None},
    },
    {"t": 15.0, "tick": 150, "nodes": {"0": ["SUCCESS", ""], "5": ["SUCCESS", "landed"]}, "blackboard": {}},
]
EVENTS = [
    {"t": 0.0, "event": "run_start", "mission": "synthetic"},
    {
        "t": 2.1,
        "event": "replan",
        "tour": [["explore", 5.0, 1.0, 1.2], ["slc", 5.0, 3.0, 1.2], ["explore", 1.0, 3.0, 1.2]],
        "viewpoints": 7,
    },
    {"t": 6.0, "event": "goal_done", "goal": [5.0, 1.0, 1.2], "why": "arrived", "behaviour": "GoToViewpoint"},
    {"t": 6.1, "event": "replan", "tour": [["slc", 5.0, 3.0, 1.2]], "viewpoints": 3},
    {
        "t": 9.0,
        "event": "loop_closure",
        "accepted": True,
        "reason": "4 landmarks agree </script><b>",
        "matched": 4,
    },
    {"t": 15.0, "event": "mission_end", "exploration": "complete", "landing": "landed"},
    {"t": 15.1, "event": "run_end", "verdict": "completed"},
]
LANDMARKS = [
    {
        "id": 1,
        "class": "chair",
        "position": [2.0, 2.0, 0.5],
        "covariance": np.eye(3).tolist(),
        "observations": 9,
    },
    {
        "id": 2,
        "class": "table",
        "position": [4.0, 2.5, 0.7],
        "covariance": (0.01 * np.eye(3)).tolist(),
        "observations": 4,
    },
]
WALL_X = (0.0, 6.0)
WALL_Y = (0.0, 4.0)
VOXEL = 0.25


def pose(t: float) -> tuple[float, float, float, float]:
    """Ground truth at ``t``: climb for 2 s, then a square (1,1)→(5,1)→(5,3)→(1,3) in 10 s, then land."""
    corners = [(1.0, 1.0), (5.0, 1.0), (5.0, 3.0), (1.0, 3.0), (1.0, 1.0)]
    if t <= 2.0:
        return 1.0, 1.0, 0.2 + 0.5 * t, 0.0
    if t >= 12.0:
        return 1.0, 1.0, max(0.2, 1.2 - 0.3 * (t - 12.0)), -math.pi / 2
    s = (t - 2.0) / 10.0 * 4  # which side, and how far along it
    k = min(int(s), 3)
    (x0, y0), (x1, y1) = corners[k], corners[k + 1]
    f = s - k
    return x0 + f * (x1 - x0), y0 + f * (y1 - y0), 1.2, math.atan2(y1 - y0, x1 - x0)


def tum(t: float, x: float, y: float, z: float, yaw: float) -> str:
    return f"{t:.6f} {x:.6f} {y:.6f} {z:.6f} 0 0 {math.sin(yaw / 2):.9f} {math.cos(yaw / 2):.9f}\n"


def room_points() -> np.ndarray:
    """Voxel centres of the room: a floor slab, four walls up to a ceiling, and one box (a table)."""
    h = VOXEL / 2
    xs = np.arange(WALL_X[0] + h, WALL_X[1], VOXEL)
    ys = np.arange(WALL_Y[0] + h, WALL_Y[1], VOXEL)
    zs = np.arange(h, 2.75, VOXEL)
    pts = []
    for x in xs:
        for y in ys:
            pts.append((x, y, h))  # floor
            pts.append((x, y, 2.75 + h))  # ceiling
            if x in (xs[0], xs[-1]) or y in (ys[0], ys[-1]):
                pts += [(x, y, z) for z in zs[1:]]  # walls
    pts += [(x, y, z) for x in (3.875, 4.125) for y in (2.375, 2.625) for z in (0.375, 0.625)]  # table
    return np.round(np.array(pts), 3)


def write_run(folder: Path, until: float = math.inf, with_summaries: bool | None = None) -> Path:
    """Write the run as it stands at time ``until`` into ``folder`` (created); returns the folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    finished = until >= EVENTS[-1]["t"] if with_summaries is None else with_summaries
    mission = {
        "name": "synthetic",
        "description": "a hand-written run",
        "platform": {"plugin": "sim", "world": {"kind": "procedural", "floors": 1, "floor_height": 3.0}},
        "slam": {"plugin": "gtsam"},
        "planner": {"plugin": "cop"},
    }
    (folder / "mission.yaml").write_text(yaml.safe_dump(mission, sort_keys=False))
    lines = [json.dumps({"structure": STRUCTURE})] + [json.dumps(r) for r in TREE if r["t"] <= until]
    _grow(folder / "tree.jsonl", "\n".join(lines) + "\n")
    stamps = [round(0.1 * i, 1) for i in range(1, 151) if 0.1 * i <= until + 1e-9]
    for name, offset in (("ground_truth", 0.0), ("vio", 0.15), ("slam", 0.05)):
        text = ""
        for t in stamps:
            x, y, z, yaw = pose(t)
            text += tum(t, x + offset * t / 15, y, z, yaw)
        _grow(folder / f"{name}.tum", text)
    if finished:
        (folder / "landmarks.json").write_text(json.dumps(LANDMARKS))
        points = room_points()
        with open(folder / "map.ply", "w") as f:
            f.write(f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n")
            f.write("property float x\nproperty float y\nproperty float z\nend_header\n")
            np.savetxt(f, points, fmt="%.3f")
        metrics = {
            "verdict": "completed",
            "mission": "synthetic",
            "explored_percent": 97.5,
            "distance_m": 12.0,
        }
        (folder / "metrics.json").write_text(json.dumps(metrics))
    # events last: the runner writes run_end after every summary, and a live reader that sees it
    # reads them at once (written earlier, a poll in between showed a finished run with no verdict)
    _grow(folder / "events.jsonl", "".join(json.dumps(e) + "\n" for e in EVENTS if e["t"] <= until))
    return folder


def _grow(path: Path, text: str) -> None:
    """Write a stream's whole text so a live reader sees it grow, as a run's appended stream does.

    Rewriting in place truncates the file first: a poll at that moment could see it shrink, which a
    live run's streams never do (the likely cause of one failure of
    test_live_view_follows_a_run_in_progress in a loaded fresh-clone suite, not reproduced in six
    runs). Replacing it whole keeps every byte a reader has read.
    """
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
