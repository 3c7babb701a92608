"""Tour path costs on the free-space graph contracted to blocks: the same reachability as the fine
graph, lengths close to its, and a wall through a block is not a shortcut."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib.free_space import FreeSpaceGraph
from amslam.lib.voxel_grid import FREE, OCCUPIED

VOXEL = 0.25


def graph(passable: np.ndarray, penalty: np.ndarray | None = None) -> FreeSpaceGraph:
    states = np.where(passable, FREE, OCCUPIED).astype(np.int8)
    return FreeSpaceGraph(passable, np.zeros(3, np.int64), VOXEL, 0.3, states, penalty=penalty)


def centre(i: int, j: int, k: int) -> np.ndarray:
    return (np.array([i, j, k]) + 0.5) * VOXEL


def rooms() -> np.ndarray:
    """Two rooms 6 × 4 m split by a wall at x = 3 m with a door at the north end, a closed box in
    the east room (unreachable from outside), 1 m high."""
    passable = np.ones((48, 16, 4), dtype=bool)
    passable[25, :, :] = False  # the wall: voxel 25 lies inside a 4-voxel block (24..27)
    passable[25, 13:15, :] = True  # the door
    passable[40:46, 2:8, :] = False  # the closed box ...
    passable[41:45, 3:7, :] = True  # ... with free space inside, cut off
    return passable


def test_reachability_is_the_fine_graphs_and_the_wall_is_no_shortcut() -> None:
    g = graph(rooms())
    points = np.array(
        [centre(24, 2, 1), centre(26, 2, 1), centre(5, 8, 2), centre(42, 4, 1), centre(30, 12, 1)]
    )
    exact = g.costs(points, points)
    contracted = g.costs(points, points, contracted_block=4)
    assert np.array_equal(np.isfinite(exact), np.isfinite(contracted))
    assert not np.isfinite(exact[0, 3])  # the closed box
    # 0.5 m apart in one block, the wall between them: the way round through the door, not 0.5 m
    assert exact[0, 1] > 5.0
    assert contracted[0, 1] > 5.0


def test_lengths_stay_close_to_the_fine_graphs() -> None:
    rng = np.random.default_rng(3)
    passable = rooms()
    penalty = 1.0 + rng.random(passable.shape)
    g = graph(passable, penalty)
    nodes = np.argwhere(passable)
    points = centre(*nodes[rng.choice(len(nodes), 40, replace=False)].T).T
    exact = g.costs(points, points)
    contracted = g.costs(points, points, contracted_block=4)
    both = np.isfinite(exact) & (exact > 2.0)
    assert both.sum() > 500
    error = (contracted[both] - exact[both]) / exact[both]
    assert abs(error.mean()) < 0.1
    assert np.percentile(np.abs(error), 95) < 0.4
    # at most a block's diagonal at each end, at the dearest cost per metre (penalty up to 2)
    diagonal = 4 * VOXEL * np.sqrt(3.0)
    assert np.all(np.abs(contracted[both] - exact[both]) <= 2 * 2.0 * diagonal)
    np.testing.assert_allclose(np.diag(contracted), 0.0, atol=1e-12)


def test_the_mapping_contracts_only_a_graph_larger_than_its_bound(tmp_path) -> None:
    from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
    from amslam.testing.mapping import ROOM_POSE, make_context, render_depth, room_scene

    def mapped(**params) -> NumpyVoxelMap:
        m = NumpyVoxelMap()
        m.configure(NumpyVoxelMap.Params(**params), make_context(tmp_path))
        m.integrate_global(
            render_depth(room_scene(), make_context(tmp_path).camera, ROOM_POSE),
            make_context(tmp_path).camera.K,
            ROOM_POSE,
        )
        return m

    exact, contracted = mapped(), mapped(contract_costs_above=0)
    graph = exact._free_graph()
    nodes = graph.node_position(np.arange(0, graph.n_nodes, max(1, graph.n_nodes // 12)))
    assert np.array_equal(exact.path_costs(nodes, nodes), graph.costs(nodes, nodes))
    assert np.array_equal(contracted.path_costs(nodes, nodes), graph.costs(nodes, nodes, contracted_block=4))
    assert not np.array_equal(exact.path_costs(nodes, nodes), contracted.path_costs(nodes, nodes))


def scipy_contraction(g: FreeSpaceGraph, block: int):
    """The contraction as scipy and numpy built it before the compiled kernels: (pieces, piece,
    representatives' positions, the pieces' graph)."""
    from scipy import sparse
    from scipy.sparse import csgraph

    n = g.n_nodes
    cell = g.node_index // block
    cell_id = np.ravel_multi_index(tuple((cell - cell.min(axis=0)).T), tuple(np.ptp(cell, axis=0) + 1))
    fine = g.graph.tocoo()
    rows, cols = fine.row.astype(np.int64), fine.col.astype(np.int64)
    inside = cell_id[rows] == cell_id[cols]
    within = sparse.csr_matrix((np.ones(int(inside.sum())), (rows[inside], cols[inside])), shape=(n, n))
    n_pieces, piece = csgraph.connected_components(within, directed=False)
    pos = g.node_position(np.arange(n))
    count = np.bincount(piece, minlength=n_pieces)
    centroid = np.stack([np.bincount(piece, pos[:, i], n_pieces) for i in range(3)], 1)
    centroid /= np.maximum(count, 1)[:, None]
    spread = np.linalg.norm(pos - centroid[piece], axis=1)
    order = np.lexsort((spread, piece))
    first = np.ones(n, dtype=bool)
    first[1:] = piece[order[1:]] != piece[order[:-1]]
    representative = np.empty(n_pieces, dtype=np.int64)
    representative[piece[order[first]]] = order[first]
    rep_position = pos[representative]
    a, b = piece[rows[~inside]], piece[cols[~inside]]
    per_metre = fine.data[~inside] / np.linalg.norm(pos[rows[~inside]] - pos[cols[~inside]], axis=1)
    pair = a * n_pieces + b
    best = np.lexsort((per_metre, pair))
    keep = np.ones(len(best), dtype=bool)
    keep[1:] = pair[best[1:]] != pair[best[:-1]]
    best = best[keep]
    a, b = a[best], b[best]
    length = np.linalg.norm(rep_position[a] - rep_position[b], axis=1) * per_metre[best]
    return n_pieces, piece, rep_position, sparse.csr_matrix((length, (a, b)), shape=(n_pieces, n_pieces))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("block", [2, 4])
def test_the_compiled_contraction_is_the_scipy_one_bit_for_bit(seed, block) -> None:
    rng = np.random.default_rng(seed)
    passable = rooms() & (rng.random((48, 16, 4)) < 0.8)  # ragged: many pieces per block
    penalty = np.where(rng.random(passable.shape) < 0.3, 3.0, 1.0)
    g = graph(passable, penalty)
    c = g.contracted(block)
    n_pieces, piece, rep_position, want = scipy_contraction(g, block)
    assert c.n_pieces == n_pieces
    np.testing.assert_array_equal(c.piece, piece)
    np.testing.assert_array_equal(c.rep_position, rep_position)
    np.testing.assert_array_equal(c.graph.indptr, want.indptr)
    np.testing.assert_array_equal(c.graph.indices, want.indices)
    np.testing.assert_array_equal(c.graph.data, want.data)
