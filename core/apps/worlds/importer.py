"""``amslam world import``: a Gazebo world or a plain mesh becomes a mesh world amslam flies.

Output, in one folder (what :mod:`amslam.plugins.sim.meshworld` reads, see docs/worlds.md):

* ``world.ply`` — every triangle, metres, world frame, z up;
* ``objects/<name>.ply`` — each object alone, in world coordinates (its triangles are also in
  world.ply, where the simulator labels them by matching triangle centroids);
* ``objects.json`` — ``name``, ``class``, ``mesh`` and ``bounds`` of each object;
* ``mission.yaml`` — a ready-to-fly mission for it with the default stack;
* ``summary.txt`` — what :func:`summary_text` prints.

An object is a model (or, in a plain mesh, a node of the scene) whose name the class map maps to
a class. The outermost model of a class owns everything inside it; a nested model mapped to
another class is an object of its own. Models no rule maps are building structure.
"""

from __future__ import annotations

import json
import re
import shutil
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from amslam.apps.worlds.classmap import SKIP, STRUCTURE, ClassMap, load_class_map
from amslam.apps.worlds.meshes import MESH_TYPES, Part, load_mesh_file, primitive
from amslam.apps.worlds.sdf import Piece, SdfReader, Skipped, WorldImportError, model_search_path

WORLD_SUFFIXES = (".world", ".sdf")


@dataclass
class ImportOptions:
    class_map: Path | None = None
    model_path: list[Path] = field(default_factory=list)
    geometry: str = "visual"  # or "collision"
    skip_missing: bool = False
    up_axis: str = "auto"  # plain meshes: auto (the file's), x, y or z
    scale: float = 1.0  # plain meshes: metres per file unit (COLLADA units are applied besides)
    plane_margin: float = 1.0  # horizontal planes are cut to the rest of the world plus this, m
    name: str | None = None


@dataclass
class ImportedObject:
    name: str
    cls: str
    rule: str
    vertices: list[np.ndarray] = field(default_factory=list)
    faces: list[np.ndarray] = field(default_factory=list)


@dataclass
class ImportResult:
    name: str
    source: Path
    out: Path
    lo: np.ndarray
    hi: np.ndarray
    triangles: int
    objects: list[ImportedObject]
    structure_models: Counter
    skipped: list[Skipped]
    notes: list[str]
    mission: Path


def family(name: str) -> str:
    """A model name without its instance numbers: ``'Chandelier_01_002'`` → ``'Chandelier'``."""
    return re.sub(r"([_\s.-]*\d+)+$", "", name) or name


# -- owners ----------------------------------------------------------------------------------------


def owner_of(names: list[tuple[str, str]], class_map: ClassMap) -> tuple[str, str, str] | None | str:
    """Who owns geometry nested in the models ``names`` (outermost first, ``(instance, kind)``).

    Returns ``(object name, class, rule)`` for an object, None for structure, ``SKIP`` to leave it out.
    """
    owner = None
    for depth, (name, kind) in enumerate(names):
        match = class_map.classify(name, kind)
        if match is None:
            continue
        cls, rule = match
        if cls == SKIP:
            return SKIP
        if cls == STRUCTURE:
            owner = None
        elif owner is None or owner[1] != cls:
            owner = ("::".join(n for n, _ in names[: depth + 1]), cls, rule)
    return owner


class _Collector:
    """Triangles gathered by owner: structure, or one object per name."""

    def __init__(self) -> None:
        self.structure_v: list[np.ndarray] = []
        self.structure_f: list[np.ndarray] = []
        self.objects: dict[str, ImportedObject] = {}

    def add(self, owner: tuple[str, str, str] | None, vertices: np.ndarray, faces: np.ndarray) -> None:
        if len(faces) == 0:
            return
        if owner is None:
            self.structure_v.append(vertices)
            self.structure_f.append(faces)
            return
        name, cls, rule = owner
        obj = self.objects.setdefault(name, ImportedObject(name, cls, rule))
        obj.vertices.append(vertices)
        obj.faces.append(faces)


# -- Gazebo worlds ---------------------------------------------------------------------------------


