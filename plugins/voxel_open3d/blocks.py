"""Unbounded log-odds voxels in dense blocks: the ``open3d`` backend's global map.

Voxels live in blocks of ``BLOCK``³ (8³ = 512) stored side by side in two arrays (log-odds and a
*known* flag per voxel, one row per block); a sorted array of block keys maps a block index to its
row. A frame looks up each block it touches once (binary search), then updates the voxels in
the blocks' rows directly, so no voxel is ever looked up in a hash table: the former
``open3d.core.HashMap`` storage took 7 ms to find and insert the 37 000 voxels one 640×480 frame
touches at 0.1 m, these blocks 1.2 ms (139 blocks). A block is allocated at the first update of
one of its voxels and never freed (the global map only grows); a voxel is *known* exactly when
its flag is set.

Written by hand: Open3D's ``VoxelBlockGrid`` stores blocks the same way but only integrates TSDF
(see :mod:`.projective`), and its hash map would bring back a look-up per block through Python
tensors for no gain at these sizes (a few thousand blocks).
"""

from __future__ import annotations

import numba
import numpy as np

from amslam.lib.voxel_grid import FREE, OCCUPIED, UNKNOWN, LogOddsModel, encode
from amslam.plugins.voxel_open3d.projective import (
    FrameUpdate,
    fold_into_blocks,
    frustum_update,
    touched_blocks,
)
from amslam.types import BoundingBox

#: voxels along a block's edge
BLOCK = 8
_VOXELS_PER_BLOCK = BLOCK**3
#: block indices that :func:`~amslam.lib.voxel_grid.encode` packs into a key (``|i| < 2**20``):
#: 8·2²⁰ voxels, 840 km at 0.1 m
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
        self._keys = np.zeros(0, dtype=np.int64)  # sorted block keys ...
        self._rows = np.zeros(0, dtype=np.int64)  # ... and their rows

    # ------------------------------------------------------------------ block table
    def _find(self, blocks: np.ndarray) -> np.ndarray:
        """Rows of blocks (M×3 block indices); -1 for blocks not stored."""
        rows = np.full(len(blocks), -1, dtype=np.int64)
        ok = np.all(np.abs(blocks) <= _MAX_BLOCK, axis=1)
        if not len(self._keys) or not ok.any():
            return rows
        keys = encode(blocks[ok])
        pos = np.minimum(np.searchsorted(self._keys, keys), len(self._keys) - 1)
        hit = self._keys[pos] == keys
        rows[np.flatnonzero(ok)[hit]] = self._rows[pos[hit]]
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
            keys = encode(blocks[new])
            order = np.argsort(keys)
            at = np.searchsorted(self._keys, keys[order])
            self._keys = np.insert(self._keys, at, keys[order])
            self._rows = np.insert(self._rows, at, rows[new][order])
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
        index = np.ascontiguousarray(index, dtype=np.int64).reshape(-1, 3)
        out = np.full(len(index), UNKNOWN, dtype=np.int8)
        if len(self._keys):
            # one compiled pass: the planner's segment checks ask for a few dozen voxels at a
            # time, where the half-dozen numpy calls of a vectorised look-up cost more than it
            _states_at(
                index, self._keys, self._rows, self.value, self.known, np.float32(self.model.l_occ), out
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
        cell = _cell(index)
        self.value[rows, cell] = values
        self.known[rows, cell] = True

    def shift_to(self, lo: np.ndarray) -> None:
        """Move the window hint to ``lo``: an unbounded map keeps every voxel."""
        self.lo = np.asarray(lo, dtype=np.int64)


def _cell(index: np.ndarray) -> np.ndarray:
    """Position of voxels (N×3 indices) inside their blocks (C order)."""
    r = np.mod(index, BLOCK)
    return (r[:, 0] * BLOCK + r[:, 1]) * BLOCK + r[:, 2]


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
def _states_at(index, keys, rows, value, known, l_occ, out):  # pragma: no cover - compiled
    """States of voxels (N×3 indices) into ``out`` (UNKNOWN already): each voxel's block found by
    binary search in the sorted block ``keys`` (as :func:`~amslam.lib.voxel_grid.encode` packs
    them); OCCUPIED above ``l_occ`` (compared in float32, as ``LogOddsModel.classify``)."""
    offset = _MAX_BLOCK + 1
    for n in range(len(index)):
        b0, b1, b2 = index[n, 0] // BLOCK, index[n, 1] // BLOCK, index[n, 2] // BLOCK
        if max(abs(b0), abs(b1), abs(b2)) > _MAX_BLOCK:
            continue
        key = ((b0 + offset) << 42) | ((b1 + offset) << 21) | (b2 + offset)
        at = np.searchsorted(keys, key)
        if at == len(keys) or keys[at] != key:
            continue
        row = rows[at]
        cell = ((index[n, 0] % BLOCK) * BLOCK + index[n, 1] % BLOCK) * BLOCK + index[n, 2] % BLOCK
        if known[row, cell]:
            out[n] = OCCUPIED if value[row, cell] > l_occ else FREE


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
