"""The built-in simulator: platform plugin ``sim`` and detector plugin ``sim``.

See docs/simulator.md (model and parameters) and docs/worlds.md (procedural and mesh worlds).
"""

from __future__ import annotations

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_platform_backends():
    """The simulator platform."""
    return {"sim": Deferred("amslam.plugins.sim.platform:SimPlatform")}


@amslam.hookimpl
def amslam_detector_backends():
    """The simulator's mask-based object detector."""
    return {"sim": Deferred("amslam.plugins.sim.detector:SimDetector")}
