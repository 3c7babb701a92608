"""Semantic loop closure (paper 1 §V-C): closed form of eqs. (2)–(6) and both solvers."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import minimize

from amslam.geometry import yaw_matrix
from amslam.plugins.gtsam_slam.slc import (
    SlcParams,
    SlcPrior,
    align_yaw,
    solve_exhaustive,
    solve_scalable,
)

from .conftest import make_instance


def residual_eq2(pa: np.ndarray, pb: np.ndarray, psi: float, t: np.ndarray) -> float:
    """Eq. (2) evaluated literally: mean ‖R(ψ)ᵀ(p_A − t) − p_B‖²."""
    return float(np.mean(np.sum(((pa - t) @ yaw_matrix(psi) - pb) ** 2, axis=1)))


@pytest.mark.parametrize("seed", range(5))
def test_closed_form_matches_numerical_minimisation(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = int(rng.integers(3, 9))
    pa = rng.uniform(-5, 5, (k, 3))
    pb = (pa - rng.uniform(-2, 2, 3)) @ yaw_matrix(rng.uniform(-np.pi, np.pi)) + rng.normal(0, 0.3, (k, 3))
    psi, t, res = align_yaw(pa, pb)
    assert res == pytest.approx(residual_eq2(pa, pb, psi, t), rel=1e-9, abs=1e-12)
    # Brute force: multi-start Nelder–Mead over (ψ, t) of eq. (2).
    best = min(
        (
            minimize(
                lambda x: residual_eq2(pa, pb, x[0], x[1:]),
                np.r_[psi0, pa.mean(0) - yaw_matrix(psi0) @ pb.mean(0)],
                method="Nelder-Mead",
                options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 20000},
            )
            for psi0 in np.linspace(-np.pi, np.pi, 8, endpoint=False)
        ),
        key=lambda r: r.fun,
    )
    assert res <= best.fun + 1e-9
    assert res == pytest.approx(best.fun, rel=1e-6, abs=1e-9)


def test_eq4_trace_and_eq5_maximum() -> None:
    rng = np.random.default_rng(3)
    da, db = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    M = db.T @ da  # Σ Δp_B Δp_Aᵀ
    for psi in np.linspace(-np.pi, np.pi, 13):
        eq4 = np.cos(psi) * (M[0, 0] + M[1, 1]) + np.sin(psi) * (M[0, 1] - M[1, 0]) + M[2, 2]
        assert np.trace(yaw_matrix(psi) @ M) == pytest.approx(eq4)
    psi_star = np.arctan2(M[0, 1] - M[1, 0], M[0, 0] + M[1, 1])  # eq. (6)
    eq5 = np.hypot(M[0, 0] + M[1, 1], M[0, 1] - M[1, 0]) + M[2, 2]
    grid = max(np.trace(yaw_matrix(p) @ M) for p in np.linspace(-np.pi, np.pi, 20001))
    assert np.trace(yaw_matrix(psi_star) @ M) == pytest.approx(eq5)
    assert eq5 >= grid - 1e-9


def test_exhaustive_recovers_noise_free_transform() -> None:
    rng = np.random.default_rng(0)
    A = rng.uniform(0, 8, (6, 3))
    psi, t = 1.1, np.array([0.5, -2.0, 0.3])
    B = (A[[4, 0, 2, 5]] - t) @ yaw_matrix(psi)
    sol = solve_exhaustive(A, B)
    assert sol.accepted, sol.reason
    assert sorted(map(tuple, sol.pairs.tolist())) == [(0, 1), (2, 2), (4, 0), (5, 3)]
    assert sol.yaw == pytest.approx(psi)
    np.testing.assert_allclose(sol.translation, t, atol=1e-9)
    assert sol.residual == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("seed", range(12))
def test_scalable_gives_the_exhaustive_answer(seed: int) -> None:
    inst = make_instance(np.random.default_rng(seed), n=6 + seed % 3, outliers=0.3)
    ex = solve_exhaustive(inst.A, inst.B, inst.ca, inst.cb)
    sc = solve_scalable(inst.A, inst.B, inst.ca, inst.cb)
    assert ex.accepted == sc.accepted, (ex.reason, sc.reason)
    assert {tuple(p) for p in ex.pairs.tolist()} == {tuple(p) for p in sc.pairs.tolist()}
    if ex.accepted:
        assert sc.yaw == pytest.approx(ex.yaw, abs=1e-9)
        assert sc.residual == pytest.approx(ex.residual, rel=1e-9)


@pytest.mark.parametrize("n", [20, 50])
def test_scalable_with_noise_and_half_outliers(n: int) -> None:
    for seed in range(5):
        inst = make_instance(np.random.default_rng(100 + seed), n=n, outliers=0.5, sigma=0.2, classes=1)
        sol = solve_scalable(inst.A, inst.B, inst.ca, inst.cb, rng=np.random.default_rng(seed))
        assert sol.accepted, sol.reason
        found = {tuple(p) for p in sol.pairs.tolist()}
        assert len(found & inst.truth) >= 0.9 * len(inst.truth)
        # A random point can land within the gate of an unmatched map point: geometrically a
        # valid pair no solver can refuse. It must stay rare.
        assert len(found - inst.truth) <= 0.2 * len(inst.truth)
        assert abs(np.angle(np.exp(1j * (sol.yaw - inst.yaw)))) < 0.03
        assert np.linalg.norm(sol.translation - inst.t) < 0.3


def chair_grid(rows: int, cols: int, spacing: float = 1.0) -> np.ndarray:
    return np.array([[i * spacing, j * spacing, 0.5] for i, j in itertools.product(range(rows), range(cols))])


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_symmetric_grid_is_rejected_as_ambiguous(solver) -> None:  # noqa: ANN001
    A = chair_grid(3, 3)  # a classroom: 3×3 identical chairs
    rng = np.random.default_rng(1)
    B = (A[[0, 1, 3, 4]] - np.array([2.0, 1.0, 0.0])) @ yaw_matrix(0.3) + rng.normal(0, 0.02, (4, 3))
    sol = solver(A, B)
    assert not sol.accepted
    assert "ambiguous" in sol.reason


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_classes_break_the_symmetry(solver) -> None:  # noqa: ANN001
    A = chair_grid(2, 3)
    labels = np.array(["chair"] * 6, dtype=object)
    labels[[0, 3]] = "table"  # two tables at one end make the layout unique
    # Seeing the whole group: the 180° turn or a shift matches at most 2 of 6, below the 75 % rule.
    B = (A - np.array([2.0, 1.0, 0.0])) @ yaw_matrix(0.3)
    sol = solver(A, B, labels, labels)
    assert sol.accepted, sol.reason
    assert sol.matched == 6
    assert sol.yaw == pytest.approx(0.3, abs=1e-6)


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_two_landmarks_are_not_enough(solver) -> None:  # noqa: ANN001
    A = np.array([[0.0, 0, 0], [3, 1, 0], [6, -2, 1]])
    sol = solver(A, A[:2])
    assert not sol.accepted


def test_tolerance_rejects_a_bad_fit() -> None:
    A = np.array([[0.0, 0, 0], [4, 0, 0], [0, 5, 0]])
    B = A + np.array([[0.3, 0, 0], [-0.3, 0, 0], [0, 0.3, 0.2]])  # no rigid motion explains it
    assert not solve_exhaustive(A, B, params=SlcParams(tolerance=0.2)).accepted
    assert solve_exhaustive(A, B, params=SlcParams(tolerance=0.4)).accepted


# ------------------------------------------------------------------ the prior (drift bound)


def classroom(rows: int = 3, cols: int = 3) -> np.ndarray:
    """Rows of identical chairs at the simulator's classroom pitch (0.9 m × 0.75 m)."""
    return np.array([[i * 0.9, j * 0.75, 0.45] for i, j in itertools.product(range(rows), range(cols))])


