"""Backend outputs checked where they enter the runtime.

A backend is someone else's code. What it hands the runtime — an odometry pose, a depth frame,
detections, viewpoints, a tour — is checked once, where it comes in (``Perception.step``,
``PlanningService.plan``), so a broken backend ends the run with a verdict that names it::

    failed: platform 'mysim' from dist mysim 0.3: odometry(): T_odom_body is not finite (nan at [0, 3])

rather than with a ``LinAlgError`` three modules later. Every message starts with the backend's
:meth:`Boundary.label`: its kind, its name and the distribution it came from
(:meth:`amslam.registry.Registry.origin`). A backend raising something that is not an
:class:`amslam.errors.AmslamError` (its own, documented failures) is named the same way
(:meth:`Boundary.calling`).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amslam.errors import AmslamError
from amslam.types import Detection, Frame, Odometry, PlanRequest, TourItem, TourItemKind, Viewpoint


class BackendError(AmslamError):
    """A backend raised something other than an AmslamError; the message names it."""


class BackendOutputError(BackendError):
    """A backend handed the runtime something unusable (a wrong type or shape, a NaN, an item
    that was not asked for); the message names it."""


def _where(array: np.ndarray) -> str:
    bad = np.argwhere(~np.isfinite(array))
    value = array[tuple(bad[0])]
    return f"{value} at {list(map(int, bad[0]))}"


def pose_problem(T: Any, name: str) -> str | None:
    """Why ``T`` is not a rigid 4×4 transform (None if it is one)."""
    try:
        T = np.asarray(T, dtype=float)
    except (TypeError, ValueError):
        return f"{name} is not a 4x4 array of numbers (got {type(T).__name__})"
    if T.shape != (4, 4):
        return f"{name} has shape {T.shape}, expected (4, 4)"
    if not np.all(np.isfinite(T)):
        return f"{name} is not finite ({_where(T)})"
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-3) or np.linalg.det(R) <= 0:
        return f"{name} has a rotation that is not orthonormal"
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
        return f"{name} has a last row {T[3].tolist()}, expected [0, 0, 0, 1]"
    return None


def _viewpoint_problem(vp: Any) -> str | None:
    """What is wrong with one viewpoint (its alternatives aside), or None."""
    if not isinstance(vp, Viewpoint):
        return f"is a {type(vp).__name__}, expected Viewpoint"
    problem = _array_problem(vp.position, "position", (3,))
    if problem is None and not (_finite_number(vp.yaw) and _finite_number(vp.gain)):
        problem = f"yaw {vp.yaw!r} or gain {vp.gain!r} is not a finite number"
    if problem is None and not isinstance(vp.alternatives, tuple):
        problem = f"alternatives is a {type(vp.alternatives).__name__}, expected a tuple"
    return problem


def _finite_number(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and math.isfinite(float(value))


def _array_problem(value: Any, name: str, shape: tuple[int | None, ...]) -> str | None:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return f"{name} is not an array of numbers (got {type(value).__name__})"
    if array.ndim != len(shape) or any(
        n is not None and n != m for n, m in zip(shape, array.shape, strict=False)
    ):
        wanted = "(" + ", ".join("N" if n is None else str(n) for n in shape) + ")"
        return f"{name} has shape {array.shape}, expected {wanted}"
    if not np.all(np.isfinite(array)):
        return f"{name} is not finite ({_where(array)})"
    return None


@dataclass(frozen=True)
class Boundary:
    """The checks, with each backend kind's label for the messages."""

    labels: Mapping[str, str] = field(default_factory=dict)  # kind → "planner 'x' from dist y 1.0"

    def label(self, kind: str) -> str:
        return self.labels.get(kind, kind)

    def fault(self, kind: str, what: str) -> BackendOutputError:
        return BackendOutputError(f"{self.label(kind)}: {what}")

    @contextlib.contextmanager
    def calling(self, kind: str, call: str) -> Iterator[None]:
        """Name the backend when ``call`` raises something other than an AmslamError."""
        try:
            yield
        except AmslamError:
            raise
        except Exception as exc:  # noqa: BLE001 — re-raised, naming the backend
            text = " ".join(str(exc).split())[:300]
            raise BackendError(f"{self.label(kind)}: {call} raised {type(exc).__name__}: {text}") from exc

    # -- the checks ----------------------------------------------------------------------------

    def pose(self, kind: str, call: str, T: Any) -> np.ndarray:
        problem = pose_problem(T, "the pose")
        if problem:
            raise self.fault(kind, f"{call}: {problem}")
        return np.asarray(T, dtype=float)

    def odometry(self, odom: Any) -> Odometry:
        if not isinstance(odom, Odometry):
            raise self.fault("platform", f"odometry() returned {type(odom).__name__}, expected Odometry")
        if not _finite_number(odom.stamp):
            raise self.fault("platform", f"odometry(): stamp {odom.stamp!r} is not a finite number")
        problem = pose_problem(odom.T_odom_body, "T_odom_body")
        if problem:
            raise self.fault("platform", f"odometry(): {problem}")
        return odom

    def frame(self, frame: Any) -> Frame | None:
        if frame is None:
            return None
        if not isinstance(frame, Frame):
            raise self.fault("platform", f"capture() returned {type(frame).__name__}, expected Frame or None")
        problem = (
            (None if _finite_number(frame.stamp) else f"stamp {frame.stamp!r} is not a finite number")
            or _depth_problem(frame.depth)
            or _array_problem(frame.K, "K", (3, 3))
            or pose_problem(frame.T_odom_cam, "T_odom_cam")
        )
        if problem:
            raise self.fault("platform", f"capture(): {problem}")
        return frame

    def detections(self, detections: Any) -> list[Detection]:
        if not isinstance(detections, Sequence) or isinstance(detections, str | bytes):
            raise self.fault("detector", f"detect() returned {type(detections).__name__}, expected a list")
        for i, d in enumerate(detections):
            problem = _detection_problem(d)
            if problem:
                raise self.fault("detector", f"detect(): detection {i}: {problem}")
        return list(detections)

    def viewpoints(self, viewpoints: Any) -> list[Viewpoint]:
        try:
            items = list(viewpoints)
        except TypeError:
            raise self.fault(
                "mapping", f"viewpoints() returned {type(viewpoints).__name__}, expected a list"
            ) from None
        for i, vp in enumerate(items):
            problem = _viewpoint_problem(vp)
            if problem is None:
                for j, alt in enumerate(vp.alternatives):
                    if problem := _viewpoint_problem(alt):
                        problem = f"alternative {j}: {problem}"
                        break
            if problem:
                raise self.fault("mapping", f"viewpoints(): viewpoint {i}: {problem}")
        return items

    def tour(self, tour: Any, request: PlanRequest, frontiers: bool) -> list[TourItem]:
        """A tour's stops: TourItems whose refs were in the request (a frontier planner's explore
        stops are the request's viewpoints; every planner's SLC stops its SLC candidates)."""
        if not isinstance(tour, Sequence) or isinstance(tour, str | bytes):
            raise self.fault("planner", f"plan() returned {type(tour).__name__}, expected a list of TourItem")
        viewpoint_ids = {vp.id for vp in request.viewpoints}
        candidate_ids = {c.keypose_id for c in request.slc_candidates}
        for i, item in enumerate(tour):
            problem = _tour_item_problem(item)
            if problem is None and item.kind == TourItemKind.SLC and item.ref not in candidate_ids:
                problem = f"SLC stop for key pose {item.ref}, which was not among the request's candidates"
            if (
                problem is None
                and frontiers
                and item.kind == TourItemKind.EXPLORE
                and item.ref not in viewpoint_ids
            ):
                problem = (
                    f"viewpoint {item.ref}, which was not among the request's {len(viewpoint_ids)} viewpoints"
                )
            if problem:
                raise self.fault("planner", f"plan(): stop {i}: {problem}")
        return list(tour)


