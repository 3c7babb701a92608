"""The tiny simulated mission tests fly: a 12 × 8 m one-floor building, gtsam SLAM, greedy planner."""

from __future__ import annotations

from pathlib import Path

MISSION = """\
name: tiny
seed: SEED
robot: {radius: 0.25, max_speed: 1.0, altitude: 1.2}
limits: {max_time: MAX_TIME, max_distance: 400}
platform:
  plugin: sim
  world: {size: [12, 8], floors: 1}
  camera: {width: 160, height: 120, rate_hz: 5}
mapping: {plugin: open3d}
slam: {plugin: gtsam}
detector: {plugin: sim}
planner: {plugin: greedy}
"""


def tiny_mission_text(max_time: float = 400, seed: int = 5) -> str:
    return MISSION.replace("MAX_TIME", str(max_time)).replace("SEED", str(seed))


def tiny_mission_file(folder: Path, max_time: float = 400, seed: int = 5) -> Path:
    """``folder/tiny.yaml``, the tiny mission flying for ``max_time`` simulated seconds."""
    path = Path(folder) / "tiny.yaml"
    path.write_text(tiny_mission_text(max_time, seed))
    return path
