"""The ``open3d`` mapping backend: the fast default, log-odds voxels updated by a projective kernel.

The depth-update kernel is *projective* rather than per-ray (:mod:`.projective`): every voxel whose
centre lies in the camera frustum (up to the max ray length) is projected into the image once; it
is crossed by free space when its range is shorter than the range measured at its pixel (or the
pixel has no return within the max length), and it is a hit when a measured point falls inside it
(hits win over misses within a frame, as in OctoMap's ``computeUpdate``). The work is proportional
to the frustum volume, not to pixels × ray length, which is what makes it an order of magnitude
faster than ray casting at 0.1 m, on every pixel of a 640×480 frame. Voxel states agree with the
exact ray-casting reference (the ``numpy`` backend) on ≥ 98 % of the voxels both observe
(tests/plugins/voxel_open3d/test_agreement.py).

Storage: the global map is unbounded, in dense 8³ blocks (:class:`~.blocks.BlockGrid`) indexed by
an Open3D tensor hash map (``open3d.core.HashMap``: block index -> row of the blocks' voxel arrays),
looked up once per block a frame or a query touches; the local map is a dense array over its
window (:class:`WindowGrid`), re-centred by copying the overlap. The kernels that read and write
the voxels are compiled with numba: Open3D has no occupancy update (its ``VoxelBlockGrid``
integrates TSDF only). Before issue #20 every *voxel* was looked up in the hash map, which cost
more than the kernel itself (see docs/benchmarks.md, "Mapping").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np
from pydantic import Field

from amslam.interfaces import BackendParams, RunContext
from amslam.lib.voxel_grid import DenseGrid, LogOddsModel
from amslam.lib.voxel_map import VoxelMapBase, VoxelMapParams
from amslam.types import BoundingBox

# The storages and kernels import numba (0.25 s) and Open3D, which listing plugins or validating a
# mission must not pay: they are imported when a map is made (tests/e2e/test_cli_imports.py).
if TYPE_CHECKING:
    from amslam.plugins.voxel_open3d.blocks import BlockGrid
    from amslam.plugins.voxel_open3d.projective import FrameUpdate


class Open3dVoxelMapParams(VoxelMapParams):
    """Parameters of the ``open3d`` backend: those of the voxel backends plus storage sizing."""

    initial_capacity: int = Field(
        200_000,
        ge=1024,
        le=100_000_000,
        description="Voxels the global map reserves at start, in whole 8³ blocks (it grows as needed;"
        " at most 10⁸: reserved at once).",
    )


class WindowGrid(DenseGrid):
    """The local window: a dense log-odds block that follows the camera (``DenseGrid.shift_to``
    keeps the overlap), updated by the projective kernel, which stamps the voxels it updates
    (``DenseGrid.forget``)."""

    def __init__(self, voxel: float, lo: np.ndarray, shape: tuple[int, int, int], model: LogOddsModel):
        super().__init__(voxel, lo, shape, model)
        self.updated = np.zeros(self.shape, dtype=np.int64)

    def integrate_depth(
        self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, stride: int, max_range: float
    ) -> BoundingBox:
        """Projective frustum update (see the module docstring); return the touched box."""
        from amslam.plugins.voxel_open3d.projective import frustum_update

        return self.integrate_frame(frustum_update(depth, K, T_world_cam, stride, max_range, self.voxel))

    def integrate_frame(self, frame: FrameUpdate) -> BoundingBox:
        """One log-odds update per voxel a frame touched inside the window; return their box."""
        from amslam.plugins.voxel_open3d.projective import fold_into_dense

        stamp = self.next_frame()
        return fold_into_dense(frame, self.value, self.known, self.lo, self.model, self.updated, stamp)


class Open3dVoxelMap(VoxelMapBase):
    """Fast default backend: Open3D-indexed block storage and a dense window, projective frustum
    updates.

    Same interface and semantics as the ``numpy`` reference (shared frontier, viewpoint and path
    code); the global map is unbounded, the local map is a window that follows the camera.
    """

    # imported when built (see Backend.requires): the global map's block index, the kernels
    requires = ("open3d", "numba")

    Params: ClassVar[type[BackendParams]] = Open3dVoxelMapParams

    def configure(self, params: BackendParams, context: RunContext) -> None:
        """Build the maps; compile the kernels (or load them from numba's cache) now, before
        take-off, not at the first frame of a flight."""
        _warm_up()
        super().configure(params, context)

    def _make_storage(
        self, voxel: float, lo: np.ndarray, shape: tuple[int, int, int], local: bool
    ) -> BlockGrid | WindowGrid:
        from amslam.plugins.voxel_open3d.blocks import BlockGrid

        if local:
            return WindowGrid(voxel, lo, shape, self.model)
        cap = self.params.initial_capacity if isinstance(self.params, Open3dVoxelMapParams) else 200_000
        return BlockGrid(voxel, self.model, cap)


def _warm_up() -> None:
    """Compile every kernel of both storages (or load them from numba's cache) and import Open3D:
    one small frame integrated into each, then read back."""
    from amslam.plugins.voxel_open3d.blocks import BlockGrid

    depth = np.full((4, 4), 1.0, dtype=np.float32)
    depth[0, 0] = 0.0  # a no-return pixel
    K = np.array([[2.0, 0.0, 2.0], [0.0, 2.0, 2.0], [0.0, 0.0, 1.0]])
    for grid in (WindowGrid(0.5, np.full(3, -4), (8, 8, 8), LogOddsModel()), BlockGrid(0.5, LogOddsModel())):
        grid.integrate_depth(depth, K, np.eye(4), 1, 2.0)
        grid.dense_states(np.full(3, -4), (8, 8, 8))
        grid.states_at_index(np.zeros((1, 3), np.int64))
        grid.extent()
