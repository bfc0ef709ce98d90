"""``drona replay RECORD [--workspace W] [--port P] [--host H]``: play a recorded run back on a map.

Builds the replay document (:func:`drona_gcs.replay.replay_document`: the frames,
``drona audit``'s findings and the workspace's geometry) and serves it with the
page ``api/static/replay.html`` from a small HTTP server of the standard
library, on 127.0.0.1 unless ``--host`` says otherwise. Everything the page
loads comes from this server (Leaflet is vendored): nothing is fetched from
outside. It prints the URL and serves until Ctrl-C or SIGTERM.

Without ``--workspace`` the run is taken for one of ``drona demo``'s embedded
campus. Exit 0 when stopped, 2 on unusable input (no such file, a malformed
line, a record of another workspace) or a port it cannot listen on.
"""

from __future__ import annotations

import argparse
import json
import mimetypes
import re
import signal
import sys
import threading
from functools import partial
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import FrameType
from typing import Any

from drona_gcs.errors import DronaError
from drona_gcs.replay import replay_document
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import load_workspace, workspace_from_mapping
from fleet.cli.audit import read_records

STATIC_DIR = Path(__file__).resolve().parents[2] / "api" / "static"
DEFAULT_PORT = 8020


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("record", type=Path, help="a JSON Lines file written by --record")
    parser.add_argument("--workspace", type=Path, help="the workspace the run flew in (default: drona demo's campus)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0: any free)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")


def run(args: argparse.Namespace) -> int:
    try:
        document = load_document(args.record, args.workspace)
        server = make_server(document, args.host, args.port)
    except (DronaError, OSError, ValueError) as exc:
        print(f"drona replay: {exc}", file=sys.stderr)
        return 2
    with server:
        host, port = server.server_address[:2]
        summary = document["summary"]
        print(f"drona replay: {args.record.name} on {document['workspace']['name']}, steps "
              f"{document['first_step']}..{document['last_step']}, {summary['violations']} violations, "
              f"{summary['deviations']} off the plan, {summary['jumps']} jumps", flush=True)
        print(f"drona replay: listening on http://{_url_host(str(host))}:{port}/ (Ctrl-C stops)", flush=True)
        _serve_until_stopped(server)
    return 0


def load_document(record: Path, workspace_file: Path | None) -> dict[str, Any]:
    """The replay document; a DronaError or OSError names the file and what is wrong in it."""
    records = list(read_records([record]))
    workspace = load_workspace(workspace_file) if workspace_file else _demo_workspace(records)
    try:
        return replay_document(workspace, records)
    except DronaError as exc:  # the core numbers records: say which file they are in
        raise DronaError(f"{record}: {exc}") from exc


def _demo_workspace(records: list[dict[str, object]]) -> Workspace:
    """``drona demo``'s campus with as many drones as the run's highest ``d<i>`` (d1..dN fly there)."""
    from fleet.cli.demo import demo_workspace

    numbers = [int(m.group(1)) for r in records if (m := re.fullmatch(r"d(\d+)", str(r.get("drone"))))]
    drones = min(max(numbers, default=1), 16)
    return workspace_from_mapping(demo_workspace(drones, 1.0), source="drona demo's campus", name="demo-campus")


def make_server(document: dict[str, Any], host: str, port: int) -> ThreadingHTTPServer:
    body = json.dumps(document, separators=(",", ":")).encode()
    try:
        server = ThreadingHTTPServer((host, port), partial(ReplayHandler, body))
    except OSError as exc:
        raise OSError(f"cannot listen on {host}:{port}: {exc.strerror or exc} (--port 0 picks a free port)") from exc
    server.daemon_threads = True  # a browser's open keep-alive connection must not hold the exit
    return server


class ReplayHandler(BaseHTTPRequestHandler):
    """``/``: the page; ``/replay.json``: the document; ``/static/...``: the service's static files."""

    protocol_version = "HTTP/1.1"

    def __init__(self, document: bytes, *args: Any, **kwargs: Any) -> None:
        self.document = document
        super().__init__(*args, **kwargs)

    def do_GET(self) -> None:
        path = self.path.split("?", 1)[0]
        if path in ("/", "/replay.html"):
            self._file(STATIC_DIR / "replay.html")
        elif path == "/replay.json":
            self._send(HTTPStatus.OK, "application/json", self.document)
        elif path.startswith("/static/"):
            self._file(STATIC_DIR / path.removeprefix("/static/"))
        else:
            self._send(HTTPStatus.NOT_FOUND, "text/plain; charset=utf-8", b"not found\n")

    def _file(self, path: Path) -> None:
        resolved = path.resolve()
        # Only files under the static folder: "/static/../../etc/passwd" stays out.
        if not resolved.is_relative_to(STATIC_DIR) or not resolved.is_file():
            self._send(HTTPStatus.NOT_FOUND, "text/plain; charset=utf-8", b"not found\n")
            return
        kind = mimetypes.guess_type(resolved.name)[0] or "application/octet-stream"
        if kind.startswith("text/") or kind.endswith("javascript"):
            kind += "; charset=utf-8"
        self._send(HTTPStatus.OK, kind, resolved.read_bytes())

    def _send(self, status: HTTPStatus, kind: str, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-cache")
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format: str, *args: Any) -> None:
        """Quiet: a page's requests are not news."""


def _serve_until_stopped(server: ThreadingHTTPServer) -> None:
    """Serve until Ctrl-C or SIGTERM; both end with exit 0."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = signal.signal(signal.SIGTERM, on_signal)
    thread = threading.Thread(target=server.serve_forever, name="replay-http", daemon=True)
    thread.start()
    try:
        stop.wait()
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        server.shutdown()
        thread.join()


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host
