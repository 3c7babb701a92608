"""A run folder as ROS 2 messages (plain dicts shaped like the message types, ready for CDR).

Frames (REP 105 names; the run's own frames in ``docs/architecture.md``):

* ``world`` — the SLAM frame; ``odom`` — the VIO frame; ``base_link`` — the body (FLU);
* ``world → odom`` is the SLAM correction ``T_world_odom = T_world_body(SLAM) · T_odom_body(VIO)⁻¹``
  at SLAM's key poses, interpolated between them; ``odom → base_link`` is VIO;
* ``world → base_link_truth`` is the ground truth (the simulator's), beside the estimate;
* ``base_link → camera_optical`` is the camera mount (optical convention: z forward, x right,
  y down), on ``/tf_static``.

Everything is stamped with the run's own clock (simulated time in the simulator), in seconds from
its start, as ROS ``Time``: Foxglove shows it as an elapsed time from 1970-01-01.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from amslam.apps.export.runfolder import RunFolder, VoxelCloud
from amslam.lib.class_colours import class_colour
from amslam.rundir import Trajectory

WORLD, ODOM, BASE, TRUTH, CAMERA = "world", "odom", "base_link", "base_link_truth", "camera_optical"
#: frame of each trajectory's poses and the body frame they move
TRAJECTORY_FRAMES = {"ground_truth": (WORLD, TRUTH), "vio": (ODOM, BASE), "slam": (WORLD, BASE)}
#: Marker types and actions (visualization_msgs/Marker constants)
ARROW, CUBE, SPHERE, CYLINDER, LINE_STRIP, SPHERE_LIST, TEXT = 0, 1, 2, 3, 4, 7, 9
ADD, DELETEALL = 0, 3
#: sensor_msgs/PointField FLOAT32
FLOAT32 = 7
#: covariance ellipsoids are drawn at this many standard deviations (≈ 74 % of the mass in 3-D)
ELLIPSOID_SIGMAS = 2.0
#: diameter of the marker of a landmark without a shape (a centroid landmark), m
POINT_LANDMARK_SIZE = 0.2
TOUR_COLOUR = (0.1, 0.8, 0.3, 1.0)
SLC_COLOUR = (1.0, 0.55, 0.0, 1.0)


def stamp(t: float) -> dict[str, int]:
    """ROS ``builtin_interfaces/Time`` of a time in seconds."""
    ns = nanoseconds(t)
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def nanoseconds(t: float) -> int:
    return max(0, round(t * 1e9))


def header(t: float, frame: str) -> dict[str, Any]:
    return {"stamp": stamp(t), "frame_id": frame}


def _point(p) -> dict[str, float]:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


def _quaternion(q) -> dict[str, float]:
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def _pose(p7) -> dict[str, Any]:
    return {"position": _point(p7[:3]), "orientation": _quaternion(p7[3:])}


def _colour(rgba) -> dict[str, float]:
    return {"r": float(rgba[0]), "g": float(rgba[1]), "b": float(rgba[2]), "a": float(rgba[3])}


def pose7(T: np.ndarray) -> np.ndarray:
    """A 4×4 transform as ``x y z qx qy qz qw``."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_quat()])


def transform(t: float, parent: str, child: str, p7) -> dict[str, Any]:
    """``geometry_msgs/TransformStamped``."""
    return {
        "header": header(t, parent),
        "child_frame_id": child,
        "transform": {"translation": _point(p7[:3]), "rotation": _quaternion(p7[3:])},
    }


# -- poses over time --------------------------------------------------------------------------------


def interpolate(trajectory: Trajectory, times: np.ndarray) -> np.ndarray:
    """Poses (N×7) of a trajectory at ``times``: linear in position, slerp in rotation, held
    at the first and last pose outside the trajectory's span."""
    stamps, poses = trajectory.stamps, trajectory.poses
    if len(stamps) == 1:
        return np.repeat(poses, len(times), axis=0)
    keep = np.concatenate([[True], np.diff(stamps) > 0])  # Slerp needs increasing times
    stamps, poses = stamps[keep], poses[keep]
    clipped = np.clip(times, stamps[0], stamps[-1])
    out = np.empty((len(times), 7))
    for axis in range(3):
        out[:, axis] = np.interp(clipped, stamps, poses[:, axis])
    out[:, 3:] = Slerp(stamps, Rotation.from_quat(poses[:, 3:]))(clipped).as_quat()
    return out