def seen_two_rows() -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """A 3×3 classroom in the map; the robot, at (-2, 0.8) facing +x, sees its first two rows.

    Shifting the observation by one row (0.9 m) matches the last two rows just as well.
    """
    A = classroom()
    yaw, t = 0.1, np.array([-2.0, 0.8, 1.0])
    rng = np.random.default_rng(4)
    B = (A[:6] - t) @ yaw_matrix(yaw) + rng.normal(0, 0.03, (6, 3))
    return A, B, yaw, t


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_row_shift_is_ambiguous_without_prior(solver) -> None:  # noqa: ANN001
    A, B, _, _ = seen_two_rows()
    sol = solver(A, B)
    assert not sol.accepted
    assert sol.reason.startswith("ambiguous")


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_drift_bound_disambiguates_the_row_shift(solver) -> None:  # noqa: ANN001
    A, B, yaw, t = seen_two_rows()
    # The SLAM estimate is 0.25 m and 0.05 rad off; the shifted rows would imply ~0.9 m.
    prior = SlcPrior(yaw - 0.05, t + np.array([0.15, -0.2, 0.0]), max_translation=0.5, max_yaw=0.15)
    sol = solver(A, B, prior=prior)
    assert sol.accepted, sol.reason
    assert sorted(map(tuple, sol.pairs.tolist())) == [(i, i) for i in range(6)]
    assert sol.yaw == pytest.approx(yaw, abs=0.02)
    np.testing.assert_allclose(sol.translation, t, atol=0.05)


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_rival_within_the_drift_bound_is_still_ambiguous(solver) -> None:  # noqa: ANN001
    A, B, yaw, t = seen_two_rows()
    prior = SlcPrior(yaw - 0.05, t + np.array([0.15, -0.2, 0.0]), max_translation=1.5, max_yaw=0.15)
    sol = solver(A, B, prior=prior)
    assert not sol.accepted
    assert sol.reason.startswith("ambiguous")


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_per_landmark_bounds_take_the_freshest_matched_landmark(solver) -> None:  # noqa: ANN001
    A, B, yaw, t = seen_two_rows()
    prior_t = t + np.array([0.15, -0.2, 0.0])
    # Only the last row is stale (loose bound): the shift also matches the fresh middle row, so
    # its own landmarks rule it out.
    loose = np.where(np.arange(len(A)) >= 6, 3.0, 0.5)
    sol = solver(A, B, prior=SlcPrior(yaw - 0.05, prior_t, loose, np.full(len(A), 0.15)))
    assert sol.accepted, sol.reason
    assert sorted(map(tuple, sol.pairs.tolist())) == [(i, i) for i in range(6)]
    # Every landmark stale: the shift is within the bound again.
    sol = solver(A, B, prior=SlcPrior(yaw - 0.05, prior_t, np.full(len(A), 3.0), 0.15))
    assert sol.reason.startswith("ambiguous")


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_under_a_prior_another_association_nearby_is_a_rival(solver) -> None:  # noqa: ANN001
    # Tiered seats on an arc, 0.18 rad apart seen from its centre (closer than distinct_yaw), each
    # tier 0.25 m higher (so the arc read backwards does not fit), five of six seen.
    ang = 0.55 / 3.0 * np.arange(6)
    chairs = np.column_stack([3.0 * np.cos(ang), 3.0 * np.sin(ang), 0.45 + 0.25 * np.arange(6)])
    A = np.vstack([chairs, [[1.0, -6.0, 0.8]]])
    labels = ["chair"] * 6 + ["shelf"]
    yaw, t = 0.2, np.array([0.0, 0.0, 1.0])
    B = (A[:5] - t) @ yaw_matrix(yaw)
    # Within a 0.3 rad bound only the turn by one seat remains: its transform is within
    # distinct_yaw of the truth, but it is another association, so still a rival.
    prior = SlcPrior(yaw + 0.05, t + 0.1, max_translation=0.5, max_yaw=0.3)
    sol = solver(A, B, labels, labels[:5], prior=prior)
    assert sol.reason == "ambiguous: another alignment matches 5 of 5 landmarks"
    # A tight bound excludes it and the partly shifted associations (RMS 0.24 m) as well.
    sol = solver(A, B, labels, labels[:5], prior=SlcPrior(yaw + 0.02, t + 0.02, 0.15, 0.1))
    assert sol.accepted, sol.reason
    assert sorted(map(tuple, sol.pairs.tolist())) == [(i, i) for i in range(5)]


