"""Reading a Gazebo world (SDF): which geometry sits where, and in which model.

Written by hand because no PyPI package does it without Gazebo itself: ``sdformat`` on PyPI is a
2019 binding that needs the C++ libsdformat installed, and the other SDF parsers load robots
(one model, joints) rather than worlds of ``model://`` includes. What is needed here is small:
walk the ``<world>``, resolve ``<include>``\\ s along a model path, compose the poses of models,
links and visuals, and collect each ``<geometry>`` with its world pose and the chain of models
it belongs to. Meshes are loaded later (:mod:`.meshes`), once per file.

Poses follow SDF: ``x y z roll pitch yaw`` (fixed axes X, then Y, then Z), or ``x y z qx qy qz qw``
with ``rotation_format="quat_xyzw"``, in degrees with ``degrees="true"``. A pose is relative to
its element's default frame — a model's to its parent model (or the world), a link's to its
model, a visual's to its link, a ``<frame>``'s to what it is ``attached_to``, a joint's to its
child link — unless ``relative_to`` (or, before SDF 1.7, a non-empty ``frame``) names another
frame of the same model: a link, a nested model, a ``<frame>``, a joint or ``__model__``.
An ``<include>``'s ``<pose>`` replaces the included model's own; ``<placement_frame>`` is honoured.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlparse
from xml.etree import ElementTree as ET
from xml.parsers import expat

import numpy as np
from scipy.spatial.transform import Rotation

from amslam.errors import AmslamError


class WorldImportError(AmslamError):
    """A world could not be imported; the message names the file, line and element."""


class MissingFileError(WorldImportError):
    """An included model or a mesh is not where its URI says (``--skip-missing`` skips these)."""


# -- XML with line numbers ------------------------------------------------------------------------


@dataclass
class XmlFile:
    """A parsed XML file and the line each element starts on (ElementTree keeps no line numbers)."""

    path: Path
    root: ET.Element
    lines: dict[int, int]

    def at(self, element: ET.Element) -> str:
        line = self.lines.get(id(element))
        return f"{self.path}:{line}" if line else str(self.path)


_BARE_AMPERSAND = re.compile(rb"&(?!#\d+;|#x[0-9a-fA-F]+;|[A-Za-z_][\w.-]*;)")
_DECLARATION = re.compile(rb"<\?xml[^>]*\?>")


def _tolerate_tinyxml(data: bytes) -> bytes:
    """What Gazebo's TinyXML reads but an XML parser refuses, made valid: a bare ``&`` (``portal,
    door & car`` in a model.config) and an XML declaration after a comment (gazebo's own
    cafe.world). Line numbers stay as they were."""
    data = _BARE_AMPERSAND.sub(b"&amp;", data)
    first = _DECLARATION.search(data)
    if first is not None and data[: first.start()].strip(b" \t\r\n\xef\xbb\xbf"):
        data = data[: first.start()] + b" " * (first.end() - first.start()) + data[first.end() :]
    return data


def parse_xml(path: Path) -> XmlFile:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise WorldImportError(f"cannot read {path}: {exc.strerror}") from None
    data = _tolerate_tinyxml(data)
    builder = ET.TreeBuilder()
    parser = expat.ParserCreate()
    lines: dict[int, int] = {}

    def start(tag, attrs):
        lines[id(builder.start(tag, attrs))] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(data, True)
        root = builder.close()
    except expat.ExpatError as exc:
        raise WorldImportError(
            f"{path}:{exc.lineno}:{exc.offset + 1}: malformed XML: {expat.ErrorString(exc.code)}"
        ) from None
    return XmlFile(path, root, lines)


# -- what the reader produces ---------------------------------------------------------------------


@dataclass(frozen=True)
class Geometry:
    """One ``<geometry>``: a primitive or a mesh file."""

    kind: str  # box | cylinder | sphere | capsule | ellipsoid | plane | mesh
    size: tuple[float, ...] = ()  # box size, plane size, ellipsoid radii
    radius: float = 0.0
    length: float = 0.0
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    mesh: Path | None = None
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    submesh: str | None = None
    center_submesh: bool = False


@dataclass(frozen=True)
class ModelRef:
    """A model on the way from the world to a piece: its instance name and the name of what it is."""

    name: str
    kind: str  # the model's name in its own file (an include's model), or the same as name


@dataclass
class Piece:
    """A geometry placed in the world: world ← geometry transform, and whose it is."""

    geometry: Geometry
    pose: np.ndarray
    models: tuple[ModelRef, ...]
    link: str
    where: str


@dataclass
class Skipped:
    what: str
    reason: str


@dataclass
class SdfWorld:
    name: str
    pieces: list[Piece] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


# -- poses -----------------------------------------------------------------------------------------


def transform(xyz, rotation: Rotation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotation.as_matrix()
    T[:3, 3] = xyz
    return T


def _floats(text: str | None, count: int | tuple[int, ...], what: str, where: str) -> list[float]:
    counts = (count,) if isinstance(count, int) else count
    try:
        values = [float(v) for v in (text or "").split()]
    except ValueError:
        raise WorldImportError(f"{where}: {what} must be numbers, got {text!r}") from None
    if len(values) not in counts:
        raise WorldImportError(
            f"{where}: {what} needs {' or '.join(map(str, counts))} numbers, got {len(values)}: {text!r}"
        )
    return values


def parse_pose(element: ET.Element | None, where: str) -> tuple[np.ndarray, str | None]:
    """The transform a ``<pose>`` gives and the frame it is relative to (None = the default)."""
    if element is None:
        return np.eye(4), None
    rotation_format = element.get("rotation_format", "euler_rpy")
    if rotation_format == "quat_xyzw":
        v = _floats(element.text, 7, "pose (x y z qx qy qz qw)", where)
        if np.linalg.norm(v[3:]) < 1e-9:
            raise WorldImportError(f"{where}: pose quaternion is zero: {element.text!r}")
        rotation = Rotation.from_quat(v[3:])
    elif rotation_format == "euler_rpy":
        v = _floats(element.text, (0, 6), "pose (x y z roll pitch yaw)", where) or [0.0] * 6
        degrees = element.get("degrees", "false").strip().lower() in ("true", "1")
        rotation = Rotation.from_euler("xyz", v[3:], degrees=degrees)  # extrinsic X, Y, Z = SDF rpy
    else:
        raise WorldImportError(f"{where}: unknown pose rotation_format {rotation_format!r}")
    relative_to = element.get("relative_to") or element.get("frame") or None
    return transform(v[:3], rotation), relative_to


# -- model path ------------------------------------------------------------------------------------

#: environment variables Gazebo (classic, then Ignition / new Gazebo) reads its model path from
MODEL_PATH_VARIABLES = ("GAZEBO_MODEL_PATH", "GZ_SIM_RESOURCE_PATH", "IGN_GAZEBO_RESOURCE_PATH", "SDF_PATH")


def model_search_path(explicit: list[Path], world_file: Path | None) -> list[Path]:
    """Where ``model://`` URIs are looked up, in order: ``--model-path``, Gazebo's variables, then
    the conventional places a world's models sit beside it (``models/`` next to the world file or
    one folder up, as in the ROS world packages) and ``~/.gazebo/models``."""
    paths = list(explicit)
    for variable in MODEL_PATH_VARIABLES:
        paths += [Path(p) for p in os.environ.get(variable, "").split(os.pathsep) if p]
    if world_file is not None:
        here = world_file.resolve().parent
        paths += [here, here / "models", here.parent / "models"]
    paths.append(Path.home() / ".gazebo" / "models")
    unique: list[Path] = []
    for p in paths:
        if p not in unique:
            unique.append(p)
    return unique


def _config_sdf(model_dir: Path, where: str) -> Path:
    """The SDF file of a model folder: the newest version ``model.config`` lists, else model.sdf."""
    config = model_dir / "model.config"
    if config.is_file():
        xml = parse_xml(config)
        choices = []
        for element in xml.root.iter("sdf"):
            version = tuple(int(x) for x in re.findall(r"\d+", element.get("version", "0")))
            if element.text and element.text.strip():
                choices.append((version, element.text.strip()))
        for _, name in sorted(choices, reverse=True):
            if (model_dir / name).is_file():
                return model_dir / name
    for name in ("model.sdf", "model.urdf"):
        if (model_dir / name).is_file():
            return model_dir / name
    raise WorldImportError(
        f"{where}: model folder {model_dir} has no model.config naming an SDF file, nor model.sdf"
    )


#: Gazebo's stock models nearly every world includes, used when they are not on the model path
#: (they come with a Gazebo installation, which amslam does not need): the sun is a light, the
#: ground plane a 100 m × 100 m plane.
STOCK_MODELS = {
    "sun": '<sdf version="1.6"><light type="directional" name="sun"/></sdf>',
    "ground_plane": (
        '<sdf version="1.6"><model name="ground_plane"><static>true</static><link name="link">'
        '<visual name="visual"><geometry><plane><normal>0 0 1</normal><size>100 100</size></plane>'
        "</geometry></visual></link></model></sdf>"
    ),
}


# -- the reader ------------------------------------------------------------------------------------


@dataclass
class _Scope:
    """The frames of one model (or the world) being read."""

    xml: XmlFile
    element: ET.Element
    path: str  # element path for messages
    refs: tuple[ModelRef, ...]


class SdfReader:
    """Reads a world file into :class:`SdfWorld`.

    ``geometry`` chooses ``visual`` (what the camera sees, the default) or ``collision`` elements.
    With ``skip_missing``, an include or mesh that cannot be found is skipped and reported
    instead of stopping the import.
    """

    def __init__(self, model_path: list[Path], geometry: str = "visual", skip_missing: bool = False):
        self.model_path = model_path
        self.geometry = geometry
        self.skip_missing = skip_missing
        self._model_files: dict[str, XmlFile] = {}

    # entry point
    def read(self, path: Path) -> SdfWorld:
        xml = parse_xml(path)
        if xml.root.tag != "sdf":
            raise WorldImportError(
                f"{xml.at(xml.root)}: not an SDF file: the root element is <{xml.root.tag}>, not <sdf>"
            )
        worlds = xml.root.findall("world")
        if worlds:
            world_el = worlds[0]
            result = SdfWorld(world_el.get("name") or path.stem)
            if len(worlds) > 1:
                result.notes.append(
                    f"{len(worlds)} <world>s in the file: imported the first, {result.name!r}"
                )
            scope = _Scope(xml, world_el, f"world[{result.name}]", ())
        elif xml.root.find("model") is not None:  # a model file imported on its own
            result = SdfWorld(xml.root.find("model").get("name") or path.stem)
            scope = _Scope(xml, xml.root, "sdf", ())
        else:
            raise WorldImportError(f"{xml.at(xml.root)}: the SDF file has neither a <world> nor a <model>")
        self._read_children(scope, np.eye(4), result)
        return result

    # a world or a model: its nested models, includes and links
    def _read_children(self, scope: _Scope, world_T_scope: np.ndarray, out: SdfWorld) -> None:
        frames = _FrameGraph(scope, world_T_scope)
        for child in scope.element:
            if child.tag == "model":
                name = child.get("name") or "?"
                placement = (child.findtext("placement_frame") or "").strip() or None
                self._read_model(scope, child, name, frames.resolve(name), placement, world_T_scope, out)
            elif child.tag == "include":
                self._read_include(scope, frames, child, world_T_scope, out)
            elif child.tag == "link":
                self._read_link(scope, frames, child, world_T_scope, out)
            elif child.tag == "actor":
                out.skipped.append(
                    Skipped(f"actor {child.get('name', '?')}", "animated actor, not static geometry")
                )
            elif child.tag == "population":
                out.skipped.append(
                    Skipped(f"population {child.get('name', '?')}", "<population> not supported")
                )

    def _read_model(
        self,
        scope: _Scope,
        element: ET.Element,
        name: str,
        scope_T_model: np.ndarray,
        placement: str | None,
        world_T_scope: np.ndarray,
        out: SdfWorld,
        kind: str | None = None,
    ) -> None:
        """A model placed at ``scope_T_model`` in its parent (or, with ``placement``, that frame of it)."""
        path = f"{scope.path}/model[{name}]"
        inner = _Scope(
            scope.xml, element, path, (*scope.refs, ModelRef(name, kind or element.get("name") or name))
        )
        if placement is not None:
            where = f"{scope.xml.at(element)} ({path}/placement_frame)"
            model_T_placement = _FrameGraph(inner, np.eye(4)).resolve(placement, where)
            scope_T_model = scope_T_model @ np.linalg.inv(model_T_placement)
        self._read_children(inner, world_T_scope @ scope_T_model, out)

    def _read_include(
        self, scope: _Scope, frames: _FrameGraph, element, world_T_scope, out: SdfWorld
    ) -> None:
        uri_el = element.find("uri")
        where = f"{scope.xml.at(element)} ({scope.path}/include)"
        if uri_el is None or not (uri_el.text or "").strip():
            raise WorldImportError(f"{where}: <include> without a <uri>")
        uri = uri_el.text.strip()
        try:
            xml = self._load_model_file(uri, scope.xml.path.parent, where)
        except MissingFileError:
            if not self.skip_missing:
                raise
            model = urlparse(uri).netloc or Path(uri).name
            out.skipped.append(
                Skipped(f"{scope.path}/include", f"model {model!r} not found on the model path")
            )
            return
        included = xml.root.find("model")
        if included is None:
            kinds = sorted({c.tag for c in xml.root if isinstance(c.tag, str)})
            out.skipped.append(
                Skipped(f"include {uri}", f"no geometry (<{'>, <'.join(kinds) or 'nothing'}>)")
            )
            return
        name = (element.findtext("name") or "").strip() or included.get("name") or uri
        # the include's <pose> replaces the model's own
        pose_el = element.find("pose")
        pose_where = where if pose_el is not None else f"{xml.at(included)} ({uri})"
        pose, relative_to = parse_pose(pose_el if pose_el is not None else included.find("pose"), pose_where)
        scope_T_model = frames.resolve(relative_to, pose_where) @ pose
        placement = (
            element.findtext("placement_frame") or included.findtext("placement_frame") or ""
        ).strip()
        sub = _Scope(xml, xml.root, f"{scope.path}/include[{uri}]", scope.refs)
        self._read_model(
            sub, included, name, scope_T_model, placement or None, world_T_scope, out, included.get("name")
        )

    def _read_link(self, scope, frames, element, world_T_model, out) -> None:
        name = element.get("name") or "?"
        path = f"{scope.path}/link[{name}]"
        world_T_link = world_T_model @ frames.resolve(name)
        wanted = self.geometry
        other = "collision" if wanted == "visual" else "visual"
        if not element.findall(wanted) and element.findall(other):
            out.skipped.append(Skipped(f"{path}", f"has only <{other}> geometry, importing <{wanted}>s"))
        skipped_before = len(out.skipped)
        found = self._read_shapes(scope, frames, element, wanted, world_T_model, world_T_link, out)
        # every visual mesh was missing (skipped): the link's collision shapes stand in for it,
        # better than a hole where a bookshelf was
        missing = any(s.reason.startswith("mesh not found") for s in out.skipped[skipped_before:])
        fallback = not found and missing and wanted == "visual" and element.findall("collision")
        if fallback and self._read_shapes(
            scope, frames, element, "collision", world_T_model, world_T_link, out
        ):
            out.notes.append(f"{path}: visual mesh missing, imported its <collision> geometry instead")

    def _read_shapes(self, scope, frames, element, tag, world_T_model, world_T_link, out) -> int:
        """The link's ``tag`` (visual or collision) shapes as pieces; returns how many."""
        name = element.get("name") or "?"
        path = f"{scope.path}/link[{name}]"
        count = 0
        for shape in element.findall(tag):
            shape_name = shape.get("name") or "?"
            shape_path = f"{path}/{tag}[{shape_name}]"
            where = f"{scope.xml.at(shape)} ({shape_path})"
            pose, relative_to = parse_pose(shape.find("pose"), where)
            if relative_to:
                world_T_shape = world_T_model @ frames.resolve(relative_to, where) @ pose
            else:
                world_T_shape = world_T_link @ pose
            geometry_el = shape.find("geometry")
            if geometry_el is None:
                out.skipped.append(Skipped(shape_path, "no <geometry>"))
                continue
            geometry = self._geometry(scope.xml, geometry_el, where, shape_path, out)
            if geometry is not None:
                out.pieces.append(Piece(geometry, world_T_shape, scope.refs, name, where))
                count += 1
        return count

    def _geometry(
        self, xml: XmlFile, element: ET.Element, where: str, path: str, out: SdfWorld
    ) -> Geometry | None:
        shapes = [c for c in element if isinstance(c.tag, str)]
        if not shapes:
            out.skipped.append(Skipped(path, "empty <geometry>"))
            return None
        shape = shapes[0]
        where = f"{xml.at(shape)} ({path}/geometry/{shape.tag})"

        def number(tag: str, default: float | None = None) -> float:
            el = shape.find(tag)
            if el is None:
                if default is None:
                    raise WorldImportError(f"{where}: <{shape.tag}> needs <{tag}>")
                return default
            value = _floats(el.text, 1, f"<{tag}>", where)[0]
            if value <= 0:
                raise WorldImportError(f"{where}: <{tag}> must be positive, got {value}")
            return value

        def vector(tag: str, n: int, default: tuple[float, ...]) -> tuple[float, ...]:
            el = shape.find(tag)
            return default if el is None else tuple(_floats(el.text, n, f"<{tag}>", where))

        if shape.tag == "box":
            size = vector("size", 3, (1.0, 1.0, 1.0))
            if min(size) <= 0:
                raise WorldImportError(f"{where}: box size must be positive, got {size}")
            return Geometry("box", size=size)
        if shape.tag == "cylinder":
            return Geometry("cylinder", radius=number("radius", 0.5), length=number("length", 1.0))
        if shape.tag == "sphere":
            return Geometry("sphere", radius=number("radius", 1.0))
        if shape.tag == "capsule":
            return Geometry("capsule", radius=number("radius", 0.5), length=number("length", 1.0))
        if shape.tag == "ellipsoid":
            radii = vector("radii", 3, (1.0, 1.0, 1.0))
            return Geometry("ellipsoid", size=radii)
        if shape.tag == "plane":
            normal = vector("normal", 3, (0.0, 0.0, 1.0))
            if np.linalg.norm(normal) < 1e-9:
                raise WorldImportError(f"{where}: plane normal is zero")
            return Geometry("plane", size=vector("size", 2, (1.0, 1.0)), normal=normal)
        if shape.tag == "mesh":
            uri_el = shape.find("uri")
            if uri_el is None or not (uri_el.text or "").strip():
                raise WorldImportError(f"{where}: <mesh> without a <uri>")
            uri = uri_el.text.strip()
            scale = vector("scale", 3, (1.0, 1.0, 1.0))
            if any(abs(s) < 1e-12 for s in scale):
                raise WorldImportError(f"{where}: mesh scale has a zero: {scale}")
            try:
                mesh_path = self._resolve_file(uri, xml.path.parent, where, "mesh")
            except MissingFileError:
                if not self.skip_missing:
                    raise
                out.skipped.append(Skipped(path, f"mesh not found: {uri}"))
                return None
            submesh_el = shape.find("submesh")
            submesh, center = None, False
            if submesh_el is not None:
                submesh = (submesh_el.findtext("name") or "").strip() or None
                center = (submesh_el.findtext("center") or "").strip().lower() in ("true", "1")
            return Geometry("mesh", mesh=mesh_path, scale=scale, submesh=submesh, center_submesh=center)
        out.skipped.append(Skipped(path, f"<{shape.tag}> geometry not supported"))
        return None

    # -- resolving URIs ---------------------------------------------------------------------------

    def _candidates(self, uri: str, base: Path) -> tuple[list[Path], str]:
        """Paths a URI may name, and a description of where they were looked for."""
        parsed = urlparse(uri)
        if parsed.scheme in ("model", "package"):
            rest = unquote(parsed.netloc + parsed.path)
            roots = self.model_path
            if parsed.scheme == "package":  # a ROS package folder: usually the model path's parent
                roots = roots + [p.parent for p in roots]
            return [root / rest for root in roots], "model path " + os.pathsep.join(map(str, roots))
        if parsed.scheme in ("http", "https"):
            return [], "the network (not fetched: download the model and pass its folder with --model-path)"
        p = Path(unquote(parsed.netloc + parsed.path)) if parsed.scheme == "file" else Path(uri)
        if p.is_absolute():
            return [p], str(p.parent)
        # a relative path: Gazebo looks beside the file, then along its resource paths, which for
        # ROS world packages is the folder holding models/ ('file://models/x/meshes/x.dae')
        roots = [base] + self.model_path + [root.parent for root in self.model_path]
        unique = list(dict.fromkeys(roots))
        return [root / p for root in unique], ", ".join(map(str, unique))

    def _resolve_file(self, uri: str, base: Path, where: str, what: str) -> Path:
        candidates, searched = self._candidates(uri, base)
        for p in candidates:
            if p.is_file():
                return p
        # case-insensitive last resort: Windows-made models name 'mesh.DAE' and refer to 'mesh.dae'
        for p in candidates:
            if p.parent.is_dir():
                for sibling in p.parent.iterdir():
                    if sibling.name.lower() == p.name.lower() and sibling.is_file():
                        return sibling
        raise MissingFileError(f"{where}: {what} {uri!r} not found; searched {searched}")

    def _load_model_file(self, uri: str, base: Path, where: str) -> XmlFile:
        key = f"{base}|{uri}"
        if key in self._model_files:
            return self._model_files[key]
        candidates, searched = self._candidates(uri, base)
        found: XmlFile | None = None
        for p in candidates:
            if p.is_dir():
                found = parse_xml(_config_sdf(p, where))
                break
            if p.is_file():
                found = parse_xml(p)
                break
        if found is None:
            name = _model_name(uri)
            # Gazebo Fuel names the stock models 'Sun' and 'Ground Plane' (ROS 2 worlds include
            # them from https://fuel.gazebosim.org/1.0/OpenRobotics/models/...)
            stock = STOCK_MODELS.get(name) or STOCK_MODELS.get(name.lower().replace(" ", "_"))
            if stock is None:
                raise MissingFileError(f"{where}: model {name!r} ({uri}) not found; searched {searched}")
            root = ET.fromstring(stock)
            found = XmlFile(Path(f"<Gazebo's stock {name}>"), root, {})
        elif found.root.tag != "sdf":
            raise WorldImportError(
                f"{found.at(found.root)}: included file is not SDF (root <{found.root.tag}>)"
            )
        self._model_files[key] = found
        return found