def _depth_problem(depth: Any) -> str | None:
    if not isinstance(depth, np.ndarray) or depth.ndim != 2 or not np.issubdtype(depth.dtype, np.number):
        shape = getattr(depth, "shape", None)
        return f"depth is not a 2-D array of numbers (got {type(depth).__name__} {shape or ''})".rstrip()
    if np.isnan(depth).any() if np.issubdtype(depth.dtype, np.floating) else False:
        return "depth holds NaN (no return is 0)"
    return None


def _detection_problem(d: Any) -> str | None:
    if not isinstance(d, Detection):
        return f"is a {type(d).__name__}, expected Detection"
    if not isinstance(d.class_name, str) or not d.class_name:
        return f"class_name {d.class_name!r} is not a name"
    if not _finite_number(d.confidence) or not 0.0 <= float(d.confidence) <= 1.0:
        return f"confidence {d.confidence!r} is not a number in [0, 1]"
    problem = _array_problem(d.centroid_cam, "centroid_cam", (3,))
    if problem is None and d.points_cam is not None and np.size(d.points_cam) > 0:
        problem = _array_problem(d.points_cam, "points_cam", (None, 3))
    return problem


def _tour_item_problem(item: Any) -> str | None:
    if not isinstance(item, TourItem):
        return f"is a {type(item).__name__}, expected TourItem"
    if item.kind not in tuple(TourItemKind):
        return f"kind {item.kind!r} is not one of {', '.join(TourItemKind)}"
    try:
        position = np.asarray(item.position, dtype=float)
    except (TypeError, ValueError):
        return f"position is not numbers (got {type(item.position).__name__})"
    if position.shape != (3,):
        return f"position has shape {position.shape}, expected (3,)"
    if np.isnan(position).any():
        return "position is NaN (an unreachable stop is +inf)"
    if np.isfinite(position).all() and not (_finite_number(item.yaw) and _finite_number(item.gain)):
        return f"yaw {item.yaw!r} or gain {item.gain!r} is not a finite number"
    if not isinstance(item.ref, int | np.integer):
        return f"ref {item.ref!r} is not an integer id"
    return None
