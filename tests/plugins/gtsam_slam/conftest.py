"""Shared fixtures: random registration instances and a driven synthetic loop."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from amslam.interfaces import RunContext
from amslam.plugins.gtsam_slam import GtsamSlam
from amslam.plugins.gtsam_slam.slc import yaw_matrix
from amslam.plugins.gtsam_slam.synthetic import LoopWorld, camera_mount


@dataclass
class Instance:
    A: np.ndarray
    B: np.ndarray
    ca: np.ndarray
    cb: np.ndarray
    yaw: float
    t: np.ndarray
    truth: set[tuple[int, int]]  # (index in A, index in B)


def make_instance(
    rng: np.random.Generator, n: int, outliers: float = 0.5, sigma: float = 0.2, classes: int = 3
) -> Instance:
    """A (n map points) and B (n observed: inliers = A subset moved by (ψ, t) + noise, rest random).

    ``sigma`` is the RMS 3-D error of an observed point (per axis σ/√3).
    """
    A = rng.uniform([0, 0, 0], [10, 10, 2], (n, 3))
    ca = rng.integers(0, classes, n)
    k = n - int(round(outliers * n))
    ia = rng.choice(n, k, replace=False)
    yaw = float(rng.uniform(-np.pi, np.pi))
    t = rng.uniform(-3, 3, 3)
    b_in = (A[ia] - t) @ yaw_matrix(yaw) + rng.normal(0, sigma / np.sqrt(3), (k, 3))
    b_out = rng.uniform([0, 0, 0], [10, 10, 2], (n - k, 3)) - t
    B = np.vstack([b_in, b_out])
    cb = np.concatenate([ca[ia], rng.integers(0, classes, n - k)])
    perm = rng.permutation(n)
    inv = np.argsort(perm)
    return Instance(A, B[perm], ca, cb[perm], yaw, t, {(int(a), int(inv[i])) for i, a in enumerate(ia)})


def configured(**params: object) -> GtsamSlam:
    slam = GtsamSlam()
    slam.configure(GtsamSlam.Params(**params), RunContext(rng=np.random.default_rng(7), run_dir=Path(".")))
    return slam


def drive_loop(seed: int = 0, slam: GtsamSlam | None = None, **world: float) -> tuple[GtsamSlam, LoopWorld]:
    """Panorama at the start, one drifting loop with detections every metre; back at the start."""
    w = LoopWorld.rectangle(np.random.default_rng(seed), **({"yaw_bias_per_m": 0.006} | world))
    slam = slam or configured()
    Tc = camera_mount()
    slam.add_odometry(w.odometry())
    for T in w.panorama():
        w.move_to(T)
        slam.add_odometry(w.odometry())
        slam.add_detections(w.odometry(), Tc, w.detect())
    for k, T in enumerate(w.loop_path()):
        w.move_to(T)
        slam.add_odometry(w.odometry())
        if k % 5 == 4:
            slam.add_detections(w.odometry(), Tc, w.detect())
    return slam, w


@pytest.fixture(scope="module")
def looped() -> tuple[GtsamSlam, LoopWorld]:
    return drive_loop(0)
