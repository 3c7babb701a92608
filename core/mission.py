"""Missions: YAML files validated into typed models.

A mission names one backend per kind with ``plugin:`` and nests that backend's parameters beside
it; the backend's own ``Params`` model validates them. Every problem is reported as one line
``FILE:LINE: field.path: what was wrong (got VALUE); expected ...`` and all problems of a file are
reported together.

    name: demo
    seed: 7
    platform: {plugin: sim, world: {floors: 1}}
    mapping: {plugin: open3d, global_voxel: 0.25}
    planner: {plugin: greedy}
"""

from __future__ import annotations

import copy
import importlib.resources
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from amslam.errors import MissionError, PluginError
from amslam.interfaces import (
    BACKEND_KINDS,
    BackendParams,
    Coordinate,
    FieldError,
    MissionFile,
    Point,
    check_mission_file,
    lo_below_hi,
    missing_modules,
)
from amslam.registry import Registry
from amslam.types import BoundingBox, RobotSpec

#: The backend a section uses when the mission does not name one.
DEFAULT_PLUGINS = {
    "platform": "sim",
    "mapping": "open3d",
    "slam": "odometry",
    "detector": "sim",
    "planner": "greedy",
}


class _Strict(BaseModel):
    # built when a mission is first validated, not at import (see BackendParams)
    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)


class RobotSection(_Strict):
    """Size and motion limits of the vehicle."""

    radius: float = Field(0.25, gt=0, le=5, description="radius of the sphere enclosing the vehicle, m")
    max_speed: float = Field(1.0, gt=0, le=30, description="horizontal and vertical speed limit, m/s")
    max_acceleration: float = Field(1.5, gt=0, le=50, description="acceleration limit, m/s²")
    max_yaw_rate: float = Field(1.0, gt=0, le=10, description="yaw rate limit, rad/s")
    altitude: float = Field(1.2, gt=0, le=100, description="take-off height above the start, m")
    clearance: float = Field(
        0.15, ge=0, le=5, description="extra distance planned paths keep from obstacles (tracking error), m"
    )
    base: tuple[Coordinate, Coordinate, Coordinate, Annotated[float, Field(ge=-360, le=360)]] | None = Field(
        None,
        description="real vehicles in a team: the take-off spot in the team's shared world frame, "
        "[x, y, z, yaw_deg], written to the measurement log for merging at the base (paper 2 §IV-B4); "
        "not for the simulator, whose odometry frame is the world frame (use platform.start)",
    )

    def spec(self) -> RobotSpec:
        return RobotSpec(**self.model_dump(exclude={"base"}))


class LimitsSection(_Strict):
    """When the mission stops exploring and returns home."""

    max_time: float = Field(
        1200.0, gt=0, le=1e6, description="mission time budget, s (simulated or wall clock)"
    )
    max_distance: float = Field(1000.0, gt=0, le=1e6, description="distance budget, m")


class AreaSection(_Strict):
    """The region to explore, world frame; defaults to the simulated world's bounds."""

    lo: Point
    hi: Point

    @model_validator(mode="after")
    def _lo_below_hi(self) -> AreaSection:
        lo_below_hi(self.lo, self.hi)
        return self

    def box(self) -> BoundingBox:
        import numpy as np

        return BoundingBox(np.array(self.lo, float), np.array(self.hi, float))


