"""Triangles from mesh files (through trimesh) and from SDF primitives."""

from __future__ import annotations

import io
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from amslam.apps.worlds.sdf import Geometry, WorldImportError

#: file suffix → trimesh file type, for the formats a world or a plain-mesh import reads
MESH_TYPES = {
    ".dae": "dae",
    ".obj": "obj",
    ".stl": "stl",
    ".ply": "ply",
    ".glb": "glb",
    ".gltf": "gltf",
    ".off": "off",
}

#: thickness of the slab an SDF <plane> becomes (its top face is the plane), m
PLANE_THICKNESS = 0.05


@dataclass
class Part:
    """Triangles of one named node of a mesh file, in metres."""

    name: str
    geometry_name: str
    vertices: np.ndarray  # N×3 float64
    faces: np.ndarray  # M×3 int64


def collada_asset(path: Path) -> tuple[float, str]:
    """``(metres per unit, up axis)`` of a COLLADA file, from its ``<asset>``.

    Read here because trimesh keeps the unit only as metadata and ignores the up axis. The asset
    block opens the file, so the first 64 kB are enough.
    """
    with path.open("rb") as f:
        head = f.read(65536).decode("utf-8", errors="replace")
    asset = head.split("</asset>")[0]
    unit = re.search(r"<unit\b[^>]*\bmeter\s*=\s*[\"']([^\"']+)[\"']", asset)
    up = re.search(r"<up_axis>\s*([XYZ])_UP\s*</up_axis>", asset)
    try:
        metres = float(unit.group(1)) if unit else 1.0
    except ValueError:
        raise WorldImportError(f"{path}: COLLADA <unit meter={unit.group(1)!r}> is not a number") from None
    if metres <= 0:
        raise WorldImportError(f"{path}: COLLADA <unit meter={metres}> must be positive")
    return metres, (up.group(1).lower() if up else "z")


def to_z_up(vertices: np.ndarray, up_axis: str) -> np.ndarray:
    """Vertices of a ``up_axis``-up file in amslam's z-up frame (COLLADA's axis conventions)."""
    if up_axis == "y":  # right +x, up +y → (x, -z, y)
        return np.stack([vertices[:, 0], -vertices[:, 2], vertices[:, 1]], axis=1)
    if up_axis == "x":  # right -y, up +x → (-y, -z, x)
        return np.stack([-vertices[:, 1], -vertices[:, 2], vertices[:, 0]], axis=1)
    return vertices


def _collada_node_names(path: Path) -> dict[str, str]:
    """Geometry id → name of the first COLLADA node instancing it.

    trimesh names a COLLADA scene's nodes after their geometry ids and drops the node names,
    which are what modelling tools show (and what a class map should see).
    """
    from xml.etree import ElementTree as ET

    names: dict[str, str] = {}
    stack: list[str] = []
    try:
        for event, element in ET.iterparse(path, events=("start", "end")):
            tag = element.tag.rsplit("}", 1)[-1]
            if tag == "node":
                if event == "start":
                    stack.append(element.get("name") or element.get("id") or "")
                else:
                    stack.pop()
            elif tag == "instance_geometry" and event == "start" and stack:
                names.setdefault(element.get("url", "").lstrip("#"), stack[-1])
    except ET.ParseError:
        return {}  # trimesh has read it; names are a nicety
    return names


def load_mesh_file(path: Path, up_axis: str | None = None, where: str | None = None) -> list[Part]:
    """Every triangle mesh node of a file, placed by the file's scene graph, in metres.

    COLLADA units are applied. ``up_axis`` (``x``, ``y``, ``z``) rotates the result into z-up;
    None leaves the file's coordinates as they are — what Gazebo does with meshes an SDF names.
    """
    import trimesh

    at = where or str(path)
    file_type = MESH_TYPES.get(path.suffix.lower())
    if file_type is None:
        raise WorldImportError(
            f"{at}: {path.name}: unknown mesh format (known: {', '.join(sorted(MESH_TYPES))})"
        )
    quiet = logging.getLogger("trimesh")
    level = quiet.level
    # trimesh logs texture and material troubles with tracebacks (textures are not read here)
    quiet.setLevel(logging.CRITICAL)
    try:
        # OBJ: one mesh per `o` object, so named objects can be classified (trimesh merges them by default)
        extra = {"split_objects": True, "group_material": False} if file_type == "obj" else {}
        if file_type == "dae":
            # pycollada rejects comments inside <geometry> (FBX exporters write them) and trimesh
            # then silently returns nothing: drop comments first. Reading from memory also skips
            # loading texture images, which the simulator does not use.
            text = re.sub(rb"<!--.*?-->", b"", path.read_bytes(), flags=re.S)
            scene = trimesh.load_scene(io.BytesIO(text), file_type=file_type, process=False)
        else:
            scene = trimesh.load_scene(str(path), file_type=file_type, process=False, **extra)
    except Exception as exc:  # trimesh and its loaders raise anything from ValueError to KeyError
        raise WorldImportError(f"{at}: cannot read mesh {path}: {type(exc).__name__}: {exc}") from None
    finally:
        quiet.setLevel(level)
    metres = collada_asset(path)[0] if file_type == "dae" else 1.0
    node_names = _collada_node_names(path) if file_type == "dae" else {}
    parts: list[Part] = []
    for node in scene.graph.nodes_geometry:
        node_T_mesh, geometry_name = scene.graph[node]
        mesh = scene.geometry.get(geometry_name)
        faces = getattr(mesh, "faces", None)
        if faces is None or len(faces) == 0:
            continue  # lines, points
        vertices = np.asarray(mesh.vertices, dtype=np.float64) @ node_T_mesh[:3, :3].T + node_T_mesh[:3, 3]
        faces = np.asarray(faces, dtype=np.int64)
        if np.linalg.det(node_T_mesh[:3, :3]) < 0:
            faces = faces[:, ::-1]
        vertices = vertices * metres
        if up_axis is not None:
            vertices = to_z_up(vertices, up_axis)
        name = node_names.get(str(geometry_name)) or node_names.get(re.sub(r"_\d+$", "", str(geometry_name)))
        parts.append(Part(name or str(node), str(geometry_name), vertices, faces))
    return parts


def _rotation_z_to(normal: np.ndarray) -> np.ndarray:
    """A rotation taking +z onto ``normal`` (shortest arc)."""
    n = normal / np.linalg.norm(normal)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    s, c = np.linalg.norm(axis), float(z @ n)
    if s < 1e-9:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def primitive(geometry: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of an SDF primitive in its own frame (SDF's conventions: centred,
    cylinders and capsules along z, a plane through the origin facing ``normal``)."""
    import trimesh

    kind = geometry.kind
    if kind == "box":
        mesh = trimesh.creation.box(extents=geometry.size)
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=geometry.radius, height=geometry.length, sections=32)
    elif kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=geometry.radius)
    elif kind == "capsule":
        mesh = trimesh.creation.capsule(height=geometry.length, radius=geometry.radius, count=[16, 16])
    elif kind == "ellipsoid":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
        mesh.vertices = mesh.vertices * np.asarray(geometry.size)
    elif kind == "plane":
        sx, sy = geometry.size
        mesh = trimesh.creation.box(extents=(sx, sy, PLANE_THICKNESS))
        mesh.vertices = (mesh.vertices - [0.0, 0.0, PLANE_THICKNESS / 2]) @ _rotation_z_to(
            np.asarray(geometry.normal, dtype=np.float64)
        ).T
    else:
        raise ValueError(f"not a primitive: {kind}")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
