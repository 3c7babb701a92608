"""How much of a flight's pose uncertainty its landmarks removed: the mean pose covariance trace
of its key poses chained by odometry alone, against the flight's own (paper 1 Table II's measure).

Per flight (a run folder), the logged VIO key poses are chained by the flight's own odometry noise
model (its ``mission.yaml``'s ``slam.graph``: the same ``BetweenFactorPose3`` noise and first-pose
prior the onboard graph uses, no landmark), and the mean trace of the 6×6 pose marginals is
compared with ``metrics.json``'s ``uncertainty.final_mean_pose_trace``. A ratio well below one
says the landmarks already tie the trajectory; in an SLC ablation it shows what share an active
loop closure still has to work on. Reads the log and the metrics only (no ground truth).

    .venv/bin/python benchmarks/uncertainty_without_landmarks.py RUN_DIR [RUN_DIR ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def odometry_only_trace(run_dir: Path, mission: object) -> tuple[float, int]:
    """(mean 6×6 pose-marginal trace of the odometry-only chain, key poses)."""
    import gtsam

    from amslam.geometry import yaw_of
    from amslam.measurements import read_measurements
    from amslam.plugins.gtsam_slam.graph import NoiseModels

    noise = NoiseModels(mission.backends["slam"].params.graph)
    log = read_measurements(run_dir)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    first = gtsam.Pose3(log.T_odom_body[0])
    graph.add(gtsam.PriorFactorPose3(0, first, noise.prior()))
    values.insert(0, first)
    for k in range(1, len(log.T_odom_body)):
        rel = log.rel[k]
        model = noise.odometry(float(np.linalg.norm(rel[:3, 3])), yaw_of(rel))
        graph.add(gtsam.BetweenFactorPose3(k - 1, k, gtsam.Pose3(rel), model))
        values.insert(k, gtsam.Pose3(log.T_odom_body[k]))
    marginals = gtsam.Marginals(graph, values)
    traces = [np.trace(marginals.marginalCovariance(k)) for k in range(len(log.T_odom_body))]
    return float(np.mean(traces)), len(traces)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uncertainty_without_landmarks.py", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("runs", nargs="+", type=Path, help="run folders (measurements.jsonl, metrics.json)")
    args = parser.parse_args(argv)
    from slam_offline import OfflineError, load_flight_mission

    from amslam.registry import build_plugin_manager

    registry = build_plugin_manager()
    print("| flight | seed | SLC | key poses | odometry alone tr(Σ) | flight tr(Σ) | ratio |")
    print("|---|---|---|---|---|---|---|")
    for run in args.runs:
        try:
            metrics = json.loads((run / "metrics.json").read_text())
            own = float(metrics["uncertainty"]["final_mean_pose_trace"])
            mission = load_flight_mission(run, [], registry, drop_unknown_keys=True)
            alone, n = odometry_only_trace(run, mission)
        except (OSError, KeyError, ValueError, OfflineError) as exc:
            print(f"{run}: {exc}", file=sys.stderr)
            return 1
        slc = "on" if mission.model.exploration.slc else "off"
        print(
            f"| {run.name} | {metrics.get('seed')} | {slc} | {n} | {alone:.3f} | {own:.3f}"
            f" | {own / alone:.2f} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
