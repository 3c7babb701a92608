"""Training data from the simulator: shaded RGB frames with their instance masks as labels.

Each seed generates one procedural building (:func:`amslam.plugins.sim.procedural.generate_building`);
camera poses are drawn inside its reachable free space (where the robot can fly), at flight
heights, level or slightly pitched like the forward camera of a multicopter. Most poses (70 %)
look towards a furniture piece in line of sight a few metres away, so that objects fill a good
share of the frames; the others look in a random direction, so that the network also sees empty walls,
corridors and doors (its negatives). Labels are the renderer's instance masks: no hand labelling.

With ``randomise`` (the training set's default) each building and frame varies what the network
should not learn (domain randomisation, issue #23): the building's storey height, room widths and
furniture density, each furniture piece's dimensions, clutter of other classes (boxes, cylinders,
lamps: background), the colours and procedural textures (noise, stripes, checker) of walls,
floors, ceilings and each object, the light (direction, ambient and diffuse shares, falloff,
colour cast) and the camera's exposure and noise. Half of the frames keep the simulator's
own look, the one the held-out buildings and the flights are rendered with. Mesh worlds (folders
written by ``amslam world import``) add other geometry; their objects of classes the model does
not have (cabinet, tv, bed, …) are background.

A dataset is a compressed ``.npz`` with::

    images     F×H×W×3 uint8   shaded RGB
    instance   F×H×W   int16   instance ids (0 = background), renumbered per frame 1..n
    inst_class F×M     int16   model class index of each instance id of each frame (-1 = unused)
    seeds      F       int64   the building seed each frame came from (-1: a mesh world)
    sources    F               the building of each frame: ``seed N`` or the mesh world's name
    names      C               the model's class names (index = class id)
"""

from __future__ import annotations

import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from amslam.errors import AmslamError
from amslam.geometry import yaw_matrix
from amslam.plugins.sim.camera import CHECKER, NOISE, PLAIN, STRIPES, CameraParams, Look, Renderer
from amslam.plugins.sim.procedural import ProceduralWorldParams, generate_building
from amslam.plugins.sim.world import (
    MeshPart,
    World,
    WorldObject,
    WorldSpec,
    boxes_mesh,
    merge_meshes,
    prism_mesh,
)
from amslam.types import CameraModel

#: The classes the procedural buildings furnish, in the order of the shipped model's class ids.
CLASSES: tuple[str, ...] = ("chair", "table", "shelf", "sofa")
#: The buildings a model is judged on (``evaluate``): no training set renders them.
HELDOUT_SEEDS: tuple[int, ...] = (900, 901, 902, 903)

#: Building footprints and floor counts the seeds cycle through (variety of rooms and depths).
_LAYOUTS: tuple[tuple[tuple[float, float], int], ...] = (
    ((20.0, 14.0), 1),
    ((16.0, 12.0), 1),
    ((24.0, 16.0), 2),
    ((18.0, 14.0), 1),
)

#: The arrays every training set file holds (:meth:`Dataset.save` writes ``sources`` too: files
#: written before it did lack that one).
_ARRAYS = ("images", "instance", "inst_class", "seeds", "names")
#: What reading a damaged ``.npz`` raises: at opening, or only when an array is decompressed.
_UNREADABLE = (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error)


class DatasetError(AmslamError, ValueError):
    """A training set, or a world to render one from, that cannot be used; the message names it."""


