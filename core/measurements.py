"""The measurement log: what a robot sends to the base for multi-robot map merging (paper 2 §IV-B4).

"Each robot maintains its own factor graph. When robots establish communication, they exchange
their history object detections and odometry." Every run writes that history to
``measurements.jsonl`` in its run folder, one JSON record per line, appended and flushed as it
happens (a crash loses nothing already written):

* ``header`` (first line): ``robot`` name, ``T_world_odom`` (4×4, the robot's odometry frame in
  the shared world frame: its *known base*; the simulator's odometry frame is the world frame at
  the start, so identity there), ``T_body_cam`` and the camera's ``depth_noise``
  (:attr:`amslam.types.CameraModel.depth_noise`; 0 when absent, logs before it).
* ``keypose``: ``id``, ``t``, the VIO pose ``T_odom_body`` and the VIO motion since the previous
  key pose ``rel`` (both ``[x, y, z, qx, qy, qz, qw]``), the VIO ``distance`` of that step, and —
  in simulation only, for evaluation, never used by the merge — the true pose ``truth``.
* ``detections``: the ``keypose`` they were made at and their ``objects``: ``class``,
  ``confidence``, the centroid ``p_body`` in that key pose's body frame and, when the detector gave
  points, at most :attr:`MeasurementLog.max_points` of them (body frame, centimetres), enough for
  the base to fit a cuboid or cylinder (paper 2 §IV-A); ``shape`` if the detection carried one.

A key pose is logged whenever the SLAM backend makes one and for every detection frame (at the
frame's own VIO pose), so each detection has an exact key pose and the chain of ``rel`` motions is
the robot's whole odometry. :func:`read_measurements` loads a log back;
:func:`read_measurements_header` its first line alone (the camera mount, without the whole log).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amslam.errors import RunFileError
from amslam.geometry import invert, transform_points
from amslam.rundir import Stream, jsonable, read_jsonl
from amslam.types import Detection, Odometry

FORMAT = "amslam-measurements"
VERSION = 1
FILENAME = "measurements.jsonl"


def pose_to_list(T: np.ndarray) -> list[float]:
    """A 4×4 pose as ``[x, y, z, qx, qy, qz, qw]`` (compact, exact to 1e-6)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_quat()
    return [round(float(v), 6) for v in (*np.asarray(T)[:3, 3], *q)]


