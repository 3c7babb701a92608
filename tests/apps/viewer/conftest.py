"""A headless Chromium driven by Selenium, from the system's packages only (nothing is downloaded)."""

from __future__ import annotations

import os

import pytest

from amslam.apps.viewer.browser import HEADLESS_FLAGS, INSTALL_HINT, find_chromedriver, find_chromium


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """A Selenium Chrome driver on the system Chromium, 1600 × 1000; skipped where there is none."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (pip install selenium, or the dev extras)")
    chromium, driver_path = find_chromium(), find_chromedriver()
    if chromium is None or driver_path is None:
        pytest.skip(f"no headless browser: {INSTALL_HINT}")
    os.environ.setdefault("SE_OFFLINE", "true")  # Selenium Manager must not fetch a driver or browser
    options = Options()
    options.binary_location = chromium
    for flag in (*HEADLESS_FLAGS, "--window-size=1600,1000"):
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(executable_path=driver_path), options=options)
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()
