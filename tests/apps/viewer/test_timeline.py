"""The state of a run at a moment, in Python (the reference) and in the page's script (under Node)."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from importlib import resources

import pytest

from amslam.apps.viewer.runfiles import poll_run
from amslam.apps.viewer.timeline import pose_at, render_text, slc_viewpoints_until, tour_at, tree_state_at
from tests.apps.viewer import synthetic


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return poll_run(synthetic.write_run(tmp_path_factory.mktemp("run") / "run"))


def test_tree_state_replays_changes_up_to_t(run):
    before = tree_state_at(run.tree, 0.0)
    assert before.tick == 0 and before.status(1) == "INVALID" and before.blackboard == {}
    start = tree_state_at(run.tree, 0.1)  # a record at exactly t counts
    assert start.status(0) == "RUNNING" and start.status(1) == "RUNNING" and start.feedback(1) == "climbing"
    assert start.status(4) == "INVALID"
    mid = tree_state_at(run.tree, 7.5)
    assert mid.tick == 60
    assert (mid.status(1), mid.feedback(1)) == ("SUCCESS", "at 1.20 m")  # kept from t = 2.0
    assert (mid.status(4), mid.feedback(4)) == ("RUNNING", "waypoint 3/4")  # overridden at t = 6.0
    assert mid.blackboard["/goal"] == ["explore", 5.0, 1.0, 1.2]
    end = tree_state_at(run.tree, 100.0)
    assert end.status(0) == "SUCCESS" and end.status(5) == "SUCCESS" and end.blackboard["/goal"] is None


def test_pose_interpolates_position_and_yaw_the_short_way():
    traj = [[0.0, 0.0, 0.0, 1.0, math.pi - 0.1], [1.0, 2.0, 4.0, 1.0, -math.pi + 0.1]]
    assert pose_at(traj, -0.5) is None
    x, y, z, yaw = pose_at(traj, 0.5)
    assert (x, y, z) == (1.0, 2.0, 1.0)
    assert abs(abs(yaw) - math.pi) < 1e-9  # through ±π, not through 0
    assert pose_at(traj, 9.0) == traj[-1][1:]


def test_tour_and_slc_viewpoints_at_t(run):
    assert tour_at(run.events, 2.0) == []
    assert tour_at(run.events, 2.1)[1] == ["slc", 5.0, 3.0, 1.2]
    assert tour_at(run.events, 8.0) == [["slc", 5.0, 3.0, 1.2]]
    assert slc_viewpoints_until(run.events, 1.0) == []
    assert slc_viewpoints_until(run.events, 20.0) == [[5.0, 3.0, 1.2]]  # the same stop in two tours: once


def test_text_rendering_marks_status_and_last_feedback(run):
    text = render_text(run.structure, tree_state_at(run.tree, 7.5))
    lines = text.splitlines()
    assert lines[0] == "t = 7.5 s (tick 60)"
    assert "▶ Mission [RUNNING]" in lines[1]
    assert lines[2].strip() == "✔ TakeOff [SUCCESS]  — at 1.20 m"
    assert lines[5].startswith("        ▶ GoToViewpoint")  # depth 2
    assert lines[6].strip() == "· Land [INVALID]"


NODE_SCRIPT = """
const T = require(process.argv[1]);
const input = JSON.parse(require("fs").readFileSync(0, "utf8"));
const tl = new T.TreeTimeline(input.structure, []);
for (const r of input.tree) tl.add([r]);  // one at a time, as a live page gets them
const out = input.times.map((t) => {
  const s = tl.stateAt(t);
  return {t, tick: s.tick, nodes: s.nodes, bb: s.bb, pose: T.poseAt(input.traj, t),
          tour: T.tourAt(input.events, t), slc: T.slcViewpointsUntil(input.events, t),
          next: tl.nextChange(t), prev: tl.previousChange(t)};
});
process.stdout.write(JSON.stringify(out));
"""


@pytest.mark.skipif(
    shutil.which("node") is None, reason="Node.js is not installed: the page's script is not run"
)
def test_page_script_agrees_with_the_reference(tmp_path):
    # many records, so that the script's snapshots (every 64 records) are crossed
    records = []
    for i in range(300):
        nodes = {str(i % 5): ["RUNNING" if i % 3 else "SUCCESS", f"step {i}"]}
        records.append([round(0.5 * i, 1), i, nodes, {"/i": i} if i % 7 == 0 else {}])
    traj = [
        [0.1 * i, math.cos(0.1 * i), math.sin(0.1 * i), 1.0, math.atan2(math.sin(i), math.cos(i))]
        for i in range(200)
    ]
    events = synthetic.EVENTS
    times = [-1.0, 0.0, 0.25, 0.5, 31.9, 32.0, 32.05, 63.5, 64.0, 100.0, 149.5, 1000.0]
    payload = {
        "structure": synthetic.STRUCTURE,
        "tree": records,
        "traj": traj,
        "events": events,
        "times": times,
    }
    script = resources.files("amslam.apps.viewer").joinpath("timeline.js")
    done = subprocess.run(
        ["node", "-e", NODE_SCRIPT, str(script)],
        input=json.dumps(payload),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout)
    for t, js in zip(times, got, strict=True):
        ref = tree_state_at(records, t)
        assert js["tick"] == ref.tick, t
        assert {int(k): v for k, v in js["nodes"].items()} == ref.nodes, t
        assert js["bb"] == ref.blackboard, t
        pose = pose_at(traj, t)
        assert (js["pose"] is None) == (pose is None), t
        if pose is not None:
            assert js["pose"] == pytest.approx(pose, abs=1e-9), t
        assert js["tour"] == tour_at(events, t) and js["slc"] == slc_viewpoints_until(events, t), t
        later = [r[0] for r in records if r[0] > t]
        earlier = [r[0] for r in records if r[0] < t]
        assert js["next"] == (later[0] if later else None) and js["prev"] == (
            earlier[-1] if earlier else None
        )