def pose_from_list(values: list[float]) -> np.ndarray:
    """Inverse of :func:`pose_to_list`."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, 3] = values[:3]
    T[:3, :3] = Rotation.from_quat(values[3:7]).as_matrix()
    return T


class MeasurementLog:
    """Appends a robot's key poses and detections to ``measurements.jsonl`` as they happen.

    Args:
        path: the file to write (created; parent folder must exist).
        robot: the robot's name.
        T_body_cam: camera mount, to move detections into the body frame.
        T_world_odom: the robot's base: its odometry frame in the shared world frame.
        depth_noise: the camera's depth noise coefficient (:attr:`.CameraModel.depth_noise`).
        max_points: points kept per detection (evenly subsampled); 0 keeps none. 128 so that a
            landmark's window at the base (12 s at 5 Hz, up to 60 views) holds as many points as
            the onboard window keeps (``ShapeParams.max_points``, 6000): with 24 a car's window fit
            was 0.5 m off (docs/multirobot.md). About 18 bytes per point in the log.
    """

    def __init__(
        self,
        path: Path,
        robot: str,
        T_body_cam: np.ndarray,
        T_world_odom: np.ndarray | None = None,
        max_points: int = 128,
        depth_noise: float = 0.0,
    ) -> None:
        # scipy's rotations, which every record needs, imported before the flight: the first key
        # pose on a real vehicle's control loop paid 0.15 s for it (a SITL flight's late_ticks)
        from scipy.spatial.transform import Rotation  # noqa: F401

        self.path = Path(path)
        self.T_body_cam = np.asarray(T_body_cam, float)
        self.max_points = max_points
        self._file = Stream(self.path)  # a full disk stops the log, not the flight
        self._last: np.ndarray | None = None
        self._count = 0
        T_wo = np.eye(4) if T_world_odom is None else np.asarray(T_world_odom, float)
        self._write(
            {
                "type": "header",
                "format": FORMAT,
                "version": VERSION,
                "robot": robot,
                "T_world_odom": np.round(T_wo, 9).tolist(),
                "T_body_cam": np.round(self.T_body_cam, 9).tolist(),
                "depth_noise": float(depth_noise),
            }
        )

    def _write(self, record: dict[str, Any]) -> None:
        if self._file.closed:
            return
        # a non-finite number becomes null: a line of measurements.jsonl is always JSON
        self._file.write(json.dumps(jsonable(record), separators=(",", ":"), allow_nan=False) + "\n")

    def keypose(self, odom: Odometry, truth: np.ndarray | None = None) -> int:
        """Log a key pose at the VIO pose ``odom`` (``truth``: true pose, simulation only).

        Returns the key pose's id; a pose within 1 mm and 1 mrad of the previous key pose is not
        logged again, its id is returned instead.
        """
        from scipy.spatial.transform import Rotation

        T = np.asarray(odom.T_odom_body, float)
        if self._last is not None:
            rel = invert(self._last) @ T
            angle = float(np.linalg.norm(Rotation.from_matrix(rel[:3, :3]).as_rotvec()))
            if np.linalg.norm(rel[:3, 3]) < 1e-3 and angle < 1e-3:
                return self._count - 1
        else:
            rel = np.eye(4)
        record: dict[str, Any] = {
            "type": "keypose",
            "id": self._count,
            "t": round(float(odom.stamp), 4),
            "T_odom_body": pose_to_list(T),
            "rel": pose_to_list(rel),
            "distance": round(float(np.linalg.norm(rel[:3, 3])), 6),
        }
        if truth is not None:
            record["truth"] = pose_to_list(truth)
        self._write(record)
        self._last = T.copy()
        self._count += 1
        return self._count - 1

    def detections(
        self, odom: Odometry, detections: list[Detection], truth: np.ndarray | None = None
    ) -> None:
        """Log detections made at the VIO pose ``odom`` (camera frame in, body frame out)."""
        if not detections:
            return
        kp = self.keypose(odom, truth)
        R, t = self.T_body_cam[:3, :3], self.T_body_cam[:3, 3]
        objects = []
        for d in detections:
            obj: dict[str, Any] = {
                "class": d.class_name,
                "confidence": round(float(d.confidence), 3),
                "p_body": [round(float(v), 4) for v in R @ np.asarray(d.centroid_cam, float) + t],
            }
            pts = np.asarray(d.points_cam, float).reshape(-1, 3)
            if self.max_points and len(pts):
                idx = np.linspace(0, len(pts) - 1, min(self.max_points, len(pts))).round().astype(int)
                obj["points"] = np.round(pts[idx] @ R.T + t, 2).tolist()
            shape = getattr(d, "shape", None)
            if shape:
                obj["shape"] = jsonable(shape)
            objects.append(obj)
        stamp = round(float(odom.stamp), 4)
        self._write({"type": "detections", "keypose": kp, "t": stamp, "objects": objects})

    @property
    def error(self) -> str | None:
        """Why the log could not all be written (a full disk), or None."""
        return self._file.error

    def close(self) -> None:
        """Close the file; safe to call twice."""
        self._file.close()


# -- reading ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class LoggedDetection:
    """One detection of a measurement log.

    Attributes:
        keypose: index of the key pose it was made at.
        class_name: semantic class.
        confidence: classification confidence.
        p_body: centroid in the key pose's body frame.
        points: M×3 object points in the key pose's body frame (may be empty).
        shape: shape parameters the detection carried, if any.
        stamp: time of its camera frame; several frames share a key pose when the robot did not
            move between them (a hover), and only their stamps tell the frames apart.
    """

    keypose: int
    class_name: str
    confidence: float
    p_body: np.ndarray
    points: np.ndarray
    shape: dict | None = None
    stamp: float = float("nan")


@dataclass
class RobotMeasurements:
    """One robot's measurement log, as read back by :func:`read_measurements`.

    Attributes:
        robot: the robot's name.
        T_world_odom: its known base (odometry frame in the world frame).
        T_body_cam: its camera mount.
        depth_noise: its camera's depth noise coefficient (0: not logged).
        stamps: K key-pose times.
        T_odom_body: K×4×4 VIO key poses.
        rel: K×4×4 VIO motion from the previous key pose (identity for the first).
        truth: K×4×4 true key poses (simulation), or None.
        detections: all detections, in log order.
    """

    robot: str
    T_world_odom: np.ndarray
    T_body_cam: np.ndarray
    stamps: np.ndarray
    T_odom_body: np.ndarray
    rel: np.ndarray
    truth: np.ndarray | None
    detections: list[LoggedDetection] = field(default_factory=list)
    depth_noise: float = 0.0

    @property
    def duration(self) -> float:
        """Time spanned by the key poses (s)."""
        return float(self.stamps[-1] - self.stamps[0]) if len(self.stamps) else 0.0

    def world_points(self, T_world_body: np.ndarray) -> list[np.ndarray]:
        """Each detection's points in the world frame, given world key poses (K×4×4)."""
        return [transform_points(T_world_body[d.keypose], d.points) for d in self.detections]


