"""The free-space graph: its compiled CSR build is entry for entry the graph scipy builds from the
edge list (both directions, the penalty's mean, vertical moves only where allowed); the global
map's graph, its rules recomputed only near the voxels that changed, is the graph built from
scratch on the same map."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from amslam.lib.free_space import FreeSpaceGraph
from amslam.lib.voxel_grid import FREE, OCCUPIED, UNKNOWN, logit
from amslam.testing.mapping import make_context
from amslam.types import BoundingBox

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


# ---------------------------------------------------------------------------------------------
# The global map's graph follows the map: rules recomputed only near the voxels that changed give
# the graph a build from scratch gives, node for node, edge for edge, cost for cost.

FREE_L, OCC_L = logit(0.2), logit(0.95)
AREA = BoundingBox(np.array([0.0, 0.0, 0.0]), np.array([10.0, 8.0, 6.0]))
SIZE = (40, 32, 24)  # the area in 0.25 m voxels


def put(
    mapping,
    states: np.ndarray,
    lo: np.ndarray,
    path,
    slab_history: np.ndarray | None = None,
    views: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> None:
    """Replace the mapping's global map by ``states`` (int8, index ``lo`` first), through ``load``,
    with ``slab_history`` (global indices; by default the mapping's own, as a flight keeps it) and
    the ``views`` records: seen through, surfaces seen from above and from below (global indices;
    None: a map saved without them)."""
    history = mapping.slab_history() if slab_history is None else slab_history
    names = ("global_seen_through", "global_seen_from_above", "global_seen_from_below")
    record = {} if views is None else dict(zip(names, views, strict=True))
    idx = np.argwhere(states != UNKNOWN)
    logodds = np.where(states[tuple(idx.T)] == OCCUPIED, OCC_L, FREE_L).astype(np.float32)
    np.savez_compressed(
        path,
        format=np.array("amslam-voxels-1"),
        global_index=idx + lo,
        global_logodds=logodds,
        global_voxel=np.array(VOXEL),
        local_index=np.zeros((0, 3), np.int64),
        local_logodds=np.zeros(0, np.float32),
        local_voxel=np.array(0.1),
        global_slab_history=history,
        **record,
    )
    mapping.load(path)


def two_storeys() -> np.ndarray:
    """Floor, a slab at z 2.75 m with a 2.5 m shaft, a ceiling, a table top (2 m²), a wall with a
    door on the ground floor; all air known free."""
    s = np.full(SIZE, UNKNOWN, dtype=np.int8)
    s[:, :, 1:21] = FREE
    s[:, :, [0, 11, 21]] = OCCUPIED
    s[28:38, 20:30, 11] = FREE  # the shaft
    s[20, :, 1:11] = OCCUPIED  # the wall ...
    s[20, 14:19, 1:9] = FREE  # ... and its door
    s[4:12, 4:8, 3] = OCCUPIED  # the table top, 2 × 1 m
    return s


def steps(rng) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """A sequence of global maps (name, states, lo) as a flight might see them, and worse."""
    full = two_storeys()
    lo = np.zeros(3, np.int64)
    seen = np.full(SIZE, UNKNOWN, dtype=np.int8)
    out = []
    seen[:14, :12, :12] = full[:14, :12, :12]
    out.append(("first look", seen.copy(), lo))
    seen[:24, :20, :12] = full[:24, :20, :12]
    out.append(("the extent grows", seen.copy(), lo))
    seen[:, :, :] = full
    out.append(("the whole building", seen.copy(), lo))
    seen[8:12, 8:12, 11] = FREE  # a hole carved into the slab from drifted poses
    seen[7:13, 7, 11] = UNKNOWN  # its rim not seen
    out.append(("a carved hole", seen.copy(), lo))
    seen[4:12, 8:12, 3] = OCCUPIED  # the table top grows to 4 m²: a slab now, far beyond the change
    out.append(("a surface becomes a slab", seen.copy(), lo))
    seen[4:12, 7, 3] = FREE  # cut in two: neither half a slab any more
    out.append(("a slab is cut in two", seen.copy(), lo))
    seen[2, 30, 2:6] = OCCUPIED  # two changes far apart: two regions
    seen[37, 2, 15:18] = OCCUPIED
    out.append(("two regions", seen.copy(), lo))
    for k in range(4):
        a = rng.integers(0, np.array(SIZE) - 4)
        b = a + rng.integers(1, 6, size=3)
        box = tuple(slice(int(i), int(j)) for i, j in zip(a, b, strict=True))
        seen[box] = rng.choice([FREE, OCCUPIED, UNKNOWN], size=seen[box].shape, p=[0.5, 0.3, 0.2])
        out.append((f"random patch {k}", seen.copy(), lo))
    bigger = np.full((SIZE[0] + 12, SIZE[1], SIZE[2]), UNKNOWN, dtype=np.int8)
    bigger[: SIZE[0]] = seen
    bigger[SIZE[0] :, :, 1:8] = FREE  # seen out of a window, beyond the area: the block is outgrown
    out.append(("beyond the area", bigger, lo))
    return out


def block_graph(mapping) -> FreeSpaceGraph:
    """The graph built as before it followed the map: every rule computed on the block of the
    extent and a voxel round it (no slabs handed in, no reach)."""
    from amslam.lib.free_space import inflate, obstacles, vertical_ok
    from amslam.lib.voxel_grid import index_box

    p, store = mapping.params, mapping.global_map
    lo, hi = store.extent()
    lo, hi = lo - 1, hi + 1
    if p.plan_through_unknown:
        a, b = index_box(mapping.area, VOXEL)
        lo, hi = np.minimum(lo, a), np.maximum(hi, b)
    shape = tuple(int(s) for s in hi - lo)
    states = store.dense_states(lo, shape)
    history = np.zeros(shape, dtype=bool)
    rel = mapping.slab_history() - lo
    history[tuple(rel[np.all((rel >= 0) & (rel < np.array(shape)), axis=1)].T)] = True
    occ = obstacles(states, VOXEL, p.unseen_surface_reach, p.floor_change_opening, slab_history=history)
    near = inflate(occ, mapping.robot_radius, VOXEL)
    base = (states != OCCUPIED) if p.plan_through_unknown else (states == FREE)
    passable, roomy = base & ~near, base & ~inflate(occ, mapping.segment_radius, VOXEL)
    if p.plan_through_unknown:
        a, b = index_box(mapping.area, VOXEL)
        inside = np.zeros(shape, dtype=bool)
        inside[tuple(slice(int(i), int(j)) for i, j in zip(a - lo, b - lo, strict=True))] = True
        passable &= inside | (states == FREE)
        roomy &= inside | (states == FREE)
    flyable = mapping._flyable(lo, shape)
    through, above, below = (np.zeros(shape, dtype=bool) for _ in range(3))
    for dense, indices in zip(
        (through, above, below), (mapping.seen_through(), *mapping.surfaces_seen_from()), strict=True
    ):
        rel = indices - lo
        dense[tuple(rel[np.all((rel >= 0) & (rel < np.array(shape)), axis=1)].T)] = True
    vertical = vertical_ok(
        states,
        mapping.robot_radius,
        VOXEL,
        observed=p.observed_floor_changes,
        opening=p.floor_change_opening,
        unseen_reach=p.unseen_surface_reach,
        seen_through=through if mapping._seen_through_rule() else None,
        through_reach=p.seen_through_reach,
        slab_history=history,
        seen_from_above=above,
        seen_from_below=below,
    )
    return FreeSpaceGraph(
        passable & flyable,
        lo,
        VOXEL,
        p.snap_radius,
        states,
        near_obstacle=near,
        penalty=np.where(roomy & flyable, 1.0, p.tight_penalty),
        vertical_ok=vertical,
    )


def graph_arrays(mapping, g: FreeSpaceGraph | None = None) -> dict[str, np.ndarray]:
    g = mapping._free_graph() if g is None else g
    return {
        "lo": g.lo,
        "node_index": g.node_index,
        "indptr": g.graph.indptr,
        "indices": g.graph.indices,
        "data": g.graph.data,
        "states": g.states,
        "near_obstacle": g.near_obstacle,
        "vertical_ok": g.vertical_ok,
    }


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"unseen_surface_reach": 0.5, "floor_change_opening": 1.0},
        {"plan_through_unknown": True},
        {"floor_change_opening": 0.0, "unseen_surface_reach": 0.0},
        {"seen_through_reach": 1.5},
        {"seen_through_reach": 2.5, "floor_change_opening": 0.0},
    ],
    ids=["defaults", "wider-rules", "through-unknown", "no-slab-rules", "seen-through", "seen-through-only"],
)
def test_the_graph_updated_near_changes_is_the_graph_built_from_scratch(params, tmp_path) -> None:
    from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap

    def configured() -> Open3dVoxelMap:
        m = Open3dVoxelMap()
        m.configure(Open3dVoxelMap.Params(**params), make_context(tmp_path, area=AREA))
        return m

    followed = configured()
    updated_in_place = 0
    rng = np.random.default_rng(6)
    # the seen-through cases: records growing as a flight's do. The shaft's core seen through (its
    # rim not) and the slab's top over the shaft's half of the building; the crossed air grows by
    # random voxels in the first steps; in the later ones, which change few voxels, the slab's
    # underside is seen a strip further each step (so that the strip alone changes the rules at the
    # shaft's rim: without the opening rule only the seen-through rule refuses it there) and both
    # sides' records grow by random voxels off the slab's layers, which change no rule
    record = None
    if "seen_through_reach" in params:
        shaft_side = np.argwhere(np.ones((20, SIZE[1], 3), bool)) + [20, 0, 10]
        core = np.argwhere(np.ones((6, 6, 3), bool)) + [30, 22, 10]
        record = [core, shaft_side, shaft_side[:0]]
    for k, (name, states, lo) in enumerate(steps(np.random.default_rng(5))):
        if record is not None and k < 6:
            record[0] = np.unique(np.concatenate([record[0], rng.integers(0, SIZE, size=(40, 3))]), axis=0)
        elif record is not None:
            strip = np.argwhere(np.ones((4, SIZE[1], 3), bool)) + [20 + 4 * (k - 6), 0, 10]
            low = rng.integers(0, [SIZE[0], SIZE[1], 8], size=(40, 3))  # layers 0-7: no slab near
            record = [record[0], np.concatenate([record[1], low]), np.concatenate([record[2], strip, low])]
        put(followed, states, lo, tmp_path / f"map{k}.npz", views=record)
        before = followed._rules
        got = graph_arrays(followed)
        updated_in_place += before is not None and followed._rules is before
        scratch = configured()
        put(scratch, states, lo, tmp_path / f"scratch{k}.npz", followed.slab_history(), record)
        want = graph_arrays(scratch)
        # and the graph of every rule computed on the extent's block, as the graph was built before
        # (the rules agree there: the voxels round the extent are unknown, like those beyond it)
        block = graph_arrays(scratch, block_graph(scratch))
        for key in want:
            np.testing.assert_array_equal(got[key], want[key], err_msg=f"{name}: {key}")
            np.testing.assert_array_equal(got[key], block[key], err_msg=f"{name}: {key} (block)")
        assert got["indices"].dtype == want["indices"].dtype
    assert updated_in_place >= 8  # the steps were followed, not rebuilt (but the last one)


def test_slabs_handed_in_are_the_slabs_the_rules_find() -> None:
    from amslam.lib.free_space import obstacles, slabs, vertical_ok

    states = two_storeys()
    slab = slabs(states, VOXEL)
    assert slab[:, :, 11].any() and not slab[:, :, 3].any()  # the table top is no slab
    for given in (None, slab):
        ok = vertical_ok(states, 0.375, VOXEL, opening=0.75, unseen_reach=0.25, slab=given)
        assert ok[6, 10, 3]  # beside the table top, 0.5 m off: its layer is no slab's
        assert not ok[6, 10, 11]  # in the slab's layer, 0.5 m off the slab
        occ = obstacles(states, VOXEL, 0.25, 0.75, slab=given)
        np.testing.assert_array_equal(occ, obstacles(states, VOXEL, 0.25, 0.75))


def test_a_path_joins_the_flown_trail_where_the_whole_way_costs_least() -> None:
    from amslam.lib.free_space import trail_join

    trail = np.array([[float(i), 0.0, 1.0] for i in range(10)])  # 1 m apart, oldest first
    inf = np.inf
    # the start reaches points 6-9, the goal 0-2: join at 6, leave at 2 (4 m along the trail)
    from_start = np.array([inf] * 6 + [3.0, 2.0, 1.0, 0.0])
    to_goal = np.array([0.5, 1.0, 1.5] + [inf] * 7)
    assert trail_join(trail, from_start, to_goal) == (6, 2)
    # a cheaper way to a point further along the trail wins over a shorter stretch of it
    from_start[7] = 0.1
    assert trail_join(trail, from_start, to_goal) == (7, 2)
    # flown either way: the goal's side may be the newer one
    assert trail_join(trail, to_goal, from_start) == (2, 7)
    # an end that reaches no trail point: no way
    assert trail_join(trail, from_start, np.full(10, inf)) is None


def test_the_trail_join_is_the_cheapest_of_all_pairs() -> None:
    from amslam.lib.free_space import trail_join

    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(2, 40))
        trail = np.cumsum(rng.normal(0.0, 0.3, size=(n, 3)), axis=0)
        from_start, to_goal = (np.where(rng.random(n) < 0.3, rng.random(n) * 10, np.inf) for _ in range(2))
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(trail, axis=0), axis=1))])
        every = from_start[:, None] + np.abs(along[:, None] - along[None]) + to_goal[None]
        got = trail_join(trail, from_start, to_goal)
        if not np.isfinite(every).any():
            assert got is None
            continue
        a, b = got
        assert every[a, b] == pytest.approx(every.min())
