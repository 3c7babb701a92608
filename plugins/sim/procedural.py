"""Procedural buildings: floors, a corridor with rooms off it, a lobby with an open shaft, furniture.

Layout of every floor (x east, y north, the building spans ``[0, W] × [0, D]``)::

    y=D ┌──────────┬───────┬─────────┬────────────┐
        │  room    │ room  │  room   │            │
        │          │       │         │   lobby    │
        ├──  ──────┴── ────┴─────  ──┤  (shaft)   │
        │ start →     corridor           ┌──┐     │
        ├───  ───────┬─────  ──┬─────  ──┤  └──┘   │
        │  room      │  room   │  room   │         │
    y=0 └────────────┴─────────┴─────────┴─────────┘
       x=0                              x=W-lobby  x=W

Rooms of random widths line both sides of a corridor running east into a lobby; each room has a
door (gap of ``door_width`` under a lintel) onto the corridor, some have a second door onto a
neighbour or the lobby. With more than one floor, the lobby holds an open shaft through every
intermediate slab, so the robot can fly between floors. Furniture (chairs, tables, shelves,
sofas) comes in arrangements: meeting tables ringed by chairs (tight clusters, loop-closure
material), classrooms with repeated rows of chairs (symmetric layouts that make data
association hard), lounges and offices. Everything is drawn from the generator handed in, so a
seed fixes the building.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from amslam.geometry import yaw_matrix
from amslam.interfaces import BackendParams, FieldError
from amslam.lib.class_colours import class_colour
from amslam.plugins.sim.world import (
    MeshPart,
    WorldObject,
    WorldSpec,
    boxes_mesh,
    merge_meshes,
)


class ProceduralWorldParams(BackendParams):
    """A seeded procedural building."""

    kind: Literal["procedural"] = "procedural"
    name: str = Field("procedural", description="name of the world in reports")
    size: tuple[Annotated[float, Field(gt=0.0, le=500.0)], Annotated[float, Field(gt=0.0, le=500.0)]] = Field(
        (20.0, 14.0), description="footprint (x, y) in metres (at most 500 m a side)"
    )
    floors: int = Field(1, ge=1, le=4, description="number of floors")
    floor_height: float = Field(3.0, gt=2.0, le=20.0, description="floor-to-floor height in metres")
    slab: float = Field(
        0.2, gt=0.0, le=1.0, description="floor slab thickness in metres (ceiling = height - slab)"
    )
    wall_thickness: float = Field(0.2, gt=0.0, le=1.0, description="thickness of every wall, m")
    corridor_width: float = Field(2.0, ge=1.2, le=50.0, description="clear width of the corridor")
    door_width: float = Field(1.2, ge=1.0, le=10.0, description="clear width of door openings")
    door_height: float = Field(2.1, gt=1.5, le=20.0, description="clear height of door openings, m")
    room_width: tuple[
        Annotated[float, Field(ge=1.5, le=100.0)], Annotated[float, Field(ge=1.5, le=100.0)]
    ] = Field((3.5, 6.0), description="range [narrowest, widest] of room widths along x, m (at least 1.5)")
    lobby_width: float = Field(4.5, ge=3.0, le=100.0, description="width (x) of the lobby at the east end")
    shaft_size: float = Field(2.6, ge=1.5, le=100.0, description="side of the open shaft between floors")
    furniture: float = Field(
        1.0, ge=0.0, le=10.0, description="furniture density multiplier (0 = empty rooms)"
    )
    extra_doors: float = Field(0.35, ge=0.0, le=1.0, description="probability of a door to a neighbour")
    seed_offset: int = Field(
        0, ge=-(2**63), le=2**63 - 1, description="added to the run seed: a different building, same run"
    )

    @model_validator(mode="after")
    def _fits(self) -> ProceduralWorldParams:
        problem = self.layout_problem()
        if problem:
            raise FieldError(*problem)
        return self

    def layout_problem(self) -> tuple[str, str] | None:
        """The field and why these dimensions make no building (None if they make one)."""
        W, D = self.size
        lo, hi = self.room_width
        if lo > hi:
            return "room_width", f"[{lo:g}, {hi:g}]: the narrowest room must not be wider than the widest"
        if self.door_height >= self.floor_height - self.slab:
            ceiling = self.floor_height - self.slab
            return (
                "door_height",
                f"{self.door_height:g} m: a door must be lower than the ceiling ({ceiling:g} m)",
            )
        if self.shaft_size >= self.lobby_width:
            return (
                "shaft_size",
                f"{self.shaft_size:g} m: the shaft must be smaller than lobby_width ({self.lobby_width:g} m)",
            )
        t = self.wall_thickness
        cy0 = D / 2 - self.corridor_width / 2 - t / 2  # corridor wall centre lines
        cy1 = D / 2 + self.corridor_width / 2 + t / 2
        if cy0 < 2.5 or D - cy1 < 2.5 or W - self.lobby_width < 4.0:
            return "size", (
                f"building {W:g}x{D:g} m is too small for a corridor ({self.corridor_width:g} m), rooms "
                f"(2.5 m deep) and a lobby ({self.lobby_width:g} m)"
            )
        return None


@dataclass
class _Rect:
    x0: float
    y0: float
    x1: float
    y1: float

    def overlaps(self, o: _Rect, pad: float = 0.0) -> bool:
        return not (
            self.x1 + pad <= o.x0 or o.x1 + pad <= self.x0 or self.y1 + pad <= o.y0 or o.y1 + pad <= self.y0
        )

    def contains(self, o: _Rect) -> bool:
        return self.x0 <= o.x0 and self.y0 <= o.y0 and o.x1 <= self.x1 and o.y1 <= self.y1


@dataclass
class _Spots:
    """Free floor in a room: ``inner`` (the room less a margin) less what is ``placed``."""

    rng: np.random.Generator
    inner: _Rect
    placed: list[_Rect]

    def take(self, r: _Rect) -> bool:
        """Claim ``r`` if it is inside the room and 0.15 m clear of everything placed."""
        if self.inner.contains(r) and not any(r.overlaps(o, 0.15) for o in self.placed):
            self.placed.append(r)
            return True
        return False

    def place(self, w: float, d: float, attempts: int = 30) -> tuple[float, float] | None:
        """The centre of a free ``w`` × ``d`` spot drawn at random (up to ``attempts`` draws)."""
        inner = self.inner
        for _ in range(attempts):
            x = self.rng.uniform(inner.x0 + w / 2, max(inner.x0 + w / 2, inner.x1 - w / 2))
            y = self.rng.uniform(inner.y0 + d / 2, max(inner.y0 + d / 2, inner.y1 - d / 2))
            if self.take(_Rect(x - w / 2, y - d / 2, x + w / 2, y + d / 2)):
                return x, y
        return None


# -------------------------------------------------------------------------------------------
# furniture models: boxes in the object's own frame (x forward, origin at floor centre)
# -------------------------------------------------------------------------------------------
def _chair(rng: np.random.Generator) -> list[tuple[list[float], list[float]]]:
    w = rng.uniform(0.42, 0.5)
    h = rng.uniform(0.43, 0.48)
    leg = 0.04
    b = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            cx, cy = sx * (w / 2 - leg / 2), sy * (w / 2 - leg / 2)
            b.append(([cx - leg / 2, cy - leg / 2, 0.0], [cx + leg / 2, cy + leg / 2, h]))
    b.append(([-w / 2, -w / 2, h], [w / 2, w / 2, h + 0.05]))  # seat
    back_h = rng.uniform(0.38, 0.5)
    b.append(([-w / 2, -w / 2, h + 0.05], [-w / 2 + 0.05, w / 2, h + 0.05 + back_h]))  # backrest (rear, -x)
    return b


def _table(rng: np.random.Generator, length: float | None = None, width: float | None = None):
    L = length if length is not None else rng.uniform(1.0, 1.8)
    W = width if width is not None else rng.uniform(0.7, 1.0)
    h = rng.uniform(0.72, 0.76)
    leg = 0.06
    b = [([-L / 2, -W / 2, h - 0.04], [L / 2, W / 2, h])]
    for sx in (-1, 1):
        for sy in (-1, 1):
            cx, cy = sx * (L / 2 - 0.08), sy * (W / 2 - 0.08)
            b.append(([cx - leg / 2, cy - leg / 2, 0.0], [cx + leg / 2, cy + leg / 2, h - 0.04]))
    return b, L, W


def _shelf(rng: np.random.Generator):
    w = rng.uniform(0.8, 1.2)
    d = 0.38
    h = rng.uniform(1.6, 2.0)
    t = 0.03
    b = [
        ([-d / 2, -w / 2, 0.0], [d / 2, -w / 2 + t, h]),  # sides
        ([-d / 2, w / 2 - t, 0.0], [d / 2, w / 2, h]),
        ([-d / 2, -w / 2, 0.0], [-d / 2 + t, w / 2, h]),  # back (-x)
    ]
    for z in np.linspace(0.05, h - t, 5):
        b.append(([-d / 2, -w / 2, z], [d / 2, w / 2, z + t]))
    return b, d, w


def _sofa(rng: np.random.Generator):
    L = rng.uniform(1.6, 2.2)
    d = 0.85
    b = [
        ([-d / 2, -L / 2, 0.0], [d / 2, L / 2, 0.42]),  # base
        ([-d / 2, -L / 2, 0.42], [-d / 2 + 0.2, L / 2, 0.85]),  # back (-x)
        ([-d / 2, -L / 2, 0.42], [d / 2, -L / 2 + 0.18, 0.62]),  # arms
        ([-d / 2, L / 2 - 0.18, 0.42], [d / 2, L / 2, 0.62]),
    ]
    return b, d, L


#: The furniture models by class: each draws one piece's boxes ``(lo, hi)`` in its own frame.
_FURNITURE = {
    "chair": _chair,
    "table": lambda rng: _table(rng)[0],
    "shelf": lambda rng: _shelf(rng)[0],
    "sofa": lambda rng: _sofa(rng)[0],
}
FURNITURE_CLASSES = tuple(_FURNITURE)


def furniture_boxes(class_name: str, rng: np.random.Generator) -> list[tuple[list[float], list[float]]]:
    """One furniture piece of a class as the buildings make it: boxes ``(lo, hi)`` in its own frame
    (x forward, origin at the floor centre), its size drawn like the buildings'; legs, seat and
    backrest apart, not a solid box (what a depth camera sees of it, for ``amslam characterise``)."""
    if class_name not in _FURNITURE:
        raise ValueError(f"no furniture model of class {class_name!r}; known: {', '.join(FURNITURE_CLASSES)}")
    return _FURNITURE[class_name](rng)


def piece_shape(boxes: list, position: np.ndarray, yaw: float) -> dict:
    """The true cuboid of a piece (paper 2): the bounds of its boxes ``(lo, hi)`` in its own frame,
    placed at ``position`` (the origin of its frame) turned by ``yaw``."""
    blo = np.min([b[0] for b in boxes], axis=0)
    bhi = np.max([b[1] for b in boxes], axis=0)
    R = yaw_matrix(yaw)
    return {
        "model": "cuboid",
        "center": (R @ ((blo + bhi) / 2.0) + np.asarray(position, float)).tolist(),
        "yaw": float(np.arctan2(R[1, 0], R[0, 0])),
        "dims": (bhi - blo).tolist(),
        "rotation": R.tolist(),
    }


class _Builder:
    """Accumulates structure boxes and furniture instances of one building."""

    def __init__(self, p: ProceduralWorldParams, rng: np.random.Generator):
        self.p = p
        self.rng = rng
        self.walls: list[list[tuple]] = [[] for _ in range(p.floors)]
        self.floors: list[list[tuple]] = [[] for _ in range(p.floors + 1)]
        self.objects: list[WorldObject] = []
        self.parts: list[MeshPart] = []
        self.counts: dict[str, int] = {}

    # ---- furniture -------------------------------------------------------------------------
    def add_object(self, cls: str, boxes: list, x: float, y: float, z: float, yaw: float) -> None:
        v, t = boxes_mesh([(np.array(lo), np.array(hi)) for lo, hi in boxes])
        v = v @ yaw_matrix(yaw).T + np.array([x, y, z])
        self.counts[cls] = self.counts.get(cls, 0) + 1
        name = f"{cls}_{self.counts[cls]}"
        inst = len(self.objects) + 1
        # per-instance colour variation so an image detector sees some diversity
        albedo = np.clip(class_colour(cls) * self.rng.uniform(0.8, 1.15) + self.rng.normal(0, 0.03, 3), 0, 1)
        self.parts.append(MeshPart.uniform(name, v, t, inst, albedo))
        lo, hi = v.min(axis=0), v.max(axis=0)
        shape = piece_shape(boxes, np.array([x, y, z]), yaw)
        self.objects.append(WorldObject(name, cls, inst, (lo + hi) / 2.0, lo, hi, shape))

    def furnish(self, room: _Rect, z: float, keep_out: list[_Rect]) -> None:
        """Place one arrangement (and maybe loose pieces) in a room, avoiding keep-out zones."""
        if self.p.furniture <= 0:
            return
        inner = _Rect(room.x0 + 0.1, room.y0 + 0.1, room.x1 - 0.1, room.y1 - 0.1)
        spots = _Spots(self.rng, inner, list(keep_out))
        kind = self.rng.choice(["meeting", "classroom", "lounge", "office"], p=[0.35, 0.25, 0.2, 0.2])
        arrange = {"meeting": self._meeting, "classroom": self._classroom, "lounge": self._lounge}
        arrange.get(str(kind), self._office)(spots, z)
        self._pieces_against_walls(spots, z)

    def _meeting(self, spots: _Spots, z: float) -> None:
        """A table with chairs along both long sides, their backs away from it."""
        rng, dens = self.rng, self.p.furniture
        tb, L, W = _table(rng)
        n_side = max(1, int(L // 0.6))
        pos = spots.place(L + 1.2, W + 1.2)
        if pos is None:
            return
        x, y = pos
        self.add_object("table", tb, x, y, z, 0.0)
        for sx in np.linspace(-L / 2 + L / (2 * n_side), L / 2 - L / (2 * n_side), n_side):
            for side in (-1, 1):
                if rng.random() < 0.85 * min(1.0, dens):
                    jit = rng.normal(0, 0.04, 2)
                    cy = y + side * (W / 2 + 0.3) + jit[1]
                    # backrest (-x in the chair frame) faces away from the table
                    yaw = -side * np.pi / 2 + rng.normal(0, 0.15)
                    self.add_object("chair", _chair(rng), x + sx + jit[0], cy, z, yaw)

    def _classroom(self, spots: _Spots, z: float) -> None:
        """Rows of chairs on a grid."""
        rng, dens = self.rng, self.p.furniture
        rows = int(rng.integers(2, 4))
        cols = int(rng.integers(2, 5))
        pitch_x, pitch_y = 0.9, 0.75
        pos = spots.place(rows * pitch_x + 0.2, cols * pitch_y + 0.2)
        if pos is None:
            return
        x, y = pos
        for i in range(rows):
            for j in range(cols):
                if rng.random() < min(1.0, 0.95 * dens):
                    cx = x + (i - (rows - 1) / 2) * pitch_x
                    cy = y + (j - (cols - 1) / 2) * pitch_y
                    self.add_object("chair", _chair(rng), cx, cy, z, rng.normal(0, 0.03))

    def _lounge(self, spots: _Spots, z: float) -> None:
        """A sofa and a low table."""
        rng = self.rng
        sb, d, L = _sofa(rng)
        pos = spots.place(d, L)
        if pos is not None:
            self.add_object("sofa", sb, *pos, z, 0.0 if rng.random() < 0.5 else np.pi)
        tb, L2, W2 = _table(rng, rng.uniform(0.8, 1.1), rng.uniform(0.5, 0.7))
        pos = spots.place(L2, W2)
        if pos is not None:
            self.add_object("table", tb, *pos, z, 0.0)

    def _office(self, spots: _Spots, z: float) -> None:
        """A desk and its chair."""
        rng = self.rng
        tb, L, W = _table(rng)
        pos = spots.place(L + 0.2, W + 1.0)
        if pos is not None:
            x, y = pos
            self.add_object("table", tb, x, y, z, 0.0)
            self.add_object("chair", _chair(rng), x, y + W / 2 + 0.3, z, -np.pi / 2 + rng.normal(0, 0.3))

    def _pieces_against_walls(self, spots: _Spots, z: float) -> None:
        """Loose shelves, chairs and sofas, each backed against one of the room's walls."""
        rng, inner = self.rng, spots.inner
        for _ in range(int(rng.poisson(1.2 * self.p.furniture))):
            which = rng.choice(["shelf", "chair", "sofa"], p=[0.5, 0.35, 0.15])
            if which == "shelf":
                b, d, w = _shelf(rng)
            elif which == "sofa":
                b, d, w = _sofa(rng)
            else:
                b, d, w = _chair(rng), 0.5, 0.5
            side = int(rng.integers(4))  # 0 west, 1 east, 2 south, 3 north wall
            for _ in range(20):
                if side < 2:
                    x = inner.x0 + d / 2 + 0.02 if side == 0 else inner.x1 - d / 2 - 0.02
                    y = rng.uniform(inner.y0 + w / 2, max(inner.y0 + w / 2, inner.y1 - w / 2))
                    r = _Rect(x - d / 2, y - w / 2, x + d / 2, y + w / 2)
                    yaw = 0.0 if side == 0 else np.pi
                else:
                    y = inner.y0 + d / 2 + 0.02 if side == 2 else inner.y1 - d / 2 - 0.02
                    x = rng.uniform(inner.x0 + w / 2, max(inner.x0 + w / 2, inner.x1 - w / 2))
                    r = _Rect(x - w / 2, y - d / 2, x + w / 2, y + d / 2)
                    yaw = np.pi / 2 if side == 2 else -np.pi / 2
                if spots.take(r):
                    self.add_object(str(which), b, x, y, z, yaw + rng.normal(0, 0.02))
                    break

    # ---- structure ---------------------------------------------------------------------------
    def wall_x(self, floor: int, y: float, x0: float, x1: float, gaps: list[tuple[float, float]]) -> None:
        """A wall along x (centre line y) from x0 to x1 with door gaps (a, b)."""
        self._wall(floor, 0, y, x0, x1, gaps)

    def wall_y(self, floor: int, x: float, y0: float, y1: float, gaps: list[tuple[float, float]]) -> None:
        """A wall along y (centre line x) from y0 to y1 with door gaps (a, b)."""
        self._wall(floor, 1, x, y0, y1, gaps)

    def _wall(self, floor: int, axis: int, c: float, a0: float, a1: float, gaps) -> None:
        p = self.p
        z0 = floor * p.floor_height
        z1 = (floor + 1) * p.floor_height - p.slab
        h = p.wall_thickness / 2
        cuts = [a0]
        for g0, g1 in sorted(gaps):
            cuts += [g0, g1]
        cuts.append(a1)

        def box(s0: float, s1: float, zlo: float, zhi: float) -> None:
            if s1 - s0 <= 1e-6 or zhi - zlo <= 1e-6:
                return
            if axis == 0:
                self.walls[floor].append(([s0, c - h, zlo], [s1, c + h, zhi]))
            else:
                self.walls[floor].append(([c - h, s0, zlo], [c + h, s1, zhi]))

        for i in range(0, len(cuts), 2):
            box(cuts[i], cuts[i + 1], z0, z1)
        for g0, g1 in gaps:  # lintels over doors
            box(g0, g1, z0 + p.door_height, z1)

    def build(self) -> WorldSpec:
        p = self.p
        at = _Layout.of(p)
        for f in range(p.floors):
            self._build_floor(f, at)
        self._add_slabs(at)
        W, D = p.size
        return WorldSpec(
            name=p.name,
            parts=self._mesh_parts(),
            objects=self.objects,
            floor_heights=tuple(f * p.floor_height for f in range(p.floors)),
            bounds_lo=np.array([0.0, 0.0, -p.slab]),
            bounds_hi=np.array([W, D, p.floors * p.floor_height]),
            start_xy=np.array([p.wall_thickness + 1.0, D / 2]),
            start_floor_z=0.0,
            start_yaw=0.0,
            places={
                "shaft": np.array([*at.shaft_centre, 0.0]),
                "corridor_east": np.array([at.xl - 1.0, D / 2, 0.0]),
                "lobby_entrance": np.array([at.xl + 1.0, D / 2, 0.0]),
            },
        )

    def _build_floor(self, f: int, at: _Layout) -> None:
        """One floor: outer walls, the rooms on both sides of the corridor (partitions, doors,
        furniture), the corridor and lobby walls, the lobby's furniture. The random draws come in
        this order, so a seed's building stays the same."""
        p, t = self.p, self.p.wall_thickness
        W, D = p.size
        z, top = f * p.floor_height, (f + 1) * p.floor_height - p.slab
        self.walls[f] += [
            ([0, 0, z], [W, t, top]),
            ([0, D - t, z], [W, D, top]),
            ([0, 0, z], [t, D, top]),
            ([W - t, 0, z], [W, D, top]),
        ]
        corridor_gaps: dict[int, list] = {0: [], 1: []}
        lobby_gaps = [(at.cy0 + t / 2, at.cy1 - t / 2)]  # the corridor opens into the lobby
        rooms: list[tuple[_Rect, list[_Rect]]] = []
        for side in (0, 1):
            rooms += self._strip_rooms(f, side, at, corridor_gaps[side], lobby_gaps)
        for room, keep in rooms:
            self.furnish(room, z, keep)
        self.wall_x(f, at.cy0, t, at.xl, corridor_gaps[0])
        self.wall_x(f, at.cy1, t, at.xl, corridor_gaps[1])
        self.wall_y(f, at.xl, t, D - t, lobby_gaps)
        # lobby furniture: a few pieces along the walls, away from the shaft and the corridor
        lobby = _Rect(at.xl + t / 2, t, W - t, D - t)
        sh = at.shaft
        keep = [
            _Rect(sh.x0 - 0.6, sh.y0 - 0.6, sh.x1 + 0.6, sh.y1 + 0.6),
            _Rect(at.xl - 1.5, at.cy0 - 0.5, at.xl + 2.0, at.cy1 + 0.5),
        ] + [_Rect(at.xl - 1.0, a - 0.3, at.xl + 1.6, b + 0.3) for a, b in lobby_gaps]
        self.furnish(lobby, z, keep)

    def _strip_rooms(
        self, f: int, side: int, at: _Layout, corridor_gaps: list, lobby_gaps: list
    ) -> list[tuple[_Rect, list[_Rect]]]:
        """The rooms of one side of the corridor (0 south, 1 north), each with the zones its
        furniture keeps clear of its doors; builds their partitions and adds their doors to the
        corridor's and the lobby's gaps."""
        p, rng, t, dw = self.p, self.rng, self.p.wall_thickness, self.p.door_width
        D = p.size[1]
        ya, yb = (t, at.cy0 - t / 2) if side == 0 else (at.cy1 + t / 2, D - t)
        wy0, wy1 = (0.0, at.cy0) if side == 0 else (at.cy1, D)  # partition walls span the strip
        door_y = yb if side == 0 else ya  # the room's corridor-side edge
        # split the strip into rooms along x
        cuts = [t / 2]
        while True:
            w = rng.uniform(*p.room_width)
            if cuts[-1] + w + p.room_width[0] > at.xl:
                break
            cuts.append(cuts[-1] + w)
        cuts.append(at.xl)
        side_gaps: dict[int, list] = {}
        for i in range(1, len(cuts) - 1):
            gaps = []
            if rng.random() < p.extra_doors and yb - ya > dw + 0.8:
                g = rng.uniform(ya + 0.4, yb - 0.4 - dw)
                gaps.append((g, g + dw))
            side_gaps[i] = gaps
            self.wall_y(f, cuts[i], wy0, wy1, gaps)
        if rng.random() < 0.5 and yb - ya > dw + 0.8:  # the last room opens into the lobby
            g = rng.uniform(ya + 0.4, yb - 0.4 - dw)
            lobby_gaps.append((g, g + dw))
            side_gaps[len(cuts) - 1] = [(g, g + dw)]
        rooms = []
        for i in range(len(cuts) - 1):
            rx0, rx1 = cuts[i] + t / 2, cuts[i + 1] - t / 2
            g = rng.uniform(rx0 + 0.3, max(rx0 + 0.3, rx1 - 0.3 - dw))
            corridor_gaps.append((g, g + dw))
            keep = [_Rect(g - 0.3, door_y - 1.3, g + dw + 0.3, door_y + 1.3)]
            for a, b in side_gaps.get(i, []):  # door in the west partition
                keep.append(_Rect(rx0 - 1.3, a - 0.3, rx0 + 1.3, b + 0.3))
            for a, b in side_gaps.get(i + 1, []):  # door in the east partition
                keep.append(_Rect(rx1 - 1.3, a - 0.3, rx1 + 1.3, b + 0.3))
            rooms.append((_Rect(rx0, ya, rx1, yb), keep))
        return rooms

    def _add_slabs(self, at: _Layout) -> None:
        """The slabs: the ground, one under each upper floor with the shaft's hole, the roof."""
        p, sh = self.p, at.shaft
        W, D = p.size
        for f in range(p.floors + 1):
            z1 = f * p.floor_height
            z0 = z1 - p.slab
            if 0 < f < p.floors:
                self.floors[f] += [
                    ([0, 0, z0], [W, sh.y0, z1]),
                    ([0, sh.y1, z0], [W, D, z1]),
                    ([0, sh.y0, z0], [sh.x0, sh.y1, z1]),
                    ([sh.x1, sh.y0, z0], [W, sh.y1, z1]),
                ]
            else:
                self.floors[f].append(([0, 0, z0], [W, D, z1]))

    def _mesh_parts(self) -> list[MeshPart]:
        """The furniture's parts, then each floor's walls and each slab as one part."""
        parts = list(self.parts)
        for f, boxes in enumerate(self.walls):
            v, tr = boxes_mesh([(np.array(a, float), np.array(b, float)) for a, b in boxes])
            parts.append(MeshPart.uniform(f"wall (floor {f})", v, tr, 0, class_colour("wall")))
        for f, boxes in enumerate(self.floors):
            v, tr = boxes_mesh([(np.array(a, float), np.array(b, float)) for a, b in boxes])
            roof = f == self.p.floors
            name = "ground slab" if f == 0 else ("roof slab" if roof else f"slab under floor {f}")
            # The top face is a floor, the bottom face a ceiling: colour per triangle by normal.
            part = MeshPart.uniform(name, v, tr, 0, class_colour("floor"))
            nz = _triangle_normals(v, tr)[:, 2]
            part.albedo[nz < -0.5] = class_colour("ceiling")
            parts.append(part)
        return parts


