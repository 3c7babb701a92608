"""One OctoMap occupancy octree (``pyoctomap.OcTree``) behind the small storage API the backend needs.

OctoMap does the occupancy work in C++: ``insertPointCloud`` casts every ray (3-D DDA over the
octree keys), applies one miss to each voxel a ray crosses and one hit to each voxel a ray ends in
(a hit wins over misses within one scan), clamps log-odds, and prunes eight equal children into
their parent. This module only converts depth images into point clouds and reads the tree back.

Lattice: OctoMap's key of a coordinate ``c`` at resolution ``s`` is ``floor(c / s) + 32768``, so
voxel index ``i`` spans ``[i s, (i + 1) s)`` — exactly amslam's voxel lattice, which lets the shared
frontier and graph-search helpers work on the states read from the tree.

Reading: a pruned leaf stands for a cube of ``2**k`` voxels per edge. Block queries walk the leaves
that intersect the block (``begin_leafs_bbx``), so their cost grows with the number of leaves, not
of voxels; point queries use ``search``. The pyoctomap bindings loop in Python over leaves and
points, which is why reads are batched into blocks wherever possible.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass

import numpy as np
import pyoctomap

from amslam.types import BoundingBox, VoxelState

UNKNOWN = np.int8(VoxelState.UNKNOWN.value)
FREE = np.int8(VoxelState.FREE.value)
OCCUPIED = np.int8(VoxelState.OCCUPIED.value)

#: OctoMap keys are 16-bit: coordinates must stay within ±32768 voxels of the origin.
_KEY_HALF_RANGE = 1 << 15


@dataclass(frozen=True)
class SensorModel:
    """OctoMap's occupancy parameters (probabilities; OctoMap stores their log-odds)."""

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    occupancy_threshold: float = 0.5
    clamping_min: float = 0.1192
    clamping_max: float = 0.971

    def apply(self, tree: pyoctomap.OcTree) -> None:
        """Set the model on a tree (trees read from a file come with OctoMap's defaults)."""
        tree.setProbHit(self.prob_hit)
        tree.setProbMiss(self.prob_miss)
        tree.setOccupancyThres(self.occupancy_threshold)
        tree.setClampingThresMin(self.clamping_min)
        tree.setClampingThresMax(self.clamping_max)


@dataclass(frozen=True)
class Leaves:
    """Leaves of the tree as arrays: each a cube of ``n`` voxels per edge starting at index ``lo``."""

    lo: np.ndarray  # N×3 int64 voxel index of the cube's first voxel
    n: np.ndarray  # N int64 voxels per edge (a power of two)
    state: np.ndarray  # N int8 VoxelState (FREE or OCCUPIED)

    def __len__(self) -> int:
        return len(self.n)


