"""Shared fixtures, and which tests run alone.

``make test`` runs the suite in two parts: every test but the ``realtime`` ones on two worker
processes (pytest-xdist, one per core), then the ``realtime`` ones alone. A realtime test judges
something measured on the wall clock while it runs — a flight against a vehicle in real time
(MAVLink emulator, SITL), late control ticks, a thread kept running while a call holds or lets
go of the interpreter lock — and a second worker beside it on two cores would be its load, not
the code's. They are marked here by file, so that a new test in one of these files is run alone
too; a test elsewhere that needs it takes ``@pytest.mark.realtime``.
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
    "e2e/test_thread_rule.py",
    "e2e/test_detection_thread.py",
    "e2e/test_hostile_cli.py",
)


def pytest_collection_modifyitems(config, items):
    for item in items:
        where = Path(item.path).resolve().relative_to(TESTS.resolve()).as_posix()
        if where.startswith(REALTIME):
            item.add_marker(pytest.mark.realtime)


@pytest.fixture(scope="session")
def registry():
    """The registry of the installed plugins (entry points), built once."""
    return build_plugin_manager()
