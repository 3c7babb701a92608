"""Detector plugin ``onnx``: YOLOv8-seg instance segmentation with onnxruntime (paper 1, §VII).

Being built for issue #8; it registers no backend yet.
"""
