"""Shape fitting (paper 2 §IV-A) on synthetic clouds with noise and partial views."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib import shapes as S  # noqa: N812


def rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def box_points(
    R: np.ndarray, center: np.ndarray, dims: np.ndarray, viewer: np.ndarray, rng: np.random.Generator,
    n: int = 3000, noise: float = 0.02,
) -> np.ndarray:  # fmt: skip
    """Points on the faces of a box that face ``viewer`` (the bottom never), with noise."""
    half = np.asarray(dims, float) / 2
    v = R.T @ (np.asarray(viewer, float) - center)
    faces = [(ax, sg) for ax in range(3) for sg in (1, -1) if not (ax == 2 and sg < 0)]
    vis = [(ax, sg) for ax, sg in faces if v[ax] * sg > half[ax]]
    area = [np.prod(np.delete(2 * half, ax)) for ax, _ in vis]
    pts = []
    for (ax, sg), a in zip(vis, area, strict=True):
        u = rng.uniform(-1, 1, (int(n * a / sum(area)), 3)) * half
        u[:, ax] = sg * half[ax]
        pts.append(u)
    p = np.concatenate(pts) @ R.T + center
    return p + rng.normal(0, noise, p.shape)


def car_points(yaw: float, viewer: np.ndarray, rng: np.random.Generator, **kw: float) -> np.ndarray:
    """A car-like body: a low hood box in front (+x) and a taller cabin box behind."""
    R = rz(yaw)
    body = box_points(R, R @ [0.0, 0, 0.5] + [2, 1, 0], np.array([4.5, 1.8, 1.0]), viewer, rng, **kw)
    cabin = box_points(R, R @ [-0.6, 0, 1.25] + [2, 1, 0], np.array([2.4, 1.7, 0.5]), viewer, rng, **kw)
    # hidden parts of the body behind the cabin would be occluded; keep it simple: drop the body's
    # top points under the cabin
    local = (body - [2, 1, 0]) @ R
    keep = ~((local[:, 2] > 0.95) & (np.abs(local[:, 0] + 0.6) < 1.2) & (np.abs(local[:, 1]) < 0.85))
    return np.concatenate([body[keep], cabin])


def cylinder_points(
    root: np.ndarray, radius: float, height: float, viewer: np.ndarray, rng: np.random.Generator,
    n: int = 1500, noise: float = 0.015,
) -> np.ndarray:  # fmt: skip
    th = rng.uniform(0, 2 * np.pi, 4 * n)
    z = rng.uniform(0, height, 4 * n)
    nrm = np.column_stack([np.cos(th), np.sin(th), np.zeros_like(th)])
    p = np.asarray(root, float) + radius * nrm + np.outer(z, [0, 0, 1.0])
    vis = np.einsum("ij,ij->i", nrm, np.asarray(viewer, float) - p) > 0
    p = p[vis][:n]
    return p + rng.normal(0, noise, p.shape)


def ground_points(rng: np.random.Generator, normal: np.ndarray, offset: float, n: int = 1500) -> np.ndarray:
    xy = rng.uniform(-6, 10, (n, 2))
    z = -(offset + xy @ normal[:2]) / normal[2]
    return np.column_stack([xy, z + rng.normal(0, 0.01, n)])


# ---------------------------------------------------------------------------------------------
#: viewers in the box frame (x forward): each sees at least two faces
VIEWERS = [
    np.array([7.0, 5.0, 2.5]),  # oblique from above: top and two sides
    np.array([-5.0, 4.0, -0.25]),  # low: two sides only (L-shaped view)
    np.array([0.3, 0.2, 6.0]),  # straight above: the top (and barely the sides)
]


@pytest.mark.parametrize("viewer", VIEWERS, ids=["oblique", "low", "overhead"])
@pytest.mark.parametrize("yaw", [0.3, 1.2, -2.4])
def test_cuboid_partial_views(yaw: float, viewer: np.ndarray) -> None:
    rng = np.random.default_rng(11)
    R = rz(yaw)
    center, dims = np.array([2.0, 1.0, 0.75]), np.array([4.5, 1.8, 1.5])
    pts = box_points(R, center, dims, center + R @ viewer, rng)
    s = S.fit_cuboid(pts, S.GroundPlane.horizontal(0.0), facing="none")
    assert s is not None
    err = S.shape_errors(s, S.cuboid_shape(R, center, dims))
    assert err["yaw"] < np.radians(1.0)
    assert err["dims"] < 0.05  # 2 cm noise on each face, so ~2 cm per edge
    assert err["position"] < 0.05


def test_paper_percentiles_shrink_the_box() -> None:
    """Raw 5th–95th percentiles (the paper's recipe) lose ~10 % of a top view's length and width."""
    rng = np.random.default_rng(3)
    R, center, dims = rz(0.5), np.array([0.0, 0.0, 0.75]), np.array([4.5, 1.8, 1.5])
    pts = box_points(R, center, dims, center + [0.1, 0.1, 8.0], rng)
    raw = S.fit_cuboid(pts, S.GroundPlane.horizontal(0.0), percentile=5, extrapolate=False, facing="none")
    ours = S.fit_cuboid(pts, S.GroundPlane.horizontal(0.0), facing="none")
    assert raw is not None and ours is not None
    assert raw["dims"][0] == pytest.approx(0.9 * 4.5, abs=0.05)
    assert ours["dims"][0] == pytest.approx(4.5, abs=0.04)


def test_pca_axis_fails_on_l_shaped_views_and_lshape_does_not() -> None:
    """The paper's PCA of the hull points along the diagonal of an L-shaped (two-side) view."""
    rng = np.random.default_rng(2)
    R, center, dims = rz(1.2), np.array([2.0, 1.0, 0.75]), np.array([4.5, 1.8, 1.5])
    pts = box_points(R, center, dims, np.array([8.0, 5.0, 1.0]), rng)
    truth = S.cuboid_shape(R, center, dims)
    pca = S.shape_errors(S.fit_cuboid(pts, S.GroundPlane.horizontal(0.0), axis="pca", facing="none"), truth)
    lsh = S.shape_errors(S.fit_cuboid(pts, S.GroundPlane.horizontal(0.0), facing="none"), truth)
    assert pca["yaw"] > np.radians(8.0)
    assert lsh["yaw"] < np.radians(1.0)


def test_percentile_extrapolation_removes_the_shrinkage() -> None:
    """Uniform points over [0, 4]: the raw 5–95 % span is 3.6, the extrapolated one 4."""
    x = np.linspace(0.0, 4.0, 2001)
    lo, hi = S._extent(x, 5.0)
    assert hi - lo == pytest.approx(4.0, abs=1e-6)


@pytest.mark.parametrize("yaw", [0.4, 2.0, -1.0])
def test_car_facing_and_dims_with_sloped_ground(yaw: float) -> None:
    """A car on a 4° slope: the vertical axis follows the ground, the front is the lower hood."""
    rng = np.random.default_rng(4)
    tilt = np.radians(4.0)
    normal = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    # rotate the whole (level-ground) scene so that z becomes ``normal``
    k = np.cross([0, 0, 1.0], normal)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]]) / np.linalg.norm(k)
    Rt = np.eye(3) + np.sin(tilt) * K + (1 - np.cos(tilt)) * K @ K
    viewer = np.array([8.0, -4.0, 4.0])
    pts = car_points(yaw, Rt.T @ viewer, rng) @ Rt.T
    ground = S.fit_plane(ground_points(rng, normal, 0.0) @ np.eye(3))
    assert ground is not None and np.degrees(np.arccos(ground.normal[2])) == pytest.approx(4.0, abs=0.2)
    s = S.fit_cuboid(pts, ground)
    assert s is not None
    R_true = Rt @ rz(yaw)
    truth = S.cuboid_shape(R_true, Rt @ np.array([2, 1, 0.75]), [4.5, 1.8, 1.5])
    err = S.shape_errors(s, truth)
    assert err["dims"] < 0.06
    assert err["position"] < 0.1
    # facing: b1 points to the front (no half-turn ambiguity for a car)
    assert np.dot(np.asarray(s["rotation"])[:, 0], R_true[:, 0]) > 0.99
    assert np.dot(np.asarray(s["rotation"])[:, 2], normal) > 0.999