class ExplorationSection(_Strict):
    """Parameters of the behaviour tree and the runner's scheduling."""

    control_rate_hz: float = Field(
        10.0, ge=1, le=1000, description="tick rate of the behaviour tree and setpoints"
    )
    replan_period: float = Field(6.0, gt=0, le=1e6, description="replan at least this often while flying, s")
    replan_fraction: float = Field(
        0.5, gt=0, le=1, description="replan once this share of the tour's stops is done (receding horizon)"
    )
    frontier_change: float = Field(
        0.3, gt=0, le=1, description="replan when this share of the viewpoints changed since the last plan"
    )
    goal_tolerance: float = Field(
        0.3, gt=0, le=100, description="distance at which a waypoint counts as reached, m"
    )
    yaw_tolerance: float = Field(0.15, gt=0, le=3.15, description="heading error counted as reached, rad")
    look_around: bool = Field(
        True, description="turn a full circle after take-off to see around the start before planning"
    )
    max_replan_failures: int = Field(
        5,
        ge=1,
        le=10_000,
        description="consecutive planner failures before exploration gives up and returns home",
    )
    max_unreachable: int = Field(
        8,
        ge=1,
        le=10_000,
        description="consecutive unreachable goals before exploration gives up and returns home",
    )
    min_height: float = Field(
        0.7, ge=0, le=100, description="fly at least this high above the floor below, m"
    )
    min_headroom: float = Field(
        0.6, ge=0, le=100, description="and at least this far below the ceiling above, m"
    )
    min_viewpoint_gain: float = Field(
        0.5, ge=0, le=1e6, description="viewpoints promising less unknown volume than this (m³) are ignored"
    )
    slc: bool = Field(False, description="actively seek semantic loop closures (paper 1 §VI-C, D)")
    slc_sensing_range: float = Field(
        4.0, gt=0, le=1000, description="range within which a landmark counts as seen, m"
    )
    slc_min_travel: float = Field(
        30.0,
        gt=0,
        le=1e6,
        description="distance to travel after take-off or the last SLC attempt before another is "
        "offered (and before the same landmarks are offered again), m",
    )
    panorama_steps: int = Field(8, ge=3, le=360, description="headings of the panorama at an SLC viewpoint")
    viewpoint_period: float = Field(
        1.0,
        gt=0,
        le=1e6,
        description="refresh frontier viewpoints at most this often, s (they feed replanning)",
    )
    trajectory_rate_hz: float = Field(10.0, gt=0, le=1000, description="rate of the trajectory files")
    uncertainty_period: float = Field(5.0, gt=0, le=1e6, description="period of covariance-trace samples, s")
    reanchor_map: bool = Field(
        False,
        description="keep the depth frames (at about 80 px across) and rebuild the global map from them at"
        " the corrected poses when SLAM moves the odometry frame by more than reanchor_min_shift"
        " (a loop closure); runs on the control thread: for the simulator",
    )
    reanchor_min_shift: float = Field(
        0.2, gt=0, le=100, description="odometry-frame correction that rebuilds the global map, m"
    )


class WaypointsSection(_Strict):
    """A fixed flight pattern for ``tree: waypoints`` (see docs/flight.md)."""

    points: list[Point] = Field(
        default_factory=list,
        description="waypoints (x east, y north, z up) in metres relative to the take-off point on the "
        "ground, flown in straight lines: the operator vouches the way is clear",
    )
    heading: Literal["keep", "travel"] = Field(
        "keep", description="keep the take-off heading, or face the direction of travel"
    )
    tolerance: float = Field(
        0.2, gt=0, le=100, description="distance at which a waypoint counts as reached, m"
    )
    follow: Literal["straight", "paths"] = Field(
        "straight",
        description="straight: straight legs (the setpoint guards hold the vehicle back from what is in"
        " the way, skip_after gives such a waypoint up); paths: each leg a path through the map, as"
        " exploration flies (round what the map shows; a waypoint with no path is skipped)",
    )
    # A PAMS overhead survey hovered 770 s before a light pole its lawnmower leg crossed: the
    # setpoint guards held it (rightly) and nothing gave the leg up before the time limit.
    skip_after: float = Field(
        15.0,
        ge=0,
        le=3600,
        description="a waypoint the vehicle comes no closer to for this long (held by the setpoint guards,"
        " a wind it cannot beat) is skipped, event waypoint_skipped, s; 0: fly on until a limit ends it",
    )
    land_timeout: float = Field(
        60.0, gt=0, le=3600, description="how long a failsafe waits to see the vehicle touch down, s"
    )


class PluginsSection(_Strict):
    """Plugins to leave out of this run, and plugins the run may do without, by entry-point name."""

    disable: list[str] = Field(default_factory=list, description="plugins not loaded at all for this run")
    optional: list[str] = Field(
        default_factory=list,
        description="plugins whose failure to load is a warning, not an error (the run goes on without them)",
    )


