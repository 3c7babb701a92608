"""Graph helpers shared by the planners: the planning graph, budgets and open-tour heuristics.

Every planner works on a small dense *planning graph*: node 0 is the robot, nodes 1..M are the
viewpoints of the request that are worth visiting and reachable from the robot. Its cost matrix is
the metric closure (all-pairs shortest paths) of ``request.costs`` restricted to those nodes, so
that a pair the mapping backend reported as unreachable still gets the finite cost of a path
through other nodes (at worst through the robot's position), and the triangle inequality holds for
the insertion and 2-opt heuristics below.

Tours are *open*: they start at the robot (node 0, never moved) and end at the last stop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amslam.errors import PlanningError
from amslam.types import PlanRequest, TourItem, TourItemKind, Viewpoint

#: Stand-in for a zero edge between two distinct nodes: scipy's dense csgraph treats 0 as "no edge".
_TINY = 1e-9


@dataclass(frozen=True)
class PlanningGraph:
    """The robot and the viewpoints worth planning over.

    Attributes:
        viewpoints: the kept viewpoints; ``viewpoints[i]`` is graph node ``i + 1``.
        columns: column of each kept viewpoint in ``request.costs`` (node ``i + 1`` ↔ ``columns[i]``).
        costs: (M+1)×(M+1) metric-closed travel costs in metres, node 0 = robot.
        gains: M rewards (information gain in m³) of the kept viewpoints.
        slc_costs: C×(M+1) metric-closed costs from each loop-closure candidate to the robot
            (column 0) and to the kept viewpoints; C = 0 unless built with ``with_slc=True``.
    """

    viewpoints: tuple[Viewpoint, ...]
    columns: np.ndarray
    costs: np.ndarray
    gains: np.ndarray
    slc_costs: np.ndarray = field(default_factory=lambda: np.zeros((0, 1)))

    @property
    def size(self) -> int:
        """Number of viewpoints (graph nodes without the robot)."""
        return len(self.gains)


def validate_request(request: PlanRequest) -> None:
    """Check the shapes of a request's matrices.

    Raises:
        PlanningError: ``costs`` or ``slc_costs`` do not match the viewpoints and candidates.
    """
    n = len(request.viewpoints)
    costs = np.asarray(request.costs)
    if costs.shape != (n + 1, n + 1):
        raise PlanningError(f"costs must be {(n + 1, n + 1)} for {n} viewpoints, got {costs.shape}")
    c = len(request.slc_candidates)
    if c and np.asarray(request.slc_costs).shape != (c, n + 1):
        raise PlanningError(
            f"slc_costs must be {(c, n + 1)} for {c} candidates and {n} viewpoints, "
            f"got {np.asarray(request.slc_costs).shape}"
        )


def metric_closure(costs: np.ndarray) -> np.ndarray:
    """All-pairs shortest paths over a dense cost matrix (inf = no edge), symmetrised.

    Path costs from a mapping backend are symmetric up to search artefacts; the larger of the two
    directions is kept so that a tour never relies on an optimistic one-way estimate.
    """
    from scipy.sparse.csgraph import shortest_path

    c = np.asarray(costs, dtype=float).copy()
    c = np.maximum(c, c.T)
    off_diagonal = ~np.eye(len(c), dtype=bool)
    c[off_diagonal & (c <= 0.0)] = _TINY
    np.fill_diagonal(c, 0.0)
    closed = shortest_path(c, method="auto", directed=False)
    closed[closed <= _TINY * len(c)] = 0.0
    np.fill_diagonal(closed, 0.0)
    return closed


def planning_graph(request: PlanRequest, min_gain: float = 0.0, *, with_slc: bool = False) -> PlanningGraph:
    """Keep the viewpoints with ``gain > min_gain`` reachable from the robot; close their costs.

    With ``with_slc`` the loop-closure candidates join the closure (candidate-to-candidate costs are
    unknown and only found through other nodes) and their costs are returned in ``slc_costs``.

    Raises:
        PlanningError: malformed request (see :func:`validate_request`).
    """
    validate_request(request)
    n = len(request.viewpoints)
    c = len(request.slc_candidates) if with_slc else 0
    full = np.full((n + 1 + c, n + 1 + c), np.inf)
    full[: n + 1, : n + 1] = np.asarray(request.costs, dtype=float)
    if c:
        slc = np.asarray(request.slc_costs, dtype=float)
        full[n + 1 :, : n + 1] = slc
        full[: n + 1, n + 1 :] = slc.T
    np.fill_diagonal(full, 0.0)
    closed = metric_closure(full) if len(full) > 1 else np.zeros((1, 1))
    gains = np.array([vp.gain for vp in request.viewpoints], dtype=float).reshape(-1)
    keep = np.flatnonzero(np.isfinite(closed[0, 1 : n + 1]) & (gains > min_gain) & np.isfinite(gains))
    nodes = np.concatenate([[0], keep + 1]).astype(int)
    return PlanningGraph(
        viewpoints=tuple(request.viewpoints[i] for i in keep),
        columns=keep + 1,
        costs=closed[np.ix_(nodes, nodes)],
        gains=gains[keep],
        slc_costs=closed[np.ix_(np.arange(n + 1, n + 1 + c), nodes)],
    )


def budget_from_nearest(costs_from_robot: np.ndarray, k: int, factor: float, minimum: float = 0.0) -> float:
    """Travel budget of paper 1 §VI-B: ``factor`` × the summed cost to the ``k`` nearest viewpoints.

    With ``factor >= 1`` the nearest viewpoint always fits, so a reachable frontier is never
    dropped because of the budget.
    """
    finite = np.sort(costs_from_robot[np.isfinite(costs_from_robot)])
    if finite.size == 0:
        return max(minimum, 0.0)
    return max(minimum, factor * float(finite[: max(k, 1)].sum()))


def tour_cost(costs: np.ndarray, tour: list[int] | np.ndarray) -> float:
    """Length of the open path robot(0) → tour[0] → … → tour[-1]."""
    path = np.concatenate([[0], np.asarray(tour, dtype=int)])
    return float(costs[path[:-1], path[1:]].sum())


def cheapest_insertion(costs: np.ndarray, tour: list[int], node: int) -> tuple[int, float]:
    """Best place to insert ``node`` into the open tour and the added cost.

    Returns:
        (position, delta): insert with ``tour.insert(position, node)``; ``delta`` is the increase
        of :func:`tour_cost`. Appending after the last stop is one of the options (open tour).
    """
    path = np.concatenate([[0], np.asarray(tour, dtype=int)])
    prev, nxt = path[:-1], path[1:]
    between = costs[prev, node] + costs[node, nxt] - costs[prev, nxt]
    append = costs[path[-1], node]
    if between.size and between.min() < append:
        pos = int(np.argmin(between))
        return pos, float(between[pos])
    return len(tour), float(append)


def two_opt(costs: np.ndarray, tour: list[int], max_rounds: int = 50) -> list[int]:
    """Improve an open tour (fixed start at the robot, free end) by segment reversals.

    Reversing ``path[i..j]`` of the path ``0, t1, …, tm`` changes its length by
    ``c(p[i-1], p[j]) + c(p[i], p[j+1]) − c(p[i-1], p[i]) − c(p[j], p[j+1])``, the ``p[j+1]``
    terms being absent when ``j`` is the free end. The inner loop over ``j`` is vectorised.
    """
    if len(tour) < 2:
        return list(tour)
    path = np.concatenate([[0], np.asarray(tour, dtype=int)])
    m = len(path)
    for _ in range(max_rounds):
        improved = False
        for i in range(1, m - 1):
            j = np.arange(i + 1, m)
            a, b = path[i - 1], path[i]
            c_, d_ = path[j], np.where(j + 1 < m, path[np.minimum(j + 1, m - 1)], -1)
            has_next = d_ >= 0
            d_safe = np.where(has_next, d_, 0)
            delta = costs[a, c_] - costs[a, b]
            delta = delta + np.where(has_next, costs[b, d_safe] - costs[c_, d_safe], 0.0)
            best = int(np.argmin(delta))
            if delta[best] < -1e-9:
                jj = int(j[best])
                path[i : jj + 1] = path[i : jj + 1][::-1].copy()
                improved = True
        if not improved:
            break
    return [int(x) for x in path[1:]]


def or_opt(costs: np.ndarray, tour: list[int], max_rounds: int = 20) -> list[int]:
    """Move single stops to their cheapest other place while that shortens the open tour."""
    tour = list(tour)
    for _ in range(max_rounds):
        improved = False
        for idx in range(len(tour)):
            node = tour[idx]
            rest = tour[:idx] + tour[idx + 1 :]
            before = tour_cost(costs, tour)
            pos, delta = cheapest_insertion(costs, rest, node)
            if tour_cost(costs, rest) + delta < before - 1e-9:
                rest.insert(pos, node)
                tour = rest
                improved = True
        if not improved:
            break
    return tour


def nearest_neighbour_tour(costs: np.ndarray, nodes: list[int] | np.ndarray) -> list[int]:
    """Open tour from the robot that always goes to the closest unvisited node."""
    left = [int(n) for n in nodes]
    tour: list[int] = []
    here = 0
    while left:
        k = int(np.argmin(costs[here, left]))
        here = left.pop(k)
        tour.append(here)
    return tour


def exact_open_tour(costs: np.ndarray, nodes: list[int] | np.ndarray) -> list[int]:
    """Shortest open tour from the robot through ``nodes`` by Held–Karp dynamic programming.

    ``O(2^n n^2)`` time and ``O(2^n n)`` memory; meant for ``n <= 12``. ``dp[S, j]`` is the length
    of the shortest path that leaves the robot, visits exactly the set ``S`` and ends at ``j``.
    """
    nodes = np.asarray(nodes, dtype=int)
    n = len(nodes)
    if n == 0:
        return []
    sub = costs[np.ix_(nodes, nodes)]
    full = 1 << n
    dp = np.full((full, n), np.inf)
    parent = np.full((full, n), -1, dtype=np.int64)
    bits = 1 << np.arange(n)
    dp[bits, np.arange(n)] = costs[0, nodes]
    # Masks in increasing order: every proper subset of S is smaller than S.
    for mask in range(1, full):
        members = np.flatnonzero(mask & bits)
        if members.size < 2:
            continue
        # For each end j in S: best predecessor i in S \ {j}.
        prev_masks = mask ^ bits[members]  # S \ {j}, one per j
        cand = dp[prev_masks][:, members] + sub[np.ix_(members, members)].T  # [j, i]
        cand[np.arange(members.size), np.arange(members.size)] = np.inf
        best = np.argmin(cand, axis=1)
        dp[mask, members] = cand[np.arange(members.size), best]
        parent[mask, members] = members[best]
    mask = full - 1
    j = int(np.argmin(dp[mask]))
    order = []
    while j >= 0:
        order.append(j)
        pj = int(parent[mask, j])
        mask ^= 1 << j
        j = pj
    return [int(nodes[k]) for k in reversed(order)]


def explore_item(vp: Viewpoint) -> TourItem:
    """The tour stop of a frontier viewpoint."""
    return TourItem(
        kind=TourItemKind.EXPLORE,
        position=np.asarray(vp.position, dtype=float),
        yaw=float(vp.yaw),
        gain=float(vp.gain),
        ref=int(vp.id),
    )
