"""Object shape models from point clouds (paper 2, §IV-A): ground planes, cuboids, cylinders.

Plain numpy in, plain dicts out. A *shape* is a dict with the same keys as
:attr:`amslam.types.WorldSummary.object_shapes` and :attr:`amslam.types.Landmark.shape`:

* cuboid — ``{"model": "cuboid", "center": [x, y, z], "yaw": ψ, "dims": [l, w, h],
  "rotation": R}``: ``center`` is the centre of the box, ``dims`` its extent along the box axes
  ``b1`` (longitudinal), ``b2 = b3 × b1`` (lateral) and ``b3`` (vertical = the local ground
  normal); ``rotation`` is the 3×3 matrix ``[b1 b2 b3]`` (row-major nested lists), which is a
  pure yaw rotation on level ground and a full rotation on a slope; ``yaw`` is the heading of
  ``b1`` projected on the horizontal plane (the only angle that matters on level ground).
* cylinder — ``{"model": "cylinder", "root": [x, y, z], "axis": [nx, ny, nz], "radius": r,
  "height": h}``: ``root`` is where the axis meets the local ground plane, ``axis`` a unit vector
  pointing up, ``height`` the extent of the object along the axis above the root.

All fitters take points in one gravity-aligned frame (world, or the VIO odometry frame: the IMU
observes roll and pitch, so both have z up) and return shapes in that frame.

Pipeline (§IV-A): :func:`cluster` splits the points of one class into instances with DBSCAN;
:func:`fit_plane` / :func:`local_ground` estimate the local ground plane from ground points
near an object; :func:`fit_cuboid` projects an instance on that plane, takes its 2-D convex
hull, finds the longitudinal axis (PCA of the hull, or L-shape fitting, see below),
the facing direction (the front of a vehicle is lower than its rear) and the dimensions from
the 5th and 95th percentiles of the projections on the axes;
:func:`fit_cylinder` fits a robust circle around the axis (ground normal or PCA) and intersects
the axis with the ground plane for the root.

Two departures from the paper's text, both because our views are partial depth-camera views
rather than 360° LIDAR sweeps:

* The 5th–95th percentile span of points spread uniformly over an edge-to-edge extent is only
  90 % of that extent. Each bound is therefore extrapolated linearly to the edge,
  ``lo = 2·q(p) − q(2p)`` and ``hi = 2·q(100−p) − q(100−2p)`` (exact for a locally uniform
  spread, unchanged when the points pile up at the edge, as on a side face), which keeps the
  percentiles' robustness to outliers without their shrinkage. With p = 5 the extrapolation
  overshoots by up to 4 % of the extent when a face holding ~5 % of the points lies on the
  edge (a car's front seen obliquely), so the default is p = 1 (bias ≤ 2 cm, σ 1.5 cm on
  1500 points over 4 m); ``percentile=5, extrapolate=False`` is the paper's recipe.
* PCA of an L-shaped partial view (two visible sides) points along the diagonal. The default
  axis is therefore the orientation found by L-shape fitting (the closeness criterion of Zhang
  et al., "Efficient L-shape fitting for vehicle detection using laser scanners", IV 2017),
  the longitudinal axis being the rectangle side with the larger extent; ``axis="pca"`` keeps
  the paper's PCA of the hull.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from amslam.geometry import wrap_angle, yaw_matrix

__all__ = [
    "GroundPlane",
    "Completion",
    "cluster",
    "complete_cuboid",
    "cuboid_pose",
    "cuboid_shape",
    "cylinder_shape",
    "depth_noise",
    "fit_cuboid",
    "fit_cylinder",
    "fit_plane",
    "fit_shapes",
    "local_ground",
    "seat_seen_faces",
    "shape_center",
    "shape_errors",
    "transform_shape",
]

UP = np.array([0.0, 0.0, 1.0])


# -------------------------------------------------------------------------------------------
# ground planes
# -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GroundPlane:
    """A plane ``normal · x + offset = 0`` with ``normal`` a unit vector pointing up (n_z > 0)."""

    normal: np.ndarray
    offset: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of each point (N×3) above the plane."""
        return np.asarray(points, float) @ self.normal + self.offset

    def project(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal projection of the points (N×3) on the plane."""
        p = np.asarray(points, float)
        return p - np.outer(self.height(p), self.normal)

    def intersect(self, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Where the line ``origin + t·direction`` meets the plane (the line must not be parallel)."""
        o, d = np.asarray(origin, float), np.asarray(direction, float)
        denom = float(self.normal @ d)
        if abs(denom) < 1e-9:
            raise ValueError("the line is parallel to the ground plane")
        t = -float(self.normal @ o + self.offset) / denom
        return o + t * d

    @staticmethod
    def horizontal(z: float) -> GroundPlane:
        """The level plane at height ``z``."""
        return GroundPlane(UP.copy(), -float(z))


def fit_plane(
    points: np.ndarray, *, threshold: float = 0.05, iterations: int = 5, min_points: int = 10
) -> GroundPlane | None:
    """Least-squares plane through ground points, with iterative outlier trimming.

    Hand-written rather than Open3D's ``segment_plane`` because the inputs are small (tens to a
    few thousand points already labelled as ground) and the result must be deterministic: an
    SVD fit, then points farther than ``max(threshold, 2.5·RMS)`` are dropped and the plane
    refitted, ``iterations`` times.

    Returns:
        The plane (normal pointing up), or ``None`` with fewer than ``min_points`` points or a
        degenerate (collinear) set.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    if len(p) < min_points:
        return None
    keep = np.ones(len(p), dtype=bool)
    normal, centroid = UP, p.mean(axis=0)
    for _ in range(max(1, iterations)):
        q = p[keep]
        if len(q) < 3:
            return None
        centroid = q.mean(axis=0)
        _, s, vt = np.linalg.svd(q - centroid, full_matrices=False)
        if s[1] < 1e-6 * max(s[0], 1e-12):  # collinear
            return None
        normal = vt[2] if vt[2, 2] >= 0 else -vt[2]
        dist = np.abs((p - centroid) @ normal)
        rms = float(np.sqrt(np.mean(dist[keep] ** 2)))
        new_keep = dist <= max(threshold, 2.5 * rms)
        if new_keep.sum() < min_points or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return GroundPlane(normal, -float(normal @ centroid))


def local_ground(
    ground_points: np.ndarray | None, near: np.ndarray, radius: float = 4.0, *, min_points: int = 15
) -> GroundPlane | None:
    """The ground plane fitted to the ground points within ``radius`` (horizontally) of ``near``."""
    if ground_points is None or len(ground_points) == 0:
        return None
    g = np.asarray(ground_points, float).reshape(-1, 3)
    sel = np.linalg.norm(g[:, :2] - np.asarray(near, float)[:2], axis=1) <= radius
    return fit_plane(g[sel], min_points=min_points)


# -------------------------------------------------------------------------------------------
# instances
# -------------------------------------------------------------------------------------------
def cluster(points: np.ndarray, eps: float = 0.5, min_samples: int = 10) -> list[np.ndarray]:
    """Split the points of one class into instances with DBSCAN (scikit-learn).

    Returns:
        One index array per cluster, largest first; noise points belong to none.
    """
    from sklearn.cluster import DBSCAN

    p = np.asarray(points, float).reshape(-1, 3)
    if len(p) < min_samples:
        return []
    labels = DBSCAN(eps=eps, min_samples=min_samples).fit(p).labels_
    groups = [np.flatnonzero(labels == k) for k in np.unique(labels) if k >= 0]
    return sorted(groups, key=len, reverse=True)


# -------------------------------------------------------------------------------------------
# robust extents
# -------------------------------------------------------------------------------------------
def _extent(
    x: np.ndarray, percentile: float, extrapolate: bool = True, spread: np.ndarray | None = None
) -> tuple:
    """Robust (lo, hi) bounds of a 1-D spread (floats), or of each row of a 2-D one (arrays).

    With ``extrapolate`` (default), the ``p``-th and ``(100−p)``-th percentiles extrapolated
    linearly to the edge: ``lo = 2·q(p) − q(2p)``, ``hi = 2·q(100−p) − q(100−2p)`` (module
    docstring); without it, the raw percentiles (the paper's recipe).

    ``spread`` (1-D only): each value's noise std. A point's noise pushes it past the edge as
    often as inside, and the outermost percentiles are the noise's tails; so the upper bound is
    taken over ``x − z·spread`` and the lower over ``x + z·spread``, ``z`` the standard normal's
    ``(100−p)``-th percentile: a point on the edge then falls beyond it with probability ``p`` %,
    as a noise-free one would at ``p`` % of the spread (:func:`depth_noise`).
    """
    p = float(percentile)
    if spread is not None and p > 0:
        from scipy.special import ndtri

        shift = float(ndtri(1.0 - p / 100.0)) * np.asarray(spread, float)
        lo, _ = _extent(x + shift, p, extrapolate)
        _, hi = _extent(x - shift, p, extrapolate)
        return lo, hi
    if p <= 0:
        lo, hi = np.min(x, axis=-1), np.max(x, axis=-1)
    elif not extrapolate:
        lo, hi = np.percentile(x, [p, 100 - p], axis=-1)
    else:
        q = np.percentile(x, [p, 2 * p, 100 - 2 * p, 100 - p], axis=-1)
        lo, hi = 2 * q[0] - q[1], 2 * q[3] - q[2]
    return (float(lo), float(hi)) if np.ndim(x) == 1 else (lo, hi)


def _least_area_axis(
    xy: np.ndarray,
    a1: np.ndarray,
    percentile: float,
    extrapolate: bool,
    spread: Callable[[np.ndarray], np.ndarray | None],
    *,
    search_deg: float = 10.0,
    step_deg: float = 1.0,
) -> np.ndarray:
    """The axis within ``search_deg`` of ``a1`` whose rectangle (extents past the points' noise)
    has the least area. The L-shape search weighs every point alike: with a depth camera's noise
    at 5-6 m it turned a car by 6° on one of three simulated views, and a turned box is a wider
    one; the area of the noise-aware extents is the rectangle criterion that noise does not
    widen (Zhang et al.'s "area" criterion)."""

    def area(t: float) -> float:
        c, s = np.cos(t), np.sin(t)
        b1 = np.array([c * a1[0] - s * a1[1], s * a1[0] + c * a1[1]])
        b2 = np.array([-b1[1], b1[0]])
        lo1, hi1 = _extent(xy @ b1, percentile, extrapolate, spread(b1))
        lo2, hi2 = _extent(xy @ b2, percentile, extrapolate, spread(b2))
        return (hi1 - lo1) * (hi2 - lo2)

    turns = np.radians(np.arange(-search_deg, search_deg + step_deg / 2, step_deg))
    t = float(turns[int(np.argmin([area(t) for t in turns]))])
    return np.array([np.cos(t) * a1[0] - np.sin(t) * a1[1], np.sin(t) * a1[0] + np.cos(t) * a1[1]])


def depth_noise(
    points: np.ndarray, origins: np.ndarray, optical_axes: np.ndarray, coefficient: float
) -> np.ndarray:
    """Each point's depth noise as a vector: its std and direction (N×3, same frame).

    A depth camera measures ``z`` along its optical axis with a std ``coefficient·z²`` (a stereo
    camera's; :attr:`amslam.types.CameraModel.depth_noise`) and back-projects the pixel's ray:
    a point ``p`` seen from ``o`` moves by ``(p − o)/z`` per metre of depth error, so its noise
    is ``coefficient · z · (p − o)`` — along the ray, 0.18 m at 6 m for the D435i-like 0.005.
    ``origins`` and ``optical_axes`` (unit) are the cameras' positions and viewing directions,
    per point (N×3) or one for all (3,).
    """
    d = np.asarray(points, float).reshape(-1, 3) - np.asarray(origins, float)
    z = np.sum(d * np.asarray(optical_axes, float), axis=-1)
    return float(coefficient) * z[:, None] * d


def _plane_basis(normal: np.ndarray) -> np.ndarray:
    """Two unit vectors spanning the plane orthogonal to ``normal`` (rows), e1 close to world x."""
    n = normal / np.linalg.norm(normal)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - (ref @ n) * n
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)])


def _polygon_axes(xy: np.ndarray) -> np.ndarray:
    """Principal axes (rows, major first) of a convex polygon's area distribution (its PCA)."""
    c = xy.mean(axis=0)
    v = xy - c
    nxt = np.roll(v, -1, axis=0)
    cross = v[:, 0] * nxt[:, 1] - v[:, 1] * nxt[:, 0]
    area = cross.sum() / 2.0
    if abs(area) < 1e-12:  # degenerate hull: PCA of the vertices
        w, vec = np.linalg.eigh(np.cov(v.T))
        return vec[:, ::-1].T
    # second moments of the polygon about c (Green's theorem over its triangles fan)
    sxx = np.sum(cross * (v[:, 0] ** 2 + v[:, 0] * nxt[:, 0] + nxt[:, 0] ** 2)) / 12.0
    syy = np.sum(cross * (v[:, 1] ** 2 + v[:, 1] * nxt[:, 1] + nxt[:, 1] ** 2)) / 12.0
    sxy = (
        np.sum(
            cross
            * (2 * v[:, 0] * v[:, 1] + v[:, 0] * nxt[:, 1] + nxt[:, 0] * v[:, 1] + 2 * nxt[:, 0] * nxt[:, 1])
        )
        / 24.0
    )
    m = np.array([[sxx, sxy], [sxy, syy]]) / area
    cen = np.array([np.sum(cross * (v[:, 0] + nxt[:, 0])), np.sum(cross * (v[:, 1] + nxt[:, 1]))]) / (
        6 * area
    )
    m -= np.outer(cen, cen)
    w, vec = np.linalg.eigh(m)
    return vec[:, ::-1].T


def _closeness(xy: np.ndarray, angles: np.ndarray, percentile: float, d0: float) -> np.ndarray:
    """L-shape fitting "closeness" score of each rectangle orientation (Zhang et al., IV 2017).

    Each point scores ``1 / max(d, d0)`` where ``d`` is its distance to the nearest side of the
    rectangle of robust extents along the angle; the sum peaks when the sides follow the
    visible faces. All angles at once (N points × A angles): one percentile call per axis
    instead of one per angle (benchmarks/shapes.py).
    """
    angles = np.asarray(angles, float)
    # angles × points, each row contiguous (the percentiles' partitions run along memory), in
    # blocks of about 32 k values that stay in cache: one block of a 6000-point window's 201
    # orientations is 9.6 MB per array and ran slower than one orientation at a time
    step = max(1, 32_768 // max(len(xy), 1))
    out = np.empty(len(angles))
    for i in range(0, len(angles), step):
        c, s = np.cos(angles[i : i + step])[:, None], np.sin(angles[i : i + step])[:, None]
        u = c * xy[:, 0] + s * xy[:, 1]
        v = c * xy[:, 1] - s * xy[:, 0]
        (lu, hu), (lv, hv) = _extent(u, percentile), _extent(v, percentile)
        lu, hu, lv, hv = lu[:, None], hu[:, None], lv[:, None], hv[:, None]
        d = np.minimum(np.minimum(np.abs(hu - u), np.abs(u - lu)), np.minimum(np.abs(hv - v), np.abs(v - lv)))
        out[i : i + step] = np.sum(1.0 / np.maximum(d, d0), axis=1)
    return out


#: Points the L-shape search scores orientations with (every k-th of a larger cloud). Its cost is
#: points × 201 orientations; 6000-point windows took a fifth of a house flight's CPU with every
#: furniture class a box. On 20 car views of 6000 points, every 6th point gives the orientation
#: within 0.14° (max 0.35°) of all of them, 5× faster (benchmarks/shapes.py): the search's own
#: error against the truth is 0.15° (max 0.5°).
ORIENTATION_POINTS = 1000


def _lshape_axes(xy: np.ndarray, percentile: float, d0: float = 0.05) -> np.ndarray:
    """Axes (rows) of the rectangle that best follows the visible faces (mod 90°).

    The closeness criterion (:func:`_closeness`) on a 0.5° grid, refined on a 0.05° grid around
    the best. Unlike PCA of the hull or the minimum-area rectangle (ambiguous for a right
    triangle: along a leg or along the hypotenuse gives the same area), it finds the box axes
    from an L-shaped view of two sides as well as from a top view. On 40 random views of a car
    with 3 cm noise: mean error 0.15°, max 0.5° (PCA of the hull: 1.5°, max 13°).
    """
    grid = np.radians(np.arange(0.0, 90.0, 0.5))
    a0 = grid[int(np.argmax(_closeness(xy, grid, percentile, d0)))]
    fine = a0 + np.radians(np.arange(-0.5, 0.5001, 0.05))
    a = float(fine[int(np.argmax(_closeness(xy, fine, percentile, d0)))])
    return np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])


