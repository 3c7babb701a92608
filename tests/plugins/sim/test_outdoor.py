"""The outdoor world kind: layouts, true shapes, and shapes recovered from rendered views."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.lib import shapes as S  # noqa: N812
from amslam.plugins.sim.camera import CameraParams, Renderer
from amslam.plugins.sim.outdoor import OutdoorWorldParams, generate_outdoor
from amslam.plugins.sim.platform import SimPlatform
from amslam.plugins.sim.world import World


@pytest.mark.parametrize("layout", ["parking_lot", "street"])
def test_layouts_have_true_shapes_resting_on_the_ground(layout: str) -> None:
    p = OutdoorWorldParams(layout=layout, slope_deg=3.0, slope_direction=0.5)
    spec = generate_outdoor(p, np.random.default_rng(4))
    world = World(spec)
    summary = world.summary(np.array([*spec.start_xy, 3.0]), cell=1.0)
    classes = {o.class_name for o in spec.objects}
    assert {"car", "pole", "tree_trunk", "ground"} <= classes
    shaped = [o for o in spec.objects if o.class_name != "ground"]
    assert len(summary.object_shapes) == len(shaped) > 5
    for o in shaped:
        s = summary.object_shapes[o.name]
        if s["model"] == "cuboid":
            T = S.cuboid_pose(s)
            bottom = T[:3, 3] - T[:3, 2] * s["dims"][2] / 2
            # the box's bottom centre lies on the ground, its vertical axis is the ground normal
            assert world.ground_below(bottom + [0, 0, 0.2]) == pytest.approx(
                bottom[2], abs=0.03
            )  # under the body
            assert np.degrees(np.arccos(T[2, 2])) == pytest.approx(3.0, abs=0.01)
        else:
            assert s["axis"] == [0.0, 0.0, 1.0]
            assert world.ground_below(np.asarray(s["root"]) + [0.6, 0, 1.0]) == pytest.approx(
                s["root"][2], abs=0.05
            )
    # nothing stands in the take-off column
    column = np.array([[*spec.start_xy, spec.start_floor_z + z] for z in (1.2, 2.0, 3.5)])
    assert world.distance(column).min() > 1.0


def test_outdoor_kind_is_a_platform_world() -> None:
    params = SimPlatform.Params(world={"kind": "outdoor", "layout": "street"})
    assert isinstance(params.world, OutdoorWorldParams)


def test_car_shape_from_rendered_views() -> None:
    """Four oblique views of one car at 3.5 m: the fitted box matches the true one."""
    spec = generate_outdoor(OutdoorWorldParams(slope_deg=2.0), np.random.default_rng(1))
    world = World(spec)
    car = next(o for o in spec.objects if o.class_name == "car")
    ground_ids = [o.instance_id for o in spec.objects if o.class_name == "ground"]
    cp = CameraParams(width=240, height=180, pitch_deg=35, max_range=8.0)
    cam = cp.model()
    rend = Renderer(cam, cp)
    rng = np.random.default_rng(0)
    pts, gpts = [], []
    for k in range(4):
        a = np.pi / 2 * k + 0.4
        T = np.eye(4)
        yaw = a + np.pi
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        T[:3, 3] = [*(car.centroid[:2] + 4.0 * np.array([np.cos(a), np.sin(a)])), 3.5]
        Twc = T @ cam.T_body_cam
        r = rend.render(world, Twc, rng)
        for ids, out in (([car.instance_id], pts), (ground_ids, gpts)):
            v, u = np.nonzero(np.isin(r.instance, ids) & (r.depth > 0))
            z = r.depth[v, u]
            pc = (np.stack([u, v, np.ones_like(u)], 1) @ np.linalg.inv(cam.K).T) * z[:, None]
            out.append(pc @ Twc[:3, :3].T + Twc[:3, 3])
    ground = S.local_ground(np.concatenate(gpts), car.centroid, 4.0)
    assert ground is not None
    fit = S.fit_cuboid(np.concatenate(pts), ground, percentile=2.5, extrapolate=False)
    assert fit is not None
    err = S.shape_errors(fit, car.shape)
    assert err["yaw"] < np.radians(2.0)
    assert err["dims"] < 0.1
    assert err["position"] < 0.1
