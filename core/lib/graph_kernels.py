"""Compiled builders of the free-space search graph (:class:`amslam.lib.free_space.FreeSpaceGraph`)
and of its contraction to blocks (:class:`amslam.lib.free_space.ContractedGraph`).

Written by hand (with numba) because the libraries build a graph from an edge list: scipy makes
the 26-connected graph of a voxel block through COO triplets, a sort by row (``coo_tocsr``), a
transpose and a sum of the two halves — three passes over the 4 million entries of a
20 × 30 × 10 m hall's graph, 0.14 s a build, and the graph is rebuilt at every map change that
is planned on. Here the rows come out in order in one pass: a node's neighbours, visited in
lexicographic order of their offsets, are in increasing node order (nodes are numbered in C order
of their voxels), so the CSR arrays are written directly, entry for entry those scipy builds.
The contraction likewise took 0.2 s a plan through scipy (the graph as COO triplets, a
connected-components matrix, a sort of the 2 million edges between blocks to find each pair of
pieces' cheapest crossing); here each piece's crossings are gathered from its own nodes, and the
pieces, their representatives and the lengths are those the scipy and numpy steps gave, bit for
bit (tests/core/test_contracted_graph.py).
"""

from __future__ import annotations

import numba
import numpy as np

#: the 26 neighbour offsets in lexicographic order (that of their voxels' C-order indices)
NEIGHBOURS = np.array([o for o in np.ndindex(3, 3, 3) if o != (1, 1, 1)], dtype=np.int64) - 1


@numba.njit(nogil=True, cache=True)
def _neighbours(  # pragma: no cover — compiled
    node_of_voxel, vertical_ok, penalty, use_penalty, offsets, lengths, shape, degree, indptr, indices, data
):
    """The graph's edges, row by row: counted into ``degree`` (``indptr`` None), or written into
    ``indices`` and ``data`` from ``indptr`` on."""
    s0, s1, s2 = shape[0], shape[1], shape[2]
    for i in range(s0):
        for j in range(s1):
            for k in range(s2):
                v = (i * s1 + j) * s2 + k
                u = node_of_voxel[v]
                if u < 0:
                    continue
                e = 0 if indptr is None else indptr[u]
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
                    if indptr is not None:
                        indices[e] = t
                        # the length times the mean of the two ends' multipliers, in the order of
                        # operations the edge-list build used: equal both ways, bit for bit
                        data[e] = lengths[o] * 0.5 * (penalty[v] + penalty[w]) if use_penalty else lengths[o]
                    e += 1
                if indptr is None:
                    degree[u] = e


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
    degree = np.zeros(int(np.count_nonzero(nodes >= 0)), dtype=np.int64)
    use_penalty = penalty is not None
    args = (nodes, vertical, pen, use_penalty, NEIGHBOURS, lengths, shape)
    _neighbours(*args, degree, None, None, None)
    nnz = int(degree.sum())
    # scipy's index type: 32 bits while the entries and the nodes fit
    itype = np.int32 if max(nnz, len(degree)) < np.iinfo(np.int32).max else np.int64
    indptr = np.zeros(len(degree) + 1, dtype=itype)
    np.cumsum(degree, out=indptr[1:])
    indices = np.empty(nnz, dtype=itype)
    data = np.empty(nnz, dtype=np.float64)
    _neighbours(*args, degree, indptr, indices, data)
    return data, indices, indptr


@numba.njit(nogil=True, cache=True)
def _root(parent, u):  # pragma: no cover — compiled
    while parent[u] != u:
        parent[u] = parent[parent[u]]  # path halving
        u = parent[u]
    return u


@numba.njit(nogil=True, cache=True)
def _pieces(indptr, indices, cell):  # pragma: no cover — compiled
    """Connected pieces of the nodes joined by edges within a cell, numbered in order of their
    first node (scipy's ``connected_components`` numbering)."""
    n = len(indptr) - 1
    parent = np.arange(n)
    for u in range(n):
        for e in range(indptr[u], indptr[u + 1]):
            v = indices[e]
            if cell[v] == cell[u]:
                a, b = _root(parent, u), _root(parent, v)
                if a != b:
                    if a < b:
                        parent[b] = a
                    else:
                        parent[a] = b
    label = np.full(n, -1, np.int32)
    piece = np.empty(n, np.int32)
    count = 0
    for u in range(n):
        r = _root(parent, u)
        if label[r] < 0:
            label[r] = count
            count += 1
        piece[u] = label[r]
    return count, piece


