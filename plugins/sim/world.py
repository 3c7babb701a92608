"""A simulated world: labelled triangle meshes in one Open3D ``RaycastingScene``.

Every triangle carries an instance id (0 = building structure) and an albedo colour. Object
instances (chairs, tables, ...) have their own geometry in the scene; mesh worlds may label the
triangles of one big mesh per triangle. Both cases go through the same lookup: the scene reports
``(geometry_id, primitive_id)`` for a hit, ``offsets[geometry_id] + primitive_id`` indexes the
concatenated per-triangle arrays.

Open3D is imported lazily so that loading the plugin (``amslam plugins``) stays fast.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amslam.lib.class_colours import class_colour
from amslam.types import BoundingBox, WorldSummary

#: Open3D's ``RaycastingScene.INVALID_ID`` (uint32 max): no geometry was hit.
INVALID_ID = np.uint32(0xFFFFFFFF)

#: Classes with fixed ids, so the same class has the same id in every procedural world.
BASE_CLASSES: tuple[str, ...] = ("background", "chair", "table", "shelf", "sofa")


@dataclass
class MeshPart:
    """One geometry of the scene.

    Attributes:
        name: what a collision report calls it, e.g. ``"walls (floor 0)"`` or ``"chair_3"``.
        vertices: N×3 vertex positions (world frame, metres).
        triangles: M×3 vertex indices.
        instance: per-triangle instance ids (M,), 0 = structure.
        albedo: per-triangle RGB albedo (M×3) in [0, 1].
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    instance: np.ndarray
    albedo: np.ndarray

    @staticmethod
    def uniform(
        name: str, vertices: np.ndarray, triangles: np.ndarray, instance: int, albedo: np.ndarray
    ) -> MeshPart:
        """A part whose triangles share one instance id and one colour."""
        m = len(triangles)
        return MeshPart(
            name,
            np.asarray(vertices, dtype=np.float64),
            np.asarray(triangles, dtype=np.int64),
            np.full(m, instance, dtype=np.int32),
            np.tile(np.asarray(albedo, dtype=np.float32), (m, 1)),
        )


@dataclass(frozen=True)
class WorldObject:
    """Ground truth of one object instance."""

    name: str
    class_name: str
    instance_id: int
    centroid: np.ndarray  # centre of the axis-aligned bounds
    lo: np.ndarray
    hi: np.ndarray
    #: true shape model (paper 2): a cuboid or cylinder dict, see amslam.lib.shapes
    shape: dict | None = None


@dataclass
class WorldSpec:
    """Everything a world generator or loader produces, before the scene is built."""

    name: str
    parts: list[MeshPart]
    objects: list[WorldObject]
    floor_heights: tuple[float, ...]
    bounds_lo: np.ndarray
    bounds_hi: np.ndarray
    start_xy: np.ndarray  # start position on the ground (x, y)
    start_floor_z: float  # z of the ground under the start
    start_yaw: float = 0.0
    extra_classes: tuple[str, ...] = field(default_factory=tuple)
    #: named places of the layout, e.g. ``"shaft"`` (centre of the open shaft on the ground floor)
    places: dict[str, np.ndarray] = field(default_factory=dict)