@dataclass(frozen=True)
class _Layout:
    """Where a floor plan's fixed lines are: the lobby wall's centre line ``xl`` (the lobby at the
    east end), the corridor walls' ``cy0`` and ``cy1``, the shaft in the lobby's middle."""

    xl: float
    cy0: float
    cy1: float
    # kept beside the rect, not derived from it: (x0 + x1) / 2 may differ from the centre in its
    # last bit, and the world's `places["shaft"]` (a mission's start) must stay what it was
    shaft_centre: tuple[float, float]
    shaft: _Rect

    @classmethod
    def of(cls, p: ProceduralWorldParams) -> _Layout:
        W, D = p.size
        t = p.wall_thickness
        xl = W - p.lobby_width
        cy0 = D / 2 - p.corridor_width / 2 - t / 2
        cy1 = D / 2 + p.corridor_width / 2 + t / 2
        if cy0 < 2.5 or D - cy1 < 2.5 or xl < 4.0:
            raise ValueError(f"building {W}x{D} m is too small for a corridor, rooms and a lobby")
        sx, sy, s = W - p.lobby_width / 2, D / 2, p.shaft_size / 2
        return cls(xl, cy0, cy1, (sx, sy), _Rect(sx - s, sy - s, sx + s, sy + s))


def _triangle_normals(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def generate_building(params: ProceduralWorldParams, rng: np.random.Generator) -> WorldSpec:
    """Generate a building from ``params``, drawing every choice from ``rng``."""
    return _Builder(params, rng).build()


__all__ = [
    "FURNITURE_CLASSES",
    "ProceduralWorldParams",
    "furniture_boxes",
    "piece_shape",
    "generate_building",
    "merge_meshes",
]
