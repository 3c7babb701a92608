"""Active SLAM (paper 1 §VI-C): where a loop closure would help, and how much (eq. 10).

Landmarks are clustered (DBSCAN per floor); each cluster's viewpoint is an old key pose a panorama
from which would see enough of it; a candidate's value is the information gain of a *virtual*
odometry factor from the current pose to that key pose, evaluated against the linearised graph
without changing the estimate (:mod:`.information`: low-rank updates of one factorisation).
"""

from __future__ import annotations

import gtsam
import numpy as np

from amslam.geometry import wrap_angle, yaw_of
from amslam.plugins.gtsam_slam.frontend import FrontEnd
from amslam.plugins.gtsam_slam.graph import LandmarkRec
from amslam.plugins.gtsam_slam.information import virtual_factor
from amslam.plugins.gtsam_slam.params import ActiveParams
from amslam.types import SlcCandidate, SlcGainModel

__all__ = ["ActiveParams", "ActiveSlam"]


class ActiveSlam:
    """Eq. (10) and the SLC candidates of one robot's front end.

    ``panorama_radius`` and ``min_matches`` are the loop closure's (:class:`.LoopClosureParams`):
    a candidate is worth flying to only if the panorama there can close the loop.
    """

    def __init__(
        self, params: ActiveParams, front: FrontEnd, panorama_radius: float, min_matches: int
    ) -> None:
        self.p = params
        self.front = front
        self.graph = front.graph
        self.panorama_radius = panorama_radius
        self.min_matches = min_matches

    def _ig_keys(self) -> list[int] | None:
        if self.p.ig_variables == "all":
            return None
        return [k.key for k in self.front.kps]

    def _virtual_noise(self, keypose_id: int, travel_distance: float) -> gtsam.noiseModel.Base:
        """The odometry model over ``travel_distance`` metres from the current pose to a key pose."""
        kps = self.front.kps
        dyaw = wrap_angle(yaw_of(self.front.pose(keypose_id)) - yaw_of(self.front.pose(kps[-1].id)))
        return self.graph.noise.odometry(float(travel_distance), dyaw)

    def information_gain(self, keypose_ids: list[int], travel_distances: list[float]) -> np.ndarray:
        """Eq. (10) for a virtual odometry factor from the current pose to each key pose.

        The factor's noise is the odometry model over ``travel_distances[i]`` metres. Each
        candidate is evaluated alone against the current graph; the estimate never changes.
        """
        if not self.front.kps or not keypose_ids:
            return np.zeros(len(keypose_ids))
        lg = self.graph.linearized()
        kps = self.front.kps
        cur = kps[-1].key
        jac = []
        for k, dist in zip(keypose_ids, travel_distances, strict=True):
            _, J = virtual_factor(cur, kps[k].key, self.graph.estimate, self._virtual_noise(k, dist))
            jac.append(J)
        return lg.information_gain(cur, [kps[k].key for k in keypose_ids], jac, self._ig_keys())

    def slc_gain_model(self, keypose_ids: list[int]) -> SlcGainModel | None:
        """Eq. (10) for chains of virtual factors among the current key pose and ``keypose_ids``
        (Algorithm 1 re-estimates each candidate given the loop closures already planned)."""
        kps = self.front.kps
        if not kps:
            return None
        ids = list(dict.fromkeys([kps[-1].id, *keypose_ids]))
        keys = [kps[i].key for i in ids]
        covariance, gram = self.graph.linearized().joint_blocks(keys, self._ig_keys())
        poses = np.array([self.graph.estimate.atPose3(k).matrix() for k in keys])
        return SlcGainModel(tuple(ids), poses, covariance, gram, self.graph.noise.odometry_noise())

    def virtual_factor(self, keypose_id: int, travel_distance: float) -> gtsam.BetweenFactorPose3:
        """The virtual factor :meth:`information_gain` evaluates (for brute-force checks)."""
        kps = self.front.kps
        noise = self._virtual_noise(keypose_id, travel_distance)
        f, _ = virtual_factor(kps[-1].key, kps[keypose_id].key, self.graph.estimate, noise)
        return f

    def slc_candidates(self, sensing_range: float) -> list[SlcCandidate]:
        """DBSCAN clusters of landmarks per floor → oldest key pose seeing the cluster → IG.

        A cluster needs ``cluster_min_landmarks`` landmarks (three fix position and yaw). Its
        viewpoint is the oldest key pose from which any landmark of the cluster lies within
        ``sensing_range``. The candidate's information gain here uses the straight-line distance
        from the current pose as the travel distance, a first estimate: the planner re-scores
        each candidate with the map's path costs and the loop closures already in its tour
        (:meth:`slc_gain_model`).
        """
        from sklearn.cluster import DBSCAN

        p = self.p
        lms = self.graph.graph_landmarks()
        kps = self.front.kps
        if len(lms) < p.cluster_min_landmarks or not kps:
            return []
        pos = np.array([self.graph.point(lm.id) for lm in lms])
        floors = np.floor(pos[:, 2] / p.floor_height).astype(int)
        kp_pos = np.array([self.front.pose(k.id)[:3, 3] for k in kps])
        cur = kps[-1].id
        out: list[tuple[int, np.ndarray, float, tuple[int, ...]]] = []
        for f in np.unique(floors):
            sel = np.flatnonzero(floors == f)
            if len(sel) < p.cluster_min_landmarks:
                continue
            labels = DBSCAN(eps=p.dbscan_eps, min_samples=1).fit(pos[sel]).labels_
            for lab in np.unique(labels):
                members = sel[labels == lab]
                if len(members) < p.cluster_min_landmarks:
                    continue
                i = self._viewpoint(lms, members, pos, kp_pos, sensing_range)
                if i is None or i == cur:
                    continue
                T = self.front.pose(i)
                out.append((i, T[:3, 3].copy(), yaw_of(T), tuple(int(lms[j].id) for j in members)))
        if not out:
            return []
        here = self.front.pose(cur)[:3, 3]
        ig = self.information_gain([o[0] for o in out], [float(np.linalg.norm(o[1] - here)) for o in out])
        return [SlcCandidate(i, q, y, ids, float(g)) for (i, q, y, ids), g in zip(out, ig, strict=True)]

    def _viewpoint(
        self,
        lms: list[LandmarkRec],
        members: np.ndarray,
        pos: np.ndarray,
        kp_pos: np.ndarray,
        sensing_range: float,
    ) -> int | None:
        """The oldest key pose a panorama from which would see enough of the cluster.

        Paper 1 takes the oldest key pose within sensing range of a landmark of the cluster. An
        SLC needs ``min_matches`` landmarks in one panorama, and range alone ignores walls: so
        prefer the oldest key pose where the landmarks actually *observed* from key poses within
        ``panorama_radius`` of it (what a panorama there would see) number enough; fall back to
        the paper's rule when no key pose qualifies.
        """
        need = min(self.min_matches, len(members))
        observed_from: dict[int, set[int]] = {}
        for j in members:
            for obs in lms[j].observations:
                if obs.robot == self.front.robot:
                    observed_from.setdefault(obs.keypose, set()).add(int(j))
        if observed_from:
            kps = np.array(sorted(observed_from))
            near = np.linalg.norm(kp_pos[kps][:, None] - kp_pos[kps][None], axis=2) <= self.panorama_radius
            for row, k in enumerate(kps):
                seen = set().union(*(observed_from[int(m)] for m in kps[near[row]]))
                close = np.linalg.norm(pos[list(seen)] - kp_pos[k], axis=1) <= sensing_range
                if close.sum() >= need:
                    return int(k)
        d = np.linalg.norm(kp_pos[:, None, :] - pos[members][None], axis=2)
        seen_any = np.flatnonzero((d <= sensing_range).any(axis=1))
        return int(seen_any[0]) if len(seen_any) else None
