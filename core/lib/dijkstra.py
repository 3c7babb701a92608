"""Shortest path lengths from several sources on a CSR graph, compiled, without the interpreter lock.

Written by hand (with numba) because no maintained library does this one thing: scipy's
``csgraph.dijkstra`` holds the interpreter lock for the whole call (about 12 ms a source on the
demo building's 35 000-node global map), and on a real vehicle the planner thread asks for a
tour's path costs while the control thread ticks. Each time the control thread let go of the lock
(any numpy call of a frame's integration does), it waited for a whole Dijkstra call of the
planner: most of a SITL demo flight's late ticks (docs/flight.md). This kernel releases the lock
(``nogil``) for all its sources at once, so the two threads run on two cores.

Same algorithm and results as scipy's (binary heap, lazy deletion); the first call compiles it
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


def distances(graph, sources: np.ndarray) -> np.ndarray:
    """S×N shortest path lengths from each of ``sources`` (node indices) over the directed CSR
    ``graph`` (non-negative weights), inf where unreachable."""
    sources = np.asarray(sources, dtype=np.int64)
    out = np.full((len(sources), graph.shape[0]), np.inf)
    if len(sources):
        _distances(
            graph.indptr.astype(np.int64, copy=False),
            graph.indices.astype(np.int64, copy=False),
            graph.data.astype(np.float64, copy=False),
            sources,
            out,
        )
    return out


def warm_up() -> None:
    """Compile (or load the compiled kernel) now, not at the first plan of a flight."""
    from scipy import sparse

    distances(sparse.csr_matrix(np.array([[0.0, 1.0], [1.0, 0.0]])), np.array([0]))
