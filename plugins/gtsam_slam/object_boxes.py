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

from collections.abc import Iterable

import gtsam
import numpy as np

from amslam.geometry import transform_points
from amslam.lib import shapes
from amslam.plugins.gtsam_slam.graph import LandmarkRec

#: Fewest points a box is fitted to; fewer and the graph's point stays.
MIN_POINTS = 20
#: Points a box is fitted to at most (every k-th): the L-shape search is linear in them.
MAX_POINTS = 1000
#: Boxes of a class before its median box completes partial views (``size_prior_min_boxes``).
MIN_CLASS_BOXES = 3


def fitted_boxes(
    landmarks: Iterable[LandmarkRec],
    observations: dict[int, list],
    values: gtsam.Values,
    T_body_cam: np.ndarray,
    tolerance: float = 0.15,
) -> dict[int, dict]:
    """Per landmark id, its box (world frame), for landmarks whose observations kept points.

    Args:
        landmarks: the landmarks to report.
        observations: per landmark id, its observations and those of the twins fused into it
            (each with ``pose_key`` and body-frame ``points``).
        values: the optimised key poses.
        T_body_cam: the camera mount (the cameras' positions tell which faces were seen).
        tolerance: a shortfall of the class's box up to this is noise, not a missing part (m).
    """
    fits: dict[int, tuple[str, dict, np.ndarray]] = {}
    for lm in landmarks:
        obs = [o for o in observations.get(lm.id, []) if o.points is not None and len(o.points)]
        if not obs:
            continue
        poses = [values.atPose3(o.pose_key).matrix() for o in obs]
        pts = np.vstack([transform_points(T, o.points) for T, o in zip(poses, obs, strict=True)])
        if len(pts) < MIN_POINTS:
            continue
        box = shapes.fit_cuboid(pts[:: -(-len(pts) // MAX_POINTS)])
        if box is None:
            continue
        cameras = np.array([(T @ T_body_cam)[:3, 3] for T in poses])
        fits[lm.id] = (lm.class_name, box, cameras)
    typical: dict[str, np.ndarray] = {}
    for cls in {c for c, _, _ in fits.values()}:
        boxes = [box for c, box, _ in fits.values() if c == cls]
        dims = [[*sorted(box["dims"][:2], reverse=True), box["dims"][2]] for box in boxes]
        if len(dims) >= MIN_CLASS_BOXES:
            typical[cls] = np.median(np.array(dims), axis=0)
    out = {}
    for lm_id, (cls, box, cameras) in fits.items():
        if cls in typical:
            box = shapes.complete_cuboid(box, cameras, typical[cls], tolerance=tolerance).shape
        out[lm_id] = box
    return out
