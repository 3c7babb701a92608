"""benchmarks/objects.py (issue #23): its figures per flight and its tables, from metrics alone."""

from __future__ import annotations

from tests.apps.benchmark_script import load_benchmark


def _benchmark():
    return load_benchmark("objects")


def _metrics(matched, objects, duplicates, spurious, err, vio, slam):
    chair = {"objects": objects, "landmarks": matched + duplicates + spurious, "matched": matched}
    chair |= {"duplicates": duplicates, "spurious": spurious, "mean_error_m": err}
    accuracy = {**chair, "median_error_m": err, "off_by_more_than_0_5_m": 0, "by_class": {"chair": chair}}
    accuracy |= {"common_offset_m": [0.3 * err / 0.1, 0.4 * err / 0.1, 0.0], "error_about_offset_m": err / 2}
    return {
        "verdict": "completed",
        "landmarks": {"accuracy": accuracy},
        "final_error": {"vio_position_m": vio, "slam_position_m": slam},
        "slc": {"attempts": 3, "accepted": 2, "events": []},
    }


def test_figures_and_tables_of_two_seeds():
    b = _benchmark()
    one = b.flight_figures(_metrics(8, 10, 1, 1, 0.2, 0.5, 0.1))
    assert one["mapped_pct"] == 80.0 and one["duplicates_pct"] == 10.0 and one["spurious_pct"] == 10.0
    assert one["slam_below_vio"] is True
    two = b.flight_figures(_metrics(10, 10, 0, 0, 0.1, 0.3, 0.4))
    rows = [
        {"building": "demo", "detector": "sim", "seed": 1, "figures": one},
        {"building": "demo", "detector": "sim", "seed": 2, "figures": two},
        {"building": "demo", "detector": "sim", "seed": 3, "figures": None},  # a failed flight
    ]
    text = b.tables(rows)
    assert "| demo | sim | 2 of 3 | 90.00 ± 10.00 | 5.00 ± 5.00 | 5.00 ± 5.00 | 0.15 ± 0.05 |" in text
    # the shifts 1.0 and 0.5 m (offsets (0.6, 0.8) and (0.3, 0.4)), errors about them 0.1 and 0.05 m
    assert "| 0.00 ± 0.00 | 0.75 ± 0.25 | 0.08 ± 0.03 | 1 of 2 |" in text
    # SLAM ended below VIO on one flight of two; loop closures accepted, summed over the flights
    assert text.split("\n")[2].endswith("| 1 of 2 | 4 of 6 |")
    no_slc = b.flight_figures({k: v for k, v in _metrics(8, 10, 1, 1, 0.2, 0.5, 0.1).items() if k != "slc"})
    assert b.tables([{**rows[0], "figures": no_slc}]).split("\n")[2].endswith("| 1 of 1 | — |")
    # per class, pooled: 20 objects, 18 mapped, mean error weighted by the mapped objects
    assert "| demo | sim | chair | 20 | 18 | 1 | 1 | 0.144 |" in text
    assert b.flight_figures({"verdict": "failed"}) is None
    # a flight that ended early is scored, and the table says so
    early = b.flight_figures({**_metrics(3, 10, 0, 0, 0.2, 0.5, 0.1), "verdict": "failed: planner"})
    assert early["completed"] is False
    assert "| demo | sim | 1 of 1 (1 not completed) |" in b.tables([{**rows[0], "figures": early}])


def test_a_mesh_world_is_scored_in_amslams_classes():
    b = _benchmark()
    metrics = _metrics(1, 10, 0, 9, 0.2, 0.5, 0.1)  # by the house's own class names
    metrics["landmarks"]["accuracy_amslam_classes"] = _metrics(8, 9, 0, 2, 0.3, 0.5, 0.1)["landmarks"][
        "accuracy"
    ]
    figures = b.flight_figures(metrics)
    assert figures["mapped_pct"] == 100.0 * 8 / 9 and figures["mean_error_m"] == 0.3


def test_unknown_building_is_one_error_line(capsys):
    assert _benchmark().main(["--buildings", "castle"]) == 2
    assert (
        capsys.readouterr().err.strip() == "error: unknown castle; choose from floors1, demo, floors3, house"
    )


def test_runs_scores_flights_flown_already_by_mission_and_slc(tmp_path, capsys):
    import json

    for name, slc, seed, metrics in (
        ("one_floor", True, 1, _metrics(8, 10, 1, 1, 0.2, 0.5, 0.1)),
        ("one_floor", False, 1, _metrics(6, 10, 4, 0, 0.4, 0.5, 0.6)),
    ):
        run = tmp_path / "runs" / f"{name}-{slc}"
        run.mkdir(parents=True)
        (run / "metrics.json").write_text(json.dumps({**metrics, "mission": name, "seed": seed}))
        (run / "mission.yaml").write_text(f"name: {name}\nexploration: {{slc: {str(slc).lower()}}}\n")
    assert _benchmark().main(["--runs", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "| one_floor | ? | 1 of 1 | 80.00 ± 0.00 | 10.00 ± 0.00 |" in out
    assert "| one_floor (SLC off) | ? | 1 of 1 | 60.00 ± 0.00 | 40.00 ± 0.00 |" in out
    assert _benchmark().main(["--runs", str(tmp_path / "empty")]) == 2
    assert "no run folder" in capsys.readouterr().err
