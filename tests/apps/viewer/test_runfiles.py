"""Reading a run folder, whole and incrementally while it is written."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from amslam.apps.viewer.runfiles import (
    floor_heights,
    floor_slices,
    floors_from_map,
    parse_tum_line,
    poll_run,
    read_lines,
    read_map_points,
    slice_levels,
    voxel_size,
)
from amslam.lib.class_colours import class_colour
from tests.apps.viewer import synthetic


def test_tum_line_gives_position_and_yaw():
    yaw = 2.5
    t, x, y, z, got = parse_tum_line(synthetic.tum(1.5, 1.0, 2.0, 3.0, yaw))
    assert (t, x, y, z) == (1.5, 1.0, 2.0, 3.0)
    assert got == pytest.approx(yaw, abs=1e-4)
    assert parse_tum_line("# comment") is None and parse_tum_line("1 2 3") is None


def test_read_lines_leaves_a_partial_line_for_later_and_notices_a_rewrite(tmp_path):
    path = tmp_path / "s.jsonl"
    path.write_text('{"a": 1}\n{"b":')
    chunk = read_lines(path, 0)
    assert chunk.lines == ['{"a": 1}'] and chunk.offset == len('{"a": 1}\n') and not chunk.reset
    with open(path, "a") as f:
        f.write(' 2}\n{"c": 3}\n')
    chunk = read_lines(path, chunk.offset)
    assert chunk.lines == ['{"b": 2}', '{"c": 3}']
    assert read_lines(path, chunk.offset).lines == []
    path.write_text('{"z": 0}\n')  # rewritten shorter: start again
    again = read_lines(path, chunk.offset)
    assert again.reset and again.lines == ['{"z": 0}']
    assert read_lines(tmp_path / "missing.jsonl", 0).lines == []


def test_poll_reads_a_whole_finished_run(tmp_path):
    run = synthetic.write_run(tmp_path / "run")
    delta = poll_run(run)
    assert delta.finished and delta.cursor["ended"] == 1
    assert [n["name"] for n in delta.structure] == [n["name"] for n in synthetic.STRUCTURE]
    assert len(delta.tree) == len(synthetic.TREE)
    assert delta.tree[1] == [2.0, 20, {"1": ["SUCCESS", "at 1.20 m"]}, {}]
    assert [e["event"] for e in delta.events] == [e["event"] for e in synthetic.EVENTS]
    assert len(delta.traj["ground_truth"]) == 150
    static = delta.static
    assert static["voxel"] == synthetic.VOXEL
    assert {lm["class"] for lm in static["landmarks"]} == {"chair", "table"}
    chair = next(lm for lm in static["landmarks"] if lm["class"] == "chair")
    assert chair["sigma"] == pytest.approx(math.sqrt(3), abs=1e-4)
    assert static["metrics"]["explored_percent"] == 97.5


def test_poll_follows_a_run_in_progress(tmp_path):
    run = synthetic.write_run(tmp_path / "run", until=5.0)
    first = poll_run(run)
    assert not first.finished and first.static is None
    assert [r[0] for r in first.tree] == [0.1, 2.0, 2.1]
    assert first.traj["ground_truth"][-1][0] == 5.0
    # the run goes on: the files are rewritten whole here, the earlier lines unchanged
    synthetic.write_run(run, until=10.0)
    second = poll_run(run, first.cursor)
    assert second.structure is None  # already sent
    assert [r[0] for r in second.tree] == [6.0]
    assert [e["event"] for e in second.events] == ["goal_done", "replan", "loop_closure"]
    assert second.traj["ground_truth"][0][0] == 5.1 and second.traj["ground_truth"][-1][0] == 10.0
    assert not second.finished and second.reset == []
    # it ends: the summaries come once, with the trajectories again from their start
    synthetic.write_run(run)
    third = poll_run(run, second.cursor)
    assert third.finished and third.static is not None
    assert set(third.reset) == {"ground_truth", "vio", "slam"}
    assert third.traj["slam"][0][0] == 0.1 and len(third.traj["slam"]) == 150
    fourth = poll_run(run, third.cursor)
    assert fourth.finished and fourth.static is None and fourth.tree == [] and fourth.traj["vio"] == []


def test_floor_heights_come_from_metrics_then_mission_then_map(tmp_path):
    run = synthetic.write_run(tmp_path / "run")
    points, _ = read_map_points(run / "map.ply")
    assert floor_heights(run, points) == [0.0]  # procedural world: floors × floor_height
    metrics = json.loads((run / "metrics.json").read_text())
    (run / "metrics.json").write_text(json.dumps({**metrics, "floor_heights": [0.0, 3.0]}))
    assert floor_heights(run, points) == [0.0, 3.0]
    (run / "metrics.json").unlink()
    (run / "mission.yaml").write_text("name: x\n")
    assert floor_heights(run, points) == [0.25]  # the map: standing on the top of the floor slab


def test_floors_from_a_two_storey_map():
    room = synthetic.room_points()
    upper = room + [0, 0, 3.0]
    slab = np.array([[x, y, 2.875 + 0.25] for x, y in {(p[0], p[1]) for p in room}])  # ceiling + slab
    points = np.vstack([room, slab, upper])
    heights = floors_from_map(points)
    assert len(heights) == 2
    assert heights[0] == pytest.approx(0.25) and heights[1] == pytest.approx(3.25)


def test_slices_keep_walls_and_furniture_not_floor_or_ceiling():
    points = synthetic.room_points()
    assert voxel_size(points) == synthetic.VOXEL
    low, high = slice_levels(points[:, 2] - points[:, 2].min(), synthetic.VOXEL)
    assert 0.0 < low < 0.25 + 1e-9 and 2.5 <= high < 2.75  # relative to the floor voxels' centres
    (floor,) = floor_slices(points, [0.0])
    cells = {(x, y): n for x, y, n in floor["cells"]}
    assert (3.125, 2.125) not in cells  # mid-room: only floor and ceiling there
    wall, table = cells[(0.125, 2.125)], cells[(3.875, 2.375)]
    assert wall == 10 and table == 2  # wall voxels from z 0.375 to 2.625; the table's two levels
    n_wall_cells = 2 * (24 + 16) - 4
    assert len(cells) == n_wall_cells + 4


def test_the_page_gets_each_class_in_the_colour_the_simulator_paints_it(tmp_path):
    static = poll_run(synthetic.write_run(tmp_path / "run")).static
    chair = class_colour("chair")
    assert static["class_colours"]["chair"] == "#{:02x}{:02x}{:02x}".format(*(round(255 * c) for c in chair))
    assert set(static["class_colours"]) == {"chair", "table"}


def test_a_landmarks_file_that_does_not_read_leaves_the_landmarks_out_with_a_warning(tmp_path, caplog):
    run = synthetic.write_run(tmp_path / "run")
    (run / "landmarks.json").write_text('[{"class": "chair", "position": [1, 2')  # cut mid-write
    static = poll_run(run).static
    assert static["landmarks"] == [] and static["floors"]  # the rest of the run is shown
    assert any("landmarks.json:1: not JSON" in r.getMessage() for r in caplog.records)


def test_a_metrics_file_that_is_not_an_object_leaves_the_metrics_out(tmp_path):
    run = synthetic.write_run(tmp_path / "run")
    (run / "metrics.json").write_text('["completed"]')  # was an AttributeError traceback
    static = poll_run(run).static
    assert static["metrics"] == {} and static["landmarks"]
