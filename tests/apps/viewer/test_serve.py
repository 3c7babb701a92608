"""``amslam view --serve``: the page and the poll endpoint follow a run while it is written."""

from __future__ import annotations

import json
import re
import urllib.error
import urllib.parse
import urllib.request

import pytest

from amslam.apps.viewer import LiveServer
from tests.apps.viewer import synthetic


def get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.read().decode()
    except urllib.error.HTTPError as err:
        return err.code, err.read().decode()


def poll(server: LiveServer, cursor: dict) -> dict:
    status, body = get(server.url + "api/poll?cursor=" + urllib.parse.quote(json.dumps(cursor)))
    assert status == 200
    return json.loads(body)


def test_page_then_polls_follow_the_run(tmp_path):
    run = synthetic.write_run(tmp_path / "run", until=4.0)
    with LiveServer(run, port=0) as server:
        assert server.url.startswith("http://127.0.0.1:")
        status, html = get(server.url)
        assert status == 200
        data = json.loads(re.search(r'id="amslam-data">(.*?)</script>', html, re.S).group(1))
        live = data["live"]
        assert live["endpoint"] == "/api/poll" and not live["finished"]
        assert [r[0] for r in data["tree"]] == [0.1, 2.0, 2.1]
        nothing = poll(server, live["cursor"])
        assert nothing["tree"] == [] and nothing["events"] == [] and nothing["traj"]["vio"] == []
        synthetic.write_run(run, until=9.5)
        more = poll(server, live["cursor"])
        assert [r[0] for r in more["tree"]] == [6.0]
        assert [e["event"] for e in more["events"]] == ["goal_done", "replan", "loop_closure"]
        assert more["traj"]["ground_truth"][-1][0] == 9.5 and not more["finished"]
        synthetic.write_run(run)
        done = poll(server, more["cursor"])
        assert done["finished"] and done["static"]["landmarks"] and "slam" in done["reset"]


@pytest.mark.parametrize(
    ("path", "code"),
    [
        ("api/poll?cursor=not-json", 400),
        ("api/poll?cursor=" + urllib.parse.quote('{"events": -5}'), 400),
        ("api/poll?cursor=" + urllib.parse.quote('{"events": 1e400}'), 400),
        ("api/poll?cursor=" + urllib.parse.quote('{"events": 1.5}'), 400),
        ("api/poll?cursor=" + urllib.parse.quote("[1, 2]"), 400),
        ("api/poll?cursor=" + urllib.parse.quote('{"events": true}'), 400),
        ("nope", 404),
    ],
)
def test_bad_requests(tmp_path, path, code, capfd):
    run = synthetic.write_run(tmp_path / "run")
    with LiveServer(run, port=0) as server:
        status, body = get(server.url + path)
    assert status == code
    assert len(body.splitlines()) == 1
    assert "Traceback" not in capfd.readouterr().err


def test_a_foreign_host_is_refused(tmp_path):
    """DNS rebinding: a page of evil.example whose name now points at 127.0.0.1."""
    run = synthetic.write_run(tmp_path / "run")
    with LiveServer(run, port=0) as server:
        request = urllib.request.Request(server.url, headers={"Host": "evil.example"})
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=10)
        assert refused.value.code == 400
        assert get(server.url.replace("127.0.0.1", "localhost"))[0] == 200
