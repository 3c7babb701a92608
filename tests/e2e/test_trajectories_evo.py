"""The run's TUM trajectories are what evo (the SLAM evaluation tool) reads."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path


def test_evo_ape_reads_ground_truth_and_slam(small_run):
    evo_ape = shutil.which("evo_ape") or str(Path(sys.executable).with_name("evo_ape"))
    done = subprocess.run(
        [evo_ape, "tum", "ground_truth.tum", "slam.tum", "--no_warnings"],
        cwd=small_run.run_dir,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "APE w.r.t. translation part" in done.stdout and "rmse" in done.stdout
