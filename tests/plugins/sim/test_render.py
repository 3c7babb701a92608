"""Rendering geometry: depth along the optical axis, image orientation, masks."""

from __future__ import annotations

import numpy as np

from amslam.plugins.sim.camera import CHECKER, CameraParams, Look, Renderer
from amslam.plugins.sim.world import World, box_room
from amslam.types import R_BODY_CAM

EXACT = CameraParams(width=160, height=120, depth_noise=0.0, dropout=0.0, grazing_dropout=0.0)


def camera_pose(position, yaw: float = 0.0) -> np.ndarray:
    """Camera pose of a level body at ``position`` with heading ``yaw``."""
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ R_BODY_CAM
    T[:3, 3] = position
    return T


def test_fronto_parallel_wall_has_constant_depth():
    world = World(box_room((10.0, 20.0, 20.0)))
    r = Renderer(EXACT.model(), EXACT)
    # 4 m from the x = 10 wall, high above the floor and far from the side walls
    f = r.render(world, camera_pose([6.0, 10.0, 10.0]), np.random.default_rng(0))
    assert np.all(f.depth > 0)
    # depth along the optical axis, not ray length: every pixel reads 4 m on a facing wall
    np.testing.assert_allclose(f.depth, 4.0, atol=1e-4)


def test_row_zero_is_the_top_of_the_image():
    world = World(box_room((10.0, 8.0, 3.0)))
    r = Renderer(EXACT.model(), EXACT)
    T = camera_pose([5.0, 4.0, 1.0])  # facing the x = 10 wall, 5 m away
    f = r.render(world, T, np.random.default_rng(0))
    K = EXACT.model().K
    H = EXACT.height
    # bottom rows see the floor (1 m below): back-projected points have world z ≈ 0
    for row, expect_z in ((H - 1, 0.0), (0, 3.0)):
        u = EXACT.width // 2
        z = f.depth[row, u]
        assert z > 0
        p_cam = np.linalg.inv(K) @ np.array([u, row, 1.0]) * z
        p_world = T[:3, :3] @ p_cam + T[:3, 3]
        assert abs(p_world[2] - expect_z) < 1e-3, (row, p_world)


def test_instance_and_class_masks_match_the_object(room_with_chair):
    world = World(room_with_chair)
    r = Renderer(EXACT.model(), EXACT)
    T = camera_pose([2.0, 4.0, 0.5])
    f = r.render(world, T, np.random.default_rng(0))
    obj = world.objects[0]
    mask = f.instance == obj.instance_id
    assert mask.sum() > 50
    assert np.all(f.class_id[mask] == world.class_names.index("chair"))
    assert np.all(f.class_id[~mask] == 0)
    # every masked pixel back-projects onto the chair's box, and every other one does not
    K_inv = np.linalg.inv(EXACT.model().K)
    v, u = np.nonzero(f.depth > 0)
    pts = (np.stack([u, v, np.ones_like(u)], 1) @ K_inv.T) * f.depth[v, u][:, None]
    pw = pts @ T[:3, :3].T + T[:3, 3]
    inside = np.all((pw > obj.lo - 1e-3) & (pw < obj.hi + 1e-3), axis=1)
    np.testing.assert_array_equal(inside, mask[v, u])


def test_depth_noise_grows_with_range_and_ranges_are_enforced():
    world = World(box_room((30.0, 30.0, 30.0)))
    p = CameraParams(width=80, height=60, depth_noise=0.01, dropout=0.0, max_range=5.0)
    r = Renderer(p.model(), p)
    rng = np.random.default_rng(1)
    near = r.render(world, camera_pose([29.0, 15.0, 15.0]), rng).depth  # 1 m from the wall
    far = r.render(world, camera_pose([26.0, 15.0, 15.0]), rng).depth  # 4 m
    assert abs(near.std() - 0.01) < 0.003  # σ = k z²
    assert abs(far[far > 0].std() - 0.16) < 0.04
    too_far = r.render(world, camera_pose([20.0, 15.0, 15.0]), rng).depth  # 10 m: no returns
    assert np.all(too_far == 0)


def test_rgb_is_shaded_per_class(room_with_chair):
    world = World(room_with_chair)
    r = Renderer(EXACT.model(), EXACT)
    f = r.render(world, camera_pose([2.0, 4.0, 0.5]), np.random.default_rng(0))
    assert f.rgb is not None and f.rgb.shape == (EXACT.height, EXACT.width, 3) and f.rgb.dtype == np.uint8
    chair = f.rgb[f.instance == 1].mean(axis=0)
    wall = f.rgb[f.instance == 0].mean(axis=0)
    assert chair[0] > chair[1] + 30  # the chair class is red
    assert abs(wall[0] - wall[1]) < 20  # walls are grey


def test_the_default_look_is_the_simulators_own_rendering(room_with_chair):
    """Flights render without a look; ``Look()`` must give the very same pixels (own-look frames)."""
    world = World(room_with_chair)
    T = camera_pose([2.0, 4.0, 0.5])
    plain = Renderer(EXACT.model(), EXACT).render(world, T, np.random.default_rng(3))
    default = Renderer(EXACT.model(), EXACT).render(world, T, np.random.default_rng(3), Look())
    np.testing.assert_array_equal(plain.rgb, default.rgb)
    np.testing.assert_array_equal(plain.depth, default.depth)


def test_a_look_recolours_and_relights_but_moves_no_pixel(room_with_chair):
    world = World(room_with_chair)
    T = camera_pose([2.0, 4.0, 0.5])
    n = world.n_triangles
    blue = np.tile(np.float32([0.1, 0.2, 0.9]), (n, 1))
    look = Look(
        albedo=blue,
        pattern=np.full(n, CHECKER, np.uint8),
        albedo2=blue * np.float32(0.3),
        pattern_scale=np.full(n, 0.25, np.float32),
        sun=(0.0, 0.0, 1.0),
        exposure=1.3,
        tint=(0.9, 1.0, 1.1),
    )
    plain = Renderer(EXACT.model(), EXACT).render(world, T, np.random.default_rng(3))
    looked = Renderer(EXACT.model(), EXACT).render(world, T, np.random.default_rng(3), look)
    np.testing.assert_array_equal(plain.instance, looked.instance)
    np.testing.assert_array_equal(plain.depth, looked.depth)
    chair = looked.instance == 1
    assert looked.rgb[chair].mean(axis=0)[2] > looked.rgb[chair].mean(axis=0)[0] + 30  # the red chair is blue
    # the checker's dark squares: a two-level image where the plain one is a smooth shading
    wall = looked.rgb[~chair & (looked.depth > 0)][:, 2].astype(float)
    assert np.percentile(wall, 90) > 2.0 * np.percentile(wall, 10)


def test_the_camera_model_carries_the_depth_noise_the_renderer_adds() -> None:
    # the backends read the sensor's noise from the camera model (a real camera's from its
    # parameters), never from the simulator
    assert CameraParams(depth_noise=0.003).model().depth_noise == 0.003
    assert CameraParams().model().depth_noise == CameraParams().depth_noise