def test_cylinder_fit_root_radius_height() -> None:
    rng = np.random.default_rng(5)
    for r in (0.08, 0.2, 0.35):
        pts = cylinder_points([1.0, 2.0, 0.2], r, 4.0, np.array([4.0, -1.0, 2.0]), rng)
        s = S.fit_cylinder(pts, S.GroundPlane.horizontal(0.2))
        assert s is not None
        err = S.shape_errors(s, S.cylinder_shape([1.0, 2.0, 0.2], [0, 0, 1], r, 4.0))
        assert err["position"] < 0.03
        assert s["radius"] == pytest.approx(r, abs=0.02)
        assert s["height"] == pytest.approx(4.0, abs=0.06)


def test_leaning_trunk_with_pca_axis() -> None:
    rng = np.random.default_rng(6)
    lean = np.radians(8.0)
    R = np.array([[np.cos(lean), 0, np.sin(lean)], [0, 1, 0], [-np.sin(lean), 0, np.cos(lean)]])
    pts = cylinder_points([0.0, 0.0, 0.0], 0.2, 3.0, np.array([0.0, -4.0, 1.5]), rng) @ R.T
    s = S.fit_cylinder(pts + [3.0, 3.0, 0.0], S.GroundPlane.horizontal(0.0), axis="pca")
    assert s is not None
    assert np.degrees(np.arccos(s["axis"][2])) == pytest.approx(8.0, abs=1.0)
    assert np.linalg.norm(np.asarray(s["root"]) - [3.0, 3.0, 0.0]) < 0.06


