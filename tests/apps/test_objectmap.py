"""The compact object-map file: round trip within the documented resolution, shapes, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from amslam.apps.objectmap import (
    ObjectMap,
    cov_decode,
    cov_encode,
    load_objectmap,
    morton_order,
    quat_decode,
    quat_encode,
    save_objectmap,
)
from amslam.types import Landmark


def random_cov(rng: np.random.Generator, n: int) -> np.ndarray:
    A = rng.normal(0, 0.1, (n, 3, 3))
    return A @ A.transpose(0, 2, 1) + np.eye(3) * 1e-3


def landmarks(rng: np.random.Generator, n: int = 300) -> list[Landmark]:
    out = []
    cov = random_cov(rng, n)
    for i in range(n):
        pos = rng.uniform([-200, -200, 0], [200, 200, 3])
        kind = i % 3
        shape = None
        if kind == 1:
            shape = {
                "model": "cuboid",
                "yaw": float(rng.uniform(-np.pi, np.pi)),
                "dims": rng.uniform(1, 5, 3),
            }
        elif kind == 2:
            axis = np.array([*rng.normal(0, 0.1, 2), 1.0])
            shape = {
                "model": "cylinder",
                "axis": axis,
                "radius": float(rng.uniform(0.05, 0.5)),
                "height": 4.0,
            }
        out.append(
            Landmark(
                1000 + 7 * i, ["car", "pole", "tree"][kind], pos, cov[i], int(rng.integers(1, 90)), -1, shape
            )
        )
    return out


def test_round_trip_within_resolution(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    lms = landmarks(rng)
    m = ObjectMap.from_landmarks(lms)
    size = save_objectmap(tmp_path / "m.amom", m, keep_ids=True)
    back = load_objectmap(tmp_path / "m.amom")
    assert len(back) == len(m) and size == (tmp_path / "m.amom").stat().st_size
    by_id = {int(i): k for k, i in enumerate(back.ids)}
    for j, lm in enumerate(lms):
        k = by_id[lm.id]
        assert back.class_names[back.class_id[k]] == lm.class_name
        assert back.model[k] == m.model[j]
        assert np.abs(back.position[k] - m.position[j]).max() <= 0.005 + 1e-9
        assert np.abs(back.dims[k] - m.dims[j]).max() <= 0.005 + 1e-9
        angle = (
            Rotation.from_quat(back.orientation[k]).inv() * Rotation.from_quat(m.orientation[j])
        ).magnitude()
        assert angle < np.radians(0.05)
        s_true = np.sqrt(np.diag(m.covariance[j]))
        s_back = np.sqrt(np.diag(back.covariance[k]))
        np.testing.assert_allclose(s_back, s_true, rtol=0.03)
        assert np.all(np.linalg.eigvalsh(back.covariance[k]) > 0)
        assert back.observations[k] == lm.observations


def test_shapes_survive_as_landmarks(tmp_path: Path) -> None:
    lms = landmarks(np.random.default_rng(2), 30)
    save_objectmap(tmp_path / "m.amom", ObjectMap.from_landmarks(lms), keep_ids=True)
    back = {lm.id: lm for lm in load_objectmap(tmp_path / "m.amom").to_landmarks()}
    for lm in lms:
        got = back[lm.id]
        if lm.shape is None:
            assert got.shape is None
        elif lm.shape["model"] == "cuboid":
            assert got.shape["model"] == "cuboid"
            d = np.angle(np.exp(1j * (got.shape["yaw"] - lm.shape["yaw"])))
            assert abs(d) < 1e-3
            np.testing.assert_allclose(got.shape["dims"], lm.shape["dims"], atol=0.006)
        else:
            axis = lm.shape["axis"] / np.linalg.norm(lm.shape["axis"])
            assert np.dot(got.shape["axis"], axis) > np.cos(1e-3)
            assert got.shape["radius"] == pytest.approx(lm.shape["radius"], abs=0.006)


def test_much_smaller_than_json(tmp_path: Path) -> None:
    lms = landmarks(np.random.default_rng(3), 2000)
    size = save_objectmap(tmp_path / "m.amom", ObjectMap.from_landmarks(lms))
    js = len(
        json.dumps(
            [
                {
                    "id": lm.id,
                    "class": lm.class_name,
                    "position": lm.position.tolist(),
                    "covariance": lm.covariance.tolist(),
                }
                for lm in lms
            ]
        )
    )
    assert size < js / 10
    assert save_objectmap(tmp_path / "d.amom", ObjectMap.from_landmarks(lms), covariance="diagonal") < size
    back = load_objectmap(tmp_path / "d.amom")
    off = back.covariance[:, [0, 0, 1], [1, 2, 2]]
    assert np.all(off == 0)
    save_objectmap(tmp_path / "n.amom", ObjectMap.from_landmarks(lms), covariance="none")
    assert np.all(np.isnan(load_objectmap(tmp_path / "n.amom").covariance))


def test_codecs() -> None:
    rng = np.random.default_rng(4)
    q = Rotation.random(500, random_state=5).as_quat()
    three, big = quat_encode(q)
    back = quat_decode(three, big)
    assert np.all(np.abs(np.abs(np.sum(back * q, axis=1)) - 1) < 1e-8)  # same rotation (q ≡ −q)
    cov = random_cov(rng, 500)
    cov[7] = np.nan  # unknown stays unknown
    dec = cov_decode(*cov_encode(cov))
    assert np.all(np.isnan(dec[7]))
    ok = np.delete(np.arange(500), 7)
    np.testing.assert_allclose(
        np.sqrt(np.diagonal(dec[ok], axis1=1, axis2=2)),
        np.sqrt(np.diagonal(cov[ok], axis1=1, axis2=2)),
        rtol=0.03,
    )
    # Z-order keeps neighbours together: consecutive points are much closer than random pairs
    xy = rng.uniform(0, 100, (2000, 2))
    o = morton_order(xy)
    assert (
        np.linalg.norm(np.diff(xy[o], axis=0), axis=1).mean()
        < 0.2 * np.linalg.norm(np.diff(xy, axis=0), axis=1).mean()
    )


def test_bad_files(tmp_path: Path) -> None:
    (tmp_path / "x.amom").write_bytes(b"NOPE" + bytes(20))
    with pytest.raises(ValueError, match="not an amslam object map"):
        load_objectmap(tmp_path / "x.amom")
    with pytest.raises(ValueError, match="at least one object"):
        save_objectmap(tmp_path / "e.amom", ObjectMap.from_landmarks([]))