def _matrices(poses: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(poses), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(poses[:, 3:]).as_matrix()
    T[:, :3, 3] = poses[:, :3]
    return T


def slam_correction(slam: Trajectory, vio: Trajectory) -> Trajectory:
    """``T_world_odom`` at SLAM's key poses: where SLAM puts the body, over where VIO puts it."""
    T_world_body = _matrices(slam.poses)
    T_odom_body = _matrices(interpolate(vio, slam.stamps))
    T_world_odom = T_world_body @ np.linalg.inv(T_odom_body)
    return Trajectory(slam.stamps.copy(), np.array([pose7(T) for T in T_world_odom]).reshape(-1, 7))


def velocities(trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Linear and angular velocity (N×3 each) in the body frame, by forward differences (the last
    sample repeats the one before); zero across repeated stamps."""
    n = len(trajectory)
    linear, angular = np.zeros((n, 3)), np.zeros((n, 3))
    if n < 2:
        return linear, angular
    dt = np.diff(trajectory.stamps)
    rotations = Rotation.from_quat(trajectory.poses[:, 3:])
    step = np.where(dt > 0, dt, np.inf)[:, None]
    world_velocity = np.diff(trajectory.poses[:, :3], axis=0) / step
    linear[:-1] = rotations[:-1].inv().apply(world_velocity)
    angular[:-1] = (rotations[:-1].inv() * rotations[1:]).as_rotvec() / step
    linear[-1], angular[-1] = linear[-2], angular[-2]
    return linear, angular


# -- messages ---------------------------------------------------------------------------------------


def odometry(t: float, frame: str, child: str, p7, linear, angular) -> dict[str, Any]:
    """``nav_msgs/Odometry``; the covariances are unknown (all zero)."""
    return {
        "header": header(t, frame),
        "child_frame_id": child,
        "pose": {"pose": _pose(p7), "covariance": [0.0] * 36},
        "twist": {"twist": {"linear": _point(linear), "angular": _point(angular)}, "covariance": [0.0] * 36},
    }


def path(trajectory: Trajectory, frame: str, t: float) -> dict[str, Any]:
    """``nav_msgs/Path`` of a whole trajectory."""
    return {
        "header": header(t, frame),
        "poses": [
            {"header": header(float(s), frame), "pose": _pose(p)}
            for s, p in zip(trajectory.stamps, trajectory.poses, strict=True)
        ],
    }


def point_cloud(cloud: VoxelCloud, frame: str, t: float) -> dict[str, Any]:
    """``sensor_msgs/PointCloud2``: x, y, z and each of the cloud's values as float32 fields."""
    names = ["x", "y", "z", *cloud.values]
    record = np.zeros(len(cloud.points), dtype=[(n, "<f4") for n in names])
    for axis, name in enumerate("xyz"):
        record[name] = cloud.points[:, axis]
    for name, values in cloud.values.items():
        record[name] = values
    step = record.dtype.itemsize
    return {
        "header": header(t, frame),
        "height": 1,
        "width": len(record),
        "fields": [
            {"name": n, "offset": record.dtype.fields[n][1], "datatype": FLOAT32, "count": 1} for n in names
        ],
        "is_bigendian": False,
        "point_step": step,
        "row_step": step * len(record),
        "data": record.tobytes(),
        "is_dense": True,
    }


def _marker(t: float, ns: str, marker_id: int, kind: int, **fields: Any) -> dict[str, Any]:
    marker = {
        "header": header(t, WORLD),
        "ns": ns,
        "id": marker_id,
        "type": kind,
        "action": ADD,
        "pose": {"position": _point((0, 0, 0)), "orientation": _quaternion((0, 0, 0, 1))},
        "scale": _point((1, 1, 1)),
        "color": _colour((1, 1, 1, 1)),
        "frame_locked": False,
    }
    marker.update(fields)
    return marker


def _rotation_taking_z_to(axis) -> np.ndarray:
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    cross = np.cross(z, axis)
    if np.linalg.norm(cross) < 1e-9:  # parallel or antiparallel to z
        return np.array([0.0, 0.0, 0.0, 1.0]) if axis[2] > 0 else np.array([1.0, 0.0, 0.0, 0.0])
    angle = math.atan2(np.linalg.norm(cross), float(axis @ z))
    return Rotation.from_rotvec(cross / np.linalg.norm(cross) * angle).as_quat()


def shape_marker(t: float, ns: str, marker_id: int, landmark: dict[str, Any], rgba) -> dict[str, Any]:
    """The landmark's body: a CUBE for a cuboid, a CYLINDER for a cylinder, else a small SPHERE."""
    shape = landmark.get("shape") or {}
    model = shape.get("model")
    if model == "cuboid":
        if "rotation" in shape:
            q = Rotation.from_matrix(np.asarray(shape["rotation"], float)).as_quat()
        else:
            q = Rotation.from_euler("z", float(shape.get("yaw", 0.0))).as_quat()
        pose = {"position": _point(shape["center"]), "orientation": _quaternion(q)}
        return _marker(t, ns, marker_id, CUBE, pose=pose, scale=_point(shape["dims"]), color=_colour(rgba))
    if model == "cylinder":
        axis = np.asarray(shape.get("axis", (0.0, 0.0, 1.0)), float)
        axis = axis / np.linalg.norm(axis)
        height, radius = float(shape["height"]), float(shape["radius"])
        centre = np.asarray(shape["root"], float) + axis * height / 2.0  # the marker is centred
        pose = {"position": _point(centre), "orientation": _quaternion(_rotation_taking_z_to(axis))}
        scale = _point((2 * radius, 2 * radius, height))
        return _marker(t, ns, marker_id, CYLINDER, pose=pose, scale=scale, color=_colour(rgba))
    pose = {"position": _point(landmark["position"]), "orientation": _quaternion((0, 0, 0, 1))}
    size = _point((POINT_LANDMARK_SIZE,) * 3)
    return _marker(t, ns, marker_id, SPHERE, pose=pose, scale=size, color=_colour(rgba))


def covariance_marker(
    t: float, ns: str, marker_id: int, landmark: dict[str, Any], rgba
) -> dict[str, Any] | None:
    """A SPHERE scaled and turned to the position covariance's ellipsoid (``ELLIPSOID_SIGMAS`` σ)."""
    cov = landmark.get("covariance")
    if cov is None:
        return None
    values, vectors = np.linalg.eigh(np.asarray(cov, float))
    if np.linalg.det(vectors) < 0:  # a proper rotation for the quaternion
        vectors[:, 2] = -vectors[:, 2]
    diameters = 2.0 * ELLIPSOID_SIGMAS * np.sqrt(np.clip(values, 0.0, None))
    pose = {
        "position": _point(landmark["position"]),
        "orientation": _quaternion(Rotation.from_matrix(vectors).as_quat()),
    }
    colour = _colour((*rgba[:3], 0.35))
    return _marker(
        t, ns, marker_id, SPHERE, pose=pose, scale=_point(np.maximum(diameters, 1e-3)), color=colour
    )


def landmark_markers(landmarks: list[dict[str, Any]], t: float) -> dict[str, Any]:
    """``visualization_msgs/MarkerArray``: per landmark its body (namespace: its class), its
    covariance ellipsoid (``<class>/covariance``) and a label (``labels``)."""
    markers: list[dict[str, Any]] = [_marker(t, "", 0, CUBE, action=DELETEALL)]
    for n, lm in enumerate(landmarks):
        cls = lm["class"]
        rgba = (*(float(c) for c in class_colour(cls)), 1.0)
        marker_id = int(lm.get("id", n))
        markers.append(shape_marker(t, cls, marker_id, lm, rgba))
        ellipsoid = covariance_marker(t, f"{cls}/covariance", marker_id, lm, rgba)
        if ellipsoid is not None:
            markers.append(ellipsoid)
        above = np.asarray(lm["position"], float) + (0.0, 0.0, 0.4)
        label = {"position": _point(above), "orientation": _quaternion((0, 0, 0, 1))}
        markers.append(
            _marker(
                t,
                "labels",
                marker_id,
                TEXT,
                pose=label,
                scale=_point((0.2, 0.2, 0.2)),
                text=f"{cls} {marker_id}",
            )
        )
    return {"markers": markers}


def _pin(t: float, ns: str, marker_id: int, xyz, rgba) -> dict[str, Any]:
    """An ARROW pointing down onto a viewpoint from 0.8 m above it."""
    top = np.asarray(xyz, float) + (0.0, 0.0, 0.8)
    return _marker(
        t,
        ns,
        marker_id,
        ARROW,
        points=[_point(top), _point(xyz)],
        scale=_point((0.06, 0.15, 0.2)),  # shaft diameter, head diameter, head length
        color=_colour(rgba),
    )


def tour_markers(t: float, tour: list[list[Any]], start) -> dict[str, Any]:
    """A tour as a LINE_STRIP from the robot (``start``, or the first stop) through its stops,
    its exploration stops as a SPHERE_LIST and its SLC viewpoints as ARROW pins."""
    markers: list[dict[str, Any]] = [_marker(t, "", 0, CUBE, action=DELETEALL)]
    stops = [[float(v) for v in stop[1:4]] for stop in tour]
    if not stops:
        return {"markers": markers}
    line = ([list(start)] if start is not None else []) + stops
    markers.append(
        _marker(
            t,
            "tour",
            0,
            LINE_STRIP,
            points=[_point(p) for p in line],
            scale=_point((0.04, 0, 0)),
            color=_colour(TOUR_COLOUR),
        )
    )
    explore = [s for stop, s in zip(tour, stops, strict=True) if stop[0] != "slc"]
    if explore:
        markers.append(
            _marker(
                t,
                "tour_stops",
                0,
                SPHERE_LIST,
                points=[_point(p) for p in explore],
                scale=_point((0.15, 0.15, 0.15)),
                color=_colour(TOUR_COLOUR),
            )
        )
    slc = [s for stop, s in zip(tour, stops, strict=True) if stop[0] == "slc"]
    markers += [_pin(t, "tour_slc", i, s, SLC_COLOUR) for i, s in enumerate(slc)]
    return {"markers": markers}


def slc_markers(t: float, viewpoints: list[list[float]]) -> dict[str, Any]:
    """Every SLC viewpoint offered so far, as ARROW pins."""
    return {"markers": [_pin(t, "slc_viewpoints", i, v, SLC_COLOUR) for i, v in enumerate(viewpoints)]}


# -- the behaviour tree -----------------------------------------------------------------------------


class TreeState:
    """The whole tree at each ``tree.jsonl`` record (the file holds changes only)."""

    def __init__(self, structure: list[dict[str, Any]] | None):
        self.structure = structure or []
        self.nodes: dict[str, list[str]] = {}
        self.blackboard: dict[str, Any] = {}

    def apply(self, record: dict[str, Any]) -> dict[str, Any]:
        """Apply one change record; the full state after it, as the ``/tree/status`` message."""
        self.nodes.update({str(k): v for k, v in (record.get("nodes") or {}).items()})
        self.blackboard.update(record.get("blackboard") or {})
        nodes = []
        for node in self.structure:
            status, feedback = (self.nodes.get(str(node["id"])) or ["INVALID", ""])[:2]
            nodes.append({**node, "status": status, "feedback": feedback})
        return {
            "t": record["t"],
            "tick": record.get("tick", 0),
            "running": self._running_path(),
            "nodes": nodes,
            "blackboard": dict(self.blackboard),
        }

    def _running_path(self) -> str:
        """Names from the root down the RUNNING nodes, e.g. ``Mission/ExploreUntilDone/…/GoToViewpoint``."""
        children: dict[Any, list[dict[str, Any]]] = {}
        for node in self.structure:
            children.setdefault(node.get("parent"), []).append(node)
        names: list[str] = []
        level = children.get(None, [])
        while True:
            running = [n for n in level if (self.nodes.get(str(n["id"])) or [""])[0] == "RUNNING"]
            if not running:
                return "/".join(names)
            names.append(str(running[0]["name"]))
            level = children.get(running[0]["id"], [])


def robot_position(run: RunFolder, t: float) -> list[float] | None:
    """Where the robot was at ``t`` in the world frame (SLAM, else ground truth), for tour lines."""
    for name in ("slam", "ground_truth"):
        trajectory = run.trajectories.get(name)
        if trajectory is not None and len(trajectory):
            return interpolate(trajectory, np.array([t]))[0, :3].tolist()
    return None
