"""Experiment tables and plots from run metrics (the runs themselves are tested in tests/e2e)."""

from __future__ import annotations

from amslam.apps.experiments import planner_table, plot_exploration, plot_fig7, slc_tables


def metrics(vio: float, slam: float, pose: float, landmark: float, accepted: int = 1) -> dict:
    return {
        "distance_m": 100.0,
        "final_error": {
            "vio_position_m": vio,
            "slam_position_m": slam,
            "vio_yaw_rad": 0.1,
            "slam_yaw_rad": 0.05,
        },
        "uncertainty": {
            "final_mean_pose_trace": pose,
            "final_mean_landmark_trace": landmark,
            "series": [[0, 0, 0.0, 0.0], [10, 20, pose, landmark]],
        },
        "slc": {"accepted": accepted, "events": [{"distance": 15.0, "accepted": True}]},
    }


def test_slc_tables_compute_reductions(tmp_path):
    rows = [
        {
            "seed": 1,
            "on": {"metrics": metrics(1.0, 0.2, 0.5, 0.4)},
            "off": {"metrics": metrics(1.0, 1.0, 1.0, 0.8)},
        },
        {
            "seed": 2,
            "on": {"metrics": metrics(2.0, 1.0, 0.3, 0.2)},
            "off": {"metrics": metrics(2.0, 2.0, 0.6, 0.4)},
        },
    ]
    table = slc_tables(rows)
    assert "| 1 | 100.0 | 1 | 1.000 | 0.200 | 80.0 % |" in table
    assert "**65.0 %**" in table  # mean of 80 % and 50 % position-error reduction
    assert "| 1 | 0.5000 | 1.0000 | 50.0 % | 0.4000 | 0.8000 | 50.0 % |" in table
    plot_fig7(rows, tmp_path / "fig7.png")
    assert (tmp_path / "fig7.png").stat().st_size > 10_000


def test_planner_table_and_plot(tmp_path):
    rows = [
        {
            "seed": 1,
            "planner": name,
            "world": "demo",
            "metrics": {
                "verdict": "completed",
                "explored_percent": pct,
                "explored_volume_m3": vol,
                "distance_m": dist,
                "sim_duration_s": 300.0,
                # cop maps 450 m³ (90 % of the best run's 500 m³) by 40 m, greedy only by 100 m
                "explored_series": [[0, 0, 0], [50, 40, 0.9 * vol * d90], [100, 100, vol], [300, dist, vol]],
            },
        }
        for name, pct, vol, dist, d90 in (
            ("cop", 95.0, 500.0, 120.0, 1.0),
            ("greedy", 90.0, 480.0, 125.0, 0.5),
        )
    ]
    table = planner_table(rows)
    assert "| cop | demo | 1 | completed | 95.0 | 120.0 | 300.0 | 4.17 | 40.0 | 50.0 |" in table
    assert "| greedy | demo | 1 | completed | 90.0 | 125.0 | 300.0 | 3.84 | 100.0 | 100.0 |" in table
    assert "| greedy | 1 | 90.0 | 125.0 | 300.0 | 100.0 | 100.0 |" in table
    plot_exploration(rows, tmp_path / "p.png")
    assert (tmp_path / "p.png").exists()
