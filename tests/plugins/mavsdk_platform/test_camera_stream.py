"""The ``stream`` camera source: frames over TCP with their intrinsics, newest first."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from amslam.errors import PlatformError
from amslam.plugins.mavsdk_platform.camera_sources import CameraSourceParams, make_camera_source
from amslam.plugins.mavsdk_platform.camera_sources.base import RgbdImage
from amslam.plugins.mavsdk_platform.camera_sources.stream import (
    StreamSource,
    decode_frame,
    encode_frame,
    send_frame,
)


def _frame(i: int, shape=(6, 8)) -> RgbdImage:
    depth = np.full(shape, 1.0 + i, np.float32)
    K = np.array([[5.0, 0, 3.5], [0, 5.0, 2.5], [0, 0, 1]])
    rgb = np.full((*shape, 3), i, np.uint8)
    instance = np.full(shape, i, np.int32)
    return RgbdImage(100.0 + i, depth, K, rgb, instance, instance * 0 + 2, ("", "wall", "chair"))


def _sender(frames: list[bytes], hold: threading.Event) -> tuple[int, threading.Thread]:
    """A one-client TCP sender of ``frames`` (already encoded) on a free port; closes after ``hold``."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        conn, _ = server.accept()
        with conn, server:
            for message in frames:
                conn.sendall(message)
            hold.wait(5.0)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return port, thread


def test_a_frame_survives_the_wire():
    sent = _frame(3)
    got = decode_frame(encode_frame(sent)[8:])
    assert got.stamp == sent.stamp and got.class_names == sent.class_names
    for name in ("depth", "K", "rgb", "instance", "class_id"):
        np.testing.assert_array_equal(getattr(got, name), getattr(sent, name))
    bare = decode_frame(encode_frame(RgbdImage(1.0, sent.depth, sent.K))[8:])
    assert bare.rgb is None and bare.instance is None and bare.class_names == ()


def test_open_takes_the_intrinsics_from_the_stream_and_read_gives_the_newest():
    hold = threading.Event()
    port, thread = _sender([encode_frame(_frame(i)) for i in range(3)], hold)
    params = CameraSourceParams(source="stream", port=port, mount_pitch_deg=10.0, stream_timeout=5.0)
    source = make_camera_source(params, base=None)
    assert isinstance(source, StreamSource)
    try:
        model = source.open()
        assert (model.width, model.height) == (8, 6)
        np.testing.assert_array_equal(model.K, _frame(0).K)
        np.testing.assert_allclose(model.T_body_cam, params.T_body_cam())
        deadline = time.monotonic() + 5.0
        while source.received < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        image = source.read()
        assert image is not None and float(image.depth[0, 0]) == 3.0  # the newest, older ones dropped
        assert image.stamp == 102.0  # same host: the sender's clock, the moment it rendered for
        assert image.class_names == ("", "wall", "chair") and int(image.instance[0, 0]) == 2
        assert source.dropped == 2
        stats = source.stats()
        assert (stats["received"], stats["dropped"]) == (3, 2) and "latency_ms" in stats
        assert source.read() is None  # nothing new
        hold.set()
        thread.join(timeout=5.0)
        deadline = time.monotonic() + 5.0
        while source.ended is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert source.ended == "the sender closed the stream"
    finally:
        source.close()
        source.close()  # twice is fine


def test_garbage_on_the_stream_ends_it_with_the_reason():
    hold = threading.Event()
    garbage = (12).to_bytes(8, "big") + b"not a frame!"
    port, _ = _sender([encode_frame(_frame(0)), garbage], hold)
    source = StreamSource(CameraSourceParams(source="stream", port=port, stream_timeout=5.0))
    try:
        source.open()
        deadline = time.monotonic() + 5.0
        while source.ended is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert source.ended is not None and "not an .npz frame" in source.ended
    finally:
        hold.set()
        source.close()


def test_nobody_sending_is_one_clear_error():
    with socket.create_server(("127.0.0.1", 0)) as probe:
        port = probe.getsockname()[1]  # closed again: nothing listens there
    source = StreamSource(CameraSourceParams(source="stream", port=port, stream_timeout=0.3))
    with pytest.raises(PlatformError, match=rf"nothing sends frames on 127.0.0.1:{port} .*amslam sitl"):
        source.open()


def test_send_frame_writes_one_message():
    a, b = socket.socketpair()
    with a, b:
        send_frame(a, _frame(1))
        from amslam.plugins.mavsdk_platform.camera_sources.stream import receive_frame

        got = receive_frame(b)
        assert got is not None and got.stamp == 101.0
