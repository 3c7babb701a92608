"""Contract tests for exploration planners: tours made of the request's own stops, reachable ones only.

    from amslam.testing.planner import PlannerContract

    class TestMyPlanner(PlannerContract):
        def make_backend(self):
            return MyPlanner()

The requests are small synthetic ones (viewpoints on a ring around the robot, Euclidean costs),
built by :func:`make_request`; loop-closure candidates are added where a test needs them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.interfaces import Planner
from amslam.testing.contract import CAMERA, BackendContract
from amslam.types import PlanRequest, SlcCandidate, TourItem, TourItemKind, Viewpoint


def make_request(
    positions: np.ndarray,
    gains: np.ndarray,
    *,
    start: tuple[float, float, float] = (0.0, 0.0, 1.2),
    costs: np.ndarray | None = None,
    slc_positions: np.ndarray | None = None,
    slc_gains: np.ndarray | None = None,
) -> PlanRequest:
    """A request over viewpoints at ``positions`` (ids 0..N-1), Euclidean costs unless ``costs`` is given.

    Each viewpoint looks away from the robot at a frontier cluster 1 m beyond it. Loop-closure
    candidates get key-pose ids 100, 101, ... and Euclidean costs to the robot and the viewpoints.
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    start_p = np.asarray(start, dtype=float)
    vps = []
    for i, (p, g) in enumerate(zip(positions, np.asarray(gains, float), strict=True)):
        away = p[:2] - start_p[:2]
        yaw = float(np.arctan2(away[1], away[0])) if np.linalg.norm(away) > 0 else 0.0
        ahead = p + np.array([np.cos(yaw), np.sin(yaw), 0.0])
        vps.append(Viewpoint(i, p.copy(), yaw, float(g), ahead, 20))
    nodes = np.vstack([start_p, positions])
    if costs is None:
        costs = np.linalg.norm(nodes[:, None] - nodes[None], axis=-1)
    cands: tuple[SlcCandidate, ...] = ()
    slc_costs = np.zeros((0, 0))
    if slc_positions is not None and len(slc_positions):
        slc_positions = np.asarray(slc_positions, dtype=float).reshape(-1, 3)
        gains_c = np.ones(len(slc_positions)) if slc_gains is None else np.asarray(slc_gains, float)
        cands = tuple(
            SlcCandidate(100 + j, p.copy(), 0.0, (1, 2, 3), float(g))
            for j, (p, g) in enumerate(zip(slc_positions, gains_c, strict=True))
        )
        slc_costs = np.linalg.norm(slc_positions[:, None] - nodes[None], axis=-1)
    return PlanRequest(start_p, 0.0, tuple(vps), np.asarray(costs, float), CAMERA, cands, slc_costs)


def ring(n: int, radius: float = 3.0, height: float = 1.2) -> np.ndarray:
    """``n`` positions on a horizontal circle around the origin."""
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.full(n, height)], axis=1)