@numba.njit(nogil=True, cache=True)
def _representatives(piece, n_pieces, pos):  # pragma: no cover — compiled
    """Each piece's node nearest its centroid (the first such node on a tie)."""
    n = len(piece)
    total = np.zeros((n_pieces, 3))
    count = np.zeros(n_pieces, np.int64)
    for u in range(n):  # in node order, as numpy's bincount adds them up
        p = piece[u]
        count[p] += 1
        for i in range(3):
            total[p, i] += pos[u, i]
    best = np.full(n_pieces, -1, np.int64)
    best_spread = np.full(n_pieces, np.inf)
    for u in range(n):
        p = piece[u]
        c = max(count[p], 1)
        d0 = pos[u, 0] - total[p, 0] / c
        d1 = pos[u, 1] - total[p, 1] / c
        d2 = pos[u, 2] - total[p, 2] / c
        spread = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if spread < best_spread[p]:
            best_spread[p], best[p] = spread, u
    return best


@numba.njit(nogil=True, cache=True)
def _piece_edges(indptr, indices, data, piece, n_pieces, pos, rep_position):  # pragma: no cover — compiled
    """CSR arrays of the pieces' graph: an edge between two pieces wherever a fine edge joins them,
    its length the representatives' distance times the cheapest crossing's cost per metre."""
    n = len(piece)
    # the nodes of each piece, pieces in order (a counting sort)
    start = np.zeros(n_pieces + 1, np.int64)
    for u in range(n):
        start[piece[u] + 1] += 1
    for p in range(n_pieces):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    members = np.empty(n, np.int64)
    for u in range(n):
        members[fill[piece[u]]] = u
        fill[piece[u]] += 1
    out_ptr = np.zeros(n_pieces + 1, np.int64)
    out_idx = np.empty(len(indices), np.int64)
    out_val = np.empty(len(indices), np.float64)
    seen = np.full(n_pieces, -1, np.int64)  # a neighbour piece's slot in the current row
    k = 0
    for a in range(n_pieces):
        row = k
        for m in range(start[a], start[a + 1]):
            u = members[m]
            for e in range(indptr[u], indptr[u + 1]):
                v = indices[e]
                b = piece[v]
                if b == a:
                    continue
                d0, d1, d2 = pos[u, 0] - pos[v, 0], pos[u, 1] - pos[v, 1], pos[u, 2] - pos[v, 2]
                per_metre = data[e] / np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                slot = seen[b]
                if slot < row:  # first crossing to b in this row
                    seen[b] = k
                    out_idx[k], out_val[k] = b, per_metre
                    k += 1
                elif per_metre < out_val[slot]:
                    out_val[slot] = per_metre
        # columns in order, then lengths through the representatives
        order = np.argsort(out_idx[row:k])
        cols, vals = out_idx[row:k][order].copy(), out_val[row:k][order].copy()
        for j in range(len(cols)):
            b = cols[j]
            d0 = rep_position[a, 0] - rep_position[b, 0]
            d1 = rep_position[a, 1] - rep_position[b, 1]
            d2 = rep_position[a, 2] - rep_position[b, 2]
            out_idx[row + j] = b
            out_val[row + j] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) * vals[j]
        out_ptr[a + 1] = k
    return out_ptr, out_idx[:k], out_val[:k]


def contract(graph, cell: np.ndarray, pos: np.ndarray):
    """Pieces of a CSR ``graph``'s nodes within their ``cell`` and the pieces' graph (see
    :class:`amslam.lib.free_space.ContractedGraph`): ``(n_pieces, piece, representative,
    (data, indices, indptr))``."""
    indptr = graph.indptr.astype(np.int64, copy=False)
    indices = graph.indices.astype(np.int64, copy=False)
    n_pieces, piece = _pieces(indptr, indices, np.ascontiguousarray(cell, dtype=np.int64))
    representative = _representatives(piece, n_pieces, pos)
    ptr, idx, val = _piece_edges(
        indptr, indices, graph.data.astype(np.float64, copy=False), piece, n_pieces, pos, pos[representative]
    )
    itype = np.int32 if max(len(idx), n_pieces) < np.iinfo(np.int32).max else np.int64
    return n_pieces, piece, representative, (val, idx.astype(itype), ptr.astype(itype))


def warm_up() -> None:
    """Compile the kernels (or load them from numba's cache) on a tiny block."""
    from scipy import sparse

    passable = np.ones((2, 2, 2), dtype=bool)
    nodes = np.arange(8, dtype=np.int64).reshape(2, 2, 2)
    csr = sparse.csr_matrix(neighbour_csr(nodes, 1.0, np.ones(passable.shape), passable), shape=(8, 8))
    contract(csr, np.array([0, 0, 0, 0, 1, 1, 1, 1]), np.argwhere(passable) + 0.5)
