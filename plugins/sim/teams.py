"""Placing a team of simulated robots in one world (paper 2 §V, Figs. 10–11): the ``sim``
platform's answer to "where do N robots take off, and what does each one's mission change?".

The multi-robot experiment (:mod:`amslam.apps.multirobot`) asks the mission's platform backend
for it (``SimPlatform.team_overrides``): the mission keys written here — ``platform.start``,
``platform.world.seed_offset``, ``platform.camera.pitch_deg`` — are this plugin's own parameters,
so they are named only here.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from amslam.mission import load_mission
from amslam.registry import Registry
from amslam.runner import backend_rng, started_platform

Mode = Literal["homogeneous", "heterogeneous"]


def sim_world_seed(seed: int) -> int:
    """The world seed the ``sim`` platform derives from a mission seed (see its ``configure``)."""
    return int(backend_rng(seed, "platform").integers(0, 2**63 - 1, size=3)[0])


def robot_seed(seed: int, k: int) -> int:
    """Mission seed of robot ``k`` of a team flown for experiment seed ``seed``."""
    return seed if k == 0 else seed * 1000 + k


def split_area(lo: np.ndarray, hi: np.ndarray, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` equal strips of the box ``[lo, hi]`` along its longer horizontal side."""
    axis = 0 if hi[0] - lo[0] >= hi[1] - lo[1] else 1
    edges = np.linspace(lo[axis], hi[axis], n + 1)
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        slo, shi = np.array(lo, float), np.array(hi, float)
        slo[axis], shi[axis] = a, b
        out.append((slo, shi))
    return out


def open_spots(platform: Any, lo: np.ndarray, hi: np.ndarray, altitude: float, radius: float) -> np.ndarray:
    """Take-off spots (x, y) in the box on the ground floor, most open first.

    A spot needs the floor right below it and a free column from the ground to ``altitude``
    (clearance above ``radius`` plus a margin); spots are ranked by their clearance.
    """
    world = platform.world
    floor = float(world.spec.floor_heights[0]) if hasattr(world, "spec") else float(lo[2])
    xs = np.arange(lo[0] + 0.5, hi[0] - 0.25, 0.25)
    ys = np.arange(lo[1] + 0.5, hi[1] - 0.25, 0.25)
    if len(xs) == 0 or len(ys) == 0:
        return np.zeros((0, 2))
    g = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    clear = np.full(len(g), np.inf)
    for h in np.linspace(radius + 0.5, altitude, 5):  # the floor itself is not an obstacle
        clear = np.minimum(clear, world.distance(np.column_stack([g, np.full(len(g), floor + h)])))
    below = np.array([world.ground_below(np.array([x, y, floor + 1.0])) for x, y in g])
    ok = (clear > radius + 0.3) & (np.abs(below - floor) < 0.1)
    g, clear = g[ok], clear[ok]
    return g[np.argsort(-clear)]


def overhead_seed(seed: int, j: int = 0) -> int:
    """Mission seed of the ``j``-th overhead robot of a heterogeneous team (the same in every team size)."""
    return seed * 1000 + 100 + j


