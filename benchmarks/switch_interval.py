"""The control loop beside busy Python threads, by the interpreter's switch interval (issue #17).

On a real vehicle the control thread ticks at 10 Hz while the mapper, SLAM and planner threads
compute. Each time the control thread lets go of the interpreter (any numpy call of a frame's
integration does) it waits until a thread running Python bytecode gives it back: up to one switch
interval each time. This script runs a 10 Hz loop whose tick is one local-map frame update of a
320 × 240 frame (the ``open3d`` backend's local window at 0.1 m, as the SITL demo flight's)
beside two threads running Python (a loop of small numpy calls, like the SLAM backend's marginals), for a few
seconds at each switch interval, and prints: ticks made, ticks whose work took over one period,
the median work of a tick, and the two threads' loops done (their throughput). The reference is
Python's default interval (5 ms), in the same run; the ratios are to it. The runner flies a real
vehicle at ``amslam.runner.REAL_TIME_SWITCH_INTERVAL``.

Run: ``.venv/bin/python benchmarks/switch_interval.py [--seconds 4]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time

import numpy as np

from amslam.lib.voxel_grid import LogOddsModel
from amslam.plugins.voxel_open3d.backend import WindowGrid
from amslam.runner import REAL_TIME_SWITCH_INTERVAL
from amslam.types import R_BODY_CAM

PERIOD = 0.1  # s, the control loop's (exploration.control_rate_hz 10)


def frame() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    H, W = 240, 320
    f = W / 2 / np.tan(np.radians(43.5))
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
    depth = np.random.default_rng(0).uniform(1, 6, (H, W)).astype(np.float32)
    T = np.eye(4)
    T[:3, :3] = R_BODY_CAM
    T[:3, 3] = [0.3, 0.2, 1.2]
    return depth, K, T


def local_window() -> WindowGrid:
    """The default local window (10 × 10 × 5 m at 0.1 m) around the frame's camera."""
    return WindowGrid(0.1, np.array([-47, -48, -38]), (100, 100, 50), LogOddsModel())


def measure(interval: float, seconds: float) -> dict[str, float]:
    depth, K, T = frame()
    window = local_window()
    sys.setswitchinterval(interval)
    stop = threading.Event()
    loops = [0, 0]

    def busy(k: int) -> None:
        covariances = {}
        while not stop.is_set():
            for i in range(2000):
                covariances[i] = np.trace(np.eye(6) * i)
            loops[k] += 1

    threads = [threading.Thread(target=busy, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    work, start = [], time.perf_counter()
    try:
        while time.perf_counter() - start < seconds:
            began = time.perf_counter()
            window.integrate_depth(depth, K, T, 2, 5.0)
            took = time.perf_counter() - began
            work.append(took)
            time.sleep(max(0.0, PERIOD - took))
    finally:
        stop.set()
        for t in threads:
            t.join()
        sys.setswitchinterval(0.005)
    w = np.array(work)
    return {
        "ticks": len(w),
        "expected": int(seconds / PERIOD),
        "over_period": int(np.count_nonzero(w > PERIOD)),
        "median_ms": 1000 * float(np.median(w)),
        "loops": sum(loops),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0)
    args = parser.parse_args()
    depth, K, T = frame()
    window = local_window()
    alone = np.median([_timed(lambda: window.integrate_depth(depth, K, T, 2, 5.0)) for _ in range(10)])
    print(f"load average {os.getloadavg()[0]:.2f}; one tick's work alone {1000 * alone:.1f} ms")
    print(
        "| switch interval | ticks made (of) | ticks over 100 ms | median tick work | other threads' loops |"
    )  # noqa: E501
    print("|---|---|---|---|---|")
    reference = None
    for interval in (0.005, 0.001, 0.0005, REAL_TIME_SWITCH_INTERVAL):
        m = measure(interval, args.seconds)
        reference = reference or m
        print(
            f"| {1000 * interval:g} ms | {m['ticks']} ({m['expected']}) | {m['over_period']} |"
            f" {m['median_ms']:.0f} ms ({m['median_ms'] / reference['median_ms']:.2f}×) |"
            f" {m['loops']} ({m['loops'] / reference['loops']:.2f}×) |"
        )
    print(f"load average {os.getloadavg()[0]:.2f}")


def _timed(fn) -> float:
    began = time.perf_counter()
    fn()
    return time.perf_counter() - began


if __name__ == "__main__":
    main()
