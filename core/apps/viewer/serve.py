"""``amslam view RUN --serve``: the replay page on localhost, following a run while it is written.

``GET /`` returns the page with the run as it is now and a cursor (byte offsets per stream);
the page then polls ``GET /api/poll?cursor=...`` for the lines written since, and extends its
timeline. The server keeps no state per client: everything it needs is in the cursor.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from amslam.apps.viewer.build import embed_json, page_data, render_page
from amslam.apps.viewer.runfiles import poll_run

POLL_PATH = "/api/poll"


def _handler(run_dir: Path, interval_ms: int) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "amslam-view"

        def do_GET(self) -> None:  # noqa: N802 — http.server's naming
            url = urlparse(self.path)
            if url.path in ("/", "/index.html"):
                live = {"endpoint": POLL_PATH, "interval": interval_ms}
                self._send(200, "text/html; charset=utf-8", render_page(page_data(run_dir, live)))
            elif url.path == POLL_PATH:
                raw = parse_qs(url.query).get("cursor", ["{}"])[0]
                try:
                    cursor = {str(k): int(v) for k, v in json.loads(raw).items()}
                except (ValueError, TypeError, AttributeError):
                    self._send(400, "text/plain", "cursor: expected a JSON object of byte offsets")
                    return
                body = embed_json(poll_run(run_dir, cursor).to_json())
                self._send(200, "application/json", body)
            else:
                self._send(404, "text/plain", "not found")

        def _send(self, code: int, kind: str, body: str) -> None:
            payload = body.encode("utf-8")
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(payload)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(payload)

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
        self.httpd = ThreadingHTTPServer(("127.0.0.1", port), _handler(self.run_dir, int(interval * 1000)))
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
