"""A third-party distribution providing a planner: pip-installed into a temporary folder, listed, flown."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tests.e2e.missions import small_mission
from tests.e2e.sites import install_into_site, site_env

PYPROJECT = """\
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "amslam-nearest-planner"
version = "0.3.0"
dependencies = []

[project.entry-points.amslam]
nearest = "amslam_nearest"

[tool.setuptools]
py-modules = ["amslam_nearest"]
"""

MODULE = '''\
"""Visit the nearest reachable viewpoint first: a third-party planner."""
import numpy as np
from pydantic import Field

import amslam
from amslam.interfaces import BackendParams, Planner
from amslam.types import TourItem, TourItemKind


class NearestFirst(Planner):
    class Params(BackendParams):
        min_gain: float = Field(0.0, description="ignore viewpoints with less gain")

    def configure(self, params, context):
        self.params = params

    def plan(self, request):
        costs = request.costs[0, 1:]
        order = [i for i in np.argsort(costs, kind="stable")
                 if np.isfinite(costs[i]) and request.viewpoints[i].gain >= self.params.min_gain]
        return [TourItem(TourItemKind.EXPLORE, request.viewpoints[i].position,
                         request.viewpoints[i].yaw, request.viewpoints[i].gain,
                         request.viewpoints[i].id) for i in order[:3]]


@amslam.hookimpl
def amslam_planner_backends():
    return {"nearest": NearestFirst}
'''


@pytest.fixture
def installed_plugin(tmp_path):
    dist = tmp_path / "amslam-nearest-planner"
    dist.mkdir()
    (dist / "pyproject.toml").write_text(PYPROJECT)
    (dist / "amslam_nearest.py").write_text(MODULE)
    return site_env(install_into_site(dist, tmp_path / "site"))


def test_third_party_planner_is_listed_and_flies(installed_plugin, tmp_path):
    amslam = Path(sys.executable).with_name("amslam")
    env = installed_plugin
    listed = subprocess.run([amslam, "plugins"], capture_output=True, text=True, env=env).stdout
    assert "nearest" in listed and "amslam-nearest-planner 0.3.0" in listed
    # 40 s of exploring, then home and land: enough for the planner to plan, fly to and replan
    mission = small_mission(
        tmp_path, name="thirdparty", planner="{plugin: nearest, min_gain: 0.5}", max_time=40
    )
    done = subprocess.run(
        [amslam, "run", str(mission), "--out", str(tmp_path / "runs"), "--quiet"],
        capture_output=True,
        text=True,
        check=False,
        env=env,
    )
    assert "verdict: completed" in done.stdout, done.stdout + done.stderr
    run_dir = next((tmp_path / "runs").iterdir())
    assert yaml.safe_load((run_dir / "mission.yaml").read_text())["planner"]["plugin"] == "nearest"
