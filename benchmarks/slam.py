"""The ``gtsam`` SLAM backend at scale: iSAM2 step time and eq. (10) information gain.

1. A synthetic run (:mod:`amslam.plugins.gtsam_slam.synthetic`): laps of a 40×20 m loop lined
   with objects, drifting VIO, detections every metre, until the graph holds ``--poses`` key poses.
   Every iSAM2 update the backend makes is recorded (its new factors and values) and replayed
   straight into a fresh ``gtsam.ISAM2`` with the same parameters: the reference for the step
   time. The backend's time includes data association and bookkeeping.
2. Information gain of ``--candidates`` virtual factors from the current pose to old key poses:
   the backend's Woodbury method (one factorisation, low-rank updates) vs brute force (clone the
   graph, add the factor, recompute all marginals with ``gtsam.Marginals``), and their agreement.
3. The cost of ``uncertainty()`` (all marginals by ``gtsam.Marginals``, cached per graph
   version) vs per-key ``ISAM2.marginalCovariance``.

    .venv/bin/python benchmarks/slam.py
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gtsam
import numpy as np

from amslam.interfaces import RunContext
from amslam.plugins.gtsam_slam.backend import GtsamSlam
from amslam.plugins.gtsam_slam.information import brute_force_information_gain
from amslam.plugins.gtsam_slam.synthetic import LoopWorld, camera_mount


class RecordingSlam(GtsamSlam):
    """The backend, recording each iSAM2 update for replay and timing it."""

    def configure(self, params: GtsamSlam.Params, context: RunContext) -> None:
        super().configure(params, context)
        self.updates: list[tuple[gtsam.NonlinearFactorGraph, gtsam.Values, int]] = []
        graph = self._graph
        flush = graph.flush

        def recording_flush(extra_iterations: int = 0) -> None:
            if graph._new_graph.size() or graph.new_values.size():
                self.updates.append(
                    (
                        gtsam.NonlinearFactorGraph(graph._new_graph),
                        gtsam.Values(graph.new_values),
                        extra_iterations,
                    )
                )
            flush(extra_iterations)

        graph.flush = recording_flush


def build(poses: int, seed: int) -> tuple[RecordingSlam, list[float], list[int]]:
    """Drive laps until ``poses`` key poses; return the backend, step times and update marks."""
    rng = np.random.default_rng(seed)
    world = LoopWorld.rectangle(
        rng,
        width=40.0,
        height=20.0,
        spacing=0.6,
        offset=1.5,
        yaw_bias_per_m=0.0003,
        yaw_walk_per_sqrt_m=0.0005,
    )
    slam = RecordingSlam()
    slam.configure(GtsamSlam.Params(), RunContext(rng=np.random.default_rng(seed), run_dir=Path(".")))
    Tc = camera_mount()
    slam.add_odometry(world.odometry())
    steps: list[float] = []  # wall time of the calls that produced each key pose
    marks: list[int] = []  # number of recorded updates after each key pose
    k = 0
    pending = 0.0
    while slam.num_keyposes < poses:
        for T in world.loop_path(40.0, 20.0):
            world.move_to(T)
            t0 = time.perf_counter()
            n = slam.num_keyposes
            slam.add_odometry(world.odometry())
            if k % 5 == 4:
                slam.add_detections(world.odometry(), Tc, world.detect())
            pending += time.perf_counter() - t0
            k += 1
            if slam.num_keyposes > n:
                steps.append(pending)
                marks.append(len(slam.updates))
                pending = 0.0
            if slam.num_keyposes >= poses:
                break
    return slam, steps, marks


def replay(slam: RecordingSlam) -> list[float]:
    """Feed the recorded updates to a fresh ISAM2; the time of each update."""
    p = gtsam.ISAM2Params()
    p.setFactorization(slam.params.graph.factorization)
    p.setRelinearizeThreshold(slam.params.graph.relinearize_threshold)
    p.relinearizeSkip = 1
    isam = gtsam.ISAM2(p)
    times = []
    for graph, values, extra in slam.updates:
        t0 = time.perf_counter()
        isam.update(graph, values)
        for _ in range(extra):
            isam.update()
        isam.calculateEstimate()  # the backend reads the estimate after every update, so does this
        times.append(time.perf_counter() - t0)
    return times


def row(figure: str, value: float, reference: float | None = None, ratio: float | None = None) -> None:
    ref = f"{reference:>10.2f}" if reference is not None else f"{'':>10}"
    rat = f"{ratio:>7.1f}×" if ratio is not None else ""
    print(f"{figure:<52} {value:>10.2f} {ref} {rat}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--candidates", type=int, default=10)
    ap.add_argument("--window", type=int, default=100, help="last N key poses whose step time is averaged")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    t0 = time.perf_counter()
    slam, steps, marks = build(args.poses, args.seed)
    built = time.perf_counter() - t0
    lms = slam.landmarks()
    print(
        f"graph: {slam.num_keyposes} key poses, {len(lms)} landmarks, "
        f"{slam.graph()[0].size()} factors, built in {built:.1f} s"
    )

    raw = replay(slam)
    w = args.window
    lo, hi = marks[-w - 1], marks[-1]
    ours_ms = 1e3 * float(np.mean(steps[-w:]))
    raw_ms = 1e3 * float(np.sum(raw[lo:hi])) / w
    print()
    print(f"{'figure':<52} {'value':>10} {'reference':>10} {'ratio':>8}")
    row(f"iSAM2 step, last {w} key poses (ms): backend vs raw", ours_ms, raw_ms, ours_ms / raw_ms)

    # Information gain: candidates spread over the history, travel = straight-line distance.
    kps = slam.keyposes()
    here = kps[-1].T_world_body[:3, 3]
    ids = [int(i) for i in np.linspace(0, len(kps) - 20, args.candidates)]
    dists = [float(np.linalg.norm(kps[i].T_world_body[:3, 3] - here)) + 1.0 for i in ids]
    slam._graph.version += 1  # time a cold factorisation, as after any new key pose
    t0 = time.perf_counter()
    fast = slam.information_gain(ids, dists)
    t_fast = time.perf_counter() - t0
    graph, values = slam.graph()
    over = [int(k) for k in values.keys()]  # noqa: SIM118 — gtsam.Values is not iterable
    t0 = time.perf_counter()
    brute = np.array(
        [
            brute_force_information_gain(graph, values, slam.virtual_factor(i, d), over)
            for i, d in zip(ids, dists, strict=True)
        ]
    )
    t_brute = time.perf_counter() - t0
    rel = float(np.max(np.abs(fast - brute) / np.abs(brute)))
    row(
        f"IG of {args.candidates} candidates (ms): brute force vs Woodbury",
        1e3 * t_brute,
        1e3 * t_fast,
        t_brute / t_fast,
    )
    print(f"{'IG max relative difference (fast vs brute)':<52} {rel:>10.1e}")

    slam._graph.version += 1  # cold: as after any new key pose
    t0 = time.perf_counter()
    slam.uncertainty()
    t_unc = time.perf_counter() - t0
    t0 = time.perf_counter()
    slam.uncertainty()
    t_warm = time.perf_counter() - t0
    t0 = time.perf_counter()
    for k in over:
        slam._graph._isam.marginalCovariance(k)
    t_isam = time.perf_counter() - t0
    row(
        "uncertainty() cold (ms): ISAM2 per key vs gtsam.Marginals", 1e3 * t_isam, 1e3 * t_unc, t_isam / t_unc
    )
    row("uncertainty() again, same graph (ms)", 1e3 * t_warm)
    print()
    print("IG per candidate (key pose, travel m, fast, brute):")
    for i, d, f, b in zip(ids, dists, fast, brute, strict=True):
        print(f"  x{i:<5} {d:7.1f} {f:12.6f} {b:12.6f}")


if __name__ == "__main__":
    main()
