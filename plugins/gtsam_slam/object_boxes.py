"""The reported object map's boxes: each object at the box fitted to all its points (issue #23).

A centroid landmark is measured at the middle of the visible part of its object, which sits on
the viewer's side (one-floor flights: chairs 0.21 m, tables 0.45 m, shelves 0.40 m from their
centres on average), so the graph's point is where the views were taken from as much as where
the object is. The graph needs that point (its range-bearing factors, the loop closures and the
planners work on it); the map a person reads needs the object. So at the end the object is
reported at the box fitted to the points of all its detections, moved into the world with the
optimised key poses (:func:`amslam.lib.shapes.fit_cuboid`), completed behind the faces the
cameras saw with the median box of its class (:func:`amslam.lib.shapes.complete_cuboid`, the
shape landmarks' rule). On ten one-floor, five two-floor and five house flights re-solved from
their logs, the objects' mean error fell from 0.347 to 0.244 m, lower on every flight
(docs/objects.md, "Objects reported at their boxes").
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import gtsam
import numpy as np

from amslam.geometry import transform_points
from amslam.lib import shapes
from amslam.plugins.gtsam_slam.graph import LandmarkRec, Observation, SlamGraph
from amslam.types import Landmark

#: Fewest points a box is fitted to; fewer and the graph's point stays.
MIN_POINTS = 20
#: Points a box is fitted to at most (every k-th): the L-shape search is linear in them.
MAX_POINTS = 1000
#: Boxes of a class before its median box completes partial views (``size_prior_min_boxes``).
MIN_CLASS_BOXES = 3
#: How far down a box is stretched to where its detections' middle says the object reaches, m
#: (:func:`_fit`): a chair's legs below its seat; more is a wrong middle, not a missed part.
MAX_REACH = 0.6
#: How far below its points' median a landmark's detections must put their centroids (median
#: over them, m) to say that the object reaches below its points (:func:`_fit`).
MIN_BELOW = 0.05


@dataclass
class ObjectBoxes:
    """The reported boxes: per kept landmark id its box (world frame); per landmark folded into
    another as the same object, the id it joined."""

    boxes: dict[int, dict]
    folded: dict[int, int]


@dataclass
class _Seen:
    """What one landmark's detections saw: world points, camera positions, key poses."""

    class_name: str
    points: np.ndarray
    cameras: np.ndarray
    keys: set[int]
    #: the height of each kept detection's centroid (world z) when the detector put them below
    #: the points' middle (:data:`MIN_BELOW`), else empty
    heights: np.ndarray


