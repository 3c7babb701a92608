"""End to end in headless Chromium: the replay page of a run, the slider, the tree, the robot, live view.

Skipped, with the reason, where Selenium or the system's Chromium and chromedriver are missing.
"""

from __future__ import annotations

import struct

import pytest

from amslam.apps.viewer import LiveServer, build_page
from amslam.apps.viewer.browser import INSTALL_HINT, find_chromium
from amslam.apps.viewer.runfiles import poll_run
from amslam.apps.viewer.timeline import tree_state_at
from amslam.cli import main
from tests.apps.viewer import synthetic

WAIT = 30  # s: the most any condition may take to hold before a test fails (never a measured time)


def open_page(browser, url: str) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get(url)
    WebDriverWait(browser, WAIT).until(lambda d: d.execute_script("return !!window.amslamViewer"))


def wait_for(browser, condition, message: str) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(browser, WAIT, poll_frequency=0.1).until(lambda d: condition(), message)


def page_time(browser) -> float:
    return browser.execute_script("return amslamViewer.time()")


def dom_statuses(browser) -> dict[int, str]:
    """Each tree row's status as the DOM shows it (``data-status`` drives its colour)."""
    from selenium.webdriver.common.by import By

    rows = browser.find_elements(By.CSS_SELECTOR, "#tree .node")
    return {int(r.get_attribute("data-node-id")): r.get_attribute("data-status") for r in rows}


def reference_statuses(run, t: float) -> dict[int, str]:
    state = tree_state_at(run.tree, t)
    return {node["id"]: state.status(node["id"]) for node in run.structure}


def pixel(browser, x: float, y: float) -> list[int]:
    """RGBA of floor 0's canvas at world point (x, y)."""
    return browser.execute_script(
        "const [px, py] = amslamViewer.toCanvas(0, arguments[0], arguments[1]);"
        "const g = document.getElementById('floor-0').getContext('2d');"
        "return Array.from(g.getImageData(px, py, 1, 1).data);",
        x,
        y,
    )


def is_robot_fill(rgba: list[int]) -> bool:
    return max(rgba[:3]) < 60  # the marker is filled near-black; nothing else on the map is


def js_errors(browser) -> list[str]:
    return [
        e["message"]
        for e in browser.get_log("browser")
        if e["level"] == "SEVERE" and "favicon.ico" not in e["message"]
    ]


def set_slider(browser, fraction: float) -> None:
    """Click the slider track at ``fraction`` of its width, as a user would."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    slider = browser.find_element(By.ID, "slider")
    width = slider.size["width"]
    offset = int((fraction - 0.5) * width)  # from the slider's centre
    ActionChains(browser).move_to_element_with_offset(slider, offset, 0).click().perform()


def test_slider_tree_and_robot_on_a_synthetic_run(browser, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    folder = synthetic.write_run(tmp_path / "run")
    run = poll_run(folder)
    open_page(browser, build_page(folder).as_uri())
    assert js_errors(browser) == []
    assert browser.execute_script("return amslamViewer.end()") == pytest.approx(15.1)
    assert browser.find_element(By.ID, "verdict").text == "completed"

    # the slider, clicked early in the run: the take-off is running
    set_slider(browser, 0.08)
    t = page_time(browser)
    assert 0.1 <= t < 2.0
    assert dom_statuses(browser) == reference_statuses(run, t)
    assert dom_statuses(browser)[1] == "RUNNING"  # TakeOff
    row = browser.find_element(By.CSS_SELECTOR, '#tree .node[data-node-id="1"]')
    assert "climbing" in row.text

    # the end key on the slider: everything succeeded, the robot landed where it started
    browser.find_element(By.ID, "slider").send_keys(Keys.END)
    assert page_time(browser) == pytest.approx(15.1)
    end = dom_statuses(browser)
    assert end == reference_statuses(run, 15.1) and end[0] == "SUCCESS" and end[5] == "SUCCESS"
    # the left arrow steps back to the previous change of the tree
    browser.find_element(By.ID, "slider").send_keys(Keys.ARROW_LEFT)
    assert page_time(browser) == 15.0
    browser.find_element(By.ID, "slider").send_keys(Keys.ARROW_LEFT)
    assert page_time(browser) == 12.0 and dom_statuses(browser)[5] == "RUNNING"  # landing

    # the robot marker moves: drawn where the robot is, gone from where it was
    browser.execute_script("amslamViewer.setTime(7.0)")
    x1, y1, _, _ = synthetic.pose(7.0)
    assert is_robot_fill(pixel(browser, x1, y1))
    readout = browser.find_element(By.ID, "robot")
    assert float(readout.get_attribute("data-x")) == pytest.approx(x1, abs=0.01)
    browser.execute_script("amslamViewer.setTime(3.0)")
    x2, y2, _, _ = synthetic.pose(3.0)
    assert not is_robot_fill(pixel(browser, x1, y1)) and is_robot_fill(pixel(browser, x2, y2))
    assert float(readout.get_attribute("data-x")) == pytest.approx(x2, abs=0.01)
    assert dom_statuses(browser) == reference_statuses(run, 3.0)

    # clicking an event jumps there
    closure = browser.find_element(By.CSS_SELECTOR, '#events .ev[data-kind="slc"]')
    assert "accepted" in closure.text and "</script>" in closure.text  # shown as text, not markup
    closure.click()
    assert page_time(browser) == 9.0 and "current" in closure.get_attribute("class")
    assert dom_statuses(browser) == reference_statuses(run, 9.0)

    # play moves time forward; pause stops it
    play = browser.find_element(By.ID, "play")
    play.click()
    wait_for(browser, lambda: page_time(browser) > 9.0, "playing did not move the time")
    play.click()
    # the button is redrawn on the page's next frame, which a loaded machine delays
    wait_for(browser, lambda: play.text == "▶", "pause did not stop the playback")
    browser.save_screenshot(str(tmp_path / "synthetic.png"))
    assert (tmp_path / "synthetic.png").stat().st_size > 10_000
    assert js_errors(browser) == []


def test_live_view_follows_a_run_in_progress(browser, tmp_path):
    from selenium.webdriver.common.by import By

    folder = synthetic.write_run(tmp_path / "run", until=4.0)
    with LiveServer(folder, port=0, interval=0.2) as server:
        open_page(browser, server.url)
        assert browser.execute_script("return amslamViewer.end()") == pytest.approx(4.0)
        assert "map and landmarks appear when the run ends" in browser.find_element(By.ID, "legend").text
        synthetic.write_run(folder, until=10.0)  # the run goes on
        wait_for(browser, lambda: browser.execute_script("return amslamViewer.end()") >= 10.0, "no new data")
        assert browser.execute_script("return amslamViewer.records()") == 4
        assert page_time(browser) == pytest.approx(10.0)  # following the newest data
        run = poll_run(folder)
        assert dom_statuses(browser) == reference_statuses(run, 10.0)
        synthetic.write_run(folder)  # it ends
        wait_for(browser, lambda: browser.execute_script("return amslamViewer.finished()"), "never finished")
        wait_for(browser, lambda: browser.find_element(By.ID, "verdict").text == "completed", "no verdict")
        assert "chair ×1" in browser.find_element(By.ID, "legend").text
        assert dom_statuses(browser) == reference_statuses(poll_run(folder), page_time(browser))
    assert js_errors(browser) == []


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A real, short simulated mission (take-off, panorama, a little exploring, return, landing)."""
    from amslam.mission import load_mission
    from amslam.registry import build_plugin_manager
    from amslam.runner import Runner
    from tests.e2e.missions import small_mission

    folder = tmp_path_factory.mktemp("small")
    registry = build_plugin_manager()
    mission = load_mission(small_mission(folder, max_time=25), registry)
    return Runner(mission, registry, folder / "runs").run().run_dir


