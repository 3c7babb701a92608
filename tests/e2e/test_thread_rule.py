"""The thread rule holds: planning on the planner thread against a live control loop corrupts nothing.

On a real vehicle the planner thread queries SLAM (``slc_candidates``, ``landmarks``) and the map
(``path_costs``) while the control thread integrates frames and detections into them. The
runtime shares both backends behind one lock each (:mod:`amslam.sharing`). Here the simulator
supplies deterministic inputs (its detector inline), and the planning service is switched to
its planner thread, which plans back to back from each new snapshot for a whole flight: the
landmarks, key poses and map must come out exactly as from the same flight without a planner
thread. Python switches threads every few milliseconds by default; the test makes it switch
every microsecond, so the two threads interleave inside every backend call they make.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from amslam.geometry import wrap_angle
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.rundir import RunDir
from amslam.runner import Runner

from .missions import small_mission

TICKS = 700  # 70 s at 10 Hz
CLIMB = 60  # ticks to climb before the scripted turns start


@pytest.fixture
def fast_thread_switches():
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    yield
    sys.setswitchinterval(before)


def fly(folder, registry, planner_thread: bool) -> dict:
    """A scripted flight (climb, then slow turns and a bob in place) through the runner's services.

    With ``planner_thread`` the planning service plans on its thread, one plan after another,
    the whole flight; without, nothing plans. Returns the final map and semantic map.
    """
    folder.mkdir()
    path = small_mission(folder, mapping="{plugin: numpy}", planner="{plugin: greedy}")
    path.write_text(path.read_text().replace("slam: {plugin: odometry}", "slam: {plugin: gtsam}"))
    mission = load_mission(path, registry, overrides=["exploration.slc=true", "exploration.slc_min_travel=1"])
    runner = Runner(mission, registry, folder / "runs")
    runner.rundir = RunDir(runner.out_root, mission.name)
    runner._configure()  # the runner's own wiring: backends, then services with their shared backends
    runtime = runner._start_runtime()
    runtime.planning.threaded = planner_thread  # the simulator's inputs, a real vehicle's threads
    platform = runner.backends["platform"]
    platform.arm_and_takeoff(mission.model.robot.altitude)
    here = runtime.robot.home_world
    job, plans, errors = None, 0, []
    dt = 1.0 / mission.model.exploration.control_rate_hz
    for k in range(TICKS):
        snapshot = runtime.perception.step(dt)
        runtime.planning.observe(snapshot)
        if k > CLIMB:
            bob = 0.3 * np.sin(0.02 * (k - CLIMB))
            setpoint = np.array([here[0], here[1], here[2] + mission.model.robot.altitude + bob])
            platform.set_setpoint(setpoint, wrap_angle(0.04 * (k - CLIMB)))
        if planner_thread and (job is None or job.done()):
            if job is not None:
                try:
                    job.result()
                    plans += 1
                except Exception as exc:  # noqa: BLE001 — collected: a plan must never fail here
                    errors.append(f"{type(exc).__name__}: {exc}")
            job = runtime.planning.plan_async(cruise_z=float(here[2] + mission.model.robot.altitude))
    if job is not None:
        job.cancel()
    runtime.close()
    slam, mapping = runner.backends["slam"], runner.backends["mapping"]
    out = {
        "landmarks": sorted((lm.id, lm.class_name, tuple(lm.position)) for lm in slam.landmarks()),
        "keyposes": [kp.T_world_body for kp in slam.keyposes()],
        "occupied": np.array(sorted(map(tuple, mapping.occupied_points()))),
        "explored": mapping.explored_volume(),
        "plans": plans,
        "errors": errors,
    }
    for backend in runner.backends.values():
        backend.close()
    runner.rundir.close()
    return out


def test_planning_on_its_thread_leaves_slam_and_map_as_without_it(tmp_path, fast_thread_switches):
    registry = build_plugin_manager()
    alone = fly(tmp_path / "alone", registry, planner_thread=False)
    beside = fly(tmp_path / "beside", registry, planner_thread=True)
    assert beside["errors"] == [], beside["errors"][:3]
    assert beside["plans"] >= 20, "the planner thread must plan throughout the flight"
    assert len(alone["landmarks"]) >= 2, "the flight must map objects"
    assert beside["landmarks"] == alone["landmarks"]
    assert len(beside["keyposes"]) == len(alone["keyposes"])
    for a, b in zip(alone["keyposes"], beside["keyposes"], strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(beside["occupied"], alone["occupied"])
    assert beside["explored"] == alone["explored"]
