"""Compiled builders of the free-space search graph (:class:`amslam.lib.free_space.FreeSpaceGraph`).

Written by hand (with numba) because the libraries build a graph from an edge list: scipy makes
the 26-connected graph of a voxel block through COO triplets, a sort by row (``coo_tocsr``), a
transpose and a sum of the two halves — three passes over the 4 million entries of a
20 × 30 × 10 m hall's graph, 0.14 s a build, and the graph is rebuilt at every map change that
is planned on. Here the rows come out in order in one pass: a node's neighbours, visited in
lexicographic order of their offsets, are in increasing node order (nodes are numbered in C order
of their voxels), so the CSR arrays are written directly, entry for entry those scipy builds.
"""

from __future__ import annotations

import numba
import numpy as np

#: the 26 neighbour offsets in lexicographic order (that of their voxels' C-order indices)
NEIGHBOURS = np.array([o for o in np.ndindex(3, 3, 3) if o != (1, 1, 1)], dtype=np.int64) - 1


@numba.njit(nogil=True, cache=True)
def _degrees(node_of_voxel, vertical_ok, offsets, shape):  # pragma: no cover — compiled
    """Edges of each node (a node's neighbours that are nodes, vertical moves where allowed)."""
    n = 0
    for v in range(node_of_voxel.size):
        if node_of_voxel[v] >= 0:
            n += 1
    degree = np.zeros(n, np.int64)
    s0, s1, s2 = shape[0], shape[1], shape[2]
    for i in range(s0):
        for j in range(s1):
            for k in range(s2):
                v = (i * s1 + j) * s2 + k
                u = node_of_voxel[v]
                if u < 0:
                    continue
                d = 0
                for o in range(len(offsets)):
                    a, b, c = i + offsets[o, 0], j + offsets[o, 1], k + offsets[o, 2]
                    if a < 0 or a >= s0 or b < 0 or b >= s1 or c < 0 or c >= s2:
                        continue
                    w = (a * s1 + b) * s2 + c
                    if node_of_voxel[w] < 0:
                        continue
                    if offsets[o, 2] != 0 and not (vertical_ok[v] and vertical_ok[w]):
                        continue
                    d += 1
                degree[u] = d
    return degree


@numba.njit(nogil=True, cache=True)
def _fill(  # pragma: no cover — compiled
    node_of_voxel, vertical_ok, penalty, use_penalty, offsets, lengths, shape, indptr, indices, data
):
    """The CSR entries, row by row (``indptr`` from :func:`_degrees`)."""
    s0, s1, s2 = shape[0], shape[1], shape[2]
    for i in range(s0):
        for j in range(s1):
            for k in range(s2):
                v = (i * s1 + j) * s2 + k
                u = node_of_voxel[v]
                if u < 0:
                    continue
                e = indptr[u]
                for o in range(len(offsets)):
                    a, b, c = i + offsets[o, 0], j + offsets[o, 1], k + offsets[o, 2]
                    if a < 0 or a >= s0 or b < 0 or b >= s1 or c < 0 or c >= s2:
                        continue
                    w = (a * s1 + b) * s2 + c
                    t = node_of_voxel[w]
                    if t < 0:
                        continue
                    if offsets[o, 2] != 0 and not (vertical_ok[v] and vertical_ok[w]):
                        continue
                    indices[e] = t
                    # the length times the mean of the two ends' multipliers, in the order of
                    # operations the edge-list build used: equal in both directions, bit for bit
                    data[e] = lengths[o] * 0.5 * (penalty[v] + penalty[w]) if use_penalty else lengths[o]
                    e += 1


def neighbour_csr(
    node_of_voxel: np.ndarray, voxel: float, penalty: np.ndarray | None, vertical_ok: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR arrays ``(data, indices, indptr)`` of the 26-connected graph of a block's nodes.

    ``node_of_voxel``: the block's node numbers (-1: no node), nodes numbered in C order. Both
    directions of each edge; an edge costs its length (``voxel`` times the offset's norm) times
    the mean of its ends' ``penalty``; an edge with a vertical component joins two voxels only
    where ``vertical_ok`` holds at both.
    """
    shape = np.array(node_of_voxel.shape, dtype=np.int64)
    nodes = np.ascontiguousarray(node_of_voxel).reshape(-1)
    if vertical_ok is None:
        vertical = np.ones(nodes.size, dtype=bool)
    else:
        vertical = np.ascontiguousarray(vertical_ok, dtype=bool).reshape(-1)
    pen = np.zeros(1) if penalty is None else np.ascontiguousarray(penalty, dtype=np.float64).reshape(-1)
    lengths = np.array([voxel * float(np.linalg.norm(o)) for o in NEIGHBOURS])
    degree = _degrees(nodes, vertical, NEIGHBOURS, shape)
    nnz = int(degree.sum())
    # scipy's index type: 32 bits while the entries and the nodes fit
    itype = np.int32 if max(nnz, len(degree)) < np.iinfo(np.int32).max else np.int64
    indptr = np.zeros(len(degree) + 1, dtype=itype)
    np.cumsum(degree, out=indptr[1:])
    indices = np.empty(nnz, dtype=itype)
    data = np.empty(nnz, dtype=np.float64)
    _fill(nodes, vertical, pen, penalty is not None, NEIGHBOURS, lengths, shape, indptr, indices, data)
    return data, indices, indptr


def warm_up() -> None:
    """Compile the kernels (or load them from numba's cache) on a tiny block."""
    passable = np.ones((2, 2, 2), dtype=bool)
    nodes = np.arange(8, dtype=np.int64).reshape(2, 2, 2)
    neighbour_csr(nodes, 1.0, np.ones(passable.shape), passable)
