"""rerun (https://rerun.io) for amslam runs: a 3-D replay of a run folder and a live view of a flight.

- :func:`replay_run` logs a finished (or running) run folder into a rerun recording
  (``amslam view RUN --rerun``);
- :class:`LiveRerun` is a run observer that streams a flight as it happens (``amslam run MISSION
  --rerun``); the command registers it for that run only;
- :mod:`amslam.apps.rerun_view.scene` is what both log, entity by entity (see docs/viewer.md).

``rerun-sdk`` is an optional dependency (``pip install 'amslam[interop]'``): it is imported inside the
functions that need it, so amslam works without it.
"""

from amslam.apps.rerun_view.live import LiveRerun
from amslam.apps.rerun_view.replay import replay_run
from amslam.apps.rerun_view.sink import INSTALL_HINT, import_rerun, open_recording

__all__ = ["INSTALL_HINT", "LiveRerun", "import_rerun", "open_recording", "replay_run"]
