"""The ``amslam sitl`` process: vehicle, camera and record set up from a mission, then served."""

from __future__ import annotations

import argparse
import time
from datetime import datetime
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

from amslam.errors import AmslamError, MissionError

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


def run_sitl(args: argparse.Namespace, registry) -> int:
    from amslam.apps.commands import load_with_registry
    from amslam.apps.sitl.camera import CameraStreamer
    from amslam.apps.sitl.record import TruthRecord
    from amslam.apps.sitl.vehicle import SitlVehicle
    from amslam.interfaces import RunContext
    from amslam.plugins.sim.platform import SimPlatform
    from amslam.runner import backend_rng

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
    mavlink_to = _mavlink_peer_address(p.url)
    sim_params = _sim_params(mission, p)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(args.out) if args.out else Path("sitl") / f"{mission.name}-{stamp}"
    record = TruthRecord(out)
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
    sim.start()  # builds the world and its ray-casting scene, places the vehicle at its start
    T_world_local = np.eye(4)
    T_world_local[:3, 3] = sim.ground_truth()[:3, 3]
    summary_of_world = sim.world_summary()
    record.world(summary_of_world, T_world_local)
    vehicle = SitlVehicle(
        sim,
        record,
        connect_to=mavlink_to,
        battery=args.battery,
        offboard_loss_timeout=1.0,  # PX4's COM_OF_LOSS_T default
        params={"MIS_TAKEOFF_ALT": mission.model.robot.altitude},
    )
    try:
        streamer = CameraStreamer(
            sim.world,
            p.camera.nominal_model(),
            sim_params.camera,
            vehicle.true_pose,
            p.camera.host,
            p.camera.port,
            seed=mission.model.seed,
        )
    except OSError as exc:
        vehicle.stop()
        raise AmslamError(
            f"cannot serve camera frames on {p.camera.host}:{p.camera.port} ({exc.strerror or exc});"
            " choose another with --set platform.camera.port=PORT (and the same for amslam fly)"
        ) from None
    start = T_world_local[:3, 3]
    print(
        f"SITL vehicle in world {summary_of_world.name!r} at ({start[0]:.2f}, {start[1]:.2f}, {start[2]:.2f})"
        f" m, its local origin; MAVLink to udp {mavlink_to[0]}:{mavlink_to[1]}; camera frames on tcp"
        f" {streamer.address}; truth in {out}",
        flush=True,
    )

    def write_summary() -> dict:
        status, truth = vehicle.truth()  # the vehicle's thread may be stepping the simulator
        est = vehicle.state()
        drift = float(np.linalg.norm(truth[:3, 3] - start - np.array(est["estimate_local_enu"])))
        return record.summary(
            mission=mission.name,
            world=summary_of_world.name,
            T_world_local=T_world_local.round(4).tolist(),
            mavlink_to=f"{mavlink_to[0]}:{mavlink_to[1]}",
            camera=streamer.stats(),
            vehicle=est,
            estimate_error_m=round(drift, 3),
            closest_approach_m=status.closest_approach,
            closest_to=status.closest_to,
            closest_position_world=status.closest_position,
            vehicle_log=[f"{t:.2f} {what}" for t, what in list(vehicle.log)],
        )

    vehicle.start()
    streamer.start()
    print("ready: waiting for amslam fly (Ctrl-C stops)", flush=True)
    flew = False
    shown = 0
    try:
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
                if args.once:
                    # PX4 heartbeats say "disarmed" twice a second here: amslam waits up to 3 s to
                    # hear it before it sends a disarm itself, which nobody would answer any more
                    time.sleep(ONCE_LINGER)
                    break
    except KeyboardInterrupt:
        pass  # SIGINT, SIGTERM: stop serving, keep the record
    finally:
        streamer.stop()
        vehicle.stop()
        write_summary()
        record.close()
        sim.close()
        print(f"truth written to {out}", flush=True)
    return 0
