"""RGB-D rendering by ray casting: depth with a D435i-like noise model, instance/class masks, RGB.

Rays are built once per camera in the optical frame with a unit z component, ``d = K⁻¹ [u, v, 1]``
for pixel centres at integer ``(u, v)`` (row 0 = top of the image, as in the image arrays), so
the ray parameter ``t_hit`` Open3D returns *is* the depth along the optical axis. We build them
ourselves rather than with ``RaycastingScene.create_rays_pinhole``: that helper shoots through
``(u + 0.5, v + 0.5)``, half a pixel off the convention of :meth:`CameraModel.from_fov` (principal
point at ``(w − 1)/2``), which would bias every back-projection; per frame only a rotation of the
cached directions remains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from amslam.interfaces import BackendParams
from amslam.plugins.sim.world import World
from amslam.types import CameraModel


class CameraParams(BackendParams):
    """The simulated depth camera (Intel RealSense D435i-like defaults)."""

    width: int = Field(640, ge=8)
    height: int = Field(480, ge=8)
    hfov_deg: float = Field(87.0, gt=10.0, lt=170.0)
    vfov_deg: float = Field(58.0, gt=10.0, lt=170.0)
    min_range: float = Field(0.3, ge=0.0, description="closer returns are dropped (0 in the image)")
    max_range: float = Field(5.0, gt=0.0, description="farther returns are dropped (0 in the image)")
    rate_hz: float = Field(10.0, gt=0.0, description="frame rate; frames are rendered only when due")
    pitch_deg: float = Field(0.0, ge=-60.0, le=60.0, description="downward tilt of the camera")
    depth_noise: float = Field(
        0.005, ge=0.0, description="σ of depth noise = depth_noise·z² (m); D435i ≈ 0.002–0.01"
    )
    dropout: float = Field(0.01, ge=0.0, le=1.0, description="probability that a pixel has no return")
    grazing_dropout: float = Field(
        0.5, ge=0.0, le=1.0, description="extra dropout probability at grazing incidence (cos < 0.2)"
    )
    rgb: bool = Field(True, description="render a shaded RGB image")
    rgb_noise: float = Field(3.0, ge=0.0, description="σ of RGB pixel noise in 8-bit levels")

    def model(self) -> CameraModel:
        """The :class:`CameraModel` these parameters describe."""
        T = np.eye(4)
        # optical frame → body: z forward (body x), x right (body −y), y down; then tilt down.
        pitch = np.radians(self.pitch_deg)
        Ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
        from amslam.types import R_BODY_CAM

        T[:3, :3] = Ry @ R_BODY_CAM
        return CameraModel.from_fov(
            self.width,
            self.height,
            self.hfov_deg,
            self.vfov_deg,
            min_range=self.min_range,
            max_range=self.max_range,
            rate_hz=self.rate_hz,
            T_body_cam=T,
        )


@dataclass
class RenderedFrame:
    depth: np.ndarray
    instance: np.ndarray
    class_id: np.ndarray
    rgb: np.ndarray | None


#: direction towards the main (ceiling) light in the world frame
_SUN = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])


class Renderer:
    """Renders frames of one world through one camera."""

    def __init__(self, camera: CameraModel, params: CameraParams):
        self.camera = camera
        self.params = params
        u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        pix = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3).astype(np.float64)
        self.dirs_cam = pix @ np.linalg.inv(camera.K).T  # z = 1: t_hit is depth along the optical axis

    def rays(self, T_world_cam: np.ndarray) -> np.ndarray:
        """(H·W)×6 float32 rays (origin, unnormalised direction) in the world frame."""
        d = self.dirs_cam @ T_world_cam[:3, :3].T
        o = np.broadcast_to(T_world_cam[:3, 3], d.shape)
        return np.concatenate([o, d], axis=1).astype(np.float32)

    def render(self, world: World, T_world_cam: np.ndarray, rng: np.random.Generator) -> RenderedFrame:
        """Ray-cast one frame and apply the sensor model."""
        p, cam = self.params, self.camera
        H, W = cam.height, cam.width
        rays = self.rays(T_world_cam)
        ans = world.cast_rays(rays)
        t = ans["t_hit"].astype(np.float64)
        tri = world.triangle_index(ans["geometry_ids"], ans["primitive_ids"])
        hit = tri >= 0
        inst = np.zeros(H * W, dtype=np.int32)
        inst[hit] = world.tri_instance[tri[hit]]
        cls = world.instance_class[inst]

        # depth: t_hit already is z-depth; D435i-like noise σ = k z², random and grazing dropouts
        normals = ans["primitive_normals"].astype(np.float64)
        dn = np.linalg.norm(rays[:, 3:], axis=1)
        cos_inc = np.abs(np.einsum("ij,ij->i", normals, rays[:, 3:])) / np.maximum(dn, 1e-9)
        z = np.where(hit, t, 0.0)
        noisy = z + rng.standard_normal(H * W) * p.depth_noise * z**2
        drop = rng.random(H * W) < p.dropout
        drop |= (cos_inc < 0.2) & (rng.random(H * W) < p.grazing_dropout)
        valid = hit & ~drop & (noisy >= cam.min_range) & (noisy <= cam.max_range)
        depth = np.where(valid, noisy, 0.0).astype(np.float32).reshape(H, W)

        rgb = None
        if p.rgb:
            rgb = self._shade(world, rays, t, tri, hit, normals, rng).reshape(H, W, 3)
        return RenderedFrame(depth, inst.reshape(H, W), cls.astype(np.int32).reshape(H, W), rgb)

    def _shade(self, world, rays, t, tri, hit, normals, rng) -> np.ndarray:
        """Lambertian shading: a ceiling light plus a head light, floor tiles, fog-free."""
        p = self.params
        n = len(rays)
        albedo = np.full((n, 3), 0.08)
        albedo[hit] = world.tri_albedo[tri[hit]]
        d = rays[:, 3:] / np.maximum(np.linalg.norm(rays[:, 3:], axis=1, keepdims=True), 1e-9)
        lam_sun = np.abs(normals @ _SUN)
        lam_head = np.abs(np.einsum("ij,ij->i", normals, d))
        shade = 0.30 + 0.40 * lam_sun + 0.35 * lam_head
        # floor tiles: a checker of 0.6 m tiles on up-facing structure surfaces
        pts = rays[:, :3] + rays[:, 3:] * np.where(hit, t, 0.0)[:, None]
        floorish = hit & (normals[:, 2] > 0.9) & (world.tri_instance[np.maximum(tri, 0)] == 0)
        checker = (np.floor(pts[:, 0] / 0.6) + np.floor(pts[:, 1] / 0.6)) % 2
        shade = np.where(floorish, shade * (0.88 + 0.12 * checker), shade)
        # distance falloff of the head light
        shade = shade / (1.0 + 0.02 * np.where(hit, t, 10.0) ** 2) ** 0.5
        img = albedo * shade[:, None] * 255.0
        if p.rgb_noise > 0:
            img = img + rng.standard_normal(img.shape) * p.rgb_noise
        return np.clip(img, 0, 255).astype(np.uint8)
