"""Synthetic characterisation samples with known trends, and models fitted to them."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.apps.characterisation import Samples
from amslam.plugins.pams.uncertainty import COMPONENTS, UncertaintyModels, fit_models


def true_confidence(r: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Confident within ~10 m, less so end-on (θ = 0 or π)."""
    return 0.95 / (1.0 + np.exp((r - 10.0) / 1.5)) * (1.0 - 0.4 * np.cos(a) ** 2)


def true_std(r: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Grows with range; smallest at oblique views (45°, 135°), as paper 2 Fig. 6 / 7."""
    return (0.02 + 0.004 * r**2) * (1.0 + 0.8 * np.cos(2 * a) ** 2)


def synthetic_samples(n: int = 3000, seed: int = 0) -> Samples:
    rng = np.random.default_rng(seed)
    parts = []
    for name, kind in (("car", "cuboid"), ("pole", "cylinder")):
        r = rng.uniform(2.0, 14.0, n)
        a = rng.uniform(0.0, np.pi, n) if kind == "cuboid" else np.zeros(n)
        conf = np.clip(true_confidence(r, a) + rng.normal(0, 0.03, n), 0, 1)
        sd = true_std(r, a)
        err = rng.normal(0.0, 1.0, (n, len(COMPONENTS))) * sd[:, None]
        if kind == "cylinder":
            err[:, 2:] = np.nan
        parts.append(Samples(np.array([name] * n), r, a, np.ones(n, bool), conf, err, {name: kind}))
    return Samples.concatenate(parts)


@pytest.fixture(scope="session")
def samples() -> Samples:
    return synthetic_samples()


@pytest.fixture(scope="session")
def models(samples) -> UncertaintyModels:
    return fit_models(samples, seed=0)


@pytest.fixture(scope="session")
def models_path(models, tmp_path_factory):
    path = tmp_path_factory.mktemp("pams") / "models.npz"
    models.save(path)
    return path
