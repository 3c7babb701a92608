"""The storage-independent voxel map that both voxel mapping backends (``numpy``, ``open3d``) build on.

:class:`VoxelMapBase` implements the whole :class:`amslam.interfaces.Mapping` contract (frontiers,
viewpoints, path costs, collision checks, volumes, save/load) on top of a small *storage* API
(``integrate_depth``, ``states_at_index``, ``dense_states``, ``voxels``, ``extent``, ``to_arrays``,
``from_arrays``, ``shift_to``); a backend plugin supplies the storage (``numpy``: dense arrays,
``open3d``: dense blocks found through an Open3D hash map, and a dense window).

A saved map (a run's ``map.npz``, a later mission's ``prior_map``) is written by
:meth:`VoxelMapBase.save` and read by :func:`read_saved_map`, here, for the backends and the apps
alike (the report's ``map.ply`` probabilities, ``amslam map``, the exports and viewers).
"""

from __future__ import annotations

import abc
import math
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar, Protocol

import numpy as np
from pydantic import Field, model_validator

from amslam.errors import RunFileError
from amslam.geometry import invert
from amslam.interfaces import BackendParams, FieldError, Mapping, Point, RunContext
from amslam.lib.free_space import (
    FreeSpaceGraph,
    graph_rules_reach,
    inflate,
    known_along,
    obstacles,
    samples_clear,
    segment_samples,
    slabs,
    smooth_path,
    trail_join,
    vertical_ok,
)
from amslam.lib.frontiers import FrontierConfig, FrontierTracker
from amslam.lib.octomap_files import read_bt
from amslam.lib.voxel_grid import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    LogOddsModel,
    centres,
    decode,
    depth_rays,
    encode,
    index_box,
    logit,
    seen_through,
    surfaces_seen_from,
    to_index,
    union,
)
from amslam.types import BoundingBox, Viewpoint

Vec3 = tuple[float, float, float]
#: the ``format`` a saved map (``.npz``) declares
SAVED_MAP_FORMAT = "amslam-voxels-1"
#: the occupancy threshold of a saved map read without its mission's ``mapping.p_occ``
#: (:attr:`VoxelMapParams.p_occ`'s default)
DEFAULT_P_OCC = LogOddsModel.p_occ
#: a side of the local window, m: its voxels are allocated at once (100 m at 0.1 m: 10⁶ a layer)
_Window = Annotated[float, Field(gt=0, le=100)]


@dataclass(frozen=True)
class SavedGrid:
    """One map of a saved map: its known voxels' indices (N×3), log-odds (N) and voxel edge (m)."""

    index: np.ndarray
    logodds: np.ndarray
    voxel: float

    def occupied(self, p_occ: float = DEFAULT_P_OCC) -> np.ndarray:
        """Which voxels are occupied: log-odds above ``logit(p_occ)``, the mapping backends' rule
        (:class:`~amslam.lib.voxel_grid.LogOddsModel`)."""
        return self.logodds > logit(p_occ)

    def probability(self) -> np.ndarray:
        """The occupancy probability of each voxel."""
        return 1.0 / (1.0 + np.exp(-self.logodds))

    def centres(self) -> np.ndarray:
        """The voxels' centres (N×3), world frame."""
        return centres(self.index, self.voxel)


@dataclass(frozen=True)
class SavedMap:
    """A map written by :meth:`VoxelMapBase.save`: the global map and, when saved, the local one."""

    global_map: SavedGrid
    local_map: SavedGrid | None
    #: global voxel indices (N×3) the flight's path rules took for a slab at some plan
    #: (:meth:`VoxelMapBase.slab_history`); empty in a map saved without them
    slab_history: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    #: global voxel indices (N×3) the flight's rays saw through vertically
    #: (:meth:`VoxelMapBase.seen_through`); None in a map saved without that record
    seen_through: np.ndarray | None = None
    #: global voxel indices (N×3) of surfaces the flight's rays hit from above and from below
    #: (:meth:`VoxelMapBase.surfaces_seen_from`); None in a map saved without them
    seen_from_above: np.ndarray | None = None
    seen_from_below: np.ndarray | None = None