@pytest.mark.parametrize("solver", [solve_exhaustive, solve_scalable])
def test_solution_outside_the_bound_is_refused(solver) -> None:  # noqa: ANN001
    A, B, yaw, t = seen_two_rows()
    far = SlcPrior(yaw, t + np.array([3.0, 0.0, 0.0]), max_translation=0.5, max_yaw=0.15)
    sol = solver(A, B, prior=far)
    assert not sol.accepted
    assert "within the drift bound" in sol.reason


@pytest.mark.parametrize("seed", range(12))
def test_prior_never_changes_a_unique_answer(seed: int) -> None:
    inst = make_instance(np.random.default_rng(seed), n=6 + seed % 3, outliers=0.3)
    rng = np.random.default_rng(1000 + seed)
    prior = SlcPrior(
        inst.yaw + rng.uniform(-0.1, 0.1),
        inst.t + rng.uniform(-0.2, 0.2, 3),
        max_translation=0.8,
        max_yaw=0.25,
    )
    ex = solve_exhaustive(inst.A, inst.B, inst.ca, inst.cb)
    answers = [
        solve_exhaustive(inst.A, inst.B, inst.ca, inst.cb, prior=prior),
        solve_scalable(inst.A, inst.B, inst.ca, inst.cb, prior=prior),
    ]
    for sol in answers:
        if ex.accepted:  # the unique answer, found with or without the prior
            assert sol.accepted, sol.reason
            assert {tuple(p) for p in sol.pairs.tolist()} == {tuple(p) for p in ex.pairs.tolist()}
            assert sol.yaw == pytest.approx(ex.yaw, abs=1e-9)
            assert sol.residual == pytest.approx(ex.residual, rel=1e-9)
    # With a prior, the two solvers still agree.
    assert answers[0].accepted == answers[1].accepted, (answers[0].reason, answers[1].reason)
    assert {tuple(p) for p in answers[0].pairs.tolist()} == {tuple(p) for p in answers[1].pairs.tolist()}


def test_prior_bounds_are_checked() -> None:
    with pytest.raises(ValueError):
        SlcPrior(0.0, np.zeros(3), -1.0, 0.1)
    pr = SlcPrior(0.0, np.zeros(3), np.array([0.5, 2.0]), 0.1)
    # A transform 1 m away is admissible only for associations using map point 1 alone.
    assert not pr.admits(0.0, np.array([1.0, 0, 0]), np.array([0, 1]))[0]
    assert pr.admits(0.0, np.array([1.0, 0, 0]), np.array([1, 1]))[0]
    assert not pr.admits(0.2, np.zeros(3), np.array([1]))[0]
