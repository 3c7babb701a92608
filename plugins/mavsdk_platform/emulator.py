"""A small MAVLink vehicle emulator: the peer the real MAVSDK core talks to in tests.

It speaks MAVLink 2 over loopback UDP like a PX4 quadrotor, enough for the ``mavsdk`` platform
plugin (and any other MAVSDK client) to connect, arm, take off, fly offboard position setpoints,
land and disarm:

* ``HEARTBEAT`` from component 1: ``MAV_AUTOPILOT_PX4``, ``MAV_TYPE_QUADROTOR``, the armed flag,
  and the PX4 custom mode kept current (main mode in bits 16–23, sub mode in bits 24–31:
  ``OFFBOARD`` while offboard, ``AUTO.TAKEOFF``/``AUTO.LOITER``/``AUTO.LAND``/``AUTO.RTL``);
* ``COMMAND_ACK`` for arm/disarm, take-off, land, return, set-mode (``MAV_CMD_DO_SET_MODE``),
  message-interval and message requests; any command named in ``refuse`` is answered
  ``MAV_RESULT_DENIED``, unknown commands ``MAV_RESULT_UNSUPPORTED``;
* ``LOCAL_POSITION_NED``, ``ATTITUDE``, ``EXTENDED_SYS_STATE`` (landed state), ``SYS_STATUS`` and
  ``BATTERY_STATUS`` (a battery draining while armed), ``PARAM_VALUE`` for a few parameters;
* ``SET_POSITION_TARGET_LOCAL_NED`` moves a point mass towards the target with horizontal,
  vertical and yaw-rate limits (no attitude dynamics: this checks the protocol, not control).

PX4's own failsafes that the plugin relies on are reproduced: offboard is refused without a
recent setpoint, and when setpoints stop for ``offboard_loss_timeout`` seconds the vehicle lands
by itself (PX4 ``COM_OF_LOSS_T`` → ``COM_OBL_ACT`` = land); it disarms after touching down
(``COM_DISARM_LAND``). :meth:`cut_link` silences the radio in both directions.

The emulator keeps its own trace of true positions (:attr:`trace`, NED, metres) and a log of
what it did (:attr:`log`), so a test can check what the vehicle really flew.

Example::

    with MavlinkVehiclePeer(connect_to=("127.0.0.1", port)) as peer:
        ...  # MAVSDK listens with "udpin://127.0.0.1:PORT"
        assert peer.trace[-1].armed is False
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

#: PX4 main modes (``px4_custom_mode.h``).
PX4_MAIN = {"MANUAL": 1, "ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "ACRO": 5, "OFFBOARD": 6, "STABILIZED": 7}
#: PX4 AUTO sub modes.
PX4_AUTO = {"READY": 1, "TAKEOFF": 2, "LOITER": 3, "MISSION": 4, "RTL": 5, "LAND": 6}

#: Modes of the emulator → (main, sub).
MODES: dict[str, tuple[int, int]] = {
    "POSCTL": (PX4_MAIN["POSCTL"], 0),
    "OFFBOARD": (PX4_MAIN["OFFBOARD"], 0),
    "TAKEOFF": (PX4_MAIN["AUTO"], PX4_AUTO["TAKEOFF"]),
    "LOITER": (PX4_MAIN["AUTO"], PX4_AUTO["LOITER"]),
    "RTL": (PX4_MAIN["AUTO"], PX4_AUTO["RTL"]),
    "LAND": (PX4_MAIN["AUTO"], PX4_AUTO["LAND"]),
}

#: Commands by the name used in ``refuse``.
COMMAND_NAMES = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: "arm",
    mavlink.MAV_CMD_NAV_TAKEOFF: "takeoff",
    mavlink.MAV_CMD_NAV_LAND: "land",
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: "return",
    mavlink.MAV_CMD_DO_SET_MODE: "set_mode",
}


def px4_custom_mode(mode: str) -> int:
    """The HEARTBEAT ``custom_mode`` of a PX4 mode name."""
    main, sub = MODES[mode]
    return (main << 16) | (sub << 24)


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port nobody is bound to right now (bind to port 0 and release it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


@dataclass(frozen=True)
class TracePoint:
    """The emulated vehicle's true state at one physics step (NED, metres, radians)."""

    t: float
    position: np.ndarray
    yaw: float
    mode: str
    armed: bool
    landed: bool