@dataclass
class Dataset:
    """Frames and labels in memory (see the module docstring for the layout)."""

    images: np.ndarray
    instance: np.ndarray
    inst_class: np.ndarray
    seeds: np.ndarray
    names: tuple[str, ...]
    #: per frame, the building it came from (``seed N`` or a mesh world's name)
    sources: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.sources is None:
            self.sources = np.array([f"seed {s}" for s in self.seeds.tolist()])

    def __len__(self) -> int:
        return len(self.images)

    def save(self, path: Path) -> None:
        """Write the dataset as a compressed ``.npz`` at ``path`` exactly."""
        path.parent.mkdir(parents=True, exist_ok=True)
        # through a file: given a name, numpy appends ".npz" to one without it, and a cache
        # saved under another name than the one asked for is never found again
        with open(path, "wb") as f:
            np.savez_compressed(
                f,
                images=self.images,
                instance=self.instance,
                inst_class=self.inst_class,
                seeds=self.seeds,
                sources=self.sources,
                names=np.array(self.names),
            )

    @staticmethod
    def load(path: Path) -> Dataset:
        """Read a dataset written by :meth:`save`; :class:`DatasetError` naming the file if it is not one."""
        try:
            archive = np.load(path)
        except ValueError:  # numpy's words for an unknown format are about pickles: unhelpful here
            raise DatasetError(f"{path}: not an .npz file (a training set written by Dataset.save)") from None
        except _UNREADABLE as exc:
            raise DatasetError(f"{path}: not a readable training set ({type(exc).__name__}: {exc})") from None
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise DatasetError(f"{path}: one array, not a training set (an .npz written by Dataset.save)")
        with archive as z:
            missing = [name for name in _ARRAYS if name not in z.files]
            if missing:
                raise DatasetError(f"{path}: not a training set, no {', '.join(missing)} in it")
            try:
                images, instance, inst_class, seeds, names = (z[name] for name in _ARRAYS)
                sources = z["sources"] if "sources" in z.files else None
            except _UNREADABLE as exc:
                raise DatasetError(f"{path}: damaged ({type(exc).__name__}: {exc})") from None
        return Dataset(images, instance, inst_class, seeds, tuple(str(n) for n in names), sources)

    @staticmethod
    def concatenate(parts: list[Dataset]) -> Dataset:
        """One dataset of the frames of ``parts`` (same class names), in order."""
        names = parts[0].names
        if any(d.names != names for d in parts):
            raise ValueError(f"datasets of different classes: {[d.names for d in parts]}")
        m = max(d.inst_class.shape[1] for d in parts)
        table = np.concatenate(
            [
                np.pad(d.inst_class, ((0, 0), (0, m - d.inst_class.shape[1])), constant_values=-1)
                for d in parts
            ]
        )
        return Dataset(
            np.concatenate([d.images for d in parts]),
            np.concatenate([d.instance for d in parts]),
            table,
            np.concatenate([d.seeds for d in parts]),
            names,
            np.concatenate([d.sources for d in parts]),
        )

    def objects(self, i: int, min_pixels: int = 1) -> list[tuple[int, np.ndarray]]:
        """``(class index, boolean mask)`` of every labelled instance of frame ``i``."""
        return labelled_masks(self.instance[i], self.inst_class[i], min_pixels)


def labelled_masks(
    instance: np.ndarray, inst_class: np.ndarray, min_pixels: int = 1
) -> list[tuple[int, np.ndarray]]:
    """``(class index, boolean mask)`` of each labelled instance of one frame, by instance id.

    ``instance``: the frame's instance image (resized or flipped as the caller needs);
    ``inst_class``: its row of :attr:`Dataset.inst_class`. Instances with fewer than
    ``min_pixels`` pixels in ``instance`` are left out.
    """
    out = []
    for iid in range(1, len(inst_class)):
        c = int(inst_class[iid])
        if c < 0:
            continue
        m = instance == iid
        if np.count_nonzero(m) >= min_pixels:
            out.append((c, m))
    return out


def mask_box(mask: np.ndarray) -> np.ndarray:
    """``(x1, y1, x2, y2)`` of a non-empty mask, in pixel edges (float): an instance's box is its mask's."""
    ys, xs = np.nonzero(mask)
    return np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], dtype=float)


