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
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {"amslam.missions"}
    for folder, package in PACKAGE_DIRS.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            parts = init.parent.relative_to(ROOT / folder).parts
            found.add(".".join([package, *parts]))
    assert found - listed == set(), "packages missing from pyproject.toml's [tool.setuptools] packages"
    assert listed - found == set(), "packages listed in pyproject.toml that do not exist"
