"""The wheel holds every package: pyproject.toml lists each folder with an ``__init__.py``.

An editable install finds subpackages by path, so a package missing from the list works in a
checkout and is missing from the wheel a user installs.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from tests.import_contract import PACKAGE_DIRS

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(_setuptools()["packages"])
    found = {"amslam.missions"}
    for folder, package in PACKAGE_DIRS.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            parts = init.parent.relative_to(ROOT / folder).parts
            found.add(".".join([package, *parts]))
    # a data folder (no __init__.py) is listed as a package too, with its files in package-data:
    # setuptools warns at every install about a data folder that is not
    data = {
        name for name in listed - found if _folder(name).is_dir() and name in _setuptools()["package-data"]
    }
    assert found - listed == set(), "packages missing from pyproject.toml's [tool.setuptools] packages"
    assert listed - found - data == set(), "packages listed in pyproject.toml that do not exist"


def _setuptools() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _folder(package: str) -> Path:
    """The checkout folder of a dotted package name (through PACKAGE_DIRS)."""
    roots = {**{p: ROOT / f for f, p in PACKAGE_DIRS.items()}, "amslam.missions": ROOT / "missions"}
    root = max((r for r in roots if package == r or package.startswith(r + ".")), key=len)
    return roots[root].joinpath(*package[len(root) :].split(".")[1:])


def test_every_data_file_of_a_package_is_in_its_package_data():
    # a file the package reads (a mission, a model, a shipped world) that no package-data pattern
    # matches is in a checkout and missing from the wheel: `amslam run small_house` from a wheel
    # once failed on a world that lived beside the checkout
    import fnmatch

    setuptools = _setuptools()
    folders = {package: ROOT / folder for folder, package in PACKAGE_DIRS.items()}
    folders["amslam.missions"] = ROOT / "missions"
    files = [p for base in folders.values() for p in base.rglob("*") if p.is_file()]
    unshipped = []
    for path in files:
        if path.suffix in (".py", ".pyc") or "__pycache__" in path.parts:
            continue
        package_dir = path.parent
        data_folders = {_folder(name) for name in setuptools["packages"]}
        while not (package_dir / "__init__.py").is_file() and package_dir not in data_folders:
            package_dir = package_dir.parent
        root, base = next((p, f) for p, f in folders.items() if package_dir.is_relative_to(f))
        package = ".".join([root, *package_dir.relative_to(base).parts])
        inside = path.relative_to(package_dir).as_posix()
        if not any(fnmatch.fnmatch(inside, glob) for glob in setuptools["package-data"].get(package, [])):
            unshipped.append(str(path.relative_to(ROOT)))
    assert unshipped == [], "files no [tool.setuptools.package-data] pattern ships"