def building(seed: int, randomise: bool = False) -> World:
    """The procedural building of a dataset seed (layouts cycle with the seed).

    With ``randomise`` its storey height, room widths, corridor and furniture density are drawn
    from the seed too, each furniture piece is stretched, and clutter of other classes stands
    in its rooms (:func:`_stretch_furniture`, :func:`_add_clutter`).
    """
    size, floors = _LAYOUTS[seed % len(_LAYOUTS)]
    if not randomise:
        params = ProceduralWorldParams(size=size, floors=floors)
        return World(generate_building(params, np.random.default_rng(seed)))
    rng = np.random.default_rng(50_000 + seed)
    narrow = rng.uniform(2.8, 4.5)
    params = ProceduralWorldParams(
        size=size,
        floors=floors,
        floor_height=float(rng.uniform(2.6, 4.0)),
        corridor_width=float(rng.uniform(1.6, 2.8)),
        room_width=(narrow, narrow + rng.uniform(1.0, 3.0)),
        furniture=float(rng.uniform(0.7, 1.6)),
    )
    spec = generate_building(params, np.random.default_rng(seed))
    _stretch_furniture(spec, rng)
    _add_clutter(spec, World(spec), rng)
    return World(spec)


def _default_start(spec: WorldSpec) -> np.ndarray:
    """The world's start at 1.2 m above its floor: a point of the free space to search from."""
    return np.array([*spec.start_xy, spec.start_floor_z + 1.2])


def _floor_below(world: World, z: np.ndarray) -> np.ndarray:
    """Height of the floor each height ``z`` stands on."""
    return np.asarray(world.spec.floor_heights)[world.floor_index(z)]


def _stretch_furniture(spec: WorldSpec, rng: np.random.Generator) -> None:
    """Scale each furniture piece about the middle of its base: 0.8–1.25 across, 0.8–1.2 tall."""
    parts_of = {int(q.instance[0]): q for q in spec.parts if len(q.instance) and q.instance[0] > 0}
    stretched = []
    for o in spec.objects:
        part = parts_of.get(o.instance_id)
        if part is None:
            stretched.append(o)
            continue
        across = rng.uniform(0.8, 1.25)
        gain = np.array(
            [across * rng.uniform(0.92, 1.08), across * rng.uniform(0.92, 1.08), rng.uniform(0.8, 1.2)]
        )
        base = np.array([o.centroid[0], o.centroid[1], o.lo[2]])
        part.vertices = (part.vertices - base) * gain + base
        lo, hi = part.vertices.min(axis=0), part.vertices.max(axis=0)
        stretched.append(WorldObject(o.name, o.class_name, o.instance_id, (lo + hi) / 2.0, lo, hi, None))
    spec.objects[:] = stretched


#: the class of the distractors :func:`_add_clutter` places: not a model class, so background
CLUTTER = "clutter"


