"""Object-map storage: file size and save/load time of the compact format for 1 million objects.

Paper 2 §V: "One million object models take only 9 MB of storage." The map is synthetic and
shaped like the paper's: objects on a 5 m grid (the paper's spacing) over 5 km × 5 km of parking
lots and streets, 60 % vehicles (cuboids, rows facing one way or the other), 20 % light poles and
20 % tree trunks (vertical cylinders), each with a marginal position covariance as a SLAM back end
reports it and an observation count. The reference is the same map as JSON in the format of a run
folder's ``landmarks.json``, measured in the same run.

    .venv/bin/python benchmarks/objectmap.py [--count 1000000] [--json-count 1000000]

Prints a Markdown table (figures and ratios; timings depend on the machine).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from amslam.apps.objectmap import ObjectMap, load_objectmap, save_objectmap

CLASSES = ["light_pole", "tree_trunk", "vehicle"]


def synthetic_map(n: int, rng: np.random.Generator, spacing: float = 5.0) -> ObjectMap:
    """``n`` objects on a ``spacing`` grid (jittered), paper-like classes, shapes and covariances."""
    side = int(np.ceil(np.sqrt(n)))
    gx, gy = np.divmod(np.arange(n), side)
    xy = np.stack([gx, gy], 1) * spacing + rng.normal(0.0, 0.5, (n, 2))
    cls = rng.choice(3, size=n, p=[0.2, 0.2, 0.6])  # light_pole, tree_trunk, vehicle
    vehicle = cls == 2
    z = np.where(vehicle, 0.75, 0.0) + rng.normal(0.0, 0.02, n)  # cuboid centre / cylinder root
    yaw = np.where(rng.random(n) < 0.5, 0.0, np.pi) + rng.normal(0.0, np.radians(5.0), n)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    quat[vehicle] = Rotation.from_euler("z", yaw[vehicle][:, None]).as_quat()
    dims = np.zeros((n, 3))
    dims[vehicle] = np.column_stack(
        [
            rng.normal(4.6, 0.3, vehicle.sum()),
            rng.normal(1.85, 0.1, vehicle.sum()),
            rng.normal(1.5, 0.1, vehicle.sum()),
        ]
    )
    pole, tree = cls == 0, cls == 1
    dims[pole, 0], dims[pole, 1] = rng.normal(0.12, 0.02, pole.sum()), rng.normal(6.0, 0.5, pole.sum())
    dims[tree, 0], dims[tree, 1] = rng.normal(0.2, 0.05, tree.sum()), rng.normal(3.0, 0.8, tree.sum())
    # marginal covariances: σ 2–30 cm per axis with small correlations
    sig = rng.uniform(0.02, 0.3, (n, 3))
    A = rng.normal(0.0, 0.2, (n, 3, 3)) + np.eye(3)
    C = A @ A.transpose(0, 2, 1)
    d = np.sqrt(np.diagonal(C, axis1=1, axis2=2))
    cov = C / d[:, :, None] / d[:, None, :] * sig[:, :, None] * sig[:, None, :]
    return ObjectMap(
        class_names=list(CLASSES),
        class_id=cls.astype(np.int64),
        model=np.where(vehicle, 1, 2).astype(np.int64),
        position=np.column_stack([xy, z]),
        orientation=quat,
        dims=dims,
        covariance=cov,
        observations=rng.poisson(20, n).astype(np.int64),
        ids=np.arange(n, dtype=np.int64),
    )


def json_records(m: ObjectMap) -> list[dict]:
    """The map in ``landmarks.json`` form (what a run folder holds)."""
    recs = []
    for lm in m.to_landmarks():
        rec = {
            "id": lm.id,
            "class": lm.class_name,
            "position": lm.position.tolist(),
            "covariance": lm.covariance.tolist(),
            "observations": lm.observations,
        }
        if lm.shape:
            rec["shape"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in lm.shape.items()}
        recs.append(rec)
    return recs


def timed(fn, repeat: int = 1) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=1_000_000)
    ap.add_argument(
        "--json-count", type=int, default=None, help="objects in the JSON reference (default: --count)"
    )
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    m = synthetic_map(args.count, rng)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        variants = [
            ("none", "full"),
            ("zlib", "full"),
            ("bz2", "full"),
            ("lzma", "full"),
            ("zlib", "diagonal"),
            ("zlib", "none"),
        ]
        for how, cov in variants:
            path = Path(tmp) / f"map-{how}-{cov}.amom"
            t_save, size = timed(
                lambda how=how, cov=cov, path=path: save_objectmap(path, m, compression=how, covariance=cov)
            )
            t_load, back = timed(lambda path=path: load_objectmap(path))
            err = float(np.abs(np.sort(back.position[:, 0]) - np.sort(m.position[:, 0])).max())
            rows.append((f"compact, {how}, covariance {cov}", size, t_save, t_load, err))
        nj = args.json_count or args.count
        mj = m if nj == args.count else synthetic_map(nj, np.random.default_rng(args.seed))
        path = Path(tmp) / "landmarks.json"
        t_save, _ = timed(lambda: path.write_text(json.dumps(json_records(mj))))
        t_load, _ = timed(lambda: json.loads(path.read_text()))
        scale = args.count / nj
        rows.append(
            (
                "JSON (landmarks.json)" + ("" if nj == args.count else f", ×{scale:g}"),
                path.stat().st_size * scale,
                t_save * scale,
                t_load * scale,
                0.0,
            )
        )
    ref = rows[-1][1]
    print(f"Object map of {args.count:,} objects (paper 2: 9 MB for 1 million)\n")
    print(
        "| format | size (MB) | bytes/object | save (s) | load (s) | size vs JSON | max position error (m) |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, size, ts, tl, err in rows:
        print(
            f"| {name} | {size / 1e6:.2f} | {size / args.count:.1f} | {ts:.2f} | {tl:.2f} | "
            f"{size / ref:.3f} | {err:.4f} |"
        )


if __name__ == "__main__":
    main()
