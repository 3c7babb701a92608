"""A small synthetic world for exercising the SLAM backend without the simulator.

Objects stand along a rectangular loop; a robot flies the loop with drifting VIO (a yaw bias and
random walk per metre, like the paper's ~1–1.5 % drift, configurable), detects the objects in
view of a forward camera with noisy centroids, and ends back at its start where it can take a
panorama. Used by the tests and benchmarks of this plugin.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from amslam.geometry import invert, pose_from, yaw_matrix, yaw_of
from amslam.types import R_BODY_CAM, Detection, Odometry

CLASSES = ("chair", "table", "plant")


def camera_mount() -> np.ndarray:
    """``T_body_cam`` of a forward-looking camera at the body origin."""
    T = np.eye(4)
    T[:3, :3] = R_BODY_CAM
    return T


@dataclass
class LoopWorld:
    """Objects along a rectangle and a robot with drifting odometry.

    Attributes:
        objects: N×3 true object centroids.
        classes: class of each object.
        rng: generator for all noise.
        yaw_bias_per_m: systematic VIO yaw drift (rad/m).
        yaw_walk_per_sqrt_m: VIO yaw random walk (rad/√m).
        trans_noise_per_m: VIO translation noise (fraction of each step).
        centroid_sigma: detection centroid noise per axis (m).
        max_range: detection range (m).
        hfov: horizontal field of view (rad).
    """

    objects: np.ndarray
    classes: list[str]
    rng: np.random.Generator
    yaw_bias_per_m: float = 0.004
    yaw_walk_per_sqrt_m: float = 0.002
    trans_noise_per_m: float = 0.01
    centroid_sigma: float = 0.05
    max_range: float = 5.0
    hfov: float = np.radians(87.0)
    T_true: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_vio: np.ndarray = field(default_factory=lambda: np.eye(4))
    stamp: float = 0.0

    @staticmethod
    def rectangle(
        rng: np.random.Generator,
        width: float = 12.0,
        height: float = 8.0,
        spacing: float = 1.6,
        offset: float = 1.6,
        altitude: float = 1.2,
        **kwargs: float,
    ) -> LoopWorld:
        """Objects every ``spacing`` m on both sides of a ``width``×``height`` loop at the origin."""
        pts, cls = [], []
        corners = np.array([[0, 0], [width, 0], [width, height], [0, height], [0, 0]], float)
        for a, b in zip(corners[:-1], corners[1:], strict=True):
            d = b - a
            n = int(np.linalg.norm(d) // spacing)
            normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)
            for i in range(n):
                base = a + d * (i + 0.5) / n
                side = 1.0 if i % 2 == 0 else -1.0
                xy = base + side * offset * normal + rng.normal(0, 0.3, 2)
                pts.append([xy[0], xy[1], rng.uniform(0.3, 1.0)])
                cls.append(CLASSES[int(rng.integers(len(CLASSES)))])
        world = LoopWorld(np.array(pts), cls, rng, **kwargs)
        world.T_true = pose_from(np.array([0.0, 0.0, altitude]), 0.0)
        world.T_vio = world.T_true.copy()
        return world

    def odometry(self) -> Odometry:
        return Odometry(self.stamp, self.T_vio.copy())

    def move_to(self, T_new: np.ndarray, dt: float = 0.1) -> None:
        """Move the true body to ``T_new``; VIO integrates the motion with drift."""
        rel = invert(self.T_true) @ T_new
        d = float(np.linalg.norm(rel[:3, 3]))
        err = np.eye(4)
        dyaw = self.yaw_bias_per_m * d + self.rng.normal(0, self.yaw_walk_per_sqrt_m * np.sqrt(d) + 1e-12)
        err[:3, :3] = yaw_matrix(dyaw)
        err[:3, 3] = self.rng.normal(0, self.trans_noise_per_m * d + 1e-12, 3)
        self.T_vio = self.T_vio @ rel @ err
        self.T_true = T_new
        self.stamp += dt

    def detect(self) -> list[Detection]:
        """Objects in view of the true camera, with noisy camera-frame centroids."""
        T_world_cam = self.T_true @ camera_mount()
        p = (self.objects - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]  # camera frame
        out = []
        for i, q in enumerate(p):
            if q[2] <= 0.3 or np.linalg.norm(q) > self.max_range:
                continue
            if abs(np.arctan2(q[0], q[2])) > self.hfov / 2 or abs(np.arctan2(q[1], q[2])) > np.radians(29):
                continue
            out.append(Detection(self.classes[i], 0.9, q + self.rng.normal(0, self.centroid_sigma, 3)))
        return out

    def loop_path(self, width: float = 12.0, height: float = 8.0, step: float = 0.2) -> Iterator[np.ndarray]:
        """True poses around the loop (counter-clockwise), turning in place at corners."""
        z = self.T_true[2, 3]
        corners = np.array([[0, 0], [width, 0], [width, height], [0, height], [0, 0]], float)
        yaw = yaw_of(self.T_true)
        for a, b in zip(corners[:-1], corners[1:], strict=True):
            target = float(np.arctan2(b[1] - a[1], b[0] - a[0]))
            yield from self._turn(np.array([a[0], a[1], z]), yaw, target)
            yaw = target
            n = int(np.ceil(np.linalg.norm(b - a) / step))
            for i in range(1, n + 1):
                xy = a + (b - a) * i / n
                yield pose_from(np.array([xy[0], xy[1], z]), yaw)

    def panorama(self, step: float = 0.25) -> Iterator[np.ndarray]:
        """True poses yawing a full turn in place."""
        yaw = yaw_of(self.T_true)
        pos = self.T_true[:3, 3].copy()
        for i in range(1, int(np.ceil(2 * np.pi / step)) + 1):
            yield pose_from(pos, yaw + i * step)

    @staticmethod
    def _turn(pos: np.ndarray, yaw: float, target: float, step: float = 0.25) -> Iterator[np.ndarray]:
        d = float(np.angle(np.exp(1j * (target - yaw))))
        n = int(np.ceil(abs(d) / step))
        for i in range(1, n + 1):
            yield pose_from(pos, yaw + d * i / n)


@dataclass
class SlcInstance:
    """A semantic loop-closure problem with its known answer (tests and ``benchmarks/slc.py``)."""

    A: np.ndarray
    B: np.ndarray
    ca: np.ndarray
    cb: np.ndarray
    yaw: float
    t: np.ndarray
    truth: set[tuple[int, int]]  # (index in A, index in B)


def make_instance(
    rng: np.random.Generator, n: int, outliers: float = 0.5, sigma: float = 0.2, classes: int = 3
) -> SlcInstance:
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
    return SlcInstance(A, B[perm], ca, cb[perm], yaw, t, {(int(a), int(inv[i])) for i, a in enumerate(ia)})
