"""An experiment's flights: serial or on a local Ray, resumable, one failure kept to its own row."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from amslam.apps import flights as flights_module
from amslam.apps.flights import Flight, FlightRunner, code_note, experiment_folder, fly_all
from amslam.errors import AmslamError
from tests.e2e.missions import small_mission


def _flights(mission: Path, seeds) -> list[Flight]:
    return [Flight(str(mission), (f"seed={s}",)) for s in seeds]


def test_a_resumed_experiment_flies_only_what_it_had_not_flown(tmp_path: Path, monkeypatch) -> None:
    mission = small_mission(tmp_path, max_time=4)
    folder = experiment_folder(tmp_path / "out", "test", str(mission))
    monkeypatch.setattr(flights_module, "source_revision", lambda: "0123abcd")
    first = fly_all(_flights(mission, [1, 2]), folder, log=lambda line: None)
    assert [r["metrics"]["verdict"] for r in first] == ["completed", "completed"]
    assert {r["code"] for r in first} == {"0123abcd"}
    assert len(list((folder / "flights").glob("*.json"))) == 2

    flown = []
    real = flights_module.fly_one
    monkeypatch.setattr(
        flights_module, "fly_one", lambda m, o, runs, reg=None: flown.append(list(o)) or real(m, o, runs, reg)
    )
    monkeypatch.setattr(flights_module, "source_revision", lambda: "4567ef01")  # the code changed since
    again = experiment_folder(tmp_path / "out", "test", str(mission), resume=str(folder))
    lines: list[str] = []
    records = fly_all(_flights(mission, [2, 3, 1]), again, log=lines.append)
    assert flown == [["seed=3"]]  # seeds 1 and 2 are found in the folder
    assert [r["overrides"] for r in records] == [["seed=2"], ["seed=3"], ["seed=1"]]
    assert records[0] == first[1] and records[2] == first[0]  # kept as flown, their code with them
    assert records[1]["code"] == "4567ef01"
    assert lines[0].startswith("  2 flight(s) already flown")
    assert (
        lines[1]
        == "  2 of them flown with other code (0123abcd), this is 4567ef01: their figures stand as flown"
    )
    assert "[1/1] seed=3" in lines[2]
    # the table under the records says so: most flights' code first
    assert code_note(records) == "\nFlown with code: 0123abcd (2 flights), 4567ef01 (1 flight).\n"
    assert code_note([{"metrics": {}}]) == "\nFlown with code: unrecorded (1 flight).\n"


def test_a_flight_that_raises_is_its_own_failed_row(tmp_path: Path) -> None:
    mission = small_mission(tmp_path, max_time=3)
    folder = experiment_folder(tmp_path / "out", "test", str(mission))
    bad = Flight(str(mission), ("seed=1", "robot.altitude=high"))
    records = fly_all([bad, *_flights(mission, [1])], folder, log=lambda line: None)
    assert records[0]["metrics"]["verdict"] == "failed"
    assert "robot.altitude" in records[0]["metrics"]["error"] and records[0]["run_dir"] is None
    assert records[1]["metrics"]["verdict"] == "completed"


def test_the_key_is_the_mission_and_its_overrides_in_any_order(tmp_path: Path, monkeypatch) -> None:
    mission = small_mission(tmp_path)
    monkeypatch.chdir(tmp_path)
    a = Flight(str(mission), ("seed=1", "planner.plugin=tsp"))
    b = Flight(mission.name, ("planner.plugin=tsp", "seed=1"))  # the same file, by a relative path
    assert a.key == b.key
    assert a.key != Flight(str(mission), ("seed=2", "planner.plugin=tsp")).key


def test_resume_needs_an_experiment_folder_and_address_needs_ray(tmp_path: Path) -> None:
    with pytest.raises(AmslamError, match="not an experiment folder"):
        experiment_folder(tmp_path, "test", "demo", resume=str(tmp_path))
    import argparse

    with pytest.raises(AmslamError, match="needs the Ray executor"):
        FlightRunner.from_args(argparse.Namespace(executor="serial", ray=False, address="auto"))
    with pytest.raises(AmslamError, match="disagree"):
        FlightRunner.from_args(argparse.Namespace(executor="serial", ray=True, address=None))


@pytest.mark.parametrize("installed", [True, False])
def test_experiments_fly_on_ray_by_default_when_it_is_installed(monkeypatch, installed: bool) -> None:
    import argparse

    from amslam.apps import flights
    from amslam.cli import build_parser
    from amslam.registry import build_plugin_manager

    monkeypatch.setattr(flights, "ray_installed", lambda: installed)
    parser = build_parser(build_plugin_manager())
    args = parser.parse_args(["experiment", "slc-ablation", "demo"])
    assert FlightRunner.from_args(args) == FlightRunner(ray=installed)
    args = parser.parse_args(["experiment", "slc-ablation", "demo", "--executor", "serial"])
    assert FlightRunner.from_args(args) == FlightRunner(ray=False)
    args = parser.parse_args(["experiment", "slc-ablation", "demo", "--executor", "ray"])
    if installed:
        assert FlightRunner.from_args(args) == FlightRunner(ray=True)
        assert FlightRunner.from_args(argparse.Namespace(ray=True, address="auto")) == FlightRunner(
            True, "auto"
        )
    else:
        with pytest.raises(AmslamError, match=r"pip install 'amslam\[ray\]'.*--executor serial"):
            FlightRunner.from_args(args)
    # a benchmark script's parser has only --ray: serial unless asked
    assert FlightRunner.from_args(argparse.Namespace(ray=False, address=None)) == FlightRunner(ray=False)


def test_flights_run_as_tasks_on_a_local_two_cpu_ray(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray")
    mission = small_mission(tmp_path, max_time=4)
    folder = experiment_folder(tmp_path / "out", "test", str(mission))
    serial = fly_all(_flights(mission, [5]), experiment_folder(tmp_path / "s", "t", str(mission)), log=print)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        lines: list[str] = []
        records = fly_all(_flights(mission, [5, 6]), folder, FlightRunner(ray=True), log=lines.append)
    finally:
        ray.shutdown()
    assert [r["metrics"]["verdict"] for r in records] == ["completed", "completed"]
    assert sorted(line.split("]")[0].strip() for line in lines) == ["[1/2", "[2/2"]
    # a worker flies exactly what this process flies (the simulator is deterministic per seed)
    for key in ("explored_percent", "distance_m"):
        assert records[0]["metrics"][key] == serial[0]["metrics"][key]
    for r in records:
        assert Path(r["run_dir"]).parent == folder / "runs"
        assert json.loads((Path(r["run_dir"]) / "metrics.json").read_text())["verdict"] == "completed"


def test_the_code_a_flight_is_flown_with(monkeypatch) -> None:
    import re
    import subprocess

    from amslam import __version__

    here = flights_module.source_revision()
    assert re.fullmatch(r"[0-9a-f]{12}(\+changes)?", here) or here == f"amslam {__version__}"

    def no_git(*args, **kwargs):
        raise FileNotFoundError("git")

    monkeypatch.setattr(subprocess, "run", no_git)  # an installed wheel, or no git on the machine
    assert flights_module.source_revision() == f"amslam {__version__}"
