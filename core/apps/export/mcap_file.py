"""Write a run folder as an MCAP file of ROS 2 messages (CDR) and JSON channels.

Libraries: ``mcap`` writes the file; ``mcap-ros2-support`` encodes the ROS 2 messages to CDR
from their definitions; ``rosbags``' type store holds the definitions of the ROS 2 Humble
message types (the ``ros2msg`` text a ROS 2 bag embeds), so no ROS installation is needed and
no definition is written by hand. One ``mcap`` writer holds both kinds of channel: the
ROS 2 writer of ``mcap-ros2-support`` registers CDR channels only, so the CDR encoders are taken
from its ``serialize_dynamic`` and the channels registered here.

All three are imported by :func:`write_mcap` only (the ``interop`` extra), never when the
command line starts.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import amslam
from amslam.apps.export import ros_messages as ros
from amslam.apps.export.runfolder import RunFolder
from amslam.rundir import jsonable

#: the ROS 2 distribution whose message definitions the file embeds
ROS_DISTRO = "ROS2_HUMBLE"
TF = "tf2_msgs/msg/TFMessage"
PATH = "nav_msgs/msg/Path"
ODOMETRY = "nav_msgs/msg/Odometry"
CLOUD = "sensor_msgs/msg/PointCloud2"
MARKERS = "visualization_msgs/msg/MarkerArray"

EVENT_SCHEMA = {
    "title": "amslam event",
    "description": "one record of the run folder's events.jsonl (docs/run-folder.md)",
    "type": "object",
    "properties": {"t": {"type": "number"}, "event": {"type": "string"}},
    "required": ["t", "event"],
}
TREE_SCHEMA = {
    "title": "amslam behaviour-tree status",
    "description": "the whole tree after one tree.jsonl record",
    "type": "object",
    "properties": {
        "t": {"type": "number"},
        "tick": {"type": "integer"},
        "running": {"type": "string", "description": "the RUNNING nodes from the root down"},
        "nodes": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "id": {"type": "integer"},
                    "name": {"type": "string"},
                    "type": {"type": "string"},
                    "parent": {"type": "integer", "description": "the parent's id; null for the root"},
                    "status": {"type": "string"},
                    "feedback": {"type": "string"},
                },
            },
        },
        "blackboard": {"type": "object"},
    },
    "required": ["t", "nodes"],
}
#: rosbag2's QoS of a latched topic (reliable, transient local; Humble's YAML), so that
#: ``ros2 bag play`` republishes ``/tf_static`` to late subscribers
LATCHED_QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  liveliness: 1\n"
    "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false\n"
)
METRICS_SCHEMA = {"title": "amslam run metrics", "description": "metrics.json", "type": "object"}


@dataclass
class ExportSummary:
    """What was written: messages per topic and the warnings about what was left out."""

    path: Path
    counts: Counter = field(default_factory=Counter)
    types: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


class _Messages:
    """Messages gathered from every source, written afterwards in time order."""

    def __init__(self) -> None:
        self.items: list[tuple[int, int, str, str, Any]] = []

    def add(self, t: float, topic: str, kind: str, message: Any) -> None:
        self.items.append((ros.nanoseconds(t), len(self.items), topic, kind, message))


def gather(run: RunFolder) -> _Messages:
    """Every message of the export, with its log time (the run's clock)."""
    out = _Messages()
    start, end = run.start, run.end
    T_body_cam = ros.pose7(run.camera.T_body_cam)
    out.add(start, "/tf_static", TF, {"transforms": [ros.transform(start, ros.BASE, ros.CAMERA, T_body_cam)]})

    trajectories = run.trajectories
    vio, slam, truth = trajectories.get("vio"), trajectories.get("slam"), trajectories.get("ground_truth")
    if vio is not None and len(vio):
        if slam is not None and len(slam):
            correction = ros.interpolate(ros.slam_correction(slam, vio), vio.stamps)
        else:
            correction = np.tile([0, 0, 0, 0, 0, 0, 1.0], (len(vio), 1))  # no SLAM: odom is world
        for t, odom, body in zip(vio.stamps, correction, vio.poses, strict=True):
            t = float(t)
            tfs = [ros.transform(t, ros.WORLD, ros.ODOM, odom), ros.transform(t, ros.ODOM, ros.BASE, body)]
            out.add(t, "/tf", TF, {"transforms": tfs})
    if truth is not None:
        for t, pose in zip(truth.stamps, truth.poses, strict=True):
            out.add(
                float(t), "/tf", TF, {"transforms": [ros.transform(float(t), ros.WORLD, ros.TRUTH, pose)]}
            )

    for name, trajectory in trajectories.items():
        if not len(trajectory):
            continue
        frame, child = ros.TRAJECTORY_FRAMES[name]
        # the whole path at the start: on screen throughout the replay
        out.add(start, f"/{name}/path", PATH, ros.path(trajectory, frame, start))
        linear, angular = ros.velocities(trajectory)
        for i, (t, pose) in enumerate(zip(trajectory.stamps, trajectory.poses, strict=True)):
            message = ros.odometry(float(t), frame, child, pose, linear[i], angular[i])
            out.add(float(t), f"/{name}/odometry", ODOMETRY, message)

    if run.global_map is not None:  # the final map, from the start on
        out.add(start, "/map/global", CLOUD, ros.point_cloud(run.global_map, ros.WORLD, start))
    if run.local_map is not None:  # the local map as the run ended (the run folder keeps no other)
        out.add(end, "/map/local", CLOUD, ros.point_cloud(run.local_map, ros.ODOM, end))
    if run.landmarks is not None:
        out.add(start, "/landmarks", MARKERS, ros.landmark_markers(run.landmarks, start))

    slc_seen: dict[tuple[float, ...], list[float]] = {}
    for event in run.events:
        t = float(event["t"])
        out.add(t, "/events", "json:event", event)
        if event["event"] != "replan":
            continue
        tour = event.get("tour") or []
        out.add(t, "/planner/tour", MARKERS, ros.tour_markers(t, tour, ros.robot_position(run, t)))
        new = [stop[1:4] for stop in tour if stop[0] == "slc" and tuple(stop[1:4]) not in slc_seen]
        for xyz in new:
            slc_seen[tuple(xyz)] = [float(v) for v in xyz]
        if new:
            out.add(t, "/planner/slc_viewpoints", MARKERS, ros.slc_markers(t, list(slc_seen.values())))

    tree = ros.TreeState(run.tree_structure)
    for record in run.tree_records:
        out.add(float(record["t"]), "/tree/status", "json:tree", tree.apply(record))
    if run.metrics is not None:
        out.add(end, "/run/metrics", "json:metrics", run.metrics)
    return out


#: JSON channels: message kind → (schema name, JSON Schema)
JSON_SCHEMAS = {
    "json:event": ("amslam/Event", EVENT_SCHEMA),
    "json:tree": ("amslam/TreeStatus", TREE_SCHEMA),
    "json:metrics": ("amslam/Metrics", METRICS_SCHEMA),
}


class _Channels:
    """Schemas and channels of an MCAP writer, registered the first time a topic is written."""

    def __init__(self, writer, summary: ExportSummary):
        from mcap_ros2._dynamic import serialize_dynamic
        from rosbags.typesys import Stores, get_typestore

        self.writer, self.summary = writer, summary
        self.typestore = get_typestore(getattr(Stores, ROS_DISTRO))
        self.serialize_dynamic = serialize_dynamic
        self.schemas: dict[str, tuple[int, Any]] = {}  # kind → (schema id, CDR encoder; None for JSON)
        self.channels: dict[str, int] = {}

    def _schema(self, kind: str) -> tuple[int, Any]:
        from mcap.well_known import SchemaEncoding

        if kind not in self.schemas:
            if kind in JSON_SCHEMAS:
                name, schema = JSON_SCHEMAS[kind]
                data = json.dumps(schema).encode()
                self.schemas[kind] = (
                    self.writer.register_schema(name, SchemaEncoding.JSONSchema, data),
                    None,
                )
            else:
                # named pkg/msg/Type as rosbag2 names its schemas (rosbags looks types up so)
                text, _ = self.typestore.generate_msgdef(kind, ros_version=2)
                schema_id = self.writer.register_schema(kind, SchemaEncoding.ROS2, text.encode())
                self.schemas[kind] = (schema_id, self.serialize_dynamic(kind, text)[kind])
        return self.schemas[kind]

    def write(self, log_time: int, topic: str, kind: str, message: Any) -> None:
        from mcap.well_known import MessageEncoding

        schema_id, encode = self._schema(kind)
        if topic not in self.channels:
            encoding = MessageEncoding.JSON if encode is None else MessageEncoding.CDR
            metadata = {"offered_qos_profiles": LATCHED_QOS} if topic == "/tf_static" else {}
            self.channels[topic] = self.writer.register_channel(topic, encoding, schema_id, metadata)
            self.summary.types[topic] = JSON_SCHEMAS[kind][0] if encode is None else kind
        data = json.dumps(jsonable(message), allow_nan=False).encode() if encode is None else encode(message)
        sequence = self.summary.counts[topic]
        self.writer.add_message(self.channels[topic], log_time, data, log_time, sequence)
        self.summary.counts[topic] += 1


def write_mcap(run: RunFolder, file: Path, *, ros_only: bool = False) -> ExportSummary:
    """Write ``run`` to ``file`` (replaced if it exists); what was written per topic.

    ``ros_only`` leaves the JSON channels out, for readers that open only ROS 2 channels:
    rosbags (0.11) stops at a JSON Schema (``KeyError: 'jsonschema'``), and ``ros2 bag play``
    has no message type for them.
    """
    from mcap.well_known import Profile
    from mcap.writer import CompressionType, Writer

    messages = sorted(gather(run).items, key=lambda m: (m[0], m[1]))  # in time, then as gathered
    summary = ExportSummary(file, warnings=list(run.warnings))
    file.parent.mkdir(parents=True, exist_ok=True)
    partial = file.with_name(file.name + ".part")
    try:
        with open(partial, "wb") as stream:
            writer = Writer(stream, compression=CompressionType.ZSTD)
            writer.start(profile=Profile.ROS2, library=f"amslam {amslam.__version__}")
            channels = _Channels(writer, summary)
            for log_time, _, topic, kind, message in messages:
                if not (ros_only and kind in JSON_SCHEMAS):
                    channels.write(log_time, topic, kind, message)
            metadata = {
                "mission": run.mission_name,
                "run_folder": str(run.path),
                "camera_mount": run.camera.source,
                "ros_distro": ROS_DISTRO,
                "amslam": amslam.__version__,
            }
            writer.add_metadata("amslam", metadata)
            writer.finish()
    except BaseException:  # a full disk, Ctrl-C: no half-written .part left behind
        partial.unlink(missing_ok=True)
        raise
    partial.replace(file)  # the file appears under its name only once complete
    return summary
