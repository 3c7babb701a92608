"""Ground truth of a small made-up world for scoring tests: objects by id, class and centre."""

from __future__ import annotations

from collections import Counter

import numpy as np

from amslam.types import WorldSummary


def objects_world(
    objects: dict[str, tuple[str, list[float]]], shapes: dict[str, dict] | None = None
) -> WorldSummary:
    """A one-floor 10 m world holding ``objects`` (id → (class, centre)) with their true ``shapes``."""
    return WorldSummary(
        name="w",
        bounds_lo=np.zeros(3),
        bounds_hi=np.ones(3) * 10,
        reachable_free_volume=1.0,
        floor_heights=(0.0,),
        reachable_free_volume_per_floor=(1.0,),
        objects_by_class=dict(Counter(c for c, _ in objects.values())),
        object_positions={k: np.array(p, float) for k, (_, p) in objects.items()},
        object_classes={k: c for k, (c, _) in objects.items()},
        object_shapes=dict(shapes or {}),
    )
