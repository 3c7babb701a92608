"""The example distribution examples/amslam-octomap: installed by pip, listed, contract-tested, flown."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tests.e2e.missions import small_mission
from tests.e2e.sites import install_into_site, site_env

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "amslam-octomap"
AMSLAM = Path(sys.executable).with_name("amslam")


ENV: dict[str, str] = {}


def _run(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(a) for a in args], capture_output=True, text=True, check=False, cwd=cwd, env=ENV or None
    )


@pytest.fixture(scope="module")
def octomap_example(tmp_path_factory):
    """``pip install`` a copy of the example into a temporary folder (never the project's venv;
    builds stay out of the repository); the amslam subprocesses see it through PYTHONPATH."""
    pytest.importorskip("pyoctomap", reason="the octomap example needs pyoctomap (in amslam's dev extras)")
    root = tmp_path_factory.mktemp("dist")
    src = root / "amslam-octomap"
    shutil.copytree(EXAMPLE, src, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    ENV.update(site_env(install_into_site(src, root / "site")))
    yield src
    ENV.clear()


def test_listed_with_its_hooks(octomap_example):
    listed = _run(AMSLAM, "plugins")
    assert listed.returncode == 0, listed.stderr
    assert "octomap" in listed.stdout and "amslam-octomap 0.1.0" in listed.stdout
    line = next(x for x in listed.stdout.splitlines() if x.strip().startswith("octomap ") and "amslam_" in x)
    assert "amslam_mapping_backends" in line
    dumped = _run(AMSLAM, "dump-config", "mapping", "octomap")
    assert dumped.returncode == 0, dumped.stderr
    config = yaml.safe_load(dumped.stdout)["mapping"]
    assert config["plugin"] == "octomap" and config["prob_miss"] == pytest.approx(0.4)


def test_passes_the_mapping_contract(octomap_example):
    # the example's own test suite, run the way its author runs it: pytest in its folder
    done = _run(sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests", cwd=octomap_example)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "18 passed" in done.stdout, done.stdout[-1000:]


def test_mission_with_octomap_flies(octomap_example, tmp_path):
    mission = small_mission(tmp_path, name="octomap", mapping="{plugin: octomap}", max_time=15)
    done = _run(AMSLAM, "run", mission, "--out", tmp_path / "runs", "--quiet")
    assert "verdict: completed" in done.stdout, done.stdout + done.stderr
    run_dir = next((tmp_path / "runs").iterdir())
    resolved = yaml.safe_load((run_dir / "mission.yaml").read_text())
    assert resolved["mapping"]["plugin"] == "octomap"
    assert resolved["mapping"]["prob_hit"] == pytest.approx(0.7)  # the backend's own defaults, filled in
