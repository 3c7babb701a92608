"""A real vehicle through MAVSDK (PX4): the ``mavsdk`` platform backend.

MAVSDK's in-process binding (``mavsdk.asyncio``) runs on an asyncio event loop in a background
thread owned by the platform, so the runner's synchronous calls stay synchronous and never wait
on the radio: commands are scheduled on the loop and their outcome shows up in ``status()``,
``odometry()`` and ``failsafe()``. Every await on the loop is bounded by a timeout.

What the platform watches, at every ``advance()`` (the runner's tick), and the failsafe it raises
(answered by the failsafe guard of the mission tree, see :mod:`amslam.trees.flight`):

=====================  ==========================================================  ===============
kind                   condition                                                   action
=====================  ==========================================================  ===============
``link_lost``          no telemetry for ``link_timeout`` s, or MAVSDK disconnected  land
``geofence``           the vehicle, or a setpoint, outside ``geofence``            land
``low_battery``        charge below ``battery_return``                             return_and_land
``critical_battery``   charge below ``battery_land``                               land
``command_refused``    the vehicle denied arm, take-off, offboard or land          land
``mode_changed``       the vehicle left offboard on its own (its failsafe, pilot)  hand_over
=====================  ==========================================================  ===============

The first failsafe is kept; a later one replaces it only when its action is more conservative
(hand_over > land > return_and_land). ``land()`` holds first when the vehicle is moving (the
operator's Ctrl-C lands through it: hold, then land), and on a lost link keeps retrying while the
vehicle's own failsafe (PX4: offboard loss → land) brings it down.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from amslam.errors import PlatformError
from amslam.interfaces import BackendParams, Coordinate, FieldError, Platform, Point, RunContext, lo_below_hi
from amslam.plugins.mavsdk_platform.camera_sources import CameraSource, CameraSourceParams, make_camera_source
from amslam.plugins.mavsdk_platform.frames import enu_to_ned, pose_enu_from_ned, yaw_enu_to_ned
from amslam.types import CameraModel, Failsafe, Frame, Odometry, RobotSpec, VehicleStatus

if TYPE_CHECKING:
    # asyncio (and mavsdk) are imported in the methods that fly: listing plugins, validating a
    # mission or drawing its tree reads only the parameter models of this module
    import asyncio

log = logging.getLogger("amslam.mavsdk")

#: Failsafe actions from least to most conservative.
_Heading = Annotated[float, Field(ge=-360, le=360)]  # degrees
_ACTION_RANK = {"return_and_land": 0, "land": 1, "hand_over": 2}


class GeofenceParams(BaseModel):
    """An axis-aligned box in the odometry frame (ENU of the autopilot's local frame), metres."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, allow_inf_nan=False)

    lo: Point
    hi: Point

    @model_validator(mode="after")
    def _lo_below_hi(self) -> GeofenceParams:
        lo_below_hi(self.lo, self.hi)
        return self

    def contains(self, p: np.ndarray, margin: float = 0.0) -> bool:
        lo, hi = np.array(self.lo) + margin, np.array(self.hi) - margin
        return bool(np.all(p >= lo) and np.all(p <= hi))


@dataclass(frozen=True)
class PreflightCheck:
    """One line of the pre-flight check."""

    name: str
    ok: bool
    detail: str


@dataclass
class _Telemetry:
    """The vehicle as last heard (NED, radians); written on the loop thread."""

    position_ned: np.ndarray | None = None
    velocity_ned: np.ndarray | None = None
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)
    landed_state: str = "UNKNOWN"
    in_air: bool = False
    armed: bool = False
    flight_mode: str = "UNKNOWN"
    battery: float = float("nan")  # 0..1
    connected: bool = False
    heard: float = -math.inf  # monotonic time of the last telemetry message
    position_heard: float = -math.inf


