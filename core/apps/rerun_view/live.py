"""The live view: a run observer that streams a flight into rerun as it happens.

``amslam run MISSION --rerun`` registers one :class:`LiveRerun` in the run's plugin manager (an
in-process plugin, as ``build_plugin_manager(extra_plugins=...)`` documents for applications that
embed amslam), so it observes that run only and costs nothing to runs that did not ask for it.

What it logs comes from the run hooks and from the run folder's streams, which the runner flushes
line by line: ``amslam_tick`` gives the time and the mapping backend, whose occupied voxels are
logged every ``map_period`` s; the poses, the events and the tree's changes are tailed from
``*.tum``, ``events.jsonl`` and ``tree.jsonl`` every ``period`` seconds of the run's clock;
``amslam_keyframe``, ``amslam_replan`` and ``amslam_loop_closure`` give key poses, tours and loop
closures as they happen; ``amslam_run_end`` the final map and the landmarks. The camera's depth
and RGB images and the detections are in no hook, so they are not shown.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import amslam
from amslam.apps.rerun_view.replay import StreamTail, landmarks_of, log_events, log_tree, read_map
from amslam.apps.rerun_view.scene import SOURCES, Scene, parse_tum
from amslam.apps.rerun_view.sink import open_recording
from amslam.rundir import landmark_records


class LiveRerun:
    """Streams one run into rerun: a viewer, or an ``.rrd`` file (``rrd``: see :func:`open_recording`)."""

    def __init__(
        self,
        rrd: str | None = None,
        *,
        announce: Callable[[str], None] = print,
        period: float = 0.5,
        path_period: float = 5.0,
        map_period: float = 10.0,
        recording: Any = None,
    ):
        self.rrd = rrd
        self.announce = announce
        self.period = period  # s of the run's clock between two reads of the streams
        self.path_period = path_period  # s between two redraws of the whole paths (each costs all points)
        self.map_period = map_period  # s between two copies of the global map's occupied voxels
        self.recording = recording  # a stream opened by the caller (tests: an in-memory one)
        self.scene: Scene | None = None
        self.paths: dict[str, list[np.ndarray]] = {s: [] for s in SOURCES}
        self.keyposes: list[np.ndarray] = []
        self.names: dict[int, str] = {}
        self.last_poll = -np.inf
        self.last_path = -np.inf
        self.last_map = -np.inf

    @amslam.hookimpl
    def amslam_run_start(self, run_dir: Path) -> None:
        rec = self.recording
        if rec is None:
            rec, where = open_recording(run_dir, self.rrd)
            self.announce(where)
            self.recording = rec
        self.scene = Scene(rec)
        self.tail = StreamTail(run_dir)

    @amslam.hookimpl
    def amslam_tick(self, t: float, mapping) -> None:
        if self.scene is None:
            return
        if t - self.last_poll >= self.period:
            self._poll(t)
        if mapping is not None and t - self.last_map >= self.map_period:  # the map as it grows
            self.last_map = t
            self.scene.at(t)
            self.scene.map(np.asarray(mapping.occupied_points(), float), mapping.voxel_size(), static=False)

    def _poll(self, t: float) -> None:
        scene = self.scene
        self.last_poll = t
        log_events(scene, self.tail.records("events"), tours=False)
        log_tree(scene, self.names, self.tail.records("tree"))
        for source in SOURCES:
            rows = parse_tum(self.tail.lines(source))
            scene.poses(source, rows)
            if len(rows):
                self.paths[source].append(rows[:, 1:4])
        if t - self.last_path >= self.path_period:
            self.last_path = t
            scene.at(t)
            for source, parts in self.paths.items():
                if parts:
                    scene.path(source, np.concatenate(parts), static=False)

    @amslam.hookimpl
    def amslam_keyframe(self, t: float, keypose) -> None:
        if self.scene is not None:
            self.keyposes.append(np.asarray(keypose.T_world_body, float)[:3, 3])
            self.scene.at(t)
            self.scene.keyposes(np.asarray(self.keyposes))

    @amslam.hookimpl
    def amslam_replan(self, t: float, tour) -> None:
        if self.scene is not None:
            self.scene.at(t)
            self.scene.tour([(item.kind.value, np.asarray(item.position, float)) for item in tour])

    @amslam.hookimpl
    def amslam_loop_closure(self, t: float, result) -> None:
        if self.scene is not None:
            self.scene.at(t)
            self.scene.loop_closure(result.accepted, result.reason, result.matched)

    @amslam.hookimpl(trylast=True)  # after the report: slam.tum holds the optimised key poses
    def amslam_run_end(self, run_dir: Path, summary) -> None:
        if self.scene is None:
            return
        scene = self.scene
        self._poll(self.last_poll)
        for source in SOURCES:  # the whole paths as flown (slam: as optimised), static like a replay's
            scene.path(source, parse_tum(StreamTail(run_dir).lines(source))[:, 1:4], static=True)
        points, voxel, classes = read_map(Path(run_dir))  # the report's map.ply has the classes
        mapping = summary.mapping
        if len(points) == 0 and mapping is not None:  # no report: the mapping backend's voxels
            points, voxel, classes = np.asarray(mapping.occupied_points(), float), mapping.voxel_size(), None
        scene.at(self.last_poll)  # timed like the growing map (a static one would hide it at every time)
        scene.map(points, voxel, classes, static=False)
        landmarks = landmark_records(summary.landmarks or []) or landmarks_of(Path(run_dir))
        scene.landmarks(landmarks)
        self.recording.flush()
