"""A full disk, a double Ctrl-C and SIGKILL: the run folder's files still parse — ``metrics.json``
is valid JSON or absent, never empty —, ``events.jsonl`` says why, and ``amslam view`` opens it."""

from __future__ import annotations

import errno
import json
import os
import resource
import signal
import subprocess
import time
from pathlib import Path

import pytest

from amslam.cli import main
from amslam.mission import load_mission
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from tests.e2e.missions import small_mission
from tests.e2e.test_hostile_cli import AMSLAM, BOUND, start_flight


def parses(run: Path, *, torn_last_line: bool = False) -> list[dict]:
    """Check every file of a run folder a reader opens; return its events."""

    def strict(name: str):
        raise AssertionError(f"bare {name} in a JSON file")

    metrics = run / "metrics.json"
    if metrics.exists():
        assert metrics.stat().st_size > 0, "an empty metrics.json"
        json.loads(metrics.read_text(), parse_constant=strict)
    assert not list(run.glob(".*.tmp")), "temporary files left behind"
    events: list[dict] = []
    for name in ("events.jsonl", "tree.jsonl", "measurements.jsonl"):
        path = run / name
        if not path.exists():
            continue
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            try:
                record = json.loads(line, parse_constant=strict)
            except json.JSONDecodeError:
                assert torn_last_line and i == len(lines) - 1, f"{name}:{i + 1} is not JSON: {line!r}"
                continue
            if name == "events.jsonl":
                events.append(record)
    return events


def view_opens(run: Path, capsys) -> None:
    assert main(["view", str(run), "--out", str(run / "page.html")]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error:" not in err, err
    assert (run / "page.html").stat().st_size > 0


def run_with_files_limited_to(tmp_path: Path, kib: int) -> tuple[subprocess.CompletedProcess, Path]:
    """``amslam run`` of a small mission with every file limited to ``kib`` KiB (RLIMIT_FSIZE):
    a write beyond it fails with EFBIG, as a full disk fails with ENOSPC."""
    mission = small_mission(tmp_path, max_time=20)
    out = tmp_path / "runs"

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (kib * 1024, kib * 1024))

    done = subprocess.run(
        [AMSLAM, "run", str(mission), "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=BOUND,
        preexec_fn=small_files,
        check=False,
    )
    return done, out


def test_files_too_large_for_the_disk_keep_the_verdict_and_say_so(tmp_path, capsys):
    """Every file limited to 96 KiB (RLIMIT_FSIZE): the map's .npz (about 600 KiB) cannot be written,
    while the flight's streams fit (measurements.jsonl, 65 KiB with 128 points per detection, the
    test's 64 KiB before)."""
    done, out = run_with_files_limited_to(tmp_path, 96)
    assert "Traceback" not in done.stderr
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        "warning: not every output of the run could be written (report: OSError: [Errno 27] File too large); "
        "events.jsonl says which"
    )
    (run,) = out.iterdir()
    events = parses(run)
    metrics = json.loads((run / "metrics.json").read_text())
    assert (
        metrics["verdict"] == "completed"
        and metrics["outputs_error"] == "report: OSError: [Errno 27] File too large"
    )
    assert "explored_percent" in metrics  # what was computed is kept
    assert [e["event"] for e in events][-2:] == ["outputs_error", "run_end"]
    assert "File too large" in events[-2]["error"]
    assert "could not all be written" in (run / "report.md").read_text()
    view_opens(run, capsys)