def _add_clutter(spec: WorldSpec, world: World, rng: np.random.Generator) -> None:
    """Stand 6–24 pieces of clutter (cabinets, boxes, bins, lamps, screens) on free floor spots.

    They are objects of class :data:`CLUTTER`: background for the model, so that it learns
    that not every box-shaped thing in a room is one of its classes (a real house has
    cabinets, beds, lamps and TVs; the procedural buildings have none).
    """
    pts = world.summary(_default_start(spec)).reachable_points
    floor_z = _floor_below(world, pts[:, 2])
    keep = (world.distance(pts) > 0.7) & (np.linalg.norm(pts[:, :2] - spec.start_xy, axis=1) > 2.0)
    pts, floor_z = pts[keep], floor_z[keep]
    if not len(pts):
        return
    placed: list[np.ndarray] = []
    next_id = 1 + max((o.instance_id for o in spec.objects), default=0)
    for _ in range(int(rng.integers(6, 25))):
        k = int(rng.integers(len(pts)))
        xy, z = pts[k, :2], float(floor_z[k])
        if any(np.linalg.norm(xy - q) < 1.5 for q in placed):
            continue
        kind = rng.integers(4)
        if kind == 0:  # a cabinet or a crate
            w, d, h = rng.uniform(0.3, 1.2), rng.uniform(0.3, 0.6), rng.uniform(0.3, 1.9)
            v, t = boxes_mesh([(np.array([-w / 2, -d / 2, 0.0]), np.array([w / 2, d / 2, h]))])
        elif kind == 1:  # a bin, a pot or a column
            v, t = prism_mesh(rng.uniform(0.1, 0.35), 0.0, rng.uniform(0.3, 1.6), sides=10)
        elif kind == 2:  # a standing lamp
            v, t = merge_meshes(
                [
                    prism_mesh(0.03, 0.0, 1.5, sides=10),
                    prism_mesh(rng.uniform(0.12, 0.25), 1.35, 1.7, sides=10),
                ]
            )
        else:  # a screen or a picture on a low stand
            w, h = rng.uniform(0.5, 1.3), rng.uniform(0.35, 0.8)
            v, t = boxes_mesh(
                [
                    (np.array([-0.2, -0.15, 0.0]), np.array([0.2, 0.15, 0.5])),
                    (np.array([-w / 2, -0.03, 0.5]), np.array([w / 2, 0.03, 0.5 + h])),
                ]
            )
        v = v @ yaw_matrix(rng.uniform(-np.pi, np.pi)).T + np.array([xy[0], xy[1], z])
        colour = rng.uniform(0.15, 0.9, 3)
        name = f"{CLUTTER}_{next_id}"
        spec.parts.append(MeshPart.uniform(name, v, t, next_id, colour))
        lo, hi = v.min(axis=0), v.max(axis=0)
        spec.objects.append(WorldObject(name, CLUTTER, next_id, (lo + hi) / 2.0, lo, hi, None))
        placed.append(xy)
        next_id += 1


def _packaged_classes(objects_file: Path) -> dict[str, str]:
    """``MeshWorldParams.class_map`` giving each object of ``objects_file`` its packaged-map class."""
    from amslam.apps.worlds.classmap import load_class_map
    from amslam.plugins.sim.meshworld import normalize_class, object_entries

    rules = load_class_map()
    out = {}
    for e in object_entries(objects_file):  # PlatformError naming the file if it is not one
        found = rules.classify(str(e.get("class", "")), str(e.get("name", "")))
        if found is not None:
            out[normalize_class(str(e.get("class", "")))] = found[0]
    return out


def mesh_world(folder: Path) -> tuple[World, np.ndarray]:
    """A mesh world written by ``amslam world import`` (``world.ply``, ``objects.json``) and its start.

    Object classes go through the importer's packaged class map (``amslam world class-map``), so
    a world whose objects file keeps Gazebo's model classes (the shared house's
    ``KitchenTable``, ``ShoeRack``) is labelled as an imported one (``table``, ``shelf``).
    The start is the one the simulator would pick (a clear, open spot on the ground floor), at
    flight height: the camera poses are drawn in the free space reachable from there.
    """
    from amslam.interfaces import RunContext
    from amslam.plugins.sim.meshworld import MeshWorldParams
    from amslam.plugins.sim.platform import SimPlatform

    folder = Path(folder)
    if not (folder / "world.ply").is_file():
        raise FileNotFoundError(
            f"mesh world {folder}: no world.ply (a folder written by `amslam world import`)"
        )
    objects = "objects.json" if (folder / "objects.json").is_file() else None
    params = SimPlatform.Params(
        world=MeshWorldParams(
            kind="mesh",
            mesh="world.ply",
            objects=objects,
            class_map=_packaged_classes(folder / objects) if objects else {},
        )
    )
    platform = SimPlatform()
    try:
        platform.configure(
            params, RunContext(rng=np.random.default_rng(0), run_dir=folder, mission_dir=folder)
        )
        platform.start()
        start = platform.ground_truth()[:3, 3] + np.array([0.0, 0.0, 1.0])
        return platform.world, start
    finally:
        platform.close()