def test_dbscan_splits_instances_and_fits_each() -> None:
    rng = np.random.default_rng(7)
    viewer = np.array([6.0, 12.0, 4.0])
    cars = [
        (np.array([0.0, 0.0, 0.75]), 0.1),
        (np.array([0.0, 3.0, 0.75]), 0.1),
        (np.array([6.0, 0.0, 0.75]), 1.6),
    ]
    pts = np.concatenate([box_points(rz(y), c, np.array([4.5, 1.8, 1.5]), viewer, rng) for c, y in cars])
    ground = ground_points(rng, np.array([0.0, 0.0, 1.0]), 0.0)
    shapes = S.fit_shapes(pts, "cuboid", ground, eps=0.4, facing="none")
    assert len(shapes) == 3
    for c, y in cars:
        best = min(shapes, key=lambda s: np.linalg.norm(S.shape_center(s) - c))
        err = S.shape_errors(best, S.cuboid_shape(rz(y), c, [4.5, 1.8, 1.5]))
        assert err["dims"] < 0.06 and err["yaw"] < np.radians(2.0)


def test_transform_shape_round_trip() -> None:
    T = np.eye(4)
    T[:3, :3] = rz(0.9)
    T[:3, 3] = [1.0, -2.0, 0.5]
    cub = S.cuboid_shape(rz(0.3), [1, 2, 3], [4, 2, 1])
    back = S.transform_shape(S.transform_shape(cub, T), np.linalg.inv(T))
    assert back["center"] == pytest.approx(cub["center"]) and back["yaw"] == pytest.approx(0.3)
    assert S.transform_shape(cub, T)["yaw"] == pytest.approx(1.2)
    cyl = S.cylinder_shape([1, 1, 0], [0, 0, 1], 0.2, 3.0)
    moved = S.transform_shape(cyl, T)
    assert S.shape_center(moved) == pytest.approx(T[:3, :3] @ [1, 1, 0] + T[:3, 3])


def test_shape_errors_symmetries() -> None:
    truth = S.cuboid_shape(rz(0.2), [0, 0, 0.7], [4.0, 2.0, 1.4])
    flipped = S.cuboid_shape(rz(0.2 + np.pi), [0, 0, 0.7], [4.1, 2.0, 1.4])
    turned = S.cuboid_shape(rz(0.2 + np.pi / 2), [0, 0, 0.7], [2.0, 4.0, 1.4])
    assert S.shape_errors(flipped, truth)["yaw"] == pytest.approx(0.0, abs=1e-9)
    assert S.shape_errors(flipped, truth)["dims"] == pytest.approx(0.1 / 3)
    assert S.shape_errors(turned, truth)["dims"] == pytest.approx(0.0, abs=1e-9)
    off = S.cuboid_shape(rz(0.5), [0, 0, 0.7], [4.0, 2.0, 1.4])
    assert S.shape_errors(off, truth)["yaw"] == pytest.approx(0.3)


# ---------------------------------------------------------------------------------------------
# completion of partial views with a class size prior