class OctreeStore:
    """An OctoMap octree with batched depth integration and block reads.

    Args:
        voxel: resolution (edge of the finest voxel), metres.
        sensor: occupancy model.
        limit: metric box outside which updates are ignored (OctoMap's BBX limit), or None.
    """

    def __init__(self, voxel: float, sensor: SensorModel, limit: BoundingBox | None = None):
        self.voxel = float(voxel)
        self.sensor = sensor
        self.tree = pyoctomap.OcTree(self.voxel)
        sensor.apply(self.tree)
        self.limit: BoundingBox | None = None
        if limit is not None:
            self.set_limit(limit)

    # ------------------------------------------------------------------ updates
    def set_limit(self, box: BoundingBox) -> None:
        """Restrict updates to ``box`` (snapped outwards to whole voxels)."""
        lo = np.floor(np.asarray(box.lo) / self.voxel) * self.voxel
        hi = np.ceil(np.asarray(box.hi) / self.voxel) * self.voxel
        self.limit = BoundingBox(lo, hi)
        self.tree.useBBXLimit(True)
        # OctoMap compares keys: the limit is the keys of the first and last voxel centres
        self.tree.setBBXMin(np.asarray(lo + 0.5 * self.voxel, dtype=np.float64))
        self.tree.setBBXMax(np.asarray(hi - 0.5 * self.voxel, dtype=np.float64))

    def integrate_depth(
        self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, stride: int, max_range: float
    ) -> BoundingBox:
        """Insert a depth image as one OctoMap scan; return the box of the voxels it can have touched.

        Pixels with a return within ``max_range`` become end points (hits). Pixels without a return
        (0, NaN, inf) or with a farther one become points beyond ``max_range`` along their ray:
        OctoMap then clears the ray up to ``max_range`` and marks no hit, which is how a sensor
        reports free space it saw through.
        """
        d = np.asarray(depth, dtype=np.float64)[::stride, ::stride]
        v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(d.shape)], -1).reshape(
            -1, 3
        )
        d = d.reshape(-1)
        norm = np.linalg.norm(rays, axis=1)
        rng = d * norm
        hit = np.isfinite(d) & (d > 0) & (rng <= max_range)
        far = max_range + 2.0 * self.voxel
        length = np.where(hit, rng, far)
        T = np.asarray(T_world_cam, dtype=np.float64)
        origin = T[:3, 3].copy()
        dirs = (rays / norm[:, None]) @ T[:3, :3].T
        points = origin + dirs * length[:, None]
        if len(points) == 0:
            return BoundingBox.nothing()
        self.tree.insertPointCloud(np.ascontiguousarray(points), origin, max_range=float(max_range))
        # every updated voxel lies on a ray between the origin and its (clipped) end point
        ends = origin + dirs * np.minimum(length, max_range)[:, None]
        corners = np.vstack([origin, ends])
        lo = np.floor(corners.min(axis=0) / self.voxel) * self.voxel
        hi = (np.floor(corners.max(axis=0) / self.voxel) + 1) * self.voxel
        if self.limit is not None:
            lo, hi = np.maximum(lo, self.limit.lo), np.minimum(hi, self.limit.hi)
        return BoundingBox(lo, hi)

    def forget_outside(self, box: BoundingBox) -> None:
        """Delete everything outside ``box`` (a moving window); voxels inside are kept as they are.

        Only the slabs between the old limit and ``box`` are visited. A pruned leaf straddling the
        boundary is deleted whole and its voxels inside ``box`` are written back with their log-odds.
        """
        old = self.limit
        self.set_limit(box)
        if old is None or len(self) == 0:
            return
        a, b = self._index_range(self.limit)
        olo, ohi = self._index_range(old)
        slabs = []
        for ax in range(3):
            if olo[ax] < a[ax]:
                hi = ohi.copy()
                hi[ax] = min(a[ax], ohi[ax])
                slabs.append((olo.copy(), hi))
            if ohi[ax] > b[ax]:
                lo = olo.copy()
                lo[ax] = max(b[ax], olo[ax])
                slabs.append((lo, ohi.copy()))
        seen: set[tuple[int, int, int, int]] = set()
        rewrite_points, rewrite_values = [], []
        for lo, hi in slabs:
            if np.any(hi <= lo):
                continue
            for c, size, depth in self._raw_leaves(lo, hi):
                n = int(round(size / self.voxel))
                first = np.floor(np.asarray(c) / self.voxel - 0.5 * n + 0.5).astype(np.int64)
                tag = (*first.tolist(), n)
                if tag in seen:
                    continue
                seen.add(tag)
                node = self.tree.search(np.asarray(c, dtype=np.float64))
                value = node.getLogOdds() if node is not None else 0.0
                self.tree.deleteNode(np.asarray(c, dtype=np.float64), int(depth))
                keep_lo, keep_hi = np.maximum(first, a), np.minimum(first + n, b)
                if np.all(keep_hi > keep_lo):  # straddling leaf: write back the part inside
                    g = np.stack(
                        np.meshgrid(
                            *[np.arange(x, y) for x, y in zip(keep_lo, keep_hi, strict=True)], indexing="ij"
                        ),
                        -1,
                    ).reshape(-1, 3)
                    rewrite_points.append((g + 0.5) * self.voxel)
                    rewrite_values.append(np.full(len(g), value))
        if rewrite_points:
            pts, vals = np.vstack(rewrite_points), np.concatenate(rewrite_values)
            for p, val in zip(pts, vals, strict=True):  # new nodes start at log-odds 0: adding sets
                self.tree.updateNode(p, float(val), True)
            self.tree.updateInnerOccupancy()

    # ------------------------------------------------------------------ reads
    def __len__(self) -> int:
        return int(self.tree.getNumLeafNodes()) if self.tree.size() > 0 else 0

    def _index_range(self, box: BoundingBox) -> tuple[np.ndarray, np.ndarray]:
        lo = np.rint(np.asarray(box.lo) / self.voxel).astype(np.int64)
        hi = np.rint(np.asarray(box.hi) / self.voxel).astype(np.int64)
        return lo, hi

    def _raw_leaves(self, lo: np.ndarray | None = None, hi: np.ndarray | None = None):
        """(centre, size, depth) of the leaves intersecting voxel indices ``[lo, hi)`` (all by default)."""
        if self.tree.size() == 0:
            return
        if lo is None:
            it = self.tree.begin_leafs()
        else:
            lo = np.maximum(np.asarray(lo), -_KEY_HALF_RANGE)
            hi = np.minimum(np.asarray(hi), _KEY_HALF_RANGE)
            if np.any(hi <= lo):
                return
            it = self.tree.begin_leafs_bbx(
                ((lo + 0.5) * self.voxel).astype(np.float64), ((hi - 0.5) * self.voxel).astype(np.float64)
            )
        for leaf in it:
            yield leaf.getCoordinate(), leaf.getSize(), leaf.getDepth()

    def leaves(self, lo: np.ndarray | None = None, hi: np.ndarray | None = None) -> Leaves:
        """The leaves intersecting voxel indices ``[lo, hi)`` (all by default), as arrays."""
        thres = self.tree.getOccupancyThresLog()
        firsts, sizes, states = [], [], []
        for c, size, _ in self._raw_leaves(lo, hi):
            node = self.tree.search(np.asarray(c, dtype=np.float64))
            if node is None:
                continue
            n = int(round(size / self.voxel))
            firsts.append(np.floor(np.asarray(c) / self.voxel - 0.5 * n + 0.5))
            sizes.append(n)
            states.append(OCCUPIED if node.getLogOdds() >= thres else FREE)  # OctoMap's isNodeOccupied
        if not sizes:
            return Leaves(np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int8))
        return Leaves(np.array(firsts, dtype=np.int64), np.array(sizes, np.int64), np.array(states, np.int8))

    def states_at_index(self, index: np.ndarray) -> np.ndarray:
        """int8 VoxelState of voxel indices (N×3); UNKNOWN where the tree holds nothing."""
        index = np.asarray(index, dtype=np.int64).reshape(-1, 3)
        out = np.full(len(index), UNKNOWN, dtype=np.int8)
        if len(index) == 0 or self.tree.size() == 0:
            return out
        ok = np.all((index >= -_KEY_HALF_RANGE) & (index < _KEY_HALF_RANGE - 1), axis=1)
        thres = self.tree.getOccupancyThresLog()
        search = self.tree.search
        for i, c in zip(np.nonzero(ok)[0], (index[ok] + 0.5) * self.voxel, strict=True):
            node = search(c)
            if node is not None:
                out[i] = OCCUPIED if node.getLogOdds() >= thres else FREE
        return out

    def dense_states(self, lo: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        """int8 VoxelState block of voxel indices ``[lo, lo + shape)``."""
        lo = np.asarray(lo, dtype=np.int64)
        shape = tuple(int(s) for s in shape)
        out = np.full(shape, UNKNOWN, dtype=np.int8)
        if 0 in shape:
            return out
        hi = lo + np.array(shape)
        leaves = self.leaves(lo, hi)
        a = np.maximum(leaves.lo, lo) - lo
        b = np.minimum(leaves.lo + leaves.n[:, None], hi) - lo
        for (x0, y0, z0), (x1, y1, z1), st in zip(a, b, leaves.state, strict=True):
            if x1 > x0 and y1 > y0 and z1 > z0:
                out[x0:x1, y0:y1, z0:z1] = st
        return out

    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices (N×3) and int8 states of every known voxel (pruned leaves expanded)."""
        leaves = self.leaves()
        if len(leaves) == 0:
            return np.zeros((0, 3), np.int64), np.zeros(0, np.int8)
        idx, st = [], []
        for n in np.unique(leaves.n):
            sel = leaves.n == n
            g = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
            idx.append((leaves.lo[sel][:, None, :] + g[None]).reshape(-1, 3))
            st.append(np.repeat(leaves.state[sel], len(g)))
        return np.vstack(idx), np.concatenate(st)

    def known_volume(
        self, lo: np.ndarray | None = None, hi: np.ndarray | None = None, free: bool = False
    ) -> float:
        """Known (or only free) volume in m³ of voxel indices ``[lo, hi)`` (everything by default)."""
        leaves = self.leaves(lo, hi)
        first, last = leaves.lo, leaves.lo + leaves.n[:, None]
        if lo is not None:
            first, last = np.maximum(first, lo), np.minimum(last, hi)
        count = np.prod(np.clip(last - first, 0, None), axis=1)
        if free:
            count = count[leaves.state == FREE]
        return float(count.sum()) * self.voxel**3

    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Index range ``[lo, hi)`` holding every known voxel (lo == hi when empty)."""
        leaves = self.leaves()
        if len(leaves) == 0:
            return np.zeros(3, np.int64), np.zeros(3, np.int64)
        return leaves.lo.min(axis=0), (leaves.lo + leaves.n[:, None]).max(axis=0)

    # ------------------------------------------------------------------ persistence
    def to_bytes(self) -> bytes:
        """The whole tree with its log-odds, in OctoMap's ``.ot`` format."""
        data = self.tree.write()
        if data is False:
            raise OSError("OctoMap could not serialise the tree")
        return bytes(data)

    def from_bytes(self, data: bytes) -> None:
        """Replace the tree with one written by :meth:`to_bytes` (same resolution)."""
        fd, name = tempfile.mkstemp(suffix=".ot")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            tree = self.tree.read(name)
        finally:
            os.unlink(name)
        if tree is None:
            raise ValueError("not an OctoMap .ot tree")
        if not np.isclose(tree.getResolution(), self.voxel):
            raise ValueError(
                f"tree resolution {tree.getResolution()} m does not match the configured {self.voxel} m"
            )
        self.sensor.apply(tree)
        self.tree = tree
        if self.limit is not None:
            self.set_limit(self.limit)
