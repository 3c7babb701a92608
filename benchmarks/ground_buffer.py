"""The ground buffer of the shape landmarks: time to fit an object's local ground plane.

Each cuboid or cylinder measurement fits the ground plane within ``ground_radius`` of the object
to the ground points of the last ``ground_window`` seconds. The reference is the buffer before
session 53: each frame's points thinned to one per voxel within that frame only, concatenated
at every fit, so a patch of ground seen in 50 frames was fitted 50 times over. The buffer now
keeps one point per voxel across frames (:class:`GroundBuffer`). A synthetic PAMS flight: 1 m/s
over a flat lot at 5 Hz, 1500 ground points a frame on the camera's 6 × 5 m footprint ahead
(1 cm height noise), three object fits a frame; both fit the same planes (printed: the largest
angle between their normals and height difference under the object).

    .venv/bin/python benchmarks/ground_buffer.py [--frames 400]

Prints a Markdown table (timings depend on the machine; trust the ratio).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from amslam.lib import shapes
from amslam.plugins.gtsam_slam.params import ShapeParams
from amslam.plugins.gtsam_slam.shape_landmarks import GroundBuffer

#: the reference's voxel (the default before session 53), the window, the fit's radius, frame rate
VOXEL, WINDOW, RADIUS, RATE = 0.04, 60.0, 4.0, 5.0


class PerFrameBuffer:
    """The reference: each frame thinned on its own, all frames concatenated at each fit."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, np.ndarray]] = []

    def add(self, stamp: float, points: np.ndarray) -> None:
        _, idx = np.unique(np.floor(points / VOXEL).astype(np.int64), axis=0, return_index=True)
        self.frames = [(t, g) for t, g in [*self.frames, (stamp, points[idx])] if stamp - t <= WINDOW]

    def near(self, centre: np.ndarray) -> shapes.GroundPlane | None:
        return shapes.local_ground(np.concatenate([g for _, g in self.frames]), centre, RADIUS)


def frame(t: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The ground points seen at time t, and three object centres in the footprint."""
    x = t * 1.0  # 1 m/s along x
    p = np.column_stack(
        [rng.uniform(x + 1.0, x + 7.0, 1500), rng.uniform(-2.5, 2.5, 1500), rng.normal(0, 0.01, 1500)]
    )
    objects = np.column_stack([np.full(3, x + 4.0), [-2.0, 0.0, 2.0], np.full(3, 0.75)])
    return p, objects


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=400, help="frames flown (the last 100 are timed)")
    ap.add_argument(
        "--voxel", type=float, default=ShapeParams().voxel, help="the buffer's voxel (default: the default's)"
    )
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    new, old = GroundBuffer(args.voxel, WINDOW), PerFrameBuffer()
    timed = {"new": 0.0, "old": 0.0}
    angle = height = 0.0
    sizes = (0, 0)
    for k in range(args.frames):
        t = k / RATE
        points, objects = frame(t, rng)
        for name, buffer in (("new", new), ("old", old)):
            start = time.perf_counter()
            buffer.add(t, points)
            planes = [
                shapes.local_ground(buffer.points, c, RADIUS) if name == "new" else buffer.near(c)
                for c in objects
            ]
            if k >= args.frames - 100:
                timed[name] += time.perf_counter() - start
            if name == "new":
                fresh = planes
            else:
                for a, b, c in zip(fresh, planes, objects, strict=True):
                    angle = max(angle, float(np.degrees(np.arccos(min(1.0, abs(a.normal @ b.normal))))))
                    height = max(height, abs(a.height(c[None])[0] - b.height(c[None])[0]))
        sizes = (len(new), sum(len(g) for _, g in old.frames))
    per_new, per_old = 1e3 * timed["new"] / 100, 1e3 * timed["old"] / 100
    print(f"load average {os.getloadavg()[0]:.1f} · {args.frames} frames, the last 100 timed\n")
    print("| buffer | points held | ms per frame (add + 3 fits) | ratio to reference |")
    print("|---|---|---|---|")
    ratio = per_new / per_old
    print(
        f"| one point per {args.voxel:g} m voxel across frames | {sizes[0]} | {per_new:.2f} | {ratio:.3f} |"
    )
    print(f"| one per {VOXEL:g} m voxel per frame (reference) | {sizes[1]} | {per_old:.2f} | 1 |")
    print(f"\nlargest difference of the fitted planes: {angle:.3f}° between normals,", end=" ")
    print(f"{100 * height:.2f} cm in height")


if __name__ == "__main__":
    main()