class MavsdkPlatform(Platform):
    """A PX4 vehicle over MAVLink through MAVSDK (platform plugin ``mavsdk``). See docs/flight.md."""

    requires = ("mavsdk",)  # imported when built (see Backend.requires)

    simulated = False

    class Params(BackendParams):
        """Parameters of the MAVSDK platform."""

        url: str = Field(
            "udpin://0.0.0.0:14540",
            description="MAVSDK connection URL: udpin://HOST:PORT (PX4 SITL: 14540), serial:///dev/ttyACM0:921600",
        )
        component: Literal["companion_computer", "ground_station"] = Field(
            "companion_computer", description="who amslam is on the MAVLink network"
        )
        connect_timeout: float = Field(15.0, gt=0, le=3600, description="wait this long for the autopilot, s")
        estimate_timeout: float = Field(
            15.0, gt=0, le=3600, description="wait this long for a position estimate, s"
        )
        command_timeout: float = Field(
            5.0, gt=0, le=3600, description="bound on every command to the vehicle, s"
        )
        link_timeout: float = Field(
            1.5, gt=0, le=3600, description="telemetry silence that counts as link lost, s"
        )
        geofence: GeofenceParams | None = Field(
            None, description="box the vehicle must stay in (odometry frame, ENU, m); none: no fence"
        )
        battery_min_start: float = Field(0.5, ge=0, le=1, description="pre-flight: least charge to take off")
        battery_return: float = Field(0.3, ge=0, le=1, description="below this charge: return and land")
        battery_land: float = Field(0.15, ge=0, le=1, description="below this charge: land where it is")
        hold_speed: float = Field(
            0.3, gt=0, le=30, description="land(): hold first when moving faster than this, m/s"
        )
        land_timeout: float = Field(
            60.0, gt=0, le=3600, description="give up confirming a landing after this, s"
        )
        camera: CameraSourceParams = Field(default_factory=CameraSourceParams)
        world: dict[str, Any] | None = Field(
            None,
            description="software in the loop: the simulated world `amslam sitl MISSION` flies this"
            " mission's vehicle in (the sim platform's world section: procedural or mesh); the"
            " platform itself does not read it",
        )
        world_from_local: tuple[Coordinate, Coordinate, Coordinate, _Heading] | None = Field(
            None,
            description="software in the loop with another autopilot (`amslam sitl --camera-only`):"
            " where its local origin stands in `world` and its heading, [x, y, z, yaw_deg] (ENU,"
            " m and degrees; PX4 SITL: the spawn pose in the Gazebo world); none: the start the"
            " simulator chooses, as `amslam sitl`'s own vehicle uses; the platform does not read it",
        )

        @model_validator(mode="after")
        def _battery_ordered(self) -> MavsdkPlatform.Params:
            """battery_land ≤ battery_return ≤ battery_min_start: the vehicle returns before it must
            land, and takes off with more than it returns at."""
            if self.battery_land > self.battery_return:
                raise FieldError(
                    "battery_land",
                    f"{self.battery_land:g} must not be above battery_return ({self.battery_return:g}):"
                    " the vehicle returns before it must land",
                )
            if self.battery_return > self.battery_min_start:
                raise FieldError(
                    "battery_return",
                    f"{self.battery_return:g} must not be above battery_min_start"
                    f" ({self.battery_min_start:g}): a flight would start already returning",
                )
            return self

    def __init__(self) -> None:
        self.params: MavsdkPlatform.Params | None = None
        self._camera: CameraModel | None = None
        self._source: CameraSource | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._tel = _Telemetry()
        self._events: collections.deque[tuple[str, dict[str, Any]]] = collections.deque()
        self._failsafe: Failsafe | None = None
        self._system = None
        self._mavsdk = None
        self._tasks: list[asyncio.Task] = []
        self._t0 = time.monotonic()
        self._deadline: float | None = None
        self._started = False
        self._closed = False
        self._link_up = False
        # intents
        self._setpoint_ned: tuple[float, float, float, float] | None = None
        self._setpoint_event: asyncio.Event | None = None
        self._offboard = False
        self._takeoff_future: Future | None = None
        self._land_future: Future | None = None
        self._landing = False
        self._commanded = False  # this instance commanded flight (a pre-flight check never does)
        self._poses: collections.deque[tuple[float, np.ndarray]] = collections.deque(maxlen=200)

    # ------------------------------------------------------------------------------------------
    # lifecycle
    # ------------------------------------------------------------------------------------------

    def configure(self, params: BackendParams, context: RunContext) -> None:
        assert isinstance(params, MavsdkPlatform.Params), type(params)
        self.params = params
        self.context = context
        self.robot: RobotSpec = context.robot
        self._source = make_camera_source(params.camera, context.mission_dir)
        self._camera = params.camera.nominal_model()

    @property
    def camera(self) -> CameraModel:
        if self._camera is None:
            raise PlatformError("the mavsdk platform is not configured yet")
        return self._camera

    def start(self) -> None:
        """Connect, wait for a position estimate, open the camera and run the pre-flight check.

        Raises:
            PlatformError: naming every check that failed.
        """
        checks = self.connect_and_check()
        for c in checks:
            self._event("preflight", check=c.name, ok=c.ok, detail=c.detail)
        self._flush_events()
        failed = [c for c in checks if not c.ok]
        if failed:
            raise PlatformError(
                "pre-flight check refused the flight: " + "; ".join(f"{c.name}: {c.detail}" for c in failed)
            )
        if self._source is not None:
            self._camera = self._source.open()
        self._flush_events()

    def connect_and_check(self) -> list[PreflightCheck]:
        """Connect (once) and return the pre-flight checks (see :meth:`preflight`)."""
        if not self._started:
            self._connect()
        return self.preflight()

    def _connect(self) -> None:
        import asyncio

        if self.params is None:
            raise PlatformError("the mavsdk platform must be configured before it is started")
        if self._closed:
            raise PlatformError("the mavsdk platform was closed")
        _route_mavsdk_logs()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="amslam-mavsdk", daemon=True)
        self._thread.start()
        self._started = True
        self._t0 = time.monotonic()
        p = self.params
        self._call(self._open(), p.connect_timeout + 5.0, "connect")
        deadline = time.monotonic() + p.estimate_timeout
        # the estimate, and the slower battery report, both count for the pre-flight check
        while time.monotonic() < deadline and not (self._estimate_ok() and math.isfinite(self._tel.battery)):
            time.sleep(0.05)

    async def _open(self) -> None:
        import asyncio

        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        p = self.params
        kind = (
            ComponentType.COMPANION_COMPUTER
            if p.component == "companion_computer"
            else ComponentType.GROUND_STATION
        )
        self._mavsdk = Mavsdk(Configuration.create_with_component_type(kind))
        try:
            await asyncio.wait_for(self._mavsdk.add_any_connection(p.url), p.command_timeout)
        except Exception as exc:
            raise PlatformError(f"mavsdk cannot open {p.url}: {exc}") from exc
        system = await asyncio.wait_for(
            self._mavsdk.first_autopilot(timeout_s=p.connect_timeout), p.connect_timeout + 2
        )
        if system is None:
            raise PlatformError(f"no autopilot heard on {p.url} within {p.connect_timeout:g} s")
        self._system = system
        self.action = ActionAsync(system)
        self.offboard = OffboardAsync(system)
        self.telemetry = TelemetryAsync(system)
        self._setpoint_event = asyncio.Event()
        self._tel.connected = True
        self._link_up = True
        for watch in (
            self._watch_position,
            self._watch_attitude,
            self._watch_landed,
            self._watch_in_air,
            self._watch_armed,
            self._watch_mode,
            self._watch_battery,
            self._watch_connection,
            self._setpoint_pump,
        ):
            self._tasks.append(asyncio.get_running_loop().create_task(watch()))
        self._event("connected", url=p.url)

    def close(self) -> None:
        """Land if still flying (bounded), then stop telemetry and release MAVSDK. Safe twice."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._started and self._loop is not None:
                flying = self._link_alive() and self.status().airborne
                if self._commanded and flying and not self._handed_over():
                    self._event("land_on_close", reason="the run ended with the vehicle in the air")
                    self.land()
                if self._land_future is not None:
                    try:
                        self._land_future.result(timeout=self.params.land_timeout + 5.0)
                    except Exception as exc:  # noqa: BLE001 — recorded, closing goes on
                        self._event("land_failed", error=f"{type(exc).__name__}: {exc}")
                self._call(self._shutdown(), 5.0, "shutdown")
        except PlatformError as exc:
            log.warning("mavsdk shutdown: %s", exc)
        finally:
            if self._loop is not None:
                self._loop.call_soon_threadsafe(self._loop.stop)
                if self._thread is not None:
                    self._thread.join(timeout=5.0)
                self._loop.close()
            if self._source is not None:
                self._source.close()
            self._flush_events()

    async def _shutdown(self) -> None:
        import asyncio

        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._mavsdk is not None:
            self._mavsdk.destroy()
            self._mavsdk = None

    # ------------------------------------------------------------------------------------------
    # the loop thread: telemetry
    # ------------------------------------------------------------------------------------------

    def _heard(self) -> None:
        self._tel.heard = time.monotonic()

    async def _watch_position(self) -> None:
        async for pv in self.telemetry.subscribe_position_velocity_ned():
            p, v = pv.position, pv.velocity
            with self._lock:
                self._tel.position_ned = np.array([p.north_m, p.east_m, p.down_m])
                self._tel.velocity_ned = np.array([v.north_m_s, v.east_m_s, v.down_m_s])
                self._tel.position_heard = time.monotonic()
                # every pose heard, not only those the control ticks read: a frame is paired with
                # the pose nearest to its stamp, and at 10 Hz ticks that was up to 50 ms off (3 cm
                # and 3° at 1 m/s and 1 rad/s, smearing the map)
                T = pose_enu_from_ned(self._tel.position_ned, *self._tel.euler)
                self._poses.append((self._tel.position_heard - self._t0, T))
            self._heard()

    async def _watch_attitude(self) -> None:
        async for e in self.telemetry.subscribe_attitude_euler():
            with self._lock:
                self._tel.euler = (
                    math.radians(e.roll_deg),
                    math.radians(e.pitch_deg),
                    math.radians(e.yaw_deg),
                )
            self._heard()

    async def _watch_landed(self) -> None:
        async for state in self.telemetry.subscribe_landed_state():
            self._tel.landed_state = state.name
            self._heard()

    async def _watch_in_air(self) -> None:
        async for in_air in self.telemetry.subscribe_in_air():
            self._tel.in_air = bool(in_air)

    async def _watch_armed(self) -> None:
        async for armed in self.telemetry.subscribe_armed():
            if armed != self._tel.armed:
                self._event("armed" if armed else "disarmed")
            self._tel.armed = bool(armed)
            self._heard()

    async def _watch_mode(self) -> None:
        async for mode in self.telemetry.subscribe_flight_mode():
            name = mode.name
            if name != self._tel.flight_mode:
                self._event("flight_mode", mode=name)
                if self._offboard and name != "OFFBOARD" and not self._landing:
                    self._offboard = False
                    self._raise(
                        "mode_changed",
                        f"the vehicle left offboard for {name} (its own failsafe or the pilot): hands off",
                        "hand_over",
                    )
            self._tel.flight_mode = name
            self._heard()

    async def _watch_battery(self) -> None:
        async for battery in self.telemetry.subscribe_battery():
            if math.isfinite(battery.remaining_percent):
                self._tel.battery = battery.remaining_percent / 100.0

    async def _watch_connection(self) -> None:
        async for connected in self._system.is_connected_state():
            self._tel.connected = bool(connected)

    # ------------------------------------------------------------------------------------------
    # the loop thread: commands
    # ------------------------------------------------------------------------------------------

    async def _bounded(self, awaitable, what: str):
        import asyncio

        try:
            return await asyncio.wait_for(awaitable, self.params.command_timeout)
        except TimeoutError:
            raise TimeoutError(f"{what}: no answer within {self.params.command_timeout:g} s") from None

    async def _takeoff_sequence(self, altitude: float) -> None:
        from mavsdk.asyncio.plugins.action import ActionError

        try:
            await self._bounded(self.action.set_takeoff_altitude(altitude), "set take-off altitude")
        except (ActionError, TimeoutError) as exc:
            self._event("takeoff_altitude_not_set", error=str(exc))
        for what, command in (("arm", self.action.arm), ("take-off", self.action.takeoff)):
            try:
                await self._bounded(command(), what)
            except ActionError as exc:
                self._raise("command_refused", f"{what} refused by the vehicle ({exc.result.name})", "land")
                return
            except TimeoutError as exc:
                self._raise("command_refused", str(exc), "land")
                return
            self._event("command_accepted", command=what)

    async def _setpoint_pump(self) -> None:
        """Send the newest setpoint (MAVSDK repeats it at 20 Hz); start offboard once airborne."""
        from mavsdk.asyncio.plugins.offboard import OffboardError, PositionNedYaw

        while True:
            await self._setpoint_event.wait()
            self._setpoint_event.clear()
            sp = self._setpoint_ned
            if sp is None or self._landing or self._handed_over():
                continue
            try:
                await self._bounded(self.offboard.set_position_ned(PositionNedYaw(*sp)), "offboard setpoint")
                if not self._offboard and self._tel.armed and self._tel.in_air:
                    await self._bounded(self.offboard.start(), "offboard start")
                    self._offboard = True
                    self._event("command_accepted", command="offboard")
            except OffboardError as exc:
                self._raise("command_refused", f"offboard refused by the vehicle ({exc.result.name})", "land")
            except TimeoutError as exc:
                self._event("setpoint_not_sent", error=str(exc))  # the link monitor decides

    async def _land_sequence(self) -> None:
        """Hold if moving, land (retrying while the link is down), wait for touchdown, disarm."""
        import asyncio

        from mavsdk.asyncio.plugins.action import ActionError
        from mavsdk.asyncio.plugins.offboard import OffboardError

        p = self.params
        deadline = time.monotonic() + p.land_timeout
        if self._on_ground():
            await self._disarm()
            return
        speed = self._speed()
        if speed > p.hold_speed:
            try:
                if self._offboard:
                    await self._bounded(self.offboard.stop(), "offboard stop (hold)")
                else:
                    await self._bounded(self.action.hold(), "hold")
                self._event("holding", speed=round(speed, 2))
                settle = time.monotonic() + 5.0
                while self._speed() > 0.5 * p.hold_speed and time.monotonic() < settle:
                    await asyncio.sleep(0.05)
            except (ActionError, OffboardError, TimeoutError) as exc:
                self._event("hold_failed", error=str(exc))
        while time.monotonic() < deadline and not self._on_ground():
            try:
                await self._bounded(self.action.land(), "land")
                self._event("command_accepted", command="land")
                break
            except ActionError as exc:
                self._event("land_refused", result=exc.result.name)
                await asyncio.sleep(1.0)
            except TimeoutError as exc:
                self._event("land_not_acknowledged", error=str(exc))
                await asyncio.sleep(0.5)
        self._offboard = False
        while time.monotonic() < deadline and not self._on_ground():
            await asyncio.sleep(0.05)
        if not self._on_ground():
            self._event("landing_unconfirmed", timeout=p.land_timeout)
            return
        self._event("touchdown")
        stats = getattr(self._source, "stats", None)
        if stats is not None:  # what a streaming source can tell of the flight's frames, before run_end
            self._event("camera_stream", **stats())
        await self._disarm()

    async def _disarm(self) -> None:
        import asyncio

        from mavsdk.asyncio.plugins.action import ActionError

        settle = time.monotonic() + 3.0  # PX4 disarms by itself after landing (COM_DISARM_LAND)
        while self._tel.armed and time.monotonic() < settle:
            await asyncio.sleep(0.05)
        if self._tel.armed:
            try:
                await self._bounded(self.action.disarm(), "disarm")
            except (ActionError, TimeoutError) as exc:
                self._event("disarm_failed", error=str(exc))

    # ------------------------------------------------------------------------------------------
    # shared helpers (either thread)
    # ------------------------------------------------------------------------------------------

    def _event(self, name: str, **fields: Any) -> None:
        self._events.append((name, fields))  # deque.append is atomic; flushed on the main thread

    def _flush_events(self) -> None:
        while self._events:
            name, fields = self._events.popleft()
            self.context.emit(name, **fields)

    def _raise(self, kind: str, reason: str, action: str) -> None:
        with self._lock:
            current = self._failsafe
            new = Failsafe(kind, reason, action, self.time())  # type: ignore[arg-type]
            if current is None or _ACTION_RANK[action] > _ACTION_RANK[current.action]:
                self._failsafe = new
            replaced = self._failsafe is new
        if current is None or replaced or current.kind != kind:
            self._event("failsafe", kind=kind, reason=reason, action=action, answered=replaced)

    def _handed_over(self) -> bool:
        f = self._failsafe
        return f is not None and f.action == "hand_over"

    def _on_ground(self) -> bool:
        return self._tel.landed_state == "ON_GROUND"

    def _speed(self) -> float:
        v = self._tel.velocity_ned
        return float(np.linalg.norm(v[:2])) if v is not None else 0.0

    def _link_alive(self) -> bool:
        return self._tel.connected and time.monotonic() - self._tel.heard < self.params.link_timeout

    def _estimate_ok(self) -> bool:
        p = self._tel.position_ned
        fresh = time.monotonic() - self._tel.position_heard < 1.0
        return p is not None and bool(np.all(np.isfinite(p))) and fresh

    def _submit(self, coro) -> Future:
        import asyncio

        assert self._loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self._loop)

    def _call(self, coro, timeout: float, what: str):
        """Run a coroutine on the loop and wait for it (start-up and shutdown only)."""
        future = self._submit(coro)
        try:
            return future.result(timeout=timeout)
        except TimeoutError:
            future.cancel()
            raise PlatformError(f"mavsdk {what}: no answer within {timeout:g} s") from None
        except PlatformError:
            raise
        except Exception as exc:
            raise PlatformError(f"mavsdk {what} failed: {type(exc).__name__}: {exc}") from exc

    # ------------------------------------------------------------------------------------------
    # pre-flight check
    # ------------------------------------------------------------------------------------------

    def preflight(self) -> list[PreflightCheck]:
        """Link up, position estimate valid, geofence contains the start and the climb, battery.

        Returns one :class:`PreflightCheck` per item, passed or not; nothing is commanded.
        """
        p = self.params
        checks = []
        age = time.monotonic() - self._tel.heard
        link = self._link_alive()
        checks.append(
            PreflightCheck(
                "link",
                link,
                f"telemetry {age:.2f} s old"
                if link
                else f"no telemetry for {min(age, 1e6):.1f} s on {p.url}",
            )
        )
        estimate = self._estimate_ok()
        pos = self._tel.position_ned
        checks.append(
            PreflightCheck(
                "position estimate",
                estimate,
                f"local position {_fmt(pos)} (NED)"
                if estimate
                else f"no valid local position within {p.estimate_timeout:g} s",
            )
        )
        if p.geofence is None:
            checks.append(PreflightCheck("geofence", True, "no geofence configured"))
        elif not estimate:
            checks.append(PreflightCheck("geofence", False, "start unknown: no position estimate"))
        else:
            start = self.odometry().T_odom_body[:3, 3]
            climb = start + np.array([0.0, 0.0, self.robot.altitude])
            inside = p.geofence.contains(start, self.robot.radius) and p.geofence.contains(
                climb, self.robot.radius
            )
            detail = f"start {_fmt(start)} and take-off height {self.robot.altitude:g} m"
            detail += " inside" if inside else f" not inside {list(p.geofence.lo)}–{list(p.geofence.hi)}"
            checks.append(PreflightCheck("geofence", inside, detail + f" (margin {self.robot.radius:g} m)"))
        battery = self._tel.battery
        if not math.isfinite(battery):
            checks.append(PreflightCheck("battery", False, "no battery reading"))
        else:
            ok = battery >= p.battery_min_start
            checks.append(
                PreflightCheck(
                    "battery",
                    ok,
                    f"{100 * battery:.0f} % ({'≥' if ok else '<'} {100 * p.battery_min_start:.0f} %)",
                )
            )
        return checks

    # ------------------------------------------------------------------------------------------
    # Platform interface (main thread)
    # ------------------------------------------------------------------------------------------

    def time(self) -> float:
        return time.monotonic() - self._t0

    def advance(self, dt: float) -> None:
        """Wait until ``dt`` of wall-clock time has passed since the last tick, then run the monitors."""
        now = time.monotonic()
        self._deadline = now + dt if self._deadline is None else self._deadline + dt
        if self._deadline < now - dt:
            self._deadline = now  # fell behind (a slow tick): do not try to catch up
        delay = self._deadline - now
        if delay > 0:
            time.sleep(delay)
        self._monitor()
        self._flush_events()

    def _monitor(self) -> None:
        p = self.params
        alive = self._link_alive()
        if alive != self._link_up:
            self._link_up = alive
            if alive:
                self._event("link_restored")
            else:
                age = time.monotonic() - self._tel.heard
                self._raise("link_lost", f"no telemetry for {age:.1f} s", "land")
        if not alive:
            return
        odom = self.odometry()
        airborne = self.status().airborne
        if p.geofence is not None and airborne:
            here = odom.T_odom_body[:3, 3]
            if not p.geofence.contains(here):
                self._raise("geofence", f"the vehicle is at {_fmt(here)}, outside the fence", "land")
        battery = self._tel.battery
        if airborne and math.isfinite(battery):
            if battery < p.battery_land:
                self._raise(
                    "critical_battery",
                    f"battery {100 * battery:.0f} % < {100 * p.battery_land:.0f} %",
                    "land",
                )
            elif battery < p.battery_return:
                self._raise(
                    "low_battery",
                    f"battery {100 * battery:.0f} % < {100 * p.battery_return:.0f} %",
                    "return_and_land",
                )

    def odometry(self) -> Odometry:
        with self._lock:
            p = self._tel.position_ned
            euler = self._tel.euler
            heard = self._tel.position_heard
        if p is None:
            return Odometry(0.0, np.eye(4))
        T = pose_enu_from_ned(p, *euler)
        return Odometry(heard - self._t0, T)

    def capture(self) -> Frame | None:
        if self._source is None:
            return None
        image = self._source.read()
        if image is None:
            return None
        stamp = image.stamp - self._t0
        with self._lock:  # the loop thread appends to it
            poses = list(self._poses)
        if not poses:
            return None
        # the pose heard nearest in time to the frame's stamp (its arrival, or the moment a sender
        # on this host rendered it for: see the camera sources)
        _, T_odom_body = min(poses, key=lambda sT: abs(sT[0] - stamp))
        return Frame(
            stamp,
            image.depth,
            image.K,
            T_odom_body @ self.camera.T_body_cam,
            rgb=image.rgb,
            instance=image.instance,
            class_id=image.class_id,
            class_names=image.class_names,
        )

    def set_setpoint(self, position_odom: np.ndarray, yaw: float) -> None:
        p = self.params
        position_odom = np.asarray(position_odom, float)
        if self._handed_over() or self._landing:
            return
        if not (np.all(np.isfinite(position_odom)) and math.isfinite(yaw)):
            # A NaN reaching the autopilot is undefined behaviour in offboard mode (PX4 reads a
            # NaN position as "not controlled"): refused here whatever the geofence, and landed.
            self._raise(
                "bad_setpoint",
                f"setpoint {_fmt(position_odom)}, yaw {yaw!r} is not finite: not sent",
                "land",
            )
            return
        if p.geofence is not None and not p.geofence.contains(position_odom):
            self._raise(
                "geofence",
                f"setpoint {_fmt(position_odom)} outside the fence: not sent",
                "land",
            )
            return
        self._commanded = True
        n, e, d = enu_to_ned(position_odom)
        self._setpoint_ned = (float(n), float(e), float(d), math.degrees(yaw_enu_to_ned(yaw)))
        if self._loop is not None and self._setpoint_event is not None:
            self._loop.call_soon_threadsafe(self._setpoint_event.set)

    def arm_and_takeoff(self, altitude: float) -> None:
        """Arm and take off to ``altitude`` above home (PX4 ``MIS_TAKEOFF_ALT``); idempotent."""
        if self._failsafe is not None:
            self._event("takeoff_skipped", reason=f"failsafe {self._failsafe.kind} active")
            return
        if self._tel.armed and self._tel.in_air:
            return  # already flying
        if self._takeoff_future is not None and not self._takeoff_future.done():
            return
        self._landing = False
        self._commanded = True
        self._takeoff_future = self._submit(self._takeoff_sequence(float(altitude)))

    def land(self) -> None:
        """Hold if moving, land, disarm after touchdown; returns at once (progress in status())."""
        if self._handed_over():
            self._event("land_skipped", reason="the vehicle is in its own or its pilot's hands")
            return
        if self._land_future is not None and not self._land_future.done():
            return
        if not self._tel.armed and self._on_ground():
            return
        self._landing = True
        self._land_future = self._submit(self._land_sequence())

    def status(self) -> VehicleStatus:
        airborne = self._tel.landed_state not in ("ON_GROUND", "UNKNOWN") or (
            self._tel.landed_state == "UNKNOWN" and self._tel.in_air
        )
        return VehicleStatus(armed=self._tel.armed, airborne=airborne)

    def failsafe(self) -> Failsafe | None:
        """The failsafe the mission tree must answer, if any (see the module docstring)."""
        return self._failsafe


def _fmt(p: np.ndarray) -> list[float]:
    """A position for a message: centimetres, no negative zero."""
    return (np.round(np.asarray(p, float), 2) + 0.0).tolist()


_logs_routed = False


def _route_mavsdk_logs() -> None:
    """Send MAVSDK's C++ log lines to Python logging (``amslam.mavsdk``) instead of stdout."""
    global _logs_routed
    if _logs_routed:
        return
    from mavsdk import LogLevel, log_subscribe

    levels = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO, LogLevel.WARN: logging.WARNING}

    def handler(level, message, file, line) -> bool:
        log.log(levels.get(level, logging.ERROR), "%s (%s:%s)", message, file, line)
        return True

    log_subscribe(handler)
    _logs_routed = True