def _place(pose: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    placed = vertices @ pose[:3, :3].T + pose[:3, 3]
    return placed, (faces[:, ::-1] if np.linalg.det(pose[:3, :3]) < 0 else faces)


def _mesh_triangles(
    piece: Piece, cache: dict, skipped: list[Skipped]
) -> tuple[np.ndarray, np.ndarray] | None:
    g = piece.geometry
    if g.mesh not in cache:
        cache[g.mesh] = load_mesh_file(g.mesh, up_axis=None, where=piece.where)
    parts: list[Part] = cache[g.mesh]
    if g.submesh is not None:
        parts = [p for p in parts if g.submesh in (p.name, p.geometry_name)]
        if not parts:
            skipped.append(Skipped(piece.where, f"submesh {g.submesh!r} not in {g.mesh.name}"))
            return None
    if not parts:
        skipped.append(Skipped(piece.where, f"{g.mesh.name} has no triangles"))
        return None
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    vertices = np.concatenate([p.vertices for p in parts])
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)])
    if g.submesh is not None and g.center_submesh:
        vertices = vertices - (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    scale = np.asarray(g.scale)
    vertices = vertices * scale
    if np.prod(np.sign(scale)) < 0:  # a mirroring scale turns the triangles inside out
        faces = faces[:, ::-1]
    return vertices, faces


def _import_sdf(
    source: Path, options: ImportOptions, class_map: ClassMap, out: _Collector, result_notes
) -> tuple:
    reader = SdfReader(
        model_search_path(options.model_path, source),
        geometry=options.geometry,
        skip_missing=options.skip_missing,
    )
    world = reader.read(source)
    skipped = list(world.skipped)
    result_notes += world.notes
    structure_models: Counter = Counter()
    cache: dict = {}
    planes: list[tuple[Piece, object]] = []
    seen_structure: set[str] = set()
    placed: list[tuple[str, object, np.ndarray, np.ndarray]] = []
    for piece in world.pieces:
        names = [(m.name, m.kind) for m in piece.models]
        owner = owner_of(names, class_map)
        if owner is None and piece.models:
            match = class_map.classify(piece.link)  # a building model whose links are named furniture
            if match is not None and match[0] not in (STRUCTURE, SKIP):
                owner = ("::".join([n for n, _ in names] + [piece.link]), match[0], match[1])
        if owner == SKIP:
            what = "::".join(n for n, _ in names)
            if not any(s.what == what for s in skipped):
                skipped.append(Skipped(what, "class map says skip"))
            continue
        if owner is None and piece.models:
            top = piece.models[0]
            if top.name not in seen_structure:
                seen_structure.add(top.name)
                structure_models[family(top.name)] += 1
        if piece.geometry.kind == "plane":
            planes.append((piece, owner))
            continue
        if piece.geometry.kind == "mesh":
            triangles = _mesh_triangles(piece, cache, skipped)
            if triangles is None:
                continue
            vertices, faces = triangles
        else:
            vertices, faces = primitive(piece.geometry)
        top = piece.models[0].name if piece.models else piece.link
        placed.append((top, owner, *_place(piece.pose, vertices, faces)))
    extents: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for top, _, vertices, _ in placed:
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        if top in extents:
            lo, hi = np.minimum(lo, extents[top][0]), np.maximum(hi, extents[top][1])
        extents[top] = (lo, hi)
    far = far_away(extents)
    for top, reason in far.items():
        skipped.append(Skipped(f"model {top}", reason))
    for top, owner, vertices, faces in placed:
        if top not in far:
            out.add(owner, vertices, faces)
    _add_planes(planes, out, options.plane_margin, result_notes)
    return world.name, skipped, structure_models


def far_away(extents: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, str]:
    """Top-level models lying far outside the rest of the world (name → why they are left out).

    Saved Gazebo worlds keep what physics threw away: the AWS bookstore has a book at z = 343 km.
    Such a model would make the world's bounds (and so the flyable volume) absurd. "Far" is
    beyond the box holding the middle 80 % of model centres, widened by its own size and 10 m.
    """
    if len(extents) < 5:
        return {}
    names = list(extents)
    lo = {n: extents[n][0] for n in names}
    hi = {n: extents[n][1] for n in names}
    centres = np.array([(lo[n] + hi[n]) / 2 for n in names])
    core_lo, core_hi = np.percentile(centres, 10, axis=0), np.percentile(centres, 90, axis=0)
    margin = (core_hi - core_lo) + 10.0
    result = {}
    for n in names:
        if np.any(lo[n] > core_hi + margin) or np.any(hi[n] < core_lo - margin):
            centre = (lo[n] + hi[n]) / 2
            result[n] = (
                f"far outside the rest of the world (at {centre[0]:.0f}, {centre[1]:.0f}, {centre[2]:.0f} m)"
            )
    return result


def _add_planes(planes, out: _Collector, margin: float, notes: list[str]) -> None:
    """Planes become thin slabs; a horizontal plane larger than the rest of the world (a 100 m
    ground plane under a house) is cut to the rest's footprint plus ``margin``, so the world's
    bounds are the building's."""
    others = out.structure_v + [v for o in out.objects.values() for v in o.vertices]
    if others:
        every = np.concatenate(others)
        lo, hi = every.min(axis=0)[:2] - margin, every.max(axis=0)[:2] + margin
    for piece, owner in planes:
        vertices, faces = _place(piece.pose, *primitive(piece.geometry))
        normal = piece.pose[:3, :3] @ np.asarray(piece.geometry.normal, dtype=np.float64)
        horizontal = abs(normal[2]) / np.linalg.norm(normal) > 0.999
        if others and horizontal:
            plo, phi = vertices.min(axis=0), vertices.max(axis=0)
            clo, chi = np.maximum(plo[:2], lo), np.minimum(phi[:2], hi)
            if np.any(chi <= clo):
                notes.append(f"plane {piece.where} lies outside the rest of the world: left out")
                continue
            if np.any(clo > plo[:2] + 1e-6) or np.any(chi < phi[:2] - 1e-6):
                before = phi[:2] - plo[:2]
                vertices = vertices.copy()
                vertices[:, :2] = np.clip(vertices[:, :2], clo, chi)
                after = chi - clo
                notes.append(
                    f"plane {' / '.join(m.name for m in piece.models) or piece.where}:"
                    f" {before[0]:.0f} × {before[1]:.0f} m cut to {after[0]:.1f} × {after[1]:.1f} m"
                    f" (the rest of the world + {margin:g} m)"
                )
        out.add(owner, vertices, faces)


# -- plain meshes ----------------------------------------------------------------------------------


def _import_mesh(source: Path, options: ImportOptions, class_map: ClassMap, out: _Collector) -> tuple:
    suffix = source.suffix.lower()
    if options.up_axis != "auto":
        up = options.up_axis
    elif suffix == ".dae":
        from amslam.apps.worlds.meshes import collada_asset

        up = collada_asset(source)[1]
    elif suffix in (".glb", ".gltf"):
        up = "y"  # glTF is y-up by its specification
    else:
        up = "z"
    parts = load_mesh_file(source, up_axis=up)
    if not parts:
        raise WorldImportError(f"{source}: no triangles")
    structure_models: Counter = Counter()
    skipped: list[Skipped] = []
    used: Counter = Counter()
    for part in parts:
        names = [(part.name, part.geometry_name)]
        owner = owner_of(names, class_map)
        if owner == SKIP:
            skipped.append(Skipped(part.name, "class map says skip"))
            continue
        if owner is not None:
            used[owner[0]] += 1
            if used[owner[0]] > 1:  # two nodes of one name are two objects
                owner = (f"{owner[0]}_{used[owner[0]]}", owner[1], owner[2])
        else:
            structure_models[family(part.name)] += 1
        out.add(owner, part.vertices * options.scale, part.faces)
    return source.stem, skipped, structure_models


# -- output ----------------------------------------------------------------------------------------


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name.replace("::", "__")).strip("._") or "object"