def _truncated_view(yaw: float, viewer_local: np.ndarray, keep_x: float, rng: np.random.Generator):
    """A 4.6 × 1.85 × 1.5 m box seen from ``viewer_local`` (box frame), with only the points
    whose box-frame x ≥ ``keep_x`` in view (the rest cut by the image): returns the points, the
    viewer (world) and the true centre."""
    R = rz(yaw)
    centre, dims = np.array([2.0, 1.0, 0.75]), np.array([4.6, 1.85, 1.5])
    viewer = R @ viewer_local + centre
    p = box_points(R, centre, dims, viewer, rng)
    p = p[(p - centre) @ R[:, 0] >= keep_x]
    return p, viewer, centre


@pytest.mark.parametrize("yaw", [0.3, -2.4])
def test_end_on_view_is_completed_behind_the_visible_faces(yaw: float) -> None:
    rng = np.random.default_rng(5)
    # a camera 4 m ahead of the front, 2.75 m above the roof: the front face and the front 2 m
    p, viewer, centre = _truncated_view(yaw, np.array([6.3, 0.4, 2.75]), 0.3, rng)
    fit = S.fit_cuboid(p, percentile=2.5, extrapolate=False)
    assert (
        fit is not None and np.linalg.norm(S.shape_center(fit)[:2] - centre[:2]) > 0.9
    )  # on the camera's side
    done = S.complete_cuboid(fit, viewer[None], [4.6, 1.85, 1.5])
    assert done.extended[0] and not done.extended[1] and not done.ambiguous.any()
    assert np.linalg.norm(S.shape_center(done.shape)[:2] - centre[:2]) < 0.12
    assert max(done.shape["dims"][:2]) == pytest.approx(4.6)
    # the prior's length overshoots a shorter car by the difference, not more
    short = S.complete_cuboid(fit, viewer[None], [5.0, 1.85, 1.5])
    assert np.linalg.norm(S.shape_center(short.shape)[:2] - centre[:2]) == pytest.approx(0.2, abs=0.12)


def test_one_end_seen_takes_the_viewing_direction_as_length() -> None:
    rng = np.random.default_rng(6)
    # only the front 1.2 m in view: shorter than the car is wide, so b1 is fitted across the car
    p, viewer, centre = _truncated_view(0.3, np.array([5.0, 0.0, 2.75]), 1.1, rng)
    fit = S.fit_cuboid(p, percentile=2.5, extrapolate=False)
    assert fit is not None and abs(np.asarray(fit["rotation"])[:, 0] @ rz(0.3)[:, 0]) < 0.2
    done = S.complete_cuboid(fit, viewer[None], [4.6, 1.85, 1.5])
    assert done.swapped and done.extended[1]
    assert np.linalg.norm(S.shape_center(done.shape)[:2] - centre[:2]) < 0.15


def test_side_view_cut_by_the_image_is_ambiguous_and_views_from_both_ends_are_kept() -> None:
    rng = np.random.default_rng(7)
    # beside the car, the rear 1.5 m cut by the image: which end is missing is unknown
    p, viewer, centre = _truncated_view(0.3, np.array([0.2, 5.0, 2.75]), -0.8, rng)
    fit = S.fit_cuboid(p, percentile=2.5, extrapolate=False)
    done = S.complete_cuboid(fit, viewer[None], [4.6, 1.85, 1.5])
    assert done.ambiguous[0] and not done.extended.any() and done.shape is fit
    assert done.missing[0] == pytest.approx(4.6 - fit["dims"][0])
    # a short object seen from beyond both of its ends is this short
    cams = np.array([viewer + 6 * rz(0.3)[:, 0], viewer - 6 * rz(0.3)[:, 0]])
    both = S.complete_cuboid(fit, cams, [4.6, 1.85, 1.5])
    assert not both.extended.any() and not both.ambiguous.any()


def test_reference_shape_tells_length_from_width() -> None:
    R = rz(0.3)
    fit = S.cuboid_shape(R, [0.0, 0.0, 0.75], [1.9, 1.3, 1.5])  # b1 across: a 1.3 m deep end view
    ref = S.cuboid_shape(R @ rz(np.pi / 2), [0.0, -1.6, 0.75], [4.6, 1.85, 1.5])  # length along b2
    cam = R @ np.array([0.0, 6.0, 3.0])
    done = S.complete_cuboid(fit, cam[None], [4.6, 1.85, 1.5], reference=ref)
    assert done.swapped and done.extended[1] and done.shape["dims"][1] == pytest.approx(4.6)
    assert np.allclose(S.shape_center(done.shape), R @ np.array([0.0, -1.65, 0.0]) + [0, 0, 0.75])


