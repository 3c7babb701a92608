"""The ``amslam sitl`` process: vehicle, camera and record set up from a mission, then served."""

from __future__ import annotations

import argparse
import functools
import shutil
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

import numpy as np

from amslam.errors import AmslamError, MissionError

if TYPE_CHECKING:
    from amslam.apps.sitl.camera import CameraStreamer
    from amslam.apps.sitl.record import TruthRecord
    from amslam.apps.sitl.vehicle import SitlVehicle

#: ``--once``: seconds the vehicle keeps talking after its landing, so that amslam hears it disarmed
ONCE_LINGER = 4.0


def _mavlink_peer_address(url: str) -> tuple[str, int]:
    """Where the vehicle sends: the ``udpin://HOST:PORT`` amslam listens on (0.0.0.0: this host)."""
    parts = urlsplit(url)
    if parts.scheme not in ("udpin", "udp") or parts.port is None:
        raise AmslamError(
            f"platform.url {url!r}: the SITL vehicle sends to the UDP port amslam listens on;"
            " give platform.url as udpin://HOST:PORT (e.g. udpin://127.0.0.1:14540)"
        )
    host = parts.hostname or "127.0.0.1"
    return ("127.0.0.1" if host in ("0.0.0.0", "") else host), parts.port


def _sim_params(mission, platform_params):
    """The simulator's parameters for the mission's world and camera (errors name the keys)."""
    from pydantic import ValidationError

    from amslam.plugins.sim.platform import SimPlatform

    cam = platform_params.camera
    section = {
        "world": platform_params.world,
        "camera": {
            "width": cam.width,
            "height": cam.height,
            "hfov_deg": cam.hfov_deg,
            "vfov_deg": cam.vfov_deg,
            "min_range": cam.min_range,
            "max_range": cam.max_range,
            "rate_hz": cam.rate_hz,
            "pitch_deg": cam.mount_pitch_deg,
        },
    }
    try:
        return SimPlatform.Params.model_validate(section, context={"mission_dir": mission.directory})
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            loc = [str(p) for p in err["loc"]]
            if loc[:1] == ["world"] and len(loc) > 1 and loc[1] in ("procedural", "mesh", "outdoor"):
                del loc[1]  # the kind pydantic tried, not a key of the mission
            where = ".".join(loc)
            key = f"platform.{where}" if where.startswith("world") else f"platform.camera ({where})"
            problems.append(f"{mission.source}: {key}: {err['msg']}")
        raise MissionError(problems) from None


def _gcs_address(text: str | None) -> tuple[tuple[str, int], ...]:
    if not text:
        return ()
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise AmslamError(f"--gcs {text!r}: give it as HOST:PORT (e.g. 127.0.0.1:14550)")
    return ((host, int(port)),)


def _load_sitl_mission(args: argparse.Namespace, registry):
    """The mission and its mavsdk platform parameters, checked for a SITL (errors name the key)."""
    from amslam.apps.commands import load_with_registry

    mission, registry = load_with_registry(args, registry)
    choice = mission.backends["platform"]
    if choice.plugin != "mavsdk":
        raise AmslamError(
            f"{mission.source}: platform.plugin is {choice.plugin!r}: amslam sitl flies a mavsdk mission"
            " (with platform.world); a sim mission flies with amslam run"
        )
    p = choice.params
    if p.world is None:
        raise AmslamError(
            f"{mission.source}: platform.world: the SITL vehicle needs a world to fly in (the sim"
            " platform's world section, e.g. {kind: procedural, size: [10, 8]})"
        )
    if p.camera.source != "stream":
        raise AmslamError(
            f"{mission.source}: platform.camera.source is {p.camera.source!r}: set it to stream, so"
            " that amslam fly reads the SITL's rendered frames"
        )
    return mission, p


def _started_simulator(mission, p, out: Path):
    """The simulator of the mission's world, started: its world built, the vehicle at its start."""
    from amslam.interfaces import RunContext
    from amslam.plugins.sim.platform import SimPlatform
    from amslam.runner import backend_rng

    sim_params = _sim_params(mission, p)
    notes: list[str] = []
    sim = SimPlatform()
    sim.configure(
        sim_params,
        RunContext(
            rng=backend_rng(mission.model.seed, "platform"),
            run_dir=out,
            emit=lambda name, **fields: notes.append(name),
            robot=mission.model.robot.spec(),
            mission_dir=mission.directory,
        ),
    )
    sim.start()
    return sim, sim_params


