"""The unknown volume each ray of a viewpoint's fan sees, compiled (:class:`amslam.lib.frontiers`).

Written by hand (with numba) because numpy cannot stop a ray at its first occupied voxel: the
vectorised walk steps every ray of every candidate through every one of its voxels (a loop over
steps, the rays of all candidates at once), most of them behind a wall already, and it was the
largest part of the viewpoints' time in the hall. Here each ray stops where it is blocked; the
float32 sums are taken in the same order as the vectorised walk took them, so the gains are the
same bit for bit (tests/plugins/voxel_numpy/test_frontiers.py).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(nogil=True, cache=True)
def _per_ray(flat, base, off, weights, occupied, unknown, out):  # pragma: no cover — compiled
    steps, rays = off.shape
    for i in range(len(base)):
        b = base[i]
        for r in range(rays):
            seen = np.float32(0.0)
            for m in range(steps):
                state = flat[b + off[m, r]]
                if state == occupied:
                    break
                if state == unknown:
                    seen += weights[m, r]
            out[i, r] = seen


def per_ray(
    flat: np.ndarray, base: np.ndarray, off: np.ndarray, weights: np.ndarray, occupied: int, unknown: int
) -> np.ndarray:
    """P×R float32: for candidates at flat indices ``base`` (P) of the state block ``flat``, the
    sum of each ray's ``weights`` (M×R, float32) over its steps (flat offsets ``off``, M×R) in
    ``unknown`` voxels, up to its first ``occupied`` one."""
    out = np.zeros((len(base), off.shape[1]), np.float32)
    _per_ray(flat, np.asarray(base, np.int64), off, weights, occupied, unknown, out)
    return out


def warm_up() -> None:
    """Compile the kernel (or load it from numba's cache)."""
    per_ray(
        np.zeros(4, np.int8),
        np.zeros(1, np.int64),
        np.zeros((2, 3), np.int64),
        np.ones((2, 3), np.float32),
        1,
        -1,
    )
