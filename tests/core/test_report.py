"""Report metrics computed from a run's outputs."""

from __future__ import annotations

import numpy as np

from amslam.report import landmark_accuracy
from amslam.types import Landmark, WorldSummary


def _world(positions: dict[str, tuple[str, list[float]]]) -> WorldSummary:
    return WorldSummary(
        name="w",
        bounds_lo=np.zeros(3),
        bounds_hi=np.ones(3) * 10,
        reachable_free_volume=1.0,
        floor_heights=(0.0,),
        reachable_free_volume_per_floor=(1.0,),
        objects_by_class={},
        object_positions={k: np.array(p, float) for k, (_, p) in positions.items()},
        object_classes={k: c for k, (c, _) in positions.items()},
    )


def _lm(i: int, cls: str, p: list[float]) -> Landmark:
    return Landmark(i, cls, np.array(p, float), np.eye(3) * 0.01, 5)


def test_landmark_accuracy_pairs_by_class_and_counts_duplicates_and_spurious() -> None:
    world = _world({"a": ("chair", [0, 0, 0]), "b": ("chair", [0.75, 0, 0]), "c": ("table", [5, 5, 0])})
    lms = [
        _lm(0, "chair", [0.1, 0, 0]),  # chair a, 0.1 m off
        _lm(1, "chair", [0.75, 0.6, 0]),  # chair b, 0.6 m off
        _lm(2, "chair", [0.05, 0.05, 0]),  # a second landmark on chair a
        _lm(3, "table", [0.0, 0.2, 0]),  # a table where there is only a chair
        _lm(4, "table", [5, 5.2, 0]),  # table c
    ]
    acc = landmark_accuracy(lms, world)
    assert acc["objects"] == 3 and acc["matched"] == 3
    assert acc["duplicates"] == 1 and acc["spurious"] == 1
    assert acc["off_by_more_than_0_5_m"] == 1
    # one-to-one: the duplicate at 0.07 m takes chair a, landmark 0 is left as the duplicate
    assert np.isclose(acc["mean_error_m"], (np.hypot(0.05, 0.05) + 0.6 + 0.2) / 3, atol=1e-3)
