"""The run folder: summaries written atomically, folder names that never collide."""

from __future__ import annotations

import errno
import json
import multiprocessing
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from amslam import rundir as rundir_module
from amslam.rundir import RunDir, RunFiles, write_atomically


def test_a_failed_write_leaves_the_previous_file_and_no_temporary(tmp_path: Path, monkeypatch):
    run = RunDir(tmp_path, "m")
    run.write_json("metrics.json", {"verdict": "completed"})

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(rundir_module.os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space left"):
        run.write_json("metrics.json", {"verdict": "failed: overwritten"})
    assert json.loads((run.path / "metrics.json").read_text()) == {"verdict": "completed"}
    assert sorted(p.name for p in run.path.iterdir()) == ["events.jsonl", "metrics.json", "tree.jsonl"]


def test_a_failed_first_write_leaves_no_file_at_all(tmp_path: Path, monkeypatch):
    def killed(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(rundir_module.os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        write_atomically(tmp_path / "report.md", "# report\n")
    assert list(tmp_path.iterdir()) == []  # never an empty report.md


def test_summaries_round_trip(tmp_path: Path):
    run = RunDir(tmp_path, "m")
    run.write_json("metrics.json", {"a": np.float64(1.5), "b": float("nan"), "c": np.arange(2)})
    assert json.loads((run.path / "metrics.json").read_text()) == {"a": 1.5, "b": None, "c": [0, 1]}
    run.write_ply("map.ply", np.array([[0.0, 1.0, 2.0], [3.25, 4.5, 5.0]]))
    lines = (run.path / "map.ply").read_text().splitlines()
    assert lines[2] == "element vertex 2" and lines[-2:] == ["0.000 1.000 2.000", "3.250 4.500 5.000"]
    run.pose("slam", 0.0, np.eye(4))  # streamed during the flight
    run.close_trajectories()
    # a run-end observer, given only the folder, replaces the trajectory as a whole
    RunFiles(run.path).write_trajectory("slam", [0.0, 1.0], [np.eye(4), np.eye(4)])
    assert len((run.path / "slam.tum").read_text().splitlines()) == 2
    run.close()


def _make_run_folder(args: tuple[str, str]) -> str:
    root, name = args
    run = RunDir(Path(root), name)
    run.close()
    return str(run.path)


def test_processes_starting_in_the_same_second_get_distinct_folders(tmp_path: Path, monkeypatch):
    # the same timestamp for all of them: the folder name alone must not decide
    monkeypatch.setattr(rundir_module.time, "strftime", lambda fmt: "20261124-120000")
    pool = multiprocessing.get_context("fork").Pool(4)
    try:
        paths = pool.map(_make_run_folder, [(str(tmp_path), "demo")] * 12)
    finally:
        # close and join, not the context manager's terminate: a worker killed while it held the
        # pool's queue lock left another waiting for it forever (a fresh-clone suite hung here)
        pool.close()
        pool.join()
    assert len(set(paths)) == 12
    assert sorted(os.listdir(tmp_path))[:3] == [
        "demo-20261124-120000",
        "demo-20261124-120000-10",
        "demo-20261124-120000-11",
    ]


def test_atomically_written_files_get_the_mode_an_ordinary_open_gives(tmp_path: Path):
    # mkstemp's 0600 survived the rename: metrics.json, landmarks.json, map.ply … came out
    # unreadable to the other users of a shared machine, while the streams were not.
    written = write_atomically(tmp_path / "metrics.json", "{}")
    opened = tmp_path / "events.jsonl"
    opened.write_text("")
    assert stat.S_IMODE(written.stat().st_mode) == stat.S_IMODE(opened.stat().st_mode)
