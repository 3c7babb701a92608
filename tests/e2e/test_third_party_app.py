"""A throwaway distribution adds a CLI command, an experiment and a mission tree through the
kernel's hooks, with no edit of amslam: the same way the built-in ones come in."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

MODULE = '''\
"""A third party's command and experiment."""
from pathlib import Path

import amslam
from amslam.cli import Command, Experiment


def _hello_arguments(parser):
    parser.add_argument("who")


def _hello(args, registry):
    kinds = ", ".join(sorted(registry.backends))
    print(f"hello {args.who}; backend kinds: {kinds}")
    return 0


def _count(args, registry):
    folder = Path(args.out) / "count-seeds"
    folder.mkdir(parents=True, exist_ok=True)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    row = f"| {args.mission} | {seeds} | {args.label} |"
    (folder / "table.md").write_text("| mission | seeds | label |\\n|---|---|---|\\n" + row)
    return folder


def _count_arguments(parser):
    parser.add_argument("--label", default="none")


def _hover(model, behaviours, failsafe=False):
    from py_trees.composites import Sequence

    return Sequence("Hover", memory=True, children=[behaviours["TakeOff"](), behaviours["Land"]()])


@amslam.hookimpl
def amslam_mission_trees():
    return {"hover": _hover}


@amslam.hookimpl
def amslam_cli_commands():
    return {"hello": Command("say hello", _hello_arguments, _hello)}


@amslam.hookimpl
def amslam_experiments():
    return {"count-seeds": Experiment("write the seeds it would fly", _count, _count_arguments)}
'''


@pytest.fixture
def throwaway_distribution(tmp_path: Path) -> dict[str, str]:
    """A distribution on the path (its module and its dist-info with the ``amslam`` entry point)."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "amslam_hello.py").write_text(MODULE)
    info = site / "amslam_hello-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: amslam-hello\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[amslam]\nhello = amslam_hello\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
    return env


def _amslam(env: dict[str, str], *args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "amslam.cli", *args], capture_output=True, text=True, env=env, cwd=cwd
    )


def test_a_third_party_command_is_listed_and_runs(throwaway_distribution, tmp_path):
    listed = _amslam(throwaway_distribution, "--help", cwd=tmp_path)
    assert listed.returncode == 0, listed.stderr
    assert "hello" in listed.stdout and "say hello" in listed.stdout
    done = _amslam(throwaway_distribution, "hello", "pilot", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "hello pilot; backend kinds: detector, mapping, planner, platform, slam" in done.stdout
    plugins = _amslam(throwaway_distribution, "plugins", cwd=tmp_path)
    assert (
        "amslam-hello 0.1: amslam_cli_commands (0.2), amslam_experiments (0.2), amslam_mission_trees (0.2)"
        in plugins.stdout
    )


def test_a_third_party_experiment_takes_the_common_and_its_own_arguments(throwaway_distribution, tmp_path):
    done = _amslam(
        throwaway_distribution,
        *("experiment", "count-seeds", "demo", "--seeds", "3", "--first-seed", "4", "--label", "x"),
        *("--out", str(tmp_path / "out")),
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert "| demo | [4, 5, 6] | x |" in done.stdout
    assert (tmp_path / "out" / "count-seeds" / "table.md").exists()


def test_without_the_distribution_the_command_is_unknown(tmp_path):
    done = _amslam(dict(os.environ), "hello", "pilot", cwd=tmp_path)
    assert done.returncode == 2
    assert "invalid choice: 'hello'" in done.stderr


def test_a_third_party_tree_is_drawn_and_flown(throwaway_distribution, tmp_path):
    from tests.e2e.missions import small_mission

    mission = small_mission(tmp_path, max_time=60)
    drawn = _amslam(throwaway_distribution, "tree", str(mission), "--set", "tree=hover", cwd=tmp_path)
    assert drawn.returncode == 0, drawn.stderr
    assert drawn.stdout.splitlines()[:3] == ["{-} Hover", "    --> TakeOff", "    --> Land"]
    run = ("run", str(mission), "--set", "tree=hover", "--out", "runs", "--quiet")
    flown = _amslam(throwaway_distribution, *run, cwd=tmp_path)
    assert "verdict: completed" in flown.stdout, flown.stdout + flown.stderr
    unknown = _amslam(dict(os.environ), "validate", str(mission), "--set", "tree=hover", cwd=tmp_path)
    assert unknown.returncode == 2 and "no mission tree named 'hover'" in unknown.stderr
