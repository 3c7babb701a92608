"""``amslam view RUN --serve``: the replay page on localhost, following a run while it is written.

``GET /`` returns the page with the run as it is now and a cursor (byte offsets per stream);
the page then polls ``GET /api/poll?cursor=...`` for the lines written since, and extends its
timeline. The server keeps no state per client: everything it needs is in the cursor.

It serves 127.0.0.1 only, and answers only requests whose ``Host`` is this machine by name
(``127.0.0.1``, ``localhost``, ``[::1]``, with the server's port): a page of another site that
rebinds its DNS name to 127.0.0.1 cannot read the run through the visitor's browser. A bad
request gets a 4xx with one line saying why; a failure serving a good one a 500, never a
traceback in the terminal.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from amslam.apps.viewer.build import embed_json, page_data, render_page
from amslam.apps.viewer.runfiles import poll_run
from amslam.errors import AmslamError

POLL_PATH = "/api/poll"
#: largest byte offset a cursor may hold (JSON numbers are exact up to 2**53)
MAX_OFFSET = 2**53


def parse_cursor(raw: str) -> dict[str, int]:
    """A poll cursor: a JSON object of stream → byte offset, each a whole number in [0, 2**53]."""
    cursor = json.loads(raw)
    if not isinstance(cursor, dict):
        raise ValueError("not an object")
    out = {}
    for key, value in cursor.items():
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_OFFSET:
            raise ValueError(f"{key}: {value!r} is not a byte offset")
        out[str(key)] = value
    return out


def _handler(run_dir: Path, interval_ms: int) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "amslam-view"

        def do_GET(self) -> None:  # noqa: N802 — http.server's naming
            port = self.server.server_address[1]
            allowed = {f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}"}
            if self.headers.get("Host", "").lower() not in allowed:
                self._send(400, "text/plain", "Host: this server answers only 127.0.0.1, localhost or [::1]")
                return
            try:
                self._get()
            except Exception as exc:  # noqa: BLE001 — a client's request must not print a traceback
                self._send(500, "text/plain", f"{type(exc).__name__}: {exc}")

        def _get(self) -> None:
            url = urlparse(self.path)
            if url.path in ("/", "/index.html"):
                live = {"endpoint": POLL_PATH, "interval": interval_ms}
                self._send(200, "text/html; charset=utf-8", render_page(page_data(run_dir, live)))
            elif url.path == POLL_PATH:
                raw = parse_qs(url.query).get("cursor", ["{}"])[0]
                try:
                    cursor = parse_cursor(raw)
                except ValueError as exc:  # json.JSONDecodeError is a ValueError
                    self._send(400, "text/plain", f"cursor: expected a JSON object of byte offsets ({exc})")
                    return
                body = embed_json(poll_run(run_dir, cursor).to_json())
                self._send(200, "application/json", body)
            else:
                self._send(404, "text/plain", "not found")

        def _send(self, code: int, kind: str, body: str) -> None:
            payload = body.encode("utf-8")
            try:
                self.send_response(code)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(payload)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(payload)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the client went away: nothing to tell it

        def log_message(self, format, *args) -> None:  # noqa: A002 — quiet: one line per poll is noise
            pass

    return Handler


class LiveServer:
    """An HTTP server for one run folder on a background thread.

    Args:
        run_dir: the run folder (may still be written by a running mission).
        port: TCP port on 127.0.0.1; 0 picks a free one.
        interval: seconds between the page's polls.
    """

    def __init__(self, run_dir: Path, port: int = 0, interval: float = 1.0):
        self.run_dir = Path(run_dir)
        try:
            self.httpd = ThreadingHTTPServer(
                ("127.0.0.1", port), _handler(self.run_dir, int(interval * 1000))
            )
        except OSError as exc:  # the port is taken, or not ours to open
            raise AmslamError(f"cannot serve on 127.0.0.1:{port}: {exc.strerror or exc}") from None
        self.httpd.daemon_threads = True
        self.thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host}:{port}/"

    def start(self) -> str:
        """Serve in a daemon thread; returns the page's URL."""
        self.thread = threading.Thread(target=self.httpd.serve_forever, name="amslam-view", daemon=True)
        self.thread.start()
        return self.url

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        if self.thread is not None:
            self.thread.join(timeout=5)

    def __enter__(self) -> LiveServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
