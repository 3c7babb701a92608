"""The setpoint filter's guards: CPU time per setpoint on the local map a flight ended with.

Every control tick (10 Hz) sends one setpoint through the height and clearance guards of
:class:`amslam.setpoints.SetpointFilter`. Since session 39 they read the mapping
backend's obstacle rule (``Mapping.blocked``: occupied voxels, the unseen continuation of a seen
slab, and for climbs the unseen rest of a ceiling), which classifies a block of the local map
round the points instead of reading voxel states. The reference, measured in the same run on the
same map and setpoints: the same guards with those rules off (``unseen_surface_reach`` and
``local_ceiling_reach`` 0), which see occupied voxels only, as the guards did before.

    amslam run demo --set seed=7 --out runs/guards      # any flown run folder will do
    .venv/bin/python benchmarks/guards.py runs/guards/demo-*/ [--setpoints 200]

Setpoints: from points of the local map's known free space, a level step (0.8 m) and a climbing
one (0.5 m on, 0.6 m up). Prints a Markdown table (figures and ratios; timings depend on the
machine and its load).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.setpoints import SetpointFilter
from amslam.testing.mapping import make_context
from amslam.types import BoundingBox

STEPS = {"level": np.array([0.8, 0.3, 0.0]), "climbing": np.array([0.5, 0.0, 0.6])}


def loaded(run: Path, **params) -> Open3dVoxelMap:
    """The run's saved maps (global and the local window as the flight ended) in a fresh backend."""
    m = Open3dVoxelMap()
    area = BoundingBox(np.full(3, -50.0), np.full(3, 50.0))
    m.configure(Open3dVoxelMap.Params(**params), make_context(Path(tempfile.mkdtemp()), area=area))
    m.load(run / "map.npz")
    return m


def per_setpoint(guard: SetpointFilter, here: np.ndarray, step: np.ndarray) -> float:
    """Mean CPU seconds of one ``apply`` over the points."""
    for p in here[:5]:  # warm caches
        guard.apply(p + step, p)
    t = time.process_time()
    for p in here:
        guard.apply(p + step, p)
    return (time.process_time() - t) / len(here)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path, help="a run folder holding map.npz")
    ap.add_argument("--setpoints", type=int, default=200)
    args = ap.parse_args(argv)
    if not (args.run / "map.npz").is_file():
        ap.error(f"{args.run}: no map.npz (a run folder of `amslam run` has one)")
    rules = loaded(args.run)
    reference = loaded(args.run, unseen_surface_reach=0.0, local_ceiling_reach=0.0)
    idx, states = rules.local_map.voxels()
    free = idx[states == 0]
    if not len(free):
        ap.error(f"{args.run}: the saved local map holds no free voxel")
    rng = np.random.default_rng(0)
    here = (free[rng.choice(len(free), args.setpoints)] + 0.5) * rules.local_map.voxel
    print(f"{args.run} · {args.setpoints} setpoints · load {os.getloadavg()[0]:.1f}")
    print()
    print("| setpoint | guards (ms CPU) | reference: occupied voxels only (ms CPU) | ratio |")
    print("|---|---:|---:|---:|")
    for name, step in STEPS.items():
        new = per_setpoint(SetpointFilter(rules, 0.25, 0.7, 0.6), here, step)
        old = per_setpoint(SetpointFilter(reference, 0.25, 0.7, 0.6), here, step)
        print(f"| {name} | {1000 * new:.2f} | {1000 * old:.2f} | {new / old:.1f}× |")


if __name__ == "__main__":
    main()
