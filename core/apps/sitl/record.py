"""What the SITL vehicle knows and amslam must not: the truth of a flight, in a folder.

``amslam sitl`` writes, into its ``--out`` folder:

* ``ground_truth.tum`` — the true body pose in the **world** frame (the simulator's), at every
  physics step while armed; stamps are seconds since the SITL started;
* ``estimate.tum`` — the pose the vehicle reported over MAVLink (its drifting VIO estimate), in
  the autopilot's **local** frame (ENU, origin at the landed start): amslam's odometry frame;
* ``reachable.npz`` — the world's reachable free cells (what explored % is a share of), their
  cell size, the start (``T_world_local``) and the objects, all in the **local** frame, so a run
  folder of amslam (its map in amslam's world frame, which starts equal to the local one) can be
  judged against them (:func:`judge`);
* ``sitl.json`` — the summary, rewritten when the vehicle lands and when the SITL stops: world,
  start, contacts, closest approach, frames sent, the vehicle's last state, the true distance flown.

Writes happen on the vehicle's thread (``truth``, ``contact``) and the main thread (``summary``),
each under the record's lock.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from amslam.geometry import tum_line
from amslam.lib.voxel_grid import encode, to_index
from amslam.lib.voxel_map import read_saved_map
from amslam.rundir import write_atomically
from amslam.types import WorldSummary


class TruthRecord:
    """The SITL's own record of a flight (see the module docstring)."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._truth = (self.folder / "ground_truth.tum").open("w")
        self._estimate = (self.folder / "estimate.tum").open("w")
        self.contacts: list[dict[str, Any]] = []
        self.distance = 0.0
        self._last: np.ndarray | None = None
        self._samples = 0

    def truth(self, t: float, T_world_body: np.ndarray, T_local_estimate: np.ndarray) -> None:
        with self._lock:
            if self._truth.closed:
                return
            self._truth.write(tum_line(t, T_world_body) + "\n")
            self._estimate.write(tum_line(t, T_local_estimate) + "\n")
            p = T_world_body[:3, 3]
            if self._last is not None:
                self.distance += float(np.linalg.norm(p - self._last))
            self._last = p.copy()
            self._samples += 1
            if self._samples % 50 == 0:  # a killed SITL leaves its trajectory up to the last second
                self._truth.flush()
                self._estimate.flush()

    def contact(self, t: float, reason: str) -> None:
        with self._lock:
            self.contacts.append({"t": round(t, 3), "what": reason})

    def world(self, summary: WorldSummary, T_world_local: np.ndarray) -> None:
        """The world's reachable free cells and objects in the local frame (``reachable.npz``)."""
        offset = T_world_local[:3, 3]
        ids = sorted(summary.object_positions)
        objects = np.array([summary.object_positions[i] for i in ids], float).reshape(-1, 3)
        np.savez(
            self.folder / "reachable.npz",
            reachable_points=np.asarray(summary.reachable_points, float).reshape(-1, 3) - offset,
            reachable_cell=np.float64(summary.reachable_cell),
            T_world_local=np.asarray(T_world_local, float),
            object_ids=np.array(ids, dtype=str),
            object_classes=np.array([summary.object_classes.get(i, "") for i in ids], dtype=str),
            object_positions=objects - offset,
        )

    def summary(self, **fields: Any) -> dict[str, Any]:
        """Write ``sitl.json`` with ``fields`` and the record's own figures; return what was written."""
        with self._lock:
            self._truth.flush()
            self._estimate.flush()
            data = {**fields, "contacts": list(self.contacts), "true_distance_m": round(self.distance, 3)}
        write_atomically(self.folder / "sitl.json", json.dumps(data, indent=2) + "\n")
        return data

    def close(self) -> None:
        with self._lock:
            self._truth.close()
            self._estimate.close()


def judge(sitl_dir: Path, run_dir: Path) -> dict[str, Any]:
    """A flight judged by its truth, with the figures the simulator's report gives a simulated run:
    explored share of amslam's ``map.npz`` over the world's reachable cells (a cell counts when the
    map knows its voxel, free or occupied, as the simulator's report counts it), contacts and
    closest approach, the vehicle's last state, the position error of the estimate (VIO) and of
    amslam's SLAM at touchdown, and the landmarks against the world's objects (the report's
    :func:`~amslam.apps.report.landmark_accuracy`)."""
    from amslam.apps.report import landmark_accuracy
    from amslam.errors import RunFileError
    from amslam.rundir import read_landmarks, read_tum

    sitl_dir, run_dir = Path(sitl_dir), Path(run_dir)
    sitl = json.loads((sitl_dir / "sitl.json").read_text())
    with np.load(sitl_dir / "reachable.npz", allow_pickle=False) as data:
        points = data["reachable_points"]
        T_world_local = data["T_world_local"]
        ids = [str(i) for i in data["object_ids"]]
        classes = [str(c) for c in data["object_classes"]]
        positions = data["object_positions"]
    grid = read_saved_map(run_dir / "map.npz").global_map
    known = np.isin(encode(to_index(points, grid.voxel)), encode(grid.index))
    out = {
        "explored_percent": round(100.0 * float(known.mean()), 2) if len(points) else None,
        "contacts": len(sitl.get("contacts", [])),
        "closest_approach_m": sitl.get("closest_approach_m"),
        "landed": sitl.get("vehicle", {}).get("landed"),
        "armed": sitl.get("vehicle", {}).get("armed"),
        "true_distance_m": sitl.get("true_distance_m"),
    }
    truth = read_tum(sitl_dir / "ground_truth.tum")
    if len(truth):
        # the truth is in the simulator's world frame; the estimate and SLAM in the local one
        end = (np.linalg.inv(T_world_local) @ truth.matrices()[-1])[:3, 3]
        errors: dict[str, Any] = {}
        for name, path in (("vio", sitl_dir / "estimate.tum"), ("slam", run_dir / "slam.tum")):
            try:
                track = read_tum(path) if path.exists() else None
            except RunFileError as exc:  # the other figures stand; the problem is said
                errors.setdefault("problems", []).append(str(exc))
                continue
            if track is not None and len(track):
                errors[f"{name}_position_m"] = round(float(np.linalg.norm(track.poses[-1, :3] - end)), 4)
        out["final_error"] = errors
    if (run_dir / "landmarks.json").exists():
        world = WorldSummary(
            name="sitl",
            bounds_lo=np.zeros(3),
            bounds_hi=np.zeros(3),
            reachable_free_volume=0.0,
            floor_heights=(),
            reachable_free_volume_per_floor=(),
            objects_by_class={},
            object_positions=dict(zip(ids, positions, strict=True)),
            object_classes=dict(zip(ids, classes, strict=True)),
        )
        landmarks = [
            SimpleNamespace(position=np.asarray(r["position"], float), class_name=r["class"])
            for r in read_landmarks(run_dir / "landmarks.json")
        ]
        accuracy = landmark_accuracy(landmarks, world)
        accuracy.pop("by_class", None)
        out["landmarks"] = accuracy
    return out