def _is_header(record: Any) -> bool:
    return isinstance(record, dict) and record.get("type") == "header" and record.get("format") == FORMAT


def read_measurements_header(path: Path) -> dict[str, Any]:
    """The header record (first line) of a ``measurements.jsonl`` file (or the one in a run folder).

    Raises:
        RunFileError: the file cannot be read or its first line is not the header; named.
    """
    path = Path(path)
    if path.is_dir():
        path = path / FILENAME
    try:
        with open(path, encoding="utf-8") as f:
            first = f.readline()
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFileError(f"{path}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        record = json.loads(first)
    except json.JSONDecodeError:
        record = None
    if not _is_header(record):
        raise RunFileError(f"{path}:1: not an amslam measurement log (first line is not its header)")
    return record


def read_measurements(path: Path) -> RobotMeasurements:
    """Load a ``measurements.jsonl`` file (or the one in a run folder).

    Raises:
        RunFileError: (a ValueError) the file cannot be read, is not a measurement log, or a
            record is malformed or lacks a field; the message names the file and line.
    """
    path = Path(path)
    if path.is_dir():
        path = path / FILENAME
    header: dict[str, Any] | None = None
    stamps, poses, rels, truths, dets = [], [], [], [], []
    depth_noise = 0.0
    for n, rec in read_jsonl(path):  # a partial last line (a run killed mid-write) is dropped
        try:
            kind = rec.get("type")
            if n == 1:
                if not _is_header(rec):
                    raise RunFileError(
                        f"{path}:1: not an amslam measurement log (first line is not its header)"
                    )
                header = rec
                depth_noise = float(rec.get("depth_noise") or 0.0)
                if not 0.0 <= depth_noise <= 1.0:  # NaN too
                    raise RunFileError(f"{path}:1: depth_noise {depth_noise!r} is not in [0, 1]")
            elif kind == "keypose":
                if rec["id"] != len(stamps):
                    raise RunFileError(f"{path}:{n}: key pose {rec['id']} out of order")
                stamps.append(rec["t"])
                poses.append(pose_from_list(rec["T_odom_body"]))
                rels.append(pose_from_list(rec["rel"]))
                truths.append(pose_from_list(rec["truth"]) if "truth" in rec else None)
            elif kind == "detections":
                for o in rec["objects"]:
                    dets.append(
                        LoggedDetection(
                            int(rec["keypose"]),
                            o["class"],
                            float(o["confidence"]),
                            np.asarray(o["p_body"], float),
                            np.asarray(o.get("points", []), float).reshape(-1, 3),
                            o.get("shape"),
                            float(rec.get("t", "nan")),
                        )
                    )
        except RunFileError:
            raise
        except KeyError as exc:  # one line naming the record, not a traceback from deep in here
            raise RunFileError(f"{path}:{n}: {kind or 'record'} record has no {exc.args[0]!r}") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise RunFileError(f"{path}:{n}: malformed {kind or 'record'} record ({exc})") from None
    if header is None:
        raise RunFileError(f"{path}: empty measurement log")
    has_truth = bool(truths) and all(t is not None for t in truths)
    return RobotMeasurements(
        robot=header["robot"],
        T_world_odom=np.asarray(header["T_world_odom"], float),
        T_body_cam=np.asarray(header["T_body_cam"], float),
        stamps=np.asarray(stamps, float),
        T_odom_body=np.asarray(poses, float).reshape(-1, 4, 4),
        rel=np.asarray(rels, float).reshape(-1, 4, 4),
        truth=np.asarray(truths, float) if has_truth else None,
        detections=[d for d in dets if d.keypose < len(stamps)],
        depth_noise=depth_noise,
    )
