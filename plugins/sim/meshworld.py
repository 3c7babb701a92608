"""Mesh worlds: a building from a triangle-mesh file plus an objects file (see docs/worlds.md).

The mesh (PLY, OBJ, STL, GLB/glTF, OFF — whatever ``open3d.io.read_triangle_mesh`` reads) is the
whole world. The objects file (JSON) lists the object instances::

    [{"name": "ChairA_01_001", "class": "ChairA", "mesh": "objects/ChairA_01_001.ply",
      "bounds": [[x0, y0, z0], [x1, y1, z1]]}, ...]

(or ``{"objects": [...]}``). An object's own mesh, already placed in world coordinates, labels the
world triangles it coincides with (matched by triangle centroid); an object whose mesh is not
part of the world mesh is added to the world. An object given by ``bounds`` only labels the
still unlabelled world triangles lying inside its box. Unlabelled triangles are structure, as
are objects whose class is listed in ``structure_classes`` (walls, floors, ceilings, ...).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import sys
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, ValidationInfo, model_validator

from amslam.errors import PlatformError
from amslam.interfaces import BackendParams, Coordinate, FieldError, mission_file_path
from amslam.lib.class_colours import class_colour
from amslam.plugins.sim.world import MeshPart, World, WorldObject, WorldSpec, survey_floors
from amslam.plugins.sim.worldpath import WorldFile, find_world_file

#: classes treated as building structure (instance 0) unless the mission says otherwise
DEFAULT_STRUCTURE = (
    "wall", "house_wall", "room_wall", "floor", "ceiling", "room_ceiling", "added", "carpet", "stairs",
)  # fmt: skip


class MeshWorldParams(BackendParams):
    """A world loaded from a mesh file and an objects file."""

    kind: Literal["mesh"] = "mesh"
    mesh: WorldFile = Field(
        description="world mesh (PLY/OBJ/STL/GLB): relative to the mission file, else found in the "
        "folders of AMSLAM_WORLDS, else a shipped world (small_house/world.ply); see docs/missions.md"
    )
    objects: WorldFile | None = Field(None, description="objects JSON, found like the mesh")
    name: str | None = Field(None, description="name in reports (default: the mesh's folder name)")
    up_axis: Literal["z", "y"] = Field("z", description="'y' for y-up files such as glTF/GLB exports")
    scale: float = Field(
        1.0, gt=0.0, le=1000.0, description="multiplies coordinates (e.g. 0.01 for centimetres)"
    )
    floor_heights: tuple[Coordinate, ...] | None = Field(
        None,
        description="z of each floor (ascending); default: found in the mesh (the lowest large walkable"
        " surface inside walls, and the storeys above it; see docs/worlds.md)",
    )
    normalize_classes: bool = Field(
        True, description="'ChairA' → 'chair', 'KitchenTable' → 'kitchen_table' (variant letter dropped)"
    )
    class_map: dict[str, str] = Field(
        default_factory=dict, description="class renames applied after normalisation, e.g. {armchair: chair}"
    )
    structure_classes: list[str] = Field(
        default_factory=lambda: list(DEFAULT_STRUCTURE),
        description="classes (after renaming) that are building structure, not objects",
    )
    match_tolerance: float = Field(
        1e-3, gt=0.0, le=10.0, description="centroid distance (m) that matches triangles"
    )

    @model_validator(mode="after")
    def _files_readable(self, info: ValidationInfo) -> MeshWorldParams:
        # the world is built when the run starts: a mesh file without triangles, or a mesh the
        # objects file lists that is not there, is named now with its field rather than ending the run
        if "mission_dir" not in (info.context or {}):
            return self
        mesh = mission_file_path(self.mesh, info)
        try:
            mesh_xy_extent(mesh, self)  # cached: the start check and the run read it once more at most
        except PlatformError:
            raise FieldError("mesh", f"no triangles in {mesh}: not a mesh file") from None
        if self.objects is None:
            return self
        path = mission_file_path(self.objects, info)
        try:
            entries = object_entries(path)
        except PlatformError as exc:
            raise FieldError("objects", str(exc)) from None
        missing = [
            (k, e.get("name"), path.parent / e["mesh"])
            for k, e in enumerate(entries)
            if isinstance(e.get("mesh"), str) and not (path.parent / e["mesh"]).is_file()
        ]
        if missing:
            k, name, mesh = missing[0]
            more = f" ({len(missing)} object meshes missing)" if len(missing) > 1 else ""
            raise FieldError("objects", f"object #{k} {name!r}: no such mesh file: {mesh}{more}")
        return self


def object_entries(path: Path) -> list[dict]:
    """The object entries of an objects file (a list, or ``{"objects": [...]}``); PlatformError
    naming the file when it is not one."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise PlatformError(f"not a JSON objects file ({type(exc).__name__}: {exc}): {path}") from None
    entries = data.get("objects") if isinstance(data, dict) else data
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise PlatformError(f"not an objects file (a list of objects, or {{objects: [...]}}): {path}")
    return entries


