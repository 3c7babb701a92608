"""OctoMap ``.bt`` files ↔ voxels on amslam's lattice (what ROS 2's ``octomap_server``, RViz's
OctoMap plugin and ``octovis`` read and write).

A ``.bt`` holds a *maximum-likelihood* tree: each leaf is occupied or free, no probabilities
(OctoMap's ``.ot`` keeps log-odds; the ROS tools exchange ``.bt``). So a map goes out as its voxel
states (occupied / free; unknown voxels are absent) and comes back the same way; a backend that
loads one sets its own clamping log-odds for the two states.

Lattice: OctoMap's key of a coordinate ``c`` at resolution ``s`` is ``floor(c / s) + 32768``, so
voxel index ``i`` spans ``[i s, (i + 1) s)`` — amslam's lattice (:func:`amslam.lib.voxel_grid.to_index`).
A tree of another resolution is resampled onto the requested voxel: a leaf covers the voxels whose
centres lie inside it, a leaf smaller than the voxel marks the voxel holding its centre, and where
several leaves meet in one voxel, occupied wins (a wall is never erased by the free space beside it).

pyoctomap is an optional dependency (the ``interop`` extra); it is imported when a file is read
or written, and its absence is an :class:`OctomapFileError` saying what to install.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np

from amslam.errors import AmslamError
from amslam.lib.voxel_grid import decode, encode

#: the first line of every ``.bt`` (OctoMap checks it too, but prints its complaint to stderr)
BT_MAGIC = b"# Octomap OcTree binary file"
INSTALL_HINT = "pip install 'amslam[interop]' (or: pip install pyoctomap)"
#: OctoMap keys are 16-bit: indices must stay within ±32768 voxels of the origin
_KEY_HALF_RANGE = 1 << 15


class OctomapFileError(AmslamError, ValueError):
    """A ``.bt`` that cannot be read or written, or pyoctomap missing; the message names the file."""


def _pyoctomap(path: Path, doing: str):
    try:
        import pyoctomap
    except ImportError:
        raise OctomapFileError(f"{path}: {doing} an OctoMap .bt needs pyoctomap: {INSTALL_HINT}") from None
    return pyoctomap


def write_bt(path: Path, index: np.ndarray, occupied: np.ndarray, voxel: float) -> Path:
    """Write voxels (indices N×3 on the lattice of edge ``voxel``, and whether each is occupied) as
    an OctoMap ``.bt``; OctoMap prunes eight equal children into their parent on the way out."""
    path = Path(path)
    pyoctomap = _pyoctomap(path, "writing")
    index = np.asarray(index, dtype=np.int64).reshape(-1, 3)
    occupied = np.asarray(occupied, dtype=bool).reshape(-1)
    if len(index) and (index.min() < -_KEY_HALF_RANGE or index.max() >= _KEY_HALF_RANGE - 1):
        raise OctomapFileError(f"{path}: the map reaches beyond OctoMap's key range (±32768 voxels)")
    tree = pyoctomap.OcTree(float(voxel))
    centres = (index + 0.5) * float(voxel)
    # one log-odds step far beyond the clamps: each voxel lands on the clamp of its state
    for selected, step in ((~occupied, -100.0), (occupied, 100.0)):
        if selected.any():
            tree.updateNodes(np.ascontiguousarray(centres[selected], dtype=np.float64), step, True)
    tree.updateInnerOccupancy()
    if not path.parent.is_dir():
        raise OctomapFileError(f"{path}: no such folder {path.parent}")
    if not os.access(path.parent, os.W_OK):
        raise OctomapFileError(f"{path}: cannot write in {path.parent}: permission denied")
    # through a temporary file and a rename: a reader never sees half a tree (OctoMap creates it,
    # so it gets the usual permissions of the umask, not mkstemp's owner-only ones)
    tmp = os.fspath(path.with_name(f".{path.name}.{os.getpid()}.tmp"))
    try:
        if not tree.writeBinary(tmp):
            raise OctomapFileError(f"{path}: OctoMap could not write the file")
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
    return path


def read_bt(path: Path, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """The known voxels of an OctoMap ``.bt`` on the lattice of edge ``voxel``: indices (N×3 int64)
    and whether each is occupied (N bool), resampled when the tree's resolution differs."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(BT_MAGIC))
    except OSError as exc:
        raise OctomapFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if head != BT_MAGIC:
        raise OctomapFileError(
            f"{path}: not an OctoMap binary tree (.bt files start with '{BT_MAGIC.decode()}')"
        )
    pyoctomap = _pyoctomap(path, "reading")
    tree = pyoctomap.OcTree(float(voxel))
    if not tree.readBinary(os.fspath(path)):
        raise OctomapFileError(f"{path}: OctoMap could not read this .bt (truncated or not an OcTree)")
    centres, sizes, occupied = [], [], []
    if tree.size() > 0:
        for leaf in tree.begin_leafs():  # the only per-leaf Python loop: ~0.2 s per 45 000 leaves
            centres.append(leaf.getCoordinate())
            sizes.append(leaf.getSize())
            occupied.append(tree.isNodeOccupied(leaf))
    if not sizes:
        return np.zeros((0, 3), np.int64), np.zeros(0, bool)
    index, leaf_of = _cells_of_cubes(np.asarray(centres, float), np.asarray(sizes, float), float(voxel))
    keys = encode(index)
    unique = np.unique(keys)
    # occupied wins: a voxel is occupied if any leaf covering it is
    return decode(unique), np.isin(unique, keys[np.asarray(occupied, bool)[leaf_of]])


def _cells_of_cubes(centres: np.ndarray, sizes: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Lattice indices of the voxels whose centres lie in each cube (centre, edge), and the cube
    each index comes from; a cube smaller than a voxel that holds no voxel centre gives the voxel
    holding its own centre."""
    lo = np.ceil((centres - 0.5 * sizes[:, None]) / voxel - 0.5 - 1e-9).astype(np.int64)
    hi = np.ceil((centres + 0.5 * sizes[:, None]) / voxel - 0.5 - 1e-9).astype(np.int64)  # exclusive
    empty = np.any(hi <= lo, axis=1)
    lo[empty] = np.floor(centres[empty] / voxel).astype(np.int64)
    hi[empty] = lo[empty] + 1
    extent = hi - lo
    cells, owners = [], []
    for n in np.unique(extent.max(axis=1)):  # cubes of one size together: a few groups, not one per leaf
        group = np.nonzero(extent.max(axis=1) == n)[0]
        offsets = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
        inside = np.all(offsets[None, :, :] < extent[group][:, None, :], axis=2)  # G × n³
        leaf, cell = np.nonzero(inside)
        cells.append(lo[group][leaf] + offsets[cell])
        owners.append(group[leaf])
    return np.vstack(cells), np.concatenate(owners)