def fitted_boxes(
    landmarks: Iterable[LandmarkRec],
    values: gtsam.Values,
    T_body_cam: np.ndarray | Mapping[int, np.ndarray],
    *,
    twin_margin: float,
    twin_share: float | None = None,
    trim_spreads: float | None = None,
    tolerance: float = 0.15,
) -> ObjectBoxes:
    """Each landmark's box, for landmarks whose observations kept points; twins folded together.

    Two landmarks of a class are one object seen twice (the graph's fusion missed them) when no
    key pose saw both (two objects in one view are two objects) and either each one's completed
    box, inflated by ``twin_margin``, holds the other's centre, or at least ``twin_share`` of the
    points of the one seen from fewer key poses lie inside the other's inflated box. The second
    rule catches a part seen alone: a table's top or one face, mapped again after the drift moved
    it, gives a thin box that holds no other centre while it lies inside the whole table's box
    (one-floor flights: 5 of the 10 duplicates left). A chair 0.75 m from its neighbour in a row
    holds neither centre, and few of the neighbour's points. A twin is folded into the one seen
    from more key poses, whose box is fitted again to both's points.

    A landmark's box is fitted to the points of the detections that agree with each other: with
    ``trim_spreads``, a detection whose points' median lies farther (horizontally) than that many
    times the landmark's median detection spread (:attr:`.Observation.spread`, about half the
    object's size) from the median of all its detections' medians is left out — a neighbour's
    detection that the association gave it under drift (a chair 0.75 m along a row) or one made
    while the drift had moved it. Five one-floor flights re-solved from their logs
    (``benchmarks/slam_offline.py``'s merge) and reported with the true key poses: objects' mean
    error 0.146 → 0.123 m with 2.5 spreads (chairs' boxes of their true detections alone: 0.07 m);
    with the re-solved key poses the trajectory's error dominates: 0.274 → 0.273 m, and 0.226 →
    0.222 m on five demo and two house flights (docs/objects.md).

    Args:
        landmarks: the landmarks to report, with their observations (``pose_key``, body-frame
            ``points``, ``spread``; the graph's fusion has moved a fused twin's observations to its
            survivor).
        values: the optimised key poses.
        T_body_cam: the camera mount (the cameras' positions tell which faces were seen), or each
            robot's by :attr:`.Observation.robot` (the base's merge of several robots).
        twin_margin: each box is inflated by this for the twins' test (m).
        twin_share: the share of a landmark's points inside another's box that makes it a part of
            that object (None: only the centres' rule).
        trim_spreads: a detection this many of its landmark's spreads away from the others is left
            out of its box (None: every detection counts).
        tolerance: a shortfall of the class's box up to this is noise, not a missing part (m).
    """
    seen = {lm.id: v for lm in landmarks if (v := _seen(lm, values, T_body_cam, trim_spreads)) is not None}
    fits = {j: box for j, v in seen.items() if (box := _fit(v.points, v.heights)) is not None}
    typical: dict[str, np.ndarray] = {}
    for cls in {seen[j].class_name for j in fits}:
        dims = [
            [*sorted(box["dims"][:2], reverse=True), box["dims"][2]]
            for j, box in fits.items()
            if seen[j].class_name == cls
        ]
        if len(dims) >= MIN_CLASS_BOXES:
            typical[cls] = np.median(np.array(dims), axis=0)

    def completed(box: dict, cls: str, cameras: np.ndarray) -> dict:
        if cls not in typical:
            return box
        return shapes.complete_cuboid(box, cameras, typical[cls], tolerance=tolerance).shape

    out = {j: completed(box, seen[j].class_name, seen[j].cameras) for j, box in fits.items()}
    folded = _twins(out, seen, twin_margin, twin_share)
    for j in set(folded.values()):  # a survivor's box from its twins' points as well
        group = [j, *(k for k, into in folded.items() if into == j)]
        heights = np.concatenate([seen[k].heights for k in group])
        box = _fit(np.vstack([seen[k].points for k in group]), heights)
        if box is not None:
            out[j] = completed(box, seen[j].class_name, np.vstack([seen[k].cameras for k in group]))
    for k in folded:
        del out[k]
    return ObjectBoxes(out, folded)


def reported_boxes(
    graph: SlamGraph, values: gtsam.Values, T_body_cam: np.ndarray | Mapping[int, np.ndarray], rules: Any
) -> ObjectBoxes:
    """:func:`fitted_boxes` of the graph's centroid-class landmarks under the ``object_*`` rules of
    ``rules`` (the backend's ``Params`` or the base merge's ``MergeParams``, which share them)."""
    return fitted_boxes(
        [lm for lm in graph.graph_landmarks() if graph.shapes.model(lm.class_name) == "centroid"],
        values,
        T_body_cam,
        twin_margin=rules.object_twin_margin,
        twin_share=rules.object_twin_share,
        trim_spreads=rules.object_trim_spreads,
    )


def placed(landmarks: Iterable[Landmark], reported: ObjectBoxes) -> list[Landmark]:
    """The reported object map: ``landmarks`` at their boxes (:func:`fitted_boxes`, by
    :attr:`Landmark.id`), those folded into a twin left out; a landmark without a box unchanged."""
    boxes = reported.boxes
    return [
        replace(lm, position=shapes.shape_center(boxes[lm.id]), shape=boxes[lm.id]) if lm.id in boxes else lm
        for lm in landmarks
        if lm.id not in reported.folded
    ]


def _seen(
    lm: LandmarkRec,
    values: gtsam.Values,
    T_body_cam: np.ndarray | Mapping[int, np.ndarray],
    trim_spreads: float | None,
) -> _Seen | None:
    """What a landmark's detections with points saw, moved with the optimised key poses (the
    detections :func:`_consistent` keeps); None without points."""
    obs = [o for o in lm.observations if o.points is not None and len(o.points)]
    if not obs:
        return None
    poses = [values.atPose3(o.pose_key).matrix() for o in obs]
    points = [transform_points(T, o.points) for T, o in zip(poses, obs, strict=True)]
    kept = _consistent(points, obs, trim_spreads)
    heights = np.array([transform_points(poses[i], obs[i].p_body[None])[0, 2] for i in kept])
    below = np.array([np.median(points[i][:, 2]) for i in kept]) - heights
    return _Seen(
        lm.class_name,
        np.vstack([points[i] for i in kept]),
        np.array([(poses[i] @ _mount(T_body_cam, obs[i]))[:3, 3] for i in kept]),
        {o.pose_key for o in obs},  # every view of it, for the twins' test
        heights if np.median(below) > MIN_BELOW else np.zeros(0),
    )


