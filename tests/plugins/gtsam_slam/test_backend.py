"""The ``gtsam`` SLAM backend: graph, data association, outputs, loop closure, eq. (10)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gtsam
import numpy as np
import pydantic
import pytest
from gtsam.symbol_shorthand import L, X

from amslam.errors import MissionError
from amslam.geometry import pose_from, yaw_of
from amslam.interfaces import RunContext
from amslam.mission import load_mission
from amslam.plugins.gtsam_slam.backend import MOVED_PARAMETERS, GtsamSlam
from amslam.plugins.gtsam_slam.information import brute_force_information_gain
from amslam.plugins.gtsam_slam.synthetic import camera_mount
from amslam.registry import build_plugin_manager
from amslam.types import Detection, Odometry

from .conftest import configured, drive_loop


def test_registered_through_the_entry_point() -> None:
    assert build_plugin_manager().factory("slam", "gtsam") is GtsamSlam


def test_params_forbid_unknown_keys() -> None:
    with pytest.raises(pydantic.ValidationError):
        GtsamSlam.Params(keypose_distanse=1.0)


def test_a_flat_key_of_before_the_split_is_one_located_error_naming_its_new_path(tmp_path, registry) -> None:
    path = tmp_path / "old.yaml"
    path.write_text("name: old\nslam:\n  plugin: gtsam\n  association_gate: 0.8\n  slc_tolerance: 0.2\n")
    with pytest.raises(MissionError) as err:
        load_mission(path, registry)
    assert err.value.problems == [
        f"{path}:4: slam.association_gate: moved: it is now slam.association.gate"
        " (the gtsam parameters are grouped by part) (got 0.8)",
        f"{path}:5: slam.slc_tolerance: moved: it is now slam.loop_closure.tolerance"
        " (the gtsam parameters are grouped by part) (got 0.2)",
    ]
    # every old flat name has a new home that exists
    for old, new in MOVED_PARAMETERS.items():
        section, name = new.split(".")
        assert name in type(getattr(GtsamSlam.Params(), section)).model_fields, old


def test_keyposes_every_half_metre_and_yaw_step() -> None:
    slam = configured()
    for i in range(51):  # 5 m straight in 0.1 m steps
        assert slam.add_odometry(Odometry(i * 0.1, pose_from(np.array([i * 0.1, 0, 1]), 0.0))) == (i % 5 == 0)
    assert len(slam.keyposes()) == 11
    assert slam.keyposes()[-1].distance == pytest.approx(5.0)
    assert slam.add_odometry(Odometry(6.0, pose_from(np.array([5.0, 0, 1]), 0.5)))  # turn in place
    np.testing.assert_allclose(slam.T_world_odom(), np.eye(4), atol=1e-9)  # no information to correct


def chair_at(T_world_body: np.ndarray, p_world: np.ndarray, cls: str = "chair") -> Detection:
    T_world_cam = T_world_body @ camera_mount()
    c = T_world_cam[:3, :3].T @ (p_world - T_world_cam[:3, 3])
    return Detection(cls, 0.9, c)


def test_landmarks_need_min_observations_and_false_positives_never_enter() -> None:
    slam = configured(association={"min_observations": 3, "tentative_timeout": 5})
    chair = np.array([4.0, 0.5, 0.6])
    ghost = np.array([3.0, -1.0, 0.5])
    for i in range(12):
        T = pose_from(np.array([i * 0.2, 0, 1]), 0.0)
        slam.add_odometry(Odometry(i, T))
        dets = [chair_at(T, chair)] + ([chair_at(T, ghost, "plant")] if i == 1 else [])
        slam.add_detections(Odometry(i, T), camera_mount(), dets)
        if i == 1:
            assert slam.landmarks() == []  # two sightings: still tentative
    lms = slam.landmarks()
    assert [lm.class_name for lm in lms] == ["chair"]
    assert lms[0].observations == 12
    np.testing.assert_allclose(lms[0].position, chair, atol=1e-6)
    assert lms[0].first_keypose == 0


def test_nearby_objects_of_one_class_stay_apart() -> None:
    slam = configured(association={"gate": 0.4})
    chairs = [np.array([4.0, 0.0, 0.5]), np.array([4.0, 0.6, 0.5]), np.array([4.3, -0.6, 0.5])]
    for i in range(6):
        T = pose_from(np.array([i * 0.3, 0.05 * i, 1]), 0.02 * i)
        slam.add_odometry(Odometry(i, T))
        slam.add_detections(Odometry(i, T), camera_mount(), [chair_at(T, c) for c in chairs])
    found = sorted(slam.landmarks(), key=lambda lm: lm.position[1])
    assert len(found) == 3
    for lm, c in zip(found, sorted(chairs, key=lambda c: c[1]), strict=True):
        np.testing.assert_allclose(lm.position, c, atol=1e-6)


def test_covariances_match_gtsam_marginals(looped) -> None:  # noqa: ANN001
    slam, _ = looped
    graph, values = slam.graph()
    marginals = gtsam.Marginals(graph, values)
    for lm in slam.landmarks()[:5]:
        np.testing.assert_allclose(
            lm.covariance, marginals.marginalCovariance(L(lm.id)), rtol=1e-6, atol=1e-12
        )
    kps = slam.keyposes()
    expected = np.mean([np.trace(marginals.marginalCovariance(X(k.id))) for k in kps])
    assert slam.uncertainty()[0] == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("variables", ["all", "poses"])
def test_information_gain_fast_equals_brute_force(variables: str) -> None:
    slam, _ = drive_loop(3, slam=configured(active={"ig_variables": variables}))
    graph, values = slam.graph()
    before = np.array([values.atPose3(X(k.id)).matrix() for k in slam.keyposes()])
    ids, dists = [0, 7, 20, 45, 80], [30.0, 25.0, 12.0, 6.0, 2.0]
    fast = slam.information_gain(ids, dists)
    over = [int(k) for k in values.keys()] if variables == "all" else [X(k.id) for k in slam.keyposes()]  # noqa: SIM118
    brute = [
        brute_force_information_gain(graph, values, slam.virtual_factor(i, d), over)
        for i, d in zip(ids, dists, strict=True)
    ]
    np.testing.assert_allclose(fast, brute, rtol=1e-6)
    assert np.all(fast > 0)
    # The estimate is untouched by the virtual factors.
    after = np.array([k.T_world_body for k in slam.keyposes()])
    np.testing.assert_allclose(after, before, atol=1e-12)
    # A longer virtual trip is a noisier factor: less gain.
    assert slam.information_gain([0], [5.0])[0] > slam.information_gain([0], [50.0])[0]


def test_slc_candidates_cluster_landmarks_and_pick_the_oldest_keypose(looped) -> None:  # noqa: ANN001
    slam, _ = looped
    cands = slam.slc_candidates(sensing_range=5.0)
    assert cands
    kps = {k.id: k for k in slam.keyposes()}
    lms = {lm.id: lm for lm in slam.landmarks()}
    for c in cands:
        assert len(c.landmark_ids) >= 3
        assert c.info_gain > 0
        # The oldest key pose from which a panorama (observations from key poses within the
        # panorama radius) saw at least three landmarks of the cluster within sensing range.
        radius = slam.params.loop_closure.panorama_radius
        observed = {}
        for i in c.landmark_ids:
            for obs in slam._graph.landmarks[i].observations:
                observed.setdefault(obs.keypose, set()).add(i)

        def panorama_sees(k, observed=observed, radius=radius):
            here = kps[k].T_world_body[:3, 3]
            seen = set().union(
                *(
                    ids
                    for m, ids in observed.items()
                    if np.linalg.norm(kps[m].T_world_body[:3, 3] - here) <= radius
                )
            )
            return sum(np.linalg.norm(lms[i].position - here) <= 5.0 for i in seen)

        qualifying = [k for k in sorted(observed) if panorama_sees(k) >= 3]
        assert qualifying and c.keypose_id == qualifying[0]
        np.testing.assert_allclose(c.position, kps[c.keypose_id].T_world_body[:3, 3])
        assert c.yaw == pytest.approx(yaw_of(kps[c.keypose_id].T_world_body))


def test_no_loop_closure_without_old_landmarks() -> None:
    slam = configured()
    T = pose_from(np.array([0.0, 0, 1]), 0.0)
    slam.add_odometry(Odometry(0, T))
    dets = [chair_at(T, np.array([3.0, y, 0.5])) for y in (-1.0, 0.0, 1.2)]
    res = slam.try_loop_closure(Odometry(0, T), camera_mount(), dets)
    assert not res.accepted


def test_semantic_loop_closure_removes_the_drift() -> None:
    slam, world = drive_loop(0)
    vio_before = np.linalg.norm(world.T_vio[:3, 3] - world.T_true[:3, 3])
    assert vio_before > 1.0  # beyond the association gate: only SLC can close this loop
    pose_tr, lm_tr = slam.uncertainty()
    Tc = camera_mount()
    for T in world.panorama():
        world.move_to(T)
        slam.add_odometry(world.odometry())
        slam.add_detections(world.odometry(), Tc, world.detect())
    res = slam.try_loop_closure(world.odometry(), Tc, [])
    assert res.accepted, res.reason
    assert res.matched >= 3
    assert res.translation_correction > 0.5
    T_slam = slam.current_pose()
    slam_err = np.linalg.norm(T_slam[:3, 3] - world.T_true[:3, 3])
    vio_err = np.linalg.norm(world.T_vio[:3, 3] - world.T_true[:3, 3])
    assert slam_err < 0.2 * vio_err
    yaw_err = abs(np.angle(np.exp(1j * (yaw_of(T_slam) - yaw_of(world.T_true)))))
    assert yaw_err < 0.3 * abs(np.angle(np.exp(1j * (yaw_of(world.T_vio) - yaw_of(world.T_true)))))
    # The correction propagates back: the pose and landmark uncertainty both drop.
    pose_after, lm_after = slam.uncertainty()
    assert pose_after < 0.7 * pose_tr
    assert lm_after < lm_tr
    # Duplicates made while drifting were fused: no two same-class landmarks within 0.4 m.
    lms = slam.landmarks()
    for a in lms:
        for b in lms:
            if a.id < b.id and a.class_name == b.class_name:
                assert np.linalg.norm(a.position - b.position) > 0.4


def _loop_then_panorama(**params: object) -> tuple[GtsamSlam, list[tuple[str, dict]]]:
    events: list[tuple[str, dict]] = []
    slam = GtsamSlam()
    emit = lambda e, **k: events.append((e, k))  # noqa: E731
    ctx = RunContext(rng=np.random.default_rng(7), run_dir=Path("."), emit=emit)
    slam.configure(GtsamSlam.Params(**params), ctx)
    slam, world = drive_loop(0, slam=slam)
    Tc = camera_mount()
    for T in world.panorama():
        world.move_to(T)
        slam.add_odometry(world.odometry())
        slam.add_detections(world.odometry(), Tc, world.detect())
    slam.try_loop_closure(world.odometry(), Tc, [])
    return slam, events


def test_loop_closure_is_held_to_the_drift_bound() -> None:
    # Default bound: the start's landmarks were last observed a whole loop (~40 m) ago.
    _, events = _loop_then_panorama()
    name, ev = events[-1]
    assert name == "slam_loop_closure" and ev["accepted"], ev
    assert ev["untied_distance"] > 30.0
    # At least 3σ of the odometry model's horizontal walk over the untied travel (0.05 m/√m per axis).
    assert ev["bound_translation"] >= 3 * 0.05 * np.sqrt(2 * ev["untied_distance"])
    assert ev["translation_correction"] <= ev["bound_translation"]
    # A bound that does not grow with the untied travel makes the 1 m correction implausible.
    _, events = _loop_then_panorama(loop_closure={"prior_sigmas": 0.0})
    assert not events[-1][1]["accepted"]
    assert "within the drift bound" in events[-1][1]["reason"]


def test_without_the_drift_bound_the_odometry_model_still_refuses_an_implausible_correction() -> None:
    # The paper's unconstrained search: the ~1 m correction after a ~40 m loop is within 4σ of the
    # odometry model's drift since the start's landmarks were first seen, so it is accepted.
    _, events = _loop_then_panorama(loop_closure={"prior": False})
    ev = events[-1][1]
    assert ev["accepted"], ev
    assert 0.5 < ev["translation_correction"] < 2.0
    # The same correction against a model that lets the robot drift almost nothing is refused.
    tight = {"prior": False, "max_drift_sigmas": 0.1, "max_drift_floor": 0.3}
    _, events = _loop_then_panorama(loop_closure=tight)
    ev = events[-1][1]
    assert not ev["accepted"]
    assert ev["reason"].startswith("correction ") and "exceeds" in ev["reason"], ev["reason"]
    limit = float(ev["reason"].split("exceeds ")[1].split(" m")[0])
    assert 0.3 <= limit < 0.5  # the 0.3 m floor and a tenth of a σ of about half a metre


def _near_duplicates(slam: GtsamSlam, radius: float = 0.4) -> int:
    lms = slam.landmarks()
    return sum(
        1
        for a in lms
        for b in lms
        if a.id < b.id and a.class_name == b.class_name and np.linalg.norm(a.position - b.position) <= radius
    )


def test_loop_closure_fuses_only_well_aligned_duplicates() -> None:
    # Default: every matched pair aligns within half the tolerance, so the duplicates are fused.
    fused, events = _loop_then_panorama()
    assert events[-1][1]["accepted"], events[-1][1]
    assert _near_duplicates(fused) == 0
    # A fusion gate no pair passes: the loop still closes (range-bearing factors to the old
    # landmarks), but the duplicates stay separate landmarks.
    kept, events = _loop_then_panorama(loop_closure={"fuse_ratio": 1e-6})
    assert events[-1][1]["accepted"], events[-1][1]
    assert _near_duplicates(kept) > 0
    assert len(kept.landmarks()) > len(fused.landmarks())


def test_duplicate_fusion_leaves_two_tentative_landmarks_to_the_front_end() -> None:
    # Two tentative (not yet in the graph) chairs 5 cm apart, never seen in one frame: fusing them
    # would tie measurements to a variable the graph does not have.
    slam = configured(association={"min_observations": 50})
    T = pose_from(np.array([0.0, 0, 1]), 0.0)
    slam.add_odometry(Odometry(0, T))
    slam.add_detections(Odometry(0, T), camera_mount(), [chair_at(T, np.array([2.0, 0.0, 0.5]))])
    T2 = pose_from(np.array([0.3, 0, 1]), 0.0)
    slam.add_odometry(Odometry(1, T2))
    first = next(iter(slam._graph.landmarks.values()))
    dup = dataclasses.replace(
        first,
        id=99,
        first_keypose=1,
        observations=[
            dataclasses.replace(o, keypose=1, pose_key=X(1), landmark=99) for o in first.observations
        ],
        last_keypose=1,
    )
    slam._graph.landmarks[99] = dup
    lc = slam.params.loop_closure  # the bar after a loop closure
    slam._graph.fuse_duplicates(lc.fuse_ratio * lc.tolerance, slam.params.association.chi2)
    assert all(lm.alias_of is None for lm in slam._graph.landmarks.values())
    assert slam.landmarks() == []  # both still tentative; nothing reaches the graph


def test_vio_odometry_is_trusted_more_in_height_than_across():
    # A gravity- and barometer-aided VIO drifts ~4x less in height; with one sigma for all axes
    # the landmarks' heights pulled the chain (the PAL home: the estimate 1.0 m low, VIO 0.05 m).
    from amslam.plugins.gtsam_slam.graph import GraphParams, NoiseModels

    sigmas = NoiseModels(GraphParams()).odometry(4.0, 0.0).sigmas()
    assert sigmas[3] == pytest.approx(0.05 * 2) and sigmas[4] == pytest.approx(0.05 * 2)
    assert sigmas[5] == pytest.approx(0.012 * 2)
    tight = NoiseModels(GraphParams(odometry_sigma_vertical=0.003)).odometry(4.0, 0.0).sigmas()
    assert tight[5] == pytest.approx(0.006)


def test_class_posterior_is_the_bayesian_update_of_the_detections_scores() -> None:
    """Paper 2's per-object class probability: the detector's label and score read as a
    symmetric confusion model, multiplied over the detections (checked against the product of
    the likelihoods written out), over the classes the map knows."""
    from amslam.plugins.gtsam_slam.graph import LandmarkRec, class_posterior

    classes = ["chair", "sofa", "table"]
    lm = LandmarkRec(0, "chair", 0, 0.0, np.zeros(3))
    lm.add_class_evidence("chair", 0.7)
    post = class_posterior(lm.class_evidence, classes)
    assert post == pytest.approx({"chair": 0.7, "sofa": 0.15, "table": 0.15})  # one look: its score
    detections = [("chair", 0.7), ("chair", 0.6), ("table", 0.9), ("chair", 0.45)]
    for c, p in detections[1:]:
        lm.add_class_evidence(c, p)
    brute = {
        k: np.prod([p if c == k else (1 - p) / (len(classes) - 1) for c, p in detections]) for k in classes
    }
    total = sum(brute.values())
    assert class_posterior(lm.class_evidence, classes) == pytest.approx(
        {k: v / total for k, v in brute.items()}
    )
    # a class the map learns later is one more alternative for every landmark
    wider = class_posterior(lm.class_evidence, [*classes, "shelf"])
    assert wider["chair"] > post["chair"] and sum(wider.values()) == pytest.approx(1.0)


def _hover_and_detect(slam: GtsamSlam, frames: list[tuple[str, float, list[float]]]) -> None:
    """One detection per frame, from a robot hovering at the origin (camera-frame points)."""
    odom = Odometry(0.0, pose_from(np.array([0.0, 0.0, 1.0]), 0.0))
    slam.add_odometry(odom)
    for i, (cls, score, where) in enumerate(frames):
        at = Odometry(0.1 * (i + 1), odom.T_odom_body)
        slam.add_detections(at, camera_mount(), [Detection(cls, score, np.array(where, float))])


@pytest.mark.parametrize("gate", [None, 0.2])
def test_association_and_the_reported_class_posterior(gate: float | None) -> None:
    """Each landmark reports its class posterior. With ``association.class_gate`` a detection may
    join a landmark of another label whose posterior still allows its class (one weak 'chair'
    look), never one whose posterior clearly disagrees (five confident 'chair' looks); without
    it, only landmarks of its own label."""
    slam = configured(association={"class_gate": gate, "min_observations": 1})
    weak, sure = [1.5, 0.0, 4.0], [-1.5, 0.0, 4.0]  # camera frame: 4 m ahead, 3 m apart
    _hover_and_detect(
        slam,
        [("sofa", 0.8, [0.0, 0.0, 7.0]), ("chair", 0.35, weak)]
        + [("chair", 0.9, sure)] * 5
        + [("table", 0.8, weak), ("table", 0.8, sure)],
    )
    lms = slam.landmarks()
    for lm in lms:
        assert set(lm.class_probabilities) == {"chair", "sofa", "table"}
        assert sum(lm.class_probabilities.values()) == pytest.approx(1.0)
    at_sure = [lm for lm in lms if abs(lm.position[1] - 1.5) < 0.5]
    at_weak = [lm for lm in lms if abs(lm.position[1] + 1.5) < 0.5]
    # the confident chair never takes the table detection
    assert sorted(lm.class_name for lm in at_sure) == ["chair", "table"]
    chair = next(lm for lm in at_sure if lm.class_name == "chair")
    assert chair.class_probabilities["chair"] > 0.999
    if gate is None:
        assert sorted(lm.class_name for lm in at_weak) == ["chair", "table"]
    else:  # one object: its posterior now says table, though it was first labelled chair
        assert len(at_weak) == 1 and at_weak[0].observations == 2
        probs = at_weak[0].class_probabilities
        assert probs["table"] > 0.6 > probs["chair"]


def test_pose_uncertainty_is_the_latest_key_poses_position_marginal_in_the_world_frame():
    from amslam.types import Odometry

    from .conftest import configured

    slam = configured()
    assert slam.pose_uncertainty() is None  # no key pose yet
    stds = []
    for k in range(41):  # 20 m due north (yaw 90°), no landmarks: nothing corrects the odometry
        T = np.eye(4)
        T[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        T[:3, 3] = (0.0, 0.5 * k, 1.2)
        slam.add_odometry(Odometry(0.1 * k, T))
        if (pose := slam.pose_uncertainty()) is not None:
            stds.append(pose.position_std)
    pose = slam.pose_uncertainty()
    cov = pose.position_covariance
    np.testing.assert_allclose(cov, cov.T)
    assert np.all(np.diff(stds) >= -1e-12) and stds[-1] > stds[0]  # grows with the distance flown
    # the yaw random walk's lever arm widens the error across the track (world x), not along it
    assert cov[0, 0] > cov[1, 1]
    # the translation walk alone over 20 m bounds it from below (σ = 0.05 m/√m · √20 m)
    assert pose.position_std >= 0.05 * np.sqrt(20.0) - 1e-6
    assert pose.odometry == slam._graph.noise.odometry_noise()


def test_spread_slack_loosens_a_wide_objects_centroid_not_a_compact_ones() -> None:
    """A detection's point landmark is the centroid of the part in view: with ``graph.spread_slack``
    a table's (points spread 0.4 m) is measured looser than a chair's (0.1 m), in range and across,
    and by nothing when the slack is off."""
    from amslam.plugins.gtsam_slam.frontend import _horizontal_spread
    from amslam.plugins.gtsam_slam.graph import LandmarkRec, Observation

    rng = np.random.default_rng(0)
    T_kp_cam = np.eye(4)
    T_kp_cam[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # camera z forward = body x
    wide = rng.normal(0.0, [0.4, 0.05, 0.05], (400, 3)) + [0, 0, 3.0]  # across the view (camera x)
    compact = rng.normal(0.0, [0.1, 0.1, 0.05], (400, 3)) + [0, 0, 3.0]  # camera y is down
    high = rng.normal(0.0, [0.05, 0.6, 0.05], (400, 3)) + [0, 0, 3.0]  # a tall, thin object: vertical
    assert _horizontal_spread(wide, T_kp_cam) == pytest.approx(0.4, abs=0.04)
    assert _horizontal_spread(compact, T_kp_cam) == pytest.approx(np.hypot(0.1, 0.05), abs=0.02)
    assert _horizontal_spread(high, T_kp_cam) < 0.1
    assert _horizontal_spread(np.zeros((0, 3)), T_kp_cam) == 0.0

    def sigmas(slack: float, spread: float) -> np.ndarray:
        slam = configured(graph={"spread_slack": slack})
        g = slam._graph
        g.landmarks[0] = LandmarkRec(0, "table", 0, 0.0, np.zeros(3))
        p = np.array([3.0, 0.0, 0.0])
        ob = Observation(0, 0, 0, 0.0, 0.0, "table", p, p, 0, spread=spread)
        factor = g.bearing_range(ob, 0, robust=False)
        return factor.noiseModel().sigmas()

    off, table, chair = sigmas(0.0, 0.4), sigmas(1.0, 0.4), sigmas(1.0, 0.1)
    np.testing.assert_allclose(off, sigmas(0.0, 0.0))
    assert table[2] == pytest.approx(off[2] + 0.4) and table[0] == pytest.approx(off[0] + 0.4 / 3.0)
    assert off[2] < chair[2] < table[2]


def test_views_within_the_spread_window_share_one_offset() -> None:
    """Detections of one object made moments apart see the same part of it, so their centroids
    share one offset from its centre: with ``graph.spread_window`` the k-th of them within the
    window is widened by √k times its spread slack (k views weigh about as one), one made after a
    longer pause or by another robot is not."""
    from amslam.plugins.gtsam_slam.graph import LandmarkRec, Observation

    slam = configured(graph={"spread_slack": 1.0, "spread_window": 10.0})
    g = slam._graph
    lm = LandmarkRec(0, "table", 0, 0.0, np.zeros(3))
    g.landmarks[0] = lm
    p = np.array([3.0, 0.0, 0.0])
    base = configured(graph={"spread_slack": 0.0})._graph.noise.bearing_range(3.0, robust=False).sigmas()

    def range_sigma(stamp: float, robot: int = 0) -> float:
        ob = Observation(robot, 0, 0, 0.0, stamp, "table", p, p, 0, spread=0.4)
        lm.observations.append(ob)  # as SlamGraph.observe records it before its factor
        return float(g.bearing_range(ob, 0, robust=False).noiseModel().sigmas()[2])

    widened = [range_sigma(t) for t in (0.0, 1.0, 2.0, 3.0)]
    np.testing.assert_allclose(widened, base[2] + 0.4 * np.sqrt([1, 2, 3, 4]))
    assert range_sigma(20.0) == pytest.approx(base[2] + 0.4)  # after a pause: a view of its own
    assert range_sigma(20.5, robot=1) == pytest.approx(base[2] + 0.4)  # another robot's view
    off = configured(graph={"spread_slack": 1.0})._graph
    off.landmarks[0] = lm
    ob = Observation(0, 0, 0, 0.0, 21.0, "table", p, p, 0, spread=0.4)
    lm.observations.append(ob)
    assert off.bearing_range(ob, 0, robust=False).noiseModel().sigmas()[2] == pytest.approx(base[2] + 0.4)