def _camera_streamer(world, p, noise, pose, seed: int):
    from amslam.apps.sitl.camera import CameraStreamer

    try:
        return CameraStreamer(
            world, p.camera.nominal_model(), noise, pose, p.camera.host, p.camera.port, seed=seed
        )
    except OSError as exc:
        raise AmslamError(
            f"cannot serve camera frames on {p.camera.host}:{p.camera.port} ({exc.strerror or exc});"
            " choose another with --set platform.camera.port=PORT (and the same for amslam fly)"
        ) from None


def run_camera_only(args: argparse.Namespace, registry) -> int:
    """``--camera-only URL``: the camera for an autopilot with its own vehicle (PX4 SITL), rendered
    at the pose it reports on URL (:mod:`amslam.apps.sitl.reported_pose`)."""
    from amslam.apps.sitl.reported_pose import ReportedPose
    from amslam.geometry import pose_from

    mission, p = _load_sitl_mission(args, registry)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(args.out) if args.out else Path("sitl") / f"{mission.name}-camera-{stamp}"
    sim, sim_params = _started_simulator(mission, p, out)
    if p.world_from_local is None:  # the start the simulator chose, as amslam sitl's vehicle
        T_world_local = np.eye(4)
        T_world_local[:3, 3] = sim.ground_truth()[:3, 3]
    else:
        x, y, z, yaw_deg = p.world_from_local
        T_world_local = pose_from(np.array([x, y, z]), float(np.radians(yaw_deg)))
    reported = ReportedPose(args.camera_only, T_world_local).start()
    try:
        streamer = _camera_streamer(sim.world, p, sim_params.camera, reported.pose, mission.model.seed)
    except AmslamError:
        reported.stop()
        raise
    origin = T_world_local[:3, 3]
    print(
        f"SITL camera in world {sim.world_summary().name!r}: rendering at the pose reported on"
        f" {args.camera_only}, local origin at ({origin[0]:.2f}, {origin[1]:.2f}, {origin[2]:.2f}) m;"
        f" frames on tcp {streamer.address}",
        flush=True,
    )
    streamer.start()
    try:
        heard = False
        while True:
            time.sleep(0.2)
            if not heard and reported.positions:
                heard = True
                print("ready: hearing the vehicle's position (Ctrl-C stops)", flush=True)
            if args.once and reported.was_armed and not reported.armed:
                time.sleep(ONCE_LINGER)
                break
    except KeyboardInterrupt:
        pass
    finally:
        streamer.stop()
        reported.stop()
        sim.close()
        stats = streamer.stats()
        print(f"camera: {stats['frames_sent']} frames sent, {reported.positions} positions heard", flush=True)
    return 0


def _truth_folder(out: str | None, mission_name: str) -> tuple[Path, Path | None]:
    """The run's truth folder (``--out``, else ``sitl/MISSION-STAMP``) and the outermost folder
    of its path that does not exist yet (removed again if the world cannot be built); None when
    the folder exists."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    folder = Path(out) if out else Path("sitl") / f"{mission_name}-{stamp}"
    made = None if folder.exists() else folder
    while made is not None and not made.parent.exists():
        made = made.parent
    return folder, made


def _serve(vehicle, write_summary: Callable[[], dict], *, once: bool) -> None:
    """Print the vehicle's log as it grows; after each flight (armed, then landed and disarmed)
    write the summary and say how it went; with ``once``, return after the first."""
    flew = False
    shown = 0
    while True:
        time.sleep(0.2)
        for t, what in list(vehicle.log)[shown:]:
            print(f"  t {t:7.2f}  {what}", flush=True)
            shown += 1
        state = vehicle.state()
        flew = flew or state["armed"]
        if flew and not state["armed"] and state["landed"]:
            summary = write_summary()
            flew = False
            print(
                f"down and disarmed: {len(summary['contacts'])} contacts, closest approach"
                f" {summary['closest_approach_m']} m, estimate off by {summary['estimate_error_m']} m",
                flush=True,
            )
            if once:
                # PX4 heartbeats say "disarmed" twice a second here: amslam waits up to 3 s to
                # hear it before it sends a disarm itself, which nobody would answer any more
                time.sleep(ONCE_LINGER)
                return


def _write_summary(
    record: TruthRecord,
    vehicle: SitlVehicle,
    streamer: CameraStreamer | None,
    mission: str,
    world: str,
    T_world_local: np.ndarray,
    mavlink_to: tuple[str, int],
) -> dict:
    """Write the truth folder's summary now (the vehicle's thread may be stepping the simulator):
    the vehicle's state and its estimate's error, the camera's stats, the closest approach."""
    status, truth = vehicle.truth()
    est = vehicle.state()
    start = T_world_local[:3, 3]
    drift = float(np.linalg.norm(truth[:3, 3] - start - np.array(est["estimate_local_enu"])))
    return record.summary(
        mission=mission,
        world=world,
        T_world_local=T_world_local.round(4).tolist(),
        mavlink_to=f"{mavlink_to[0]}:{mavlink_to[1]}",
        camera=streamer.stats() if streamer else None,
        vehicle=est,
        estimate_error_m=round(drift, 3),
        closest_approach_m=status.closest_approach,
        closest_to=status.closest_to,
        closest_position_world=status.closest_position,
        vehicle_log=[f"{t:.2f} {what}" for t, what in list(vehicle.log)],
    )


