"""The run's map in formats other tools read: a binary PLY with class and probability per voxel, and
an OctoMap ``.bt`` (``amslam map RUN --bt FILE``).

``map.ply`` (written by the run report) is one vertex per occupied voxel of the global map, at the
voxel's centre, world frame, metres, binary little-endian::

    ply
    format binary_little_endian 1.0
    comment amslam map: occupied voxels of the global map (world frame, metres)
    obj_info voxel_size 0.25
    obj_info class 0 none
    obj_info class 1 chair
    ...
    element vertex N
    property float x
    property float y
    property float z
    property uchar class
    property float probability
    end_header

* ``class`` indexes the ``obj_info class <index> <name>`` lines: the class of the semantic-map
  landmark the voxel belongs to (inside its fitted shape, or within :data:`LANDMARK_RADIUS` of a
  landmark without one; the nearest when several claim it), 0 (``none``) for everything else;
* ``probability`` is the occupancy probability from the map's log-odds (``map.npz``), NaN when the
  mapping backend does not save its log-odds;
* the voxel size is an ``obj_info`` line, not a ``comment``: the PLY format reserves ``obj_info``
  for data about the object as a whole and ``comment`` for remarks, and readers keep them apart
  (plyfile's ``PlyData.obj_info``), so a tool that adds its own comments cannot be mistaken for it.

Open3D (``o3d.t.io.read_point_cloud``), CloudCompare, MeshLab and plyfile read the file; the class
and the probability show as scalar fields. :func:`read_map_ply` also reads the ASCII ``map.ply``
(x, y, z only) of runs made before.
"""

from __future__ import annotations

import argparse
import contextlib
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import amslam
from amslam.cli import Command
from amslam.errors import AmslamError, RunFileError
from amslam.lib.octomap_files import write_bt
from amslam.lib.shapes import points_inside
from amslam.rundir import write_atomically

#: a landmark without a fitted shape claims the occupied voxels within this distance of its
#: position (m): about half an office chair or table; a shape, when fitted, is used instead
LANDMARK_RADIUS = 0.5
#: class 0: a voxel no landmark claims (walls, floors, unmapped objects)
NO_CLASS = "none"


@dataclass(frozen=True)
class MapCloud:
    """The occupied voxels of a map: centres, class per voxel and occupancy probability.

    Attributes:
        points: N×3 voxel centres, world frame, m.
        classes: N indices into ``class_names`` (0: ``none``).
        probability: N occupancy probabilities (NaN where unknown).
        voxel_size: the voxel edge, m (None in a file that does not say).
        class_names: the class of each index; ``class_names[0]`` is ``none``.
    """

    points: np.ndarray
    classes: np.ndarray
    probability: np.ndarray
    voxel_size: float | None
    class_names: tuple[str, ...] = (NO_CLASS,)
    comments: tuple[str, ...] = field(default=(), compare=False)

    def __len__(self) -> int:
        return len(self.points)


def landmark_classes(points: np.ndarray, landmarks, voxel: float) -> tuple[np.ndarray, tuple[str, ...]]:
    """The class of each voxel centre from the semantic map: the nearest landmark whose shape
    (inflated by half a voxel) holds it, or, for a landmark without a shape, that lies within
    :data:`LANDMARK_RADIUS` of it; 0 (``none``) where no landmark claims it."""
    points = np.asarray(points, float).reshape(-1, 3)
    names = (NO_CLASS, *sorted({lm.class_name for lm in landmarks}))
    number = {name: i for i, name in enumerate(names)}
    classes = np.zeros(len(points), np.uint8)
    best = np.full(len(points), np.inf)
    for lm in landmarks:
        distance = np.linalg.norm(points - np.asarray(lm.position, float), axis=1)
        claimed = points_inside(lm.shape, points, 0.5 * voxel) if lm.shape else distance <= LANDMARK_RADIUS
        nearer = claimed & (distance < best)
        classes[nearer] = number[lm.class_name]
        best[nearer] = distance[nearer]
    return classes, names


