"""Voxel lattice, log-odds occupancy model, depth-to-ray conversion and a dense log-odds grid.

Lattice convention shared by every amslam voxel backend: voxel ``i`` along an axis spans
``[i * s, (i + 1) * s)`` for voxel edge ``s``; its centre is ``(i + 0.5) * s``. Two maps of the same
voxel size therefore always share voxel boundaries, which makes cross-backend comparisons exact.

Voxel indices are packed into one int64 *key* (21 bits per axis, offset by 2**20) so sets of voxels
can be manipulated with sorted numpy arrays (``np.unique``, ``np.isin``, ``np.setdiff1d``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amslam.types import BoundingBox, VoxelState

UNKNOWN = np.int8(VoxelState.UNKNOWN.value)
FREE = np.int8(VoxelState.FREE.value)
OCCUPIED = np.int8(VoxelState.OCCUPIED.value)

_KEY_OFFSET = 1 << 20
_KEY_MASK = (1 << 21) - 1


def logit(p: float) -> float:
    """Log-odds of a probability."""
    return float(np.log(p / (1.0 - p)))


def to_index(points: np.ndarray, voxel: float) -> np.ndarray:
    """Integer voxel indices (N×3 int64) of world points (N×3)."""
    return np.floor(np.asarray(points, dtype=np.float64) / voxel).astype(np.int64)


def centres(index: np.ndarray, voxel: float) -> np.ndarray:
    """Centres (N×3) of voxels given by their indices."""
    return (np.asarray(index, dtype=np.float64) + 0.5) * voxel


def encode(index: np.ndarray) -> np.ndarray:
    """Pack N×3 voxel indices into int64 keys (|index| < 2**20 per axis)."""
    i = np.asarray(index, dtype=np.int64) + _KEY_OFFSET
    return (i[:, 0] << 42) | (i[:, 1] << 21) | i[:, 2]


def decode(keys: np.ndarray) -> np.ndarray:
    """Inverse of :func:`encode`."""
    k = np.asarray(keys, dtype=np.int64)
    return np.stack([(k >> 42) & _KEY_MASK, (k >> 21) & _KEY_MASK, k & _KEY_MASK], axis=1) - _KEY_OFFSET


def index_box(box: BoundingBox, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Voxel index range ``[lo, hi)`` of the voxels whose centres lie inside ``box``."""
    lo = np.ceil(np.asarray(box.lo) / voxel - 0.5).astype(np.int64)
    hi = np.floor(np.asarray(box.hi) / voxel - 0.5).astype(np.int64) + 1
    return lo, hi


def box_of_indices(index: np.ndarray, voxel: float) -> BoundingBox:
    """Metric box enclosing a set of voxels (their full extent), or an empty box."""
    if len(index) == 0:
        return BoundingBox.nothing()
    return BoundingBox(index.min(axis=0) * voxel, (index.max(axis=0) + 1) * voxel)


def union(a: BoundingBox, b: BoundingBox) -> BoundingBox:
    """Smallest box containing both (an empty box is the identity)."""
    if a.empty:
        return b
    if b.empty:
        return a
    return BoundingBox(np.minimum(a.lo, b.lo), np.maximum(a.hi, b.hi))