def test_streams_that_cannot_be_flushed_mid_flight_are_output_errors(tmp_path, capsys):
    """8 KiB per file: the trajectories and measurements.jsonl fill up during the flight, and
    their buffered tail cannot be flushed when they are closed. The flight goes on to its verdict;
    the streams are named as outputs that could not be written."""
    done, out = run_with_files_limited_to(tmp_path, 8)
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 1, done.stderr
    assert "verdict: completed" in done.stdout.splitlines()
    too_large = "OSError: [Errno 27] File too large"
    streams = ("vio.tum", "slam.tum", "ground_truth.tum", "measurements.jsonl")
    outputs_error = "; ".join([*(f"{name}: {too_large}" for name in streams), f"report: {too_large}"])
    assert done.stderr.strip().splitlines() == [
        f"warning: not every output of the run could be written ({outputs_error}); events.jsonl says which"
    ]
    (run,) = out.iterdir()
    events = parses(run, torn_last_line=True)
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["verdict"] == "completed" and metrics["outputs_error"] == outputs_error
    assert [e["event"] for e in events][-2:] == ["outputs_error", "run_end"]
    assert events[-1]["verdict"] == "completed"
    view_opens(run, capsys)


def test_a_disk_full_while_the_summary_is_saved_leaves_no_empty_file(tmp_path, capsys, monkeypatch):
    """ENOSPC when each summary file is synced (where a full disk shows up): no file half-written."""
    registry = build_plugin_manager()
    mission = load_mission(small_mission(tmp_path, max_time=15), registry)
    runner = Runner(mission, registry, tmp_path / "runs")
    real_finish = runner._finish

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def finish_on_a_full_disk(verdict: str):
        monkeypatch.setattr(os, "fsync", full)  # the flight is done; from now on the disk is full
        return real_finish(verdict)

    monkeypatch.setattr(runner, "_finish", finish_on_a_full_disk)
    result = runner.run()
    monkeypatch.undo()
    assert result.verdict == "completed"
    full_disk = "OSError: [Errno 28] No space left on device"
    assert result.metrics["outputs_error"] == f"metrics.json: {full_disk}; report: {full_disk}"
    run = result.run_dir
    assert not (run / "metrics.json").exists() and not (run / "report.md").exists()
    events = parses(run)
    assert [e["event"] for e in events][-4:] == ["outputs_error", "write_failed", "write_failed", "run_end"]
    assert [(e["file"], e["error"]) for e in events[-3:-1]] == [
        ("metrics.json", "No space left on device"),
        ("report.md", "No space left on device"),
    ]
    view_opens(run, capsys)


def test_a_double_ctrl_c_lands_and_completes_the_run_folder(tmp_path, capsys):
    proc, out = start_flight(tmp_path)
    proc.send_signal(signal.SIGINT)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)  # impatient: must not tear the run folder nor print a traceback
    stdout, stderr = proc.communicate(timeout=BOUND)
    assert proc.returncode == 128 + signal.SIGINT, stderr
    assert "Traceback" not in stderr
    assert "verdict: aborted" in stdout
    (run,) = out.iterdir()
    events = parses(run)
    assert json.loads((run / "metrics.json").read_text())["verdict"] == "aborted"
    assert events[-1] == {"t": events[-1]["t"], "event": "run_end", "verdict": "aborted"}
    assert any(e["event"] == "aborted" and "SIGINT" in e["reason"] for e in events)
    view_opens(run, capsys)


def test_sigkill_leaves_streams_that_parse_and_a_folder_the_viewer_opens(tmp_path, capsys):
    proc, out = start_flight(tmp_path)
    time.sleep(1.0)
    proc.kill()  # no handler runs: whatever was flushed is what is left
    proc.communicate(timeout=BOUND)
    assert proc.returncode == -signal.SIGKILL
    (run,) = out.iterdir()
    events = parses(run, torn_last_line=True)
    assert not (run / "metrics.json").exists()  # never written, rather than empty
    assert events[0]["event"] == "run_start" or any(e["event"] == "takeoff" for e in events)
    view_opens(run, capsys)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_says_why_in_the_events(tmp_path, capsys, signum):
    proc, out = start_flight(tmp_path)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=BOUND)
    assert proc.returncode == 128 + signum and "Traceback" not in stderr
    (run,) = out.iterdir()
    events = parses(run)
    name = signal.Signals(signum).name
    assert any(
        e["event"] == "aborted" and e["reason"] == f"stopped by {name}: landing where it is" for e in events
    )
    view_opens(run, capsys)
