"""A pip-installed plugin with an import error: one named line, never a traceback; optional skips it.

The broken distribution is installed with ``pip --target`` into a temporary folder put on
``PYTHONPATH`` for the ``amslam`` subprocesses only, so other tests sharing the environment never see it.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.e2e.missions import small_mission
from tests.e2e.sites import install_into_site, site_env

PYPROJECT = """\
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "amslam-broken"
version = "0.2.0"
dependencies = []

[project.entry-points.amslam]
broken = "amslam_broken"

[tool.setuptools]
py-modules = ["amslam_broken"]
"""

MODULE = '''\
"""A plugin whose dependency is not installed."""
import amslam
import amslam_missing_dependency_xyz  # noqa: F401


@amslam.hookimpl
def amslam_planner_backends():
    return {}
'''

ERROR = (
    "plugin 'broken' (distribution amslam-broken 0.2.0, amslam_broken) failed to load: "
    "ModuleNotFoundError: No module named 'amslam_missing_dependency_xyz'"
)
AMSLAM = Path(sys.executable).with_name("amslam")


@pytest.fixture(scope="module")
def broken_site(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("broken")
    dist = root / "amslam-broken"
    dist.mkdir()
    (dist / "pyproject.toml").write_text(PYPROJECT)
    (dist / "amslam_broken.py").write_text(MODULE)
    return install_into_site(dist, root / "site")


def _amslam(site: Path, *args) -> subprocess.CompletedProcess:
    env = site_env(site)
    done = subprocess.run([AMSLAM, *map(str, args)], capture_output=True, text=True, check=False, env=env)
    assert "Traceback" not in done.stdout + done.stderr, done.stderr
    return done


def test_plugins_lists_the_rest_and_names_the_broken_one(broken_site):
    done = _amslam(broken_site, "plugins")
    assert done.returncode == 1
    assert f"  {ERROR}\n" in done.stdout
    assert "greedy" in done.stdout and "sim" in done.stdout


def test_mission_refuses_with_one_line(broken_site, tmp_path):
    mission = small_mission(tmp_path)
    for command in ("validate", "run"):
        done = _amslam(
            broken_site, command, mission, *(["--out", tmp_path / "runs"] if command == "run" else [])
        )
        assert done.returncode == 2
        errors = done.stderr.strip().splitlines()
        assert len(errors) == 1, done.stderr
        assert errors[0].startswith(f"error: {mission}: plugins: {ERROR} — ")
        assert "plugins.optional" in errors[0]
    assert not (tmp_path / "runs").exists()  # refused before anything flew


def test_optional_plugin_is_skipped_with_a_warning(broken_site, tmp_path):
    mission = small_mission(tmp_path)
    mission.write_text(mission.read_text() + "plugins: {optional: [broken]}\n")
    done = _amslam(broken_site, "validate", mission)
    assert done.returncode == 0, done.stderr
    assert done.stderr.strip() == f"warning: optional {ERROR}; going on without it"
    assert "valid" in done.stdout


def test_disabled_plugin_is_not_imported(broken_site, tmp_path):
    mission = small_mission(tmp_path)
    mission.write_text(mission.read_text() + "plugins: {disable: [broken]}\n")
    done = _amslam(broken_site, "validate", mission)
    assert done.returncode == 0 and done.stderr == "", done.stderr
