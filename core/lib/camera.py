"""Pinhole camera geometry shared by detectors and tools: pixels with depth back to 3-D points."""

from __future__ import annotations

import numpy as np


def backproject(mask: np.ndarray, depth: np.ndarray, Kinv: np.ndarray) -> np.ndarray:
    """Camera-frame points (N×3) of the masked depth pixels (``Kinv``: the inverse intrinsics)."""
    v, u = np.nonzero(mask)
    z = depth[v, u].astype(np.float64)
    pix = np.stack([u, v, np.ones_like(u)], axis=1).astype(np.float64)
    return (pix @ Kinv.T) * z[:, None]
