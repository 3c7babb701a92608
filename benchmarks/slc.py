"""Semantic loop closure solvers (paper 1 §V-C): exhaustive search vs the scalable solver.

Instances: n map centroids uniform in a 10×10×2 m box with ``--classes`` object classes; the
observation holds n points, of which a share ``--outliers`` are random (objects not in the map)
and the rest are map points moved by a random yaw and translation plus noise of RMS ``--sigma``
metres (3-D). A solver *succeeds* when it accepts, its yaw is within 0.05 rad and its translation
within 0.3 m of the truth, and at least 90 % of the true pairs are matched. *Spurious* is the mean
number of accepted pairs that are not true ones: a random point that lands within the gate of an
unmatched map point is a geometrically valid pair no solver can refuse (at n = 50 about 1.5 are
expected by volume). *Agree* counts instances where the scalable solver returns exactly the
exhaustive search's verdict and pairs. *scalable ms* is wall-clock time per instance; *cpu ms* is
the process's CPU time, which other load on a shared machine inflates much less.

    .venv/bin/python benchmarks/slc.py              # the tables of docs/slam.md
    .venv/bin/python benchmarks/slc.py --instances 20 --exhaustive-max 8
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from amslam.plugins.gtsam_slam.slc import SlcSolution, solve_exhaustive, solve_scalable
from amslam.plugins.gtsam_slam.synthetic import make_instance


def success(sol: SlcSolution, yaw: float, t: np.ndarray, truth: set) -> bool:
    if not sol.accepted:
        return False
    found = {tuple(p) for p in sol.pairs.tolist()}
    return (
        abs(np.angle(np.exp(1j * (sol.yaw - yaw)))) < 0.05
        and np.linalg.norm(sol.translation - t) < 0.3
        and len(found & truth) >= 0.9 * len(truth)
    )


def spurious(sol: SlcSolution, truth: set) -> int:
    return len({tuple(p) for p in sol.pairs.tolist()} - truth) if sol.accepted else 0


def same(a: SlcSolution, b: SlcSolution) -> bool:
    return a.accepted == b.accepted and {tuple(p) for p in a.pairs.tolist()} == {
        tuple(p) for p in b.pairs.tolist()
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--instances", type=int, default=100)
    ap.add_argument("--sigma", type=float, default=0.2, help="RMS 3-D noise of an observed centroid, m")
    ap.add_argument("--outliers", type=float, default=0.5)
    ap.add_argument("--classes", type=int, default=3)
    ap.add_argument("--exhaustive-max", type=int, default=9, help="largest n for the exhaustive search")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    print(
        f"SLC solvers: {args.instances} instances per row, sigma={args.sigma} m, "
        f"outliers={args.outliers:.0%}, classes={args.classes}"
    )
    head = (
        f"{'n=m':>4} | {'exhaustive ms':>13} {'succ':>5} | {'scalable ms':>11} {'cpu ms':>6} {'succ':>5} "
        f"{'spurious':>8} | {'agree':>5} | {'speed-up':>8}"
    )
    print(head)
    print("-" * len(head))
    for n in [5, 6, 7, 8, 9, 20, 50]:
        rng = np.random.default_rng(args.seed + n)
        te = ts = cs = 0.0
        se = ss = agree = spur = 0
        run_ex = n <= args.exhaustive_max
        for i in range(args.instances):
            inst = make_instance(rng, n, args.outliers, args.sigma, args.classes)
            A, B, ca, cb, yaw, t, truth = inst.A, inst.B, inst.ca, inst.cb, inst.yaw, inst.t, inst.truth
            t0, c0 = time.perf_counter(), time.process_time()
            sc = solve_scalable(A, B, ca, cb, rng=np.random.default_rng(i))
            ts += time.perf_counter() - t0
            cs += time.process_time() - c0
            ss += success(sc, yaw, t, truth)
            spur += spurious(sc, truth)
            if run_ex:
                t0 = time.perf_counter()
                ex = solve_exhaustive(A, B, ca, cb)
                te += time.perf_counter() - t0
                se += success(ex, yaw, t, truth)
                agree += same(ex, sc)
        m = args.instances
        ex_cols = f"{1e3 * te / m:>13.2f} {se / m:>5.0%}" if run_ex else f"{'—':>13} {'—':>5}"
        ratio = f"{te / ts:>7.1f}×" if run_ex else f"{'—':>8}"
        ag = f"{agree / m:>5.0%}" if run_ex else f"{'—':>5}"
        print(
            f"{n:>4} | {ex_cols} | {1e3 * ts / m:>11.2f} {1e3 * cs / m:>6.2f} {ss / m:>5.0%} {spur / m:>8.2f}"
            f" | {ag} | {ratio}"
        )


if __name__ == "__main__":
    main()
