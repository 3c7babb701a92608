"""benchmarks/flight_safety.py (issue #19): its rows, summary and run-folder tables, from metrics alone."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from tests.apps.benchmark_script import load_benchmark


def _benchmark():
    return load_benchmark("flight_safety")


def _metrics(verdict, explored, clearance, radius=0.25):
    return {
        "verdict": verdict,
        "explored_percent": explored,
        "explored_percent_per_floor": [explored, explored],
        "distance_m": 100.0,
        "sim_duration_s": 400.0,
        "closest_approach": {"clearance_m": clearance, "robot_radius_m": radius, "to": "wall (floor 0)"},
        "final_error": {"vio_position_m": 1.0, "slam_position_m": 0.2},
        "landmarks": {"accuracy": {"objects": 10, "matched": 9}},
    }


def _run_folder(root: Path, name: str, metrics: dict, mission: dict, heights: list[float]) -> Path:
    run = root / name
    run.mkdir(parents=True)
    (run / "metrics.json").write_text(json.dumps(metrics))
    (run / "mission.yaml").write_text(yaml.safe_dump(mission))
    lines = [f"{i}.0 0 0 {z} 0 0 0 1" for i, z in enumerate(heights)]
    (run / "ground_truth.tum").write_text("\n".join(lines) + "\n")
    return run


def test_rows_name_the_building_and_judge_contact_at_the_radius(tmp_path):
    b = _benchmark()
    three = {"name": "demo", "seed": 4, "platform": {"world": {"floors": 3}}}
    run = _run_folder(tmp_path, "r", _metrics("completed", 99.0, 0.25), three, [0.2, 3.4, 1.2])
    row = b.flight_row(json.loads((run / "metrics.json").read_text()), three, str(run))
    assert row["building"] == "demo, 3 floors" and row["seed"] == 4
    assert row["contact"] is True  # a clearance equal to the radius is a touch
    assert row["top_z_m"] == 3.4
    mesh = {"name": "cafe", "seed": 1, "platform": {"world": {"kind": "mesh"}}}
    assert b.flight_row(_metrics("completed", 95.0, 0.26), mesh, None)["building"] == "cafe"
    assert b.flight_row(_metrics("completed", 95.0, 0.26), mesh, None)["contact"] is False


def test_summary_counts_contacts_and_gives_the_closest_approach_distribution():
    b = _benchmark()
    mission = {"name": "demo", "seed": 1}
    rows = [b.flight_row(_metrics("completed", e, c), mission, None) for e, c in ((99.5, 0.4), (80.0, 0.3))]
    rows.append(b.flight_row(_metrics("crashed", 20.0, 0.2), mission, None))
    text = b.summary(rows)
    assert "flights 3; completed 2; contacts 1" in text
    # a crash is a contact even where the closest approach the metrics kept is larger
    crash = b.flight_row(_metrics("crashed: collision at (0, 0, 1)", 90.0, 0.4), mission, None)
    assert crash["contact"] is True
    assert "explored min 20.00" in text and "1 of 3 ≥ 90 %" in text
    assert "closest approach min 0.200" in text and "median 0.300 m" in text
    # a flight that raised has no figures: it is a row, and counted as not completed
    failed = b.flight_row({"verdict": "failed", "error": "boom"}, mission, None)
    assert b.summary([failed]) == "flights 1; completed 0; contacts 0"
    assert "| demo | 1 | failed | — |" in b.tables([failed])


def test_tabulate_reads_every_run_folder_and_says_when_there_is_none(tmp_path, capsys):
    b = _benchmark()
    for seed in (1, 2):
        mission = {"name": "demo", "seed": seed}
        _run_folder(tmp_path / "sweep", f"demo_s{seed}", _metrics("completed", 99.0, 0.4), mission, [1.2])
    assert b.main(["--tabulate", str(tmp_path / "sweep")]) == 0
    out = capsys.readouterr().out
    assert out.count("| demo | ") == 2 and "**All: flights 2; completed 2; contacts 0" in out
    # a sweep's final flights gathered as links to their run folders
    (tmp_path / "final").mkdir()
    (tmp_path / "final" / "s1").symlink_to(tmp_path / "sweep" / "demo_s1")
    assert b.main(["--tabulate", str(tmp_path / "final")]) == 0
    assert capsys.readouterr().out.count("| demo | ") == 1
    (tmp_path / "empty").mkdir()
    assert b.main(["--tabulate", str(tmp_path / "empty")]) == 2
    assert "no run folder" in capsys.readouterr().err


def test_bad_arguments_are_one_error_line(tmp_path, capsys):
    b = _benchmark()
    assert b.main(["--buildings", "castle"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: unknown building castle; choose from demo, floors1, floors3, house"
    )
    assert b.main(["--world", str(tmp_path / "nowhere.yaml")]) == 2
    assert "no such mission file" in capsys.readouterr().err


def test_a_flight_option_error_is_one_line_and_flies_nothing(tmp_path, capsys):
    b = _benchmark()
    assert b.main(["--buildings", "house", "--seeds", "1", "--address", "auto", "--out", str(tmp_path)]) == 2
    assert (
        capsys.readouterr().err.strip()
        == "error: --address names a Ray cluster: it needs the Ray executor (--executor ray, or --ray)"
    )
    assert not list(tmp_path.rglob("metrics.json"))
