"""Run replay and live view: a self-contained HTML page of the tree, map and trajectories.

- :func:`build_page` writes the page of a run folder (``amslam view RUN``);
- :class:`LiveServer` serves it on localhost and follows a run in progress (``--serve``);
- :mod:`amslam.apps.viewer.timeline` rebuilds the tree's state at a moment (``--at T``).
"""

from amslam.apps.viewer.build import build_page, resolve_run_folder
from amslam.apps.viewer.serve import LiveServer

__all__ = ["LiveServer", "build_page", "resolve_run_folder"]
