"""A finished run folder read strictly for export: every record checked, every problem located.

The viewer reads run folders leniently (a run in progress, bad lines skipped); an export is a
file handed to other tools, so here a malformed record is an :class:`ExportError` naming the
file and line. Only a partial *last* line of a stream is forgiven (a run killed mid-write leaves
one): it is dropped with a warning. A missing optional file (``landmarks.json``, ``map.npz``, ...)
is a warning; its topics are left out.

The files are read by the modules that write them (the trajectories and ``landmarks.json``:
:mod:`amslam.rundir`; ``map.npz``: :mod:`amslam.lib.voxel_map`; ``map.ply``:
:mod:`amslam.apps.mapformats`); the streams ``events.jsonl`` and ``tree.jsonl`` are checked here
record by record, for what an export needs of them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amslam.apps.mapformats import read_map_ply
from amslam.errors import AmslamError, RunFileError
from amslam.lib.voxel_map import DEFAULT_P_OCC, read_saved_map
from amslam.measurements import read_measurements_header
from amslam.rundir import (
    TRAJECTORIES,
    Trajectory,
    read_jsonl,
    read_landmarks,
    read_metrics,
    read_run_mission,
    read_tum,
)
from amslam.types import CameraModel


class ExportError(AmslamError):
    """A run folder that cannot be exported; the message names the file (and line)."""


@dataclass
class VoxelCloud:
    """Occupied voxels: N×3 centres and named per-voxel values (e.g. occupancy probability)."""

    points: np.ndarray
    voxel: float | None
    values: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class CameraMount:
    """``T_body_cam`` (4×4) and where it came from, for the user to see what was assumed."""

    T_body_cam: np.ndarray
    source: str


@dataclass
class RunFolder:
    """What an export needs of a run folder; None / empty where the run folder did not have it."""

    path: Path
    mission_name: str
    trajectories: dict[str, Trajectory]
    events: list[dict[str, Any]]
    tree_structure: list[dict[str, Any]] | None
    tree_records: list[dict[str, Any]]
    landmarks: list[dict[str, Any]] | None
    global_map: VoxelCloud | None
    local_map: VoxelCloud | None
    camera: CameraMount
    metrics: dict[str, Any] | None
    warnings: list[str]

    @property
    def start(self) -> float:
        """The first simulated (or vehicle) time any stream recorded, s."""
        times = [float(t.stamps[0]) for t in self.trajectories.values() if len(t)]
        times += [float(e["t"]) for e in self.events[:1]]
        times += [float(r["t"]) for r in self.tree_records[:1]]
        return min(times) if times else 0.0

    @property
    def end(self) -> float:
        times = [float(t.stamps[-1]) for t in self.trajectories.values() if len(t)]
        times += [float(e["t"]) for e in self.events[-1:]]
        times += [float(r["t"]) for r in self.tree_records[-1:]]
        return max(times) if times else 0.0


def read_run_folder(path: Path) -> RunFolder:
    """Read ``path`` for export.

    Raises:
        ExportError: the folder is missing or not a run folder, or one of its files is malformed.
    """
    try:
        return _read_run_folder(Path(path))
    except RunFileError as exc:  # a file read by its format's own reader: the message names it
        raise ExportError(str(exc)) from None


def _read_run_folder(path: Path) -> RunFolder:
    if not path.is_dir():
        raise ExportError(f"{path}: no such run folder")
    if not (path / "events.jsonl").is_file() and not any((path / f"{n}.tum").is_file() for n in TRAJECTORIES):
        raise ExportError(f"{path}: not a run folder (no events.jsonl, no ground_truth/vio/slam .tum)")
    warnings: list[str] = []

    def missing(name: str, skipped: str) -> None:
        warnings.append(f"{path / name} missing: {skipped} left out")

    trajectories = {}
    for name in TRAJECTORIES:
        file = path / f"{name}.tum"
        if file.is_file():
            trajectories[name] = read_tum(file, warnings)
        else:
            missing(f"{name}.tum", f"the {name} path, odometry and frames")
    events = []
    if (path / "events.jsonl").is_file():
        events = _read_jsonl(path / "events.jsonl", warnings, _check_event)
    else:
        missing("events.jsonl", "events, the tour and SLC viewpoints")
    structure, records = None, []
    if (path / "tree.jsonl").is_file():
        structure, records = read_tree(path / "tree.jsonl", warnings)
    else:
        missing("tree.jsonl", "the behaviour-tree status")
    mission = _read_mission(path / "mission.yaml", warnings)
    landmarks = None
    if (path / "landmarks.json").is_file():
        landmarks = read_landmarks(path / "landmarks.json")
    else:
        missing("landmarks.json", "the landmarks")
    p_occ = _nested(mission, "mapping", "p_occ", default=DEFAULT_P_OCC)
    if not isinstance(p_occ, int | float) or not 0.0 < p_occ < 1.0:
        raise ExportError(f"{path / 'mission.yaml'}: mapping.p_occ must be a probability, got {p_occ!r}")
    global_map = local_map = None
    if (path / "map.npz").is_file():
        global_map, local_map = read_voxel_maps(path / "map.npz", float(p_occ))
    elif (path / "map.ply").is_file():
        global_map = map_ply_cloud(path / "map.ply")
        # map.ply carries each voxel's probability since it became binary; older ones do not
        lost = "the final local map"
        if "probability" not in global_map.values:
            lost = "the occupancy probabilities and " + lost
        missing("map.npz", lost)
    else:
        missing("map.npz (and map.ply)", "the map")
    metrics = None
    if (path / "metrics.json").is_file():
        metrics = read_metrics(path / "metrics.json")
    name = (metrics or {}).get("mission") or (mission or {}).get("name") or path.name
    return RunFolder(
        path=path,
        mission_name=str(name),
        trajectories=trajectories,
        events=events,
        tree_structure=structure,
        tree_records=records,
        landmarks=landmarks,
        global_map=global_map,
        local_map=local_map,
        camera=camera_mount(path, mission, warnings),
        metrics=metrics,
        warnings=warnings,
    )


# -- streams ----------------------------------------------------------------------------------------


def _check_event(record: dict[str, Any]) -> str | None:
    if not isinstance(record.get("t"), int | float) or not isinstance(record.get("event"), str):
        return "an event needs a number 't' and a string 'event'"
    if record["event"] == "replan":
        tour = record.get("tour")
        ok = isinstance(tour, list) and all(
            isinstance(s, list) and len(s) == 4 and all(isinstance(v, int | float) for v in s[1:])
            for s in tour
        )
        if not ok:
            return "a replan event's 'tour' must be a list of [kind, x, y, z]"
    return None


def _read_jsonl(
    file: Path, warnings: list[str], check: Callable[[dict[str, Any]], str | None]
) -> list[dict[str, Any]]:
    """The records of a stream (:func:`amslam.rundir.read_jsonl`), each checked by ``check``."""
    records = []
    for number, record in read_jsonl(file, warnings):
        problem = check(record)
        if problem:
            raise ExportError(f"{file}:{number}: {problem}")
        records.append(record)
    return records


def _check_tree_record(record: dict[str, Any]) -> str | None:
    if "structure" in record:
        nodes = record["structure"]
        ok = isinstance(nodes, list) and all(isinstance(n, dict) and "id" in n and "name" in n for n in nodes)
        return None if ok else "'structure' must be a list of nodes with 'id' and 'name'"
    if not isinstance(record.get("t"), int | float):
        return "a tree record needs a number 't'"
    if not isinstance(record.get("nodes", {}), dict) or not isinstance(record.get("blackboard", {}), dict):
        return "'nodes' and 'blackboard' must be JSON objects"
    return None


def read_tree(file: Path, warnings: list[str]) -> tuple[list[dict[str, Any]] | None, list[dict[str, Any]]]:
    """``tree.jsonl``: the structure (first record) and the change records after it."""
    structure = None
    records = []
    for record in _read_jsonl(file, warnings, _check_tree_record):
        if "structure" in record:
            structure = record["structure"]
        else:
            records.append(record)
    return structure, records


# -- summaries --------------------------------------------------------------------------------------


def _is_vector(value: Any, n: int) -> bool:
    return (
        isinstance(value, list)
        and len(value) == n
        and all(isinstance(v, int | float) and math.isfinite(v) for v in value)
    )


def read_voxel_maps(file: Path, p_occ: float) -> tuple[VoxelCloud, VoxelCloud | None]:
    """The global and local maps of ``map.npz`` (:func:`amslam.lib.voxel_map.read_saved_map`):
    occupied voxels with their occupancy probability; the local map None when it was not saved.

    A voxel is occupied when its log-odds exceed ``logit(p_occ)``, the rule of the mapping
    plugins (``core/lib/voxel_grid.py``), so the global cloud is exactly ``map.ply``'s points.
    """
    saved = read_saved_map(file)
    maps = []
    for grid in (saved.global_map, saved.local_map):
        if grid is None:  # a saved map without its local window
            maps.append(None)
            continue
        occupied = grid.occupied(p_occ)
        maps.append(
            VoxelCloud(grid.centres()[occupied], grid.voxel, {"probability": grid.probability()[occupied]})
        )
    return maps[0], maps[1]


def map_ply_cloud(file: Path) -> VoxelCloud:
    """The points of ``map.ply`` (:func:`amslam.apps.mapformats.read_map_ply`: the binary one with
    class and probability per voxel, or the ASCII x, y, z of older runs) with their class and,
    where the file knows it, their occupancy probability."""
    try:
        cloud = read_map_ply(file)
    except ValueError as exc:  # names the file already
        raise ExportError(str(exc)) from None
    except OSError as exc:
        raise ExportError(f"{file}: cannot be read ({exc})") from None
    values: dict[str, np.ndarray] = {}
    if np.isfinite(cloud.probability).any():
        values["probability"] = cloud.probability.astype(float)
    values["class"] = cloud.classes.astype(float)
    return VoxelCloud(cloud.points, cloud.voxel_size, values)


# -- mission and camera -----------------------------------------------------------------------------


def _read_mission(file: Path, warnings: list[str]) -> dict[str, Any] | None:
    if not file.is_file():
        warnings.append(f"{file} missing: occupancy threshold p_occ = {DEFAULT_P_OCC} assumed")
        return None
    try:
        return read_run_mission(file)
    except RunFileError as exc:
        raise ExportError(str(exc)) from None


def _nested(data: dict[str, Any] | None, *keys: str, default: Any = None) -> Any:
    for key in keys:
        if not isinstance(data, dict) or key not in data:
            return default
        data = data[key]
    return data if data is not None else default


def camera_mount(path: Path, mission: dict[str, Any] | None, warnings: list[str]) -> CameraMount:
    """The camera mount the run used: the one recorded in ``measurements.jsonl``'s header, else
    the mission's (the simulator's ``platform.camera.pitch_deg``, a MAVSDK camera's
    ``mount_pitch_deg`` and ``mount_xyz``), else a forward-looking camera at the body origin."""
    file = path / "measurements.jsonl"
    if file.is_file():
        try:
            T = np.asarray(read_measurements_header(file)["T_body_cam"], float)
            if T.shape == (4, 4) and np.all(np.isfinite(T)):
                return CameraMount(T, f"{file.name} header")
        except (RunFileError, KeyError, TypeError, ValueError):  # no usable header: the mission's mount
            pass
        warnings.append(f"{file}:1: no T_body_cam in the header; camera mount taken from the mission")
    camera = _nested(mission, "platform", "camera", default={})
    if isinstance(camera, dict):
        if isinstance(camera.get("pitch_deg"), int | float):
            return CameraMount(
                CameraModel.forward_mount(float(camera["pitch_deg"])), "mission.yaml pitch_deg"
            )
        if isinstance(camera.get("mount_pitch_deg"), int | float):
            xyz = camera.get("mount_xyz")
            offset = tuple(float(v) for v in xyz) if _is_vector(xyz, 3) else (0.0, 0.0, 0.0)
            return CameraMount(
                CameraModel.forward_mount(float(camera["mount_pitch_deg"]), offset),  # type: ignore[arg-type]
                "mission.yaml mount_pitch_deg/mount_xyz",
            )
    warnings.append(
        "the run folder does not state the camera mount: a level, forward-looking camera at the body "
        "origin assumed for base_link → camera_optical"
    )
    return CameraMount(CameraModel.forward_mount(), "assumed: level, forward, at the body origin")
