"""Small, fast missions for end-to-end tests."""

from __future__ import annotations

import textwrap
from pathlib import Path

SMALL = """\
name: {name}
seed: {seed}
robot: {{radius: 0.25, max_speed: 1.0, altitude: 1.2}}
limits: {{max_time: {max_time}, max_distance: 400}}
platform:
  plugin: sim
  world: {{size: [10, 8], floors: 1}}
  camera: {{width: 160, height: 120, rate_hz: 5}}
mapping: {mapping}
slam: {{plugin: odometry}}
detector: {{plugin: sim}}
planner: {planner}
"""


def small_mission(
    folder: Path,
    *,
    name: str = "small",
    seed: int = 3,
    max_time: float = 400,
    planner: str = "{plugin: greedy}",
    mapping: str = "{plugin: open3d}",
) -> Path:
    """Write a one-floor 10 × 8 m mission into ``folder`` and return its path."""
    path = Path(folder) / f"{name}.yaml"
    text = SMALL.format(name=name, seed=seed, max_time=max_time, planner=planner, mapping=mapping)
    path.write_text(textwrap.dedent(text))
    return path
