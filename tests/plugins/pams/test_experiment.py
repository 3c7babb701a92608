"""The Fig. 9 table of ``amslam experiment pams``: pooling per-run object errors."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.apps.experiments import pams_flights_table, pams_table, pool_errors


def test_pooled_errors_equal_the_errors_of_all_objects_together():
    a, b = np.array([0.1, 0.3, 0.2]), np.array([0.5, 0.7])
    blocks = [
        {"objects": 4, "mapped": 3, "dims_error_mean_m": a.mean(), "dims_error_std_m": a.std()},
        {"objects": 2, "mapped": 2, "dims_error_mean_m": b.mean(), "dims_error_std_m": b.std()},
        {"objects": 1, "mapped": 0},
    ]
    both = np.concatenate([a, b])
    p = pool_errors(blocks)
    assert p["mapped"] == 5 and p["objects"] == 7
    assert p["mean"] == pytest.approx(both.mean()) and p["std"] == pytest.approx(both.std())


def test_table_has_a_column_per_world_and_all_data():
    def run(world, planner, mean, mapped):
        car = {"objects": 2, "mapped": mapped, "dims_error_mean_m": mean, "dims_error_std_m": 0.1}
        return {
            "world": world,
            "planner": planner,
            "metrics": {"objects": {"car": car, "overall": car}, "distance_m": 10.0},
        }

    rows = [
        run("w1", "pams", 0.2, 2),
        run("w1", "prior_visit", 0.6, 1),
        run("w2", "pams", 0.4, 2),
        run("w2", "prior_visit", 0.5, 2),
    ]
    text = pams_table(rows)
    assert "| measure | w1 | w2 | all data |" in text
    assert "| Err. mean | 0.20 m / 0.60 m | 0.40 m / 0.50 m | 0.30 m / 0.53 m |" in text
    assert "| Obj. mapped — car | 100 % / 50 % | 100 % / 100 % | 100 % / 75 % |" in text
    assert "| Obj. discovered — car | — / — | — / — | — / — |" in text  # runs from before it


def test_table_counts_objects_discovered_with_the_maps_drift_taken_out():
    def run(planner, mapped, discovered):
        car = {
            "objects": 4,
            "mapped": mapped,
            "discovered": discovered,
            "dims_error_mean_m": 0.2,
            "dims_error_std_m": 0.1,
        }
        overall = {**car, "fig9_objects": 4, "fig9_mapped": mapped, "fig9_discovered": discovered}
        overall.update(fig9_error_mean_m=0.2, fig9_error_std_m=0.1)
        return {"world": "w", "planner": planner, "metrics": {"objects": {"car": car, "overall": overall}}}

    text = pams_table([run("pams", 2, 4), run("prior_visit", 3, 3)])
    assert "| Obj. mapped | 50 % / 75 % | 50 % / 75 % |" in text
    assert "| Obj. discovered | 100 % / 75 % | 100 % / 75 % |" in text
    assert "| Obj. discovered — car | 100 % / 75 % | 100 % / 75 % |" in text


def test_table_scores_vehicles_by_the_fig9_error_and_cylinders_by_their_diameter():
    def run(planner, car_lw, car_lwh, pole_d):
        car = {
            "model": "cuboid",
            "objects": 2,
            "mapped": 2,
            "fig9_error_mean_m": car_lw,
            "fig9_error_std_m": 0.0,
            "dims_error_mean_m": car_lwh,
            "dims_error_std_m": 0.0,
        }
        pole = {
            "model": "cylinder",
            "objects": 1,
            "mapped": 1,
            "dims_error_mean_m": pole_d,
            "dims_error_std_m": 0,
        }
        overall = {
            "objects": 3,
            "mapped": 3,
            "fig9_objects": 2,
            "fig9_mapped": 2,
            "fig9_error_mean_m": car_lw,
            "fig9_error_std_m": 0.0,
            "dims_error_mean_m": 9.0,
            "dims_error_std_m": 0.0,
        }
        objects = {"car": car, "pole": pole, "overall": overall}
        return {"world": "w", "planner": planner, "metrics": {"objects": objects, "distance_m": 1.0}}

    text = pams_table([run("pams", 0.1, 0.5, 0.02), run("prior_visit", 0.3, 0.7, 0.04)])
    assert "| Err. mean | 0.10 m / 0.30 m | 0.10 m / 0.30 m |" in text  # vehicles' l, w only
    assert "| Obj. mapped | 100 % / 100 % |" in text  # of the vehicles
    assert "| Err. mean — car | 0.10 m / 0.30 m |" in text
    assert "| Err. mean — pole | 0.02 m / 0.04 m |" in text


def test_the_flights_table_shows_each_flight_and_where_slam_drifted_above_vio():
    def run(seed, planner, slam, vio):
        overall = {"fig9_objects": 20, "fig9_mapped": 18, "fig9_discovered": 19, "fig9_error_mean_m": 0.125}
        metrics = {
            "verdict": "completed",
            "objects": {"overall": overall},
            "distance_m": 412.34,
            "trajectory_error": {"slam_rms_m": slam, "vio_rms_m": vio},
            "final_error": {"slam_position_m": 0.2, "vio_position_m": 0.4},
        }
        return {"world": "lot", "seed": seed, "planner": planner, "metrics": metrics}

    failed = {"world": "lot", "seed": 2, "planner": "pams", "metrics": {"verdict": "failed", "error": "x"}}
    text = pams_flights_table([run(1, "pams", 0.5, 1.0), run(1, "prior_visit", 1.2, 0.9), failed])
    assert (
        "| lot | 1 | pams | completed | 0.125 | 18 (19) of 20 | 412.3 | 0.500 / 1.000 | 0.200 / 0.400 |"
        in text
    )
    assert "| prior_visit | completed | 0.125 | 18 (19) of 20 | 412.3 | 1.200 / 0.900 (above) |" in text
    assert "| lot | 2 | pams | failed | — | — | — | — / — | — / — |" in text
    below = (
        "SLAM below VIO: pams 1 of 1 by RMS, 1 of 1 at the end, prior_visit 0 of 1 by RMS, 1 of 1 at the end"
    )
    assert below in text


def test_the_planners_visit_the_map_of_an_overhead_survey_flown_first(tmp_path, monkeypatch):
    """No simulator truth in the loop: both planners get the survey's landmarks.json as prior map;
    a survey that left no map gives its planner rows as failed, without flying them."""
    import json
    from pathlib import Path

    from amslam.apps import experiments, multirobot

    monkeypatch.setattr(
        multirobot,
        "team_overrides",
        lambda spec, registry, n, mode, seed, overrides, scratch: [["tree=waypoints", f"overhead={seed}"]],
    )
    batches = []

    def fly_all(flights, folder, runner, log, registry):
        batches.append(list(flights))
        out = []
        for f in flights:
            if "tree=waypoints" in f.overrides and "overhead=2" in f.overrides:  # seed 2's survey crashes
                out.append(
                    {"overrides": list(f.overrides), "run_dir": None, "metrics": {"verdict": "failed"}}
                )
                continue
            run = Path(folder) / "runs" / f"r{len(out)}-{len(batches)}"
            run.mkdir(parents=True)
            (run / "landmarks.json").write_text("[]")
            car = {"landmarks": 5, "mapped": 3, "objects": 4, "duplicates": 1}
            metrics = {"verdict": "completed", "objects": {"car": car}}
            out.append({"overrides": list(f.overrides), "run_dir": str(run), "metrics": metrics})
        return out

    monkeypatch.setattr(experiments, "fly_all", fly_all)
    folder = experiments.pams_comparison(["lot.yaml"], None, [1, 2], tmp_path, log=lambda line: None)
    surveys, planned = batches
    expected = [("tree=waypoints", "overhead=1"), ("tree=waypoints", "overhead=2")]
    assert [f.overrides for f in surveys] == expected
    assert len(planned) == 2  # seed 1 with each planner; seed 2 has no prior map
    prior = [o for o in planned[0].overrides if o.startswith("planner.prior_objects=")]
    assert prior and prior[0].endswith("landmarks.json") and Path(prior[0].split("=", 1)[1]).is_file()
    assert {o for f in planned for o in f.overrides if o.startswith("planner.plugin=")} == {
        "planner.plugin=pams",
        "planner.plugin=prior_visit",
    }
    rows = json.loads((folder / "results.json").read_text())
    failed = [r for r in rows if r["seed"] == 2]
    assert len(failed) == 2 and all(r["metrics"]["verdict"] == "failed" for r in failed)
    assert all("no prior map" in r["metrics"]["error"] for r in failed)
    table = (folder / "table.md").read_text()
    assert "| lot | 1 | completed | car: 5 / 3 of 4 / 1 |" in table
    assert "| lot | 2 | failed | — |" in table
    assert "Flown with code: " in table and "(4 flights)" in table  # two surveys, two planner flights


def test_the_simulators_truth_is_refused_as_a_prior_map():
    from pydantic import ValidationError

    from amslam.plugins.pams.planner import PamsParams, PriorVisitParams

    for params in (PamsParams, PriorVisitParams):
        with pytest.raises(ValidationError, match="a real robot has no such thing"):
            params(prior_objects="world")
