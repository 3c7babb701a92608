"""Shortest path lengths from several sources on a CSR graph, compiled, without the interpreter lock.

Written by hand (with numba) because no maintained library does this one thing: scipy's
``csgraph.dijkstra`` holds the interpreter lock for the whole call (about 12 ms a source on the
demo building's 35 000-node global map), and on a real vehicle the planner thread asks for a
tour's path costs while the control thread ticks. Each time the control thread let go of the lock
(any numpy call of a frame's integration does), it waited for a whole Dijkstra call of the
planner: most of a SITL demo flight's late ticks (docs/flight.md). This kernel releases the lock
(``nogil``) for all its sources at once, so the two threads run on two cores.

Same algorithm and results as scipy's (binary heap, lazy deletion); on a graph of few distinct
edge weights (the free-space graph has nine) one FIFO queue per weight replaces the heap, with
the same distances bit for bit (:func:`weight_classes`). The first call compiles the kernels
(about a second, cached on disk beside this file), which ``warm_up`` does before a flight.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(nogil=True, cache=True)
def _distances(indptr, indices, weights, sources, out):  # pragma: no cover — compiled
    n = len(indptr) - 1
    # a binary heap of (distance, node) in two arrays; a node may be in it more than once (lazy
    # deletion), at most once per edge into it
    size_max = len(indices) + 1
    key = np.empty(size_max, np.float64)
    node = np.empty(size_max, np.int64)
    for k in range(len(sources)):
        dist = out[k]
        done = np.zeros(n, np.bool_)
        s = sources[k]
        dist[s] = 0.0
        key[0], node[0], size = 0.0, s, 1
        while size > 0:
            d, u = key[0], node[0]
            size -= 1
            if size > 0:  # the last entry to the root, sifted down
                kd, kv, i = key[size], node[size], 0
                while True:
                    c = 2 * i + 1
                    if c >= size:
                        break
                    if c + 1 < size and key[c + 1] < key[c]:
                        c += 1
                    if key[c] >= kd:
                        break
                    key[i], node[i] = key[c], node[c]
                    i = c
                key[i], node[i] = kd, kv
            if done[u]:
                continue
            done[u] = True
            for e in range(indptr[u], indptr[u + 1]):
                v = indices[e]
                nd = d + weights[e]
                if nd < dist[v]:
                    dist[v] = nd
                    i = size  # push, sifted up
                    size += 1
                    while i > 0:
                        parent = (i - 1) // 2
                        if key[parent] <= nd:
                            break
                        key[i], node[i] = key[parent], node[parent]
                        i = parent
                    key[i], node[i] = nd, v


@numba.njit(nogil=True, cache=True)
def _distances_by_class(indptr, indices, edge_class, values, sources, out):  # pragma: no cover — compiled
    """Dijkstra with one FIFO queue per distinct edge weight instead of a heap.

    Entries a settled node pushes through edges of one weight carry its distance plus that weight,
    and nodes are settled in order of distance, so every queue stays sorted: the next node is the
    least of the queues' heads (a few comparisons, no sifting). The free-space graph has nine
    weights (three lengths by three mean penalties), and this search settles it 2-3× faster than
    the heap; the distances are the same, bit for bit (a node's distance is the least of its
    settled neighbours' distance plus the edge, whichever order ties are settled in).
    """
    n = len(indptr) - 1
    n_classes = len(values)
    start = np.zeros(n_classes + 1, np.int64)  # a node relaxes each edge at most once a search
    for e in range(len(edge_class)):
        start[edge_class[e] + 1] += 1
    for c in range(n_classes):
        start[c + 1] += start[c]
    key = np.empty(len(indices), np.float64)
    node = np.empty(len(indices), np.int64)
    head = np.empty(n_classes, np.int64)
    tail = np.empty(n_classes, np.int64)
    for k in range(len(sources)):
        dist = out[k]
        done = np.zeros(n, np.bool_)
        head[:] = start[:-1]
        tail[:] = start[:-1]
        u, d = sources[k], 0.0
        dist[u] = 0.0
        while True:
            if not done[u]:
                done[u] = True
                for e in range(indptr[u], indptr[u + 1]):
                    v = indices[e]
                    c = edge_class[e]
                    nd = d + values[c]
                    if nd < dist[v]:
                        dist[v] = nd
                        key[tail[c]], node[tail[c]] = nd, v
                        tail[c] += 1
            best, best_key = -1, np.inf
            for c in range(n_classes):
                if head[c] < tail[c] and key[head[c]] < best_key:
                    best, best_key = c, key[head[c]]
            if best < 0:
                break
            u, d = node[head[best]], best_key
            head[best] += 1


@numba.njit(nogil=True, cache=True)
def _classes(weights, most):  # pragma: no cover — compiled
    values = np.empty(most, np.float64)
    edge_class = np.empty(len(weights), np.int8)
    n = 0
    for e in range(len(weights)):
        w = weights[e]
        c = 0
        while c < n and values[c] != w:
            c += 1
        if c == n:
            if n == most:
                return edge_class, values[:0], False
            values[n] = w
            n += 1
        edge_class[e] = c
    return edge_class, values[:n], True


def weight_classes(graph, most: int = 16) -> tuple[np.ndarray, np.ndarray] | None:
    """The distinct edge weights of a CSR ``graph`` and each edge's (int8 index into them), or
    None when it has more than ``most``: what :func:`distances` searches by queues instead of a
    heap. Worth computing once per graph that is searched from many sources."""
    edge_class, values, few = _classes(graph.data.astype(np.float64, copy=False), min(int(most), 127))
    return (edge_class, values.copy()) if few else None


def distances(graph, sources: np.ndarray, classes: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """S×N shortest path lengths from each of ``sources`` (node indices) over the directed CSR
    ``graph`` (non-negative weights), inf where unreachable.

    ``classes``: the graph's :func:`weight_classes`, for the search by one queue per weight (the
    same distances, faster on a graph of few distinct weights such as the free-space graph)."""
    sources = np.asarray(sources, dtype=np.int64)
    out = np.full((len(sources), graph.shape[0]), np.inf)
    if not len(sources):
        return out
    indptr = graph.indptr.astype(np.int64, copy=False)
    indices = graph.indices.astype(np.int64, copy=False)
    if classes is not None:
        edge_class, values = classes
        _distances_by_class(indptr, indices, edge_class, values, sources, out)
    else:
        _distances(indptr, indices, graph.data.astype(np.float64, copy=False), sources, out)
    return out


def warm_up() -> None:
    """Compile (or load the compiled kernel) now, not at the first plan of a flight."""
    from scipy import sparse

    graph = sparse.csr_matrix(np.array([[0.0, 1.0], [1.0, 0.0]]))
    distances(graph, np.array([0]))
    distances(graph, np.array([0]), weight_classes(graph))
