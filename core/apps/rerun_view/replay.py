"""A run folder into a rerun recording: what ``amslam view RUN --rerun`` shows."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from amslam.apps.rerun_view.scene import SOURCES, Scene, parse_tum
from amslam.apps.viewer.runfiles import FILES, parse_json_line, read_lines
from amslam.errors import AmslamError, RunFileError
from amslam.rundir import read_landmarks

log = logging.getLogger(__name__)


class StreamTail:
    """The complete lines each stream of a run folder gained since the last call (a live run is
    read as it is written; a finished one in one call)."""

    def __init__(self, run_dir: Path):
        self.run_dir = Path(run_dir)
        self.offsets: dict[str, int] = {}

    def lines(self, stream: str) -> list[str]:
        chunk = read_lines(self.run_dir / FILES[stream], self.offsets.get(stream, 0))
        self.offsets[stream] = chunk.offset
        return chunk.lines

    def records(self, stream: str) -> list[dict[str, Any]]:
        return [r for r in map(parse_json_line, self.lines(stream)) if r is not None]


def log_events(scene: Scene, records: list[dict[str, Any]], *, tours: bool = True) -> None:
    """Events as text; with ``tours``, the tour of each ``replan`` and each loop closure too (the
    live view gets those from their hooks instead)."""
    for record in records:
        scene.at(float(record.get("t", 0.0)))
        scene.event(record)
        if not tours:
            continue
        if record.get("event") == "replan":
            scene.tour([(str(s[0]), s[1:4]) for s in record.get("tour") or [] if len(s) >= 4])
        elif record.get("event") == "loop_closure":
            scene.loop_closure(
                bool(record.get("accepted")), str(record.get("reason", "")), record.get("matched", 0)
            )


def log_tree(scene: Scene, names: dict[int, str], records: list[dict[str, Any]]) -> int:
    """The tree's changes as text lines; ``names`` (node id → name) is filled from the structure
    record. Returns the number of lines logged."""
    logged = 0
    for record in records:
        if "structure" in record:
            names.update({int(n["id"]): str(n["name"]) for n in record["structure"]})
            continue
        scene.at(float(record.get("t", 0.0)))
        logged += scene.tree(names, record.get("nodes") or {})
    return logged


def read_map(run_dir: Path) -> tuple[np.ndarray, float | None, list[str] | None]:
    """Occupied voxel centres of the run's map, its voxel size and, when the file names any, the
    voxels' classes (None when every voxel is ``none``): ``map.ply`` (binary with class per voxel,
    or the ASCII one of older runs, read by :func:`amslam.apps.mapformats.read_map_ply`), else
    ``map.npz`` (voxels above the default occupancy probability, 0.8, read by
    :func:`amslam.lib.voxel_map.read_saved_map`).

    Raises:
        AmslamError: a map file that cannot be read, named."""
    ply, npz = run_dir / "map.ply", run_dir / "map.npz"
    if ply.exists():
        from amslam.apps.mapformats import NO_CLASS, read_map_ply
        from amslam.apps.viewer.runfiles import voxel_size

        try:
            cloud = read_map_ply(ply)
        except (OSError, ValueError) as exc:
            # read_map_ply's ValueError names the file already
            raise AmslamError(
                str(exc) if isinstance(exc, ValueError) else f"cannot read {ply}: {exc}"
            ) from None
        known = cloud.class_names
        names = [known[i] if i < len(known) else f"class {i}" for i in cloud.classes.tolist()]
        classes = names if any(n != NO_CLASS for n in names) else None
        guess = voxel_size(cloud.points) if len(cloud.points) else None
        return cloud.points, cloud.voxel_size or guess, classes
    if npz.exists():
        from amslam.lib.voxel_map import read_saved_map

        grid = read_saved_map(npz).global_map
        return grid.centres()[grid.occupied()], grid.voxel, None
    return np.zeros((0, 3)), None, None


def landmarks_of(run_dir: Path) -> list[dict[str, Any]]:
    """The run's ``landmarks.json`` (:func:`amslam.rundir.read_landmarks`); none when the file is
    missing, or, with a warning, when it cannot be read (the rest of the run is still shown)."""
    path = run_dir / "landmarks.json"
    if not path.is_file():  # a run stopped before its end, or one without SLAM
        return []
    try:
        return read_landmarks(path)
    except RunFileError as exc:
        log.warning(f"{exc}: the landmarks left out")
        return []


def replay_run(run_dir: Path, rec: Any) -> dict[str, int]:
    """Log everything of ``run_dir`` into the recording stream ``rec``; what was logged, counted."""
    run_dir = Path(run_dir)
    scene = Scene(rec)
    tail = StreamTail(run_dir)
    counts: dict[str, int] = {}
    events = tail.records("events")
    log_events(scene, events)
    counts["events"] = len(events)
    counts["tree"] = log_tree(scene, {}, tail.records("tree"))
    for source in SOURCES:
        rows = parse_tum(tail.lines(source))
        scene.poses(source, rows)
        scene.path(source, rows[:, 1:4], static=True)
        counts[source] = len(rows)
    points, voxel, classes = read_map(run_dir)
    scene.map(points, voxel, classes)
    counts["map"] = len(points)
    counts.update({f"landmarks_{k}": n for k, n in scene.landmarks(landmarks_of(run_dir)).items()})
    return counts
