"""Exceptions, one family per domain, each carrying a message fit to print as is."""

from __future__ import annotations


class AmslamError(Exception):
    """Base of every error amslam reports to the user without a traceback."""


class MissionError(AmslamError):
    """A mission file is invalid. ``problems`` holds one line per problem."""

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


class PluginError(AmslamError):
    """A plugin could not be loaded or a backend name is unknown."""


class PlatformError(AmslamError):
    """The vehicle refused a command or the link failed."""


class PlanningError(AmslamError):
    """No valid plan could be found."""


class NoPathFoundError(PlanningError):
    """No collision-free path exists between two points in the known free space."""
