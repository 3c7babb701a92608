"""Simulator benchmark: ms per rendered frame, vehicle integration speed, real-time factor.

Prints three tables:

1. **Rendering** at 640×480 and 320×240 in the default procedural building, from a fixed pose in
   a furnished room: the full sensor model (depth noise and dropout, instance and class masks,
   shaded RGB), depth and masks without RGB, and — the reference, measured in the same run —
   Open3D's raw ``RaycastingScene.cast_rays`` on the same prepared rays; the ratio says what the
   sensor model costs on top of the ray casting itself.
2. **Vehicle**: simulated seconds integrated per wall-clock second by ``advance()`` alone
   (physics at 50 Hz, VIO, collision checks, no rendering).
3. **Real-time factor** of a whole mission (default: the packaged demo mission) through
   ``amslam.runner``: simulated time / wall-clock time, and the share of wall time spent in the
   platform (``advance`` + ``capture``), measured by wrapping the platform's methods.

Run: ``.venv/bin/python benchmarks/sim.py [--mission demo] [--no-mission] [--repeats 10]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from amslam.interfaces import RunContext
from amslam.plugins.sim.camera import CameraParams, Renderer, viewing_pose
from amslam.plugins.sim.platform import SimPlatform


def _best_ms(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def _platform(**params) -> SimPlatform:
    plat = SimPlatform()
    plat.configure(SimPlatform.Params(**params), RunContext(rng=np.random.default_rng(7), run_dir=Path(".")))
    plat.start()
    return plat


def rendering_table(repeats: int) -> None:
    plat = _platform()
    world = plat.world
    # look into a furnished room from its doorway-side: many objects, walls at 1–6 m
    obj = max(
        world.objects, key=lambda o: sum(np.linalg.norm(o.centroid - p.centroid) < 3 for p in world.objects)
    )
    print(f"world: {world.name}, {world.n_triangles} triangles, {len(world.objects)} objects")
    print()
    head = ("resolution", "full frame", "no RGB", "cast_rays", "full / cast_rays")
    print(f"{head[0]:>11} | {head[1]:>10} | {head[2]:>8} | {head[3]:>9} | {head[4]:>16}")
    print(f"{'':>11} | {'ms':>10} | {'ms':>8} | {'ms':>9} | {'':>16}")
    print("-" * 68)
    for w, h in ((640, 480), (320, 240)):
        full = CameraParams(width=w, height=h)
        nrgb = CameraParams(width=w, height=h, rgb=False)
        r_full, r_nrgb = Renderer(full.model(), full), Renderer(nrgb.model(), nrgb)
        T_wc = viewing_pose(world, obj.centroid, full.model().T_body_cam)
        rng = np.random.default_rng(0)
        rays = r_full.rays(T_wc)
        import open3d as o3d

        rays_t = o3d.core.Tensor(rays)
        r_full.render(world, T_wc, rng)  # warm-up
        ms_full = _best_ms(lambda r=r_full, T=T_wc, g=rng: r.render(world, T, g), repeats)
        ms_nrgb = _best_ms(lambda r=r_nrgb, T=T_wc, g=rng: r.render(world, T, g), repeats)
        ms_cast = _best_ms(lambda rt=rays_t: world.scene.cast_rays(rt, nthreads=0), repeats)
        ratio = ms_full / ms_cast
        print(f"{w:>5}×{h:<5} | {ms_full:>10.1f} | {ms_nrgb:>8.1f} | {ms_cast:>9.1f} | {ratio:>15.1f}×")
    print()


def vehicle_table() -> None:
    plat = _platform(camera={"width": 32, "height": 24})
    plat.arm_and_takeoff(1.2)
    plat.advance(4.0)
    goals = [np.array([6.0, 7.0, 1.2]), np.array([1.5, 7.0, 1.5])]
    t0 = time.perf_counter()
    sim = 0.0
    for i in range(20):
        plat.set_setpoint(goals[i % 2], 0.0)
        for _ in range(30):
            plat.advance(0.1)
            sim += 0.1
    wall = time.perf_counter() - t0
    print(
        f"vehicle: {sim:.0f} s simulated in {wall:.2f} s wall ({sim / wall:.0f}× real time), advance() only"
    )
    print()


def mission_table(mission: str) -> None:
    from amslam.mission import load_mission
    from amslam.registry import build_plugin_manager
    from amslam.runner import Runner

    registry = build_plugin_manager()
    m = load_mission(mission, registry)
    spent = {"advance": 0.0, "capture": 0.0, "frames": 0}
    orig_adv, orig_cap = SimPlatform.advance, SimPlatform.capture

    def advance(self, dt):
        t = time.perf_counter()
        try:
            return orig_adv(self, dt)
        finally:
            spent["advance"] += time.perf_counter() - t

    def capture(self):
        t = time.perf_counter()
        try:
            f = orig_cap(self)
            spent["frames"] += f is not None
            return f
        finally:
            spent["capture"] += time.perf_counter() - t

    SimPlatform.advance, SimPlatform.capture = advance, capture
    try:
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            result = Runner(m, registry, Path(out)).run()
            wall = time.perf_counter() - t0
    finally:
        SimPlatform.advance, SimPlatform.capture = orig_adv, orig_cap
    mt = result.metrics
    sim = float(mt.get("sim_duration_s", float("nan")))
    dist, explored = mt.get("distance_m", float("nan")), mt.get("explored_percent", float("nan"))
    print(f"mission {m.name!r}: verdict {result.verdict!r}, distance {dist:.0f} m, explored {explored} %")
    head = ("simulated s", "wall s", "real-time factor", "frames", "platform share")
    print(f"{head[0]:>12} | {head[1]:>7} | {head[2]:>16} | {head[3]:>6} | {head[4]:>14}")
    print("-" * 70)
    share = (spent["advance"] + spent["capture"]) / wall
    print(
        f"{sim:>12.1f} | {wall:>7.1f} | {sim / wall:>15.2f}× | {spent['frames']:>6} | {100 * share:>13.1f}%"
    )
    print(
        f"  platform: advance {spent['advance']:.2f} s, capture (rendering) {spent['capture']:.2f} s "
        f"= {1e3 * spent['capture'] / max(1, spent['frames']):.1f} ms per frame"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--mission", default="demo", help="mission for the real-time factor")
    ap.add_argument("--no-mission", action="store_true", help="skip the whole-mission measurement")
    args = ap.parse_args()
    rendering_table(args.repeats)
    vehicle_table()
    if not args.no_mission:
        mission_table(args.mission)


if __name__ == "__main__":
    main()