def sample_poses(
    world: World,
    n: int,
    rng: np.random.Generator,
    pitch_deg: float = 6.0,
    start: np.ndarray | None = None,
) -> list[np.ndarray]:
    """``n`` camera poses ``T_world_cam`` in the free space of ``world`` reachable from ``start``.

    Positions are reachable cells at least 0.3 m from any geometry and 0.6–2.2 m above their
    floor; 70 % of the headings aim at an object 0.8–5 m away in line of sight, the rest are
    uniform. The camera pitches by up to ``pitch_deg`` either way around the level forward
    mount. ``start``: a point in the free space (default: the world's start, 1.2 m up).
    :class:`DatasetError` if no such position is reachable from ``start``.
    """
    if start is None:
        start = _default_start(world.spec)
    pts = world.summary(start).reachable_points
    above = pts[:, 2] - _floor_below(world, pts[:, 2])
    pts = pts[(above > 0.6) & (above < 2.2)]
    pts = pts[world.distance(pts) > 0.3]
    if len(pts) == 0:
        raise DatasetError(f"world {world.name}: no reachable point at flight height")
    centroids = np.array([o.centroid for o in world.objects]) if world.objects else np.zeros((0, 3))
    poses = []
    for _ in range(n):
        p = pts[rng.integers(len(pts))] + rng.uniform(-0.12, 0.12, 3)
        yaw = rng.uniform(-np.pi, np.pi)
        if len(centroids) and rng.random() < 0.7:
            d = np.linalg.norm(centroids[:, :2] - p[:2], axis=1)
            near = np.flatnonzero((d > 0.8) & (d < 5.0) & (np.abs(centroids[:, 2] - p[2]) < 2.0))
            if len(near):
                # keep only objects in line of sight: the first hit towards the centroid is near it
                c = centroids[near]
                ray = np.column_stack([np.tile(p, (len(c), 1)), c - p]).astype(np.float32)
                t = world.cast_rays(ray)["t_hit"]  # in units of the (unnormalised) direction
                dist = np.linalg.norm(c - p, axis=1)
                seen = np.flatnonzero(t * dist > dist - 0.6)
                if len(seen):
                    c = c[seen[rng.integers(len(seen))]]
                    yaw = float(np.arctan2(c[1] - p[1], c[0] - p[0]) + rng.normal(0.0, 0.35))
        mount = CameraModel.forward_mount(rng.uniform(-pitch_deg, pitch_deg))
        T = np.eye(4)
        T[:3, :3] = yaw_matrix(yaw) @ mount[:3, :3]
        T[:3, 3] = p
        poses.append(T)
    return poses


def _surfaces(world: World) -> np.ndarray:
    """Per triangle, the surface it belongs to: an object's instance id, or for structure
    ``n_instances`` + 0 (walls), 1 (floors: horizontal, within 1 m of a floor), 2 (ceilings)."""
    n_inst = len(world.instance_class)
    group = world.tri_instance.astype(np.int64).copy()
    structure = group == 0
    centres = np.concatenate(
        [
            np.asarray(q.vertices)[np.asarray(q.triangles)].mean(axis=1)[:, 2]
            for q in world.spec.parts
            if len(q.triangles)
        ]
    )
    above = centres - _floor_below(world, centres)
    horizontal = world.tri_abs_nz > 0.9
    group[structure] = n_inst
    group[structure & horizontal & (above < 1.0)] = n_inst + 1
    group[structure & horizontal & (above >= 1.0)] = n_inst + 2
    return group