@dataclass(frozen=True)
class LogOddsModel:
    """Occupancy update rule of paper 1 (and FUEL/SEER, which its mapper builds on).

    A voxel is UNKNOWN until first observed. At its first observation it starts from the occupancy
    threshold ``logit(p_occ)`` rather than from 0 (FUEL's ``SDFMap`` does the same): with
    ``p_hit = 0.70 < p_occ = 0.80`` a voxel starting at 0 would need two hits before it could ever be
    reported occupied, so a thin obstacle seen once would be reported FREE. Starting at the threshold,
    one hit makes it OCCUPIED and one miss FREE, and later evidence moves it with the usual increments.
    Values are clamped to ``[logit(p_min), logit(p_max)]`` so the map stays responsive.
    """

    p_hit: float = 0.70
    p_miss: float = 0.35
    p_occ: float = 0.80
    p_min: float = 0.12
    p_max: float = 0.97

    @property
    def l_hit(self) -> float:
        return logit(self.p_hit)

    @property
    def l_miss(self) -> float:
        return logit(self.p_miss)

    @property
    def l_occ(self) -> float:
        return logit(self.p_occ)

    def update(self, value: np.ndarray, known: np.ndarray, hit: np.ndarray) -> np.ndarray:
        """New log-odds after one hit (``hit``) or miss (``~hit``) per voxel."""
        start = np.where(known, value, np.float32(self.l_occ))
        step = np.where(hit, np.float32(self.l_hit), np.float32(self.l_miss))
        return np.clip(start + step, logit(self.p_min), logit(self.p_max)).astype(np.float32)

    def classify(self, value: np.ndarray, known: np.ndarray) -> np.ndarray:
        """int8 VoxelState of voxels from their log-odds and observed flag."""
        out = np.where(value > self.l_occ, OCCUPIED, FREE).astype(np.int8)
        out[~known] = UNKNOWN
        return out


