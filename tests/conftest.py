"""Shared fixtures."""

from __future__ import annotations

import pytest

from amslam.registry import build_plugin_manager


@pytest.fixture(scope="session")
def registry():
    """The registry of the installed plugins (entry points), built once."""
    return build_plugin_manager()
