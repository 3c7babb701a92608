"""The block storage (global map) and the window storage (local map) against a plain reference:
random frame updates folded into each, then every query of the storage API compared."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib.voxel_grid import UNKNOWN, LogOddsModel, box_of_indices, encode
from amslam.plugins.voxel_open3d.backend import WindowGrid
from amslam.plugins.voxel_open3d.blocks import BlockGrid
from amslam.plugins.voxel_open3d.projective import HIT, MISS, FrameUpdate

MODEL = LogOddsModel(0.7, 0.35, 0.8, 0.12, 0.97)
VOXEL = 0.1


def random_frames(seed: int, n: int = 12) -> list[FrameUpdate]:
    """Frames over random boxes (negative indices, across block faces, overlapping each other)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        lo = rng.integers(-40, 20, 3)
        shape = tuple(rng.integers(1, 24, 3))
        status = rng.choice([0, MISS, HIT], size=shape, p=[0.5, 0.35, 0.15]).astype(np.uint8)
        touched = rng.permutation(np.flatnonzero(status))  # the kernel lists them in no set order
        out.append(FrameUpdate(lo, status, touched, VOXEL))
    return out


class Reference:
    """Voxels in a dict, updated with ``LogOddsModel.update`` one frame at a time."""

    def __init__(self, lo=None, shape=None):
        self.value: dict[tuple[int, int, int], np.float32] = {}
        self.lo, self.shape = lo, shape

    def integrate(self, frame: FrameUpdate):
        index, hit = frame.indices(), frame.hits()
        if self.lo is not None:
            inside = np.all((index >= self.lo) & (index < self.lo + np.array(self.shape)), axis=1)
            index, hit = index[inside], hit[inside]
        keys = [tuple(i) for i in index.tolist()]
        known = np.array([k in self.value for k in keys], bool)
        old = np.array([self.value.get(k, 0.0) for k in keys], np.float32)
        for k, v in zip(keys, MODEL.update(old, known, hit), strict=True):
            self.value[k] = v
        return box_of_indices(index, VOXEL)

    def arrays(self):
        index = np.array(sorted(self.value), np.int64).reshape(-1, 3)
        return index, np.array([self.value[tuple(i)] for i in index.tolist()], np.float32)

    def states(self, query):
        out = np.full(len(query), UNKNOWN, np.int8)
        for n, q in enumerate(query.tolist()):
            if tuple(q) in self.value:
                out[n] = MODEL.classify(np.array([self.value[tuple(q)]]), np.ones(1, bool))[0]
        return out


def sorted_arrays(arrays):
    order = np.argsort(encode(arrays["index"]))
    return arrays["index"][order], arrays["logodds"][order]


def assert_same(grid, ref: Reference, seed: int):
    index, logodds = sorted_arrays(grid.to_arrays())
    ref_index, ref_logodds = ref.arrays()
    np.testing.assert_array_equal(index, ref_index)
    np.testing.assert_array_equal(logodds, ref_logodds)  # bit for bit
    vox, st = grid.voxels()
    order = np.argsort(encode(vox))
    np.testing.assert_array_equal(vox[order], ref_index)
    np.testing.assert_array_equal(st[order], ref.states(ref_index))
    lo, hi = grid.extent()
    np.testing.assert_array_equal(lo, ref_index.min(axis=0))
    np.testing.assert_array_equal(hi, ref_index.max(axis=0) + 1)
    rng = np.random.default_rng(seed)
    query = rng.integers(lo - 5, hi + 5, (3000, 3))
    np.testing.assert_array_equal(grid.states_at_index(query), ref.states(query))
    # the same with queries far apart (blocks then sorted, not flagged in their box) and beyond
    # every block (2**40)
    spread = np.vstack([query, [[8_000_000, -8_000_000, 3], [2**40, 0, 0]]])
    np.testing.assert_array_equal(grid.states_at_index(spread), ref.states(spread))
    np.testing.assert_array_equal(grid.states_at_index(query[:7]), ref.states(query[:7]))
    assert np.all(grid.states_at_index(np.array([[2**40, 0, 0], [0, 0, -(2**40)]])) == UNKNOWN)
    for _ in range(5):
        a = rng.integers(lo - 10, hi, 3)
        shape = tuple(int(s) for s in rng.integers(1, 40, 3))
        g = np.indices(shape).reshape(3, -1).T + a
        np.testing.assert_array_equal(grid.dense_states(a, shape).reshape(-1), ref.states(g))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_blocks_hold_what_a_reference_holds(seed):
    grid, ref = BlockGrid(VOXEL, MODEL, capacity=512), Reference()  # one block: it must grow
    for frame in random_frames(seed):
        box, ref_box = grid.integrate_frame(frame), ref.integrate(frame)
        np.testing.assert_allclose(box.lo, ref_box.lo)
        np.testing.assert_allclose(box.hi, ref_box.hi)
    assert grid.n_blocks > 1
    assert_same(grid, ref, seed)
    copy = BlockGrid(VOXEL, MODEL, capacity=512)  # saved and loaded
    copy.integrate_frame(random_frames(seed + 10, 1)[0])  # replaced, not added to
    copy.from_arrays(grid.to_arrays())
    assert_same(copy, ref, seed)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_window_holds_what_a_reference_holds_inside_it(seed):
    lo, shape = np.array([-30, -25, -20]), (40, 30, 25)
    grid, ref = WindowGrid(VOXEL, lo, shape, MODEL), Reference(lo, shape)
    for frame in random_frames(seed):
        box, ref_box = grid.integrate_frame(frame), ref.integrate(frame)
        assert box.empty == ref_box.empty
        if not box.empty:
            np.testing.assert_allclose(box.lo, ref_box.lo)
            np.testing.assert_allclose(box.hi, ref_box.hi)
    assert_same(grid, ref, seed)


def test_an_empty_block_grid_knows_nothing():
    grid = BlockGrid(VOXEL, MODEL)
    assert len(grid.voxels()[0]) == 0 and len(grid.to_arrays()["index"]) == 0
    lo, hi = grid.extent()
    np.testing.assert_array_equal(lo, hi)
    assert np.all(grid.states_at_index(np.array([[0, 0, 0], [-1, 5, 3]])) == UNKNOWN)
    assert np.all(grid.dense_states(np.array([-4, -4, -4]), (8, 8, 8)) == UNKNOWN)
    far = np.array([[2**40, 0, 0], [0, -(2**40), 0]])  # beyond what a block key holds: unknown
    assert np.all(grid.states_at_index(far) == UNKNOWN)


def test_the_open3d_block_index_finds_every_block_at_its_row_whatever_the_array_layout():
    grid = BlockGrid(VOXEL, MODEL, capacity=512)  # a hash map of one block: it rehashes as it grows
    for frame in random_frames(3):
        grid.integrate_frame(frame)
    coords = grid.coords[: grid.n_blocks]
    assert grid._index.size() == grid.n_blocks > 1
    rows = np.arange(grid.n_blocks)
    np.testing.assert_array_equal(grid._find(coords), rows)
    np.testing.assert_array_equal(grid._find(np.asfortranarray(coords)), rows)  # read as C order
    np.testing.assert_array_equal(grid._find(coords.astype(np.int32)[::-1]), rows[::-1])
    assert np.all(grid._find(coords + np.array([0, 0, 10_000])) == -1)
