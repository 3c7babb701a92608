"""Incremental frontier detection, clustering and viewpoint sampling (paper 1 §VI-A, after FUEL/SEER).

Backend-independent: the tracker reads voxel states through a :class:`StateSource` (a dense int8
``VoxelState`` block for any index range), so the numpy and open3d backends share one copy.

* A **frontier** voxel is a known-free voxel inside the exploration area with an unknown 6-neighbour
  inside the area.
* After a map update only the touched box is re-examined: old frontiers there that are no longer
  frontiers are removed, new ones added. Clusters that reach into the box are dissolved and their
  surviving voxels re-clustered with the new ones (26-connected components); a re-formed cluster with
  exactly the voxels of a dissolved one *is* that cluster (same id, viewpoint kept). Clusters
  elsewhere keep their id and viewpoint.
* A cluster whose extent along its principal axis exceeds ``max_extent`` is split in two at its mean
  along that axis, recursively.
* Each new cluster gets one viewpoint: candidate positions on rings around its centroid (radii ×
  angles × heights, snapped to voxel centres) that are known free with robot-radius clearance; at
  each, the information gain of every candidate yaw is the unknown volume inside the camera's view
  (azimuth within ±hfov/2 of the yaw, elevation within ±vfov/2, range up to ``sensing_range``) that
  rays from the position reach before their first occupied voxel (see :class:`RayFan`); the best
  (position, yaw) is kept. A cluster whose best gain is below ``min_gain`` gets no viewpoint and is
  dropped.
* The viewpoint carries up to ``n_alternatives`` **alternatives**: the best candidate of each
  candidate height, then the best of each (height, quadrant around the centroid) by gain, each with
  at least ``min_gain``. The best view is chosen without knowing what the robot can reach: with a
  level camera a cluster above a shaft is best seen from the floor above, which the robot reaches
  only after seeing the way up free — from a lower alternative inside the shaft (the demo, seed 11,
  ended at 60 % explored with the upper floor's every viewpoint out of reach). The planning service
  takes the best alternative it has a path to.
* A kept viewpoint within sensing range of the touched box is re-checked at its position (clearance,
  gain of every yaw, best yaw taken); it is resampled when it lost its clearance or its gain fell
  below ``resample_ratio`` of the gain it was sampled with (or below ``min_gain``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from amslam.lib.free_space import clearance_kernel
from amslam.lib.voxel_grid import FREE, OCCUPIED, UNKNOWN, centres, decode, encode, index_box
from amslam.types import BoundingBox, Viewpoint

_IGNORE = np.int8(2)  # unknown outside the exploration area: neither gain nor occlusion
_CHUNK_SAMPLES = 1 << 21  # ray samples per gain batch (bounds the temporaries to a few tens of MB)


class StateSource(Protocol):
    """What the frontier tracker needs from a map."""

    def dense_states(self, lo: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        """int8 VoxelState block for voxel indices ``[lo, lo + shape)``."""
        ...


@dataclass(frozen=True)
class FrontierConfig:
    """Frontier and viewpoint parameters (plain values, unpacked from a backend's Params)."""

    voxel: float
    area: BoundingBox
    robot_radius: float = 0.25
    hfov: float = np.radians(87.0)
    vfov: float = np.radians(58.0)
    sensing_range: float = 4.5
    min_cluster_size: int = 4
    max_extent: float = 2.5
    radii: tuple[float, ...] = (1.0, 1.75, 2.5)
    n_angles: int = 12
    heights: tuple[float, ...] = (-0.5, 0.0, 0.5)
    n_yaws: int = 24
    n_rays_azimuth: int = 72
    n_rays_elevation: int = 8
    min_gain: float = 0.5
    resample_ratio: float = 0.5
    n_alternatives: int = 6


@dataclass
class Cluster:
    """A frontier cluster and its viewpoint."""

    id: int
    keys: np.ndarray
    centroid: np.ndarray
    viewpoint: Viewpoint | None = None
    lo: np.ndarray = field(default_factory=lambda: np.zeros(3, np.int64))
    hi: np.ndarray = field(default_factory=lambda: np.zeros(3, np.int64))
    sampled_gain: float = 0.0  # gain of the viewpoint when it was (re)sampled


# ---------------------------------------------------------------------- information gain
@dataclass(frozen=True)
class RayFan:
    """A fixed fan of rays from a voxel centre, traversed once, reused for every candidate position.

    The fan covers all azimuths (``n_az`` bins of ``2π / n_az``) and the vertical field of view
    (``n_el`` elevation bins). Each ray stands for the cone of its (azimuth, elevation) cell, of solid
    angle ``dΩ = Δaz · (sin e_hi − sin e_lo)``; the voxels it crosses (exact Amanatides–Woo traversal
    from the voxel centre up to the sensing range) carry the volume of that cone between the ray's
    entry and exit distances, ``dΩ (t_out³ − t_in³) / 3``. The unknown volume a candidate sees in an
    azimuth bin is then a weighted sum over the unknown voxels before each ray's first occupied one,
    with no de-duplication, and the gain of a yaw is the sum over the azimuth bins inside its
    horizontal field of view (edge bins counted by their overlap). In free space the weights add up to
    the exact volume of the viewing sector; the estimate agrees with an exact count of distinct
    visible unknown voxels (:func:`exact_gain`) to a few percent (tests/plugins/voxel_numpy).

    Because candidates sit on voxel centres, the crossed voxels are the same integer offsets for
    every candidate: one gather per (candidate, ray, step) evaluates all candidates at once.

    Attributes:
        offsets: M×R×3 voxel offsets of the voxels crossed by each ray, padded with the start voxel.
        weights: M×R volume (m³) of each ray's cone inside each crossed voxel (0 for padding).
        n_az, n_el: azimuth and elevation bins; ray ``r`` is azimuth ``r // n_el``.
        yaw_share: Y×n_az share of each azimuth bin inside the horizontal field of view of each yaw.
    """

    offsets: np.ndarray
    weights: np.ndarray
    n_az: int
    n_el: int
    yaw_share: np.ndarray

    @classmethod
    def build(cls, cfg: FrontierConfig, yaws: np.ndarray) -> RayFan:
        """The fan for a frontier configuration and its candidate yaws."""
        n_az, n_el, v = cfg.n_rays_azimuth, cfg.n_rays_elevation, cfg.voxel
        d_az = 2 * np.pi / n_az
        az = -np.pi + (np.arange(n_az) + 0.5) * d_az
        e_edges = np.linspace(-cfg.vfov / 2, cfg.vfov / 2, n_el + 1)
        el = 0.5 * (e_edges[:-1] + e_edges[1:])
        omega = d_az * (np.sin(e_edges[1:]) - np.sin(e_edges[:-1]))  # solid angle of each cell
        A, E = np.meshgrid(az, el, indexing="ij")
        dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
        offsets, t_in, t_out = _traverse_from_centre(dirs, cfg.sensing_range / v)
        weights = np.tile(omega, n_az)[None, :] * (t_out**3 - t_in**3) / 3.0 * v**3
        # share of azimuth bin [a - d_az/2, a + d_az/2] inside [yaw - h, yaw + h]
        h = min(cfg.hfov / 2, np.pi)
        diff = np.angle(np.exp(1j * (az[None, :] - yaws[:, None])))
        overlap = np.minimum(diff + d_az / 2, h) - np.maximum(diff - d_az / 2, -h)
        share = np.clip(overlap, 0.0, d_az) / d_az
        return cls(offsets, weights, n_az, n_el, share)

    def gains(self, block: _Block, base: np.ndarray) -> np.ndarray:
        """P×Y gain (m³) of candidates at block-flat voxel indices ``base`` (P,), for every yaw."""
        from amslam.lib import gain_rays

        off = self.offsets @ np.asarray(block.strides)  # M×R flat offsets
        M, R = off.shape
        out = np.zeros((len(base), len(self.yaw_share)))
        chunk = max(1, _CHUNK_SAMPLES // (M * R))
        w = np.ascontiguousarray(self.weights, dtype=np.float32)
        off = np.ascontiguousarray(off, dtype=np.int64)
        for i in range(0, len(base), chunk):
            b = base[i : i + chunk]
            # each ray's unknown volume up to its first occupied voxel (_IGNORE neither counts nor
            # blocks), compiled: numpy cannot stop a ray (amslam.lib.gain_rays)
            per_ray = gain_rays.per_ray(block.flat, b, off, w, int(OCCUPIED), int(UNKNOWN))
            per_az = per_ray.reshape(len(b), self.n_az, self.n_el).sum(axis=2)
            out[i : i + chunk] = per_az @ self.yaw_share.T
        return out


def _traverse_from_centre(dirs: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voxels crossed by rays from the centre of voxel 0 (Amanatides–Woo, all rays in lock-step).

    Args:
        dirs: R×3 unit directions; length: ray length in voxel units.

    Returns:
        M×R×3 integer offsets, M×R entry and exit distances (voxel units); finished rays are padded
        with offset 0 and zero-length segments.
    """
    R = len(dirs)
    step = np.sign(dirs).astype(np.int64)
    with np.errstate(divide="ignore"):
        inv = np.where(dirs != 0, 1.0 / np.abs(dirs), np.inf)
    tmax = 0.5 * inv  # the next boundary is half a voxel away on every axis
    cur = np.zeros((R, 3), np.int64)
    t = np.zeros(R)
    rows = np.arange(R)
    offs, t_ins, t_outs = [], [], []
    while np.any(t < length):
        active = t < length
        t_out = np.minimum(tmax.min(axis=1), length)
        offs.append(np.where(active[:, None], cur, 0))
        t_ins.append(np.where(active, t, 0.0))
        t_outs.append(np.where(active, t_out, 0.0))
        axis = np.argmin(tmax, axis=1)
        cur[rows, axis] += step[rows, axis]
        tmax[rows, axis] += inv[rows, axis]
        t = np.where(active, t_out, t)
    return np.stack(offs), np.stack(t_ins), np.stack(t_outs)


@dataclass
class _Block:
    """A dense int8 state block (indices ``[lo, lo + shape)``), unknown outside the area masked."""

    flat: np.ndarray
    lo: np.ndarray
    shape: tuple[int, int, int]

    @property
    def strides(self) -> tuple[int, int, int]:
        return (self.shape[1] * self.shape[2], self.shape[2], 1)

    def flat_index(self, index: np.ndarray) -> np.ndarray:
        return (np.asarray(index, np.int64) - self.lo) @ np.asarray(self.strides, np.int64)


def exact_gain(source: StateSource, cfg: FrontierConfig, position: np.ndarray, yaw: float) -> float:
    """Reference gain (m³): distinct unknown voxels (inside the area) visible in the view of a yaw.

    A voxel counts when its centre lies within ``sensing_range`` of the centre of the position's voxel,
    at an azimuth within ±hfov/2 of ``yaw`` and an elevation within ±vfov/2, and the segment to it
    crosses no occupied voxel (sampled every tenth of a voxel). Slow; for checking :class:`RayFan`.
    """
    v = cfg.voxel
    p_idx = np.floor(np.asarray(position, float) / v).astype(np.int64)
    tracker = FrontierTracker(cfg)
    tracker.sync(source)
    block, reach = tracker.block, tracker._reach
    origin = (p_idx + 0.5) * v
    st = block.flat.reshape(block.shape)
    wlo = p_idx - reach - block.lo
    window = st[tuple(slice(int(a), int(a) + 2 * reach + 1) for a in wlo)]
    cand = np.argwhere(window == UNKNOWN) + p_idx - reach
    vec = centres(cand, v) - origin
    rng = np.linalg.norm(vec, axis=1)
    with np.errstate(invalid="ignore"):
        el = np.arcsin(np.clip(vec[:, 2] / np.maximum(rng, 1e-12), -1, 1))
    az = np.angle(np.exp(1j * (np.arctan2(vec[:, 1], vec[:, 0]) - yaw)))
    inside = (rng <= cfg.sensing_range) & (np.abs(az) <= cfg.hfov / 2) & (np.abs(el) <= cfg.vfov / 2)
    cand, vec, rng = cand[inside], vec[inside], rng[inside]
    if len(cand) == 0:
        return 0.0
    n = int(np.ceil(cfg.sensing_range / (0.1 * v))) + 1
    s = np.linspace(0.0, 1.0, n)
    pts = origin + vec[:, None, :] * s[None, :, None]
    idx = np.floor(pts / v).astype(np.int64)
    on_path = ~np.all(idx == cand[:, None, :], axis=2)  # the target voxel itself does not occlude
    hit = (st[tuple((idx - block.lo).transpose(2, 0, 1))] == OCCUPIED) & on_path
    return float(np.sum(~hit.any(axis=1))) * v**3


class FrontierTracker:
    """Frontier voxels and clusters of one global map, updated box by box.

    ``stats`` counts clusters whose viewpoint was sampled (``sampled``), kept viewpoints re-checked
    in place (``refreshed``) and dissolved clusters that re-formed unchanged (``reused``).
    """

    def __init__(self, config: FrontierConfig):
        self.cfg = config
        self.area_lo, self.area_hi = index_box(config.area, config.voxel)
        self.frontier = np.zeros(0, dtype=np.int64)  # sorted keys
        self.clusters: dict[int, Cluster] = {}
        self._next_id = 0
        self.fan = RayFan.build(config, self._yaws())
        self._reach = int(np.ceil(np.abs(self.fan.offsets).max())) + 1
        r = max(config.robot_radius, 1e-6)
        self._clear_half = int(np.ceil(r / config.voxel + 0.5))
        self._clear = np.argwhere(clearance_kernel(r, config.voxel)) - self._clear_half
        ang = np.linspace(0, 2 * np.pi, config.n_angles, endpoint=False)
        Rr, A, H = np.meshgrid(np.asarray(config.radii), ang, np.asarray(config.heights), indexing="ij")
        self._rings = np.stack([Rr * np.cos(A), Rr * np.sin(A), H], -1).reshape(-1, 3)
        self.stats = {"sampled": 0, "refreshed": 0, "reused": 0}
        # A mirror of the map's states over the area (grown by the clearance), refreshed box by box,
        # padded with _IGNORE far enough that no gain ray or clearance check of a position inside
        # the area leaves the array: every lookup is a plain gather, no bounds checks, no map reads.
        grow, pad = self._clear_half + 2, max(self._reach, self._clear_half) + 1
        self._read_lo, self._read_hi = self.area_lo - grow, self.area_hi + grow
        lo = self._read_lo - pad
        shape = tuple(int(x) for x in self._read_hi - self._read_lo + 2 * pad)
        self._mirror = np.full(shape, _IGNORE, dtype=np.int8)
        self.block = _Block(self._mirror.reshape(-1), lo, shape)
        self._synced = False

    # ------------------------------------------------------------------ state mirror
    def sync(self, source: StateSource, lo: np.ndarray | None = None, hi: np.ndarray | None = None) -> None:
        """Copy the map's states of voxel indices ``[lo, hi)`` (default: all) into the mirror.

        Only the area grown by the clearance is read; unknown voxels outside the area become
        ``_IGNORE`` (they neither make frontiers nor count as gain nor occlude).
        """
        full = lo is None and hi is None
        lo = self._read_lo if lo is None else np.maximum(lo, self._read_lo)
        hi = self._read_hi if hi is None else np.minimum(hi, self._read_hi)
        if np.any(hi <= lo):
            return
        sub = source.dense_states(lo, tuple(int(x) for x in hi - lo))
        a = np.clip(self.area_lo - lo, 0, np.array(sub.shape))
        b = np.clip(self.area_hi - lo, 0, np.array(sub.shape))
        inside = np.zeros(sub.shape, dtype=bool)
        inside[a[0] : b[0], a[1] : b[1], a[2] : b[2]] = True
        sub[(sub == UNKNOWN) & ~inside] = _IGNORE
        self._mirror[self._slices(lo, hi)] = sub
        self._synced = self._synced or full

    def _slices(self, lo: np.ndarray, hi: np.ndarray) -> tuple[slice, slice, slice]:
        return tuple(
            slice(int(x), int(y)) for x, y in zip(lo - self.block.lo, hi - self.block.lo, strict=True)
        )

    # ------------------------------------------------------------------ frontier voxels
    def _frontier_in(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Sorted keys of frontier voxels with indices in ``[lo, hi)`` (already clipped to the area)."""
        s = self._mirror[self._slices(lo - 1, hi + 1)]
        unknown = s == UNKNOWN  # unknown outside the area is _IGNORE in the mirror
        core = (slice(1, -1),) * 3
        near_unknown = np.zeros_like(unknown[core])
        for ax in range(3):
            for d in (-1, 1):
                sl = [slice(1, -1)] * 3
                sl[ax] = slice(1 + d, s.shape[ax] - 1 + d)
                near_unknown |= unknown[tuple(sl)]
        mask = (s[core] == FREE) & near_unknown
        return np.sort(encode(np.argwhere(mask) + lo))

    def update(self, source: StateSource, box: BoundingBox) -> None:
        """Re-examine frontiers inside ``box`` (plus one voxel) and re-cluster what changed."""
        if box.empty:
            return
        v = self.cfg.voxel
        lo = np.floor(np.asarray(box.lo) / v).astype(np.int64) - 1
        hi = np.floor(np.asarray(box.hi) / v).astype(np.int64) + 2
        if self._synced:
            self.sync(source, lo, hi)
        else:
            self.sync(source)
        lo, hi = np.maximum(lo, self.area_lo), np.minimum(hi, self.area_hi)
        if np.any(hi <= lo):
            return
        new = self._frontier_in(lo, hi)
        idx = decode(self.frontier)
        in_box = np.all((idx >= lo) & (idx < hi), axis=1)
        self.frontier = np.union1d(self.frontier[~in_box], new)

        # dissolve clusters that reach into the box grown by one voxel (adjacency), keep the rest
        glo, ghi = lo - 1, hi + 1
        pool = [new]
        dissolved: dict[tuple[int, int], Cluster] = {}
        for cid in list(self.clusters):
            c = self.clusters[cid]
            if np.all(c.hi > glo) and np.all(c.lo < ghi):
                pool.append(c.keys)
                dissolved[_signature(c.keys)] = c
                del self.clusters[cid]
        kept = (
            np.concatenate([c.keys for c in self.clusters.values()])
            if self.clusters
            else np.zeros(0, np.int64)
        )
        pool_keys = np.setdiff1d(np.intersect1d(np.concatenate(pool), self.frontier), kept)
        fresh: list[Cluster] = []
        for keys in self._components(pool_keys):
            for part in self._split(keys):
                if len(part) < self.cfg.min_cluster_size:
                    continue
                old = dissolved.pop(_signature(part), None)
                if old is not None and np.array_equal(old.keys, part):
                    self.clusters[old.id] = old  # the same frontier voxels: the same cluster
                    self.stats["reused"] += 1
                else:
                    fresh.append(self._new_cluster(part))
        self._update_viewpoints(fresh, lo, hi)

    def recompute(self, source: StateSource) -> None:
        """Forget everything and detect frontiers and clusters over the whole area."""
        self.frontier = np.zeros(0, dtype=np.int64)
        self.clusters.clear()
        self._synced = False
        v = self.cfg.voxel
        self.update(source, BoundingBox(self.area_lo * v, self.area_hi * v))

    # ------------------------------------------------------------------ clusters
    @staticmethod
    def _components(keys: np.ndarray) -> list[np.ndarray]:
        from scipy import ndimage

        if len(keys) == 0:
            return []
        idx = decode(keys)
        lo = idx.min(axis=0)
        grid = np.zeros(tuple(idx.max(axis=0) - lo + 1), dtype=bool)
        grid[tuple((idx - lo).T)] = True
        labels, n = ndimage.label(grid, structure=np.ones((3, 3, 3), dtype=bool))
        lab = labels[tuple((idx - lo).T)]
        order = np.argsort(lab, kind="stable")
        bounds = np.searchsorted(lab[order], np.arange(1, n + 2))
        return [np.sort(keys[order[bounds[i] : bounds[i + 1]]]) for i in range(n)]

    def _split(self, keys: np.ndarray) -> list[np.ndarray]:
        pts = centres(decode(keys), self.cfg.voxel)
        if len(pts) < 2:
            return [keys]
        centred = pts - pts.mean(axis=0)
        _, vecs = np.linalg.eigh(centred.T @ centred)  # principal axis: largest eigenvalue, last
        proj = centred @ vecs[:, -1]
        if proj.max() - proj.min() <= self.cfg.max_extent:
            return [keys]
        side = proj > 0
        if side.all() or not side.any():
            return [keys]
        return self._split(keys[side]) + self._split(keys[~side])

    def _new_cluster(self, keys: np.ndarray) -> Cluster:
        idx = decode(keys)
        c = Cluster(
            id=self._next_id,
            keys=keys,
            centroid=centres(idx, self.cfg.voxel).mean(axis=0),
            lo=idx.min(axis=0),
            hi=idx.max(axis=0) + 1,
        )
        self._next_id += 1
        return c

    # ------------------------------------------------------------------ viewpoints
    def _yaws(self) -> np.ndarray:
        return np.linspace(-np.pi, np.pi, self.cfg.n_yaws, endpoint=False) + np.pi / self.cfg.n_yaws

    def _safe(self, index: np.ndarray) -> np.ndarray:
        """Candidate voxels whose voxels within the robot radius are all known free, and where the
        robot stays inside the area on every face but the floor's (the planner's flyable volume:
        a viewpoint over an open-topped building's walls could never be reached)."""
        inside = self.cfg.area.flyable(self.cfg.robot_radius).contains(centres(index, self.cfg.voxel))
        out = np.zeros(len(index), dtype=bool)
        if inside.any():
            base = self.block.flat_index(index[inside])
            kern = self._clear @ np.asarray(self.block.strides, np.int64)
            out[inside] = np.all(self.block.flat[base[:, None] + kern[None, :]] == FREE, axis=1)
        return out

    def _candidates(self, c: Cluster) -> np.ndarray:
        """Voxel indices (N×3, distinct) of the candidate positions around a cluster's centroid."""
        v = self.cfg.voxel
        return decode(np.unique(encode(np.floor((c.centroid + self._rings) / v).astype(np.int64))))

    def _update_viewpoints(self, fresh: list[Cluster], lo: np.ndarray, hi: np.ndarray) -> None:
        """Sample viewpoints of new clusters and re-check kept ones that can see into ``[lo, hi)``.

        A kept viewpoint within sensing range of the box stays where it is (best yaw re-chosen, gain
        updated) unless it lost its clearance or its gain fell below ``resample_ratio`` of its sampled
        gain or below ``min_gain``; then its cluster is sampled again.
        """
        cfg, v = self.cfg, self.cfg.voxel
        blo, bhi = lo * v, hi * v
        kept = list(self.clusters.values())
        pos = np.array([c.viewpoint.position for c in kept]).reshape(-1, 3)
        gap = np.linalg.norm(np.maximum(np.maximum(blo - pos, pos - bhi), 0.0), axis=1)
        near = [c for c, g in zip(kept, gap, strict=True) if g <= cfg.sensing_range + v]
        resample = []
        if near:
            self.stats["refreshed"] += len(near)
            here = np.floor(np.array([c.viewpoint.position for c in near]) / v).astype(np.int64)
            safe = self._safe(here)
            gains = np.zeros((len(near), len(self.fan.yaw_share)))
            if safe.any():
                gains[safe] = self.fan.gains(self.block, self.block.flat_index(here[safe]))
            yaws = self._yaws()
            kept_near = []
            for c, ok, g in zip(near, safe, gains, strict=True):
                best = int(np.argmax(g))
                if not ok or g[best] < max(cfg.resample_ratio * c.sampled_gain, cfg.min_gain):
                    del self.clusters[c.id]
                    resample.append(c)
                else:
                    alternatives = c.viewpoint.alternatives
                    c.viewpoint = self._make_viewpoint(c, c.viewpoint.position, yaws[best], g[best])
                    c.viewpoint = dataclasses.replace(c.viewpoint, alternatives=alternatives)
                    kept_near.append(c)
            self._refresh_alternatives(kept_near)
        self._sample_viewpoints(fresh + resample)

    def _refresh_alternatives(self, clusters: list[Cluster]) -> None:
        """Re-check the alternatives of viewpoints kept in place: the best yaw again, and those that
        lost their clearance or fell below ``min_gain`` dropped."""
        alts = [(c, a) for c in clusters for a in c.viewpoint.alternatives]
        if not alts:
            return
        v = self.cfg.voxel
        here = np.floor(np.array([a.position for _, a in alts]) / v).astype(np.int64)
        safe = self._safe(here)
        gains = np.zeros((len(alts), len(self.fan.yaw_share)))
        if safe.any():
            gains[safe] = self.fan.gains(self.block, self.block.flat_index(here[safe]))
        yaws = self._yaws()
        fresh: dict[int, list[Viewpoint]] = {c.id: [] for c in clusters}
        for (c, a), ok, g in zip(alts, safe, gains, strict=True):
            best = int(np.argmax(g))
            if ok and g[best] >= self.cfg.min_gain:
                fresh[c.id].append(self._make_viewpoint(c, a.position, yaws[best], g[best]))
        for c in clusters:
            kept = sorted(fresh[c.id], key=lambda a: -a.gain)
            c.viewpoint = dataclasses.replace(c.viewpoint, alternatives=tuple(kept))

    def _sample_viewpoints(self, clusters: list[Cluster]) -> None:
        """Pick each cluster's best (candidate, yaw), all candidates in one batch; keep those with one."""
        if not clusters:
            return
        self.stats["sampled"] += len(clusters)
        v = self.cfg.voxel
        cands = [self._candidates(c) for c in clusters]
        owner = np.concatenate([np.full(len(k), i) for i, k in enumerate(cands)])
        index = np.concatenate(cands)
        safe = self._safe(index)
        index, owner = index[safe], owner[safe]
        gains = self.fan.gains(self.block, self.block.flat_index(index)) if len(index) else np.zeros((0, 1))
        yaws = self._yaws()
        best_p = np.argmax(gains, axis=1)
        best_g = gains[np.arange(len(index)), best_p]
        pos = centres(index, v)
        for i, c in enumerate(clusters):
            rows = np.nonzero(owner == i)[0]
            if len(rows) == 0:
                continue
            r = rows[int(np.argmax(best_g[rows]))]  # first best on ties: deterministic
            c.viewpoint = self._make_viewpoint(c, pos[r], yaws[best_p[r]], best_g[r])
            if c.viewpoint is not None:
                alts = self._alternative_rows(c, rows, r, pos, best_g)
                c.viewpoint = dataclasses.replace(
                    c.viewpoint,
                    alternatives=tuple(
                        self._make_viewpoint(c, pos[a], yaws[best_p[a]], best_g[a]) for a in alts
                    ),
                )
                c.sampled_gain = float(best_g[r])
                self.clusters[c.id] = c

    def _alternative_rows(
        self, c: Cluster, rows: np.ndarray, best: int, pos: np.ndarray, gain: np.ndarray
    ) -> list[int]:
        """Rows of a cluster's alternative viewpoints (see the module doc), best first.

        Candidates are grouped by height (their voxel layer: one per candidate height) and by
        quadrant around the centroid; the best of every height comes first, then the best of
        every (height, quadrant) group by gain, up to ``n_alternatives``.
        """
        n = self.cfg.n_alternatives
        rows = rows[gain[rows] >= self.cfg.min_gain]
        if n <= 0 or len(rows) < 2:
            return []
        rel = pos[rows] - c.centroid
        level = np.round(pos[rows, 2] / self.cfg.voxel).astype(np.int64)  # one per candidate height
        quadrant = ((np.arctan2(rel[:, 1], rel[:, 0]) + np.pi) // (np.pi / 2)).astype(np.int64)
        order = np.argsort(-gain[rows], kind="stable")
        first_of_level: dict[int, int] = {}
        first_of_group: dict[tuple[int, int], int] = {}
        for k in order:
            first_of_level.setdefault(int(level[k]), int(rows[k]))
            first_of_group.setdefault((int(level[k]), int(quadrant[k])), int(rows[k]))
        by_gain = sorted(first_of_group.values(), key=lambda q: -gain[q])
        out: list[int] = []
        for q in [*sorted(first_of_level.values(), key=lambda q: -gain[q]), *by_gain]:
            if q != best and q not in out and len(out) < n:
                out.append(q)
        return sorted(out, key=lambda q: -gain[q])

    def _make_viewpoint(self, c: Cluster, position: np.ndarray, yaw: float, gain: float) -> Viewpoint | None:
        if gain < self.cfg.min_gain:
            return None
        return Viewpoint(
            id=c.id,
            position=np.asarray(position, dtype=float).copy(),
            yaw=float(yaw),
            gain=float(gain),
            cluster_centroid=c.centroid.copy(),
            cluster_size=len(c.keys),
        )

    def yaw_gains(self, source: StateSource, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidate yaws (Y,) and the P×Y ray-fan gain (m³) from the voxel centres of ``positions``.

        Reads the whole area from ``source`` first (a diagnostic, not on the update path); positions
        must lie inside the area.
        """
        pts = np.asarray(positions, float).reshape(-1, 3)
        if not np.all((pts >= self.cfg.area.lo) & (pts <= self.cfg.area.hi)):
            raise ValueError("yaw_gains: positions must lie inside the exploration area")
        self.sync(source)
        index = np.floor(pts / self.cfg.voxel).astype(np.int64)
        return self._yaws(), self.fan.gains(self.block, self.block.flat_index(index))

    def viewpoints(self) -> list[Viewpoint]:
        """Current viewpoints, ordered by cluster id."""
        return [self.clusters[k].viewpoint for k in sorted(self.clusters) if self.clusters[k].viewpoint]

    def frontier_points(self) -> np.ndarray:
        """Centres of all frontier voxels (N×3)."""
        return centres(decode(self.frontier), self.cfg.voxel)


def _signature(keys: np.ndarray) -> tuple[int, int]:
    """A cheap fingerprint of a sorted key set (its size and a hash of its bytes)."""
    return len(keys), hash(np.ascontiguousarray(keys).tobytes())