class _Sender:
    """File-like object pymavlink writes packed messages to."""

    def __init__(self, peer: MavlinkVehiclePeer):
        self.peer = peer

    def write(self, data: bytes) -> None:
        self.peer._send_raw(data)


@dataclass
class MavlinkVehiclePeer:
    """A PX4-like quadrotor on a UDP socket (see the module docstring).

    Args:
        connect_to: (host, port) of a MAVSDK listening with ``udpin://``; the emulator sends
            there first. Without it the emulator only answers whoever writes to :attr:`port`
            (MAVSDK with ``udpout://127.0.0.1:PORT``).
        max_speed: horizontal speed limit, m/s.
        max_vertical_speed: climb and descent speed limit, m/s.
        max_yaw_rate: rad/s.
        position_gain: 1/s, the point mass flies at ``gain × distance`` below the limits.
        land_speed: descent speed in LAND, m/s.
        rate_hz: physics and telemetry rate.
        battery: charge at start, 0–1; ``battery_drain`` per second while armed.
        refuse: command names to answer with ``MAV_RESULT_DENIED`` (``arm``, ``disarm``,
            ``takeoff``, ``land``, ``return``, ``set_mode``, or ``offboard`` for set-mode to
            offboard only).
        offboard_loss_timeout: PX4 ``COM_OF_LOSS_T``: seconds without a setpoint before landing.
        disarm_after_landing: PX4 ``COM_DISARM_LAND``, s.
        yaw: initial heading (NED, rad).
        also_to: more (host, port) addresses every message is sent to, as PX4 SITL sends its
            ground-station stream to UDP 14550 beside the offboard API's 14540.
    """

    connect_to: tuple[str, int] | None = None
    also_to: tuple[tuple[str, int], ...] = ()
    max_speed: float = 2.0
    max_vertical_speed: float = 1.5
    max_yaw_rate: float = 2.0
    position_gain: float = 2.0
    land_speed: float = 1.0
    rate_hz: float = 50.0
    battery: float = 0.9
    battery_drain: float = 0.0
    refuse: frozenset[str] = frozenset()
    offboard_loss_timeout: float = 0.5
    disarm_after_landing: float = 0.5
    yaw: float = 0.0
    params: dict[str, float] = field(default_factory=lambda: {"MIS_TAKEOFF_ALT": 2.5})
    trace: list[TracePoint] = field(default_factory=list, init=False)
    log: list[tuple[float, str]] = field(default_factory=list, init=False)
    #: every command answered: (time, name, MAV_RESULT) — names as in ``refuse``, else the MAV_CMD id
    commands: list[tuple[float, str, int]] = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        self.refuse = frozenset(self.refuse)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self._sock.setblocking(False)
        self._remote: tuple[str, int] | None = self.connect_to
        self._mav = mavlink.MAVLink(_Sender(self), srcSystem=1, srcComponent=1)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._link_up = True
        self._t0 = time.monotonic()
        # vehicle state (NED)
        self.position = np.zeros(3)
        self.mode = "POSCTL"
        self.armed = False
        self.landed = True
        self._setpoint: np.ndarray | None = None
        self._setpoint_yaw = self.yaw
        self._setpoint_time = -math.inf
        self._hold = np.zeros(3)
        self._touchdown: float | None = None
        self._next = {"heartbeat": 0.0, "ext": 0.0, "sys": 0.0}
        self.setpoints_received = 0
        self._answering = ""

    # -- lifecycle ----------------------------------------------------------------------------

    @property
    def port(self) -> int:
        """The UDP port the emulator is bound to."""
        return self._sock.getsockname()[1]

    def start(self) -> MavlinkVehiclePeer:
        """Start the physics and radio thread."""
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="mavlink-peer", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close the socket (safe to call twice)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._sock.close()

    def __enter__(self) -> MavlinkVehiclePeer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def now(self) -> float:
        """Seconds since :meth:`start`."""
        return time.monotonic() - self._t0

    def cut_link(self) -> None:
        """Silence the radio both ways (the vehicle keeps flying on its own)."""
        with self._lock:
            self._link_up = False
            self._note("link cut")

    def restore_link(self) -> None:
        with self._lock:
            self._link_up = True
            self._note("link restored")

    def set_battery(self, charge: float) -> None:
        """Set the remaining charge (0–1), e.g. to trigger a low-battery failsafe."""
        with self._lock:
            self.battery = float(charge)

    def _note(self, what: str) -> None:
        self.log.append((round(self.now(), 3), what))

    # -- radio --------------------------------------------------------------------------------

    def _send_raw(self, data: bytes) -> None:
        if not self._link_up:
            return
        for to in (self._remote, *self.also_to) if self._remote is not None else self.also_to:
            with contextlib.suppress(OSError):  # the client went away; keep flying like a vehicle
                self._sock.sendto(data, to)

    def _receive(self) -> None:
        while True:
            try:
                data, addr = self._sock.recvfrom(4096)
            except (BlockingIOError, OSError):
                return
            if not self._link_up:
                continue
            self._remote = addr
            try:
                messages = self._mav.parse_buffer(data) or []
            except mavlink.MAVError:
                continue
            for msg in messages:
                self._handle(msg)

    def _handle(self, msg) -> None:
        kind = msg.get_type()
        if kind == "COMMAND_LONG":
            self._command(msg.command, [msg.param1, msg.param2, msg.param3, msg.param4, msg.param7])
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._position_target(msg)
        elif kind == "PARAM_REQUEST_READ":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            self._param_value(name.rstrip("\x00"))
        elif kind == "PARAM_REQUEST_LIST":
            for name in self.params:
                self._param_value(name)
        elif kind == "PARAM_SET":
            name = (msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()).rstrip("\x00")
            self.params[name] = float(msg.param_value)
            self._note(f"param {name}={msg.param_value:g}")
            self._param_value(name)

    def _param_value(self, name: str) -> None:
        if name not in self.params:
            return
        names = list(self.params)
        self._mav.param_value_send(
            name.encode(),
            self.params[name],
            mavlink.MAV_PARAM_TYPE_REAL32,
            len(names),
            names.index(name),
        )

    def _ack(self, command: int, result: int) -> None:
        self.commands.append((round(self.now(), 3), self._answering, result))
        self._mav.command_ack_send(command, result)

    def _command(self, command: int, p: list[float]) -> None:
        name = COMMAND_NAMES.get(command)
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and p[0] < 0.5:
            name = "disarm"
        self._answering = name or str(command)
        ok, denied = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
        if name in self.refuse:
            self._note(f"refused {name}")
            self._ack(command, denied)
            return
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] >= 0.5:
                if not self.armed:
                    self.armed = True
                    self._touchdown = None
                    self._hold = self.position.copy()
                    self._note("armed")
                self._ack(command, ok)
            elif self.landed or int(p[1]) == 21196:
                if self.armed:
                    self.armed = False
                    self._note("disarmed")
                self._ack(command, ok)
            else:
                self._ack(command, denied)  # PX4 refuses to disarm in the air
        elif command == mavlink.MAV_CMD_NAV_TAKEOFF:
            if not self.armed:
                self._ack(command, denied)
                return
            self._set_mode("TAKEOFF")
            self._ack(command, ok)
        elif command == mavlink.MAV_CMD_NAV_LAND:
            self._set_mode("LAND")
            self._ack(command, ok)
        elif command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._set_mode("RTL")
            self._ack(command, ok)
        elif command == mavlink.MAV_CMD_DO_SET_MODE:
            self._ack(command, self._request_mode(int(p[1]), int(p[2])))
        elif command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            if int(p[0]) == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                self._ack(command, ok)
                self._autopilot_version()
            else:
                self._ack(command, ok)
        elif command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._ack(command, ok)
            self._autopilot_version()
        elif command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self._ack(command, ok)
        else:
            self._ack(command, mavlink.MAV_RESULT_UNSUPPORTED)

    def _autopilot_version(self) -> None:
        caps = (
            mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
        )
        self._mav.autopilot_version_send(caps, 0, 0, 0, 0, bytes(8), bytes(8), bytes(8), 0, 0, 1, bytes(18))

    def _request_mode(self, main: int, sub: int) -> int:
        wanted = next((name for name, ms in MODES.items() if ms == (main, sub)), None)
        if main == PX4_MAIN["AUTO"] and sub == 0:
            wanted = "LOITER"
        if wanted is None:
            self._note(f"unsupported mode main={main} sub={sub}")
            return mavlink.MAV_RESULT_UNSUPPORTED
        if wanted == "OFFBOARD":
            if "offboard" in self.refuse:
                self._note("refused offboard")
                return mavlink.MAV_RESULT_DENIED
            if self.now() - self._setpoint_time > self.offboard_loss_timeout:
                self._note("refused offboard: no setpoint stream")
                return mavlink.MAV_RESULT_DENIED
        if wanted == "TAKEOFF" and not self.armed:
            return mavlink.MAV_RESULT_DENIED
        self._set_mode(wanted)
        return mavlink.MAV_RESULT_ACCEPTED

    def _set_mode(self, mode: str) -> None:
        if mode != self.mode:
            self._note(f"mode {mode}")
        self.mode = mode
        if mode in ("LOITER", "TAKEOFF"):
            self._hold = self.position.copy()
            if mode == "TAKEOFF":
                self._hold[2] = -float(self.params.get("MIS_TAKEOFF_ALT", 2.5))

    def _position_target(self, msg) -> None:
        ignore_pos = msg.type_mask & (
            mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
        )
        if ignore_pos or msg.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
            return  # only position setpoints in the local NED frame are emulated
        self._setpoint = np.array([msg.x, msg.y, msg.z], float)
        if not msg.type_mask & mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE:
            self._setpoint_yaw = float(msg.yaw)
        self._setpoint_time = self.now()
        self.setpoints_received += 1

    # -- physics ------------------------------------------------------------------------------

    def _step(self, dt: float) -> None:
        now = self.now()
        if self.armed:
            self.battery = max(0.0, self.battery - self.battery_drain * dt)
        if self.mode == "OFFBOARD" and now - self._setpoint_time > self.offboard_loss_timeout:
            self._note("failsafe: offboard setpoints lost, landing")
            self._set_mode("LAND")
        if not self.armed:
            self.landed = self._resting()
            return
        target, yaw_target = self._hold, self.yaw
        vz_max = self.max_vertical_speed
        if self.mode == "OFFBOARD" and self._setpoint is not None:
            target, yaw_target = self._setpoint, self._setpoint_yaw
        elif self.mode == "TAKEOFF":
            if abs(self.position[2] - self._hold[2]) < 0.05:
                self._set_mode("LOITER")
        elif self.mode == "LAND":
            # PX4 descends at MPC_LAND_SPEED all the way down, not slowing near the ground
            target = np.array([self.position[0], self.position[1], self.position[2] + 1.0])
            vz_max = self.land_speed
        elif self.mode == "RTL":
            target = np.array([0.0, 0.0, self.position[2]])
            if np.linalg.norm(self.position[:2]) < 0.05:
                self._set_mode("LAND")
        elif self.mode == "POSCTL":
            target = self.position.copy()  # sticks centred: stay
        if self.landed and target[2] >= -1e-6:
            target = self.position.copy()  # on the ground and not asked up: motors idle
        descending = self._move(target, yaw_target, vz_max, dt)
        on_ground = self._on_ground()
        if self.landed and not on_ground:
            self.landed = False
        if not self.landed and on_ground and descending and self.mode in ("LAND", "OFFBOARD", "LOITER"):
            self.landed = True
            self.position[2] = 0.0
            self._touchdown = now
            self._note("touched down")
        if self.landed and self._touchdown is not None and now - self._touchdown >= self.disarm_after_landing:
            self.armed = False
            self._touchdown = None
            self._set_mode("LOITER")
            self._note("disarmed after landing")

    # -- the vehicle model: a subclass flies another one (amslam.apps.sitl: the simulator's) -----

    def _move(self, target: np.ndarray, yaw_target: float, vz_max: float, dt: float) -> bool:
        """Move ``dt`` towards ``target`` (NED) and ``yaw_target`` with climb/descent at most
        ``vz_max``; True unless climbing. Updates :attr:`position` and :attr:`yaw`, which the
        telemetry reports. Here: the point mass, its estimate exact."""
        err = target - self.position
        v = self.position_gain * err
        horizontal = float(np.linalg.norm(v[:2]))
        if horizontal > self.max_speed:
            v[:2] *= self.max_speed / horizontal
        v[2] = float(np.clip(v[2], -vz_max, vz_max))
        self.position = self.position + v * dt
        self.position[2] = min(self.position[2], 0.0)  # the ground
        yaw_err = math.remainder(yaw_target - self.yaw, 2 * math.pi)
        self.yaw = math.remainder(
            self.yaw + float(np.clip(yaw_err, -self.max_yaw_rate * dt, self.max_yaw_rate * dt)), 2 * math.pi
        )
        return bool(v[2] >= 0)

    def _on_ground(self) -> bool:
        """Whether the vehicle's land detector sees it on the ground (in flight)."""
        return bool(self.position[2] >= -0.01)

    def _resting(self) -> bool:
        """Whether a disarmed vehicle stands on the ground."""
        return bool(self.position[2] >= -1e-6)

    def _landed_state(self) -> int:
        if self.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.mode == "TAKEOFF":
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if self.mode == "LAND":
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _telemetry(self, now: float, dt: float, velocity: np.ndarray) -> None:
        ms = int(now * 1000) & 0xFFFFFFFF
        if now >= self._next["heartbeat"]:
            self._next["heartbeat"] = now + 0.5
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0
            )
            state = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
            self._mav.heartbeat_send(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, px4_custom_mode(self.mode), state
            )
        n, e, d = self.position
        vn, ve, vd = velocity
        self._mav.local_position_ned_send(ms, n, e, d, vn, ve, vd)
        self._mav.attitude_send(ms, 0.0, 0.0, self.yaw, 0.0, 0.0, 0.0)
        if now >= self._next["ext"]:
            self._next["ext"] = now + 0.2
            self._mav.extended_sys_state_send(mavlink.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        if now >= self._next["sys"]:
            self._next["sys"] = now + 0.2
            percent = int(round(100 * self.battery))
            self._mav.sys_status_send(0, 0, 0, 500, 15800, -1, percent, 0, 0, 0, 0, 0, 0)
            cells = [4000] * 4 + [65535] * 6
            self._mav.battery_status_send(
                0,
                mavlink.MAV_BATTERY_FUNCTION_ALL,
                mavlink.MAV_BATTERY_TYPE_LIPO,
                2500,
                cells,
                -1,
                -1,
                -1,
                percent,
            )

    def _run(self) -> None:
        dt = 1.0 / self.rate_hz
        next_tick = time.monotonic()
        while not self._stop.is_set():
            with self._lock:
                self._receive()
                before = self.position.copy()
                self._step(dt)
                velocity = (self.position - before) / dt
                now = self.now()
                self._telemetry(now, dt, velocity)
                self.trace.append(
                    TracePoint(now, self.position.copy(), self.yaw, self.mode, self.armed, self.landed)
                )
            next_tick += dt
            time.sleep(max(0.0, next_tick - time.monotonic()))
