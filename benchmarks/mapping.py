"""Mapping benchmark: the ``open3d`` backend against OctoMap and the numpy reference on one frame.

Prints, for the same 640×480 depth frame of a furnished room (``amslam.testing.mapping.room_scene``)
at 0.1 m and 0.25 m voxels: ms per frame of the ``open3d`` backend, of OctoMap
(pyoctomap ``OcTree.insertPointCloud``, full rays, same max range) and of the ``numpy`` reference,
the speed-up over OctoMap, and the agreement of voxel states with OctoMap over the voxels both
observed. Each voxel size has two rows (issue #20): *same rays*, every pixel of the frame as
OctoMap gets (stride 1), and *strided*, the default pixel stride of the backends (``auto_stride``:
3 at 0.1 m, 8 at 0.25 m), whose speed comes partly from skipping pixels. Then the local window
(0.1 m, every pixel), and the incremental frontier update after one more frame next to a full
recompute.

Run: ``.venv/bin/python benchmarks/mapping.py`` (needs ``pip install pyoctomap``; benchmark only).
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from amslam.lib.voxel_grid import encode, to_index
from amslam.lib.voxel_map import auto_stride
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.testing.mapping import ROOM_POSE, camera_pose, make_context, render_depth, room_scene
from amslam.types import BoundingBox, CameraModel

CAMERA = CameraModel.from_fov(640, 480, 87.0, 58.0, max_range=5.0)
AREA = BoundingBox(np.array([0.0, 0.0, 0.0]), np.array([20.0, 6.0, 3.0]))
MAX_RANGE = 5.0
REPEATS = 5


def best_ms(fn, repeats: int = REPEATS) -> float:
    """Best wall-clock time of ``fn()`` in ms (each call on a fresh map, built outside the timing)."""
    best = np.inf
    for _ in range(repeats):
        setup = fn()
        t = time.perf_counter()
        setup()
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def backend(cls, voxel: float, stride: int | None = None, **extra):
    """A map of ``cls`` with ``voxel`` global voxels and pixel stride ``stride`` (None: auto) for
    both maps (``extra``: more parameters)."""
    m = cls()
    params = cls.Params(global_voxel=voxel, global_stride=stride, local_stride=stride, **extra)
    m.configure(params, make_context(tempfile.mkdtemp(), camera=CAMERA, area=AREA))
    return m


def octomap_points(depth: np.ndarray, T: np.ndarray) -> np.ndarray:
    """World points of every pixel; no-return pixels become points beyond the max range, which
    OctoMap truncates to free rays of ``max_range`` — the same semantics as amslam's maps."""
    K = CAMERA.K
    v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]]
    d = np.where(depth > 0, depth, 2.0 * MAX_RANGE).astype(np.float64)
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], -1).reshape(-1, 3)
    return cam @ T[:3, :3].T + T[:3, 3]


def octomap_insert(voxel: float, points: np.ndarray, origin: np.ndarray):
    import pyoctomap

    tree = pyoctomap.OcTree(voxel)
    # one frame: hits -> occupied, misses -> free, as in amslam (whose prior starts at p_occ)
    tree.setProbHit(0.7)
    tree.setProbMiss(0.35)
    tree.setOccupancyThres(0.5)
    tree.insertPointCloud(points, origin, max_range=MAX_RANGE)
    return tree


