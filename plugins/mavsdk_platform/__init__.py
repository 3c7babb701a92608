"""Real flight through MAVSDK (PX4): platform plugin ``mavsdk``. See docs/flight.md."""

from __future__ import annotations

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_platform_backends():
    """A PX4 vehicle over MAVLink."""
    return {"mavsdk": Deferred("amslam.plugins.mavsdk_platform.platform:MavsdkPlatform")}
