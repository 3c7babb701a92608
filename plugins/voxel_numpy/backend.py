"""The ``numpy`` mapping backend: :class:`~amslam.lib.voxel_map.VoxelMapBase` on
:class:`~amslam.lib.voxel_grid.DenseGrid`, dense arrays bounded by the exploration area, updated by
exact per-ray voxel traversal (free where a crossed voxel's centre lies in front of the measured
surface): the reference the other voxel backends are checked against.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from amslam.interfaces import BackendParams
from amslam.lib.voxel_grid import DenseGrid
from amslam.lib.voxel_map import VoxelMapBase, VoxelMapParams


class NumpyVoxelMap(VoxelMapBase):
    """Reference backend: dense numpy log-odds grids, exact per-ray voxel traversal.

    Simple and obviously correct rather than fast; the ``open3d`` backend is checked against it.
    The global grid covers the exploration area plus ``area_margin``; the local grid is a window of
    ``local_size`` metres that follows the camera.
    """

    Params: ClassVar[type[BackendParams]] = VoxelMapParams

    def _make_storage(
        self, voxel: float, lo: np.ndarray, shape: tuple[int, int, int], local: bool
    ) -> DenseGrid:
        return DenseGrid(voxel, lo, shape, self.model)
