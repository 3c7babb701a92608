"""The setpoint filter: the last check of every setpoint against the fresh local map.

Goals and paths come from the world-frame map; the vehicle flies in the odometry frame, where
the local map was built moments ago. Before a setpoint goes to the platform it passes two guards
that look only at that local map: the height guard (floor/ceiling band) and the clearance guard
(a convex safe flight corridor). Both run on the control thread. Landing is checked against the
same map: the vertical descent of :meth:`SetpointFilter.landing_spot`'s column touches nothing.
"""

from __future__ import annotations

import numpy as np

from amslam.interfaces import Mapping
from amslam.types import VoxelState


class SetpointFilter:
    """Height guard, then clearance guard, on odometry-frame setpoints."""

    #: grid step of the clearance guard's look into the local map: paper 1's local voxel, m
    GUARD_STEP = 0.1
    #: distance kept from occupied local voxels beyond the robot radius, m: the local map's VIO
    #: drift since a surface was seen eats into it (demo seed 1 lost 0.055 m over a slab with 0.05)
    GUARD_MARGIN = 0.1
    #: how far around the vehicle the clearance guard looks, m: the largest kept distance (radius,
    #: margin, one voxel) plus a braking distance (1 m/s at 1.5 m/s² stops in 0.33 m), so that a
    #: surface enters the look before the vehicle can reach it
    GUARD_LOOK = 0.8

    def __init__(
        self,
        mapping: Mapping,
        radius: float,
        min_height: float,
        min_headroom: float,
        ceiling: float = np.inf,
    ):
        self.mapping = mapping
        self.radius = radius
        self.min_height = min_height
        self.min_headroom = min_headroom
        #: highest setpoint, world frame, m: the flight area's top less the radius (its flyable top)
        self.ceiling = float(ceiling)
        k = int(np.ceil(self.GUARD_LOOK / self.GUARD_STEP))
        axis = np.arange(-k, k + 1) * self.GUARD_STEP
        grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        distance = np.linalg.norm(grid, axis=1)
        self._offsets = grid[(distance > 0) & (distance <= self.GUARD_LOOK)]
        rim = [radius * np.array([np.cos(a), np.sin(a), 0.0]) for a in np.arange(4) * np.pi / 2]
        self._footprint = np.array([np.zeros(3), *rim])  # the height guard's columns

    def apply(self, setpoint: np.ndarray, here: np.ndarray, odom_z: float = 0.0) -> np.ndarray:
        """The setpoint (odometry frame) the vehicle at ``here`` (odometry frame) may fly to.

        ``odom_z`` is the height of the odometry frame's origin in the world frame (the SLAM
        correction's z), which places the area's ceiling in the frame the vehicle flies in.

        Both guards may lift a setpoint: the height guard takes the top of a wall the path
        crosses for a floor, the corridor slides the vehicle over what is in its way. Under a
        ceiling (the flight area's top) that lift is refused: over an open-topped building's
        walls the vehicle would leave it (the PAL home, walls 2.5 m, was flown up to 3.27 m for 19 %
        of its flight). A shorter step towards the setpoint is tried first (half, a quarter, an
        eighth of the way): the corridor turns a long step that passes over something below into
        a lift as long as the step, where a short one passes with little or none (a turtlebot3
        house flight was held 80 s by a sofa 0.5 m below and 0.4 m beside it while every detour
        asked for a point 2.6 m away, and its east rooms were never explored). Only when no such
        step stays under the top does the vehicle stay where it is, and the goal is given up as
        unreachable by the behaviour that waits for it.
        """
        here = np.asarray(here, float)
        top = self.ceiling - odom_z
        p = self.height_guard(np.asarray(setpoint, float), here)
        if p[2] > top:
            p = np.array([p[0], p[1], top])
        for share in (1.0, 0.5, 0.25, 0.125):
            sent = self.clearance_guard(here + share * (p - here), here)
            if sent[2] <= top + 1e-6:
                return sent
        stay = self.clearance_guard(np.array([here[0], here[1], min(here[2], top)]), here)
        return stay if stay[2] <= top + 1e-6 else here

    def height_guard(self, p_odom: np.ndarray, here: np.ndarray | None = None) -> np.ndarray:
        """Keep a setpoint inside the floor/ceiling band of the fresh local (odometry-frame) map.

        Goals come from the world-frame map, whose floors and ceilings carry the height error the
        estimate had when they were seen; the local map was built moments ago in the frame the
        vehicle flies in. This is the last line of defence against flying into a slab. Floors and
        ceilings are what the mapping backend calls blocked (``Mapping.blocked``): seen surfaces,
        and over the vehicle (what a climb meets) the unseen rest of a ceiling seen nearby, which
        the level camera never shows overhead. The ceiling is looked for over the vehicle's
        footprint at the setpoint and, for a climb, over it where it is (``here``), from there up:
        a climb to a setpoint above a ceiling meets it on the way.
        """
        offsets = np.arange(0.1, 2.05, 0.1)
        z = float(p_odom[2])
        below, ceiling = self._floor_and_ceiling(p_odom, offsets)
        if here is not None and z > float(here[2]) + 0.05:
            # a climb meets, over the vehicle where it is, also the unseen rest of a ceiling
            # (the wider rule costs over 1 ms a tick more, so only climbs ask for it)
            rise = np.arange(0.1, z - float(here[2]) + 2.05, 0.1)
            ceiling = min(ceiling, self._ceiling(np.asarray(here, float), rise, climbing=True))
        if not below.any() and not np.isfinite(ceiling):
            return p_odom
        floor = z - offsets[np.argmax(below)] if below.any() else -np.inf
        if ceiling <= floor:  # the setpoint stands on the slab whose underside the climb meets
            floor = -np.inf
        lo, hi = floor + self.min_height, ceiling - self.min_headroom
        new_z = 0.5 * (floor + ceiling) if lo > hi else float(np.clip(z, lo, hi))
        return p_odom if new_z == z else np.array([p_odom[0], p_odom[1], new_z])

    def _overhead(self, p: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """The points ``offsets`` above the vehicle's footprint at ``p``: its centre and four points
        on its rim (a slab edge beside the centre line is over the vehicle), column by column."""
        return (p + self._footprint[:, None, :] + np.outer(offsets, [0.0, 0.0, 1.0])[None]).reshape(-1, 3)

    def _lowest(self, p: np.ndarray, offsets: np.ndarray, hit: np.ndarray) -> float:
        """Height of the lowest blocked point of :meth:`_overhead` (``hit``); inf when none. A rim
        column that starts in a blocked voxel stands beside a wall the voxels quantised into the
        footprint: only what it meets after free space counts."""
        hit = hit.reshape(len(self._footprint), len(offsets)).copy()
        hit[1:] &= np.cumsum(~hit[1:], axis=1) > 0
        rows = hit.any(axis=0)
        return float(p[2] + offsets[np.argmax(rows)]) if rows.any() else np.inf

    def _ceiling(self, p: np.ndarray, offsets: np.ndarray, *, climbing: bool) -> float:
        """Height of the lowest blocked voxel over the vehicle's footprint at ``p``, ``offsets``
        above it (``climbing``: what a climb meets, ``Mapping.blocked``); inf when none."""
        return self._lowest(
            p, offsets, self.mapping.blocked(self._overhead(p, offsets), local=True, climbing=climbing)
        )

    def _floor_and_ceiling(self, p: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, float]:
        """Blocked points ``offsets`` below ``p`` and the ceiling over its footprint (ordinary rule),
        from one query of the local map."""
        below = p - np.outer(offsets, [0.0, 0.0, 1.0])
        hit = self.mapping.blocked(np.concatenate([below, self._overhead(p, offsets)]), local=True)
        return hit[: len(offsets)], self._lowest(p, offsets, hit[len(offsets) :])

    def clearance_guard(self, setpoint: np.ndarray, here: np.ndarray) -> np.ndarray:
        """Move a setpoint so that the straight flight to it keeps clear of the fresh local map.

        Paths are laid on the coarse world map: 0.25 m voxels carrying the pose error of when each
        wall was seen, so a door can be 0.1–0.2 m narrower or offset from what the vehicle meets,
        and a path checked against it can graze the frame. The local map was built moments ago in
        the frame the vehicle flies in. Each occupied local voxel near the vehicle bounds a
        half-space: its tangent plane towards the vehicle, pushed out by the safe distance. The
        setpoint is projected into their intersection (a few rounds of projection onto the most
        violated one); the vehicle is inside it too (or the constraint moves the setpoint away),
        so the straight flight between them stays inside: a convex safe flight corridor (Liu et
        al., RA-L 2017), rebuilt every tick. Opposite door jambs give opposite half-spaces, which
        centre the vehicle in the opening. No maintained library filters a position setpoint
        against a voxel map, hence by hand.
        """
        samples = here + self._offsets
        occupied = samples[self.mapping.blocked(samples, local=True)]
        if not len(occupied):
            return setpoint
        away = here - occupied
        dist = np.maximum(np.linalg.norm(away, axis=1), 1e-6)
        normals = away / dist[:, None]
        # A sample can lie up to one voxel deeper than the face of the voxel it fell in.
        need = self.radius + self.GUARD_MARGIN + self.GUARD_STEP - dist  # normals · step ≥ need
        step = np.asarray(setpoint, float) - here
        for _ in range(12):
            slack = normals @ step - need
            worst = int(np.argmin(slack))
            if slack[worst] >= -1e-3:
                break
            step = step - slack[worst] * normals[worst]
        return here + step

    #: distance a descent column keeps from occupied voxels beyond the robot radius, m: twice the
    #: clearance guard's, for nothing guards a landing on its way down (a PAMS survey, its column
    #: judged clear with 0.1 m, descended onto a 1 m post beside it — thin, half seen, 0.25 m
    #: voxels in the global map — and touched it at 0.59 m)
    LANDING_MARGIN = 0.2
    #: how far from the vehicle a clear landing column is looked for, m, and the ring spacing
    LANDING_SEARCH = 1.5
    LANDING_RING = 0.25
    #: how far below the vehicle the surface it would land on is looked for in the local map, m
    DESCENT_REACH = 3.0
    #: as deep, m, the global map is read below a vehicle whose local map shows no surface within
    #: ``DESCENT_REACH`` (a PAMS overhead survey at 6 m landed blind, its local map's window ending
    #: 3.5 m above the lot, onto a bench the survey had mapped moments before)
    GLOBAL_DESCENT_REACH = 12.0
    #: a surface the local map shows free space under, with another surface at most this far
    #: below, is furniture (a table, a counter), not the floor: landing there is landing on it, m.
    #: Furniture stands lower; the room under a slab is taller (the demo's: 2.35 m)
    RAISED_MAX = 1.6
    #: how deep under the surface below the centre each cell of the vehicle's footprint is looked at
    #: for support, m: a cell seen free from that surface's height down to this far below it is over
    #: a void — past a slab's edge (a PAMS survey landed half off the lot's ground slab, its
    #: column judged at the centre only), off a table's side — and the landing would tip or fall
    SUPPORT_DEPTH = 0.3
    #: a landing is judged on the local map from at most this high over the surface, m: the local
    #: window reaches 1.5 m or more below the camera (5 m tall by default, re-centred once 1 m off
    #: centre), so that it holds ``SUPPORT_DEPTH`` and a voxel under the surface. A survey whose
    #: window ended right at the ground judged its spot on the global map and landed off an edge
    LOCAL_JUDGE_REACH = 1.1

    def _look(self, T_world_odom: np.ndarray | None):
        """The voxel states a descent is judged on (odometry-frame points): the local map's, and
        with ``T_world_odom`` the global map's where the local map has nothing."""
        mapping = self.mapping

        def look(points: np.ndarray) -> np.ndarray:
            states = mapping.states(points, local=True)
            unseen = states == VoxelState.UNKNOWN
            if T_world_odom is not None and unseen.any():
                world = points[unseen] @ T_world_odom[:3, :3].T + T_world_odom[:3, 3]
                states = states.copy()
                states[unseen] = mapping.states(world, local=False)
            return states

        return look

    def descent_clear(self, p_odom: np.ndarray) -> bool:
        """Whether a vertical descent from ``p_odom`` to the floor below keeps clear of the local map.

        A platform lands straight down (PX4's land mode, the simulator's): anything the fresh local
        map shows within the robot radius plus ``LANDING_MARGIN`` of that column, between the surface
        it lands on and the vehicle, would be touched on the way (a table's edge, a window sill).
        The surface is the first occupied voxel straight below; without one in reach the column is
        not judged clear, nor when that surface is furniture (``RAISED_MAX``: free space under it,
        the floor not far below), nor when part of the footprint (the robot radius) is over a void
        at that surface's height (``SUPPORT_DEPTH``). Unknown voxels count as free, as for the
        clearance guard, and as no evidence of a void.
        """
        return self._descent(p_odom)[0]

    def _descent(
        self, p_odom: np.ndarray, T_world_odom: np.ndarray | None = None
    ) -> tuple[bool, float, bool]:
        """(descent clear, height of the floor below — the surface landed on, or the one under
        the furniture the column meets first — or +inf when none is in reach, the column within
        reach free: nothing within the radius plus margin of it, down to the first surface or as
        deep as the search looks).

        The local map judges it; when it shows no surface within ``DESCENT_REACH`` and
        ``T_world_odom`` is given, the global map fills in what the local map has not seen, down
        to ``GLOBAL_DESCENT_REACH`` (what stands on the ground was mapped on the way there, in
        the estimate's frame of moments ago), and then the column counts as free only where
        seen free."""
        p = np.asarray(p_odom, float)
        step = self.GUARD_STEP
        look = self._look(None)
        depth = np.arange(step, self.DESCENT_REACH + 1e-9, step)
        states = look(p - np.outer(depth, [0.0, 0.0, 1.0]))
        global_map = T_world_odom is not None and not np.any(states == VoxelState.OCCUPIED)
        if global_map:
            look = self._look(np.asarray(T_world_odom, float))
            depth = np.arange(step, self.GLOBAL_DESCENT_REACH + 1e-9, step)
            states = look(p - np.outer(depth, [0.0, 0.0, 1.0]))
        below = states == VoxelState.OCCUPIED
        found = bool(below.any())
        first = int(np.argmax(below))
        # the first surface met below (the search's end when none is), and the floor under it
        top = float(p[2] - depth[first]) if found else float(p[2] - depth[-1] - step)
        surface = top
        # A cafe flight that could not get home descended onto a counter the local map showed 0.7 m
        # below it, with seen free space under the counter: the simulator's vehicle went on down to
        # the floor past the counter's edge and touched it (a real one would land on the counter).
        raised = False
        if found:
            under = np.flatnonzero(~below[first:]) + first  # below the first surface's thickness
            if len(under) and states[under[0]] == VoxelState.FREE:
                lower = np.flatnonzero(below[under[0] :]) + under[0]
                if len(lower) and depth[lower[0]] - depth[first] <= self.RAISED_MAX:
                    raised, surface = True, float(p[2] - depth[lower[0]])
        # from a voxel above the first surface (an occupied voxel's top face) up to the vehicle
        heights = np.append(np.arange(top + 1.5 * step, p[2] - 1e-9, step), p[2])
        seen = look(self._column(p, heights).reshape(-1, 3))
        free = not bool(np.any(seen == VoxelState.OCCUPIED))
        if global_map:
            # From altitude the pitched camera may never have looked below the vehicle (a survey's
            # last waypoint: 73 % of the box under it unknown when its landing began, and clutter
            # there): a column the global map judges must have been seen free, not merely unseen.
            free = free and not bool(np.any(seen == VoxelState.UNKNOWN))
        supported = found and not raised and self._supported(look, p, top)
        return free and supported, (surface if found else float("inf")), free

    def _supported(self, look, p: np.ndarray, top: float, reach: float | None = None) -> bool:
        """Whether no cell of the footprint (the disc of ``reach``, default the robot radius,
        under ``p``) is over a void at ``top``, the height of the surface found below the centre:
        a cell is over a void when the maps saw it free from there down ``SUPPORT_DEPTH`` (where
        the surface should be, nothing — a slab's edge, whose void the rays past it carve free).
        Unknown cells are no evidence: below a floor nothing is ever seen."""
        heights = top - np.arange(0.0, self.SUPPORT_DEPTH + 1e-9, self.GUARD_STEP)
        footprint = self._column(p, heights, reach=self.radius if reach is None else reach)
        states = look(footprint.reshape(-1, 3)).reshape(footprint.shape[:2])
        return not bool(np.any(np.all(states == VoxelState.FREE, axis=0)))

    def _column(self, p: np.ndarray, heights: np.ndarray, reach: float | None = None) -> np.ndarray:
        """The descent column under ``p`` at ``heights`` (len(heights) × k × 3): at each height,
        a disc of ``reach`` (default the robot radius plus ``LANDING_MARGIN``) on the
        ``GUARD_STEP`` grid."""
        step = self.GUARD_STEP
        reach = self.radius + self.LANDING_MARGIN if reach is None else reach
        k = int(np.ceil(reach / step))
        axis = np.arange(-k, k + 1) * step
        ring = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
        ring = ring[np.linalg.norm(ring, axis=1) <= reach]
        column = np.empty((len(heights), len(ring), 3))
        column[:, :, :2] = np.asarray(p, float)[:2] + ring
        column[:, :, 2] = np.asarray(heights, float)[:, None]
        return column

    def seen_free_below(self, p_odom: np.ndarray, T_world_odom: np.ndarray | None = None) -> float:
        """How far below ``p_odom`` the descent column (robot radius plus ``LANDING_MARGIN`` around
        the vertical) has been seen free, m: every voxel of it down to there FREE in the local map
        or, with ``T_world_odom``, in the global map where the local one has nothing; at most
        ``GLOBAL_DESCENT_REACH``.

        A vehicle that cannot judge its landing from altitude (the surface below out of its maps'
        reach: a PAMS survey at 6 m maps only 5 m deep) may descend through this much, and look
        again (``trees.behaviours.Land``)."""
        p = np.asarray(p_odom, float)
        step = self.GUARD_STEP
        depth = np.arange(step, self.GLOBAL_DESCENT_REACH + 1e-9, step)
        column = self._column(p, p[2] - depth)
        states = self._look(T_world_odom)(column.reshape(-1, 3)).reshape(column.shape[:2])
        seen_free = np.all(states == VoxelState.FREE, axis=1)
        # the vehicle's own body fills the top of its column, where a camera pitched down (or its
        # minimum range) never looks: there, nothing occupied is enough
        body = depth <= self.radius + self.GUARD_MARGIN
        seen_free[body] = ~np.any(states[body] == VoxelState.OCCUPIED, axis=1)
        if seen_free.all():
            return float(depth[-1])
        first = int(np.argmin(seen_free))  # the highest level not seen free throughout
        return float(depth[first - 1]) if first else 0.0

    def surface_seen_locally(self, p_odom: np.ndarray) -> bool:
        """Whether the local map shows a surface within ``LOCAL_JUDGE_REACH`` below ``p_odom``.

        A landing judged otherwise was judged on the global map, built in the estimate's frame of
        minutes ago (a PAMS survey's put the lot's ground slab edge 0.3 m from where the vehicle,
        landing by it, met it), or at the bottom of the local window, where what lies under the
        surface (the void past a slab's edge, ``SUPPORT_DEPTH``) is out of the window. Only the
        local map is in the frame the vehicle flies in now (``trees.behaviours.Land`` steps down
        until this holds)."""
        p = np.asarray(p_odom, float)
        depth = np.arange(self.GUARD_STEP, self.LOCAL_JUDGE_REACH + 1e-9, self.GUARD_STEP)
        states = self.mapping.states(p - np.outer(depth, [0.0, 0.0, 1.0]), local=True)
        return bool(np.any(states == VoxelState.OCCUPIED))

    def landing_spot(
        self, here_odom: np.ndarray, T_world_odom: np.ndarray | None = None
    ) -> np.ndarray | None:
        """The nearest point at the vehicle's height whose descent is clear (:meth:`descent_clear`),
        onto a surface no higher than the one below the vehicle (the floor beside a table, never the
        table top), reached in a straight line clear of the local map; ``here_odom`` itself when
        its own column is clear; None if no such point lies within ``LANDING_SEARCH``.

        When the local map does not reach the surface below the vehicle (outdoors at 3.5 m its
        window ends about a metre above the ground), a surface it does reach nearby is higher than
        that ground — a car's roof — and never a landing spot: the vehicle lands where it is if
        its column is free as deep as the map sees, else at the nearest point whose column is;
        unless the vehicle is low over that surface and past its edge, its own vertical seen free
        where the surface would be (``_supported`` of the vertical alone): then the surface is
        the landing spot, not the drop beside it.
        With ``T_world_odom`` the global map sees what the local map does not reach
        (:meth:`_descent`)."""
        here = np.asarray(here_odom, float)
        clear, surface_here, free_here = self._descent(here, T_world_odom)
        if clear:
            return here
        unseen_ground = not np.isfinite(surface_here)
        if unseen_ground and free_here:
            return here
        for r in np.arange(self.LANDING_RING, self.LANDING_SEARCH + 1e-9, self.LANDING_RING):
            n = max(8, int(np.ceil(2 * np.pi * r / self.LANDING_RING)))
            for a in np.arange(n) * (2 * np.pi / n):
                spot = here + np.array([r * np.cos(a), r * np.sin(a), 0.0])
                clear, surface, free = self._descent(spot, T_world_odom)
                if unseen_ground:
                    # past the edge of a surface it is low over (a survey's drift took it 0.05 m
                    # past the lot's ground slab, seen free below it): that surface, over the drop
                    ok = (free and not np.isfinite(surface)) or (
                        clear
                        and here[2] - surface <= self.LOCAL_JUDGE_REACH
                        and not self._supported(self._look(None), here, surface, reach=0.0)
                    )
                else:
                    ok = clear and surface <= surface_here + 1.5 * self.GUARD_STEP
                if ok and self._straight_clear(here, spot):
                    return spot
        return None

    def _straight_clear(self, a: np.ndarray, b: np.ndarray) -> bool:
        """No occupied local voxel within the robot radius plus ``GUARD_MARGIN`` of segment a–b."""
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / self.GUARD_STEP)) + 1)
        line = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        keep = np.linalg.norm(self._offsets, axis=1) <= self.radius + self.GUARD_MARGIN
        near = (line[:, None, :] + self._offsets[keep][None, :, :]).reshape(-1, 3)
        return not bool(np.any(self.mapping.states(near, local=True) == VoxelState.OCCUPIED))