def lawnmower(
    world: Any,
    lo: np.ndarray,
    hi: np.ndarray,
    base: np.ndarray,
    altitude: float,
    spacing: float,
    clearance: float,
    margin: float = 1.5,
) -> list[list[float]]:
    """Lanes along the longer side of ``[lo, hi]`` at ``altitude``, ``spacing`` apart, clear of obstacles.

    Each lane is moved across (up to half the spacing, in 0.25 m steps) to where the whole lane, and the
    leg to it from the previous point, keep ``clearance`` from every surface (light poles and tree
    trunks reach above the overhead altitude); a lane that finds no such place is left out.
    Returns the waypoints relative to ``base`` (``tree: waypoints``), starting with the climb.
    """
    axis = 0 if hi[0] - lo[0] >= hi[1] - lo[1] else 1
    other = 1 - axis
    a0, a1 = lo[axis] + margin, hi[axis] - margin
    c0, c1 = lo[other] + margin, hi[other] - margin
    n = max(1, int(np.ceil((c1 - c0) / spacing)) + 1)
    offsets = np.linspace(c0, c1, n) if n > 1 else np.array([(c0 + c1) / 2])

    def point(a: float, c: float) -> np.ndarray:
        q = np.zeros(3)
        q[axis], q[other], q[2] = a, c, altitude
        return q

    def clear(p: np.ndarray, q: np.ndarray) -> bool:
        k = max(2, int(np.linalg.norm(q - p) / 0.25) + 1)
        seg = p[None] + np.linspace(0, 1, k)[:, None] * (q - p)[None]
        return bool(np.all(world.distance(seg) > clearance))

    here = np.array([base[0], base[1], altitude])
    pts = [here]
    forward = True
    for c in offsets:
        for shift in [0.0, *[s * d for d in np.arange(0.25, spacing / 2 + 0.01, 0.25) for s in (1, -1)]]:
            ends = (point(a0, c + shift), point(a1, c + shift))
            if not forward:
                ends = ends[::-1]
            if clear(*ends) and clear(pts[-1], ends[0]):
                pts += list(ends)
                forward = not forward
                break
    rel = [
        [round(float(q[0] - base[0]), 2), round(float(q[1] - base[1]), 2), round(float(q[2]), 2)] for q in pts
    ]
    return rel


def team_overrides(
    spec: str,
    registry: Registry,
    n: int,
    mode: Mode,
    seed: int,
    overrides: Sequence[str] = (),
    overhead_altitude: float | None = None,
    overhead_pitch: float = 60.0,
    overhead_spacing: float = 6.0,
    base_spacing: float = 1.0,
    split: bool | None = None,
    scratch: Path = Path("."),
) -> list[list[str]]:
    """The ``--set`` overrides of each robot of a team: seed, world pin, start, area, altitude.

    Homogeneous: ``n`` low-altitude robots, each exploring its own strip of the area. Heterogeneous
    (paper 2 Fig. 10): ``n − 1`` low-altitude robots exactly as a homogeneous team of ``n − 1``
    (same seeds, strips and bases, so each low robot alone is a homogeneous run), plus one
    **overhead** robot (the last; ``n = 1`` is the overhead robot alone). Outdoors (a world
    without a roof) the overhead robot flies a lawnmower (``tree: waypoints``) over the whole
    area at ``overhead_altitude`` with its camera pitched ``overhead_pitch`` down, holding its
    altitude; elsewhere it explores the whole area like a low robot from that altitude.

    Args:
        spec: the mission.
        registry: the plugins.
        n: robots in the team.
        mode: homogeneous (same robots) or heterogeneous (low-altitude robots and an overhead one).
        seed: the experiment seed (robot 1 flies it; the others fly in the same world).
        overrides: applied to every robot first.
        overhead_altitude: the overhead robot's altitude (m); default: twice the mission's altitude,
            at most 1 m below the top of the world's flight volume.
        overhead_pitch: its camera's downward tilt (degrees).
        overhead_spacing: distance between its lawnmower lanes (m).
        base_spacing: smallest distance between two bases (m).
        split: give each low robot its own strip of the area (default: yes).
        scratch: a folder for the throw-away run context of the world look-up.
    """
    if split is None:
        split = True
    base = [*overrides, f"seed={seed}"]
    mission = load_mission(spec, registry, base)
    n_low = n if mode == "homogeneous" else n - 1
    platform = started_platform(mission, registry, scratch)
    try:
        world = platform.world_summary()
        area = mission.model.area
        lo = np.array(area.lo if area else world.bounds_lo, float)
        hi = np.array(area.hi if area else world.bounds_hi, float)
        radius = mission.model.robot.radius
        low_alt = mission.model.robot.altitude
        top = float(world.bounds_hi[2]) - float(world.floor_heights[0])
        high_alt = (
            overhead_altitude if overhead_altitude is not None else round(min(2 * low_alt, top - 1.0), 2)
        )
        boxes = split_area(lo, hi, n_low) if split and n_low > 0 else [(lo, hi)] * n_low
        bases = _low_bases(platform, boxes, low_alt, radius, base_spacing, n)
        overhead_flags: list[str] = []
        if mode == "heterogeneous":
            bases.append(_overhead_base(platform, lo, hi, high_alt, radius, bases, base_spacing))
            overhead_flags = [f"robot.altitude={high_alt}", f"platform.camera.pitch_deg={overhead_pitch}"]
            if getattr(mission.backends["platform"].params.world, "kind", None) == "outdoor":
                overhead_flags += _lawnmower_flags(
                    platform.world, lo, hi, bases[-1], high_alt, overhead_spacing, radius
                )
    finally:
        platform.close()
    teams = []
    for k in range(n):
        overhead = mode == "heterogeneous" and k == n - 1
        flags = _robot_flags(mission, base, seed, k, overhead, bases[k])
        if overhead:
            flags += overhead_flags
        elif split:
            blo, bhi = boxes[k]
            flags.append(f"area={{lo: {np.round(blo, 2).tolist()}, hi: {np.round(bhi, 2).tolist()}}}")
        teams.append(flags)
    return teams