def _write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    import trimesh

    trimesh.Trimesh(vertices, faces, process=False).export(str(path), file_type="ply", encoding="binary")


def mission_text(name: str, source: Path) -> str:
    return f"""# Imported by `amslam world import {source}`: a mesh world (world.ply, objects.json beside this
# file) flown with the default stack, as missions/demo.yaml. Paths are relative to this file.
name: {name}
description: Explore {name} (imported from {source.name}) and map its objects.
seed: 1

robot: {{radius: 0.25, max_speed: 0.8, altitude: 1.2}}
limits: {{max_time: 900, max_distance: 600}}

platform:
  plugin: sim
  world: {{kind: mesh, mesh: world.ply, objects: objects.json}}
  camera: {{width: 320, height: 240, rate_hz: 5}}

mapping: {{plugin: open3d}}
slam: {{plugin: gtsam}}
detector: {{plugin: sim}}
planner: {{plugin: cop}}
exploration: {{slc: true}}
"""


def import_world(source: Path, out_dir: Path, options: ImportOptions | None = None) -> ImportResult:
    """Import ``source`` (a .world/.sdf or a mesh file) into ``out_dir``."""
    options = options or ImportOptions()
    if not source.is_file():
        raise WorldImportError(f"world not found: {source}")
    class_map = load_class_map(options.class_map)
    collector = _Collector()
    notes: list[str] = []
    suffix = source.suffix.lower()
    if suffix in WORLD_SUFFIXES:
        name, skipped, structure_models = _import_sdf(source, options, class_map, collector, notes)
    elif suffix in MESH_TYPES:
        name, skipped, structure_models = _import_mesh(source, options, class_map, collector)
    else:
        known = ", ".join(sorted(set(WORLD_SUFFIXES) | set(MESH_TYPES)))
        raise WorldImportError(f"{source}: unknown kind of world {suffix!r} (known: {known})")
    # Gazebo worlds are mostly called "default" or "world": the file name says more
    name = options.name or (name if name.lower() not in ("default", "world", "") else source.stem)
    name = _safe(name)

    all_v = collector.structure_v + [v for o in collector.objects.values() for v in o.vertices]
    all_f = collector.structure_f + [f for o in collector.objects.values() for f in o.faces]
    if not all_f:
        raise WorldImportError(f"{source}: no geometry to import (skipped: {len(skipped)})")
    offsets = np.cumsum([0] + [len(v) for v in all_v[:-1]])
    V = np.concatenate(all_v)
    F = np.concatenate([f + o for f, o in zip(all_f, offsets, strict=True)])

    out_dir.mkdir(parents=True, exist_ok=True)
    objects_dir = out_dir / "objects"
    if objects_dir.is_dir() and all(p.suffix == ".ply" for p in objects_dir.iterdir()):
        shutil.rmtree(objects_dir)  # a previous import's objects
    objects_dir.mkdir(exist_ok=True)
    _write_ply(out_dir / "world.ply", V, F)
    entries = []
    objects = sorted(collector.objects.values(), key=lambda o: (o.cls, o.name))
    used_files: set[str] = set()
    for obj in objects:
        offsets = np.cumsum([0] + [len(v) for v in obj.vertices[:-1]])
        ov = np.concatenate(obj.vertices)
        of = np.concatenate([f + o for f, o in zip(obj.faces, offsets, strict=True)])
        stem = _safe(obj.name)
        while stem.lower() in used_files:
            stem += "_"
        used_files.add(stem.lower())
        _write_ply(objects_dir / f"{stem}.ply", ov, of)
        lo, hi = ov.min(axis=0), ov.max(axis=0)
        entries.append(
            {
                "name": obj.name,
                "class": obj.cls,
                "mesh": f"objects/{stem}.ply",
                "bounds": [lo.tolist(), hi.tolist()],
            }
        )
    (out_dir / "objects.json").write_text(json.dumps(entries, indent=1) + "\n")
    mission = out_dir / "mission.yaml"
    mission.write_text(mission_text(name, source))
    result = ImportResult(
        name,
        source,
        out_dir,
        V.min(axis=0),
        V.max(axis=0),
        len(F),
        objects,
        structure_models,
        skipped,
        notes,
        mission,
    )
    (out_dir / "summary.txt").write_text(summary_text(result) + "\n")
    return result