class MissionModel(_Strict):
    """The top level of a mission file (backend sections are validated separately)."""

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$", description="used in the run folder name")
    description: str = ""
    seed: int = Field(0, ge=0, le=2**63 - 1, description="seeds every random stream of the run")
    plugins: PluginsSection = PluginsSection()
    robot: RobotSection = RobotSection()
    limits: LimitsSection = LimitsSection()
    area: AreaSection | None = None
    prior_map: MissionFile | None = Field(
        None,
        description="a map to start from: an earlier run's map.npz, or an OctoMap .bt (any resolution, "
        "resampled; needs pyoctomap: amslam[interop]); relative to the mission file",
    )
    exploration: ExplorationSection = ExplorationSection()
    tree: str = Field(
        "exploration",
        description="the mission tree, by name: exploration (default), waypoints (fly the waypoints "
        "section), or one a plugin provides (amslam_mission_trees)",
    )
    waypoints: WaypointsSection = WaypointsSection()
    platform: dict[str, Any] = Field(default_factory=dict)
    mapping: dict[str, Any] = Field(default_factory=dict)
    slam: dict[str, Any] = Field(default_factory=dict)
    detector: dict[str, Any] = Field(default_factory=dict)
    planner: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _waypoints_given(self) -> MissionModel:
        if self.tree == "waypoints" and not self.waypoints.points:
            raise FieldError("waypoints.points", "tree: waypoints needs at least one point here")
        return self


@dataclass
class BackendChoice:
    """One backend of the mission: its plugin name and validated parameters."""

    kind: str
    plugin: str
    params: BackendParams


@dataclass
class Mission:
    """A validated mission."""

    model: MissionModel
    backends: dict[str, BackendChoice]
    source: Path
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def directory(self) -> Path:
        return self.source.parent

    def resolved(self) -> dict[str, Any]:
        """The whole mission with every default filled in, as written to the run folder: every file
        it names (:data:`MissionFile`) an absolute path, so the copy stands on its own anywhere."""
        out = _absolute_files(
            self.model, self.model.model_dump(mode="json", exclude=set(BACKEND_KINDS)), self.directory
        )
        for kind, choice in self.backends.items():
            params = _absolute_files(choice.params, choice.params.model_dump(mode="json"), self.directory)
            out[kind] = {"plugin": choice.plugin, **params}
        return out


def _names_a_file(annotation: Any, metadata: Sequence[Any] = ()) -> bool:
    """Whether a field of this annotation is a :data:`MissionFile` (also inside ``| None``)."""
    marks = [*metadata, *getattr(annotation, "__metadata__", ())]
    if any(getattr(mark, "func", None) is check_mission_file for mark in marks):
        return True
    return any(_names_a_file(arg) for arg in typing.get_args(annotation))


def _absolute_files(model: BaseModel, dumped: dict[str, Any], base: Path) -> dict[str, Any]:
    """``dumped`` (the JSON dump of ``model``) with each file the model names resolved against
    ``base``, in nested models too (a world section, a list of them)."""
    for name, info in type(model).model_fields.items():
        value = getattr(model, name)
        if name not in dumped or value is None:
            continue
        if isinstance(value, str) and _names_a_file(info.annotation, info.metadata):
            dumped[name] = str((base / Path(value).expanduser()).resolve())
        elif isinstance(value, BaseModel):
            _absolute_files(value, dumped[name], base)
        elif isinstance(value, list | tuple):
            for item, out in zip(value, dumped[name], strict=False):
                if isinstance(item, BaseModel):
                    _absolute_files(item, out, base)
        elif isinstance(value, dict):
            for key, item in value.items():
                if isinstance(item, BaseModel) and str(key) in dumped[name]:
                    _absolute_files(item, dumped[name][str(key)], base)
    return dumped


def packaged_missions() -> list[str]:
    """Names of the missions shipped with amslam."""
    files = importlib.resources.files("amslam.missions")
    return sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".yaml"))


def resolve_mission_path(spec: str | Path) -> Path:
    """A file path, or the name of a packaged mission (``demo``). A folder of that name (a run's
    output folder: ``amslam run demo --out demo`` made one) does not hide the packaged mission."""
    path = Path(spec)
    name = str(spec).removesuffix(".yaml")
    packaged = name in packaged_missions()
    if path.exists() and not (packaged and path.is_dir()):
        return path
    if packaged:
        with importlib.resources.as_file(importlib.resources.files("amslam.missions") / f"{name}.yaml") as p:
            return Path(p)
    shipped = ", ".join(packaged_missions())
    raise MissionError([f"{spec}: no such mission file, and no packaged mission of that name ({shipped})"])


