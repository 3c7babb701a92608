"""Voxel maps loaded from a dense grid of states, through the backends' public ``load``."""

from __future__ import annotations

import numpy as np

from amslam.lib.voxel_grid import OCCUPIED, UNKNOWN, logit
from amslam.testing.mapping import make_context
from amslam.types import BoundingBox

FREE_L, OCC_L = logit(0.2), logit(0.95)


def _known(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = np.argwhere(states != UNKNOWN)
    return idx, np.where(states[tuple(idx.T)] == OCCUPIED, OCC_L, FREE_L).astype(np.float32)


def _save_global(path, states: np.ndarray, voxel: float, **arrays: np.ndarray) -> None:
    """A saved map (``map.npz``) whose global map holds ``states``, with further ``arrays``."""
    idx, logodds = _known(states)
    np.savez_compressed(
        path,
        format=np.array("amslam-voxels-1"),
        global_index=idx,
        global_logodds=logodds,
        global_voxel=np.array(voxel),
        **arrays,
    )


def load_states(
    mapping_cls,
    tmp_path,
    states: np.ndarray,
    area: BoundingBox,
    voxel: float = 0.25,
    *,
    local: np.ndarray | None = None,
    local_origin: tuple[int, int, int] = (0, 0, 0),
    **params,
):
    """A ``mapping_cls`` configured over ``area`` whose global map holds ``states`` (int8 grid of
    FREE / OCCUPIED / UNKNOWN, index 0 at the origin) and whose local map holds ``local`` (the same,
    at the local voxel size, its index 0 at lattice index ``local_origin``: the local window starts
    centred on the origin; None: empty)."""
    m = mapping_cls()
    m.configure(mapping_cls.Params(**params), make_context(tmp_path, area=area))
    local_idx, local_logodds = (
        _known(local) if local is not None else (np.zeros((0, 3), np.int64), np.zeros(0))
    )
    _save_global(
        tmp_path / "map.npz",
        states,
        voxel,
        local_index=local_idx + np.asarray(local_origin, dtype=np.int64),
        local_logodds=local_logodds.astype(np.float32),
        local_voxel=np.array(m.params.local_voxel),
    )
    m.load(tmp_path / "map.npz")
    return m


def replace_states(mapping, tmp_path, states: np.ndarray) -> None:
    """Put ``states`` into ``mapping``'s global map as a flight's later map, through ``load``: the
    slab history its plans kept goes with it, as it does with a saved map."""
    path = tmp_path / "later.npz"
    _save_global(path, states, mapping.global_map.voxel, global_slab_history=mapping.slab_history())
    mapping.load(path)
