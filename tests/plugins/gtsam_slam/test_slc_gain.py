"""Eq. (10) for chains of loop closures (Algorithm 1, line 6): the planner's model against gtsam."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from amslam.geometry import wrap_angle
from amslam.lib.slc_gain import between_jacobians, chain_gain

from .conftest import configured, drive_loop


@pytest.fixture(scope="module", params=["all", "poses"])
def looped_graph(request):
    slam, _ = drive_loop(3, slam=configured(active={"ig_variables": request.param}))
    graph, values = slam.graph()
    over = [int(k) for k in values.keys()] if request.param == "all" else [X(k.id) for k in slam.keyposes()]  # noqa: SIM118
    return slam, graph, values, over


def chain_brute_force(slam, graph, values, over, legs) -> float:
    """Add every leg's virtual factor to a copy of the graph and recompute the marginals."""
    with_chain = gtsam.NonlinearFactorGraph(graph)
    noise = slam._graph.noise
    for a, b, d in legs:
        Ta, Tb = values.atPose3(X(a)), values.atPose3(X(b))
        dyaw = wrap_angle(Tb.rotation().yaw() - Ta.rotation().yaw())
        with_chain.add(gtsam.BetweenFactorPose3(X(a), X(b), Ta.between(Tb), noise.odometry(d, dyaw)))
    return _trace(graph, values, over) - _trace(with_chain, values, over)


def _trace(graph, values, over) -> float:
    marginals = gtsam.Marginals(graph, values)
    return float(sum(np.trace(marginals.marginalCovariance(k)) for k in over))


def test_between_jacobians_are_gtsams():
    rng = np.random.default_rng(1)
    for _ in range(5):
        Ta = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 5)
        Tb = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 5)
        values = gtsam.Values()
        values.insert(X(0), Ta)
        values.insert(X(1), Tb)
        factor = gtsam.BetweenFactorPose3(X(0), X(1), Ta.between(Tb), gtsam.noiseModel.Unit.Create(6))
        A, _ = factor.linearize(values).jacobian()
        Ha, Hb = between_jacobians(Ta.matrix(), Tb.matrix())
        np.testing.assert_allclose(np.hstack([Ha, Hb]), A, atol=1e-9)


def test_one_leg_is_the_backends_eq10(looped_graph):
    slam, graph, values, over = looped_graph
    ids, dists = [0, 7, 20, 45], [30.0, 25.0, 12.0, 6.0]
    model = slam.slc_gain_model(ids)
    assert model.keypose_ids == (slam.keyposes()[-1].id, *ids)
    current = model.keypose_ids[0]
    np.testing.assert_allclose(
        [chain_gain(model, [(current, i, d)]) for i, d in zip(ids, dists, strict=True)],
        slam.information_gain(ids, dists),
        rtol=1e-9,
    )


def test_a_chain_of_two_closures_is_gtsams(looped_graph):
    slam, graph, values, over = looped_graph
    model = slam.slc_gain_model([7, 45])
    current = model.keypose_ids[0]
    legs = [(current, 45, 6.0), (45, 7, 14.0)]
    assert chain_brute_force(slam, graph, values, over, legs[:1]) == pytest.approx(
        slam.information_gain([45], [6.0])[0], rel=1e-6
    )
    expected = chain_brute_force(slam, graph, values, over, legs)
    assert chain_gain(model, legs) == pytest.approx(expected, rel=1e-6)


def test_a_second_closure_after_the_first_is_worth_less_than_alone(looped_graph):
    slam, *_ = looped_graph
    model = slam.slc_gain_model([0, 7])
    current = model.keypose_ids[0]
    first = chain_gain(model, [(current, 0, 10.0)])
    alone = chain_gain(model, [(current, 7, 12.0)])
    after_first = chain_gain(model, [(current, 0, 10.0), (0, 7, 2.0)]) - first
    assert 0.0 <= after_first < alone
    assert chain_gain(model, []) == 0.0


def test_the_model_holds_each_key_pose_once(looped_graph):
    slam, *_ = looped_graph
    current = slam.keyposes()[-1].id
    model = slam.slc_gain_model([7, 7, current, 45])
    assert model.keypose_ids == (current, 7, 45)
    assert model.covariance.shape == model.gram.shape == (18, 18)
