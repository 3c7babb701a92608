"""``amslam tree MISSION --format ascii|unicode|dot|svg|png``."""

from __future__ import annotations

import shutil

import pytest

from amslam.cli import main

needs_graphviz = pytest.mark.skipif(shutil.which("dot") is None, reason="Graphviz (dot) is not installed")


def test_ascii_to_stdout_and_dot_to_a_file(tmp_path, capsys):
    assert main(["tree", "demo", "--format", "ascii"]) == 0
    out = capsys.readouterr().out
    assert "Mission" in out and "GoToViewpoint" in out and out.isascii()
    assert main(["tree", "demo", "--format", "dot", "--blackboard", "--out", str(tmp_path / "t.dot")]) == 0
    dot = (tmp_path / "t.dot").read_text()
    assert dot.startswith("digraph demo {") and "Mission -> TakeOff" in dot
    assert "/tour" in dot  # the blackboard keys the leaves registered
    assert 'fontname="DejaVu Sans"' in dot


@needs_graphviz
@pytest.mark.parametrize("fmt", ["svg", "png"])
def test_drawings(tmp_path, capsys, fmt):
    out = tmp_path / f"tree.{fmt}"
    assert main(["tree", "demo", "--format", fmt, "--out", str(out)]) == 0
    data = out.read_bytes()
    assert data.startswith(b"\x89PNG") if fmt == "png" else b"<svg" in data and b"GoToViewpoint" in data
    assert str(out) in capsys.readouterr().out


def test_without_graphviz_drawings_fail_in_one_clear_line(tmp_path, capsys, monkeypatch):
    real_which = shutil.which
    monkeypatch.setattr(
        shutil, "which", lambda name, *a, **k: None if name == "dot" else real_which(name, *a, **k)
    )
    assert main(["tree", "demo", "--format", "svg", "--out", str(tmp_path / "t.svg")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "graphviz" in err and "apt-get install" in err
    assert not (tmp_path / "t.svg").exists()
    assert main(["tree", "demo", "--format", "dot"]) == 0  # text formats still work