#: largest mission file read, bytes: a mission is a page of YAML, not a data set
MAX_MISSION_BYTES = 1 << 20
#: most YAML nodes a mission may expand to, aliases followed: a few hundred bytes of nested
#: aliases ("billion laughs") otherwise expand to gigabytes in whatever walks the document
MAX_MISSION_NODES = 100_000


def read_mission_text(path: Path) -> str:
    """The text of a mission file: a regular, readable UTF-8 file of at most ``MAX_MISSION_BYTES``."""
    try:
        if not path.is_file():
            kind = "a directory" if path.is_dir() else "not a regular file"
            raise MissionError([f"{path}: {kind}; a mission is a YAML file"])
        size = path.stat().st_size
        if size > MAX_MISSION_BYTES:
            raise MissionError([f"{path}: {size} bytes; a mission file is at most {MAX_MISSION_BYTES} bytes"])
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MissionError([f"{path}: not UTF-8 text (byte {exc.start}); a mission is a YAML file"]) from None
    except OSError as exc:
        raise MissionError([f"{path}: cannot read: {exc.strerror or exc}"]) from None


def parse_yaml(text: str, where: str) -> Any:
    """``yaml.safe_load`` with located errors and the alias expansion bounded (MAX_MISSION_NODES)."""
    try:
        return _bounded_safe_load(text, where)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f"{where}:{mark.line + 1}" if mark and not where.startswith("--set") else where
        raise MissionError([f"{at}: not valid YAML: {getattr(exc, 'problem', None) or exc}"]) from None


def _bounded_safe_load(text: str, where: str) -> Any:
    """``yaml.safe_load`` in one pass: the document is composed once, its size checked, then
    constructed from the same nodes (composing it for the check and loading it again parsed it
    twice, and PyYAML's pure-Python parser is slow)."""
    loader = yaml.SafeLoader(text)
    try:
        root = loader.get_single_node()
        _check_expansion(root, where)
        return loader.construct_document(root) if root is not None else None
    finally:
        loader.dispose()


def _check_expansion(root: yaml.Node | None, where: str) -> None:
    """Refuse a document whose node tree, aliases followed, exceeds MAX_MISSION_NODES.

    Sizes are memoised per node object (an alias is the same node object in PyYAML's graph), so
    the check costs one visit per distinct node however much the aliases would expand.
    """
    sizes: dict[int, int] = {}

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        sizes[key] = 1  # a recursive alias counts once; the loader refuses it anyway
        children: list = []
        if isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        elif isinstance(node, yaml.SequenceNode):
            children = node.value
        total = 1
        for child in children:
            total += size(child)
            if total > MAX_MISSION_NODES:
                break
        sizes[key] = total
        return total

    if root is not None and size(root) > MAX_MISSION_NODES:
        raise MissionError([f"{where}: expands to more than {MAX_MISSION_NODES} YAML nodes (aliases)"])


#: how a key no schema knows is reported (:attr:`_Problems.unknown_keys` collects them)
UNKNOWN_KEY = "unknown key "


def apply_override(raw: dict[str, Any], assignment: str) -> None:
    """Apply ``key.path=value`` (value parsed as YAML) to a raw mission dict."""
    if "=" not in assignment:
        raise MissionError([f"--set {assignment!r}: expected key.path=value"])
    key, value = assignment.split("=", 1)
    parts = key.strip().split(".")
    if not all(parts):
        raise MissionError([f"--set {assignment!r}: {key!r} is not a key path (section.key)"])
    node = raw
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise MissionError([f"--set {assignment!r}: {part!r} is not a section"])
    node[parts[-1]] = parse_yaml(value, f"--set {assignment!r}")


