"""Detector plugin ``onnx``: YOLOv8-seg instance segmentation with onnxruntime (paper 1, §VII).

See docs/detector.md. :class:`OnnxDetector` runs any model in the YOLOv8-seg ONNX layout (an
ultralytics export or the shipped ``models/sim_yolov8seg.onnx``, trained on the simulator's
images by ``train.py``) and lifts each instance mask to 3-D with the depth image.
"""

from __future__ import annotations

import amslam
from amslam.deferred import Deferred


@amslam.hookimpl
def amslam_detector_backends():
    """The ONNX instance-segmentation detector."""
    return {"onnx": Deferred("amslam.plugins.onnx_detector.detector:OnnxDetector")}
