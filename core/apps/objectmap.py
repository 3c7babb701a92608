"""A compact binary file for object maps (paper 2 §V: "one million object models take only 9 MB").

An object map is a set of objects, each a class, a model (centroid, cuboid or cylinder, paper 2
§IV-A), a position (centroid, cuboid centre or cylinder root), an orientation (cuboid attitude,
or the rotation taking z to a cylinder's axis), dimensions (cuboid length, width, height;
cylinder radius and height), the 3×3 position covariance and an observation count.

Storage is column-wise, quantised, and compressed column by column:

========================= ================================================ ====================
column                    encoding                                         resolution
========================= ================================================ ====================
class, model              uint8
position                  int, ``position_step`` grid, delta-coded along   1 cm (default)
                          a Morton (Z-order) sort of the objects
orientation               "smallest three" quaternion: 3 × int16 + uint8   12 bits: < 0.05°
dimensions                uint16, ``dims_step`` grid                        1 cm (default)
covariance                σ of x, y, z log-quantised (uint8, 1e-4–100 m)   5.6 % of σ
                          and the 3 correlations as int8 (×127)            1/127
observations              uint16 (saturating)
========================= ================================================ ====================

Integer columns are byte-shuffled (all low bytes, then all high bytes, ...) before compression:
spatially sorted, delta-coded positions are small numbers whose high bytes are almost all 0 or
255, which zlib/LZMA then store for nearly nothing. Objects are stored in Z-order, so loading
returns them in that order, numbered 0..N−1 (the map is a set; ``keep_ids`` stores the ids too).

File layout: ``b"AMOM"``, a format version byte, a little-endian uint32 header length, the JSON
header (count, class names, steps, compression, origin, the column table), then the columns'
compressed bytes in the table's order.
"""

from __future__ import annotations

import bz2
import json
import lzma
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from amslam.types import Landmark

MAGIC = b"AMOM"
VERSION = 1
MODELS = ("centroid", "cuboid", "cylinder")

Compression = Literal["none", "zlib", "bz2", "lzma"]

#: log-σ quantisation of the covariance: 255 steps from SIGMA_MIN to SIGMA_MAX (0 = unknown)
SIGMA_MIN, SIGMA_MAX = 1e-4, 100.0
_LOG_STEP = np.log(SIGMA_MAX / SIGMA_MIN) / 254.0


@dataclass
class ObjectMap:
    """An object map as columns (N objects).

    Attributes:
        class_names: names of the class ids.
        class_id: (N,) index into ``class_names``.
        model: (N,) index into :data:`MODELS`.
        position: (N, 3) centroid, cuboid centre or cylinder root (world frame, m).
        orientation: (N, 4) unit quaternions ``x, y, z, w`` (identity for centroids).
        dims: (N, 3) cuboid length, width, height; cylinder radius, height, 0; centroid 0 (m).
        covariance: (N, 3, 3) position covariance (m²); NaN when unknown.
        observations: (N,) detections of the object.
        ids: (N,) object ids.
    """

    class_names: list[str]
    class_id: np.ndarray
    model: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    dims: np.ndarray
    covariance: np.ndarray
    observations: np.ndarray
    ids: np.ndarray

    def __len__(self) -> int:
        return len(self.class_id)

    @staticmethod
    def from_landmarks(landmarks: Sequence[Landmark]) -> ObjectMap:
        """Columns of a landmark list; a landmark's ``shape`` gives model, orientation and dims.

        Recognised shapes: ``{"model": "cuboid", "dims": [l, w, h]}`` with ``"rotation"`` (3×3)
        or ``"yaw"``, and a ``"center"`` that replaces the position if given;
        ``{"model": "cylinder", "radius", "height"}`` with ``"axis"`` and ``"root"``. Anything
        else is stored as a centroid.
        """
        n = len(landmarks)
        names = sorted({lm.class_name for lm in landmarks})
        index = {c: i for i, c in enumerate(names)}
        m = ObjectMap(
            names,
            np.array([index[lm.class_name] for lm in landmarks], np.int64),
            np.zeros(n, np.int64),
            np.array([lm.position for lm in landmarks], float).reshape(n, 3),
            np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
            np.zeros((n, 3)),
            np.array([np.asarray(lm.covariance, float).reshape(3, 3) for lm in landmarks]).reshape(n, 3, 3),
            np.array([lm.observations for lm in landmarks], np.int64),
            np.array([lm.id for lm in landmarks], np.int64),
        )
        for i, lm in enumerate(landmarks):
            s = lm.shape or {}
            if s.get("model") == "cuboid" and "dims" in s:
                m.model[i] = 1
                m.dims[i] = np.asarray(s["dims"], float)[:3]
                if "rotation" in s:
                    m.orientation[i] = Rotation.from_matrix(np.asarray(s["rotation"], float)).as_quat()
                elif "yaw" in s:
                    m.orientation[i] = Rotation.from_euler("z", float(s["yaw"])).as_quat()
                if "center" in s:
                    m.position[i] = np.asarray(s["center"], float)
            elif s.get("model") == "cylinder" and "radius" in s:
                m.model[i] = 2
                m.dims[i] = [float(s["radius"]), float(s.get("height", 0.0)), 0.0]
                axis = np.asarray(s.get("axis", [0.0, 0.0, 1.0]), float)
                m.orientation[i] = _z_to(axis)
                if "root" in s:
                    m.position[i] = np.asarray(s["root"], float)
        return m

    def to_landmarks(self) -> list[Landmark]:
        """The map as landmarks (shapes in the keys :meth:`from_landmarks` reads)."""
        out = []
        R = Rotation.from_quat(self.orientation).as_matrix()
        for i in range(len(self)):
            shape = None
            if self.model[i] == 1:
                shape = {
                    "model": "cuboid",
                    "center": self.position[i].copy(),
                    "rotation": R[i],
                    "yaw": float(np.arctan2(R[i][1, 0], R[i][0, 0])),
                    "dims": self.dims[i].copy(),
                }
            elif self.model[i] == 2:
                shape = {
                    "model": "cylinder",
                    "root": self.position[i].copy(),
                    "axis": R[i][:, 2].copy(),
                    "radius": float(self.dims[i, 0]),
                    "height": float(self.dims[i, 1]),
                }
            out.append(
                Landmark(
                    int(self.ids[i]),
                    self.class_names[int(self.class_id[i])],
                    self.position[i].copy(),
                    self.covariance[i].copy(),
                    int(self.observations[i]),
                    -1,
                    shape,
                )
            )
        return out


