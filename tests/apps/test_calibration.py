"""``amslam experiment calibrate``: a value chosen on training seeds, judged on held-out seeds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from amslam.apps import flights as flights_module
from amslam.apps.calibration import Requirement, calibrate, calibration_table, choose, metric_of, score_values
from amslam.errors import AmslamError, MissionError
from amslam.registry import build_plugin_manager
from tests.e2e.missions import small_mission


def _row(value, seed, error, verdict="completed", explored=99.0, world="w"):
    metrics = {"verdict": verdict, "explored_percent": explored, "trajectory_error": {"slam_rms_m": error}}
    return {"world": world, "seed": seed, "value": value, "metrics": metrics, "run_dir": None}


def test_the_best_value_that_always_completed_is_chosen_and_compared_with_the_one_flown_before():
    values = [3.0, 10.0, 30.0]
    rows = [
        _row(3.0, 1, 0.05),
        _row(3.0, 2, 0.06, verdict="crashed: collision with a wall"),  # best mean, but it crashed once
        _row(10.0, 1, 0.30),
        _row(10.0, 2, 0.20),
        _row(30.0, 1, 0.10),
        _row(30.0, 2, 0.20),
    ]
    scores = score_values(rows, values, "trajectory_error.slam_rms_m")
    assert [s["eligible"] for s in scores] == [False, True, True]
    assert "1 of 2 flights did not complete (w seed 2: crashed" in scores[0]["why_not"]
    assert scores[2]["mean"] == pytest.approx(0.15) and scores[2]["std"] == pytest.approx(0.05)
    assert choose(values, scores, baseline=10.0) == (30.0, 10.0)
    # the value flown before wins: the held-out seeds compare it with the runner-up
    assert choose(values, scores, baseline=30.0) == (30.0, 10.0)
    assert choose(values, scores, baseline=10.0, maximise=True) == (10.0, 30.0)
    # a requirement every training flight must meet
    rows[4]["metrics"]["explored_percent"] = 80.0
    scores = score_values(
        rows, values, "trajectory_error.slam_rms_m", [Requirement.parse("explored_percent>=95")]
    )
    assert [s["eligible"] for s in scores] == [False, True, False]
    assert scores[2]["why_not"] == "1 flight(s) miss explored_percent >= 95"
    assert choose(values, scores, baseline=10.0) == (10.0, None)
    assert choose(values, [dict(s, eligible=False) for s in scores], baseline=10.0) == (None, None)


def test_the_table_gives_the_choice_and_whether_the_held_out_seeds_confirm_it():
    result = {
        "param": "planner.slc_scale",
        "values": [10.0, 30.0],
        "flown_before": 10.0,
        "metric": "trajectory_error.slam_rms_m",
        "maximise": False,
        "requirements": ["explored_percent >= 95"],
        "scores": {"10.0": {"eligible": True}, "30.0": {"eligible": True}},
        "chosen": 30.0,
        "compared_with": 10.0,
        "training": [_row(10.0, 1, 0.3), _row(30.0, 1, 0.1)],
        "held_out": [_row(30.0, 2, 0.1), _row(10.0, 2, 0.2), _row(30.0, 3, 0.3), _row(10.0, 3, 0.2)],
    }
    table = calibration_table(result)
    assert "**Chosen: `planner.slc_scale: 30.0`**" in table
    assert "and met `explored_percent >= 95`" in table
    assert "| 30.0 | w | 1 of 1 | 0.100 ± 0.000 |" in table  # training
    assert "| 30.0 | w | 2 of 2 | 0.200 ± 0.100 |" in table  # held out
    assert "`30.0` minus `10.0`: -0.000 ± 0.100; lower on 1 of 2 held-out flights" in table
    assert "do not confirm" in table  # a tie is no confirmation
    result["held_out"][2]["metrics"]["trajectory_error"]["slam_rms_m"] = 0.25
    assert "**Better on average, within the seeds' noise** (paired standard error 0.075)" in (
        calibration_table(result)
    )
    result["held_out"][2]["metrics"]["trajectory_error"]["slam_rms_m"] = 0.12
    assert "**The held-out seeds confirm the choice.**" in calibration_table(result)
    assert "on the held-out seeds" not in calibration_table(result)
    # a metric that is one of the context columns is shown once
    assert calibration_table(dict(result, metric="sim_duration_s")).count("time (s)") == 0
    assert "| time (s) |" in table
    # a held-out flight of the chosen value that misses the requirement is said
    result["held_out"][2]["metrics"]["explored_percent"] = 77.0
    assert "- `30.0` on the held-out seeds: 1 flight(s) miss explored_percent >= 95" in calibration_table(
        result
    )


def test_metric_paths_and_requirements_read_numbers_only():
    metrics = {"a": {"b": 2.5, "flag": True, "nan": float("nan")}, "verdict": "completed"}
    assert metric_of(metrics, "a.b") == 2.5
    assert metric_of(metrics, "a.flag") is None and metric_of(metrics, "a.nan") is None
    assert metric_of(metrics, "a.c") is None and metric_of(metrics, "verdict") is None
    assert Requirement.parse("a.b<3").met(metrics) and not Requirement.parse("a.b > 3").met(metrics)
    with pytest.raises(AmslamError, match="expected METRIC>=NUMBER"):
        Requirement.parse("explored == 3")


def test_a_calibration_flies_training_then_held_out_seeds_and_writes_its_folder(tmp_path: Path, monkeypatch):
    mission = small_mission(tmp_path, max_time=3)
    registry = build_plugin_manager()
    flown: list[list[str]] = []

    def fake_flight(m, overrides, runs, reg=None):  # the flight's error depends on min_gain alone
        flown.append(sorted(overrides))
        gain = float(next(o for o in overrides if o.startswith("planner.min_gain=")).split("=")[1])
        seed = int(next(o for o in overrides if o.startswith("seed=")).split("=")[1])
        metrics = {"verdict": "completed", "trajectory_error": {"slam_rms_m": abs(gain - 1.0) + 0.01 * seed}}
        return {"overrides": list(overrides), "run_dir": None, "metrics": metrics, "wall_s": 0.0}

    monkeypatch.setattr(flights_module, "fly_one", fake_flight)

    def run(resume=None):
        values, training, held_out = ["0.0", "1.0", "2.5"], [1, 2], [3, 4]
        return calibrate(
            [str(mission)], registry, "planner.min_gain", values, training, held_out, tmp_path / "out",
            log=lambda line: None, resume=resume,
        )  # fmt: skip

    folder = run()
    result = json.loads((folder / "results.json").read_text())
    assert result["flown_before"] == 0.0 and result["chosen"] == 1.0 and result["compared_with"] == 0.0
    assert len(result["training"]) == 6 and {r["seed"] for r in result["held_out"]} == {3, 4}
    assert flown[6:] == [
        ["planner.min_gain=1.0", "seed=3"],
        ["planner.min_gain=0.0", "seed=3"],
        ["planner.min_gain=1.0", "seed=4"],
        ["planner.min_gain=0.0", "seed=4"],
    ]
    assert "confirm the choice" in (folder / "table.md").read_text()
    # a resumed calibration flies nothing again
    flown.clear()
    run(resume=str(folder))
    assert flown == []


def test_bad_values_are_refused_before_anything_flies(tmp_path: Path, monkeypatch):
    mission = small_mission(tmp_path, max_time=3)
    registry = build_plugin_manager()
    monkeypatch.setattr(flights_module, "fly_one", lambda *a, **k: pytest.fail("flew"))

    def run(param, values, train=(1,), held=(2,)):
        calibrate([str(mission)], registry, param, values, list(train), list(held), tmp_path / "o", log=print)

    with pytest.raises(MissionError, match=r"--values -1: .*planner.min_gain"):
        run("planner.min_gain", ["1", "-1"])
    with pytest.raises(MissionError, match="has no such parameter"):
        run("planner.no_such_thing", ["1", "2"])
    with pytest.raises(MissionError, match="a value is given twice"):
        run("planner.min_gain", ["1", "1.0"])
    with pytest.raises(AmslamError, match="held-out seeds must differ"):
        run("planner.min_gain", ["1", "2"], held=(1,))
    assert not (tmp_path / "o").exists()
