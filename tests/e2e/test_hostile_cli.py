"""Hostile input and signals at the command line: one ``error:`` line and a documented exit status,
never a traceback; a stopped flight still lands and leaves a complete run folder."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.e2e.missions import small_mission

AMSLAM = Path(sys.executable).with_name("amslam")
BOUND = 120  # s: no hostile input may keep the command line longer than this (a hang fails the test)

BILLION_LAUGHS = "".join(
    f"{name}: &{name} [{', '.join([f'*{prev}'] * 9)}]\n"
    for prev, name in zip("abcdefg", "bcdefgh", strict=True)
)


def amslam(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    # stderr is a pipe: a run's status line would be on it every 5 s of wall time, besides the
    # single error line these tests look for; an hour apart, a busy machine writes none
    env = {**os.environ, "AMSLAM_STATUS_INTERVAL": "3600"}
    return subprocess.run(
        [AMSLAM, *args], capture_output=True, text=True, check=False, timeout=BOUND, cwd=cwd, env=env
    )


def one_error(done: subprocess.CompletedProcess) -> str:
    """The single ``error:`` line of a refused command (exit 2, no traceback)."""
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 2, (done.returncode, done.stderr)
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1, done.stderr
    return errors[0]


@pytest.fixture
def bad_files(tmp_path: Path) -> dict[str, Path]:
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfe\x00mission")
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(
        'a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]\n' + BILLION_LAUGHS
    )
    big = tmp_path / "big.yaml"
    big.write_text("name: big\n" + "# padding\n" * 200_000)
    return {"binary": binary, "bomb": bomb, "big": big, "folder": tmp_path}


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("binary", "not UTF-8 text (byte 0); a mission is a YAML file"),
        ("bomb", "expands to more than 100000 YAML nodes (aliases)"),
        ("big", "bytes; a mission file is at most 1048576 bytes"),
        ("folder", "a directory; a mission is a YAML file"),
    ],
)
def test_unreadable_mission_files(bad_files, case, expected):
    line = one_error(amslam("validate", str(bad_files[case])))
    assert str(bad_files[case]) in line and expected in line


def test_a_special_file_is_not_a_mission():
    assert "/dev/null: not a regular file" in one_error(amslam("validate", "/dev/null"))


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("seed=[1", "--set 'seed=[1': not valid YAML: expected ',' or ']'"),
        (".x=1", "--set '.x=1': '.x' is not a key path"),
        ("seed", "--set 'seed': expected key.path=value"),
        ("name.x=1", "--set 'name.x=1': 'name' is not a section"),
    ],
)
def test_bad_overrides(override, expected):
    assert expected in one_error(amslam("validate", "demo", "--set", override))


def test_set_plugins_disable_is_honoured_like_the_file(tmp_path):
    done = amslam("validate", "demo", "--set", "plugins.disable=[voxel_open3d]")
    assert "mapping.plugin: no mapping backend named 'open3d'" in one_error(done)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("experiment", "multi-robot", "demo", "--robots", "abc"), "argument --robots: 'abc': team sizes"),
        (("experiment", "planners", "demo", "--seeds", "0"), "argument --seeds: 0 is not at least 1"),
        (("experiment", "planners", "demo", "--first-seed", "-3"), "--first-seed: -3 is not at least 0"),
        (("experiment", "no-such", "demo"), "argument NAME: invalid choice: 'no-such'"),
        (("fly-to-the-moon",), "invalid choice: 'fly-to-the-moon'"),
        (("experiment", "multi-robot", "demo", "three_floors"), "multi-robot flies one mission; also given"),
    ],
)
def test_bad_arguments(args, expected):
    assert expected in one_error(amslam(*args))


def test_out_where_no_folder_can_be(tmp_path):
    a_file = tmp_path / "taken"
    a_file.write_text("")
    assert f"cannot create a run folder in {a_file}: File exists" in one_error(
        amslam("run", "demo", "--out", str(a_file))
    )
    assert "cannot create a run folder in /proc/amslam" in one_error(
        amslam("run", "demo", "--out", "/proc/amslam")
    )


@pytest.mark.parametrize("experiment", ["planners", "multi-robot"])
def test_experiment_out_where_no_folder_can_be(tmp_path, experiment):
    a_file = tmp_path / "taken"
    a_file.write_text("")
    mission = str(small_mission(tmp_path, max_time=5))
    line = one_error(amslam("experiment", experiment, mission, "--seeds", "1", "--out", str(a_file)))
    assert line == f"error: cannot create an experiment folder in {a_file}: File exists"


def _a_run_folder(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    (run / "events.jsonl").write_text('{"t": 0.0, "event": "run_start"}\n')
    return run


@pytest.mark.parametrize(
    ("out", "why"), [("/proc/page.html", "No such file or directory"), (".", "Is a directory")]
)
def test_view_out_where_no_page_can_be(tmp_path, out, why):
    out = out if out.startswith("/") else str(tmp_path)
    line = one_error(amslam("view", str(_a_run_folder(tmp_path)), "--out", out))
    assert line == f"error: cannot write {out}: {why}"


AT = "which prints the tree's state at a time and writes no page"
RERUN = "which replays the run into rerun and writes no page"


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("--time", "5"), "error: --time needs --screenshot"),
        (("--time", "5", "--out", "page.html"), "error: --time needs --screenshot"),
        (("--port", "9000"), "error: --port needs --serve"),
        (("--at", "5", "--out", "page.html"), f"error: --out does not go with --at, {AT}"),
        (("--at", "5", "--serve"), f"error: --serve does not go with --at, {AT}"),
        (("--at", "5", "--screenshot", "x.png"), f"error: --screenshot does not go with --at, {AT}"),
        (
            ("--serve", "--out", "page.html"),
            "error: --out does not go with --serve, which serves the page live and writes none",
        ),
        (("--rrd", "x.rrd"), "error: --rrd needs --rerun"),
        (("--rrd",), "error: --rrd needs --rerun"),
        (("--web",), "error: --web needs --rerun"),
        (("--rerun", "--out", "page.html"), f"error: --out does not go with --rerun, {RERUN}"),
        (("--rerun", "--port", "9000"), f"error: --port does not go with --rerun, {RERUN}"),
        (
            ("--rerun", "--serve"),
            "error: --rerun does not go with --serve, which serves the page live and writes none",
        ),
        (("--at", "5", "--rerun"), f"error: --rerun does not go with --at, {AT}"),
        (
            ("--rerun", "--rrd", "x.rrd", "--web"),
            "error: --rrd does not go with --web, which serves the recording and saves none",
        ),
        (("--rerun", "--rrd", "/proc/x.rrd"), "error: cannot write /proc/x.rrd: No such file or directory"),
    ],
)
def test_view_options_of_another_mode_are_refused(tmp_path, args, expected):
    """An option the chosen mode would ignore is misuse: one line naming it, nothing written."""
    run = _a_run_folder(tmp_path)
    assert one_error(amslam("view", str(run), *args, cwd=tmp_path)) == expected
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["events.jsonl", "run"]


def test_run_rerun_options_are_checked_before_flying(tmp_path):
    """--rrd without --rerun, or an .rrd that cannot be written, is refused before take-off."""
    mission = str(small_mission(tmp_path))
    assert one_error(amslam("run", mission, "--rrd", "x.rrd", cwd=tmp_path)) == "error: --rrd needs --rerun"
    line = one_error(amslam("run", mission, "--rerun", "--rrd", "/proc/x.rrd", cwd=tmp_path))
    assert line == "error: cannot write /proc/x.rrd: No such file or directory"
    assert not (tmp_path / "runs").exists()


def test_tree_out_where_no_file_can_be(tmp_path):
    line = one_error(amslam("tree", str(small_mission(tmp_path)), "--out", "/proc/tree.txt"))
    assert line == "error: cannot write /proc/tree.txt: No such file or directory"


def test_output_closed_early_is_quiet():
    done = subprocess.run(
        f"{AMSLAM} dump-config slam gtsam | head -1",
        shell=True,
        capture_output=True,
        text=True,
        timeout=BOUND,
        executable="/bin/bash",
    )
    assert done.stdout.startswith("# slam backend 'gtsam'")
    assert "Traceback" not in done.stderr and "BrokenPipe" not in done.stderr


def first_line_then_close(*args: str) -> tuple[str, int, str]:
    """``amslam ARGS | head -1``: the first stdout line, then the pipe closed. Returns that line,
    the exit status and stderr."""
    proc = subprocess.Popen([AMSLAM, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()
    proc.stdout.close()  # the reader goes away: amslam's next print meets a broken pipe
    try:
        status = proc.wait(timeout=BOUND)
    finally:
        proc.kill()
    return first, status, proc.stderr.read()


def test_a_closed_stdout_does_not_stop_the_flight(tmp_path):
    """``amslam run | head -1``: the flight goes on to its verdict and completes its run folder;
    events.jsonl says stdout was closed; exit 141 (README)."""
    mission, out = small_mission(tmp_path, max_time=20), tmp_path / "runs"
    first, status, stderr = first_line_then_close("run", str(mission), "--out", str(out), "--quiet")
    assert first == f"flying mission 'small' ({mission})\n"
    assert status == 141 and stderr == "", stderr
    (run,) = out.iterdir()
    assert json.loads((run / "metrics.json").read_text())["verdict"] == "completed"
    assert (run / "report.md").stat().st_size > 0
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    closed = [e for e in events if e["event"] == "stdout_closed"]
    assert closed == [
        {
            "t": closed[0]["t"],
            "event": "stdout_closed",
            "reason": "stdout's reader went away; the run goes on to its end, printing nothing more there",
        }
    ]
    assert events[-1] == {"t": events[-1]["t"], "event": "run_end", "verdict": "completed"}


def test_a_closed_stdout_does_not_stop_an_experiment(tmp_path):
    mission, out = small_mission(tmp_path, max_time=5), tmp_path / "out"
    # --quiet: its runs' status lines (stderr is a pipe) would be on stderr besides the nothing checked
    args = (
        "--quiet",
        "experiment",
        "planners",
        str(mission),
        "--seeds",
        "1",
        "--executor",
        "serial",
        "--out",
        str(out),
    )
    first, status, stderr = first_line_then_close(*args)
    assert first == f"experiment planners on {mission}, seeds [1]\n"
    assert status == 141 and stderr == "", stderr
    (folder,) = out.iterdir()
    assert (folder / "table.md").stat().st_size > 0  # every run flown, the summary written
    runs = [Path(row["run_dir"]) for row in json.loads((folder / "results.json").read_text())]
    assert len(runs) == 3 and sorted(runs) == sorted((folder / "runs").iterdir())  # in flight order
    for run in runs:
        events = (run / "events.jsonl").read_text().splitlines()
        assert json.loads(events[-1])["event"] == "run_end"
        assert json.loads((run / "metrics.json").read_text())["verdict"] == "completed"
    # the first run ended before the experiment printed again (and met the closed pipe)
    assert ["stdout_closed" in (run / "events.jsonl").read_text() for run in runs] == [False, True, True]


def test_sigterm_lands_and_leaves_a_complete_run_folder_and_a_second_signal_waits(tmp_path):
    proc, out = start_flight(tmp_path)
    proc.send_signal(signal.SIGTERM)
    time.sleep(0.2)
    proc.send_signal(signal.SIGINT)  # while landing and saving: must not tear the run folder
    stdout, stderr = proc.communicate(timeout=BOUND)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "Traceback" not in stderr
    assert "verdict: aborted" in stdout
    (run,) = out.iterdir()
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["verdict"] == "aborted"
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert events[-1] == {"t": events[-1]["t"], "event": "run_end", "verdict": "aborted"}
    assert (run / "report.md").stat().st_size > 0


def _events(out: Path) -> str:
    return "".join(p.read_text() for p in out.glob("*/events.jsonl"))


def start_flight(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    """``amslam run`` of a long small mission in a child process, returned once it has taken off."""
    mission = small_mission(tmp_path, max_time=600)
    out = tmp_path / "runs"
    proc = subprocess.Popen(
        [AMSLAM, "run", str(mission), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + BOUND
    while not list(out.glob("*/events.jsonl")) or "takeoff" not in _events(out):
        assert proc.poll() is None and time.monotonic() < deadline, "the flight did not start"
        time.sleep(0.2)
    return proc, out


def test_an_experiment_whose_every_run_failed_exits_1(tmp_path):
    mission = small_mission(tmp_path, max_time=30)
    wide = ("--set", "robot.radius=2.5")  # no room to take off anywhere: every run fails
    out = ("--out", str(tmp_path / "out"))
    done = amslam("experiment", "planners", str(mission), "--seeds", "1", "--executor", "serial", *wide, *out)
    assert done.returncode == 1, done.stderr
    # that one line only: no warning from averaging or plotting series that no run produced
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: none of the 3 runs completed (failed: no room to take off"), line
    (folder,) = (tmp_path / "out").iterdir()
    assert "| cop | 1 | — | — | — | — | — |" in (folder / "table.md").read_text()
    assert not (folder / "explored_vs_distance.png").exists()  # nothing to draw


def test_view_port_out_of_range_or_taken_is_one_error(tmp_path: Path) -> None:
    import socket

    run = _a_run_folder(tmp_path)
    for port in ("99999", "-1"):
        assert "argument --port:" in one_error(amslam("view", str(run), "--serve", "--port", port))
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        line = one_error(amslam("view", str(run), "--serve", "--port", port))
    assert line.startswith(f"error: cannot serve on 127.0.0.1:{port}:"), line


def test_an_experiment_whose_summary_cannot_be_written_is_one_warning_line(tmp_path, capsys):
    # a full disk after the flights: the table and plots fail, the flown run folders stay
    import errno
    from types import SimpleNamespace

    from amslam.cli import run_experiment

    def run(args, registry):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "exp" / "results.json"))

    registry = SimpleNamespace(experiments={"full": SimpleNamespace(several_missions=False, run=run)})
    args = SimpleNamespace(
        experiment="full", more=[], mission="demo", first_seed=1, seeds=1, out=str(tmp_path)
    )
    assert run_experiment(args, registry) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line == (
        f"warning: experiment full: cannot write {tmp_path}/exp/results.json: No space left on device;"
        f" the runs flown so far are kept under {tmp_path}"
    )


def test_a_full_disk_names_the_experiment_folder_when_the_error_names_no_file(tmp_path, capsys):
    import errno
    from types import SimpleNamespace

    from amslam.cli import run_experiment

    def run(args, registry):
        (tmp_path / "planners-demo-1").mkdir()
        raise OSError(errno.ENOSPC, "No space left on device")  # as a write on a full disk raises it

    registry = SimpleNamespace(experiments={"full": SimpleNamespace(several_missions=False, run=run)})
    args = SimpleNamespace(
        experiment="full", more=[], mission="demo", first_seed=1, seeds=1, out=str(tmp_path)
    )
    assert run_experiment(args, registry) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"warning: experiment full: cannot write {tmp_path}/planners-demo-1: No space"), (
        line
    )
