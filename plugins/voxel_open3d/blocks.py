"""Unbounded log-odds voxels in dense blocks: the ``open3d`` backend's global map.

Voxels live in blocks of ``BLOCK``³ (8³ = 512) stored side by side in two numpy arrays (log-odds
and a *known* flag per voxel, one row per block); an Open3D tensor hash map
(``open3d.core.HashMap``, int32×3 block index -> int64 row) maps a block to its row. A frame looks
up the ~100-200 blocks it touches in one batched ``find`` (and ``insert``s the new ones), then
the compiled fold (:mod:`.projective`) updates the voxels in the blocks' rows directly: no voxel
is ever looked up in a hash table. (The storage before issue #20 kept every *voxel* in an
``open3d.core.HashMap``: 7 ms a frame to find and insert the 37 000 voxels of a 640×480 frame at
0.1 m; per block, the look-ups cost a few µs.) Point queries likewise look each distinct block up
once. A block is allocated at the first update of one of its voxels and never freed (the global
map only grows); a voxel is *known* exactly when its flag is set.

The rows are ours, not the hash map's buffer slots: Open3D re-inserts every key when it rehashes,
which moves them to new slots, whereas a row (the hash map's value) stays put, so the voxel arrays
never move and are laid out in allocation order. ``open3d.t.geometry.VoxelBlockGrid`` has the same
block layout, but its integration is TSDF-only (see :mod:`.projective`), so only its hash map is
used here. The blocks' voxels are read and written by the numba kernels below and in
:mod:`.projective`; Open3D has no occupancy (log-odds) update to do it.
"""

from __future__ import annotations

import numba
import numpy as np
import open3d.core as o3c

from amslam.lib.voxel_grid import FREE, OCCUPIED, UNKNOWN, LogOddsModel
from amslam.plugins.voxel_open3d.projective import (
    FrameUpdate,
    fold_into_blocks,
    frustum_update,
    touched_blocks,
)
from amslam.types import BoundingBox

#: voxels along a block's edge (a power of two: blocks and cells by shifts and masks)
BLOCK = 8
_BLOCK_BITS = 3
_VOXELS_PER_BLOCK = BLOCK**3
#: block indices stored (``|i| < 2**20``: 8·2²⁰ voxels, 840 km at 0.1 m): point queries pack a
#: block in an int64 key (21 bits an axis) to sort them, well within the hash map's int32 keys
_MAX_BLOCK = (1 << 20) - 1