def test_reference_length_is_its_longer_axis_and_a_long_fit_is_never_a_width() -> None:
    R = rz(0.3)
    cam = R @ np.array([0.0, 6.0, 3.0])
    # the estimate's b1 is across the car (its dims say so): the length is along its b2
    ref = S.cuboid_shape(R, [0.0, -1.6, 0.75], [1.85, 4.6, 1.5])
    fit = S.cuboid_shape(R, [0.0, 0.0, 0.75], [1.9, 1.3, 1.5])
    done = S.complete_cuboid(fit, cam[None], [4.6, 1.85, 1.5], reference=ref)
    assert done.swapped and done.shape["dims"][1] == pytest.approx(4.6)
    # a 3 m fitted extent cannot be a 1.85 m wide car's width, whatever the reference says
    long_fit = S.cuboid_shape(R, [0.0, 0.0, 0.75], [3.0, 1.8, 1.5])
    done = S.complete_cuboid(long_fit, (R @ np.array([6.0, 0.5, 3.0]))[None], [4.6, 1.85, 1.5], reference=ref)
    assert not done.swapped and done.extended[0] and not done.extended[1]
    assert done.shape["dims"][0] == pytest.approx(4.6) and done.shape["dims"][1] == pytest.approx(1.8)


def test_no_clear_length_axis_extends_nothing() -> None:
    R = rz(0.3)
    fit = S.cuboid_shape(R, [0.0, 0.0, 0.75], [1.8, 1.5, 1.5])  # a corner of a car
    cam = R @ np.array([5.0, 5.0, 3.0])  # seen diagonally: end-on along neither axis
    done = S.complete_cuboid(fit, cam[None], [4.6, 1.85, 1.5])
    assert not done.extended.any() and done.ambiguous.any() and done.shape is fit
    square = S.cuboid_shape(R, [0.0, 0.0, 0.75], [2.0, 1.9, 1.5])  # neither is the reference
    done = S.complete_cuboid(fit, cam[None], [4.6, 1.85, 1.5], reference=square)
    assert not done.extended.any()


def test_shape_errors_give_a_vehicles_length_and_width_errors_whatever_its_heading() -> None:
    truth = S.cuboid_shape(rz(0.2), np.array([0.0, 0.0, 0.75]), np.array([4.5, 1.8, 1.5]))
    # a quarter turn with length and width swapped is the same box; 0.3 m short, 0.1 m too wide
    est = S.cuboid_shape(rz(0.2 + np.pi / 2), np.array([0.0, 0.0, 0.75]), np.array([1.9, 4.2, 1.5]))
    err = S.shape_errors(est, truth)
    assert err["length"] == pytest.approx(0.3) and err["width"] == pytest.approx(0.1)


def _ray_noise(p: np.ndarray, camera: np.ndarray, k: float, rng: np.random.Generator) -> np.ndarray:
    """Depth-camera noise: along each point's ray, σ = k · range² (a stereo camera's)."""
    ray = p - camera
    r = np.linalg.norm(ray, axis=1, keepdims=True)
    return p + ray / r * rng.normal(0.0, 1.0, (len(p), 1)) * k * r**2


@pytest.mark.parametrize("yaw", [0.0, 0.4, 1.2])
def test_faces_seen_head_on_are_seated_where_their_points_crowd_not_at_the_noise_s_tail(yaw: float) -> None:
    rng = np.random.default_rng(3)
    R, centre, dims = rz(yaw), np.array([1.0, -2.0, 0.775]), np.array([4.5, 1.85, 1.55])
    camera = centre + R @ np.array([-5.0, -4.0, 0.0]) + [0, 0, 2.7]  # beyond the rear and the right side
    pts = _ray_noise(box_points(R, centre, dims, camera, rng, n=6000, noise=0.0), camera, 0.005, rng)
    ground = S.GroundPlane.horizontal(0.0)
    fitted = S.fit_cuboid(pts, ground, percentile=2.5, extrapolate=False)
    seated = S.seat_seen_faces(fitted, pts, camera[None])
    los = (centre - camera)[:2] / np.linalg.norm((centre - camera)[:2])

    def toward_camera(shape: dict) -> float:  # the centre's error along the line of sight, + toward it
        return -float((np.asarray(shape["center"])[:2] - centre[:2]) @ los)

    assert toward_camera(fitted) > 0.07  # the percentile edge is the noise's tail on the camera's side
    assert abs(toward_camera(seated)) < 0.05
    # the two seen faces, each within 5 cm of the box's
    Rf = np.asarray(seated["rotation"])
    local = R.T @ Rf  # the seated box's axes in the true box's frame (a quarter or half turn)
    d = np.abs(local[:2, :2]) @ np.asarray(seated["dims"][:2])
    c = R.T @ (np.asarray(seated["center"]) - centre)
    assert abs((c[0] - d[0] / 2) - (-dims[0] / 2)) < 0.05  # the rear face
    assert abs((c[1] - d[1] / 2) - (-dims[1] / 2)) < 0.05  # the right side


