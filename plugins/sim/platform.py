"""The simulator platform: a kinematic multicopter with a depth camera and drifting VIO."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Discriminator, Field, Tag, ValidationInfo, model_validator

from amslam.errors import PlatformError
from amslam.geometry import pose_from, wrap_angle
from amslam.interfaces import BackendParams, Coordinate, FieldError, Platform, RunContext, mission_file_path
from amslam.plugins.sim.camera import CameraParams, Renderer
from amslam.plugins.sim.hall import HallWorldParams, generate_hall
from amslam.plugins.sim.meshworld import MeshWorldParams, load_mesh_world, mesh_xy_extent
from amslam.plugins.sim.outdoor import OutdoorWorldParams, generate_outdoor
from amslam.plugins.sim.procedural import ProceduralWorldParams, generate_building
from amslam.plugins.sim.vio import VioParams, VioState
from amslam.plugins.sim.world import World, WorldSpec
from amslam.types import CameraModel, Frame, Odometry, RobotSpec, VehicleStatus, WorldSummary


def _world_kind(v: Any) -> str:
    """``kind`` of a world section; a section without one is procedural."""
    if isinstance(v, dict):
        return v.get("kind", "procedural")
    return getattr(v, "kind", "procedural")


WorldParams = Annotated[
    Annotated[ProceduralWorldParams, Tag("procedural")]
    | Annotated[MeshWorldParams, Tag("mesh")]
    | Annotated[OutdoorWorldParams, Tag("outdoor")]
    | Annotated[HallWorldParams, Tag("hall")],
    Discriminator(_world_kind),
]


class SimPlatform(Platform):
    """The built-in simulator (platform plugin ``sim``).

    The world is built in :meth:`start` (or on the first call that needs it). Setpoints are in
    the odometry frame: the vehicle drives its *VIO estimate* to them, so the true motion carries
    the drift, exactly as on a real vehicle. The odometry frame equals the world frame at the
    start pose.
    """

    requires = ("open3d",)  # imported when built (see Backend.requires)

    simulated = True
    simulator = True  # builds the world: its ground truth is its own (Backend.simulator)

    @staticmethod
    def team_overrides(*args, **kwargs) -> list[list[str]]:
        """Each robot's mission overrides for a team in one world (:func:`.teams.team_overrides`)."""
        from amslam.plugins.sim.teams import team_overrides

        return team_overrides(*args, **kwargs)

    class Params(BackendParams):
        """Parameters of the simulator platform."""

        world: WorldParams = Field(
            default_factory=ProceduralWorldParams,
            description="kind: procedural (seeded building), mesh (a mesh file + objects file), outdoor"
            " (seeded parking lot / street) or hall (seeded warehouse hall with racks)",
        )
        start: tuple[Coordinate, Coordinate] | None = Field(
            None,
            description="start (x, y) on the ground floor; default: the procedural world's corridor end,"
            " or a mesh world's most open spot on its ground floor whose take-off column is clear, inside"
            " the building (see docs/simulator.md)",
        )
        start_margin: float = Field(
            0.2,
            ge=0.0,
            le=10.0,
            description="clearance beyond the robot radius that the take-off column needs at the start,"
            " from the landed height to the flight altitude (m)",
        )
        start_yaw: float | None = Field(
            None, ge=-100.0, le=100.0, description="start heading in radians; default: the world's"
        )
        camera: CameraParams = Field(default_factory=CameraParams)
        vio: VioParams = Field(default_factory=VioParams)
        physics_hz: float = Field(50.0, ge=10.0, le=1000.0, description="integration rate of the vehicle")
        position_gain: float = Field(
            1.5, gt=0.0, le=100.0, description="P gain (1/s) of the position loop near the goal"
        )
        yaw_gain: float = Field(2.0, gt=0.0, le=100.0, description="P gain (1/s) of the yaw loop")
        landing_speed: float = Field(0.4, gt=0.0, le=10.0, description="descent speed when landing, m/s")
        landed_clearance: float = Field(
            0.05, ge=0.0, le=1.0, description="gap between the collision sphere and the ground when landed"
        )
        reachable_cell: float = Field(
            0.25, ge=0.05, le=10.0, description="grid of the reachable-free-space summary"
        )
        reachable_by: Literal["robot", "air"] = Field(
            "robot",
            description="what explored % is a share of: 'robot', the free space the robot's body can"
            " reach inside the flight bound (the mission area, else the building's box); 'air', all"
            " free space connected to the start through gaps wider than half a cell (the measure before"
            " issue #19)",
        )

        @model_validator(mode="after")
        def _start_inside(self, info: ValidationInfo) -> SimPlatform.Params:
            # a generated world spans [0, W] x [0, D]; a mesh world, its mesh's extent (read here,
            # once the mesh file is known to be there: the world itself is built when the run starts)
            size = getattr(self.world, "size", None)
            if self.start is None:
                return self
            x, y = self.start
            if size is not None:
                W, D = size
                if not (0.0 < x < W and 0.0 < y < D):
                    raise FieldError(
                        "start",
                        f"({x:g}, {y:g}) is outside the {self.world.kind} world, which spans "
                        f"[0, {W:g}] x [0, {D:g}] m",
                    )
            elif isinstance(self.world, MeshWorldParams):
                path = mission_file_path(self.world.mesh, info)
                if not path.is_absolute():
                    return self  # no mission folder to resolve against: checked when the world is built
                try:
                    x0, x1, y0, y1 = mesh_xy_extent(path, self.world)
                except PlatformError:
                    raise FieldError("world.mesh", f"no triangles in {path}: not a mesh file") from None
                if not (x0 < x < x1 and y0 < y < y1):
                    raise FieldError(
                        "start",
                        f"({x:g}, {y:g}) is outside the mesh world, which spans "
                        f"[{x0:.2f}, {x1:.2f}] x [{y0:.2f}, {y1:.2f}] m",
                    )
            return self

    def __init__(self) -> None:
        self.params: SimPlatform.Params | None = None
        self._camera: CameraModel | None = None
        self._world: World | None = None
        self._closed = False

    # ---------------------------------------------------------------------------------------
    # lifecycle
    # ---------------------------------------------------------------------------------------
    def configure(self, params: BackendParams, context: RunContext) -> None:
        assert isinstance(params, SimPlatform.Params), type(params)
        self.params = params
        self.context = context
        self.robot: RobotSpec = context.robot
        self._camera = params.camera.model()
        self._renderer = Renderer(self._camera, params.camera)
        # Separate streams: the world, the VIO, the camera and the detector noise must not
        # shift one another when one of them is reconfigured.
        seeds = context.rng.integers(0, 2**63 - 1, size=3)
        world_seed = int(seeds[0]) + getattr(params.world, "seed_offset", 0)
        # a negative sum is no seed numpy takes: wrap it (every seed that worked before is unchanged)
        self._world_seed = world_seed if world_seed >= 0 else world_seed % 2**63
        self._vio_rng = np.random.default_rng(int(seeds[1]))
        self._cam_rng = np.random.default_rng(int(seeds[2]))

    def close(self) -> None:
        self._world = None
        self._closed = True

    @property
    def camera(self) -> CameraModel:
        if self._camera is None:
            raise PlatformError("the sim platform is not configured yet")
        return self._camera

    @property
    def world(self) -> World:
        """The simulated world (built on first use)."""
        if self._world is None:
            self._build()
        assert self._world is not None
        return self._world

    def start(self) -> None:
        """Build the world and put the vehicle, landed, at the start."""
        _ = self.world

    def _build(self) -> None:
        if self.params is None:
            raise PlatformError("the sim platform must be configured before it is started")
        p = self.params
        spec = self._make_world_spec(p)
        self._world = World(spec)
        floor = float(spec.floor_heights[0])
        if p.start is not None:
            xy = np.asarray(p.start, float)
            what = f"the start {np.round(xy, 2).tolist()} (platform.start)"
        elif np.all(np.isfinite(spec.start_xy)):
            xy = np.asarray(spec.start_xy, float)
            what = f"the start {np.round(xy, 2).tolist()} of world {spec.name}"
        else:
            xy = self._open_spot(self._world, spec)
            what = ""
        self._ground_z = spec.start_floor_z
        if p.start is not None:  # the ground under the given point: the first surface below flight height
            g = self._world.ground_below(np.array([xy[0], xy[1], floor + self.robot.altitude]))
            if np.isfinite(g):
                # the ray cast is float32: a floor found within a millimetre is the floor itself
                near = [f for f in spec.floor_heights if abs(f - g) < 1e-3]
                self._ground_z = float(near[0]) if near else g
        if what:  # a start given by the user or the world is checked as a chosen one would be
            self._check_start(self._world, xy, self._ground_z, what)
        yaw = float(p.start_yaw if p.start_yaw is not None else spec.start_yaw)
        self._landed_height = self.robot.radius + p.landed_clearance
        pos = np.array([xy[0], xy[1], self._ground_z + self._landed_height])
        self._start = pos.copy()
        # true state
        self._p = pos.copy()
        self._yaw = wrap_angle(yaw)
        self._vel = np.zeros(3)  # commanded velocity in the odometry frame
        self._vio = VioState(position=pos.copy(), yaw=self._yaw)
        self._t = 0.0
        self._armed = False
        self._airborne = False
        self._landing = False
        self._crashed = False
        self._crash_reason = ""
        self._cruise_z = np.inf  # take-off height; clearance is tracked from reaching it to landing
        self._cruising = False
        self._closest: tuple[float, np.ndarray | None, str] = (np.inf, None, "")  # clearance, where, what
        self._sp: np.ndarray = pos.copy()
        self._sp_yaw = self._yaw
        self._odom = Odometry(0.0, self._T_odom_body())
        self._next_odom = 1.0 / p.vio.rate_hz
        self._next_frame = 0.0
        self._pending: tuple[float, np.ndarray, np.ndarray] | None = None
        self._check_due_frame()
        self._frames_rendered = 0

    def use_world(self, spec: WorldSpec) -> None:
        """Fly in a world built by the caller (tests, scripts) instead of the one in the params.

        Call after :meth:`configure` and before :meth:`start`.
        """
        if self._world is not None:
            raise PlatformError("use_world() must be called before the world is built")
        self._custom_spec = spec

    def _make_world_spec(self, p: SimPlatform.Params) -> WorldSpec:
        if getattr(self, "_custom_spec", None) is not None:
            return self._custom_spec
        if isinstance(p.world, MeshWorldParams):
            return load_mesh_world(p.world, Path(self.context.mission_dir))
        if isinstance(p.world, OutdoorWorldParams):
            return generate_outdoor(p.world, np.random.default_rng(self._world_seed))
        if isinstance(p.world, HallWorldParams):
            return generate_hall(p.world, np.random.default_rng(self._world_seed))
        return generate_building(p.world, np.random.default_rng(self._world_seed))

    # ---------------------------------------------------------------------------------------
    # the start
    # ---------------------------------------------------------------------------------------
    def _needed_clearance(self) -> float:
        assert self.params is not None
        return self.robot.radius + self.params.start_margin

    def _column_clearance(
        self, world: World, xy: np.ndarray, ground: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Clearance of the take-off column over each (x, y) and the height where it is smallest.

        The column runs from the landed height to the flight altitude above ``ground`` (N,). The
        floor the vehicle stands on is not an obstacle: at each height only geometry closer than
        the floor counts, and a rug or a door sill less than 5 cm high is part of the floor (what
        the picker stands on too).
        """
        assert self.params is not None
        z0 = self.robot.radius + self.params.landed_clearance
        z1 = max(self.robot.altitude, z0)
        rel = np.linspace(z0, z1, max(2, int(np.ceil((z1 - z0) / 0.1)) + 1))
        clear = np.full(len(xy), np.inf)
        worst = np.full(len(xy), rel[-1])
        for h in rel:
            d = world.distance(np.column_stack([xy, ground + h]))
            d = np.where(d < h - 0.05, d, np.inf)
            lower = d < clear
            clear[lower], worst[lower] = d[lower], h
        return clear, ground + worst

    def _check_start(self, world: World, xy: np.ndarray, ground: float, what: str) -> None:
        """Refuse a start whose take-off column is not clear (before anything flies)."""
        assert self.params is not None
        z = ground + np.array([self.robot.radius + self.params.landed_clearance, self.robot.altitude])
        column = np.column_stack([np.tile(xy, (2, 1)), z])
        if np.any(world.backface_share(column) >= 0.75):  # far from surfaces, but inside a solid
            _, _, hit = world.closest(column[1])
            raise PlatformError(
                f"no room to take off at {what}: it is inside {hit} (every surface around it is seen"
                " from behind); set platform.start to a spot in free space"
            )
        clear, at = self._column_clearance(world, np.reshape(xy, (1, 2)), np.array([ground]))
        need = self._needed_clearance()
        if clear[0] >= need:
            return
        d, _, hit = world.closest(np.array([xy[0], xy[1], at[0]]))
        raise PlatformError(
            f"no room to take off at {what}: at height {at[0]:.2f} m it is {d:.2f} m from {hit}; the"
            " take-off column from the landed height to the flight altitude"
            f" ({ground + self.robot.altitude:.2f} m) needs {need:.2f} m (robot radius"
            f" {self.robot.radius} m + start_margin {self.params.start_margin} m)"
        )

    def _mission_area(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The mission's exploration ``area`` (lo, hi), if it has one.

        The runner writes the run's resolved mission into the run folder before it configures
        the platform, and hands the area itself to backends only after the platform has
        started: the file is where the start can learn it.
        """
        area = getattr(self.context, "area", None)
        if area is not None:
            return np.asarray(area.lo, float), np.asarray(area.hi, float)
        path = Path(self.context.run_dir) / "mission.yaml"
        if not path.is_file():
            return None
        import yaml

        try:
            data = yaml.safe_load(path.read_text()) or {}
        except (OSError, yaml.YAMLError):
            return None
        a = data.get("area") if isinstance(data, dict) else None
        if not isinstance(a, dict) or "lo" not in a or "hi" not in a:
            return None
        return np.asarray(a["lo"], float), np.asarray(a["hi"], float)

    def _open_spot(self, world: World, spec: WorldSpec) -> np.ndarray:
        """The start (x, y): a clear take-off column standing on the ground floor, inside, open.

        Candidates on a grid over the world must stand on the ground floor (the first surface
        below flight height is the floor, not a table top) and have their whole take-off column
        clear by the robot radius plus ``start_margin``, not only at flight height, and must not
        lie inside a closed solid. No roof is required (open-topped buildings). Among them the
        most open spot (largest column clearance and horizontal room) is taken, preferring spots
        inside the mission area (when the mission has one) and spots with walls on most sides
        (inside the building, not on the ground around it). The best few are then looked at again
        on a finer grid: a corridor just wide enough may have its middle between two grid lines.
        """
        floor = float(spec.floor_heights[0])
        need = self._needed_clearance()
        lo, hi = np.asarray(spec.bounds_lo, float), np.asarray(spec.bounds_hi, float)
        span = np.maximum(hi[:2] - lo[:2], 0.25)
        step = max(0.25, float(np.sqrt(span[0] * span[1] / 40000)))
        xs = np.arange(lo[0] + step, hi[0] - step / 2, step)
        ys = np.arange(lo[1] + step, hi[1] - step / 2, step)
        g = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
        key, clear = self._rate_spots(world, g, floor)
        fine = np.linspace(-step / 2, step / 2, 5)
        offsets = np.stack(np.meshgrid(fine, fine, indexing="ij"), -1).reshape(-1, 2)
        best = np.lexsort((key[:, 1], key[:, 0]))[::-1][:6]
        g2 = (g[best][:, None, :] + offsets[None, :, :]).reshape(-1, 2)
        key2, clear2 = self._rate_spots(world, g2, floor)
        g, key, clear = np.vstack([g, g2]), np.vstack([key, key2]), np.concatenate([clear, clear2])
        i = int(np.lexsort((key[:, 1], key[:, 0]))[-1])
        if key[i, 0] >= 0:
            return g[i]
        z_fly = floor + self.robot.altitude
        assert self.params is not None
        if not np.isfinite(clear[i]):
            where = f"no point of the world stands on the ground floor under {z_fly:.2f} m"
        elif clear[i] >= need:  # clear enough, but refused by the closed-solid test of _rate_spots
            where = (
                f"every spot clear enough lies inside a closed solid (the surfaces around it are seen"
                f" from behind), the best, {np.round(g[i], 2).tolist()}, with {clear[i]:.2f} m"
            )
        else:
            where = f"the best spot, {np.round(g[i], 2).tolist()}, has {max(clear[i], 0.0):.2f} m"
        raise PlatformError(
            f"world {spec.name}: no start spot: a spot must stand on the ground floor (z = {floor:.2f} m)"
            f" with its take-off column clear by {need:.2f} m (robot radius {self.robot.radius} m +"
            f" start_margin {self.params.start_margin} m) from the landed height to the flight altitude"
            f" ({z_fly:.2f} m); {where}. Set platform.start to a clear spot, or"
            " platform.world.floor_heights if the ground floor is wrong"
        )

    def _rate_spots(self, world: World, g: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
        """Rank start candidates: (tier, openness) per spot, higher is better, and their clearance.

        The tier is −1 for spots that do not qualify (openness is then their clearance, to name the
        best of them), else 2 × inside the mission area + 1 × inside walls. The column clearance
        counts only what is nearer than the floor, so it cannot rank spots farther than the flight
        altitude from any wall: openness is the smaller of it and the horizontal room.
        """
        need = self._needed_clearance()
        z_fly = floor + self.robot.altitude
        down = np.column_stack([g, np.full(len(g), z_fly), np.tile([0.0, 0.0, -1.0], (len(g), 1))])
        ground = z_fly - world.cast_rays(down)["t_hit"].astype(float)
        idx = np.flatnonzero(np.abs(ground - floor) < 0.05)  # on the floor, not on a table or a step
        clear = np.full(len(g), -np.inf)
        clear[idx] = self._column_clearance(world, g[idx], np.full(len(idx), floor))[0]
        key = np.column_stack([np.full(len(g), -1.0), clear])
        idx = idx[clear[idx] >= need]
        if len(idx):  # a point deep inside a closed solid is far from its surfaces too
            idx = idx[world.backface_share(np.column_stack([g[idx], np.full(len(idx), z_fly)])) < 0.75]
        if not len(idx):
            return key, clear
        tier = (world.enclosed_share(g[idx], np.array([floor + 1.2, floor + 1.8])) >= 0.75).astype(float)
        area = self._mission_area()
        if area is not None:
            alo, ahi = area
            tier += 2.0 * np.all((g[idx] >= alo[:2] + need) & (g[idx] <= ahi[:2] - need), axis=1)
        room = np.minimum.reduce(
            [
                world.horizontal_room(np.column_stack([g[idx], np.full(len(idx), floor + h)]))
                for h in (need + 0.1, self.robot.altitude)
            ]
        )
        key[idx, 0] = tier
        key[idx, 1] = np.minimum(clear[idx], room)
        return key, clear

    def _hover_point(self) -> np.ndarray:
        return np.array([self._start[0], self._start[1], self._ground_z + self.robot.altitude])

    # ---------------------------------------------------------------------------------------
    # clock and dynamics
    # ---------------------------------------------------------------------------------------
    def time(self) -> float:
        _ = self.world
        return self._t

    def advance(self, dt: float) -> None:
        """Integrate ``dt`` seconds of simulated time in sub-steps of at most 1/physics_hz."""
        if dt <= 0:
            return
        w = self.world
        assert self.params is not None
        n = max(1, int(np.ceil(dt * self.params.physics_hz - 1e-9)))
        h = dt / n
        for _ in range(n):
            self._step(h, w)
            self._t += h
            if self._t >= self._next_odom - 1e-9:
                self._odom = Odometry(self._t, self._T_odom_body())
                while self._next_odom <= self._t + 1e-9:
                    self._next_odom += 1.0 / self.params.vio.rate_hz
            self._check_due_frame()

    def _check_due_frame(self) -> None:
        if self._t >= self._next_frame - 1e-9:
            # a queue of one: a frame not collected before the next one is due is dropped
            self._pending = (self._t, self._T_world_body(), self._T_odom_body())
            period = 1.0 / self.camera.rate_hz
            while self._next_frame <= self._t + 1e-9:
                self._next_frame += period

    def _step(self, h: float, w: World) -> None:
        if self._crashed or not self._armed:
            self._vel[:] = 0.0
            return
        p, r = self.params, self.robot
        assert p is not None
        # --- position loop on the VIO estimate: fastest approach that can still brake in time
        target = self._sp
        err = target - self._vio.position
        dist = float(np.linalg.norm(err))
        vmax = p.landing_speed if self._landing else r.max_speed
        if dist > 1e-9:
            speed = min(vmax, np.sqrt(2.0 * r.max_acceleration * dist), p.position_gain * dist)
            v_des = err / dist * speed
        else:
            v_des = np.zeros(3)
        dv = v_des - self._vel
        dvn = float(np.linalg.norm(dv))
        if dvn > r.max_acceleration * h:
            dv *= r.max_acceleration * h / dvn
        self._vel = self._vel + dv
        sp = float(np.linalg.norm(self._vel))
        if sp > vmax:
            self._vel *= vmax / sp
        # --- yaw loop
        yaw_err = wrap_angle(self._sp_yaw - self._vio.yaw)
        dyaw = float(np.clip(p.yaw_gain * yaw_err, -r.max_yaw_rate, r.max_yaw_rate)) * h
        # --- the true motion is the commanded odometry-frame motion rotated back by the yaw error
        c, s = np.cos(-self._vio.yaw_error), np.sin(-self._vio.yaw_error)
        v = self._vel * h
        dp_true = np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])
        self._p = self._p + dp_true
        self._yaw = wrap_angle(self._yaw + dyaw)
        self._vio.step(dp_true, dyaw, self._yaw, p.vio, self._vio_rng)

        if self._landing and self._p[2] - self._land_ground <= self._landed_height + 0.02:
            self._armed = self._airborne = self._landing = False
            self._vel[:] = 0.0
            self.context.emit("sim_landed", t=self._t, position=self._p.round(3).tolist())
            return
        # --- collision: the robot's sphere touching any geometry
        clearance = float(w.distance(self._p)[0])
        self._cruising = self._cruising or (not self._landing and self._p[2] >= self._cruise_z - 0.2)
        if self._cruising and clearance < self._closest[0]:
            self._closest = (clearance, self._p.copy(), "")
        if clearance < r.radius:
            d, q, what = w.closest(self._p)
            # the closest approach leaves out the landing's descent onto the floor, not a crash in it
            if d < self._closest[0]:
                self._closest = (d, self._p.copy(), what)
            self._crashed = True
            self._vel[:] = 0.0
            pos = ", ".join(f"{x:.2f}" for x in self._p)
            self._crash_reason = (
                f"collision at ({pos}) with {what}: clearance {d:.3f} m < robot radius {r.radius} m"
            )
            self.context.emit("sim_crash", t=self._t, position=self._p.round(3).tolist(), hit=what)

    # ---------------------------------------------------------------------------------------
    # poses
    # ---------------------------------------------------------------------------------------
    def _T_world_body(self) -> np.ndarray:
        return pose_from(self._p, self._yaw)

    def _T_odom_body(self) -> np.ndarray:
        return pose_from(self._vio.position, self._vio.yaw)

    def ground_truth(self) -> np.ndarray:
        _ = self.world
        return self._T_world_body()

    def odometry(self) -> Odometry:
        _ = self.world
        return self._odom

    def distance_travelled(self) -> float:
        """True distance flown so far (m)."""
        return self._vio.distance

    # ---------------------------------------------------------------------------------------
    # commands
    # ---------------------------------------------------------------------------------------
    def set_setpoint(self, position_odom: np.ndarray, yaw: float) -> None:
        _ = self.world
        if self._landing:
            return  # landing overrides setpoints, as on a real autopilot
        self._sp = np.asarray(position_odom, dtype=float).reshape(3).copy()
        self._sp_yaw = wrap_angle(float(yaw))

    def arm_and_takeoff(self, altitude: float) -> None:
        """Arm and climb to ``altitude`` above the ground at the start (odometry frame z)."""
        _ = self.world
        if self._crashed:
            raise PlatformError(f"cannot take off after a crash: {self._crash_reason}")
        if self._airborne and not self._landing:
            return
        self._armed = self._airborne = True
        self._landing = False
        self._sp = np.array([self._vio.position[0], self._vio.position[1], self._ground_z + altitude])
        self._sp_yaw = self._vio.yaw
        self._cruise_z = float(self._sp[2])
        self._cruising = False
        self.context.emit("sim_takeoff", t=self._t, altitude=altitude)

    def land(self) -> None:
        """Descend at the current place until the vehicle rests on what is below it, then disarm."""
        _ = self.world
        if not self._airborne or self._landing:
            return
        self._landing = True
        self._cruising = False
        # the descent is vertical: the surface below is found once, not at every sub-step. Beyond
        # the world's geometry (a parking lot's asphalt ends where its mesh does; drift took the
        # lot_team overhead robot 0.7 m past it) the earth goes on at the ground floor's height:
        # without a surface, the descent's target was -inf and the vehicle's state NaN.
        ground = self.world.ground_below(self._p)
        self._land_ground = ground if np.isfinite(ground) else float(self.world.spec.floor_heights[0])
        drop = self._p[2] - (self._land_ground + self._landed_height) + 0.05  # aim just below touchdown
        self._sp = self._vio.position - np.array([0.0, 0.0, drop])
        self._sp_yaw = self._vio.yaw

    def status(self) -> VehicleStatus:
        world = self.world
        clearance, where, what = self._closest
        if where is not None and not what and not self._airborne:
            # Named once the vehicle is down: the closest-point query is not free, and nothing
            # during the flight needs the name.
            what = world.closest(where)[2]
            self._closest = (clearance, where, what)
        if where is None:
            return VehicleStatus(self._armed, self._airborne, self._crashed, self._crash_reason)
        return VehicleStatus(
            self._armed,
            self._airborne,
            self._crashed,
            self._crash_reason,
            closest_approach=round(clearance, 4),
            closest_to=what,
            closest_position=tuple(round(float(x), 3) for x in where),
        )

    # ---------------------------------------------------------------------------------------
    # sensing
    # ---------------------------------------------------------------------------------------
    def capture(self) -> Frame | None:
        """Render the frame that fell due most recently, if it has not been collected yet."""
        _ = self.world
        if self._pending is None:
            return None
        stamp, T_wb, T_ob = self._pending
        self._pending = None
        cam = self.camera
        T_wc = T_wb @ cam.T_body_cam
        r = self._renderer.render(self.world, T_wc, self._cam_rng)
        self._frames_rendered += 1
        return Frame(
            stamp=stamp,
            depth=r.depth,
            K=cam.K.copy(),
            T_odom_cam=T_ob @ cam.T_body_cam,
            rgb=r.rgb,
            instance=r.instance,
            class_id=r.class_id,
            class_names=self.world.class_names,
            T_world_cam_truth=T_wc,
        )

    def world_summary(self) -> WorldSummary:
        assert self.params is not None
        if self.params.reachable_by == "air":
            return self.world.summary(self._hover_point(), cell=self.params.reachable_cell)
        spec = self.world.spec
        bound = self._mission_area() or (np.asarray(spec.bounds_lo, float), np.asarray(spec.bounds_hi, float))
        return self.world.summary(
            self._hover_point(), cell=self.params.reachable_cell, robot_radius=self.robot.radius, bound=bound
        )

    def stats(self) -> dict[str, Any]:
        """Counters for profiling and reports."""
        return {"frames_rendered": self._frames_rendered, "sim_time": self._t, "distance": self._vio.distance}