class BlockGrid:
    """Sparse, unbounded log-odds voxels in dense 8³ blocks, with the storage API of ``DenseGrid``.

    Args:
        voxel: voxel edge (m).
        model: the log-odds update rule.
        capacity: voxels to reserve at start (rounded up to whole blocks; the storage grows as needed).
    """

    def __init__(self, voxel: float, model: LogOddsModel, capacity: int = 200_000):
        self.voxel = float(voxel)
        self.model = model
        self.lo = np.zeros(3, dtype=np.int64)  # kept by shift_to; an unbounded map ignores it
        self._clear(max(1, -(-int(capacity) // _VOXELS_PER_BLOCK)))

    def _clear(self, blocks: int) -> None:
        self.value = np.zeros((blocks, _VOXELS_PER_BLOCK), dtype=np.float32)
        self.known = np.zeros((blocks, _VOXELS_PER_BLOCK), dtype=bool)
        self.coords = np.zeros((blocks, 3), dtype=np.int64)  # block index of each row
        self.n_blocks = 0
        # block index (int32×3) -> row; it rehashes itself as it fills
        self._index = o3c.HashMap(blocks, o3c.int32, (3,), o3c.int64, (1,), o3c.Device("CPU:0"))

    # ------------------------------------------------------------------ block table
    def _find(self, blocks: np.ndarray) -> np.ndarray:
        """Rows of blocks (M×3 block indices, each within ``_MAX_BLOCK``); -1 for blocks not stored."""
        rows = np.full(len(blocks), -1, dtype=np.int64)
        if not self.n_blocks or not len(blocks):
            return rows
        slots, found = self._index.find(_keys(blocks))
        found = found.numpy()
        rows[found] = self._index.value_tensor().numpy()[slots.numpy()[found], 0]
        return rows

    def _rows_for(self, blocks: np.ndarray) -> np.ndarray:
        """Rows of blocks (M×3 block indices, each once), allocating the missing ones."""
        rows = self._find(blocks)
        new = rows < 0
        if new.any():
            need = self.n_blocks + int(new.sum())
            if need > len(self.value):
                self._reserve(max(2 * len(self.value), need))
            rows[new] = np.arange(self.n_blocks, need)
            self.coords[rows[new]] = blocks[new]
            self.n_blocks = need
            self._index.insert(
                _keys(blocks[new]), o3c.Tensor.from_numpy(np.ascontiguousarray(rows[new].reshape(-1, 1)))
            )
        return rows

    def _reserve(self, blocks: int) -> None:
        grow = blocks - len(self.value)
        self.value = np.concatenate([self.value, np.zeros((grow, _VOXELS_PER_BLOCK), np.float32)])
        self.known = np.concatenate([self.known, np.zeros((grow, _VOXELS_PER_BLOCK), bool)])
        self.coords = np.concatenate([self.coords, np.zeros((grow, 3), np.int64)])

    # ------------------------------------------------------------------ updates
    def integrate_depth(
        self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, stride: int, max_range: float
    ) -> BoundingBox:
        """Projective frustum update (:mod:`.projective`); return the touched box."""
        return self.integrate_frame(frustum_update(depth, K, T_world_cam, stride, max_range, self.voxel))

    def integrate_frame(self, frame: FrameUpdate) -> BoundingBox:
        """One log-odds update per voxel a frame touched; return their box."""
        blocks = touched_blocks(frame, BLOCK)
        if not len(blocks) or np.abs(blocks).max() > _MAX_BLOCK:  # beyond the keys' range: 840 km
            return BoundingBox.nothing()
        rows = self._rows_for(blocks)
        return fold_into_blocks(frame, blocks, rows, self.value, self.known, self.model, BLOCK)

    # ------------------------------------------------------------------ queries
    def states_at_index(self, index: np.ndarray) -> np.ndarray:
        """int8 VoxelState of voxel indices (N×3); UNKNOWN where nothing is stored."""
        # per axis (3×N): numpy reduces and shifts contiguous rows far faster than N×3 columns
        index = np.ascontiguousarray(np.asarray(index, dtype=np.int64).reshape(-1, 3).T)
        out = np.full(index.shape[1], UNKNOWN, dtype=np.int8)
        if not self.n_blocks or not len(out):
            return out
        block_of = index >> _BLOCK_BITS  # floor division by BLOCK, negative indices too
        at = None  # the queries kept (None: all of them)
        if max(-int(block_of.min()), int(block_of.max())) > _MAX_BLOCK:  # beyond every block
            at = np.flatnonzero(np.all(np.abs(block_of) <= _MAX_BLOCK, axis=0))
            if not len(at):
                return out
            index, block_of = index[:, at], block_of[:, at]
        # each block once: one batched look-up in the hash map, then a gather per voxel
        blocks, which = _distinct(block_of)
        rows = self._find(blocks)[which]
        stored = np.flatnonzero(rows >= 0)
        rows, cell = rows[stored], _cell(index)[stored]
        out[stored if at is None else at[stored]] = self.model.classify(
            self.value[rows, cell], self.known[rows, cell]
        )
        return out

    def dense_states(self, lo: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        """int8 VoxelState block for indices ``[lo, lo + shape)``."""
        lo = np.asarray(lo, dtype=np.int64)
        out = np.full(tuple(int(s) for s in shape), UNKNOWN, dtype=np.int8)
        if out.size == 0 or self.n_blocks == 0:
            return out
        coords = self.coords[: self.n_blocks]
        overlap = np.all((coords * BLOCK < lo + np.array(out.shape)) & ((coords + 1) * BLOCK > lo), axis=1)
        rows = np.flatnonzero(overlap)
        if len(rows):
            _blocks_into_box(
                rows, coords, self.value, self.known, np.float32(self.model.l_occ), BLOCK, lo, out
            )
        return out

    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices (N×3) and int8 states of all known voxels."""
        row, cell = np.nonzero(self.known[: self.n_blocks])
        index = self.coords[row] * BLOCK + np.stack(np.unravel_index(cell, (BLOCK,) * 3), 1)
        return index, self.model.classify(self.value[row, cell], np.ones(len(row), bool))

    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Index range ``[lo, hi)`` holding every known voxel (lo == hi when empty)."""
        box = np.zeros(6, dtype=np.int64)
        if not _known_extent(self.coords[: self.n_blocks], self.known, BLOCK, box):
            return self.lo.copy(), self.lo.copy()
        return box[:3], box[3:]

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Known voxels as plain arrays (the format of ``DenseGrid.to_arrays``)."""
        row, cell = np.nonzero(self.known[: self.n_blocks])
        index = self.coords[row] * BLOCK + np.stack(np.unravel_index(cell, (BLOCK,) * 3), 1)
        return {"index": index, "logodds": self.value[row, cell].copy(), "voxel": np.array(self.voxel)}

    def from_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        """Replace the content with voxels from :meth:`to_arrays`."""
        index = np.asarray(arrays["index"], dtype=np.int64).reshape(-1, 3)
        values = np.asarray(arrays["logodds"], dtype=np.float32).reshape(-1)
        block_of = np.floor_divide(index, BLOCK)
        keep = np.all(np.abs(block_of) <= _MAX_BLOCK, axis=1)
        index, values, block_of = index[keep], values[keep], block_of[keep]
        blocks, which = np.unique(block_of, axis=0, return_inverse=True)
        self._clear(max(len(self.value), len(blocks)))
        rows = self._rows_for(blocks)[which.reshape(-1)]
        cell = _cell(index.T)
        self.value[rows, cell] = values
        self.known[rows, cell] = True

    def shift_to(self, lo: np.ndarray) -> None:
        """Move the window hint to ``lo``: an unbounded map keeps every voxel."""
        self.lo = np.asarray(lo, dtype=np.int64)


def _distinct(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct blocks (M×3) among block indices given per axis (3×N, each within
    ``_MAX_BLOCK``), and which of them each one is."""
    lo, hi = blocks.min(axis=1), blocks.max(axis=1)
    extent = hi - lo + 1
    rel = blocks - lo[:, None]
    if float(np.prod(extent.astype(float))) <= max(8 * blocks.shape[1], 4096):
        # queries close together (a segment, a viewpoint's rays): a flag per block of their box
        # marks the distinct ones without sorting
        flat = (rel[0] * extent[1] + rel[1]) * extent[2] + rel[2]
        seen = np.zeros(int(np.prod(extent)), dtype=np.int64)
        seen[flat] = 1
        cells = np.flatnonzero(seen)
        seen[cells] = np.arange(len(cells))
        plane = extent[1] * extent[2]
        found = np.stack([cells // plane, cells // extent[2] % extent[1], cells % extent[2]], axis=1)
        return found + lo, seen[flat]
    # spread out: sort their keys (21 bits an axis, as encode packs them)
    keys, which = np.unique((rel[0] << 42) | (rel[1] << 21) | rel[2], return_inverse=True)
    which = which.reshape(-1)
    one = np.empty(len(keys), dtype=np.int64)  # a query in each distinct block
    one[which] = np.arange(len(which))
    return blocks[:, one].T, which


def _keys(blocks: np.ndarray) -> o3c.Tensor:
    """Block indices (M×3) as the hash map's keys: C-contiguous int32 (the hash map reads the raw
    buffer, whatever strides the tensor has; ``touched_blocks`` gives a Fortran-ordered array)."""
    return o3c.Tensor.from_numpy(np.ascontiguousarray(blocks, dtype=np.int32))


def _cell(index: np.ndarray) -> np.ndarray:
    """Position of voxels (indices given per axis, 3×N) inside their blocks (C order)."""
    r = index & (BLOCK - 1)  # the index modulo BLOCK, negative indices too
    return (r[0] * BLOCK + r[1]) * BLOCK + r[2]


@numba.njit(nogil=True, cache=True)
def _blocks_into_box(rows, coords, value, known, l_occ, block, lo, out):  # pragma: no cover - compiled
    """Write the states of the known voxels of blocks ``rows`` that lie in the box ``out`` (at
    index ``lo``): OCCUPIED above ``l_occ`` (compared in float32, as ``LogOddsModel.classify``)."""
    for r in rows:
        for cell in range(block * block * block):
            if not known[r, cell]:
                continue
            i = coords[r, 0] * block + cell // (block * block) - lo[0]
            j = coords[r, 1] * block + (cell // block) % block - lo[1]
            k = coords[r, 2] * block + cell % block - lo[2]
            if 0 <= i < out.shape[0] and 0 <= j < out.shape[1] and 0 <= k < out.shape[2]:
                out[i, j, k] = OCCUPIED if value[r, cell] > l_occ else FREE


@numba.njit(nogil=True, cache=True)
def _known_extent(coords, known, block, box):  # pragma: no cover - compiled
    """Index range (``box``: lo[3], hi[3]) of the known voxels of blocks ``coords``; whether any."""
    any_known = False
    for r in range(len(coords)):
        for cell in range(block * block * block):
            if not known[r, cell]:
                continue
            idx = (
                coords[r, 0] * block + cell // (block * block),
                coords[r, 1] * block + (cell // block) % block,
                coords[r, 2] * block + cell % block,
            )
            for axis in range(3):
                if not any_known or idx[axis] < box[axis]:
                    box[axis] = idx[axis]
                if not any_known or idx[axis] + 1 > box[3 + axis]:
                    box[3 + axis] = idx[axis] + 1
            any_known = True
    return any_known
