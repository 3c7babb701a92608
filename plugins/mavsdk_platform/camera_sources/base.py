"""The camera source interface and its parameters."""

from __future__ import annotations

import abc
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, model_validator

from amslam.errors import PlatformError
from amslam.interfaces import FieldError, mission_file_path
from amslam.types import CameraModel


@dataclass(frozen=True)
class RgbdImage:
    """One RGB-D capture from a source.

    Attributes:
        stamp: arrival time on the host, ``time.monotonic()`` seconds (the platform maps it to
            its clock and picks the odometry pose nearest in time).
        depth: H×W float32 depth along the optical axis in metres, 0 where there is no return.
        K: 3×3 intrinsics of ``depth`` (and of ``rgb``, which is aligned to it).
        rgb: H×W×3 uint8, if the source has colour.
        instance, class_id: H×W int32 instance and class masks, from a rendering sender only
            (``stream`` from ``amslam sitl``: what the simulator's detector reads).
        class_names: names of the class ids, index 0 unused.
    """

    stamp: float
    depth: np.ndarray
    K: np.ndarray
    rgb: np.ndarray | None = None
    instance: np.ndarray | None = None
    class_id: np.ndarray | None = None
    class_names: tuple[str, ...] = ()


#: an offset on the vehicle's body, m
_Mount = Annotated[float, Field(ge=-10, le=10)]