def octomap_states(tree, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Keys and states (0 free, 1 occupied) of the OctoMap leaves, expanded to finest voxels."""
    keys, states = [], []
    for leaf in tree.begin_leafs():
        size = leaf.getSize()
        c = np.asarray(leaf.getCoordinate(), dtype=float)
        occ = 1 if tree.isNodeOccupied(leaf) else 0
        n = max(int(round(size / voxel)), 1)
        offs = (np.arange(n) - (n - 1) / 2.0) * voxel
        g = np.stack(np.meshgrid(offs, offs, offs, indexing="ij"), -1).reshape(-1, 3) + c
        keys.append(encode(to_index(g, voxel)))
        states.append(np.full(len(g), occ, dtype=np.int8))
    return np.concatenate(keys), np.concatenate(states)


def agreement(keys_a, st_a, keys_b, st_b) -> tuple[float, int]:
    _, ia, ib = np.intersect1d(keys_a, keys_b, return_indices=True)
    return float(np.mean(st_a[ia] == st_b[ib])), len(ia)


def main() -> None:
    scene = room_scene()
    depth = render_depth(scene, CAMERA, ROOM_POSE)
    print(
        f"frame: {CAMERA.width}x{CAMERA.height}, {np.mean(depth == 0):.0%} no-return pixels, "
        f"max range {MAX_RANGE} m"
    )
    integration_table(depth)
    local_window(depth)
    numpy_centre_test(depth)
    frontier_update(scene, depth)


def integration_table(depth: np.ndarray) -> None:
    """One frame into the global map: Open3D (every pixel and strided) against OctoMap and the
    numpy reference, time and agreement of the voxel states, at 0.1 and 0.25 m."""
    pts = octomap_points(depth, ROOM_POSE)
    origin = ROOM_POSE[:3, 3].copy()
    try:
        import pyoctomap  # noqa: F401

        have_octomap = True
    except ImportError:
        have_octomap = False
        print("pyoctomap not installed: `pip install pyoctomap` for the OctoMap columns")

    header = (
        f"{'voxel':>6} | {'rays':>17} | {'open3d ms':>9} | {'octomap ms':>10} | {'speed-up':>8} | "
        f"{'agree vs octomap':>16} | {'both seen':>9} | {'numpy ms':>8} | {'agree vs numpy':>14}"
    )
    print(header)
    print("-" * len(header))
    for voxel in (0.1, 0.25):
        t_oct = ok = os_ = None
        if have_octomap:
            t_oct = best_ms(lambda voxel=voxel: lambda: octomap_insert(voxel, pts, origin), repeats=2)
            ok, os_ = octomap_states(octomap_insert(voxel, pts, origin), voxel)
        for stride in (1, None):
            rays = (
                "same (stride 1)" if stride == 1 else f"strided ({auto_stride(CAMERA.K, voxel, MAX_RANGE)})"
            )

            def run_o3d(voxel=voxel, stride=stride):
                m = backend(Open3dVoxelMap, voxel, stride)
                return lambda: m.integrate_global(depth, CAMERA.K, ROOM_POSE)

            def run_np(voxel=voxel, stride=stride):
                m = backend(NumpyVoxelMap, voxel, stride)
                return lambda: m.integrate_global(depth, CAMERA.K, ROOM_POSE)

            t_o3d = best_ms(run_o3d)
            t_np = best_ms(run_np, repeats=1 if stride == 1 else 2)  # 2-3 s a frame on every pixel
            fast, ref = backend(Open3dVoxelMap, voxel, stride), backend(NumpyVoxelMap, voxel, stride)
            fast.integrate_global(depth, CAMERA.K, ROOM_POSE)
            ref.integrate_global(depth, CAMERA.K, ROOM_POSE)
            fi, fs = fast.global_map.voxels()
            ri, rs = ref.global_map.voxels()
            agree_np, _ = agreement(encode(fi), fs, encode(ri), rs)
            if have_octomap:
                agree_oct, both = agreement(encode(fi), fs, ok, os_)
                print(
                    f"{voxel:>6} | {rays:>17} | {t_o3d:>9.1f} | {t_oct:>10.1f} | {t_oct / t_o3d:>7.1f}x | "
                    f"{agree_oct:>16.2%} | {both:>9d} | {t_np:>8.1f} | {agree_np:>14.2%}"
                )
            else:
                print(
                    f"{voxel:>6} | {rays:>17} | {t_o3d:>9.1f} | {'-':>10} | {'-':>8} | {'-':>16} | "
                    f"{'-':>9} | {t_np:>8.1f} | {agree_np:>14.2%}"
                )


def local_window(depth: np.ndarray) -> None:
    """The local window (0.1 m, 10 x 10 x 5 m) on every pixel, as a flight feeds it; with the
    forgetting of voxels no recent frame updated (local_memory_frames, the default) and without."""

    def run_local(memory: int):
        def setup():
            m = backend(Open3dVoxelMap, 0.25, 1, local_memory_frames=memory)
            return lambda: m.integrate_local(depth, CAMERA.K, ROOM_POSE)

        return setup

    forgetting, keeping = best_ms(run_local(300)), best_ms(run_local(0))
    print(
        f"\nlocal window (0.1 m, every pixel, open3d): {forgetting:.1f} ms per frame forgetting stale free"
        f" voxels (local_memory_frames 300), {keeping:.1f} ms keeping them (0): x{forgetting / keeping:.2f}"
    )


def numpy_centre_test(depth: np.ndarray) -> None:
    """The numpy reference's centre test (a crossed voxel is free only where its centre lies in
    front of the measured surface, lib.voxel_grid.centres_in_front) against plain traversal, which
    it replaced in session 44: the test switched off by replacing it for the timing."""
    from amslam.lib import voxel_grid

    def run_numpy(voxel: float):
        m = backend(NumpyVoxelMap, voxel)
        return lambda: m.integrate_global(depth, CAMERA.K, ROOM_POSE)

    centre_test = voxel_grid.centres_in_front
    for voxel in (0.1, 0.25):
        times = {}
        for on in (True, False):
            voxel_grid.centres_in_front = centre_test if on else (lambda index, *_: np.ones(len(index), bool))
            times[on] = best_ms(lambda voxel=voxel: run_numpy(voxel), repeats=3)
        voxel_grid.centres_in_front = centre_test
        print(
            f"numpy reference, {voxel} m strided: {times[True]:.1f} ms with the centre test,"
            f" {times[False]:.1f} ms plain traversal: x{times[True] / times[False]:.2f}"
        )


def frontier_update(scene, depth: np.ndarray) -> None:  # noqa: ANN001
    """Incremental frontier update after one more frame vs a full recompute, 0.25 m global map."""
    second = camera_pose((6.0, 4.5, 1.2), np.radians(-150.0))
    depth2 = render_depth(scene, CAMERA, second)
    inc_ms, full_ms = [], []
    for _ in range(3):
        m = backend(Open3dVoxelMap, 0.25)
        m.integrate_global(depth, CAMERA.K, ROOM_POSE)
        m.viewpoints()
        m.integrate_global(depth2, CAMERA.K, second)
        t = time.perf_counter()
        vps_inc = m.viewpoints()
        inc_ms.append((time.perf_counter() - t) * 1e3)
        frontier_inc = np.sort(m.frontiers.frontier)
        t = time.perf_counter()
        vps_full = m.recompute_frontiers()
        full_ms.append((time.perf_counter() - t) * 1e3)
        same = np.array_equal(frontier_inc, np.sort(m.frontiers.frontier))
    print(
        f"frontiers after one frame (0.25 m, open3d): incremental {min(inc_ms):.0f} ms "
        f"({len(vps_inc)} viewpoints) vs full recompute {min(full_ms):.0f} ms ({len(vps_full)} viewpoints); "
        f"identical frontier voxels: {same}"
    )


if __name__ == "__main__":
    main()
