"""Request builders shared by the planner tests."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.types import CameraModel, PlanRequest, SlcCandidate, Viewpoint


@pytest.fixture
def camera() -> CameraModel:
    return CameraModel.from_fov(64, 48, 90.0, 60.0, min_range=0.3, max_range=5.0)


def make_request(
    positions,
    gains,
    camera: CameraModel,
    *,
    start=(0.0, 0.0, 1.0),
    yaws=None,
    costs=None,
    slc_positions=(),
    slc_gains=(),
    slc_costs=None,
) -> PlanRequest:
    """A request with Euclidean costs unless ``costs`` is given."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    start = np.asarray(start, dtype=float)
    yaws = np.zeros(len(positions)) if yaws is None else np.asarray(yaws, dtype=float)
    vps = tuple(
        Viewpoint(i, p, float(y), float(g), p + np.array([1.0, 0.0, 0.0]), 10)
        for i, (p, y, g) in enumerate(zip(positions, yaws, gains, strict=True))
    )
    nodes = np.vstack([start, positions])
    if costs is None:
        costs = np.linalg.norm(nodes[:, None] - nodes[None], axis=-1)
    cands = tuple(
        SlcCandidate(100 + j, np.asarray(p, dtype=float), 0.0, (1, 2, 3), float(g))
        for j, (p, g) in enumerate(zip(slc_positions, slc_gains, strict=True))
    )
    if slc_costs is None:
        slc_costs = (
            np.linalg.norm(np.asarray(slc_positions, dtype=float)[:, None] - nodes[None], axis=-1)
            if cands
            else np.zeros((0, 0))
        )
    return PlanRequest(start, 0.0, vps, np.asarray(costs, dtype=float), camera, cands, slc_costs)
