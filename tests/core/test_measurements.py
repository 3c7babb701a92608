"""The measurement log keeps enough of a detection's points for the base's window fits."""

import json
import re

import numpy as np
import pytest

from amslam.errors import RunFileError
from amslam.measurements import MeasurementLog, read_measurements
from amslam.types import Detection, Odometry


def _detection(n_points: int) -> Detection:
    pts = np.column_stack([np.linspace(-1, 1, n_points), np.zeros(n_points), np.full(n_points, 4.0)])
    return Detection(class_name="car", confidence=0.9, centroid_cam=pts.mean(0), points_cam=pts)


def test_a_detection_keeps_128_evenly_spread_points_and_a_small_one_keeps_all(tmp_path):
    log = MeasurementLog(tmp_path / "measurements.jsonl", "r1", np.eye(4))
    odom = Odometry(stamp=1.0, T_odom_body=np.eye(4))
    log.detections(odom, [_detection(1500), _detection(50)])
    log.close()
    lines = (tmp_path / "measurements.jsonl").read_text().splitlines()
    objects = json.loads(lines[-1])["objects"]
    big, small = (np.array(o["points"]) for o in objects)
    assert len(big) == 128 and len(small) == 50
    # evenly subsampled: the ends of the cloud are kept
    assert big[:, 0].min() == -1.0 and big[:, 0].max() == 1.0
    assert read_measurements(tmp_path) is not None


def test_the_camera_s_depth_noise_reaches_the_base_and_a_log_without_it_reads_as_unmodelled(tmp_path):
    log = MeasurementLog(tmp_path / "measurements.jsonl", "r1", np.eye(4), depth_noise=0.005)
    log.detections(Odometry(stamp=1.0, T_odom_body=np.eye(4)), [_detection(30)])
    log.close()
    assert read_measurements(tmp_path).depth_noise == 0.005
    # a log written before the header carried it: the base fits boxes as before
    lines = (tmp_path / "measurements.jsonl").read_text().splitlines()
    header = json.loads(lines[0])
    del header["depth_noise"]
    (tmp_path / "measurements.jsonl").write_text("\n".join([json.dumps(header), *lines[1:]]) + "\n")
    assert read_measurements(tmp_path).depth_noise == 0.0


def test_a_header_with_a_depth_noise_that_is_no_coefficient_is_one_error_naming_the_line(tmp_path):
    MeasurementLog(tmp_path / "measurements.jsonl", "r1", np.eye(4)).close()
    header = json.loads((tmp_path / "measurements.jsonl").read_text().splitlines()[0])
    for bad, says in (("loud", "malformed header record"), (-0.1, "depth_noise -0.1 is not in [0, 1]")):
        (tmp_path / "measurements.jsonl").write_text(json.dumps({**header, "depth_noise": bad}) + "\n")
        with pytest.raises(RunFileError, match=re.escape(f"measurements.jsonl:1: {says}")):
            read_measurements(tmp_path)
