"""The command line as a user meets it: clear errors without tracebacks, helpful listings."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

AMSLAM = Path(sys.executable).with_name("amslam")


def amslam(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([AMSLAM, *args], capture_output=True, text=True, check=False)


def test_validate_reports_three_clear_errors(tmp_path):
    mission = tmp_path / "bad.yaml"
    mission.write_text(
        textwrap.dedent(
            """\
            name: bad
            robot:
              raduis: 0.3
            limits:
              max_time: soon
            planner:
              plugin: astar
            """
        )
    )
    done = amslam("validate", str(mission))
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 3, done.stderr
    assert any(f"{mission}:3: robot.raduis: unknown key 'raduis'; expected one of:" in e for e in errors)
    assert any(f"{mission}:5: limits.max_time:" in e and "'soon'" in e for e in errors)
    assert any(
        f"{mission}:7: planner.plugin: no planner backend named 'astar'; installed:" in e for e in errors
    )


def test_validate_ok_and_dump_config_and_tree():
    assert amslam("validate", "demo").returncode == 0
    dumped = amslam("dump-config", "mapping", "open3d")
    assert dumped.returncode == 0 and "global_voxel: 0.25" in dumped.stdout and "p_hit: 0.7" in dumped.stdout
    tree = amslam("tree", "demo")
    assert tree.returncode == 0
    for name in ("TakeOff", "Replan", "Explore", "Land"):
        assert name in tree.stdout


def test_unknown_mission_and_unknown_backend_are_one_line_errors():
    done = amslam("run", "no-such-mission")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "no such mission file" in done.stderr
    done = amslam("dump-config", "planner", "nope")
    assert done.returncode == 2 and "no planner backend named 'nope'; installed:" in done.stderr
