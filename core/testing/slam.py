"""Contract tests for SLAM backends: key poses, drift correction and the semantic map from a synthetic flight.

    from amslam.testing.slam import SlamContract

    class TestMySlam(SlamContract):
        def make_backend(self):
            return MySlam()

The flight is an exact, drift-free VIO trajectory (a 6 m leg along +x at 1.2 m, then a 90° turn)
at 10 Hz, with two objects (a chair and a table) seen by the forward camera with exact centroids,
so the world estimate must agree with the odometry and the landmarks must sit on the objects.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amslam.geometry import pose_from
from amslam.interfaces import Slam
from amslam.lib.slc_gain import chain_gain
from amslam.testing.contract import BackendContract
from amslam.types import (
    R_BODY_CAM,
    Detection,
    KeyPose,
    Landmark,
    LoopClosureResult,
    Odometry,
    PoseUncertainty,
    SlcCandidate,
    SlcGainModel,
)

#: Camera mounted at the body origin looking along body +x.
T_BODY_CAM = np.eye(4)
T_BODY_CAM[:3, :3] = R_BODY_CAM
#: The objects of the synthetic flight (world = odometry frame, no drift).
OBJECTS = {"chair": np.array([4.0, 1.5, 0.5]), "table": np.array([7.0, -1.0, 0.6])}


def body_pose(x: float, y: float, yaw: float, z: float = 1.2) -> np.ndarray:
    """``T_odom_body`` of a level vehicle at (x, y, z) heading ``yaw``."""
    return pose_from(np.array([x, y, z], float), yaw)


def flight(rate_hz: float = 10.0) -> list[Odometry]:
    """6 m along +x at 1 m/s, then a quarter turn to the left in place at 0.5 rad/s."""
    out = []
    t = 0.0
    for x in np.arange(0.0, 6.0 + 1e-9, 1.0 / rate_hz):
        out.append(Odometry(t, body_pose(float(x), 0.0, 0.0)))
        t += 1.0 / rate_hz
    for yaw in np.arange(0.05, np.pi / 2 + 1e-9, 0.5 / rate_hz):
        out.append(Odometry(t, body_pose(6.0, 0.0, float(yaw))))
        t += 1.0 / rate_hz
    return out


def visible_detections(odom: Odometry, max_range: float = 5.0) -> list[Detection]:
    """Exact detections of the objects in front of the camera (60° half-angle cone, in range)."""
    T_cam_world = np.linalg.inv(odom.T_odom_body @ T_BODY_CAM)
    out = []
    for name, p in OBJECTS.items():
        c = T_cam_world[:3, :3] @ p + T_cam_world[:3, 3]
        if (
            c[2] > 0.3
            and np.linalg.norm(c) <= max_range
            and np.arctan2(np.hypot(c[0], c[1]), c[2]) < np.radians(40)
        ):
            pts = c + np.random.default_rng(len(out)).normal(0.0, 0.05, (30, 3))
            out.append(Detection(name, 0.9, c, pts))
    return out


def is_rigid(T: np.ndarray) -> bool:
    """A 4×4 homogeneous rigid transform."""
    T = np.asarray(T)
    R = T[:3, :3]
    return (
        T.shape == (4, 4)
        and np.allclose(T[3], [0, 0, 0, 1])
        and np.allclose(R @ R.T, np.eye(3), atol=1e-6)
        and np.isclose(np.linalg.det(R), 1.0, atol=1e-6)
    )


class SlamContract(BackendContract):
    """Mix-in of SLAM contract tests; override :meth:`make_backend`."""

    kind = Slam
    #: Landmark positions must land within this of the objects (m) after the exact flight.
    landmark_tolerance: float = 0.3

    @pytest.fixture
    def flown(self, backend: Slam) -> tuple[Slam, list[Odometry], int]:
        """The backend after the synthetic flight with detections at 2 Hz; also the count of True returns."""
        odoms = flight()
        created = 0
        for k, odom in enumerate(odoms):
            created += bool(backend.add_odometry(odom))
            if k % 5 == 0:
                backend.add_detections(odom, T_BODY_CAM, visible_detections(odom))
        return backend, odoms, created

    def test_no_keyposes_before_odometry(self, backend: Slam) -> None:
        assert backend.keyposes() == []
        assert backend.landmarks() == []
        assert is_rigid(backend.T_world_odom())

    def test_keyposes_oldest_first(self, flown) -> None:
        slam, odoms, created = flown
        kps = slam.keyposes()
        assert created >= 2 and len(kps) >= created
        assert all(isinstance(k, KeyPose) for k in kps)
        ids = [k.id for k in kps]
        assert len(set(ids)) == len(ids) and ids == sorted(ids)
        stamps = [k.stamp for k in kps]
        assert stamps == sorted(stamps) and odoms[0].stamp <= stamps[0] and stamps[-1] <= odoms[-1].stamp
        distances = [k.distance for k in kps]
        assert distances == sorted(distances) and distances[-1] <= 6.0 + 1e-6

    def test_without_drift_the_world_estimate_is_the_odometry(self, flown) -> None:
        slam, odoms, _ = flown
        T_wo = slam.T_world_odom()
        assert is_rigid(T_wo)
        by_stamp = {round(o.stamp, 6): o.T_odom_body for o in odoms}
        for kp in slam.keyposes():
            assert is_rigid(kp.T_world_body)
            T_odom_body = by_stamp[round(kp.stamp, 6)]
            np.testing.assert_allclose(kp.T_world_body[:3, 3], (T_wo @ T_odom_body)[:3, 3], atol=0.05)
            np.testing.assert_allclose(kp.T_world_body[:3, :3], (T_wo @ T_odom_body)[:3, :3], atol=0.02)

    def test_landmarks_sit_on_the_objects(self, flown) -> None:
        slam, _, _ = flown
        lms = slam.landmarks()
        assert all(isinstance(lm, Landmark) for lm in lms)
        assert len({lm.id for lm in lms}) == len(lms)
        for name, p in OBJECTS.items():
            mine = [lm for lm in lms if lm.class_name == name]
            assert len(mine) == 1, f"expected one {name} landmark, got {len(mine)}"
            (lm,) = mine
            assert np.linalg.norm(np.asarray(lm.position) - p) < self.landmark_tolerance
            assert lm.observations >= 1
            assert np.shape(lm.covariance) == (3, 3)

    def test_low_level_queries_have_their_shapes(self, flown) -> None:
        slam, odoms, _ = flown
        pose_trace, landmark_trace = slam.uncertainty()
        assert np.isfinite(pose_trace) and pose_trace >= 0
        assert np.isfinite(landmark_trace) and landmark_trace >= 0
        result = slam.try_loop_closure(odoms[-1], T_BODY_CAM, visible_detections(odoms[-1]))
        assert isinstance(result, LoopClosureResult) and isinstance(result.reason, str)
        cands = slam.slc_candidates(4.0)
        assert isinstance(cands, list) and all(isinstance(c, SlcCandidate) for c in cands)
        ids = [k.id for k in slam.keyposes()[:3]]
        gain = np.asarray(slam.information_gain(ids, [1.0] * len(ids)))
        assert gain.shape == (len(ids),) and np.all(np.isfinite(gain)) and np.all(gain >= -1e-9)
        model = slam.slc_gain_model(ids)
        if model is not None:  # a backend that scores chains of loop closures (Algorithm 1)
            assert isinstance(model, SlcGainModel) and set(ids) <= set(model.keypose_ids)
            current = model.keypose_ids[0]
            one = [chain_gain(model, [(current, i, 1.0)]) for i in ids if i != current]
            assert np.all(np.isfinite(one)) and np.all(np.asarray(one) >= -1e-9)
        pose = slam.pose_uncertainty()
        if pose is not None:  # a backend with covariances (PAMS's localisation constraint reads it)
            assert isinstance(pose, PoseUncertainty)
            cov = np.asarray(pose.position_covariance)
            assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) >= -1e-12)
            assert np.isfinite(pose.position_std) and pose.reach(pose.position_std + 1.0) > 0

    def test_loop_closure_adds_only_what_it_is_handed_now(self, flown) -> None:
        """``try_loop_closure`` gets the detections seen now, at ``odom``; the earlier ones were fed
        at their own poses by ``add_detections`` and are not handed over again (the runtime passes
        none). Passing none adds no observation; detections handed over are placed at ``odom``."""
        slam, odoms, _ = flown

        def observations() -> int:
            return sum(lm.observations for lm in slam.landmarks())

        # turn on the spot to face the chair: it is seen now, from here
        now = Odometry(odoms[-1].stamp + 0.1, body_pose(6.0, 0.0, float(np.arctan2(1.5, -2.0))))
        slam.add_odometry(now)
        before = observations()
        result = slam.try_loop_closure(now, T_BODY_CAM, [])
        assert isinstance(result, LoopClosureResult)
        assert observations() <= before, "try_loop_closure(..., []) added observations"
        seen_now = visible_detections(now)
        assert seen_now, "the chair is in view"
        slam.try_loop_closure(now, T_BODY_CAM, seen_now)
        assert observations() <= before + len(seen_now)
        for name, p in OBJECTS.items():
            # a detection placed at any pose but `now` would drag its landmark off the object
            mine = [lm for lm in slam.landmarks() if lm.class_name == name]
            assert (
                len(mine) == 1 and np.linalg.norm(np.asarray(mine[0].position) - p) < self.landmark_tolerance
            )

    def test_empty_detections_change_nothing(self, backend: Slam) -> None:
        odom = Odometry(0.0, body_pose(0.0, 0.0, 0.0))
        backend.add_odometry(odom)
        backend.add_detections(odom, T_BODY_CAM, [])
        assert backend.landmarks() == []

    def test_same_input_same_estimate(self, tmp_path: Path) -> None:
        runs = []
        for _ in range(2):
            slam = self.configured(tmp_path, seed=3)
            for k, odom in enumerate(flight()):
                slam.add_odometry(odom)
                if k % 5 == 0:
                    slam.add_detections(odom, T_BODY_CAM, visible_detections(odom))
            runs.append(
                (
                    [k.T_world_body for k in slam.keyposes()],
                    sorted((lm.class_name, tuple(np.round(lm.position, 9))) for lm in slam.landmarks()),
                )
            )
            slam.close()
        assert len(runs[0][0]) == len(runs[1][0])
        for a, b in zip(runs[0][0], runs[1][0], strict=True):
            np.testing.assert_allclose(a, b, atol=1e-9)
        assert runs[0][1] == runs[1][1]
