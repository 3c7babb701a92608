"""COP tour construction (paper 1 §VI-B) and Algorithm 1 SLC insertion (§VI-D)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from amslam.geometry import pose_from
from amslam.lib.slc_gain import chain_gain
from amslam.lib.tours import PlanningGraph, tour_cost
from amslam.plugins.planners.cop import CopParams, CopPlanner, cop_reward, cop_tour, refine_with_slc
from amslam.plugins.planners.correlation import fov_correlation
from amslam.types import OdometryNoise, SlcCandidate, SlcGainModel, TourItemKind

from .conftest import make_request


def planner(**params) -> CopPlanner:
    p = CopPlanner()
    p.params = CopParams(**params)
    return p


def path_length(request, tour) -> float:
    pts = [request.start] + [t.position for t in tour]
    return float(sum(np.linalg.norm(b - a) for a, b in zip(pts, pts[1:], strict=False)))


def redundant_pair_request(camera):
    # A and A' look at the same place (w ≈ 1); B looks the other way (w = 0 with both).
    positions = [[2.0, 0, 1], [2.1, 0, 1], [-2.0, 0, 1]]
    return make_request(positions, [50.0, 49.0, 40.0], camera, yaws=[0.0, 0.0, np.pi])


def test_cop_prefers_uncorrelated_reward_over_redundant_reward(camera):
    req = redundant_pair_request(camera)
    w = fov_correlation(np.array([v.position for v in req.viewpoints]), np.zeros(3) + [0, 0, np.pi], camera)
    assert w[0, 1] > 0.9 and w[0, 2] == 0 and w[1, 2] == 0
    gains = np.array([50.0, 49.0, 40.0])
    budget = 6.05  # {A, B} costs 6.0, any tour through all three at least 6.1
    tour = cop_tour(req.costs, gains, w, budget)
    assert sorted(tour) == [1, 3]
    assert tour_cost(req.costs, tour) <= budget
    # Plain greedy-by-reward under the same budget keeps the redundant pair.
    by_reward, picked = [], []
    for v in np.argsort(-gains):
        trial = sorted([*picked, int(v)], key=lambda i: req.costs[0, i + 1])
        if tour_cost(req.costs, [i + 1 for i in trial]) <= budget:
            picked = trial
    by_reward = sorted(picked)
    assert by_reward == [0, 1]
    assert cop_reward(gains, w, np.array(tour) - 1) > cop_reward(gains, w, np.array(by_reward)) + 30


def test_planner_uses_budget_from_nearest_viewpoints(camera):
    req = redundant_pair_request(camera)
    p = planner(budget_factor=1.0, budget_k=1, min_budget=6.05, slc=False)
    tour = p.plan(req)
    assert {t.ref for t in tour} == {0, 2}
    assert p.summary.budget == pytest.approx(6.05)
    assert p.summary.selected == 2
    # factor × summed cost to the 2 nearest viewpoints: 2.0 × (2 + 2) = 8 m, room for all three
    q = planner(budget_factor=2.0, budget_k=2, slc=False)
    q.plan(req)
    assert q.summary.budget == pytest.approx(8.0) and q.summary.selected == 3


def test_a_replan_keeps_the_goal_the_robot_was_flying_to(camera):
    # West: one viewpoint 7 m away; east: two 6 m away. A budget of 2 × the nearest cost (12 m)
    # takes the east pair, whatever the robot was doing; the robot was flying west.
    positions = [[-7.0, 0, 1], [6.0, 0, 1], [6.0, 0.5, 1]]
    req = make_request(positions, [30.0, 30.0, 30.0], camera, yaws=[np.pi, 0.0, 0.0])
    fresh = planner(budget_factor=2.0, budget_k=1, slc=False).plan(req)
    assert {t.ref for t in fresh} == {1, 2}
    flying_west = dataclasses.replace(req, goal=np.array([-7.3, 0.2, 1.0]))
    kept = planner(budget_factor=2.0, budget_k=1, slc=False, commit_radius=1.0).plan(flying_west)
    assert kept[0].ref == 0  # the goal stays first though it breaks the budget; nothing fits after it
    assert [t.ref for t in kept] == [0]
    # its viewpoint gone (the frontier was seen), or commitment off: the plan chooses afresh
    gone = dataclasses.replace(req, goal=np.array([-5.0, 3.0, 1.0]))
    assert [t.ref for t in planner(budget_factor=2.0, budget_k=1, slc=False).plan(gone)] == [
        t.ref for t in fresh
    ]
    off = planner(budget_factor=2.0, budget_k=1, slc=False).plan(flying_west)  # the default: off
    assert [t.ref for t in off] == [t.ref for t in fresh]


def test_the_kept_goal_counts_its_views_as_taken(camera):
    # The kept goal A and A' see the same place: the rest of the budget goes to B (A then B: 6.0 m),
    # not to A' (worth more alone, 49 against 40, but its view is A's).
    req = redundant_pair_request(camera)
    w = fov_correlation(np.array([v.position for v in req.viewpoints]), np.zeros(3) + [0, 0, np.pi], camera)
    tour = cop_tour(req.costs, np.array([50.0, 49.0, 40.0]), w, 6.05, first=1)
    assert tour == [1, 3]
    blind = cop_tour(req.costs, np.array([50.0, 49.0, 40.0]), np.eye(3), 6.05, first=1)
    assert blind == [1, 2]  # without the correlation A' comes first and B no longer fits


@pytest.mark.parametrize("seed", range(5))
def test_random_tours_respect_budget_and_are_valid_open_tours(camera, seed):
    rng = np.random.default_rng(seed)
    n = 30
    positions = rng.uniform(0, 20, (n, 3))
    req = make_request(positions, rng.uniform(1, 40, n), camera, yaws=rng.uniform(-np.pi, np.pi, n))
    p = planner(slc=False)
    tour = p.plan(req)
    refs = [t.ref for t in tour]
    assert tour and len(set(refs)) == len(refs)
    assert all(t.kind is TourItemKind.EXPLORE for t in tour)
    assert path_length(req, tour) <= p.summary.budget + 1e-6
    assert path_length(req, tour) == pytest.approx(p.summary.cop_cost)
    for t in tour:
        np.testing.assert_allclose(t.position, positions[t.ref])
    # 2-opt leaves no improving reversal: reversing any segment does not shorten the tour.
    for i in range(len(tour)):
        for j in range(i + 1, len(tour)):
            alt = tour[:i] + tour[i : j + 1][::-1] + tour[j + 1 :]
            assert path_length(req, alt) >= path_length(req, tour) - 1e-9


def test_unreachable_viewpoints_are_never_planned_and_empty_when_none(camera):
    req = make_request([[1, 0, 1], [2, 0, 1], [3, 0, 1]], [5.0, 50.0, 5.0], camera)
    costs = req.costs.copy()
    costs[2, :] = costs[:, 2] = np.inf
    costs[2, 2] = 0
    req = make_request([[1, 0, 1], [2, 0, 1], [3, 0, 1]], [5.0, 50.0, 5.0], camera, costs=costs)
    assert 1 not in [t.ref for t in planner(budget_factor=10).plan(req)]
    costs[0, 1:] = costs[1:, 0] = np.inf
    req = make_request([[1, 0, 1], [2, 0, 1], [3, 0, 1]], [5.0, 50.0, 5.0], camera, costs=costs)
    assert planner().plan(req) == []


def test_never_empty_while_a_viewpoint_is_reachable(camera):
    # The best-valued viewpoint is far beyond the budget; the nearest still fits.
    req = make_request([[1, 0, 1], [40, 0, 1]], [1.0, 500.0], camera)
    tour = planner(budget_factor=1.0, budget_k=1).plan(req)
    assert [t.ref for t in tour] == [0]
    assert planner(budget_factor=1.0, budget_k=1, stop_at_first_violation=True).plan(req) == []


# --- Algorithm 1 -------------------------------------------------------------------------------


def line_request(camera, slc_positions, slc_gains, gains=(20.0, 20.0)):
    """Robot at x=0; viewpoints at x=4 and x=8 looking along +y (no overlap); candidates anywhere."""
    return make_request(
        [[4.0, 0, 1], [8.0, 0, 1]],
        list(gains),
        camera,
        yaws=[np.pi / 2, -np.pi / 2],
        slc_positions=slc_positions,
        slc_gains=slc_gains,
    )


def kinds(tour):
    return [(t.kind.value, t.ref) for t in tour]


def test_slc_inserted_when_informative_and_cheap(camera):
    # utility of the first viewpoint 20 m³ / (4 + 0.5) m ≈ 4.4; scaled IG of the candidate 10·1 = 10.
    req = line_request(camera, [[0.0, 1.0, 1]], [1.0])
    tour = planner(budget_factor=2.0, budget_k=2).plan(req)
    assert kinds(tour) == [("slc", 100), ("explore", 0), ("explore", 1)]
    slc = tour[0]
    assert slc.gain == 1.0
    np.testing.assert_allclose(slc.position, [0, 1, 1])


def test_slc_not_inserted_when_low_ig(camera):
    req = line_request(camera, [[0.0, 1.0, 1]], [0.3])  # 10 · 0.3 = 3 < 4.4
    assert kinds(planner(budget_factor=2.0, budget_k=2).plan(req)) == [("explore", 0), ("explore", 1)]


def test_slc_not_inserted_when_too_expensive(camera):
    # Budget 2 × (4 + 8) = 24 m; the candidate is 30 m away.
    req = line_request(camera, [[-30.0, 0.0, 1]], [5.0])
    assert kinds(planner(budget_factor=2.0, budget_k=2).plan(req)) == [("explore", 0), ("explore", 1)]
    # A larger refined-tour budget lets it in.
    tour = planner(budget_factor=2.0, budget_k=2, slc_budget_factor=4.0).plan(req)
    assert ("slc", 100) in kinds(tour)


def test_slc_switch_off_and_scale_zero_disable_insertion(camera):
    req = line_request(camera, [[0.0, 1.0, 1]], [5.0])
    assert all(t.kind is TourItemKind.EXPLORE for t in planner(slc=False).plan(req))
    assert all(t.kind is TourItemKind.EXPLORE for t in planner(slc_scale=0.0).plan(req))


def test_at_most_one_slc_between_viewpoints_and_each_used_once(camera):
    # Three informative, cheap candidates: without limits they would all go first.
    req = line_request(camera, [[0, 1.0, 1], [0.5, -1, 1], [4, 1, 1]], [5.0, 4.0, 3.0])
    tour = planner(budget_factor=4.0, budget_k=2).plan(req)
    k = kinds(tour)
    assert k[0] == ("slc", 100)
    assert all(not (a[0] == b[0] == "slc") for a, b in zip(k, k[1:], strict=False))
    slc_refs = [r for kind, r in k if kind == "slc"]
    assert len(slc_refs) == len(set(slc_refs)) == 2  # two gaps before two viewpoints
    assert [r for kind, r in k if kind == "explore"] == [0, 1]


def test_slc_can_displace_a_viewpoint_when_the_budget_is_tight(camera):
    # Budget 2 × 4 = 8 m: robot → candidate (4 m back) → first viewpoint (8 m) would be 12 m.
    req = line_request(camera, [[-4.0, 0.0, 1]], [5.0])
    p = planner(budget_factor=2.0, budget_k=1)
    tour = p.plan(req)
    assert kinds(tour) == [("slc", 100)]
    assert p.summary.refined_cost <= p.summary.budget


def test_remaining_ig_accounts_for_viewpoints_already_in_the_refined_path():
    # Two viewpoints with identical footprints: the second one adds nothing once the first is in.
    costs = np.array([[0, 4, 8], [4, 0, 4], [8, 4, 0]], float)
    graph = PlanningGraph(
        viewpoints=(),
        columns=np.array([1, 2]),
        costs=costs,
        gains=np.array([20.0, 20.0]),
        slc_costs=np.array([[1.0, 3.0, 5.0]]),
    )
    cand = (SlcCandidate(7, np.zeros(3), 0.0, (1, 2, 3), info_gain=0.2),)
    params = CopParams(slc_scale=10.0)  # scaled IG 2 < 20/4.5, but > 0 remaining of the twin
    same = np.ones((2, 2))
    assert refine_with_slc(graph, [1, 2], same, cand, 100.0, params)[0] == [("vp", 1), ("slc", 0), ("vp", 2)]
    distinct = np.eye(2)  # 2 < 20/4.5 at both steps
    assert refine_with_slc(graph, [1, 2], distinct, cand, 100.0, params)[0] == [("vp", 1), ("vp", 2)]


def test_events_and_summary_are_reported(camera, tmp_path):
    from amslam.interfaces import RunContext

    events = []
    p = CopPlanner()
    ctx = RunContext(
        rng=np.random.default_rng(0), run_dir=tmp_path, emit=lambda e, **f: events.append((e, f))
    )
    p.configure(CopParams(), ctx)
    p.plan(line_request(camera, [[0.0, 1.0, 1]], [1.0]))
    name, fields = events[-1]
    assert name == "planner_tour" and fields["planner"] == "cop" and fields["slc_inserted"] == [100]


@pytest.mark.parametrize("name", ["greedy", "cop", "tsp"])
def test_every_planner_accepts_the_runner_request_shape(camera, name):
    """The runner sends ``slc_costs`` of shape (0, N+1) when SLC is off or has no candidates."""
    from amslam.registry import build_plugin_manager

    backend = build_plugin_manager().factory("planner", name)()
    req = make_request([[1, 0, 1], [3, 1, 1]], [5.0, 8.0], camera)
    req = type(req)(req.start, 0.0, req.viewpoints, req.costs, camera, (), np.zeros((0, 3)))
    tour = backend.plan(req)
    assert tour and all(t.kind is TourItemKind.EXPLORE for t in tour)
    assert {t.ref for t in tour} <= {0, 1}


def two_place_model(b_variance: float = 0.01, correlated: bool = False) -> SlcGainModel:
    """A drifted current key pose (id 1, variance 1) and two old key poses 100 (known well) and 101;
    with ``correlated`` the two old ones are known well *relative to each other* too (seen together)."""
    poses = np.array([pose_from(np.array(p), 0.0) for p in ([0.0, 0, 1], [0.0, 1, 1], [0.5, -1, 1])])
    cov = np.zeros((18, 18))
    cov[:6, :6] = np.eye(6)
    cov[6:12, 6:12] = 0.01 * np.eye(6)
    cov[12:, 12:] = b_variance * np.eye(6)
    if correlated:
        cov[6:12, 12:] = cov[12:, 6:12] = 0.0099 * np.eye(6)
    noise = OdometryNoise(0.05, 0.012, 0.005, 0.004, 0.01, 0.002, 0.002)
    return SlcGainModel((1, 100, 101), poses, cov, cov @ cov, noise)  # V = S: gram = Σ_SS Σ_SS


def test_a_second_closure_is_scored_given_the_first(camera):
    # Standalone, both candidates are worth inserting (test_at_most_one_slc_between_...). Given the
    # first, the second closes a loop the first already closed when the two places are known
    # relative to each other, and is skipped; when the second place is itself uncertain, tying it
    # to the robot (now known well) still pays, and it goes in.
    req = line_request(camera, [[0, 1.0, 1], [0.5, -1, 1]], [5.0, 4.0])
    p = planner(budget_factor=4.0, budget_k=2)
    assert [k for k, _ in kinds(p.plan(req))].count("slc") == 2
    tour = p.plan(dataclasses.replace(req, slc_gain=two_place_model(correlated=True)))
    assert [k for k, _ in kinds(tour)].count("slc") == 1
    model = two_place_model(b_variance=0.5)
    tour = p.plan(dataclasses.replace(req, slc_gain=model))
    slcs = [t for t in tour if t.kind is TourItemKind.SLC]
    assert len(slcs) == 2
    # each stop carries the gain it was chosen with: the first alone, the second given the first
    first, second = (t.ref for t in slcs)
    assert slcs[0].gain == pytest.approx(chain_gain(model, [(1, first, 1.0)]), rel=0.05)
    assert 0 < slcs[1].gain < slcs[0].gain


def test_the_chain_uses_the_maps_path_costs_not_straight_lines(camera):
    req = line_request(camera, [[0, 1.0, 1]], [5.0])
    model = two_place_model()
    near = planner(budget_factor=4.0, budget_k=2).plan(dataclasses.replace(req, slc_gain=model))
    far_costs = req.slc_costs.copy()
    far_costs[0] += 36.0  # a wall around the candidate: every way to it is 36 m longer
    far = planner(budget_factor=40.0, budget_k=2).plan(
        dataclasses.replace(req, slc_gain=model, slc_costs=far_costs)
    )
    (g_near,) = [t.gain for t in near if t.kind is TourItemKind.SLC]
    (g_far,) = [t.gain for t in far if t.kind is TourItemKind.SLC]
    assert g_near == pytest.approx(chain_gain(model, [(1, 100, 1.0)]))
    assert kinds(far)[0] == ("slc", 100)
    assert g_far == pytest.approx(chain_gain(model, [(1, 100, 37.0)]))
    assert g_far < g_near
