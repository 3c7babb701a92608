"""PAMS's path choice walks every order of the free samples: the same choice as the plain loop."""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from amslam.plugins.pams.planner import PamsPlanner, _TargetState, entropy


def _every_order(st: _TargetState, start, threshold: float, horizon: int, cost_weight: float):
    """The paper's rule written plainly (the planner's former loop): each of the P(a, T) orders."""
    left = np.flatnonzero(~st.used).tolist()
    T = min(horizon, len(left))
    if T == 0:
        return [], 0.0
    h0, info0 = entropy(st.cov), np.linalg.inv(st.cov)
    meas = {i: np.linalg.inv(st.sample_covs[i]) for i in left}
    best = None
    for path in itertools.permutations(left, T):
        info, here, length, h, taken = info0, start, 0.0, h0, []
        for i in path:
            info = info + meas[i]
            length += float(np.linalg.norm(st.samples[i] - here))
            here = st.samples[i]
            taken.append(i)
            h = -0.5 * float(np.linalg.slogdet(info)[1])
            if h <= threshold:
                break
        utility = (h0 - h) - cost_weight * length
        if best is None or utility > best[0] + 1e-12:
            best = (utility, taken, h0 - h)
    return best[1], best[2]


def _state(rng, n: int, dim: int = 4) -> _TargetState:
    def spd(scale: float) -> np.ndarray:
        a = rng.normal(size=(dim, dim))
        return scale * (a @ a.T / dim + 0.2 * np.eye(dim))

    used = rng.random(n) < 0.3
    return _TargetState(
        model=None,
        cov=spd(1.0),
        samples=rng.uniform(-5, 5, size=(n, 3)),
        sample_covs=[spd(rng.uniform(0.05, 2.0)) for _ in range(n)],
        used=used,
        attempts=np.zeros(n, dtype=int),
    )


@pytest.mark.parametrize("horizon", [1, 2, 3])
@pytest.mark.parametrize("seed", range(6))
def test_the_same_path_and_gain_as_every_order_one_by_one(horizon, seed) -> None:
    rng = np.random.default_rng(seed)
    st = _state(rng, n=int(rng.integers(1, 12)))
    start = rng.uniform(-5, 5, size=3)
    h0 = entropy(st.cov)
    cases = [(-np.inf, 0.0), (-np.inf, 0.05), (h0 - 0.4, 0.05), (h0 - 1.5, 0.2), (h0 + 1, 0.1)]
    for threshold, weight in cases:
        planner = SimpleNamespace(params=SimpleNamespace(horizon=horizon, cost_weight=weight))
        got = PamsPlanner.best_path(planner, st, start, threshold)
        assert got == _every_order(st, start, threshold, horizon, weight), (threshold, weight)


def test_ties_between_orders_of_one_set_keep_the_first() -> None:
    # four samples on a line, equal covariances: every order of a set has the same information
    st = _state(np.random.default_rng(1), n=4)
    st.samples = np.array([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0], [4.0, 0, 0]])
    st.sample_covs = [np.eye(4)] * 4
    st.used[:] = False
    planner = SimpleNamespace(params=SimpleNamespace(horizon=2, cost_weight=0.0))
    got = PamsPlanner.best_path(planner, st, np.zeros(3), -np.inf)
    assert got == _every_order(st, np.zeros(3), -np.inf, 2, 0.0)
    assert got[0] == [0, 1]  # no cost: every pair ties, the first order wins