def test_a_face_without_a_crowd_of_points_keeps_its_edge() -> None:
    # only a roof, evenly spread, seen from beyond one end: no face stacks its points
    rng = np.random.default_rng(4)
    roof = np.column_stack([rng.uniform(-2.25, 2.25, 4000), rng.uniform(-0.9, 0.9, 4000), np.full(4000, 1.5)])
    roof += rng.normal(0, 0.01, roof.shape)
    fitted = S.fit_cuboid(roof, S.GroundPlane.horizontal(0.0), percentile=2.5, extrapolate=False)
    assert S.seat_seen_faces(fitted, roof, np.array([[-7.0, 0.0, 4.0]])) is fitted
    # cameras on both sides of every face (a survey above it): nothing is moved either
    car = box_points(np.eye(3), np.array([0.0, 0, 0.775]), np.array([4.5, 1.85, 1.55]), [0, 0, 6.0], rng)
    fitted = S.fit_cuboid(car, S.GroundPlane.horizontal(0.0), percentile=2.5, extrapolate=False)
    cams = np.array([[-6.0, -3.0, 6.0], [6.0, 3.0, 6.0]])
    assert S.seat_seen_faces(fitted, car, cams) is fitted


@pytest.mark.parametrize("yaw", [0.0, 0.7])
def test_a_box_fitted_past_each_point_s_depth_noise_is_the_object_not_the_noise_s_tails(yaw: float) -> None:
    # a car seen from 5 m up and 5-6 m off on both sides (the overhead robot's lawnmower): at
    # those depths the camera's noise (0.005·z²) is 0.15-0.25 m along each ray
    rng = np.random.default_rng(11)
    R, centre, dims = rz(yaw), np.array([3.0, -1.0, 0.775]), np.array([4.6, 1.85, 1.55])
    pts, noise = [], []
    for offset in ([-3.0, -5.0, 5.0], [3.0, 5.0, 5.0], [-5.0, 1.0, 5.0]):
        camera = centre + R @ np.array(offset)
        clean = box_points(R, centre, dims, camera, rng, n=3000, noise=0.0)
        axis = (centre - camera) / np.linalg.norm(centre - camera)  # looking at the car
        n = S.depth_noise(clean, camera, axis, 0.005)
        pts.append(clean + n * rng.normal(0.0, 1.0, (len(clean), 1)))
        noise.append(n)
    pts, noise = np.vstack(pts), np.vstack(noise)
    assert np.median(np.linalg.norm(noise, axis=1)) > 0.12

    def length_width_errors(shape: dict) -> np.ndarray:
        return np.sort(shape["dims"][:2])[::-1] - dims[:2]

    ground = S.GroundPlane.horizontal(0.0)
    assert np.all(length_width_errors(S.fit_cuboid(pts, ground)) > 0.2)  # the tails: too big
    fitted = S.fit_cuboid(pts, ground, noise=noise)
    assert np.all(np.abs(length_width_errors(fitted)) < 0.08)
    assert np.linalg.norm(np.asarray(fitted["center"])[:2] - centre[:2]) < 0.05


def test_depth_noise_lies_along_each_ray_and_grows_with_the_square_of_the_depth() -> None:
    camera, axis = np.zeros(3), np.array([1.0, 0.0, 0.0])
    pts = np.array([[2.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 3.0, 0.0]])
    n = S.depth_noise(pts, camera, axis, 0.005)
    assert np.allclose(n[0], [0.02, 0, 0]) and np.allclose(n[1], [0.08, 0, 0])
    # off the optical axis: the depth error is along z, the point moves along its ray by z/range more
    assert np.allclose(n[2], 0.005 * 4.0 * np.array([4.0, 3.0, 0.0]))
    assert np.allclose(S.depth_noise(pts, camera, axis, 0.0), 0.0)
