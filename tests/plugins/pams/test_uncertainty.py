"""Fitted confidence MLP and variance splines: recover known trends, save and load without pickle."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.plugins.pams.uncertainty import Mlp, UncertaintyModels, cell_variances

from .conftest import true_confidence, true_std


def test_mlp_forward_pass_matches_sklearn():
    from sklearn.neural_network import MLPRegressor

    rng = np.random.default_rng(1)
    X = rng.uniform(-1, 1, (200, 2))
    y = np.sin(2 * X[:, 0]) * X[:, 1]
    m = Mlp.fit(X, y, (8, 8), seed=0)
    # the same fit through sklearn, on the same standardised inputs
    reg = MLPRegressor(
        hidden_layer_sizes=(8, 8),
        activation="tanh",
        solver="lbfgs",
        alpha=0.3,
        max_iter=1000,
        random_state=0,
    )
    reg.fit((X - m.x_mean) / m.x_scale, y)
    np.testing.assert_allclose(m(X), reg.predict((X - m.x_mean) / m.x_scale), atol=1e-9)


def test_cell_variances_are_mean_squared_errors():
    r = np.array([0.2, 0.4, 0.6, 1.5, 1.6])
    e = np.array([0.1, -0.1, 0.2, 1.0, 3.0])
    rc, ac, var, n = cell_variances(r, None, e, 1.0, 0.3, 2)
    np.testing.assert_allclose(rc, [0.5, 1.5])
    np.testing.assert_allclose(var, [(0.01 + 0.01 + 0.04) / 3, (1 + 9) / 2])
    np.testing.assert_array_equal(n, [3, 2])
    assert np.all(ac == 0)


def test_models_recover_the_trends(models):
    car = models["car"]
    assert car.angle_dependent and car.components == ["x", "y", "length", "width"]
    r = np.array([3.0, 6.0, 9.0, 12.0])
    for a in (0.3, np.pi / 4, np.pi / 2):
        conf = car.confidence(r, np.full(4, a))
        np.testing.assert_allclose(conf, true_confidence(r, np.full(4, a)), atol=0.08)
        sd = np.sqrt(car.variances(r, np.full(4, a)))
        np.testing.assert_allclose(sd[:, 0], true_std(r, np.full(4, a)), rtol=0.35)
    # oblique views beat side and end-on ones; near beats far
    sd = lambda rr, aa: float(np.sqrt(car.variances(rr, aa)[0, 0]))  # noqa: E731
    assert sd(5.0, np.pi / 4) < sd(5.0, np.pi / 2) and sd(5.0, np.pi / 4) < sd(5.0, 0.0)
    assert sd(4.0, np.pi / 4) < sd(10.0, np.pi / 4)
    pole = models["pole"]
    assert not pole.angle_dependent and pole.components == ["x", "y"]
    # range only: the angle argument does not matter
    np.testing.assert_allclose(pole.variances(6.0, 0.0), pole.variances(6.0, 2.0))


def test_predictions_clamp_to_the_fitted_domain(models):
    car = models["car"]
    lo, hi = car.range_bounds
    np.testing.assert_allclose(car.variances(hi + 50.0, 1.0), car.variances(hi, 1.0))
    np.testing.assert_allclose(car.confidence(0.0, 1.0), car.confidence(lo, 1.0))


def test_save_and_load_round_trip_without_pickle(models, models_path):
    loaded = UncertaintyModels.load(models_path)
    with np.load(models_path, allow_pickle=False) as f:
        assert all(f[k].dtype != object for k in f.files)
    r, a = np.linspace(2, 14, 9), np.linspace(0, np.pi, 9)
    for name in ("car", "pole"):
        np.testing.assert_allclose(loaded[name].confidence(r, a), models[name].confidence(r, a))
        np.testing.assert_allclose(loaded[name].variances(r, a), models[name].variances(r, a))
        assert loaded[name].components == models[name].components


def test_load_rejects_other_files(tmp_path):
    path = tmp_path / "x.npz"
    np.savez(path, header=np.array('{"format": "something-else"}'))
    with pytest.raises(ValueError, match="not an uncertainty model"):
        UncertaintyModels.load(path)
