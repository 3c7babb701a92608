"""Cuboid fitting (paper 2 §IV-A): time of one ``fit_cuboid`` on car views of typical sizes.

The L-shape search scores 201 box orientations per fit (:func:`amslam.lib.shapes._lshape_axes`).
The reference is the same search scoring one orientation at a time (the implementation before the
scores were computed for all orientations at once), measured in the same run on the same clouds;
both must pick the same axes.

    .venv/bin/python benchmarks/shapes.py [--repeats 20]

Prints a Markdown table (figures and ratios; timings depend on the machine).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from amslam.lib import shapes


def one_angle_at_a_time(xy: np.ndarray, percentile: float, d0: float = 0.05) -> np.ndarray:
    """The reference: the closeness of each orientation computed on its own."""

    def closeness(a: float) -> float:
        c, s = np.cos(a), np.sin(a)
        u, v = xy @ np.array([c, s]), xy @ np.array([-s, c])
        (lu, hu), (lv, hv) = shapes._extent(u, percentile), shapes._extent(v, percentile)
        d = np.minimum(np.minimum(np.abs(hu - u), np.abs(u - lu)), np.minimum(np.abs(hv - v), np.abs(v - lv)))
        return float(np.sum(1.0 / np.maximum(d, d0)))

    grid = np.radians(np.arange(0.0, 90.0, 0.5))
    a0 = grid[int(np.argmax([closeness(a) for a in grid]))]
    fine = a0 + np.radians(np.arange(-0.5, 0.5001, 0.05))
    a = float(fine[int(np.argmax([closeness(a) for a in fine]))])
    return np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])


def car_view(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points on the two faces and the top of a 4.5 × 1.8 × 1.5 m car seen from a corner."""
    yaw = rng.uniform(0, np.pi)
    R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    face = rng.integers(0, 3, n)
    p = rng.uniform([-2.25, -0.9, 0.0], [2.25, 0.9, 1.5], (n, 3))
    p[face == 0, 0] = -2.25
    p[face == 1, 1] = -0.9
    p[face == 2, 2] = 1.5
    p[:, :2] = p[:, :2] @ R.T
    return p + rng.normal(0, 0.02, p.shape)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print(f"load average {os.getloadavg()[0]:.1f}\n")
    print("| points | orientations in blocks (ms) | one at a time, reference (ms) | ratio | same axes |")
    print("|---|---|---|---|---|")
    sizes = (24, 200, 1000, 6000)
    clouds = {n: [car_view(n, rng) for _ in range(args.repeats)] for n in sizes}
    for n in sizes:
        t = time.perf_counter()
        new = [shapes._lshape_axes(c[:, :2], 2.5) for c in clouds[n]]
        fast = (time.perf_counter() - t) / args.repeats
        t = time.perf_counter()
        old = [one_angle_at_a_time(c[:, :2], 2.5) for c in clouds[n]]
        slow = (time.perf_counter() - t) / args.repeats
        same = sum(np.allclose(a, b, atol=1e-9) for a, b in zip(new, old, strict=True))
        print(
            f"| {n} | {fast * 1e3:.2f} | {slow * 1e3:.2f} | {slow / fast:.1f}× | {same} of {args.repeats} |"
        )
    # fit_cuboid scores orientations on at most ORIENTATION_POINTS of the cloud (every k-th point)
    k_max = shapes.ORIENTATION_POINTS
    print(
        f"\n| points | search on every k-th point, <= {k_max} (ms) | search on all, reference (ms) | ratio |"
        " max orientation difference (deg) |"
    )
    print("|---|---|---|---|---|")
    for n in sizes:
        stride = -(-n // k_max)
        t = time.perf_counter()
        sub = [shapes._lshape_axes(c[::stride, :2], 2.5) for c in clouds[n]]
        fast = (time.perf_counter() - t) / args.repeats
        t = time.perf_counter()
        full = [shapes._lshape_axes(c[:, :2], 2.5) for c in clouds[n]]
        slow = (time.perf_counter() - t) / args.repeats
        diff = max(_angle_deg(a, b) for a, b in zip(sub, full, strict=True))
        print(f"| {n} | {fast * 1e3:.2f} | {slow * 1e3:.2f} | {slow / fast:.1f}× | {diff:.2f} |")


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two rectangles' first axes, modulo 90° (a rectangle's axes are)."""
    d = np.degrees(np.arctan2(a[0, 1], a[0, 0]) - np.arctan2(b[0, 1], b[0, 0])) % 90.0
    return float(min(d, 90.0 - d))


if __name__ == "__main__":
    main()