def _lawnmower_flags(
    world: Any,
    lo: np.ndarray,
    hi: np.ndarray,
    base: np.ndarray,
    altitude: float,
    spacing: float,
    radius: float,
) -> list[str]:
    """The overhead robot's flags outdoors: a lawnmower of waypoints over the area from its base,
    lanes ``spacing`` apart, kept ``radius`` + 0.75 m from the world, heading along each lane."""
    wps = lawnmower(world, lo, hi, base, altitude, spacing, radius + 0.75)
    return [
        "tree=waypoints",
        f"waypoints.points={wps}",
        "waypoints.heading=travel",
        "waypoints.tolerance=0.3",
    ]


def _far_enough(spots: np.ndarray, bases: list[np.ndarray], spacing: float) -> list[np.ndarray]:
    """The spots at least ``spacing`` from every base already taken, in their order."""
    return [s for s in spots if all(np.linalg.norm(s - b) >= spacing for b in bases)]


def _low_bases(
    platform: Any,
    boxes: list[tuple[np.ndarray, np.ndarray]],
    altitude: float,
    radius: float,
    spacing: float,
    n: int,
) -> list[np.ndarray]:
    """One take-off spot per low robot, the most open of its box not too close to the others'."""
    bases: list[np.ndarray] = []
    for k, (lo, hi) in enumerate(boxes):
        far = _far_enough(open_spots(platform, lo, hi, altitude, radius), bases, spacing)
        if not far:
            raise ValueError(f"no free base for robot {k + 1} of {n} in {lo[:2]}–{hi[:2]}")
        bases.append(np.asarray(far[0], float))
    return bases


def _overhead_base(
    platform: Any,
    lo: np.ndarray,
    hi: np.ndarray,
    altitude: float,
    radius: float,
    bases: list[np.ndarray],
    spacing: float,
) -> np.ndarray:
    """The overhead robot's take-off spot: the lawnmower starts at the area's low corner, so the
    open spot nearest it (not too close to the low robots' bases)."""
    spots = open_spots(platform, lo, hi, altitude, radius)
    spots = spots[np.argsort(np.linalg.norm(spots - (lo[:2] + 1.5), axis=1), kind="stable")]
    far = _far_enough(spots, bases, spacing)
    if not far:
        raise ValueError(f"no free base for the overhead robot in {lo[:2]}–{hi[:2]}")
    return np.asarray(far[0], float)


def _robot_flags(
    mission: Any, base: list[str], seed: int, k: int, overhead: bool, start: np.ndarray
) -> list[str]:
    """Robot ``k``'s seed, name, world pin and start (what every robot of a team gets)."""
    s = overhead_seed(seed) if overhead else robot_seed(seed, k)
    flags = [*base, f"seed={s}", f"name={mission.name}-{'overhead' if overhead else f'r{k + 1}'}"]
    world_params = mission.backends["platform"].params.world
    if hasattr(world_params, "seed_offset"):  # a generated world: pin it to robot 1's
        pin = sim_world_seed(seed)
        flags.append(f"platform.world.seed_offset={pin - sim_world_seed(s) + world_params.seed_offset}")
    flags.append(f"platform.start=[{start[0]:.2f}, {start[1]:.2f}]")
    return flags
