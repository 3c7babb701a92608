"""The thread rule holds: planning on the planner thread against a live control loop corrupts nothing.

On a real vehicle the planner thread queries SLAM (``slc_candidates``, ``landmarks``) and the map
(``path_costs``) while the control thread integrates frames and detections into them. The
runtime shares both backends behind one lock each (:mod:`amslam.sharing`). Here the simulator
supplies deterministic inputs (its detector inline), and the planning service is switched to
its planner thread, which plans back to back from each new snapshot for a whole flight: the
landmarks, key poses and map must come out exactly as from the same flight without a planner
thread. Python switches threads every few milliseconds by default; the test lets the other
thread in at every line of backend code, so the two threads interleave inside the backend calls
they make (as they do when a native library releases the GIL).
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from contextlib import contextmanager
from pathlib import Path

import numpy as np

import amslam.plugins
from amslam.geometry import wrap_angle
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.rundir import RunDir
from amslam.runner import Runner

from .missions import small_mission

TICKS = 160  # 16 s at 10 Hz
CLIMB = 40  # ticks to climb before the scripted turns start
QUEUED = 3  # plans kept waiting for the planner thread


@contextmanager
def switch_inside_backends():
    """Let the other thread in at every line of backend code, on both threads.

    Python hands the GIL over only every few milliseconds, so two threads rarely meet inside
    the same short backend call; native libraries that release the GIL meet there all the time.
    A trace function that sleeps a microsecond at each line executed in ``plugins/`` (a real
    sleep releases the GIL long enough for the waiting thread to take it; ``sleep(0)`` may not) makes
    every such interleaving possible within one flight.
    """
    backends = str(Path(amslam.plugins.__file__).parent)

    def on_line(frame, event, arg):
        if event == "line":
            time.sleep(1e-6)  # a real sleep: the waiting thread takes the GIL meanwhile
        return on_line

    def on_call(frame, event, arg):
        return on_line if frame.f_code.co_filename.startswith(backends) else None

    sys.settrace(on_call)
    threading.settrace(on_call)
    try:
        yield
    finally:
        sys.settrace(None)
        threading.settrace(None)


def fly(folder, registry, planner_thread: bool) -> dict:
    """A scripted flight (climb, then slow turns and a bob in place) through the runner's services.

    With ``planner_thread`` the planning service plans on its thread, one plan after another,
    the whole flight; without, nothing plans. Meanwhile the control thread asks the map for path
    costs between fixed places, as GoTo does. Returns those, the final map and semantic map.
    """
    folder.mkdir()
    path = small_mission(folder, mapping="{plugin: numpy}", planner="{plugin: greedy}")
    path.write_text(path.read_text().replace("slam: {plugin: odometry}", "slam: {plugin: gtsam}"))
    overrides = [
        "exploration.slc=true",
        "exploration.slc_min_travel=1",
    ]
    mission = load_mission(path, registry, overrides=overrides)
    runner = Runner(mission, registry, folder / "runs")
    runner.rundir = RunDir(runner.out_root, mission.name)
    runner._configure()  # the runner's own wiring: backends, then services with their shared backends
    runtime = runner._start_runtime()
    runtime.planning.threaded = planner_thread  # the simulator's inputs, a real vehicle's threads
    platform = runner.backends["platform"]
    platform.arm_and_takeoff(mission.model.robot.altitude)
    here = runtime.robot.home_world
    jobs: deque = deque()
    plans, errors, paths = 0, [], []
    # places around the start the control thread asks the map for paths between, as GoTo does
    probes = here + np.array(
        [[0.0, 0.0, 1.0], [2.5, 0.0, 1.0], [0.0, 2.5, 1.0], [-2.5, 0.0, 1.0], [0.0, -2.5, 1.0]]
    )
    cruise_z = float(here[2] + mission.model.robot.altitude)
    dt = 1.0 / mission.model.exploration.control_rate_hz
    for k in range(TICKS):
        snapshot = runtime.perception.step(dt)
        runtime.planning.observe(snapshot)
        if k > CLIMB:
            bob = 0.3 * np.sin(0.02 * (k - CLIMB))
            platform.set_setpoint(np.array([*here[:2], cruise_z + bob]), wrap_angle(0.04 * (k - CLIMB)))
        if k % 5 == 0:
            paths.append(runtime.robot.mapping.path_costs(probes, probes))
        while jobs and jobs[0].done():
            try:
                jobs.popleft().result()
                plans += 1
            except Exception as exc:  # noqa: BLE001 — collected: a plan must never fail here
                errors.append(f"{type(exc).__name__}: {exc}")
        while planner_thread and len(jobs) < QUEUED:  # keep the planner thread busy all the time
            jobs.append(runtime.planning.plan_async(cruise_z=cruise_z))
    for job in jobs:
        job.cancel()
    runtime.close()
    slam, mapping = runner.backends["slam"], runner.backends["mapping"]
    out = {
        "landmarks": sorted((lm.id, lm.class_name, tuple(lm.position)) for lm in slam.landmarks()),
        "keyposes": [kp.T_world_body for kp in slam.keyposes()],
        "occupied": np.array(sorted(map(tuple, mapping.occupied_points()))),
        "explored": mapping.explored_volume(),
        "paths": np.array(paths),
        "plans": plans,
        "errors": errors,
    }
    for backend in runner.backends.values():
        backend.close()
    runner.rundir.close()
    return out


def test_planning_on_its_thread_leaves_slam_and_map_as_without_it(tmp_path):
    registry = build_plugin_manager()
    alone = fly(tmp_path / "alone", registry, planner_thread=False)  # one thread: nothing to switch to
    with switch_inside_backends():
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
    # what the control thread's path queries saw along the flight (the map's search graph)
    np.testing.assert_array_equal(beside["paths"], alone["paths"])
