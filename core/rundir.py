"""The run folder: everything a run produces, written as it happens.

Streams (events, trajectories, tree changes) are appended and flushed line by line, so that a
crash or Ctrl-C loses nothing already computed; summaries (metrics, map, plots, report) are
written once at the end — by :meth:`RunDir.finish`, which the runner calls on every exit path.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from amslam.geometry import tum_line

TRAJECTORIES = ("ground_truth", "vio", "slam")


def jsonable(value: Any) -> Any:
    """``value`` with numpy arrays and scalars, enums and non-finite floats made JSON-safe."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "value") and hasattr(value, "name"):  # enums
        return value.value
    return value


class RunDir:
    """One run's folder, ``<root>/<mission>-<timestamp>/``."""

    def __init__(self, root: Path, mission_name: str):
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = Path(root) / f"{mission_name}-{stamp}"
        suffix = 1
        while path.exists():
            suffix += 1
            path = Path(root) / f"{mission_name}-{stamp}-{suffix}"
        path.mkdir(parents=True)
        self.path = path
        self._events = open(path / "events.jsonl", "w")  # noqa: SIM115 — lives as long as the run
        self._tree = open(path / "tree.jsonl", "w")  # noqa: SIM115
        self._tum: dict[str, IO[str]] = {}

    # -- streams ------------------------------------------------------------------------------

    def event(self, t: float, name: str, /, **fields: Any) -> None:
        """Append one event to ``events.jsonl`` (the run's clock ``t`` wins over a field of that name)."""
        record = {"t": round(float(t), 4), "event": name, **{k: v for k, v in fields.items() if k != "t"}}
        self._events.write(json.dumps(jsonable(record)) + "\n")
        self._events.flush()

    def tree_change(self, record: dict[str, Any]) -> None:
        """Append one behaviour-tree change record to ``tree.jsonl``."""
        self._tree.write(json.dumps(jsonable(record)) + "\n")
        self._tree.flush()

    def pose(self, which: str, stamp: float, T: np.ndarray) -> None:
        """Append a pose to ``<which>.tum``."""
        f = self._tum.get(which)
        if f is None:
            f = self._tum[which] = open(self.path / f"{which}.tum", "w")  # noqa: SIM115
        f.write(tum_line(stamp, T))
        f.flush()

    def rewrite_trajectory(self, which: str, stamps: list[float], poses: list[np.ndarray]) -> None:
        """Replace ``<which>.tum`` as a whole (SLAM key poses change when the graph is optimised)."""
        old = self._tum.pop(which, None)
        if old:
            old.close()
        with open(self.path / f"{which}.tum", "w") as f:
            f.writelines(tum_line(t, T) for t, T in zip(stamps, poses, strict=True))

    # -- files ---------------------------------------------------------------------------------

    def write_yaml(self, name: str, data: Any) -> Path:
        path = self.path / name
        path.write_text(yaml.safe_dump(jsonable(data), sort_keys=False))
        return path

    def write_json(self, name: str, data: Any) -> Path:
        path = self.path / name
        path.write_text(json.dumps(jsonable(data), indent=2) + "\n")
        return path

    def write_ply(self, name: str, points: np.ndarray) -> Path:
        """Points as an ASCII PLY (readable by Open3D, MeshLab, CloudCompare)."""
        path = self.path / name
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        properties = "".join(f"property float {axis}\n" for axis in "xyz")
        header = f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n{properties}end_header\n"
        with open(path, "w") as f:
            f.write(header)
            np.savetxt(f, points, fmt="%.3f")
        return path

    def close(self) -> None:
        for f in (self._events, self._tree, *self._tum.values()):
            if not f.closed:
                f.close()
