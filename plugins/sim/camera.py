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
from pydantic import Field, model_validator

from amslam.geometry import pose_from
from amslam.interfaces import BackendParams, FieldError
from amslam.plugins.sim.world import World
from amslam.types import CameraModel


class CameraParams(BackendParams):
    """The simulated depth camera (Intel RealSense D435i-like defaults)."""

    width: int = Field(640, ge=8, le=4096, description="image width, pixels")
    height: int = Field(480, ge=8, le=4096, description="image height, pixels")
    hfov_deg: float = Field(87.0, gt=10.0, lt=170.0)
    vfov_deg: float = Field(58.0, gt=10.0, lt=170.0)
    min_range: float = Field(0.3, ge=0.0, le=100.0, description="closer returns are dropped (0 in the image)")
    max_range: float = Field(
        5.0, gt=0.0, le=100.0, description="farther returns are dropped (0 in the image)"
    )
    rate_hz: float = Field(
        10.0, gt=0.0, le=1000.0, description="frame rate; frames are rendered only when due"
    )
    pitch_deg: float = Field(0.0, ge=-60.0, le=60.0, description="downward tilt of the camera")
    depth_noise: float = Field(
        0.005, ge=0.0, le=1.0, description="σ of depth noise = depth_noise·z² (m); D435i ≈ 0.002–0.01"
    )
    dropout: float = Field(0.01, ge=0.0, le=1.0, description="probability that a pixel has no return")
    grazing_dropout: float = Field(
        0.5, ge=0.0, le=1.0, description="extra dropout probability at grazing incidence (cos < 0.2)"
    )
    rgb: bool = Field(True, description="render a shaded RGB image")
    rgb_noise: float = Field(3.0, ge=0.0, le=255.0, description="σ of RGB pixel noise in 8-bit levels")

    @model_validator(mode="after")
    def _ranges(self) -> CameraParams:
        if not self.min_range < self.max_range:
            raise FieldError(
                "min_range", f"{self.min_range:g} m must be below max_range ({self.max_range:g} m)"
            )
        return self

    def model(self) -> CameraModel:
        """The :class:`CameraModel` these parameters describe."""
        T = CameraModel.forward_mount(self.pitch_deg)
        return CameraModel.from_fov(
            self.width,
            self.height,
            self.hfov_deg,
            self.vfov_deg,
            min_range=self.min_range,
            max_range=self.max_range,
            rate_hz=self.rate_hz,
            T_body_cam=T,
            depth_noise=self.depth_noise,
        )


@dataclass
class RenderedFrame:
    depth: np.ndarray
    instance: np.ndarray
    class_id: np.ndarray
    rgb: np.ndarray | None


#: direction towards the main (ceiling) light in the world frame
_SUN = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])

#: surface patterns of :class:`Look` (per triangle): plain, blocky value noise, stripes, checker
PLAIN, NOISE, STRIPES, CHECKER = 0, 1, 2, 3


@dataclass(frozen=True)
class Look:
    """How a frame is coloured and lit: the simulator's own look, or a randomised one.

    The detector's training data varies all of it per frame (domain randomisation, so that the
    network learns shapes rather than one palette under one light); the simulator renders with
    the defaults, which are the constants it always used (``Look()`` renders exactly what no look
    renders). Per-triangle arrays are indexed like ``World.tri_albedo``.

    Attributes:
        albedo: RGB in [0, 1] per triangle, instead of the world's own colours.
        pattern: per triangle, which pattern mixes ``albedo`` with ``albedo2``
            (:data:`PLAIN`, :data:`NOISE`, :data:`STRIPES`, :data:`CHECKER`); needs ``albedo``.
        albedo2: the pattern's second colour per triangle.
        pattern_scale: the pattern's period per triangle, metres.
        stripe_direction: unit vector across the stripes (world frame).
        sun: unit vector towards the main light (world frame).
        ambient, sun_gain, head_gain: the light that reaches every surface, the main light's
            Lambertian share, the head light's (along the rays).
        falloff: the head light's falloff, ``1 / sqrt(1 + falloff · distance²)``.
        floor_tiles: darken every other 0.6 m tile of up-facing structure.
        tint: colour cast, a gain per RGB channel.
        exposure: gain of the whole image.
        noise_gain: gain of the camera's ``rgb_noise``.
    """

    albedo: np.ndarray | None = None
    pattern: np.ndarray | None = None
    albedo2: np.ndarray | None = None
    pattern_scale: np.ndarray | None = None
    stripe_direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    sun: tuple[float, float, float] = tuple(_SUN.tolist())
    ambient: float = 0.30
    sun_gain: float = 0.40
    head_gain: float = 0.35
    falloff: float = 0.02
    floor_tiles: bool = True
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    exposure: float = 1.0
    noise_gain: float = 1.0


