"""A headless Chromium for pictures of the page (``amslam view RUN --screenshot FILE``) and for tests.

Only the system's browser is used (Debian: ``chromium``, driven by ``chromium-driver`` in the
tests); nothing is downloaded.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from amslam.errors import AmslamError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: flags for a quiet, isolated headless run: no network chatter, no updates, no first-run UI
HEADLESS_FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--hide-scrollbars",
)
INSTALL_HINT = (
    "install the Debian packages chromium and chromium-driver "
    "(sudo apt-get install -y chromium chromium-driver)"
)


def find_chromium() -> str | None:
    """Path of a Chromium (or Chrome) executable on PATH, or None."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def find_chromedriver() -> str | None:
    """Path of the ``chromedriver`` matching the system Chromium, or None."""
    return shutil.which("chromedriver")


def screenshot(page: Path, out: Path, at: float | None = None, size: tuple[int, int] = (1440, 900)) -> Path:
    """Render ``page`` in headless Chromium at time ``at`` (default: the start) and save a PNG.

    Raises:
        AmslamError: no Chromium, or it failed.
    """
    chromium = find_chromium()
    if chromium is None:
        raise AmslamError(f"--screenshot needs a Chromium browser: {INSTALL_HINT}")
    url = Path(page).resolve().as_uri() + (f"?t={at}" if at is not None else "")
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="amslam-chromium-") as profile:
        command = [
            chromium,
            *HEADLESS_FLAGS,
            f"--user-data-dir={profile}",
            f"--window-size={size[0]},{size[1]}",
            f"--screenshot={out}",
            url,
        ]
        done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    if done.returncode != 0 or not out.exists():
        raise AmslamError(f"chromium could not take the screenshot: {done.stderr.strip()[-500:]}")
    return out
