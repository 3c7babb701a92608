"""Shared fixtures, and which tests run at normal priority.

``make test`` runs the suite in two parts at once on pytest-xdist workers: the ``realtime``
tests on two at normal priority, every other test on three at the lowest (``nice -n 19``). A
realtime test judges something measured on the wall clock while it runs — a flight against a
vehicle in real time (MAVLink emulator, SITL), late control ticks, a thread kept running while a
call holds or lets go of the interpreter lock. Such a test mostly waits on the clock (the SITL
exploration uses under a third of a core), so the other tests fill the cores meanwhile; the
scheduler hands the cores to a realtime test whenever it wants them, so their load is not its
load. They are marked here by file, so that a new test in one of these files runs at normal
priority too; a test elsewhere that needs it takes ``@pytest.mark.realtime``. One that failed
while the cores were loaded (by the other part, or by other users of a shared machine) runs once
more, alone, after the other part is done; a test failing both times fails ``make test``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from amslam.registry import build_plugin_manager

TESTS = Path(__file__).parent
#: files whose tests measure on the wall clock (see above)
REALTIME = (
    "plugins/mavsdk_platform",
    "apps/test_realtime.py",
    "apps/test_sitl_camera_only.py",
    "core/test_backend_process.py",
    "core/test_dijkstra.py",
    "core/test_slam_thread.py",
    "core/test_mapper_thread.py",
    "e2e/test_detection_thread.py",
    "e2e/test_hostile_cli.py",
    # its flights run under the hostile command line's wall-clock bound on hangs (BOUND): starved
    # at the lowest priority on a loaded machine, a flight took longer than it (session 46)
    "e2e/test_hostile_disk.py",
)


#: the longest tests, started first: a part lasts about as long as its longest test only if that
#: test does not start last (the SITL flights, about 100 s and 20 s of wall clock each; the thread
#: rule's two flights and the flights other end-to-end tests share, 10-40 s each)
LONGEST_FIRST = (
    "plugins/mavsdk_platform/test_sitl_exploration.py",
    "e2e/test_thread_rule.py",
    "e2e/test_octomap_example.py",
    "e2e/test_rerun_view.py",
    "e2e/test_export_mcap.py",
    "e2e/test_ground_truth_withheld.py",
)


def pytest_collection_modifyitems(config, items):
    def where(item) -> str:
        return Path(item.path).resolve().relative_to(TESTS.resolve()).as_posix()

    for item in items:
        if where(item).startswith(REALTIME):
            item.add_marker(pytest.mark.realtime)

    def rank(item) -> int:
        here = where(item)
        return next((k for k, long in enumerate(LONGEST_FIRST) if here.startswith(long)), len(LONGEST_FIRST))

    items.sort(key=rank)  # stable: otherwise in order


@pytest.fixture(scope="session")
def registry():
    """The registry of the installed plugins (entry points), built once."""
    return build_plugin_manager()