def depth_rays(
    depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, stride: int, max_range: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rays of a depth image, subsampled by ``stride`` in both image axes.

    Depth is along the optical axis. A pixel with a finite positive depth whose range is within
    ``max_range`` is a *return* (its end voxel is a hit). No-return pixels (0, NaN, inf) and returns
    beyond ``max_range`` still carve free space up to ``max_range``.

    Returns:
        origin (3,), unit directions (N×3, world frame), lengths (N,), hit flags (N,).
    """
    d = np.asarray(depth, dtype=np.float64)[::stride, ::stride]
    v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(d)], axis=-1).reshape(
        -1, 3
    )
    d = d.reshape(-1)
    norm = np.linalg.norm(rays, axis=1)
    rng = d * norm
    valid = np.isfinite(d) & (d > 0)
    hit = valid & (rng <= max_range)
    lengths = np.where(hit, rng, max_range)
    dirs = (rays / norm[:, None]) @ np.asarray(T_world_cam)[:3, :3].T
    return np.asarray(T_world_cam)[:3, 3].astype(np.float64), dirs, lengths, hit


def seen_through(
    rays: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], voxel: float, rise: float
) -> np.ndarray:
    """Keys of the voxels a ray of a depth image (``rays``: its :func:`depth_rays`) crossed on its
    way to a point at least ``rise`` metres higher or lower than the voxel: air the camera saw
    *through*, vertically.

    A slab is opaque: no ray crosses it. So the air of a slab's layer that a ray crossed to end a
    floor above or below (or at ``max_range`` beyond, when it met nothing) is an opening, and the
    air rays carved into a slab's layer from poses a few centimetres off in z is not: those rays
    ended on the slab itself, within its thickness of the voxels they carved. Samples every half
    voxel along a ray, up to a voxel before its end (the voxels in front of the surface).
    """
    origin, dirs, lengths, _ = rays
    # a sample t metres along a ray is |dz| (length - t) below (or above) its end: ``rise`` away
    # up to length - rise / |dz|, and a voxel in front of the end up to length - voxel
    dz = np.abs(dirs[:, 2])
    with np.errstate(divide="ignore"):
        reach = np.minimum(lengths - rise / dz, lengths - voxel)
    ok = reach >= 0
    if not ok.any():
        return np.zeros(0, dtype=np.int64)
    dirs, reach = dirs[ok], reach[ok]
    step = voxel / 2
    count = np.floor(reach / step).astype(np.int64) + 1
    ray = np.repeat(np.arange(len(count)), count)
    t = (np.arange(len(ray)) - np.repeat(np.cumsum(count) - count, count)) * step
    points = origin + dirs[ray] * t[:, None]
    return np.unique(encode(to_index(points, voxel)))


def surfaces_seen_from(
    rays: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """Keys of the voxels a return of a depth image hit from above (its end more than a voxel
    lower than the camera) and from below (more than a voxel higher).

    The air over a slab can be seen from below, through a shaft beside it, before any pose was
    on the floor above; its top cannot: a hit from above is the proof that the camera was over
    the slab (:func:`~amslam.lib.free_space.vertical_ok`'s "seen from both floors"). ``rays``: as
    for :func:`seen_through`.
    """
    origin, dirs, lengths, hit = rays
    ends = origin + dirs[hit] * lengths[hit, None]
    keys = encode(to_index(ends, voxel))
    dz = ends[:, 2] - origin[2]
    return np.unique(keys[dz < -voxel]), np.unique(keys[dz > voxel])


def traverse_rays(
    origin: np.ndarray, dirs: np.ndarray, lengths: np.ndarray, hit: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """Exact voxel traversal (Amanatides & Woo) of many rays at once.

    Every ray advances one voxel boundary per iteration, all rays in lock-step; finished rays are
    compacted away. This is the reference kernel: simple, exact, and slow for fine voxels.

    Returns:
        keys of voxels crossed by free space (end voxels of returns excluded), keys of end voxels
        of returns (hits). Both unique; a voxel both crossed and hit in one frame is a hit only
        (OctoMap's ``computeUpdate`` rule).
    """
    o = np.asarray(origin, dtype=np.float64) / voxel
    d = np.asarray(dirs, dtype=np.float64)
    L = np.asarray(lengths, dtype=np.float64) / voxel  # lengths in voxel units
    n = len(d)
    start = np.floor(o).astype(np.int64)
    end = np.floor(o + d * L[:, None]).astype(np.int64)
    step = np.sign(d).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(d != 0, 1.0 / np.abs(d), np.inf)
        frac = np.where(step > 0, (start + 1) - o, o - start)
        tmax = np.where(d != 0, frac * inv, np.inf)
    cur = np.broadcast_to(start, (n, 3)).copy()
    alive = np.nonzero(L > 0)[0]
    cur, tmax, inv, step, end, L, h = (
        cur[alive],
        tmax[alive],
        inv[alive],
        step[alive],
        end[alive],
        L[alive],
        hit[alive],
    )
    free_chunks: list[np.ndarray] = []
    rows = np.arange(len(cur))
    while len(cur):
        at_end = np.all(cur == end, axis=1)
        free_chunks.append(cur[~(at_end & h)])
        axis = np.argmin(tmax, axis=1)
        rows = np.arange(len(cur))
        tnext = tmax[rows, axis]
        go = (tnext <= L) & ~at_end
        cur, tmax, inv, step, end, L, h, axis = (
            cur[go],
            tmax[go],
            inv[go],
            step[go],
            end[go],
            L[go],
            h[go],
            axis[go],
        )
        rows = np.arange(len(cur))
        cur[rows, axis] += step[rows, axis]
        tmax[rows, axis] += inv[rows, axis]
    hits = np.unique(encode(to_index(origin + dirs[hit] * lengths[hit, None], voxel)))
    free = np.unique(encode(np.concatenate(free_chunks))) if free_chunks else np.zeros(0, np.int64)
    free = np.setdiff1d(free, hits, assume_unique=True)
    return free, hits


def centres_in_front(
    index: np.ndarray,
    voxel: float,
    depth: np.ndarray,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    max_range: float,
) -> np.ndarray:
    """Whether each voxel's centre lies in front of what the depth image measured at its pixel.

    The free-space rule of the projective kernel (``open3d`` backend), for voxels a ray traversal
    crossed: a voxel is free only if its centre projects into the image, no farther than
    ``max_range``, and nearer than the range measured at that pixel (any range where the pixel has
    no return). Exact traversal alone frees every voxel a ray crosses, including one it only
    grazes on its way to a surface inside it: a level camera sees a ceiling at grazing angles,
    its rays cross the bottom few centimetres of the ceiling's voxel layer before they end, and
    the slab vanished from the map (a demo flight climbed into it, docs/mapping.md).
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    cam = (centres(index, voxel) - T[:3, 3]) @ T[:3, :3]  # centres in the camera frame
    H, W = depth.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    out = np.zeros(len(index), dtype=bool)
    ahead = np.nonzero(cam[:, 2] > 0)[0]
    x, y, z = cam[ahead].T
    u, v = np.rint(fx * x / z + cx), np.rint(fy * y / z + cy)
    seen = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    ahead, u, v = ahead[seen], u[seen].astype(np.int64), v[seen].astype(np.int64)
    d = np.asarray(depth, dtype=np.float64)[v, u]
    measured = d * np.sqrt(((u - cx) / fx) ** 2 + ((v - cy) / fy) ** 2 + 1.0)
    measured = np.where(np.isfinite(d) & (d > 0) & (measured <= max_range), measured, np.inf)
    rng = np.linalg.norm(cam[ahead], axis=1)
    out[ahead] = (rng <= max_range) & (rng < measured)
    return out


class DenseGrid:
    """A dense block of log-odds voxels, indices ``[lo, lo + shape)`` of the shared lattice.

    Voxels outside the block are UNKNOWN and updates there are dropped.
    """

    def __init__(self, voxel: float, lo: np.ndarray, shape: tuple[int, int, int], model: LogOddsModel):
        self.voxel = float(voxel)
        self.lo = np.asarray(lo, dtype=np.int64)
        self.shape = tuple(int(s) for s in shape)
        self.model = model
        self.value = np.zeros(self.shape, dtype=np.float32)
        self.known = np.zeros(self.shape, dtype=bool)
        #: frames integrated so far, and per voxel the frame that last updated it, kept from the
        #: first :meth:`forget` on (a local window's; a global grid does not pay for the array)
        self.frame = 0
        self.updated: np.ndarray | None = None

    @property
    def hi(self) -> np.ndarray:
        return self.lo + np.array(self.shape)

    def _flat(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = np.asarray(index, dtype=np.int64) - self.lo
        inside = np.all((rel >= 0) & (rel < np.array(self.shape)), axis=1)
        flat = (
            np.ravel_multi_index(tuple(rel[inside].T), self.shape) if inside.any() else np.zeros(0, np.int64)
        )
        return flat, inside

    def integrate_keys(self, free_keys: np.ndarray, hit_keys: np.ndarray) -> BoundingBox:
        """Apply one miss to each free voxel and one hit to each hit voxel; return the touched box."""
        index = decode(np.concatenate([free_keys, hit_keys]))
        is_hit = np.zeros(len(index), dtype=bool)
        is_hit[len(free_keys) :] = True
        flat, inside = self._flat(index)
        is_hit = is_hit[inside]
        v, k = self.value.reshape(-1), self.known.reshape(-1)
        v[flat] = self.model.update(v[flat], k[flat], is_hit)
        k[flat] = True
        self.mark_updated(flat)
        return box_of_indices(index[inside], self.voxel)

    def next_frame(self) -> int:
        """Count one more frame; return its stamp (what :attr:`updated` holds for its voxels)."""
        self.frame += 1
        return self.frame

    def mark_updated(self, flat: np.ndarray) -> None:
        """Count one more frame; the voxels at flat (C-order) indices were updated by it."""
        stamp = self.next_frame()
        if self.updated is not None:
            self.updated.reshape(-1)[flat] = stamp

    def forget(self, frames: int) -> int:
        """Make free voxels no frame updated in the last ``frames`` frames UNKNOWN again; return
        how many.

        A window that follows the camera keeps what it saw for as long as it stays inside the
        window — minutes, in a building the window spans — in the frame the odometry had then:
        VIO's drift since then moves it against what is seen now (a demo flight: the free air of
        the floor above, seen 200 s earlier, lay 0.15 m lower than the slab now overhead, cleared
        it in the local map, and the vehicle climbed into it; docs/mapping.md). Stale free space
        is what is dangerous: it can stand where something now is. A stale obstacle only keeps the
        vehicle away, and the guards count unknown space as free anyway, so occupied voxels stay
        (forgetting them too changed every one-floor flight's path)."""
        if self.updated is None:  # from now on: what the grid holds counts as seen now
            self.updated = np.full(self.shape, self.frame, dtype=np.int64)
        stale = self.known & (self.value <= self.model.l_occ) & (self.frame - self.updated >= frames)
        self.known[stale] = False
        self.value[stale] = 0.0
        return int(stale.sum())

    def states_at_index(self, index: np.ndarray) -> np.ndarray:
        """int8 VoxelState of voxel indices (N×3); UNKNOWN outside the block."""
        out = np.full(len(index), UNKNOWN, dtype=np.int8)
        flat, inside = self._flat(index)
        out[inside] = self.model.classify(self.value.reshape(-1)[flat], self.known.reshape(-1)[flat])
        return out

    def dense_states(self, lo: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        """int8 VoxelState block for indices ``[lo, lo + shape)``; UNKNOWN outside this grid."""
        out = np.full(tuple(int(s) for s in shape), UNKNOWN, dtype=np.int8)
        a = np.maximum(np.asarray(lo), self.lo)
        b = np.minimum(np.asarray(lo) + np.array(shape), self.hi)
        if np.any(b <= a):
            return out
        src = tuple(slice(int(x), int(y)) for x, y in zip(a - self.lo, b - self.lo, strict=True))
        dst = tuple(slice(int(x), int(y)) for x, y in zip(a - lo, b - lo, strict=True))
        out[dst] = self.model.classify(self.value[src], self.known[src])
        return out

    def all_states(self) -> np.ndarray:
        """int8 VoxelState of the whole block."""
        return self.model.classify(self.value, self.known)

    def shift_to(self, lo: np.ndarray) -> None:
        """Move the block to start at ``lo``, keeping the overlap and forgetting the rest."""
        lo = np.asarray(lo, dtype=np.int64)
        if np.array_equal(lo, self.lo):
            return
        value = np.zeros(self.shape, dtype=np.float32)
        known = np.zeros(self.shape, dtype=bool)
        updated = None if self.updated is None else np.zeros(self.shape, dtype=np.int64)
        a = np.maximum(lo, self.lo)
        b = np.minimum(lo + np.array(self.shape), self.hi)
        if np.all(b > a):
            src = tuple(slice(int(x), int(y)) for x, y in zip(a - self.lo, b - self.lo, strict=True))
            dst = tuple(slice(int(x), int(y)) for x, y in zip(a - lo, b - lo, strict=True))
            value[dst] = self.value[src]
            known[dst] = self.known[src]
            if updated is not None:
                updated[dst] = self.updated[src]
        self.value, self.known, self.updated, self.lo = value, known, updated, lo

    # ------------------------------------------------------------------ storage API used by backends
    def integrate_depth(
        self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, stride: int, max_range: float
    ) -> BoundingBox:
        """Ray-cast a depth image (reference kernel) and fuse it; return the touched box. Of the
        voxels the rays cross, only those whose centre lies in front of the measured surface are
        free (:func:`centres_in_front`)."""
        origin, dirs, lengths, hit = depth_rays(depth, K, T_world_cam, stride, max_range)
        free, hits = traverse_rays(origin, dirs, lengths, hit, self.voxel)
        free = free[centres_in_front(decode(free), self.voxel, depth, K, T_world_cam, max_range)]
        return self.integrate_keys(free, hits)

    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices (N×3) and int8 states of all known voxels."""
        idx = np.argwhere(self.known)
        return idx + self.lo, self.model.classify(self.value[self.known], np.ones(len(idx), dtype=bool))

    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Index range ``[lo, hi)`` holding every known voxel (lo == hi when empty)."""
        if not self.known.any():
            return self.lo.copy(), self.lo.copy()
        idx = np.argwhere(self.known)
        return idx.min(axis=0) + self.lo, idx.max(axis=0) + 1 + self.lo

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The known voxels as plain arrays (sparse form, any backend can read it)."""
        idx = np.argwhere(self.known)
        return {"index": idx + self.lo, "logodds": self.value[self.known], "voxel": np.array(self.voxel)}

    def from_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        """Replace the content with voxels from :meth:`to_arrays` (those inside the block)."""
        self.value[:] = 0.0
        self.known[:] = False
        flat, inside = self._flat(arrays["index"])
        self.value.reshape(-1)[flat] = arrays["logodds"][inside]
        self.known.reshape(-1)[flat] = True
        if self.updated is not None:
            self.updated[:] = self.frame  # what a saved map holds counts as seen now