class PlannerContract(BackendContract):
    """Mix-in of planner contract tests; override :meth:`make_backend`."""

    kind = Planner

    def _check_items(self, tour: list[TourItem], request: PlanRequest) -> None:
        by_id = {vp.id: vp for vp in request.viewpoints}
        by_kp = {c.keypose_id: c for c in request.slc_candidates}
        assert isinstance(tour, list)
        seen = set()
        for item in tour:
            assert isinstance(item, TourItem)
            assert item.kind in (TourItemKind.EXPLORE, TourItemKind.SLC)
            assert np.shape(item.position) == (3,) and np.all(np.isfinite(item.position))
            assert -np.pi <= item.yaw <= np.pi
            assert (item.kind, item.ref) not in seen, f"stop {item.kind} {item.ref} visited twice"
            seen.add((item.kind, item.ref))
            if item.kind == TourItemKind.EXPLORE:
                assert item.ref in by_id, f"EXPLORE item refers to unknown viewpoint {item.ref}"
                np.testing.assert_allclose(item.position, by_id[item.ref].position, atol=1e-9)
            else:
                assert item.ref in by_kp, f"SLC item refers to unknown key pose {item.ref}"

    def test_no_viewpoints_no_tour(self, backend: Planner) -> None:
        empty = make_request(np.zeros((0, 3)), np.zeros(0))
        assert backend.plan(empty) == []

    def test_a_worthwhile_reachable_viewpoint_is_visited(self, backend: Planner) -> None:
        request = make_request(np.array([[2.0, 0.0, 1.2]]), np.array([25.0]))
        tour = backend.plan(request)
        self._check_items(tour, request)
        assert [i.ref for i in tour if i.kind == TourItemKind.EXPLORE] == [0]

    def test_tour_stops_come_from_the_request(self, backend: Planner) -> None:
        request = make_request(ring(8), np.linspace(5.0, 40.0, 8))
        tour = backend.plan(request)
        self._check_items(tour, request)
        assert any(i.kind == TourItemKind.EXPLORE for i in tour), "eight reachable viewpoints, empty tour"

    def test_unreachable_viewpoints_are_never_visited(self, backend: Planner) -> None:
        positions = ring(6)
        request = make_request(positions, np.full(6, 30.0))
        costs = request.costs.copy()
        unreachable = [1, 4]  # viewpoint ids; their node is id + 1
        for i in unreachable:
            costs[i + 1, :] = np.inf
            costs[:, i + 1] = np.inf
            costs[i + 1, i + 1] = 0.0
        request = make_request(positions, np.full(6, 30.0), costs=costs)
        tour = backend.plan(request)
        self._check_items(tour, request)
        assert tour, "four reachable viewpoints, empty tour"
        assert not {i.ref for i in tour if i.kind == TourItemKind.EXPLORE} & set(unreachable)
        nowhere = make_request(positions, np.full(6, 30.0), costs=np.where(np.eye(7) > 0, 0.0, np.inf))
        assert [i for i in backend.plan(nowhere) if i.kind == TourItemKind.EXPLORE] == []

    def test_request_is_left_untouched(self, backend: Planner) -> None:
        request = make_request(ring(5), np.full(5, 10.0), slc_positions=np.array([[0.5, 0.5, 1.2]]))
        costs, slc_costs = request.costs.copy(), request.slc_costs.copy()
        positions = [vp.position.copy() for vp in request.viewpoints]
        backend.plan(request)
        np.testing.assert_array_equal(request.costs, costs)
        np.testing.assert_array_equal(request.slc_costs, slc_costs)
        for vp, p in zip(request.viewpoints, positions, strict=True):
            np.testing.assert_array_equal(vp.position, p)

    def test_same_seed_same_tour(self, tmp_path: Path) -> None:
        request = make_request(ring(7, radius=4.0), np.array([3.0, 12.0, 7.0, 30.0, 1.0, 9.0, 15.0]))
        tours = []
        for _ in range(2):
            planner = self.configured(tmp_path, seed=5)
            tours.append([(i.kind, i.ref) for i in planner.plan(request)])
            planner.close()
        assert tours[0] == tours[1]

    def test_loop_closure_stops_only_from_candidates(self, backend: Planner) -> None:
        request = make_request(ring(4), np.full(4, 10.0))
        assert all(i.kind == TourItemKind.EXPLORE for i in backend.plan(request))
        with_slc = make_request(
            ring(4), np.full(4, 10.0), slc_positions=np.array([[1.0, 0.5, 1.2]]), slc_gains=np.array([50.0])
        )
        self._check_items(backend.plan(with_slc), with_slc)

    @pytest.mark.parametrize("n", [1, 2, 12])
    def test_any_number_of_viewpoints(self, backend: Planner, n: int) -> None:
        request = make_request(ring(n, radius=2.5), np.full(n, 8.0))
        tour = backend.plan(request)
        self._check_items(tour, request)
        assert tour