def load_mission(
    spec: str | Path, registry: Registry, overrides: list[str] = (), unset: list[str] = ()
) -> Mission:
    """Read, override and validate a mission; raise MissionError listing every problem.

    ``unset``: dotted key paths removed before validation where present (a run folder's mission
    naming parameters a later version renamed: :attr:`MissionError.unknown_keys`).
    """
    path = resolve_mission_path(spec)
    text = read_mission_text(path)
    raw = parse_yaml(text, str(path))
    if not isinstance(raw, dict):
        raise MissionError([f"{path}: a mission is a mapping of sections, got {type(raw).__name__}"])
    raw = copy.deepcopy(raw)
    for assignment in overrides:
        apply_override(raw, assignment)
    for dotted in unset:
        *parents, last = dotted.split(".")
        node: Any = raw
        for part in parents:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.pop(last, None)
    problems = _Problems(path, text)
    context = {"mission_dir": path.resolve().parent}  # relative file parameters resolve against it
    try:
        model = MissionModel.model_validate(raw, context=context)
    except ValidationError as exc:
        for err in exc.errors():
            problems.report(_data_loc(raw, err), _describe(err, MissionModel, err["loc"]))
        model = None
    _check_plugins(model, registry, problems)
    backends: dict[str, BackendChoice] = {}
    for kind in BACKEND_KINDS:
        if (choice := _backend_choice(kind, raw, model, registry, context, problems)) is not None:
            backends[kind] = choice
    if model is not None and "platform" in backends:
        _check_waypoints_fit_the_fence(model, backends["platform"].params, problems)
    if problems.lines:
        raise MissionError(problems.lines, problems.unknown_keys)
    assert model is not None
    return Mission(model=model, backends=backends, source=path.resolve(), raw=raw)


@dataclass
class _Problems:
    """Every problem of one mission file, each named by file, line and dotted key."""

    path: Path
    text: str
    lines: list[str] = field(default_factory=list)
    #: key path -> line, indexed at the first problem (a valid mission needs no second YAML pass)
    line_index: dict[tuple, int] | None = None
    #: dotted paths of the keys no schema knows (a subset of the problems)
    unknown_keys: list[str] = field(default_factory=list)

    def report(self, loc: tuple, message: str) -> None:
        if self.line_index is None:
            self.line_index = _line_index(self.text)
        dotted = ".".join(str(p) for p in loc) or "(top level)"
        if message.startswith(UNKNOWN_KEY):
            self.unknown_keys.append(dotted)
        line = _line_of(self.line_index, loc)
        where = f"{self.path}:{line}" if line else f"{self.path}"
        self.lines.append(f"{where}: {dotted}: {message}")


def _check_plugins(model: MissionModel | None, registry: Registry, problems: _Problems) -> None:
    """The mission's tree exists; no plugin failed to load unless the mission marks it optional."""
    if model is not None:
        try:
            registry.tree(model.tree)
        except PluginError as exc:
            problems.report(("tree",), str(exc))
    optional = set(model.plugins.optional) if model is not None else set()
    for name, error in sorted(registry.load_errors.items()):
        if name not in optional:
            problems.report(
                ("plugins",),
                f"{error} — fix or uninstall it, or list it under plugins.disable or plugins.optional",
            )


def _backend_choice(
    kind: str,
    raw: dict[str, Any],
    model: MissionModel | None,
    registry: Registry,
    context: dict[str, Any],
    problems: _Problems,
) -> BackendChoice | None:
    """The backend a section chooses, its parameters validated; None (reported) if it cannot be."""
    section = raw.get(kind) or {}
    if not isinstance(section, dict):
        return None  # already reported by MissionModel
    section = dict(section)
    plugin = section.pop("plugin", DEFAULT_PLUGINS[kind])
    if not isinstance(plugin, str):
        problems.report((kind, "plugin"), f"expected a plugin name (text), got {plugin!r}")
        return None
    try:
        cls = registry.backend_class(kind, plugin)
    except PluginError as exc:
        problems.report((kind, "plugin"), str(exc))
        return None
    if missing := missing_modules(cls.requires):
        needs = ", ".join(repr(m) for m in missing)
        problems.report(
            (kind, "plugin"),
            f"{plugin!r} needs the Python module{'s' * (len(missing) > 1)} {needs}, not installed here",
        )
    try:
        params = cls.Params.model_validate(section, context=context)
    except ValidationError as exc:
        for err in exc.errors():
            problems.report((kind, *_data_loc(section, err)), _describe(err, cls.Params, err["loc"]))
        return None
    if kind == "platform" and model is not None and model.robot.base is not None and cls.simulated:
        problems.report(
            ("robot", "base"),
            f"the {plugin!r} platform is simulated: its odometry frame is the world frame already; "
            "robot.base is for real vehicles (platform.start chooses where a simulated robot takes off)",
        )
    return BackendChoice(kind, plugin, params)