def _z_to(axis: np.ndarray) -> np.ndarray:
    """Quaternion of the smallest rotation taking +z to ``axis``."""
    a = axis / np.linalg.norm(axis)
    v = np.cross([0.0, 0.0, 1.0], a)
    s, c = np.linalg.norm(v), a[2]
    if s < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0]) if c > 0 else np.array([1.0, 0.0, 0.0, 0.0])
    return Rotation.from_rotvec(v / s * np.arctan2(s, c)).as_quat()


# -- quantisation ----------------------------------------------------------------------------


def morton_order(xy: np.ndarray, cell: float = 1.0) -> np.ndarray:
    """Indices sorting 2-D points along a Z-order curve on a ``cell`` grid (neighbours stay close)."""
    q = np.floor((xy - xy.min(axis=0)) / cell).astype(np.uint64)
    q = np.minimum(q, np.uint64(2**32 - 1))

    def spread(v: np.ndarray) -> np.ndarray:  # interleave zeros between the bits of a 32-bit int
        v = v & np.uint64(0xFFFFFFFF)
        for shift, mask in ((16, 0x0000FFFF0000FFFF), (8, 0x00FF00FF00FF00FF), (4, 0x0F0F0F0F0F0F0F0F)):
            v = (v | (v << np.uint64(shift))) & np.uint64(mask)
        v = (v | (v << np.uint64(2))) & np.uint64(0x3333333333333333)
        return (v | (v << np.uint64(1))) & np.uint64(0x5555555555555555)

    return np.argsort(spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)), kind="stable")


