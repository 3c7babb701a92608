"""Where a mesh world's files are found: the world search path (docs/missions.md, "Worlds").

A relative ``mesh:`` or ``objects:`` of a mesh world is looked for, in this order:

1. beside the mission file (as every file a mission names);
2. in each folder of ``AMSLAM_WORLDS`` (separated like ``PATH``), e.g. ``AMSLAM_WORLDS=~/worlds``
   finds ``small_house/world.ply`` as ``~/worlds/small_house/world.ply``;
3. in the worlds amslam ships, when the path's first folder names one (``small_house/...``).

The shipped worlds are xz-compressed tar archives in this package's ``worlds`` folder (the
small house is 7.1 MB of PLY files, 1.1 MB as ``.tar.xz``; open3d reads meshes from files only,
so an archive is unpacked once, on first use, into the user's cache folder
``$XDG_CACHE_HOME/amslam/worlds`` (default ``~/.cache/amslam/worlds``), in a folder named by the
archive's digest: a newer archive never meets an older copy, and a run folder's ``mission.yaml``
keeps naming files that stay there.
"""

from __future__ import annotations

import hashlib
import importlib.resources
import os
import shutil
import tarfile
import tempfile
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, ValidationInfo

from amslam.errors import PlatformError
from amslam.interfaces import check_mission_file

#: environment variable listing folders of worlds (``os.pathsep``-separated, like ``PATH``)
WORLDS_ENV = "AMSLAM_WORLDS"
#: suffix of a shipped world's archive in the package's ``worlds`` folder
ARCHIVE_SUFFIX = ".tar.xz"


def _archives() -> dict[str, Path]:
    folder = importlib.resources.files("amslam.plugins.sim") / "worlds"
    if not folder.is_dir():
        return {}
    return {
        entry.name.removesuffix(ARCHIVE_SUFFIX): Path(str(entry))
        for entry in folder.iterdir()
        if entry.name.endswith(ARCHIVE_SUFFIX)
    }


def packaged_worlds() -> list[str]:
    """Names of the worlds shipped with amslam (``small_house``)."""
    return sorted(_archives())


def world_folders() -> list[Path]:
    """The folders listed in ``AMSLAM_WORLDS``, in order (empty entries skipped)."""
    listed = os.environ.get(WORLDS_ENV, "")
    return [Path(entry).expanduser() for entry in listed.split(os.pathsep) if entry.strip()]


def cache_folder() -> Path:
    """Where shipped worlds are unpacked: ``$XDG_CACHE_HOME/amslam/worlds`` (``~/.cache/...``)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "amslam" / "worlds"


def unpacked_world(name: str) -> Path:
    """The folder of the shipped world ``name``, unpacked on first use (see the module's doc)."""
    archive = _archives().get(name)
    if archive is None:
        raise PlatformError(f"no shipped world {name!r} (shipped: {', '.join(packaged_worlds()) or 'none'})")
    digest = hashlib.sha256(archive.read_bytes()).hexdigest()[:16]
    home = cache_folder() / digest
    folder = home / name
    if folder.is_dir():
        return folder
    try:
        home.mkdir(parents=True, exist_ok=True)
        # unpacked beside its final place and renamed there in one step: a run started meanwhile
        # (another terminal, a parallel experiment) sees the whole world or none of it
        staging = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=home))
        try:
            with tarfile.open(archive, "r:xz") as tar:
                if hasattr(tarfile, "data_filter"):  # Python >= 3.11.4: refuse links and paths out
                    tar.extractall(staging, filter="data")
                else:  # the archive is ours, shipped in the package
                    tar.extractall(staging)
            try:
                (staging / name).rename(folder)
            except OSError:
                if not folder.is_dir():  # not just another process that got there first
                    raise
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    except (OSError, tarfile.TarError) as exc:
        raise PlatformError(
            f"cannot unpack the shipped world {name!r} into {home}: {getattr(exc, 'strerror', None) or exc}"
            f" (set XDG_CACHE_HOME to a writable folder, or unpack {archive} into a folder of {WORLDS_ENV})"
        ) from None
    return folder


def find_world_file(value: str, mission_dir: Path | None) -> Path | None:
    """Where the world file ``value`` a mission names is along the search path; None if nowhere.

    An absolute path is itself. A shipped world is unpacked only when nothing earlier on the path
    has the file, so a user's copy (beside the mission, in ``AMSLAM_WORLDS``) always wins.
    """
    path = Path(value).expanduser()
    if path.is_absolute():
        return path if path.exists() else None
    if mission_dir is not None and (Path(mission_dir) / path).exists():
        return Path(mission_dir) / path
    for folder in world_folders():
        if (folder / path).exists():
            return folder / path
    if len(path.parts) > 1 and path.parts[0] in _archives():
        candidate = unpacked_world(path.parts[0]).parent / path
        return candidate if candidate.exists() else None
    return None


def locate_world_file(value: str | None, info: ValidationInfo) -> str | None:
    """A world file found along the search path, as an absolute path when it is not beside the
    mission (the mission's folder cannot locate it later); a file found nowhere is refused naming
    every place looked in. The kernel's :func:`check_mission_file` checks what is found."""
    mission_dir = (info.context or {}).get("mission_dir")
    if value is None or mission_dir is None or Path(value).expanduser().is_absolute():
        return value  # the kernel's check: an absolute path, or no mission folder to search from yet
    if (Path(mission_dir) / Path(value).expanduser()).exists():
        return value
    try:
        found = find_world_file(value, Path(mission_dir))
    except PlatformError as exc:
        raise ValueError(str(exc)) from None
    if found is not None:
        return str(found.resolve())
    folders = ", ".join(str(f) for f in world_folders()) or "not set"
    raise ValueError(
        f"no such file: {Path(mission_dir) / value} (nor in {WORLDS_ENV}: {folders}; shipped worlds: "
        f"{', '.join(packaged_worlds()) or 'none'})"
    )


#: a world file a mission names (mesh, objects): found along the world search path, then checked
#: present and readable like every :data:`~amslam.interfaces.MissionFile`
WorldFile = Annotated[str, AfterValidator(locate_world_file), AfterValidator(check_mission_file)]
