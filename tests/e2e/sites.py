"""Third-party distributions for tests, installed into a temporary folder, never the project's venv.

``pip install --target`` puts the distribution (its modules and its ``.dist-info`` with the
``amslam`` entry points) into a folder of its own; only subprocesses given :func:`site_env`
see it. So two users of one ``.venv`` — two test runs, or a developer running the CLI while the
tests run — never see plugins appear and vanish.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def install_into_site(dist: Path, site: Path) -> Path:
    """``pip install`` the distribution in ``dist`` into the folder ``site``; returns ``site``."""
    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation"]
        + ["--target", str(site), str(dist)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return site


def site_env(site: Path) -> dict[str, str]:
    """The environment of a subprocess that sees the distributions installed in ``site``."""
    path = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path}