class World:
    """The ray-castable world built from a :class:`WorldSpec`."""

    def __init__(self, spec: WorldSpec):
        import open3d as o3d

        self.spec = spec
        self.name = spec.name
        self.objects = list(spec.objects)
        classes = list(BASE_CLASSES)
        for c in sorted({o.class_name for o in self.objects} | set(spec.extra_classes)):
            if c not in classes:
                classes.append(c)
        self.class_names: tuple[str, ...] = tuple(classes)
        class_index = {c: i for i, c in enumerate(self.class_names)}
        n_inst = 1 + max((o.instance_id for o in self.objects), default=0)
        #: instance id → class id (0 for structure)
        self.instance_class = np.zeros(n_inst, dtype=np.int32)
        self.instance_names = ["structure"] * n_inst
        for o in self.objects:
            self.instance_class[o.instance_id] = class_index[o.class_name]
            self.instance_names[o.instance_id] = o.name

        self.scene = o3d.t.geometry.RaycastingScene()
        offsets, inst, albedo, names = [], [], [], []
        total = 0
        for part in spec.parts:
            if len(part.triangles) == 0:
                continue
            # Open3D wants float32 vertices and uint32 triangle indices.
            gid = self.scene.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(part.vertices, dtype=np.float32)),
                o3d.core.Tensor(np.ascontiguousarray(part.triangles, dtype=np.uint32)),
            )
            assert gid == len(offsets), "RaycastingScene geometry ids are expected to be sequential"
            offsets.append(total)
            total += len(part.triangles)
            inst.append(part.instance)
            albedo.append(part.albedo)
            names.append(part.name)
        self._offsets = np.array(offsets + [total], dtype=np.int64)
        self.tri_instance = np.concatenate(inst).astype(np.int32)
        self.tri_albedo = np.concatenate(albedo).astype(np.float32)
        # |z| of each triangle's unit normal: horizontal surfaces (floors, table tops) are found by
        # it whatever the winding of an imported mesh (its normals may point up or down).
        nz = []
        for part in spec.parts:
            if len(part.triangles) == 0:
                continue
            v = np.asarray(part.vertices, dtype=np.float64)[np.asarray(part.triangles)]
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            nz.append(np.abs(n[:, 2]) / np.maximum(np.linalg.norm(n, axis=1), 1e-12))
        self.tri_abs_nz = np.concatenate(nz) if nz else np.zeros(0)
        self.part_names = names
        self.n_triangles = total
        self._summary: WorldSummary | None = None
        self._summary_key: tuple | None = None

    # ---------------------------------------------------------------------------------------
    # queries
    # ---------------------------------------------------------------------------------------
    def triangle_index(self, geometry_ids: np.ndarray, primitive_ids: np.ndarray) -> np.ndarray:
        """Global triangle index of hits; -1 where nothing was hit (INVALID_ID)."""
        gid = np.asarray(geometry_ids, dtype=np.uint32)
        hit = gid != INVALID_ID
        out = np.full(gid.shape, -1, dtype=np.int64)
        out[hit] = self._offsets[gid[hit].astype(np.int64)] + np.asarray(primitive_ids)[hit].astype(np.int64)
        return out

    def cast_rays(self, rays: np.ndarray) -> dict[str, np.ndarray]:
        """Cast ``(..., 6)`` rays (origin, direction); returns numpy arrays of Open3D's answer."""
        import open3d as o3d

        ans = self.scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32)), nthreads=0)
        return {k: v.numpy() for k, v in ans.items()}

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (m) from each point (N×3) to the nearest surface."""
        import open3d as o3d

        pts = np.ascontiguousarray(np.atleast_2d(points), dtype=np.float32)
        return self.scene.compute_distance(o3d.core.Tensor(pts), nthreads=0).numpy().astype(np.float64)

    def closest(self, point: np.ndarray) -> tuple[float, np.ndarray, str]:
        """Distance, closest surface point and a description of what it belongs to."""
        import open3d as o3d

        p = np.ascontiguousarray(np.reshape(point, (1, 3)), dtype=np.float32)
        ans = self.scene.compute_closest_points(o3d.core.Tensor(p), nthreads=1)
        q = ans["points"].numpy()[0].astype(np.float64)
        tri = self.triangle_index(ans["geometry_ids"].numpy(), ans["primitive_ids"].numpy())[0]
        gid = int(ans["geometry_ids"].numpy()[0])
        inst = int(self.tri_instance[tri]) if tri >= 0 else 0
        if inst > 0:
            what = f"{self.instance_names[inst]} ({self.class_names[self.instance_class[inst]]})"
        else:
            what = self.part_names[gid] if 0 <= gid < len(self.part_names) else "structure"
        return float(np.linalg.norm(q - p[0])), q, what

    def ground_below(self, position: np.ndarray) -> float:
        """z of the first surface straight below ``position`` (−inf if none)."""
        ray = np.array([[*position, 0.0, 0.0, -1.0]])
        t = float(self.cast_rays(ray)["t_hit"][0])
        return float(position[2] - t) if np.isfinite(t) else -np.inf

    def enclosed_share(self, xy: np.ndarray, heights: np.ndarray, n_dirs: int = 16) -> np.ndarray:
        """Share of ``n_dirs`` horizontal directions in which geometry surrounds each (x, y).

        A direction counts as closed when a horizontal ray from the point at any of its
        ``heights`` (N×k absolute z, or k values for all points) hits something, however far:
        inside a building the walls close nearly every direction (a window or a door leaves
        one open at one height, rarely at all), outside it half of them at most.
        """
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        n = len(xy)
        h = np.asarray(heights, dtype=float)
        h = np.broadcast_to(h if h.ndim == 2 else h[None, :], (n, h.shape[-1]))
        if n == 0:
            return np.zeros(0)
        ang = np.arange(n_dirs) * (2 * np.pi / n_dirs)
        dirs = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n_dirs)])
        closed = np.zeros((n, n_dirs), dtype=bool)
        for k in range(h.shape[1]):
            origins = np.repeat(np.column_stack([xy, h[:, k]]), n_dirs, axis=0)
            rays = np.column_stack([origins, np.tile(dirs, (n, 1))])
            closed |= np.isfinite(self.cast_rays(rays)["t_hit"]).reshape(n, n_dirs)
        return closed.mean(axis=1)

    def horizontal_room(self, points: np.ndarray, n_dirs: int = 16) -> np.ndarray:
        """Distance to the nearest surface along ``n_dirs`` horizontal rays from each point (m).

        Unlike :meth:`distance` it does not see the floor under a point: it tells how open a
        spot is around it (inf where nothing is hit in any direction).
        """
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        if len(pts) == 0:
            return np.zeros(0)
        ang = np.arange(n_dirs) * (2 * np.pi / n_dirs)
        dirs = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n_dirs)])
        rays = np.column_stack([np.repeat(pts, n_dirs, axis=0), np.tile(dirs, (len(pts), 1))])
        return self.cast_rays(rays)["t_hit"].astype(float).reshape(len(pts), n_dirs).min(axis=1)

    def backface_share(self, points: np.ndarray, n_dirs: int = 16) -> np.ndarray:
        """Share of the surfaces seen from each point (horizontally, up and down) seen from behind.

        Inside a closed solid (a thick pillar, a cabinet modelled as a box) every ray leaves
        through the back of an outward-facing triangle, and the unsigned distance alone cannot
        tell such a point from free space. In a room nearly none is seen from behind.
        """
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        n = len(pts)
        if n == 0:
            return np.zeros(0)
        ang = np.arange(n_dirs) * (2 * np.pi / n_dirs)
        dirs = np.vstack(
            [np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n_dirs)]), [0, 0, 1], [0, 0, -1]]
        )
        k = len(dirs)
        rays = np.column_stack([np.repeat(pts, k, axis=0), np.tile(dirs, (n, 1))])
        ans = self.cast_rays(rays)
        hit = np.isfinite(ans["t_hit"]).reshape(n, k)
        back = (np.einsum("ij,ij->i", ans["primitive_normals"], rays[:, 3:]) > 0).reshape(n, k) & hit
        return back.sum(axis=1) / np.maximum(hit.sum(axis=1), 1)

    def floor_index(self, z: np.ndarray | float) -> np.ndarray:
        """Index of the floor holding height ``z`` (clipped to the valid range)."""
        fh = np.asarray(self.spec.floor_heights)
        return np.clip(np.searchsorted(fh, z, side="right") - 1, 0, len(fh) - 1)

    # ---------------------------------------------------------------------------------------
    # ground truth summary
    # ---------------------------------------------------------------------------------------
    def summary(
        self,
        start: np.ndarray,
        cell: float = 0.25,
        margin: float | None = None,
        robot_radius: float | None = None,
        bound: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> WorldSummary:
        """Ground truth for metrics, computed once and cached.

        Reachable free space: centres of grid cells (edge ``cell``) inside the building bounds
        that are farther than ``margin`` (default half a cell) from any geometry, 6-connected to
        the cell holding ``start``. ``scipy.ndimage.label`` does the flood fill.

        With ``robot_radius``, what the robot can reach: the flood fill runs over the cells where
        the robot's centre fits (farther than its radius from any geometry, its body inside
        ``bound`` on every face but the floor: the flight bound of the mapping backends, by
        default the building's box), and the reachable space is the free cells within a radius of
        them. Without it, air behind a gap narrower than the robot, or outside an open-topped
        building's walls (reached over them), counts as reachable though no flight may go there
        (an imported small house: 11 % of its "reachable" volume was a strip outside its walls).
        """
        from scipy import ndimage

        margin = cell / 2.0 if margin is None else margin
        bound_key = None if bound is None else tuple(np.round(np.concatenate(bound), 6))
        key = (tuple(np.round(start, 6)), cell, margin, robot_radius, bound_key)
        if self._summary is not None and self._summary_key == key:
            return self._summary
        lo, hi = self.spec.bounds_lo, self.spec.bounds_hi
        shape = np.maximum(np.floor((hi - lo) / cell).astype(int), 1)
        axes = [lo[i] + (np.arange(shape[i]) + 0.5) * cell for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        distance = self.distance(grid).reshape(shape)
        free = distance > margin
        idx = np.clip(np.floor((np.asarray(start) - lo) / cell).astype(int), 0, shape - 1)
        if robot_radius is None:
            reachable = _component(free, idx)
        else:
            fits = distance > robot_radius
            if bound is not None:
                fits &= BoundingBox(*bound).flyable(robot_radius).contains(grid).reshape(shape)
            flown = _component(fits, idx)
            # the free cells the robot's body sweeps: within its radius (plus half a cell, the
            # cell centres' spacing) of a cell its centre can reach
            near = ndimage.distance_transform_edt(~flown) * cell <= robot_radius + cell / 2
            reachable = free & near
        points = grid[reachable.reshape(-1)]
        vol = cell**3
        floors = self.floor_index(points[:, 2]) if len(points) else np.zeros(0, dtype=int)
        per_floor = tuple(
            float(np.count_nonzero(floors == i) * vol) for i in range(len(self.spec.floor_heights))
        )
        by_class: dict[str, int] = {}
        for o in self.objects:
            by_class[o.class_name] = by_class.get(o.class_name, 0) + 1
        self._summary = WorldSummary(
            name=self.name,
            bounds_lo=np.array(lo, dtype=float),
            bounds_hi=np.array(hi, dtype=float),
            reachable_free_volume=float(len(points) * vol),
            floor_heights=tuple(float(z) for z in self.spec.floor_heights),
            reachable_free_volume_per_floor=per_floor,
            objects_by_class=by_class,
            object_positions={o.name: o.centroid.copy() for o in self.objects},
            object_classes={o.name: o.class_name for o in self.objects},
            object_shapes={o.name: dict(o.shape) for o in self.objects if o.shape is not None},
            reachable_points=points,
            reachable_cell=cell,
        )
        self._summary_key = key
        return self._summary


# -------------------------------------------------------------------------------------------
# floors of a building
# -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Level:
    """Walkable surfaces of a world at one height (see :func:`survey_floors`).

    Attributes:
        z: height of the surfaces (m).
        area: walkable area (m²): horizontal structure with ``headroom`` of free space above.
        enclosed_area: the part of it with walls around (inside the building).
        open_sky_area: the part with nothing above, no walls around and no storey below: the
            ground around a building (a roof lies over a storey, a courtyard inside walls).
        over_storey_area: the part lying over a storey: over a walkable surface with ``storey``
            of headroom below it (a mezzanine or an upper floor, not a raised step or a table).
    """

    z: float
    area: float
    enclosed_area: float
    open_sky_area: float
    over_storey_area: float


@dataclass(frozen=True)
class FloorSurvey:
    """What :func:`survey_floors` found: every level, the ground floor and the floor heights."""

    levels: tuple[Level, ...]
    floors: tuple[float, ...]
    terrain: float | None  # z of the ground outside the building, if the mesh has some
    large: float  # smallest area (m²) of a level that counts as a floor

    def describe(self) -> str:
        rows = [
            f"z {lv.z:.2f} m: {lv.area:.1f} m² walkable, {lv.enclosed_area:.1f} m² inside walls"
            for lv in self.levels
            if lv.area >= self.large
        ]
        return "; ".join(rows) or "no walkable surface"


def survey_floors(
    world: World,
    *,
    cell: float = 0.25,
    headroom: float = 1.0,
    storey: float = 1.8,
    large: float = 4.0,
    share: float = 0.1,
    enclosed: float = 0.75,
    basement_tolerance: float = 0.5,
    max_columns: int = 40000,
) -> FloorSurvey:
    """Floor heights of a building mesh, found from vertical rays through the whole world.

    Every column of a ``cell`` grid is cut by one ray from above the world, listing every
    surface it crosses. A **walkable** surface is a horizontal piece of structure (not an object)
    with at least ``headroom`` of free space above it: a slab's underside, a floor under a
    table or a shelf's inner boards are not. Walkable surfaces are grouped by height into
    levels. A surface is **inside** the building where walls close at least ``enclosed`` of the
    horizontal directions around it (at 1.2 m and 1.8 m above it: over a parapet, under a
    ceiling). A level is **large** from ``large`` m² and ``share`` of the largest level inside
    walls on (of the ground floor, for the floors above it).

    * The ground outside (``terrain``) is the lowest large level open to the sky and outside
      walls (a ground plane or a terrain skirt around the building), if there is one.
    * The **ground floor** is the lowest large level inside walls (more of it inside than open
      ground) that is not more than ``basement_tolerance`` below the terrain: geometry under it
      (a basement, foundations, stairs down, the ground plane under the floor slab) does not count.
      Without terrain (a mesh of the building alone), the lowest large level inside walls.
    * An **upper floor** (a storey, a mezzanine) is a large level inside walls lying over at least
      ``large`` m² of a walkable surface with ``storey`` of headroom below it; a raised platform
      on solid ground beside a floor, a table or a rack top is not a floor of its own.
    """
    lo = np.asarray(world.spec.bounds_lo, float)
    hits = _vertical_hits(world, cell, max_columns)
    z, tri, first = hits.z, hits.triangle, hits.first
    # headroom: to the next surface above in the same column (none above: open sky)
    above = np.where(first, np.inf, np.r_[np.inf, z[:-1]])
    room = above - z
    # the same surface twice (both faces of a plane, coincident meshes): keep the upper copy
    dup = ~first & (room < 0.01)
    horizontal = world.tri_abs_nz[tri] > 0.9
    structure = world.tri_instance[tri] == 0
    walk = horizontal & structure & (room >= headroom) & ~dup
    # storey below a walkable surface: a walkable surface lower in the same column with `storey`
    # of headroom (under this one's slab)
    tall = (walk & (room >= storey)).astype(np.int64)
    last = np.searchsorted(hits.ray, hits.ray, side="right") - 1  # last (lowest) hit of each hit's column
    cs = np.cumsum(tall)
    storey_below = (cs[last] - cs) > 0

    wz, wxy = z[walk], hits.xy[hits.ray[walk]]
    if len(wz) == 0:
        return FloorSurvey((), (float(lo[2]),), None, large)
    inside = world.enclosed_share(wxy, np.column_stack([wz + 1.2, wz + 1.8])) >= enclosed
    levels = _levels(wz, hits.cell * hits.cell, inside, first[walk], storey_below[walk])
    # a floor (and the ground around) is a large share of the building, not a patch of ground in
    # a corner of its walls, nor the eaves of a roof
    big = max(large, share * max((lv.enclosed_area for lv in levels), default=0.0))
    terrain = next((lv.z for lv in levels if lv.open_sky_area >= big), None)
    floors = _floors_of(levels, terrain, big, float(lo[2]), large, share, storey, basement_tolerance)
    return FloorSurvey(tuple(levels), tuple(floors), terrain, large)


@dataclass(frozen=True)
class _VerticalHits:
    """Every surface a vertical ray down each column of a grid crosses, column by column from the
    top: the hit's column (``ray``, an index into ``xy``), height, triangle, and whether it is
    its column's first."""

    xy: np.ndarray
    cell: float
    ray: np.ndarray
    z: np.ndarray
    triangle: np.ndarray
    first: np.ndarray