def quat_encode(q: np.ndarray, bits: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """The "smallest three" code: drop the largest |component| (made positive), keep 3 as int16.

    ``bits`` < 16 rounds the int16 values to multiples of ``2**(16 - bits)`` (fewer distinct
    values compress better).
    """
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    big = np.argmax(np.abs(q), axis=1)
    q = q * np.where(q[np.arange(len(q)), big] < 0, -1.0, 1.0)[:, None]
    keep = np.array([[j for j in range(4) if j != b] for b in range(4)])[big]
    three = np.take_along_axis(q, keep, axis=1)  # each within ±1/√2
    step = 2 ** (16 - min(max(bits, 4), 16))
    coded = np.round(three * np.sqrt(2.0) * 32767 / step) * step
    return np.clip(coded, -32767, 32767).astype(np.int16), big.astype(np.uint8)


def quat_decode(three: np.ndarray, big: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quat_encode`."""
    t = three.astype(float) / (np.sqrt(2.0) * 32767)
    w = np.sqrt(np.clip(1.0 - (t**2).sum(axis=1), 0.0, 1.0))
    q = np.empty((len(t), 4))
    keep = np.array([[j for j in range(4) if j != b] for b in range(4)])[big.astype(int)]
    np.put_along_axis(q, keep, t, axis=1)
    q[np.arange(len(t)), big.astype(int)] = w
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def cov_encode(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """σ (N×3, uint8 log scale; 0 = unknown) and correlations xy, xz, yz (N×3, int8 × 127)."""
    cov = np.asarray(cov, float).reshape(-1, 3, 3)
    var = np.diagonal(cov, axis1=1, axis2=2)
    ok = np.all(np.isfinite(cov.reshape(len(cov), -1)), axis=1) & np.all(var > 0, axis=1)
    sig = np.sqrt(np.where(ok[:, None], var, 1.0))
    code = np.clip(np.round(np.log(np.clip(sig, SIGMA_MIN, SIGMA_MAX) / SIGMA_MIN) / _LOG_STEP), 0, 254) + 1
    code[~ok] = 0
    rho = np.stack(
        [
            cov[:, 0, 1] / (sig[:, 0] * sig[:, 1]),
            cov[:, 0, 2] / (sig[:, 0] * sig[:, 2]),
            cov[:, 1, 2] / (sig[:, 1] * sig[:, 2]),
        ],
        axis=1,
    )
    rho = np.where(ok[:, None], np.nan_to_num(rho), 0.0)
    return code.astype(np.uint8), np.round(np.clip(rho, -1, 1) * 127).astype(np.int8)


def cov_decode(code: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Inverse of :func:`cov_encode`; a non-positive-definite result is clipped to PD."""
    sig = SIGMA_MIN * np.exp((code.astype(float) - 1) * _LOG_STEP)
    r = rho.astype(float) / 127.0
    C = np.repeat(np.eye(3)[None], len(code), axis=0)
    C[:, 0, 1] = C[:, 1, 0] = r[:, 0]
    C[:, 0, 2] = C[:, 2, 0] = r[:, 1]
    C[:, 1, 2] = C[:, 2, 1] = r[:, 2]
    a, b, c = r[:, 0], r[:, 1], r[:, 2]
    det = 1.0 + 2.0 * a * b * c - a * a - b * b - c * c  # Sylvester: PD iff 1 − a² > 0 and det > 0
    bad = (1.0 - a * a < 1e-6) | (det < 1e-6)  # quantised correlations of a near-degenerate covariance
    if bad.any():
        w, V = np.linalg.eigh(C[bad])
        C[bad] = np.einsum("nij,nj,nkj->nik", V, np.maximum(w, 1e-3), V)
    cov = C * sig[:, :, None] * sig[:, None, :]
    cov[np.any(code == 0, axis=1)] = np.nan
    return cov


# -- columns and compression -----------------------------------------------------------------


def _shuffle(a: np.ndarray) -> bytes:
    """Byte planes of a little-endian integer array: all first bytes, then all second bytes..."""
    a = np.ascontiguousarray(a)
    b = a.view(np.uint8).reshape(-1, a.dtype.itemsize)
    return b.T.tobytes()


def _unshuffle(data: bytes, dtype: np.dtype, shape: tuple[int, ...]) -> np.ndarray:
    dtype = np.dtype(dtype)
    b = np.frombuffer(data, np.uint8).reshape(dtype.itemsize, -1).T
    return np.ascontiguousarray(b).view(dtype).reshape(shape)


def _compress(data: bytes, how: Compression) -> bytes:
    if how == "zlib":
        return zlib.compress(data, 6)
    if how == "bz2":
        return bz2.compress(data, 9)
    if how == "lzma":
        return lzma.compress(data, preset=3)
    return data


def _decompress(data: bytes, how: Compression) -> bytes:
    if how == "zlib":
        return zlib.decompress(data)
    if how == "bz2":
        return bz2.decompress(data)
    if how == "lzma":
        return lzma.decompress(data)
    return data


def _smallest_int(a: np.ndarray) -> np.ndarray:
    for dt in (np.int8, np.int16, np.int32):
        info = np.iinfo(dt)
        if a.size == 0 or (a.min() >= info.min and a.max() <= info.max):
            return a.astype(dt)
    return a.astype(np.int64)


def save_objectmap(
    path: Path,
    objects: ObjectMap,
    *,
    compression: Compression = "zlib",
    position_step: float = 0.01,
    dims_step: float = 0.01,
    orientation_bits: int = 12,
    covariance: Literal["full", "diagonal", "none"] = "full",
    keep_ids: bool = False,
) -> int:
    """Write an object map; returns the file size in bytes.

    Args:
        path: the file to write.
        objects: the map.
        compression: per-column compressor.
        position_step: position resolution (m).
        dims_step: dimension resolution (m).
        orientation_bits: bits kept of each stored quaternion component (≤ 16); 12 bits is an
            angle error below 0.05°.
        covariance: store σ and correlations ("full"), σ only ("diagonal"), or nothing.
        keep_ids: also store the objects' ids (otherwise they are renumbered on load).
    """
    n = len(objects)
    if len(objects.class_names) > 256:
        raise ValueError(f"at most 256 classes, got {len(objects.class_names)}")
    if n == 0:
        raise ValueError("an object map needs at least one object")
    order = morton_order(objects.position[:, :2])
    pos = objects.position[order]
    origin = pos.min(axis=0)
    qpos = np.round((pos - origin) / position_step).astype(np.int64)
    dpos = np.diff(qpos, axis=0, prepend=np.zeros((1, 3), np.int64))
    three, big = quat_encode(objects.orientation[order], orientation_bits)
    sig, rho = cov_encode(objects.covariance[order])
    dims = np.round(np.clip(objects.dims[order], 0, None) / dims_step)
    if dims.size and dims.max() > 65535:
        raise ValueError(f"a dimension exceeds {65535 * dims_step:.0f} m at dims_step {dims_step}")
    columns: dict[str, np.ndarray] = {
        "class_id": objects.class_id[order].astype(np.uint8),
        "model": objects.model[order].astype(np.uint8),
        "position": _smallest_int(dpos.T.copy()),  # x deltas, then y, then z
        "quat_three": three.T.copy(),
        "quat_big": big,
        "dims": dims.astype(np.uint16).T.copy(),
        "sigma": sig.T.copy(),
        "rho": rho.T.copy(),
        "observations": np.clip(objects.observations[order], 0, 65535).astype(np.uint16),
    }
    if covariance != "full":
        del columns["rho"]
    if covariance == "none":
        del columns["sigma"]
    if keep_ids:
        columns["ids"] = _smallest_int(np.diff(objects.ids[order].astype(np.int64), prepend=0))
    blobs, table = [], []
    for name, arr in columns.items():
        blob = _compress(_shuffle(arr), compression)
        blobs.append(blob)
        table.append({"name": name, "dtype": arr.dtype.str, "shape": list(arr.shape), "bytes": len(blob)})
    header = json.dumps(
        {
            "count": n,
            "class_names": objects.class_names,
            "models": list(MODELS),
            "compression": compression,
            "position_step": position_step,
            "dims_step": dims_step,
            "origin": origin.tolist(),
            "columns": table,
        },
        separators=(",", ":"),
    ).encode()
    with open(path, "wb") as f:
        f.write(MAGIC + struct.pack("<BI", VERSION, len(header)) + header)
        for blob in blobs:
            f.write(blob)
    return Path(path).stat().st_size


def load_objectmap(path: Path) -> ObjectMap:
    """Read a file written by :func:`save_objectmap`.

    Raises:
        ValueError: not an object map file, or a newer format version.
    """
    data = Path(path).read_bytes()
    if data[:4] != MAGIC:
        raise ValueError(f"{path}: not an amslam object map (bad magic)")
    version, hlen = struct.unpack("<BI", data[4:9])
    if version > VERSION:
        raise ValueError(f"{path}: object map format {version} is newer than this amslam reads ({VERSION})")
    header = json.loads(data[9 : 9 + hlen])
    how = header["compression"]
    cols: dict[str, np.ndarray] = {}
    at = 9 + hlen
    for c in header["columns"]:
        raw = _decompress(data[at : at + c["bytes"]], how)
        cols[c["name"]] = _unshuffle(raw, np.dtype(c["dtype"]), tuple(c["shape"]))
        at += c["bytes"]
    n = header["count"]
    qpos = np.cumsum(cols["position"].T.astype(np.int64), axis=0)
    ids = np.cumsum(cols["ids"].astype(np.int64)) if "ids" in cols else np.arange(n, dtype=np.int64)
    return ObjectMap(
        class_names=list(header["class_names"]),
        class_id=cols["class_id"].astype(np.int64),
        model=cols["model"].astype(np.int64),
        position=qpos * header["position_step"] + np.asarray(header["origin"]),
        orientation=quat_decode(cols["quat_three"].T, cols["quat_big"]),
        dims=cols["dims"].T.astype(float) * header["dims_step"],
        covariance=cov_decode(cols["sigma"].T, cols["rho"].T if "rho" in cols else np.zeros((n, 3), np.int8))
        if "sigma" in cols
        else np.full((n, 3, 3), np.nan),
        observations=cols["observations"].astype(np.int64),
        ids=ids,
    )
