"""Training data from the simulator: shaded RGB frames with their instance masks as labels.

Each seed generates one procedural building (:func:`amslam.plugins.sim.procedural.generate_building`);
camera poses are drawn inside its reachable free space (where the robot can fly), at flight
heights, level or slightly pitched like the forward camera of a multicopter. Most poses (70 %)
look towards a furniture piece in line of sight a few metres away, so that objects fill a good
share of the frames; the others look in a random direction, so that the network also sees empty walls,
corridors and doors (its negatives). Labels are the renderer's instance masks: no hand labelling.

A dataset is a compressed ``.npz`` with::

    images     F×H×W×3 uint8   shaded RGB
    instance   F×H×W   int16   instance ids (0 = background), renumbered per frame 1..n
    inst_class F×M     int16   model class index of each instance id of each frame (-1 = unused)
    seeds      F       int64   the building seed each frame came from
    names      C               the model's class names (index = class id)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from amslam.plugins.sim.camera import CameraParams, Renderer
from amslam.plugins.sim.procedural import ProceduralWorldParams, generate_building
from amslam.plugins.sim.world import World

#: The classes the procedural buildings furnish, in the order of the shipped model's class ids.
CLASSES: tuple[str, ...] = ("chair", "table", "shelf", "sofa")

#: Building footprints and floor counts the seeds cycle through (variety of rooms and depths).
_LAYOUTS: tuple[tuple[tuple[float, float], int], ...] = (
    ((20.0, 14.0), 1),
    ((16.0, 12.0), 1),
    ((24.0, 16.0), 2),
    ((18.0, 14.0), 1),
)


@dataclass
class Dataset:
    """Frames and labels in memory (see the module docstring for the layout)."""

    images: np.ndarray
    instance: np.ndarray
    inst_class: np.ndarray
    seeds: np.ndarray
    names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.images)

    def save(self, path: Path) -> None:
        """Write the dataset as a compressed ``.npz``."""
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            path,
            images=self.images,
            instance=self.instance,
            inst_class=self.inst_class,
            seeds=self.seeds,
            names=np.array(self.names),
        )

    @staticmethod
    def load(path: Path) -> Dataset:
        """Read a dataset written by :meth:`save`."""
        with np.load(path) as z:
            return Dataset(
                z["images"], z["instance"], z["inst_class"], z["seeds"], tuple(str(n) for n in z["names"])
            )

    def objects(self, i: int, min_pixels: int = 1) -> list[tuple[int, np.ndarray]]:
        """``(class index, boolean mask)`` of every labelled instance of frame ``i``."""
        out = []
        inst = self.instance[i]
        for iid in range(1, self.inst_class.shape[1]):
            c = int(self.inst_class[i, iid])
            if c < 0:
                continue
            m = inst == iid
            if m.sum() >= min_pixels:
                out.append((c, m))
        return out


def building(seed: int) -> World:
    """The procedural building of a dataset seed (layouts cycle with the seed)."""
    size, floors = _LAYOUTS[seed % len(_LAYOUTS)]
    params = ProceduralWorldParams(size=size, floors=floors)
    return World(generate_building(params, np.random.default_rng(seed)))


def sample_poses(world: World, n: int, rng: np.random.Generator, pitch_deg: float = 6.0) -> list[np.ndarray]:
    """``n`` camera poses ``T_world_cam`` in the reachable free space of ``world``.

    Positions are reachable cells at least 0.3 m from any geometry and 0.6–2.2 m above their
    floor; 70 % of the headings aim at an object 0.8–5 m away in line of sight, the rest are
    uniform. The camera
    pitches by up to ``pitch_deg`` either way around the level forward mount.
    """
    spec = world.spec
    start = np.array([*spec.start_xy, spec.start_floor_z + 1.2])
    pts = world.summary(start).reachable_points
    fh = np.asarray(spec.floor_heights)
    above = pts[:, 2] - fh[world.floor_index(pts[:, 2])]
    pts = pts[(above > 0.6) & (above < 2.2)]
    pts = pts[world.distance(pts) > 0.3]
    if len(pts) == 0:
        raise ValueError(f"world {world.name}: no reachable point at flight height")
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
        pitch = np.radians(rng.uniform(-pitch_deg, pitch_deg))
        # body: level, heading yaw; camera: optical z along body x, pitched down by `pitch`
        cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
        R_wb = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        tilt = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        R_bc = tilt @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        T = np.eye(4)
        T[:3, :3] = R_wb @ R_bc
        T[:3, 3] = p
        poses.append(T)
    return poses


def render_dataset(
    seeds: list[int],
    frames_per_seed: int,
    *,
    width: int = 320,
    height: int = 240,
    min_pixels: int = 12,
    classes: tuple[str, ...] = CLASSES,
    progress: bool = False,
) -> Dataset:
    """Render ``frames_per_seed`` labelled frames of each seed's building.

    Args:
        seeds: building seeds; training and held-out sets use disjoint seeds.
        frames_per_seed: frames per building.
        width: image width (the simulator camera's defaults otherwise: D435i-like FOV and noise).
        height: image height.
        min_pixels: visible instances smaller than this are left unlabelled (background).
        classes: the model's classes; objects of other classes are background.
        progress: print one line per seed.
    """
    cam_params = CameraParams(width=width, height=height)
    camera = cam_params.model()
    renderer = Renderer(camera, cam_params)
    images, instances, inst_classes, frame_seeds = [], [], [], []
    max_inst = 1
    for seed in seeds:
        world = building(seed)
        rng = np.random.default_rng(10_000 + seed)
        class_of = {i: c for i, c in enumerate(world.class_names)}
        for T in sample_poses(world, frames_per_seed, rng):
            r = renderer.render(world, T, rng)
            ids, counts = np.unique(r.instance[r.instance > 0], return_counts=True)
            relabel = np.zeros(int(r.instance.max()) + 1, dtype=np.int16)
            labels = [-1]
            for iid, cnt in zip(ids.tolist(), counts.tolist(), strict=True):
                name = class_of[int(world.instance_class[iid])]
                if cnt < min_pixels or name not in classes:
                    continue
                relabel[iid] = len(labels)
                labels.append(classes.index(name))
            images.append(r.rgb)
            instances.append(relabel[r.instance])
            inst_classes.append(labels)
            frame_seeds.append(seed)
            max_inst = max(max_inst, len(labels))
        if progress:
            print(f"seed {seed}: {frames_per_seed} frames, {len(world.objects)} objects", flush=True)
    table = np.full((len(images), max_inst), -1, dtype=np.int16)
    for i, labels in enumerate(inst_classes):
        table[i, : len(labels)] = labels
    return Dataset(
        np.stack(images), np.stack(instances), table, np.asarray(frame_seeds, dtype=np.int64), tuple(classes)
    )