def _vertical_hits(world: World, cell: float, max_columns: int) -> _VerticalHits:
    """One ray down through the whole world per ``cell`` column (the cell grown to keep at most
    ``max_columns`` of them), every surface it crosses listed."""
    import open3d as o3d

    lo, hi = np.asarray(world.spec.bounds_lo, float), np.asarray(world.spec.bounds_hi, float)
    span = np.maximum(hi[:2] - lo[:2], cell)
    cell = max(cell, float(np.sqrt(span[0] * span[1] / max_columns)))
    xs = np.arange(lo[0] + cell / 2, hi[0], cell)
    ys = np.arange(lo[1] + cell / 2, hi[1], cell)
    xy = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    top = hi[2] + 1.0
    rays = np.column_stack([xy, np.full(len(xy), top), np.tile([0.0, 0.0, -1.0], (len(xy), 1))])
    ans = world.scene.list_intersections(o3d.core.Tensor(rays.astype(np.float32)), nthreads=0)
    ray = ans["ray_ids"].numpy().astype(np.int64)
    t = ans["t_hit"].numpy().astype(np.float64)
    tri = world.triangle_index(ans["geometry_ids"].numpy(), ans["primitive_ids"].numpy())
    order = np.lexsort((t, ray))
    ray, t, tri = ray[order], t[order], tri[order]
    first = np.r_[True, ray[1:] != ray[:-1]]
    return _VerticalHits(xy, cell, ray, top - t, tri, first)


