"""Incremental frontier detection, clustering and viewpoint sampling (paper 1 §VI-A, after FUEL/SEER).

Backend-independent: the tracker reads voxel states through a :class:`StateSource` (a dense int8
``VoxelState`` block for any index range), so the numpy and open3d backends share one copy.

* A **frontier** voxel is a known-free voxel inside the exploration area with an unknown 6-neighbour
  inside the area.
* After a map update only the touched box is re-examined: old frontiers there that are no longer
  frontiers are removed, new ones added. Clusters that reach into the box are dissolved and their
  surviving voxels re-clustered with the new ones (26-connected components); clusters elsewhere keep
  their id and viewpoint.
* A cluster whose extent along its principal axis exceeds ``max_extent`` is split in two at its mean
  along that axis, recursively.
* Each cluster gets one viewpoint: candidate positions on rings around its centroid (radii × angles ×
  heights) that are known free with robot-radius clearance; at each, the information gain of every
  candidate yaw is the number of distinct unknown voxels inside the camera frustum, counted by
  casting rays that stop at the first occupied voxel; the best (position, yaw) is kept. A cluster
  whose best gain is negligible gets no viewpoint and is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy import ndimage

from amslam.plugins.voxel_numpy.grid import FREE, OCCUPIED, UNKNOWN, centres, decode, encode, index_box
from amslam.plugins.voxel_numpy.search import clearance_kernel
from amslam.types import BoundingBox, Viewpoint

_IGNORE = np.int8(2)  # unknown outside the exploration area: neither gain nor occlusion


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


@dataclass
class Cluster:
    """A frontier cluster and its viewpoint."""

    id: int
    keys: np.ndarray
    centroid: np.ndarray
    viewpoint: Viewpoint | None = None
    lo: np.ndarray = field(default_factory=lambda: np.zeros(3, np.int64))
    hi: np.ndarray = field(default_factory=lambda: np.zeros(3, np.int64))


class FrontierTracker:
    """Frontier voxels and clusters of one global map, updated box by box."""

    def __init__(self, config: FrontierConfig):
        self.cfg = config
        self.area_lo, self.area_hi = index_box(config.area, config.voxel)
        self.frontier = np.zeros(0, dtype=np.int64)  # sorted keys
        self.clusters: dict[int, Cluster] = {}
        self._next_id = 0

    # ------------------------------------------------------------------ frontier voxels
    def _frontier_in(self, source: StateSource, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Sorted keys of frontier voxels with indices in ``[lo, hi)`` (already clipped to the area)."""
        shape = tuple(int(s) for s in hi - lo + 2)
        s = source.dense_states(lo - 1, shape)
        # neighbours outside the area never make a frontier: mark them as not unknown
        rel_lo, rel_hi = self.area_lo - (lo - 1), self.area_hi - (lo - 1)
        outside = np.ones(shape, dtype=bool)
        a, b = np.maximum(rel_lo, 0), np.minimum(rel_hi, np.array(shape))
        outside[a[0] : b[0], a[1] : b[1], a[2] : b[2]] = False
        unknown = (s == UNKNOWN) & ~outside
        core = (slice(1, -1),) * 3
        near_unknown = np.zeros_like(unknown[core])
        for ax in range(3):
            for d in (-1, 1):
                sl = [slice(1, -1)] * 3
                sl[ax] = slice(1 + d, shape[ax] - 1 + d)
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
        lo, hi = np.maximum(lo, self.area_lo), np.minimum(hi, self.area_hi)
        if np.any(hi <= lo):
            return
        new = self._frontier_in(source, lo, hi)
        idx = decode(self.frontier)
        in_box = np.all((idx >= lo) & (idx < hi), axis=1)
        self.frontier = np.union1d(self.frontier[~in_box], new)

        # dissolve clusters that reach into the box grown by one voxel (adjacency), keep the rest
        glo, ghi = lo - 1, hi + 1
        pool = [new]
        for cid in list(self.clusters):
            c = self.clusters[cid]
            if np.all(c.hi > glo) and np.all(c.lo < ghi):
                pool.append(c.keys)
                del self.clusters[cid]
        kept = (
            np.concatenate([c.keys for c in self.clusters.values()])
            if self.clusters
            else np.zeros(0, np.int64)
        )
        pool_keys = np.setdiff1d(np.intersect1d(np.concatenate(pool), self.frontier), kept)
        for keys in self._components(pool_keys):
            for part in self._split(keys):
                if len(part) >= self.cfg.min_cluster_size:
                    self._add_cluster(source, part)
        self._refresh_viewpoints(source, lo, hi)

    def recompute(self, source: StateSource) -> None:
        """Forget everything and detect frontiers and clusters over the whole area."""
        self.frontier = np.zeros(0, dtype=np.int64)
        self.clusters.clear()
        v = self.cfg.voxel
        self.update(source, BoundingBox(self.area_lo * v, self.area_hi * v))

    # ------------------------------------------------------------------ clusters
    @staticmethod
    def _components(keys: np.ndarray) -> list[np.ndarray]:
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
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        proj = centred @ vt[0]
        if proj.max() - proj.min() <= self.cfg.max_extent:
            return [keys]
        side = proj > 0
        if side.all() or not side.any():
            return [keys]
        return self._split(keys[side]) + self._split(keys[~side])

    def _add_cluster(self, source: StateSource, keys: np.ndarray) -> None:
        idx = decode(keys)
        c = Cluster(
            id=self._next_id,
            keys=keys,
            centroid=centres(idx, self.cfg.voxel).mean(axis=0),
            lo=idx.min(axis=0),
            hi=idx.max(axis=0) + 1,
        )
        self._next_id += 1
        c.viewpoint = self._sample_viewpoint(source, c)
        if c.viewpoint is not None:
            self.clusters[c.id] = c

    def _refresh_viewpoints(self, source: StateSource, lo: np.ndarray, hi: np.ndarray) -> None:
        """Clusters whose viewpoint can see into the touched box: re-check safety and gain."""
        v = self.cfg.voxel
        reach = self.cfg.sensing_range + v
        blo, bhi = lo * v - reach, hi * v + reach
        for cid in list(self.clusters):
            c = self.clusters[cid]
            vp = c.viewpoint
            if vp is None or np.any(vp.position < blo) or np.any(vp.position > bhi):
                continue
            pos = vp.position[None]
            region_lo, shape = self._region(pos)
            states = source.dense_states(region_lo, shape)
            self._mask_outside_area(states, region_lo)
            if not self._safe(states, region_lo, pos)[0]:
                c.viewpoint = self._sample_viewpoint(source, c)
            else:
                gains = self._yaw_gains(states, region_lo, pos)[0]
                yaws = self._yaws()
                best = int(np.argmax(gains))
                c.viewpoint = self._make_viewpoint(c, vp.position, yaws[best], gains[best])
            if c.viewpoint is None:
                del self.clusters[cid]

    # ------------------------------------------------------------------ viewpoints
    def _yaws(self) -> np.ndarray:
        return np.linspace(-np.pi, np.pi, self.cfg.n_yaws, endpoint=False) + np.pi / self.cfg.n_yaws

    def _region(self, positions: np.ndarray) -> tuple[np.ndarray, tuple[int, int, int]]:
        v = self.cfg.voxel
        reach = self.cfg.sensing_range + self.cfg.robot_radius + 2 * v
        lo = np.floor((positions.min(axis=0) - reach) / v).astype(np.int64)
        hi = np.floor((positions.max(axis=0) + reach) / v).astype(np.int64) + 1
        return lo, tuple(int(s) for s in hi - lo)

    def _mask_outside_area(self, states: np.ndarray, lo: np.ndarray) -> None:
        a = np.clip(self.area_lo - lo, 0, np.array(states.shape))
        b = np.clip(self.area_hi - lo, 0, np.array(states.shape))
        inside = np.zeros(states.shape, dtype=bool)
        inside[a[0] : b[0], a[1] : b[1], a[2] : b[2]] = True
        states[(states == UNKNOWN) & ~inside] = _IGNORE

    def _safe(self, states: np.ndarray, lo: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """Candidates inside the area whose voxels within the robot radius are all known free."""
        v = self.cfg.voxel
        kernel = np.argwhere(clearance_kernel(max(self.cfg.robot_radius, 1e-6), v)) - int(
            np.ceil(max(self.cfg.robot_radius, 1e-6) / v + 0.5)
        )
        rel = np.floor(positions / v).astype(np.int64) - lo
        cells = rel[:, None, :] + kernel[None]
        ok = np.all((cells >= 0) & (cells < np.array(states.shape)), axis=(1, 2))
        out = np.zeros(len(positions), dtype=bool)
        if ok.any():
            st = states[tuple(cells[ok].reshape(-1, 3).T)].reshape(int(ok.sum()), -1)
            out[ok] = np.all(st == FREE, axis=1)
        a_lo, a_hi = self.cfg.area.lo, self.cfg.area.hi
        return out & np.all((positions >= a_lo) & (positions <= a_hi), axis=1)

    def _yaw_gains(self, states: np.ndarray, lo: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """P×Y cell-counting information gain (m³) of each candidate position and yaw.

        Rays fan out over all azimuths and the vertical field of view; each stops at its first
        occupied voxel. A voxel counts once per (position, yaw) however many rays see it.
        """
        chunk = 12  # bounds memory: chunk × rays × steps samples at a time
        return np.vstack(
            [
                self._yaw_gains_chunk(states, lo, positions[i : i + chunk])
                for i in range(0, len(positions), chunk)
            ]
            or [np.zeros((0, self.cfg.n_yaws))]
        )

    def _yaw_gains_chunk(self, states: np.ndarray, lo: np.ndarray, positions: np.ndarray) -> np.ndarray:
        cfg, v = self.cfg, self.cfg.voxel
        az = np.linspace(-np.pi, np.pi, cfg.n_rays_azimuth, endpoint=False)
        el = np.linspace(-cfg.vfov / 2, cfg.vfov / 2, cfg.n_rays_elevation)
        A, E = np.meshgrid(az, el, indexing="ij")
        dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
        ray_az = np.repeat(np.arange(cfg.n_rays_azimuth), cfg.n_rays_elevation)
        t = np.arange(0.5 * v, cfg.sensing_range, 0.5 * v)
        P, R, S = len(positions), len(dirs), len(t)
        pts = positions[:, None, None, :] + dirs[None, :, None, :] * t[None, None, :, None]
        rel = np.floor(pts / v).astype(np.int64) - lo
        inside = np.all((rel >= 0) & (rel < np.array(states.shape)), axis=-1)
        rel = np.where(inside[..., None], rel, 0)
        st = np.where(inside, states[rel[..., 0], rel[..., 1], rel[..., 2]], _IGNORE)
        blocked = np.cumsum(st == OCCUPIED, axis=-1) > 0
        seen = (st == UNKNOWN) & ~blocked
        flat = np.ravel_multi_index((rel[..., 0], rel[..., 1], rel[..., 2]), states.shape)
        # (position, azimuth bin, voxel) triples, unique
        p_id = np.broadcast_to(np.arange(P)[:, None, None], (P, R, S))[seen]
        b_id = np.broadcast_to(ray_az[None, :, None], (P, R, S))[seen]
        vox = flat[seen]
        nvox = int(np.prod(states.shape))
        yaws = self._yaws()
        gains = np.zeros((P, len(yaws)))
        if len(vox) == 0:
            return gains
        # which yaws see each azimuth bin (bin centre within half the horizontal fov)
        diff = np.angle(np.exp(1j * (az[:, None] - yaws[None, :])))
        sees = np.abs(diff) <= cfg.hfov / 2
        for y in range(len(yaws)):
            sel = sees[b_id, y]
            u = np.unique(p_id[sel].astype(np.int64) * nvox + vox[sel])
            gains[:, y] = np.bincount(u // nvox, minlength=P)
        return gains * v**3

    def _sample_viewpoint(self, source: StateSource, c: Cluster) -> Viewpoint | None:
        cfg = self.cfg
        ang = np.linspace(0, 2 * np.pi, cfg.n_angles, endpoint=False)
        R, A, H = np.meshgrid(np.asarray(cfg.radii), ang, np.asarray(cfg.heights), indexing="ij")
        cand = np.stack([R * np.cos(A), R * np.sin(A), H], -1).reshape(-1, 3) + c.centroid
        lo, shape = self._region(cand)
        states = source.dense_states(lo, shape)
        self._mask_outside_area(states, lo)
        cand = cand[self._safe(states, lo, cand)]
        if len(cand) == 0:
            return None
        gains = self._yaw_gains(states, lo, cand)
        p, y = np.unravel_index(int(np.argmax(gains)), gains.shape)
        return self._make_viewpoint(c, cand[p], self._yaws()[y], gains[p, y])

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

    def viewpoints(self) -> list[Viewpoint]:
        """Current viewpoints, ordered by cluster id."""
        return [self.clusters[k].viewpoint for k in sorted(self.clusters) if self.clusters[k].viewpoint]

    def frontier_points(self) -> np.ndarray:
        """Centres of all frontier voxels (N×3)."""
        return centres(decode(self.frontier), self.cfg.voxel)