class CameraSourceParams(BaseModel):
    """Which camera a real platform reads, its nominal model and where it is mounted."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    source: Literal["none", "realsense", "replay", "stream"] = Field(
        "none",
        description="none (no frames), realsense (pyrealsense2), replay (a folder of .npz frames),"
        " stream (frames sent over TCP from host:port, e.g. by amslam sitl)",
    )
    width: int = Field(640, gt=0, le=4096, description="image width, px")
    height: int = Field(480, gt=0, le=4096, description="image height, px")
    hfov_deg: float = Field(87.0, gt=0, lt=180, description="nominal horizontal field of view (D435: 87°)")
    vfov_deg: float = Field(58.0, gt=0, lt=180, description="nominal vertical field of view (D435: 58°)")
    rate_hz: float = Field(15.0, gt=0, le=1000, description="frame rate")
    min_range: float = Field(0.3, ge=0, le=100, description="closest valid depth, m")
    max_range: float = Field(5.0, gt=0, le=100, description="farthest depth used, m")
    depth_noise: float = Field(
        0.005,
        ge=0,
        le=1,
        description="σ of a depth reading = depth_noise·z², m (a D435's is of this order; measure "
        "yours on a flat wall at a few ranges; 0: not modelled). Box fits take their extents past it",
    )
    mount_xyz: tuple[_Mount, _Mount, _Mount] = Field(
        (0.1, 0.0, 0.0), description="camera position in the body frame (FLU), m (within 10 m)"
    )
    mount_pitch_deg: float = Field(0.0, ge=-90, le=90, description="downward tilt of the camera, degrees")
    serial: str | None = Field(None, description="realsense: the device serial number (default: the first)")
    folder: str | None = Field(None, description="replay: folder of .npz frames (relative to the mission)")
    host: str = Field("127.0.0.1", min_length=1, description="stream: the sender's host")
    port: int = Field(5600, ge=1, le=65535, description="stream: the sender's TCP port")
    stream_timeout: float = Field(
        15.0, gt=0, le=3600, description="stream: wait this long for the sender and its first frame, s"
    )

    @model_validator(mode="after")
    def _replay_folder(self, info: ValidationInfo) -> CameraSourceParams:
        # the frames are read when the vehicle is already connected: a missing folder is named by
        # `amslam validate` and the pre-flight check instead
        if self.source != "replay":
            return self
        if not self.folder:
            raise FieldError("folder", "camera.source replay needs camera.folder: a folder of .npz frames")
        path = mission_file_path(self.folder, info)
        if not path.is_absolute() and "mission_dir" not in (info.context or {}):
            return self  # no mission folder to resolve against: checked when the source opens
        if not path.is_dir():
            what = "not a folder" if path.exists() else "no such folder"
            raise FieldError("folder", f"{what}: {path}")
        try:
            has_frames = any(path.glob("*.npz"))
        except OSError as exc:
            raise FieldError("folder", f"cannot read {path}: {exc.strerror or exc}") from None
        if not has_frames:
            raise FieldError("folder", f"no .npz frames in {path}")
        return self

    def T_body_cam(self) -> np.ndarray:
        """Pose of the optical frame in the body: forward-looking, tilted down by the pitch."""
        return CameraModel.forward_mount(self.mount_pitch_deg, self.mount_xyz)

    def nominal_model(self) -> CameraModel:
        """The camera model from the parameters (a source may refine K when it opens)."""
        return CameraModel.from_fov(
            self.width,
            self.height,
            self.hfov_deg,
            self.vfov_deg,
            min_range=self.min_range,
            max_range=self.max_range,
            rate_hz=self.rate_hz,
            T_body_cam=self.T_body_cam(),
            depth_noise=self.depth_noise,
        )


class CameraSource(abc.ABC):
    """A camera that delivers RGB-D frames; opened by the platform in ``start()``.

    Sources never block the control loop: :meth:`read` returns the newest frame that arrived
    since the last call, or None.
    """

    @abc.abstractmethod
    def open(self) -> CameraModel:
        """Start streaming; return the camera model (intrinsics from the device, extrinsics)."""

    @abc.abstractmethod
    def read(self) -> RgbdImage | None:
        """The newest frame since the last call, or None (never waits)."""

    def close(self) -> None:  # noqa: B027 — nothing to release by default
        """Stop streaming; safe to call twice."""


class ReplaySource(CameraSource):
    """Frames from ``.npz`` files (``depth`` in metres; optional ``rgb``, ``K``), in name order."""

    def __init__(self, params: CameraSourceParams, base: Path):
        if not params.folder:
            raise PlatformError("camera.source replay needs camera.folder: a folder of .npz frames")
        self.params = params
        self.folder = (base / params.folder).resolve()
        self.files: list[Path] = []
        self.index = 0
        self.next_time = 0.0

    def open(self) -> CameraModel:
        self.files = sorted(self.folder.glob("*.npz"))
        if not self.files:
            raise PlatformError(f"camera.source replay: no .npz frames in {self.folder}")
        self.model = self.params.nominal_model()
        with np.load(self.files[0]) as first:
            depth = first["depth"]
            K = first.get("K", self.model.K)
        self.model = CameraModel(
            depth.shape[1], depth.shape[0], np.asarray(K, float), self.model.T_body_cam,
            self.model.min_range, self.model.max_range, self.model.rate_hz, self.model.depth_noise,
        )  # fmt: skip
        self.next_time = time.monotonic()
        return self.model

    def read(self) -> RgbdImage | None:
        now = time.monotonic()
        if self.index >= len(self.files) or now < self.next_time:
            return None
        self.next_time = now + 1.0 / self.params.rate_hz
        with np.load(self.files[self.index]) as data:
            depth = np.asarray(data["depth"], np.float32)
            rgb = np.asarray(data["rgb"], np.uint8) if "rgb" in data else None
        self.index += 1
        return RgbdImage(now, depth, self.model.K, rgb)


def make_camera_source(params: CameraSourceParams, base: Path) -> CameraSource | None:
    """The source the parameters name (None for ``none``); nothing is opened yet."""
    if params.source == "none":
        return None
    if params.source == "replay":
        return ReplaySource(params, base)
    if params.source == "stream":
        from amslam.plugins.mavsdk_platform.camera_sources.stream import StreamSource

        return StreamSource(params)
    from amslam.plugins.mavsdk_platform.camera_sources.realsense import RealSenseSource

    return RealSenseSource(params)
