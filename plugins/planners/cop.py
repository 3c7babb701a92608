"""The ``cop`` planner: correlated orienteering over frontier viewpoints, refined with SLC stops.

Paper 1 §VI-B and §VI-D.

**COP.** Vertices are the reachable viewpoints with reward ``r_v`` = information gain (m³); edge
costs are path lengths; the correlation ``w(u, v)`` is the overlap of the two viewpoints' fields of
view (:mod:`.correlation`). The budget is ``budget_factor`` × the summed cost from the robot to its
``budget_k`` nearest viewpoints. The greedy constructive heuristic of Agarwal & Akella (paper 1
ref. [30]) starts from an empty tour and repeatedly takes the unselected vertex of highest

    value(v) = r_v + Σ_{u ∉ S, u ≠ v} r_u w(v, u) − Σ_{u ∈ S} r_u w(u, v),

inserts it into the open tour from the robot at its cheapest place and improves the tour with
2-opt; a vertex whose insertion would break the budget is dropped (or, with
``stop_at_first_violation``, ends the construction, the paper's literal wording). Moving ``v`` into
``S`` flips the sign of its term in every other vertex's value, so values are updated in ``O(|V|)``
per step instead of recomputed.

**Keeping the goal** (``commit_radius`` > 0; off by default). A replan while the robot flies to an
exploration viewpoint (every ``exploration.replan_period`` s, or when the frontiers changed)
starts the tour at that goal while a reachable viewpoint is within ``commit_radius`` of it
(:attr:`PlanRequest.goal`), the rest
chosen from there with the budget left: the budget follows the robot's position, and without this
two far groups of viewpoints can take turns at the head of the tour every few seconds.

**Algorithm 1 (uncertainty-reduction planning).** The COP tour is walked in order. For each next
exploration viewpoint ``VP``: its remaining gain ``r_VP · max(0, 1 − Σ_{u ∈ refined} w(u, VP))``
(constraint (8) of the paper) and its utility ``IG / cost`` from the previous stop; among the
loop-closure candidates not yet used whose travel (the map's path cost) fits the remaining
budget, the best scaled IG ``slc_scale · IG``, each candidate's IG re-estimated given the loop
closures already in the refined tour (eq. 10 of the chain of virtual factors, line 6 of the
algorithm; :func:`amslam.lib.slc_gain.chain_gain`); if that beats the viewpoint's utility the
candidate is inserted first, then the viewpoint if the budget still allows; otherwise the
viewpoint alone if it fits, else the refined tour ends. At most one SLC goes between
consecutive exploration viewpoints, and a candidate is used at most once per tour.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import Field

from amslam.interfaces import BackendParams, Planner, RunContext
from amslam.lib.slc_gain import Leg, chain_gain
from amslam.lib.tours import (
    PlanningGraph,
    budget_from_nearest,
    cheapest_insertion,
    explore_item,
    or_opt,
    planning_graph,
    tour_cost,
    two_opt,
)
from amslam.plugins.planners.correlation import fov_correlation
from amslam.types import PlanRequest, SlcCandidate, SlcGainModel, TourItem, TourItemKind

_EPS = 1e-9


class CopParams(BackendParams):
    """Parameters of the ``cop`` planner."""

    budget_factor: float = Field(
        2.0, ge=1.0, le=1000, description="budget = factor × summed cost to the budget_k nearest viewpoints"
    )
    budget_k: int = Field(3, ge=1, le=1000, description="how many nearest viewpoints set the budget")
    min_budget: float = Field(
        0.0, ge=0.0, le=100_000, description="lower bound of the travel budget in metres"
    )
    min_gain: float = Field(
        0.0, ge=0.0, le=1_000_000, description="viewpoints with gain (m³) at or below this are ignored"
    )
    stop_at_first_violation: bool = Field(
        False,
        description="end construction at the first vertex that breaks the budget (else skip it and go on)",
    )
    fov_samples: int = Field(256, ge=8, le=8192, description="points sampled per frustum for the correlation")
    fov_range: float | None = Field(
        None,
        gt=0.0,
        le=1000,
        description="far range (m) of the frustum used for correlation; default camera max_range",
    )
    slc: bool = Field(True, description="refine the tour with loop-closure stops (Algorithm 1)")
    slc_scale: float = Field(
        10.0,
        ge=0.0,
        le=1_000_000,
        description="Scale(IG): exploration utility (m³/m) worth one unit of covariance-trace reduction",
    )
    slc_min_gain: float = Field(
        0.0, ge=0.0, le=1_000_000, description="loop-closure candidates with IG at or below this are ignored"
    )
    slc_budget_factor: float = Field(
        1.0, ge=1.0, le=1000, description="budget of the refined tour relative to the COP budget"
    )
    utility_epsilon: float = Field(
        0.5, gt=0.0, le=1000, description="metres added to a viewpoint's cost in its utility IG/(cost+eps)"
    )
    # Off by default: on ten held-out flights exploring alone it made COP faster than TSP, but
    # with SLC on `make demo`'s flight (demo seed 7) ended with SLAM 0.90 m RMS off (0.165 m
    # without), every loop closure ambiguous, and four one-floor SLC flights were no better
    # (docs/experiments.md, "COP vs TSP vs greedy on held-out seeds").
    commit_radius: float = Field(
        0.0,
        ge=0.0,
        le=100,
        description="a replan keeps the goal the robot was flying to first while a reachable viewpoint"
        " is within this of it (m; 0: every plan chooses afresh)",
    )


@dataclass
class CopSummary:
    """What the last :meth:`CopPlanner.plan` did (for events, benchmarks and debugging)."""

    viewpoints: int = 0
    selected: int = 0
    budget: float = 0.0
    cop_cost: float = 0.0
    cop_reward: float = 0.0
    refined_cost: float = 0.0
    slc_inserted: list[int] = field(default_factory=list)


def cop_reward(gains: np.ndarray, w: np.ndarray, selected: np.ndarray) -> float:
    """Objective (7) of paper 1: ``Σ r_v (x_v + ω_v (1 − x_v))`` with ``ω_v = min(1, Σ_u w(u,v) x_u)``."""
    x = np.zeros(len(gains), dtype=bool)
    x[np.asarray(selected, dtype=int)] = True
    off = w - np.diag(np.diag(w))
    omega = np.minimum(1.0, off[x].sum(axis=0)) if x.any() else np.zeros(len(gains))
    return float(np.sum(gains * np.where(x, 1.0, omega)))


def cop_tour(
    costs: np.ndarray,
    gains: np.ndarray,
    w: np.ndarray,
    budget: float,
    *,
    stop_at_first_violation: bool = False,
    first: int | None = None,
) -> list[int]:
    """Greedy constructive COP heuristic (see module docstring).

    Args:
        costs: (M+1)×(M+1) metric travel costs, node 0 = robot.
        gains: M rewards; vertex ``i`` is node ``i + 1``.
        w: M×M symmetric correlation, ones on the diagonal.
        budget: maximum length of the open tour from the robot.
        stop_at_first_violation: end at the first best vertex that does not fit.
        first: a node the tour must start with (the goal the robot is flying to), whatever the
            budget; the rest is chosen from there with what the budget has left, its views
            counted as already taken.

    Returns:
        The open tour as node indices (1..M), robot excluded.
    """
    off = w - np.diag(np.diag(w))
    value = gains + off @ gains  # nothing selected yet: every other vertex is in V \ S
    if first is None:
        return _construct(costs, gains, off, value, budget, stop_at_first_violation)
    # The same construction from ``first`` as its start: node 0 of the sub-problem is ``first``.
    f = first - 1
    rest = [n for n in range(1, len(gains) + 1) if n != first]
    order = [first, *rest]
    idx = np.array(rest, dtype=int) - 1
    value = value - 2.0 * gains[f] * off[:, f]  # f joined S
    sub = _construct(
        costs[np.ix_(order, order)],
        gains[idx],
        off[np.ix_(idx, idx)],
        value[idx],
        budget - float(costs[0, first]),
        stop_at_first_violation,
    )
    return [first, *(order[k] for k in sub)]


def _construct(
    costs: np.ndarray, gains: np.ndarray, off: np.ndarray, value: np.ndarray, budget: float, stop: bool
) -> list[int]:
    """:func:`cop_tour`'s greedy construction from node 0 with each vertex's starting ``value``."""
    value = value.copy()
    open_ = np.ones(len(gains), dtype=bool)
    tour: list[int] = []
    length = 0.0
    while open_.any():
        v = int(np.flatnonzero(open_)[np.argmax(value[open_])])
        open_[v] = False
        if costs[0, v + 1] > budget + _EPS:  # no open tour through v is shorter (metric costs)
            if stop:
                break
            continue
        pos, delta = cheapest_insertion(costs, tour, v + 1)
        candidate = [*tour[:pos], v + 1, *tour[pos:]]
        new_length = length + delta
        if new_length > budget + _EPS:
            # Insertion alone breaks the budget; a better order of the same stops may not.
            candidate = two_opt(costs, candidate)
            new_length = tour_cost(costs, candidate)
        if new_length > budget + _EPS:
            if stop:
                break
            continue
        tour = two_opt(costs, candidate)
        length = tour_cost(costs, tour)
        value -= 2.0 * gains[v] * off[:, v]  # v leaves V \ S and joins S
    if len(tour) > 2:
        tour = two_opt(costs, or_opt(costs, tour))
    return tour


def refine_with_slc(
    graph: PlanningGraph,
    tour: list[int],
    w: np.ndarray,
    candidates: tuple[SlcCandidate, ...],
    budget: float,
    params: CopParams,
    gain_model: SlcGainModel | None = None,
) -> tuple[list[tuple[str, int]], list[float]]:
    """Algorithm 1 of paper 1: insert loop-closure stops along the COP tour.

    Line 6 ("estimate cost & IG for LC(j)") at every step of the tour: a candidate's cost is the
    map's path cost from the previous stop, and with ``gain_model`` its IG is eq. (10) of the
    virtual factors the refined tour already holds plus this one, minus theirs (the chain of
    paper 1 §VI-C: from the current pose, or the last planned loop closure, to the candidate's
    key pose over the metres flown in between along the tour). A second closure of the same
    drift is then worth less than the first. Without a model each candidate keeps its own
    ``info_gain``.

    Args:
        graph: the planning graph; ``graph.slc_costs`` holds the candidates' costs.
        tour: the COP tour (nodes 1..M).
        w: M×M viewpoint correlation.
        candidates: loop-closure candidates, row ``j`` of ``graph.slc_costs``.
        budget: maximum length of the refined open tour.
        params: planner parameters (scale, thresholds).
        gain_model: the SLAM backend's model for chains of loop closures, or None.

    Returns:
        The refined tour as ``("vp", node)`` and ``("slc", j)`` stops, and the IG each inserted
        loop closure was chosen with.
    """
    own_ig = np.array([c.info_gain for c in candidates], dtype=float)
    usable = (own_ig > params.slc_min_gain) & np.isfinite(own_ig)
    chained = gain_model is not None and all(c.keypose_id in gain_model.keypose_ids for c in candidates)
    chain = _ClosureChain(gain_model) if chained else None
    out = _RefinedTour(graph.size, chain)

    def cost_from(stop: tuple[str, int], node: int) -> float:
        kind, i = stop
        return float(graph.slc_costs[i, node] if kind == "slc" else graph.costs[i, node])

    prev: tuple[str, int] = ("vp", 0)  # the robot
    for node in tour:
        v = node - 1
        remaining = graph.gains[v] * max(0.0, 1.0 - float(w[out.in_path, v].sum()))
        vp_cost = cost_from(prev, node)
        utility = remaining / (vp_cost + params.utility_epsilon)
        best, ig = -1, own_ig
        if prev[0] == "vp":
            best, ig = _best_closure(
                graph.slc_costs[:, prev[1]], usable, out.used, budget, own_ig, candidates, chain, params
            )
        if best >= 0 and params.slc_scale * ig[best] > utility:
            usable[best] = False
            out.close(
                best, candidates[best].keypose_id, float(ig[best]), float(graph.slc_costs[best, prev[1]])
            )
            prev = ("slc", best)
            on = float(graph.slc_costs[best, node])
            if out.used + on <= budget + _EPS:
                out.visit(node, on)
                prev = ("vp", node)
        elif out.used + vp_cost <= budget + _EPS:
            out.visit(node, vp_cost)
            prev = ("vp", node)
        else:
            break
    return out.stops, out.gains


class _RefinedTour:
    """Algorithm 1's tour as it grows: its stops, the IG each closure was chosen with, the
    viewpoints in it, the metres it uses, and the chain of closures the next one is scored on."""

    def __init__(self, size: int, chain: _ClosureChain | None) -> None:
        self.stops: list[tuple[str, int]] = []
        self.gains: list[float] = []
        self.in_path = np.zeros(size, dtype=bool)
        self.used = 0.0
        self.chain = chain

    def visit(self, node: int, metres: float) -> None:
        """Fly ``metres`` to viewpoint ``node`` (1..M)."""
        self.stops.append(("vp", node))
        self.in_path[node - 1] = True
        self._fly(metres)

    def close(self, j: int, keypose_id: int, gain: float, metres: float) -> None:
        """Fly ``metres`` to loop-closure candidate ``j`` (at key pose ``keypose_id``), chosen for
        ``gain``."""
        self.stops.append(("slc", j))
        self.gains.append(gain)
        self._fly(metres)
        if self.chain is not None:
            self.chain.close_at(keypose_id, gain)

    def _fly(self, metres: float) -> None:
        self.used += metres
        if self.chain is not None:
            self.chain.since_anchor += metres


def _best_closure(
    to_slc: np.ndarray,
    usable: np.ndarray,
    used: float,
    budget: float,
    own_ig: np.ndarray,
    candidates: tuple[SlcCandidate, ...],
    chain: _ClosureChain | None,
    params: CopParams,
) -> tuple[int, np.ndarray]:
    """The usable candidate of largest IG the budget still fits after ``used`` (``to_slc``: each
    one's cost from the robot's viewpoint), and every candidate's IG: its own, or with ``chain`` eq. (10)
    given the closures already in the tour. ``-1`` when none fits or the best is worth no more
    than ``slc_min_gain``."""
    fits = usable & (used + to_slc <= budget + _EPS)
    if not fits.any():
        return -1, own_ig
    ig = own_ig if chain is None else chain.gains([c.keypose_id for c in candidates], fits, to_slc)
    best = int(np.flatnonzero(fits)[np.argmax(ig[fits])])
    return (best if ig[best] > params.slc_min_gain else -1), ig


def _committed(graph: PlanningGraph, goal: np.ndarray | None, radius: float) -> int | None:
    """The node of the reachable viewpoint nearest the goal the robot was flying to, within
    ``radius``; None without such a goal or viewpoint.

    The budget is set from the robot's position (its nearest viewpoints), so a plan made a few
    metres on can choose another far group of viewpoints, and the next one the first again: on
    one floor (seed 7, exploration alone) the tour's first stop jumped between two clusters 14 m
    apart every 6 s for 600 s, 340 m flown for 100 m³. Keeping the goal first while a viewpoint is
    still there (its frontier not yet seen) lets the robot finish what it set out for.
    """
    if goal is None or radius <= 0 or graph.size == 0:
        return None
    # the planning graph holds the viewpoints reachable from the robot only
    d = np.linalg.norm(np.array([vp.position for vp in graph.viewpoints]) - np.asarray(goal, float), axis=1)
    best = int(np.argmin(d))
    return best + 1 if d[best] <= radius else None


class _ClosureChain:
    """The loop closures of a refined tour so far, as the chain of virtual odometry factors whose
    eq. (10) scores the next candidate (Algorithm 1, line 6)."""

    def __init__(self, model: SlcGainModel) -> None:
        self.model = model
        self.legs: list[Leg] = []
        self.anchor = model.keypose_ids[0]  # the key pose the robot's pose was last tied to
        self.since_anchor = 0.0  # metres flown along the refined tour since then
        self.gain = 0.0  # eq. (10) of the legs so far

    def gains(self, keypose_ids: list[int], fits: np.ndarray, to_slc: np.ndarray) -> np.ndarray:
        """Each fitting candidate's IG given the chain (−inf for the others): the chain's eq. (10)
        with a leg from the anchor to it over the metres flown since plus its travel, minus the
        chain's own."""
        ig = np.full(len(keypose_ids), -np.inf)
        for j in np.flatnonzero(fits):
            leg = (self.anchor, keypose_ids[j], self.since_anchor + float(to_slc[j]))
            ig[j] = chain_gain(self.model, [*self.legs, leg]) - self.gain
        return ig

    def close_at(self, keypose_id: int, gain: float) -> None:
        """A loop closure at ``keypose_id`` joins the tour (the travel to it already flown)."""
        self.legs.append((self.anchor, keypose_id, self.since_anchor))
        self.gain += gain
        self.anchor, self.since_anchor = keypose_id, 0.0