# -------------------------------------------------------------------------------------------
# cuboids
# -------------------------------------------------------------------------------------------
def _footprint_axis(xy: np.ndarray, axis: str, percentile: float, extrapolate: bool) -> np.ndarray | None:
    """The footprint's longitudinal direction (2-D unit vector) by ``axis`` (:func:`fit_cuboid`);
    None when the points span no area (no convex hull)."""
    from scipy.spatial import ConvexHull, QhullError

    if axis not in ("pca", "lshape"):
        raise ValueError(f"axis must be 'pca' or 'lshape', not {axis!r}")
    try:
        hull = ConvexHull(xy)
    except (QhullError, ValueError):
        return None
    if axis == "pca":
        return _polygon_axes(xy[hull.vertices])[0]
    # orientation (mod 90°) by L-shape fitting; longitudinal = the larger robust span
    rect = _lshape_axes(xy[:: -(-len(xy) // ORIENTATION_POINTS)], percentile)
    u = xy @ rect.T
    spans = [np.subtract(*_extent(u[:, k], percentile, extrapolate)[::-1]) for k in range(2)]
    return rect[int(np.argmax(spans))]


def _footprint_extents(
    xy: np.ndarray,
    a1: np.ndarray,
    percentile: float,
    extrapolate: bool,
    spread: Callable[[np.ndarray], np.ndarray | None],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, float, float, float]]:
    """The footprint's axes ``a1`` (the longer side), ``a2``, the projections on ``a1`` and the
    extents ``(lo1, hi1, lo2, hi2)`` along them (past each point's ``spread`` when given)."""
    a2 = np.array([-a1[1], a1[0]])
    u1, u2 = xy @ a1, xy @ a2
    lo1, hi1 = _extent(u1, percentile, extrapolate, spread(a1))
    lo2, hi2 = _extent(u2, percentile, extrapolate, spread(a2))
    if hi2 - lo2 > hi1 - lo1:  # keep b1 the longer side: a turn by 90°, the extents with it
        a1, a2, u1 = a2, -a1, u2
        lo1, hi1, lo2, hi2 = lo2, hi2, -hi1, -lo1
    return a1, a2, u1, (lo1, hi1, lo2, hi2)


def fit_cuboid(
    points: np.ndarray,
    ground: GroundPlane | None = None,
    *,
    percentile: float = 1.0,
    extrapolate: bool = True,
    axis: str = "lshape",
    facing: str = "lower_front",
    min_points: int = 20,
    noise: np.ndarray | None = None,
) -> dict | None:
    """Fit an object-aligned cuboid to the points of one instance (§IV-A).

    Args:
        points: N×3 points of the instance (gravity-aligned frame).
        ground: the local ground plane; its normal is the vertical axis ``b3`` and the box rests
            on it. ``None``: a level ground under the lowest points (vertical axis = z).
        percentile: the ``p``-th and ``(100−p)``-th percentiles bound the projections.
        extrapolate: extrapolate those percentiles to the edges (module docstring). The paper's
            recipe is ``percentile=5, extrapolate=False``; the default ``1, True`` measured
            better (``docs/objects.md``).
        axis: ``"pca"`` (the paper's PCA of the 2-D convex hull) or ``"lshape"`` (the rectangle
            orientation that best follows the visible faces; right on L-shaped partial views).
        facing: ``"lower_front"`` — the longitudinal axis points to the lower end (a vehicle's
            front is lower than its rear); ``"none"`` — keep the sign PCA gives.
        min_points: fewer points give ``None``.
        noise: each point's noise vector (N×3, :func:`depth_noise`), or ``None``. With it the
            extents are taken past each point's noise along the box's axes (:func:`_extent`):
            a depth camera's noise grows as z², and at 6 m its tails put the percentile edges of
            a car 0.3–0.4 m beyond the faces (a merged map's cars 0.6 m too wide, the overhead
            robot's seen from 5 m; with the true poses and the noise: 0.69 → 0.10 m length and
            width error, docs/multirobot.md).

    Returns:
        A cuboid shape dict (module docstring) or ``None``.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    if len(p) < min_points:
        return None
    n = ground.normal if ground is not None else UP
    basis = _plane_basis(n)
    xy = p @ basis.T  # coordinates in the ground plane
    noise_xy = None if noise is None else np.asarray(noise, float).reshape(-1, 3) @ basis.T
    noise_h = None if noise is None else np.abs(np.asarray(noise, float).reshape(-1, 3) @ n)

    def spread(axis: np.ndarray) -> np.ndarray | None:
        return None if noise_xy is None else np.abs(noise_xy @ axis)

    h = ground.height(p) if ground is not None else p[:, 2]
    a1 = _footprint_axis(xy, axis, percentile, extrapolate)
    if a1 is None:
        return None
    if noise_xy is not None:
        a1 = _least_area_axis(xy, a1, percentile, extrapolate, spread)
    a1, a2, u1, (lo1, hi1, lo2, hi2) = _footprint_extents(xy, a1, percentile, extrapolate, spread)
    if facing == "lower_front":
        mid = 0.5 * (lo1 + hi1)
        front, rear = h[u1 > mid], h[u1 <= mid]
        if len(front) >= 3 and len(rear) >= 3 and np.percentile(front, 90) > np.percentile(rear, 90):
            a1, a2 = -a1, -a2
            lo1, hi1, lo2, hi2 = -hi1, -lo1, -hi2, -lo2
    elif facing != "none":
        raise ValueError(f"facing must be 'lower_front' or 'none', not {facing!r}")
    _, top = _extent(h, percentile, extrapolate, noise_h)
    bottom = 0.0 if ground is not None else _extent(h, percentile, extrapolate, noise_h)[0]
    b1 = basis.T @ a1
    b2 = np.cross(n, b1)
    # centre of the footprint, on the ground plane (on z = 0 without one: then h = z)
    c_plane = basis.T @ ((0.5 * (lo1 + hi1)) * a1 + (0.5 * (lo2 + hi2)) * a2)
    foot = c_plane - n * (ground.offset if ground is not None else 0.0)
    centre = foot + n * (0.5 * (bottom + top))
    R = np.column_stack([b1, b2, n])
    return cuboid_shape(R, centre, [hi1 - lo1, hi2 - lo2, top - bottom])


def seat_seen_faces(
    shape: dict,
    points: np.ndarray,
    cameras: np.ndarray,
    *,
    band: float = 0.6,
    bin_width: float = 0.05,
    prominence: float = 1.2,
) -> dict:
    """Move each vertical face of a fitted box that every camera saw head-on onto its points.

    A depth camera's noise lies along its rays (σ ∝ depth² for a stereo camera). A face seen
    head-on stacks its points on one line of the footprint, and the noise spreads them on
    both sides of it: the ones pushed toward the camera fall outside the box, the others
    inside among the roof's. :func:`fit_cuboid`'s low percentile is therefore the noise's
    outer tail, and every box lies on its cameras' side — by 0.1 m at 3 m and 0.6 m at 9 m
    on the simulated D435i's PAMS flights (``docs/pams.md``), a bias of every measurement
    toward the robot that drags the key poses along its path. The face itself is where the
    points crowd: per horizontal box axis whose one face all ``cameras`` are beyond, the
    densest ``bin_width`` slice (smoothed) within ``band`` inside that face's fitted position
    (its points' mean with the slices on either side) becomes the face if it stands out (at
    least ``prominence`` × the band's median density), so a roof seen from above, evenly
    spread, keeps its percentile edge. The far face and the height are kept
    (:func:`complete_cuboid` places the far face behind a seen one).

    Args:
        shape: a cuboid fitted to ``points`` (:func:`fit_cuboid`).
        points: the N×3 points it was fitted to (same frame).
        cameras: K×3 positions of the cameras the points were seen from (same frame).

    Returns:
        The box with its seen faces moved (the same dict when none moved).
    """
    R = np.asarray(shape["rotation"], float)
    c = np.asarray(shape["center"], float)
    d = np.asarray(shape["dims"], float)
    u = (np.asarray(points, float).reshape(-1, 3) - c) @ R
    local = (np.asarray(cameras, float).reshape(-1, 3) - c) @ R
    lo, hi = -d / 2, d / 2
    moved = False
    for a in (0, 1):
        for sign in (1.0, -1.0):
            face = hi[a] if sign > 0 else lo[a]
            if not np.all(sign * local[:, a] > sign * face):
                continue
            depth_in = sign * (face - u[:, a])  # how far inside the face each point lies
            x = depth_in[(depth_in >= 0) & (depth_in < band)]
            if len(x) < 20:
                continue
            counts, edges = np.histogram(x, bins=int(round(band / bin_width)), range=(0.0, band))
            smooth = np.convolve(counts, [1.0, 2.0, 1.0], "same") / 4.0
            k = int(np.argmax(smooth))
            if smooth[k] < prominence * max(float(np.median(smooth)), 1e-9):
                continue
            near_peak = x[(x >= edges[max(k - 1, 0)]) & (x < edges[min(k + 2, len(edges) - 1)])]
            shift = float(np.mean(near_peak))  # within the peak: finer than the bins
            if sign > 0:
                hi[a] -= shift
            else:
                lo[a] += shift
            moved = True
    if not moved:
        return shape
    mid = 0.5 * (lo + hi)
    mid[2] = 0.0
    return cuboid_shape(R, c + R @ mid, [hi[0] - lo[0], hi[1] - lo[1], d[2]])


@dataclass(frozen=True)
class Completion:
    """A partial cuboid view completed with a class size prior (:func:`complete_cuboid`).

    Attributes:
        shape: the completed box (same frame as the input).
        measured: the fitted dims before completion (along the box axes ``b1, b2, b3``).
        missing: per box axis, how much the fitted extent lacks against the prior (≥ 0, m).
        extended: per box axis, whether the box was extended behind its visible faces.
        ambiguous: per box axis, whether the extent is short but the missing side is unknown
            (every camera looked from within the box's slab along that axis).
        swapped: whether the box's ``b1`` is the object's width (the prior was applied as
            ``[width, length, height]``).
    """

    shape: dict
    measured: np.ndarray
    missing: np.ndarray
    extended: np.ndarray
    ambiguous: np.ndarray
    swapped: bool = False


def complete_cuboid(
    shape: dict,
    cameras: np.ndarray,
    prior: np.ndarray | list[float],
    *,
    reference: dict | None = None,
    tolerance: float = 0.15,
) -> Completion:
    """Place a box fitted to a partial view *behind* its visible faces, with a class size prior.

    A depth camera sees at most the faces of a box that face it. When the far end of an object
    is out of view (cut by the image, the range limit or a neighbour), the fitted box spans only
    the visible part and its centre sits on the camera's side — for every car seen along a lane,
    the same way, which drags the key poses. Along each horizontal box axis whose fitted extent
    falls short of the prior by more than ``tolerance``:

    * if every camera of the window was beyond one face (outside the box's slab along the axis,
      on the same side), that face was seen and the missing part lies behind: the far face is
      put at the prior's distance from the seen one (centre moved away from the cameras by half
      the shortfall, the dimension set to the prior's);
    * if cameras were beyond both faces, both were seen: the object is this short, kept;
    * if no camera was beyond either face (looking across the axis, the extent cut by the image),
      the missing side is unknown: kept, flagged ``ambiguous`` (its noise must cover it).

    The height is not completed (seen from above; the bottom is on the ground plane).

    Args:
        shape: a cuboid fitted by :func:`fit_cuboid` (``b1`` the longer fitted side).
        cameras: K×3 camera positions of the views the points came from (same frame).
        prior: the class's typical ``[length, width, height]`` (length ≥ width).
        reference: a shape of the same object (same frame), e.g. the current estimate: if it is
            elongated (long side ≥ 1.5 × short side), its longer horizontal axis tells which
            fitted axis is the length — unless the fitted extent along one is longer than the
            prior's width: that one is. Without either cue, a box seen end-on (mean viewing
            direction within 30° of a box axis) takes that axis as its length — a car seen
            end-on shows its full width across the view; otherwise nothing is extended and the
            short axes are flagged ``ambiguous``.
        tolerance: shortfalls up to this are measurement noise, not missing parts (m).
    """
    R = np.asarray(shape["rotation"], float)
    c = np.asarray(shape["center"], float)
    d = np.asarray(shape["dims"], float)
    pr = np.asarray(prior, float).copy()
    cams = np.asarray(cameras, float).reshape(-1, 3)
    local = (cams - c) @ R  # camera positions along b1, b2, b3
    swapped, decided = _length_axis(R, d, pr, local, reference, tolerance)
    if swapped:
        pr[[0, 1]] = pr[[1, 0]]
    missing = np.zeros(3)
    extended = np.zeros(3, bool)
    ambiguous = np.zeros(3, bool)
    c_new, d_new = c.copy(), d.copy()
    for a in (0, 1):
        need = pr[a] - d[a]
        if need <= tolerance:
            continue
        beyond = np.abs(local[:, a]) > d[a] / 2
        pos, neg = bool(np.any(beyond & (local[:, a] > 0))), bool(np.any(beyond & (local[:, a] < 0)))
        if pos and neg:
            continue
        missing[a] = need
        if (pos or neg) and decided:
            c_new -= (1.0 if pos else -1.0) * 0.5 * need * R[:, a]
            d_new[a] = pr[a]
            extended[a] = True
        else:
            ambiguous[a] = True
    out = cuboid_shape(R, c_new, d_new) if extended.any() else shape
    return Completion(out, d, missing, extended, ambiguous, bool(swapped))


def _length_axis(
    R: np.ndarray,
    d: np.ndarray,
    prior: np.ndarray,
    local: np.ndarray,
    reference: dict | None,
    tolerance: float,
) -> tuple[bool, bool]:
    """Which fitted horizontal axis of :func:`complete_cuboid`'s box is the object's length.

    A fitted extent longer than the object is wide is; else an elongated reference's longer
    axis; else, for a first view of one end, the axis within 30° of the viewing direction
    (``local``: the cameras in box axes). Without a clear cue nothing is extended (a box grown
    along the wrong axis would cover the car in the next stall).

    Returns:
        Whether ``b2`` (not ``b1``) is the length, and whether a cue decided it.
    """
    dr = None if reference is None else np.asarray(reference["dims"], float)
    if d[0] > prior[1] + 2 * tolerance:
        return False, True
    if dr is not None and max(dr[:2]) >= 1.5 * min(dr[:2]):
        length = np.asarray(reference["rotation"], float)[:, int(np.argmax(dr[:2]))]
        return bool(abs(R[:, 0] @ length) < abs(R[:, 1] @ length)), True
    if len(local):
        view = np.abs(np.mean(local[:, :2], axis=0))  # mean viewing direction, box axes
        return bool(view[1] > view[0]), bool(max(view) >= np.tan(np.radians(60.0)) * min(view))
    return False, False


def cuboid_shape(R: np.ndarray, center: np.ndarray, dims: np.ndarray | list[float]) -> dict:
    """A cuboid shape dict from its rotation ``[b1 b2 b3]``, centre and dimensions."""
    R = np.asarray(R, float)
    return {
        "model": "cuboid",
        "center": [float(x) for x in np.asarray(center, float)],
        "yaw": float(np.arctan2(R[1, 0], R[0, 0])),
        "dims": [float(x) for x in np.asarray(dims, float)],
        "rotation": np.round(R, 12).tolist(),
    }


def points_inside(shape: dict, pts: np.ndarray, margin: float) -> np.ndarray:
    """Which points (N×3) lie inside a cuboid / cylinder shape inflated by ``margin``."""
    if shape["model"] == "cuboid":
        T = cuboid_pose(shape)
        local = (pts - T[:3, 3]) @ T[:3, :3]
        return np.all(np.abs(local) <= np.asarray(shape["dims"]) / 2 + margin, axis=1)
    root, n = np.asarray(shape["root"]), np.asarray(shape["axis"])
    v = pts - root
    along = v @ n
    radial = np.linalg.norm(v - np.outer(along, n), axis=1)
    return (radial <= shape["radius"] + margin) & (along >= -margin)


def cuboid_pose(shape: dict) -> np.ndarray:
    """4×4 pose ``T_frame_cuboid`` of a cuboid shape (from ``rotation``, or ``yaw`` if absent)."""
    T = np.eye(4)
    if "rotation" in shape:
        T[:3, :3] = np.asarray(shape["rotation"], float)
    else:
        T[:3, :3] = yaw_matrix(shape["yaw"])
    T[:3, 3] = shape["center"]
    return T


# -------------------------------------------------------------------------------------------
# cylinders
# -------------------------------------------------------------------------------------------
def _circle_fit(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Robust circle fit: algebraic (Kåsa) start, then geometric least squares with a soft-L1 loss.

    Kåsa's linear fit is biased on the half-circle arcs a single view sees; the geometric
    refinement (scipy ``least_squares``) removes the bias and the soft-L1 loss down-weights
    stray points (a sign, a branch).
    """
    from scipy.optimize import least_squares

    A = np.column_stack([2 * xy, np.ones(len(xy))])
    b = (xy**2).sum(axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c0 = sol[:2]
    r0 = float(np.sqrt(max(sol[2] + c0 @ c0, 1e-6)))
    scale = max(r0, 0.02)

    def resid(x: np.ndarray) -> np.ndarray:
        return np.linalg.norm(xy - x[:2], axis=1) - x[2]

    res = least_squares(resid, np.array([*c0, r0]), loss="soft_l1", f_scale=0.1 * scale)
    return res.x[:2], float(abs(res.x[2]))


def fit_cylinder(
    points: np.ndarray,
    ground: GroundPlane | None = None,
    *,
    axis: str = "vertical",
    percentile: float = 1.0,
    min_points: int = 15,
) -> dict | None:
    """Fit an upright cylinder (pole, tree trunk) to the points of one instance.

    Args:
        points: N×3 points of the instance (gravity-aligned frame).
        ground: local ground plane; the root is where the axis meets it. ``None``: a level
            ground under the lowest points.
        axis: ``"vertical"`` — gravity (z; poles and trunks stand upright even on a slope, and
            the IMU gives gravity); ``"ground"`` — the local ground normal; ``"pca"`` — the
            first principal direction of the points (leaning trunks), oriented up.
        percentile: the top of the cylinder is the ``(100−p)``-th percentile of heights along the
            axis, extrapolated to the edge.
        min_points: fewer points give ``None``.

    Returns:
        A cylinder shape dict (module docstring) or ``None``.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    if len(p) < min_points:
        return None
    if axis == "vertical":
        n = UP
    elif axis == "ground":
        n = ground.normal if ground is not None else UP
    elif axis == "pca":
        _, _, vt = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)
        n = vt[0] if vt[0, 2] >= 0 else -vt[0]
    else:
        raise ValueError(f"axis must be 'vertical', 'ground' or 'pca', not {axis!r}")
    basis = _plane_basis(n)
    xy = p @ basis.T
    c2, r = _circle_fit(xy)
    along = p @ n
    on_axis = basis.T @ c2  # a point of the axis (its component along n is zero)
    if ground is not None:
        root = ground.intersect(on_axis, n)
    else:
        lo, _ = _extent(along, percentile)
        root = on_axis + lo * n
    _, hi = _extent(along, percentile)
    return cylinder_shape(root, n, r, hi - float(root @ n))


def cylinder_shape(root: np.ndarray, axis: np.ndarray, radius: float, height: float) -> dict:
    """A cylinder shape dict (the axis is normalised and turned to point up)."""
    n = np.asarray(axis, float)
    n = n / np.linalg.norm(n)
    if n[2] < 0:
        n = -n
    return {
        "model": "cylinder",
        "root": [float(x) for x in np.asarray(root, float)],
        "axis": [float(x) for x in n],
        "radius": float(radius),
        "height": float(height),
    }


# -------------------------------------------------------------------------------------------
# whole clouds, frames, comparisons
# -------------------------------------------------------------------------------------------
def fit_shapes(
    points: np.ndarray,
    model: str,
    ground_points: np.ndarray | None = None,
    *,
    eps: float = 0.5,
    min_samples: int = 10,
    ground_radius: float = 4.0,
    **kwargs: object,
) -> list[dict]:
    """DBSCAN the points of one class into instances and fit ``model`` to each.

    Args:
        points: N×3 points labelled with one class (gravity-aligned frame).
        model: ``"cuboid"`` or ``"cylinder"``.
        ground_points: points labelled as ground, for the local ground plane of each instance.
        eps, min_samples: DBSCAN parameters.
        ground_radius: ground points within this horizontal distance of an instance count.
        **kwargs: passed to :func:`fit_cuboid` / :func:`fit_cylinder`.

    Returns:
        One shape per instance that could be fitted, largest cluster first.
    """
    if model not in ("cuboid", "cylinder"):
        raise ValueError(f"model must be 'cuboid' or 'cylinder', not {model!r}")
    fit = fit_cuboid if model == "cuboid" else fit_cylinder
    out = []
    for idx in cluster(points, eps, min_samples):
        q = np.asarray(points, float)[idx]
        ground = local_ground(ground_points, q.mean(axis=0), ground_radius)
        s = fit(q, ground, **kwargs)  # type: ignore[arg-type]
        if s is not None:
            out.append(s)
    return out


def shape_center(shape: dict) -> np.ndarray:
    """The reference point of a shape: a cuboid's centre, a cylinder's root (paper 2 §IV-B2)."""
    return np.asarray(shape["center"] if shape["model"] == "cuboid" else shape["root"], float)


def transform_shape(shape: dict, T: np.ndarray) -> dict:
    """The shape expressed in frame *a*, given the shape in frame *b* and ``T = T_a_b``."""
    T = np.asarray(T, float)
    if shape["model"] == "cuboid":
        P = T @ cuboid_pose(shape)
        return cuboid_shape(P[:3, :3], P[:3, 3], shape["dims"])
    if shape["model"] == "cylinder":
        root = T[:3, :3] @ np.asarray(shape["root"], float) + T[:3, 3]
        out = cylinder_shape(
            root, T[:3, :3] @ np.asarray(shape["axis"], float), shape["radius"], shape["height"]
        )
        return out
    raise ValueError(f"unknown shape model {shape.get('model')!r}")


def shape_errors(est: dict, true: dict) -> dict[str, float]:
    """Errors of an estimated shape against the truth (same model).

    Returns:
        ``dims`` — mean absolute dimension error (|d_est − d_true| averaged over the dimensions:
        l, w, h for a cuboid; the diameter for a cylinder, whose height is reported apart as
        ``height``, since the paper's cylinder has none); for a cuboid also ``length`` and
        ``width`` — the absolute errors of its longer and shorter horizontal side (paper 2 §VI-B:
        "the accuracy of width and length estimates", the error of Figs. 9–11); ``position``
        — distance between the reference points (:func:`shape_center`); ``yaw`` — heading error
        of a cuboid modulo π (a box is symmetric under a half turn), ``axis`` — angle between
        cylinder axes (rad).
    """
    if est["model"] != true["model"]:
        raise ValueError(f"cannot compare a {est['model']} with a {true['model']}")
    out: dict[str, float] = {"position": float(np.linalg.norm(shape_center(est) - shape_center(true)))}
    if est["model"] == "cuboid":
        de, dt = np.asarray(est["dims"], float), np.asarray(true["dims"], float)
        dyaw = wrap_angle(est["yaw"] - true["yaw"])
        # a half turn is the same box; a quarter turn with length and width swapped is too
        cands = [(abs(wrap_angle(dyaw - k * np.pi)), de) for k in (0, 1, -1)]
        cands += [(abs(wrap_angle(dyaw - k * np.pi / 2)), de[[1, 0, 2]]) for k in (1, -1)]
        err, dims = min(cands, key=lambda c: c[0] + np.mean(np.abs(c[1] - dt)))
        out["yaw"] = float(err)
        out["dims"] = float(np.mean(np.abs(dims - dt)))
        # paper 2 §VI-B, Figs. 9-11: the length and width of a vehicle (its longer and shorter
        # horizontal side, whatever the box's heading)
        (we, le), (wt, lt) = np.sort(de[:2]), np.sort(dt[:2])
        out["length"], out["width"] = float(abs(le - lt)), float(abs(we - wt))
    else:
        # the paper's cylinder state has no height (the top of a pole is rarely in view)
        out["dims"] = float(abs(2 * est["radius"] - 2 * true["radius"]))
        out["height"] = float(abs(est["height"] - true["height"]))
        out["axis"] = float(np.arccos(np.clip(np.dot(est["axis"], true["axis"]), -1.0, 1.0)))
    return out
