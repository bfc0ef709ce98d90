"""``drona serve`` as a process: start-up refusals, SSE, kill -9 during a burst, the request head's limit,
schemathesis on the document."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx

from api.main import MAX_HEAD_BYTES
from tests.api.conftest import OPERATOR, REPO, ServiceProcess, auth, run


def serve(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "fleet.cli", "serve", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})},
                          check=False)


def test_serve_refuses_to_start_without_a_token_or_workspace(workspace_file: Path, tmp_path: Path) -> None:
    no_token = {"DRONA_API_TOKENS": "", "DRONA_API_TOKEN_FILE": ""}
    res = serve("--workspace", str(workspace_file), "--db", str(tmp_path / "x.db"), "--gateway", "simulated",
                env=no_token)
    assert res.returncode == 2 and "no API token" in res.stderr
    res = serve("--db", str(tmp_path / "x.db"), "--gateway", "simulated",
                env={"DRONA_API_TOKENS": f"operator:{OPERATOR}"})
    assert res.returncode == 2 and "no workspace" in res.stderr
    res = serve("--workspace", str(tmp_path / "missing.yaml"), "--gateway", "simulated",
                env={"DRONA_API_TOKENS": f"operator:{OPERATOR}"})
    assert res.returncode == 2 and "missing.yaml" in res.stderr
    assert not (tmp_path / "x.db").exists()


def events(url: str, token: str, until: Any, timeout: float = 20.0) -> list[tuple[str, dict[str, Any]]]:
    """Read /v1/events until ``until(seen)`` holds; every (event, data) seen."""
    seen: list[tuple[str, dict[str, Any]]] = []
    deadline = time.monotonic() + timeout
    with httpx.stream("GET", f"{url}/v1/events", params={"access_token": token}, timeout=5.0) as res:
        assert res.status_code == 200 and res.headers["content-type"].startswith("text/event-stream")
        kind = ""
        for line in res.iter_lines():
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: "):
                seen.append((kind, json.loads(line[6:])))
                if until(seen):
                    return seen
            assert time.monotonic() < deadline, f"no end in {timeout} s; saw {len(seen)} events"
    return seen


def test_events_stream_drone_states_and_mail_changes(service: ServiceProcess) -> None:
    assert httpx.get(f"{service.url}/v1/events").status_code == 401
    first = events(service.url, OPERATOR, lambda seen: {d["id"] for k, d in seen if k == "drone"} >= {"d1", "d2",
                                                                                                       "d3"})
    assert all(k == "drone" and "battery_pct" in d for k, d in first)
    created = httpx.post(f"{service.url}/v1/mail", json={"pickup": [1, 2, 0], "dropoff": [3, 6, 0], "priority": 4},
                         headers=auth())
    mail_id = created.json()["id"]

    def delivered(seen: list[tuple[str, dict[str, Any]]]) -> bool:
        return any(k == "mail" and d["id"] == mail_id and d["status"] == "delivered" for k, d in seen)

    seen = events(service.url, OPERATOR, delivered)
    statuses = [d["status"] for k, d in seen if k == "mail" and d["id"] == mail_id]
    assert statuses[-1] == "delivered"
    assert any(k == "drone" and d["task"] and d["task"]["mail_id"] == mail_id for k, d in seen)


async def burst(url: str, count: int, kill_after: int, kill: Any) -> tuple[list[str], int]:
    """Submit ``count`` mails over 16 connections; kill the service once ``kill_after`` got their 201."""
    acked: list[str] = []
    lost = 0
    limits = httpx.Limits(max_connections=16)
    async with httpx.AsyncClient(base_url=url, limits=limits, timeout=10.0) as client:
        async def one(i: int) -> None:
            nonlocal lost
            try:
                res = await client.post("/v1/mail", headers={**auth(), "Idempotency-Key": f"burst-{i}"},
                                        json={"pickup": [1 + i % 3, 1, 0], "dropoff": [7, 1 + i % 6, 0],
                                              "priority": i % 10})
            except httpx.TransportError:
                lost += 1
                return
            assert res.status_code == 201, res.text
            acked.append(res.json()["id"])
            if len(acked) == kill_after:
                kill()

        await asyncio.gather(*(one(i) for i in range(count)))
    return acked, lost


def test_every_acknowledged_mail_survives_kill_9_and_is_delivered(workspace_file: Path, tmp_path: Path) -> None:
    """Killed in the middle of a burst; restarted on the same file, it has and delivers every mail it acknowledged.

    The first service's simulated drones stand still (a step of an hour), so nothing is on board a
    drone that dies with it: what the restart must do is find every mail and finish the assigned ones,
    which no drone of the new fleet mentions (requeued after the 1 s assign timeout)."""
    db = tmp_path / "mail.db"
    first = ServiceProcess(workspace_file, db, sim_step=3600)
    try:
        acked, lost = run(burst(first.url, 300, kill_after=100, kill=first.kill))
    finally:
        first.kill()
    assert first.proc.returncode == -9
    assert len(acked) >= 100 and lost > 0, (len(acked), lost)  # killed in the middle of the burst
    second = ServiceProcess(workspace_file, db, "--sim-drones", "8", sim_step=0.002,
                            env={"DRONA_API_ASSIGN_TIMEOUT_S": "1", "DRONA_API_PER_DRONE": "4"})
    try:
        for mail_id in acked:
            res = httpx.get(f"{second.url}/v1/mail/{mail_id}", headers=auth())
            assert res.status_code == 200, mail_id
        remaining = set(acked)

        def all_delivered(seen: list[tuple[str, dict[str, Any]]]) -> bool:
            kind, data = seen[-1]
            if kind == "mail" and data["status"] == "delivered":
                remaining.discard(data["id"])
            return not remaining

        page = httpx.get(f"{second.url}/v1/mail", params={"status": "delivered", "limit": 500}, headers=auth()).json()
        remaining -= {m["id"] for m in page["items"]}
        if remaining:
            events(second.url, OPERATOR, all_delivered, timeout=40.0)
        assert not remaining
    finally:
        assert second.stop() == 0


def exchange(url: str, request: bytes) -> tuple[bytes, bool]:
    """Send ``request`` raw on a new connection: the answer, and whether the service cut the sending short."""
    where = urlsplit(url)
    with socket.create_connection((where.hostname, where.port), timeout=10) as sock:
        cut = False
        try:
            sock.sendall(request)
            sock.shutdown(socket.SHUT_WR)
        except (BrokenPipeError, ConnectionResetError):
            cut = True
        answer = b""
        with contextlib.suppress(ConnectionResetError):  # closed with our bytes unread: the answer may be lost
            while chunk := sock.recv(65536):
                answer += chunk
    return answer, cut


def head_of(padding: int) -> bytes:
    """A GET /healthz (no token needed: a 200 if the app sees it) with a header ``padding`` bytes long."""
    return b"GET /healthz HTTP/1.1\r\nHost: test\r\nConnection: close\r\nX-Padding: " + b"a" * padding + b"\r\n\r\n"


def test_a_request_head_over_the_limit_is_refused_unread(service: ServiceProcess) -> None:
    """Under the limit, served; over it, a 431 and not the route's answer; 10 MB, cut short by the
    server (uvicorn's h11) before the head is complete; and the service lives on."""
    answer, _ = exchange(service.url, head_of(MAX_HEAD_BYTES // 2))
    assert answer.startswith(b"HTTP/1.1 200 "), answer[:200]
    answer, _ = exchange(service.url, head_of(MAX_HEAD_BYTES + 1024))
    assert answer.startswith(b"HTTP/1.1 431 "), answer[:200]
    answer, cut = exchange(service.url, head_of(10 * 1024 * 1024))
    assert cut, answer[:200]  # read whole, it would have had its 431
    assert not answer or answer.startswith(b"HTTP/1.1 400 "), answer[:200]
    assert httpx.get(f"{service.url}/healthz").status_code == 200


def test_schemathesis_finds_no_server_error_and_no_schema_violation(service: ServiceProcess, tmp_path: Path) -> None:
    """Every check but positive_data_acceptance: a schema-valid cell may still be on an obstacle (a 422)."""
    res = subprocess.run(
        [str(Path(sys.executable).parent / "schemathesis"), "run", f"{service.url}/openapi.json",
         "-H", f"Authorization: Bearer {OPERATOR}", "--exclude-path", "/v1/events",
         "--checks", "all", "--exclude-checks", "positive_data_acceptance", "--max-time", "15",
         "--report", "junit", "--report-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=120, check=False, cwd=tmp_path)
    summary = res.stdout[-3000:]
    assert res.returncode == 0, summary
    assert "Server error" not in summary and "passed" in summary