def test_replay_of_a_real_run(browser, small_run, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    run = poll_run(small_run)
    open_page(browser, build_page(small_run).as_uri() + "?t=0")
    assert js_errors(browser) == []
    names = {n["name"]: n["id"] for n in run.structure}
    slider = browser.find_element(By.ID, "slider")
    slider.send_keys(Keys.ARROW_RIGHT)  # the first change: taking off
    first = page_time(browser)
    assert first == run.tree[0][0] and dom_statuses(browser)[names["TakeOff"]] == "RUNNING"
    robot_start = browser.execute_script("return amslamViewer.robot()")
    seen = set()
    for _ in range(12):  # step through the tree's changes; the page agrees with the reference each time
        slider.send_keys(Keys.ARROW_RIGHT)
        t = page_time(browser)
        statuses = dom_statuses(browser)
        assert statuses == reference_statuses(run, t), t
        seen |= {(node, status) for node, status in statuses.items()}
    assert (names["TakeOff"], "SUCCESS") in seen and (names["LookAround"], "RUNNING") in seen
    set_slider(browser, 0.6)
    t = page_time(browser)
    assert dom_statuses(browser) == reference_statuses(run, t)
    robot_mid = browser.execute_script("return amslamViewer.robot()")
    assert robot_mid != robot_start
    slider.send_keys(Keys.END)
    assert dom_statuses(browser)[names["Mission"]] == "SUCCESS"
    assert dom_statuses(browser)[names["Land"]] == "SUCCESS"
    wall = [c for c in run.static["floors"][0]["cells"] if c[2] >= 4][0]  # a wall column is drawn dark
    assert max(pixel(browser, wall[0], wall[1])[:3]) < 140
    browser.save_screenshot(str(tmp_path / "real.png"))
    assert js_errors(browser) == []


@pytest.mark.skipif(find_chromium() is None, reason=f"no headless browser: {INSTALL_HINT}")
def test_cli_screenshot(tmp_path, capsys):
    folder = synthetic.write_run(tmp_path / "run")
    png = tmp_path / "shot.png"
    assert main(["view", str(folder), "--screenshot", str(png), "--time", "7"]) == 0
    header = png.read_bytes()[:24]
    assert header.startswith(b"\x89PNG")
    width, height = struct.unpack(">II", header[16:24])
    assert (width, height) == (1440, 900)
    assert f"screenshot: {png}" in capsys.readouterr().out


def test_a_crafted_run_folder_runs_no_script_in_the_page(browser, tmp_path):
    """Strings from events.jsonl, metrics.json and tree.jsonl are shown as text, never as markup."""
    import json

    folder = synthetic.write_run(tmp_path / "run")
    attack = '<img src=x onerror="window.__pwned=1">'
    events = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    events[1]["event"] = attack
    events[1]["t"] = attack  # a time that is not a number goes through the page's number formatter
    (folder / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    metrics = json.loads((folder / "metrics.json").read_text())
    metrics["explored_percent_per_floor"] = [attack]
    metrics["verdict"] = attack
    (folder / "metrics.json").write_text(json.dumps(metrics))
    open_page(browser, build_page(folder).as_uri())
    shown = browser.page_source.replace("&lt;", "<").replace("&gt;", ">")
    assert attack in shown  # as text
    assert browser.execute_script("return window.__pwned === undefined")