def read_saved_map(path: Path) -> SavedMap:
    """A saved map (``map.npz``, format :data:`SAVED_MAP_FORMAT`), checked.

    Raises:
        RunFileError: not a readable ``.npz``, not that format, or a map's arrays missing or not
            agreeing; the message names the file.
    """
    if Path(path).is_file() and not zipfile.is_zipfile(path):  # np.load would speak of pickled data
        raise RunFileError(f"{path}: not a readable .npz (not a zip archive)")
    try:
        with np.load(Path(path), allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # BadZipFile: a member cut short
        raise RunFileError(f"{path}: not a readable .npz ({exc})") from None
    # a file without ``format`` is read by its arrays (the maps saved by amslam always say it)
    if "format" in arrays and str(arrays["format"]) != SAVED_MAP_FORMAT:
        raise RunFileError(f"{path}: not an amslam voxel map (format {SAVED_MAP_FORMAT!r} expected)")
    grids: dict[str, SavedGrid | None] = {}
    for name in ("global", "local"):
        keys = (f"{name}_index", f"{name}_logodds", f"{name}_voxel")
        if name == "local" and not any(k in arrays for k in keys):
            grids[name] = None
            continue
        try:
            index = np.asarray(arrays[keys[0]], np.int64).reshape(-1, 3)
            logodds = np.asarray(arrays[keys[1]], np.float64).reshape(-1)
            voxel = float(arrays[keys[2]])
        except (KeyError, ValueError, TypeError) as exc:
            raise RunFileError(f"{path}: the {name} map is incomplete ({exc})") from None
        if len(index) != len(logodds) or not voxel > 0:
            raise RunFileError(f"{path}: the {name} map's index, log-odds and voxel size do not agree")
        grids[name] = SavedGrid(index, logodds, voxel)
    none = np.zeros((0, 3), np.int64)
    history = _saved_indices(path, arrays.get("global_slab_history", none), "slab history")
    records = {}
    for name, what in (
        ("seen_through", "seen-through record"),
        ("seen_from_above", "record of surfaces seen from above"),
        ("seen_from_below", "record of surfaces seen from below"),
    ):
        raw = arrays.get(f"global_{name}")
        records[name] = None if raw is None else _saved_indices(path, raw, what)
    return SavedMap(grids["global"], grids["local"], history, **records)  # type: ignore[arg-type]


def _saved_indices(path: Path, raw: np.ndarray, what: str) -> np.ndarray:
    """A saved map's record of global voxels as N×3 indices, checked: whole numbers, within the
    range a key packs (voxel_grid.encode)."""
    raw = np.asarray(raw)
    if raw.size % 3 or raw.dtype.kind not in "iu" or (raw.size and np.abs(raw).max() >= 2**20):
        raise RunFileError(f"{path}: the global map's {what} is not N×3 voxel indices")
    return raw.astype(np.int64).reshape(-1, 3)


class VoxelMapParams(BackendParams):
    """Parameters of the voxel mapping backends (paper 1 §V-A, §VI-A defaults)."""

    global_voxel: float = Field(
        0.25, ge=0.02, le=5.0, description="Edge of a global (world-frame) voxel, metres (0.02 to 5)."
    )
    local_voxel: float = Field(
        0.1, ge=0.02, le=5.0, description="Edge of a local (odometry-frame) voxel, metres (0.02 to 5)."
    )
    local_size: tuple[_Window, _Window, _Window] = Field(
        (10.0, 10.0, 5.0), description="Size (x, y, z) in metres of the ego-centric local window."
    )
    local_memory_frames: int = Field(
        300,
        ge=0,
        le=1_000_000,
        description="A free local voxel no depth frame updated in this many frames becomes unknown again"
        " (300: a minute at 5 Hz): the window keeps what it saw in the odometry frame of then, which"
        " VIO's drift since moves against what is there now; 0: kept while inside the window",
    )
    local_recentre: float = Field(
        1.0,
        ge=0,
        le=100,
        description="The local window re-centres on the camera once it is this far off-centre (m).",
    )
    p_hit: float = Field(0.70, gt=0.5, lt=1, description="Occupancy probability of a voxel where a ray ends.")
    p_miss: float = Field(0.35, gt=0, lt=0.5, description="Occupancy probability of a voxel a ray crosses.")
    p_occ: float = Field(
        DEFAULT_P_OCC,
        gt=0,
        lt=1,
        description="A voxel is OCCUPIED above this probability (and the prior at first sight).",
    )
    p_min: float = Field(0.12, gt=0, lt=0.5, description="Lower clamp of the occupancy probability.")
    p_max: float = Field(0.97, gt=0.5, lt=1, description="Upper clamp of the occupancy probability.")
    max_range: float = Field(
        5.0,
        gt=0,
        le=100,
        description="Max ray length (m); no-return and farther pixels carve free space to it.",
    )
    global_stride: int | None = Field(
        None,
        ge=1,
        le=1000,
        description="Use every n-th pixel (both axes) for the global map; None: the largest stride whose "
        "rays are at most half a voxel apart at max_range (8 for 640×480 at 0.25 m).",
    )
    local_stride: int | None = Field(
        None, ge=1, le=1000, description="Same for the local map (None: auto, 3 for 640×480 at 0.1 m)."
    )
    area_margin: float = Field(
        1.0, ge=0, le=100, description="The global map extends this far (m) beyond the exploration area."
    )
    default_area: tuple[Point, Point] = Field(
        ((-25.0, -25.0, -1.0), (25.0, 25.0, 6.0)),
        description="Exploration area (lo, hi corners, m) when the run context gives none.",
    )
    min_cluster_size: int = Field(
        4, ge=1, le=1_000_000, description="Frontier clusters smaller than this (voxels) are ignored."
    )
    max_cluster_extent: float = Field(
        2.5,
        gt=0,
        le=100,
        description="Clusters longer than this along their principal axis (m) are split in two.",
    )
    viewpoint_radii: tuple[Annotated[float, Field(gt=0, le=100)], ...] = Field(
        (1.0, 1.75, 2.5), description="Distances (m) of candidate viewpoints from a cluster centroid."
    )
    viewpoint_angles: int = Field(
        12, ge=1, le=360, description="Candidate directions around a cluster centroid."
    )
    viewpoint_heights: tuple[Annotated[float, Field(ge=-100, le=100)], ...] = Field(
        (-0.5, 0.0, 0.5), description="Candidate heights (m) relative to the cluster centroid."
    )
    viewpoint_yaws: int = Field(
        24, ge=1, le=360, description="Candidate yaws evaluated at each candidate position."
    )
    gain_rays_azimuth: int = Field(
        72, ge=4, le=3600, description="Azimuths of the ray fan counting information gain."
    )
    gain_rays_elevation: int = Field(
        8, ge=1, le=1000, description="Elevations (over the vertical fov) of that fan."
    )
    sensing_range: float | None = Field(
        None,
        gt=0,
        le=100,
        description="Range (m) of the gain rays; default min(camera max range, max_range) - 0.5.",
    )
    min_gain: float = Field(
        0.5,
        ge=0,
        le=1_000_000,
        description="Viewpoints expecting to see less unknown volume (m³) than this are dropped.",
    )
    viewpoint_alternatives: int = Field(
        6,
        ge=0,
        le=100,
        description="Alternative viewpoints kept per frontier cluster (the best of each candidate height,"
        " then of each height and quadrant): the planner looks from the best one it can reach when the"
        " best view cannot be reached yet (a cluster above a shaft, seen best from the floor above).",
    )
    viewpoint_resample_ratio: float = Field(
        0.5,
        ge=0,
        le=1,
        description="A kept viewpoint whose re-checked gain falls below this fraction of its gain when "
        "sampled is sampled again.",
    )
    tight_penalty: float = Field(
        3.0,
        ge=1.0,
        le=1000,
        description="Cost multiplier of path stretches closer to obstacles than the robot radius plus "
        "its clearance margin (still passable, e.g. doors).",
    )
    snap_radius: float = Field(
        0.6,
        ge=0,
        le=100,
        description="Path start/goal off the free graph connect to the nearest free voxel within this.",
    )
    unseen_surface_reach: float = Field(
        0.25,
        ge=0,
        le=100,
        description="Unknown voxels connected to a seen slab, floor or ceiling within this distance (m)"
        " count as occupied in path search and segment checks, both maps (the unseen top or edge of a"
        " slab seen from one side); 0: only occupied voxels keep paths away.",
    )
    observed_floor_changes: bool = Field(
        True,
        description="Near a slab, floor or ceiling, paths move vertically only where every voxel within"
        " the robot radius was observed: a floor change never passes through unknown space.",
    )
    local_ceiling_reach: float = Field(
        1.5,
        ge=0,
        le=100,
        description="For a climb, the height guard counts unknown voxels of the fine local map in"
        " the layer of a ceiling seen from below, within this distance (m) of it"
        " through unknown voxels of that layer, as more of that ceiling: the level camera"
        " never sees the part over the vehicle's head, and a vehicle off where it thinks climbed"
        " under one (a three-floor flight hit the slab); 0: only unseen_surface_reach.",
    )
    floor_change_opening: float = Field(
        0.75,
        ge=0,
        le=100,
        description="In the z layer of a slab, floor or ceiling, paths move vertically only this far (m)"
        " horizontally from it: floors are changed through wide openings (a shaft, a stairwell), not"
        " through a hole the global map carved into a slab from drifted poses; 0: no such rule.",
    )
    seen_through_rise: float = Field(
        1.0,
        ge=0,
        le=100,
        description="A global voxel counts as seen through (an opening between floors) where a ray"
        " crossed it to end at least this much higher or lower (m): a slab stops rays, so the rays"
        " that carve a slab's voxels from poses a few centimetres off in z end on it; 0: no"
        " seen-through rule.",
    )
    seen_through_reach: float = Field(
        1.5,
        ge=0,
        le=100,
        description="Within this distance (m) horizontally of a slab, floor or ceiling seen from both"
        " floors, in its z layer, paths move vertically only through voxels seen through"
        " (seen_through_rise): a floor is changed where the camera saw the other floor, not through a"
        " strip the map carved into a slab seen from above and below by poses that disagreed in z;"
        " 0: no such rule.",
    )
    contract_costs_above: int = Field(
        100_000,
        ge=0,
        le=10**9,
        description="Tour path costs on a free-space graph of more nodes than this are searched on the"
        " graph contracted to blocks (contract_block voxels a side): the same reachability, lengths a"
        " few % longer, a search that no longer grows with the map as fast (a 20 x 30 x 10 m hall: 5 s"
        " -> 0.3 s a plan). Below it the exact search is cheap enough; 0: always contracted.",
    )
    contract_block: int = Field(4, ge=2, le=64, description="Block side (voxels) of the contracted graph.")
    plan_through_unknown: bool = Field(
        False,
        description="Plan paths through unknown voxels inside the mission area too (open outdoor areas,"
        " where a robot must cross ground it has not mapped to reach a known object); the local map"
        " still checks every step. Off: paths stay in known free space (buildings).",
    )

    #: most voxels of the local window, allocated at once (the default: 10 x 10 x 5 m at 0.1 m, 5·10⁵)
    MAX_LOCAL_VOXELS: ClassVar[int] = 50_000_000

    @model_validator(mode="after")
    def _local_window_fits(self) -> VoxelMapParams:
        cells = math.prod(math.ceil(s / self.local_voxel) for s in self.local_size)
        if cells > self.MAX_LOCAL_VOXELS:
            size = " x ".join(f"{s:g}" for s in self.local_size)
            raise FieldError(
                "local_size",
                f"{size} m at local_voxel {self.local_voxel:g} m is {cells:.3g} voxels, more than"
                f" {self.MAX_LOCAL_VOXELS:.0e} (a smaller window or a coarser local_voxel)",
            )
        return self


def _smoothed_path(
    graph: FreeSpaceGraph,
    start: np.ndarray,
    goal: np.ndarray,
    voxel: float,
    clear: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], bool],
) -> np.ndarray | None:
    """The graph's shortest path from ``start`` to ``goal``, shortcut-smoothed, or None.

    A shortcut ``a → b`` is taken when, sampled every half voxel (the two end voxels excepted),
    it stays on graph nodes — clear of every obstacle the graph knows, carved slab holes too — and,
    if it climbs or descends, obeys the graph's rule for vertical moves; and when ``clear(a, b,
    samples, at_end)`` (the map-specific check) agrees.
    """
    raw = graph.shortest_path(start, goal)
    if raw is None:
        return None
    raw, goal = _end_on_graph(graph, raw, start, goal)
    ends = to_index(np.array([start, goal]), voxel)

    def line_of_sight(a: np.ndarray, b: np.ndarray) -> bool:
        samples = segment_samples(a, b, 0.5 * voxel)
        idx = to_index(samples, voxel)
        at_end = np.all(idx == ends[0], axis=1) | np.all(idx == ends[1], axis=1)
        if abs(b[2] - a[2]) > 1e-6 and not np.all(graph.vertical_ok_at(samples) | at_end):
            return False
        return bool(np.all(graph.passable_at(samples) | at_end)) and clear(a, b, samples, at_end)

    return smooth_path(raw, line_of_sight)