def probabilities_from_saved_map(points: np.ndarray, saved_map: Path, voxel: float) -> np.ndarray:
    """Occupancy probability of each voxel centre from a map saved as ``amslam-voxels-1``
    (``map.npz``: the global map's indices and log-odds); NaN where the file has no such voxel
    or is not that format."""
    points = np.asarray(points, float).reshape(-1, 3)
    from amslam.lib.voxel_map import read_saved_map  # the voxel map's module: not at `amslam --help`

    out = np.full(len(points), np.nan, np.float32)
    try:
        saved = read_saved_map(saved_map).global_map
    except RunFileError:  # missing, or not a saved map: the probabilities are unknown
        return out
    index, logodds, saved_voxel = saved.index, saved.logodds, saved.voxel
    if len(points) == 0 or len(index) == 0 or not np.isclose(saved_voxel, voxel):
        return out
    wanted = np.floor(points / voxel).astype(np.int64)
    # match rows of two index arrays through one sortable key per voxel
    lo = np.minimum(index.min(axis=0), wanted.min(axis=0))
    span = np.maximum(index.max(axis=0), wanted.max(axis=0)) - lo + 1
    key_saved = np.ravel_multi_index(tuple((index - lo).T), span)
    key_wanted = np.ravel_multi_index(tuple((wanted - lo).T), span)
    order = np.argsort(key_saved)
    at = np.clip(np.searchsorted(key_saved[order], key_wanted), 0, len(order) - 1)
    found = key_saved[order][at] == key_wanted
    out[found] = 1.0 / (1.0 + np.exp(-logodds[order][at][found]))
    return out


# ------------------------------------------------------------------ PLY
#: ``class`` is a uchar: Open3D's PLY reader skips ushort and uint properties (int and uchar it reads)
_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("class", "u1"), ("probability", "<f4")])


def write_map_ply(path: Path, cloud: MapCloud) -> Path:
    """``cloud`` as a binary little-endian PLY (see the module docstring), written atomically."""
    from plyfile import PlyData, PlyElement

    if len(cloud.class_names) > 256:
        raise ValueError(f"{path}: {len(cloud.class_names) - 1} classes; a map PLY holds at most 255")

    vertices = np.zeros(len(cloud), _VERTEX)
    points = np.asarray(cloud.points, float).reshape(-1, 3)
    vertices["x"], vertices["y"], vertices["z"] = points.T
    vertices["class"] = cloud.classes
    vertices["probability"] = cloud.probability
    info = [] if cloud.voxel_size is None else [f"voxel_size {cloud.voxel_size:g}"]
    info += [f"class {i} {name}" for i, name in enumerate(cloud.class_names)]
    data = PlyData(
        [PlyElement.describe(vertices, "vertex")],
        text=False,
        byte_order="<",
        comments=["amslam map: occupied voxels of the global map (world frame, metres)"],
        obj_info=info,
    )
    buffer = io.BytesIO()
    data.write(buffer)
    return write_atomically(Path(path), buffer.getvalue())


def read_map_ply(path: Path) -> MapCloud:
    """A map PLY: the binary one of :func:`write_map_ply`, or any PLY whose vertices have x, y, z
    (the ASCII ``map.ply`` of older runs: class ``none``, probability NaN, voxel size None).

    Raises:
        OSError: the file cannot be read.
        ValueError: it is not a PLY with x, y, z vertices.
    """
    from plyfile import PlyData, PlyParseError

    try:
        data = PlyData.read(str(path))
    except PlyParseError as exc:
        raise ValueError(f"{path}: not a PLY file: {exc}") from None
    if "vertex" not in data or not {"x", "y", "z"} <= set(data["vertex"].data.dtype.names or ()):
        raise ValueError(f"{path}: a map PLY needs vertices with x, y, z")
    vertex = data["vertex"].data
    n = len(vertex)
    voxel, names = None, {0: NO_CLASS}
    for line in data.obj_info:
        words = line.split()
        if len(words) == 2 and words[0] == "voxel_size":
            voxel = float(words[1])
        elif len(words) >= 3 and words[0] == "class" and words[1].isdigit():
            names[int(words[1])] = " ".join(words[2:])
    fields = vertex.dtype.names
    return MapCloud(
        points=np.stack([vertex["x"], vertex["y"], vertex["z"]], -1).astype(float).reshape(-1, 3),
        classes=vertex["class"].astype(np.uint8) if "class" in fields else np.zeros(n, np.uint8),
        probability=(
            vertex["probability"].astype(np.float32) if "probability" in fields else np.full(n, np.nan)
        ),
        voxel_size=voxel,
        class_names=tuple(names.get(i, f"class {i}") for i in range(max(names) + 1)),
        comments=tuple(data.comments),
    )