_DEFAULT_LOOK = Look()


class Renderer:
    """Renders frames of one world through one camera.

    Everything per pixel is float32 and done column by column: with a 3-wide inner dimension,
    numpy's matmul and einsum are several times slower than three fused multiply-adds.
    """

    def __init__(self, camera: CameraModel, params: CameraParams):
        self.camera = camera
        self.params = params
        u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        pix = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3).astype(np.float64)
        d = pix @ np.linalg.inv(camera.K).T  # z = 1: t_hit is depth along the optical axis
        self.dirs_cam = np.ascontiguousarray(d, dtype=np.float32)
        self._x = np.ascontiguousarray(d[:, 0], dtype=np.float32)
        self._y = np.ascontiguousarray(d[:, 1], dtype=np.float32)
        # ray length per unit depth; rotation does not change it
        self._inv_norm = (1.0 / np.linalg.norm(d, axis=1)).astype(np.float32)
        self._rays = np.empty((len(d), 6), dtype=np.float32)
        self._rgb_noise: np.ndarray | None = None

    def rays(self, T_world_cam: np.ndarray) -> np.ndarray:
        """(H·W)×6 float32 rays (origin, unnormalised direction) in the world frame.

        The returned array is a buffer reused by the next call.
        """
        R = T_world_cam[:3, :3].astype(np.float32)
        out = self._rays
        out[:, :3] = T_world_cam[:3, 3].astype(np.float32)
        for i in range(3):  # d_world = R d_cam with d_cam = (x, y, 1)
            np.multiply(self._x, R[i, 0], out=out[:, 3 + i])
            out[:, 3 + i] += self._y * R[i, 1]
            out[:, 3 + i] += R[i, 2]
        return out

    def render(
        self, world: World, T_world_cam: np.ndarray, rng: np.random.Generator, look: Look | None = None
    ) -> RenderedFrame:
        """Ray-cast one frame and apply the sensor model.

        ``look``: the colours and the light (:class:`Look`; default: the simulator's own).
        """
        p, cam = self.params, self.camera
        H, W = cam.height, cam.width
        N = H * W
        rays = self.rays(T_world_cam)
        ans = world.cast_rays(rays)
        t = ans["t_hit"]  # float32, inf where nothing was hit
        tri = world.triangle_index(ans["geometry_ids"], ans["primitive_ids"])
        hit = tri >= 0
        tri0 = np.where(hit, tri, 0)
        inst = np.where(hit, world.tri_instance[tri0], 0).astype(np.int32)
        cls = world.instance_class[inst]

        # depth: t_hit already is z-depth; D435i-like noise σ = k z², random and grazing dropouts
        n = ans["primitive_normals"]
        cos_inc = np.abs(n[:, 0] * rays[:, 3] + n[:, 1] * rays[:, 4] + n[:, 2] * rays[:, 5]) * self._inv_norm
        z = np.where(hit, t, np.float32(0.0))
        noisy = z + rng.standard_normal(N, dtype=np.float32) * np.float32(p.depth_noise) * z * z
        # one uniform draw per pixel: P(drop) = p + (1 − p)·g at grazing incidence, else p
        p_drop = np.where(cos_inc < 0.2, p.dropout + (1.0 - p.dropout) * p.grazing_dropout, p.dropout)
        drop = rng.random(N, dtype=np.float32) < p_drop
        valid = hit & ~drop & (noisy >= cam.min_range) & (noisy <= cam.max_range)
        depth = np.where(valid, noisy, np.float32(0.0)).astype(np.float32).reshape(H, W)

        rgb = None
        if p.rgb:
            rgb = self._shade(world, rays, t, tri0, hit, n, cos_inc, inst, rng, look or _DEFAULT_LOOK)
            rgb = rgb.reshape(H, W, 3)
        return RenderedFrame(depth, inst.reshape(H, W), cls.astype(np.int32).reshape(H, W), rgb)

    def _shade(self, world, rays, t, tri0, hit, n, cos_inc, inst, rng, look: Look) -> np.ndarray:
        """Lambertian shading: a ceiling light plus a head light, tiled floors, light falloff."""
        p = self.params
        sun = np.asarray(look.sun, dtype=np.float32)
        lam_sun = np.abs(n[:, 0] * sun[0] + n[:, 1] * sun[1] + n[:, 2] * sun[2])
        shade = look.ambient + look.sun_gain * lam_sun + look.head_gain * cos_inc
        # floor tiles: a checker of 0.6 m tiles on up-facing structure surfaces
        floorish = np.flatnonzero(hit & (n[:, 2] > 0.9) & (inst == 0)) if look.floor_tiles else []
        if len(floorish):
            tf = t[floorish]
            px = rays[floorish, 0] + rays[floorish, 3] * tf
            py = rays[floorish, 1] + rays[floorish, 4] * tf
            checker = (np.floor(px / 0.6) + np.floor(py / 0.6)) % 2
            shade[floorish] *= 0.88 + 0.12 * checker
        # distance falloff of the head light
        dist = np.where(hit, t, np.float32(10.0))
        shade /= np.sqrt(1.0 + look.falloff * dist * dist)
        if look.albedo is None:
            albedo = world.tri_albedo[tri0]
        else:
            albedo = look.albedo[tri0].astype(np.float32)
            if look.pattern is not None:
                self._apply_patterns(albedo, look, rays, t, tri0, hit)
        albedo[~hit] = 0.08
        # a default look's gains of exactly 1 leave every value as it was (IEEE): the simulator's
        # frames are those it always rendered
        albedo *= np.asarray(look.tint, dtype=np.float32)
        gain = 255.0 * look.exposure
        img = albedo * (shade * gain)[:, None]
        if p.rgb_noise > 0 and look.noise_gain > 0:
            # Sensor noise from a cached buffer twice the image size at a random offset per frame:
            # drawing 3·H·W normals every frame cost as much as the shading itself.
            m = img.size
            if self._rgb_noise is None:
                self._rgb_noise = rng.standard_normal(2 * m, dtype=np.float32) * np.float32(p.rgb_noise)
            off = int(rng.integers(0, m))
            noise = self._rgb_noise[off : off + m].reshape(img.shape)
            img += noise * np.float32(look.noise_gain)
        return np.clip(img, 0, 255).astype(np.uint8)

    @staticmethod
    def _apply_patterns(albedo, look: Look, rays, t, tri0, hit) -> None:
        """Mix ``albedo`` (per pixel, in place) with the second colour by each triangle's pattern.

        Patterns are functions of the hit point in the world frame, so a surface keeps its
        pattern from every viewpoint, like a texture.
        """
        assert look.pattern is not None and look.albedo2 is not None and look.pattern_scale is not None
        kind = np.where(hit, look.pattern[tri0], PLAIN)
        sel = np.flatnonzero(kind != PLAIN)
        if not len(sel):
            return
        ts = t[sel]
        x = rays[sel, 0] + rays[sel, 3] * ts
        y = rays[sel, 1] + rays[sel, 4] * ts
        z = rays[sel, 2] + rays[sel, 5] * ts
        s = look.pattern_scale[tri0[sel]].astype(np.float32)
        ix, iy, iz = (np.floor(c / s).astype(np.int64) for c in (x, y, z))
        k = kind[sel]
        # value noise: a hash of the cell, in [0, 1]
        h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)
        noise = ((h * 2654435761) >> 16 & 0xFFFF).astype(np.float32) / 65535.0
        sd = look.stripe_direction
        stripes = (np.floor((x * sd[0] + y * sd[1] + z * sd[2]) / s) % 2).astype(np.float32)
        checker = ((ix + iy + iz) % 2).astype(np.float32)
        mix = np.where(k == NOISE, noise, np.where(k == STRIPES, stripes, checker))[:, None]
        albedo[sel] = albedo[sel] * (1.0 - mix) + look.albedo2[tri0[sel]] * mix


def viewing_pose(
    world: World, target: np.ndarray, T_body_cam: np.ndarray, distance: float = 2.5, height: float = 1.2
) -> np.ndarray:
    """``T_world_cam`` of a level body ``distance`` from ``target`` at ``height``, facing it.

    Of 24 headings around the target, the one whose body position is farthest from any geometry.
    Handy for benchmarks, tests and scripted views.
    """
    best: tuple[float, np.ndarray, float] | None = None
    for a in np.linspace(-np.pi, np.pi, 24, endpoint=False):
        pos = np.array([target[0] + distance * np.cos(a), target[1] + distance * np.sin(a), height])
        d = float(world.distance(pos)[0])
        if best is None or d > best[0]:
            best = (d, pos, a + np.pi)
    assert best is not None
    _, pos, yaw = best
    return pose_from(pos, yaw) @ T_body_cam