def _random_colours(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` RGB colours in [0, 1]: any hue, from grey to saturated, dark to light."""
    h = rng.uniform(0.0, 1.0, n)
    sat = rng.uniform(0.0, 0.85, n) ** 1.3
    val = rng.uniform(0.15, 0.95, n)
    k = (np.array([5.0, 3.0, 1.0])[None, :] + 6.0 * h[:, None]) % 6.0
    return val[:, None] * (1.0 - sat[:, None] * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0))


def random_look(world: World, rng: np.random.Generator, surfaces: np.ndarray | None = None) -> Look:
    """A randomised :class:`Look` of ``world`` for one frame (domain randomisation).

    Every surface (each object, the walls, the floors, the ceilings) keeps its own colour with
    probability 0.5 (objects: times a brightness jitter) or gets a random one, and a pattern
    (noise, stripes or checker in a second colour) with probability 0.4; light direction, the
    ambient, main and head lights' shares, falloff, colour cast, exposure and sensor noise are
    drawn too. ``surfaces``: :func:`_surfaces` of the world (computed when not given).
    """
    group = _surfaces(world) if surfaces is None else surfaces
    n_groups = int(group.max()) + 1
    own = rng.random(n_groups) < 0.5
    colours = _random_colours(n_groups, rng)
    albedo = colours[group]
    keep = own[group]
    gain = rng.uniform(0.75, 1.2, n_groups)[group]
    albedo[keep] = np.clip(world.tri_albedo[keep] * gain[keep, None], 0.0, 1.0)
    pattern = np.where(rng.random(n_groups) < 0.4, rng.choice([NOISE, STRIPES, CHECKER], n_groups), PLAIN)
    second = np.where(
        (rng.random(n_groups) < 0.7)[:, None],
        colours * rng.uniform(0.4, 0.85, (n_groups, 1)),
        _random_colours(n_groups, rng),
    )
    objects = np.arange(n_groups) < len(world.instance_class)
    scale = np.where(objects, rng.uniform(0.03, 0.3, n_groups), rng.uniform(0.1, 1.2, n_groups))
    albedo2 = second[group]
    albedo2[keep] = albedo[keep] * rng.uniform(0.45, 0.85)
    sun = np.array([*rng.normal(0.0, 0.6, 2), rng.uniform(0.3, 1.0)])
    stripe = rng.normal(0.0, 1.0, 3)
    return Look(
        albedo=albedo.astype(np.float32),
        pattern=pattern[group].astype(np.uint8),
        albedo2=albedo2.astype(np.float32),
        pattern_scale=scale[group].astype(np.float32),
        stripe_direction=tuple((stripe / np.linalg.norm(stripe)).tolist()),
        sun=tuple((sun / np.linalg.norm(sun)).tolist()),
        ambient=float(rng.uniform(0.1, 0.5)),
        sun_gain=float(rng.uniform(0.1, 0.7)),
        head_gain=float(rng.uniform(0.1, 0.6)),
        falloff=float(rng.uniform(0.0, 0.08)),
        floor_tiles=bool(rng.random() < 0.5),
        tint=tuple(np.clip(1.0 + rng.normal(0.0, 0.08, 3), 0.75, 1.25).tolist()),
        exposure=float(rng.uniform(0.6, 1.4)),
        noise_gain=float(rng.uniform(0.3, 3.0)),
    )


def label_frame(
    world: World, instance: np.ndarray, classes: tuple[str, ...], min_pixels: int
) -> tuple[np.ndarray, list[int]]:
    """A rendered instance image relabelled for the model: ids 1..n and each one's class index.

    Instances of other classes than ``classes`` (clutter, cabinets, beds, …) and instances
    smaller than ``min_pixels`` become background (0). Returns the int16 image and the class
    index of each new id (entry 0, the background, is -1).
    """
    ids, counts = np.unique(instance[instance > 0], return_counts=True)
    relabel = np.zeros(int(instance.max()) + 1, dtype=np.int16)
    labels = [-1]
    for iid, cnt in zip(ids.tolist(), counts.tolist(), strict=True):
        name = world.class_names[int(world.instance_class[iid])]
        if cnt < min_pixels or name not in classes:
            continue
        relabel[iid] = len(labels)
        labels.append(classes.index(name))
    return relabel[instance], labels


#: share of randomised frames that keep the simulator's own look
OWN_LOOK_SHARE = 0.5


def _worlds_to_render(
    seeds: list[int], frames_per_seed: int, mesh_worlds: tuple[Path, ...], mesh_frames: int | None
) -> list[tuple[str, int, int, int]]:
    """``(source, seed, rng stream, frames)`` of each world :func:`render_dataset` renders.

    ``seed`` is -1 for a mesh world, whose source is its folder. ValueError when there is no
    frame to render or a frame count is negative.
    """
    mesh_n = frames_per_seed if mesh_frames is None else mesh_frames
    asked = (
        f"{len(seeds)} buildings × {frames_per_seed} frames, {len(mesh_worlds)} mesh worlds × {mesh_n} frames"
    )
    if min(frames_per_seed, mesh_n) < 0:
        raise ValueError(f"a negative frame count: {asked}")
    if len(seeds) * frames_per_seed + len(mesh_worlds) * mesh_n == 0:
        raise ValueError(f"no frames to render: {asked}")
    worlds = [(f"seed {s}", s, 10_000 + s, frames_per_seed) for s in seeds]
    for k, folder in enumerate(mesh_worlds):
        # a stream of its own per world, apart from the procedural seeds' 10 000+
        worlds.append((str(folder), -1, 70_000 + k, mesh_n))
    return worlds


def render_dataset(
    seeds: list[int],
    frames_per_seed: int,
    *,
    width: int = 320,
    height: int = 240,
    min_pixels: int = 12,
    classes: tuple[str, ...] = CLASSES,
    progress: bool = False,
    randomise: bool = False,
    mesh_worlds: tuple[Path, ...] = (),
    mesh_frames: int | None = None,
) -> Dataset:
    """Render ``frames_per_seed`` labelled frames of each seed's building, and of mesh worlds.

    Args:
        seeds: building seeds; training and held-out sets use disjoint seeds.
        frames_per_seed: frames per building.
        width: image width (the simulator camera's defaults otherwise: D435i-like FOV and noise).
        height: image height.
        min_pixels: visible instances smaller than this are left unlabelled (background).
        classes: the model's classes; objects of other classes are background.
        progress: print one line per building.
        randomise: domain randomisation (module docstring): randomised buildings, and a random
            look in all but :data:`OWN_LOOK_SHARE` of the frames. Off: the simulator's buildings
            and look, as the held-out sets are rendered.
        mesh_worlds: folders written by ``amslam world import`` to render too.
        mesh_frames: frames per mesh world (default ``frames_per_seed``).

    Raises:
        ValueError: no frame to render, or a negative frame count.
        AmslamError: a mesh world that cannot be read (``PlatformError``), a world without a
            reachable point at flight height (:class:`DatasetError`); the message names it.
    """
    worlds = _worlds_to_render(seeds, frames_per_seed, mesh_worlds, mesh_frames)
    cam_params = CameraParams(width=width, height=height)
    camera = cam_params.model()
    renderer = Renderer(camera, cam_params)
    images, instances, inst_classes, frame_seeds, sources = [], [], [], [], []
    max_inst = 1
    for source, seed, stream, n_frames in worlds:
        if seed >= 0:
            world, start, name = building(seed, randomise), None, source
        else:
            world, start = mesh_world(Path(source))
            name = world.name
        rng = np.random.default_rng(stream)
        surfaces = _surfaces(world) if randomise else None
        for T in sample_poses(world, n_frames, rng, start=start):
            look = random_look(world, rng, surfaces) if randomise and rng.random() >= OWN_LOOK_SHARE else None
            r = renderer.render(world, T, rng, look)
            instance, labels = label_frame(world, r.instance, classes, min_pixels)
            images.append(r.rgb)
            instances.append(instance)
            inst_classes.append(labels)
            frame_seeds.append(seed)
            sources.append(name)
            max_inst = max(max_inst, len(labels))
        if progress:
            print(f"{name}: {n_frames} frames, {len(world.objects)} objects", flush=True)
    table = np.full((len(images), max_inst), -1, dtype=np.int16)
    for i, labels in enumerate(inst_classes):
        table[i, : len(labels)] = labels
    return Dataset(
        np.stack(images),
        np.stack(instances),
        table,
        np.asarray(frame_seeds, dtype=np.int64),
        tuple(classes),
        np.asarray(sources),
    )
