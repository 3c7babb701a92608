"""The free-space graph's compiled CSR build: entry for entry the graph scipy builds from the edge
list (both directions, the penalty's mean, vertical moves only where allowed)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from amslam.lib.free_space import FreeSpaceGraph
from amslam.lib.voxel_grid import FREE, OCCUPIED

VOXEL = 0.25
#: half of the 26 neighbour offsets (the other half are their negatives)
HALF = np.array([o for o in np.ndindex(3, 3, 3) if o > (1, 1, 1)], dtype=np.int64) - 1


def edge_list_graph(passable, voxel, penalty=None, vertical_ok=None) -> sparse.csr_matrix:
    """The graph built from its edge list with scipy (how FreeSpaceGraph built it before)."""
    node_of_voxel = np.full(passable.shape, -1, dtype=np.int64)
    nodes = np.argwhere(passable)
    node_of_voxel[tuple(nodes.T)] = np.arange(len(nodes))
    rows, cols, weights = [], [], []
    for off in HALF:
        sa = tuple(slice(max(0, -o), s - max(0, o)) for o, s in zip(off, passable.shape, strict=True))
        sb = tuple(slice(max(0, o), s - max(0, -o)) for o, s in zip(off, passable.shape, strict=True))
        both = passable[sa] & passable[sb]
        if vertical_ok is not None and off[2] != 0:
            both &= vertical_ok[sa] & vertical_ok[sb]
        rows.append(node_of_voxel[sa][both])
        cols.append(node_of_voxel[sb][both])
        length = voxel * float(np.linalg.norm(off))
        if penalty is None:
            weights.append(np.full(int(both.sum()), length))
        else:
            weights.append(length * 0.5 * (penalty[sa][both] + penalty[sb][both]))
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    half = sparse.csr_matrix((w, (r, c)), shape=(len(nodes), len(nodes)))
    return (half + half.T).tocsr()


def assert_same_csr(a: sparse.csr_matrix, b: sparse.csr_matrix) -> None:
    assert a.shape == b.shape
    np.testing.assert_array_equal(a.indptr, b.indptr)
    np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_array_equal(a.data, b.data)  # bit for bit, not close
    assert a.indices.dtype == b.indices.dtype and a.indptr.dtype == b.indptr.dtype


@pytest.mark.parametrize("shape", [(1, 1, 1), (2, 1, 3), (7, 5, 6), (12, 9, 8), (3, 3, 0)])
@pytest.mark.parametrize("rules", ["plain", "penalty", "vertical", "both"])
def test_the_compiled_build_is_the_edge_list_graph(shape, rules) -> None:
    rng = np.random.default_rng(sum(shape))
    passable = rng.random(shape) < 0.7
    penalty = 1.0 + 2.0 * rng.random(shape) if rules in ("penalty", "both") else None
    vertical_ok = rng.random(shape) < 0.6 if rules in ("vertical", "both") else None
    states = np.where(passable, FREE, OCCUPIED).astype(np.int8)
    g = FreeSpaceGraph(
        passable, np.zeros(3, np.int64), VOXEL, 0.3, states, penalty=penalty, vertical_ok=vertical_ok
    )
    assert_same_csr(g.graph, edge_list_graph(passable, VOXEL, penalty, vertical_ok))
    np.testing.assert_array_equal(g.node_index, np.argwhere(passable))
