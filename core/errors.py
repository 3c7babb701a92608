"""Exceptions, one family per domain, each carrying a message fit to print as is."""

from __future__ import annotations


class AmslamError(Exception):
    """Base of every error amslam reports to the user without a traceback."""


class MissionError(AmslamError):
    """A mission file is invalid. ``problems`` holds one line per problem; ``unknown_keys`` the
    dotted paths of those that are keys no schema knows."""

    def __init__(self, problems: list[str], unknown_keys: list[str] = ()):
        self.problems = list(problems)
        self.unknown_keys = list(unknown_keys)
        super().__init__("\n".join(self.problems))


class PluginError(AmslamError):
    """A plugin could not be loaded or a backend name is unknown."""


class PlatformError(AmslamError):
    """The vehicle refused a command or the link failed."""


class PlanningError(AmslamError):
    """No valid plan could be found."""


class NoPathFoundError(PlanningError):
    """No collision-free path exists between two points in the known free space."""


class RunFileError(AmslamError, ValueError):
    """A file of a run folder (a trajectory, ``landmarks.json``, ``map.npz``) cannot be read: the
    message names the file (and the line or record). A ``ValueError`` too, so code that caught the
    ``ValueError`` of a bad file before the readers were shared still catches it."""
