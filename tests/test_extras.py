"""Every ``pip install 'amslam[NAME]'`` amslam tells its users names an extra pyproject.toml
defines (the RealSense error once named ``amslam[realsense]``, which did not exist), and the
README's install section lists every extra. (The RealSense error itself:
tests/plugins/mavsdk_platform/test_platform.py.)"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXTRAS = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
NAMED = re.compile(r"amslam\[([a-z0-9_,-]+)\]")


def _sources() -> list[Path]:
    return [
        path
        for folder in ("core", "plugins", "trees", "docs")
        for path in sorted((ROOT / folder).rglob("*"))
        if path.suffix in (".py", ".md", ".yaml") and path.is_file()
    ] + [ROOT / "README.md"]


def test_every_extra_a_message_or_page_names_exists():
    named = {}
    for path in _sources():
        for match in NAMED.finditer(path.read_text(encoding="utf-8", errors="replace")):
            for name in match.group(1).split(","):
                named.setdefault(name, path.relative_to(ROOT))
    assert "realsense" in named  # the camera's error names its extra
    unknown = {name: str(where) for name, where in named.items() if name not in EXTRAS}
    assert unknown == {}, f"extras named but not defined in pyproject.toml: {unknown}"


def test_the_readme_lists_every_extra():
    readme = (ROOT / "README.md").read_text()
    missing = [name for name in sorted(EXTRAS) if f"amslam[{name}]" not in readme]
    assert missing == [], f"extras the README's install section does not list: {missing}"