_SNAKE = re.compile(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])")


def normalize_class(name: str) -> str:
    """``'ChairA'`` → ``'chair'``, ``'TVCabinet'`` → ``'tv_cabinet'``, ``'HouseWallB'`` → ``'house_wall'``."""
    base = re.sub(r"(?<=[a-z])[A-Z]$", "", name.strip())  # trailing model-variant letter
    base = re.sub(r"[_\s-]*\d+$", "", base)  # trailing numbers
    return _SNAKE.sub("_", base).replace("-", "_").replace(" ", "_").lower()


def _read_mesh(path: Path, p: MeshWorldParams) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    import open3d as o3d

    if not path.is_file():
        raise PlatformError(f"mesh world: file not found: {path}")
    mesh = o3d.io.read_triangle_mesh(str(path))
    v = np.asarray(mesh.vertices, dtype=np.float64)
    t = np.asarray(mesh.triangles, dtype=np.int64)
    if len(t) == 0:
        raise PlatformError(f"mesh world: no triangles in {path}")
    v = v * p.scale
    if p.up_axis == "y":  # (x, y, z) y-up → (x, -z, y) z-up
        v = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)
    colours = np.asarray(mesh.vertex_colors, dtype=np.float64) if mesh.has_vertex_colors() else None
    return v, t, colours


@contextlib.contextmanager
def _c_stderr_silenced():
    """File descriptor 2 pointed at /dev/null meanwhile (what C libraries print there is dropped)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def mesh_xy_extent(path: Path, p: MeshWorldParams) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) of the world mesh at ``path`` as the world will place it (scale, up axis),
    for validating a start before the run; PlatformError if the file holds no triangles. Cached
    per file version, so validating and then running a mission reads the mesh once for this."""
    stat = path.stat()
    return _mesh_xy_extent(str(path), stat.st_mtime_ns, stat.st_size, p.scale, p.up_axis)


@functools.lru_cache(maxsize=4)
def _mesh_xy_extent(
    path: str, mtime_ns: int, size: int, scale: float, up_axis: str
) -> tuple[float, float, float, float]:
    import open3d as o3d

    # a file that is no mesh is the caller's error line, not also open3d's warning on stdout, nor
    # its PLY reader's (RPly: "Unable to read magic number"), printed on the C stderr directly
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error), _c_stderr_silenced():
        v, _, _ = _read_mesh(Path(path), MeshWorldParams.model_construct(scale=scale, up_axis=up_axis))
    lo, hi = v.min(axis=0), v.max(axis=0)
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def load_mesh_world(p: MeshWorldParams, base_dir: Path) -> WorldSpec:
    """Load a mesh world; relative paths are resolved against ``base_dir`` (the mission folder)."""
    mesh_path = (find_world_file(p.mesh, base_dir) or base_dir / p.mesh).resolve()
    V, T, C = _read_mesh(mesh_path, p)
    entries: list[dict] = []
    obj_dir = base_dir
    if p.objects is not None:
        obj_path = (find_world_file(p.objects, base_dir) or base_dir / p.objects).resolve()
        if not obj_path.is_file():
            raise PlatformError(f"mesh world: objects file not found: {obj_path}")
        entries = object_entries(obj_path)
        obj_dir = obj_path.parent
    labelled = _classified_entries(entries, p)
    instances = _instance_ids(labelled, set(p.structure_classes))
    tri_inst, extra_parts = _label_triangles(V, T, labelled, instances, obj_dir, p)
    objects = _objects_of(V, T, tri_inst, labelled, instances, extra_parts, p.scale)
    owner_class = {instances[e["name"]]: cls for e, cls in labelled}
    world_part = MeshPart(
        mesh_path.parent.name if mesh_path.name.startswith("world") else mesh_path.stem,
        V,
        T,
        tri_inst,
        _albedo(V, T, C, tri_inst, owner_class).astype(np.float32),
    )
    all_v = np.concatenate([V] + [q.vertices for q in extra_parts])
    lo, hi = all_v.min(axis=0), all_v.max(axis=0)
    name = p.name or (mesh_path.parent.name if mesh_path.stem == "world" else mesh_path.stem)
    spec = WorldSpec(
        name=name,
        parts=[world_part, *extra_parts],
        objects=objects,
        floor_heights=tuple(p.floor_heights) if p.floor_heights else (float(lo[2]),),
        bounds_lo=lo,
        bounds_hi=hi,
        start_xy=np.array([np.nan, np.nan]),  # chosen by the platform (a clear, open spot) unless given
        start_floor_z=0.0,
        start_yaw=0.0,
    )
    if not p.floor_heights:
        # The floors are found in the scene the platform will fly: the lowest geometry of an
        # imported mesh is often not the ground floor (a ground plane under the slab, stairs
        # down, a basement), see survey_floors.
        spec.floor_heights = survey_floors(World(spec)).floors
    spec.start_floor_z = spec.floor_heights[0]
    return spec