def _levels(
    wz: np.ndarray, cell_area: float, inside: np.ndarray, sky: np.ndarray, over: np.ndarray
) -> list[Level]:
    """The walkable surfaces (heights ``wz``, each a cell's area; inside walls, open to the sky,
    over a storey) grouped into levels, lowest first: the heights holding the most walkable area
    first, each claiming what lies within 6 cm."""
    bins = np.round(wz / 0.02).astype(np.int64)
    ub, inv = np.unique(bins, return_inverse=True)
    weight = np.bincount(inv, minlength=len(ub)).astype(float)
    claimed = np.zeros(len(wz), dtype=bool)
    levels: list[Level] = []
    for b in ub[np.argsort(-weight, kind="stable")]:
        sel = ~claimed & (np.abs(wz - b * 0.02) <= 0.06)
        if not sel.any():
            continue
        claimed |= sel
        levels.append(
            Level(
                z=float(np.median(wz[sel])),
                area=float(sel.sum() * cell_area),
                enclosed_area=float((sel & inside).sum() * cell_area),
                open_sky_area=float((sel & sky & ~inside & ~over).sum() * cell_area),
                over_storey_area=float((sel & inside & over).sum() * cell_area),
            )
        )
    levels.sort(key=lambda lv: lv.z)
    return levels


