"""Camera sources for real flights: RGB-D frames with intrinsics and extrinsics.

A real platform (``mavsdk``) gets its frames from a :class:`CameraSource`; which one is chosen by
the platform's ``camera.source`` parameter:

* ``none`` — no camera (waypoint flights, link tests): ``capture()`` returns None, and the
  nominal model of the parameters describes the camera the map would have;
* ``realsense`` — an Intel RealSense (D435i and kin) through ``pyrealsense2``, an optional extra
  imported only when this source is opened;
* ``replay`` — recorded frames (``.npz`` files with ``depth`` and optionally ``rgb`` and ``K``),
  played back in name order at the camera rate, for bench tests without a camera;
* ``stream`` — frames sent over TCP by another process (``amslam sitl``'s rendered camera), with
  their intrinsics in each frame (:mod:`.stream`).
"""

from __future__ import annotations

from amslam.plugins.mavsdk_platform.camera_sources.base import (
    CameraSource,
    CameraSourceParams,
    RgbdImage,
    make_camera_source,
)

__all__ = ["CameraSource", "CameraSourceParams", "RgbdImage", "make_camera_source"]
