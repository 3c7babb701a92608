"""RGB-D frames received over a TCP socket: camera source ``stream``.

A sender (``amslam sitl``'s rendered camera, or any program on the vehicle that has the frames)
listens on ``camera.host:camera.port``; the source connects to it when the platform starts and
reads frames on a thread of its own, keeping only the newest. One message on the wire is

    8 bytes: big-endian length N of what follows, then N bytes: an uncompressed ``.npz``

with the arrays ``depth`` (H×W float32, metres along the optical axis, 0 = no return), ``K``
(3×3), ``stamp`` (the sender's ``time.monotonic()`` when the pose it rendered for was sampled)
and optionally ``rgb`` (H×W×3 uint8), ``instance`` and ``class_id`` (H×W int32, a simulator's
masks, for its detector) with ``class_names``. The intrinsics travel with every frame, so the
camera model is what the sender says, not a nominal one. ``.npz`` (numpy's own container) is the
format because both ends hold numpy arrays already and it names, types and shapes each array;
only the length prefix that cuts the TCP stream into messages is written here.

``stamp`` is a point on the sender's monotonic clock. On the same host (a loopback address:
software in the loop, a camera process on the companion computer) that is the clock of the
platform too, and the frame is paired with the odometry pose heard nearest to the moment it was
rendered for; from another host the clocks differ and the arrival time stands in for it.

Thread rule: the reader thread owns the socket; it hands the control thread immutable
:class:`RgbdImage` objects through a one-slot box under a lock and touches nothing else.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import ipaddress
import socket
import struct
import threading
import time

import numpy as np

from amslam.errors import PlatformError
from amslam.plugins.mavsdk_platform.camera_sources.base import CameraSource, CameraSourceParams, RgbdImage
from amslam.types import CameraModel

#: the length prefix of a message: unsigned 64-bit, big-endian
_LENGTH = struct.Struct(">Q")
#: a message larger than this is not a frame (a 4096² RGB-D frame with masks is ~250 MB)
MAX_MESSAGE = 512 * 1024 * 1024


def encode_frame(frame: RgbdImage) -> bytes:
    """One message (length prefix + ``.npz``) for :func:`send_frame` or a socket of your own."""
    arrays: dict[str, np.ndarray] = {
        "stamp": np.float64(frame.stamp),
        "depth": np.asarray(frame.depth, np.float32),
        "K": np.asarray(frame.K, np.float64),
    }
    if frame.rgb is not None:
        arrays["rgb"] = np.asarray(frame.rgb, np.uint8)
    if frame.instance is not None and frame.class_id is not None:
        arrays["instance"] = np.asarray(frame.instance, np.int32)
        arrays["class_id"] = np.asarray(frame.class_id, np.int32)
        arrays["class_names"] = np.array(list(frame.class_names) or [""], dtype=str)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    body = buffer.getvalue()
    return _LENGTH.pack(len(body)) + body


def decode_frame(body: bytes) -> RgbdImage:
    """The frame of one message body (without its length prefix).

    Raises:
        ValueError: naming what is missing or malformed.
    """
    try:
        with np.load(io.BytesIO(body), allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except Exception as exc:  # a zip or npy error of any kind: not a frame
        raise ValueError(f"not an .npz frame ({type(exc).__name__}: {exc})") from None
    for name in ("stamp", "depth", "K"):
        if name not in arrays:
            raise ValueError(f"frame without {name!r} (has {sorted(arrays)})")
    depth, K = arrays["depth"], arrays["K"]
    if depth.ndim != 2 or K.shape != (3, 3):
        raise ValueError(f"depth must be H×W and K 3×3, got {depth.shape} and {K.shape}")
    rgb = arrays.get("rgb")
    if rgb is not None and rgb.shape[:2] != depth.shape:
        raise ValueError(f"rgb {rgb.shape} does not match depth {depth.shape}")
    instance, class_id = arrays.get("instance"), arrays.get("class_id")
    names = tuple(str(n) for n in arrays.get("class_names", ()))
    return RgbdImage(
        float(arrays["stamp"]), depth.astype(np.float32, copy=False), K.astype(float),
        rgb, instance, class_id, names,
    )  # fmt: skip


def send_frame(sock: socket.socket, frame: RgbdImage) -> None:
    """Send one frame on a connected socket (blocks until it is written)."""
    sock.sendall(encode_frame(frame))


def _receive_exactly(sock: socket.socket, n: int) -> bytes | None:
    """``n`` bytes, or None when the peer closed the connection first."""
    chunks, left = [], n
    while left:
        chunk = sock.recv(min(left, 1 << 20))
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def receive_frame(sock: socket.socket) -> RgbdImage | None:
    """The next frame on a connected socket, or None when the sender closed the stream.

    Raises:
        ValueError: a message that is not a frame (the stream cannot be trusted after it).
    """
    head = _receive_exactly(sock, _LENGTH.size)
    if head is None:
        return None
    (length,) = _LENGTH.unpack(head)
    if length > MAX_MESSAGE:
        raise ValueError(f"a message of {length} bytes is not a frame (limit {MAX_MESSAGE})")
    body = _receive_exactly(sock, length)
    if body is None:
        return None
    return decode_frame(body)


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
    except (OSError, ValueError):
        return False


class StreamSource(CameraSource):
    """Frames from a sender on ``camera.host:camera.port`` (see the module docstring)."""

    def __init__(self, params: CameraSourceParams):
        self.params = params
        self.same_clock = _is_loopback(params.host)
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._newest: RgbdImage | None = None
        self._stop = threading.Event()
        #: frames received, and frames replaced by a newer one before the control thread read them
        self.received = 0
        self.dropped = 0
        #: why the stream ended, once it has (the sender closed it, or sent garbage)
        self.ended: str | None = None
        #: same clock only: seconds from the moment a frame was rendered for to its arrival here
        self.latencies: list[float] = []

    def open(self) -> CameraModel:
        p = self.params
        where = f"{p.host}:{p.port}"
        deadline = time.monotonic() + p.stream_timeout
        while True:
            try:
                self._sock = socket.create_connection((p.host, p.port), timeout=max(0.1, p.stream_timeout))
                break
            except OSError as exc:
                if time.monotonic() >= deadline:
                    raise PlatformError(
                        f"camera.source stream: nothing sends frames on {where} ({exc.strerror or exc});"
                        " start the sender first (e.g. amslam sitl MISSION)"
                    ) from None
                time.sleep(0.2)
        self._sock.settimeout(p.stream_timeout)
        try:
            first = receive_frame(self._sock)
        except (OSError, ValueError) as exc:
            self.close()
            raise PlatformError(f"camera.source stream: no frame from {where}: {exc}") from None
        if first is None:
            self.close()
            raise PlatformError(f"camera.source stream: {where} closed the stream before its first frame")
        height, width = first.depth.shape
        self.model = CameraModel(
            width, height, first.K.copy(), p.T_body_cam(), p.min_range, p.max_range, p.rate_hz, p.depth_noise
        )
        self._keep(first)
        self._sock.settimeout(None)  # the reader blocks; close() shuts the socket down to end it
        self._thread = threading.Thread(target=self._read_stream, name="amslam-camera-stream", daemon=True)
        self._thread.start()
        return self.model

    def _keep(self, frame: RgbdImage) -> None:
        arrival = time.monotonic()
        stamp = frame.stamp if self.same_clock else arrival
        image = dataclasses.replace(frame, stamp=stamp)  # on the wire: the sender's clock
        with self._lock:
            if self._newest is not None:
                self.dropped += 1
            self._newest = image
            self.received += 1
            if self.same_clock:
                self.latencies.append(arrival - frame.stamp)

    def stats(self) -> dict:
        """Frames received and dropped (replaced before they were read), latency, how it ended."""
        with self._lock:
            out: dict = {"received": self.received, "dropped": self.dropped}
            if self.latencies:
                ms = 1000 * np.asarray(self.latencies)
                median, most = round(float(np.median(ms)), 1), round(float(ms.max()), 1)
                out["latency_ms"] = {"median": median, "max": most}
        if self.ended:
            out["ended"] = self.ended
        return out

    def _read_stream(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                frame = receive_frame(self._sock)
            except (OSError, ValueError) as exc:
                self.ended = f"{type(exc).__name__}: {exc}"
                return
            if frame is None:
                self.ended = "the sender closed the stream"
                return
            self._keep(frame)

    def read(self) -> RgbdImage | None:
        with self._lock:
            image, self._newest = self._newest, None
        return image

    def close(self) -> None:
        self._stop.set()
        if self._sock is not None:
            with contextlib.suppress(OSError):  # already closed by the sender
                self._sock.shutdown(socket.SHUT_RDWR)
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None