def _end_on_graph(
    graph: FreeSpaceGraph, raw: np.ndarray, start: np.ndarray, goal: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A raw path, and its goal, ending on the graph when the goal is within the robot radius of an
    obstacle.

    The goal snapped onto the graph from such a voxel (a viewpoint moved into a height band under a
    carved ceiling patch, say): end the path at the node it snapped to rather than fly the last,
    unchecked stretch into it.
    """
    if not graph.near_obstacle_at(goal[None])[0]:
        return raw, goal
    raw = raw[:-1] if len(raw) > 2 else np.array([start, graph.node_position(graph.snap(goal))])
    return raw, raw[-1]


def _changed_regions(
    changed: np.ndarray, reach: np.ndarray, chunk: int = 8
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boxes ``[lo, hi)`` of a block covering every voxel within ``reach`` (per axis) of a
    ``changed`` one: the block cut in ``chunk``³ cubes, the cubes holding changes widened by the
    reach, one box round each connected group (a frame's changes near the robot, another group
    where a slab grew)."""
    from scipy import ndimage

    if not changed.any():
        return []
    shape = np.array(changed.shape)
    cubes = -(-shape // chunk)
    padded = np.zeros(tuple(cubes * chunk), dtype=bool)
    padded[tuple(slice(0, int(s)) for s in shape)] = changed
    hit = padded.reshape(cubes[0], chunk, cubes[1], chunk, cubes[2], chunk).any(axis=(1, 3, 5))
    grow = -(-np.asarray(reach) // chunk)
    near = ndimage.binary_dilation(hit, structure=np.ones(tuple(2 * grow + 1), dtype=bool))
    labels, _ = ndimage.label(near, structure=np.ones((3, 3, 3), dtype=bool))
    boxes = []
    for found in ndimage.find_objects(labels):
        lo = np.array([s.start for s in found]) * chunk
        hi = np.minimum(np.array([s.stop for s in found]) * chunk, shape)
        boxes.append((lo, hi))
    return boxes


def auto_stride(K: np.ndarray, voxel: float, max_range: float) -> int:
    """Largest pixel stride whose neighbouring rays are at most half a voxel apart at ``max_range``.

    A coarse voxel needs far fewer rays than the full image: 640×480 at 0.25 m and 5 m uses every
    8th pixel (4800 rays) and still hits every voxel of a surface facing the camera.
    """
    f = float(max(K[0, 0], K[1, 1]))
    return max(1, int(0.5 * voxel * f / max_range))


@dataclass
class _GraphRules:
    """The path graph's rules, voxel by voxel, over a block of the global map (indices ``[lo, lo +
    shape)``), and the states and slabs they were computed from: kept between graph builds, so
    that a build recomputes them only around the voxels that changed
    (:meth:`VoxelMapBase._rules_for`)."""

    lo: np.ndarray
    states: np.ndarray
    slab: np.ndarray  # the one non-local rule, over the whole block (see free_space.obstacles)
    slab_history: np.ndarray  # voxels some plan's rules took for a slab (VoxelMapBase.slab_history)
    seen_through: np.ndarray  # (3, *shape): _VerticalViews.over, crossed and surfaces from above, below
    passable: np.ndarray
    roomy: np.ndarray  # passable at the full clearance margin (no penalty)
    near: np.ndarray  # within the robot radius of an obstacle
    vertical: np.ndarray  # vertical moves allowed

    @property
    def hi(self) -> np.ndarray:
        return self.lo + np.array(self.states.shape)


class _GrowingKeys:
    """A set of global voxels (sorted int64 keys) that grows by additions, and its dense copy over
    a block kept up to date by ORing in what was added since the last copy (a dense read of every
    key is ~5 ms on the demo's block, an update a fraction of that)."""

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.int64)
        self._unfolded: list[np.ndarray] = []  # added, not yet in keys
        self._since_copy: list[np.ndarray] | None = []  # added since the last dense copy; None: replaced

    def add(self, keys: np.ndarray) -> None:
        if len(keys):
            self._unfolded.append(keys)
            if self._since_copy is not None:
                self._since_copy.append(keys)

    def replace(self, keys: np.ndarray) -> None:
        self.keys, self._unfolded, self._since_copy = np.unique(keys), [], None

    @property
    def replaced(self) -> bool:
        """Whether :meth:`replace` came after the last dense copy (which no longer holds)."""
        return self._since_copy is None

    def merged(self) -> np.ndarray:
        """Every key, additions folded in."""
        if self._unfolded:
            self.keys = np.union1d(self.keys, np.concatenate(self._unfolded))
            self._unfolded = []
        return self.keys

    def over(self, lo: np.ndarray, shape: tuple[int, ...], before: np.ndarray | None) -> np.ndarray:
        """The set as a dense mask over the block ``[lo, lo + shape)``; ``before``: the mask this
        gave for the same block last time (None for a new block)."""
        every = self.merged()
        if before is not None and self._since_copy is not None:
            out = before.copy()
            keys = np.concatenate(self._since_copy) if self._since_copy else np.zeros(0, np.int64)
        else:
            out, keys = np.zeros(shape, dtype=bool), every
        self._since_copy = []
        if len(keys):
            rel = decode(keys) - lo
            inside = np.all((rel >= 0) & (rel < np.array(shape)), axis=1)
            out[tuple(rel[inside].T)] = True
        return out


class _VerticalViews:
    """What the flight's rays saw vertically, three growing records of global voxels: the air they
    crossed on the way to a point well above or below (:meth:`VoxelMapBase.seen_through`) and the
    surfaces they hit from above and from below (:meth:`VoxelMapBase.surfaces_seen_from`)."""

    def __init__(self) -> None:
        self.parts = (_GrowingKeys(), _GrowingKeys(), _GrowingKeys())

    def add(self, keys: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        for part, k in zip(self.parts, keys, strict=True):
            part.add(k)

    def replace(self, keys: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        for part, k in zip(self.parts, keys, strict=True):
            part.replace(k)

    @property
    def keys(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return tuple(part.keys for part in self.parts)  # type: ignore[return-value]

    def merged(self, part: int) -> np.ndarray:
        return self.parts[part].merged()

    def over(self, lo: np.ndarray, shape: tuple[int, ...], before: np.ndarray | None) -> np.ndarray:
        """The three records as dense masks over the block, stacked (``before``: as for
        :meth:`_GrowingKeys.over`, the stack this gave last time)."""
        return np.stack(
            [part.over(lo, shape, None if before is None else before[i]) for i, part in enumerate(self.parts)]
        )


_NO_VIEWS = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))


class VoxelStorage(Protocol):
    """Storage operations a voxel backend provides (see :class:`~.grid.DenseGrid`)."""

    voxel: float

    def integrate_depth(
        self, depth: np.ndarray, K: np.ndarray, T: np.ndarray, stride: int, max_range: float
    ) -> BoundingBox: ...
    def states_at_index(self, index: np.ndarray) -> np.ndarray: ...
    def dense_states(self, lo: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray: ...
    def voxels(self) -> tuple[np.ndarray, np.ndarray]: ...
    def extent(self) -> tuple[np.ndarray, np.ndarray]: ...
    def to_arrays(self) -> dict[str, np.ndarray]: ...
    def from_arrays(self, arrays: dict[str, np.ndarray]) -> None: ...
    def shift_to(self, lo: np.ndarray) -> None: ...
    def forget(self, frames: int) -> int: ...  # the local window's: voxels no recent frame updated


class VoxelMapBase(Mapping):
    """Everything of the Mapping contract except voxel storage; subclasses build the two maps."""

    Params: ClassVar[type[BackendParams]] = VoxelMapParams

    #: the local window (``local_map``, ``_local_centre``) and the global map (``global_map``,
    #: the frontier tracker, the search graph) share only the read-only parameters
    separate_local_map = True

    def __init__(self) -> None:
        self.params: VoxelMapParams = VoxelMapParams()
        self.context: RunContext | None = None
        self.global_map: Any = None
        self.local_map: Any = None
        self.frontiers: FrontierTracker | None = None
        self.area = BoundingBox.nothing()
        self.robot_radius = 0.25
        self.segment_radius = 0.25
        self.local_radius = 0.2
        self._pending = BoundingBox.nothing()  # global updates not yet seen by the frontier tracker
        self._version = 0
        self._graph: tuple[int, FreeSpaceGraph] | None = None
        self._rules: _GraphRules | None = None
        self._slab_history = _GrowingKeys()  # see slab_history
        self._seen_through = _VerticalViews()  # see seen_through, surfaces_seen_from
        self._start_seen_through(_NO_VIEWS, known=True)
        self._trail: list[np.ndarray] = []  # see trail

    # ------------------------------------------------------------------ lifecycle
    @abc.abstractmethod
    def _make_storage(self, voxel: float, lo: np.ndarray, shape: tuple[int, int, int], local: bool) -> Any:
        """Voxel storage for indices ``[lo, lo + shape)`` (a hint for sparse stores)."""

    def configure(self, params: BackendParams, context: RunContext) -> None:
        """Build both maps and the frontier tracker from validated params and the run context."""
        assert isinstance(params, VoxelMapParams), (
            f"expected {self.Params.__name__}, got {type(params).__name__}"
        )
        p = self.params = params
        self.context = context
        self.model = LogOddsModel(p.p_hit, p.p_miss, p.p_occ, p.p_min, p.p_max)
        if context.area is not None:  # the mission's area, or in simulation the world's bounds
            self.area = context.area
        else:
            self.area = BoundingBox(np.array(p.default_area[0]), np.array(p.default_area[1]))
        # Hard limit: the robot radius plus half the clearance margin from occupied voxel *boxes*
        # (drift of the odometry between mapping a surface and passing it eats into the margin;
        # a 1.2 m door still leaves four 0.25 m voxels whose centres clear 0.375 m). Paths are
        # pushed out to the full margin by the cost penalty, and straight shortcuts keep it.
        self.robot_radius = float(context.robot.radius + 0.5 * context.robot.clearance)
        self.segment_radius = float(context.robot.planning_radius)
        # The local check catches what the coarse map missed (thin parts, odometry drift since the
        # coarse map saw a surface). A surface the coarse plan clears by r lies at least r − one
        # fine voxel from the fine voxel boxes, so the check uses the bare robot radius less half a
        # fine voxel: it stops real intrusions without refusing every door the plan allows. (The
        # full radius was tried: demo seed 7 then refused a passage, explored 76.5 % instead of
        # 99 % and could not find its way home; with this radius two runs in about 30 grazed an
        # obstacle at 0.248 m, robot radius 0.25 m, on paths laid off by the SLAM correction.)
        self.local_radius = float(context.robot.radius - 0.5 * p.local_voxel)
        # compile the path-cost, graph-building and view-gain kernels (or load them from numba's cache)
        # before take-off, not at the first plan: on a real vehicle the first plan is made while
        # it flies
        from amslam.lib import dijkstra, gain_rays, graph_kernels

        dijkstra.warm_up()
        graph_kernels.warm_up()
        gain_rays.warm_up()
        v = p.global_voxel
        lo = np.floor((self.area.lo - p.area_margin) / v).astype(np.int64)
        hi = np.ceil((self.area.hi + p.area_margin) / v).astype(np.int64)
        self._global_extent = (lo, tuple(int(s) for s in hi - lo))
        self.global_map = self._make_storage(v, *self._global_extent, local=False)
        self._prior_global: dict[str, np.ndarray] | None = None  # a loaded map, the base of a rebuild
        lshape = tuple(int(np.ceil(s / p.local_voxel)) for s in p.local_size)
        self.local_map = self._make_storage(p.local_voxel, -(np.array(lshape) // 2), lshape, local=True)
        self._local_centre: np.ndarray | None = None
        cam = context.camera
        hfov, vfov = (cam.hfov, cam.vfov) if cam else (np.radians(87.0), np.radians(58.0))
        cam_range = min(cam.max_range if cam else p.max_range, p.max_range)
        self.frontiers = FrontierTracker(
            FrontierConfig(
                voxel=v,
                area=self.area,
                robot_radius=self.robot_radius,
                hfov=hfov,
                vfov=vfov,
                sensing_range=p.sensing_range or max(cam_range - 0.5, v),
                min_cluster_size=p.min_cluster_size,
                max_extent=p.max_cluster_extent,
                radii=tuple(p.viewpoint_radii),
                n_angles=p.viewpoint_angles,
                heights=tuple(p.viewpoint_heights),
                n_yaws=p.viewpoint_yaws,
                n_rays_azimuth=p.gain_rays_azimuth,
                n_rays_elevation=p.gain_rays_elevation,
                min_gain=p.min_gain,
                n_alternatives=p.viewpoint_alternatives,
                resample_ratio=p.viewpoint_resample_ratio,
            )
        )
        self._pending = BoundingBox.nothing()
        self._version = 0
        self._graph = None
        self._rules = None
        self._slab_history = _GrowingKeys()
        self._start_seen_through(_NO_VIEWS, known=True)
        self._trail = []

    def close(self) -> None:
        """Drop the maps (safe to call twice)."""
        self.global_map = None
        self.local_map = None
        self._graph = None
        self._rules = None

    def _require(self) -> None:
        if self.global_map is None:
            raise RuntimeError(f"{type(self).__name__} is not configured (or already closed)")

    # ------------------------------------------------------------------ updates
    def integrate_global(self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> BoundingBox:
        """Fuse a depth image into the global map (SLAM pose); return the box it touched."""
        self._require()
        p = self.params
        stride = p.global_stride or auto_stride(K, p.global_voxel, p.max_range)
        box = self.global_map.integrate_depth(depth, K, T_world_cam, stride, p.max_range)
        self._seen_through.add(self._through(depth, K, T_world_cam, stride))
        self._extend_trail(T_world_cam)
        if not box.empty:
            self._pending = union(self._pending, box)
            self._version += 1
        return box

    def rebuild_global(self, frames: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> bool:
        """Build the global map anew from ``(depth, K, T_world_cam)`` frames (on a loaded prior map).

        After SLAM moved the poses earlier frames were integrated at (a loop closure), the
        surfaces they put in the map stand where the robot thought it was: a wall drawn 0.5 m off
        through a corridor, a slab carved away. Integrating the same frames at the corrected poses
        is the only exact repair with log-odds (taking a frame's update back is not, once values
        were clamped). Frontiers are recomputed over the whole map.
        """
        self._require()
        store = self._make_storage(self.params.global_voxel, *self._global_extent, local=False)
        if self._prior_global is not None:
            store.from_arrays(self._prior_global)
        p = self.params
        through = [self._prior_seen_through]
        self._trail = []
        for depth, K, T_world_cam in frames:
            stride = p.global_stride or auto_stride(K, p.global_voxel, p.max_range)
            store.integrate_depth(depth, K, T_world_cam, stride, p.max_range)
            through.append(self._through(depth, K, T_world_cam, stride))
            self._extend_trail(T_world_cam)
        self.global_map = store
        self._seen_through.replace(tuple(np.concatenate(part) for part in zip(*through, strict=True)))
        self._version += 1
        self._graph = None
        self.recompute_frontiers()
        return True

    def integrate_local(self, depth: np.ndarray, K: np.ndarray, T_odom_cam: np.ndarray) -> BoundingBox:
        """Fuse a depth image into the local window (VIO pose), re-centring it first if needed."""
        self._require()
        p = self.params
        cam = np.asarray(T_odom_cam)[:3, 3]
        if self._local_centre is None or np.linalg.norm(cam - self._local_centre) > p.local_recentre:
            shape = np.array(self._local_shape())
            self.local_map.shift_to(to_index(cam[None], p.local_voxel)[0] - shape // 2)
            self._local_centre = cam.copy()
        stride = p.local_stride or auto_stride(K, p.local_voxel, p.max_range)
        box = self.local_map.integrate_depth(depth, K, T_odom_cam, stride, p.max_range)
        if p.local_memory_frames:
            self.local_map.forget(p.local_memory_frames)
        return box

    def _through(
        self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, stride: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Keys of the global voxels a frame saw through vertically (:meth:`seen_through`) and of
        the surfaces it hit from above and from below (:meth:`surfaces_seen_from`)."""
        p = self.params
        if p.seen_through_rise <= 0:
            return _NO_VIEWS
        v, rays = p.global_voxel, depth_rays(depth, K, T_world_cam, stride, p.max_range)
        return (seen_through(rays, v, p.seen_through_rise), *surfaces_seen_from(rays, v))

    def _start_seen_through(self, keys: tuple[np.ndarray, np.ndarray, np.ndarray], *, known: bool) -> None:
        """Start the seen-through records from ``keys`` (a loaded map's, also the base of a rebuild);
        ``known``: False for a map without them, which turns the rule off (:meth:`_seen_through_rule`)."""
        self._seen_through.replace(keys)
        self._prior_seen_through = self._seen_through.keys
        self._seen_through_known = known

    def seen_through(self) -> np.ndarray:
        """Global voxel indices (N×3) a ray crossed on its way to a point at least
        ``seen_through_rise`` higher or lower (:func:`~amslam.lib.voxel_grid.seen_through`): air
        between floors the camera saw through, vertically — an opening, where a path may change
        floors (:func:`~amslam.lib.free_space.vertical_ok`). Rebuilt with the global map."""
        return decode(self._seen_through.merged(0))

    def surfaces_seen_from(self) -> tuple[np.ndarray, np.ndarray]:
        """Global voxel indices (N×3, twice) of the surfaces rays hit from above (the camera more
        than a voxel higher) and from below (:func:`~amslam.lib.voxel_grid.surfaces_seen_from`): a
        slab between floors whose top and underside were both seen, where drifted poses of the
        two floors may have carved it (:func:`~amslam.lib.free_space.vertical_ok`). Rebuilt with
        the global map."""
        return decode(self._seen_through.merged(1)), decode(self._seen_through.merged(2))

    def _extend_trail(self, T_world_cam: np.ndarray) -> None:
        """Add the body's position at a frame to :meth:`trail`, a global voxel or more from the last."""
        camera = self.context.camera if self.context is not None else None
        T_world_body = T_world_cam @ invert(camera.T_body_cam) if camera is not None else T_world_cam
        here = np.asarray(T_world_body, float)[:3, 3].copy()
        if not self._trail or np.linalg.norm(here - self._trail[-1]) >= self.params.global_voxel:
            self._trail.append(here)

    def trail(self) -> np.ndarray:
        """The body's positions (N×3, world frame, oldest first, a global voxel apart) at the frames
        the global map holds, at the poses it holds them at (moved with it by a rebuild): the way
        the robot flew, in the map's frame."""
        return np.array(self._trail, float).reshape(-1, 3)

    def _local_shape(self) -> tuple[int, int, int]:
        return tuple(int(np.ceil(s / self.params.local_voxel)) for s in self.params.local_size)

    # ------------------------------------------------------------------ queries
    def states(self, points: np.ndarray, *, local: bool = False) -> np.ndarray:
        """int8 VoxelState of the voxels holding ``points`` (N×3); UNKNOWN outside the map."""
        self._require()
        store = self.local_map if local else self.global_map
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        return store.states_at_index(to_index(pts, store.voxel))

    def viewpoints(self) -> list[Viewpoint]:
        """Frontier viewpoints after folding in every global update since the last call."""
        self._require()
        if not self._pending.empty:
            self.frontiers.update(self.global_map, self._pending)
            self._pending = BoundingBox.nothing()
        return self.frontiers.viewpoints()

    def recompute_frontiers(self) -> list[Viewpoint]:
        """Full (non-incremental) frontier detection over the whole area, for cross-checks."""
        self._require()
        self.frontiers.recompute(self.global_map)
        self._pending = BoundingBox.nothing()
        return self.frontiers.viewpoints()

    def frontier_points(self) -> np.ndarray:
        """Centres of the current frontier voxels (N×3), after pending updates."""
        self.viewpoints()
        return self.frontiers.frontier_points()

    def _free_graph(self) -> FreeSpaceGraph:
        """The free-space graph of the global map, rebuilt only when the map changed."""
        if self._graph is not None and self._graph[0] == self._version:
            return self._graph[1]
        lo, hi = self.global_map.extent()
        lo, hi = lo - 1, hi + 1
        if self.params.plan_through_unknown:
            a, b = index_box(self.area, self.global_map.voxel)
            lo, hi = np.minimum(lo, a), np.maximum(hi, b)
        rules = self._rules_for(lo, hi)
        crop = tuple(slice(int(a), int(b)) for a, b in zip(lo - rules.lo, hi - rules.lo, strict=True))
        # copies: the rules' arrays are updated in place by the next build
        graph = FreeSpaceGraph(
            rules.passable[crop].copy(),
            lo,
            self.global_map.voxel,
            self.params.snap_radius,
            rules.states[crop].copy(),
            near_obstacle=rules.near[crop].copy(),
            penalty=np.where(rules.roomy[crop], 1.0, self.params.tight_penalty),
            vertical_ok=rules.vertical[crop].copy(),
        )
        self._graph = (self._version, graph)
        return graph

    def _rules_reach(self) -> np.ndarray:
        """How far (voxels, per axis) the graph's rules look from a voxel (free_space.graph_rules_reach)."""
        p = self.params
        radii = (self.robot_radius, self.segment_radius)
        return graph_rules_reach(
            p.global_voxel, radii, p.unseen_surface_reach, p.floor_change_opening, p.seen_through_reach
        )

    def _rules_for(self, lo: np.ndarray, hi: np.ndarray) -> _GraphRules:
        """The graph's rules over a block holding ``[lo, hi)``, updated to the map's voxels.

        The rules of a voxel depend on the states within :meth:`_rules_reach` of it (and on the
        slabs, which are found over the whole block each time: a surface is a slab by the size of
        its whole component). So only the voxels within that reach of a voxel whose state or slab
        changed since the last build are recomputed, each group of them on a block widened by the
        reach again: the rules come out as a build from scratch gives them, at a fraction of the
        work (the hall changes some 40 × 35 × 25 voxels between plans, of 90 × 130 × 50). The
        block is kept at least one reach plus a voxel beyond the extent (its outer layers unknown,
        like the voxels beyond it) and made anew, round the mission area, when the map outgrows it.
        """
        store = self.global_map
        pad = self._rules_reach() + 1
        rules = self._rules
        if rules is None or np.any(lo - pad < rules.lo) or np.any(hi + pad > rules.hi):
            # room to grow: the area (the map leaves it a little, through doors and windows) and
            # another reach; when unknown space is not planned through, at most half the map's
            # size on each side: a mission area far larger than what is mapped (a waypoint
            # mission's 200 × 200 m, say) made the first block 8 M voxels and its build 8 s
            a, b = index_box(self.area, store.voxel)
            if not self.params.plan_through_unknown:
                room = (hi - lo) // 2
                a, b = np.maximum(a, lo - room), np.minimum(b, hi + room)
            block_lo, block_hi = np.minimum(lo, a) - 2 * pad, np.maximum(hi, b) + 2 * pad
            states = store.dense_states(block_lo, tuple(int(s) for s in block_hi - block_lo))
            slab = self._slabs(states)
            history = self._remember_slabs(slab, block_lo, None)
            through = self._through_over(block_lo, states.shape, None)
            self._rules = _GraphRules(
                block_lo,
                states,
                slab,
                history,
                through,
                *self._graph_rules(states, block_lo, slab, history, through),
            )
            return self._rules
        states = store.dense_states(rules.lo, rules.states.shape)
        slab = self._slabs(states)
        history = self._remember_slabs(slab, rules.lo, rules.slab_history)
        through = self._through_over(rules.lo, states.shape, rules.seen_through)
        changed = (states != rules.states) | (slab != rules.slab) | (history != rules.slab_history)
        changed |= (through != rules.seen_through).any(axis=0)
        shape = np.array(states.shape)
        for box_lo, box_hi in _changed_regions(changed, pad):
            # computed on the region widened by the reach (and a voxel, for the horizontal
            # surfaces at its edge), clipped to the block
            c_lo, c_hi = np.maximum(box_lo - pad, 0), np.minimum(box_hi + pad, shape)
            part = tuple(slice(int(i), int(j)) for i, j in zip(c_lo, c_hi, strict=True))
            layers = self._graph_rules(
                states[part], rules.lo + c_lo, slab[part], history[part], through[(slice(None), *part)]
            )
            inner = tuple(slice(int(i), int(j)) for i, j in zip(box_lo - c_lo, box_hi - c_lo, strict=True))
            region = tuple(slice(int(i), int(j)) for i, j in zip(box_lo, box_hi, strict=True))
            for mine, fresh in zip(
                (rules.passable, rules.roomy, rules.near, rules.vertical), layers, strict=True
            ):
                mine[region] = fresh[inner]
        rules.states, rules.slab, rules.slab_history, rules.seen_through = states, slab, history, through
        return rules

    def _remember_slabs(self, slab: np.ndarray, lo: np.ndarray, before: np.ndarray | None) -> np.ndarray:
        """Add a block's slabs (indices ``[lo, lo + shape)``) to :meth:`slab_history`; return the
        history over that block. ``before``: the history over the same block at the last build,
        still true unless a map was loaded since (then, and for a new block, it is read back from
        the keys: ~5 ms on the demo's block, against ~0.3 ms for the update)."""
        still = before is not None and not self._slab_history.replaced
        new = slab & ~before if still else slab
        if new.any():
            self._slab_history.add(encode(np.argwhere(new) + lo))
        return self._slab_history.over(lo, slab.shape, before)

    def slab_history(self) -> np.ndarray:
        """Global voxel indices (N×3) that the path rules took for a slab, floor or ceiling at some
        plan of this flight (or of the flight a loaded map was saved by).

        A 0.2 m slab seen from below and from above at different times, by poses whose heights
        disagree by a few centimetres, is carved by the rays of one side through the voxels of the
        other: a demo flight's global map lost a strip 2 m wide of the slab between two floors, and
        the planner took it for a way up (docs/experiments.md, "A slab the maps carved"). The map
        keeps no history of its voxels; the rules keep this one, and such voxels stay obstacles
        to the paths (:func:`~amslam.lib.free_space.obstacles`) whatever the map says of them now.
        """
        return decode(self._slab_history.merged())

    def _slabs(self, states: np.ndarray) -> np.ndarray:
        """The slabs of a block (free_space.slabs), where the rules use them."""
        if self.params.floor_change_opening > 0 or self._seen_through_rule():
            return slabs(states, self.global_map.voxel)
        return np.zeros(states.shape, dtype=bool)

    def _graph_rules(
        self,
        states: np.ndarray,
        lo: np.ndarray,
        slab: np.ndarray,
        slab_history: np.ndarray,
        through: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The graph's rules on the block ``states`` (indices ``[lo, lo + shape)``) with its slabs,
        :meth:`slab_history` and the vertical views (``through``, :meth:`_through_over`): passable,
        roomy (no clearance penalty), near an obstacle, vertical moves allowed."""
        shape = states.shape
        v, reach, p = self.global_map.voxel, self.params.unseen_surface_reach, self.params
        unknown_free = p.plan_through_unknown
        occ = obstacles(states, v, reach, p.floor_change_opening, slab=slab, slab_history=slab_history)
        near = inflate(occ, self.robot_radius, v)  # within the robot radius of an obstacle
        base = (states != OCCUPIED) if unknown_free else (states == FREE)
        passable = base & ~near
        roomy = base & ~inflate(occ, self.segment_radius, v)
        if unknown_free:
            # Unknown space is free only inside the mission area (not under the ground, say).
            a, b = index_box(self.area, v)
            inside = np.zeros(shape, dtype=bool)
            inside[
                tuple(slice(max(int(i), 0), max(int(j), 0)) for i, j in zip(a - lo, b - lo, strict=True))
            ] = True
            passable &= inside | (states == FREE)
            roomy &= inside | (states == FREE)
        flyable = self._flyable(lo, shape)
        passable &= flyable
        roomy &= flyable
        vertical = vertical_ok(
            states,
            self.robot_radius,
            v,
            observed=p.observed_floor_changes,
            opening=p.floor_change_opening,
            unseen_reach=reach,
            slab=slab,
            seen_through=through[0] if self._seen_through_rule() else None,
            through_reach=p.seen_through_reach,
            slab_history=slab_history,
            seen_from_above=through[1],
            seen_from_below=through[2],
        )
        return passable, roomy, near, vertical

    def _through_over(self, lo: np.ndarray, shape: tuple[int, ...], before: np.ndarray | None) -> np.ndarray:
        """The seen-through records over a rules block (crossed air, surfaces seen from above, from
        below: ``(3, *shape)``), or nothing while the rule is off: then the records' growth is no
        change to the rules. (The rule turns on or off only at a ``load``, which replaces the
        records, so the next copy is read whole.)"""
        if self._seen_through_rule():
            return self._seen_through.over(lo, shape, before)
        return np.zeros((3, *shape), dtype=bool)

    def _seen_through_rule(self) -> bool:
        """Whether floor changes need air seen through: the record is kept, and complete (a map
        loaded without it has openings this flight never saw through, e.g. an OctoMap file)."""
        p = self.params
        return p.seen_through_rise > 0 and p.seen_through_reach > 0 and self._seen_through_known

    def _flyable(self, lo: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        """Voxels of the block ``[lo, lo + shape)`` whose centre keeps the robot inside the area.

        The area (the mission's, by default the building's box) bounds the flight, known free
        space included: an open-topped building is explored inside, not over its walls (issue
        #19: the small house was flown at z 3.24 m over its 3.0 m walls, a shop without a ceiling
        up to 4.3 m). The robot's radius stays inside every face but the floor's.
        """
        v = self.global_map.voxel
        box = self.area.flyable(self.robot_radius)
        centres = [(lo[i] + np.arange(shape[i]) + 0.5) * v for i in range(3)]
        ok = [(c >= box.lo[i]) & (c <= box.hi[i]) for i, c in enumerate(centres)]
        return ok[0][:, None, None] & ok[1][None, :, None] & ok[2][None, None, :]

    def path_costs(self, sources: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """S×T path lengths (m) through known free space with robot clearance; inf if unreachable."""
        self._require()
        graph, p = self._free_graph(), self.params
        block = p.contract_block if graph.n_nodes > p.contract_costs_above else 0
        return graph.costs(sources, targets, contracted_block=block)

    def plan_path(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Shortest 26-connected path over clear known-free voxels, shortcut-smoothed; or None."""
        self._require()
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        v = self.global_map.voxel

        def clear(a: np.ndarray, b: np.ndarray, samples: np.ndarray, at_end: np.ndarray) -> bool:
            if self.params.plan_through_unknown:
                return self.segment_free(a, b)
            known = known_along(samples, v, self.global_map.states_at_index)
            return bool(np.all(known | at_end)) and self.segment_free(a, b)

        return _smoothed_path(self._free_graph(), start, goal, v, clear)

    def plan_path_along_trail(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """A path through the map to the flown :meth:`trail`, along it, and through the map to the
        goal, the cheapest such (:func:`~amslam.lib.free_space.trail_join`); or None.

        Flown as it was flown: the trail's points are a voxel apart, and corners the vehicle did
        not cut are not cut (a straight shortcut between two of them may cross the slab the rules
        keep it from)."""
        self._require()
        trail = self.trail()
        if len(trail) < 2:
            return None
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        costs = self.path_costs(np.stack([start, goal]), trail)
        join = trail_join(trail, costs[0], costs[1])
        if join is None:
            return None
        a, b = join
        to_trail, from_trail = self.plan_path(start, trail[a]), self.plan_path(trail[b], goal)
        if to_trail is None or from_trail is None:
            return None
        along = trail[a : b + 1] if a <= b else trail[b : a + 1][::-1]
        return np.vstack([to_trail, along[1:-1], from_trail])

    def plan_local_path(
        self, start: np.ndarray, goal: np.ndarray, *, margin: float = 1.0
    ) -> np.ndarray | None:
        """A path on the fine local map (odometry frame) from ``start`` to ``goal``, or None.

        The building block of local planning (paper 1 plans trajectories on the local map): the
        same graph rules as the global planner — known free voxels clear of obstacles (occupied,
        unseen slab continuation, carved slab patches) by the local check's radius, vertical moves
        near slabs only through observed space and wide openings — on the 0.1 m voxels the vehicle
        flies by, inside the box spanned by the two ends plus ``margin``. Both ends should lie in
        the local window (a runtime plans to a point of the global path a few metres ahead).
        Line-of-sight shortcuts are checked with :meth:`segment_free` (``local=True``).
        """
        self._require()
        store, p = self.local_map, self.params
        v = store.voxel
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        ends = to_index(np.array([start, goal]), v)
        pad = int(np.ceil(margin / v))
        lo = ends.min(axis=0) - pad
        shape = tuple(int(s) for s in ends.max(axis=0) + pad + 1 - lo)
        states = store.dense_states(lo, shape)
        occ = obstacles(states, v, p.unseen_surface_reach, p.floor_change_opening)
        near = inflate(occ, self.local_radius, v)
        graph = FreeSpaceGraph(
            (states == FREE) & ~near,
            lo,
            v,
            min(p.snap_radius, 3 * v),  # the vehicle's own voxel may be unseen; no more slack than that
            states,
            near_obstacle=near,
            vertical_ok=vertical_ok(
                states,
                self.local_radius,
                v,
                observed=p.observed_floor_changes,
                opening=p.floor_change_opening,
                unseen_reach=p.unseen_surface_reach,
            ),
        )
        return _smoothed_path(graph, start, goal, v, lambda a, b, *_: self.segment_free(a, b, local=True))

    def segment_free(self, a: np.ndarray, b: np.ndarray, *, local: bool = False) -> bool:
        """No occupied voxel within the robot radius of the segment; unknown counts as free except
        the unseen continuation of a seen slab, floor or ceiling (``unseen_surface_reach``)."""
        self._require()
        store = self.local_map if local else self.global_map
        samples = segment_samples(a, b, 0.5 * store.voxel)
        # The local check guards against collision (see local_radius); global segments are
        # planning shortcuts and keep the clearance margin as well.
        radius = self.local_radius if local else self.segment_radius
        return samples_clear(
            samples, radius, store.voxel, store.states_at_index, self.params.unseen_surface_reach
        )

    def blocked(self, points: np.ndarray, *, local: bool = False, climbing: bool = False) -> np.ndarray:
        """Whether each point lies in an obstacle voxel: occupied, or unknown continuing a seen slab,
        floor or ceiling (``unseen_surface_reach``), the rule paths and ``segment_free`` use; with
        ``climbing`` on the local map also the unseen rest of a ceiling's layer
        (``local_ceiling_reach``), what a climb keeps off.

        For clearance checks outside the planner (a setpoint filter): ``states(...) == OCCUPIED``
        misses the unseen top or edge of a slab seen from one side.
        """
        self._require()
        store = self.local_map if local else self.global_map
        idx = to_index(np.asarray(points, dtype=float).reshape(-1, 3), store.voxel)
        if len(idx) == 0:
            return np.zeros(0, dtype=bool)
        reach = self.params.unseen_surface_reach
        ceiling = self.params.local_ceiling_reach if local and climbing else 0.0
        # the surface an unknown voxel continues (a ceiling's rest only within its layer)
        pad = np.array([max(reach, ceiling)] * 2 + [reach]) / store.voxel
        pad = np.maximum(np.round(pad).astype(np.int64), 1) + 2
        lo = idx.min(axis=0) - pad
        shape = tuple(int(s) for s in idx.max(axis=0) + pad + 1 - lo)
        block = store.dense_states(lo, shape)
        return obstacles(block, store.voxel, reach, ceiling_reach=ceiling)[tuple((idx - lo).T)]

    def explored_volume(self) -> float:
        """Known (free or occupied) volume of the global map in m³."""
        self._require()
        idx, _ = self.global_map.voxels()
        return len(idx) * self.global_map.voxel**3

    def _in_box(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        idx, st = self.global_map.voxels()
        a, b = index_box(BoundingBox(np.asarray(lo, float), np.asarray(hi, float)), self.global_map.voxel)
        inside = np.all((idx >= a) & (idx < b), axis=1)
        return idx[inside], st[inside]

    def explored_volume_in(self, lo: np.ndarray, hi: np.ndarray) -> float:
        """Known volume (m³) of global voxels whose centres lie inside the box."""
        self._require()
        return len(self._in_box(lo, hi)[0]) * self.global_map.voxel**3

    def free_volume_in(self, lo: np.ndarray, hi: np.ndarray) -> float:
        """Known free volume (m³) of global voxels whose centres lie inside the box."""
        self._require()
        _, st = self._in_box(lo, hi)
        return int(np.sum((st != OCCUPIED) & (st != UNKNOWN))) * self.global_map.voxel**3

    def occupied_points(self) -> np.ndarray:
        """Centres of occupied global voxels (N×3)."""
        self._require()
        idx, st = self.global_map.voxels()
        return centres(idx[st == OCCUPIED], self.global_map.voxel)

    def voxel_size(self) -> float:
        """Edge of a global voxel in metres."""
        return float(self.params.global_voxel)

    # ------------------------------------------------------------------ persistence
    def save(self, path: Path) -> None:
        """Write both maps (known voxels, sparse) to a compressed ``.npz``."""
        self._require()
        g, loc = self.global_map.to_arrays(), self.local_map.to_arrays()
        np.savez_compressed(
            Path(path),
            format=np.array(SAVED_MAP_FORMAT),
            global_index=g["index"],
            global_logodds=g["logodds"],
            global_voxel=np.array(self.global_map.voxel),
            local_index=loc["index"],
            local_logodds=loc["logodds"],
            local_voxel=np.array(self.local_map.voxel),
            global_slab_history=self.slab_history(),
            **(self._saved_views() if self._seen_through_known else {}),
        )

    def _saved_views(self) -> dict[str, np.ndarray]:
        above, below = self.surfaces_seen_from()
        return {
            "global_seen_through": self.seen_through(),
            "global_seen_from_above": above,
            "global_seen_from_below": below,
        }

    def load(self, path: Path) -> None:
        """Load a map written by :meth:`save` (same voxel sizes), or an OctoMap ``.bt`` into the
        global map (any resolution, resampled: :mod:`amslam.lib.octomap_files`), and recompute
        frontiers. A ``.bt`` has states, not probabilities: its occupied voxels start at the upper
        clamp ``p_max``, its free ones at the lower ``p_min``, as if seen many times."""
        self._require()
        if Path(path).suffix.lower() == ".bt":
            self._load_octomap(Path(path))
            return
        saved = read_saved_map(Path(path))
        for name, grid, store in (
            ("global", saved.global_map, self.global_map),
            ("local", saved.local_map, self.local_map),
        ):
            if grid is None:  # a saved map without its local window starts with an empty one
                continue
            if not np.isclose(grid.voxel, store.voxel):
                raise ValueError(
                    f"{path}: {name} voxel {grid.voxel} m does not match the configured {store.voxel} m"
                )
            store.from_arrays({"index": grid.index, "logodds": grid.logodds})
        history = np.unique(encode(saved.slab_history))
        if not np.array_equal(history, self._slab_history.merged()):  # else the rules' copy holds
            self._slab_history.replace(history)
        views = (saved.seen_through, saved.seen_from_above, saved.seen_from_below)
        known = all(v is not None for v in views)  # a map saved before the sides were kept: rule off
        self._start_seen_through(tuple(encode(v) for v in views) if known else _NO_VIEWS, known=known)
        self._prior_global = self.global_map.to_arrays()
        self._version += 1
        self._graph = None
        self.recompute_frontiers()

    def _load_octomap(self, path: Path) -> None:
        index, occupied = read_bt(path, self.global_map.voxel)
        logodds = np.where(occupied, logit(self.params.p_max), logit(self.params.p_min)).astype(np.float32)
        self.global_map.from_arrays({"index": index, "logodds": logodds})
        self._slab_history.replace(np.zeros(0, np.int64))
        # its openings were never seen through by this flight
        self._start_seen_through(_NO_VIEWS, known=False)
        self._prior_global = self.global_map.to_arrays()
        self._version += 1
        self._graph = None
        self.recompute_frontiers()
