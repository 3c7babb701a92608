"""Multi-robot experiment set-up and scoring (the flights themselves: the slow test at the end)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from amslam.apps.multirobot import (
    class_models,
    flight_key,
    fly_team,
    index_runs,
    score,
    tables,
    team_overrides,
)
from amslam.measurements import read_measurements
from amslam.mission import load_mission
from amslam.plugins.sim.teams import split_area
from amslam.registry import build_plugin_manager
from amslam.runner import Runner, started_platform
from amslam.types import Landmark, WorldSummary
from tests.tiny_mission import tiny_mission_file, tiny_mission_text
from tests.world_summaries import objects_world


@pytest.fixture(scope="module")
def registry():  # noqa: ANN201
    return build_plugin_manager(())


def mission_file(folder: Path, max_time: float = 400) -> Path:
    return tiny_mission_file(folder, max_time)


def test_the_base_merges_shapes_as_the_robots_mapped_them(registry) -> None:  # noqa: ANN001
    """The merge's shape classes are the robots' ``slam.landmark_models``, not the world's true
    shapes (which no robot knows)."""
    team = load_mission("lot_team", registry)
    assert class_models(team) == {"car": "cuboid", "pole": "cylinder", "tree_trunk": "cylinder"}
    as_points = load_mission("lot_team", registry, ["slam.landmark_models={car: centroid}"])
    assert class_models(as_points) == {}
    assert class_models(load_mission("one_floor", registry)) == {}  # odometry SLAM: no models


def test_split_area_along_the_longer_side() -> None:
    strips = split_area(np.array([0.0, 0.0, 0.0]), np.array([12.0, 8.0, 3.0]), 3)
    assert len(strips) == 3
    np.testing.assert_allclose([s[0][0] for s in strips], [0, 4, 8])
    np.testing.assert_allclose([s[1][0] for s in strips], [4, 8, 12])
    assert all(s[0][1] == 0 and s[1][1] == 8 for s in strips)


def test_team_flies_one_world_from_own_bases(registry, tmp_path: Path) -> None:  # noqa: ANN001
    spec = str(mission_file(tmp_path))
    teams = team_overrides(spec, registry, 2, "homogeneous", 5, scratch=tmp_path)
    assert len(teams) == 2
    worlds, seeds, starts = [], [], []
    for k, flags in enumerate(teams):
        mission = load_mission(spec, registry, flags)
        assert mission.name == f"tiny-r{k + 1}"
        area = mission.model.area
        assert area is not None
        start = np.array(mission.backends["platform"].params.start)
        assert area.lo[0] <= start[0] <= area.hi[0] and area.lo[1] <= start[1] <= area.hi[1]
        platform = started_platform(mission, registry, tmp_path)
        worlds.append(platform.world_summary().object_positions)
        seeds.append(mission.model.seed)
        starts.append(start)
        platform.close()
    assert seeds[0] != seeds[1]  # own VIO, camera and detector noise ...
    assert worlds[0].keys() == worlds[1].keys()  # ... in the same world
    for key in worlds[0]:
        np.testing.assert_allclose(worlds[0][key], worlds[1][key])
    assert np.linalg.norm(starts[0] - starts[1]) >= 1.0


def test_heterogeneous_team_has_an_overhead_robot(registry, tmp_path: Path) -> None:  # noqa: ANN001
    spec = str(mission_file(tmp_path))
    hom = team_overrides(spec, registry, 2, "homogeneous", 5, scratch=tmp_path)
    het = team_overrides(spec, registry, 3, "heterogeneous", 5, overhead_altitude=2.0, scratch=tmp_path)
    # the low robots of a heterogeneous team of 3 are the homogeneous team of 2, flight for flight
    missions = [load_mission(spec, registry, flags) for flags in [*hom, *het]]
    assert [flight_key(m) for m in missions[:2]] == [flight_key(m) for m in missions[2:4]]
    high = missions[-1]
    assert high.name == "tiny-overhead" and high.model.robot.altitude == 2.0
    assert high.backends["platform"].params.camera.pitch_deg == 60.0
    assert high.model.area is None  # the overhead robot covers the whole area
    assert high.model.tree == "exploration"  # indoors (a roof): it explores from its altitude
    assert flight_key(high) not in {flight_key(m) for m in missions[:-1]}


def test_overhead_lawnmower_stays_high_and_clear(registry, tmp_path: Path) -> None:  # noqa: ANN001
    spec = tmp_path / "lot.yaml"
    spec.write_text(
        tiny_mission_text(240)
        .replace("altitude: 1.2", "altitude: 3.0")
        .replace(
            "world: {size: [12, 8], floors: 1}", "world: {kind: outdoor, size: [24, 14], ground_class: null}"
        )
    )
    (flags,) = team_overrides(str(spec), registry, 1, "heterogeneous", 5, scratch=tmp_path)
    mission = load_mission(str(spec), registry, flags)
    assert mission.model.tree == "waypoints" and mission.model.robot.altitude == 6.0  # 2 × 3 m
    platform = started_platform(mission, registry, tmp_path)
    try:
        start = np.array([*mission.backends["platform"].params.start, 0.0])
        pts = np.array(mission.model.waypoints.points) + start
        assert np.all(pts[:, 2] == 6.0)  # climbs at its base, then holds its altitude
        legs = [
            a + (b - a) * t for a, b in zip(pts[:-1], pts[1:], strict=True) for t in np.linspace(0, 1, 40)
        ]
        assert platform.world.distance(np.array(legs)).min() > mission.model.robot.radius + 0.5
        # lanes across the whole lot (along its longer side, x), at most 6 m apart
        lanes = sorted({round(float(y), 2) for y in pts[1:, 1]})
        assert np.ptp(pts[:, 0]) > 18.0 and max(np.diff(lanes)) <= 6.0 + 3.0 and np.ptp(lanes) > 8.0
    finally:
        platform.close()


def test_earlier_flights_are_found_by_what_they_fly(registry, tmp_path: Path) -> None:  # noqa: ANN001
    spec = str(mission_file(tmp_path))
    teams = team_overrides(spec, registry, 2, "homogeneous", 5, scratch=tmp_path)
    for k, flags in enumerate(teams):  # two finished runs as the runner leaves them
        run = tmp_path / "earlier" / f"run{k}"
        run.mkdir(parents=True)
        (run / "mission.yaml").write_text(yaml.safe_dump(load_mission(spec, registry, flags).resolved()))
        (run / "metrics.json").write_text('{"sim_duration_s": 100.0}')
        (run / "measurements.jsonl").write_text("")
    found = index_runs([tmp_path / "earlier"], registry)
    assert len(found) == 2
    # robot 2 of the pair is found from its flags, whatever its name; a 1-robot team is not
    again = load_mission(spec, registry, [*teams[1], "name=renamed"])
    assert found[flight_key(again)]["run_dir"] == tmp_path / "earlier" / "run1"
    (alone,) = team_overrides(spec, registry, 1, "homogeneous", 5, scratch=tmp_path)
    assert flight_key(load_mission(spec, registry, alone)) not in found


def world_summary() -> WorldSummary:
    return objects_world(
        {"a": ("car", [1.0, 1.0, 0.7]), "b": ("car", [5.0, 1.0, 0.7]), "c": ("pole", [3, 3, 0.0])},
        {
            "a": {"model": "cuboid", "center": [1.0, 1.0, 0.7], "yaw": 0.0, "dims": [4.0, 2.0, 1.4]},
            "b": {"model": "cuboid", "center": [5.0, 1.0, 0.7], "yaw": 0.0, "dims": [4.0, 2.0, 1.4]},
        },
    )


def test_score_matches_by_class_within_the_gate() -> None:
    cov = np.eye(3) * 0.01
    shape = {"model": "cuboid", "center": [1.1, 1.0, 0.7], "yaw": 0.0, "dims": [4.3, 2.0, 1.4]}
    lms = [
        Landmark(0, "car", np.array([1.1, 1.0, 0.7]), cov, 5, -1, shape),
        Landmark(1, "car", np.array([5.0, 1.3, 0.7]), cov, 5),
        Landmark(2, "car", np.array([3.0, 3.0, 0.0]), cov, 5),  # wrong class at the pole
        Landmark(3, "pole", np.array([8.0, 8.0, 0.0]), cov, 5),  # nothing there
    ]
    s = score(lms, world_summary())
    assert s["objects"] == 3 and s["mapped"] == 2 and s["spurious"] == 2
    assert s["position_error_mean"] == pytest.approx(0.2)
    assert s["dimension_error_mean"] == pytest.approx(0.1) and s["shapes_compared"] == 1
    # paper 2's error (Figs. 10-11): the vehicles' length (0.3 m off) and width (exact), pooled
    assert s["length_width_error_mean"] == pytest.approx(0.15) and s["vehicles_compared"] == 1
    assert s["length_width_error_std"] == pytest.approx(0.15)
    assert s["errors"] == {
        "a": pytest.approx(0.1),
        "b": pytest.approx(0.3),
    }  # per object, for common-object rows


def test_tables_like_figs_10_11() -> None:
    def row(name: str, opm: float, err: float) -> dict:
        return {
            "name": name,
            "objects_per_minute": opm,
            "mapped": 10,
            "spurious": 1,
            "position_error_mean": err,
            "position_error_std": 0.1,
            "minutes": 4.0,
            "objects": 12,
        }

    results = [
        {
            "seed": s,
            "n": 2,
            "mode": "homogeneous",
            "schedule": "simultaneous",
            "rows": [row("robot 1", 1.0, 0.3), row("robot 2", 2.0, 0.2), row("combined", 3.0, 0.1 * s)],
        }
        for s in (1, 2)
    ]
    text = tables(results)
    assert "| Num. of obj. / min | 1.00 | 2.00 | 3.00 |" in text
    assert "| Pos. err. mean (m) | 0.30 | 0.20 | 0.15 |" in text
    assert "longest robot time" in text
    assert "| 2 | 3.00 | 10.0 | 1.0 | 0.15 | 0.10 |" in text


@pytest.mark.slow
def test_a_run_logs_its_measurements(registry, tmp_path: Path) -> None:  # noqa: ANN001
    mission = load_mission(
        str(mission_file(tmp_path, max_time=15)), registry, ["exploration.look_around=true"]
    )
    result = Runner(mission, registry, tmp_path / "runs").run()
    log = read_measurements(result.run_dir)
    assert log.robot == "tiny" and len(log.stamps) >= 2
    np.testing.assert_allclose(log.T_world_odom, np.eye(4))
    assert log.truth is not None
    # the simulator's odometry frame is the world frame at the start: VIO and truth agree there
    np.testing.assert_allclose(log.T_odom_body[0][:3, 3], log.truth[0][:3, 3], atol=1e-6)
    header = yaml.safe_load((result.run_dir / "measurements.jsonl").read_text().splitlines()[0])
    assert header["type"] == "header"
    # the camera's depth noise, for the base's box fits: the simulated camera's own
    assert log.depth_noise == mission.backends["platform"].params.camera.depth_noise > 0


@pytest.mark.slow
def test_two_robot_team_end_to_end(registry, tmp_path: Path) -> None:  # noqa: ANN001
    spec = str(mission_file(tmp_path, max_time=150))
    team = fly_team(spec, registry, 2, "homogeneous", 5, tmp_path / "runs", log=lambda s: None)
    robots, combined = team["rows"][:-1], team["rows"][-1]
    assert combined["mapped"] >= max(r["mapped"] for r in robots)
    assert combined["minutes"] == pytest.approx(max(r["minutes"] for r in robots))
    assert (Path(team["merged_dir"]) / "landmarks.json").exists()


def test_lot_team_flies_the_papers_altitudes(registry, tmp_path: Path) -> None:  # noqa: ANN001
    # paper 2 Fig. 10: a robot at 2.5 m and a robot at 5 m (the overhead robot's altitude is twice
    # the mission's, under the lot's 7 m flight volume)
    spec = "lot_team"  # the packaged mission
    low, high = (
        load_mission(spec, registry, flags)
        for flags in team_overrides(spec, registry, 2, "heterogeneous", 1, scratch=tmp_path)
    )
    assert low.model.robot.altitude == 2.5 and high.model.robot.altitude == 5.0
