"""Semantic loop closure (paper 1 §V-C): a panorama's objects registered against old landmarks.

The objects of the current panorama (in the yaw-free local frame) are registered against the
map's old landmarks by :mod:`.slc` (eqs. 2–6); an accepted registration ties the panorama's
measurements to the old landmarks, fuses the duplicates the drifting front end made, and lets
iSAM2 propagate the correction.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from amslam.geometry import wrap_angle, yaw_matrix, yaw_of
from amslam.plugins.gtsam_slam import slc
from amslam.plugins.gtsam_slam.frontend import FrontEnd
from amslam.plugins.gtsam_slam.graph import LandmarkRec, Observation
from amslam.plugins.gtsam_slam.params import LoopClosureParams
from amslam.types import Detection, LoopClosureResult, Odometry

__all__ = ["LoopCloser", "LoopClosureParams"]


@dataclass(frozen=True)
class _PathDrift:
    """Per key pose of the path flown (and the robot now, last): its odometry distance, and the
    standard deviation of the robot's drift now relative to it (position, m; yaw, rad)."""

    distances: np.ndarray
    position_sigma: np.ndarray
    yaw_sigma: np.ndarray


class LoopCloser:
    """Semantic loop closures of one robot's front end against its graph."""

    def __init__(
        self,
        params: LoopClosureParams,
        front: FrontEnd,
        chi2: float,
        rng: np.random.Generator | None = None,
        emit: Callable[..., None] = lambda *a, **k: None,
    ) -> None:
        self.p = params
        self.front = front
        self.graph = front.graph
        self.chi2 = chi2  # the association's gate, for fusing the duplicates a closure brings together
        self.rng = rng
        self.emit = emit

    def _panorama(self, odom: Odometry) -> tuple[list[list[Observation]], np.ndarray, list[str]]:
        """Objects seen in the current panorama, in the yaw-free local frame.

        Detections the front end associated with the same landmark are one object (one chair seen
        from several headings gives centroids more than ``merge_radius`` apart, biased towards
        the visible side; splitting it would put several B points on one map landmark). Objects of
        one class whose centres (odometry frame) lie within ``merge_radius`` are then merged:
        duplicates the drifting front end created for one physical object.
        """
        p = self.p
        kps = self.front.kps
        T = odom.T_odom_body
        recent = [
            o
            for o in self.graph.observations
            if o.robot == self.front.robot
            and odom.stamp - o.stamp <= p.window
            and np.linalg.norm(kps[o.keypose].T_odom_body[:3, 3] - T[:3, 3]) <= p.panorama_radius
        ]
        by_landmark: dict[int, list[Observation]] = {}
        for o in recent:
            by_landmark.setdefault(self.graph.live_id(o.landmark), []).append(o)
        groups: list[list[Observation]] = []
        centres: list[np.ndarray] = []
        for obs in by_landmark.values():
            c = np.mean([q.p_odom for q in obs], axis=0)
            best, bd = -1, p.merge_radius
            for g, (grp, cg) in enumerate(zip(groups, centres, strict=True)):
                dd = float(np.linalg.norm(cg - c))
                if grp[0].class_name == obs[0].class_name and dd <= bd:
                    best, bd = g, dd
            if best < 0:
                groups.append(list(obs))
                centres.append(c)
            else:
                groups[best].extend(obs)
                centres[best] = np.mean([q.p_odom for q in groups[best]], axis=0)
        local = (np.array(centres).reshape(-1, 3) - T[:3, 3]) @ yaw_matrix(yaw_of(T))  # Rzᵀ (p − t), row-wise
        return groups, local, [g[0].class_name for g in groups]

    def _path_drift(self, odom: Odometry) -> _PathDrift:
        """The drift of the robot's estimate now relative to each key pose of the path flown (the
        key poses, then the robot where it is now; a few ms at 3000 key poses, and loop closures
        are tried a few times a flight)."""
        front = self.front
        kps = front.kps
        poses = [*(kp.T_odom_body for kp in kps), odom.T_odom_body]
        positions = np.array([T_odom[:3, 3] for T_odom in poses])
        yaws = np.array([yaw_of(T_odom) for T_odom in poses])
        distances = np.array([*(kp.distance for kp in kps), front.distance])
        position_var, yaw_var = self.graph.noise.odometry_noise().drift_to_end(positions, yaws, distances)
        return _PathDrift(distances, np.sqrt(position_var), np.sqrt(yaw_var))

    def _prior(
        self, odom: Odometry, old: list[LandmarkRec], groups: list[list[Observation]], drift: _PathDrift
    ) -> tuple[slc.SlcPrior, np.ndarray]:
        """The current estimate of the robot's world yaw and position, and per-landmark drift bounds.

        A registration's correction is the drift of the estimate relative to the landmarks it
        matches, accumulated since the estimate was last tied to them: since each landmark was last
        observed by a detection *other than the panorama's own* (those are what the loop closure
        verifies), or since its first sighting. Landmark ``i`` thus bounds the correction by
        ``√(floor² + (prior_sigmas · σᵢ)²)`` — the registration's own error and the drift, which are
        independent — where σᵢ is the graph's own odometry model propagated along the key poses
        flown since that tie (:meth:`.OdometryNoise.drift_to_end`: the translation walk plus the
        yaw walk's sweep of the path since), for position and yaw alike; a solution
        must respect the bound of every landmark it matches (:class:`.slc.SlcPrior`). A robot that
        returns after a long loop, whose detections made new duplicates instead of re-observing the
        old landmarks, gets a wide bound; one whose front end kept re-observing them a narrow one,
        which rules out alignments shifted by a row of a repeated layout. The bound grows like the
        square root of the untied travel, as a random walk does: a bound linear in it let an 8 m
        false correction through after 290 m untied in a three-floor flight (this bound: 5.2 m).

        Returns:
            The prior and the untied travel of each landmark of ``old`` (m).
        """
        p = self.p
        front = self.front
        T = front.T_world_odom() @ odom.T_odom_body
        own = {id(o) for g in groups for o in g}
        tie_keypose = np.array(
            [
                max((o.keypose for o in lm.observations if id(o) not in own), default=lm.first_keypose)
                for lm in old
            ]
        )
        tie = np.clip(tie_keypose, 0, len(front.kps) - 1)
        prior = slc.SlcPrior(
            yaw=yaw_of(T),
            translation=T[:3, 3].copy(),
            max_translation=np.hypot(p.prior_translation_floor, p.prior_sigmas * drift.position_sigma[tie]),
            max_yaw=np.minimum(np.pi, np.hypot(p.prior_yaw_floor, p.prior_sigmas * drift.yaw_sigma[tie])),
        )
        return prior, np.maximum(front.distance - drift.distances[tie], 0.0)

    def try_loop_closure(
        self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]
    ) -> LoopClosureResult:
        """Register the panorama's objects against old map landmarks (eqs. 2–6) and close the loop.

        ``detections`` (seen now) are added first; the objects are all detections of the last
        ``window`` seconds taken within ``panorama_radius`` of the robot, so a panorama made of
        several detection frames is registered at once.
        """
        p = self.p
        front = self.front
        if detections:
            front.add_detections(odom, T_body_cam, detections)
        if not front.kps:
            return LoopClosureResult(False, "no key poses yet")
        groups, B, cb = self._panorama(odom)
        if len(groups) < p.min_matches:
            return LoopClosureResult(False, f"only {len(groups)} objects in view")
        now = front.distance
        old = [lm for lm in self.graph.graph_landmarks() if lm.first_distance <= now - p.min_age]
        if len(old) < p.min_matches:
            return LoopClosureResult(False, f"only {len(old)} old landmarks in the map")
        A = np.array([self.graph.point(lm.id) for lm in old])
        ca = [lm.class_name for lm in old]
        sp = slc.SlcParams(
            tolerance=p.tolerance,
            inlier_gate=p.inlier_gate,
            min_matches=p.min_matches,
            ambiguity_ratio=p.ambiguity_ratio,
        )
        drift = self._path_drift(odom)
        prior, untied = self._prior(odom, old, groups, drift) if p.prior else (None, np.zeros(0))
        bound: dict[str, float] = {}
        sol = (
            slc.solve_scalable(A, B, ca, cb, sp, prior=prior, rng=self.rng)
            if p.solver == "scalable"
            else slc.solve_exhaustive(A, B, ca, cb, sp, prior=prior)
        )
        if prior is not None and sol.matched:
            # The bound the solution (or the rejected best) was held to: its freshest landmark's.
            fresh = int(sol.pairs[np.argmin(untied[sol.pairs[:, 0]]), 0])
            bound = dict(
                untied_distance=float(untied[fresh]),
                bound_translation=float(prior.max_translation[fresh]),
                bound_yaw=float(prior.max_yaw[fresh]),
            )
        if not sol.accepted:
            return self._report(LoopClosureResult(False, sol.reason, sol.matched, sol.rms), **bound)
        # The robot's world pose implied by the registration vs the current SLAM estimate.
        T = odom.T_odom_body
        T_world_body = np.eye(4)
        T_world_body[:3, :3] = yaw_matrix(sol.yaw) @ yaw_matrix(yaw_of(T)).T @ T[:3, :3]
        T_world_body[:3, 3] = sol.translation
        before = front.T_world_odom() @ T
        dyaw = wrap_angle(yaw_of(T_world_body) - yaw_of(before))
        dt = float(np.linalg.norm(T_world_body[:3, 3] - before[:3, 3]))
        # However the registration was searched, a correction larger than the odometry model lets
        # the robot drift since the oldest matched landmark was first seen is a wrong registration.
        # With the drift bound (``prior``) this never binds (its floor and sigmas are smaller and
        # it counts from a later key pose); without it (the paper's search) it is the only check.
        oldest = min(old[int(a)].first_keypose for a, _ in sol.pairs)
        first = min(max(oldest, 0), len(front.kps) - 1)
        limit = float(np.hypot(p.max_drift_floor, p.max_drift_sigmas * drift.position_sigma[first]))
        if dt > limit:
            reason = f"correction {dt:.2f} m exceeds {limit:.2f} m"
            return self._report(LoopClosureResult(False, reason, sol.matched, sol.rms), **bound)
        self._close_loop(sol, old, groups, A, B)
        return self._report(LoopClosureResult(True, sol.reason, sol.matched, sol.rms, dyaw, dt), **bound)

    def _close_loop(
        self,
        sol: slc.SlcSolution,
        old: list[LandmarkRec],
        groups: list[list[Observation]],
        A: np.ndarray,
        B: np.ndarray,
    ) -> None:
        """Add the loop-closure constraints and let iSAM2 propagate the correction.

        A registration accepted at an RMS near the tolerance may hold a wrong pairing (chairs on a
        0.75 m grid against a 0.5 m inlier gate), so every loop-closure factor carries the robust
        kernel, and a duplicate is fused with its old twin (a stiff ``graph.fusion_sigma`` tie)
        only when that pair's own post-alignment error is below ``fuse_ratio × tolerance``.
        """
        p = self.p
        g = self.graph
        pair_err = np.linalg.norm(A[sol.pairs[:, 0]] - sol.transform(B[sol.pairs[:, 1]]), axis=1)
        for (a, b), err in zip(sol.pairs, pair_err, strict=True):
            target = old[int(a)]
            group = groups[int(b)]
            for o in group:
                # The panorama's own measurement, now tied to the old landmark. A shape's detection
                # already measuring the old landmark itself (its eq. 1 / eq. 2 factor) is not
                # measured again as a point.
                if not g.measured_as_point(target) and g.live_id(o.landmark) == target.id:
                    continue
                g.add_factor(g.bearing_range(o, target.id))
            # The robot is tied to this landmark again: the front end may track it with a tight gate.
            latest = max(group, key=lambda o: o.distance)
            target.seen_by(latest.robot, latest.keypose, latest.distance)
            if err > p.fuse_ratio * p.tolerance:
                continue
            for dup_id in {o.landmark for o in group} - {target.id}:
                dup = g.landmarks[dup_id]
                while dup.alias_of is not None and dup.alias_of >= 0 and dup.alias_of != target.id:
                    dup = g.landmarks[dup.alias_of]
                if dup.id == target.id or dup.alias_of == target.id:
                    continue
                g.fuse(target, dup, skip_pose_keys={q.pose_key for q in group})
        # Large corrections need a few relinearisation rounds to settle.
        g.flush(extra_iterations=5)
        # The panorama matches only the objects it sees; duplicates of objects just outside it were
        # also created while drifting and now, corrected, sit on their old twins: fuse them with
        # the bar matched pairs must pass.
        if g.fuse_duplicates(p.fuse_ratio * p.tolerance, self.chi2, class_gate=self.front.p.class_gate):
            g.flush(extra_iterations=2)

    def _report(self, result: LoopClosureResult, **extra: float) -> LoopClosureResult:
        self.emit(
            "slam_loop_closure",
            accepted=result.accepted,
            reason=result.reason,
            matched=result.matched,
            residual=result.residual,
            yaw_correction=result.yaw_correction,
            translation_correction=result.translation_correction,
            **extra,
        )
        return result
