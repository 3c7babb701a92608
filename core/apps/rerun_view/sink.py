"""Where a rerun recording goes: an ``.rrd`` file, a spawned viewer, or a web viewer served locally."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from amslam.errors import AmslamError

INSTALL_HINT = "pip install 'amslam[interop]'"
#: the recording's file in the run folder when none is named (``--rrd`` alone, or no display)
DEFAULT_RRD = "recording.rrd"
#: rerun's application id: recordings of amslam runs share one, so the viewer keeps their layout
APPLICATION_ID = "amslam"


def import_rerun() -> Any:
    """The ``rerun`` module, or one error line naming the extra that installs it."""
    try:
        import rerun
    except ImportError as exc:
        raise AmslamError(
            f"--rerun needs rerun-sdk, which is not installed ({exc}): {INSTALL_HINT}"
        ) from None
    return rerun


def has_display() -> bool:
    """Whether ``rerun.spawn()`` can open a window: always on macOS and Windows, else with X11 or Wayland."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def writable_file(path: Path) -> Path:
    """``path`` if a file can be written there, else one error line saying why (nothing is left behind)."""
    existed = path.exists()
    try:
        with open(path, "ab"):
            pass
    except OSError as exc:
        raise AmslamError(f"cannot write {path}: {exc.strerror or exc}") from None
    if not existed:
        path.unlink()
    return path


def open_recording(
    run_dir: Path, rrd: str | None, web: bool = False, *, web_port: int | None = None
) -> tuple[Any, str]:
    """A recording stream for the run in ``run_dir`` and a line telling the user where it goes.

    ``rrd``: None — spawn the desktop viewer (or, without a display, save to ``RUN/recording.rrd``
    and say so); ``""`` — save to ``RUN/recording.rrd``; a path — save there. ``web``: serve the
    recording and rerun's web viewer on localhost instead (the caller keeps the process alive).
    """
    rr = import_rerun()
    # the run folder's name (mission and start time) tells recordings apart in the viewer
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=Path(run_dir).resolve().name)
    if web:
        url = rec.serve_grpc()
        rr.serve_web_viewer(connect_to=url, open_browser=False, web_port=web_port)
        port = 9090 if web_port is None else web_port
        from urllib.parse import quote

        return rec, f"rerun web viewer: http://localhost:{port}/?url={quote(url, safe='')} (Ctrl-C to stop)"
    if rrd is None and has_display():
        rec.spawn()
        return rec, "rerun viewer spawned"
    note = "" if rrd is not None else " (no display for a viewer: saved instead; --web serves one)"
    path = writable_file(Path(rrd) if rrd else Path(run_dir) / DEFAULT_RRD)
    rec.save(path)
    return rec, f"rerun recording: {path}{note}; open it with: rerun {path}"
