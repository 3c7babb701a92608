"""Contract tests for object detectors: valid 3-D detections of what is in the frame, nothing in an empty one.

    from amslam.testing.detector import DetectorContract

    class TestMyDetector(DetectorContract):
        def make_backend(self):
            return MyDetector()

        def scene(self):            # optional: a frame your detector recognises, and what is in it
            return frame, [("chair", centroid_cam)]

The default scene is a simulator-style frame: a wall 4 m ahead and a chair-sized box 2 m ahead in
the middle of the image, with depth, a shaded RGB image and instance/class masks. A detector that
works from images (not masks) overrides :meth:`DetectorContract.scene` with a recorded frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from amslam.interfaces import Detector
from amslam.testing.contract import CAMERA, BackendContract
from amslam.types import R_BODY_CAM, CameraModel, Detection, Frame


def box_scene(
    camera: CameraModel = CAMERA, wall: float = 4.0, box: float = 2.0
) -> tuple[Frame, list[tuple[str, np.ndarray]]]:
    """A frame of a box (instance 1, class ``chair``) in front of a wall, and the box face's centroid."""
    H, W = camera.height, camera.width
    depth = np.full((H, W), wall, dtype=np.float32)
    rows, cols = slice(3 * H // 8, 5 * H // 8), slice(7 * W // 16, 9 * W // 16)
    depth[rows, cols] = box
    instance = np.zeros((H, W), dtype=np.int32)
    instance[rows, cols] = 1
    rgb = np.full((H, W, 3), 180, dtype=np.uint8)
    rgb[rows, cols] = (150, 90, 40)
    v, u = np.mgrid[0:H, 0:W]
    K = camera.K
    pts = np.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], -1)
    centroid = pts[rows, cols].reshape(-1, 3).mean(axis=0)
    T = np.eye(4)
    T[:3, :3] = R_BODY_CAM
    T[:3, 3] = (0.0, 0.0, 1.2)
    frame = Frame(
        stamp=1.0,
        depth=depth,
        K=K.copy(),
        T_odom_cam=T,
        rgb=rgb,
        instance=instance,
        class_id=instance.copy(),
        class_names=("background", "chair"),
        T_world_cam_truth=T,
    )
    return frame, [("chair", centroid)]


def empty_frame(camera: CameraModel = CAMERA) -> Frame:
    """A frame with nothing in it: no depth returns, a black image, empty masks."""
    H, W = camera.height, camera.width
    zeros = np.zeros((H, W), dtype=np.int32)
    return Frame(
        stamp=2.0,
        depth=np.zeros((H, W), dtype=np.float32),
        K=camera.K.copy(),
        T_odom_cam=np.eye(4),
        rgb=np.zeros((H, W, 3), dtype=np.uint8),
        instance=zeros,
        class_id=zeros.copy(),
        class_names=("background", "chair"),
        T_world_cam_truth=np.eye(4),
    )


class DetectorContract(BackendContract):
    """Mix-in of detector contract tests; override :meth:`make_backend` (and :meth:`scene`)."""

    kind = Detector
    #: A detection counts as the expected object within this distance of its centroid (m).
    centroid_tolerance: float = 0.3
    #: Calls of detect() on the scene; the object must be found in most of them (detectors may miss).
    trials: int = 5

    def scene(self) -> tuple[Frame, list[tuple[str, np.ndarray]]]:
        """A frame and the (class, camera-frame centroid) of each object the detector should find."""
        return box_scene()

    def _check(self, detections: list[Detection], frame: Frame) -> None:
        assert isinstance(detections, list)
        for det in detections:
            assert isinstance(det, Detection)
            assert isinstance(det.class_name, str) and det.class_name
            assert 0.0 <= det.confidence <= 1.0
            c = np.asarray(det.centroid_cam)
            assert c.shape == (3,) and np.all(np.isfinite(c)) and c[2] > 0, (
                "centroids lie in front of the camera"
            )
            pts = np.asarray(det.points_cam)
            assert pts.ndim == 2 and pts.shape[1] == 3 and np.all(np.isfinite(pts))

    def test_rate_is_positive(self, backend: Detector) -> None:
        assert float(backend.rate_hz) > 0

    def test_finds_the_objects_of_the_scene(self, backend: Detector) -> None:
        frame, expected = self.scene()
        found = {name: 0 for name, _ in expected}
        for _ in range(self.trials):
            detections = backend.detect(frame)
            self._check(detections, frame)
            for name, centroid in expected:
                near = [
                    d
                    for d in detections
                    if d.class_name == name
                    and np.linalg.norm(d.centroid_cam - centroid) < self.centroid_tolerance
                ]
                found[name] += bool(near)
        missed = {n: self.trials - k for n, k in found.items() if 2 * k <= self.trials}
        assert not missed, f"objects missed in most of {self.trials} calls: {missed}"

    def test_empty_frame_no_detections(self, backend: Detector) -> None:
        assert backend.detect(empty_frame()) == []

    def test_frame_is_left_untouched(self, backend: Detector) -> None:
        frame, _ = self.scene()
        copies = {
            k: np.array(getattr(frame, k), copy=True) for k in ("depth", "rgb", "instance", "class_id", "K")
        }
        backend.detect(frame)
        for k, v in copies.items():
            np.testing.assert_array_equal(getattr(frame, k), v, err_msg=f"detect() modified frame.{k}")

    def test_same_seed_same_detections(self, tmp_path: Path) -> None:
        frame, _ = self.scene()
        runs = []
        for _ in range(2):
            det = self.configured(tmp_path, seed=7)
            runs.append(
                [
                    (d.class_name, d.confidence, tuple(d.centroid_cam))
                    for _ in range(3)
                    for d in det.detect(frame)
                ]
            )
            det.close()
        assert runs[0] == runs[1]
