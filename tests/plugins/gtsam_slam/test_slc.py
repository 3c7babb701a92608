"""Semantic loop closure (paper 1 §V-C): closed form of eqs. (2)–(6) and both solvers."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import minimize

from amslam.plugins.gtsam_slam.slc import (
    SlcParams,
    align_yaw,
    solve_exhaustive,
    solve_scalable,
    yaw_matrix,
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