def _model_name(uri: str) -> str:
    """The model a URI names: ``model://NAME/...``'s NAME, a Fuel URL's last path segment (its
    version number skipped: ``.../models/Ground Plane/2``), or a path's last part."""
    parsed = urlparse(uri)
    if parsed.scheme in ("http", "https"):
        parts = [unquote(p) for p in parsed.path.split("/") if p]
        if parts and parts[-1].isdigit():
            parts = parts[:-1]
        return parts[-1] if parts else parsed.netloc
    return parsed.netloc or Path(uri).name


class _FrameGraph:
    """The named frames of one model and their poses in the model frame (resolved on demand)."""

    def __init__(self, scope: _Scope, world_T_scope: np.ndarray):
        self.scope = scope
        self.entries: dict[str, tuple[ET.Element, str]] = {}
        for child in scope.element:
            name = child.get("name")
            if child.tag in ("link", "model", "frame", "joint") and name:
                self.entries[name] = (child, child.tag)
            elif child.tag == "include":
                # an include is a frame under its (possibly overridden) name; its pose is its <pose>
                name_el = child.find("name")
                if name_el is not None and (name_el.text or "").strip():
                    self.entries[name_el.text.strip()] = (child, "include")
        self.cache: dict[str, np.ndarray] = {"__model__": np.eye(4), "world": np.linalg.inv(world_T_scope)}
        self.resolving: set[str] = set()

    def resolve(self, name: str | None, where: str | None = None) -> np.ndarray:
        if not name:
            return np.eye(4)
        if name in self.cache:
            return self.cache[name]
        at = where or f"{self.scope.xml.at(self.scope.element)} ({self.scope.path})"
        if name not in self.entries:
            raise WorldImportError(
                f"{at}: frame {name!r} not found in {self.scope.path}"
                f" (frames: {', '.join(sorted(self.entries)) or 'none'};"
                " scoped names 'a::b' are not supported)"
            )
        if name in self.resolving:
            raise WorldImportError(
                f"{at}: the poses of {name!r} and the frames it is relative to form a cycle"
            )
        self.resolving.add(name)
        element, tag = self.entries[name]
        el_where = f"{self.scope.xml.at(element)} ({self.scope.path}/{tag}[{name}])"
        pose, relative_to = parse_pose(element.find("pose"), el_where)
        if relative_to is None:
            if tag == "frame":
                relative_to = element.get("attached_to") or None
            elif tag == "joint":
                relative_to = (element.findtext("child") or "").strip() or None
        result = self.resolve(relative_to, el_where) @ pose
        self.resolving.discard(name)
        self.cache[name] = result
        return result
