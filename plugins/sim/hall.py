"""A warehouse hall: one tall open space with rows of pallet racks and an open bay at one end.

Plan (x east, y north, the hall spans ``[0, W] × [0, D]``, ``height`` high, no inner walls)::

    y=D ┌──────────────────────────────┐
        │ ▌▐  ▌▐  ▌▐  ▌▐  ▌▐  ▌▐  ▌▐    │   racks in rows along y, aisles between them
        │ ▌▐  ▌▐  ▌▐  ▌▐  ▌▐  ▌▐  ▌▐    │
        │          cross aisle         │
        │ ▌▐  ▌▐  ▌▐  ▌▐  ▌▐  ▌▐  ▌▐    │
        │                              │
        │  bay: tables, chairs, shelves│
    y=0 └────────────── start ─────────┘
       x=0                            x=W

It is the large, tall, repetitive building that the office floors of :mod:`.procedural` are not:
the volume the maps cover, the frontiers they keep and the graph the planner searches grow with
it (issue #20 measures the mission's time per module against building size on it). Every rack
bay is a ``shelf`` object (uprights, beams and decks as boxes); the bay near the start holds a
few tables with chairs and shelves like the office furniture. Everything is drawn from the
generator handed in, so a seed fixes the hall.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from amslam.interfaces import BackendParams, FieldError
from amslam.lib.class_colours import class_colour
from amslam.plugins.sim.procedural import ProceduralWorldParams, _Builder, _Rect, _triangle_normals
from amslam.plugins.sim.world import MeshPart, WorldSpec, boxes_mesh


class HallWorldParams(BackendParams):
    """A seeded warehouse hall (``world: {kind: hall, ...}``)."""

    kind: Literal["hall"] = "hall"
    name: str = Field("hall", description="name of the world in reports")
    size: tuple[Annotated[float, Field(gt=0.0, le=500.0)], Annotated[float, Field(gt=0.0, le=500.0)]] = Field(
        (20.0, 30.0), description="footprint (x, y) in metres (at most 500 m a side)"
    )
    height: float = Field(10.0, gt=3.0, le=50.0, description="clear height under the roof, m")
    slab: float = Field(0.2, gt=0.0, le=1.0, description="thickness of the floor and roof slabs, m")
    wall_thickness: float = Field(0.2, gt=0.0, le=1.0, description="thickness of the outer walls, m")
    rack_height: tuple[Annotated[float, Field(ge=1.0, le=45.0)], Annotated[float, Field(ge=1.0, le=45.0)]] = (
        Field((4.0, 6.0), description="range [lowest, highest] of a rack row's height, m")
    )
    rack_depth: float = Field(1.1, ge=0.3, le=5.0, description="depth (x) of a rack, m")
    bay_length: float = Field(2.7, ge=0.8, le=10.0, description="length (y) of one rack bay, one object, m")
    aisle_width: float = Field(3.0, ge=1.5, le=50.0, description="clear width of the aisles between rows, m")
    open_bay: float = Field(
        6.0, ge=3.0, le=100.0, description="depth (y) of the open bay at the south end (the start), m"
    )
    furniture: float = Field(1.0, ge=0.0, le=10.0, description="furniture density in the open bay (0: none)")

    @model_validator(mode="after")
    def _fits(self) -> HallWorldParams:
        W, D = self.size
        lo, hi = self.rack_height
        if lo > hi:
            raise FieldError("rack_height", f"[{lo:g}, {hi:g}]: the lowest row must not be the higher")
        if hi >= self.height:
            raise FieldError("rack_height", f"{hi:g} m: racks must be lower than the hall ({self.height:g})")
        if self.open_bay + 2.0 * self.bay_length + 2.0 > D or self.rack_depth + 2.0 * self.aisle_width > W:
            raise FieldError(
                "size",
                f"hall {W:g}x{D:g} m is too small for an open bay ({self.open_bay:g} m), two rack bays "
                f"({self.bay_length:g} m) and a rack row between two aisles ({self.aisle_width:g} m)",
            )
        return self


def _rack(rng: np.random.Generator, depth: float, length: float, height: float):
    """Boxes of one pallet-rack bay in its own frame (x across, y along the row, z up), its dims."""
    post, beam, deck = 0.08, 0.1, 0.03
    b = []
    for sx in (-1, 1):  # four uprights
        for sy in (-1, 1):
            cx, cy = sx * (depth / 2 - post / 2), sy * (length / 2 - post / 2)
            b.append(([cx - post / 2, cy - post / 2, 0.0], [cx + post / 2, cy + post / 2, height]))
    levels = max(2, int(height / rng.uniform(1.3, 1.8)))
    for z in np.linspace(0.15, height - beam, levels):
        for sx in (-1, 1):  # front and back beams, a deck between
            cx = sx * (depth / 2 - post / 2)
            b.append(([cx - post / 2, -length / 2, z], [cx + post / 2, length / 2, z + beam]))
        deck_lo, deck_hi = z + beam, z + beam + deck
        b.append(([-depth / 2, -length / 2 + post, deck_lo], [depth / 2, length / 2 - post, deck_hi]))
        if rng.random() < 0.6:  # a pallet load on this level
            load_h = min(rng.uniform(0.4, 1.0), height - z - beam - deck - 0.05)
            if load_h > 0.2:
                ly = rng.uniform(0.3, 0.45) * length
                b.append(
                    (
                        [-depth / 2 + 0.1, -ly, z + beam + deck],
                        [depth / 2 - 0.1, ly, z + beam + deck + load_h],
                    )
                )
    return b


def generate_hall(params: HallWorldParams, rng: np.random.Generator) -> WorldSpec:
    """Generate a hall from ``params``, drawing every choice from ``rng``."""
    p = params
    W, D = p.size
    t, H = p.wall_thickness, p.height
    # the open bay's furniture comes from the office building's arrangements (of its parameters
    # only the furniture density is read)
    builder = _Builder(ProceduralWorldParams(furniture=p.furniture), rng)

    # rack rows along y, aisles between them and along the side walls
    pitch = p.rack_depth + p.aisle_width
    rows = int((W - 2 * t - p.aisle_width) // pitch)
    x_first = t + (W - 2 * t - rows * pitch + p.aisle_width) / 2 + p.rack_depth / 2
    y0, y1 = p.open_bay, D - t - 1.0
    bays = int((y1 - y0) // p.bay_length)
    cross = bays // 2 if bays >= 4 else None  # a cross aisle halfway, one bay wide
    for r in range(rows):
        x = x_first + r * pitch
        height = rng.uniform(*p.rack_height)
        for i in range(bays):
            if i == cross:
                continue
            y = y0 + (i + 0.5) * p.bay_length
            builder.add_object("shelf", _rack(rng, p.rack_depth, p.bay_length, height), x, y, 0.0, 0.0)

    # the open bay: an office arrangement on each side of the start's take-off column
    for x0, x1 in ((t, W / 2 - 1.5), (W / 2 + 1.5, W - t)):
        if x1 - x0 >= 2.0:
            builder.furnish(_Rect(x0, t, x1, p.open_bay - 0.5), 0.0, [])

    structure = [
        ([0, 0, 0], [W, t, H]),
        ([0, D - t, 0], [W, D, H]),
        ([0, 0, 0], [t, D, H]),
        ([W - t, 0, 0], [W, D, H]),
    ]
    parts = list(builder.parts)
    v, tr = boxes_mesh([(np.array(a, float), np.array(b, float)) for a, b in structure])
    parts.append(MeshPart.uniform("wall", v, tr, 0, class_colour("wall")))
    for name, (z0, z1) in (("ground slab", (-p.slab, 0.0)), ("roof slab", (H, H + p.slab))):
        v, tr = boxes_mesh([(np.array([0.0, 0.0, z0]), np.array([W, D, z1]))])
        part = MeshPart.uniform(name, v, tr, 0, class_colour("floor"))
        part.albedo[_triangle_normals(v, tr)[:, 2] < -0.5] = class_colour("ceiling")  # bottom faces
        parts.append(part)

    return WorldSpec(
        name=p.name,
        parts=parts,
        objects=builder.objects,
        floor_heights=(0.0,),
        bounds_lo=np.array([0.0, 0.0, -p.slab]),
        bounds_hi=np.array([W, D, H]),
        start_xy=np.array([W / 2, t + 1.0]),
        start_floor_z=0.0,
        start_yaw=float(np.pi / 2),  # facing the racks
    )


__all__ = ["HallWorldParams", "generate_hall"]
