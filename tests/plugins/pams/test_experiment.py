"""The Fig. 9 table of ``amslam experiment pams``: pooling per-run object errors."""

from __future__ import annotations

import numpy as np
import pytest

from amslam.apps.experiments import pams_table, pool_errors


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
