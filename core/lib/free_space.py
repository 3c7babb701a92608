"""Collision checks and graph search over a dense block of voxel states (any backend).

Backends hand over an int8 ``VoxelState`` block (indices ``[lo, lo + shape)`` of the shared lattice)
and these functions do the rest: robot-radius inflation, the 26-connected free-space graph, multi
source Dijkstra for path costs (:mod:`amslam.lib.dijkstra`, which lets other threads run), one path
(``scipy.sparse.csgraph``), path extraction and line-of-sight smoothing.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from amslam.lib.voxel_grid import FREE, OCCUPIED, UNKNOWN, centres, to_index


def clearance_kernel(radius: float, voxel: float) -> np.ndarray:
    """Offsets of voxels whose box comes closer than ``radius`` to a voxel centre, as a mask.

    A robot of radius ``radius`` centred on a voxel centre touches exactly the voxels in this mask.
    """
    m = int(np.ceil(radius / voxel + 0.5))
    g = np.arange(-m, m + 1)
    off = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1)
    gap = np.maximum(np.abs(off) - 0.5, 0.0) * voxel  # per-axis distance centre → voxel box
    return np.sqrt((gap**2).sum(-1)) < radius


#: 6-connected structuring element (``ndimage.generate_binary_structure(3, 1)``, spelled out so that
#: importing this module does not import scipy.ndimage)
_CROSS = np.abs(np.indices((3, 3, 3)) - 1).sum(axis=0) <= 1


def _shift(mask: np.ndarray, axis: int, step: int) -> np.ndarray:
    """``mask`` moved by ``step`` voxels along ``axis`` (out of the block: False)."""
    out = np.zeros_like(mask)
    src = [slice(None)] * 3
    dst = [slice(None)] * 3
    if step > 0:
        src[axis], dst[axis] = slice(0, -step), slice(step, None)
    else:
        src[axis], dst[axis] = slice(-step, None), slice(0, step)
    out[tuple(dst)] = mask[tuple(src)]
    return out


def horizontal_surfaces(states: np.ndarray) -> np.ndarray:
    """Occupied voxels of horizontal surfaces: slabs, floors, ceilings (and table tops).

    An occupied voxel that spreads in both horizontal directions (an occupied neighbour along x and
    one along y) and has a non-occupied voxel above or below it. Walls are excluded by the last
    condition (their voxels have occupied voxels above and below) except their top and bottom rows,
    which meet a slab anyway.
    """
    occ = states == OCCUPIED
    along = [_shift(occ, a, 1) | _shift(occ, a, -1) for a in range(3)]
    open_vertically = ~(_shift(occ, 2, 1) & _shift(occ, 2, -1))
    return occ & along[0] & along[1] & open_vertically


#: a horizontal surface larger than this (m², one z layer, 8-connected) is a slab, floor or
#: ceiling; smaller ones are furniture tops (a 2.4 × 1.2 m conference table is 2.9 m²)
SLAB_MIN_AREA = 4.0


def slabs(states: np.ndarray, voxel: float) -> np.ndarray:
    """The :func:`horizontal_surfaces` voxels of slabs, floors and ceilings: components of at least
    ``SLAB_MIN_AREA`` within their z layer (furniture tops excluded)."""
    return large_in_layer(horizontal_surfaces(states), voxel, SLAB_MIN_AREA)


def large_in_layer(mask: np.ndarray, voxel: float, min_area: float) -> np.ndarray:
    """The voxels of ``mask`` whose component within their z layer (8-connected) covers at least
    ``min_area`` m²."""
    from scipy import ndimage

    if not mask.any():
        return mask
    eight = np.zeros((3, 3, 3), dtype=bool)
    eight[:, :, 1] = True  # connected within the layer only
    labels, n = ndimage.label(mask, structure=eight)
    big = np.bincount(labels.reshape(-1), minlength=n + 1) * voxel**2 >= min_area
    big[0] = False
    return big[labels]


def _disc(radius: float, voxel: float) -> np.ndarray:
    """Flat structuring element: the voxels of one z layer whose box comes within ``radius``."""
    k = clearance_kernel(radius, voxel)
    return k[:, :, k.shape[2] // 2 : k.shape[2] // 2 + 1]


def narrow_slab_gaps(
    states: np.ndarray,
    voxel: float,
    opening: float,
    unseen_reach: float = 0.0,
    *,
    slab: np.ndarray | None = None,
) -> np.ndarray:
    """Free voxels in a slab's z layer, near it, in a part of the layer too narrow for an opening.

    A hole the global map carved into a slab from drifted poses is free space in the slab's layer
    where there is none: a robot under or over it would fly into the slab. Free voxels of a slab's
    layer within ``opening`` of the slab (horizontally), with nothing occupied right above or below,
    that no disc of radius ``opening`` of free voxels in that layer covers (a morphological opening
    per layer) are taken for such holes. A real
    opening between floors — a shaft, a stairwell, an atrium — is wider and keeps its free space.
    ``slab``: the block's :func:`slabs`, when the caller has them (see :func:`obstacles`).
    """
    from scipy import ndimage

    slab = slabs(states, voxel) if slab is None else slab.copy()
    if opening <= 0 or not slab.any():
        return np.zeros(states.shape, dtype=bool)
    slab |= unseen_surface(states, voxel, unseen_reach) & ndimage.binary_dilation(slab, structure=_CROSS)
    disc = _disc(opening, voxel)
    free = states == FREE
    near = ndimage.binary_dilation(slab, structure=disc)
    wide = ndimage.binary_opening(free, structure=disc)
    # A hole goes through: nothing occupied right above or below. (Air next to a ragged ceiling or
    # floor, whose surface straddles two layers where poses differed, has the surface above or
    # below it and is no hole.)
    occ = states == OCCUPIED
    through = ~_shift(occ, 2, 1) & ~_shift(occ, 2, -1)
    return free & near & ~wide & through


def unseen_surface(
    states: np.ndarray, voxel: float, reach: float, surface: np.ndarray | None = None
) -> np.ndarray:
    """Unknown voxels taken for the unseen continuation of a seen slab, floor or ceiling.

    A 0.2 m slab seen from below is one layer of occupied voxels with unknown above it; a slab edge
    or the rim of a hole seen for a moment stays unknown next to the occupied part. Only occupied
    voxels keep a path off a surface, so a path along (or through) such a slab can pass within a
    radius of it. Unknown voxels connected to a horizontal surface through unknown voxels within
    ``reach`` metres (6-connected steps) are treated as occupied for clearance instead.
    ``surface``: the block's :func:`horizontal_surfaces`, when the caller has them.
    """
    from scipy import ndimage

    if reach <= 0:
        return np.zeros(states.shape, dtype=bool)
    slab = horizontal_surfaces(states) if surface is None else surface
    if not slab.any():
        return np.zeros(states.shape, dtype=bool)
    unknown = states == UNKNOWN
    steps = max(1, int(round(reach / voxel)))
    grown = ndimage.binary_dilation(slab, structure=_CROSS, iterations=steps, mask=slab | unknown)
    return grown & unknown


#: a ceiling seen from below over less than this (m², one z layer) is not continued into unknown
#: space: door lintels (a 0.2 m wall over a 1.2–2 m door) and beams are not ceilings
CEILING_MIN_AREA = 1.0


def unseen_ceiling(
    states: np.ndarray, voxel: float, reach: float, surface: np.ndarray | None = None
) -> np.ndarray:
    """Unknown voxels taken for the unseen rest of a ceiling seen from below, in its own layer.

    The camera looks level: a vehicle sees a ceiling only ahead of it, from a metre or more below,
    and never the part over its head. When it is off where the map of the building puts it (its
    pose error), it may climb a "shaft" under a ceiling whose underside it saw a metre away (a
    three-floor flight did, 1.2 m off, and hit the slab). Unknown voxels in the layer of a
    horizontal surface with free space under it, connected to it within ``reach`` metres through
    unknown voxels of that layer (8-connected steps), are taken for more of it; seen air in that
    layer (a shaft seen from below) stays air. Only in the layer: the unseen air under it is not
    lowered. Only ceilings seen over ``CEILING_MIN_AREA`` of the block are continued.
    ``surface``: the block's :func:`horizontal_surfaces`, when the caller has them.
    """
    from scipy import ndimage

    if reach <= 0:
        return np.zeros(states.shape, dtype=bool)
    surface = horizontal_surfaces(states) if surface is None else surface
    # a ceiling spreads: the underside of a door's lintel (0.2 m deep) is no ceiling to continue
    ceiling = large_in_layer(surface & _shift(states == FREE, 2, 1), voxel, CEILING_MIN_AREA)
    if not ceiling.any():
        return np.zeros(states.shape, dtype=bool)
    unknown = states == UNKNOWN
    steps = max(1, int(round(reach / voxel)))
    out = np.zeros(states.shape, dtype=bool)
    eight = np.ones((3, 3), dtype=bool)
    for z in np.flatnonzero(ceiling.any(axis=(0, 1))):  # layer by layer: few hold a ceiling
        layer, free_to_grow = ceiling[:, :, z], unknown[:, :, z]
        grown = ndimage.binary_dilation(layer, structure=eight, iterations=steps, mask=layer | free_to_grow)
        out[:, :, z] = grown & free_to_grow
    return out


def obstacles(
    states: np.ndarray,
    voxel: float,
    unseen_reach: float = 0.0,
    slab_opening: float = 0.0,
    *,
    slab: np.ndarray | None = None,
    ceiling_reach: float = 0.0,
    slab_history: np.ndarray | None = None,
) -> np.ndarray:
    """Voxels the robot must keep its radius from: occupied ones, :func:`unseen_surface` and (with
    ``slab_opening``, on a block holding whole free regions, e.g. the path graph's) the
    :func:`narrow_slab_gaps`; with ``ceiling_reach`` (the fine local map's rule) also
    :func:`unseen_ceiling`; with ``slab_history`` (the global map's voxels taken for a slab at
    some earlier time) those as well, whatever their state now: a slab the map carved away from
    drifted poses is still there.

    ``slab``: the :func:`slabs` of the block, when the caller has them. They are the one rule that
    is not local (a surface is a slab by the size of its whole component): a caller working on a
    part of a larger block passes those of the whole block, and everything else here depends only
    on the voxels within :func:`graph_rules_reach` of a voxel."""
    occ = states == OCCUPIED
    surface = horizontal_surfaces(states) if unseen_reach > 0 or ceiling_reach > 0 else None
    if unseen_reach > 0:
        occ |= unseen_surface(states, voxel, unseen_reach, surface)
    if ceiling_reach > 0:
        occ |= unseen_ceiling(states, voxel, ceiling_reach, surface)
    if slab_opening > 0:
        occ |= narrow_slab_gaps(states, voxel, slab_opening, unseen_reach, slab=slab)
    if slab_history is not None:
        occ |= slab_history
    return occ


def traversable(
    states: np.ndarray,
    radius: float,
    voxel: float,
    unknown_free: bool = False,
    unseen_reach: float = 0.0,
    slab_opening: float = 0.0,
) -> np.ndarray:
    """Known-free (or, with ``unknown_free``, not occupied) voxels with no :func:`obstacles` voxel
    within ``radius`` of their centre."""
    free = (states != OCCUPIED) if unknown_free else (states == FREE)
    return free & ~inflate(obstacles(states, voxel, unseen_reach, slab_opening), radius, voxel)


def inflate(occ: np.ndarray, radius: float, voxel: float) -> np.ndarray:
    """Voxels of ``occ`` and those whose centre lies within ``radius`` of an ``occ`` voxel's box."""
    from scipy import ndimage

    if radius > 0 and occ.any():
        return ndimage.binary_dilation(occ, structure=clearance_kernel(radius, voxel))
    return occ.copy()


def vertical_ok(
    states: np.ndarray,
    radius: float,
    voxel: float,
    *,
    observed: bool = True,
    opening: float = 0.0,
    unseen_reach: float = 0.0,
    slab: np.ndarray | None = None,
    seen_through: np.ndarray | None = None,
    through_reach: float = 0.0,
    slab_history: np.ndarray | None = None,
    seen_from_above: np.ndarray | None = None,
    seen_from_below: np.ndarray | None = None,
) -> np.ndarray:
    """Voxels where a path may move vertically (climb, descend) near slabs, floors and ceilings.

    The camera looks level (±29° for a D435): a robot climbing or descending does not see where it
    goes, so a floor change can only trust what was observed before, and the global map it trusts
    carves holes into 0.2 m slabs wherever a slab was seen from poses a few centimetres off in z
    (measured on the demo: 157 of 1931 slab voxels free at the end of a flight, in patches of
    0.25–2.75 m, most at the lowest log-odds). Two rules, each optional:

    * ``observed``: within ``radius`` plus one voxel of a horizontal surface, a vertical move only
      where every voxel within ``radius`` was observed (free or occupied, no unknown): a hole whose
      rim was never seen, or the unseen top of a slab seen from below, is not a way up or down.
    * ``opening``: in the z layer of a slab, floor or ceiling (:func:`slabs`, or its unseen
      continuation, :func:`unseen_surface`), a vertical move only ``opening`` metres from it:
      floors are changed through wide openings (a shaft, a stairwell), not through a patch the map
      carved into a slab, which is only as wide as the pose error that carved it allows.
    * ``seen_through`` (voxels a ray crossed on its way to a point well above or below,
      :func:`~amslam.lib.voxel_grid.seen_through`): within ``through_reach`` horizontally of a
      slab, floor or ceiling (or of a voxel of ``slab_history``) seen from both floors, in its z
      layer, a vertical move only through such air. A slab seen from above and below by poses
      whose heights disagree sits in two layers in two places, and the rays of each side carve
      the other's layer: a three-floor flight's map had a free strip 2 m wide and 7 m long
      through both layers of a slab, more than the opening rule's distance from either, and
      climbed into it. Rays cross a real opening (the camera sees the floor above or below
      through it); those that carved the strip ended on the slab. "Seen from both floors":
      observed free air two or three layers over and under it and, when given, a hit on it (or a
      layer off) in ``seen_from_above`` and ``seen_from_below``
      (:func:`~amslam.lib.voxel_grid.surfaces_seen_from`).

    Elsewhere vertical moves keep the ordinary rule (known free, clear of obstacles). ``slab``: the
    block's :func:`slabs`, when the caller has them (see :func:`obstacles`).
    """
    from scipy import ndimage

    ok = np.ones(states.shape, dtype=bool)
    surface = horizontal_surfaces(states)
    if not surface.any():
        return ok
    if observed:
        unknown = states == UNKNOWN
        if unknown.any():
            seen_around = ~ndimage.binary_dilation(unknown, structure=clearance_kernel(radius, voxel))
            m = int(np.ceil(radius / voxel)) + 1
            # the (2m + 1)³ box as three 1-D dilations: the same voxels, a seventh of the work at m = 3
            near_slab = surface
            for axis in range(3):
                segment = np.ones(tuple(2 * m + 1 if a == axis else 1 for a in range(3)), dtype=bool)
                near_slab = ndimage.binary_dilation(near_slab, structure=segment)
            ok &= seen_around | ~near_slab
    big = slabs(states, voxel) if slab is None else slab.copy()
    if big.any() and (opening > 0 or seen_through is not None):
        big |= unseen_surface(states, voxel, unseen_reach) & ndimage.binary_dilation(big, structure=_CROSS)
    if opening > 0 and big.any():
        ok &= ~ndimage.binary_dilation(big, structure=_disc(opening, voxel))
    if seen_through is not None and through_reach > 0:
        floors = big | slab_history if slab_history is not None else big
        floors &= _seen_from_both_floors(states, seen_from_above, seen_from_below)
        if floors.any():
            ok &= seen_through | ~ndimage.binary_dilation(floors, structure=_disc(through_reach, voxel))
    return ok


def _seen_from_both_floors(
    states: np.ndarray, seen_from_above: np.ndarray | None, seen_from_below: np.ndarray | None
) -> np.ndarray:
    """Voxels of a slab's layer seen from both floors (:func:`vertical_ok`): observed free air two
    or three layers over them and under them (one layer off may be the slab itself, seen a layer
    high or low) and, when given, a hit on them or a layer off from above and from below.

    The carving the seen-through rule guards against needs both sides seen; a slab seen from below
    only (a floor not yet visited) keeps the other rules, or the first climb to it would wait for a
    proof the level camera cannot give from below (a ray 1.6 m under the slab, 29° up at most, ends
    at 5 m range 0.8 m above it). The air over a slab is also seen from below, through a shaft
    beside it, before any pose was over it (the demo's first climb waited for a proof it could not
    get); its top is hit from above only by a camera that was over it.
    """
    free = states == FREE
    both = (_shift(free, 2, -2) | _shift(free, 2, -3)) & (_shift(free, 2, 2) | _shift(free, 2, 3))
    for side in (seen_from_above, seen_from_below):
        if side is not None:
            both &= side | _shift(side, 2, 1) | _shift(side, 2, -1)
    return both


def _reach(structure: np.ndarray) -> np.ndarray:
    """Per axis, how far from its centre a structuring element reaches (voxels)."""
    hits = np.argwhere(structure)
    if len(hits) == 0:
        return np.zeros(3, dtype=np.int64)
    return np.abs(hits - np.array(structure.shape) // 2).max(axis=0)


def graph_rules_reach(
    voxel: float,
    radii: tuple[float, ...],
    unseen_reach: float = 0.0,
    slab_opening: float = 0.0,
    through_reach: float = 0.0,
) -> np.ndarray:
    """Per axis, how far (voxels) the path graph's rules look from a voxel: its passability, its
    clearance penalty and whether it allows vertical moves depend only on the states within this
    box, given the :func:`slabs` of the whole block (the one non-local rule).

    For :func:`obstacles` inflated by each of ``radii`` and :func:`vertical_ok` with the first of
    them; each step's reach added up along the chain of rules (a bound, not the least one). A
    caller recomputes the rules near changed voxels only (the global map's graph) with it.
    """
    steps = max(1, int(round(unseen_reach / voxel))) if unseen_reach > 0 else 0
    unseen = 1 + steps  # horizontal surfaces (1), grown through unknown voxels
    disc = _reach(_disc(slab_opening, voxel)) if slab_opening > 0 else np.zeros(3, dtype=np.int64)
    # the slabs and their unseen continuation widened by the disc; the free voxels' opening
    narrow = np.maximum.reduce([unseen + disc, 2 * disc, np.array([0, 0, 1])])
    obstacle = np.maximum(unseen, narrow)
    inflated = [obstacle + _reach(clearance_kernel(r, voxel)) for r in radii]
    m = int(np.ceil(radii[0] / voxel)) + 1  # vertical_ok's box round horizontal surfaces
    # the slabs, their unseen continuation and the slab history (seen from both floors: three
    # layers over and under) widened by the seen-through disc
    band = _reach(_disc(through_reach, voxel)) + np.array([0, 0, 3]) if through_reach > 0 else 0
    vertical = np.maximum.reduce(
        [_reach(clearance_kernel(radii[0], voxel)), np.full(3, 1 + m), unseen + disc, unseen + band]
    )
    return np.maximum.reduce([*inflated, vertical]).astype(np.int64)


def segment_samples(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Points along the segment a→b, both ends included, spaced at most ``step``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
    return a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)


def samples_clear(
    samples: np.ndarray,
    radius: float,
    voxel: float,
    states_at: Callable[[np.ndarray], np.ndarray],
    unseen_reach: float = 0.0,
) -> bool:
    """Whether no occupied voxel comes within ``radius`` of any sample point.

    Unknown counts as free, except (with ``unseen_reach`` > 0) the :func:`unseen_surface` voxels
    next to a seen slab, floor or ceiling, which count as occupied (the same rule as the path graph).
    """
    m = int(np.ceil(radius / voxel)) + 1
    idx = to_index(samples, voxel)
    # The voxels within m of a sample, each once: marked in a box around the samples, not by
    # np.unique(axis=0) over every sample's (2m+1)³ offsets, whose row sort was a fifth of a
    # small flight's time (segment checks run every control tick).
    near_lo = idx.min(axis=0) - m
    near = np.zeros(tuple(int(s) for s in idx.max(axis=0) + m + 1 - near_lo), dtype=bool)
    g = np.arange(-m, m + 1)
    offsets = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    near[tuple((idx - near_lo + offsets[:, None, :]).reshape(-1, 3).T)] = True
    cand = np.argwhere(near) + near_lo
    if unseen_reach > 0:
        # Classify a block around the samples, wide enough that the rule sees every surface voxel
        # an unknown voxel within reach of the samples could be connected to.
        pad = m + max(1, int(round(unseen_reach / voxel))) + 2
        lo = idx.min(axis=0) - pad
        shape = tuple(int(s) for s in idx.max(axis=0) + pad + 1 - lo)
        block = states_at(np.indices(shape).reshape(3, -1).T + lo).reshape(shape)
        occ = cand[obstacles(block, voxel, unseen_reach)[tuple((cand - lo).T)]]
    else:
        occ = cand[states_at(cand) == OCCUPIED]
    if len(occ) == 0:
        return True
    lo = occ * voxel
    hi = lo + voxel
    gap = np.maximum(np.maximum(lo[None] - samples[:, None], samples[:, None] - hi[None]), 0.0)
    return bool(np.all(np.sqrt((gap**2).sum(-1)) >= radius))


class FreeSpaceGraph:
    """26-connected graph over the traversable voxels of a dense block, for shortest paths.

    Args:
        passable: boolean block (indices ``[lo, lo + shape)``) of voxels the robot may occupy.
        lo: lattice index of the block's first voxel.
        voxel: voxel edge in metres.
        snap_radius: a query point off the graph connects to the nearest node within this distance,
            provided its own voxel is not occupied (the robot's own cell is unseen at take-off) or
            it is a path's start (see :meth:`snap`).
        states: the matching VoxelState block, used to refuse snapping from occupied voxels.
        penalty: optional per-voxel cost multiplier (≥ 1); an edge costs its length times the mean
            of its two ends' multipliers. Like a costmap's inflation layer, it keeps paths away from
            walls where there is room without closing narrow doors.
        vertical_ok: optional boolean block; an edge with a vertical component joins two voxels
            only where it is True at both ends (see :func:`vertical_ok`).
        near_obstacle: optional boolean block of voxels within the robot radius of an obstacle
            (:meth:`near_obstacle_at`).
    """

    def __init__(
        self,
        passable: np.ndarray,
        lo: np.ndarray,
        voxel: float,
        snap_radius: float,
        states: np.ndarray,
        penalty: np.ndarray | None = None,
        vertical_ok: np.ndarray | None = None,
        near_obstacle: np.ndarray | None = None,
    ):
        from scipy import sparse

        from amslam.lib.graph_kernels import neighbour_csr

        self.lo = np.asarray(lo, dtype=np.int64)
        self.vertical_ok = vertical_ok
        self.near_obstacle = near_obstacle
        self.voxel = voxel
        self.snap_radius = snap_radius
        self.states = states
        self.shape = passable.shape
        self.node_of_voxel = np.full(passable.shape, -1, dtype=np.int64)
        self.node_index = np.argwhere(passable)
        self.node_of_voxel[tuple(self.node_index.T)] = np.arange(len(self.node_index))
        # Both directions stored, searched as a directed graph (with ``directed=False`` scipy
        # transposes the matrix at every call; amslam.lib.dijkstra takes it as it is)
        data, indices, indptr = neighbour_csr(self.node_of_voxel, voxel, penalty, vertical_ok)
        n = len(self.node_index)
        self.graph = sparse.csr_matrix((data, indices, indptr), shape=(n, n))
        self.graph.has_sorted_indices = True

    @property
    def n_nodes(self) -> int:
        return len(self.node_index)

    def node_position(self, node: np.ndarray) -> np.ndarray:
        """World positions of nodes (voxel centres)."""
        return centres(self.node_index[node] + self.lo, self.voxel)

    def vertical_ok_at(self, points: np.ndarray) -> np.ndarray:
        """Whether each point's voxel allows vertical moves (True everywhere without the rule;
        False outside the block)."""
        rel = to_index(np.asarray(points, dtype=float).reshape(-1, 3), self.voxel) - self.lo
        inside = np.all((rel >= 0) & (rel < np.array(self.shape)), axis=1)
        if self.vertical_ok is None:
            return inside
        out = np.zeros(len(rel), dtype=bool)
        out[inside] = self.vertical_ok[tuple(rel[inside].T)]
        return out

    def near_obstacle_at(self, points: np.ndarray) -> np.ndarray:
        """Whether each point's voxel is within the robot radius of an obstacle (False outside the
        block or without the mask)."""
        rel = to_index(np.asarray(points, dtype=float).reshape(-1, 3), self.voxel) - self.lo
        inside = np.all((rel >= 0) & (rel < np.array(self.shape)), axis=1)
        out = np.zeros(len(rel), dtype=bool)
        if self.near_obstacle is not None:
            out[inside] = self.near_obstacle[tuple(rel[inside].T)]
        return out

    def passable_at(self, points: np.ndarray) -> np.ndarray:
        """Whether each point's voxel is a graph node."""
        rel = to_index(np.asarray(points, dtype=float).reshape(-1, 3), self.voxel) - self.lo
        inside = np.all((rel >= 0) & (rel < np.array(self.shape)), axis=1)
        out = np.zeros(len(rel), dtype=bool)
        out[inside] = self.node_of_voxel[tuple(rel[inside].T)] >= 0
        return out

    def snap(self, point: np.ndarray, *, start: bool = False) -> int:
        """Graph node for a point: its own voxel, or the nearest node within the snap radius; -1.

        A point in an occupied voxel is off the graph — unless it is where a path ``start``s: the
        robot is there, so the map is wrong there (a surface integrated at a pose SLAM corrected
        later: demo seed 3 found such a phantom wall through home after a loop closure, was off
        the graph, and ended "no reachable frontier left" at 56 % explored). The path then leaves
        through it to the nearest node; the fresh local map checks that leg as it is flown."""
        point = np.asarray(point, dtype=float)
        rel = to_index(point[None], self.voxel)[0] - self.lo
        inside = bool(np.all((rel >= 0) & (rel < np.array(self.shape))))
        if inside:
            node = self.node_of_voxel[tuple(rel)]
            if node >= 0:
                return int(node)
            if self.states[tuple(rel)] == OCCUPIED and not start:
                return -1
        m = int(np.ceil(self.snap_radius / self.voxel))
        a = np.maximum(rel - m, 0)
        b = np.minimum(rel + m + 1, np.array(self.shape))
        if np.any(b <= a):
            return -1
        block = self.node_of_voxel[a[0] : b[0], a[1] : b[1], a[2] : b[2]]
        nodes = block[block >= 0]
        if len(nodes) == 0:
            return -1
        dist = np.linalg.norm(self.node_position(nodes) - point, axis=1)
        best = int(np.argmin(dist))
        return int(nodes[best]) if dist[best] <= self.snap_radius + 1e-9 else -1

    def costs(self, sources: np.ndarray, targets: np.ndarray, *, contracted_block: int = 0) -> np.ndarray:
        """S×T shortest path lengths (m), point to point, inf where unreachable.

        ``contracted_block`` > 0: searched on the graph contracted to blocks of that many voxels a
        side (:class:`ContractedGraph`): the same reachability, lengths a little longer (through
        the pieces' representative voxels), a search some 50× cheaper on a large map."""
        from amslam.lib import dijkstra

        sources = np.asarray(sources, dtype=float).reshape(-1, 3)
        targets = np.asarray(targets, dtype=float).reshape(-1, 3)
        out = np.full((len(sources), len(targets)), np.inf)
        s_nodes = np.array([self.snap(p, start=True) for p in sources], dtype=np.int64)
        t_nodes = np.array([self.snap(p) for p in targets], dtype=np.int64)
        ok_s, ok_t = s_nodes >= 0, t_nodes >= 0
        if not ok_s.any() or not ok_t.any() or self.n_nodes == 0:
            return out
        if contracted_block > 0:
            node_dist = self.contracted(contracted_block).node_distances(s_nodes[ok_s], t_nodes[ok_t])
        else:
            uniq, inverse = np.unique(s_nodes[ok_s], return_inverse=True)
            # Not scipy's Dijkstra: it holds the interpreter, ours lets other threads run (the control
            # loop of a real vehicle while the planner thread asks for a tour's costs; amslam.lib.dijkstra)
            node_dist = dijkstra.distances(self.graph, uniq, self.weight_classes())[inverse][:, t_nodes[ok_t]]
        s_off = np.linalg.norm(sources[ok_s] - self.node_position(s_nodes[ok_s]), axis=1)
        t_off = np.linalg.norm(targets[ok_t] - self.node_position(t_nodes[ok_t]), axis=1)
        sub = node_dist + s_off[:, None] + t_off[None, :]
        same = s_nodes[ok_s][:, None] == t_nodes[ok_t][None, :]  # same voxel: straight line
        direct = np.linalg.norm(sources[ok_s][:, None] - targets[ok_t][None], axis=-1)
        sub = np.where(same, direct, sub)
        out[np.ix_(np.nonzero(ok_s)[0], np.nonzero(ok_t)[0])] = sub
        return out

    def weight_classes(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The graph's distinct edge weights (:func:`amslam.lib.dijkstra.weight_classes`: nine
        with a penalty of two values), found once per graph: its searches queue by weight."""
        from amslam.lib import dijkstra

        if not hasattr(self, "_weight_classes"):
            self._weight_classes = dijkstra.weight_classes(self.graph)
        return self._weight_classes

    def contracted(self, block: int) -> ContractedGraph:
        """This graph contracted to blocks of ``block`` voxels a side (built once per graph)."""
        cached = getattr(self, "_contracted", None)
        if cached is None or cached.block != block:
            cached = self._contracted = ContractedGraph(self, block)
        return cached

    def shortest_path(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Voxel-centre waypoints from start to goal (both included), or None."""
        from scipy.sparse import csgraph

        s, g = self.snap(start, start=True), self.snap(goal)
        if s < 0 or g < 0:
            return None
        if s == g:
            return np.array([start, goal], dtype=float)
        _, pred = csgraph.dijkstra(self.graph, directed=True, indices=s, return_predecessors=True)
        if pred[g] < 0:
            return None
        nodes = [g]
        while nodes[-1] != s:
            nodes.append(int(pred[nodes[-1]]))
        pts = self.node_position(np.array(nodes[::-1]))
        return np.vstack([np.asarray(start, float), pts, np.asarray(goal, float)])


class ContractedGraph:
    """A :class:`FreeSpaceGraph` contracted to blocks: one node per connected piece of graph nodes
    inside each block of ``block``³ voxels, an edge between two pieces wherever a fine edge joins
    them.

    Path costs for a tour join every viewpoint to every other; on the fine graph that is one
    Dijkstra over the whole map per viewpoint, and it grew with the building (a 20 × 30 × 10 m
    hall: 171 000 nodes, 50 ms a source, 7 s a plan). Contracted to 1 m blocks the same map has
    some 50× fewer nodes. Pieces (not whole blocks) keep reachability exact: two voxels of a block
    separated by a wall are two pieces, joined only through the fine edges that exist. Lengths
    run through each piece's representative (its voxel nearest the piece's centroid): an edge
    costs the distance between the two representatives times the cheapest crossing's cost per
    metre (the clearance penalty), so a cost is at most a block's diagonal or so longer at each
    end than the fine graph's, and detours between pieces are kept. Written here because the
    graph libraries contract by node clustering without these geometric weights.
    """

    def __init__(self, graph: FreeSpaceGraph, block: int):
        from scipy import sparse

        from amslam.lib.graph_kernels import contract

        self.block = int(block)
        n = graph.n_nodes
        cell = graph.node_index // self.block
        cell_id = np.ravel_multi_index(tuple((cell - cell.min(axis=0)).T), tuple(np.ptp(cell, axis=0) + 1))
        pos = graph.node_position(np.arange(n))
        # pieces (scipy's connected_components numbering), each one's representative (its node
        # nearest the piece's centroid) and the edges between pieces (the cheapest crossing's cost
        # per metre times the representatives' distance), compiled: see amslam.lib.graph_kernels
        self.n_pieces, self.piece, representative, csr = contract(graph.graph, cell_id, pos)
        self.rep_position = pos[representative]
        self.node_positions = pos  # every fine node's position, by node
        self.graph = sparse.csr_matrix(csr, shape=(self.n_pieces, self.n_pieces))
        self.graph.has_sorted_indices = True

    def node_distances(self, sources: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """S×T path lengths between fine graph nodes through the pieces; a straight line within a
        piece (a block at most), inf where unreachable."""
        from amslam.lib import dijkstra

        sp, tp = self.piece[sources], self.piece[targets]
        uniq, inverse = np.unique(sp, return_inverse=True)
        between = dijkstra.distances(self.graph, uniq)[inverse][:, tp]
        to_rep = np.linalg.norm(self.node_positions[sources] - self.rep_position[sp], axis=1)
        from_rep = np.linalg.norm(self.rep_position[tp] - self.node_positions[targets], axis=1)
        out = between + to_rep[:, None] + from_rep[None, :]
        same = sp[:, None] == tp[None, :]
        a, b = self.node_positions[sources], self.node_positions[targets]
        straight = np.linalg.norm(a[:, None] - b[None], axis=-1)
        return np.where(same, straight, out)


def smooth_path(path: np.ndarray, line_of_sight: Callable[[np.ndarray, np.ndarray], bool]) -> np.ndarray:
    """Line-of-sight pruning: keep a waypoint only where the straight shortcut past it is blocked."""
    out = [path[0]]
    anchor = 0
    k = 1
    while k < len(path):
        if k + 1 < len(path) and line_of_sight(path[anchor], path[k + 1]):
            k += 1
            continue
        out.append(path[k])
        anchor = k
        k += 1
    pruned = np.array(out)
    # drop duplicated consecutive points (start/goal equal to their snapped voxel centre)
    keep = np.ones(len(pruned), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(pruned, axis=0), axis=1) > 1e-9
    return pruned[keep]


def known_along(
    samples: np.ndarray, voxel: float, states_at: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """Whether each sample lies in a known (non-UNKNOWN) voxel."""
    return states_at(to_index(samples, voxel)) != UNKNOWN


def trail_join(trail: np.ndarray, from_start: np.ndarray, to_goal: np.ndarray) -> tuple[int, int] | None:
    """Where a path from a start to a goal joins the robot's flown ``trail`` (N×3, oldest first)
    and where it leaves it: the indices ``(a, b)`` that minimise the path cost from the start to
    ``trail[a]`` (``from_start``, N; inf: no path) plus the length flown along the trail between
    ``a`` and ``b`` (either way) plus the cost from ``trail[b]`` to the goal (``to_goal``); None
    when no trail point is reachable from one of the ends.

    The trail is free space proven by the vehicle itself, where the map's rules may allow no way
    (see :meth:`~amslam.interfaces.Mapping.plan_path_along_trail`). Linear in the trail's length
    (a 40-minute flight's trail is some 4 000 points: all pairs would be 16 M): the best leave for
    every join is the lower envelope of ``to_goal[b] + |along[a] - along[b]|``, a running minimum
    of ``to_goal - along`` from the start of the trail and of ``to_goal + along`` from its end.
    """
    trail = np.asarray(trail, float).reshape(-1, 3)
    from_start, to_goal = np.asarray(from_start, float), np.asarray(to_goal, float)
    if not np.isfinite(from_start).any() or not np.isfinite(to_goal).any():
        return None
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(trail, axis=0), axis=1))])
    before = along + np.minimum.accumulate(to_goal - along)  # leave at or before a
    after = np.minimum.accumulate((to_goal + along)[::-1])[::-1] - along  # at or after a
    a = int(np.argmin(from_start + np.minimum(before, after)))
    leave = to_goal + np.abs(along - along[a])
    return a, int(np.argmin(leave))