def _classified_entries(entries: list[dict], p: MeshWorldParams) -> list[tuple[dict, str]]:
    """Each object entry with its class as the world names it (normalised, then ``class_map``)."""
    labelled = []
    for k, e in enumerate(entries):
        if "name" not in e or "class" not in e:
            raise PlatformError(f"mesh world: object #{k} of {p.objects} needs 'name' and 'class'")
        cls = normalize_class(e["class"]) if p.normalize_classes else e["class"]
        cls = p.class_map.get(cls, p.class_map.get(e["class"], cls))
        labelled.append((e, cls))
    return labelled


def _instance_ids(labelled: list[tuple[dict, str]], structure: set[str]) -> dict[str, int]:
    """Instance id per object name, 1, 2, … in file order; 0 for the structure classes (walls)."""
    ids: dict[str, int] = {}
    next_id = 1
    for e, cls in labelled:
        if cls in structure:
            ids[e["name"]] = 0
        else:
            ids[e["name"]] = next_id
            next_id += 1
    return ids


def _label_triangles(
    V: np.ndarray,
    T: np.ndarray,
    labelled: list[tuple[dict, str]],
    instances: dict[str, int],
    obj_dir: Path,
    p: MeshWorldParams,
) -> tuple[np.ndarray, list[MeshPart]]:
    """The instance id of each world triangle, and the object meshes the world mesh lacks.

    First the objects with meshes: every world triangle within ``match_tolerance`` of one of an
    object mesh's triangle centroids is the object's (a structure object's triangles are marked
    and kept from the next step); an object mesh of which fewer than half the triangles match is
    not in the world mesh and is added as a part of its own. Then the objects given by bounds:
    the unlabelled triangles inside their box."""
    from scipy.spatial import cKDTree

    tri_inst = np.zeros(len(T), dtype=np.int32)
    struct_mask = np.zeros(len(T), dtype=bool)
    extra_parts: list[MeshPart] = []
    tree = cKDTree(V[T].mean(axis=1))
    for e, cls in labelled:
        if "mesh" not in e:
            continue
        ov, ot, _ = _read_mesh((obj_dir / e["mesh"]).resolve(), p)
        hits = tree.query_ball_point(ov[ot].mean(axis=1), r=p.match_tolerance)
        idx = np.unique(np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])) if len(hits) else []
        iid = instances[e["name"]]
        if len(idx) >= 0.5 * len(ot):
            if iid:
                tri_inst[idx] = iid
            else:
                struct_mask[idx] = True
        else:  # not part of the world mesh: add it
            albedo = class_colour("wall" if iid == 0 else cls)
            extra_parts.append(MeshPart.uniform(e["name"], ov, ot, iid, albedo))
    for e, _cls in labelled:
        if "mesh" in e or "bounds" not in e:
            continue
        lo, hi = (np.asarray(b, dtype=np.float64) * p.scale for b in e["bounds"])
        inside = np.all((V[T] >= lo - 0.01) & (V[T] <= hi + 0.01), axis=(1, 2))
        tri_inst[inside & (tri_inst == 0) & ~struct_mask] = instances[e["name"]]
    return tri_inst, extra_parts


def _objects_of(
    V: np.ndarray,
    T: np.ndarray,
    tri_inst: np.ndarray,
    labelled: list[tuple[dict, str]],
    instances: dict[str, int],
    extra_parts: list[MeshPart],
    scale: float,
) -> list[WorldObject]:
    """The ground truth per object: the bounds of its labelled triangles, else of its own mesh,
    else of its entry's ``bounds``; an object with none of them is left out."""
    objects = []
    for e, cls in labelled:
        iid = instances[e["name"]]
        if iid == 0:
            continue
        sel = tri_inst == iid
        if sel.any():
            pts = V[T[sel]].reshape(-1, 3)
        else:
            part = next((q for q in extra_parts if q.name == e["name"]), None)
            if part is not None:
                pts = part.vertices
            elif "bounds" in e:
                pts = np.asarray(e["bounds"], dtype=np.float64) * scale
            else:
                continue
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        objects.append(WorldObject(e["name"], cls, iid, (lo + hi) / 2, lo, hi))
    return objects


def _albedo(
    V: np.ndarray, T: np.ndarray, C: np.ndarray | None, tri_inst: np.ndarray, owner_class: dict[int, str]
) -> np.ndarray:
    """Per triangle: the file's vertex colours when it has them, else the class colours (walls,
    floors facing up, ceilings facing down, objects by their class)."""
    if C is not None and len(C) == len(V):
        return C[T].mean(axis=1)
    normals = np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    albedo = np.tile(class_colour("wall"), (len(T), 1))
    albedo[(tri_inst == 0) & (normals[:, 2] > 0.9)] = class_colour("floor")
    albedo[(tri_inst == 0) & (normals[:, 2] < -0.9)] = class_colour("ceiling")
    for iid in np.unique(tri_inst[tri_inst > 0]):
        albedo[tri_inst == iid] = class_colour(owner_class[int(iid)])
    return albedo