# ------------------------------------------------------------------ OctoMap
def write_run_octomap(run_dir: Path, out: Path) -> tuple[int, int]:
    """A run folder's final global map as an OctoMap ``.bt``: the occupied voxels of its
    ``map.ply`` and the free ones of its ``map.npz`` (the saved log-odds; without it, the
    occupied voxels alone). Returns (occupied, free) voxel counts written.

    Raises:
        AmslamError: no map in the folder, no voxel size for it, pyoctomap missing, or the file
            cannot be written; the message names the file.
    """
    run_dir = Path(run_dir)
    ply, saved = run_dir / "map.ply", run_dir / "map.npz"
    if not ply.is_file():
        raise AmslamError(f"{run_dir}: no map.ply (is it a finished run folder?)")
    try:
        cloud = read_map_ply(ply)
    except (OSError, ValueError) as exc:
        raise AmslamError(f"{ply}: {exc}") from None
    voxel, known = cloud.voxel_size, np.zeros((0, 3), np.int64)
    if saved.is_file():
        from amslam.lib.voxel_map import read_saved_map

        grid = read_saved_map(saved).global_map  # a RunFileError names the file
        known, voxel = grid.index, grid.voxel
    if voxel is None:
        raise AmslamError(f"{ply}: the voxel size is unknown (no obj_info voxel_size line, no map.npz)")
    occupied = np.unique(np.floor(cloud.points / voxel).astype(np.int64), axis=0)
    index = np.unique(np.vstack([known, occupied]), axis=0)
    is_occupied = _rows_in(index, occupied)
    write_bt(out, index, is_occupied, voxel)
    return int(is_occupied.sum()), int((~is_occupied).sum())


def _rows_in(rows: np.ndarray, among: np.ndarray) -> np.ndarray:
    """Which rows of ``rows`` are rows of ``among`` (both N×3 int)."""
    if len(rows) == 0 or len(among) == 0:
        return np.zeros(len(rows), bool)
    both = np.vstack([rows, among])
    lo, span = both.min(axis=0), np.ptp(both, axis=0) + 1
    keys = [np.ravel_multi_index(tuple((a - lo).T), span) for a in (rows, among)]
    return np.isin(keys[0], keys[1])


# ------------------------------------------------------------------ `amslam map`
def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "run",
        help="a finished run folder (holding map.ply, and map.npz for free space), or a folder of them:"
        " the newest",
    )
    parser.add_argument(
        "--bt",
        metavar="FILE",
        required=True,
        help="write the final global map as an OctoMap binary tree (.bt: octovis, RViz, octomap_server; "
        "a later mission's prior_map)",
    )


def _run(args: argparse.Namespace, registry) -> int:
    run_dir, out = Path(args.run), Path(args.bt)
    if not run_dir.is_dir():
        raise AmslamError(f"{run_dir}: no such run folder")
    if out.suffix.lower() != ".bt":
        raise AmslamError(f"--bt {out}: the file name must end in .bt")
    if not (run_dir / "map.ply").is_file():  # a folder of runs: its newest, as `amslam view` and `export`
        from amslam.apps.viewer import resolve_run_folder

        with contextlib.suppress(AmslamError):
            found, newest = resolve_run_folder(run_dir)
            if newest:
                print(f"newest run in {run_dir}: {found}")
                run_dir = found
    occupied, free = write_run_octomap(run_dir, out)
    print(f"{out}: {occupied} occupied and {free} free voxels ({out.stat().st_size} bytes)")
    return 0


@amslam.hookimpl
def amslam_cli_commands() -> dict[str, Command]:
    return {"map": Command("write a run's map in another format (OctoMap .bt)", _arguments, _run)}
