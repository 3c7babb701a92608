"""The built-in simulator: platform plugin ``sim`` and detector plugin ``sim``.

See docs/simulator.md (model and parameters) and docs/worlds.md (procedural and mesh worlds).
"""

from __future__ import annotations

import amslam
from amslam.plugins.sim.detector import SimDetector
from amslam.plugins.sim.platform import SimPlatform


@amslam.hookimpl
def amslam_platform_backends():
    """The simulator platform."""
    return {"sim": SimPlatform}


@amslam.hookimpl
def amslam_detector_backends():
    """The simulator's mask-based object detector."""
    return {"sim": SimDetector}


__all__ = ["SimDetector", "SimPlatform"]