def summary_text(r: ImportResult) -> str:
    size = r.hi - r.lo
    lines = [
        f"imported {r.source} → {r.out}",
        f"  world.ply: {r.triangles:,} triangles; bounds x {r.lo[0]:.2f} … {r.hi[0]:.2f},"
        f" y {r.lo[1]:.2f} … {r.hi[1]:.2f},"
        f" z {r.lo[2]:.2f} … {r.hi[2]:.2f} m ({size[0]:.1f} × {size[1]:.1f} × {size[2]:.1f} m)",
    ]
    by_class = Counter(o.cls for o in r.objects)
    listing = ", ".join(f"{c} {n}" for c, n in sorted(by_class.items(), key=lambda kv: (-kv[1], kv[0])))
    lines.append(f"  objects: {len(r.objects)}" + (f" — {listing}" if listing else ""))
    if r.structure_models:
        total = sum(r.structure_models.values())
        common = ", ".join(f"{k} ×{n}" if n > 1 else k for k, n in r.structure_models.most_common(12))
        more = f", … {len(r.structure_models) - 12} more kinds" if len(r.structure_models) > 12 else ""
        lines.append(f"  structure (no class): {total} model{'s' if total > 1 else ''} — {common}{more}")
    if r.skipped:
        lines.append(f"  skipped: {len(r.skipped)}")
        reasons = Counter(s.reason for s in r.skipped)
        first = {}
        for s in r.skipped:
            first.setdefault(s.reason, s.what)
        for reason, n in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0])):
            example = f"×{n}, e.g. {first[reason]}" if n > 1 else first[reason]
            lines.append(f"    - {reason} ({example})")
    for note in r.notes:
        lines.append(f"  note: {note}")
    lines.append(f"  mission: {r.mission}   fly it: amslam run {r.mission}")
    return "\n".join(lines)