def _mount(T_body_cam: np.ndarray | Mapping[int, np.ndarray], observation: Observation) -> np.ndarray:
    return T_body_cam[observation.robot] if isinstance(T_body_cam, Mapping) else T_body_cam


def _consistent(points: list[np.ndarray], observations: list, trim_spreads: float | None) -> list[int]:
    """Indices of a landmark's detections (their world points, their observations) within
    ``trim_spreads`` × their median spread of the median of their medians, horizontally (all of
    them without ``trim_spreads``, or when none would be kept)."""
    everything = list(range(len(points)))
    if trim_spreads is None or len(points) < 3:
        return everything
    middles = np.array([np.median(p[:, :2], axis=0) for p in points])
    off = np.linalg.norm(middles - np.median(middles, axis=0), axis=1)
    radius = trim_spreads * float(np.median([o.spread for o in observations]))
    kept = [i for i in everything if off[i] <= radius]
    return kept or everything


def _fit(points: np.ndarray, heights: np.ndarray | None = None) -> dict | None:
    """The box of a landmark's points, reaching down as far as its detections' middle says.

    ``heights``: the world height of each detection's centroid, given when the detector put
    them below their points' middle (by :data:`MIN_BELOW` over the landmark's detections). A
    detector whose masks miss an object's thin lower parts (the ``onnx`` network's do not reach
    a chair's legs) leaves the points' bottom at the seat, while its centroid's height is the
    middle of the object's image box, which reaches the feet (``centroid_height: box``): the
    object then reaches down to twice their median less the points' top, and the box is
    stretched to there — by at most :data:`MAX_REACH`, and never raised. A detector whose
    centroid is its points' median (the ``sim`` detector) says nothing more than its points:
    taken as the middle, the median of a bed's or a cabinet's points, low under a tall
    headboard or top, would put the floor too low (the house's objects 0.162 → 0.178 m when
    every landmark was stretched so).
    """
    # Not past the camera's depth noise (fit_cuboid's ``noise``, which the base merge's cars
    # use): indoors at 2-5 m it is a few centimetres, and on the 15 SLC-ablation flights of
    # 8829d9f re-solved (benchmarks/slam_offline.py --depth-noise logged,0.005) the objects'
    # mean error went 0.265 -> 0.268 m (0.180 -> 0.190 on the true key poses): no gain.
    if len(points) < MIN_POINTS:
        return None
    box = shapes.fit_cuboid(points[:: -(-len(points) // MAX_POINTS)])
    if box is None or heights is None or len(heights) == 0:
        return box
    centre, dims = np.asarray(box["center"], float), np.asarray(box["dims"], float)
    top, bottom = centre[2] + dims[2] / 2, centre[2] - dims[2] / 2
    reach = 2.0 * float(np.median(heights)) - top
    if reach >= bottom:
        return box
    bottom = max(reach, bottom - MAX_REACH)
    centre[2], dims[2] = (top + bottom) / 2, top - bottom
    return shapes.cuboid_shape(np.asarray(box["rotation"], float), centre, dims)


def _twins(
    fits: dict[int, dict], seen: dict[int, _Seen], margin: float, share: float | None
) -> dict[int, int]:
    """Landmark id → the id it is folded into (see :func:`fitted_boxes`); chains resolved."""
    ids = sorted(fits, key=lambda j: -len(seen[j].keys))  # more observations first
    into: dict[int, int] = {}
    for a_i, a in enumerate(ids):
        if a in into:
            continue
        for b in ids[a_i + 1 :]:
            if b in into or seen[a].class_name != seen[b].class_name or seen[a].keys & seen[b].keys:
                continue
            if _holds_centre(fits[a], fits[b], margin) and _holds_centre(fits[b], fits[a], margin):
                into[b] = a  # each holds the other's centre
            elif share is not None and shapes.points_inside(fits[a], seen[b].points, margin).mean() >= share:
                into[b] = a  # b's points lie in a's box: a part of a seen alone
    return into


def _holds_centre(box: dict, other: dict, margin: float) -> bool:
    return bool(shapes.points_inside(box, shapes.shape_center(other)[None], margin)[0])
