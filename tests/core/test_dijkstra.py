"""The path-cost Dijkstra: scipy's distances, computed while other threads run."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from amslam.lib import dijkstra
from amslam.lib.free_space import FreeSpaceGraph
from tests.core.pausing import beats_during


def _voxel_graph(shape, seed: int = 0) -> FreeSpaceGraph:
    rng = np.random.default_rng(seed)
    passable = rng.random(shape) > 0.2
    passable[shape[0] // 2] = False  # a wall: two halves that do not reach each other
    states = np.zeros(shape, np.int8)
    return FreeSpaceGraph(passable, np.zeros(3, np.int64), 0.25, 0.5, states, penalty=1 + rng.random(shape))


def test_the_distances_are_scipys_including_the_unreachable():
    graph = _voxel_graph((20, 15, 6)).graph
    sources = np.array([0, 7, 7, graph.shape[0] - 1])
    ours = dijkstra.distances(graph, sources)
    theirs = csgraph.dijkstra(graph, directed=True, indices=sources)
    assert np.array_equal(np.isinf(ours), np.isinf(theirs)) and np.isinf(ours).any()
    np.testing.assert_allclose(ours[np.isfinite(ours)], theirs[np.isfinite(theirs)], rtol=0, atol=1e-12)
    assert dijkstra.distances(graph, np.array([], np.int64)).shape == (0, graph.shape[0])
    lone = sparse.csr_matrix((3, 3))
    assert dijkstra.distances(lone, np.array([1])).tolist() == [[np.inf, 0.0, np.inf]]


def test_other_threads_run_while_it_searches():
    """The reason it exists: scipy's Dijkstra holds the interpreter lock for the whole call, and a
    real vehicle's control thread waited for the planner's path costs (docs/flight.md)."""
    graph = _voxel_graph((60, 50, 12)).graph
    sources = np.arange(0, graph.shape[0], graph.shape[0] // 12)
    dijkstra.warm_up()
    inside, seconds = beats_during(lambda: dijkstra.distances(graph, sources))
    assert inside >= 5, f"{inside} beats of the other thread during a {seconds:.3f} s search"


def test_the_search_by_weight_queues_gives_the_heaps_distances_bit_for_bit():
    rng = np.random.default_rng(4)
    shape = (30, 24, 10)
    passable = rng.random(shape) > 0.25
    passable[15] = False  # two halves that do not reach each other
    penalty = np.where(rng.random(shape) < 0.3, 3.0, 1.0)  # the free-space graph's two multipliers
    g = FreeSpaceGraph(passable, np.zeros(3, np.int64), 0.25, 0.5, np.zeros(shape, np.int8), penalty=penalty)
    classes = g.weight_classes()
    assert classes is not None and len(classes[1]) == 9  # three lengths by three mean penalties
    sources = rng.choice(g.n_nodes, 12, replace=False)
    by_queue = dijkstra.distances(g.graph, sources, classes)
    np.testing.assert_array_equal(by_queue, dijkstra.distances(g.graph, sources))
    assert np.isinf(by_queue).any() and np.isfinite(by_queue).any()
    np.testing.assert_array_equal(by_queue, csgraph.dijkstra(g.graph, indices=sources))


def test_a_graph_of_many_weights_is_searched_with_the_heap():
    assert _voxel_graph((8, 8, 4)).weight_classes() is None  # a penalty of every value