def _check_waypoints_fit_the_fence(model: MissionModel, platform: Any, problems: _Problems) -> None:
    """Waypoints are relative to the take-off spot and the fence is in the odometry frame: wherever
    the vehicle takes off, the pattern (take-off spot included) must fit inside the fence."""
    fence = getattr(platform, "geofence", None)
    if fence is None or not model.waypoints.points:
        return
    pts = [(0.0, 0.0, 0.0), *model.waypoints.points]
    for axis, name in enumerate("xyz"):
        span = max(p[axis] for p in pts) - min(p[axis] for p in pts)
        room = fence.hi[axis] - fence.lo[axis]
        if span > room:
            problems.report(
                ("waypoints", "points"),
                f"the pattern spans {span:g} m in {name}, more than the geofence's {room:g} m "
                f"(platform.geofence): it cannot lie inside the fence",
            )


def _data_loc(data: Any, err: dict) -> tuple:
    """Where in the mission's data a pydantic error is: its ``loc`` without the tags pydantic adds
    for a union's members (``world.procedural.size`` → ``world.size``), plus the field a
    :class:`FieldError` names (a cross-field rule points at the field, not the whole section)."""
    loc = tuple(err["loc"])
    error = (err.get("ctx") or {}).get("error")
    if isinstance(error, FieldError):
        loc = (*loc, *error.field.split("."))

    def resolve(node: Any, parts: tuple, strict: bool = False) -> tuple | None:
        """``parts`` as found in ``node``, skipping tags; None if they are not there."""
        if not parts:
            return ()
        head, rest = parts[0], parts[1:]
        present = (isinstance(node, dict) and head in node) or (
            isinstance(node, list) and isinstance(head, int) and 0 <= head < len(node)
        )
        if present:
            found = resolve(node[head], rest, strict)
            if found is not None:
                return (head, *found)
        if not rest and not strict and isinstance(node, dict):
            return (head,)  # a missing or unknown key, at the end of the path
        if isinstance(head, str) and isinstance(node, dict) and rest:
            # a union member's tag (``kind``), not in the data
            return resolve(node, rest, strict=strict or node.get("kind") != head)
        return None

    return resolve(data, loc) or loc


_MISSING = object()


def _describe(err: dict, model: type[BaseModel], loc: tuple) -> str:
    """A pydantic error as a sentence saying what was wrong and what was expected."""
    kind = err["type"]
    got = err.get("input")
    if kind == "extra_forbidden":
        allowed = _fields_at(model, loc[:-1])
        hint = f"; expected one of: {', '.join(allowed)}" if allowed else ""
        return f"{UNKNOWN_KEY}{loc[-1]!r}{hint}"
    if kind == "missing":
        return "required, but missing"
    if kind == "value_error":  # a rule of ours: its message says what it got
        return str((err.get("ctx") or {}).get("error") or err["msg"])
    return f"{err['msg'].lower()} (got {got!r})"


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation holds (through Optional, unions and Annotated)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in getattr(annotation, "__args__", ()) for m in _models_in(arg)]


def _fields_at(model: type[BaseModel], loc: tuple) -> list[str]:
    parts = list(loc)
    while parts:
        part = parts.pop(0)
        info = model.model_fields.get(str(part)) if isinstance(part, str) else None
        if info is None:
            return []
        models = _models_in(info.annotation)
        if len(models) > 1 and parts:  # a tagged union: pydantic's loc names the member next
            tag = parts.pop(0)
            models = [m for m in models if getattr(m.model_fields.get("kind"), "default", None) == tag]
        if len(models) != 1:
            return []
        model = models[0]
    return sorted(model.model_fields)


def _line_index(text: str) -> dict[tuple, int]:
    """Map each key path of a YAML document to its 1-based line, for error messages."""
    try:
        root = yaml.compose(text)
    except yaml.YAMLError:
        return {}
    index: dict[tuple, int] = {}
    seen: set[int] = set()

    def walk(node: yaml.Node, prefix: tuple) -> None:
        if id(node) in seen:
            return  # an alias: its lines were indexed where it was anchored
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            for key_node, value_node in node.value:
                key = (*prefix, key_node.value)
                index[key] = key_node.start_mark.line + 1
                walk(value_node, key)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                index[(*prefix, i)] = item.start_mark.line + 1
                walk(item, (*prefix, i))

    if root is not None:
        walk(root, ())
    return index


def _line_of(index: dict[tuple, int], loc: tuple) -> int | None:
    loc = tuple(str(p) if not isinstance(p, int) else p for p in loc)
    while loc:
        if loc in index:
            return index[loc]
        loc = loc[:-1]
    return None
