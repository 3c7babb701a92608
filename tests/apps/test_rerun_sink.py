"""Where a rerun recording goes, and the one error line without rerun-sdk."""

from __future__ import annotations

import sys

import pytest

from amslam.apps.rerun_view import open_recording
from amslam.apps.rerun_view.sink import import_rerun
from amslam.errors import AmslamError


def test_without_rerun_sdk_the_error_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # an import of it now fails
    with pytest.raises(AmslamError, match=r"--rerun needs rerun-sdk.*: pip install 'amslam\[interop\]'$"):
        import_rerun()


def test_without_a_display_the_recording_is_saved_in_the_run_folder_and_that_is_said(monkeypatch, tmp_path):
    pytest.importorskip("rerun")
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    rec, where = open_recording(tmp_path, None)
    rec.log("x", __import__("rerun").TextLog("hello"))
    rec.flush()
    assert (tmp_path / "recording.rrd").stat().st_size > 0
    assert where.startswith(f"rerun recording: {tmp_path / 'recording.rrd'} (no display for a viewer: saved")


def test_rrd_alone_means_the_run_folder_and_a_path_is_taken_as_given(tmp_path):
    pytest.importorskip("rerun")
    _, where = open_recording(tmp_path, "")
    assert where.startswith(f"rerun recording: {tmp_path / 'recording.rrd'}; open it with: rerun ")
    _, where = open_recording(tmp_path, str(tmp_path / "elsewhere.rrd"))
    assert (tmp_path / "elsewhere.rrd").exists()
