"""VIO drift model: truth plus random walks scaled by the distance travelled.

The estimate is integrated from the true motion increments the way a VIO integrates body-frame
motion: each increment ``dp`` (world frame) enters the odometry frame rotated by the current yaw
error ``δψ``, plus white noise whose variance grows with the length of the increment:

    δψ ← δψ + w_ψ,            w_ψ ~ N(0, σ_ψ² |dp| + σ_ψr² |dψ|)
    p_odom ← p_odom + R_z(δψ) dp + Δe,   e(s) a random walk in distance s: Var e = diag(σ_xy², σ_xy², σ_z²) s
    ψ_odom = ψ_true + δψ,     roll and pitch exact

The additive walk ``e`` is drawn at nodes ``smoothing_distance`` apart and interpolated linearly
between them, so it has exactly the random walk's variance at the nodes but no per-step jitter
(a real VIO is locally smooth; jitter would smear the local map).

So position and yaw errors are random walks in distance (σ in m/√m and rad/√m), and the yaw
error also bends the path (the error that dominates long missions). The defaults are set from
Table I of paper 1 (errors of 0.6–1.4 % of a 180–500 m trajectory, yaw 3–13°): on a 200 m closed
loop the expected position error is about 1–1.5 % of the distance (see ``drift_covariance``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import Field

from amslam.geometry import wrap_angle
from amslam.interfaces import BackendParams


class VioParams(BackendParams):
    """Drift of the simulated visual-inertial odometry."""

    rate_hz: float = Field(30.0, gt=0.0, le=1000.0, description="rate at which odometry is published")
    sigma_xy: float = Field(
        0.05, ge=0.0, le=10.0, description="horizontal position random walk, m/√m travelled"
    )
    sigma_z: float = Field(
        0.012,
        ge=0.0,
        le=10.0,
        description="vertical position random walk, m/√m travelled (gravity + barometer aided)",
    )
    sigma_yaw: float = Field(0.004, ge=0.0, le=10.0, description="yaw random walk, rad/√m travelled")
    sigma_yaw_rotation: float = Field(0.003, ge=0.0, le=10.0, description="yaw random walk, rad/√rad turned")
    smoothing_distance: float = Field(
        1.0,
        ge=0.01,
        le=1000.0,
        description="the position random walk is drawn at nodes this far apart (m) and interpolated"
        " linearly in between, so the estimate drifts smoothly instead of jittering every step",
    )


@dataclass
class VioState:
    """The odometry estimate and its error state."""

    position: np.ndarray  # odometry-frame position of the body
    yaw: float  # odometry-frame yaw
    yaw_error: float = 0.0  # δψ = ψ_odom − ψ_true
    distance: float = 0.0  # true distance travelled
    #: additive position error: a random walk in distance sampled at nodes, linear in between
    error: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _node_gap: np.ndarray | None = None  # error change to reach the next node
    _to_node: float = 0.0  # distance left to the next node

    def step(
        self,
        dp_true: np.ndarray,
        dyaw_true: float,
        yaw_true_after: float,
        p: VioParams,
        rng: np.random.Generator,
    ) -> None:
        """Integrate one true motion increment (world frame) into the estimate."""
        d = float(np.linalg.norm(dp_true))
        c, s = np.cos(self.yaw_error), np.sin(self.yaw_error)
        rotated = np.array([c * dp_true[0] - s * dp_true[1], s * dp_true[0] + c * dp_true[1], dp_true[2]])
        # additive error: walk linearly towards the next node of the random walk
        sig = np.array([p.sigma_xy, p.sigma_xy, p.sigma_z])
        ell = p.smoothing_distance
        before = self.error.copy()
        left = d
        while left > 0.0:
            if self._node_gap is None or self._to_node <= 1e-12:
                self._node_gap = sig * np.sqrt(ell) * rng.standard_normal(3)
                self._to_node = ell
            step = min(left, self._to_node)
            self.error = self.error + self._node_gap * (step / ell)
            self._to_node -= step
            left -= step
        self.position = self.position + rotated + (self.error - before)
        w = rng.standard_normal()  # drawn every step, so a zero sigma does not shift the stream
        self.yaw_error += np.sqrt(p.sigma_yaw**2 * d + p.sigma_yaw_rotation**2 * abs(dyaw_true)) * w
        self.yaw = wrap_angle(yaw_true_after + self.yaw_error)
        self.distance += d


def drift_covariance(positions: np.ndarray, yaws: np.ndarray | None, p: VioParams) -> np.ndarray:
    """Linearised 3×3 covariance of the final position error after flying ``positions``.

    ``positions`` (N×3) is the true path (densely sampled), ``yaws`` (N,) the true heading (for
    the rotation-driven yaw noise; None ignores it). A yaw error increment ``w_j`` picked up at
    ``p_j`` displaces the end point by ``J (p_end − p_j) w_j`` with ``J`` the 90° rotation, so

        Σ = Σ_j (σ_ψ² d_j + σ_ψr² |Δψ_j|) J r_j r_jᵀ Jᵀ + diag(σ_xy², σ_xy², σ_z²) L,

    with ``r_j = p_end − p_j`` (horizontal part) and ``L`` the path length. Exact to first order
    in the yaw error.
    """
    P = np.asarray(positions, dtype=float)
    dp = np.diff(P, axis=0)
    d = np.linalg.norm(dp, axis=1)
    var_yaw = p.sigma_yaw**2 * d
    if yaws is not None:
        var_yaw = var_yaw + p.sigma_yaw_rotation**2 * np.abs(wrap_angle(np.diff(np.asarray(yaws, float))))
    r = P[-1] - P[1:]  # the yaw error picked up on step j acts on the rest of the path
    Jr = np.stack([-r[:, 1], r[:, 0], np.zeros(len(r))], axis=1)
    cov = (Jr * var_yaw[:, None]).T @ Jr
    L = float(d.sum())
    cov += np.diag([p.sigma_xy**2, p.sigma_xy**2, p.sigma_z**2]) * L
    return cov
