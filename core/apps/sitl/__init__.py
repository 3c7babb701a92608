"""``amslam sitl MISSION``: a software-in-the-loop vehicle to fly a ``mavsdk`` mission against.

One process holds what a PX4 SITL with a depth camera would, for the mission's own settings:

* the MAVLink vehicle (:class:`~amslam.apps.sitl.vehicle.SitlVehicle`: the emulator's PX4
  protocol over the simulator's vehicle, VIO drift and contact check) at the start of the world
  in ``platform.world``, sending to the ``udpin://HOST:PORT`` of ``platform.url``;
* the rendered RGB-D camera (:class:`~amslam.apps.sitl.camera.CameraStreamer`) on
  ``platform.camera.host:port``, with the mission's camera size, field of view, rate and mount;
* its own record of the truth (:class:`~amslam.apps.sitl.record.TruthRecord`) in ``--out``.

Then ``amslam fly MISSION`` (same file, ``camera.source: stream``) flies the mission against it.
See docs/flight.md, "Software in the loop".

With ``--camera-only URL`` the process is the camera alone, for an autopilot that brings its own
vehicle (PX4 SITL): it renders the world at the pose that autopilot reports on ``URL``
(:mod:`amslam.apps.sitl.reported_pose`). ``--no-camera --gcs HOST:PORT`` makes this process's
vehicle stand in for PX4 SITL in front of it.
"""

from __future__ import annotations

import argparse

import amslam
from amslam.cli import Command


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mission", help="a mavsdk mission with platform.world (e.g. sitl_small)")
    parser.add_argument(
        "--out",
        help="folder for the truth: ground_truth.tum, estimate.tum, reachable.npz, sitl.json"
        " (default: sitl/<mission>-<time>)",
    )
    parser.add_argument(
        "--set",
        dest="set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a mission key, as for amslam fly (give both the same ones)",
    )
    parser.add_argument(
        "--once", action="store_true", help="exit when the vehicle is down and disarmed after a flight"
    )
    parser.add_argument("--battery", type=float, default=0.9, help="charge at start, 0–1 (default 0.9)")
    parser.add_argument(
        "--no-camera",
        action="store_true",
        help="the vehicle only, as PX4 SITL is (a camera then comes from --camera-only)",
    )
    parser.add_argument(
        "--gcs",
        metavar="HOST:PORT",
        help="also send the vehicle's MAVLink there, as PX4 SITL sends its ground-station stream"
        " to UDP 14550",
    )
    parser.add_argument(
        "--camera-only",
        metavar="URL",
        help="no vehicle: render the camera at the pose an autopilot (PX4 SITL) reports on URL"
        " (udpin://0.0.0.0:14550), placed in the world by platform.world_from_local",
    )


def _run(args: argparse.Namespace, registry) -> int:
    from amslam.apps.sitl.run import run_camera_only, run_sitl

    return (run_camera_only if args.camera_only else run_sitl)(args, registry)


@amslam.hookimpl
def amslam_cli_commands():
    return {
        "sitl": Command(
            "a software-in-the-loop vehicle (MAVLink + rendered depth camera) for amslam fly MISSION",
            _arguments,
            _run,
        )
    }
