"""The command line's output options: --version, python -m amslam, --quiet / --verbose /
--log-level, and Python warnings routed through logging to stderr."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from amslam import console
from tests.e2e.missions import small_mission

AMSLAM = Path(sys.executable).with_name("amslam")


def amslam(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([AMSLAM, *args], capture_output=True, text=True, check=False, timeout=120)


def test_version_is_the_installed_distributions():
    from importlib.metadata import version

    for command in ([AMSLAM, "--version"], [sys.executable, "-m", "amslam", "--version"]):
        done = subprocess.run(command, capture_output=True, text=True, check=False, timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout == f"amslam {version('amslam')}\n"
    assert version("amslam") == "0.2.0"


def test_python_m_amslam_is_the_command_line():
    done = subprocess.run(
        [sys.executable, "-m", "amslam", "--help"], capture_output=True, text=True, check=False, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: amslam [-h] [--version] [-q] [-v] [--log-level LEVEL] COMMAND")
    assert "validate" in done.stdout and "experiment" in done.stdout


@pytest.mark.parametrize("where", ["before", "after"])
def test_log_level_debug_shows_debug_messages(tmp_path, where):
    mission = str(small_mission(tmp_path))
    args = ["--log-level", "DEBUG", "validate", mission]
    done = amslam(*(args if where == "before" else args[2:] + args[:2]))
    assert done.returncode == 0, done.stderr
    assert "valid" in done.stdout
    debug = done.stderr.splitlines()
    assert debug[0].startswith("debug: amslam.cli: amslam 0.2.0 on Python"), debug
    assert "debug: amslam.cli: plugin commands from amslam 0.2.0" in debug


def test_without_options_there_are_no_debug_messages(tmp_path):
    done = amslam("validate", str(small_mission(tmp_path)))
    assert done.returncode == 0 and done.stderr == "", done.stderr


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--log-level", "loud", "plugins"], "'loud' is not a level; levels are debug, info, warning, error"),
        (["plugins", "--log-level", "loud"], "'loud' is not a level"),
        (["-q", "-v", "plugins"], "error: --quiet and --verbose contradict each other"),
        (["--quiet", "plugins", "--verbose"], "error: --quiet and --verbose contradict each other"),
    ],
)
def test_a_bad_output_option_is_one_error_line(args, expected):
    done = amslam(*args)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and expected in errors[0], done.stderr
    assert done.stdout == ""


def test_quiet_keeps_the_error_line(tmp_path):
    done = amslam("--quiet", "run", str(tmp_path / "nowhere.yaml"))
    assert done.returncode == 2
    (line,) = done.stderr.splitlines()
    assert line.startswith(f"error: {tmp_path / 'nowhere.yaml'}: no such mission file"), line


def test_quiet_silences_warnings(tmp_path):
    """A mission whose optional plugin failed to load flies with a warning; --quiet drops it."""
    mission = small_mission(tmp_path)
    mission.write_text(mission.read_text() + "plugins: {optional: [no_such_plugin]}\n")
    site = tmp_path / "site"
    site.mkdir()
    (site / "no_such_plugin.py").write_text("raise ImportError('no module named gone')\n")
    dist = site / "no_such_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: no-such-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[amslam]\nno_such_plugin = no_such_plugin\n")
    env = {**os.environ, "PYTHONPATH": str(site)}

    def validate(*options: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [AMSLAM, *options, "validate", str(mission)], capture_output=True, text=True, env=env, timeout=120
        )

    loud, quiet = validate(), validate("--quiet")
    assert loud.returncode == quiet.returncode == 0, loud.stderr
    assert loud.stderr.startswith("warning: optional plugin 'no_such_plugin'"), loud.stderr
    assert quiet.stderr == ""
    assert quiet.stdout == loud.stdout


def _warn_through_logging(level: str, capsys) -> str:
    with console.logging_to_stderr(level), warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.warn("Mean of empty slice", RuntimeWarning, stacklevel=1)
    return capsys.readouterr().err


def test_python_warnings_go_through_logging(capsys):
    shown = _warn_through_logging("info", capsys).splitlines()
    assert len(shown) == 1 and shown[0].startswith("warning: "), shown
    assert shown[0].endswith("RuntimeWarning: Mean of empty slice")
    verbose = _warn_through_logging("debug", capsys).splitlines()
    assert len(verbose) == 2 and "warnings.warn(" in verbose[1]  # the source line too
    assert _warn_through_logging("error", capsys) == ""  # --quiet