def run_sitl(args: argparse.Namespace, registry) -> int:
    from amslam.apps.sitl.record import TruthRecord
    from amslam.apps.sitl.vehicle import SitlVehicle

    mission, p = _load_sitl_mission(args, registry)
    if p.world_from_local is not None:
        raise AmslamError(
            f"{mission.source}: platform.world_from_local places another autopilot's vehicle in the"
            " world (amslam sitl --camera-only beside PX4 SITL); amslam sitl's own vehicle starts where"
            " the simulator chooses: remove it to fly this vehicle"
        )
    mavlink_to = _mavlink_peer_address(p.url)
    also_to = _gcs_address(args.gcs)
    out, made = _truth_folder(args.out, mission.name)
    record = TruthRecord(out)
    try:
        sim, sim_params = _started_simulator(mission, p, out)
    except BaseException:  # a world it cannot build (one error line): leave no empty truth folder
        record.close()
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)
        raise
    T_world_local = np.eye(4)
    T_world_local[:3, 3] = sim.ground_truth()[:3, 3]
    summary_of_world = sim.world_summary()
    record.world(summary_of_world, T_world_local)
    vehicle = SitlVehicle(
        sim,
        record,
        connect_to=mavlink_to,
        also_to=also_to,
        battery=args.battery,
        offboard_loss_timeout=1.0,  # PX4's COM_OF_LOSS_T default
        params={"MIS_TAKEOFF_ALT": mission.model.robot.altitude},
    )
    streamer = None
    if not args.no_camera:
        try:
            seed = mission.model.seed
            streamer = _camera_streamer(sim.world, p, sim_params.camera, vehicle.true_pose, seed)
        except AmslamError:
            vehicle.stop()
            raise
    start = T_world_local[:3, 3]
    sends = " and ".join(f"{h}:{port}" for h, port in (mavlink_to, *also_to))
    camera = f"camera frames on tcp {streamer.address}" if streamer else "no camera (--no-camera)"
    print(
        f"SITL vehicle in world {summary_of_world.name!r} at ({start[0]:.2f}, {start[1]:.2f}, {start[2]:.2f})"
        f" m, its local origin; MAVLink to udp {sends}; {camera}; truth in {out}",
        flush=True,
    )

    write_summary = functools.partial(
        _write_summary,
        record,
        vehicle,
        streamer,
        mission.name,
        summary_of_world.name,
        T_world_local,
        mavlink_to,
    )
    vehicle.start()
    if streamer:
        streamer.start()
    print("ready: waiting for amslam fly (Ctrl-C stops)", flush=True)
    try:
        _serve(vehicle, write_summary, once=args.once)
    except KeyboardInterrupt:
        pass  # SIGINT, SIGTERM: stop serving, keep the record
    finally:
        if streamer:
            streamer.stop()
        vehicle.stop()
        write_summary()
        record.close()
        sim.close()
        print(f"truth written to {out}", flush=True)
    return 0
