"""Real flight through MAVSDK (PX4): platform plugin ``mavsdk``. See docs/flight.md."""

from __future__ import annotations

import amslam
from amslam.plugins.mavsdk_platform.platform import GeofenceParams, MavsdkPlatform, PreflightCheck


@amslam.hookimpl
def amslam_platform_backends():
    """A PX4 vehicle over MAVLink."""
    return {"mavsdk": MavsdkPlatform}


__all__ = ["GeofenceParams", "MavsdkPlatform", "PreflightCheck"]
