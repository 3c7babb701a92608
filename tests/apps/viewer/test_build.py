"""The replay page is one self-contained file; ``amslam view`` writes it, finds runs, prints a moment."""

from __future__ import annotations

import json
import os
import re
import time

import pytest

from amslam.apps.viewer import build_page, resolve_run_folder
from amslam.cli import main
from amslam.errors import AmslamError
from tests.apps.viewer import synthetic


def embedded(html: str) -> dict:
    match = re.search(r'<script type="application/json" id="amslam-data">(.*?)</script>', html, re.S)
    assert match, "no data block"
    return json.loads(match.group(1))


def test_page_is_self_contained_and_carries_the_run(tmp_path):
    run = synthetic.write_run(tmp_path / "run")
    page = build_page(run)
    assert page == run / "viewer.html"
    html = page.read_text()
    # nothing to fetch: no external script, style, image or font
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=", html)
    assert "http://" not in html and "https://" not in html and "@import" not in html
    assert "AmslamTimeline" in html and ".node[data-status" in html  # script and style inline
    data = embedded(html)
    assert data["info"]["mission"] == "synthetic" and data["info"]["floor_heights"] == [0.0]
    assert len(data["tree"]) == len(synthetic.TREE) and len(data["events"]) == len(synthetic.EVENTS)
    assert data["static"]["floors"][0]["cells"] and "live" not in data
    # an event's text with markup stays data: the block is not closed early
    closure = next(e for e in data["events"] if e["event"] == "loop_closure")
    assert closure["reason"] == "4 landmarks agree </script><b>"
    assert html.count("</script>") == 3  # the data block and the two scripts


def test_page_of_a_run_that_has_just_started(tmp_path):
    run = synthetic.write_run(tmp_path / "run", until=1.0)
    data = embedded(build_page(run, tmp_path / "out" / "page.html").read_text())
    assert data["static"] is None and len(data["tree"]) == 1 and data["structure"]


def test_newest_run_in_a_folder_of_runs(tmp_path):
    older = synthetic.write_run(tmp_path / "runs" / "a")
    newer = synthetic.write_run(tmp_path / "runs" / "b", until=3.0)
    past = time.time() - 100
    os.utime(older / "events.jsonl", (past, past))
    assert resolve_run_folder(tmp_path / "runs") == (newer, True)
    assert resolve_run_folder(older) == (older, False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(AmslamError, match="not a run folder"):
        resolve_run_folder(tmp_path / "empty")


def test_cli_view_writes_the_page_and_prints_a_moment(tmp_path, capsys):
    run = synthetic.write_run(tmp_path / "run")
    assert main(["view", str(run), "--out", str(tmp_path / "p.html")]) == 0
    assert "replay page:" in capsys.readouterr().out and (tmp_path / "p.html").exists()
    assert main(["view", str(run), "--at", "7.5"]) == 0
    out = capsys.readouterr().out
    assert "t = 7.5 s (tick 60)" in out and "GoToViewpoint [RUNNING]  — waypoint 3/4" in out
    assert main(["view", str(tmp_path / "nowhere")]) == 2
    assert "no such folder" in capsys.readouterr().err
