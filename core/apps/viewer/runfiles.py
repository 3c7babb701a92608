"""Reading a run folder for the viewer, whole or incrementally while the run is still writing it.

The streams (``events.jsonl``, ``tree.jsonl``, ``*.tum``) are read from a byte offset and only up
to their last complete line, so a reader polling a run in progress never sees half a record.
The summaries (``map.ply``, ``landmarks.json``, ``metrics.json``) exist once the run has finished.

Everything is turned into small JSON-ready structures, the shapes the page's script expects:

- ``structure``: ``[{id, name, type, parent}, ...]`` in pre-order (root first);
- ``tree``: ``[[t, tick, {node_id: [status, feedback]}, {key: value}], ...]``, changes only;
- ``events``: the event records as written;
- ``traj``: ``{"ground_truth" | "vio" | "slam": [[t, x, y, z, yaw], ...]}``;
- ``static``: ``{"floors", "voxel", "landmarks", "metrics", "bounds"}`` once the run is finished.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amslam.apps.mapformats import read_map_ply
from amslam.errors import RunFileError
from amslam.lib.class_colours import class_hex
from amslam.rundir import TRAJECTORIES, read_landmarks, read_metrics, read_run_mission, tum_values

log = logging.getLogger(__name__)

STREAMS = ("events", "tree", *TRAJECTORIES)
FILES = {
    "events": "events.jsonl",
    "tree": "tree.jsonl",
    "ground_truth": "ground_truth.tum",
    "vio": "vio.tum",
    "slam": "slam.tum",
}
#: a z level of the map holding this many times the median count of its floor's levels is a
#: horizontal surface (floor or ceiling), not walls or furniture
SURFACE_SPIKE = 1.6


def yaw_from_quaternion(qx: float, qy: float, qz: float, qw: float) -> float:
    """Heading (rotation about z) of a unit quaternion, in (-π, π]."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def parse_tum_line(line: str) -> list[float] | None:
    """``t x y z qx qy qz qw`` → ``[t, x, y, z, yaw]`` rounded for the page; None for a bad line
    (:func:`amslam.rundir.tum_values`)."""
    values = tum_values(line)
    if values is None:
        return None
    t, x, y, z, qx, qy, qz, qw = values
    return [round(t, 3), round(x, 3), round(y, 3), round(z, 3), round(yaw_from_quaternion(qx, qy, qz, qw), 4)]


def parse_json_line(line: str) -> dict[str, Any] | None:
    try:
        value = json.loads(line)
    except json.JSONDecodeError:
        return None
    return value if isinstance(value, dict) else None


def tree_record(raw: dict[str, Any]) -> list[Any]:
    """A ``tree.jsonl`` change record in the page's compact form ``[t, tick, nodes, blackboard]``."""
    return [raw.get("t", 0.0), raw.get("tick", 0), raw.get("nodes") or {}, raw.get("blackboard") or {}]


@dataclass
class Chunk:
    """What a poll of one stream returned: new complete lines and the offset after them."""

    lines: list[str]
    offset: int
    reset: bool = False  # the file shrank (rewritten): lines start again from its beginning


def read_lines(path: Path, offset: int = 0) -> Chunk:
    """Complete lines of ``path`` from byte ``offset`` on (a trailing partial line is left for later)."""
    try:
        size = os.path.getsize(path)
    except OSError:
        return Chunk([], 0, reset=offset > 0)
    reset = size < offset
    if reset:
        offset = 0
    if size == offset:
        return Chunk([], offset)
    with open(path, "rb") as f:
        f.seek(offset)
        data = f.read(size - offset)
    end = data.rfind(b"\n")
    if end < 0:
        return Chunk([], offset, reset)
    text = data[: end + 1].decode("utf-8", errors="replace")
    return Chunk([line for line in text.splitlines() if line.strip()], offset + end + 1, reset)