def _floors_of(
    levels: list[Level],
    terrain: float | None,
    big: float,
    bottom: float,
    large: float,
    share: float,
    storey: float,
    basement_tolerance: float,
) -> list[float]:
    """The floor heights among the levels (the rules of :func:`survey_floors`): ``big`` the area
    of a large level, ``bottom`` the mesh's lowest point (the floor when no level is large)."""
    grounds = [lv for lv in levels if lv.enclosed_area >= big and lv.enclosed_area >= lv.open_sky_area]
    at_ground = [lv for lv in grounds if terrain is None or lv.z >= terrain - basement_tolerance]
    if not grounds:  # nothing inside walls: the lowest large walkable level, else the bottom of the mesh
        wide = [lv for lv in levels if lv.area >= large]
        return [wide[0].z if wide else bottom]
    ground = (at_ground or grounds)[0]
    floors = [ground.z]
    big = max(large, share * ground.enclosed_area)
    for lv in levels:
        if lv.z - floors[-1] >= storey and lv.enclosed_area >= big and lv.over_storey_area >= big:
            floors.append(lv.z)
    return floors


# -------------------------------------------------------------------------------------------
# mesh helpers
# -------------------------------------------------------------------------------------------
_BOX_TRIANGLES = np.array(
    [
        [0, 2, 1], [0, 3, 2],  # bottom (z = lo)
        [4, 5, 6], [4, 6, 7],  # top
        [0, 1, 5], [0, 5, 4],  # y = lo
        [2, 3, 7], [2, 7, 6],  # y = hi
        [1, 2, 6], [1, 6, 5],  # x = hi
        [3, 0, 4], [3, 4, 7],  # x = lo
    ],
    dtype=np.int64,
)  # fmt: skip


