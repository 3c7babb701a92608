"""Run replay and live view: a self-contained HTML page of the tree, map and trajectories.

- :func:`build_page` writes the page of a run folder (``amslam view RUN``);
- :class:`LiveServer` serves it on localhost and follows a run in progress (``--serve``);
- :mod:`amslam.viewer.timeline` rebuilds the tree's state at a moment (``--at T``).
"""

from amslam.viewer.build import build_page, resolve_run_folder
from amslam.viewer.serve import LiveServer

__all__ = ["LiveServer", "build_page", "resolve_run_folder"]
