"""What amslam logs into rerun, entity by entity; the replay and the live view both log through it.

Entity paths (world frame, z up; timeline ``sim_time`` in seconds of the run's clock):

===============================  ==================  ==============================================
``world``                        static              z-up view coordinates; the landmark classes'
                                                     labels and colours (annotation context)
``world/map``                    static or timed     occupied voxel centres (``Points3D``)
``world/trajectory/<source>``    static or timed     ground_truth, vio, slam paths (``LineStrips3D``)
``world/robot/<source>``         timed               the pose at each trajectory stamp
                                                     (``Transform3D`` with axes)
``world/keyposes``               timed (live)        SLAM key poses so far (``Points3D``)
``world/landmarks/cuboids``      static              cuboid landmarks with their yaw (``Boxes3D``)
``world/landmarks/cylinders``    static              cylinder landmarks (``Cylinders3D``)
``world/landmarks/points``       static              landmarks without a shape (``Points3D``)
``world/tour``                   timed               the adopted tour (``LineStrips3D``)
``world/tour/viewpoints``        timed               its stops, SLC stops labelled ``slc``
``events``                       timed               every event of ``events.jsonl`` (``TextLog``)
``slam/loop_closures``           timed               loop-closure attempts, accepted or not
``tree``                         timed               the tree's changes: node, status, feedback
===============================  ==================  ==============================================
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from amslam.lib.class_colours import class_rgb
from amslam.rundir import TRAJECTORIES, tum_values

TIMELINE = "sim_time"
SOURCES = TRAJECTORIES
#: trajectory colours (RGB 0-255): truth green, VIO orange, SLAM blue, as in the web viewer
SOURCE_COLOURS = {"ground_truth": (46, 160, 67), "vio": (230, 126, 34), "slam": (41, 98, 255)}
TOUR_COLOURS = {"explore": (0, 170, 200), "slc": (214, 39, 40)}
#: events logged as warnings or errors in the text log; every other event is INFO
WARN_EVENTS = {"unreachable", "land_failed", "outputs_error", "stdout_closed", "stderr_closed", "aborted"}
ERROR_EVENTS = {"error", "crash", "observer_failed", "summary_failed", "close_failed"}
#: a field longer than this is cut in the text log (the tour is drawn, not printed)
FIELD_CHARS = 120


def parse_tum(lines: Iterable[str]) -> np.ndarray:
    """TUM rows ``t x y z qx qy qz qw`` as an N×8 array; comments and malformed lines are skipped
    (a live run's streams are read as they are written: :func:`amslam.rundir.tum_values`)."""
    rows = [values for values in map(tum_values, lines) if values is not None]
    return np.asarray(rows, float).reshape(-1, 8)


class Scene:
    """One recording stream and the class ids it has announced."""

    def __init__(self, rec: Any):
        import rerun as rr

        self.rr = rr
        self.rec = rec
        self.class_ids: dict[str, int] = {}
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for source in SOURCES:
            rec.log(f"world/robot/{source}", rr.TransformAxes3D(0.4), static=True)

    def at(self, t: float) -> None:
        self.rec.set_time(TIMELINE, duration=float(t))

    # -- classes -----------------------------------------------------------------------------

    def classes(self, names: Iterable[str]) -> list[int]:
        """Class ids of ``names``; new classes extend the annotation context (label and colour)."""
        names = list(names)
        new = sorted({n for n in names if n not in self.class_ids})
        if new:
            for name in new:
                self.class_ids[name] = len(self.class_ids) + 1
            context = [(i, name, class_rgb(name)) for name, i in self.class_ids.items()]
            self.rec.log("world", self.rr.AnnotationContext(context), static=True)
        return [self.class_ids[n] for n in names]

    # -- trajectories ------------------------------------------------------------------------

    def poses(self, source: str, rows: np.ndarray) -> None:
        """The pose of ``source`` at each TUM row's stamp, sent as columns (one row per stamp)."""
        if len(rows) == 0:
            return
        rr = self.rr
        self.rec.send_columns(
            f"world/robot/{source}",
            indexes=[rr.TimeColumn(TIMELINE, duration=rows[:, 0])],
            columns=rr.Transform3D.columns(translation=rows[:, 1:4], quaternion=rows[:, 4:8]),
        )

    def path(self, source: str, positions: np.ndarray, *, static: bool) -> None:
        """The whole path of ``source`` so far as one line strip."""
        if len(positions) == 0:
            return
        strip = self.rr.LineStrips3D([positions], colors=[SOURCE_COLOURS[source]], labels=[source])
        self.rec.log(f"world/trajectory/{source}", strip, static=static)

    def keyposes(self, positions: np.ndarray) -> None:
        self.rec.log("world/keyposes", self.rr.Points3D(positions, colors=SOURCE_COLOURS["slam"], radii=0.06))

    # -- map and landmarks -------------------------------------------------------------------

    def map(
        self,
        points: np.ndarray,
        voxel: float | None,
        classes: Sequence[str] | None = None,
        *,
        static: bool = True,
    ) -> None:
        """Occupied voxel centres: coloured by class where the map knows it, else by height."""
        if len(points) == 0:
            return
        radius = 0.5 * (voxel or 0.1)
        if classes is not None:
            cloud = self.rr.Points3D(points, radii=radius, class_ids=self.classes(classes))
        else:
            from matplotlib import colormaps

            z = points[:, 2]
            span = float(np.ptp(z)) or 1.0
            colours = (colormaps["viridis"]((z - z.min()) / span)[:, :3] * 255).astype(np.uint8)
            cloud = self.rr.Points3D(points, radii=radius, colors=colours)
        self.rec.log("world/map", cloud, static=static)

    def landmarks(self, landmarks: Sequence[dict[str, Any]]) -> dict[str, int]:
        """Landmarks as ``landmarks.json`` holds them: cuboids as boxes turned by their yaw,
        cylinders as cylinders along their axis, the rest as labelled points. Counts per kind."""
        rr = self.rr
        kinds: dict[str, list[dict[str, Any]]] = {"cuboid": [], "cylinder": [], "point": []}
        for lm in landmarks:
            shape = lm.get("shape") or {}
            kinds[shape.get("model") if shape.get("model") in ("cuboid", "cylinder") else "point"].append(lm)

        def labels(group):
            return [f"{lm['class']} #{lm['id']}" for lm in group]

        if kinds["cuboid"]:
            group = kinds["cuboid"]
            self.rec.log(
                "world/landmarks/cuboids",
                rr.Boxes3D(
                    centers=[lm["shape"]["center"] for lm in group],
                    half_sizes=[np.asarray(lm["shape"]["dims"], float) / 2 for lm in group],
                    rotation_axis_angles=[
                        rr.RotationAxisAngle(axis=[0, 0, 1], radians=float(lm["shape"]["yaw"]))
                        for lm in group
                    ],
                    class_ids=self.classes(lm["class"] for lm in group),
                    labels=labels(group),
                ),
                static=True,
            )
        if kinds["cylinder"]:
            group = kinds["cylinder"]
            axes = [np.asarray(lm["shape"]["axis"], float) for lm in group]
            self.rec.log(
                "world/landmarks/cylinders",
                rr.Cylinders3D(
                    lengths=[lm["shape"]["height"] for lm in group],
                    radii=[lm["shape"]["radius"] for lm in group],
                    # rerun's cylinder is centred and along z; amslam's stands on its root along its axis
                    centers=[
                        np.asarray(lm["shape"]["root"], float) + a * lm["shape"]["height"] / 2
                        for lm, a in zip(group, axes, strict=True)
                    ],
                    rotation_axis_angles=[_z_to(a, rr) for a in axes],
                    class_ids=self.classes(lm["class"] for lm in group),
                    labels=labels(group),
                ),
                static=True,
            )
        if kinds["point"]:
            group = kinds["point"]
            self.rec.log(
                "world/landmarks/points",
                rr.Points3D(
                    [lm["position"][:3] for lm in group],
                    radii=0.12,
                    class_ids=self.classes(lm["class"] for lm in group),
                    labels=labels(group),
                ),
                static=True,
            )
        return {kind: len(group) for kind, group in kinds.items()}

    # -- tour, events, tree ------------------------------------------------------------------

    def tour(self, stops: Sequence[tuple[str, Sequence[float]]]) -> None:
        """The adopted tour: ``(kind, [x, y, z])`` per stop, ``kind`` explore or slc."""
        rr = self.rr
        positions = np.asarray([p[:3] for _, p in stops], float).reshape(-1, 3)
        self.rec.log(
            "world/tour", rr.LineStrips3D([positions] if len(positions) else [], colors=[(0, 170, 200)])
        )
        self.rec.log(
            "world/tour/viewpoints",
            rr.Points3D(
                positions,
                radii=0.1,
                colors=[TOUR_COLOURS.get(kind, TOUR_COLOURS["explore"]) for kind, _ in stops],
                labels=["slc" if kind == "slc" else "" for kind, _ in stops],
            ),
        )

    def event(self, record: dict[str, Any]) -> None:
        name = str(record.get("event", "?"))
        fields = " ".join(
            f"{k}={_short(v)}" for k, v in record.items() if k not in ("t", "event", "traceback")
        )
        level = "ERROR" if name in ERROR_EVENTS else "WARN" if name in WARN_EVENTS else "INFO"
        self.rec.log("events", self.rr.TextLog(f"{name} {fields}".strip(), level=level))

    def loop_closure(self, accepted: bool, reason: str, matched: int) -> None:
        text = f"{'accepted' if accepted else 'rejected'}: {reason} ({matched} landmarks matched)"
        self.rec.log("slam/loop_closures", self.rr.TextLog(text, level="INFO" if accepted else "WARN"))

    def tree(self, names: dict[int, str], nodes: dict[Any, Sequence[Any]]) -> bool:
        """One text line of the nodes that changed in a tick (``tree.jsonl``'s ``nodes``); False
        when all of them were merely reset (INVALID), which is logged as nothing."""
        parts = []
        for key, (status, feedback) in nodes.items():
            if status == "INVALID":
                continue
            name = names.get(int(key), f"node {key}")
            parts.append(f"{name} {status}" + (f": {feedback}" if feedback else ""))
        if not parts:
            return False
        failed = any(" FAILURE" in p for p in parts)
        self.rec.log("tree", self.rr.TextLog("; ".join(parts), level="WARN" if failed else "INFO"))
        return True


def _z_to(axis: np.ndarray, rr: Any) -> Any:
    """The rotation taking +z onto ``axis`` (unit), as an axis and angle."""
    axis = axis / (np.linalg.norm(axis) or 1.0)
    turn = np.cross([0.0, 0.0, 1.0], axis)
    angle = math.atan2(float(np.linalg.norm(turn)), float(axis[2]))
    if np.linalg.norm(turn) < 1e-9:
        turn = np.array([1.0, 0.0, 0.0])
    return rr.RotationAxisAngle(axis=turn / np.linalg.norm(turn), radians=angle)


def _short(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    return text if len(text) <= FIELD_CHARS else text[: FIELD_CHARS - 1] + "…"