def prism_mesh(radius: float, z0: float, z1: float, sides: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward triangles of a closed regular prism around the z axis from ``z0`` to
    ``z1`` (vertices at ``radius``): a cylinder, coarsely (poles, trunks, bins, lamps)."""
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    v = np.vstack([np.column_stack([ring, np.full(sides, z0)]), np.column_stack([ring, np.full(sides, z1)])])
    v = np.vstack([v, [[0, 0, z0], [0, 0, z1]]])
    tris = []
    for i in range(sides):
        j = (i + 1) % sides
        tris += [[i, j, sides + j], [i, sides + j, sides + i]]
        tris += [[2 * sides, j, i], [2 * sides + 1, sides + i, sides + j]]
    return v, np.array(tris, dtype=np.int64)


def box_mesh(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward-facing triangles of an axis-aligned box."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array(
        [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
         [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]],
        dtype=np.float64,
    )  # fmt: skip
    return v, _BOX_TRIANGLES.copy()


def merge_meshes(meshes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (vertices, triangles) pairs into one mesh."""
    verts, tris, n = [], [], 0
    for v, t in meshes:
        verts.append(v)
        tris.append(t + n)
        n += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(tris)


def boxes_mesh(boxes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """One mesh made of several axis-aligned boxes ``(lo, hi)``."""
    return merge_meshes([box_mesh(np.asarray(lo, float), np.asarray(hi, float)) for lo, hi in boxes])


def room_shell(size: tuple[float, float, float], wall: float = 0.2) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (lo, hi) boxes of the floor, ceiling and four walls of a room ``[0, sx] × [0, sy] ×
    [0, sz]``, each ``wall`` thick outside it."""
    sx, sy, sz = size
    w = wall
    return [
        (np.array([-w, -w, -w]), np.array([sx + w, sy + w, 0.0])),  # floor
        (np.array([-w, -w, sz]), np.array([sx + w, sy + w, sz + w])),  # ceiling
        (np.array([-w, -w, 0.0]), np.array([0.0, sy + w, sz])),
        (np.array([sx, -w, 0.0]), np.array([sx + w, sy + w, sz])),
        (np.array([-w, -w, 0.0]), np.array([sx + w, 0.0, sz])),
        (np.array([-w, sy, 0.0]), np.array([sx + w, sy + w, sz])),
    ]


def box_room(
    size: tuple[float, float, float],
    objects: list[tuple[str, str, np.ndarray, np.ndarray]] = (),
    *,
    wall: float = 0.2,
    start_xy: tuple[float, float] | None = None,
    start_yaw: float = 0.0,
) -> WorldSpec:
    """A closed box room ``[0, sx] × [0, sy] × [0, sz]`` (walls outside it) with box objects.

    ``objects`` lists ``(name, class, lo, hi)``. Handy for tests and as a minimal world.
    """
    sx, sy, sz = size
    w = wall
    shell = boxes_mesh(room_shell(size, wall))
    parts = [MeshPart.uniform("walls", *shell, 0, class_colour("wall"))]
    objs = []
    for i, (name, cls, lo, hi) in enumerate(objects, start=1):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        parts.append(MeshPart.uniform(name, *box_mesh(lo, hi), i, class_colour(cls)))
        objs.append(WorldObject(name, cls, i, (lo + hi) / 2, lo, hi))
    return WorldSpec(
        name="box_room",
        parts=parts,
        objects=objs,
        floor_heights=(0.0,),
        bounds_lo=np.array([-w, -w, -w]),
        bounds_hi=np.array([sx + w, sy + w, sz + w]),
        start_xy=np.array(start_xy if start_xy is not None else (sx / 2, sy / 2)),
        start_floor_z=0.0,
        start_yaw=start_yaw,
    )


def _component(cells: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The 6-connected component of ``cells`` holding index ``idx`` (or the nearest cell's)."""
    from scipy import ndimage

    labels, _ = ndimage.label(cells)  # default structure = 6-connectivity
    start_label = labels[tuple(idx)]
    if start_label == 0:  # the start cell is not one of them: take the nearest that is
        free_idx = np.argwhere(cells)
        if len(free_idx):
            nearest = free_idx[np.argmin(np.linalg.norm(free_idx - idx, axis=1))]
            start_label = labels[tuple(nearest)]
    return (labels == start_label) if start_label > 0 else np.zeros(cells.shape, dtype=bool)