class CopPlanner(Planner):
    """COP exploration tour over frontier viewpoints, refined with loop-closure stops."""

    Params = CopParams

    def __init__(self) -> None:
        self.params = CopParams()
        self.summary = CopSummary()
        self._emit = None

    def configure(self, params: CopParams, context: RunContext) -> None:
        """Keep the validated parameters; import what the first plan samples with."""
        self.params = params
        self._emit = context.emit
        # Here, before take-off, not at the first plan: on a real vehicle that import (0.3-0.6 s
        # of scipy.stats) ran on the planner thread in flight and stalled the control loop 1.6 s
        # (a SITL flight's late_ticks.jsonl). Not at module load either: listing plugins stays fast.
        from scipy.stats import qmc  # noqa: F401

    def plan(self, request: PlanRequest) -> list[TourItem]:
        """COP tour, then Algorithm 1 when ``slc`` is on and candidates were given.

        Raises:
            PlanningError: the request's matrices do not match its viewpoints and candidates.
        """
        p = self.params
        with_slc = p.slc and len(request.slc_candidates) > 0
        graph = planning_graph(request, p.min_gain, with_slc=with_slc)
        self.summary = CopSummary(viewpoints=graph.size)
        if graph.size == 0:
            self._report()
            return []
        w = fov_correlation(
            np.array([vp.position for vp in graph.viewpoints]),
            np.array([vp.yaw for vp in graph.viewpoints]),
            request.camera,
            samples=p.fov_samples,
            far=p.fov_range,
        )
        budget = budget_from_nearest(graph.costs[0, 1:], p.budget_k, p.budget_factor, p.min_budget)
        tour = cop_tour(
            graph.costs,
            graph.gains,
            w,
            budget,
            stop_at_first_violation=p.stop_at_first_violation,
            first=_committed(graph, request.goal, p.commit_radius),
        )
        s = self.summary
        s.selected, s.budget = len(tour), budget
        s.cop_cost = tour_cost(graph.costs, tour)
        s.cop_reward = cop_reward(graph.gains, w, np.array(tour, dtype=int) - 1)
        slc_gains: list[float] = []
        if with_slc:
            stops, slc_gains = refine_with_slc(
                graph,
                tour,
                w,
                request.slc_candidates,
                budget * p.slc_budget_factor,
                self.params,
                request.slc_gain,
            )
        else:
            stops = [("vp", node) for node in tour]
        chosen_gain = iter(slc_gains)
        items = [
            self._item(graph, request.slc_candidates, stop, next(chosen_gain) if stop[0] == "slc" else 0.0)
            for stop in stops
        ]
        s.refined_cost = _refined_cost(graph, stops)
        s.slc_inserted = [request.slc_candidates[j].keypose_id for kind, j in stops if kind == "slc"]
        self._report()
        return items

    @staticmethod
    def _item(
        graph: PlanningGraph, candidates: tuple[SlcCandidate, ...], stop: tuple[str, int], slc_gain: float
    ) -> TourItem:
        kind, i = stop
        if kind == "vp":
            return explore_item(graph.viewpoints[i - 1])
        c = candidates[i]
        return TourItem(
            kind=TourItemKind.SLC,
            position=np.asarray(c.position, dtype=float),
            yaw=float(c.yaw),
            gain=float(slc_gain),
            ref=int(c.keypose_id),
        )

    def _report(self) -> None:
        if self._emit is None:
            return
        s = self.summary
        self._emit(
            "planner_tour",
            planner="cop",
            viewpoints=s.viewpoints,
            selected=s.selected,
            budget=round(s.budget, 3),
            cop_cost=round(s.cop_cost, 3),
            cop_reward=round(s.cop_reward, 3),
            refined_cost=round(s.refined_cost, 3),
            slc_inserted=list(s.slc_inserted),
        )


def _refined_cost(graph: PlanningGraph, stops: list[tuple[str, int]]) -> float:
    """Length of the refined open tour from the robot (two SLC stops are never adjacent)."""
    total, prev = 0.0, ("vp", 0)
    for stop in stops:
        if prev[0] == "vp" and stop[0] == "vp":
            total += float(graph.costs[prev[1], stop[1]])
        elif stop[0] == "slc":
            total += float(graph.slc_costs[stop[1], prev[1]])
        else:
            total += float(graph.slc_costs[prev[1], stop[1]])
        prev = stop
    return total
