"""The SLAM front end of one robot: key poses, data association, the tentative-landmark buffer and
the shape front end hook-up (paper 1 §V-B; paper 2 §IV-B).

A :class:`FrontEnd` turns one robot's VIO and detections into factors of a :class:`.graph.SlamGraph`.
Onboard there is one (:class:`.backend.GtsamSlam`); at the base station there is one per robot,
all on one graph (:mod:`.merge`), so every robot's data is associated the same way.

* **Key poses** every ``keyposes.distance`` metres or ``keyposes.yaw`` radians, and whenever
  objects are detected away from the last key pose; the first is held at the robot's start.
* **Association** per class, one-to-one per frame (Hungarian) on the Mahalanobis distance between
  detection and landmark, tracked landmarks first; an ambiguous detection starts a new landmark
  (:meth:`FrontEnd.associate`).
* **Tentative buffer**: a new object enters the graph only once seen ``min_observations`` times,
  with all its buffered measurements, so a single false positive never reaches the optimiser;
  one unseen for ``tentative_timeout`` key poses is dropped.
* **Shape classes** (``landmark_models``: cuboid / cylinder / plane) go through
  :class:`.shape_landmarks.ShapeLandmarks` first: associated by overlap, measured as a shape fitted
  over a time window, whose reference point replaces the visible-surface centroid.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from amslam.geometry import invert, wrap_angle, yaw_of
from amslam.lib import shapes
from amslam.plugins.gtsam_slam.graph import LandmarkRec, Observation, PoseKeys, SlamGraph
from amslam.plugins.gtsam_slam.params import AssociationParams, KeyPoseParams
from amslam.types import Detection, Odometry

__all__ = ["AssociationParams", "FrontEnd", "KeyPoseParams", "KeyPoseRec"]


class KeyPoseRec:
    """A key pose of one robot: its id (index in the chain), key, stamp, VIO pose and travel."""

    __slots__ = ("id", "key", "stamp", "T_odom_body", "distance")

    def __init__(self, id: int, key: int, stamp: float, T_odom_body: np.ndarray, distance: float) -> None:  # noqa: A002
        self.id, self.key, self.stamp, self.T_odom_body, self.distance = id, key, stamp, T_odom_body, distance


class FrontEnd:
    """One robot's key poses and detections, associated and buffered into a shared graph.

    Args:
        graph: the map this robot's factors go into.
        association: gates and the tentative buffer.
        keyposes: the key-pose schedule (only :meth:`add_odometry` uses it).
        robot: the robot's index (landmark records note who saw them).
        keys: the gtsam keys of this robot's key poses.
        T_world_odom: the robot's known start: its odometry frame in the world frame.
        emit: ``emit(event, **fields)`` for the run's event log.
        keep_points: keep each observation's object points (the base and the reported object
            map fit boxes to all of them), at most ``max_kept_points`` of each (every k-th).
    """

    def __init__(
        self,
        graph: SlamGraph,
        association: AssociationParams,
        keyposes: KeyPoseParams | None = None,
        robot: int = 0,
        keys: PoseKeys | None = None,
        T_world_odom: np.ndarray | None = None,
        emit: Callable[..., None] = lambda *a, **k: None,
        keep_points: bool = False,
        max_kept_points: int | None = None,
    ) -> None:
        self.graph = graph
        self.p = association
        self.keypose_params = keyposes or KeyPoseParams()
        self.robot = robot
        self.keys = keys or PoseKeys()
        self.T_world_odom_start = np.eye(4) if T_world_odom is None else np.asarray(T_world_odom, float)
        self.emit = emit
        self.keep_points = keep_points
        self.max_kept_points = max_kept_points
        self.kps: list[KeyPoseRec] = []
        self.last_odom: Odometry | None = None
        self.distance = 0.0  # travelled so far (VIO), m
        self._shape_assoc: dict[int, int] = {}  # detection index → shape landmark (this frame)
        self._shape_meas: dict[int, dict] = {}  # detection index → measured shape, body frame
        self._shape_twins: list[tuple[int, int]] = []  # (measured landmark, same-object landmark)
        self._shape_version = -1  # graph version of the shape estimates used for association

    # ---------------------------------------------------------------- key poses

    def pose(self, kp: int) -> np.ndarray:
        """The current world-frame estimate of key pose ``kp``."""
        return self.graph.pose(self.kps[kp].key)

    def track(self, odom: Odometry) -> None:
        """Follow VIO: the distance travelled."""
        if self.last_odom is not None and odom.stamp >= self.last_odom.stamp:
            step = odom.T_odom_body[:3, 3] - self.last_odom.T_odom_body[:3, 3]
            self.distance += float(np.linalg.norm(step))
        self.last_odom = odom

    def new_keypose(self, odom: Odometry) -> int:
        """A key pose at ``odom``: the first at the robot's start, the others chained by VIO."""
        i = len(self.kps)
        key = self.keys(i)
        T = odom.T_odom_body
        if i == 0:
            self.graph.add_first_pose(key, self.T_world_odom_start @ T)
        else:
            prev = self.kps[-1]
            dyaw = wrap_angle(yaw_of(T) - yaw_of(prev.T_odom_body))
            self.graph.add_odometry(
                prev.key, key, invert(prev.T_odom_body) @ T, dyaw, self.T_world_odom_start @ T
            )
        self.kps.append(KeyPoseRec(i, key, odom.stamp, T.copy(), self.distance))
        return i

    def add_keypose(self, odom: Odometry) -> int:
        """A key pose at ``odom`` whatever the schedule (the base replays a robot's own key poses)."""
        self.track(odom)
        kp = self.new_keypose(odom)
        self.expire_tentative()
        return kp

    def _due(self, T: np.ndarray, dist: float, dyaw: float) -> bool:
        ref = self.kps[-1].T_odom_body
        return (
            float(np.linalg.norm(T[:3, 3] - ref[:3, 3])) >= dist
            or abs(wrap_angle(yaw_of(T) - yaw_of(ref))) >= dyaw
        )

    def add_odometry(self, odom: Odometry) -> bool:
        """Track VIO; a key pose every ``keyposes.distance`` m or ``keyposes.yaw`` rad."""
        self.track(odom)
        kp = self.keypose_params
        if self.kps and not self._due(odom.T_odom_body, kp.distance, kp.yaw):
            return False
        self.new_keypose(odom)
        self.expire_tentative()
        self.graph.flush()
        return True

    # ---------------------------------------------------------------- detections

    def add_detections(
        self,
        odom: Odometry,
        T_body_cam: np.ndarray,
        detections: list[Detection],
        keypose: int | None = None,
        flush: bool = True,
    ) -> None:
        """Associate detections (camera frame, made at VIO pose ``odom``) and add their factors.

        ``keypose``: the key pose they were made at (the base replays a log whose every detection
        frame has one); by default a new key pose is made when ``odom`` is away from the last.
        """
        p = self.p
        dets = [d for d in detections if d.confidence >= p.min_confidence]
        pts_cam = [np.asarray(d.centroid_cam, float) for d in dets]
        keep = [i for i, c in enumerate(pts_cam) if 1e-3 < np.linalg.norm(c) <= p.max_range]
        dets = [dets[i] for i in keep]
        if not dets:
            return
        kp = keypose if keypose is not None else self._detection_keypose(odom)
        rec = self.kps[kp]
        T_odom_kp = rec.T_odom_body
        # Re-express the detections in the key pose's body frame with the (locally exact) VIO motion.
        T_kp_cam = invert(T_odom_kp) @ odom.T_odom_body @ T_body_cam
        p_body = np.array([T_kp_cam[:3, :3] @ pts_cam[i] + T_kp_cam[:3, 3] for i in keep])
        T_world_kp = self.pose(kp)
        self._shape_assoc, self._shape_meas, self._shape_twins = {}, {}, []
        if self.graph.shapes.models:  # paper 2's shape landmarks: their own front end
            dets, p_body = self._shape_detections(odom.stamp, kp, T_kp_cam, dets, p_body)
        if dets:
            p_world = p_body @ T_world_kp[:3, :3].T + T_world_kp[:3, 3]
            assoc = self.associate([d.class_name for d in dets], p_world, p_body, rec.distance)
            for i, lm_id in self._shape_assoc.items():
                assoc[i] = lm_id
            self._observe(odom.stamp, kp, T_kp_cam, dets, p_body, p_world, assoc)
            if self._shape_twins:
                self.graph.fuse_shape_twins(self._shape_twins, self.emit)
                self._shape_twins = []
        self.expire_tentative()
        if flush:
            self.graph.flush()

    def _detection_keypose(self, odom: Odometry) -> int:
        """The key pose a detection frame at ``odom`` is made at: a new one when ``odom`` is away
        from the last (``keyposes.detection_distance`` / ``detection_yaw``), else the last."""
        if self.last_odom is None or odom.stamp > self.last_odom.stamp:
            self.track(odom)
        kpp = self.keypose_params
        due = not self.kps or self._due(odom.T_odom_body, kpp.detection_distance, kpp.detection_yaw)
        return self.new_keypose(odom) if due else len(self.kps) - 1

    def _observe(
        self,
        stamp: float,
        kp: int,
        T_kp_cam: np.ndarray,
        dets: list[Detection],
        p_body: np.ndarray,
        p_world: np.ndarray,
        assoc: list[int],
    ) -> None:
        """Record each associated detection as an observation of its landmark (a new landmark for
        ``-1``), admit landmarks seen often enough into the graph, add the shapes' measurements."""
        p = self.p
        g = self.graph
        rec = self.kps[kp]
        T_odom_kp = rec.T_odom_body
        p_odom = p_body @ T_odom_kp[:3, :3].T + T_odom_kp[:3, 3]
        for k, (d, pb, pw, po, lm_id) in enumerate(zip(dets, p_body, p_world, p_odom, assoc, strict=True)):
            if lm_id < 0:
                lm_id = g.new_landmark_id()
                g.landmarks[lm_id] = self._new_landmark(lm_id, d.class_name, kp)
            lm = g.landmarks[lm_id]
            points = None
            if self.keep_points:
                pc = np.asarray(d.points_cam, float).reshape(-1, 3)
                if self.max_kept_points and len(pc) > self.max_kept_points:
                    pc = pc[:: -(-len(pc) // self.max_kept_points)]
                points = pc @ T_kp_cam[:3, :3].T + T_kp_cam[:3, 3]
            obs = Observation(
                self.robot,
                kp,
                rec.key,
                rec.distance,
                stamp,
                d.class_name,
                pb,
                po,
                lm_id,
                points,
                d.confidence,
                _horizontal_spread(d.points_cam, T_kp_cam),
            )
            g.observe(lm, obs, pw)
            if not lm.in_graph and lm.count >= p.min_observations:
                g.admit(lm)
            if k in self._shape_meas:
                g.observe_shape(lm, rec.key, self._shape_meas[k])

    def _new_landmark(self, lm_id: int, class_name: str, kp: int) -> LandmarkRec:
        rec = self.kps[kp]
        return LandmarkRec(
            lm_id,
            class_name,
            kp,
            rec.distance,
            np.zeros(3),
            robot=self.robot,
            last_robot=self.robot,
            last_keypose=kp,
            last_distance=rec.distance,
        )

    def expire_tentative(self) -> None:
        """Drop this robot's tentative landmarks unseen for ``tentative_timeout`` key poses."""
        if not self.kps:
            return
        now = len(self.kps) - 1
        for lm in self.graph.landmarks.values():
            if (
                not lm.in_graph
                and lm.alias_of is None
                and lm.last_robot == self.robot
                and now - lm.last_keypose > self.p.tentative_timeout
            ):
                lm.alias_of = -1  # dropped: never re-associated, never reported

    # ---------------------------------------------------------------- association

    def associate(
        self, classes: list[str], p_world: np.ndarray, p_body: np.ndarray, distance: float
    ) -> list[int]:
        """Per class, one-to-one (Hungarian) on Mahalanobis distance, tracked landmarks first.

        A metric nearest-neighbour gate wider than the spacing of similar objects (chairs 0.75 m
        apart) makes the estimate lock onto the neighbouring object and slide along a row of them.
        So the gate is statistical: the innovation variance is the detection's range-bearing noise,
        plus the spread of an object's centroid across viewpoints (the visible part moves with the
        view), plus the landmark's own estimate noise, plus the drift the robot may have accumulated
        relative to the landmark since it last saw it (VIO's random walk over that travel, in
        position and, through yaw, at the detection's range), capped by ``gate``. A landmark
        another robot saw last is as far from this robot's estimate as this robot has travelled
        from its known start.

        Landmarks seen within the last ``track_distance`` metres of travel are matched first
        (tracking: drift is negligible, the gate is tight); only detections none of them explains
        are matched against older landmarks. A detection that two candidates explain nearly
        equally well (χ² within ``ambiguity``) is not matched to either: it starts a new tentative
        landmark, which a later fusion (loop closure, or the base's) joins to its twin. A duplicate
        costs little; a wrong association corrupts the map.

        Returns, per detection, a landmark id or ``-1`` for a new landmark.
        """
        from scipy.optimize import linear_sum_assignment

        p = self.p
        out = [-1] * len(classes)
        live = self.graph.live_landmarks()
        if not live:
            return out
        travel = np.array(
            [
                max(0.0, distance - lm.last_distance) if lm.last_robot == self.robot else distance
                for lm in live
            ]
        )
        recent = travel <= p.track_distance
        for stage in (recent, ~recent):
            todo = [i for i in range(len(classes)) if out[i] == -1]
            cands = [lm for lm, keep in zip(live, stage, strict=True) if keep]
            if not todo or not cands:
                continue
            m2, gated = self._innovations(
                [classes[i] for i in todo], p_world[todo], p_body[todo], cands, travel[stage]
            )
            if not gated.any():
                continue
            r, c = linear_sum_assignment(np.where(gated, m2, 1e9))
            for i, j in zip(r, c, strict=True):
                rivals = np.flatnonzero(gated[i])
                rivals = rivals[rivals != j]
                if gated[i, j] and not np.any(m2[i, rivals] - m2[i, j] < p.ambiguity):
                    out[todo[i]] = cands[j].id
        return out

    def _innovations(
        self,
        classes: list[str],
        p_world: np.ndarray,
        p_body: np.ndarray,
        cands: list[LandmarkRec],
        travel: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Squared Mahalanobis distances detections × landmarks, and which pairs pass the gates."""
        p = self.p
        g = self.graph
        pos = np.array([g.landmark_position(lm) for lm in cands])
        lm_var = np.array([g.landmark_variance(lm) for lm in cands])
        det_var = np.array([g.noise.detection_variance(pb) for pb in p_body])
        drift_var = g.noise.drift_variance(travel, np.linalg.norm(p_body, axis=1))
        d2 = np.sum((p_world[:, None, :] - pos[None, :, :]) ** 2, axis=2)
        m2 = d2 / (det_var[:, None] + p.object_sigma**2 + lm_var[None, :] + drift_var)
        if p.class_gate is None:
            same_class = np.array(classes)[:, None] == np.array([lm.class_name for lm in cands])[None, :]
        else:  # a landmark whose class posterior clearly disagrees (below the gate) is not a candidate
            post = [g.class_probabilities(lm, classes) for lm in cands]
            same_class = np.array([[q.get(c, 0.0) >= p.class_gate for q in post] for c in classes])
        gated = same_class & (d2 <= p.gate**2) & (m2 <= p.chi2)
        return m2, gated

    # ---------------------------------------------------------------- shape classes (paper 2)

    def _shape_detections(
        self, stamp: float, kp: int, T_kp_cam: np.ndarray, dets: list[Detection], p_body: np.ndarray
    ) -> tuple[list[Detection], np.ndarray]:
        """The shape-class front end (:mod:`.shape_landmarks`), before centroid association.

        ``plane`` detections feed the ground buffer and leave. A ``cuboid`` / ``cylinder``
        detection is associated by overlap, its points join its landmark's window and the
        window's fitted shape becomes the measurement: its reference point (box centre, cylinder
        root) replaces the visible-surface centroid as the detection's point: the landmark's
        position is the shape's reference point. A detection that yields no shape is dropped.

        Returns:
            The detections and body-frame points that go on to :meth:`associate`;
            ``_shape_assoc`` / ``_shape_meas`` hold, by their new index, the landmark and the
            measured shape of the shape-class ones, ``_shape_twins`` the same-object pairs found.
        """
        g = self.graph
        sh = g.shapes
        rec = self.kps[kp]
        T_odom_kp = rec.T_odom_body
        T_odom_cam = T_odom_kp @ T_kp_cam
        T_world_kp = self.pose(kp)
        T_world_odom = T_world_kp @ invert(T_odom_kp)
        live = {lm.id: lm.class_name for lm in g.live_landmarks()}
        if self._shape_version != g.version:
            sh.refresh_estimates(g.estimate)
            self._shape_version = g.version
            # moved estimates can bring two landmarks of one object together: fuse them now
            self._shape_twins += sh.all_twins(live)
        out_d: list[Detection] = []
        out_p: list[np.ndarray] = []
        for d, pb in zip(dets, p_body, strict=True):
            model = sh.model(d.class_name)
            if model == "centroid":
                out_d.append(d)
                out_p.append(pb)
                continue
            pts = np.asarray(d.points_cam, float).reshape(-1, 3) @ T_odom_cam[:3, :3].T + T_odom_cam[:3, 3]
            if model == "plane":
                sh.add_ground(stamp, pts)
                continue
            if len(pts) == 0:
                continue
            pts_world = pts @ T_world_odom[:3, :3].T + T_world_odom[:3, 3]
            # two detections of one frame are two objects: a landmark this frame measured is taken
            taken = set(self._shape_assoc.values())
            free = {j: c for j, c in live.items() if j not in taken}
            associated = sh.associate(d.class_name, pts, pts_world, free, stamp)
            first = associated if associated >= 0 else g.new_landmark_id()
            lm_id, shape_body = sh.measure_view(
                first, associated >= 0, g.new_landmark_id, T_world_kp,
                d.class_name, stamp, pts, T_odom_kp, T_odom_cam[:3, 3], T_world_odom,
            )  # fmt: skip
            new = associated < 0 or lm_id != first
            if shape_body is None:
                if new:
                    sh.recs.pop(lm_id, None)
                continue
            if new:
                g.landmarks[lm_id] = self._new_landmark(lm_id, d.class_name, kp)
                live[lm_id] = d.class_name
            sh.set_world(lm_id, shapes.transform_shape(shape_body, T_world_kp))
            sh.record_slack(lm_id, rec.key, shape_body)
            self._shape_twins += [(lm_id, j) for j in sh.twins(lm_id, live)]
            k = len(out_d)
            self._shape_assoc[k] = lm_id
            self._shape_meas[k] = shape_body
            out_d.append(d)
            out_p.append(shapes.shape_center(shape_body))
        return out_d, np.array(out_p).reshape(-1, 3)

    # ---------------------------------------------------------------- outputs

    def T_world_odom(self) -> np.ndarray:
        """SLAM-minus-VIO correction at the latest key pose (drift compensation, paper 1 §VI-E)."""
        if not self.kps:
            return self.T_world_odom_start.copy()
        kp = self.kps[-1]
        return self.graph.pose(kp.key) @ invert(kp.T_odom_body)


def _horizontal_spread(points_cam: np.ndarray | None, T_kp_cam: np.ndarray) -> float:
    """Horizontal RMS spread (m) of a detection's points about their centroid, in the key pose's
    body frame (z up); 0 without points."""
    pts = np.asarray(points_cam if points_cam is not None else np.zeros((0, 3)), float).reshape(-1, 3)
    if len(pts) < 2:
        return 0.0
    xy = pts @ T_kp_cam[:2, :3].T
    return float(np.sqrt(np.mean(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1))))