@dataclass
class Delta:
    """New data of a run since a cursor; ``to_json()`` is what the live endpoint sends."""

    cursor: dict[str, int]
    structure: list[dict[str, Any]] | None = None
    tree: list[list[Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    traj: dict[str, list[list[float]]] = field(default_factory=dict)
    reset: list[str] = field(default_factory=list)
    static: dict[str, Any] | None = None
    finished: bool = False

    def to_json(self) -> dict[str, Any]:
        return {
            "cursor": self.cursor,
            "structure": self.structure,
            "tree": self.tree,
            "events": self.events,
            "traj": self.traj,
            "reset": self.reset,
            "static": self.static,
            "finished": self.finished,
        }


def poll_run(run_dir: Path, cursor: dict[str, int] | None = None) -> Delta:
    """Everything new in ``run_dir`` since ``cursor`` (byte offsets per stream; None: from the start).

    The run is finished once ``run_end`` is in the events: the runner writes it after all the
    summaries and after rewriting ``slam.tum`` with the optimised key poses. The poll that first
    sees it sends the summaries and the trajectories again from their start (marked ``reset``);
    ``cursor["ended"]`` remembers that the caller has them.
    """
    run_dir = Path(run_dir)
    cursor = dict(cursor or {})
    delta = Delta(cursor={})
    already_ended = bool(cursor.get("ended"))
    for stream in STREAMS:  # events first: whether the run ended decides how to read the rest
        offset = int(cursor.get(stream, 0))
        newly_ended = delta.finished and not already_ended
        if stream in TRAJECTORIES and newly_ended and offset > 0:
            offset = 0
            delta.reset.append(stream)
        chunk = read_lines(run_dir / FILES[stream], offset)
        delta.cursor[stream] = chunk.offset
        if chunk.reset and stream not in delta.reset:
            delta.reset.append(stream)
        if stream == "events":
            delta.events = [r for r in map(parse_json_line, chunk.lines) if r is not None]
            delta.finished = already_ended or any(e.get("event") == "run_end" for e in delta.events)
        elif stream == "tree":
            for raw in (r for r in map(parse_json_line, chunk.lines) if r is not None):
                if "structure" in raw:
                    delta.structure = raw["structure"]
                else:
                    delta.tree.append(tree_record(raw))
        else:
            delta.traj[stream] = [r for r in map(parse_tum_line, chunk.lines) if r is not None]
    delta.cursor["ended"] = int(delta.finished)
    if delta.finished and not already_ended:
        delta.static = read_summaries(run_dir)
    return delta


# -- summaries --------------------------------------------------------------------------------------


def read_map_points(path: Path) -> tuple[np.ndarray, float | None]:
    """Vertices of a map PLY (N×3) and the voxel size its header gives (None: not given); empty
    when the file is missing, empty or not a PLY."""
    try:
        cloud = read_map_ply(path)
    except (OSError, ValueError):
        return np.zeros((0, 3)), None
    return cloud.points, cloud.voxel_size


def voxel_size(points: np.ndarray) -> float:
    """The lattice spacing of voxel centres: the smallest gap between distinct coordinates."""
    gaps = []
    for axis in range(3):
        values = np.unique(np.round(points[:, axis], 4))
        if len(values) > 1:
            gaps.append(float(np.diff(values).min()))
    return round(min(gaps), 4) if gaps else 0.25


def floor_heights(run_dir: Path, points: np.ndarray) -> list[float]:
    """Heights of the floors' slabs, best source first.

    ``metrics.json`` ``floor_heights`` (the world's truth) when the run recorded it; else the
    simulated world's parameters in ``mission.yaml``; else the map: horizontal surfaces are the
    z levels holding many occupied voxels (floors and ceilings); each floor stands on the top
    of one such band, and the highest band is the roof.
    """
    metrics = _metrics(run_dir)
    with contextlib.suppress(TypeError, ValueError):  # floor heights that are not numbers: the next source
        if metrics.get("floor_heights"):
            return [float(h) for h in metrics["floor_heights"]]
    try:
        world = (read_run_mission(run_dir).get("platform") or {}).get("world") or {}
        if world.get("floor_heights"):
            return [float(h) for h in world["floor_heights"]]
        if world.get("floors") and world.get("floor_height"):
            return [i * float(world["floor_height"]) for i in range(int(world["floors"]))]
    except (RunFileError, AttributeError, TypeError, ValueError):  # the next source
        pass
    return floors_from_map(points)


def floors_from_map(points: np.ndarray, min_storey: float = 1.8) -> list[float]:
    """Floor heights guessed from the z histogram of occupied voxels (see :func:`floor_heights`)."""
    if len(points) == 0:
        return []
    v = voxel_size(points)
    z0 = float(points[:, 2].min())
    levels, counts = np.unique(np.round((points[:, 2] - z0) / v).astype(int), return_counts=True)
    dense = levels[counts >= 0.35 * counts.max()]
    bands: list[list[int]] = []
    for level in dense:
        if bands and level - bands[-1][-1] <= 2:
            bands[-1].append(int(level))
        else:
            bands.append([int(level)])
    heights: list[float] = []
    # A floor stands on the top of a band (a slab, or a ceiling with the next slab); the last is the roof.
    for band in bands[:-1]:
        top = z0 + (band[-1] + 0.5) * v
        if not heights or top - heights[-1] >= min_storey:
            heights.append(top)
    if not heights:
        heights = [z0]
    return [round(h, 3) for h in heights]


def slice_levels(z: np.ndarray, v: float) -> tuple[float, float]:
    """The z range of a floor's points to look at from above: above its floor, below its ceiling.

    Walls add about as many voxels to every level; a floor or a ceiling adds a spike. Spikes in
    the lower half of the floor are its floor surface, in the upper half its ceiling.
    """
    if len(z) == 0:
        return math.inf, -math.inf
    levels, counts = np.unique(np.round(z / v).astype(np.int64), return_counts=True)
    spikes = levels[counts > SURFACE_SPIKE * np.median(counts)]
    middle = (levels[0] + levels[-1]) / 2
    lower = spikes[spikes <= middle]
    upper = spikes[spikes > middle]
    low = (lower.max() + 0.5) * v if len(lower) else -math.inf
    high = (upper.min() - 0.5) * v if len(upper) else math.inf
    return float(low), float(high)


def floor_slices(points: np.ndarray, heights: list[float]) -> list[dict[str, Any]]:
    """Per floor, the occupied columns seen from above: ``[[x, y, n], ...]`` with n voxels in the slice.

    A floor spans ``[heights[i], heights[i+1])``; its slice leaves out its floor and ceiling
    surfaces (:func:`slice_levels`) so walls and furniture remain, and ``n`` (voxels in the
    column) tells a wall from a chair.
    """
    if not heights:
        heights = [float(points[:, 2].min()) if len(points) else 0.0]
    tops = [*heights[1:], math.inf]
    v = voxel_size(points) if len(points) else 0.25
    origin = points.min(axis=0) if len(points) else np.zeros(3)
    floors = []
    for lo, hi in zip(heights, tops, strict=True):
        inside = points[(points[:, 2] >= lo) & (points[:, 2] < hi)]
        # levels relative to the lowest centre: rounding centres like 0.125 / 0.25 directly would
        # send neighbours to one cell (round half to even)
        low, high = slice_levels(inside[:, 2] - origin[2], v) if len(points) else (0.0, 0.0)
        rel = inside[:, 2] - origin[2]
        inside = inside[(rel > low) & (rel < high)]
        cells: list[list[float]] = []
        if len(inside):
            keys = np.round((inside[:, :2] - origin[:2]) / v).astype(np.int64)
            uniq, counts = np.unique(keys, axis=0, return_counts=True)
            xy = np.round(origin[:2] + uniq * v, 3)
            cells = [[float(x), float(y), int(n)] for (x, y), n in zip(xy, counts, strict=True)]
        floors.append({"lo": round(lo, 3), "hi": None if math.isinf(hi) else round(hi, 3), "cells": cells})
    return floors


def page_landmarks(path: Path) -> list[dict[str, Any]]:
    """``landmarks.json`` (:func:`amslam.rundir.read_landmarks`) as the page's
    ``{id, class, p: [x, y, z], sigma: √(tr Σ), n}``; empty when the file is missing, or, with a
    warning, when it cannot be read (the page shows the rest of the run)."""
    if not path.is_file():
        return []
    try:
        landmarks = read_landmarks(path)
    except RunFileError as exc:
        log.warning(f"{exc}: the landmarks left out")
        return []
    out = []
    for lm in landmarks:
        cov = np.asarray(lm.get("covariance") or np.zeros((3, 3)), float)
        out.append(
            {
                "id": lm.get("id"),
                "class": lm["class"],
                "p": [round(float(c), 3) for c in lm["position"]],
                "sigma": round(float(math.sqrt(max(np.trace(cov), 0.0))), 4),
                "n": lm.get("observations", 0),
            }
        )
    return out


METRIC_KEYS = (
    "verdict",
    "mission",
    "seed",
    "plugins",
    "sim_duration_s",
    "distance_m",
    "explored_percent",
    "explored_percent_per_floor",
    "explored_volume_m3",
    "final_error",
    "landmarks",
    "keyposes",
)


def _metrics(run_dir: Path) -> dict[str, Any]:
    """``metrics.json`` (:func:`amslam.rundir.read_metrics`), empty while the run has not written
    it or when it does not read (the page shows what the other files hold)."""
    try:
        return read_metrics(Path(run_dir) / "metrics.json")
    except RunFileError:
        return {}


def read_summaries(run_dir: Path) -> dict[str, Any]:
    """The end-of-run files: the map sliced per floor, the landmarks (and their classes' colours,
    :mod:`amslam.lib.class_colours`) and the headline metrics."""
    points, voxel = read_map_points(run_dir / "map.ply")
    heights = floor_heights(run_dir, points)
    metrics = _metrics(run_dir)
    landmarks = page_landmarks(run_dir / "landmarks.json")
    return {
        "voxel": voxel or (voxel_size(points) if len(points) else None),
        "floors": floor_slices(points, heights),
        "landmarks": landmarks,
        "class_colours": {lm["class"]: class_hex(lm["class"]) for lm in landmarks},
        "metrics": {k: metrics[k] for k in METRIC_KEYS if k in metrics},
    }


def mission_info(run_dir: Path) -> dict[str, Any]:
    """Name and floors from ``mission.yaml`` (known from the start of a run, unlike the map)."""
    info: dict[str, Any] = {"folder": Path(run_dir).resolve().name}
    try:
        mission = read_run_mission(run_dir)
        info["mission"] = mission.get("name")
        info["description"] = mission.get("description")
        info["plugins"] = {
            kind: (mission.get(kind) or {}).get("plugin")
            for kind in ("platform", "mapping", "slam", "detector", "planner")
            if isinstance(mission.get(kind), dict)
        }
    except RunFileError:  # the page shows what the other files hold
        pass
    info["floor_heights"] = floor_heights(Path(run_dir), np.zeros((0, 3)))
    return info
