"""Planner timings: COP with Algorithm 1 against the tsp and greedy baselines on the same instances.

Random, seeded instances stand in for a building: ``|V|`` viewpoints spread over a 40 m × 40 m
area on three floors (z = 1.2, 4.2, 7.2 m), random headings, gains of 5–60 m³, and 5 loop-closure
candidates with IG 0.05–1.5. Path costs are Euclidean distances stretched by a random symmetric
detour factor in [1, 1.4] (what A* through rooms and doors adds). Every planner sees exactly the same
requests; the figure reported is the median over ``--repeats`` runs of each instance, averaged
over ``--seeds`` instances, with the ratio to the tsp baseline measured in the same run.

Usage::

    .venv/bin/python benchmarks/planner.py                    # |V| = 10, 50, 200; 5 seeds
    .venv/bin/python benchmarks/planner.py --sizes 10 50 --seeds 3 --repeats 5
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from amslam.lib.tours import planning_graph
from amslam.plugins.planners.cop import CopPlanner, cop_tour, refine_with_slc
from amslam.plugins.planners.correlation import fov_correlation
from amslam.plugins.planners.greedy import GreedyPlanner
from amslam.plugins.planners.tsp import TspPlanner
from amslam.types import CameraModel, PlanRequest, SlcCandidate, Viewpoint

#: A D435i-like depth camera (87° × 58°, 5 m).
CAMERA = CameraModel.from_fov(848, 480, 87.0, 58.0, min_range=0.3, max_range=5.0)
SLC_CANDIDATES = 5


def random_request(n: int, seed: int) -> PlanRequest:
    """A seeded building-like instance with ``n`` viewpoints and 5 loop-closure candidates."""
    rng = np.random.default_rng(seed)
    floors = np.array([1.2, 4.2, 7.2])
    pos = np.column_stack([rng.uniform(0, 40, (n, 2)), rng.choice(floors, n)])
    cand = np.column_stack([rng.uniform(0, 40, (SLC_CANDIDATES, 2)), rng.choice(floors, SLC_CANDIDATES)])
    start = np.array([20.0, 20.0, 1.2])
    nodes = np.vstack([start, pos, cand])
    dist = np.linalg.norm(nodes[:, None] - nodes[None], axis=-1)
    stretch = rng.uniform(1.0, 1.4, dist.shape)
    stretch = np.triu(stretch, 1) + np.triu(stretch, 1).T + np.eye(len(nodes))
    cost = dist * stretch
    vps = tuple(
        Viewpoint(i, pos[i], float(rng.uniform(-np.pi, np.pi)), float(rng.uniform(5, 60)), pos[i], 50)
        for i in range(n)
    )
    cands = tuple(
        SlcCandidate(1000 + j, cand[j], 0.0, (1, 2, 3), float(rng.uniform(0.05, 1.5)))
        for j in range(SLC_CANDIDATES)
    )
    return PlanRequest(
        start=start,
        start_yaw=0.0,
        viewpoints=vps,
        costs=cost[: n + 1, : n + 1],
        camera=CAMERA,
        slc_candidates=cands,
        slc_costs=cost[n + 1 :, : n + 1],
    )


def timed(fn, repeats: int) -> tuple[float, object]:
    """Median wall time (s) of ``fn()`` over ``repeats`` calls, and its last result."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def stages(planner: CopPlanner, request: PlanRequest, repeats: int) -> dict[str, float]:
    """Median times of COP's stages: graph, correlation, construction, Algorithm 1."""
    p = planner.params
    t_graph, graph = timed(lambda: planning_graph(request, p.min_gain, with_slc=True), repeats)
    pos = np.array([v.position for v in graph.viewpoints])
    yaw = np.array([v.yaw for v in graph.viewpoints])
    t_corr, w = timed(lambda: fov_correlation(pos, yaw, request.camera, samples=p.fov_samples), repeats)
    budget = planner.summary.budget
    t_cop, tour = timed(lambda: cop_tour(graph.costs, graph.gains, w, budget), repeats)
    t_alg1, _ = timed(
        lambda: refine_with_slc(
            graph, tour, w, request.slc_candidates, budget * p.slc_budget_factor, p, request.slc_gain
        ),
        repeats,
    )
    return {"graph": t_graph, "corr": t_corr, "construct": t_cop, "alg1": t_alg1}


def main(argv: list[str] | None = None) -> None:
    """Print the timing table (Markdown)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 50, 200])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    print(
        f"COP + Algorithm 1 vs tsp and greedy; {SLC_CANDIDATES} SLC candidates; "
        f"median of {args.repeats} runs, mean over {args.seeds} seeds; times in ms\n"
    )
    print(
        "| V | cop+alg1 | graph | corr | construct | alg1 | tsp | greedy | cop/tsp | "
        "cop sel | refined stops | slc | refined m | budget m | tsp m |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        rows = []
        for seed in range(args.seeds):
            req = random_request(n, seed)
            cop, tsp, greedy = CopPlanner(), TspPlanner(), GreedyPlanner()
            t_cop, tour = timed(lambda cop=cop, req=req: cop.plan(req), args.repeats)
            t_tsp, _ = timed(lambda tsp=tsp, req=req: tsp.plan(req), args.repeats)
            t_greedy, _ = timed(lambda greedy=greedy, req=req: greedy.plan(req), args.repeats)
            st = stages(cop, req, args.repeats)
            rows.append(
                {
                    "cop": t_cop,
                    "tsp": t_tsp,
                    "greedy": t_greedy,
                    **st,
                    "sel": cop.summary.selected,
                    "stops": sum(t.kind.value == "explore" for t in tour),
                    "slc": len(cop.summary.slc_inserted),
                    "cop_m": cop.summary.refined_cost,
                    "budget": cop.summary.budget,
                    "tsp_m": tsp.last_cost,
                }
            )

        def mean(key: str, rows=rows) -> float:
            return float(np.mean([r[key] for r in rows]))

        ms = {k: 1e3 * mean(k) for k in ("cop", "graph", "corr", "construct", "alg1", "tsp", "greedy")}
        print(
            f"| {n} | {ms['cop']:.1f} | {ms['graph']:.1f} | {ms['corr']:.1f} | {ms['construct']:.1f} | "
            f"{ms['alg1']:.2f} | {ms['tsp']:.1f} | {ms['greedy']:.2f} | {ms['cop'] / ms['tsp']:.2f} | "
            f"{mean('sel'):.1f} | {mean('stops'):.1f} | {mean('slc'):.1f} | {mean('cop_m'):.1f} | "
            f"{mean('budget'):.1f} | {mean('tsp_m'):.1f} |"
        )


if __name__ == "__main__":
    main()
