"""Experiment tables and plots from run metrics (the runs themselves are tested in tests/e2e)."""

from __future__ import annotations

import numpy as np

from amslam.apps.experiments import planner_table, plot_exploration, plot_fig7, slc_tables


def metrics(vio: float, slam: float, pose: float, landmark: float, accepted: int = 1) -> dict:
    return {
        "verdict": "completed",
        "distance_m": 100.0,
        "final_error": {
            "vio_position_m": vio,
            "slam_position_m": slam,
            "vio_yaw_rad": 0.1,
            "slam_yaw_rad": 0.05,
            "vio_offset_m": [0.6 * vio, -0.8 * vio, 0.0],
            "slam_offset_m": [0.0, 0.0, slam],
            "vio_yaw_deg": -4.0,
            "slam_yaw_deg": 1.0,
        },
        "uncertainty": {
            "final_mean_pose_trace": pose,
            "final_mean_landmark_trace": landmark,
            "series": [[0, 0, 0.0, 0.0], [10, 20, pose, landmark]],
            "pose_reduction_upon_slc_percent": [40.0, 20.0],
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
    # per axis (estimate - truth), VIO drift as a share of the trajectory, signed yaw in degrees
    assert (
        "| 1 | 100.0 | 1 | 1.00 (+0.60, -0.80, +0.00) | 0.20 (+0.00, +0.00, +0.20) | 80.0 % | 1.00 % |"
        in table
    )
    assert "| -4.00 | 1.00 | 75.0 % |" in table  # |yaw| 4° -> 1°
    assert "**65.0 %**" in table  # mean of 80 % and 50 % position-error reduction
    assert "| 1 | 40.0 %; 20.0 % | 0.5000 | 1.0000 | 50.0 % | 0.4000 | 0.8000 | 50.0 % | 100.0 |" in table
    assert "| **mean** | | 30.0 % |" in table  # the drops upon SLC of all flights
    # summary: SLAM on vs VIO 80 % / 50 %, on vs off 80 % / 50 %, pose trace 50 % / 50 %
    assert (
        "| 2 | 2 / 2 | 2 of 2 | 2 / — | 65.0 ± 15.0 % | 65.0 ± 15.0 % | 75.0 ± 0.0 % | 0.0 ± 0.0 % | "
        in table
    )
    plot_fig7(rows, tmp_path / "fig7.png")
    assert (tmp_path / "fig7.png").stat().st_size > 10_000


def test_slc_tables_summarise_each_world_and_all_of_them():
    def row(world, seed, slam_on, slam_off, verdict="completed"):
        on, off = metrics(1.0, slam_on, 0.5, 0.4), metrics(1.0, slam_off, 1.0, 0.8)
        on["slc"]["attempts"] = 2
        off["verdict"], on["verdict"] = verdict, "completed"
        return {"world": world, "seed": seed, "on": {"metrics": on}, "off": {"metrics": off}}

    rows = [row("a", 1, 0.2, 0.4), row("a", 2, 0.4, 0.8), row("b", 1, 0.5, 1.0, verdict="crashed")]
    table = slc_tables(rows)
    assert "| a | 1 | 100.0 | 1 |" in table and "| b | 1 | 100.0 | 1 |" in table
    # world a: vs VIO 80 % and 60 %; vs SLC off 50 % both; 2 accepted of 4 attempts
    assert "| a | 2 | 2 / 2 | 2 of 2 | 2 / 4 | 70.0 ± 10.0 % | 50.0 ± 0.0 % |" in table
    assert "| b | 1 | 1 / 0 | 1 of 1 | 1 / 2 | 50.0 ± 0.0 % | 50.0 ± 0.0 % |" in table
    # over all three: vs VIO 80, 60, 50 %
    assert "| **all** | 3 | 3 / 2 | 3 of 3 | 3 / 6 | 63.3 ± 12.5 % | 50.0 ± 0.0 % |" in table


def test_slc_tables_also_reduce_the_summed_errors():
    # Seed 2's VIO barely drifted: its own percentage (-400 %) swamps the mean of the two flights,
    # while the summed errors weigh it by what it drifted: 1 - (0.2 + 0.05) / (1.0 + 0.01).
    rows = [
        {
            "world": "w",
            "seed": 1,
            "on": {"metrics": metrics(1.0, 0.2, 0.5, 0.4)},
            "off": {"metrics": metrics(1.0, 0.4, 1.0, 0.8)},
        },
        {
            "world": "w",
            "seed": 2,
            "on": {"metrics": metrics(0.01, 0.05, 0.3, 0.2)},
            "off": {"metrics": metrics(0.01, 0.1, 0.5, 0.2)},
        },
    ]
    table = slc_tables(rows)
    assert "| w | 2 | 2 / 2 | 1 of 2 | 2 / — | -160.0 ± 240.0 % |" in table
    # position vs VIO 75.2 %, vs SLC off 1 - 0.25 / 0.5; yaw 4° -> 1° on both (vs VIO 75 %, vs off 0 %);
    # pose traces 1 - 0.8 / 1.5, landmark traces 1 - 0.6 / 1.0
    assert "| w | 2 | 75.2 % | 50.0 % | 75.0 % | 0.0 % | 46.7 % | 40.0 % |" in table


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
    assert "| demo | cop | 1 of 1 | 95.0 ± 0.0 | 120.0 ± 0.0 | 50.0 ± 0.0 | 40.0 ± 0.0 |" in table
    plot_exploration(rows, tmp_path / "p.png")
    assert (tmp_path / "p.png").exists()
    # two worlds: a row of panels each, as tall again as one
    import matplotlib.image

    plot_exploration([*rows, {**rows[0], "world": "house"}], tmp_path / "two.png")
    one, two = (matplotlib.image.imread(tmp_path / f) for f in ("p.png", "two.png"))
    assert two.shape[0] > 1.8 * one.shape[0]


def test_slc_tables_read_runs_from_before_the_per_axis_errors():
    old = metrics(1.0, 0.5, 0.5, 0.4)
    for key in ("vio_offset_m", "slam_offset_m", "vio_yaw_deg", "slam_yaw_deg"):
        del old["final_error"][key]
    del old["uncertainty"]["pose_reduction_upon_slc_percent"]
    table = slc_tables([{"seed": 3, "on": {"metrics": old}, "off": {"metrics": old}}])
    assert "| 3 | 100.0 | 1 | 1.00 — | 0.50 — | 50.0 % | 1.00 % | 5.73 | 2.86 | 50.0 % |" in table
    assert "| 3 | — |" in table
    assert "| 1 | 1 / 1 | 1 of 1 | 1 / — |" in table  # no attempts recorded


def test_the_pose_trace_drop_across_each_accepted_slc():
    from amslam.apps.report import reduction_upon_slc

    series = [(0.0, 0.0, 0.1, 0.0), (5.0, 3.0, 0.2, 0.0), (10.0, 6.0, 0.05, 0.0), (15.0, 9.0, 0.06, 0.0)]
    assert reduction_upon_slc(series, [7.5]) == [75.0]  # 0.2 before, 0.05 after
    assert reduction_upon_slc(series, [10.0, 20.0, -1.0]) == [75.0]  # no sample after 20 s or before -1 s


def test_trajectory_plot_per_world_from_the_run_folders(tmp_path):
    from amslam.apps.experiments import plot_trajectories

    def run(name: str, drift: float) -> str:
        folder = tmp_path / name
        folder.mkdir()
        t = np.linspace(0, 10, 20)
        for which, d in (("ground_truth", 0.0), ("vio", drift), ("slam", drift / 5)):
            lines = [f"{ti} {ti} {np.sin(ti) + d * ti} 1.2 0 0 0 1" for ti in t]
            (folder / f"{which}.tum").write_text("\n".join(lines) + "\n")
        return str(folder)

    failed = {"run_dir": None, "metrics": {"verdict": "failed"}}
    rows = [
        {"world": "a", "seed": 1, "on": failed, "off": {"run_dir": run("a1off", 0.1)}},  # skipped
        {"world": "a", "seed": 2, "on": {"run_dir": run("a2on", 0.1)}, "off": {"run_dir": run("a2off", 0.1)}},
        {"world": "b", "seed": 1, "on": {"run_dir": run("b1on", 0.2)}, "off": {"run_dir": run("b1off", 0.2)}},
    ]
    plot_trajectories(rows, tmp_path / "t.png")
    import matplotlib.image

    image = matplotlib.image.imread(tmp_path / "t.png")
    assert image.shape[0] > image.shape[1] * 0.3  # two worlds: two rows of four panels (one: ~0.19)
    plot_trajectories(rows[:1], tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()
