"""One self-contained HTML page replaying a run: data, script and style inline, nothing fetched.

The page is ``template.html`` with ``viewer.css``, ``timeline.js`` and ``viewer.js`` pasted in
and the run's data as a JSON block, so it opens offline from disk or from an e-mail attachment.
"""

from __future__ import annotations

import json
import math
import re
from importlib import resources
from pathlib import Path
from typing import Any

from amslam.apps.viewer.runfiles import FILES, mission_info, poll_run
from amslam.errors import AmslamError
from amslam.rundir import write_output

PAGE_NAME = "viewer.html"


def _asset(name: str) -> str:
    return resources.files("amslam.apps.viewer").joinpath(name).read_text(encoding="utf-8")


def _finite(value: Any) -> Any:
    """NaN and infinities as null: JSON.parse rejects them."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def embed_json(data: Any) -> str:
    """JSON safe inside a ``<script>`` element: no ``<`` at all, so no ``</script>`` or ``<!--``."""
    text = json.dumps(_finite(data), separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c")


def is_run_folder(path: Path) -> bool:
    return path.is_dir() and any((path / name).exists() for name in (FILES["events"], FILES["tree"]))


def resolve_run_folder(path: Path) -> tuple[Path, bool]:
    """``path`` if it is a run folder, else the newest run folder inside it (and True).

    Raises:
        AmslamError: neither ``path`` nor any folder in it holds a run.
    """
    path = Path(path)
    if not path.exists():
        raise AmslamError(f"{path}: no such folder")
    if is_run_folder(path):
        return path, False
    runs = [p for p in path.iterdir() if is_run_folder(p)] if path.is_dir() else []
    if not runs:
        raise AmslamError(
            f"{path}: not a run folder (no events.jsonl or tree.jsonl in it or in its sub-folders)"
        )
    return max(
        runs, key=lambda p: (p / FILES["events"]).stat().st_mtime if (p / FILES["events"]).exists() else 0
    ), True


def page_data(run_dir: Path, live: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything the page shows, read from the run folder now (``live``: poll settings, or None)."""
    delta = poll_run(run_dir)
    data = {
        "info": mission_info(run_dir),
        "structure": delta.structure or [],
        "tree": delta.tree,
        "events": delta.events,
        "traj": delta.traj,
        "static": delta.static,
    }
    if live is not None:
        data["live"] = {**live, "cursor": delta.cursor, "finished": delta.finished}
    return data


def render_page(data: dict[str, Any]) -> str:
    """The HTML page for ``data`` (see :func:`page_data`)."""
    info = data.get("info") or {}
    title = f"amslam · {info.get('mission') or 'run'} · {info.get('folder', '')}"
    parts = {
        "TITLE": title.replace("&", "&amp;").replace("<", "&lt;"),
        "CSS": _asset("viewer.css"),
        "TIMELINE_JS": _asset("timeline.js"),
        "VIEWER_JS": _asset("viewer.js"),
        "DATA": embed_json(data),
    }
    # One pass, so that nothing pasted in (a script, the data) is taken for a placeholder.
    return re.sub(
        r"__(TITLE|CSS|TIMELINE_JS|VIEWER_JS|DATA)__", lambda m: parts[m.group(1)], _asset("template.html")
    )


def build_page(run_dir: Path, out: Path | None = None) -> Path:
    """Write the replay page of ``run_dir`` to ``out`` (default ``<run_dir>/viewer.html``)."""
    run_dir = Path(run_dir)
    out = Path(out) if out is not None else run_dir / PAGE_NAME
    return write_output(out, render_page(page_data(run_dir)))
