"""`drona serve` dispatching to real agents over Zenoh: a dead agent never leaves a mail stuck."""

from __future__ import annotations

import json
import signal
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from fleet.sim.ports import free_port_block
from tests.integration.harness import FleetProcesses

pytestmark = pytest.mark.slow
TOKEN = "service-fleet-token-0123456789"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}


class Events:
    """The service's /v1/events stream, read from the moment it is made until the service goes, folded into
    the latest mail and drone states: nothing that happens between two waits is missed."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.mail: dict[str, dict[str, Any]] = {}
        self.drones: dict[str, dict[str, Any]] = {}
        self.lost: set[str] = set()
        self._changed = threading.Condition()
        self._connected = threading.Event()
        self._ended: BaseException | None = None
        threading.Thread(target=self._read, name="events", daemon=True).start()
        if not self._connected.wait(10):
            raise AssertionError(f"no event stream from {url} within 10 s")

    def until(self, condition: Callable[[], bool], timeout: float, what: str, logs: Callable[[], str]) -> None:
        deadline = time.monotonic() + timeout
        with self._changed:
            while not condition():
                left = deadline - time.monotonic()
                if left <= 0 or self._ended is not None:
                    ended = f" (the stream ended: {self._ended!r})" if self._ended else ""
                    raise AssertionError(f"timed out after {timeout:g} s waiting for {what}{ended}: {self.mail}\n"
                                         f"{logs()}")
                self._changed.wait(left)

    def status(self, mail: str) -> str | None:
        return self.mail.get(mail, {}).get("status")

    def _read(self) -> None:
        try:
            with httpx.stream("GET", f"{self.url}/v1/events", params={"access_token": TOKEN},
                              timeout=httpx.Timeout(10.0, read=60.0)) as stream:
                kind = ""
                for line in stream.iter_lines():
                    self._connected.set()  # the first line comes once the service subscribed this stream
                    if line.startswith("event: "):
                        kind = line[7:]
                    elif line.startswith("data: "):
                        with self._changed:
                            self._take(kind, json.loads(line[6:]))
                            self._changed.notify_all()
            raise ConnectionError("the service closed the stream")
        except Exception as exc:  # reported by the next wait
            with self._changed:
                self._ended = exc
                self._changed.notify_all()

    def _take(self, kind: str, data: dict[str, Any]) -> None:
        if kind == "mail":
            self.mail[data["id"]] = data
        elif kind == "drone":
            self.drones[data["id"]] = data
        elif kind == "drone_lost":
            self.lost.add(data["id"])


def start_service(fleet: FleetProcesses, db: Path) -> str:
    port = free_port_block(1, socket.SOCK_STREAM)
    arguments = ["serve", "--workspace", str(fleet.workspace), "--db", str(db), "--port", str(port), "--demo",
                 "--token", TOKEN, "--fleet", fleet.fleet, "--log-level", "warning"]
    for drone in fleet.drones:
        arguments += ["--connect", fleet.endpoint(drone)]
    fleet.spawn("serve", arguments)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:  # the port answers once uvicorn is up: nothing to wait on but it
        try:
            if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                return url
        except httpx.TransportError:
            pass
        time.sleep(0.2)  # not up yet, or up but not yet linked to the fleet (503)
    raise AssertionError(f"the service did not come up\n{fleet.logs()}")


def test_a_dead_agent_never_leaves_its_mail_stuck_and_another_drone_delivers_it(tmp_path: Path) -> None:
    fleet = FleetProcesses(tmp_path, ["d1", "d2"], agent_options=("--no-adopt-mail",))
    fleet.start()
    try:
        url = start_service(fleet, tmp_path / "mail.db")
        events = Events(url)
        # Both parked: d1 nearer the first pickup than d2, so the service gives it to d1.
        events.until(lambda: set(events.drones) == {"d1", "d2"} and all(
            d["phase"] == "idle" and d["health"]["ok"] for d in events.drones.values()), 60, "both drones parked",
            fleet.logs)
        first = httpx.post(f"{url}/v1/mail", headers=HEADERS, timeout=10,
                           json={"pickup": [2, 2, 0], "dropoff": [7, 7, 0], "priority": 9}).json()["id"]
        events.until(lambda: events.status(first) in ("assigned", "picked_up"), 30, "the first mail assigned",
                     fleet.logs)
        busy, idle = events.mail[first]["drone"], "d2"
        assert busy == "d1", f"the first mail went to {busy}: alone, only d1 (first by name) is a quorum of two"
        fleet.signal(idle, signal.SIGSTOP)  # frozen: the service still sees it, and will give it the next mail
        second = httpx.post(f"{url}/v1/mail", headers=HEADERS, timeout=10,
                            json={"pickup": [8, 2, 0], "dropoff": [2, 8, 0], "priority": 5}).json()["id"]
        fleet.signal(idle, signal.SIGKILL)
        events.until(lambda: events.status(first) == events.status(second) == "delivered", 150,
                     "both mails delivered", fleet.logs)
        assert events.mail[second]["drone"] == busy
        history = httpx.get(f"{url}/v1/mail/{second}", headers=HEADERS, timeout=10).json()["history"]
        steps = [(h["status"], h["drone"]) for h in history]
        # It went to the frozen drone first (the idle one), came back when that drone died, then flew.
        assert ("assigned", idle) in steps and steps[-1] == ("delivered", busy), steps
        assert steps.index(("assigned", idle)) < steps.index(("assigned", busy))
        assert all(status != "failed" for status, _ in steps)
    finally:
        fleet.kill_all()
