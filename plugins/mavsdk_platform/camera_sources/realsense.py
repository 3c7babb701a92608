"""Intel RealSense depth cameras through ``pyrealsense2`` (optional: imported when opened)."""

from __future__ import annotations

import time

import numpy as np

from amslam.errors import PlatformError
from amslam.plugins.mavsdk_platform.camera_sources.base import CameraSource, CameraSourceParams, RgbdImage
from amslam.types import CameraModel


def _import_pyrealsense2():
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        raise PlatformError(
            "camera.source realsense needs the RealSense SDK's Python binding: "
            "pip install 'amslam[realsense]' (x86-64; on ARM build librealsense with its Python binding), "
            "or set camera.source: none"
        ) from exc
    return rs


class RealSenseSource(CameraSource):
    """Depth aligned to colour at the configured resolution and rate."""

    def __init__(self, params: CameraSourceParams):
        self.params = params
        self.pipeline = None

    def open(self) -> CameraModel:
        rs = _import_pyrealsense2()
        p = self.params
        config = rs.config()
        if p.serial:
            config.enable_device(p.serial)
        fps = int(round(p.rate_hz))
        config.enable_stream(rs.stream.depth, p.width, p.height, rs.format.z16, fps)
        config.enable_stream(rs.stream.color, p.width, p.height, rs.format.rgb8, fps)
        self.pipeline = rs.pipeline()
        try:
            profile = self.pipeline.start(config)
        except RuntimeError as exc:
            self.pipeline = None
            raise PlatformError(f"RealSense camera did not start: {exc}") from exc
        self.depth_scale = profile.get_device().first_depth_sensor().get_depth_scale()
        self.align = rs.align(rs.stream.color)
        intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        K = np.array([[intr.fx, 0.0, intr.ppx], [0.0, intr.fy, intr.ppy], [0.0, 0.0, 1.0]])
        self.model = CameraModel(
            intr.width, intr.height, K, p.T_body_cam(), p.min_range, p.max_range, p.rate_hz, p.depth_noise
        )
        return self.model

    def read(self) -> RgbdImage | None:
        if self.pipeline is None:
            return None
        frames = self.pipeline.poll_for_frames()
        if not frames:
            return None
        frames = self.align.process(frames)
        depth_frame, color_frame = frames.get_depth_frame(), frames.get_color_frame()
        if not depth_frame or not color_frame:
            return None
        depth = np.asanyarray(depth_frame.get_data()).astype(np.float32) * self.depth_scale
        depth[(depth < self.params.min_range) | (depth > self.params.max_range)] = 0.0
        rgb = np.asanyarray(color_frame.get_data()).copy()
        return RgbdImage(time.monotonic(), depth, self.model.K, rgb)

    def close(self) -> None:
        if self.pipeline is not None:
            self.pipeline.stop()
            self.pipeline = None
