"""Outdoor procedural worlds (paper 2's urban experiments): a parking lot or a street.

``world: {kind: outdoor, layout: parking_lot | street, ...}``. No roof and no walls: a ground
surface (optionally sloped by ``slope_deg`` along ``slope_direction``), parked vehicles
(class ``car``: cars and vans, named ``car_i`` / ``van_i``, modelled as cuboids), ``pole``
(light poles) and ``tree_trunk`` instances (cylinders), and some unlabelled clutter (benches,
bins) that belongs to the structure.

Layouts (x east, y north; the lot spans ``[0, W] × [0, D]``)::

    parking_lot                                   street
    ┌──────────────────────────────┐              ┌──────────────────────────────┐
    │ T   T   T   T   T   T   T   T│ trees        │ T    T    P    T    T    P    │ sidewalk
    │ ▯▯▯▯▯▯▯▯▯▯▯▯▯▯▯  P          │ stalls       │ ▭ ▭  ▭ ▭   ▭  ▭ ▭   ▭        │ parallel parking
    │ ▯▯▯▯▯▯▯▯▯▯▯▯▯▯▯             │ (back to     │                              │ road
    │           aisle              │  back)       │ ▭  ▭ ▭   ▭  ▭ ▭  ▭           │
    │ ▯▯▯▯▯▯▯▯▯▯▯▯▯▯▯  P          │              │ T    P    T    T    P    T    │
    │ start                        │              │ start                        │
    └──────────────────────────────┘              └──────────────────────────────┘

Every vehicle, pole and trunk is an object instance with its true shape in
:attr:`WorldObject.shape` (so :class:`WorldSummary.object_shapes` holds the ground truth the
metrics compare with). A car is a lower body on four wheels with a cabin set back from the
front, so that its front is lower than its rear (the facing cue of §IV-A); a van is a tall box
with a short, low bonnet. Their true cuboid is the bounding box in the vehicle frame, which
follows the local ground (a full rotation on a slope).

The ground is split into square tiles of ``ground_tile`` metres, each an instance of class
``ground_class`` (``ground`` by default): the detector then reports ground points near the
objects, which the SLAM backend uses for the local ground planes (``landmark_models: {ground:
plane}``). ``ground_class: null`` makes the ground plain structure.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from amslam.geometry import yaw_matrix
from amslam.interfaces import BackendParams, FieldError
from amslam.plugins.sim.world import MeshPart, WorldObject, WorldSpec, box_mesh, merge_meshes, prism_mesh

__all__ = ["OutdoorWorldParams", "generate_outdoor"]

#: albedo of the outdoor classes (cars get a random paint per instance)
_COLOURS = {
    "ground": (0.36, 0.36, 0.38),
    "pole": (0.55, 0.57, 0.6),
    "tree_trunk": (0.40, 0.28, 0.18),
    "clutter": (0.6, 0.58, 0.52),
}
_PAINTS = np.array(
    [
        [0.75, 0.1, 0.1],
        [0.1, 0.2, 0.6],
        [0.85, 0.85, 0.85],
        [0.1, 0.1, 0.1],
        [0.5, 0.5, 0.55],
        [0.2, 0.45, 0.25],
    ]
)


class OutdoorWorldParams(BackendParams):
    """A seeded outdoor scene: a parking lot or a street."""

    kind: Literal["outdoor"] = "outdoor"
    name: str = Field("outdoor", description="name of the world in reports")
    layout: Literal["parking_lot", "street"] = Field("parking_lot", description="scene layout")
    size: tuple[Annotated[float, Field(ge=12.0, le=500.0)], Annotated[float, Field(ge=12.0, le=500.0)]] = (
        Field((36.0, 26.0), description="extent (x, y) of the scene in metres (12 to 500 m a side)")
    )
    height: float = Field(
        7.0, gt=2.0, le=100.0, description="top of the flight volume above the lowest ground, m"
    )
    slope_deg: float = Field(0.0, ge=0.0, le=10.0, description="ground slope in degrees")
    slope_direction: float = Field(
        0.0, ge=-100.0, le=100.0, description="direction (rad, from +x) in which the ground rises"
    )
    occupancy: float = Field(0.7, ge=0.0, le=1.0, description="share of parking spaces holding a vehicle")
    van_fraction: float = Field(0.25, ge=0.0, le=1.0, description="share of vehicles that are vans")
    yaw_jitter_deg: float = Field(
        4.0, ge=0.0, le=90.0, description="σ of a parked vehicle's yaw about its stall"
    )
    poles: int = Field(4, ge=0, le=1000, description="light poles")
    trees: int = Field(6, ge=0, le=1000, description="tree trunks")
    clutter: int = Field(4, ge=0, le=1000, description="unlabelled clutter items (benches, bins)")
    pole_height: tuple[
        Annotated[float, Field(gt=0.0, le=100.0)], Annotated[float, Field(gt=0.0, le=100.0)]
    ] = Field((5.0, 7.0), description="range of light-pole heights, m")
    trunk_height: tuple[
        Annotated[float, Field(gt=0.0, le=100.0)], Annotated[float, Field(gt=0.0, le=100.0)]
    ] = Field((4.0, 6.5), description="range of tree-trunk heights, m")
    ground_tile: float = Field(
        6.0, gt=1.0, le=1000.0, description="side of a ground tile (one ground instance), m"
    )
    ground_class: str | None = Field("ground", description="class of the ground tiles; null = structure")
    seed_offset: int = Field(
        0, ge=-(2**63), le=2**63 - 1, description="added to the run seed: a different scene, same run"
    )

    @model_validator(mode="after")
    def _ranges(self) -> OutdoorWorldParams:
        for name in ("pole_height", "trunk_height"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise FieldError(name, f"[{lo:g}, {hi:g}]: the lower end must not be above the upper")
        return self


# -------------------------------------------------------------------------------------------
# geometry helpers
# -------------------------------------------------------------------------------------------
class _Ground:
    """The ground surface ``z = g·(x, y)``: a plane through the origin rising along a direction."""

    def __init__(self, slope_deg: float, direction: float):
        t = np.tan(np.radians(slope_deg))
        self.grad = t * np.array([np.cos(direction), np.sin(direction)])
        n = np.array([-self.grad[0], -self.grad[1], 1.0])
        self.normal = n / np.linalg.norm(n)
        # rotation taking z to the normal (about the horizontal axis z × n): vehicles sit on it
        k = np.cross([0.0, 0.0, 1.0], self.normal)
        sk = np.linalg.norm(k)
        if sk < 1e-12:
            self.R = np.eye(3)
        else:
            k /= sk
            K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            ang = np.arccos(np.clip(self.normal[2], -1.0, 1.0))
            self.R = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K

    def z(self, xy: np.ndarray) -> np.ndarray:
        return np.asarray(xy, float)[..., :2] @ self.grad

    def frame(self, x: float, y: float, yaw: float) -> tuple[np.ndarray, np.ndarray]:
        """Rotation and origin of an object standing on the ground at (x, y) with heading ``yaw``."""
        R = self.R @ yaw_matrix(yaw)
        return R, np.array([x, y, float(self.z(np.array([x, y])))])


def _car_boxes(
    rng: np.random.Generator, van: bool
) -> tuple[list[tuple[list[float], list[float]]], np.ndarray]:
    """Boxes of a vehicle in its own frame (x forward, origin on the ground under its centre)."""
    if van:
        L, W, H = rng.uniform(4.9, 5.5), rng.uniform(1.9, 2.05), rng.uniform(1.9, 2.3)
        bonnet = rng.uniform(0.6, 0.9)
        hood_h = rng.uniform(1.0, 1.15)
    else:
        L, W, H = rng.uniform(4.1, 4.9), rng.uniform(1.72, 1.88), rng.uniform(1.38, 1.55)
        bonnet = rng.uniform(1.0, 1.3)
        hood_h = rng.uniform(0.85, 1.0)
    clear, wheel_r, tyre = 0.3, 0.33, 0.22
    b: list[tuple[list[float], list[float]]] = [
        ([-L / 2, -W / 2, clear], [L / 2, W / 2, hood_h]),  # lower body
        ([-L / 2, -W / 2 + 0.04, hood_h], [L / 2 - bonnet, W / 2 - 0.04, H]),  # cabin, set back
    ]
    for sx in (-1, 1):
        for sy in (-1, 1):
            cx = sx * (L / 2 - 0.8)
            cy = sy * (W / 2 - tyre / 2)
            b.append(([cx - wheel_r, cy - tyre / 2, 0.0], [cx + wheel_r, cy + tyre / 2, clear + 0.05]))
    return b, np.array([L, W, H])


# -------------------------------------------------------------------------------------------
# the builder
# -------------------------------------------------------------------------------------------
class _Builder:
    def __init__(self, p: OutdoorWorldParams, rng: np.random.Generator):
        self.p, self.rng = p, rng
        self.ground = _Ground(p.slope_deg, p.slope_direction)
        self.parts: list[MeshPart] = []
        self.objects: list[WorldObject] = []
        self.counts: dict[str, int] = {}
        self.footprints: list[tuple[np.ndarray, float]] = []  # (xy, radius) of everything placed

    def _next(self, kind: str) -> tuple[str, int]:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        return f"{kind}_{self.counts[kind]}", len(self.objects) + 1

    def _add(
        self, cls: str, v: np.ndarray, t: np.ndarray, albedo: np.ndarray, shape: dict | None, kind: str = ""
    ) -> None:
        name, inst = self._next(kind or cls)
        self.parts.append(MeshPart.uniform(name, v, t, inst, albedo))
        lo, hi = v.min(axis=0), v.max(axis=0)
        self.objects.append(WorldObject(name, cls, inst, (lo + hi) / 2.0, lo, hi, shape))

    def free(self, xy: np.ndarray, radius: float) -> bool:
        return all(np.linalg.norm(xy - q) >= radius + r for q, r in self.footprints)

    # ---- objects ---------------------------------------------------------------------------
    def vehicle(self, x: float, y: float, yaw: float) -> None:
        van = bool(self.rng.random() < self.p.van_fraction)
        boxes, dims = _car_boxes(self.rng, van)
        v, t = merge_meshes([box_mesh(np.array(lo, float), np.array(hi, float)) for lo, hi in boxes])
        R, o = self.ground.frame(x, y, yaw)
        v = v @ R.T + o
        centre = o + R @ np.array([0.0, 0.0, dims[2] / 2])
        shape = {
            "model": "cuboid",
            "center": centre.tolist(),
            "yaw": float(np.arctan2(R[1, 0], R[0, 0])),
            "dims": dims.tolist(),
            "rotation": R.tolist(),
        }
        paint = _PAINTS[self.rng.integers(len(_PAINTS))] * self.rng.uniform(0.85, 1.1)
        self._add("car", v, t, np.clip(paint, 0, 1), shape, kind="van" if van else "car")
        self.footprints.append((np.array([x, y]), 0.5 * float(np.hypot(dims[0], dims[1]))))

    def cylinder(self, cls: str, x: float, y: float, radius: float, height: float) -> None:
        # upright (gravity-aligned) on sloped ground: sunk into the ground on the uphill side
        gz = float(self.ground.z(np.array([x, y])))
        v, t = prism_mesh(radius, gz - 0.3, gz + height)
        v[:, :2] += [x, y]
        shape = {
            "model": "cylinder",
            "root": [x, y, gz],
            "axis": [0.0, 0.0, 1.0],
            # the mesh is a 20-gon: its vertices at ``radius``, its faces at radius·cos(π/20)
            "radius": float(0.5 * radius * (1.0 + np.cos(np.pi / 20))),
            "height": float(height),
        }
        albedo = np.array(_COLOURS[cls]) * self.rng.uniform(0.9, 1.1)
        self._add(cls, v, t, np.clip(albedo, 0, 1), shape)
        self.footprints.append((np.array([x, y]), radius))

    def place_cylinders(self, cls: str, n: int, candidates: np.ndarray) -> None:
        lo, hi = self.p.pole_height if cls == "pole" else self.p.trunk_height
        order = self.rng.permutation(len(candidates))
        placed = 0
        for i in order:
            if placed >= n:
                break
            xy = candidates[i] + self.rng.normal(0, 0.3, 2)
            r = self.rng.uniform(0.08, 0.12) if cls == "pole" else self.rng.uniform(0.15, 0.32)
            if not self.free(xy, r + 1.0):
                continue
            self.cylinder(cls, float(xy[0]), float(xy[1]), r, float(self.rng.uniform(lo, hi)))
            placed += 1

    def clutter(self, n: int) -> list[MeshPart]:
        """Benches and bins: unlabelled structure near the edges."""
        W, D = self.p.size
        out = []
        for _ in range(200):
            if n <= 0:
                break
            y = self.rng.uniform(0.8, 2.0) if self.rng.random() < 0.5 else self.rng.uniform(D - 2.0, D - 0.8)
            xy = np.array([self.rng.uniform(1.5, W - 1.5), y])
            if not self.free(xy, 1.2):
                continue
            yaw = self.rng.uniform(-np.pi, np.pi)
            R, o = self.ground.frame(float(xy[0]), float(xy[1]), yaw)
            if self.rng.random() < 0.5:  # bench
                boxes = [([-0.8, -0.25, 0.0], [0.8, 0.25, 0.45]), ([-0.8, 0.2, 0.45], [0.8, 0.25, 0.85])]
            else:  # bin
                boxes = [([-0.3, -0.3, 0.0], [0.3, 0.3, 0.9])]
            v, t = merge_meshes([box_mesh(np.array(a, float), np.array(b, float)) for a, b in boxes])
            out.append(MeshPart.uniform("clutter", v @ R.T + o, t, 0, np.array(_COLOURS["clutter"])))
            self.footprints.append((xy, 0.9))
            n -= 1
        return out

    # ---- layouts ---------------------------------------------------------------------------
    def parking_lot(self) -> tuple[np.ndarray, float]:
        """Two double rows of perpendicular stalls along x; poles between them, trees around."""
        W, D = self.p.size
        stall_w, stall_d, aisle = 2.6, 5.2, 6.0
        x0, x1 = 4.0, W - 6.0  # stalls leave the west entrance and an east end free
        n_stalls = max(1, int((x1 - x0) // stall_w))
        # the two double rows, centred in y
        span = 4 * stall_d + aisle
        y_lo = max(2.5, (D - span) / 2)
        rows = [  # (y of the stall centre, yaw of a nose-in vehicle)
            (y_lo + stall_d / 2, -np.pi / 2),
            (y_lo + 1.5 * stall_d, np.pi / 2),
            (y_lo + 2.5 * stall_d + aisle, -np.pi / 2),
            (y_lo + 3.5 * stall_d + aisle, np.pi / 2),
        ]
        jit = np.radians(self.p.yaw_jitter_deg)
        for y, yaw in rows:
            if y + stall_d / 2 > D - 1.0:
                continue
            for i in range(n_stalls):
                if self.rng.random() >= self.p.occupancy:
                    continue
                x = x0 + (i + 0.5) * stall_w
                facing = yaw + (np.pi if self.rng.random() < 0.3 else 0.0)  # some reversed in
                self.vehicle(
                    x + self.rng.normal(0, 0.1),
                    y + self.rng.normal(0, 0.15),
                    facing + self.rng.normal(0, jit),
                )
        # poles at the ends of the double rows, trees along the north and south edges
        pole_xy = np.array(
            [[x, y] for x in (x0 - 1.2, x1 + 1.2) for y in (y_lo + stall_d, y_lo + 3 * stall_d + aisle)]
        )
        tree_xy = np.array([[x, y] for x in np.arange(3.0, W - 2.0, 4.0) for y in (1.2, D - 1.2)])
        self.place_cylinders("pole", self.p.poles, pole_xy)
        self.place_cylinders("tree_trunk", self.p.trees, tree_xy)
        start = np.array([1.5, y_lo + 2 * stall_d + aisle / 2])
        return start, 0.0

    def street(self) -> tuple[np.ndarray, float]:
        """A road along x with parallel parking on both sides; poles and trees on the sidewalks."""
        W, D = self.p.size
        yc = D / 2
        lane = 3.2
        jit = np.radians(self.p.yaw_jitter_deg)
        for side in (-1, 1):
            y = yc + side * (lane + 1.1)
            x = 2.0
            while True:
                x += self.rng.uniform(0.8, 2.5)
                van = self.rng.random() < self.p.van_fraction
                L = 5.3 if van else 4.6
                if x + L > W - 2.0:
                    break
                if self.rng.random() < self.p.occupancy:
                    yaw = (0.0 if side < 0 else np.pi) + self.rng.normal(0, jit)
                    self.vehicle(x + L / 2, y + self.rng.normal(0, 0.1), yaw)
                x += L
        walk = [yc - lane - 3.2, yc + lane + 3.2]
        pole_xy = np.array([[x, y] for x in np.arange(4.0, W - 2.0, 8.0) for y in walk])
        tree_xy = np.array([[x, y] for x in np.arange(8.0, W - 2.0, 8.0) for y in walk])
        self.place_cylinders("pole", self.p.poles, pole_xy)
        self.place_cylinders("tree_trunk", self.p.trees, tree_xy)
        return np.array([1.5, yc]), 0.0

    # ---- the scene -------------------------------------------------------------------------
    def ground_parts(self, lo: np.ndarray, hi: np.ndarray) -> list[MeshPart]:
        """The ground as tiles (one instance each, or structure): a closed slab under the surface."""
        p = self.p
        tile = p.ground_tile
        nx, ny = int(np.ceil((hi[0] - lo[0]) / tile)), int(np.ceil((hi[1] - lo[1]) / tile))
        xs = np.linspace(lo[0], hi[0], nx + 1)
        ys = np.linspace(lo[1], hi[1], ny + 1)
        out = []
        colour = np.array(_COLOURS["ground"])
        for i in range(nx):
            for j in range(ny):
                xy = np.array(
                    [[xs[i], ys[j]], [xs[i + 1], ys[j]], [xs[i + 1], ys[j + 1]], [xs[i], ys[j + 1]]]
                )
                top = np.column_stack([xy, self.ground.z(xy)])
                bottom = top - [0.0, 0.0, 0.3]
                v = np.vstack([bottom, top])
                t = np.array(
                    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                     [2, 3, 7], [2, 7, 6], [1, 2, 6], [1, 6, 5], [3, 0, 4], [3, 4, 7]],
                    dtype=np.int64,
                )  # fmt: skip
                albedo = np.clip(colour * self.rng.uniform(0.93, 1.07), 0, 1)
                if p.ground_class is None:
                    out.append(MeshPart.uniform(f"ground tile {i},{j}", v, t, 0, albedo))
                else:
                    name, inst = self._next(p.ground_class)
                    out.append(MeshPart.uniform(name, v, t, inst, albedo))
                    self.objects.append(
                        WorldObject(name, p.ground_class, inst, v.mean(axis=0), v.min(0), v.max(0))
                    )
        return out

    def build(self) -> WorldSpec:
        p = self.p
        W, D = p.size
        start, yaw = self.parking_lot() if p.layout == "parking_lot" else self.street()
        clutter = self.clutter(p.clutter)
        lo2, hi2 = np.array([0.0, 0.0]), np.array([W, D])
        ground = self.ground_parts(lo2, hi2)
        corners = np.array([[0, 0], [W, 0], [W, D], [0, D]], float)
        zc = self.ground.z(corners)
        parts = self.parts + clutter + ground
        return WorldSpec(
            name=p.name,
            parts=parts,
            objects=self.objects,
            floor_heights=(float(zc.min()),),
            bounds_lo=np.array([0.0, 0.0, float(zc.min()) - 0.2]),
            bounds_hi=np.array([W, D, float(zc.max()) + p.height]),
            start_xy=start,
            start_floor_z=float(self.ground.z(start)),
            start_yaw=yaw,
            extra_classes=(p.ground_class,) if p.ground_class else (),
            places={"start": np.array([*start, float(self.ground.z(start))])},
        )


def generate_outdoor(params: OutdoorWorldParams, rng: np.random.Generator) -> WorldSpec:
    """Generate an outdoor scene from ``params``, drawing every choice from ``rng``."""
    return _Builder(params, rng).build()
